"""One case's section: its motion (animated, for the cases the report animates), metrics, drift
over time, convergence in dt, work-precision, stability map and, for a contact-free case, its
measured outcomes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from comparators.sweep import SweepResult
from reports import plots, texts
from reports.convergence import ERROR_FLOOR_DEG, lowest_front
from reports.sections.layout import case_figure, case_title, folded, subsection
from reports.sections.outcomes import case_outcomes
from reports.tables import EMPTY_CELL, escape_markdown, format_number, markdown_table

# results column -> metrics-table header, in table order
METRIC_HEADERS = {
    "engine": "engine",
    "integrator": "integrator",
    "dt": "dt (s)",
    "steps_per_s": "steps/s",
    "realtime_factor": "realtime factor",
    "energy_drift": "energy drift",
    "angular_momentum_drift": "L drift",
    "position_error": "position error (m)",
    "orientation_error_deg": "orientation error (deg)",
    "rest_com_height": "rest height (m)",
    "shape_error": "shape error",
    "solver_sweeps": "solver sweeps per solve",
    "solver_at_limit": "solves stopped unconverged",
    "solver_subspace": "subspace steps per solve",
    "solver_extrapolations": "extrapolations per solve",
    "engine_messages": "engine messages",
    "verdict": "verdict",
}
# what a case's folded detail holds
CASE_DETAIL = (
    "Metrics",
    "drift",
    "convergence in dt",
    "work-precision",
    "stability map",
    "outcomes",
)
# columns dropped when all NaN
SHOWN_WHERE_MEASURED = (
    "rest_com_height",
    "shape_error",
    "solver_sweeps",
    "solver_at_limit",
    "solver_subspace",
    "solver_extrapolations",
)


# Characters of an engine's first message shown in a cell (the results table has it whole).
MESSAGE_CELL_CHARS = 80


def any_engine_messages(runs: pd.DataFrame) -> bool:
    """True when an engine printed or warned something in some run of `runs`."""
    return bool((runs["engine_messages"].fillna(0) > 0).any())


def _messages_cell(row) -> str:
    """ "N: the first message" (shortened), or EMPTY_CELL when the engine said nothing."""
    if not row.engine_messages > 0:  # also NaN: a failed run, whose verdict says it all
        return EMPTY_CELL
    first = str(row.first_engine_message)
    if len(first) > MESSAGE_CELL_CHARS:
        first = first[: MESSAGE_CELL_CHARS - 1] + "…"
    return f"{int(row.engine_messages)}: {first}"


def _metrics_table(runs: pd.DataFrame) -> str:
    """One row per run, grouped by engine/integrator, largest dt first."""
    headers = {
        col: head
        for col, head in METRIC_HEADERS.items()
        if col not in SHOWN_WHERE_MEASURED or runs[col].notna().any()
    }
    if not any_engine_messages(runs):
        del headers["engine_messages"]
    pairs = list(zip(runs["engine"], runs["integrator"], strict=True))
    rank = {pair: k for k, pair in enumerate(dict.fromkeys(pairs))}
    table = runs.assign(_pair=[rank[p] for p in pairs])
    table = table.sort_values(["_pair", "dt"], ascending=[True, False], kind="stable")
    table["engine_messages"] = [_messages_cell(r) for r in table.itertuples()]
    return markdown_table(table[list(headers)].rename(columns=headers))


def _fit_table(fits: pd.DataFrame) -> str:
    """The fitted orders (`reports.convergence.fit_orders` rows) of one case."""

    def dt_range(row) -> str:
        return EMPTY_CELL if np.isnan(row.dt_min) else f"{row.dt_min:.3g} to {row.dt_max:.3g}"

    def position(row) -> str:
        if np.isfinite(row.position_order):
            return format_number(row.position_order)
        return row.position_note

    table = pd.DataFrame(
        {
            "engine": fits["engine"],
            "integrator": fits["integrator"],
            "fitted order": fits["order"],
            "expected": fits["expected_order"].astype(float),
            "R²": fits["r2"],
            "points": fits["points"],
            "dt range (s)": [dt_range(r) for r in fits.itertuples()],
            "position order": [position(r) for r in fits.itertuples()],
            "note": fits["note"],
        }
    )
    return markdown_table(table)


def _smallest_error(data: pd.DataFrame) -> str:
    """The sentence naming the run with the smallest error, and whether it is rounding."""
    best = data.loc[data[plots.ERROR].idxmin()]
    smallest = (
        f"The smallest error, {best[plots.ERROR]:.3g} deg, is {best['engine']} "
        f"{best['integrator']} at dt {best['dt']:.3g} s ({best[plots.COST]:.3g} s/s)."
    )
    if best[plots.ERROR] < ERROR_FLOOR_DEG:
        smallest += (
            f" Errors below {ERROR_FLOOR_DEG:g} deg are rounding: differences among them say "
            "nothing about accuracy."
        )
    return smallest


def _lowest(data: pd.DataFrame) -> pd.DataFrame:
    """`lowest_front` by engine of valid runs' orientation error against stepping time."""
    return lowest_front(data, plots.COST, plots.ERROR, "engine", ERROR_FLOOR_DEG)


