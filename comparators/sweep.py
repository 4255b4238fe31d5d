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

import dataclasses
import itertools
import os
import platform
import time
from concurrent.futures import as_completed
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from cases.errors import InputError
from cases.exact import exact_trajectory_available
from cases.scene import Scene
from comparators import interrupt
from comparators.cache import RESULT_PACKAGES, ResultsCache, code_version, run_key
from comparators.engine import ENGINES, unsupported
from comparators.interrupt import worker_pool
from comparators.limits import check_run
from comparators.metrics import pose_errors_between
from comparators.outcomes import OUTCOME_COLUMNS, outcomes
from comparators.progress import Bar, stage
from comparators.summary import summarize
from comparators.timing import SWEEP_REPEATS, attempt_run, repeat_run, spread
from comparators.trajectory import Trajectory, package_versions
from reference_sim.compiled_cache import is_compiled
from reference_sim.simulate import COMPILE_GROUPS, COMPILE_STAGES, compile_stage, compile_stages

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
    "solver_sweeps",  # contact solver sweeps per solve, where the engine reports it, else NaN
    "solver_at_limit",  # contact solves stopped unconverged (iteration limit, stalled or cycling)
    "solver_subspace",  # the reference's subspace steps (direct solves) per solve, else NaN
    "solver_extrapolations",  # the reference's extrapolations per solve, else NaN
    "energy_drift",
    "energy_gain",  # largest rise of energy above its start, relative to verdict.energy_scale
    "momentum_drift",
    "angular_momentum_drift",
    "position_error",  # m, against `reference`
    "orientation_error_deg",  # degrees, against `reference`
    "reference",  # "exact" or "self-convergence (dt=...)"
    "shape_error",  # seed only, else NaN
    "rest_com_height",  # where the case predicts rest, else NaN
    "rest_height_error",
    "engine_messages",  # lines the engine printed or warned during the run (RunMeta.messages)
    "first_engine_message",  # the first of them, else NaN
    "verdict",  # comparators.verdict.VERDICTS (ok, diverged, dissipated, ...), "failed: ..."
    "engine_version",
    "code_version",
    "key",  # results-cache key; indexes SweepResult.trajectories
]
# One row per run and measured quantity (comparators.outcomes), long format.
OUTCOMES_COLUMNS = ["case", "engine", "integrator", "dt", *OUTCOME_COLUMNS]
_NUMERIC_OUTCOMES = ("dt", "measured", "expected", "error")


def empty_outcomes() -> pd.DataFrame:
    """An outcomes table without rows, with `OUTCOMES_COLUMNS` and their dtypes."""
    return pd.DataFrame(
        {c: pd.Series(dtype=float if c in _NUMERIC_OUTCOMES else object) for c in OUTCOMES_COLUMNS}
    )


