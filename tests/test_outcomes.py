"""Outcomes and verdicts, measured from trajectories whose answers are known exactly.

The synthetic trajectories are written by hand (`Trajectory.from_samples`): ballistic bounces,
uniform deceleration, uniform acceleration down a slope, bodies behind planes, blow-ups and
bodies that should rest but move. A few real runs of the reference engine show the same
measurements on engine output.
"""

import dataclasses
import math

import numpy as np
import pytest

from cases import CATALOG, Body, Contact, Expected, Scene
from cases.builders import floor, seed_cube_particles
from cases.exact import exact_states
from comparators import RunMeta, Trajectory, run
from comparators.outcomes import OUTCOME_COLUMNS, STAND_DISTANCE, bounces, outcomes
from comparators.run_data import RunData, particle_positions
from comparators.sliding import path_on_line
from comparators.verdict import (
    ENERGY_GROWTH_LIMIT,
    ENERGY_LOSS_LIMIT,
    JITTER_SPEED,
    energy_growth,
    energy_loss,
    verdict,
)
from rigidmath.quaternion import quat_from_rotvec, quat_to_matrix

G = 10.0
RADIUS = 0.2  # the seed cube's particle radius
REST = 0.5 + RADIUS  # COM height of the unit cube resting on a face
META = RunMeta("synthetic", "test", "none", 0.001, 1, 1.0, 0.0, 1.0)
IDENTITY = (1.0, 0.0, 0.0, 0.0)
# The measurements are exact for these motions (ballistic flight, uniform deceleration and
# acceleration); what is left is rounding of O(1) numbers in a few operations (~1e-15) and of
# least-squares fits over ~300 samples (~1e-13).
EXACT_RTOL = 1e-10
EXACT_ATOL = 1e-12
# Sample intervals deliberately out of step with the events (impacts, stop), so that no sample
# falls on one.
BOUNCE_SAMPLE = 0.0037
SLIDE_SAMPLE = 0.007


def cube(height: float = REST, **kwargs) -> Body:
    """The seed's cube, faces axis-aligned, COM at (0, 0, height)."""
    return Body(
        name="cube",
        particle_radius=RADIUS,
        particles=seed_cube_particles(offset=(-0.5, -0.5, height - 0.5)),
        **kwargs,
    )


def floor_scene(expected=None, bodies=None, duration=3.0, contact=(0.5, 0.5)) -> Scene:
    return Scene(
        name="synthetic",
        duration=duration,
        dt=0.001,
        gravity=(0.0, 0.0, -G),
        contact=Contact(restitution=contact[0], friction=contact[1]),
        planes=(floor(),),
        bodies=bodies or (cube(),),
        expected=expected,
    )


def trajectory(scene, t, x, v, q=None, w=None, body=0) -> Trajectory:
    """One body's samples: x, v (S, 3); q (S, 4) identity and w (S, 3) zero by default."""
    n = len(t)
    q = np.tile(IDENTITY, (n, 1)) if q is None else np.asarray(q, dtype=float)
    w = np.zeros((n, 3)) if w is None else np.asarray(w, dtype=float)
    samples = np.concatenate([x, q, v, w], axis=1)[:, None, :]
    return Trajectory.from_samples(t, [scene.bodies[body].name], samples, META)


def several(scene, t, xs, vs) -> Trajectory:
    """Several bodies without rotation: xs, vs lists of (S, 3), one per body in scene order."""
    n = len(t)
    q, w = np.tile(IDENTITY, (n, 1)), np.zeros((n, 3))
    samples = [np.concatenate([x, q, v, w], axis=1) for x, v in zip(xs, vs, strict=True)]
    samples = np.stack(samples, axis=1)
    return Trajectory.from_samples(t, [b.name for b in scene.bodies], samples, META)


def along_z(z, vz) -> tuple[np.ndarray, np.ndarray]:
    zeros = np.zeros_like(z)
    return np.stack([zeros, zeros, z], axis=1), np.stack([zeros, zeros, vz], axis=1)


