"""The report: a sweep's results as tables, figures, `report.md` and a self-contained `index.html`.

`write_report` writes into one directory: results.parquet and results.csv (one row per run,
`RESULT_COLUMNS`), outcomes.parquet and outcomes.csv (one row per run and measured quantity,
`OUTCOMES_COLUMNS`), figures/*.png, report.md (renders on GitHub) and index.html (the same text,
figures referenced beside it). Every number comes from the `SweepResult`, and those of the
Scaling section from a `comparators.scaling.measure_scaling` table, written as scaling.csv.
"""

from __future__ import annotations

import html
import json
import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from datetime import UTC, datetime
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlparse

import markdown
import numpy as np
import pandas as pd

from cases.catalog import CUBE_RAIN_CLEARANCE, GRAVITY
from comparators.bench import BASELINE, throughput_from_results
from comparators.engine import ENGINES
from comparators.outcomes import ENERGY_GROWTH_LIMIT, FINAL_FRACTION, FINAL_WINDOW_S, JITTER_SPEED
from comparators.scaling import PLATEAU_FACTOR, SCALING_COLUMNS, plateau_ends
from comparators.sweep import OUTCOMES_COLUMNS, RESULT_COLUMNS, SweepResult
from comparators.trajectory import atomic_path
from reports import plots
from reports.convergence import (
    ERROR_CEILING_DEG,
    ERROR_FLOOR_DEG,
    MIN_FIT_POINTS,
    POSITION_FLOOR_M,
    cost_to_tolerance,
    fit_orders,
    largest_stable_dt,
    lowest_front,
)

FIGURES = "figures"
TOLERANCES_DEG = (1e-2, 1e-4, 1e-6)
MISSING = "–"  # a cell with no value (not measured, or not relevant to the run)

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
    "verdict": "verdict",
}
# columns dropped when all NaN
SHOWN_WHERE_MEASURED = (
    "rest_com_height",
    "shape_error",
    "solver_sweeps",
    "solver_at_limit",
    "solver_subspace",
    "solver_extrapolations",
)

CSS = """
body { font-family: system-ui, sans-serif; max-width: 60rem; margin: 2rem auto; padding: 0 1rem;
       line-height: 1.45; color: #222; }
table { border-collapse: collapse; margin: 0.8rem 0; font-size: 0.9rem; display: block;
        overflow-x: auto; }
th, td { border: 1px solid #bbb; padding: 0.2rem 0.5rem; }
th { background: #f0f0f0; }
td { font-variant-numeric: tabular-nums; }
img { max-width: 100%; }
code { background: #f4f4f4; padding: 0 0.2rem; }
"""

PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>{css}</style>
</head>
<body>
{body}
</body>
</html>
"""


# ---- cells and tables --------------------------------------------------------------------


def _escape(text: object) -> str:
    """Text safe in a Markdown table cell, on GitHub and in Python-Markdown."""
    text = str(text).replace("\n", " ")
    for char in "\\`*_[]":
        text = text.replace(char, "\\" + char)
    return text.replace("|", "\\|").replace("<", "&lt;")


def _missing(value: object) -> bool:
    return value is None or (isinstance(value, float) and np.isnan(value))


def _number(value: object) -> str:
    """3 significant digits; NaN and None as MISSING."""
    return MISSING if _missing(value) else f"{value:.3g}"


def _text(value: object) -> str:
    return MISSING if _missing(value) else _escape(value)


def markdown_table(df: pd.DataFrame, formats: dict[str, Callable] | None = None) -> str:
    """A GitHub pipe table: numeric columns to 3 significant digits and right-aligned, text
    escaped, NaN as MISSING. `formats` overrides the formatter of named columns."""
    formats = formats or {}
    cells, align = pd.DataFrame(index=df.index), []
    for col in df.columns:
        numeric = pd.api.types.is_numeric_dtype(df[col]) and not pd.api.types.is_bool_dtype(df[col])
        cells[col] = df[col].map(formats.get(col, _number if numeric else _text))
        align.append("right" if numeric else "left")
    return cells.to_markdown(index=False, disable_numparse=True, colalign=align)


# ---- files ----------------------------------------------------------------------------------


def _write_text(path: Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")
    return path


def _write_table(table: pd.DataFrame, columns: list[str], name: str, out: Path, formats):
    """NAME.csv (and NAME.parquet among `formats`) in `out`, exactly `columns`, written
    atomically; a missing column is an error naming what was expected."""
    missing = [c for c in columns if c not in table]
    if missing:
        raise ValueError(f"{name} table lacks column(s) {missing}: expected {columns}")
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


def expected_orders(result: SweepResult) -> dict[tuple[str, str], int]:
    """The sweep's expected orders, completed by what each registered engine declares."""
    declared = {(n, i): p for n, e in ENGINES.items() for i, p in e.orders.items()}
    return declared | result.orders


