"""A body sliding or spinning on a plane under friction, measured from its trajectory: how far
and how long it slides (`stopping`), how far it turns (`spin`), how fast it accelerates down a
slope (`slope_acceleration`), and how well it keeps to the path these closed forms assume (on its
plane: `lift`; along its straight line, or in place: `sideways`, `path_on_line`). Each `*_rows`
function gives `comparators.outcomes` its rows (quantity, measured, expected, unit), none when
the scene states no such closed form.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cases.scene import Body, Plane, Scene
from comparators.metrics import REST_ANGULAR_SPEED, REST_SPEED, support_plane
from comparators.run_data import RunData, plane_under, quantity_label
from comparators.trajectory import Trajectory
from rigidmath.quaternion import qmul, quat_conjugate

# A sliding body has stopped once its COM speed stays below this (m/s): REST_SPEED again. A body
# decelerating at mu g >= 1 m/s^2 covers 0.5 um after falling below it.
STOP_SPEED = REST_SPEED
# A spinning body has stopped once its angular speed about its plane's normal stays below this
# (rad/s): REST_ANGULAR_SPEED again; decelerating at >= 1 rad/s^2 it turns 0.5 urad after.
STOP_SPIN = REST_ANGULAR_SPEED
# Slope acceleration is fitted after this fraction of the run: soft contacts (MuJoCo, PyBullet)
# take a few steps to reach their steady penetration on a body placed on the plane.
SLOPE_SETTLE_FRACTION = 0.1
# An in-plane component of gravity (a slope), or of a starting velocity across the downhill line,
# smaller than this relative to the whole is the rounding of the scene's coordinates (~1e-16).
DIRECTION_RTOL = 1e-12


def stopping(run: RunData, body_index: int) -> tuple[float, float]:
    """(distance (m), time (s)) from t = 0 until the COM speed stays below STOP_SPEED.

    The distance is the COM displacement along the support plane (all of it without one) at
    the first sample of the stopped stretch; the time is refined between samples (`_stop`).
    NaN, NaN: still moving at the end.
    """
    a = run.arrays(body_index)
    s, stop = _stop(a["t"], np.linalg.norm(a["v"], axis=1) / STOP_SPEED)
    if s < 0:
        return np.nan, np.nan
    shift = a["x"][s] - a["x"][0]
    plane = support_plane(run.scene)
    if plane is not None:
        shift = _in_plane(shift, plane)
    return float(np.linalg.norm(shift)), stop


def _measured_rows(run: RunData, measure, quantities: tuple[tuple[str, str], ...]) -> list[tuple]:
    """Per body, a row for each of `quantities` ((name, unit), in the order `measure(run, body)`
    returns their values) that the scene's `Expected` states; none when it states none."""
    scene, expected = run.scene, run.scene.expected
    stated = [
        expected is not None and getattr(expected, name) is not None for name, _ in quantities
    ]
    if not any(stated):
        return []
    rows = []
    for k, body in enumerate(scene.bodies):
        for (name, unit), value, wanted in zip(quantities, measure(run, k), stated, strict=True):
            if wanted:
                rows.append(
                    (quantity_label(scene, body, name), value, getattr(expected, name), unit)
                )
    return rows


def stopping_rows(run: RunData) -> list[tuple]:
    return _measured_rows(run, stopping, (("stopping_distance", "m"), ("stopping_time", "s")))


def _stop(t: np.ndarray, speed: np.ndarray) -> tuple[int, float]:
    """(first sample of the stretch where `speed` stays below its stop threshold, the stop's
    time), `speed` already divided by that threshold: the time is refined between the last
    moving sample and that one by continuing the last sampled deceleration to zero, exact for
    uniform deceleration, otherwise within one sample interval. (-1, NaN): still moving."""
    moving = np.flatnonzero(speed >= 1.0)
    if len(moving) and moving[-1] == len(speed) - 1:
        return -1, np.nan
    s = moving[-1] + 1 if len(moving) else 0
    stop = t[s]
    if s >= 2:
        decel = (speed[s - 2] - speed[s - 1]) / (t[s - 1] - t[s - 2])
        if decel > 0:
            stop = min(t[s], t[s - 1] + speed[s - 1] / decel)
    return int(s), float(stop)


def _states_a_spin(scene: Scene) -> bool:
    """Whether the scene states a spin closed form (angle or time)."""
    expected = scene.expected
    return expected is not None and (
        expected.spin_angle is not None or expected.spin_time is not None
    )


