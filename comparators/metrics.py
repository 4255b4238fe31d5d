"""Metrics computed by the suite from any engine's states, the same way for every engine.

Nothing here reads an engine's own energy: every quantity comes from the trajectory table and
the scene (masses and the particle inertia tensor).

Drifts are relative: max over the run of |f(t) - f_expected(t)| / max over the run of
|f_expected(t)|, with f_expected the initial value for conserved quantities (linear momentum
corrected by the gravity impulse M g t); when f_expected is zero throughout, the drift is
absolute.
Potential energy is -M g . x, zero at the world origin.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cases.scene import Scene
from comparators.trajectory import ANGULAR_VELOCITY, POSITION, QUATERNION, VELOCITY, Trajectory
from rigidmath.quaternion import quats_angle_between, quats_to_matrices

# A body is at rest when its COM speed and angular speed stay below these over the rest window:
# 1 mm/s and 1 mrad/s are far below the motion of any case yet far above impulse-solver noise.
REST_SPEED = 1e-3
REST_ANGULAR_SPEED = 1e-3
REST_WINDOW = 0.5  # s, the final stretch of the run inspected for rest


def body_arrays(traj: Trajectory, body: str) -> dict[str, np.ndarray]:
    """{'t': (S,), 'x': (S, 3), 'q': (S, 4), 'v': (S, 3), 'w': (S, 3)} of one body."""
    columns = {"t": ["t"], "x": POSITION, "q": QUATERNION, "v": VELOCITY, "w": ANGULAR_VELOCITY}
    values = traj.state_by_body.get(body, np.empty((0, 14)))
    out, start = {}, 0
    for key, names in columns.items():
        out[key] = np.ascontiguousarray(values[:, start : start + len(names)])
        start += len(names)
    out["t"] = out["t"][:, 0]
    return out


def _world_inertia(q: np.ndarray, inertia0: np.ndarray) -> np.ndarray:
    r = quats_to_matrices(np.ascontiguousarray(q))
    return r @ inertia0 @ r.transpose(0, 2, 1)


def conserved_quantities(traj: Trajectory, scene: Scene) -> pd.DataFrame:
    """Per sample time, summed over bodies: kinetic (translational, rotational), potential and
    total energy (J); linear momentum p (kg m/s); angular momentum L about the system COM,
    world axes (kg m^2/s)."""
    g = np.asarray(scene.gravity)
    total_mass = sum(b.mass for b in scene.bodies)
    arrays = [body_arrays(traj, b.name) for b in scene.bodies]
    t = arrays[0]["t"]
    ke_t = np.zeros(len(t))
    ke_r = np.zeros(len(t))
    pe = np.zeros(len(t))
    p = np.zeros((len(t), 3))
    com = np.zeros((len(t), 3))
    spin = np.zeros((len(t), 3))
    for body, a in zip(scene.bodies, arrays, strict=True):
        m = body.mass
        iw = _world_inertia(a["q"], body.inertia)
        lw = np.einsum("sij,sj->si", iw, a["w"])
        ke_t += 0.5 * m * np.einsum("si,si->s", a["v"], a["v"])
        ke_r += 0.5 * np.einsum("si,si->s", a["w"], lw)
        pe -= m * a["x"] @ g
        p += m * a["v"]
        com += m * a["x"] / total_mass
        spin += lw
    v_com = p / total_mass
    orbital = sum(
        b.mass * np.cross(a["x"] - com, a["v"] - v_com)
        for b, a in zip(scene.bodies, arrays, strict=True)
    )
    L = spin + orbital
    return pd.DataFrame(
        {
            "t": t,
            "kinetic_translational": ke_t,
            "kinetic_rotational": ke_r,
            "potential": pe,
            "energy": ke_t + ke_r + pe,
            **{f"p{c}": p[:, k] for k, c in enumerate("xyz")},
            **{f"L{c}": L[:, k] for k, c in enumerate("xyz")},
        }
    )


def relative_drift(values: np.ndarray, expected: np.ndarray | None = None) -> float:
    """max_t |values(t) - expected(t)| / max_t |expected(t)|, absolute when expected is zero.

    `values` is (S,) or (S, k); `expected` defaults to the initial value.
    """
    values = np.asarray(values, dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    expected = values[:1] if expected is None else np.asarray(expected).reshape(values.shape)
    scale = np.linalg.norm(expected, axis=-1).max()
    err = np.linalg.norm(values - expected, axis=1).max()
    return float(err / scale) if scale > 0 else float(err)


def drifts(traj: Trajectory, scene: Scene) -> dict[str, float]:
    """Relative drifts of total energy, linear momentum and angular momentum."""
    c = conserved_quantities(traj, scene)
    p = c[["px", "py", "pz"]].to_numpy()
    total_mass = sum(b.mass for b in scene.bodies)
    p_expected = p[0] + total_mass * np.outer(c["t"].to_numpy(), scene.gravity)
    return {
        "energy_drift": relative_drift(c["energy"].to_numpy()),
        "momentum_drift": relative_drift(p, p_expected),
        "angular_momentum_drift": relative_drift(c[["Lx", "Ly", "Lz"]].to_numpy()),
    }


def pose_errors(traj: Trajectory, reference: list[dict[str, np.ndarray]], scene: Scene):
    """Per body and sample: COM distance (m) and geodesic rotation angle (deg) to `reference`.

    `reference` holds per body (scene order) 'x' (S, 3) and 'q' (S, 4) at the trajectory's
    sample times. Returns a DataFrame with t, body, position_error, orientation_error_deg.
    """
    frames = []
    for body, ref in zip(scene.bodies, reference, strict=True):
        a = body_arrays(traj, body.name)
        angle = quats_angle_between(np.ascontiguousarray(a["q"]), np.ascontiguousarray(ref["q"]))
        frames.append(
            pd.DataFrame(
                {
                    "t": a["t"],
                    "body": body.name,
                    "position_error": np.linalg.norm(a["x"] - ref["x"], axis=1),
                    "orientation_error_deg": np.degrees(angle),
                }
            )
        )
    return pd.concat(frames, ignore_index=True)


# Sample times of runs with different dt are compared after rounding to this (s): far below any
# sample interval, far above the rounding of step * dt.
TIME_MATCH = 1e-9


def pose_errors_between(traj: Trajectory, reference: Trajectory, scene: Scene) -> pd.DataFrame:
    """`pose_errors` of `traj` against another run's trajectory, at the sample times they share."""
    ref_t = np.round(body_arrays(reference, scene.bodies[0].name)["t"] / TIME_MATCH)
    own_t = np.round(body_arrays(traj, scene.bodies[0].name)["t"] / TIME_MATCH)
    shared = np.intersect1d(own_t, ref_t)
    if len(shared) == 0:
        raise ValueError(f"{scene.name}: the two runs share no sample time")
    keep = np.isin(np.round(traj.table["t"].to_numpy() / TIME_MATCH), shared)
    sub = Trajectory(traj.table[keep].reset_index(drop=True), traj.meta)
    states = []
    for body in scene.bodies:
        a = body_arrays(reference, body.name)
        rows = np.isin(np.round(a["t"] / TIME_MATCH), shared)
        states.append({k: v[rows] for k, v in a.items()})
    return pose_errors(sub, states, scene)