def _case_figures(task: tuple) -> dict[tuple, Path]:
    """One case's figures, by (case, kind): `task` is (case, runs, trajectories, scene, fits,
    directory)."""
    case, runs, trajectories, scene, fits, path = task
    converges = runs["dt"].nunique() >= MIN_FIT_POINTS  # fewer dt: no line worth drawing
    drawn = {
        "drift": plots.plot_drift(runs, trajectories, scene, path / f"{case}_drift.png"),
        "convergence": plots.plot_convergence(runs, fits, path / f"{case}_convergence.png")
        if converges
        else None,
        "work_precision": plots.plot_work_precision(runs, path / f"{case}_work_precision.png"),
        "stability": plots.plot_stability(runs, path / f"{case}_stability.png"),
    }
    return {(case, kind): p for kind, p in drawn.items() if p is not None}


def write_figures(
    result: SweepResult, fits: pd.DataFrame, out: Path, jobs: int | None = None
) -> dict[tuple, Path]:
    """All figures, by (case, kind); kinds without anything to draw are left out.

    Cases are drawn in `jobs` processes (default: one per core, at most one per case): Agg
    rendering is CPU-bound and the cases are independent.
    """
    tasks = []
    for case, runs in result.results.groupby("case", sort=False):
        scene = result.scenes[case]
        drawn = plots.closest_runs(runs, set(result.trajectories), scene.dt)["key"]
        trajectories = {key: result.trajectories[key] for key in drawn}
        tasks.append((case, runs, trajectories, scene, fits[fits["case"] == case], out / FIGURES))
    jobs = min(len(tasks), jobs or os.cpu_count() or 1)
    if jobs <= 1:
        drawn = [_case_figures(task) for task in tasks]
    else:
        with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("fork")) as pool:
            drawn = list(pool.map(_case_figures, tasks))
    return {key: path for figures in drawn for key, path in figures.items()}


# ---- sections ---------------------------------------------------------------------------------


def _image(figures: dict, case: str, kind: str, out: Path, alt: str) -> str:
    path = figures.get((case, kind))
    if path is None:
        return (
            f"*No {alt} figure: nothing to show (a convergence plot needs {MIN_FIT_POINTS} or "
            "more dt swept; the other figures need a valid run).*"
        )
    return f"![{alt}, {case}]({path.relative_to(out).as_posix()})"


def _header(result: SweepResult, command: str, scaling: bool = False) -> list[str]:
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    runs = len(result.results)
    scaled = ("scaling with the number of bodies; ", ", `scaling.csv` (one row per scaling run)")
    scaled = scaled if scaling else ("", "")
    return [
        "# rigidbench report",
        "",
        f"Generated {when} by `{command}`.",
        f"The sweep took {result.elapsed_s:.3g} s: {runs} runs, {result.computed} computed now "
        f"and {result.cached} taken from the results cache; executor: {_escape(result.executor)}.",
        "",
        "Sections: how the timings were measured; throughput; the catalog; per case its "
        "metrics, drift over "
        "time, convergence in dt, work-precision, stability map and measured outcomes; the "
        "largest stable dt; contact validation against closed forms; cost to reach a tolerance; "
        f"{scaled[0]}the parity manifest; machine and versions. All numbers are in `results.csv` "
        f"(one row per run){scaled[1]} and `outcomes.csv` (one row per run and measured "
        "quantity).",
    ]


def _timing(results: pd.DataFrame) -> list[str]:
    repeats = results["repeats"].dropna().astype(int)
    n = f"{repeats.min()}" if repeats.nunique() <= 1 else f"{repeats.min()} to {repeats.max()}"
    setup = results.groupby("engine", sort=False)["setup_s"].agg(["count", "median", "max"])
    setup = setup.reset_index().rename(
        columns={"count": "runs", "median": "setup_s median (s)", "max": "setup_s max (s)"}
    )
    return [
        "## How the timings were measured",
        "",
        "Times are stepping only (`wall_s`): building the engine's model and JIT compilation "
        "are timed apart as `setup_s` (below). Each `wall_s` is the median of "
        f"{n} repeat(s) (min and max in `results.csv` as `wall_min_s`, `wall_max_s`), engines "
        "are interleaved so that machine load falls on all of them alike, and only valid runs "
        "(finite, not diverged) are timed. steps/s = steps / `wall_s`; realtime factor = "
        "simulated seconds per stepping second (above 1 is faster than real time).",
        "",
        markdown_table(setup),
    ]