def bouncing(t, h0, e):
    """COM height and vertical velocity of the cube dropped from rest with clearance h0 onto the
    floor, instantaneous impacts with restitution e, resting once the rebound is below 1e-9 m/s."""
    segments = [(0.0, REST + h0, 0.0)]  # (start, height, upward velocity)
    speed = math.sqrt(2 * G * h0)
    impact = speed / G
    while speed * e > 1e-9:
        speed *= e
        segments.append((impact, REST, speed))
        impact += 2 * speed / G
    segments.append((impact, REST, None))  # at rest from here on
    z, vz = np.empty_like(t), np.empty_like(t)
    starts = np.array([s[0] for s in segments])
    for i, ti in enumerate(t):
        start, height, v0 = segments[np.searchsorted(starts, ti, side="right") - 1]
        if v0 is None:
            z[i], vz[i] = REST, 0.0
        else:
            tau = ti - start
            z[i], vz[i] = height + v0 * tau - 0.5 * G * tau**2, v0 - G * tau
    return along_z(z, vz)


def measured(table, quantity: str) -> float:
    return float(table.set_index("quantity").loc[quantity, "measured"])


# ---- geometry -----------------------------------------------------------------------------------


def test_particle_positions_follow_the_pose():
    scene = floor_scene()
    q = quat_from_rotvec(np.array([0.0, 0.0, np.pi / 2]))
    traj = trajectory(scene, [0.0], np.array([[1.0, 2.0, 3.0]]), np.zeros((1, 3)), q=[q])
    body = scene.bodies[0]
    expected = np.array([1.0, 2.0, 3.0]) + (body.positions - body.com) @ quat_to_matrix(q).T
    assert particle_positions(traj, scene, 0)[0] == pytest.approx(expected, abs=EXACT_ATOL)


# ---- verdicts ---------------------------------------------------------------------------------


def test_a_bounce_that_comes_to_rest_is_ok():
    scene = floor_scene(Expected(rest_com_height=REST), bodies=(cube(REST + 1.0),))
    t = np.arange(0.0, 3.0, BOUNCE_SAMPLE)
    assert verdict(trajectory(scene, t, *bouncing(t, 1.0, 0.5)), scene) == "ok"


def test_a_particle_centre_behind_the_floor_is_a_tunnel():
    scene = floor_scene()
    t = np.array([0.0, 0.01, 0.02])
    # lowest particle centres at z = 0.2, then 0.05 (penetrating by 0.15 < radius), then -0.01
    sunk = along_z(np.array([REST, REST - 0.15, REST - 0.21]), np.zeros(3))
    assert verdict(trajectory(scene, t, *sunk), scene) == "tunnelled"
    deep = along_z(np.array([REST, REST - 0.15, REST - 0.15]), np.zeros(3))
    assert verdict(trajectory(scene, t, *deep), scene) == "ok"


def test_a_non_finite_state_is_diverged_before_anything_else():
    scene = floor_scene()
    x, v = along_z(np.array([REST, REST - 0.3, np.nan]), np.zeros(3))  # tunnelled, then NaN
    assert verdict(trajectory(scene, [0.0, 0.01, 0.02], x, v), scene) == "diverged"


@pytest.mark.parametrize("factor, expected", [(0.9, "ok"), (1.1, "diverged")])
def test_energy_growth_past_the_limit_is_diverged(factor, expected):
    """A cube spinning freely whose spin grows: rotational energy 2 |w|^2 (inertia 4 about any
    axis), so the growth relative to the initial energy is (w1 / w0)^2 - 1."""
    scene = dataclasses.replace(CATALOG["free_spin_cube"], bodies=(cube(),))
    w1 = math.sqrt(1 + factor * ENERGY_GROWTH_LIMIT)
    w = np.array([[1.0, 0, 0], [w1, 0, 0]])
    traj = trajectory(scene, [0.0, 1.0], np.full((2, 3), REST), np.zeros((2, 3)), w=w)
    assert energy_growth(traj, scene) == pytest.approx(factor * ENERGY_GROWTH_LIMIT, rel=1e-12)
    assert verdict(traj, scene) == expected


