"""The report's figures, one PNG per case and kind, 800 px wide, and the throughput figure of
all cases (the report's and `rigidbench bench`'s).

Every figure colours a run by its engine and marks it (marker and line style) by its integrator,
the same in every figure (`run_style`). Figures are `matplotlib.figure.Figure` objects rendered
by Agg, never pyplot's: nothing is registered globally, so nothing stays open after saving.
Inputs are the rows of one case from a sweep's results (`comparators.sweep.RESULT_COLUMNS`), or
for throughput a table with `comparators.bench.BENCH_COLUMNS`.
"""

from __future__ import annotations

import textwrap
import zlib
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.cm import ScalarMappable
from matplotlib.colors import LogNorm, to_rgba
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

from cases.scene import Scene
from comparators.closed_forms import ABSOLUTE_TOLERANCES, is_miss
from comparators.engine import ENGINES
from comparators.metrics import conserved_quantities
from comparators.scaling import FASTEST, scaling_rows
from comparators.sliding import path_on_line, spin_rate
from comparators.trajectory import Trajectory, atomic_path
from reports.convergence import ERROR_CEILING_DEG, ERROR_FLOOR_DEG, pareto_front

WIDTH_IN, DPI = 8.0, 100  # 800 px wide
ENGINE_COLOURS = matplotlib.colormaps["tab10"].colors
MARKERS = "osD^vPX*<>"
LINESTYLES = ["-", "--", "-.", ":"]
# Relative drifts below double-precision rounding (and the exact 0 at t = 0) cannot be drawn
# on a log axis; they are drawn at this floor, which the figure states.
DRIFT_FLOOR = 1e-16
SHORT_RANGE = 2.0  # decades: a log axis this short gets ticks at 1, 2 and 5 per decade
ERROR = "orientation_error_deg"
COST = "cost_s_per_s"  # stepping wall time per simulated second
PAIR = ["engine", "integrator"]
ERROR_CMAP = matplotlib.colormaps["viridis"]
# Verdict colours stay clear of viridis (purple through green to yellow): white, light grey,
# red, brown, orange, pink, dark grey.
VERDICT_COLOURS = {
    "no run": "white",
    "ok": "#e0e0e0",
    "diverged": "#d62728",
    "dissipated": "#8c564b",
    "tunnelled": "#ff7f0e",
    "jitter": "#e377c2",
    "failed": "#404040",
}


def _colour(engine: str) -> tuple:
    """An engine's colour: registered engines in registry order; an engine the registry does
    not list (runs cached by a plugin since removed) takes a stable colour among those the
    registered ones leave free, where any are."""
    known = list(ENGINES)
    if engine in known:
        slot = known.index(engine)
    else:
        crc, free = zlib.crc32(engine.encode()), len(ENGINE_COLOURS) - len(known)
        slot = len(known) + crc % free if free > 0 else crc
    return ENGINE_COLOURS[slot % len(ENGINE_COLOURS)]


def _name_slot(integrator: str) -> int:
    """The marker slot an integrator's name asks for, the same in every engine."""
    return zlib.crc32(integrator.lower().encode()) % len(MARKERS)


def _marker_slots(engine: str) -> dict[str, int]:
    """The marker slot of each of `engine`'s integrators: the one its name hashes to
    (case-insensitive, so that MuJoCo's RK4 and the reference's rk4 share a marker), or where an
    integrator of the engine listed before it holds that, the next free one: no two integrators
    of an engine share a marker while it has no more than `MARKERS`. Only `engine` is loaded."""
    slots: dict[str, int] = {}
    for name in ENGINES[engine].integrators if engine in ENGINES else ():
        slot = _name_slot(name)
        while slot in slots.values() and len(slots) < len(MARKERS):
            slot = (slot + 1) % len(MARKERS)
        slots[name] = slot
    return slots


def run_style(engine: str, integrator: str) -> dict:
    """matplotlib keyword arguments for one engine/integrator: colour by engine, marker and line
    style by integrator (`_marker_slots`)."""
    k = _marker_slots(engine).get(integrator, _name_slot(integrator))
    return {
        "color": _colour(engine),
        "marker": MARKERS[k],
        "linestyle": LINESTYLES[k % len(LINESTYLES)],
    }