THROUGHPUT = "throughput"  # the figure's kind, and its key (None, THROUGHPUT) in `figures`


def _throughput_cell(row) -> str:
    """ "steps/s (ratio to the baseline)", or the verdict of a run without a timing."""
    if _missing(row.steps_per_s):
        return "failed" if str(row.verdict).startswith("failed") else _text(row.verdict)
    ratio = MISSING if _missing(row.ratio_vs_mujoco_euler) else f"{row.ratio_vs_mujoco_euler:.2f}"
    return f"{row.steps_per_s:.3g} ({ratio})"


def _throughput(result: SweepResult, figures: dict, out: Path) -> list[str]:
    table = throughput_from_results(result.results, result.scenes)
    engine, integrator = BASELINE
    lines = [
        "## Throughput",
        "",
        "How to read: per case at its default dt (rows) and engine/integrator (columns), steps "
        "per second of stepping from this sweep's timings (medians, measured as above; higher "
        f"is faster), in parentheses its ratio to {engine} {integrator} on the same case and dt; "
        "the figure adds each run's [min, max] over its repeats. Runs went through the "
        "executor's workers, which share the machine; `rigidbench bench` times the same side "
        "by side in one process, at least 5 repeats each.",
        "",
    ]
    if table.empty:
        return [*lines, "No run at a case's default dt."]
    path = figures.get((None, THROUGHPUT))
    if path is not None:
        lines += [f"![stepping throughput]({path.relative_to(out).as_posix()})", ""]
    table = table.assign(
        pair=[_pair_label(r.engine, r.integrator) for r in table.itertuples()],
        cell=[_throughput_cell(r) for r in table.itertuples()],
    )
    cells = table.pivot(index="case", columns="pair", values="cell")
    cells = cells.reindex(index=list(dict.fromkeys(table["case"])))
    pairs = dict.fromkeys(zip(table["engine"], table["integrator"], strict=True))
    cells = cells.reindex(columns=[_pair_label(*p) for p in sorted(pairs, key=plots.pair_rank)])
    cells = cells.fillna(MISSING)
    return [*lines, markdown_table(cells.reset_index(), {c: str for c in cells.columns})]


def write_throughput_figure(result: SweepResult, out: Path) -> dict[tuple, Path]:
    """figures/throughput.png by (None, THROUGHPUT); none when no run is at a default dt."""
    table = throughput_from_results(result.results, result.scenes)
    if table.empty:
        return {}
    title = "stepping throughput at each case's default dt (higher is faster)"
    path = plots.plot_throughput(table, out / FIGURES / f"{THROUGHPUT}.png", title)
    return {(None, THROUGHPUT): path}


def _catalog(result: SweepResult) -> list[str]:
    rows = [
        {
            "case": name,
            "description": scene.description,
            "models": scene.modelled(),
            "tags": ", ".join(scene.tags),
            "reference solution": result.references.get(name, MISSING),
        }
        for name, scene in result.scenes.items()
    ]
    return [
        "## Catalog",
        "",
        "How to read: what each case is, what an engine has to model for it, and what its errors "
        "are measured against (exact: closed form; self-convergence: the same engine and "
        "integrator at the finest dt).",
        "",
        markdown_table(pd.DataFrame(rows)),
    ]


def _metrics(runs: pd.DataFrame) -> str:
    headers = {
        col: head
        for col, head in METRIC_HEADERS.items()
        if col not in SHOWN_WHERE_MEASURED or runs[col].notna().any()
    }
    pairs = list(zip(runs["engine"], runs["integrator"], strict=True))
    rank = {pair: k for k, pair in enumerate(dict.fromkeys(pairs))}
    table = runs.assign(_pair=[rank[p] for p in pairs])
    table = table.sort_values(["_pair", "dt"], ascending=[True, False], kind="stable")
    return markdown_table(table[list(headers)].rename(columns=headers))


def _fit_table(fits: pd.DataFrame) -> str:
    def dt_range(row) -> str:
        return MISSING if np.isnan(row.dt_min) else f"{row.dt_min:.3g} to {row.dt_max:.3g}"

    def position(row) -> str:
        return _number(row.position_order) if np.isfinite(row.position_order) else row.position_note

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


def _pareto_sentence(runs: pd.DataFrame) -> str:
    data = plots.valid_costs(runs)
    if data.empty:
        return "No valid run with a nonzero orientation error: nothing to rank."
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
    if data["engine"].nunique() == 1:
        return f"Only {data['engine'].iloc[0]} has valid runs with an error here. {smallest}"
    lowest = lowest_front(data, plots.COST, plots.ERROR, "engine", ERROR_FLOOR_DEG)
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