@pytest.mark.parametrize("factor, expected", [(0.99, "ok"), (1.01, "dissipated")])
def test_energy_lost_without_contact_past_the_limit_is_dissipated(factor, expected):
    """tumbling_box's exact motion (no contact, no gravity) with its velocities scaled by s from
    t = 1 s on: its energy, all kinetic and the energy scale, falls by 1 - s^2."""
    scene = CATALOG["tumbling_box"]
    t = np.linspace(0.0, 2.0, 21)
    (state,) = exact_states(scene, t)
    s = math.sqrt(1 - factor * ENERGY_LOSS_LIMIT)
    late = (t >= 1.0)[:, None]
    v, w = (np.where(late, s * state[k], state[k]) for k in ("v", "w"))
    traj = trajectory(scene, t, state["x"], v, q=state["q"], w=w)
    assert energy_loss(traj, scene) == pytest.approx(factor * ENERGY_LOSS_LIMIT, rel=1e-9)
    assert verdict(traj, scene) == expected


def test_energy_lost_with_contact_is_never_dissipated():
    """The cube dropped from 10 m comes to rest: its impacts took 10 / 10.7 of the energy scale
    (m g times its COM height), past the limit, and a contact may: ok."""
    scene = floor_scene(bodies=(cube(REST + 10.0),), duration=6.0)
    t = np.arange(0.0, 6.0, BOUNCE_SAMPLE)
    traj = trajectory(scene, t, *bouncing(t, 10.0, 0.5))
    assert energy_loss(traj, scene) > ENERGY_LOSS_LIMIT
    assert verdict(traj, scene) == "ok"


def test_every_list_of_verdicts_names_them_all():
    """The gates, the stability map's colours, the findings, the report's verdict table and the
    bench's timed verdicts know every verdict of `comparators.verdict`."""
    from comparators.bench import TIMED_VERDICTS
    from comparators.verdict import VERDICTS
    from gates.spec import VERDICT_NAMES
    from reports.findings import VERDICT_PHRASES
    from reports.plots import VERDICT_COLOURS
    from reports.texts import verdict_bounds

    assert set(VERDICT_NAMES) == {*VERDICTS, "failed"}
    assert set(VERDICT_COLOURS) == {*VERDICTS, "failed", "no run"}
    assert set(VERDICT_PHRASES) == set(VERDICTS) - {"ok"}
    assert {row[0] for row in verdict_bounds()} == {*VERDICTS, "failed"}
    assert set(TIMED_VERDICTS) == set(VERDICTS) - {"diverged"}


def resting_cube_moving(speed=0.0, spin=0.0, depth=0.0, creep_speed=0.0):
    """The cube placed on the floor (expected to rest) for 4 s: it creeps along x at
    `creep_speed`, sits `depth` into the floor, and over its last second moves at `speed` along y
    and spins at `spin` about z."""
    scene = floor_scene(Expected(rest_com_height=REST), duration=4.0)
    t = np.arange(0.0, 4.0 + 1e-9, 0.01)
    x = np.stack([creep_speed * t, np.zeros_like(t), np.full_like(t, REST - depth)], axis=1)
    v = np.stack([np.full_like(t, creep_speed), np.zeros_like(t), np.zeros_like(t)], axis=1)
    w = np.zeros_like(v)
    v[t >= 3.0, 1] = speed
    w[t >= 3.0, 2] = spin
    return scene, trajectory(scene, t, x, v, w=w)


@pytest.mark.parametrize(
    "motion, expected",
    [
        ({"speed": 0.5 * JITTER_SPEED}, "ok"),
        ({"speed": 2 * JITTER_SPEED}, "jitter"),
        # COM still, corners at sqrt(0.5) m from the z axis moving at 2 JITTER_SPEED
        ({"spin": 2 * JITTER_SPEED / math.sqrt(0.5)}, "jitter"),
    ],
)
def test_a_body_that_should_rest_but_moves_jitters(motion, expected):
    scene, traj = resting_cube_moving(**motion)
    assert verdict(traj, scene) == expected


def test_tunnelling_takes_precedence_over_jitter():
    scene, traj = resting_cube_moving(speed=2 * JITTER_SPEED, depth=0.25)  # centres behind
    assert verdict(traj, scene) == "tunnelled"


# ---- outcomes -----------------------------------------------------------------------------------