def _spin_axis(scene: Scene, body: Body) -> tuple[np.ndarray, float] | None:
    """The unit normal of the plane a body starts on (`plane_under`) and the sign of its starting
    spin about it; None: no such plane."""
    plane = plane_under(scene, body)
    if plane is None:
        return None
    n = plane.unit_normal
    return n, (1.0 if np.dot(body.angular_velocity, n) >= 0 else -1.0)


def spin(run: RunData, body_index: int) -> tuple[float, float]:
    """(angle (rad), time (s)) a body turns about the normal of the plane it starts on from t = 0
    until its angular speed about that normal stays below STOP_SPIN; the time refined between
    samples (`_stop`). The angle is the rotation about the normal since the start, unwrapped
    sample to sample, at the first sample of the stopped stretch, positive the way it was spun.
    NaN, NaN: no such plane, or still spinning at the end."""
    found = _spin_axis(run.scene, run.scene.bodies[body_index])
    if found is None:
        return np.nan, np.nan
    n, sign = found
    a = run.arrays(body_index)
    s, stop = _stop(a["t"], np.abs(a["w"] @ n) / STOP_SPIN)
    if s < 0:
        return np.nan, np.nan
    q = a["q"]  # (S, 4), scalar first: the turn since the start is q q0^-1, its angle about n
    turn = np.array(qmul(q.T, quat_conjugate(q[0])))  # (4, S)
    turned = np.unwrap(2.0 * np.arctan2(n @ turn[1:], turn[0]))
    return float(sign * turned[s]), stop


def spin_rate(traj: Trajectory, scene: Scene, body_index: int = 0) -> pd.DataFrame | None:
    """A spun body's angular speed about the normal of the plane it starts on, per sample: t (s)
    and `rate` (rad/s, positive the way it was spun). None: the scene states no spin closed
    form, or the body starts on no plane."""
    found = _spin_axis(scene, scene.bodies[body_index]) if _states_a_spin(scene) else None
    if found is None:
        return None
    n, sign = found
    a = RunData(traj, scene).arrays(body_index)
    return pd.DataFrame({"t": a["t"], "rate": sign * (a["w"] @ n)})


def spin_rows(run: RunData) -> list[tuple]:
    return _measured_rows(run, spin, (("spin_angle", "rad"), ("spin_time", "s")))


def _without(vector, unit) -> np.ndarray:
    """`vector` (or each row of it) less its component along the unit vector `unit`."""
    vector = np.asarray(vector, dtype=float)
    return vector - np.multiply.outer(vector @ unit, unit)


def _in_plane(vector, plane: Plane) -> np.ndarray:
    """The component of `vector` (or of each row of it) within `plane`."""
    return _without(vector, plane.unit_normal)


def _downhill(scene: Scene, plane: Plane) -> np.ndarray | None:
    """The unit direction of gravity's component within `plane`; None on a level plane."""
    g = np.asarray(scene.gravity, dtype=float)
    downhill = _in_plane(g, plane)
    size = np.linalg.norm(downhill)
    return downhill / size if size > DIRECTION_RTOL * np.linalg.norm(g) else None


def slope_acceleration(run: RunData, body_index: int) -> tuple[float, bool]:
    """(acceleration (m/s^2), slides) of one body down the plane it starts on.

    The acceleration is the least-squares fit of the COM's downhill displacement s(t) (along
    gravity's component in the plane) by s0 + v0 t + a t^2 / 2 over the run after its first
    SLOPE_SETTLE_FRACTION: exact for uniform acceleration, ~0 for a body that sticks. It slides
    when its COM speed at the end is at least STOP_SPEED. NaN, False: no plane with a downhill
    direction under it.
    """
    plane = plane_under(run.scene, run.scene.bodies[body_index])
    downhill = None if plane is None else _downhill(run.scene, plane)
    if downhill is None:
        return np.nan, False
    a = run.arrays(body_index)
    t, s = a["t"], (a["x"] - a["x"][0]) @ downhill
    fit = t >= t[0] + SLOPE_SETTLE_FRACTION * (t[-1] - t[0])
    if fit.sum() < 3 or not np.isfinite(s[fit]).all():
        return np.nan, False
    acceleration = 2.0 * np.polyfit(t[fit], s[fit], 2)[0]
    slides = bool(np.linalg.norm(a["v"][-1]) >= STOP_SPEED)
    return float(acceleration), slides


