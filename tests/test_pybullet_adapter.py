"""The PyBullet adapter: model parity, frames, exact free flight, contact mapping, isolation.

Adapter-specific checks only; the cross-engine accuracy gates live elsewhere.
"""

import dataclasses
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest

p = pytest.importorskip("pybullet")

from scenes import head_on  # noqa: E402

from cases import Body, Contact, Scene  # noqa: E402
from cases.builders import box_corners, floor, seed_cube_particles  # noqa: E402
from cases.catalog import CATALOG  # noqa: E402
from cases.exact import exact_states  # noqa: E402
from comparators import ENGINES, Trajectory, run  # noqa: E402
from comparators.metrics import body_arrays, conserved_quantities, rest  # noqa: E402
from comparators.outcomes import bounces  # noqa: E402
from comparators.pybullet_engine import (  # noqa: E402
    PybulletSettings,
    connect,
    run_pybullet,
)
from comparators.run_data import RunData  # noqa: E402
from rigidmath.inertia import principal_frame  # noqa: E402
from rigidmath.quaternion import (  # noqa: E402
    quat_to_matrix,
    quats_angle_between,
    quats_to_matrices,
)

INTEGRATORS = ENGINES["pybullet"].integrators

# Mass and inertia are doubles set from the scene's; PyBullet returns them rounded at ~1e-15.
INERTIA_RTOL = 1e-12
# Without damping a free body keeps its velocities to rounding (the multibody default, 0.04,
# loses 8 % per second).
FREE_VELOCITY_RTOL = 1e-12
# Isotropic inertia: omega is constant and both body types advance the orientation by the exact
# exponential map, so only rounding remains (measured 3e-15 to 4e-13 rad over 10 s).
FREE_SPIN_ATOL = 1e-9  # rad
# q(0) = q_in(0) q_in(0)^-1 is the identity up to the rounding of that product (~1e-17).
IDENTITY_ATOL = 1e-15
# A spin about a principal axis is steady: any frame mix-up would make it tumble at O(1) rad;
# measured 2e-14 rad over 2 s.
PRINCIPAL_SPIN_ATOL = 1e-12  # rad
# Generic rotated-box spin over 0.5 s: first order in dt, measured 2.5e-4 to 2.7e-4 rad and
# 3.3e-4 to 6.6e-4 rad/s at dt 1e-3 (ten times that at dt 1e-2); twice the measurement.
ROTATED_Q_ATOL = 5e-4  # rad
ROTATED_W_ATOL = 1.3e-3  # rad/s
# First-order convergence: the error ratio between dt 1e-3 and 1e-2 is 0.100 (measured).
FIRST_ORDER_RATIO = (0.08, 0.12)
# tumbling_box at dt 0.001: first-order gyroscopic update, measured 1.96 deg (maximal) and
# 1.97 deg (multibody); 19.4 and 19.9 deg at dt 0.01.
TUMBLING_DEG = 2.5
# The rest height the catalog asks for (half edge 0.5 + particle radius 0.2), measured 6e-8 off.
REST_HEIGHT_TOL = 0.005  # m
# Contact impulses are equal and opposite; what is left is rounding of metre-scale sums.
MOMENTUM_ATOL = 1e-12  # kg m/s
# One step of dt 0.01 from a generic spin: local error O(dt^2), measured 5.3e-5 rad; the inverse
# convention would be off by 2 |omega| dt = 0.047 rad.
ONE_STEP_ATOL = 2e-4  # rad
# A maximal body whose contact is found on overlap bounces at exactly e (split impulse): 1e-16.
REBOUND_ATOL = 1e-9
# A maximal body's contact found up to speculative_speed * dt early loses at most 0.01 m/s of its
# rebound: 0.009 of the ratio on the catalog bounce's slowest listed impact (1.1 m/s). Measured
# 0.0044 at most (dt 0.001) and 0.0002 (dt 1/16 of it).
BOUNCE_RATIO_ATOL = 0.01


def _rotated_box(angular_velocity, dt=0.001, duration=0.5) -> Scene:
    """box_corners (1 x 2 x 3) turned by a generic rotation: a non-diagonal inertia tensor."""
    c, s = np.cos, np.sin
    a, b, g = 0.4, -0.7, 1.1
    rx = np.array([[1, 0, 0], [0, c(a), -s(a)], [0, s(a), c(a)]])
    ry = np.array([[c(b), 0, s(b)], [0, 1, 0], [-s(b), 0, c(b)]])
    rz = np.array([[c(g), -s(g), 0], [s(g), c(g), 0], [0, 0, 1]])
    center = np.array([0.3, -0.2, 0.5])
    rows = np.array(box_corners((1.0, 2.0, 3.0)))
    rows[:, :3] = rows[:, :3] @ (rz @ ry @ rx).T + center
    return Scene(
        name="rotated_box",
        duration=duration,
        dt=dt,
        gravity=(0.0, 0.0, 0.0),
        bodies=(
            Body(
                name="box",
                particle_radius=0.2,
                particles=tuple(map(tuple, rows.tolist())),
                angular_velocity=tuple(float(w) for w in angular_velocity),
            ),
        ),
    )


