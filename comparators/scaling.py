"""Scaling: cost per step of every engine against the number of bodies, on `cube_rain_N`.

`measure_scaling` runs `cases.catalog.cube_rain(n)` for each n on each engine through
`comparators.engine.run`, the path of every run (model built from the scene, parity checked,
trajectory recorded at the scene's sample interval), for each window: a number of steps from
t = 0 at the scene's dt. Times are stepping only (`wall_s`; model building and compilation are
`setup_s`), after one warm-up run per engine, engines interleaved within every repeat, the
median of the repeats. A run that fails or diverges is a row with its verdict and no cost;
nothing is raised.

Each engine runs its default integrator and its fastest for contact scenes (`series`): users
compare against the fastest setting of the engine they would otherwise pick, and a default such
as MuJoCo's `RK4` costs several times its `Euler` per step. `choose_fastest` picks it from a
trial, every integrator of the engine on one contact scene (`FASTEST_TRIAL_N`), by measurement.

`plateau_ends` finds, per engine and window, the N at which cost per body-step stops being flat.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from cases.catalog import cube_rain
from comparators.engine import ENGINES, unsupported
from comparators.engine_output import message_count
from comparators.timing import (
    LONG_RUN_S,
    SCALING_REPEATS,
    attempt_run,
    interleaved,
    spread,
    wants_another_timing,
)
from comparators.verdict import verdict

# Cube counts. Full: half-decade steps from 1 to the family's largest N. Quick: decades to 100.
FULL_COUNTS = (1, 3, 10, 30, 100, 300, 1000)
QUICK_COUNTS = (1, 10, 100)
# Windows, in steps from t = 0 at cube_rain's dt of 0.01 s. FALL_STEPS: the first 0.1 s, before
# the bottom layer lands (after about 0.3 s): integration, recording and collision detection
# only, the same work per body at every N, so a cost per body that grows is the algorithm's.
# WHOLE_STEPS: the whole 1 s, landings and the pile, contact solving included; there the work per
# body also grows with the pile (a lone cube touches only the floor). The quick report measures
# the fall alone, a few seconds in all.
FALL_STEPS = 10
WHOLE_STEPS = 100
FULL_WINDOWS = (FALL_STEPS, WHOLE_STEPS)
QUICK_WINDOWS = (FALL_STEPS,)
WARM_UP_STEPS = 1  # enough to load an engine's compiled code and libraries before timing
# Cost per body-step has stopped being flat at the first N where it exceeds this factor times
# its smallest value over the smaller N (the plateau). The smallest value, not the first: a
# fixed cost per step divided among few bodies makes the smallest N dearest per body. 2: the
# fastest repeats still differ by tens of percent between runs of the measurement, so smaller
# factors would flag noise, and a doubled cost per body means the part growing faster than N
# has caught up with the linear part. The rule reads the fastest repeat (`wall_min_s`), not the
# median: other processes only ever add time, and a burst of load during the repeats of one N
# can move its median by up to 10x (docs/measurement.md), enough to end a plateau.
PLATEAU_FACTOR = 2.0
# The trial that picks each engine's fastest integrator: every integrator of the engine (the
# reference's five, `seed` included: the blog's scheme, which tests every pair of particles,
# counts when it is the fastest valid one) on cube_rain_8, the catalog's member that `bench`
# times too, over the whole second (landings and the pile: contact solving included, which is
# what decides the cost of a contact scene; a lone falling cube would not), timed as the
# measurement times, in interleaved repeats. Only valid runs (verdict ok) count; the rate is
# that of the fastest repeat, as in the plateau rule (other processes only ever add time).
FASTEST_TRIAL_N = 8
FASTEST_TRIAL_STEPS = WHOLE_STEPS
# The default stays the fastest unless another integrator's trial rate exceeds its own by more
# than this factor: the fastest repeats of equal runs still differ by a few percent, and without
# a margin near-equal integrators (the reference's `splitting`, `rk4` and `exact` on cube_rain_8,
# within 8 % of each other) would swap from one measurement to the next.
FASTEST_MARGIN = 1.1
# The fastest on cube_rain_8 need not be at larger N (Drake's `tamsi` steps cube_rain_8 about 10 %
# faster than its default `sap`, cube_rain_100's fall 3 times slower): a fastest series whose
# fastest repeat at some N costs over this factor times its default's is not run at larger N in
# that window (its rows say so), so that it adds little to the measurement once it is no longer
# the fastest. 2, as PLATEAU_FACTOR: fastest repeats still differ by tens of percent.
FASTEST_DROP_FACTOR = 2.0
# `series` of a row: which of its engine's integrators it is. A default that is also the fastest
# is one series, DEFAULT_AND_FASTEST; TRIAL rows are the runs that chose the fastest (cube_rain_8,
# not part of the scaling plot or tables); OTHER: any other integrator (`all_integrators`).
DEFAULT = "default"
FASTEST = "fastest"
DEFAULT_AND_FASTEST = "default, fastest"
TRIAL = "trial"
OTHER = ""
# An engine whose run at some N took longer than this, model building included (s), is not run
# at larger N in that window: building Drake's geometry grows faster than N (about 4 s for
# cube_rain_100, minutes beyond), and one engine must not hold the measurement for the others.
# Its rows at larger N say so; 30 s is 30 times the slowest run of the other engines at N = 1000.
SCALING_RUN_LIMIT_S = 30.0

SCALING_COLUMNS = [
    "case",
    "engine",
    "integrator",
    "series",  # DEFAULT, FASTEST, DEFAULT_AND_FASTEST; TRIAL: the runs that chose the fastest
    "n_bodies",
    "dt",
    "steps",
    "repeats",
    "wall_s",  # median over repeats, stepping only
    "wall_min_s",
    "wall_max_s",
    "cost_per_step_s",  # wall_s / steps
    "cost_per_body_step_s",  # wall_s / (steps * n_bodies)
    "setup_s",  # median over repeats: model building and compilation
    "engine_messages",  # lines the engine printed or warned in the first repeat (RunMeta.messages)
    "verdict",  # comparators.verdict.VERDICTS (ok, diverged, dissipated, ...), "failed: ..."
]
PLATEAU_COLUMNS = [
    "engine",
    "integrator",
    "series",
    "steps",
    "plateau_cost_per_body_step_s",  # smallest before the plateau ends, fastest repeats
    "plateau_n",  # the N where that smallest cost was measured
    "flat_up_to",  # the largest N before the plateau ends (or the largest N measured)
    "ends_at",  # the first N above PLATEAU_FACTOR times the plateau; NaN: flat throughout
]


def _pairs(
    engines: Sequence[str], all_integrators: bool, scene, fastest: dict[str, str] | None = None
) -> list[tuple[str, str]]:
    """(engine, integrator) pairs to measure: engines that model `scene`, default integrator
    and the `fastest` (by engine) where it differs, or all."""
    pairs = []
    for name in engines:
        engine = ENGINES[name]
        if unsupported(engine, scene):
            continue
        chosen = (engine.default_integrator, (fastest or {}).get(name, engine.default_integrator))
        chosen = engine.integrators if all_integrators else tuple(dict.fromkeys(chosen))
        pairs += [(name, integrator) for integrator in chosen]
    return pairs


def series_of(integrator: str, default: str, fastest: str | None) -> str:
    """The `series` of one engine's integrator, given its `default` and `fastest` (None: not
    chosen)."""
    if integrator == default:
        return DEFAULT_AND_FASTEST if fastest == default else DEFAULT
    return FASTEST if integrator == fastest else OTHER


def choose_fastest(
    runs: pd.DataFrame, defaults: dict[str, str], margin: float = FASTEST_MARGIN
) -> dict[str, str]:
    """Each engine's fastest integrator from the runs of a trial (rows of `SCALING_COLUMNS`, one per
    engine and integrator): the most steps per second in the fastest repeat (`steps` /
    `wall_min_s`) among valid runs (verdict ok), but the engine's default (`defaults`) unless
    that rate exceeds the default's by more than `margin` times. An engine without a valid run
    is absent."""
    valid = runs[(runs["verdict"] == "ok") & np.isfinite(runs["wall_min_s"].astype(float))]
    valid = valid.assign(_rate=valid["steps"] / valid["wall_min_s"])
    chosen = {}
    for engine, own in valid.groupby("engine", sort=False):
        best = own.loc[own["_rate"].idxmax()]
        default = own[own["integrator"] == defaults.get(engine)]
        keeps = not default.empty and default["_rate"].iloc[0] * margin >= best["_rate"]
        chosen[engine] = defaults[engine] if keeps else best["integrator"]
    return chosen


def _attempt_window(scene, engine: str, integrator: str, steps: int):
    """`comparators.timing.attempt_run` of `steps` steps from t = 0 at the scene's dt."""
    return attempt_run(scene, engine, integrator, scene.dt, steps * scene.dt)


