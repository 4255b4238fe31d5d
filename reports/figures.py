"""Which figures the report draws, where they go, and the keys the sections find them by.

Figures are keyed by (case, kind): per case "drift", "convergence", "work_precision" and
"stability"; `THROUGHPUT_FIGURE` and `SCALING_FIGURE` for the two figures across cases. How each
figure is drawn is `reports.plots`.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pandas as pd

from comparators.bench import throughput_from_results
from comparators.sweep import SweepResult
from reports import plots
from reports.convergence import MIN_FIT_POINTS

FIGURES_DIR = "figures"  # beside report.md and index.html
THROUGHPUT_FIGURE = (None, "throughput")
SCALING_FIGURE = ("scaling", "scaling")


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


def write_case_figures(
    result: SweepResult, fits: pd.DataFrame, out: Path, jobs: int | None = None
) -> dict[tuple, Path]:
    """Every case's figures, by (case, kind); kinds without anything to draw are left out.

    Cases are drawn in `jobs` processes (default: one per core, at most one per case): Agg
    rendering is CPU-bound and the cases are independent.
    """
    tasks = []
    for case, runs in result.results.groupby("case", sort=False):
        scene = result.scenes[case]
        drawn = plots.closest_runs(runs, set(result.trajectories), scene.dt)["key"]
        trajectories = {key: result.trajectories[key] for key in drawn}
        tasks.append(
            (case, runs, trajectories, scene, fits[fits["case"] == case], out / FIGURES_DIR)
        )
    jobs = min(len(tasks), jobs or os.cpu_count() or 1)
    if jobs <= 1:
        drawn = [_case_figures(task) for task in tasks]
    else:
        with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("fork")) as pool:
            drawn = list(pool.map(_case_figures, tasks))
    return {key: path for figures in drawn for key, path in figures.items()}


def write_throughput_figure(result: SweepResult, out: Path) -> dict[tuple, Path]:
    """figures/throughput.png by THROUGHPUT_FIGURE; none when no run is at a default dt."""
    table = throughput_from_results(result.results, result.scenes)
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