@pytest.mark.parametrize("e", [0.3, 0.5, 0.8])
def test_rebound_ratio_and_apex_heights_of_ballistic_bounces(e):
    h0 = 1.0
    apexes = tuple(h0 * e ** (2 * k) for k in (1, 2, 3))
    expected = Expected(rebound_ratio=e, apex_heights=apexes, rest_com_height=REST)
    scene = floor_scene(expected, bodies=(cube(REST + h0),), duration=6.0)
    t = np.arange(0.0, 6.0, BOUNCE_SAMPLE)
    table = outcomes(trajectory(scene, t, *bouncing(t, h0, e)), scene)
    assert list(table.columns) == OUTCOME_COLUMNS
    rows = table.set_index("quantity")
    assert rows.loc["rebound_ratio", "measured"] == pytest.approx(e, rel=EXACT_RTOL)
    for k, apex in enumerate(apexes, start=1):
        assert rows.loc[f"apex_height_{k}", "measured"] == pytest.approx(apex, rel=EXACT_RTOL)
        assert rows.loc[f"apex_height_{k}", "expected"] == apex
    for quantity in ("creep", "jitter_rms", "penetration"):  # at rest at the end, on the floor
        assert rows.loc[quantity, "measured"] == pytest.approx(0.0, abs=EXACT_ATOL)
    assert rows.loc["rest_com_height", "error"] == pytest.approx(0.0, abs=EXACT_ATOL)
    assert np.isnan(rows.loc["max_penetration", "expected"])


def test_a_landing_without_rebound_has_ratio_zero():
    """Falling onto the floor and staying there: the sign change ends at 0 m/s, no apex."""
    expected = Expected(rebound_ratio=0.0, apex_heights=(0.01,))
    scene = floor_scene(expected, bodies=(cube(REST + 1.0),), contact=(0.0, 0.5))
    t = np.arange(0.0, 2.0, BOUNCE_SAMPLE)
    traj = trajectory(scene, t, *bouncing(t, 1.0, 0.0))
    found = bounces(RunData(traj, scene), 0, scene.planes[0])
    assert found["approach"].tolist() == pytest.approx([math.sqrt(2 * G)], rel=EXACT_RTOL)
    assert found["rebound"].tolist() == [0.0]
    table = outcomes(traj, scene)
    assert measured(table, "rebound_ratio") == 0.0
    assert np.isnan(measured(table, "apex_height_1"))


@pytest.mark.parametrize("hop", [0.0, 0.05])
def test_stopping_distance_and_time_of_uniform_deceleration(hop):
    """With `hop` (m) the cube also leaves the floor by that much for a while: `lift` says so,
    and the stopping figures, along the floor, are unchanged."""
    v0, mu = 3.0, 0.5
    a = mu * G
    stop, distance = v0 / a, v0**2 / (2 * a)  # 0.6 s, 0.9 m
    scene = floor_scene(
        Expected(stopping_distance=distance, stopping_time=stop, rest_com_height=REST),
        bodies=(cube(velocity=(v0, 0.0, 0.0)),),
        duration=2.0,
    )
    t = np.arange(0.0, 2.0, SLIDE_SAMPLE)
    moving = t < stop
    s = np.where(moving, v0 * t - 0.5 * a * t**2, distance)
    speed = np.where(moving, v0 - a * t, 0.0)
    zeros = np.zeros_like(t)
    x = np.stack([s, zeros, REST + hop * ((t > 0.2) & (t < 0.3))], axis=1)
    v = np.stack([speed, zeros, zeros], axis=1)
    table = outcomes(trajectory(scene, t, x, v), scene)
    assert measured(table, "stopping_distance") == pytest.approx(distance, rel=EXACT_RTOL)
    assert measured(table, "stopping_time") == pytest.approx(stop, rel=EXACT_RTOL)
    assert measured(table, "lift") == pytest.approx(hop, abs=EXACT_ATOL)
    assert measured(table, "sideways") == 0.0  # the hop is off the plane, not sideways
    assert measured(table, "creep") == 0.0  # launched, then still: measured from its stop