def _figure(height_in: float, nrows: int = 1) -> tuple[Figure, np.ndarray]:
    fig = Figure(figsize=(WIDTH_IN, height_in), dpi=DPI, layout="constrained")
    axes = fig.subplots(nrows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, axes


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return path


def _legend_below(fig: Figure, ncols: int = 3, **kwargs) -> None:
    fig.legend(loc="outside lower center", ncols=ncols, fontsize=8, frameon=False, **kwargs)


def _log_axes(ax, dts: np.ndarray | None = None, x: pd.Series | None = None) -> None:
    """Log-log axes with a light grid; x ticks at the swept dts (s) when given, else at 1, 2
    and 5 per decade when the `x` values span less than SHORT_RANGE decades."""
    ax.set(xscale="log", yscale="log")
    ax.grid(True, which="major", alpha=0.3)
    ax.xaxis.set_minor_formatter(NullFormatter())  # labelled minor ticks collide at 800 px
    if dts is not None:
        ax.set_xticks(dts, [f"{dt:g}" for dt in dts])
    elif x is not None and np.log10(x.max() / x.min()) < SHORT_RANGE:
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))


def valid_costs(runs: pd.DataFrame) -> pd.DataFrame:
    """Valid runs with a positive orientation error and a finite stepping time, with their
    COST: stepping wall time per simulated second (s/s)."""
    ok = runs[(runs["verdict"] == "ok") & (runs[ERROR] > 0) & np.isfinite(runs["wall_s"])]
    return ok.assign(**{COST: ok["wall_s"] / ok["duration"]})


def _relative_deviation(values: np.ndarray) -> np.ndarray:
    """|f(t) - f(0)| / |f(0)| per sample for (S,) or (S, k) values; absolute when f(0) = 0."""
    values = values.reshape(len(values), -1)
    deviation = np.linalg.norm(values - values[0], axis=1)
    scale = np.linalg.norm(values[0])
    return deviation / scale if scale > 0 else deviation


def closest_runs(runs: pd.DataFrame, keys: set[str], dt: float) -> pd.DataFrame:
    """Per engine/integrator, the valid run with a trajectory whose dt is closest to `dt` (on a
    log scale), in the order of `runs`."""
    have = runs[runs["key"].isin(keys) & (runs["verdict"] == "ok")]
    distance = np.abs(np.log(have["dt"].to_numpy(float) / dt))
    have = have.assign(_distance=distance).sort_values("_distance", kind="stable")
    return have.groupby(PAIR, sort=False).head(1).drop(columns="_distance").sort_index()


def _at(chosen: pd.DataFrame, scene: Scene) -> str:
    """The dt a figure of the default-dt runs shows, as its title says it."""
    if chosen["dt"].nunique() == 1:
        return f"dt = {chosen['dt'].iloc[0]:g} s"
    return f"dt closest to {scene.dt:g} s"


def plot_drift(
    runs: pd.DataFrame, trajectories: dict[str, Trajectory], scene: Scene, path: Path
) -> Path | None:
    """Relative energy and angular-momentum error against time (s), log y, one line per
    engine/integrator at the scene's default dt (or the closest swept). None: no trajectory."""
    chosen = closest_runs(runs, set(trajectories), scene.dt)
    if chosen.empty:
        return None
    fig, (ax_e, ax_l) = _figure(6.5, nrows=2)
    one_dt = chosen["dt"].nunique() == 1
    for run in chosen.itertuples():
        c = conserved_quantities(trajectories[run.key], scene)
        label = f"{run.engine} {run.integrator}" + ("" if one_dt else f" (dt {run.dt:g} s)")
        style = run_style(run.engine, run.integrator) | {"markevery": 0.1, "markersize": 4}
        for ax, values in ((ax_e, c["energy"]), (ax_l, c[["Lx", "Ly", "Lz"]])):
            drift = np.maximum(_relative_deviation(values.to_numpy()), DRIFT_FLOOR)
            ax.plot(c["t"], drift, label=label if ax is ax_e else None, **style)
    ax_e.set_ylabel("|E(t) - E(0)| / |E(0)|")
    ax_l.set_ylabel("|L(t) - L(0)| / |L(0)|")
    ax_l.set_xlabel(f"t (s); values below {DRIFT_FLOOR:g}, including 0, drawn at {DRIFT_FLOOR:g}")
    for ax in (ax_e, ax_l):
        ax.set_yscale("log")
        ax.grid(True, which="major", alpha=0.3)
    ax_e.set_title(
        f"{scene.name}: energy and angular momentum drift, {_at(chosen, scene)}", fontsize=10
    )
    _legend_below(fig, ncols=4)
    return _save(fig, path)