def front_leader(runs: pd.DataFrame) -> tuple[str, int, int] | None:
    """(engine, budgets it is lowest at, budgets) of the engine most accurate at equal cost
    (`pareto_sentence`), None when fewer than two engines have valid runs with an error."""
    data = plots.valid_costs(runs)
    if data.empty or data["engine"].nunique() < 2:
        return None
    lowest = _lowest(data)
    counts = lowest.sum().sort_values(ascending=False, kind="stable")
    return counts.index[0], int(counts.iloc[0]), len(lowest)


def pareto_sentence(runs: pd.DataFrame) -> str:
    """Which engine holds the lowest work-precision front most often, and the smallest error."""
    data = plots.valid_costs(runs)
    if data.empty:
        return "No valid run with a nonzero orientation error: nothing to rank."
    smallest = _smallest_error(data)
    if data["engine"].nunique() == 1:
        return f"Only {data['engine'].iloc[0]} has valid runs with an error here. {smallest}"
    lowest = _lowest(data)
    counts = lowest.sum().sort_values(ascending=False, kind="stable")
    leader = counts.index[0]
    tied = lowest[lowest[leader] & (lowest.sum(axis=1) > 1)]
    ties = ""
    if len(tied):
        others = [e for e in tied.columns if e != leader and tied[e].any()]
        ties = f", {len(tied)} of them tied with {' and '.join(others)}"
    return (
        f"Lowest front: **{leader}**, which reaches the smallest error at "
        f"{counts.iloc[0]} of {len(lowest)} time budgets{ties} (a budget is each valid run's "
        "cost; an engine's error at a budget is the smallest error among its runs costing no "
        f"more, and errors below {ERROR_FLOOR_DEG:g} deg, rounding, count as equal). " + smallest
    )


def _intro(result: SweepResult, case: str) -> list[str]:
    """The case's heading, description, what is modelled and its reference."""
    scene = result.scenes[case]
    reference = result.references.get(case, EMPTY_CELL)
    lines = [
        f"## {case_title(case)}",
        "",
        f"{escape_markdown(scene.description)} Modelled: {escape_markdown(scene.modelled())}. "
        f"Errors against: {escape_markdown(reference)}.",
    ]
    if scene.expected is not None and scene.expected.rest_com_height is not None:
        lines.append(f"Expected rest height of the COM: {scene.expected.rest_com_height:g} m.")
    return lines


def case_section(
    result: SweepResult, case: str, fits: pd.DataFrame, figures: dict, out: Path
) -> list[str]:
    """The section of one case: its subsections, each with its figure or table."""
    scene = result.scenes[case]
    runs = result.results[result.results["case"] == case]
    if runs.empty:
        return [*_intro(result, case), "", "No runs."]
    solver = texts.SOLVER_NOTE if runs["solver_sweeps"].notna().any() else ""
    solver += texts.MESSAGES_NOTE if any_engine_messages(runs) else ""
    contact = texts.CONTACT_ORDER_NOTE if scene.has_contact else ""
    drift = case_figure(figures, case, "drift", out, "energy and angular momentum drift")
    errors = case_figure(figures, case, "convergence", out, "orientation error against dt")
    wp_alt = "orientation error against stepping time"
    work_precision = case_figure(figures, case, "work_precision", out, wp_alt)
    stability = case_figure(figures, case, "stability", out, "stability map")
    # only a case with a sliding body's straight line has a path to draw, a spun one's a spin
    sliding = {
        title: subsection(title, text, case_figure(figures, case, kind, out, title.lower()))
        for kind, title, text in (
            ("path", "Path on its plane", texts.PATH),
            ("spin", "Spin against time", texts.SPIN),
        )
        if (case, kind) in figures
    }
    fit_table = _fit_table(fits[fits["case"] == case])
    # the motion stays outside the fold: a reader sees each core case move without a click
    motion = []
    if (case, "animation") in figures:
        motion = subsection(
            "Motion", texts.MOTION, case_figure(figures, case, "animation", out, "motion")
        )
    detail = [
        *subsection("Metrics", texts.METRICS + solver, _metrics_table(runs)),
        *subsection("Drift over time", texts.DRIFT, drift),
        *(line for lines in sliding.values() for line in lines),
        *subsection("Convergence in dt", texts.CONVERGENCE + contact, errors, fit_table),
        *subsection("Work-precision", texts.WORK_PRECISION, work_precision, pareto_sentence(runs)),
        *subsection("Stability map", texts.STABILITY_MAP, stability),
        *case_outcomes(result, case),
    ]
    named = (*CASE_DETAIL[:2], *(title.lower() for title in sliding), *CASE_DETAIL[2:])
    return [*_intro(result, case), *motion, *folded(", ".join(named), detail)]
