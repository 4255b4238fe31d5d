"""Which figures the report draws, where they go, and the keys the sections find them by.

Figures are keyed by (case, kind): per case "drift", "path" (a sliding body's), "spin" (a spun
body's), "convergence", "work_precision" and "stability", and for `ANIMATED_CASES` "animation";
`THROUGHPUT_FIGURE` and `SCALING_FIGURE` for the two figures across cases. How each figure is
drawn is `reports.plots`, how an animation is `reports.animation`.
"""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from comparators.bench import throughput_from_results
from comparators.engine import ENGINES
from comparators.interrupt import worker_pool
from comparators.sweep import HARD_TAG, SweepResult
from comparators.trajectory import Trajectory
from reports import animation, plots
from reports.convergence import MIN_FIT_POINTS

FIGURES_DIR = "figures"  # beside report.md and index.html
THROUGHPUT_FIGURE = (None, "throughput")
SCALING_FIGURE = ("scaling", "scaling")
# The cases whose motion the report animates: the core ones, whose motions are the report's
# story (the seed's cube flattening, the box's flip). Each takes about half a second to draw and
# up to 0.8 MB: every case's would double the figures' size and add ~10 s of drawing.
ANIMATED_CASES = ("seed_cube", "free_spin_cube", "tumbling_box", "dropped_cube")
# The full report, whose budget has room for them, animates the hard cases as well (tag
# `comparators.sweep.HARD_TAG`): where engines break, the motion shows how.


def animated_cases(scenes: dict, full: bool) -> tuple[str, ...]:
    """The cases a report animates: ANIMATED_CASES, and in a full report the hard ones."""
    hard = [name for name, scene in scenes.items() if full and HARD_TAG in scene.tags]
    return tuple(dict.fromkeys([*ANIMATED_CASES, *hard]))


# Runs an animation shows beside each engine's default integrator: the blog's scheme on the
# blog's scene, where its cube flattens.
EXTRA_ANIMATED_RUNS = {"seed_cube": (("reference", "seed"),)}


def _case_figures(task: tuple) -> dict[tuple, Path]:
    """One case's figures, by (case, kind): `task` is (case, runs, trajectories, scene, fits,
    directory)."""
    case, runs, trajectories, scene, fits, path = task
    converges = runs["dt"].nunique() >= MIN_FIT_POINTS  # fewer dt: no line worth drawing
    drawn = {
        "drift": plots.plot_drift(runs, trajectories, scene, path / f"{case}_drift.png"),
        "path": plots.plot_path(runs, trajectories, scene, path / f"{case}_path.png"),
        "spin": plots.plot_spin(runs, trajectories, scene, path / f"{case}_spin.png"),
        "convergence": plots.plot_convergence(runs, fits, path / f"{case}_convergence.png")
        if converges
        else None,
        "work_precision": plots.plot_work_precision(runs, path / f"{case}_work_precision.png"),
        "stability": plots.plot_stability(runs, path / f"{case}_stability.png"),
    }
    return {(case, kind): p for kind, p in drawn.items() if p is not None}


def animated_runs(result: SweepResult, case: str) -> list[tuple[str, Trajectory | str]]:
    """(label, trajectory or why there is none) of the runs `case`'s animation shows: at its
    default dt, each engine's default integrator and the case's EXTRA_ANIMATED_RUNS; the
    reference's first, then by engine, each engine's default integrator first."""
    scene = result.scenes[case]
    table = result.results
    runs = table[(table["case"] == case) & (table["dt"] == scene.dt)]
    defaults = {name: engine.default_integrator for name, engine in ENGINES.items()}
    wanted = set(defaults.items()) | set(EXTRA_ANIMATED_RUNS.get(case, ()))
    chosen = [r for r in runs.itertuples() if (r.engine, r.integrator) in wanted]
    chosen.sort(
        key=lambda r: (r.engine != "reference", r.engine, r.integrator != defaults.get(r.engine))
    )
    panels = []
    for r in chosen:
        traj = result.trajectories.get(r.key)
        reason = str(r.verdict).removeprefix("failed: ")
        panels.append((f"{r.engine}/{r.integrator}", reason if traj is None else traj))
    return panels


def _case_animation(task: tuple) -> dict[tuple, Path]:
    """One case's animation by (case, "animation"): `task` is (case, scene, runs, directory)."""
    case, scene, runs, path = task
    path.mkdir(parents=True, exist_ok=True)
    return {(case, "animation"): animation.animate(scene, runs, path / f"{case}_motion.gif")}


def _draw(task: tuple) -> dict[tuple, Path]:
    """Run one drawing task, (function, its argument), in whichever process the pool chose."""
    function, argument = task
    return function(argument)


def write_case_figures(
    result: SweepResult,
    fits: pd.DataFrame,
    out: Path,
    jobs: int | None = None,
    animated: tuple[str, ...] = ANIMATED_CASES,
) -> dict[tuple, Path]:
    """Every case's figures, by (case, kind), and the animations of the `animated` cases;
    kinds without anything to draw are left out.

    Figures are drawn in `jobs` processes (default: one per core, at most one per task), the
    animations first, the longest tasks: drawing is CPU-bound and the cases are independent.
    """
    tasks = []
    for case in animated:
        runs = animated_runs(result, case) if case in result.scenes else []
        if runs:
            tasks.append((_case_animation, (case, result.scenes[case], runs, out / FIGURES_DIR)))
    for case, runs in result.results.groupby("case", sort=False):
        scene = result.scenes[case]
        drawn = plots.closest_runs(runs, set(result.trajectories), scene.dt)["key"]
        trajectories = {key: result.trajectories[key] for key in drawn}
        arguments = (case, runs, trajectories, scene, fits[fits["case"] == case], out / FIGURES_DIR)
        tasks.append((_case_figures, arguments))
    jobs = min(len(tasks), jobs or os.cpu_count() or 1)
    if jobs <= 1:
        drawn = [_draw(task) for task in tasks]
    else:
        with worker_pool(jobs) as pool:
            drawn = list(pool.map(_draw, tasks))
    return {key: path for figures in drawn for key, path in figures.items()}


def write_throughput_figure(result: SweepResult, out: Path) -> dict[tuple, Path]:
    """figures/throughput.png by THROUGHPUT_FIGURE; none when no run is at a default dt."""
    table = throughput_from_results(result.results, result.scenes, result.outcomes)
    if table.empty:
        return {}
    title = "stepping throughput at each case's default dt (higher is faster)"
    path = plots.plot_throughput(table, out / FIGURES_DIR / "throughput.png", title)
    return {THROUGHPUT_FIGURE: path}


def write_scaling_figure(table: pd.DataFrame, out: Path) -> dict[tuple, Path]:
    """figures/scaling.png by SCALING_FIGURE; none without a valid scaling run."""
    drawn = plots.plot_scaling(table, out / FIGURES_DIR / "scaling.png")
    return {SCALING_FIGURE: drawn} if drawn is not None else {}


def figure_link(figures: dict, key: tuple, out: Path, alt: str) -> str | None:
    """The Markdown image of figure `key`, its path relative to `out`; None when not drawn."""
    path = figures.get(key)
    return None if path is None else f"![{alt}]({path.relative_to(out).as_posix()})"
