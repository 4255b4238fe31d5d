"""The Scaling section: the stepping cost of `cube_rain_N` against N, and where the cost per
body-step stops being flat."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from cases.catalog import CUBE_RAIN_CLEARANCE, GRAVITY
from comparators.scaling import (
    FASTEST,
    FASTEST_DROP_FACTOR,
    FASTEST_MARGIN,
    OTHER,
    plateau_ends,
    scaling_rows,
    trial_rows,
)
from reports import texts
from reports.figures import SCALING_FIGURE, figure_link
from reports.sections.layout import section
from reports.tables import format_count, markdown_table

SCALING_HEADERS = {
    "steps": "steps",
    "n_bodies": "N",
    "engine": "engine",
    "integrator": "integrator",
    "series": "series",
    "cost_per_step_s": "per step (s)",
    "cost_per_body_step_s": "per body-step (s)",
    "repeats": "repeats",
    "setup_s": "setup (s)",
    "verdict": "verdict",
}
PLATEAU_HEADERS = {
    "engine": "engine",
    "integrator": "integrator",
    "series": "series",
    "steps": "steps",
    "plateau_cost_per_body_step_s": "plateau (s per body-step, fastest repeat)",
    "plateau_n": "at N",
    "flat_up_to": "flat up to N",
    "ends_at": "ends at N",
}


def _window(steps: int, dt: float, landing_s: float) -> str:
    """A measured window, and whether it ends before the first landing."""
    span = steps * dt
    what = "free fall" if span < landing_s else "landings and the pile included"
    return f"{steps} steps ({span:g} s): {what}"


def _by_header(formats: dict[str, Callable]) -> dict[str, Callable]:
    """`formats` keyed by the table headers (SCALING_HEADERS, PLATEAU_HEADERS) of the columns."""
    headers = SCALING_HEADERS | PLATEAU_HEADERS
    return {headers[column]: f for column, f in formats.items()}


def _runs_table(table: pd.DataFrame) -> str:
    """One row per scaling run, by window then N."""
    shown = scaling_rows(table).sort_values(["steps", "n_bodies"], kind="stable")
    shown = shown[list(SCALING_HEADERS)]
    counts = {"steps": format_count, "n_bodies": format_count, "repeats": format_count}
    return markdown_table(shown.rename(columns=SCALING_HEADERS), _by_header(counts))


def _plateau_table(table: pd.DataFrame) -> str:
    """Per engine and window, the plateau of cost per body-step and the N where it ends."""
    counts = {c: format_count for c in ("steps", "plateau_n", "flat_up_to", "ends_at")}
    return markdown_table(plateau_ends(table).rename(columns=PLATEAU_HEADERS), _by_header(counts))


def _trial(table: pd.DataFrame) -> tuple[str, str] | None:
    """The text and table of the trial that chose each engine's fastest integrator: every
    integrator's steps/s in its fastest repeat, its verdict and the series it became; None
    without a trial."""
    trial = trial_rows(table)
    if trial.empty:
        return None
    measured = scaling_rows(table)
    pairs = zip(measured["engine"], measured["integrator"], strict=True)
    series = dict(zip(pairs, measured["series"], strict=True))
    shown = pd.DataFrame(
        {
            "engine": trial["engine"],
            "integrator": trial["integrator"],
            "steps/s (fastest repeat)": trial["steps"] / trial["wall_min_s"],
            "repeats": trial["repeats"],
            "verdict": trial["verdict"],
            "series": [
                series.get(p, OTHER) for p in zip(trial["engine"], trial["integrator"], strict=True)
            ],
        }
    )
    text = texts.fastest(
        str(trial["case"].iloc[0]),
        int(trial["steps"].iloc[0]),
        float(trial["dt"].iloc[0]),
        FASTEST_MARGIN,
        FASTEST_DROP_FACTOR,
        _seed_note(shown),
    )
    return text, markdown_table(shown, {"repeats": format_count})


def _seed_note(shown: pd.DataFrame) -> str:
    """Whether the reference's `seed` (all pairs) was its fastest valid integrator."""
    own = shown[shown["engine"] == "reference"]
    seed = own[own["integrator"] == "seed"]
    if seed.empty:
        return "the reference's `seed` was not tried"
    if FASTEST in str(seed["series"].iloc[0]):
        return (
            "here `seed` was the reference's fastest valid integrator, so the reference's "
            "fastest series is the blog's all-pairs algorithm, not the rigid integrators' grid"
        )
    rates = own[own["verdict"] == "ok"].set_index("integrator")["steps/s (fastest repeat)"]
    if "seed" not in rates:
        return f"here `seed` was not valid ({seed['verdict'].iloc[0]})"
    return (
        f"here it was not the fastest ({rates['seed']:.3g} steps/s against "
        f"{rates.drop('seed').max():.3g})"
    )


def scaling_section(table: pd.DataFrame, figures: dict, out: Path) -> list[str]:
    """The section of a `comparators.scaling.measure_scaling` table, with its figure."""
    landing_s = float(np.sqrt(2 * CUBE_RAIN_CLEARANCE / np.linalg.norm(GRAVITY)))
    measured = scaling_rows(table)  # the trial's window is not one of the measured windows
    dt = float(measured["dt"].iloc[0]) if len(measured) else np.nan
    windows = "; ".join(_window(int(k), dt, landing_s) for k in sorted(measured["steps"].unique()))
    figure = figure_link(figures, SCALING_FIGURE, out, "stepping cost against N")
    figure = "*No scaling figure: no valid run.*" if figure is None else figure
    trial = _trial(table)
    return section(
        "Scaling",
        texts.scaling(landing_s, windows, fastest=trial is not None),
        *(trial or ()),
        figure,
        _runs_table(table),
        texts.PLATEAU,
        _plateau_table(table),
    )