@pytest.mark.parametrize("heading", [0.0, 0.7])
def test_sideways_is_the_furthest_stray_from_the_line_of_the_starting_velocity(heading):
    """Sliding along its starting velocity (heading, rad, from x) while drifting across it by
    up to 3 mm, and hopping 5 cm off the floor: sideways counts the drift only."""
    direction = np.array([math.cos(heading), math.sin(heading), 0.0])
    across = np.array([-direction[1], direction[0], 0.0])
    scene = floor_scene(
        Expected(stopping_distance=0.9),
        bodies=(cube(velocity=tuple(3.0 * direction)),),
        duration=1.0,
    )
    t = np.arange(0.0, 1.0, SLIDE_SAMPLE)
    drift = 0.003 * np.sin(np.pi * t)  # largest at t = 0.5, which no sample hits
    x = (
        scene.bodies[0].com
        + np.outer(3.0 * t, direction)
        + np.outer(drift, across)
        + np.outer(0.05 * (t > 0.2), [0.0, 0.0, 1.0])
    )
    traj = trajectory(scene, t, x, np.zeros_like(x))
    assert measured(outcomes(traj, scene), "sideways") == pytest.approx(drift.max(), rel=EXACT_RTOL)
    # the path the report draws: the same drift, signed (to the left of the line), and the
    # distance along it
    path = path_on_line(traj, scene)
    np.testing.assert_allclose(path["across"], drift, atol=EXACT_ATOL)
    np.testing.assert_allclose(path["along"], 3.0 * t, rtol=EXACT_RTOL, atol=EXACT_ATOL)
    np.testing.assert_array_equal(path["t"], t)


@pytest.mark.parametrize("w0", [5.0, -12.0])
def test_spin_angle_and_time_of_uniform_angular_deceleration(w0):
    """Spun about the floor's normal at w0 (rad/s) and slowed at 7 rad/s^2: the angle turned and
    the time to stop, exact; at -12 rad/s it turns 10.3 rad, past several half turns, the way
    it was spun (the angle's sign)."""
    a = 7.0
    stop, angle = abs(w0) / a, w0**2 / (2 * a)
    scene = floor_scene(
        Expected(spin_angle=angle, spin_time=stop, rest_com_height=REST),
        bodies=(cube(angular_velocity=(0.0, 0.0, w0)),),
        duration=2.5,
    )
    t = np.arange(0.0, 2.5, SLIDE_SAMPLE)
    moving = t < stop
    sign = np.sign(w0)
    turned = sign * np.where(moving, abs(w0) * t - 0.5 * a * t**2, angle)
    w = np.zeros((len(t), 3))
    w[:, 2] = sign * np.where(moving, abs(w0) - a * t, 0.0)
    q = np.stack([np.cos(turned / 2), 0 * t, 0 * t, np.sin(turned / 2)], axis=1)
    x = np.tile(scene.bodies[0].com, (len(t), 1))
    table = outcomes(trajectory(scene, t, x, np.zeros_like(x), q=q, w=w), scene)
    assert measured(table, "spin_angle") == pytest.approx(angle, rel=EXACT_RTOL)
    assert measured(table, "spin_time") == pytest.approx(stop, rel=EXACT_RTOL)


def test_a_body_still_spinning_at_the_end_has_no_spin_angle():
    scene = floor_scene(Expected(spin_angle=1.0), bodies=(cube(angular_velocity=(0, 0, 1.0)),))
    t = np.arange(0.0, 1.0, SLIDE_SAMPLE)
    w = np.tile([0.0, 0.0, 1.0], (len(t), 1))
    q = np.stack([np.cos(t / 2), 0 * t, 0 * t, np.sin(t / 2)], axis=1)
    x = np.tile(scene.bodies[0].com, (len(t), 1))
    table = outcomes(trajectory(scene, t, x, np.zeros_like(x), q=q, w=w), scene)
    assert np.isnan(measured(table, "spin_angle"))


def test_a_body_starting_still_on_a_level_plane_strays_by_any_move_along_it():
    scene = floor_scene(Expected(stopping_distance=0.9), duration=1.0)  # it never starts
    t = np.arange(0.0, 1.0, SLIDE_SAMPLE)
    x = scene.bodies[0].com + np.outer(t, [0.003, 0.004, 0.1])  # 5 mm along the floor at t = 1
    traj = trajectory(scene, t, x, np.zeros_like(x))
    assert measured(outcomes(traj, scene), "sideways") == pytest.approx(
        0.005 * t[-1], rel=EXACT_RTOL
    )
    assert path_on_line(traj, scene) is None  # no direction to draw it along


