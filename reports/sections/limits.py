"""The sections across cases that say how far each engine goes: the largest stable dt, and the
cost of reaching an orientation tolerance."""

from __future__ import annotations

import numpy as np
import pandas as pd

from comparators.sweep import SweepResult
from reports import plots, texts
from reports.convergence import cost_to_tolerance, largest_stable_dt
from reports.sections.layout import section
from reports.tables import escape_markdown, format_text, markdown_table, pair_label

TOLERANCES_DEG = (1e-2, 1e-4, 1e-6)  # the orientation tolerances of the cost table's columns


def _stable_cell(row) -> str:
    """ "≥ dt_max" when every swept dt is ok, else the largest stable dt (or "none") and the
    verdict of the first failing dt."""
    if row.all_stable:
        return f"≥ {row.dt_max:.3g}"
    failure = str(row.first_unstable_verdict)
    failure = "failed" if failure.startswith("failed") else failure
    stable = "none" if np.isnan(row.largest_stable_dt) else f"{row.largest_stable_dt:.3g}"
    return f"{stable} ({failure} at {row.first_unstable_dt:.3g})"


def largest_stable_section(result: SweepResult) -> list[str]:
    """Per case and engine/integrator, the largest dt up to which every run is ok."""
    stable = largest_stable_dt(result.results)
    if stable.empty:
        return section("Largest stable dt", texts.LARGEST_STABLE, "No runs.")
    stable = stable.assign(
        pair=[pair_label(r.engine, r.integrator) for r in stable.itertuples()],
        cell=[_stable_cell(r) for r in stable.itertuples()],
    )
    table = stable.pivot(index="case", columns="pair", values="cell")
    table = table.reindex(index=list(dict.fromkeys(stable["case"])))
    pairs = sorted(dict.fromkeys(zip(stable["engine"], stable["integrator"], strict=True)))
    table = table.reindex(columns=[pair_label(*p) for p in sorted(pairs, key=plots.pair_rank)])
    cells = markdown_table(table.reset_index(), {c: format_text for c in table.columns})
    return section("Largest stable dt", texts.LARGEST_STABLE, cells)


def _cost_cell(row) -> str:
    """ "cost s/s (integrator, dt)" of the cheapest run within the tolerance, or "not reached"."""
    if np.isnan(row.cost_s_per_s):
        return "not reached"
    return f"{row.cost_s_per_s:.3g} s/s ({escape_markdown(row.integrator)}, dt {row.dt:.3g} s)"


def cost_section(results: pd.DataFrame) -> list[str]:
    """Per case and engine, the least stepping time that keeps the error within each tolerance."""
    costs = cost_to_tolerance(results, TOLERANCES_DEG)
    if costs.empty:
        none = "No case with an exact reference was swept."
        return section("Cost to reach a tolerance", texts.COST_TO_TOLERANCE, none)
    costs = costs.assign(cell=[_cost_cell(r) for r in costs.itertuples()])
    table = costs.pivot(index=["case", "engine"], columns="tolerance_deg", values="cell")
    table = table.reindex(columns=list(TOLERANCES_DEG))
    table.columns = [f"≤ {tol:g} deg" for tol in table.columns]
    order = costs[["case", "engine"]].drop_duplicates()
    order = order.assign(
        rank=order["case"].map({c: k for k, c in enumerate(dict.fromkeys(order["case"]))})
    )
    table = table.reindex(
        order.sort_values(["rank", "engine"])[["case", "engine"]].itertuples(index=False)
    )
    cells = markdown_table(table.reset_index(), {c: str for c in table.columns})
    return section("Cost to reach a tolerance", texts.COST_TO_TOLERANCE, cells)
