"""Sweeps: the matrix case x engine x integrator x dt, run once each through the results cache.

`plan` lists the runs, `run_sweep` executes the missing ones on an executor (a local process
pool, or a Dask cluster), stores every trajectory in the cache as it arrives, and returns a
`SweepResult`: one tidy row per run with the metrics computed by the suite, plus the
trajectories for plots.

Reference solutions: contact-free cases are measured against the exact solution
(`cases.exact`); contact cases against the same engine and integrator at the sweep's finest dt
(self-convergence), labelled as such, plus the closed-form rest height where the case states one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd

from cases.scene import Scene
from comparators.trajectory import Trajectory

# One row per run. Errors are maxima over the run; drifts are relative (comparators.metrics).
RESULT_COLUMNS = [
    "case",
    "engine",
    "integrator",
    "dt",
    "duration",
    "steps",
    "repeats",
    "setup_s",
    "wall_s",  # median over repeats, stepping only
    "wall_min_s",
    "wall_max_s",
    "steps_per_s",
    "realtime_factor",
    "energy_drift",
    "momentum_drift",
    "angular_momentum_drift",
    "position_error",  # m, against `reference`
    "orientation_error_deg",  # degrees, against `reference`
    "reference",  # "exact" or "self-convergence (dt=...)"
    "shape_error",  # seed only, else NaN
    "rest_com_height",  # where the case predicts rest, else NaN
    "rest_height_error",
    "verdict",  # "ok", "diverged" or "failed: <reason>"
    "engine_version",
    "code_version",
    "key",  # results-cache key; indexes SweepResult.trajectories
]


@dataclass
class SweepResult:
    """What a sweep produced.

    Attributes:
      scenes: the cases swept, by name, in report order.
      results: one row per run, columns `RESULT_COLUMNS`.
      trajectories: by `results["key"]`, for every run that produced one.
      references: per case, what its errors are measured against.
      elapsed_s: wall time of the whole sweep; machine: CPU, cores, Python and library versions.
      executor: how runs were executed ("local process pool, 2 workers", "dask at ...").
      computed, cached: how many runs were computed now and how many came from the cache.
    """

    scenes: dict[str, Scene]
    results: pd.DataFrame
    trajectories: dict[str, Trajectory]
    references: dict[str, str]
    elapsed_s: float
    machine: dict[str, str]
    executor: str
    computed: int = 0
    cached: int = 0
    orders: dict[tuple[str, str], int] = field(default_factory=dict)  # (engine, integrator)