def test_no_path_where_the_scene_states_no_slide():
    """A cube pushed along the floor in a scene that states only its rest height: no closed form
    has it slide on a line, so there is no line to measure a path against."""
    scene = floor_scene(Expected(rest_com_height=REST), bodies=(cube(velocity=(3.0, 0, 0)),))
    t = np.arange(0.0, 1.0, SLIDE_SAMPLE)
    x = scene.bodies[0].com + np.outer(t, [3.0, 0.0, 0.0])
    assert path_on_line(trajectory(scene, t, x, np.zeros_like(x)), scene) is None


def incline_scene(degrees: float, acceleration: float) -> tuple[Scene, np.ndarray]:
    """The cube resting on a plane through the origin tilted by `degrees` about y (descending
    towards +x); returns the scene and the downhill unit vector."""
    theta = math.radians(degrees)
    c, s = math.cos(theta), math.sin(theta)
    rotation = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    rows = np.array(seed_cube_particles(offset=(-0.5, -0.5, RADIUS)))
    rows[:, :3] = rows[:, :3] @ rotation.T
    body = Body(name="cube", particle_radius=RADIUS, particles=tuple(map(tuple, rows)))
    plane = dataclasses.replace(floor(), normal=(s, 0.0, c))
    scene = dataclasses.replace(
        floor_scene(Expected(slope_acceleration=acceleration), duration=2.0),
        planes=(plane,),
        bodies=(body,),
    )
    return scene, np.array([c, 0.0, -s])


@pytest.mark.parametrize("degrees, mu", [(35.0, 0.5), (20.0, 0.5)])
def test_slope_acceleration_slides_or_sticks(degrees, mu):
    theta = math.radians(degrees)
    slides = math.tan(theta) > mu
    a = G * (math.sin(theta) - mu * math.cos(theta)) if slides else 0.0
    scene, downhill = incline_scene(degrees, a)
    t = np.arange(0.0, 2.0, 0.01)
    x = scene.bodies[0].com + np.outer(0.5 * a * t**2, downhill)
    v = np.outer(a * t, downhill)
    rows = outcomes(trajectory(scene, t, x, v), scene).set_index("quantity")
    assert rows.loc["slope_acceleration", "measured"] == pytest.approx(a, rel=EXACT_RTOL, abs=1e-12)
    assert rows.loc["slides", "measured"] == rows.loc["slides", "expected"] == float(slides)
    assert rows.loc["lift", "measured"] == pytest.approx(0.0, abs=EXACT_ATOL)
    assert rows.loc["sideways", "measured"] == pytest.approx(0.0, abs=EXACT_ATOL)


def test_sideways_on_a_slope_is_measured_across_the_downhill_line():
    """A cube sliding down the slope while drifting across it (y, within the plane) by 2 mm and
    rising off it (along the normal) by 4 mm: sideways is the 2 mm only."""
    scene, downhill = incline_scene(35.0, 1.64)
    normal = np.asarray(scene.planes[0].normal)
    t = np.arange(0.0, 2.0, 0.01)
    x = (
        scene.bodies[0].com
        + np.outer(0.82 * t**2, downhill)
        + np.outer(0.001 * t, [0.0, 1.0, 0.0])
        + np.outer(0.002 * t, normal)
    )
    table = outcomes(trajectory(scene, t, x, np.zeros_like(x)), scene)
    assert measured(table, "sideways") == pytest.approx(0.001 * t[-1], rel=EXACT_RTOL)


def test_sideways_is_not_measured_where_the_closed_forms_path_is_curved():
    """Started across the slope, a sliding body's path bends downhill: no straight line."""
    scene, _ = incline_scene(35.0, 1.64)
    across = dataclasses.replace(scene.bodies[0], velocity=(0.0, 1.0, 0.0))
    scene = dataclasses.replace(scene, bodies=(across,))
    t = np.arange(0.0, 2.0, 0.01)
    x = np.tile(scene.bodies[0].com, (len(t), 1))
    assert np.isnan(
        measured(outcomes(trajectory(scene, t, x, np.zeros_like(x)), scene), "sideways")
    )


