"""Stepping throughput: every case x engine x integrator x dt timed side by side in one process.

`bench` measures steps/s through `comparators.engine.run`, the path the report takes (model
built from the scene, trajectory recorded at the scene's sample interval, stepping timed apart
from model building as `wall_s`). Per case and dt, every engine/integrator runs once as warm-up
(its `setup_s` is reported, its trajectory gives the verdict), then BENCH_REPEATS timed repeats
go round-robin over the engines/integrators, each round starting one further along, so that
machine load during the bench falls on all of them alike (`comparators.timing`). steps/s is
the median over the repeats of steps / wall_s, with the min and max beside it. Each run
simulates the case's duration capped at BENCH_DURATION_S (10 s: 1000 steps at dt 0.01), or a
given duration. Beside the speed, what the warm-up run got wrong: its verdict and, where it ran
the case's whole duration, the closed forms it missed (`comparators.closed_forms`): a fast run
that misses its physics is not a fast run of the same physics.

`throughput_from_results` makes the same table from a sweep's results (`comparators.sweep`),
for the report.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

from cases.errors import InputError
from cases.scene import Scene
from comparators.closed_forms import RUN_KEYS, missed, missed_by_run
from comparators.engine import ENGINES, get_engine, unsupported
from comparators.engine_output import message_count
from comparators.limits import STEPS_ENV, check_run, current_limits
from comparators.outcomes import outcomes
from comparators.progress import Bar
from comparators.timing import BENCH_REPEATS, MIN_REPEATS, attempt_run, interleaved, spread
from comparators.verdict import verdict

BENCH_COLUMNS = [
    "case",
    "engine",
    "integrator",
    "dt",
    "duration",  # simulated seconds per run
    "steps",
    "repeats",  # timed repeats that ran
    "steps_per_s",  # median over repeats of steps / wall_s
    "steps_per_s_min",
    "steps_per_s_max",
    "setup_s",  # model building (and compilation) of the warm-up run
    "ratio_vs_mujoco_euler",
    "engine_messages",  # lines the engine printed or warned in the warm-up run (RunMeta.messages)
    "verdict",  # of the warm-up run: "ok", "diverged", ... or "failed: <reason>"
    "closed_forms_missed",  # of the warm-up run (`closed_forms.missed`); empty where not judged
]
# Every steps/s is compared with MuJoCo's Euler at the same case and dt.
BASELINE = ("mujoco", "Euler")
# Simulated seconds per run at most (unless a duration is given): 1000 steps at dt 0.01, so
# every run takes enough steps to time and the long cases (seed_cube's 100 s) no more than the
# others; what that costs: docs/measurement.md.
BENCH_DURATION_S = 10.0


@dataclass(frozen=True)
class BenchRun:
    """One engine/integrator on one case at one dt, for `duration` simulated seconds."""

    scene: Scene
    engine: str
    integrator: str
    dt: float
    duration: float

    @property
    def label(self) -> str:
        return f"{self.scene.name}/{self.engine}/{self.integrator}/dt={self.dt:g}"


def bench_duration(scene: Scene, duration: float | None = None) -> float:
    """Simulated seconds per run: `duration` when given, else the scene's capped at
    BENCH_DURATION_S."""
    return duration if duration is not None else min(scene.duration, BENCH_DURATION_S)


def plan_bench(
    scenes: list[Scene],
    engines: list[str],
    dts: Iterable[float] | None = None,
    duration: float | None = None,
    repeats: int = BENCH_REPEATS,
) -> list[list[BenchRun]]:
    """The runs, one block per case and dt, each listing every engine/integrator in registry
    order, leaving out engines that do not model the scene. `dts` None: each scene's own dt.
    Bad names, and a dt or duration `comparators.limits.check_run` refuses, raise InputError;
    so does a run whose warm-up and `repeats` together take more steps than the step limit."""
    for name in engines:
        get_engine(name)
    dts = None if dts is None else list(dts)
    blocks = []
    for scene in scenes:
        length = bench_duration(scene, duration)
        for dt in dts or [scene.dt]:
            check_run(scene, dt, length)
            _check_repeats(scene, dt, length, repeats)
            block = [
                BenchRun(scene, name, integrator, float(dt), float(length))
                for name in engines
                if not unsupported(ENGINES[name], scene)
                for integrator in ENGINES[name].integrators
            ]
            if block:
                blocks.append(block)
    return blocks


def _check_repeats(scene: Scene, dt: float, length: float, repeats: int) -> None:
    """InputError when one run, warm-up and `repeats` timed, steps more than the step limit."""
    limit = current_limits().steps
    steps = (1 + repeats) * (length / dt)
    if steps > limit + 0.5:
        raise InputError(
            f"{scene.name!r} with dt {dt:g} for {length:g} s, warmed up and repeated {repeats} "
            f"times, takes {steps:.3g} steps, over the limit of {limit:.3g}: expected fewer "
            f"--repeats, or raise it with --max-steps (or {STEPS_ENV})"
        )


def _attempt(spec: BenchRun):
    """`comparators.timing.attempt_run` of `spec`: (trajectory, None) or (None, reason)."""
    return attempt_run(spec.scene, spec.engine, spec.integrator, spec.dt, spec.duration)


def _empty_bench_row(spec: BenchRun) -> dict:
    """The table row of `spec` before any run: NaN throughout, no repeats."""
    row = dict.fromkeys(BENCH_COLUMNS, np.nan)
    row.update(
        case=spec.scene.name,
        engine=spec.engine,
        integrator=spec.integrator,
        dt=spec.dt,
        duration=spec.duration,
        repeats=0,
    )
    return row


# Verdicts whose runs are timed: the architecture counts only finite, non-diverged runs. A
# dissipated run, like a tunnelled or jittering one, stepped finitely to its end: its time is
# what the engine costs, though its physics is wrong, and the verdict beside it says so.
TIMED_VERDICTS = ("ok", "dissipated", "tunnelled", "jitter")


def bench(
    scenes: list[Scene],
    engines: list[str],
    dts: Iterable[float] | None = None,
    duration: float | None = None,
    repeats: int = BENCH_REPEATS,
    progress: bool = True,
    console: Console | None = None,
) -> pd.DataFrame:
    """Steps/s of every scene x engine x integrator x dt, one row each, columns BENCH_COLUMNS.

    dts: None runs each scene at its own dt; duration: None simulates each scene's duration
    capped at BENCH_DURATION_S. Each run goes through `comparators.engine.run` with the
    trajectory recorded. Per case and dt: one warm-up run per engine/integrator (setup_s, the
    verdict), then `repeats` (>= MIN_REPEATS) timed rounds over the engines/integrators whose
    warm-up gave a finite, non-diverged run. A failed or diverged run never raises: its row has
    steps/s NaN and says why in `verdict`; a repeat that fails turns its row into that failure.
    Call `comparators.sweep.warm_up` first to compile the reference simulator outside the bench.
    The progress bar goes to `console` (default: rich's, on `sys.stdout`); runs in this process
    capture their output (`comparators.engine_output`), so give a console that writes past it
    (`terminal_stream`), or the bar's refreshes during a run land in that run's record.
    """
    if repeats < MIN_REPEATS:
        raise InputError(f"repeats: expected at least {MIN_REPEATS}, got {repeats}")
    blocks = plan_bench(scenes, engines, dts, duration, repeats)
    rows = []
    total = sum(len(block) for block in blocks) * (1 + repeats)
    columns = [
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
    ]
    with Bar(*columns, console=console, disable=not progress, transient=False) as bar:
        task = bar.add_task("bench", total=total)

        def advance(label: str) -> None:
            bar.update(task, advance=1, description=label)

        for block in blocks:
            rows += _bench_block(block, repeats, advance)
    table = pd.DataFrame(rows, columns=BENCH_COLUMNS)
    return with_ratio(table)


def _bench_block(block: list[BenchRun], repeats: int, advance) -> list[dict]:
    """One case and dt: warm-ups, then `repeats` rotated rounds; one row per spec."""
    rows = [_empty_bench_row(spec) for spec in block]
    timed = _warm_up_block(block, rows, advance)
    for _ in range((len(block) - len(timed)) * repeats):
        advance("skipped")
    walls: dict[int, list[float]] = {k: [] for k in timed}
    for _, k in interleaved(timed, repeats, rotate=True):
        if rows[k]["verdict"].startswith("failed"):
            advance(block[k].label)
            continue
        traj, error = _attempt(block[k])
        advance(block[k].label)
        if traj is None:
            rows[k]["verdict"] = f"failed: {error}"
        else:
            walls[k].append(traj.meta.wall_s)
    for k in timed:
        if rows[k]["verdict"].startswith("failed"):
            continue
        rates = spread(rows[k]["steps"] / np.asarray(walls[k]))
        rows[k].update(
            repeats=rates.count,
            steps_per_s=rates.median,
            steps_per_s_min=rates.least,
            steps_per_s_max=rates.largest,
        )
    return rows


def _warm_up_block(block: list[BenchRun], rows: list[dict], advance) -> list[int]:
    """Run every spec of `block` once: its steps, setup_s, verdict and, for a run of its case's
    whole duration, the closed forms it missed into `rows`; the indices of the specs whose run
    is timed (a verdict in TIMED_VERDICTS)."""
    timed = []
    for k, spec in enumerate(block):
        traj, error = _attempt(spec)
        advance(spec.label)
        if traj is None:
            rows[k]["verdict"] = f"failed: {error}"
            continue
        rows[k].update(steps=traj.meta.steps, setup_s=traj.meta.setup_s)
        rows[k]["engine_messages"] = message_count(traj.meta.messages)
        rows[k]["verdict"] = verdict(traj, spec.scene)
        if rows[k]["verdict"] in TIMED_VERDICTS:
            timed.append(k)
            if math.isclose(spec.duration, spec.scene.duration):  # the case's own run
                rows[k]["closed_forms_missed"] = missed(outcomes(traj, spec.scene))
    return timed


def with_ratio(table: pd.DataFrame) -> pd.DataFrame:
    """`table` with ratio_vs_mujoco_euler: steps_per_s over that of BASELINE at the same case
    and dt (NaN where the baseline has no valid timing)."""
    engine, integrator = BASELINE
    is_base = (table["engine"] == engine) & (table["integrator"] == integrator)
    base = table[is_base].drop_duplicates(["case", "dt"]).set_index(["case", "dt"])
    keys = pd.MultiIndex.from_frame(table[["case", "dt"]])
    reference = base["steps_per_s"].reindex(keys).to_numpy(dtype=float)
    return table.assign(ratio_vs_mujoco_euler=table["steps_per_s"].to_numpy(float) / reference)


def throughput_from_results(
    results: pd.DataFrame, scenes: dict[str, Scene], outcomes: pd.DataFrame
) -> pd.DataFrame:
    """The bench table (BENCH_COLUMNS) from a sweep's results (`comparators.sweep.RESULT_COLUMNS`)
    and outcomes (`OUTCOMES_COLUMNS`) at each case's default dt: its median steps/s, min and max
    from wall_max_s and wall_min_s, NaN where the run failed or diverged; the closed forms a
    timed run of the case's whole duration missed."""
    default = results["dt"].to_numpy(float) == results["case"].map(
        {name: scene.dt for name, scene in scenes.items()}
    ).to_numpy(float)
    runs = results[default].reset_index(drop=True)
    valid = runs["verdict"].isin(TIMED_VERDICTS).to_numpy()
    said = missed_by_run(outcomes)
    keys = list(runs[RUN_KEYS].itertuples(index=False, name=None))
    whole = runs["case"].map({name: scene.duration for name, scene in scenes.items()})
    judged = valid & np.isclose(runs["duration"].to_numpy(float), whole.to_numpy(float))
    steps = runs["steps"].to_numpy(float)
    table = pd.DataFrame(
        {
            "case": runs["case"],
            "engine": runs["engine"],
            "integrator": runs["integrator"],
            "dt": runs["dt"],
            "duration": runs["duration"],
            "steps": runs["steps"],
            "repeats": runs["repeats"],
            "steps_per_s": np.where(valid, runs["steps_per_s"], np.nan),
            "steps_per_s_min": np.where(valid, steps / runs["wall_max_s"], np.nan),
            "steps_per_s_max": np.where(valid, steps / runs["wall_min_s"], np.nan),
            "setup_s": runs["setup_s"],
            "ratio_vs_mujoco_euler": np.nan,
            "engine_messages": runs["engine_messages"],
            "verdict": runs["verdict"],
            "closed_forms_missed": [
                said.get(key) if judge else None for key, judge in zip(keys, judged, strict=True)
            ],
        },
        columns=BENCH_COLUMNS,
    )
    return with_ratio(table)
