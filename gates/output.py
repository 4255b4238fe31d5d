"""The checks of `gates.evaluate` as text: table cells, the command's closing line, a failure's
message, and JUnit XML (one test case per check) for CI systems that read it."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd

from comparators.trajectory import atomic_path


def format_measured(value) -> str:
    """A measured value: 4 significant digits (the verdict of a verdict check as it is)."""
    if isinstance(value, str):
        return value
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return f"{value:.4g}"


def format_margin(margin: float) -> str:
    """The fraction of the limit left, as a percentage."""
    if math.isnan(margin):
        return ""
    if math.isinf(margin):
        return "+inf" if margin > 0 else "-inf"
    return f"{100 * margin:+.1f}%"


def result_word(passed) -> str:
    return "not checked" if passed is None else ("pass" if passed else "FAIL")


def check_id(row) -> str:
    """case-engine-integrator-dt-measure of a checks-table row (`gates.evaluate.Check.id`)."""
    dt = "all-dt" if math.isnan(row.dt) else f"dt={row.dt:g}"
    return f"{row.case}-{row.engine}-{row.integrator}-{dt}-{row.measure}"


def failure_message(row) -> str:
    """Why a check failed (or was not checked): measured against limit, or the reason."""
    where = f"{row.gate} [{check_id(row)}]"
    if row.reason:
        shown = format_measured(row.measured)
        measured = f" (measured {shown})" if shown not in ("n/a", "failed") else ""
        return f"{where}: {row.reason}{measured}; limit {row.limit}"
    return (
        f"{where}: {row.measure} measured {format_measured(row.measured)} against limit "
        f"{row.limit} (margin {format_margin(row.margin)})"
    )


def closing_line(checks: pd.DataFrame, elapsed_s: float) -> str:
    """The gate command's closing line: counts of checks and runs."""
    passed = int((checks["passed"] == True).sum())  # noqa: E712 (None: not checked)
    failed = int((checks["passed"] == False).sum())  # noqa: E712
    unchecked = len(checks) - passed - failed
    runs = checks.attrs
    text = (
        f"gate: {len(checks)} checks of {checks['gate'].nunique()} gate(s): {passed} passed, "
        f"{failed} failed"
    )
    if unchecked:
        text += f", {unchecked} not checked"
    if "computed" in runs:
        text += f" ({runs['computed']} runs computed, {runs['cached']} cached)"
    return text + f" in {elapsed_s:.1f} s"


def write_junit(checks: pd.DataFrame, out: Path) -> None:
    """`out` as JUnit XML, written atomically: a test suite per gate file, a test case per
    check (classname the file and gate, name its id), failed and not-checked ones with why."""
    root = ET.Element("testsuites", name="rigidbench gate")
    for file, rows in checks.groupby("file", sort=False):
        failed = int((rows["passed"] == False).sum())  # noqa: E712
        skipped = int(rows["passed"].isna().sum())
        suite = ET.SubElement(
            root,
            "testsuite",
            name=str(file),
            tests=str(len(rows)),
            failures=str(failed),
            skipped=str(skipped),
            errors="0",
        )
        for row in rows.itertuples():
            case = ET.SubElement(
                suite, "testcase", classname=f"{file}::{row.gate}", name=check_id(row)
            )
            if row.passed is None:
                ET.SubElement(case, "skipped", message=row.reason)
            elif not row.passed:
                ET.SubElement(case, "failure", message=failure_message(row))
    with atomic_path(out) as tmp:
        ET.ElementTree(root).write(tmp, encoding="utf-8", xml_declaration=True)