def measure_scaling(
    counts: Sequence[int] = FULL_COUNTS,
    engines: Sequence[str] | None = None,
    windows: Sequence[int] = FULL_WINDOWS,
    repeats: int = SCALING_REPEATS,
    all_integrators: bool = False,
    progress: Callable[[str], None] | None = None,
    run_limit_s: float = SCALING_RUN_LIMIT_S,
    fastest_trial: tuple[int, int] | None = (FASTEST_TRIAL_N, FASTEST_TRIAL_STEPS),
) -> pd.DataFrame:
    """Cost per step of `cube_rain_N` for N in `counts`: one row per window, N, engine and
    integrator (`SCALING_COLUMNS`), in that order of nesting, after the rows of the trial
    (`series` TRIAL).

    `engines` defaults to every available one; each runs its default integrator and its fastest
    where that differs (`choose_fastest` on a trial of every integrator on
    `cube_rain(fastest_trial[0])` over `fastest_trial[1]` steps; None: no trial, defaults
    only), or all of them with `all_integrators`. Each window is a number of steps from t = 0
    at the scene's dt. A run is repeated up to `repeats` times while one run takes under LONG_RUN_S
    (longer runs average scheduler noise within themselves); each repeat runs every engine once,
    so machine load falls on all of them alike. The verdict is that of the first repeat's
    trajectory. `progress` is called with a label before every run. A pair whose run took over
    `run_limit_s` (setup and stepping) is not run at larger N in that window, nor at an N its
    engine does not model (`comparators.engine.unsupported`), nor a fastest over
    FASTEST_DROP_FACTOR times its default's cost: its rows say so.
    """
    engines = [n for n, e in ENGINES.items() if not e.missing] if engines is None else engines
    defaults = {name: ENGINES[name].default_integrator for name in engines}
    smallest = cube_rain(min(counts))
    report = progress or (lambda label: None)
    tried = all_integrators or fastest_trial is not None
    for engine, integrator in _pairs(engines, tried, smallest):  # loads compiled code and
        report(f"warm-up {engine} {integrator}")  # libraries; nothing is kept
        _attempt_window(smallest, engine, integrator, WARM_UP_STEPS)
    rows, fastest = [], {}
    if fastest_trial is not None:
        trial_n, trial_steps = fastest_trial
        trial_scene = cube_rain(trial_n)
        candidates = _pairs(engines, True, trial_scene)
        rows = _measure_count(trial_scene, candidates, trial_steps, repeats, report)
        rows = [row | {"series": TRIAL} for row in rows]
        fastest = choose_fastest(pd.DataFrame(rows, columns=SCALING_COLUMNS), defaults)
    pairs = _pairs(engines, all_integrators, smallest, fastest)
    series = {(e, i): series_of(i, defaults[e], fastest.get(e)) for e, i in pairs}
    for steps in windows:
        over: dict[tuple, str] = {}  # pairs past the run limit: why they are not run
        for n in sorted(counts):
            scene = cube_rain(n)
            refused = {p: unsupported(ENGINES[p[0]], scene) for p in pairs if p not in over}
            skipped = over | {p: f"not run: {why}" for p, why in refused.items() if why}
            timed = [p for p in pairs if p not in skipped]
            measured = _measure_count(scene, timed, steps, repeats, report)
            by_pair = {(r["engine"], r["integrator"]): r for r in measured}
            for pair in pairs:
                row = by_pair.get(pair) or _scaling_row(scene, pair, steps, [], [], skipped[pair])
                rows.append(row | {"series": series[pair]})
                took = np.nan_to_num(row["setup_s"]) + np.nan_to_num(row["wall_max_s"])
                if pair not in over and took > run_limit_s:
                    over[pair] = f"not run: at N = {n} a run took {took:.3g} s (> {run_limit_s:g})"
            over |= _no_longer_fastest(by_pair, series, defaults, n, over)
    return pd.DataFrame(rows, columns=SCALING_COLUMNS)


