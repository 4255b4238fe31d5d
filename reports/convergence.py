"""Convergence in dt, Pareto fronts and the cost of reaching a tolerance, from sweep results.

Inputs are the tidy results of a sweep (`comparators.sweep.RESULT_COLUMNS`): one row per run,
errors are maxima over the run, `orientation_error_deg` in degrees, `position_error` in m,
`wall_s` the stepping time in s.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

# The asymptotic range of an orientation error, where error ~ C dt^p holds.
# Floor: each step rounds the orientation by ~1e-16 rad (~1e-14 deg); over 1e3-1e5 steps that
# accumulates to at most ~1e-11 deg, so above 1e-9 deg rounding is under 1 % of the error.
ERROR_FLOOR_DEG = 1e-9
# Ceiling: beyond ~30 deg the error stops growing like dt^p: it saturates (the largest possible
# angle is 180 deg) and near 180 deg it measures a different flip pattern, not truncation.
ERROR_CEILING_DEG = 30.0
# A slope from two points always fits perfectly; three is the least that can show a bad fit.
MIN_FIT_POINTS = 3
# Position errors below this are rounding: a COM coordinate of 1-10 m carries ~1e-15 m per step,
# ~1e-13 m over 1e3-1e5 steps. Free flight does not saturate, so position has no ceiling.
POSITION_FLOOR_M = 1e-12

KEYS = ["case", "engine", "integrator"]
# float64's epsilon: an engine computing with a larger one (`Engine.epsilon`, float32's) has a
# precision floor of its own, found from its errors (`precision_floor`).
FLOAT64_EPSILON = float(np.finfo(float).eps)


def precision_floor(dt: np.ndarray, error: np.ndarray) -> float | None:
    """The dt below which a single-precision engine's errors stop falling: that of its smallest
    error, when some smaller dt has a larger one (rounding, which grows with the steps, has
    overtaken the truncation error); None when the errors fall down to the smallest dt."""
    finite = np.isfinite(error)
    if finite.sum() < 2:
        return None
    dt, error = dt[finite], error[finite]
    best = dt[np.argmin(error)]
    return float(best) if (dt < best).any() else None


def fit_power_law(dt: np.ndarray, error: np.ndarray, floor: float, ceiling: float) -> dict:
    """Least-squares slope of log(error) against log(dt) over floor <= error <= ceiling.

    Returns order (the slope), r2 (coefficient of determination in log space), points (used),
    dt_min and dt_max (s, of the points used) and note ("" when the fit exists, else why not).
    """
    dt, error = np.asarray(dt, dtype=float), np.asarray(error, dtype=float)
    used = np.isfinite(error) & (error >= floor) & (error <= ceiling) & (dt > 0)
    out = {"order": np.nan, "r2": np.nan, "points": int(used.sum())}
    out["dt_min"] = float(dt[used].min()) if used.any() else np.nan
    out["dt_max"] = float(dt[used].max()) if used.any() else np.nan
    if len(np.unique(dt[used])) < MIN_FIT_POINTS:
        out["note"] = f"{out['points']} run(s) in the fit range, need {MIN_FIT_POINTS} dt"
        return out
    x, y = np.log(dt[used]), np.log(error[used])
    slope, intercept = np.polyfit(x, y, 1)
    residual = y - (slope * x + intercept)
    spread = ((y - y.mean()) ** 2).sum()
    out.update(order=float(slope), note="")
    out["r2"] = float(1.0 - (residual**2).sum() / spread) if spread > 0 else np.nan
    return out


def _position_fit(dt: np.ndarray, error: np.ndarray) -> dict:
    fit = fit_power_law(dt, error, POSITION_FLOOR_M, np.inf)
    finite = error[np.isfinite(error)]
    if len(finite) and (finite < POSITION_FLOOR_M).all():
        fit["note"] = "exact"
    return {f"position_{k}": v for k, v in fit.items()}


def fit_orders(results: pd.DataFrame, orders: dict[tuple[str, str], int]) -> pd.DataFrame:
    """Observed convergence order in dt per (case, engine, integrator).

    `orders` maps (engine, integrator) to the expected order. Only runs with verdict "ok" count;
    orientation errors (deg) are fitted inside [ERROR_FLOOR_DEG, ERROR_CEILING_DEG], position
    errors (m) above POSITION_FLOOR_M. Columns: case, engine, integrator, expected_order,
    order, r2, points, dt_min, dt_max (s), note (starting "rounding" when every orientation
    error is below ERROR_FLOOR_DEG, or "precision floor" when a single-precision engine's
    errors stop falling as dt shrinks: the fit then leaves out the dt below its smallest error),
    and the same prefixed `position_` for position errors (note "exact" when every position
    error is below POSITION_FLOOR_M).
    """
    rows = []
    for (case, engine, integrator), runs in results.groupby(KEYS, sort=False):
        valid = runs[runs["verdict"] == "ok"]
        dt = valid["dt"].to_numpy(float)
        error = valid["orientation_error_deg"].to_numpy(float)
        floor_dt = None
        if _epsilon(engine) > FLOAT64_EPSILON:
            floor_dt = precision_floor(dt, error)
        kept = dt >= floor_dt if floor_dt is not None else np.ones(len(dt), dtype=bool)
        fit = fit_power_law(dt[kept], error[kept], ERROR_FLOOR_DEG, ERROR_CEILING_DEG)
        if floor_dt is not None:
            below = (
                f"precision floor: {_precision(engine)} errors stop falling below "
                f"dt {floor_dt:g} s, fitted above it"
            )
            fit["note"] = f"{below}; {fit['note']}" if fit["note"] else below
        finite = error[np.isfinite(error)]
        if not len(finite):
            fit["note"] = "no valid run with an orientation error"
        elif (finite < ERROR_FLOOR_DEG).all():
            fit["note"] = f"rounding: every error below {ERROR_FLOOR_DEG:g} deg, no order to fit"
        row = {"case": case, "engine": engine, "integrator": integrator}
        row["expected_order"] = orders.get((engine, integrator), np.nan)
        rows.append(row | fit | _position_fit(dt, valid["position_error"].to_numpy(float)))
    return pd.DataFrame(rows)


def _epsilon(engine: str) -> float:
    from comparators.engine import ENGINES

    return float(getattr(ENGINES.get(engine), "epsilon", FLOAT64_EPSILON))


def _precision(engine: str) -> str:
    return "float32" if _epsilon(engine) == float(np.finfo(np.float32).eps) else "its"


def pareto_front(df: pd.DataFrame, x: str, y: str) -> pd.DataFrame:
    """The rows of `df` no other row dominates (another row with x and y both <= and one <).

    Rows with a non-finite x or y are left out; exact duplicates keep one. Sorted by x, with
    y decreasing along the front; the original index is kept.
    """
    finite = df[np.isfinite(df[x].astype(float)) & np.isfinite(df[y].astype(float))]
    ordered = finite.sort_values([x, y], kind="stable")
    best_before = ordered[y].cummin().shift(1, fill_value=np.inf)
    return ordered[ordered[y] < best_before]


def cost_to_tolerance(
    results: pd.DataFrame, tolerances: tuple[float, ...] = (1e-2, 1e-4, 1e-6)
) -> pd.DataFrame:
    """Per case and engine, the cheapest run reaching each orientation tolerance (deg).

    Cost is stepping wall time per simulated second (`wall_s / duration`, s/s), among the
    engine's valid runs (any integrator, any dt) with orientation_error_deg <= tolerance.
    Only cases whose reference is "exact". Columns: case, engine, tolerance_deg,
    cost_s_per_s (NaN when not reached), integrator, dt (s).
    """
    exact = results[results["reference"] == "exact"]
    rows = []
    for (case, engine), runs in exact.groupby(["case", "engine"], sort=False):
        valid = runs[(runs["verdict"] == "ok") & np.isfinite(runs["wall_s"].astype(float))]
        cost = valid["wall_s"] / valid["duration"]
        for tol in tolerances:
            reached = cost[valid["orientation_error_deg"] <= tol]
            row = {"case": case, "engine": engine, "tolerance_deg": tol}
            if reached.empty:
                row |= {"cost_s_per_s": np.nan, "integrator": None, "dt": np.nan}
            else:
                best = reached.idxmin()
                row |= {"cost_s_per_s": float(reached[best])}
                row |= {"integrator": valid.at[best, "integrator"], "dt": valid.at[best, "dt"]}
            rows.append(row)
    columns = ["case", "engine", "tolerance_deg", "cost_s_per_s", "integrator", "dt"]
    return pd.DataFrame(rows, columns=columns)


def lowest_front(df: pd.DataFrame, x: str, y: str, by: str, floor: float = 0.0) -> pd.DataFrame:
    """At each budget (every distinct finite x), which `by` groups reach the smallest y with
    rows costing at most that budget. A y below `floor` counts as `floor`: errors there are
    rounding, so every group below it ties. Index: budget; columns: the groups; True where the
    group is lowest there (a group with no row within the budget never is)."""
    finite = df[np.isfinite(df[x].astype(float)) & np.isfinite(df[y].astype(float))]
    groups = sorted(finite[by].unique())
    lowest = {}
    for budget in np.unique(finite[x]):
        best = finite[finite[x] <= budget].groupby(by)[y].min().clip(lower=floor)
        lowest[budget] = best.reindex(groups) == best.min()
    return pd.DataFrame.from_dict(lowest, orient="index", columns=groups).astype(bool)


def largest_stable_dt(results: pd.DataFrame) -> pd.DataFrame:
    """Per (case, engine, integrator): the largest swept dt at which the run and every run at a
    smaller dt have the verdict "ok".

    Columns: case, engine, integrator, largest_stable_dt (s; NaN when even the smallest dt
    fails), all_stable (every swept dt is ok: the largest stable dt is at least the largest
    swept), dt_max (s, the largest swept), first_unstable_dt (s, the smallest dt whose run is
    not ok, NaN when none), first_unstable_verdict.
    """
    rows = []
    for (case, engine, integrator), runs in results.groupby(KEYS, sort=False):
        runs = runs.sort_values("dt")
        ok = (runs["verdict"] == "ok").to_numpy()
        failing = np.flatnonzero(~ok)
        stable = runs["dt"].to_numpy(float)[: failing[0] if len(failing) else len(runs)]
        first = runs.iloc[failing[0]] if len(failing) else None
        rows.append(
            {
                "case": case,
                "engine": engine,
                "integrator": integrator,
                "largest_stable_dt": float(stable[-1]) if len(stable) else np.nan,
                "all_stable": not len(failing),
                "dt_max": float(runs["dt"].max()),
                "first_unstable_dt": np.nan if first is None else float(first["dt"]),
                "first_unstable_verdict": None if first is None else first["verdict"],
            }
        )
    columns = [*KEYS, "largest_stable_dt", "all_stable", "dt_max", "first_unstable_dt"]
    return pd.DataFrame(rows, columns=[*columns, "first_unstable_verdict"])
