"""The report: a sweep's results as tables, figures, `report.md` and a self-contained `index.html`.

`write_report` writes into one directory: results.parquet and results.csv (one row per run,
`RESULT_COLUMNS`), outcomes.parquet and outcomes.csv (one row per run and measured quantity,
`OUTCOMES_COLUMNS`), figures/*.png, report.md (renders on GitHub) and index.html (the same text,
figures referenced beside it). Every number comes from the `SweepResult`, and those of the
Scaling section from a `comparators.scaling.measure_scaling` table, written as scaling.csv.

The parts: `reports.tables` (cells and files), `reports.figures` (which figures, where),
`reports.sections` (one function per section), `reports.texts` (how to read each section),
`reports.html_page` (index.html).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from comparators.engine import ENGINES
from comparators.sweep import SweepResult
from reports.convergence import fit_orders
from reports.figures import (
    ANIMATED_CASES,
    FIGURES_DIR,
    write_case_figures,
    write_scaling_figure,
    write_throughput_figure,
)
from reports.html_page import render_html
from reports.sections.case import case_section
from reports.sections.layout import contents
from reports.sections.limits import cost_section, largest_stable_section
from reports.sections.manifest import parity_section, versions_section
from reports.sections.outcomes import contact_validation_section
from reports.sections.overview import (
    catalog_section,
    header_section,
    throughput_section,
    timing_section,
)
from reports.sections.physics import physics_section
from reports.sections.scaling import scaling_section
from reports.sections.summary import summary_section
from reports.tables import write_outcomes, write_results, write_scaling, write_text


def expected_orders(result: SweepResult) -> dict[tuple[str, str], int]:
    """The sweep's expected orders, completed by what each registered engine declares."""
    declared = {(n, i): p for n, e in ENGINES.items() for i, p in e.orders.items()}
    return declared | result.orders


def render_markdown(
    result: SweepResult,
    command: str,
    fits: pd.DataFrame,
    figures: dict,
    out: Path,
    scaling: pd.DataFrame | None = None,
) -> str:
    """report.md's text; `figures` by key (`reports.figures`), paths under `out`; a Scaling
    section when `scaling` is given."""
    parts = [summary_section(result, fits), throughput_section(result, figures, out)]
    parts += [catalog_section(result)]
    parts += [case_section(result, case, fits, figures, out) for case in result.scenes]
    parts += [largest_stable_section(result), contact_validation_section(result)]
    parts += [physics_section(result)]
    parts += [cost_section(result.results)]
    if scaling is not None:
        parts += [scaling_section(scaling, figures, out)]
    parts += [timing_section(result.results), parity_section(result), versions_section(result)]
    # the summary first, then the contents of everything after it
    parts = [
        header_section(result, command, scaling is not None),
        parts[0],
        contents(parts),
        *parts[1:],
    ]
    return "\n".join("\n".join(p) + "\n" for p in parts)


def write_report(
    result: SweepResult,
    out: Path,
    command: str,
    scaling: pd.DataFrame | None = None,
    animated: tuple[str, ...] = ANIMATED_CASES,
) -> dict[str, Path]:
    """Write results, figures (the animations of the `animated` cases among them), report.md
    and index.html into `out`, and with a `scaling` table
    (`comparators.scaling.measure_scaling`) scaling.csv, figures/scaling.png and the Scaling
    section; returns them by name relative to `out` ("results.csv",
    "figures/tumbling_box_drift.png", ...)."""
    out = Path(out)
    (out / FIGURES_DIR).mkdir(parents=True, exist_ok=True)
    written = write_results(result.results, out)
    written |= write_outcomes(result.outcomes, out)
    fits = fit_orders(result.results, expected_orders(result))
    figures = write_case_figures(result, fits, out, animated=animated)
    figures |= write_throughput_figure(result, out)
    if scaling is not None:
        written |= write_scaling(scaling, out)
        figures |= write_scaling_figure(scaling, out)
    text = render_markdown(result, command, fits, figures, out, scaling)
    written["report.md"] = write_text(out / "report.md", text)
    written["index.html"] = write_text(out / "index.html", render_html(text))
    written |= {p.relative_to(out).as_posix(): p for p in figures.values()}
    return written
