"""The Physics gates section: which engine and integrator meets which of the physics gates
shipped with the package (`gates.PHYSICS_DIR`, what `rigidbench gate --physics` runs), judged
from the sweep's own runs, with the measured value. It runs nothing: a gate whose runs the sweep
does not hold (another dt, a case not swept) is "not measured in this report".

A gate with a shorter duration than its case (the order gate's 2 s before the box flips) is read
from the first seconds of the sweep's runs: fixed-step engines take the same steps whatever the
run's length, so those samples are the shorter run's own.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cases.exact import exact_trajectory_available
from cases.toml_io import scene_to_toml
from comparators.engine import ENGINES
from comparators.summary import summarize
from comparators.sweep import RESULT_COLUMNS, RunSpec, SweepResult, empty_outcomes, run_outcomes
from comparators.trajectory import Trajectory
from gates import PHYSICS_DIR
from gates.evaluate import CHECK_COLUMNS, Check, check_from_runs, check_labels, plan_checks
from gates.spec import Gate, is_outcome_measure, load_gates
from reports import plots, texts
from reports.sections.layout import section
from reports.tables import EMPTY_CELL, escape_markdown, markdown_table, pair_label

NOT_MEASURED = "not measured in this report"
# Measures that read a run's timing: a run cut short keeps its whole run's timing, so these are
# not measured on a gate shorter than its case.
TIMING_MEASURES = (
    "steps",
    "setup_s",
    "wall_s",
    "wall_min_s",
    "wall_max_s",
    "steps_per_s",
    "realtime_factor",
)
# Measures against a reference: without an exact solution the reference is the finest dt of the
# runs measured together, so the sweep's errors are the gate's only when their finest dt agree.
REFERENCE_MEASURES = ("position_error", "orientation_error_deg", "order")
# s: sample times within this of a gate's duration belong to it (far below any sample interval,
# far above the rounding of step * dt).
TIME_MATCH = 1e-9


def physics_gates() -> list[Gate]:
    """The physics gates shipped with the package, in file order."""
    return load_gates([PHYSICS_DIR])


def _same_case(gate: Gate, swept) -> bool:
    """The sweep's scene is the gate's case (its duration aside)."""
    if swept is None:
        return False
    whole = dataclasses.replace(gate.scene, duration=swept.duration)
    return scene_to_toml(whole) == scene_to_toml(swept)


def _cut(traj: Trajectory, duration: float) -> Trajectory:
    """The first `duration` seconds of a run, as the run of that duration records them."""
    keep = traj.table["t"].to_numpy() <= duration + TIME_MATCH
    steps = int(round(duration / traj.meta.dt))
    meta = dataclasses.replace(traj.meta, duration=duration, steps=steps)
    return Trajectory(traj.table[keep].reset_index(drop=True), meta)


def _cut_runs(result: SweepResult, runs: pd.DataFrame, gate: Gate):
    """(results, outcomes) rows of `runs` (sweep rows, each with a trajectory) measured over
    the gate's shorter duration; outcomes only where one of the gate's limits reads them."""
    wanted = any(is_outcome_measure(limit.measure) for limit in gate.limits)
    rows, measured = [], []
    for run in runs.itertuples():
        row = {c: getattr(run, c) for c in RESULT_COLUMNS}
        traj = _cut(result.trajectories[run.key], gate.scene.duration)
        row |= {k: v for k, v in summarize(traj, gate.scene).items() if k in row and k != "key"}
        row["duration"] = gate.scene.duration
        rows.append(row)
        if wanted:
            measured.append(
                run_outcomes(RunSpec(gate.scene, run.engine, run.integrator, run.dt), traj)
            )
    frames = [m for m in measured if len(m)]
    outcomes = pd.concat(frames, ignore_index=True) if frames else empty_outcomes()
    return pd.DataFrame(rows, columns=RESULT_COLUMNS), outcomes


@dataclass(frozen=True)
class _GateRuns:
    """The sweep's runs of one gate on one engine and integrator, at each of its dts."""

    results: pd.DataFrame
    outcomes: pd.DataFrame
    shorter: bool  # read from the first seconds of longer runs