SOLVER_NOTE = (
    " Solver columns are what an engine reports of its own contact solver, where it reports "
    "anything: the reference's Gauss-Seidel sweeps per solve (two solves a step with contact), "
    "the solves it stopped unconverged (at its iteration limit, or stalled), its subspace steps "
    "per solve (a direct solve of the contacts that push, each costing more than a sweep) and "
    "its extrapolations per solve (a jump along the sweeps' steady rate of convergence)."
)
CONTACT_ORDER_NOTE = (
    " With contact, impacts are resolved once per step, so no integrator converges faster "
    "than first order overall; the expected orders are those of the smooth motion between "
    "contacts, and a low R² says the error is not a power law of dt at all (a contact "
    "sequence that changes with dt)."
)


def _case(result: SweepResult, case: str, fits: pd.DataFrame, figures: dict, out: Path):
    scene = result.scenes[case]
    runs = result.results[result.results["case"] == case]
    reference = result.references.get(case, MISSING)
    lines = [
        f"## Case `{case}`",
        "",
        f"{_escape(scene.description)} Modelled: {_escape(scene.modelled())}. "
        f"Errors against: {_escape(reference)}.",
    ]
    if scene.expected is not None and scene.expected.rest_com_height is not None:
        lines.append(f"Expected rest height of the COM: {scene.expected.rest_com_height:g} m.")
    if runs.empty:
        return [*lines, "", "No runs."]
    return [
        *lines,
        "",
        "### Metrics",
        "",
        "How to read: drifts are relative maxima over the run (0 is exact conservation), errors "
        "the largest over the run against the reference; steps/s and realtime factor are "
        "stepping only, higher is faster."
        + (SOLVER_NOTE if runs["solver_sweeps"].notna().any() else ""),
        "",
        _metrics(runs),
        "",
        "### Drift over time",
        "",
        "How to read: relative error of total energy and angular momentum against time at the "
        "case's default dt (or the closest swept); a bounded wobble is what a symplectic "
        "integrator gives, a steady climb is secular drift.",
        "",
        _image(figures, case, "drift", out, "energy and angular momentum drift"),
        "",
        "### Convergence in dt",
        "",
        "How to read: on log-log axes an error ~ dt^p is a straight line of slope p, the "
        "fitted order; fits use valid runs with errors between "
        f"{ERROR_FLOOR_DEG:g} deg (rounding below) and {ERROR_CEILING_DEG:g} deg (saturation "
        f"above) and need {MIN_FIT_POINTS} such dt. R² near 1: a clean power law. Position "
        f'order "exact": every position error is below {POSITION_FLOOR_M:g} m (rounding).'
        + (CONTACT_ORDER_NOTE if scene.has_contact else ""),
        "",
        _image(figures, case, "convergence", out, "orientation error against dt"),
        "",
        _fit_table(fits[fits["case"] == case]),
        "",
        "### Work-precision",
        "",
        "How to read: lower left is better, less error for less stepping time; each engine's "
        "Pareto front is its best error for a given time.",
        "",
        _image(figures, case, "work_precision", out, "orientation error against stepping time"),
        "",
        _pareto_sentence(runs),
        "",
        "### Stability map",
        "",
        "How to read: where each engine and integrator breaks as dt grows: red diverged (a "
        "non-finite state, or the energy grown past "
        f"{ENERGY_GROWTH_LIMIT:g} times what the scene holds), orange tunnelled (a particle "
        "centre behind a plane), pink jitter (a body that should rest still moves faster than "
        f"{JITTER_SPEED:g} m/s at the end), dark grey failed (no run); valid runs are coloured "
        "by their orientation error, light grey where none is measured.",
        "",
        _image(figures, case, "stability", out, "stability map"),
        *_case_outcomes(result, case),
    ]


# ---- stability and outcomes -------------------------------------------------------------------


def _pair_label(engine: str, integrator: str) -> str:
    return f"{engine} {integrator}"


def _stable_cell(row) -> str:
    """ "≥ dt_max" when every swept dt is ok, else the largest stable dt (or "none") and the
    verdict of the first failing dt."""
    if row.all_stable:
        return f"≥ {row.dt_max:.3g}"
    failure = str(row.first_unstable_verdict)
    failure = "failed" if failure.startswith("failed") else failure
    stable = "none" if np.isnan(row.largest_stable_dt) else f"{row.largest_stable_dt:.3g}"
    return f"{stable} ({failure} at {row.first_unstable_dt:.3g})"