def test_lift_is_one_row_where_both_sliding_closed_forms_are_stated():
    scene, _ = incline_scene(35.0, 1.64)
    both = dataclasses.replace(
        scene, expected=Expected(slope_acceleration=1.64, stopping_distance=1.0)
    )
    t = np.arange(0.0, 2.0, 0.01)
    x = np.tile(both.bodies[0].com, (len(t), 1))
    table = outcomes(trajectory(both, t, x, np.zeros_like(x)), both)
    assert (table["quantity"] == "lift").sum() == 1
    assert (table["quantity"] == "sideways").sum() == 1


def test_creep_jitter_and_steady_penetration_of_a_resting_body():
    creep_speed, depth = 1e-4, 1e-3
    scene, traj = resting_cube_moving(depth=depth, creep_speed=creep_speed)
    rows = outcomes(traj, scene).set_index("quantity")
    # it starts at rest on the floor: creep counts from t = 0 (4 s); the final window is the
    # last quarter of the run (1 s), where it moves at creep_speed throughout
    assert rows.loc["creep", "measured"] == pytest.approx(4.0 * creep_speed, rel=EXACT_RTOL)
    assert rows.loc["jitter_rms", "measured"] == pytest.approx(creep_speed, rel=EXACT_RTOL)
    assert rows.loc["penetration", "measured"] == pytest.approx(depth, rel=EXACT_RTOL)
    assert (rows.loc[["creep", "jitter_rms", "penetration"], "expected"] == 0.0).all()


@pytest.mark.parametrize("drift", [0.6 * STAND_DISTANCE, 1.2 * STAND_DISTANCE])
def test_a_stack_stands_while_its_top_drifts_less_than_the_bound(drift):
    pitch = 1.0 + 2 * RADIUS  # touching
    bottom, top = cube(), dataclasses.replace(cube(REST + pitch), name="top")
    scene = floor_scene(bodies=(bottom, top), duration=1.0)
    t = np.linspace(0.0, 1.0, 101)
    still = np.tile(bottom.com, (len(t), 1))
    moving = np.tile(top.com, (len(t), 1)) + np.outer(t * drift, [0.6, 0.8, 0.0])
    velocity = np.tile([0.6 * drift, 0.8 * drift, 0.0], (len(t), 1))
    traj = several(scene, t, [still, moving], [np.zeros_like(still), velocity])
    rows = outcomes(traj, scene).set_index("quantity")
    assert rows.loc["top_drift", "measured"] == pytest.approx(drift, rel=EXACT_RTOL)
    assert rows.loc["standing", "measured"] == float(drift <= STAND_DISTANCE)


def free_pair() -> Scene:
    a = Body(
        name="a", particle_radius=RADIUS, particles=seed_cube_particles(offset=(-3.0, 0.0, 0.0))
    )
    b = Body(
        name="b", particle_radius=RADIUS, particles=seed_cube_particles(offset=(0.0, 0.0, 0.0))
    )
    return Scene(name="pair", duration=1.0, dt=0.01, gravity=(0.0, 0.0, 0.0), bodies=(a, b))


@pytest.mark.parametrize("after, change", [(1.0, 0.0), (1.1, 0.1)])
def test_momentum_change_of_a_collision_in_free_space(after, change):
    """Equal cubes, head on along the line of their centres: a (1 m/s) stops, b leaves at
    `after` m/s. Conserved when after = 1; else |dp| / (m |v_a|) = after - 1."""
    scene = free_pair()
    t = np.array([0.0, 1.0])
    xa = np.array([scene.bodies[0].com, scene.bodies[0].com + [0.5, 0, 0]])
    xb = np.array([scene.bodies[1].com, scene.bodies[1].com + [0.5 * after, 0, 0]])
    va, vb = np.array([[1.0, 0, 0], [0, 0, 0]]), np.array([[0, 0, 0], [after, 0, 0]])
    rows = outcomes(several(scene, t, [xa, xb], [va, vb]), scene).set_index("quantity")
    assert rows.loc["momentum_change", "measured"] == pytest.approx(change, abs=EXACT_ATOL)
    assert rows.loc["angular_momentum_change", "measured"] == pytest.approx(0.0, abs=EXACT_ATOL)