def _body_lines(chosen: pd.DataFrame, trajectories: dict, scene: Scene, measure) -> list:
    """(label, style, table) per chosen run and body that `measure(trajectory, scene, body)`
    gives a table for (a sliding body's path, a spun body's spin)."""
    one_dt = chosen["dt"].nunique() == 1
    lines = []
    for run in chosen.itertuples():
        for k, body in enumerate(scene.bodies):
            found = measure(trajectories[run.key], scene, k)
            if found is None:
                continue
            label = f"{run.engine} {run.integrator}" + ("" if one_dt else f" (dt {run.dt:g} s)")
            label += f", {body.name}" if len(scene.bodies) > 1 else ""
            style = run_style(run.engine, run.integrator) | {"markevery": 0.1, "markersize": 4}
            lines.append((label, style, found))
    return lines


def plot_path(
    runs: pd.DataFrame, trajectories: dict[str, Trajectory], scene: Scene, path: Path
) -> Path | None:
    """Each sliding body's COM path on its plane (`comparators.sliding.path_on_line`): along
    the closed forms' straight line (m) against across it (mm, magnified), one line per
    engine/integrator at the scene's default dt (or the closest swept), with the band the
    findings allow across and, where the scene states one, the closed-form stopping distance.
    None: no body with such a line, or no trajectory."""
    chosen = closest_runs(runs, set(trajectories), scene.dt)
    lines = _body_lines(chosen, trajectories, scene, path_on_line)
    if not lines:
        return None
    fig, (ax,) = _figure(4.5)
    band = ABSOLUTE_TOLERANCES["sideways"] * 1e3  # mm
    ax.axhspan(-band, band, color="0.9", label=f"within {band:g} mm of the line")
    stop = scene.expected.stopping_distance
    if stop is not None:
        ax.axvline(stop, color="0.3", linestyle=":", label=f"closed form: stops at {stop:g} m")
    for label, style, found in lines:
        ax.plot(found["along"], found["across"] * 1e3, label=label, **style)
    ax.set(xlabel="along the line it should slide on (m)", ylabel="across it (mm; + to its left)")
    title = f"{scene.name}: centre of mass on its plane, {_at(chosen, scene)}"
    return _finish_lines(fig, ax, title, path)


def plot_spin(
    runs: pd.DataFrame, trajectories: dict[str, Trajectory], scene: Scene, path: Path
) -> Path | None:
    """A spun body's angular speed about its plane's normal against time
    (`comparators.sliding.spin_rate`), one line per engine/integrator at the scene's default dt
    (or the closest swept), with the closed form's uniform deceleration from the starting spin
    to zero at the stated spin time. None: no spin closed form, or no trajectory."""
    chosen = closest_runs(runs, set(trajectories), scene.dt)
    lines = _body_lines(chosen, trajectories, scene, spin_rate)
    if not lines:
        return None
    fig, (ax,) = _figure(4.5)
    stop = scene.expected.spin_time
    if stop is not None:
        w0 = float(lines[0][2]["rate"].iloc[0])
        closed = ([0.0, stop, scene.duration], [w0, 0.0, 0.0])
        ax.plot(*closed, color="0.3", linestyle=":", label=f"closed form (stops at {stop:.3g} s)")
    for label, style, found in lines:
        ax.plot(found["t"], found["rate"], label=label, **style)
    ax.set(xlabel="t (s)", ylabel="spin about the plane's normal (rad/s)")
    return _finish_lines(fig, ax, f"{scene.name}: spin against time, {_at(chosen, scene)}", path)


def _finish_lines(fig: Figure, ax, title: str, path: Path) -> Path:
    """The end of every figure of `_body_lines`: grid, `title`, legend below, saved to `path`."""
    ax.grid(True, which="major", alpha=0.3)
    ax.set_title(title, fontsize=10)
    _legend_below(fig, ncols=4)
    return _save(fig, path)


def _order_label(fits: pd.DataFrame, engine: str, integrator: str) -> str:
    fit = fits[(fits["engine"] == engine) & (fits["integrator"] == integrator)]
    if fit.empty:
        return f"{engine} {integrator}"
    fit = fit.iloc[0]
    expected = "" if pd.isna(fit["expected_order"]) else f" (expected {fit['expected_order']:g})"
    order = "no fit" if pd.isna(fit["order"]) else f"order {fit['order']:.2f}"
    return f"{engine} {integrator}: {order}{expected}"


