"""Measured outcomes against their closed forms: a contact-free case's Outcomes subsection, and
the Contact validation section for the cases with contact."""

from __future__ import annotations

import numpy as np
import pandas as pd

from comparators.sweep import SweepResult
from reports import plots, texts
from reports.sections.layout import section, subsection
from reports.tables import EMPTY_CELL, escape_markdown, is_empty, markdown_table, pair_label


def _outcome_cell(measured: float, error: float, errors: pd.Series) -> str:
    """ "measured (error)" at the default dt, and "[min, max]" of the error over the swept dts
    when there are several."""
    if is_empty(measured):
        return EMPTY_CELL
    cell = f"{measured:.4g}"
    if not is_empty(error):
        cell += f" ({error:+.2g})"
    errors = errors.dropna()
    if len(errors) > 1:
        cell += f" [{errors.min():+.2g}, {errors.max():+.2g}]"
    return cell


def _closest_cell(runs: pd.DataFrame, default_dt: float) -> str:
    """`_outcome_cell` of the run closest to `default_dt` on a log scale, among `runs` (one
    quantity, one engine/integrator)."""
    if not len(runs):
        return EMPTY_CELL
    distance = np.abs(np.log(runs["dt"].to_numpy(float) / default_dt))
    at = runs.iloc[int(np.argmin(distance))]
    return _outcome_cell(at["measured"], at["error"], runs["error"])


def outcome_table(outcomes: pd.DataFrame, default_dt: float) -> pd.DataFrame:
    """One case's outcomes as a table: a row per quantity (with its unit and closed form), a
    column per engine/integrator holding `_outcome_cell` at `default_dt` (or the closest swept
    dt on a log scale when the run at `default_dt` is missing)."""
    quantities = list(dict.fromkeys(outcomes["quantity"]))
    pairs = dict.fromkeys(zip(outcomes["engine"], outcomes["integrator"], strict=True))
    pairs = sorted(pairs, key=plots.pair_rank)
    rows = []
    for quantity in quantities:
        own = outcomes[outcomes["quantity"] == quantity]
        expected = own["expected"].dropna()
        row = {
            "quantity": f"{quantity} ({own['unit'].iloc[0]})",
            "closed form": f"{expected.iloc[0]:.4g}" if len(expected) else EMPTY_CELL,
        }
        for engine, integrator in pairs:
            runs = own[(own["engine"] == engine) & (own["integrator"] == integrator)]
            row[pair_label(engine, integrator)] = _closest_cell(runs, default_dt)
        rows.append(row)
    return pd.DataFrame(rows)


def _outcomes_of(result: SweepResult, case: str) -> pd.DataFrame:
    return result.outcomes[result.outcomes["case"] == case]


def case_outcomes(result: SweepResult, case: str) -> list[str]:
    """Outcomes of a contact-free case, in its own subsection (contact cases have theirs in the
    contact validation section)."""
    scene = result.scenes[case]
    own = _outcomes_of(result, case)
    if scene.has_contact or own.empty:
        return []
    return subsection("Outcomes", texts.CASE_OUTCOMES, markdown_table(outcome_table(own, scene.dt)))


def contact_validation_section(result: SweepResult) -> list[str]:
    """Per case with contact, its outcomes against their closed forms."""
    cases = [
        case
        for case, scene in result.scenes.items()
        if scene.has_contact and not _outcomes_of(result, case).empty
    ]
    if not cases:
        none = "No case with contact has measured outcomes."
        return section("Contact validation", texts.CONTACT_VALIDATION, none)
    lines = section("Contact validation", texts.CONTACT_VALIDATION, texts.CONTACT_OUTCOMES)
    for case in cases:
        scene = result.scenes[case]
        table = markdown_table(outcome_table(_outcomes_of(result, case), scene.dt))
        about = f"{escape_markdown(scene.description)} Default dt {scene.dt:g} s."
        lines += subsection(f"`{case}`", about, table)
    return lines