def _largest_stable(result: SweepResult) -> list[str]:
    stable = largest_stable_dt(result.results)
    lines = [
        "## Largest stable dt",
        "",
        "How to read: per case (rows) and engine/integrator (columns), the largest swept dt (s) "
        "whose run and every run at a smaller dt have the verdict ok, with in parentheses the "
        "verdict and dt of the first run that is not; ≥ dt: every swept dt is ok, the limit lies "
        "beyond the sweep; none: even the smallest swept dt fails. A case swept at one dt only "
        "(the quick report's hard cases) says ok or not at its default dt.",
        "",
    ]
    if stable.empty:
        return [*lines, "No runs."]
    stable = stable.assign(
        pair=[_pair_label(r.engine, r.integrator) for r in stable.itertuples()],
        cell=[_stable_cell(r) for r in stable.itertuples()],
    )
    table = stable.pivot(index="case", columns="pair", values="cell")
    table = table.reindex(index=list(dict.fromkeys(stable["case"])))
    pairs = sorted(dict.fromkeys(zip(stable["engine"], stable["integrator"], strict=True)))
    table = table.reindex(columns=[_pair_label(*p) for p in sorted(pairs, key=plots.pair_rank)])
    return [*lines, markdown_table(table.reset_index(), {c: _text for c in table.columns})]


def _outcome_cell(measured: float, error: float, errors: pd.Series) -> str:
    """ "measured (error)" at the default dt, and "[min, max]" of the error over the swept dts
    when there are several."""
    if _missing(measured):
        return MISSING
    cell = f"{measured:.4g}"
    if not _missing(error):
        cell += f" ({error:+.2g})"
    errors = errors.dropna()
    if len(errors) > 1:
        cell += f" [{errors.min():+.2g}, {errors.max():+.2g}]"
    return cell


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
            "closed form": f"{expected.iloc[0]:.4g}" if len(expected) else MISSING,
        }
        for engine, integrator in pairs:
            runs = own[(own["engine"] == engine) & (own["integrator"] == integrator)]
            cell = MISSING
            if len(runs):
                distance = np.abs(np.log(runs["dt"].to_numpy(float) / default_dt))
                at = runs.iloc[int(np.argmin(distance))]
                cell = _outcome_cell(at["measured"], at["error"], runs["error"])
            row[_pair_label(engine, integrator)] = cell
        rows.append(row)
    return pd.DataFrame(rows)


OUTCOMES_HOW_TO_READ = (
    "How to read: per quantity (unit), its closed form and per engine/integrator the value "
    "measured at the case's default dt from the trajectory, its error (measured - closed form) "
    "in parentheses and, when several dts were swept, the range of that error over them in "
    "brackets; – where there is no closed form or no measurement. rebound_ratio: mean over the "
    "first bounces of the COM's normal rebound over approach speed, each carried ballistically "
    "to the floor; apex_height_k: clearance of the lowest particle surface at the k-th apex; "
    "stopping distance and time: until the COM speed stays below 1 mm/s; slope_acceleration: "
    "least-squares fit of the downhill COM displacement, slides 1 or sticks 0; creep, "
    "jitter_rms (RMS COM speed) and penetration (deepest particle surface below the floor) over "
    f"the final window (the last {FINAL_FRACTION:.0%} of the run, at most {FINAL_WINDOW_S:g} s), "
    "whose closed form at rest is 0; standing 1 or fallen 0 and top_drift of a stack; momentum "
    "changes relative to the bodies' summed momenta; max_penetration: the deepest any particle "
    "surface went below a plane (no closed form; beyond the particle radius is a tunnel); "
    "flip_period: mean time between sign changes of the intermediate principal axis's component "
    "along the angular momentum (the flips of a spin near that axis; half the nutation period "
    "of a spin near another), against the exact solution's at the same sample times."
)


def _outcomes_for(result: SweepResult, case: str) -> pd.DataFrame:
    return result.outcomes[result.outcomes["case"] == case]


def _case_outcomes(result: SweepResult, case: str) -> list[str]:
    """Outcomes of a contact-free case, in its own section (contact cases have theirs in the
    contact validation section)."""
    scene = result.scenes[case]
    own = _outcomes_for(result, case)
    if scene.has_contact or own.empty:
        return []
    table = outcome_table(own, scene.dt)
    how = (
        "How to read: per quantity (unit), its closed form and per engine/integrator the value "
        "measured at the case's default dt, its error (measured - closed form) in parentheses "
        "and, with several dts swept, the error's range over them in brackets. flip_period: mean "
        "time between sign changes of the intermediate principal axis's component along the "
        "angular momentum (the flips of a spin near that axis; half the nutation period of a "
        "spin near another), against the exact solution's at the same sample times."
    )
    return ["", "### Outcomes", "", how, "", markdown_table(table)]


