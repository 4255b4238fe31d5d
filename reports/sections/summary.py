"""The report's first screen: per case the verdict of every engine/integrator at the case's
default dt and who is most accurate at equal cost, each engine's error on the closed-form
outcomes, and the findings (`reports.findings`) with links to their evidence."""

from __future__ import annotations

import pandas as pd

from cases.exact import exact_trajectory_available
from comparators.closed_forms import RUN_KEYS, is_miss, missed_by_run
from comparators.engine import ENGINES
from comparators.sweep import SweepResult
from reports import plots, texts
from reports.findings import Finding, at_default_dt, findings
from reports.sections.case import front_leader
from reports.sections.layout import case_link, section, subsection
from reports.tables import EMPTY_CELL, markdown_table

# The closed-form outcome the summary shows for a case, the first of these it measures: the
# one quantity that says most about the case (the contact validation section has them all).
HEADLINE_QUANTITIES = (
    "rebound_ratio",
    "stopping_distance",
    "spin_angle",
    "slope_acceleration",
    "rest_com_height",
    "flip_period",
    "momentum_change",
    "top_drift",
)


# The summary's state of a run whose verdict is ok but which misses a closed form.
OFF = "off"


def verdict_badge(verdict: str) -> str:
    """The verdict as a word in a span the page colours (`reports.html_page`); "failed: ..." as
    "failed"."""
    word = "failed" if verdict.startswith("failed") else verdict
    return f'<span class="verdict verdict-{word}">{word}</span>'


def _verdict_cell(runs: pd.DataFrame) -> str:
    """One engine's runs on one case (with their `shown` state, `_shown_states`): its
    integrators grouped by state ("ok" alone when all are), in the engine's integrator order."""
    pairs = list(zip(runs["engine"], runs["integrator"], strict=True))
    runs = runs.iloc[sorted(range(len(runs)), key=lambda k: plots.pair_rank(pairs[k]))]
    states = runs["shown"]
    if states.nunique() == 1:
        return verdict_badge(states.iloc[0])
    groups = dict.fromkeys(states)
    return "; ".join(
        f"{verdict_badge(v)} {', '.join(runs['integrator'][states == v])}" for v in groups
    )


def _shown_states(runs: pd.DataFrame, outcomes: pd.DataFrame) -> pd.Series:
    """Per run, what the summary shows: its verdict ("failed: ..." as "failed"), or OFF where
    the verdict is ok and a closed form is missed (`closed_forms.missed`, its `outcomes` rows)."""
    said = missed_by_run(outcomes)
    verdicts = runs["verdict"].map(lambda v: "failed" if v.startswith("failed") else v)
    off = [
        verdict == "ok" and is_miss(said.get(tuple(run)))
        for verdict, run in zip(verdicts, runs[RUN_KEYS].itertuples(index=False), strict=True)
    ]
    return verdicts.mask(off, OFF)


def verdict_table(result: SweepResult) -> pd.DataFrame:
    """Cases (rows, linked to their sections) by engine (columns, registry order):
    `_verdict_cell` at the case's default dt; then the engine most accurate at equal cost."""
    runs = at_default_dt(result.results, result.scenes)
    runs = runs.assign(shown=_shown_states(runs, result.outcomes))
    engines = sorted(runs["engine"].unique(), key=lambda e: plots.pair_rank((e, "")))
    rows = []
    for case in result.scenes:
        own = runs[runs["case"] == case]
        row = {"case": case_link(case)}
        for engine in engines:
            mine = own[own["engine"] == engine]
            row[engine] = _verdict_cell(mine) if len(mine) else EMPTY_CELL
        row["most accurate at equal cost"] = _leader_cell(result, case)
        rows.append(row)
    return pd.DataFrame(rows)


def _leader_cell(result: SweepResult, case: str) -> str:
    """ "engine (budgets it leads at of budgets)" (`front_leader`), marked where the errors are
    each engine's against its own finest dt (no exact motion): its runs' agreement with
    themselves, not with the physics; EMPTY_CELL where there is no leader."""
    leader = front_leader(result.results[result.results["case"] == case])
    if leader is None:
        return EMPTY_CELL
    against = "" if exact_trajectory_available(result.scenes[case]) else ", self-convergence"
    return f"{leader[0]} ({leader[1]} of {leader[2]}{against})"