def support_plane(scene: Scene):
    """The plane a body comes to rest on: the one whose normal points most against gravity."""
    if not scene.planes or not scene.has_gravity:
        return None
    g = np.asarray(scene.gravity)
    return max(scene.planes, key=lambda p: -np.dot(p.unit_normal, g) / np.linalg.norm(g))


def rest(traj: Trajectory, scene: Scene, body: str, window: float = REST_WINDOW) -> dict:
    """Rest detection over the last `window` seconds of one body's run.

    Returns at_rest (speeds below REST_SPEED and REST_ANGULAR_SPEED throughout the window),
    rest_time (start of the final stretch at rest, NaN if not at rest), com_height (final
    distance of the COM from the support plane, NaN without one), max_speed and
    max_angular_speed over the window.
    """
    a = body_arrays(traj, body)
    speed = np.linalg.norm(a["v"], axis=1)
    spin = np.linalg.norm(a["w"], axis=1)
    still = (speed < REST_SPEED) & (spin < REST_ANGULAR_SPEED)
    in_window = a["t"] >= a["t"][-1] - window
    at_rest = bool(still[in_window].all())
    moving = np.flatnonzero(~still)
    rest_time = (a["t"][moving[-1] + 1] if len(moving) else a["t"][0]) if at_rest else np.nan
    plane = support_plane(scene)
    height = np.nan if plane is None else float(np.dot(plane.unit_normal, a["x"][-1] - plane.point))
    return {
        "at_rest": at_rest,
        "rest_time": float(rest_time),
        "com_height": height,
        "max_speed": float(speed[in_window].max()),
        "max_angular_speed": float(spin[in_window].max()),
    }
