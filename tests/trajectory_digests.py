"""Digests of a fixed set of trajectories, to prove a change of structure changed no number.

`RUNS` covers every integrator of every engine, the contact cases and `cube_rain_8`. Running
this file writes `trajectory_digests.json` beside it, keyed by the host fingerprint: the digests
of a run are only comparable on the same CPU model and the same engine and numpy builds (numpy's
and the engines' kernels are chosen per CPU). Regenerate on the commit before a change, then
let `test_trajectory_digests.py` check the change against them:

    python tests/trajectory_digests.py
"""

import hashlib
import json
import platform
import sys
from importlib import metadata
from pathlib import Path

import numpy as np

DIGEST_FILE = Path(__file__).with_name("trajectory_digests.json")

CONTACT_CASES = (
    "dropped_cube",
    "resting_cube",
    "fast_impact",
    "cube_stack",
    "cube_collision",
    "bounce",
    "bounce_e0.3",
    "bounce_e0.8",
    "slide",
    "slide_oblique",
    "spin_down",
    "incline",
    "incline_stick",
)
RIGID = ("euler", "splitting", "rk4", "exact")

# (case, engine, integrator, dt or None for the case's own, duration or None for the case's own)
RUNS: tuple[tuple[str, str, str, float | None, float | None], ...] = (
    ("seed_cube", "reference", "seed", None, None),
    ("dropped_cube", "reference", "seed", None, None),
    ("cube_rain_8", "reference", "seed", None, None),
    *(("tumbling_box", "reference", i, 0.01, 3.0) for i in RIGID),
    *(("high_spin", "reference", i, None, 2.0) for i in RIGID),
    *((c, "reference", i, None, None) for c in CONTACT_CASES for i in RIGID),
    ("dropped_cube", "reference", "euler", 0.02, None),  # the restarted one-body solve
    *(("cube_rain_8", "reference", i, None, None) for i in RIGID),
    *(
        (c, "mujoco", i, None, d)
        for c, d in (("tumbling_box", 3.0), ("dropped_cube", None), ("bounce", None))
        for i in ("RK4", "Euler", "implicit", "implicitfast")
    ),
    ("cube_rain_8", "mujoco", "Euler", None, None),
    *(
        (c, "pybullet", i, None, d)
        for c, d in (("tumbling_box", 3.0), ("dropped_cube", None), ("bounce", None))
        for i in ("maximal", "multibody")
    ),
    ("cube_rain_8", "pybullet", "maximal", None, None),
)


def run_id(run) -> str:
    case, engine, integrator, dt, duration = run
    return f"{case}/{engine}/{integrator}/dt={dt or 'own'}/T={duration or 'own'}"


def host_fingerprint() -> str:
    """CPU model, the CPU numba compiles for (a virtual machine's model name, "AMD EPYC", hides
    whether it has AVX-512: numba's code, numpy's kernels and libm's differ with it), and the
    builds whose kernels decide the last bits of a trajectory."""
    from llvmlite.binding import get_host_cpu_name

    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    versions = [f"{n} {metadata.version(n)}" for n in ("numpy", "numba", "mujoco", "pybullet")]
    model = f"{model} ({get_host_cpu_name()})"
    return " | ".join([model, f"python {platform.python_version()}", *versions])


def digest(run) -> str:
    """sha256 of the trajectory table: body names and every float column's bytes, in order."""
    from cases import resolve_case
    from comparators import run as run_engine

    case, engine, integrator, dt, duration = run
    table = run_engine(resolve_case(case), engine, integrator, dt, duration).table
    h = hashlib.sha256()
    h.update("\n".join(table.columns).encode())
    h.update("\n".join(table["body"].astype(str)).encode())
    for column in table.columns.drop("body"):
        h.update(np.ascontiguousarray(table[column].to_numpy(dtype=np.float64)).tobytes())
    return h.hexdigest()


def main() -> int:
    stored = json.loads(DIGEST_FILE.read_text()) if DIGEST_FILE.exists() else {}
    digests = {}
    for run in RUNS:
        digests[run_id(run)] = digest(run)
        print(run_id(run), digests[run_id(run)][:16], flush=True)
    stored[host_fingerprint()] = digests
    DIGEST_FILE.write_text(json.dumps(stored, indent=1, sort_keys=True) + "\n")
    print(f"wrote {len(digests)} digests for {host_fingerprint()!r} to {DIGEST_FILE}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).parents[1]))
    sys.exit(main())
