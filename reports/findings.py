"""Findings: short statements generated from a sweep's results, each naming its evidence.

Every finding follows from the results and outcomes tables by a rule below, at each case's
default dt (what a user of the engine gets); none is written by hand. The summary section lists
them with links to the cases they come from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from cases.scene import Scene
from comparators.closed_forms import RELATIVE_TOLERANCES, miss

# Verdicts other than "ok" worth a finding, worst first, and how a sentence says each.
VERDICT_PHRASES = {
    "diverged": "diverged",
    "dissipated": "dissipated (lost energy without contact)",
    "tunnelled": "tunnelled (a body passed through a plane)",
    "jitter": "jitter (never came to rest)",
}
QUANTITY_NAMES = {
    "rebound_ratio": "rebound ratio",
    "stopping_distance": "stopping distance",
    "spin_angle": "spin-down angle",
    "slope_acceleration": "slope acceleration",
    "rest_com_height": "rest height",
    "creep": "creep",
    "lift": "lift",
    "sideways": "sideways",
    "slides": "slides",
}
# How a sliding body that leaves the path both closed forms assume is said (the value in m).
OFF_PATH = {
    "lift": "lifts {} m off the plane it should slide on",
    "sideways": "strays {} m sideways of the line it should slide along",
}
# A body without contact conserves its energy exactly; a drift above a tenth at the default dt
# changes the motion's character (a tumbler's spin moves between its axes), not only its phase.
ENERGY_DRIFT_NOTE = 0.1
# A fitted convergence order this far from the expected one, with a fit this good, is a
# different order (fits scatter by about 0.1 around the expected order, docs/benchmarks.md).
ORDER_MISMATCH = 0.5
ORDER_FIT_R2 = 0.9


@dataclass(frozen=True)
class Finding:
    """One statement: `text` (Markdown, naming engine and integrator), `cases` its evidence."""

    kind: str
    text: str
    cases: tuple[str, ...]


def at_default_dt(table: pd.DataFrame, scenes: dict[str, Scene]) -> pd.DataFrame:
    """The rows of `table` (results or outcomes) run at their case's default dt."""
    default = table["case"].map({name: scene.dt for name, scene in scenes.items()})
    return table[np.isclose(table["dt"].astype(float), default.astype(float), rtol=1e-9)]


def _values(items, fmt: str) -> str:
    """The items' values as "low to high" (one value when they read the same)."""
    values = [i.value for i in items]
    low, high = format(min(values), fmt), format(max(values), fmt)
    return low if low == high else f"{low} to {high}"


@dataclass(frozen=True)
class _Item:
    engine: str
    integrator: str
    case: str
    value: float
    squared: bool = False  # a rebound ratio at e squared, within the rebound's tolerance


def _gather(items: list[_Item], kind: str, describe) -> list[Finding]:
    """One finding per engine and set of cases: the engine's integrators among `items` that
    share the same cases, so that each integrator named did it on each case linked;
    `describe(their items)` the sentence after them."""
    by_run: dict[tuple[str, str], list[_Item]] = {}
    for item in items:
        by_run.setdefault((item.engine, item.integrator), []).append(item)
    groups: dict[tuple[str, tuple[str, ...]], list[_Item]] = {}
    for (engine, _), own in by_run.items():
        cases = tuple(dict.fromkeys(i.case for i in own))
        groups.setdefault((engine, cases), []).extend(own)
    engines = list(dict.fromkeys(i.engine for i in items))  # an engine's findings together
    found = []
    for (engine, cases), own in sorted(groups.items(), key=lambda g: engines.index(g[0][0])):
        integrators = ", ".join(dict.fromkeys(i.integrator for i in own))
        found.append(Finding(kind, f"**{engine}** {integrators}: {describe(own)}", cases))
    return found


def verdict_findings(results: pd.DataFrame, scenes: dict[str, Scene]) -> list[Finding]:
    """Engine/integrators whose runs at the default dt end in a verdict other than ok."""
    runs = at_default_dt(results, scenes)
    found = []
    for verdict, phrase in VERDICT_PHRASES.items():
        bad = runs[runs["verdict"] == verdict]
        items = [_Item(r.engine, r.integrator, r.case, 0.0) for r in bad.itertuples()]
        found += _gather(items, verdict, lambda _, p=phrase: f"{p} at the default dt")
    return found