def _contact_validation(result: SweepResult) -> list[str]:
    lines = [
        "## Contact validation",
        "",
        "What every engine does on the cases with contact, measured from its trajectories the "
        "same way for all (`comparators.outcomes`), against what physics predicts in closed form "
        "where the case states it.",
    ]
    cases = [
        case
        for case, scene in result.scenes.items()
        if scene.has_contact and not _outcomes_for(result, case).empty
    ]
    if not cases:
        return [*lines, "", "No case with contact has measured outcomes."]
    lines += ["", OUTCOMES_HOW_TO_READ]
    for case in cases:
        scene = result.scenes[case]
        table = outcome_table(_outcomes_for(result, case), scene.dt)
        lines += [
            "",
            f"### `{case}`",
            "",
            f"{_escape(scene.description)} Default dt {scene.dt:g} s.",
            "",
            markdown_table(table),
        ]
    return lines


def _cost(results: pd.DataFrame) -> list[str]:
    costs = cost_to_tolerance(results, TOLERANCES_DEG)
    lines = [
        "## Cost to reach a tolerance",
        "",
        "How to read: per case and engine, the least stepping time per simulated second (s/s) "
        "among its valid runs (any integrator, any dt) whose orientation error stays within "
        "the tolerance, and which run achieved it; only cases with an exact reference.",
        "",
    ]
    if costs.empty:
        return [*lines, "No case with an exact reference was swept."]

    def cell(row) -> str:
        if np.isnan(row.cost_s_per_s):
            return "not reached"
        return f"{row.cost_s_per_s:.3g} s/s ({_escape(row.integrator)}, dt {row.dt:.3g} s)"

    costs = costs.assign(cell=[cell(r) for r in costs.itertuples()])
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
    return [*lines, markdown_table(table.reset_index(), {c: str for c in table.columns})]


SCALING_HEADERS = {
    "steps": "steps",
    "n_bodies": "N",
    "engine": "engine",
    "integrator": "integrator",
    "cost_per_step_s": "per step (s)",
    "cost_per_body_step_s": "per body-step (s)",
    "repeats": "repeats",
    "setup_s": "setup (s)",
    "verdict": "verdict",
}
PLATEAU_HEADERS = {
    "engine": "engine",
    "integrator": "integrator",
    "steps": "steps",
    "plateau_cost_per_body_step_s": "plateau (s per body-step, fastest repeat)",
    "plateau_n": "at N",
    "flat_up_to": "flat up to N",
    "ends_at": "ends at N",
}


def _count(value: object) -> str:
    return MISSING if _missing(value) else f"{int(value)}"


def _window(steps: int, dt: float, landing_s: float) -> str:
    span = steps * dt
    what = "free fall" if span < landing_s else "landings and the pile included"
    return f"{steps} steps ({span:g} s): {what}"


def _scaling(table: pd.DataFrame, figure: Path | None, out: Path) -> list[str]:
    landing_s = float(np.sqrt(2 * CUBE_RAIN_CLEARANCE / np.linalg.norm(GRAVITY)))
    dt = float(table["dt"].iloc[0]) if len(table) else np.nan
    windows = "; ".join(_window(int(k), dt, landing_s) for k in sorted(table["steps"].unique()))
    lines = [
        "## Scaling",
        "",
        "How to read: the stepping cost of `cube_rain_N`, N cubes raining into an open box "
        "(`cases.catalog.cube_rain`), against N, each engine with its default integrator, run "
        "from t = 0 through the same path as every run (trajectory recorded). Times are "
        "stepping only, the median of the repeats (min and max in `scaling.csv`), engines "
        "interleaved; setup (model building and compilation) is apart. On the log-log plot a "
        "cost growing as N runs parallel to the dashed line; a steeper line grows faster than "
        "N. The bottom layer lands after "
        f"about {landing_s:.1g} s, so a window shorter than that is free fall: the same work "
        "per body at every N, a cost per body that grows is the engine's collision detection. "
        "A longer window adds contact solving, and the work per body then grows with the pile "
        f"as well (a lone cube touches only the floor). Windows: {windows}.",
        "",
    ]
    if figure is None:
        lines += ["*No scaling figure: no valid run.*", ""]
    else:
        lines += [f"![stepping cost against N]({figure.relative_to(out).as_posix()})", ""]
    shown = table.sort_values(["steps", "n_bodies"], kind="stable")[list(SCALING_HEADERS)]
    counts = {"steps": _count, "n_bodies": _count, "repeats": _count}
    lines += [markdown_table(shown.rename(columns=SCALING_HEADERS), _renamed(counts))]
    ends = plateau_ends(table)
    lines += [
        "",
        "Where cost per body-step stops being flat: per engine and window, the plateau is the "
        "smallest cost per body-step over the smaller N, and it ends at the first N whose cost "
        f"per body-step exceeds {PLATEAU_FACTOR:g} times it ({MISSING}: flat up to the largest "
        "N measured). Both are read from the fastest repeat: other processes only ever add "
        "time, and a burst of load must not end a plateau.",
        "",
        markdown_table(
            ends.rename(columns=PLATEAU_HEADERS),
            _renamed({c: _count for c in ("steps", "plateau_n", "flat_up_to", "ends_at")}),
        ),
    ]
    return lines