def _orientation_error(traj: Trajectory, scene: Scene, name: str):
    a = body_arrays(traj, name)
    k = [b.name for b in scene.bodies].index(name)
    ex = exact_states(scene, a["t"])[k]
    angle = quats_angle_between(np.ascontiguousarray(a["q"]), np.ascontiguousarray(ex["q"]))
    return a, ex, angle


def test_engine_registered():
    engine = ENGINES["pybullet"]
    assert engine.missing is None
    assert engine.default_integrator == "maximal"
    assert set(engine.integrators) == {"maximal", "multibody"}


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("case", ["tumbling_box", "dropped_cube", "rotated"])
def test_inertia_read_back_is_the_scenes(case, integrator):
    """Mass and world inertia read back from PyBullet equal the particle tensor, not Bullet's
    bounding-box estimate of the sphere compound."""
    scene = _rotated_box((0.3, -1.2, 2.0)) if case == "rotated" else CATALOG[case]
    traj = run(scene, "pybullet", integrator, duration=scene.dt)
    for body in scene.bodies:
        got = traj.meta.bodies[body.name]
        assert got["mass"] == pytest.approx(body.mass, rel=INERTIA_RTOL)
        inertia = np.asarray(got["inertia"])
        scale = np.linalg.norm(body.inertia)
        assert np.linalg.norm(inertia - body.inertia) / scale < INERTIA_RTOL
        moments = traj.meta.settings["inertia"][body.name]["principal_moments"]
        np.testing.assert_allclose(moments, principal_frame(body.inertia)[0], rtol=INERTIA_RTOL)
    assert traj.meta.settings["linear_damping"] == traj.meta.settings["angular_damping"] == 0.0


