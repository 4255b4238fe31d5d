"""Repeated timing of engine runs, shared by sweeps, the bench and the scaling measurement.

One repeat policy (`wants_another_timing`), one interleaving of runs (`interleaved`), one
statistic (`spread`: median, min, max), one way to attempt a run without raising
(`attempt_run`). Each use names its repeat count: `SWEEP_REPEATS`, `BENCH_REPEATS`,
`SCALING_REPEATS`. Figures behind the counts: docs/measurement.md.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from cases.scene import Scene
from comparators.engine import failure_reason, run
from comparators.trajectory import Trajectory

# The architecture's timing rule: a median with min and max needs at least this many repeats.
MIN_REPEATS = 5
# Timings per sweep run: three, a median that ignores one outlier, for a sweep of hundreds of runs.
SWEEP_REPEATS = 3
# Timed repeats per bench run: the rule's minimum.
BENCH_REPEATS = MIN_REPEATS
# Timings per scaling run: runs of a few milliseconds vary by up to 3x between repeats on a
# shared machine; the median of 5 ignores two outliers.
SCALING_REPEATS = 5
# A run taking at least this long (s) is timed once where a use allows it (sweeps, scaling):
# it averages scheduler noise within itself.
LONG_RUN_S = 1.0

Item = TypeVar("Item")


def wants_another_timing(walls: Sequence[float], repeats: int, long_run_s: float | None) -> bool:
    """The repeat policy: time again until there are `repeats` timings, unless the first one
    took `long_run_s` or more (None: always `repeats`)."""
    if len(walls) >= repeats:
        return False
    return long_run_s is None or not walls or walls[0] < long_run_s


def interleaved(items: Sequence[Item], repeats: int, rotate: bool) -> Iterator[tuple[int, Item]]:
    """(round, item) for `repeats` rounds over `items`, so that machine load during the
    measurement falls on every item alike; with `rotate`, each round starts one item further
    along, so that no item is always first after a pause."""
    for round_ in range(repeats):
        shift = round_ % max(1, len(items)) if rotate else 0
        for item in [*items[shift:], *items[:shift]]:
            yield round_, item


@dataclass(frozen=True)
class Spread:
    """The median of a run's repeated measurements, with their least and largest values."""

    median: float
    least: float
    largest: float
    count: int


def spread(values: Sequence[float] | np.ndarray) -> Spread:
    """`Spread` of `values` (timings or rates), at least one."""
    array = np.asarray(values, dtype=float)
    return Spread(float(np.median(array)), float(array.min()), float(array.max()), len(array))


def attempt_run(
    scene: Scene, engine: str, integrator: str, dt: float, duration: float | None = None
) -> tuple[Trajectory | None, str | None]:
    """One run through `comparators.engine.run`: (trajectory, None), or (None, the reason it
    failed); never raises, so one bad run cannot stop a measurement."""
    try:
        return run(scene, engine, integrator, dt=dt, duration=duration), None
    except Exception as exc:  # noqa: BLE001  (reported in the tables, never raised)
        return None, failure_reason(exc)


def repeat_run(
    attempt: Callable[[], tuple[Trajectory | None, str | None]],
    repeats: int,
    long_run_s: float | None = LONG_RUN_S,
) -> tuple[Trajectory | None, str | None, list[float]]:
    """Call `attempt` (an `attempt_run`) as the repeat policy asks: the first trajectory, the
    first failure's reason (None if every run succeeded), and every stepping time `wall_s`."""
    first, walls = None, []
    while not walls or wants_another_timing(walls, repeats, long_run_s):  # at least once
        traj, error = attempt()
        if traj is None:
            return first, error, walls
        if first is None:
            first = traj
        walls.append(traj.meta.wall_s)
    return first, None, walls