def plot_convergence(runs: pd.DataFrame, fits: pd.DataFrame, path: Path) -> Path | None:
    """Max orientation error (deg) against dt (s), log-log, one line per engine/integrator,
    the fitted order (`reports.convergence.fit_orders` rows) in the legend. None: no errors."""
    data = valid_costs(runs)
    if data.empty:
        return None
    fig, (ax,) = _figure(5.5)
    for (engine, integrator), pair in data.groupby(PAIR, sort=False):
        pair = pair.sort_values("dt")
        label = _order_label(fits, engine, integrator)
        ax.plot(pair["dt"], pair[ERROR], label=label, **run_style(engine, integrator))
    fit_range = {"color": "grey", "linewidth": 0.8, "linestyle": (0, (2, 4))}
    ax.axhline(ERROR_FLOOR_DEG, **fit_range)
    ax.axhline(
        ERROR_CEILING_DEG,
        label=f"fit range {ERROR_FLOOR_DEG:g} to {ERROR_CEILING_DEG:g} deg",
        **fit_range,
    )
    _log_axes(ax, np.sort(runs["dt"].unique()))
    ax.set(xlabel="dt (s)", ylabel="max orientation error (deg)")
    ax.set_title(f"{runs['case'].iloc[0]}: orientation error against dt", fontsize=10)
    _legend_below(fig, ncols=2)  # long labels
    return _save(fig, path)


def plot_work_precision(runs: pd.DataFrame, path: Path) -> Path | None:
    """Max orientation error (deg) against stepping wall time per simulated second (s/s),
    log-log; each engine's Pareto front as a step line. None: no valid run with an error."""
    data = valid_costs(runs)
    if data.empty:
        return None
    fig, (ax,) = _figure(5.5)
    for (engine, integrator), pair in data.groupby(PAIR, sort=False):
        style = run_style(engine, integrator) | {"linestyle": "none"}
        ax.plot(pair[COST], pair[ERROR], label=f"{engine} {integrator}", **style)
    for engine, own in data.groupby("engine", sort=False):
        front = pareto_front(own, COST, ERROR)
        line = {"color": run_style(engine, "")["color"], "linewidth": 2, "alpha": 0.5}
        ax.step(front[COST], front[ERROR], where="post", label=f"{engine} Pareto front", **line)
    _log_axes(ax, x=data[COST])
    if data[ERROR].min() < ERROR_FLOOR_DEG:  # the report ranks errors down there as ties
        bottom, top = ax.get_ylim()
        shade = {"color": "grey", "alpha": 0.15, "linewidth": 0}
        label = f"rounding, below {ERROR_FLOOR_DEG:g} deg (ties)"
        ax.axhspan(bottom, ERROR_FLOOR_DEG, label=label, **shade)
        ax.set_ylim(bottom, top)
    ax.set(xlabel="stepping wall time per simulated second (s/s)")
    ax.set(ylabel="max orientation error (deg)")
    ax.set_title(f"{runs['case'].iloc[0]}: work-precision (lower left is better)", fontsize=10)
    _legend_below(fig)
    return _save(fig, path)


def _cell_label(value: float) -> str:
    """1.8e-09 -> 1.8e-9: short enough for a map cell."""
    mantissa, exponent = f"{value:.1e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def _cell(verdict: str, error: float, norm: LogNorm | None) -> tuple[tuple, str]:
    """A map cell's colour (RGBA) and label: valid runs with an error by its magnitude."""
    if verdict == "ok" and error > 0 and norm is not None:
        return ERROR_CMAP(norm(error)), _cell_label(error)
    category = "failed" if verdict.startswith("failed") else verdict
    category = category if category in VERDICT_COLOURS else "failed"
    return to_rgba(VERDICT_COLOURS[category]), "" if category == "no run" else category


def pair_rank(pair: tuple[str, str]) -> tuple:
    """Registry order of an (engine, integrator): engines as registered, integrators as their
    engine lists them (default first); unknown ones after, by name."""
    engine, integrator = pair
    engines = list(ENGINES)
    integrators = list(ENGINES[engine].integrators) if engine in ENGINES else []
    k = integrators.index(integrator) if integrator in integrators else len(integrators)
    return (engines.index(engine) if engine in engines else len(engines), k, engine, integrator)


