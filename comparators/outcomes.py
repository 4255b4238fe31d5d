"""Outcomes measured from any engine's trajectory and the scene: the quantities physics predicts
in closed form (rebound ratio, apex heights, rest, momentum, flip period, and from
`comparators.sliding` a sliding or spinning body's distance, time, turn, slope acceleration
and path on its plane), each against its expected value.

Everything here reads the trajectory table (COM position and velocity, orientation, angular
velocity per sample; `comparators.trajectory`) and the scene, never an engine's internals, so
every engine is measured the same way. What is measured is decided by what the scene states (its
`Expected` fields, number of bodies, planes, gravity), never by its name: a case loaded from TOML
gets the same treatment as a catalog case. The run's arrays come from `comparators.run_data`, its
verdict from `comparators.verdict`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cases.exact import EQUAL_MOMENTS_RTOL, exact_states, exact_trajectory_available
from cases.scene import Body, Plane, Scene
from comparators.metrics import support_plane
from comparators.run_data import (
    RunData,
    contact_planes,
    expects_rest,
    final_window,
    quantity_label,
    starts_at_rest,
)
from comparators.sliding import STOP_SPEED, path_rows, slope_rows, spin_rows, stopping_rows
from comparators.trajectory import Trajectory
from rigidmath.quaternion import quats_to_matrices

OUTCOME_COLUMNS = ["quantity", "measured", "expected", "error", "unit"]

# Rebound ratio: the mean over the bounces whose apex heights the case states, else over the
# first REBOUND_BOUNCES impacts (later ones are slow, at the contact's resolution). Impacts
# approaching slower than MIN_IMPACT_FRACTION of the fastest are contact noise, not bounces (a
# body resting in a soft contact oscillates at up to 1e-5 of it).
REBOUND_BOUNCES = 3
MIN_IMPACT_FRACTION = 0.01
# Clearances below this (m) are the plane itself: metre-scale coordinates round to ~1e-16 m, which
# carried ballistically (sqrt(2 g c)) would read as a rebound of 6e-8 m/s.
CLEARANCE_ROUNDING = 1e-12
# A stack stands while every body's COM stays within this of where it started (m): far beyond
# soft-contact settling (1e-4 m), well below a tenth of a cube's edge.
STAND_DISTANCE = 0.05


# ---- measurements ------------------------------------------------------------------------------
# Each returns rows (quantity, measured, expected, unit); none when the scene does not state what
# it measures. Multi-body scenes prefix per-body quantities with "<body>.".


def bounces(run: RunData, body_index: int, plane: Plane) -> pd.DataFrame:
    """Impacts of one body on `plane` under gravity, in order: t (s, the sample of the impact),
    approach and rebound speed of the COM along the plane normal (m/s), their ratio, and the
    apex (m): the clearance of the lowest particle surface at the top of the following flight.

    Method: an impact is a sign change of the COM normal velocity v from negative to >= 0 (a
    speed below STOP_SPEED counts as 0, so a landing without rebound is one too), a top one from
    positive to <= 0. Each sample's normal speed carried ballistically to the plane,
    u = sqrt(v^2 + 2 g_n c) with c the clearance of the lowest particle surface (0 when below
    CLEARANCE_ROUNDING or unknown), is
    constant in free flight and drops in contact; the approach speed is its largest value on the
    way down since the previous top, the rebound speed its largest value on the way up to the
    next top (or the next impact). This is exact for a body that does not rotate in flight,
    whatever the sample interval and however long the contact lasts (soft contacts, contact
    margins): the free-flight samples on either side carry the speeds. The apex is c + v^2 / 2 g_n
    at whichever of the two samples around the top has the smaller |v|: exact in free flight,
    and with rotation the lowest particle's actual clearance there. A rebound that never reaches
    a top before the next impact or the end has no apex (NaN). Impacts approaching slower than
    MIN_IMPACT_FRACTION of the fastest are contact noise and left out.
    """
    a = run.arrays(body_index)
    n = plane.unit_normal
    g_n = -float(np.dot(run.scene.gravity, n))
    vn = a["v"] @ n
    vn = np.where(np.abs(vn) < STOP_SPEED, 0.0, vn)
    c = run.clearance(body_index, plane)
    # unknown (deforming) and rounding-level clearances: at the plane
    lift = np.where(np.isfinite(c) & (c > CLEARANCE_ROUNDING), c, 0.0)
    u = np.sqrt(vn**2 + 2 * g_n * lift)
    impacts = np.flatnonzero((vn[:-1] < 0) & (vn[1:] >= 0))
    tops = np.flatnonzero((vn[:-1] > 0) & (vn[1:] <= 0))
    rows = []
    for i, k in enumerate(impacts):
        earlier = tops[tops < k]
        down = np.arange(earlier[-1] + 1 if len(earlier) else 0, k + 1)
        following = impacts[i + 1] if i + 1 < len(impacts) else len(vn) - 1
        later = tops[(tops > k) & (tops < following)]
        up = np.arange(k + 1, (later[0] if len(later) else following) + 1)
        approach = u[down][vn[down] <= 0].max()
        rising = up[vn[up] >= 0]
        rebound = u[rising].max() if len(rising) else 0.0
        apex = np.nan
        if len(later):
            m = later[0] + int(abs(vn[later[0] + 1]) < abs(vn[later[0]]))
            apex = c[m] + vn[m] ** 2 / (2 * g_n)
        rows.append((a["t"][k], approach, rebound, apex))
    df = pd.DataFrame(rows, columns=["t", "approach", "rebound", "apex"])
    if len(df):
        df = df[df["approach"] >= MIN_IMPACT_FRACTION * df["approach"].max()]
    df = df.assign(ratio=df["rebound"] / df["approach"])
    return df.reset_index(drop=True)


def _bounce_rows(run: RunData) -> list[tuple]:
    scene = run.scene
    expected = scene.expected
    if expected is None or (expected.rebound_ratio is None and expected.apex_heights is None):
        return []
    plane = support_plane(scene)
    # the bounces the case predicts apexes for, else REBOUND_BOUNCES
    count = max(1, len(expected.apex_heights)) if expected.apex_heights else REBOUND_BOUNCES
    rows = []
    for k, body in enumerate(scene.bodies):
        found = bounces(run, k, plane) if plane is not None else pd.DataFrame()
        if expected.rebound_ratio is not None:
            first = found["ratio"].iloc[:count] if len(found) else []
            ratio = float(np.mean(first)) if len(first) else np.nan
            rows.append(
                (quantity_label(scene, body, "rebound_ratio"), ratio, expected.rebound_ratio, "1")
            )
        for i, h in enumerate(expected.apex_heights or ()):
            apex = float(found["apex"].iloc[i]) if i < len(found) else np.nan
            rows.append((quantity_label(scene, body, f"apex_height_{i + 1}"), apex, h, "m"))
    return rows


def _rest_height_rows(run: RunData) -> list[tuple]:
    """The final COM height above the support plane (`comparators.metrics.rest`)."""
    scene = run.scene
    if not expects_rest(scene):
        return []
    plane = support_plane(scene)
    rows = []
    for k, body in enumerate(scene.bodies):
        x = run.arrays(k)["x"][-1]
        height = np.nan if plane is None else float(np.dot(plane.unit_normal, x - plane.point))
        rows.append(
            (
                quantity_label(scene, body, "rest_com_height"),
                height,
                scene.expected.rest_com_height,
                "m",
            )
        )
    return rows


def resting(run: RunData) -> dict[str, float]:
    """Rest measured over the final window (`final_window`), largest over the bodies:

    creep: largest COM displacement (m) from its start for a body that starts at rest, else
      from its position at the start of the final window;
    jitter_rms: RMS COM speed (m/s) over the final window;
    penetration: mean over the final window of the depth (m) of the deepest particle surface
      below the support plane (negative: a gap).
    """
    scene = run.scene
    plane = support_plane(scene)
    creep, jitter, depths = 0.0, 0.0, []
    for k, body in enumerate(scene.bodies):
        a = run.arrays(k)
        window = final_window(a["t"])
        origin = a["x"][0] if starts_at_rest(scene, body) else a["x"][window][0]
        stretch = slice(None) if starts_at_rest(scene, body) else window
        creep = max(creep, float(np.linalg.norm(a["x"][stretch] - origin, axis=1).max()))
        speed = np.linalg.norm(a["v"][window], axis=1)
        jitter = max(jitter, float(np.sqrt(np.mean(speed**2))))
        if plane is not None:
            depths.append(-run.clearance(k, plane)[window])
    deepest = np.max(depths, axis=0) if depths else np.array([])  # NaN where any is unknown
    deepest = deepest[np.isfinite(deepest)]
    penetration = float(deepest.mean()) if len(deepest) else np.nan
    return {"creep": creep, "jitter_rms": jitter, "penetration": penetration}


def _rest_rows(run: RunData) -> list[tuple]:
    """Creep, jitter and steady penetration of a scene that expects rest, against 0: a rigid
    body at rest on a rigid floor stays exactly where it is, still and on the surface."""
    if not expects_rest(run.scene):
        return []
    r = resting(run)
    units = {"creep": "m", "jitter_rms": "m/s", "penetration": "m"}
    return [(name, value, 0.0, units[name]) for name, value in r.items()]


def _is_stack(scene: Scene) -> bool:
    """Several bodies placed at rest under gravity on planes: physics says they stay put."""
    slope = scene.expected is not None and scene.expected.slope_acceleration is not None
    return (
        len(scene.bodies) > 1
        and scene.has_gravity
        and bool(contact_planes(scene))
        and not slope
        and all(starts_at_rest(scene, b) for b in scene.bodies)
    )


def stack(run: RunData) -> dict[str, float]:
    """standing: 1 when every body's COM stays within STAND_DISTANCE of its start throughout,
    else 0; top_drift: the largest horizontal (normal to gravity) displacement (m) of the body
    that starts highest."""
    bodies = run.scene.bodies
    g = np.asarray(run.scene.gravity, dtype=float)
    down = g / np.linalg.norm(g)
    top = max(range(len(bodies)), key=lambda k: -np.dot(bodies[k].com, down))
    standing = True
    for k in range(len(bodies)):
        x = run.arrays(k)["x"]
        standing &= bool((np.linalg.norm(x - x[0], axis=1) <= STAND_DISTANCE).all())
    x = run.arrays(top)["x"]
    shift = x - x[0]
    shift -= np.outer(shift @ down, down)
    return {"standing": float(standing), "top_drift": float(np.linalg.norm(shift, axis=1).max())}


def _stack_rows(run: RunData) -> list[tuple]:
    """Against the closed form of a rigid stack: it stands (1) and nothing drifts (0 m)."""
    if not _is_stack(run.scene):
        return []
    s = stack(run)
    return [("standing", s["standing"], 1.0, "1/0"), ("top_drift", s["top_drift"], 0.0, "m")]


def max_penetration(run: RunData) -> float:
    """The largest depth (m) of any particle surface below any plane over the run (negative:
    never touched; NaN: no rigid sample). A depth beyond the particle radius is a tunnel."""
    depths = [
        body.particle_radius - run.distances(k, plane)
        for k, body in enumerate(run.scene.bodies)
        for plane in contact_planes(run.scene)
    ]
    known = np.concatenate([d[np.isfinite(d)] for d in depths]) if depths else np.array([])
    return float(known.max()) if len(known) else np.nan


def _penetration_rows(run: RunData) -> list[tuple]:
    """No closed form: how deep an impact goes is the contact model's (and the sampling's)."""
    if not contact_planes(run.scene):
        return []
    return [("max_penetration", max_penetration(run), np.nan, "m")]


def momentum_change(run: RunData) -> dict[str, float]:
    """Change of total linear and angular momentum (about the system COM) from the first to the
    last sample, relative to the sum of the bodies' magnitudes at the first: sum m |v| and
    sum |L_b| (spin plus orbital part about the system COM). Both sums are positive whenever
    something moves, even when the totals are zero (a head-on collision)."""
    scene = run.scene
    c = run.conserved()
    p = c[["px", "py", "pz"]].to_numpy()
    L = c[["Lx", "Ly", "Lz"]].to_numpy()
    arrays = [run.arrays(k) for k in range(len(scene.bodies))]
    mass = sum(b.mass for b in scene.bodies)
    com = sum(b.mass * a["x"][0] for b, a in zip(scene.bodies, arrays, strict=True)) / mass
    v_com = p[0] / mass
    p_scale, l_scale = 0.0, 0.0
    for body, a in zip(scene.bodies, arrays, strict=True):
        r = quats_to_matrices(np.ascontiguousarray(a["q"][:1]))[0]
        spin = r @ body.inertia @ r.T @ a["w"][0]
        orbital = body.mass * np.cross(a["x"][0] - com, a["v"][0] - v_com)
        p_scale += body.mass * np.linalg.norm(a["v"][0])
        l_scale += np.linalg.norm(spin + orbital)

    def relative(values: np.ndarray, scale: float) -> float:
        change = float(np.linalg.norm(values[-1] - values[0]))
        return change / scale if scale > 0 else change

    return {
        "momentum_change": relative(p, p_scale),
        "angular_momentum_change": relative(L, l_scale),
    }


def _momentum_rows(run: RunData) -> list[tuple]:
    """Bodies alone in free space (no gravity, no planes) conserve their total momenta: 0."""
    scene = run.scene
    if len(scene.bodies) < 2 or scene.has_gravity or scene.planes:
        return []
    return [(name, value, 0.0, "relative") for name, value in momentum_change(run).items()]


def _intermediate_axis(body: Body) -> np.ndarray | None:
    moments, axes = np.linalg.eigh(body.inertia)
    gap = EQUAL_MOMENTS_RTOL * moments[-1]
    if moments[1] - moments[0] <= gap or moments[2] - moments[1] <= gap:
        return None
    return axes[:, 1]


def flip_times(t: np.ndarray, q: np.ndarray, body: Body) -> np.ndarray:
    """Times (s) at which the body's intermediate principal axis crosses the plane normal to its
    initial angular momentum L (constant without contact), linearly interpolated between samples.

    For a spin near the intermediate axis along world y (tumbling_box) these are the sign
    changes of that axis's world y-component: the flips. In general they come twice per period
    of the body-frame motion of L (its polhode), so for a spin near the largest or smallest axis
    they are half the nutation period apart. Empty when the intermediate axis is undefined (two
    equal moments) or the body does not spin."""
    axis = _intermediate_axis(body)
    momentum = body.inertia @ np.asarray(body.angular_velocity, dtype=float)
    if axis is None or not np.linalg.norm(momentum) > 0:
        return np.array([])
    s = (quats_to_matrices(np.ascontiguousarray(q)) @ axis) @ (momentum / np.linalg.norm(momentum))
    k = np.flatnonzero(np.sign(s[:-1]) * np.sign(s[1:]) < 0)
    return t[k] + (t[k + 1] - t[k]) * s[k] / (s[k] - s[k + 1])


def _mean_period(times: np.ndarray) -> float:
    return float((times[-1] - times[0]) / (len(times) - 1)) if len(times) >= 2 else np.nan


def _flip_rows(run: RunData) -> list[tuple]:
    """The mean time between flips (s) against the exact solution's at the same sample times;
    for bodies whose exact motion flips at least twice in the run."""
    scene = run.scene
    if not exact_trajectory_available(scene):
        return []
    rows = []
    t = run.arrays(0)["t"]
    exact = None
    for k, body in enumerate(scene.bodies):
        if _intermediate_axis(body) is None:
            continue
        exact = exact_states(scene, t) if exact is None else exact
        expected = _mean_period(flip_times(t, exact[k]["q"], body))
        if np.isnan(expected):
            continue
        measured = _mean_period(flip_times(t, run.arrays(k)["q"], body))
        rows.append((quantity_label(scene, body, "flip_period"), measured, expected, "s"))
    return rows


MEASUREMENTS = (
    _rest_height_rows,
    _bounce_rows,
    stopping_rows,
    spin_rows,
    slope_rows,
    path_rows,
    _rest_rows,
    _stack_rows,
    _penetration_rows,
    _momentum_rows,
    _flip_rows,
)


def outcomes(traj: Trajectory, scene: Scene, run: RunData | None = None) -> pd.DataFrame:
    """Every outcome the scene states or implies, one row each: quantity, measured, expected
    (closed form, NaN without one), error (measured - expected), unit.

    A run with a non-finite state keeps its rows with measured NaN: nothing it did is a result.
    """
    run = run or RunData(traj, scene)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        rows = [row for measure in MEASUREMENTS for row in measure(run)]
    df = pd.DataFrame(rows, columns=["quantity", "measured", "expected", "unit"])
    df = df.astype({"measured": float, "expected": float})
    if not run.finite():
        df["measured"] = np.nan
    df["error"] = df["measured"] - df["expected"]
    return df[OUTCOME_COLUMNS]
