"""The report's tables: cells formatted for Markdown pipe tables, and the tables (and any text
file) written as CSV, Parquet or text, atomically."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from comparators.scaling import SCALING_COLUMNS
from comparators.sweep import OUTCOMES_COLUMNS, RESULT_COLUMNS
from comparators.trajectory import atomic_path

EMPTY_CELL = "–"  # a cell with no value (not measured, or not relevant to the run)


# ---- cells ----------------------------------------------------------------------------------


def escape_markdown(text: object) -> str:
    """Text safe in a Markdown table cell, on GitHub and in Python-Markdown."""
    text = str(text).replace("\n", " ")
    for char in "\\`*_[]":
        text = text.replace(char, "\\" + char)
    return text.replace("|", "\\|").replace("<", "&lt;")


def is_empty(value: object) -> bool:
    """None or NaN: a value that was not measured."""
    return value is None or (isinstance(value, float) and np.isnan(value))


def format_number(value: object) -> str:
    """3 significant digits; NaN and None as EMPTY_CELL."""
    return EMPTY_CELL if is_empty(value) else f"{value:.3g}"


def format_text(value: object) -> str:
    """Escaped text; NaN and None as EMPTY_CELL."""
    return EMPTY_CELL if is_empty(value) else escape_markdown(value)


def format_count(value: object) -> str:
    """A whole number; NaN and None as EMPTY_CELL."""
    return EMPTY_CELL if is_empty(value) else f"{int(value)}"


def pair_label(engine: str, integrator: str) -> str:
    """The column header of one engine/integrator."""
    return f"{engine} {integrator}"


def markdown_table(df: pd.DataFrame, formats: dict[str, Callable] | None = None) -> str:
    """A GitHub pipe table: numeric columns to 3 significant digits and right-aligned, text
    escaped, NaN as EMPTY_CELL. `formats` overrides the formatter of named columns."""
    formats = formats or {}
    cells, align = pd.DataFrame(index=df.index), []
    for col in df.columns:
        numeric = pd.api.types.is_numeric_dtype(df[col]) and not pd.api.types.is_bool_dtype(df[col])
        cells[col] = df[col].map(formats.get(col, format_number if numeric else format_text))
        align.append("right" if numeric else "left")
    # unpadded: padding every cell to its column's widest made the report half spaces
    rule = {"right": "---:", "left": ":---"}
    lines = [
        _row(str(c) for c in df.columns),
        _row(rule[a] for a in align),
        *(_row(row) for row in cells.itertuples(index=False)),
    ]
    return "\n".join(lines)


def _row(cells) -> str:
    return "| " + " | ".join(cells) + " |"


# ---- files ----------------------------------------------------------------------------------


def write_text(path: Path, text: str) -> Path:
    """`text` as UTF-8 into `path`, atomically."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path


def _write_table(table: pd.DataFrame, columns: list[str], name: str, out: Path, formats):
    """NAME.csv (and NAME.parquet among `formats`) in `out`, exactly `columns`, written
    atomically; a missing column is an error naming what was expected."""
    absent = [c for c in columns if c not in table]
    if absent:
        raise ValueError(f"{name} table lacks column(s) {absent}: expected {columns}")
    table = table[columns].reset_index(drop=True)
    paths = {}
    for fmt in formats:
        path = paths[f"{name}.{fmt}"] = out / f"{name}.{fmt}"
        with atomic_path(path) as tmp:
            if fmt == "parquet":
                table.to_parquet(tmp, index=False)
            else:
                table.to_csv(tmp, index=False)
    return paths


def write_results(results: pd.DataFrame, out: Path) -> dict[str, Path]:
    """results.parquet and results.csv: one row per run, exactly `RESULT_COLUMNS`."""
    return _write_table(results, RESULT_COLUMNS, "results", out, ("parquet", "csv"))


def write_outcomes(outcomes: pd.DataFrame, out: Path) -> dict[str, Path]:
    """outcomes.parquet and outcomes.csv: one row per run and measured quantity, exactly
    `OUTCOMES_COLUMNS`."""
    return _write_table(outcomes, OUTCOMES_COLUMNS, "outcomes", out, ("parquet", "csv"))


def write_scaling(table: pd.DataFrame, out: Path) -> dict[str, Path]:
    """scaling.csv: one row per scaling run, exactly `SCALING_COLUMNS`."""
    return _write_table(table, SCALING_COLUMNS, "scaling", out, ("csv",))