def lift(run: RunData, body_index: int) -> float:
    """The largest clearance (m) of a body's lowest particle surface above the plane it starts
    on (`plane_under`) over the run: the stopping, slope and spin closed forms have it slide
    on that plane throughout, clearance 0; a body that hops off it lifts by its hops' height.
    NaN: no such plane, or no rigid sample."""
    plane = plane_under(run.scene, run.scene.bodies[body_index])
    if plane is None:
        return np.nan
    clearance = run.clearance(body_index, plane)
    known = clearance[np.isfinite(clearance)]
    return float(max(known.max(), 0.0)) if len(known) else np.nan


def _states_a_slide(scene: Scene) -> bool:
    """Whether the scene states a stopping, slope or spin closed form: each has its bodies
    slide on their plane, along a straight line (a body spun in place: its COM stays put)."""
    expected = scene.expected
    return _states_a_spin(scene) or (
        expected is not None
        and any(
            value is not None
            for value in (
                expected.stopping_distance,
                expected.stopping_time,
                expected.slope_acceleration,
            )
        )
    )


def _line(scene: Scene, body: Body) -> tuple[Plane, np.ndarray] | None:
    """(plane, unit direction) of the straight line the stopping and slope closed forms have
    `body` slide along within the plane it starts on: downhill on a slope, along its starting
    velocity on a level plane (the zero vector for a body starting still there, or spun in
    place: it should stay put). None: no such plane, or the line is not straight (a slope
    crossed by a starting velocity)."""
    plane = plane_under(scene, body)
    if plane is None:
        return None
    start = _in_plane(body.velocity, plane)
    line = _downhill(scene, plane)
    if line is None:
        speed = np.linalg.norm(start)
        line = start / speed if speed > 0 else np.zeros(3)
    if np.linalg.norm(_without(start, line)) > DIRECTION_RTOL * np.linalg.norm(start):
        return None
    return plane, line


def sideways(run: RunData, body_index: int) -> float:
    """The furthest (m) a body's COM strays, within the plane it starts on, from the straight
    line the stopping and slope closed forms have it slide along (`_line`). NaN: no such line."""
    found = _line(run.scene, run.scene.bodies[body_index])
    if found is None:
        return np.nan
    plane, line = found
    x = run.arrays(body_index)["x"]
    off = np.linalg.norm(_without(_in_plane(x - x[0], plane), line), axis=1)
    known = off[np.isfinite(off)]
    return float(known.max()) if len(known) else np.nan


def path_on_line(traj: Trajectory, scene: Scene, body_index: int = 0) -> pd.DataFrame | None:
    """A sliding body's COM path in the plane it starts on, per sample: t (s), `along` the
    closed forms' line (`_line`) and `across` it (m, signed: positive towards normal x line,
    left of the line seen from above the plane). `sideways` is the largest |across|. None:
    no stated slide (`_states_a_slide`), no line, or a body that starts still on a level plane
    (no direction to be along)."""
    found = _line(scene, scene.bodies[body_index]) if _states_a_slide(scene) else None
    if found is None or not found[1].any():
        return None
    plane, line = found
    a = RunData(traj, scene).arrays(body_index)
    shift = _in_plane(a["x"] - a["x"][0], plane)
    left = np.cross(plane.unit_normal, line)
    return pd.DataFrame({"t": a["t"], "along": shift @ line, "across": shift @ left})


def path_rows(run: RunData) -> list[tuple]:
    """Per body, its `lift` off its plane and how far it strays `sideways`, both against 0,
    where the scene states a stopping, slope or spin closed form: each assumes the body slides
    on its plane, along a straight line or in place (`_states_a_slide`)."""
    scene = run.scene
    if not _states_a_slide(scene):
        return []
    rows = []
    for k, body in enumerate(scene.bodies):
        rows.append((quantity_label(scene, body, "lift"), lift(run, k), 0.0, "m"))
        rows.append((quantity_label(scene, body, "sideways"), sideways(run, k), 0.0, "m"))
    return rows


def slope_rows(run: RunData) -> list[tuple]:
    scene = run.scene
    expected = scene.expected
    if expected is None or expected.slope_acceleration is None:
        return []
    rows = []
    for k, body in enumerate(scene.bodies):
        acceleration, slides = slope_acceleration(run, k)
        a0 = expected.slope_acceleration
        rows.append((quantity_label(scene, body, "slope_acceleration"), acceleration, a0, "m/s^2"))
        rows.append((quantity_label(scene, body, "slides"), float(slides), float(a0 > 0), "1/0"))
    return rows