class _Sweep:
    """A sweep's runs indexed by case, engine and integrator, and what each gate reads of
    them, gathered once per gate, engine and integrator."""

    KEYS = ["case", "engine", "integrator"]

    def __init__(self, result: SweepResult):
        self.result = result
        self.results = dict(iter(result.results.groupby(self.KEYS, sort=False)))
        self.outcomes = dict(iter(result.outcomes.groupby(self.KEYS, sort=False)))
        self.pairs = {(e, i) for _, e, i in self.results}
        self._gathered: dict[tuple, _GateRuns | str] = {}
        self._swept: dict[Gate, bool] = {}

    def runs(self, gate: Gate, engine: str, integrator: str) -> _GateRuns | str:
        """The gate's runs on `engine` and `integrator`, or why the sweep does not hold them."""
        key = (gate, engine, integrator)
        if key not in self._gathered:
            self._gathered[key] = self._gather(gate, engine, integrator)
        return self._gathered[key]

    def _gather(self, gate: Gate, engine: str, integrator: str) -> _GateRuns | str:
        swept = self.result.scenes.get(gate.scene.name)
        if gate not in self._swept:
            self._swept[gate] = _same_case(gate, swept)
        if not self._swept[gate]:
            return f"case {gate.scene.name!r} not swept"
        key = (gate.scene.name, engine, integrator)
        runs = self.results.get(key, self.result.results.iloc[:0])
        at = {dt: runs[np.isclose(runs["dt"], dt, rtol=1e-9, atol=0.0)] for dt in gate.dts}
        missing = [f"{dt:g}" for dt, found in at.items() if found.empty]
        if missing:
            return f"no run at dt {', '.join(missing)} s"
        runs = pd.concat(at.values()).assign(dt=list(gate.dts))  # the gate's dts, exactly
        if gate.scene.duration > swept.duration + TIME_MATCH:
            return f"needs runs of {gate.scene.duration:g} s, swept {swept.duration:g} s"
        shorter = gate.scene.duration < swept.duration - TIME_MATCH
        failed = runs["verdict"].str.startswith("failed")
        if shorter and not runs[~failed]["key"].isin(list(self.result.trajectories)).all():
            return "a run without its trajectory"
        if shorter:
            cut, outcomes = _cut_runs(self.result, runs[~failed], gate)
            return _GateRuns(pd.concat([cut, runs[failed]], ignore_index=True), outcomes, True)
        outcomes = self.outcomes.get(key, empty_outcomes())
        outcomes = pd.concat(
            [
                outcomes[np.isclose(outcomes["dt"], dt, rtol=1e-9, atol=0.0)].assign(dt=dt)
                for dt in at
            ]
        )
        return _GateRuns(runs, outcomes, False)


def _unmeasurable(check: Check, runs: _GateRuns) -> str | None:
    """Why the sweep's runs do not give `check`'s measure, else None: errors against another
    reference than the gate's own runs would have, or timings of a run cut short."""
    gate, measure = check.gate, check.limit.measure
    own = exact_trajectory_available(gate.scene)  # errors against the exact motion
    finest = runs.results["dt"].min()
    if measure in REFERENCE_MEASURES and not own and (runs.shorter or min(gate.dts) != finest):
        return "errors against another reference"
    if runs.shorter and measure in TIMING_MEASURES:
        return f"needs runs of {gate.scene.duration:g} s"
    return None


def _not_measured(check: Check, why: str) -> dict:
    """The `CHECK_COLUMNS` row of a check the sweep cannot judge."""
    return check_labels(check) | {"passed": None, "reason": f"{NOT_MEASURED}: {why}"}


def physics_checks(result: SweepResult, gates: list[Gate] | None = None) -> pd.DataFrame:
    """One `gates.evaluate.CHECK_COLUMNS` row per check of `gates` (default: the physics
    gates) on every engine and integrator the sweep ran, judged on the sweep's runs; a check the
    sweep holds no runs for has `passed` None and the reason starting NOT_MEASURED."""
    gates = physics_gates() if gates is None else gates
    sweep = _Sweep(result)
    engines = {e for e, _ in sweep.pairs if e in ENGINES}
    rows = []
    for engine in sorted(engines, key=lambda e: plots.pair_rank((e, ""))):
        for check in plan_checks(gates, engine):
            if (engine, check.integrator) not in sweep.pairs:
                continue  # an integrator the sweep left out: no column of its own
            runs = sweep.runs(check.gate, engine, check.integrator)
            why = runs if isinstance(runs, str) else _unmeasurable(check, runs)
            if why is not None:
                rows.append(_not_measured(check, why))
                continue
            rows.append(check_from_runs(check, runs.results, runs.outcomes))
    return pd.DataFrame(rows, columns=CHECK_COLUMNS)