def _no_longer_fastest(by_pair: dict, series: dict, defaults: dict, n: int, over: dict) -> dict:
    """The FASTEST pairs whose fastest repeat at this N took over FASTEST_DROP_FACTOR times
    their default's, each with why it is not run at larger N."""
    dropped = {}
    for (engine, integrator), label in series.items():
        fast, default = by_pair.get((engine, integrator)), by_pair.get((engine, defaults[engine]))
        if label != FASTEST or (engine, integrator) in over or fast is None or default is None:
            continue
        ratio = fast["wall_min_s"] / default["wall_min_s"]  # NaN unless both valid: not dropped
        if ratio > FASTEST_DROP_FACTOR:
            dropped[engine, integrator] = (
                f"not run: at N = {n} {ratio:.3g} times its default's cost (> "
                f"{FASTEST_DROP_FACTOR:g}), no longer the fastest"
            )
    return dropped


def _measure_count(scene, pairs, steps: int, repeats: int, report) -> list[dict]:
    """One scene and window: every (engine, integrator) pair timed in interleaved rounds; one
    row per pair."""
    walls: dict[tuple, list[float]] = {pair: [] for pair in pairs}
    setups: dict[tuple, list[float]] = {pair: [] for pair in pairs}
    verdicts: dict[tuple, str] = {}
    said: dict[tuple, int] = {}
    for repeat, pair in interleaved(pairs, repeats, rotate=False):
        if pair in verdicts and (
            verdicts[pair] != "ok" or not wants_another_timing(walls[pair], repeats, LONG_RUN_S)
        ):
            continue
        report(f"{scene.name}, {steps} steps, {pair[0]} {pair[1]}, run {repeat + 1}")
        traj, error = _attempt_window(scene, *pair, steps)
        if traj is None:
            verdicts[pair] = f"failed: {error}"
            continue
        if pair not in verdicts:
            verdicts[pair] = verdict(traj, scene)
            said[pair] = message_count(traj.meta.messages)
        walls[pair].append(traj.meta.wall_s)
        setups[pair].append(traj.meta.setup_s)
    return [
        _scaling_row(scene, pair, steps, walls[pair], setups[pair], verdicts[pair], said.get(pair))
        for pair in pairs
    ]