def test_bounding_box_estimate_is_wrong_for_particles():
    """Why the adapter overrides the inertia: PyBullet's own estimate for the compound."""
    body = CATALOG["tumbling_box"].bodies[0]
    cid = connect()
    try:
        offsets = (body.positions - body.com).tolist()
        shape = p.createCollisionShapeArray(
            [p.GEOM_SPHERE] * 8,
            radii=[0.2] * 8,
            collisionFramePositions=offsets,
            physicsClientId=cid,
        )
        uid = p.createMultiBody(body.mass, shape, physicsClientId=cid)
        estimate = np.array(p.getDynamicsInfo(uid, -1, physicsClientId=cid)[2])
    finally:
        p.disconnect(cid)
    assert np.abs(estimate - np.diag(body.inertia)).max() > 0.1 * np.diag(body.inertia).max()


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_free_flight_without_damping(integrator):
    """A translating, spinning body keeps v and omega: linear and angular damping are 0."""
    scene = CATALOG["free_spin_cube"]
    moving = dataclasses.replace(scene.bodies[0], velocity=(0.5, -0.25, 1.0))
    scene = dataclasses.replace(scene, bodies=(moving,))
    a = body_arrays(run(scene, "pybullet", integrator), "cube")
    v0, w0 = np.array(moving.velocity), np.array(moving.angular_velocity)
    assert np.abs(a["v"] - v0).max() <= FREE_VELOCITY_RTOL * np.linalg.norm(v0)
    assert np.abs(a["w"] - w0).max() <= FREE_VELOCITY_RTOL * np.linalg.norm(w0)
    np.testing.assert_allclose(a["x"], moving.com + np.outer(a["t"], v0), atol=1e-12)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_free_spin_cube_is_exact(integrator):
    scene = CATALOG["free_spin_cube"]
    traj = run(scene, "pybullet", integrator)
    a, ex, angle = _orientation_error(traj, scene, "cube")
    assert angle.max() < FREE_SPIN_ATOL
    np.testing.assert_allclose(a["q"][0], [1, 0, 0, 0], atol=IDENTITY_ATOL)
    np.testing.assert_allclose(a["x"], ex["x"], atol=1e-12)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_tumbling_box_flips_like_exact(integrator):
    """dt 0.001: orientation within TUMBLING_DEG of exact, and the intermediate axis flips
    against L at the same samples as the exact motion (2.6 s and 9.4 s)."""
    scene = CATALOG["tumbling_box"]
    traj = run(scene, "pybullet", integrator, dt=0.001)
    a, ex, angle = _orientation_error(traj, scene, "box")
    assert np.degrees(angle.max()) < TUMBLING_DEG
    body = scene.bodies[0]
    moments, axes = principal_frame(body.inertia)
    middle = axes[:, 1]
    momentum = body.inertia @ np.array(body.angular_velocity)

    def flips(q):
        along = quats_to_matrices(np.ascontiguousarray(q)) @ middle @ momentum
        return a["t"][np.flatnonzero(np.diff(np.sign(along)))]

    exact_flips = flips(ex["q"])
    assert len(exact_flips) >= 2
    np.testing.assert_array_equal(flips(a["q"]), exact_flips)
    # The gyroscopic term's character: implicit (maximal) loses energy, explicit gains.
    energy = conserved_quantities(traj, scene)["energy"].to_numpy()
    sign = -1 if integrator == "maximal" else 1
    assert sign * (energy[-1] - energy[0]) > 0


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_rotated_box_frames(integrator):
    """Non-diagonal inertia: t = 0 state, a steady principal-axis spin, and a generic spin that
    converges to exact at first order."""
    probe = _rotated_box((1.0, 0.0, 0.0))
    moments, axes = principal_frame(probe.bodies[0].inertia)
    # Steady spin about the largest-moment axis, which is not a world axis here.
    scene = _rotated_box(2.5 * axes[:, 2], dt=0.01, duration=2.0)
    a, ex, angle = _orientation_error(run(scene, "pybullet", integrator), scene, "box")
    assert angle.max() < PRINCIPAL_SPIN_ATOL
    np.testing.assert_allclose(a["w"], ex["w"], atol=PRINCIPAL_SPIN_ATOL)

    errors = {}
    for dt in (0.01, 0.001):
        scene = _rotated_box((0.3, -1.2, 2.0), dt=dt)
        traj = run(scene, "pybullet", integrator)
        a, ex, angle = _orientation_error(traj, scene, "box")
        body = scene.bodies[0]
        np.testing.assert_allclose(a["q"][0], [1, 0, 0, 0], atol=IDENTITY_ATOL)
        np.testing.assert_array_equal(a["w"][0], body.angular_velocity)
        np.testing.assert_array_equal(traj.meta.bodies["box"]["w"], body.angular_velocity)
        np.testing.assert_allclose(a["x"][0], body.com, atol=1e-15)
        errors[dt] = angle.max()
        w_error = np.abs(a["w"] - ex["w"]).max()
    assert errors[0.001] < ROTATED_Q_ATOL
    assert w_error < ROTATED_W_ATOL  # at dt 0.001, the last in the loop
    lo, hi = FIRST_ORDER_RATIO
    assert lo < errors[0.001] / errors[0.01] < hi


def _contact_probe() -> int:
    """Contact points between a sphere 0.1 m above a plane and the plane, in a fresh client."""
    cid = connect()
    try:
        plane = p.createMultiBody(
            0, p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid), physicsClientId=cid
        )
        sphere = p.createMultiBody(
            1,
            p.createCollisionShape(p.GEOM_SPHERE, radius=0.2, physicsClientId=cid),
            basePosition=[0, 0, 0.3],
            physicsClientId=cid,
        )
        p.performCollisionDetection(physicsClientId=cid)
        return len(p.getContactPoints(sphere, plane, physicsClientId=cid))
    finally:
        p.disconnect(cid)


def _set_global_breaking_threshold(value: float) -> None:
    cid = connect()
    p.setPhysicsEngineParameter(contactBreakingThreshold=value, physicsClientId=cid)
    p.disconnect(cid)


