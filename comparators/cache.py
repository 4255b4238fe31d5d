"""The results cache: each run's trajectory stored once, under a key of everything it depends on.

The key hashes the case's content (its TOML), engine, integrator, dt, timing repeats, the
duration where a run (an animation's) covers other than the case's, the versions of the packages
that compute results, the code version (a hash of the sources of
`cases`, `reference_sim` and `comparators`) and the sources of the package that defines the
engine (a plugin's own code). Re-running after a change recomputes only what the
change can affect. Entries are Parquet files written atomically (temporary name, then rename), so
a sweep killed midway leaves only complete entries.
"""

from __future__ import annotations

import hashlib
import importlib
import json
from functools import cache
from pathlib import Path

from cases.toml_io import scene_to_toml
from comparators.engine import ENGINES
from comparators.trajectory import Trajectory, package_versions

ROOT = Path(__file__).resolve().parent.parent
CODE_PACKAGES = ("cases", "reference_sim", "comparators")
RESULT_PACKAGES = ("numba", "scipy", "mujoco", "pybullet", "drake", "dartpy")


def _sources_digest(files: list[Path], root: Path) -> str:
    digest = hashlib.sha256()
    for path in files:
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


@cache
def code_version() -> str:
    """Hash of the sources that compute results (the report's own code is not part of it)."""
    files = [path for package in CODE_PACKAGES for path in sorted((ROOT / package).rglob("*.py"))]
    return _sources_digest(files, ROOT)


@cache
def engine_code(engine: str) -> str:
    """Hash of the sources of the top-level package that defines `engine`'s class, so that an
    edit to a plugin recomputes its runs."""
    module = importlib.import_module(type(ENGINES[engine]).__module__.split(".")[0])
    if not hasattr(module, "__path__"):  # a single-file module
        path = Path(module.__file__)
        return _sources_digest([path], path.parent)
    root = Path(next(iter(module.__path__)))
    return _sources_digest(sorted(root.rglob("*.py")), root)


def run_key(
    scene, engine: str, integrator: str, dt: float, repeats: int, duration: float | None = None
) -> str:
    """The cache key of one run; `duration` (s) when it is not the scene's own."""
    payload = {
        "scene": scene_to_toml(scene),
        "engine": engine,
        "integrator": integrator,
        "dt": repr(float(dt)),
        "repeats": int(repeats),
        "versions": package_versions(*RESULT_PACKAGES),
        "code": code_version(),
        "engine_code": engine_code(engine),
    }
    if duration is not None and duration != scene.duration:
        payload["duration"] = repr(float(duration))
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


class ResultsCache:
    """Trajectories by run key, as Parquet files in one directory."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> Path:
        return self.root / f"{key}.parquet"

    def get(self, key: str) -> Trajectory | None:
        path = self.path(key)
        return Trajectory.read(path) if path.exists() else None

    def put(self, key: str, traj: Trajectory) -> None:
        traj.write(self.path(key))