def _scaling_row(scene, pair, steps, walls, setups, outcome, said=None) -> dict:
    """The table row of one pair at one N and window, timed only when its runs were valid;
    `said`: the lines its engine printed or warned (None: not run)."""
    n = len(scene.bodies)
    row = dict.fromkeys(SCALING_COLUMNS, np.nan)
    row.update(
        case=scene.name,
        engine=pair[0],
        integrator=pair[1],
        n_bodies=n,
        dt=scene.dt,
        steps=steps,
        repeats=len(walls) if outcome == "ok" else 0,
        verdict=outcome,
    )
    if said is not None:
        row["engine_messages"] = said
    if setups:
        row["setup_s"] = spread(setups).median
    if outcome == "ok":  # only valid runs are timed
        wall = spread(walls)
        row.update(
            wall_s=wall.median,
            wall_min_s=wall.least,
            wall_max_s=wall.largest,
            cost_per_step_s=wall.median / steps,
            cost_per_body_step_s=wall.median / (steps * n),
        )
    return row


def plateau_ends(table: pd.DataFrame, factor: float = PLATEAU_FACTOR) -> pd.DataFrame:
    """Per engine, integrator and window (steps) of a `measure_scaling` table, where cost per
    body-step stops being flat (`PLATEAU_COLUMNS`): the first N whose cost per body-step exceeds
    `factor` times the smallest cost per body-step over the smaller N, both from the fastest
    repeat (`wall_min_s` / (steps N)). Only valid runs (verdict ok, finite time) count; a group
    without any has NaN throughout. The trial's rows (`series` TRIAL) are not part of it."""
    rows = []
    keys = ["engine", "integrator", "steps"]
    table = scaling_rows(table)
    fastest = table["wall_min_s"] / (table["steps"] * table["n_bodies"])
    table = table.assign(_fastest=fastest)
    for (engine, integrator, steps), own in table.groupby(keys, sort=False):
        valid = own[(own["verdict"] == "ok") & np.isfinite(own["_fastest"])]
        valid = valid.sort_values("n_bodies")
        row = dict.fromkeys(PLATEAU_COLUMNS, np.nan)
        row.update(engine=engine, integrator=integrator, series=own["series"].iloc[0], steps=steps)
        best_cost, best_n = np.inf, np.nan
        for n, cost in zip(valid["n_bodies"], valid["_fastest"], strict=True):
            if cost > factor * best_cost:
                row["ends_at"] = n
                break
            if cost < best_cost:
                best_cost, best_n = cost, n
            row["flat_up_to"] = n
        if np.isfinite(best_cost):
            row.update(plateau_cost_per_body_step_s=best_cost, plateau_n=best_n)
        rows.append(row)
    return pd.DataFrame(rows, columns=PLATEAU_COLUMNS)


def scaling_rows(table: pd.DataFrame) -> pd.DataFrame:
    """The rows of a `measure_scaling` table that measure scaling: all but the trial's."""
    return table[table["series"] != TRIAL]


def trial_rows(table: pd.DataFrame) -> pd.DataFrame:
    """The trial's rows of a `measure_scaling` table: every integrator on one scene, the runs
    that chose each engine's fastest (empty without a trial)."""
    return table[table["series"] == TRIAL]
