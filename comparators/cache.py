"""The results cache: each run's trajectory stored once, under a key of everything it depends on.

The key hashes the case's content (its TOML), engine, integrator, dt, timing repeats, the
duration where a run (an animation's) covers other than the case's, the versions of the packages
that compute results, the code version (a hash of the sources of
`cases`, `reference_sim` and `comparators`) and the sources of the package that defines the
engine (a plugin's own code). Re-running after a change recomputes only what the
change can affect. Entries are Parquet files written atomically (temporary name, then rename), so
a sweep killed midway leaves only complete entries.

Each entry carries its key and a checksum of its content (`Trajectory.write`'s stamp). An entry
that cannot be read (truncated, garbage), holds another key's run, fails its checksum, or has no
stamp (written by an older rigidbench) is reported in one `CacheWarning`, moved aside into
`discarded/` and treated as missing, so the run is computed again: a bad entry costs a rerun,
never a crash or a wrong result.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import warnings
from functools import cache
from pathlib import Path

import pyarrow.parquet as pq

from cases.toml_io import scene_to_toml
from comparators.engine import ENGINES
from comparators.trajectory import STAMP_KEY, Trajectory, package_versions

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


class CacheWarning(UserWarning):
    """A results-cache entry was discarded; the message is one line naming the file and why."""


DISCARDED = "discarded"  # the folder inside the cache where discarded entries are moved
MAX_REASON_CHARS = 200  # of an exception's message quoted in a warning


class ResultsCache:
    """Trajectories by run key, as Parquet files in one directory."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> Path:
        return self.root / f"{key}.parquet"

    def get(self, key: str) -> Trajectory | None:
        """The trajectory stored under `key`, or None: none stored, or the entry was bad (it
        is then discarded with a `CacheWarning`)."""
        path = self.path(key)
        if not path.exists():
            return None
        try:
            traj, stamp, checksum = Trajectory.read_stamped(path)
        except Exception as exc:  # whatever a damaged file makes the reader raise
            return self._discard(path, f"is unreadable ({_exception_line(exc)})")
        reason = _stamp_problem(stamp, key)
        if reason is None and stamp["checksum"] != checksum:
            reason = "fails its checksum (its content changed after it was written)"
        return traj if reason is None else self._discard(path, reason)

    def has(self, key: str) -> bool:
        """Whether an entry is stored under `key` and its stamp names `key`, read from the
        file's footer alone (the content's checksum is checked by `get`). A bad entry is
        discarded as by `get`."""
        path = self.path(key)
        if not path.exists():
            return False
        try:
            metadata = pq.read_schema(path).metadata or {}
            stamp = json.loads(metadata[STAMP_KEY]) if STAMP_KEY in metadata else None
        except Exception as exc:
            reason = f"is unreadable ({_exception_line(exc)})"
        else:
            reason = _stamp_problem(stamp, key)
        if reason is None:
            return True
        self._discard(path, reason)
        return False

    def put(self, key: str, traj: Trajectory) -> None:
        traj.write(self.path(key), stamp={"key": key})

    def _discard(self, path: Path, reason: str) -> None:
        """Move a bad entry aside (or delete it), warn in one line; None, as a miss."""
        aside = self.root / DISCARDED / path.name
        try:
            aside.parent.mkdir(exist_ok=True)
            os.replace(path, aside)
            fate = f"moved to {aside.as_posix()}"
        except OSError:
            try:
                path.unlink(missing_ok=True)
                fate = "deleted"
            except OSError as exc:
                fate = f"could not be removed ({_exception_line(exc)})"
        message = f"cache entry {path.as_posix()} {reason}: discarded ({fate}), recomputing"
        warnings.warn(message, CacheWarning, stacklevel=3)
        return None


def _stamp_problem(stamp, key: str) -> str | None:
    """What is wrong with an entry's stamp for `key`, or None."""
    if not isinstance(stamp, dict) or "key" not in stamp or "checksum" not in stamp:
        return "has no key or checksum (written by an older rigidbench)"
    if stamp["key"] != key:
        return f"holds the run of another key ({str(stamp['key'])[:64]})"
    return None


def _exception_line(exc: BaseException) -> str:
    first = (str(exc).splitlines() or [""])[0][:MAX_REASON_CHARS]
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__