def test_global_contact_breaking_threshold_does_not_leak(tmp_path):
    """contactBreakingThreshold survives disconnect (the probe proves it in this PyBullet); a run
    after someone changed it equals a run in a fresh process, bit for bit."""
    scene = CATALOG["dropped_cube"]
    duration = 1.5
    out = tmp_path / "fresh.parquet"
    code = textwrap.dedent(
        f"""
        from cases.catalog import CATALOG
        from comparators import run
        run(CATALOG["dropped_cube"], "pybullet", duration={duration}).write({str(out)!r})
        """
    )
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)
    fresh = Trajectory.read(out).table
    try:
        _set_global_breaking_threshold(0.5)
        assert _contact_probe() == 1  # the leak is real: 0.1 m gap < 0.5 m threshold
        after_leak = run(scene, "pybullet", duration=duration).table
        assert _contact_probe() == 0  # the run set its own threshold (1e-4 m at dt 0.01)
    finally:
        _set_global_breaking_threshold(0.02)  # Bullet's default, for whoever runs next
    pd.testing.assert_frame_equal(after_leak, fresh, check_exact=True)
    # The comparison is sensitive: the threshold does change this run.
    wide = PybulletSettings(speculative_speed=0.5 / scene.dt)  # a 0.5 m threshold
    table = run_pybullet(scene, "maximal", scene.dt, duration, wide).table
    assert not table[["x", "y", "z"]].equals(fresh[["x", "y", "z"]])


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_dropped_cube_rests_on_a_face(integrator):
    scene = CATALOG["dropped_cube"]
    traj = run(scene, "pybullet", integrator, dt=0.01)
    r = rest(traj, scene, "cube")
    assert r["at_rest"]
    assert abs(r["com_height"] - scene.expected.rest_com_height) < REST_HEIGHT_TOL


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("restitution", [0.0, 0.5, 1.0])
def test_head_on_conserves_momentum(integrator, restitution):
    scene = head_on(restitution)
    traj = run(scene, "pybullet", integrator)
    c = conserved_quantities(traj, scene)
    np.testing.assert_allclose(c[["px", "py", "pz"]].to_numpy(), 0.0, atol=MOMENTUM_ATOL)
    va = body_arrays(traj, "a")["v"][-1]
    assert va[0] < 0 or restitution == 0.0  # they did collide
    if integrator == "maximal":  # body-body restitution is sqrt(e) * sqrt(e) = e
        np.testing.assert_allclose(va, (-restitution, 0, 0), atol=REBOUND_ATOL)


@pytest.mark.parametrize("restitution", [0.25, 1.0])
def test_plane_rebound_is_e(restitution):
    """Body-plane restitution sqrt(e) * sqrt(e) = e, with no speculative loss (maximal)."""
    scene = Scene(
        name="rebound",
        duration=1.0,
        dt=0.01,
        gravity=(0.0, 0.0, 0.0),
        contact=Contact(restitution=restitution, friction=0.0),
        planes=(floor(0.0),),
        bodies=(
            Body(
                name="c",
                particle_radius=0.2,
                particles=seed_cube_particles(offset=(-0.5, -0.5, 1.0)),
                velocity=(0.0, 0.0, -3.0),
            ),
        ),
    )
    v = body_arrays(run(scene, "pybullet", "maximal"), "c")["v"][-1]
    np.testing.assert_allclose(v, (0, 0, 3.0 * restitution), atol=REBOUND_ATOL)


@pytest.mark.parametrize("dt_factor", [1.0, 1 / 16])
def test_every_bounce_rebounds_at_e(dt_factor):
    """The catalog's bounce, maximal, at its dt and 16 times smaller: every impact rebounds at e.
    With a 1 mm speculative margin the second of them did not rebound at all (dt 0.001), nor
    any at dt 1/16 of it: found before touching, the bounce was aimed at e v - gap / dt."""
    scene = CATALOG["bounce"]
    traj = run(scene, "pybullet", "maximal", dt=scene.dt * dt_factor)
    impacts = bounces(RunData(traj, scene), 0, scene.planes[0])
    listed = impacts.iloc[: len(scene.expected.apex_heights)]
    assert len(listed) == len(scene.expected.apex_heights)
    np.testing.assert_allclose(listed["ratio"], scene.contact.restitution, atol=BOUNCE_RATIO_ATOL)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_without_contact_bodies_pass_through(integrator):
    """No contact in the scene: collision filtered out, the cubes fly through each other."""
    scene = head_on(1.0, contact=False)
    traj = run(scene, "pybullet", integrator)
    assert traj.meta.settings["contact"].startswith("none")
    for name, vx in (("a", 1.0), ("b", -1.0)):
        np.testing.assert_array_equal(body_arrays(traj, name)["v"][-1], (vx, 0, 0))


def test_quaternion_convention_at_t0():
    """PyBullet reports the principal (inertial) frame; the adapter maps it to identity."""
    scene = _rotated_box((0.3, -1.2, 2.0), dt=0.01, duration=0.01)
    traj = run(scene, "pybullet", "maximal")
    frame = np.array(traj.meta.settings["inertia"]["box"]["principal_frame_wxyz"])
    moments, axes = principal_frame(scene.bodies[0].inertia)
    np.testing.assert_allclose(quat_to_matrix(frame), axes, atol=1e-15)
    assert not np.allclose(np.abs(frame), [1, 0, 0, 0])  # the trap: it is not identity
    # q maps the t = 0 placement to the current one (not its inverse): one step against exact.
    a, ex, angle = _orientation_error(traj, scene, "box")
    assert angle[1] < ONE_STEP_ATOL