def plot_stability(runs: pd.DataFrame, path: Path) -> Path:
    """Engine/integrator (rows, in registry order) x dt (s, columns) coloured by verdict
    (`VERDICT_COLOURS`: ok, diverged, dissipated, tunnelled, jitter, failed, no run; legend
    below); valid
    runs with an error by its magnitude (deg, log colour scale), each cell labelled."""
    pairs = sorted(
        dict.fromkeys(zip(runs["engine"], runs["integrator"], strict=True)), key=pair_rank
    )
    dts = np.sort(runs["dt"].unique())
    errors = runs.loc[(runs["verdict"] == "ok") & (runs[ERROR] > 0), ERROR]
    norm = LogNorm(errors.min(), max(errors.max(), 10 * errors.min())) if len(errors) else None
    face = np.ones((len(pairs), len(dts), 4))  # white: no run
    fig, (ax,) = _figure(1.8 + 0.45 * len(pairs))
    for run in runs.itertuples():
        i, j = pairs.index((run.engine, run.integrator)), int(np.searchsorted(dts, run.dt))
        face[i, j], text = _cell(run.verdict, getattr(run, ERROR), norm)
        dark = face[i, j, :3] @ (0.299, 0.587, 0.114) < 0.5  # perceived luminance
        colour = "white" if dark else "black"
        ax.text(j, i, text, ha="center", va="center", fontsize=8, color=colour)
    ax.imshow(face, aspect="auto")
    if norm is not None:
        fig.colorbar(ScalarMappable(norm, ERROR_CMAP), ax=ax, label="max orientation error (deg)")
    ax.set_xticks(range(len(dts)), [f"{dt:g}" for dt in dts])
    ax.set_yticks(range(len(pairs)), [f"{e} {i}" for e, i in pairs])
    ax.set_xlabel("dt (s)")
    ax.set_title(f"{runs['case'].iloc[0]}: stability map", fontsize=10)
    legend = {"ok": "ok, no error measured"}
    handles = [
        Patch(facecolor=colour, edgecolor="grey", label=legend.get(name, name))
        for name, colour in VERDICT_COLOURS.items()
    ]
    _legend_below(fig, handles=handles, ncols=len(handles), title="verdict", title_fontsize=8)
    return _save(fig, path)


THROUGHPUT_ROW_IN = 0.55  # inches per case row: room for one marker per engine/integrator
NOTE_WIDTH = 120  # characters per line of 7-point text across the 800 px figure


def plot_throughput(table: pd.DataFrame, path: Path, title: str | None = None) -> Path:
    """Steps/s (log x, median with a [min, max] bar) and its ratio to MuJoCo Euler (log x, 1
    marked) per case (rows, and dt when several) and engine/integrator (markers, offset within
    a row), from a throughput table (`comparators.bench.BENCH_COLUMNS`). A run whose physics
    is wrong (`wrong_physics`) has a hollow marker. Runs without a timing are left out and
    listed under the figure."""
    rows = list(dict.fromkeys(zip(table["case"], table["dt"], strict=True)))
    several_dt = table.groupby("case")["dt"].nunique().max() > 1
    labels = [f"{case} (dt {dt:g})" if several_dt else case for case, dt in rows]
    pairs = sorted(
        dict.fromkeys(zip(table["engine"], table["integrator"], strict=True)), key=pair_rank
    )
    fig = Figure(
        figsize=(WIDTH_IN, 1.6 + THROUGHPUT_ROW_IN * len(rows)), dpi=DPI, layout="constrained"
    )
    ax_rate, ax_ratio = fig.subplots(1, 2, sharey=True, width_ratios=(3, 2))
    spacing = 0.8 / max(1, len(pairs))
    timed = table[np.isfinite(table["steps_per_s"].to_numpy(float))]
    for k, (engine, integrator) in enumerate(pairs):
        own = timed[(timed["engine"] == engine) & (timed["integrator"] == integrator)]
        if own.empty:
            continue
        y = np.array([rows.index(r) for r in zip(own["case"], own["dt"], strict=True)])
        y = y + (k - (len(pairs) - 1) / 2) * spacing
        rate = own["steps_per_s"].to_numpy(float)
        low = np.nan_to_num(rate - own["steps_per_s_min"].to_numpy(float))
        high = np.nan_to_num(own["steps_per_s_max"].to_numpy(float) - rate)
        style = run_style(engine, integrator) | {"linestyle": "none", "markersize": 4}
        label = f"{engine} {integrator}"
        ax_rate.errorbar(rate, y, xerr=(low, high), label=label, elinewidth=0.8, **style)
        ax_ratio.plot(own["ratio_vs_mujoco_euler"], y, **style)
        wrong = wrong_physics(own)
        # over the filled one, and larger: a hollow star or triangle of size 4 reads as filled
        hollow = style | {"markerfacecolor": "white", "markersize": 6, "zorder": 3}
        ax_rate.plot(rate[wrong], y[wrong], **hollow)
        ax_ratio.plot(own["ratio_vs_mujoco_euler"][wrong], y[wrong], **hollow)
    ax_ratio.axvline(1.0, color="grey", linewidth=0.8, linestyle="--")
    for ax, column in ((ax_rate, "steps_per_s"), (ax_ratio, "ratio_vs_mujoco_euler")):
        ax.set_xscale("log")
        ax.grid(True, which="major", axis="x", alpha=0.3)
        ax.xaxis.set_minor_formatter(NullFormatter())
        values = timed[column].to_numpy(float)
        values = values[np.isfinite(values) & (values > 0)]
        if len(values) and np.log10(values.max() / values.min()) < SHORT_RANGE:
            ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    ax_rate.set_yticks(range(len(rows)), labels, fontsize=8)
    ax_rate.set_ylim(len(rows) - 0.5, -0.5)  # first case on top
    ax_rate.set_xlabel("steps/s, stepping only\n(median, bar: min to max)")
    ax_ratio.set_xlabel("ratio to MuJoCo Euler\n(same case and dt)")
    fig.suptitle(title or "stepping throughput (higher is faster)", fontsize=10)
    untimed = table[~np.isfinite(table["steps_per_s"].to_numpy(float))]
    notes = []
    if wrong_physics(timed).any():
        notes.append("hollow: the run's physics is wrong (its verdict, or a closed form missed)")
    if len(untimed):
        listed = ", ".join(f"{r.case} {r.engine} {r.integrator}" for r in untimed.itertuples())
        notes.append(textwrap.fill(f"not timed (failed or diverged): {listed}", NOTE_WIDTH))
    note = {"title": "\n".join(notes), "title_fontsize": 7} if notes else {}
    _legend_below(fig, ncols=4, **note)
    return _save(fig, path)


