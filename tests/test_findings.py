"""The summary's findings follow from the results: alter a result and the findings change.

Results, outcomes and fits are built by hand here (the columns the rules read), starting from a
sweep in which every run is right; each test alters one thing and checks what is said.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cases.catalog import CATALOG
from comparators.closed_forms import ABSOLUTE_TOLERANCES, RELATIVE_TOLERANCES
from comparators.sweep import RESULT_COLUMNS, SweepResult
from comparators.verdict import ENERGY_LOSS_LIMIT
from gates import PHYSICS_DIR
from gates.spec import is_outcome_measure, load_gates, measure_parts
from reports.findings import ENERGY_DRIFT_NOTE, findings
from reports.sections.summary import summary_section

CASES = ("tumbling_box", "bounce", "slide")
SCENES = {name: CATALOG[name] for name in CASES}
PAIRS = (("mujoco", "Euler"), ("mujoco", "RK4"), ("reference", "splitting"))
E = SCENES["bounce"].contact.restitution
CLOSED_FORMS = {"bounce": ("rebound_ratio", E, "1"), "slide": ("stopping_distance", 0.9, "m")}


def _runs(factor: float) -> list[dict]:
    return [
        {"case": c, "engine": e, "integrator": i, "dt": SCENES[c].dt * factor}
        for c in CASES
        for e, i in PAIRS
    ]


def right_sweep() -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """(results, outcomes, fits) of a sweep at the default dt and twice it with nothing wrong."""
    rows = _runs(1.0) + _runs(2.0)
    results = pd.DataFrame(rows).assign(verdict="ok", energy_drift=1e-6)
    outcomes = pd.DataFrame(
        [
            {**row, "quantity": q, "measured": v, "expected": v, "error": 0.0, "unit": u}
            for row in rows
            if row["case"] in CLOSED_FORMS
            for q, v, u in [CLOSED_FORMS[row["case"]]]
        ]
    )
    orders = {"Euler": 1, "RK4": 4, "splitting": 2}
    fits = pd.DataFrame(
        [
            {"case": c, "engine": e, "integrator": i, "order": orders[i] + 0.02}
            | {"expected_order": orders[i], "r2": 0.999}
            for c in CASES
            for e, i in PAIRS
        ]
    )
    return results, outcomes, fits


def at(table: pd.DataFrame, case: str, engine: str, integrator: str, factor: float = 1.0):
    dt = SCENES[case].dt * factor
    return (
        (table["case"] == case)
        & (table["engine"] == engine)
        & (table["integrator"] == integrator)
        & np.isclose(table["dt"], dt)
    )


def test_nothing_found_when_every_run_is_right():
    assert findings(*right_sweep()[:2], SCENES, right_sweep()[2]) == []


@pytest.mark.parametrize("verdict", ["diverged", "dissipated", "tunnelled", "jitter"])
def test_a_verdict_at_the_default_dt_is_found(verdict):
    results, outcomes, fits = right_sweep()
    results.loc[at(results, "slide", "mujoco", "RK4"), "verdict"] = verdict
    found = findings(results, outcomes, SCENES, fits)
    assert [(f.kind, f.cases) for f in found] == [(verdict, ("slide",))]
    assert found[0].text.startswith("**mujoco** RK4:") and verdict in found[0].text


def test_a_verdict_at_another_dt_is_not_a_finding():
    results, outcomes, fits = right_sweep()
    results.loc[at(results, "slide", "mujoco", "RK4", 2.0), "verdict"] = "diverged"
    assert findings(results, outcomes, SCENES, fits) == []


def test_a_diverged_run_has_no_outcome_finding():
    results, outcomes, fits = right_sweep()
    results.loc[at(results, "bounce", "mujoco", "Euler"), "verdict"] = "diverged"
    outcomes.loc[at(outcomes, "bounce", "mujoco", "Euler"), "measured"] = 1e9
    assert [f.kind for f in findings(results, outcomes, SCENES, fits)] == ["diverged"]


def test_a_rebound_at_e_squared_is_named():
    results, outcomes, fits = right_sweep()
    outcomes.loc[at(outcomes, "bounce", "reference", "splitting"), "measured"] = E**2
    (found,) = findings(results, outcomes, SCENES, fits)
    assert found.kind == "rebound_ratio" and found.cases == ("bounce",)
    assert "at e²" in found.text and "**reference** splitting" in found.text


@pytest.mark.parametrize("miss, found", [(0.5, False), (1.5, True), (-20.0, True)])
def test_a_rebound_is_found_only_beyond_its_tolerance(miss, found):
    """`miss` in units of the rebound tolerance; a miss of 20 of them is not e squared."""
    results, outcomes, fits = right_sweep()
    ratio = E * (1 + miss * RELATIVE_TOLERANCES["rebound_ratio"])
    outcomes.loc[at(outcomes, "bounce", "mujoco", "RK4"), "measured"] = ratio
    got = findings(results, outcomes, SCENES, fits)
    assert len(got) == found
    assert not any("e²" in f.text for f in got)


SLIDING_PATH = {  # a quantity a sliding body's path should keep at 0, a miss of it, what is said
    "lift": (0.07, "lifts 0.07 m off the plane it should slide on"),
    "sideways": (0.03, "strays 0.03 m sideways of the line it should slide along"),
}


@pytest.mark.parametrize("quantity", SLIDING_PATH)
@pytest.mark.parametrize("beyond", [False, True])
def test_a_sliding_body_off_its_path_is_found_beyond_the_tolerance(quantity, beyond):
    miss, text = SLIDING_PATH[quantity]
    value = miss if beyond else 0.5 * ABSOLUTE_TOLERANCES[quantity]
    results, outcomes, fits = right_sweep()
    off = outcomes[at(outcomes, "slide", "mujoco", "Euler")].assign(
        quantity=quantity, measured=value, expected=0.0, error=value, unit="m"
    )
    got = findings(results, pd.concat([outcomes, off], ignore_index=True), SCENES, fits)
    said = f"**mujoco** Euler: {text}"
    assert [(f.kind, f.cases, f.text) for f in got] == [(quantity, ("slide",), said)] * beyond


def test_integrators_of_one_engine_share_a_finding():
    results, outcomes, fits = right_sweep()
    for integrator in ("Euler", "RK4"):
        outcomes.loc[at(outcomes, "slide", "mujoco", integrator), "measured"] = 0.95
    (found,) = findings(results, outcomes, SCENES, fits)
    assert found.text.startswith("**mujoco** Euler, RK4: stopping distance")
    assert "+6%" in found.text


def test_integrators_on_different_cases_are_found_apart():
    results, outcomes, fits = right_sweep()
    results.loc[at(results, "slide", "mujoco", "Euler"), "verdict"] = "diverged"
    results.loc[at(results, "bounce", "mujoco", "Euler"), "verdict"] = "diverged"
    results.loc[at(results, "bounce", "mujoco", "RK4"), "verdict"] = "diverged"
    found = findings(results, outcomes, SCENES, fits)
    said = [(f.text.split(":")[0], f.cases) for f in found]
    assert said == [("**mujoco** Euler", ("bounce", "slide")), ("**mujoco** RK4", ("bounce",))]


def test_values_that_read_the_same_are_said_once():
    results, outcomes, fits = right_sweep()
    for integrator, distance in (("Euler", 0.9521), ("RK4", 0.9549)):  # +5.8 % and +6.1 %
        outcomes.loc[at(outcomes, "slide", "mujoco", integrator), "measured"] = distance
    (found,) = findings(results, outcomes, SCENES, fits)
    assert found.text.endswith("stopping distance off its closed form by +6%")


def test_energy_drift_is_a_finding_without_contact_only():
    results, outcomes, fits = right_sweep()
    drift = 2 * ENERGY_DRIFT_NOTE
    results.loc[at(results, "tumbling_box", "mujoco", "Euler"), "energy_drift"] = drift
    results.loc[at(results, "slide", "mujoco", "Euler"), "energy_drift"] = drift
    (found,) = findings(results, outcomes, SCENES, fits)
    assert found.kind == "energy" and found.cases == ("tumbling_box",)


@pytest.mark.parametrize("order, found", [(1.0, True), (3.0, False), (-1.5, False)])
def test_an_order_below_the_expected_is_found(order, found):
    results, outcomes, fits = right_sweep()
    mine = (fits["case"] == "tumbling_box") & (fits["integrator"] == "splitting")
    fits.loc[mine, "order"] = order
    got = findings(results, outcomes, SCENES, fits)
    assert [f.kind for f in got] == (["order"] if found else [])


def _result(results: pd.DataFrame, outcomes: pd.DataFrame) -> SweepResult:
    table = results.reindex(columns=RESULT_COLUMNS)
    return SweepResult(SCENES, table, {}, {}, 1.0, {}, "test", outcomes=outcomes)


def test_the_summary_shows_verdicts_and_findings():
    results, outcomes, fits = right_sweep()
    text = "\n".join(summary_section(_result(results, outcomes), fits))
    table, legend = text.split("### Verdicts")  # the legend names every verdict
    assert "Nothing to report" in text and "verdict-diverged" not in table
    assert f"energy loss > {ENERGY_LOSS_LIMIT:g} × energy scale" in legend
    results.loc[at(results, "bounce", "mujoco", "Euler"), "verdict"] = "diverged"
    text = "\n".join(summary_section(_result(results, outcomes), fits))
    row = next(line for line in text.splitlines() if line.startswith("| [bounce](#case-bounce)"))
    assert "verdict-diverged" in row and "Euler" in row and "verdict-ok" in row
    assert "- **mujoco** Euler: diverged at the default dt ([bounce](#case-bounce))" in text


def test_the_most_accurate_engine_says_when_its_errors_are_against_its_own_runs():
    """mujoco's runs err a tenth of the reference's at equal cost on every case: it leads each
    one, and where the case has no exact motion (bounce, slide) its lead is by
    self-convergence."""
    results, outcomes, fits = right_sweep()
    finest = results["dt"] == results.groupby("case")["dt"].transform("min")
    results = results.assign(
        duration=1.0,
        wall_s=np.where(finest, 1.0, 0.5),
        orientation_error_deg=np.where(results["engine"] == "mujoco", 1.0, 10.0),
    )
    text = "\n".join(summary_section(_result(results, outcomes), fits))
    leaders = {
        line.split("]")[0][3:]: line.split("|")[-2].strip()
        for line in text.split("### Verdicts")[0].splitlines()
        if line.startswith("| [")
    }
    assert leaders == {
        "tumbling_box": "mujoco (2 of 2)",
        "bounce": "mujoco (2 of 2, self-convergence)",
        "slide": "mujoco (2 of 2, self-convergence)",
    }


def test_the_summary_shows_a_run_off_its_closed_form():
    results, outcomes, fits = right_sweep()
    miss = 3 * RELATIVE_TOLERANCES["stopping_distance"]
    outcomes.loc[at(outcomes, "slide", "mujoco", "Euler"), "measured"] = 0.9 * (1 + miss)
    # at another dt a miss is not the summary's
    outcomes.loc[at(outcomes, "slide", "mujoco", "RK4", 2.0), "measured"] = 0.9 * (1 + miss)
    text = "\n".join(summary_section(_result(results, outcomes), fits))
    row = next(line for line in text.splitlines() if line.startswith("| [slide](#case-slide)"))
    assert 'verdict-off">off</span> Euler; <span class="verdict verdict-ok">ok</span> RK4' in row
    # a run whose verdict is not ok shows its verdict, not its closed forms
    results.loc[at(results, "slide", "mujoco", "Euler"), "verdict"] = "jitter"
    text = "\n".join(summary_section(_result(results, outcomes), fits))
    row = next(line for line in text.splitlines() if line.startswith("| [slide](#case-slide)"))
    assert "verdict-off" not in row and 'verdict-jitter">jitter</span> Euler' in row


def test_the_summary_shows_no_number_where_nothing_was_measured():
    results, outcomes, fits = right_sweep()
    outcomes.loc[at(outcomes, "slide", "mujoco", "RK4"), "measured"] = np.nan  # never stops
    text = "\n".join(summary_section(_result(results, outcomes), fits))
    row = next(line for line in text.splitlines() if line.startswith("| [slide](#case-slide)"))
    assert "nan" not in row and "| – |" in row


def test_findings_tell_what_the_physics_gates_fail():
    """A quantity both judge is held to one limit: a report must not find fault with a run that
    its own gates table passes, nor pass one that it fails."""
    compared = set()
    for gate in load_gates([PHYSICS_DIR]):
        for limit in gate.limits:
            if not is_outcome_measure(limit.measure) or limit.measure == "slides":
                continue  # `slides` is 0 or 1: the findings' 0.5 is "must match", not a bound
            quantity, part = measure_parts(limit.measure)
            own = RELATIVE_TOLERANCES if part == "relative_error" else ABSOLUTE_TOLERANCES
            if quantity in own:
                bound = limit.max if limit.abs_max is None else limit.abs_max
                assert own[quantity] == bound, (gate.name, limit.measure)
                compared.add(quantity)
    assert compared == {
        "rebound_ratio",
        "stopping_distance",
        "spin_angle",
        "slope_acceleration",
        "lift",
        "sideways",
        "creep",
    }
