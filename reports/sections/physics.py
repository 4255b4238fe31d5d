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

import numpy as np
import pandas as pd

from cases.exact import exact_trajectory_available
from cases.toml_io import scene_to_toml
from comparators.engine import ENGINES
from comparators.sweep import RESULT_COLUMNS, RunSpec, SweepResult, analyse, empty_outcomes
from comparators.trajectory import Trajectory
from gates import PHYSICS_DIR
from gates.evaluate import CHECK_COLUMNS, Check, check_from_runs, plan_checks
from gates.spec import Gate, load_gates
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
    the gate's shorter duration."""
    rows, measured = [], []
    for run in runs.itertuples():
        spec = RunSpec(gate.scene, run.engine, run.integrator, run.dt)
        row = {c: getattr(run, c) for c in RESULT_COLUMNS}
        summary, outcomes = analyse(spec, _cut(result.trajectories[run.key], gate.scene.duration))
        row |= {k: v for k, v in summary.items() if k in row and k != "key"}
        row["duration"] = gate.scene.duration
        rows.append(row)
        measured.append(outcomes)
    frames = [m for m in measured if len(m)]
    outcomes = pd.concat(frames, ignore_index=True) if frames else empty_outcomes()
    return pd.DataFrame(rows, columns=RESULT_COLUMNS), outcomes


def _runs_for(result: SweepResult, check: Check) -> tuple[pd.DataFrame, pd.DataFrame] | str:
    """The sweep's (results, outcomes) rows `check` is judged on: its case, engine and
    integrator at each dt of its gate; or why the sweep does not hold them."""
    gate = check.gate
    swept = result.scenes.get(gate.scene.name)
    if not _same_case(gate, swept):
        return f"case {gate.scene.name!r} not swept"
    results = result.results
    runs = results[
        (results["case"] == gate.scene.name)
        & (results["engine"] == check.engine)
        & (results["integrator"] == check.integrator)
    ]
    at = {dt: runs[np.isclose(runs["dt"], dt, rtol=1e-9, atol=0.0)] for dt in gate.dts}
    missing = [f"{dt:g}" for dt, found in at.items() if found.empty]
    if missing:
        return f"no run at dt {', '.join(missing)} s"
    runs = pd.concat(at.values()).assign(dt=list(gate.dts))  # the gate's dts, exactly
    measure = check.limit.measure
    own = exact_trajectory_available(gate.scene)  # errors against the exact motion
    if measure in REFERENCE_MEASURES and not own and min(gate.dts) != runs["dt"].min():
        return "errors against another reference"
    if gate.scene.duration > swept.duration + TIME_MATCH:
        return f"needs runs of {gate.scene.duration:g} s, swept {swept.duration:g} s"
    shorter = gate.scene.duration < swept.duration - TIME_MATCH
    if shorter and (measure in TIMING_MEASURES or not own and measure in REFERENCE_MEASURES):
        return f"needs runs of {gate.scene.duration:g} s"
    if shorter and not runs["key"].isin(list(result.trajectories)).all():
        return "a run without its trajectory"
    outcomes = result.outcomes
    outcomes = outcomes[
        (outcomes["case"] == gate.scene.name)
        & (outcomes["engine"] == check.engine)
        & (outcomes["integrator"] == check.integrator)
    ]
    if shorter:
        valid = runs[~runs["verdict"].str.startswith("failed")]
        cut, cut_outcomes = _cut_runs(result, valid, gate)
        failed = runs[runs["verdict"].str.startswith("failed")]
        return pd.concat([cut, failed], ignore_index=True), cut_outcomes
    outcomes = pd.concat(
        [outcomes[np.isclose(outcomes["dt"], dt, rtol=1e-9, atol=0.0)].assign(dt=dt) for dt in at]
    )
    return runs, outcomes


def physics_checks(result: SweepResult, gates: list[Gate] | None = None) -> pd.DataFrame:
    """One `gates.evaluate.CHECK_COLUMNS` row per check of `gates` (default: the physics
    gates) on every engine and integrator the sweep ran, judged on the sweep's runs; a check the
    sweep holds no runs for has `passed` None and the reason starting NOT_MEASURED."""
    gates = physics_gates() if gates is None else gates
    swept = set(zip(result.results["engine"], result.results["integrator"], strict=True))
    engines = sorted({e for e, _ in swept if e in ENGINES}, key=lambda e: plots.pair_rank((e, "")))
    rows = []
    for engine in engines:
        for check in plan_checks(gates, engine):
            if (engine, check.integrator) not in swept:
                continue  # an integrator the sweep left out: no column of its own
            runs = _runs_for(result, check)
            if isinstance(runs, str):
                dt = check.dt
                row = dict.fromkeys(CHECK_COLUMNS, np.nan) | {
                    "file": str(check.gate.file),
                    "gate": check.gate.name,
                    "case": check.gate.scene.name,
                    "engine": engine,
                    "integrator": check.integrator,
                    "dt": dt,
                    "measure": check.limit.measure,
                    "limit": check.limit_text,
                    "passed": None,
                    "reason": f"{NOT_MEASURED}: {runs}",
                }
                rows.append(row)
                continue
            rows.append(check_from_runs(check, *runs))
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