def _renamed(formats: dict[str, Callable]) -> dict[str, Callable]:
    """`formats` keyed by the table headers (SCALING_HEADERS, PLATEAU_HEADERS) of the columns."""
    headers = SCALING_HEADERS | PLATEAU_HEADERS
    return {headers[column]: f for column, f in formats.items()}


def write_scaling(table: pd.DataFrame, out: Path) -> dict[str, Path]:
    """scaling.csv: one row per scaling run, exactly `SCALING_COLUMNS`."""
    return _write_table(table, SCALING_COLUMNS, "scaling", out, ("csv",))


def _flatten(settings: dict, prefix: str = "") -> dict[str, str]:
    """Nested settings as {"a.b": value}; lists and scalars as compact text."""
    flat = {}
    for key, value in settings.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat |= _flatten(value, name + ".")
        else:
            flat[name] = value if isinstance(value, str) else json.dumps(value, default=str)
    return flat


def _representative(runs: pd.DataFrame, trajectories: dict) -> pd.DataFrame:
    """One run with a trajectory per integrator of one engine, all from the same case and dt
    where possible: the case and dt of the run whose manifest lists the most settings."""
    have = runs[runs["key"].isin(trajectories.keys())]
    if have.empty:
        return have
    size = [len(_flatten(trajectories[k].meta.settings)) for k in have["key"]]
    richest = have.iloc[int(np.argmax(size))]
    same = (have["case"] == richest["case"]) & (have["dt"] == richest["dt"])
    ranked = have.assign(_other=~same).sort_values("_other", kind="stable")
    return ranked.groupby("integrator", sort=False).head(1).drop(columns="_other")


def _settings_table(reps: pd.DataFrame, trajectories: dict) -> str:
    """setting | value; a value that differs between integrators is given per integrator."""
    flat = {
        rep.integrator: _flatten(trajectories[rep.key].meta.settings) for rep in reps.itertuples()
    }
    names = list(dict.fromkeys(name for settings in flat.values() for name in settings))
    rows = []
    for name in names:
        values = {i: s.get(name, MISSING) for i, s in flat.items()}
        if len(set(values.values())) == 1:
            rows.append((name, next(iter(values.values()))))
        else:
            rows.append((name, "; ".join(f"{i}: {v}" for i, v in values.items())))
    return markdown_table(pd.DataFrame(rows, columns=["setting", "value"]))


def _parity_status(runs: pd.DataFrame) -> str:
    failed = runs[runs["verdict"].str.startswith("failed: parity")]
    if failed.empty:
        return "passed"
    return f"failed in {len(failed)} of {len(runs)} runs: {failed['verdict'].iloc[0]}"


def _parity(result: SweepResult) -> list[str]:
    results = result.results
    status = results.groupby(["engine", "integrator"], sort=False).apply(
        lambda runs: pd.Series({"runs": len(runs), "parity at t = 0": _parity_status(runs)}),
        include_groups=False,
    )
    lines = [
        "## Parity manifest",
        "",
        "How to read: the parity check confirms, before stepping, that each run's model has the "
        "scene's mass, inertia, energy, momentum and angular momentum (1e-9 relative); a run "
        "that fails it has the verdict `failed: parity ...`. Below it, per engine, every "
        "setting that affects the result, read back from the engine's model (`meta.settings`) "
        "of one run per integrator.",
        "",
        markdown_table(status.reset_index()),
    ]
    for engine, runs in results.groupby("engine", sort=False):
        reps = _representative(runs, result.trajectories)
        lines += ["", f"### Settings: {engine}", ""]
        if reps.empty:
            lines.append("No run produced a trajectory, so no settings were read back.")
            continue
        where = ", ".join(
            f"{r.integrator} on `{r.case}` at dt {r.dt:.3g} s" for r in reps.itertuples()
        )
        lines += [
            f"From the runs: {where}. Settings that depend on the case (contact) or on dt "
            "differ between runs.",
            "",
            _settings_table(reps, result.trajectories),
        ]
    return lines