def _outcome_miss(row) -> _Item | None:
    """The item of an outcome row that misses its closed form (`closed_forms.miss`), None
    within tolerance."""
    value = miss(row.quantity, float(row.measured), float(row.expected))
    if value is None:
        return None
    tolerance = RELATIVE_TOLERANCES.get(row.quantity, 0.0) * row.expected**2
    squared = row.quantity == "rebound_ratio" and abs(row.measured - row.expected**2) <= tolerance
    return _Item(row.engine, row.integrator, row.case, value, squared)


def outcome_findings(
    outcomes: pd.DataFrame, results: pd.DataFrame, scenes: dict[str, Scene]
) -> list[Finding]:
    """Engine/integrators whose closed-form outcomes at the default dt miss their closed form
    by more than the quantity's tolerance: relative misses for RELATIVE_TOLERANCES (a rebound
    ratio at e squared said so), absolute ones for ABSOLUTE_TOLERANCES. Only runs
    with the verdict ok: the others have their verdict's finding."""
    ok = results.loc[results["verdict"] == "ok", ["case", "engine", "integrator", "dt"]]
    rows = at_default_dt(outcomes.merge(ok, on=["case", "engine", "integrator", "dt"]), scenes)
    found = []
    for quantity, name in QUANTITY_NAMES.items():
        own = rows[rows["quantity"] == quantity]
        items = [i for i in map(_outcome_miss, own.itertuples()) if i is not None]
        if quantity in RELATIVE_TOLERANCES:

            def describe(mine, name=name):
                text = f"{name} off its closed form by {_values(mine, '+.0%')}"
                return text + (
                    ", at e² (restitution applied twice)" if all(i.squared for i in mine) else ""
                )
        elif quantity in OFF_PATH:

            def describe(mine, phrase=OFF_PATH[quantity]):
                return phrase.format(_values(mine, ".2g"))
        elif quantity == "slides":

            def describe(mine):
                return " and ".join(
                    sorted(
                        {
                            "slides where it should stick"
                            if i.value > 0
                            else "sticks where it should slide"
                            for i in mine
                        }
                    )
                )
        else:
            unit = own["unit"].iloc[0] if len(own) else ""

            def describe(mine, name=name, unit=unit):
                return f"{name} off its closed form by {_values(mine, '+.2g')} {unit}"

        found += _gather(items, quantity, describe)
    return found


def energy_findings(results: pd.DataFrame, scenes: dict[str, Scene]) -> list[Finding]:
    """Engine/integrators that drift in energy without contact, where energy is conserved."""
    runs = at_default_dt(results, scenes)
    free = [name for name, scene in scenes.items() if not scene.has_contact]
    runs = runs[runs["case"].isin(free) & (runs["verdict"] == "ok")]
    runs = runs[runs["energy_drift"] > ENERGY_DRIFT_NOTE]
    items = [_Item(r.engine, r.integrator, r.case, r.energy_drift) for r in runs.itertuples()]
    return _gather(
        items, "energy", lambda mine: f"energy drifts {_values(mine, '.0%')} without contact"
    )


def order_findings(fits: pd.DataFrame, scenes: dict[str, Scene]) -> list[Finding]:
    """Engine/integrators whose fitted order in dt on a contact-free case is below the expected
    one (contact lowers every order: the report says so where it fits it; an order above the
    expected one is a symmetric body's errors cancelling, not a fault)."""
    free = [name for name, scene in scenes.items() if not scene.has_contact]
    fits = fits[fits["case"].isin(free) & np.isfinite(fits["order"].astype(float))]
    # a negative order is rounding growing with the step count (the `exact` integrator over
    # 100 s), not an order of the integrator's truncation error
    off = (fits["expected_order"] - fits["order"] > ORDER_MISMATCH) & (fits["order"] > 0)
    fits = fits[off & (fits["r2"] >= ORDER_FIT_R2)]
    found = []
    for expected, own in fits.groupby("expected_order", sort=False):
        items = [_Item(f.engine, f.integrator, f.case, f.order) for f in own.itertuples()]
        found += _gather(
            items,
            "order",
            lambda mine, e=expected: f"fitted order {_values(mine, '.2g')}, expected {e:g}",
        )
    return found


def findings(
    results: pd.DataFrame, outcomes: pd.DataFrame, scenes: dict[str, Scene], fits: pd.DataFrame
) -> list[Finding]:
    """Every rule's findings: verdicts, closed-form outcomes, energy, convergence orders."""
    return [
        *verdict_findings(results, scenes),
        *outcome_findings(outcomes, results, scenes),
        *energy_findings(results, scenes),
        *order_findings(fits, scenes),
    ]
