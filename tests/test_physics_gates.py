"""The physics gates shipped with the package (`gates/physics/`): valid, every limit justified
beside it, shipped as package data, met by the reference simulator's splitting integrator; the
energy_gain measure they use; and the report's Physics gates section, judged from the sweep's
own runs (a pass that becomes a fail when the results say so, a gate the sweep lacks runs for
left unmeasured)."""

import dataclasses
import tomllib
from fnmatch import fnmatch
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_report import build_result

from cases import CATALOG
from comparators import ENGINES, run
from comparators.cache import ResultsCache
from comparators.sweep import SweepResult
from gates import PHYSICS_DIR
from gates.evaluate import evaluate_checks, plan_checks
from gates.spec import ALL_INTEGRATORS
from reports.report import write_report
from reports.sections.physics import NOT_MEASURED, _cut, physics_checks, physics_section

ROOT = Path(__file__).resolve().parent.parent
GATE_FILES = sorted(PHYSICS_DIR.glob("*.toml"))


@pytest.fixture(scope="module")
def gates():
    from reports.sections.physics import physics_gates

    return physics_gates()


def test_there_is_a_physics_gate_per_expectation(gates):
    names = {path.stem for path in GATE_FILES}
    assert names == {
        "angular_momentum",
        "energy",
        "order",
        "rebound",
        "friction",
        "resting",
        "stack",
    }
    assert len(gates) >= len(names)


def test_physics_gates_leave_the_engine_out_and_take_every_integrator(gates):
    for gate in gates:
        assert gate.engine is None, f"{gate.file.name}: {gate.name} names an engine"
        assert gate.integrator == ALL_INTEGRATORS, f"{gate.file.name}: {gate.name}"


@pytest.mark.parametrize("path", GATE_FILES, ids=lambda p: p.name)
def test_every_limit_is_justified_beside_it(path):
    """A comment line right above each limit says why its number (the project's rule for every
    tolerance)."""
    lines = path.read_text().splitlines()
    in_limits = False
    for k, line in enumerate(lines):
        stripped = line.strip()
        if stripped.startswith("["):
            in_limits = stripped == "[gates.limits]"
            continue
        if in_limits and stripped and not stripped.startswith("#"):
            assert lines[k - 1].lstrip().startswith("#"), (
                f"{path.name}:{k + 1}: limit {stripped!r} has no comment above it saying why"
            )


def test_the_physics_gates_are_package_data():
    """pyproject's package data matches every physics gate file, so a wheel ships them (an
    editable install reads them where they are)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    patterns = config["tool"]["setuptools"]["package-data"]["gates"]
    for path in GATE_FILES:
        relative = path.relative_to(PHYSICS_DIR.parent).as_posix()
        assert any(fnmatch(relative, p) for p in patterns), f"{relative} not in {patterns}"
    assert "gates*" in config["tool"]["setuptools"]["packages"]["find"]["include"]


def test_energy_gain_is_signed_where_energy_drift_is_not():
    """A contact that dissipates drifts the energy but gains none; the reference's `euler` on
    the tumbling box gains what it drifts."""
    from comparators.summary import summarize

    dropped = CATALOG["dropped_cube"]
    rest = summarize(run(dropped, "reference", "splitting"), dropped)
    assert rest["energy_drift"] > 0.5 and rest["energy_gain"] == 0.0
    tumbling = CATALOG["tumbling_box"]
    gained = summarize(run(tumbling, "reference", "euler"), tumbling)
    assert gained["energy_gain"] == pytest.approx(gained["energy_drift"], rel=1e-12)
    assert gained["energy_gain"] > 0.05


def test_the_reference_splitting_integrator_meets_every_physics_gate(gates, tmp_path):
    """Every gate measures what it names on the case it names (no 'measures no ...'), and the
    reference's default integrator meets every limit."""
    checks = [c for c in plan_checks(gates, "reference") if c.integrator == "splitting"]
    table = evaluate_checks(checks, ResultsCache(tmp_path), progress=False)
    failed = table[table["passed"] != True]  # noqa: E712 (None: not checked)
    assert failed.empty, failed[["gate", "measure", "measured", "limit", "reason"]].to_string()
    assert set(table["gate"]) == {g.name for g in gates}


@pytest.mark.parametrize("engine, integrator", [("reference", "splitting"), ("mujoco", "RK4")])
def test_a_runs_first_seconds_are_the_shorter_run(engine, integrator):
    """What the report reads for a gate shorter than its case (the order gate's 2 s): the first
    2 s of a 10 s run are the 2 s run's samples, bit for bit."""
    if ENGINES[engine].missing:
        pytest.skip(ENGINES[engine].missing)
    scene = CATALOG["tumbling_box"]
    whole = run(scene, engine, integrator, dt=0.01)
    short = run(dataclasses.replace(scene, duration=2.0), engine, integrator, dt=0.01)
    cut = _cut(whole, 2.0)
    columns = [c for c in short.table.columns if c != "wall_s"]
    pd.testing.assert_frame_equal(cut.table[columns], short.table[columns])
    assert (cut.meta.duration, cut.meta.steps) == (short.meta.duration, short.meta.steps)


