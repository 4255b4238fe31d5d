"""The sections before the cases: the title, how the timings were measured, throughput at each
case's default dt, and the catalog."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from comparators.bench import BASELINE, throughput_from_results
from comparators.sweep import SweepResult
from reports import plots, texts
from reports.figures import THROUGHPUT_FIGURE, figure_link
from reports.sections.layout import section
from reports.tables import (
    EMPTY_CELL,
    escape_markdown,
    format_text,
    is_empty,
    markdown_table,
    pair_label,
)


def header_section(result: SweepResult, command: str, scaling: bool = False) -> list[str]:
    """The title, when and by which command the report was made, what the sweep did."""
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    runs = len(result.results)
    return [
        "# rigidbench report",
        "",
        f"Generated {when} by `{command}`.",
        f"The sweep took {result.elapsed_s:.3g} s: {runs} runs, {result.computed} computed now "
        f"and {result.cached} taken from the results cache; executor: "
        f"{escape_markdown(result.executor)}.",
        "",
        *_left_out_lines(result.left_out),
        texts.data_files(scaling),
    ]


def _left_out_lines(lines: list[str]) -> list[str]:
    """The engines and runs the report leaves out and why, as a list (nothing when none)."""
    if not lines:
        return []
    return ["Left out:", "", *(f"- {escape_markdown(line)}" for line in lines), ""]


def timing_section(results: pd.DataFrame) -> list[str]:
    """How `wall_s` and `setup_s` were measured, with each engine's setup times."""
    repeats = results["repeats"].dropna().astype(int)
    n = f"{repeats.min()}" if repeats.nunique() <= 1 else f"{repeats.min()} to {repeats.max()}"
    setup = results.groupby("engine", sort=False)["setup_s"].agg(["count", "median", "max"])
    setup = setup.reset_index().rename(
        columns={"count": "runs", "median": "setup_s median (s)", "max": "setup_s max (s)"}
    )
    return section("How the timings were measured", texts.timing(n), markdown_table(setup))


def _throughput_cell(row) -> str:
    """ "steps/s (ratio to the baseline)", or the verdict of a run without a timing."""
    if is_empty(row.steps_per_s):
        return "failed" if str(row.verdict).startswith("failed") else format_text(row.verdict)
    ratio = (
        EMPTY_CELL if is_empty(row.ratio_vs_mujoco_euler) else f"{row.ratio_vs_mujoco_euler:.2f}"
    )
    return f"{row.steps_per_s:.3g} ({ratio})"


def _throughput_table(table: pd.DataFrame) -> str:
    """Cases (rows) by engine/integrator (columns, registry order), `_throughput_cell` each."""
    table = table.assign(
        pair=[pair_label(r.engine, r.integrator) for r in table.itertuples()],
        cell=[_throughput_cell(r) for r in table.itertuples()],
    )
    cells = table.pivot(index="case", columns="pair", values="cell")
    cells = cells.reindex(index=list(dict.fromkeys(table["case"])))
    pairs = dict.fromkeys(zip(table["engine"], table["integrator"], strict=True))
    cells = cells.reindex(columns=[pair_label(*p) for p in sorted(pairs, key=plots.pair_rank)])
    cells = cells.fillna(EMPTY_CELL)
    return markdown_table(cells.reset_index(), {c: str for c in cells.columns})


def throughput_section(result: SweepResult, figures: dict, out: Path) -> list[str]:
    """Steps/s per case at its default dt and engine/integrator, with the ratio to BASELINE."""
    table = throughput_from_results(result.results, result.scenes, result.outcomes)
    how = texts.throughput(*BASELINE)
    if table.empty:
        return section("Throughput", how, "No run at a case's default dt.")
    figure = figure_link(figures, THROUGHPUT_FIGURE, out, "stepping throughput")
    blocks = [figure] if figure is not None else []
    return section("Throughput", how, *blocks, _throughput_table(table))


def catalog_section(result: SweepResult) -> list[str]:
    """Each swept case: what it is, what it models, its tags and its reference solution."""
    rows = [
        {
            "case": name,
            "description": scene.description,
            "models": scene.modelled(),
            "tags": ", ".join(scene.tags),
            "reference solution": result.references.get(name, EMPTY_CELL),
        }
        for name, scene in result.scenes.items()
    ]
    return section("Catalog", texts.CASE_CATALOG, markdown_table(pd.DataFrame(rows)))