def _versions(result: SweepResult) -> list[str]:
    machine = pd.DataFrame({"item": list(result.machine), "value": list(result.machine.values())})
    versions = {}
    for row in result.results.itertuples():
        traj = result.trajectories.get(row.key)
        for package, version in (traj.meta.versions if traj else {}).items():
            versions.setdefault((row.engine, package), set()).add(version)
    frame = pd.DataFrame(
        [(e, p, ", ".join(sorted(v))) for (e, p), v in versions.items()],
        columns=["engine", "package", "version"],
    )
    code = ", ".join(sorted(result.results["code_version"].dropna().astype(str).unique()))
    return [
        "## Machine and versions",
        "",
        "How to read: where the timings were taken, and the library versions each engine's runs "
        "recorded (`meta.versions`); several versions in one cell mean runs came from different "
        "installs (for instance from the results cache).",
        "",
        markdown_table(machine),
        "",
        markdown_table(frame),
        "",
        f"Code version(s) of the runs: {_escape(code) or MISSING}.",
    ]


def render_markdown(
    result: SweepResult,
    command: str,
    fits: pd.DataFrame,
    figures: dict,
    out: Path,
    scaling: pd.DataFrame | None = None,
) -> str:
    """report.md's text; `figures` by (case, kind), paths under `out`, the scaling figure as
    ("scaling", "scaling"); a Scaling section when `scaling` is given."""
    parts = [_header(result, command, scaling is not None), _timing(result.results)]
    parts += [_throughput(result, figures, out), _catalog(result)]
    parts += [_case(result, case, fits, figures, out) for case in result.scenes]
    parts += [_largest_stable(result), _contact_validation(result), _cost(result.results)]
    if scaling is not None:
        parts += [_scaling(scaling, figures.get(SCALING_FIGURE), out)]
    parts += [_parity(result), _versions(result)]
    return "\n".join("\n".join(p) + "\n" for p in parts)


def render_html(markdown_text: str, title: str = "rigidbench report") -> str:
    """index.html: the Markdown converted (tables, fenced code) in a small styled page."""
    body = markdown.markdown(markdown_text, extensions=["tables", "fenced_code"])
    return PAGE.format(title=html.escape(title), css=CSS, body=body)


SCALING_FIGURE = ("scaling", "scaling")  # its key among the figures


def write_report(
    result: SweepResult, out: Path, command: str, scaling: pd.DataFrame | None = None
) -> dict[str, Path]:
    """Write results, figures, report.md and index.html into `out`, and with a `scaling` table
    (`comparators.scaling.measure_scaling`) scaling.csv, figures/scaling.png and the Scaling
    section; returns them by name relative to `out` ("results.csv",
    "figures/tumbling_box_drift.png", ...)."""
    out = Path(out)
    (out / FIGURES).mkdir(parents=True, exist_ok=True)
    written = write_results(result.results, out)
    written |= write_outcomes(result.outcomes, out)
    fits = fit_orders(result.results, expected_orders(result))
    figures = write_figures(result, fits, out) | write_throughput_figure(result, out)
    if scaling is not None:
        written |= write_scaling(scaling, out)
        drawn = plots.plot_scaling(scaling, out / FIGURES / "scaling.png")
        figures |= {SCALING_FIGURE: drawn} if drawn is not None else {}
    text = render_markdown(result, command, fits, figures, out, scaling)
    written["report.md"] = _write_text(out / "report.md", text)
    written["index.html"] = _write_text(out / "index.html", render_html(text))
    written |= {p.relative_to(out).as_posix(): p for p in figures.values()}
    return written


class _References(HTMLParser):
    def __init__(self):
        super().__init__()
        self.found: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.found += [v for k, v in attrs if k in ("src", "href") and v]


def missing_references(html_path: Path) -> list[str]:
    """Local files (src, href) the HTML page refers to that do not exist beside it."""
    html_path = Path(html_path)
    parser = _References()
    parser.feed(html_path.read_text(encoding="utf-8"))
    local = [
        ref
        for ref in parser.found
        if not urlparse(ref).scheme and not urlparse(ref).netloc and not ref.startswith("#")
    ]
    return [ref for ref in local if not (html_path.parent / unquote(urlparse(ref).path)).exists()]