@dataclass
class SweepResult:
    """What a sweep produced.

    Attributes:
      scenes: the cases swept, by name, in report order.
      results: one row per run, columns `RESULT_COLUMNS`.
      outcomes: one row per run with a trajectory and quantity it measures, columns
        `OUTCOMES_COLUMNS` (`comparators.outcomes.outcomes`, tagged with the run).
      trajectories: by `results["key"]`, for every run that produced one.
      references: per case, what its errors are measured against.
      elapsed_s: wall time of the whole sweep; machine: CPU, cores, Python and library versions.
      executor: how runs were executed ("local process pool, 2 workers", "dask at ...").
      computed, cached: how many runs were computed now and how many came from the cache.
      left_out: engines that could not run here and cases an engine does not model, one line
        each saying why.
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
    outcomes: pd.DataFrame = field(default_factory=empty_outcomes)
    left_out: list[str] = field(default_factory=list)  # `comparators.engine.left_out`


# dt sweeps as multiples of each case's default dt. Full: two octaves coarser and four finer
# reach the asymptotic range of every integrator on the exact cases; cases simulating more than
# LONG_CASE_S (long-run drift, rest and the blog's 100 s) stop two octaves finer, four points:
# their finest two dts cost three quarters of the full report's stepping on them (about a
# fifth of it in all), which keeps the full report within its 15-minute budget
# (docs/benchmarks.md). Quick: three points, the fewest a convergence fit can use; the hard
# cases (tag "hard": long runs, small default dt) and the long ones only at their default dt,
# to keep `rigidbench report --quick` within its 3-minute budget (docs/measurement.md).
FULL_DT_FACTORS = (2.0, 1.0, 0.5, 0.25, 0.125, 0.0625)
FULL_LONG_DT_FACTORS = (2.0, 1.0, 0.5, 0.25)
QUICK_DT_FACTORS = (2.0, 1.0, 0.5)
QUICK_HARD_DT_FACTORS = (1.0,)
LONG_CASE_S = 20.0
# ... and timed once: the quick report shows their verdicts and outcomes, and their runs of up
# to a second are not worth repeating for a timing median there (the full report and every
# other case keep SWEEP_REPEATS).
QUICK_HARD_REPEATS = 1
HARD_TAG = "hard"


@dataclass(frozen=True)
class RunSpec:
    """One run of the matrix."""

    scene: Scene
    engine: str
    integrator: str
    dt: float
    repeats: int = SWEEP_REPEATS

    @property
    def label(self) -> str:
        return f"{self.scene.name}/{self.engine}/{self.integrator}/dt={self.dt:g}"


def plan(
    scenes: list[Scene],
    engines: list[str],
    quick: bool = False,
    repeats: int = SWEEP_REPEATS,
    dt_factors: tuple[float, ...] | None = None,
) -> list[RunSpec]:
    """The runs of the matrix, ordered so that consecutive runs cycle through the engines:
    machine drift during the sweep then falls on every engine alike.

    dt sweeps are `dt_factors` times each scene's dt; by default the full factors (for scenes
    longer than LONG_CASE_S FULL_LONG_DT_FACTORS), or with `quick` the quick ones, and for
    scenes tagged "hard" or longer than LONG_CASE_S QUICK_HARD_DT_FACTORS with at most
    QUICK_HARD_REPEATS timings. Scenes an engine does not model
    (`comparators.engine.unsupported`) are left out for it (`comparators.engine.left_out`).
    A run over the limits (`comparators.limits.check_run`) raises `InputError`.
    """

    def long(scene: Scene) -> bool:
        return scene.duration > LONG_CASE_S

    def hard(scene: Scene) -> bool:
        return quick and dt_factors is None and (HARD_TAG in scene.tags or long(scene))

    def factors(scene: Scene) -> tuple[float, ...]:
        if dt_factors:
            return dt_factors
        if hard(scene):
            return QUICK_HARD_DT_FACTORS
        if quick:
            return QUICK_DT_FACTORS
        return FULL_LONG_DT_FACTORS if long(scene) else FULL_DT_FACTORS

    per_engine = {
        name: [
            RunSpec(
                scene,
                name,
                integrator,
                scene.dt * f,
                min(repeats, QUICK_HARD_REPEATS) if hard(scene) else repeats,
            )
            for scene in scenes
            if not unsupported(ENGINES[name], scene)
            for f in factors(scene)
            for integrator in ENGINES[name].integrators
        ]
        for name in engines
    }
    ordered = []
    for group in itertools.zip_longest(*per_engine.values()):
        ordered.extend(spec for spec in group if spec is not None)
    for spec in ordered:
        check_run(spec.scene, spec.dt, spec.scene.duration)  # over the limits: before any run
    return ordered


def execute(spec: RunSpec) -> tuple[Trajectory | None, str | None, tuple | None]:
    """Run `spec` (repeated for timing as `comparators.timing` says) in whatever process the
    executor chose.

    Returns the trajectory, with wall_s the median stepping time and wall_runs every timing,
    no error and its `analyse`, computed here so that workers share the work; or None, the
    reason it failed and None: an exception never escapes, so one bad run cannot stop a sweep.
    """
    traj, error, walls = repeat_run(
        lambda: attempt_run(spec.scene, spec.engine, spec.integrator, spec.dt), spec.repeats
    )
    if error is not None:
        return None, error, None
    meta = dataclasses.replace(traj.meta, wall_s=spread(walls).median, wall_runs=walls)
    traj = dataclasses.replace(traj, meta=meta)
    return traj, None, analyse(spec, traj)


def analyse(spec: RunSpec, traj: Trajectory) -> tuple[dict, pd.DataFrame]:
    """What the results need from one run alone: `summarize` and `run_outcomes`."""
    return summarize(traj, spec.scene), run_outcomes(spec, traj)


# The compile stage's texts: compiling where numba's cache lacks this version's code, else loading.
COMPILING = "compiling the reference simulator (once per version of its code: about 2 minutes)"
LOADING = "loading the compiled reference simulator"


def warm_up(engines: list[str], console: Console | None = None) -> None:
    """Compile the reference simulator before workers fork from this process, where `engines`
    include it: its `COMPILE_GROUPS` in parallel processes where numba's cache lacks its code
    (they write the cache), then load it all here; on `console`, a stage saying which."""
    if "reference" not in engines:
        return
    compiled = is_compiled()
    with stage(console, LOADING if compiled else COMPILING) if console else nullcontext():
        if not compiled:
            with worker_pool(len(COMPILE_GROUPS)) as pool:
                list(pool.map(compile_stages, COMPILE_GROUPS))
        for name in COMPILE_STAGES:
            compile_stage(name)
            interrupt.check()  # loading compiled code defers Ctrl-C


class LocalExecutor:
    """A process pool on this machine (fork: workers inherit the compiled simulator); an
    interrupt stops its workers at once (`comparators.interrupt`)."""

    def __init__(self, jobs: int):
        self.jobs = jobs
        self.name = f"local process pool, {jobs} worker(s)"

    def map_unordered(self, fn, items):
        with worker_pool(self.jobs) as pool:
            futures = {pool.submit(fn, item): item for item in items}
            for future in as_completed(futures):
                yield futures[future], future.result()


class DaskExecutor:
    """Runs on a Dask cluster (`pip install 'rigidbench[dask]'`); results come back here."""

    def __init__(self, scheduler: str):
        try:
            from distributed import Client
        except ImportError as exc:
            raise InputError(
                f"--executor dask needs the dask extra: pip install 'rigidbench[dask]' ({exc})"
            ) from None
        try:
            self.client = Client(scheduler, timeout="10s")
        except OSError as exc:
            raise InputError(f"--scheduler {scheduler!r}: cannot connect: {exc}") from None
        self.name = f"dask cluster at {scheduler}"

    def map_unordered(self, fn, items):
        from distributed import as_completed as dask_completed

        futures = {self.client.submit(fn, item, pure=False): item for item in items}
        for future in dask_completed(futures):
            yield futures[future], future.result()


def machine_info() -> dict[str, str]:
    """CPU, cores, OS, Python and the versions of every package that computes results."""
    cpu = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    info = {"cpu": cpu, "cores": str(os.cpu_count()), "os": platform.platform()}
    info.update(package_versions("numba", "scipy", "pandas", *RESULT_PACKAGES))
    return info


def run_sweep(
    specs: list[RunSpec],
    cache: ResultsCache,
    executor,
    progress: bool = True,
    left_out: list[str] | None = None,
    console: Console | None = None,
) -> SweepResult:
    """Run every spec not already in `cache`, store each trajectory as it arrives, and
    assemble the results table; `left_out` lines pass through to the result. The progress bar
    goes to `console` (default: rich's, on `sys.stdout`)."""
    start = time.perf_counter()
    keys = {
        spec: run_key(spec.scene, spec.engine, spec.integrator, spec.dt, spec.repeats)
        for spec in specs
    }
    trajectories: dict[RunSpec, Trajectory] = {}
    analyses: dict[RunSpec, tuple] = {}
    failures: dict[RunSpec, str] = {}
    todo = []
    for spec in specs:
        cached = cache.get(keys[spec])
        if cached is None:
            todo.append(spec)
        else:
            trajectories[spec] = cached
    columns = [
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
    ]
    show = progress and bool(todo)
    with Bar(*columns, console=console, disable=not show, transient=False) as bar:
        task = bar.add_task(f"{len(todo)} runs ({len(specs) - len(todo)} cached)", total=len(todo))
        for spec, (traj, error, analysis) in executor.map_unordered(execute, todo):
            if traj is None:
                failures[spec] = error
            else:
                cache.put(keys[spec], traj)
                trajectories[spec] = traj
                analyses[spec] = analysis
            bar.update(task, advance=1, description=spec.label)
            interrupt.check()
    scenes = {spec.scene.name: spec.scene for spec in specs}
    results, references, measured = _results(specs, keys, trajectories, analyses, failures)
    return SweepResult(
        scenes=scenes,
        results=results,
        trajectories={keys[s]: t for s, t in trajectories.items()},
        references=references,
        elapsed_s=time.perf_counter() - start,
        machine=machine_info(),
        executor=executor.name,
        computed=len(todo),
        cached=len(specs) - len(todo),
        orders={(s.engine, s.integrator): ENGINES[s.engine].orders[s.integrator] for s in specs},
        outcomes=measured,
        left_out=list(left_out or []),
    )


def _engine_version(traj: Trajectory) -> str:
    return ", ".join(f"{k} {v}" for k, v in traj.meta.versions.items() if k not in COMMON_PACKAGES)


COMMON_PACKAGES = ("python", "numpy")


def _reference_label(scene: Scene) -> str:
    if exact_trajectory_available(scene):
        return "exact: ballistic COM and closed-form torque-free rotation (cases.exact)"
    label = "self-convergence: each engine and integrator against its own run at the finest dt"
    if scene.expected is not None and scene.expected.rest_com_height is not None:
        label += f"; rest height against the closed form {scene.expected.rest_com_height:g} m"
    return label


def run_outcomes(spec: RunSpec, traj: Trajectory) -> pd.DataFrame:
    """`comparators.outcomes.outcomes` of one run, tagged with its case, engine, integrator, dt."""
    measured = outcomes(traj, spec.scene)
    tags = {"case": spec.scene.name, "engine": spec.engine, "integrator": spec.integrator}
    return measured.assign(**tags, dt=spec.dt)[OUTCOMES_COLUMNS]


def _results(specs, keys, trajectories, analyses, failures):
    """(results table, references by case, outcomes table) of a sweep's runs."""
    finest: dict[tuple, RunSpec] = {}
    for spec in trajectories:
        group = (spec.scene.name, spec.engine, spec.integrator)
        if group not in finest or spec.dt < finest[group].dt:
            finest[group] = spec
    rows, measured = [], []
    for spec in specs:
        row = dict.fromkeys(RESULT_COLUMNS, np.nan)
        row.update(
            case=spec.scene.name,
            engine=spec.engine,
            integrator=spec.integrator,
            dt=spec.dt,
            key=keys[spec],
            code_version=code_version(),
        )
        traj = trajectories.get(spec)
        if traj is None:
            row.update(verdict=f"failed: {failures[spec]}", repeats=0)
            rows.append(row)
            continue
        summary, run_measured = analyses.get(spec) or analyse(spec, traj)
        measured.append(run_measured)
        row.update({k: v for k, v in summary.items() if k in row and k != "key"})
        walls = spread(traj.meta.wall_runs or [traj.meta.wall_s])
        row.update(
            duration=traj.meta.duration,
            repeats=walls.count,
            wall_min_s=walls.least,
            wall_max_s=walls.largest,
            engine_version=_engine_version(traj),
        )
        if not exact_trajectory_available(spec.scene):
            ref = finest[(spec.scene.name, spec.engine, spec.integrator)]
            row["reference"] = f"self-convergence (dt={ref.dt:g})"
            if ref is not spec:
                errors = pose_errors_between(traj, trajectories[ref], spec.scene)
                row["position_error"] = errors["position_error"].max()
                row["orientation_error_deg"] = errors["orientation_error_deg"].max()
        rows.append(row)
    references = {spec.scene.name: _reference_label(spec.scene) for spec in specs}
    frames = [m for m in measured if len(m)]
    table = pd.concat(frames, ignore_index=True) if frames else empty_outcomes()
    return pd.DataFrame(rows, columns=RESULT_COLUMNS), references, table