def _value(measured) -> str:
    if isinstance(measured, str):
        return escape_markdown(measured)
    return EMPTY_CELL if measured is None or math.isnan(measured) else f"{measured:.3g}"


def check_cell(row) -> str:
    """pass or fail (coloured in index.html) and the measured value; why a failed check has
    none; "not measured" or "not modelled" where the check has no verdict."""
    if row.passed is None or (isinstance(row.passed, float) and math.isnan(row.passed)):
        return "not measured" if str(row.reason).startswith(NOT_MEASURED) else "not modelled"
    word = "pass" if row.passed else "fail"
    cell = f'<span class="verdict gate-{word}">{word}</span> {_value(row.measured)}'
    if not row.passed and row.reason:
        cell += f" ({escape_markdown(row.reason)})"
    return cell


def _check_label(row) -> str:
    dt = "" if math.isnan(row.dt) else f" at dt {row.dt:g} s"
    return f"{escape_markdown(row.measure)}{dt}"


def physics_table(checks: pd.DataFrame) -> pd.DataFrame:
    """Checks (rows: gate, measure and dt, limit) by engine/integrator (columns, registry
    order), each cell `check_cell`; rows measured for no engine are left out."""
    measured = checks.groupby(["gate", "measure", "dt"], dropna=False, sort=False)["passed"]
    keep = measured.transform(lambda p: p.notna().any())
    checks = checks[keep.astype(bool)]
    pairs = sorted(
        dict.fromkeys(zip(checks["engine"], checks["integrator"], strict=True)),
        key=plots.pair_rank,
    )
    rows = {}
    for row in checks.itertuples():
        key = (row.file, row.gate, row.measure, row.dt)
        if key not in rows:
            expectation = row.file.rsplit("/", 1)[-1].removesuffix(".toml")
            rows[key] = {
                "expectation": escape_markdown(expectation),
                "gate": escape_markdown(row.gate),
                "measure": _check_label(row),
                "limit": escape_markdown(row.limit),
            }
        rows[key][pair_label(row.engine, row.integrator)] = check_cell(row)
    columns = ["expectation", "gate", "measure", "limit", *(pair_label(*p) for p in pairs)]
    return pd.DataFrame(list(rows.values()), columns=columns).fillna(EMPTY_CELL)


def _unmeasured(checks: pd.DataFrame) -> str:
    """The gates no engine was measured on here, with why."""
    by_gate = checks.groupby("gate", sort=False)
    lines = []
    for gate, own in by_gate:
        if own["passed"].notna().any():
            continue
        reasons = own["reason"].str.removeprefix(f"{NOT_MEASURED}: ").unique()
        lines.append(f"`{gate}` ({'; '.join(reasons)})")
    if not lines:
        return ""
    return f"Not measured in this report (its sweep holds no such runs): {', '.join(lines)}."


def _passing(checks: pd.DataFrame) -> str:
    """The engine/integrators that pass every physics gate measured here."""
    judged = checks[checks["passed"].notna()]
    if judged.empty:
        return ""
    every = judged.groupby(["engine", "integrator"], sort=False)["passed"].all()
    passing = [pair_label(*pair) for pair in sorted(every[every].index, key=plots.pair_rank)]
    listed = ", ".join(passing) if passing else "none"
    return f"Pass every physics gate measured here: {listed} (of {len(every)})."


def physics_section(result: SweepResult, gates: list[Gate] | None = None) -> list[str]:
    """The physics gates by engine/integrator, from the sweep's runs."""
    checks = physics_checks(result, gates)
    table = physics_table(checks)
    if table.empty:
        return section("Physics gates", texts.PHYSICS_GATES, _unmeasured(checks) or "No runs.")
    cells = markdown_table(table, {c: str for c in table.columns})
    blocks = [b for b in (_passing(checks), cells, _unmeasured(checks)) if b]
    return section("Physics gates", texts.PHYSICS_GATES, *blocks)