def _outcome_cell(row) -> str:
    """ "measured (relative error)", the absolute error against a zero closed form, or
    EMPTY_CELL where nothing was measured (a body still sliding at the end has no stopping
    distance), as the contact validation table shows it."""
    if pd.isna(row.measured):
        return EMPTY_CELL
    if row.expected == 0:
        return f"{row.measured:.3g} ({row.error:+.2g} {row.unit})"
    return f"{row.measured:.4g} ({row.measured / row.expected - 1:+.1%})"


def outcome_table(result: SweepResult) -> pd.DataFrame:
    """Per case with a closed-form outcome, its first HEADLINE_QUANTITIES quantity: the closed
    form and each engine's measurement with its default integrator at the default dt, beside
    the run's verdict when it is not ok (instead of it when the run diverged or failed)."""
    measured = at_default_dt(result.outcomes, result.scenes)
    measured = measured[measured["expected"].notna()]
    runs = at_default_dt(result.results, result.scenes)
    engines = sorted(runs["engine"].unique(), key=lambda e: plots.pair_rank((e, "")))
    defaults = {e: ENGINES[e].default_integrator if e in ENGINES else None for e in engines}
    rows = []
    for case in result.scenes:
        own = measured[measured["case"] == case]
        quantity = next((q for q in HEADLINE_QUANTITIES if (own["quantity"] == q).any()), None)
        if quantity is None:
            continue
        own = own[own["quantity"] == quantity]
        first = own.iloc[0]
        row = {
            "case": case_link(case),
            "quantity": f"{quantity} ({first['unit']})",
            "closed form": f"{first['expected']:.4g}",
        }
        for engine in engines:
            mine = own[(own["engine"] == engine) & (own["integrator"] == defaults[engine])]
            run = runs[
                (runs["case"] == case)
                & (runs["engine"] == engine)
                & (runs["integrator"] == defaults[engine])
            ]
            verdict = run["verdict"].iloc[0] if len(run) else "ok"
            cell = _outcome_cell(mine.iloc[0]) if len(mine) else EMPTY_CELL
            if verdict.startswith(("diverged", "failed")):
                cell = verdict_badge(verdict)  # its measurements say nothing
            elif verdict != "ok":
                cell += " " + verdict_badge(verdict)
            row[f"{engine} {defaults[engine]}"] = cell
        rows.append(row)
    return pd.DataFrame(rows)


def verdicts_block() -> str:
    """Every verdict with what it says and its bound (`texts.verdict_bounds`), each verdict
    word in its colour."""
    rows = [
        {"verdict": verdict_badge(v), "what it says": what, "bound": bound}
        for v, what, bound in texts.verdict_bounds()
    ]
    table = pd.DataFrame(rows)
    return markdown_table(table, {c: str for c in table.columns})


def _finding_line(finding: Finding) -> str:
    links = ", ".join(case_link(case) for case in finding.cases)
    return f"- {finding.text} ({links})"


def summary_section(result: SweepResult, fits: pd.DataFrame) -> list[str]:
    """The summary: verdicts (and what each means, with its bound), closed forms, findings."""
    verdicts = verdict_table(result)
    as_is = {c: str for c in verdicts.columns}
    lines = section("Summary", texts.SUMMARY, markdown_table(verdicts, as_is), texts.SUMMARY_LEGEND)
    lines += subsection("Verdicts", texts.VERDICTS, verdicts_block())
    outcomes = outcome_table(result)
    if len(outcomes):
        table = markdown_table(outcomes, {c: str for c in outcomes.columns})
        lines += subsection("Closed forms", texts.SUMMARY_OUTCOMES, table)
    found = findings(result.results, result.outcomes, result.scenes, fits)
    listed = "\n".join(_finding_line(f) for f in found) or "Nothing to report: every run is ok."
    lines += subsection("Findings", texts.FINDINGS, listed)
    return lines