def exact_trajectory(scene, t, time_scale=1.0) -> Trajectory:
    """The exact motion at times t * time_scale, labelled t: a body tumbling time_scale faster."""
    (state,) = exact_states(scene, np.asarray(t) * time_scale)
    samples = np.concatenate([state["x"], state["q"], state["v"], state["w"]], axis=1)
    return Trajectory.from_samples(t, [scene.bodies[0].name], samples[:, None, :], META)


# A flip time is found by linear interpolation between samples 0.1 s apart; the flips are fast
# (about 0.3 s), so interpolating a sped-up motion moves each by ~1e-4 s of the ~3.4 s period.
FLIP_RTOL = 1e-3


def test_flip_period_against_the_exact_solution():
    scene = CATALOG["tumbling_box_long"] if "tumbling_box_long" in CATALOG else None
    scene = scene or dataclasses.replace(CATALOG["tumbling_box"], duration=100.0)
    t = np.arange(0.0, scene.duration + 1e-9, scene.sample_interval)
    exact = outcomes(exact_trajectory(scene, t), scene).set_index("quantity")
    period = exact.loc["flip_period", "expected"]
    assert exact.loc["flip_period", "measured"] == period  # same motion, same times
    assert period > 0
    faster = outcomes(exact_trajectory(scene, t, 1.01), scene).set_index("quantity")
    assert faster.loc["flip_period", "measured"] == pytest.approx(period / 1.01, rel=FLIP_RTOL)


def test_a_diverged_run_has_no_measured_outcomes():
    scene = floor_scene(Expected(rest_com_height=REST))
    x, v = along_z(np.array([REST, np.inf]), np.zeros(2))
    table = outcomes(trajectory(scene, [0.0, 1.0], x, v), scene)
    assert len(table) and table["measured"].isna().all() and table["error"].isna().all()


def test_what_is_measured_follows_what_the_scene_states():
    """No closed form, no contact: no rows. The measurements depend on the scene only."""
    scene = CATALOG["free_spin_cube"]  # isotropic: no intermediate axis, no flips
    traj = run(scene, "reference", "splitting", duration=0.1)
    assert outcomes(traj, scene).empty
    renamed = dataclasses.replace(CATALOG["dropped_cube"], name="my_case", tags=())
    rows = outcomes(run(renamed, "reference", "splitting", duration=0.1), renamed)
    assert set(rows["quantity"]) == {
        "rest_com_height",
        "creep",
        "jitter_rms",
        "penetration",
        "max_penetration",
    }


# ---- real runs ----------------------------------------------------------------------------------

# The reference's impulses leave a resting body on the surface to ~1e-10 m (README).
REST_HEIGHT_ATOL = 1e-9
# The gate for the reference simulator: its rebound ratio within 2 % of e.
REBOUND_RTOL = 0.02


def test_dropped_cube_on_the_reference_engine():
    scene = CATALOG["dropped_cube"]
    traj = run(scene, "reference", "splitting")
    assert verdict(traj, scene) == "ok"
    rows = outcomes(traj, scene).set_index("quantity")
    assert abs(rows.loc["rest_com_height", "error"]) < REST_HEIGHT_ATOL
    assert rows.loc["jitter_rms", "measured"] < JITTER_SPEED
    assert abs(rows.loc["penetration", "measured"]) < REST_HEIGHT_ATOL


def test_a_real_bounce_on_the_reference_engine():
    """The cube dropped flat from 1 m onto the floor with e = 0.5, dt 0.001: the measured
    ratio is e to the reference's accuracy, and each apex is h0 times the square of the
    measured ratios so far (both come from the same ballistic speeds)."""
    e, h0 = 0.5, 1.0
    scene = dataclasses.replace(
        floor_scene(Expected(rebound_ratio=e, rest_com_height=REST), contact=(e, 0.0)),
        bodies=(cube(REST + h0),),
        sample_interval=0.001,
    )
    traj = run(scene, "reference", "splitting")
    assert verdict(traj, scene) == "ok"
    assert measured(outcomes(traj, scene), "rebound_ratio") == pytest.approx(e, rel=REBOUND_RTOL)
    found = bounces(RunData(traj, scene), 0, scene.planes[0]).iloc[:3]
    rebound = found["rebound"].to_numpy()
    assert found["apex"].to_numpy() == pytest.approx(rebound**2 / (2 * G), rel=1e-6)