# ---- the report's section ----------------------------------------------------------------------

PAIRS = [("reference", "splitting"), ("mujoco", "RK4")]
TUMBLING_DTS = (0.02, 0.01, 0.005)  # the order gate's dts
FREE_FLIGHT_DT = 0.00125  # the L and energy gates' dt


@pytest.fixture(scope="module")
def sweep() -> SweepResult:
    """tumbling_box (10 s) swept by two engines at the order gate's dts and the L and energy
    gates' dt: what the free-flight gates need, and nothing the contact gates need."""
    for engine, _ in PAIRS:
        if ENGINES[engine].missing:
            pytest.skip(f"{engine}: {ENGINES[engine].missing}")
    return build_result([CATALOG["tumbling_box"]], PAIRS, (*TUMBLING_DTS, FREE_FLIGHT_DT))


def _cell(checks: pd.DataFrame, gate: str, engine: str, measure: str) -> pd.Series:
    """The check of `gate`'s `measure` on the sweep's integrator of `engine`."""
    integrator = dict(PAIRS)[engine]
    found = checks[
        (checks["gate"] == gate)
        & (checks["engine"] == engine)
        & (checks["integrator"] == integrator)
        & (checks["measure"] == measure)
    ]
    assert len(found) == 1, found
    return found.iloc[0]


def test_the_section_judges_the_sweeps_own_runs(sweep):
    checks = physics_checks(sweep)
    L = _cell(checks, "tumbling_box_L", "mujoco", "angular_momentum_drift")
    measured = sweep.results.set_index(["case", "engine", "integrator", "dt"]).loc[
        ("tumbling_box", "mujoco", "RK4", FREE_FLIGHT_DT), "angular_momentum_drift"
    ]
    assert L["passed"] == True and L["measured"] == measured  # noqa: E712
    order = _cell(checks, "tumbling_box_order", "reference", "order")
    assert order["passed"] == True and order["measured"] == pytest.approx(2.0, abs=0.03)  # noqa: E712
    # the contact cases were not swept: not measured, and said so
    bounce = _cell(checks, "bounce_e0.5", "reference", "rebound_ratio.relative_error")
    assert bounce["passed"] is None and bounce["reason"].startswith(NOT_MEASURED)


def test_a_pass_becomes_a_fail_when_the_results_say_so(sweep):
    def row(result):
        lines = "\n".join(physics_section(result)).splitlines()
        header = next(line for line in lines if line.startswith("| expectation"))
        found = next(line for line in lines if r"| tumbling\_box\_L |" in line)
        cells = [c.strip() for c in found.split("|")[1:-1]]
        return dict(zip([c.strip() for c in header.split("|")[1:-1]], cells, strict=True))

    before = row(sweep)["mujoco RK4"]
    assert before.startswith('<span class="verdict gate-pass">pass</span>')
    results = sweep.results.copy()
    at = (results["engine"] == "mujoco") & np.isclose(results["dt"], FREE_FLIGHT_DT)
    results.loc[at, "angular_momentum_drift"] = 0.05  # five times the 1 % the gate allows
    altered = dataclasses.replace(sweep, results=results)
    assert row(altered)["mujoco RK4"] == '<span class="verdict gate-fail">fail</span> 0.05'
    assert row(altered)["reference splitting"] == row(sweep)["reference splitting"]


def test_a_diverged_run_fails_with_its_reason(sweep):
    results = sweep.results.copy()
    at = (results["engine"] == "reference") & np.isclose(results["dt"], FREE_FLIGHT_DT)
    results.loc[at, "verdict"] = "diverged"
    checks = physics_checks(dataclasses.replace(sweep, results=results))
    energy = _cell(checks, "tumbling_box_energy", "reference", "energy_gain")
    assert energy["passed"] == False and energy["reason"] == "the run diverged"  # noqa: E712


def test_a_gate_the_sweep_lacks_runs_for_is_not_measured(sweep):
    """Without the run at dt 0.005 the order gate has no fit: 'not measured', and the gates no
    engine was measured on are listed with why."""
    results = sweep.results[~np.isclose(sweep.results["dt"], 0.005)]
    text = "\n".join(physics_section(dataclasses.replace(sweep, results=results)))
    lines = text.splitlines()
    assert r"| tumbling\_box\_order |" not in text
    unmeasured = next(line for line in lines if line.startswith("Not measured in this report"))
    assert "`tumbling_box_order` (no run at dt 0.005 s)" in unmeasured
    assert "`bounce_e0.5` (case 'bounce' not swept)" in unmeasured


def test_the_report_lists_the_section_in_its_contents(sweep, tmp_path):
    written = write_report(sweep, tmp_path, "test")
    text = written["report.md"].read_text()
    contents = text.split("## Contents")[1].split("\n## ")[0]
    assert "- [Physics gates](#physics-gates)" in contents
    assert 'id="physics-gates"' in written["index.html"].read_text()
    assert "Pass every physics gate measured here: mujoco RK4, reference splitting (of 2)" in text
