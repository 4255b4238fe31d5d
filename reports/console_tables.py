"""The tables the `rigidbench` commands print on the terminal: a run's metrics and its outcomes
against their closed forms (`run`), the bench's throughput (`bench`) and the gates' checks
(`gate`), with the number formats they share."""

from __future__ import annotations

import math

from rich import box
from rich.table import Table
from rich.text import Text

from comparators import closed_forms


def metrics_table(summary: dict) -> Table:
    """One run's metrics (`comparators.summary.summarize`), a row each."""
    table = Table(show_header=False)
    table.add_column("metric", style="bold")
    table.add_column("value", justify="right")
    for key, value in summary.items():
        table.add_row(key, format_metric(value))
    return table


def format_metric(value) -> str:
    """A metric for the terminal: 4 significant digits, small values in scientific notation."""
    if isinstance(value, float):
        if math.isnan(value):
            return "n/a"
        return f"{value:.4g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.3e}"
    return str(value)


def format_rate(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{value:.3g}"


THROUGHPUT_HEADERS = ("case", "engine", "integrator", "dt", "steps/s [min, max]", "vs MuJoCo Euler")


def throughput_table(table, title: str) -> Table:
    """The bench table for the terminal: steps/s median [min, max], the ratio, the lines the
    engine printed or warned (where any did), the verdict and the closed forms missed (where
    any run was judged). Nothing is cut short in a narrow terminal: a cell too wide folds onto
    the next line (cut short, `cube_rain_8` and `cube_rain_1000` both read `cube_rai…`). No
    vertical rules and one space between columns leave the names whole in 80 columns in most
    tables."""
    said = bool((table["engine_messages"].fillna(0) > 0).any())
    judged = bool(table["closed_forms_missed"].notna().any())
    shown = Table(title=title, box=box.SIMPLE_HEAD, padding=0, show_edge=False)
    words = ("case", "engine", "integrator", "verdict", "closed forms missed")
    for col in (
        *THROUGHPUT_HEADERS,
        *(("messages",) if said else ()),
        "verdict",
        *(("closed forms missed",) if judged else ()),
    ):
        shown.add_column(
            Text(col),  # Text: "[min, max]" is no markup
            justify="left" if col in words else "right",
            overflow="fold",
        )
    for row in table.itertuples():
        rate = format_rate(row.steps_per_s)
        if not math.isnan(row.steps_per_s):
            rate += f" [{format_rate(row.steps_per_s_min)}, {format_rate(row.steps_per_s_max)}]"
        ratio = format_rate(row.ratio_vs_mujoco_euler)
        cells = [row.case, row.engine, row.integrator, f"{row.dt:g}", rate, ratio]
        if said:
            cells.append(format_metric(row.engine_messages))
        cells.append(row.verdict)
        if judged:
            missed = row.closed_forms_missed
            cells.append(missed if isinstance(missed, str) else "n/a")
        shown.add_row(*map(Text, cells))
    return shown


def outcomes_table(said, verdict: str = "ok") -> Table:
    """One run's outcomes (`comparators.outcomes`) against their closed forms, each judged by
    the rule of the report's findings (`comparators.closed_forms`) where it has a tolerance;
    under a run whose verdict is not ok, a caption says the report judges only ok runs."""
    table = Table(title="outcomes against their closed forms")
    if verdict != "ok":
        table.caption = f"the run's verdict is {verdict}: the report's findings judge only ok runs"
    numbers = ("measured", "closed form", "tolerance")
    for header in ("quantity", "unit", *numbers, "judged"):
        table.add_column(header, justify="right" if header in numbers else "left")
    for row in said.itertuples():
        allowed = closed_forms.tolerance(row.quantity)
        value = closed_forms.miss(row.quantity, row.measured, row.expected)
        if allowed is None or math.isnan(row.expected) or math.isnan(row.measured):
            judged = ""
        elif value is None:
            judged = "within"
        else:
            judged = f"missed by {closed_forms.missed_by(row.quantity, value, row.unit)}"
        cells = (
            row.quantity,
            row.unit,
            format_metric(row.measured),
            format_metric(row.expected),
            allowed or "",
            judged,
        )
        table.add_row(*map(Text, cells))
    return table


def gate_table(checks) -> Table:
    """The checks for the terminal, one row each (why a check has no measurement follows the
    table, `gate_reasons`)."""
    from gates.output import format_margin, format_measured, result_word

    shown = Table(title="gates")
    for col in ("gate", "run", "measure", "measured", "limit", "margin", "result"):
        right = col in ("measured", "margin")
        shown.add_column(col, justify="right" if right else "left", overflow="fold")
    for row in checks.itertuples():
        dt = "all dt" if math.isnan(row.dt) else f"dt={row.dt:g}"
        cells = [row.gate, f"{row.engine} {row.integrator} {dt}", row.measure]
        cells += [format_measured(row.measured), row.limit, format_margin(row.margin)]
        cells.append(result_word(row.passed))
        shown.add_row(*map(Text, cells))  # Text: brackets in a name are no markup
    return shown


def gate_reasons(checks) -> list[str]:
    """One line per check that failed or was not checked for a reason: which, and why."""
    from gates.output import failure_message, result_word

    said = checks[checks["reason"] != ""]
    return [f"{result_word(row.passed)}: {failure_message(row)}" for row in said.itertuples()]