def wrong_physics(table: pd.DataFrame) -> np.ndarray:
    """Per row of a throughput table, whether its run got the physics wrong: a verdict other
    than ok, or a closed form missed (`closed_forms.is_miss`)."""
    said = table["closed_forms_missed"].map(is_miss)
    return ((table["verdict"] != "ok") | said).to_numpy(bool)


def plot_scaling(table: pd.DataFrame, path: Path) -> Path | None:
    """Stepping wall time per step (s) against the number of bodies N, log-log, one panel per
    window (steps from t = 0) and one line per engine/integrator labelled with its series
    (default solid, fastest dotted, in the engine's colour), valid runs only (rows of
    `comparators.scaling.measure_scaling`, not the trial's). The dashed line grows as N through
    the smallest cost per body-step of the panel: a line parallel to it scales linearly. None:
    no valid run."""
    table = scaling_rows(table)
    valid = table[(table["verdict"] == "ok") & np.isfinite(table["cost_per_step_s"])]
    if valid.empty:
        return None
    windows = sorted(valid["steps"].unique())
    fig, axes = _figure(1.0 + 3.5 * len(windows), nrows=len(windows))
    for ax, steps in zip(axes, windows, strict=True):
        own = valid[valid["steps"] == steps]
        for (engine, integrator), pair in own.groupby(PAIR, sort=False):
            pair = pair.sort_values("n_bodies")
            series = pair["series"].iloc[0]
            named = f" ({series})" if isinstance(series, str) and series else ""
            label = f"{engine} {integrator}{named}" if ax is axes[0] else None
            style = run_style(engine, integrator)
            if named:  # an engine's two series: its colour, solid for the default, dotted
                style["linestyle"] = ":" if series == FASTEST else "-"
            ax.plot(pair["n_bodies"], pair["cost_per_step_s"], label=label, **style)
        n = np.sort(own["n_bodies"].unique()).astype(float)
        slope = own["cost_per_body_step_s"].min()
        label = "∝ N (through the smallest cost per body-step)" if ax is axes[0] else None
        ax.plot(n, slope * n, color="grey", linestyle="--", linewidth=1, label=label)
        _log_axes(ax)
        ax.set_xticks(n, [f"{v:g}" for v in n])
        ax.set_ylabel("wall time per step (s)")
        dt = own["dt"].iloc[0]
        ax.set_title(f"the first {steps} steps from t = 0 ({steps * dt:g} s)", fontsize=10)
    axes[-1].set_xlabel("N (bodies)")
    fig.suptitle("cube_rain_N: stepping cost against N", fontsize=11)
    _legend_below(fig, ncols=3)  # "engine integrator (default, fastest)": four would not fit
    return _save(fig, path)
