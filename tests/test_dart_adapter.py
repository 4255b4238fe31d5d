"""The DART adapter: model parity, frames, exact free flight, contact mapping, sleeping, NaN.

Adapter-specific checks only; the cross-engine accuracy gates live elsewhere. Every tolerance
says what was measured (dartpy 6.20.0, docs/engines/dart.md).
"""

import dataclasses
import math

import numpy as np
import pytest

pytest.importorskip("dartpy")

from scenes import TILTED_CLUSTER, head_on  # noqa: E402

import comparators.dart_engine as de  # noqa: E402
from cases import Body, Contact, Scene  # noqa: E402
from cases.builders import floor, seed_cube_particles  # noqa: E402
from cases.catalog import CATALOG  # noqa: E402
from cases.exact import exact_states  # noqa: E402
from comparators import ENGINES, run  # noqa: E402
from comparators.metrics import body_arrays, conserved_quantities  # noqa: E402
from rigidmath.inertia import principal_frame  # noqa: E402
from rigidmath.quaternion import (  # noqa: E402
    quat_to_matrix,
    quats_angle_between,
)

INTEGRATORS = ENGINES["dart"].integrators

# Mass and tensor are doubles handed to DART and read back through one rotation by the identity:
# measured 3.5e-17 relative.
READBACK_RTOL = 1e-14
# The joint state against the body node's world transform and spatial velocity: the same
# doubles through DART's exponential map and ours (measured 4.4e-16).
FRAME_ATOL = 1e-14
# A spin about a principal axis is steady; any body/world frame mix-up in omega would tumble the
# body at O(1) rad. Measured 7e-15 rad (orientation) and 5e-15 rad/s over 2 s at dt 0.01.
PRINCIPAL_SPIN_ATOL = 1e-12
# A generic spin of the tilted cluster over 0.5 s at dt 0.001: first order in dt, measured
# 1.30e-4 rad and 4.61e-4 rad/s (ten times that at dt 0.01); about twice the measurement.
ROTATED_Q_ATOL = 2.5e-4  # rad
ROTATED_W_ATOL = 1e-3  # rad/s
# First order: the error ratio between dt 0.001 and 0.01 measured 0.0999.
FIRST_ORDER_RATIO = (0.08, 0.12)
# Free flight: the COM follows semi-implicit Euler's closed form x0 + v0 t + g t (t + dt) / 2 and
# v0 + g t; measured 3e-14 m and 6e-14 m/s over 2 s (metre-scale sums).
BALLISTIC_ATOL = 1e-12
# Without damping a free body keeps its linear velocity to rounding (measured 1e-16 m/s).
FREE_VELOCITY_ATOL = 1e-14
# Rebound off a plane at 3 m/s, no gravity: DART's target e v_in less what its CFM (1e-5 on the
# LCP diagonal) leaks: measured e - v_out / v_in up to 1.0e-5 (dantzig) and 6.7e-5 (pgs).
REBOUND_ATOL = 1e-4
# A flat fall onto a frictionless plane gets no lateral impulse: measured 7e-21 m/s sideways.
LATERAL_ATOL = 1e-12  # m/s
# e = 0: the body leaves the plane at DART's maximum error-reduction velocity, 1e-3 m/s, while
# the impact's penetration is pushed out (measured 1.000e-3 dantzig, 1.058e-3 pgs).
INELASTIC_SEPARATION = 1.1e-3  # m/s
# Contact impulses are equal and opposite: momentum is conserved to rounding (measured 4e-19).
MOMENTUM_ATOL = 1e-12  # kg m/s
# A slow creep on a frictionless floor (5e-4 m/s, below DART's sleep gate of 10 % of its 0.01 m/s
# threshold) over 2 s at dt 0.001: with sleeping off it covers v t (measured to 1e-13 m); with
# DART's default it is frozen after 0.5 s (measured 2.5e-4 m of the 1e-3 m).
CREEP_ATOL = 1e-9  # m


def _free_scene(body, dt=0.001, duration=0.5, gravity=(0.0, 0.0, 0.0)) -> Scene:
    return Scene(
        name="free",
        duration=duration,
        dt=dt,
        sample_interval=0.01,
        gravity=gravity,
        bodies=(body,),
    )


def _orientation_error(traj, scene, name):
    a = body_arrays(traj, name)
    exact = exact_states(scene, a["t"])[0]
    angle = quats_angle_between(np.ascontiguousarray(a["q"]), np.ascontiguousarray(exact["q"]))
    return a, exact, angle


def _plane_scene(restitution, speed, gap=1.0, friction=0.0, duration=1.0) -> Scene:
    """The seed cube `gap` m above the floor falling at `speed` m/s, no gravity."""
    return Scene(
        name="rebound",
        duration=duration,
        dt=0.01,
        gravity=(0.0, 0.0, 0.0),
        contact=Contact(restitution=restitution, friction=friction),
        planes=(floor(0.0),),
        bodies=(
            Body(
                name="c",
                particle_radius=0.2,
                particles=seed_cube_particles(offset=(-0.5, -0.5, 0.2 + gap)),
                velocity=(0.0, 0.0, -speed),
            ),
        ),
    )


def test_engine_registered():
    engine = ENGINES["dart"]
    assert engine.missing is None
    assert engine.default_integrator == "dantzig"
    assert set(engine.integrators) == {"dantzig", "pgs"}
    assert engine.orders == {"dantzig": 1, "pgs": 1}


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_readback_of_a_rotated_asymmetric_body(integrator):
    """Mass and full tensor as the body node holds them after its shapes were added (shapes add
    no inertia), the COM and the world-frame velocities set through the body-frame FreeJoint."""
    scene = _free_scene(TILTED_CLUSTER)
    world, nodes, _ = de.build_world(scene, integrator, scene.dt)
    node, body = nodes[0], TILTED_CLUSTER
    assert node.getNumShapeNodes() == len(body.particles)
    inertia = node.getInertia()
    assert inertia.getMass() == body.mass
    scale = np.linalg.norm(body.inertia)
    assert np.linalg.norm(inertia.getMoment() - body.inertia) <= READBACK_RTOL * scale
    np.testing.assert_array_equal(inertia.getLocalCOM(), 0.0)  # body frame at the COM
    traj = run(scene, "dart", integrator)  # comparators.run checks parity to 1e-9
    got = traj.meta.bodies["cluster"]
    assert np.linalg.norm(np.array(got["inertia"]) - body.inertia) <= READBACK_RTOL * scale
    np.testing.assert_allclose(got["w"], body.angular_velocity, rtol=0, atol=1e-15)
    np.testing.assert_allclose(got["v"], body.velocity, rtol=0, atol=1e-15)
    a = body_arrays(traj, "cluster")
    np.testing.assert_array_equal(a["q"][0], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(a["x"][0], body.com, rtol=0, atol=1e-15)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_generic_spin_follows_the_exact_world_omega_at_first_order(integrator):
    """A body-frame omega reported as world-frame would differ by O(1) rad/s at once."""
    errors = {}
    for dt in (0.01, 0.001):
        scene = _free_scene(TILTED_CLUSTER, dt=dt)
        a, exact, angle = _orientation_error(run(scene, "dart", integrator), scene, "cluster")
        errors[dt] = angle.max()
        w_error = np.abs(a["w"] - exact["w"]).max()
        np.testing.assert_allclose(a["v"], exact["v"], rtol=0, atol=FREE_VELOCITY_ATOL)
    assert errors[0.001] < ROTATED_Q_ATOL
    assert w_error < ROTATED_W_ATOL  # dt 0.001, the last in the loop
    lo, hi = FIRST_ORDER_RATIO
    assert lo < errors[0.001] / errors[0.01] < hi


@pytest.mark.parametrize("axis", [0, 2], ids=["smallest", "largest"])
def test_spin_about_a_principal_axis_stays_steady(axis):
    """The principal axes of the tilted cluster are not world axes: a steady spin checks the
    tensor's orientation and the frames of omega together."""
    moments, axes = principal_frame(TILTED_CLUSTER.inertia)
    body = dataclasses.replace(
        TILTED_CLUSTER, velocity=(0.0, 0.0, 0.0), angular_velocity=tuple(2.5 * axes[:, axis])
    )
    scene = _free_scene(body, dt=0.01, duration=2.0)
    a, exact, angle = _orientation_error(run(scene, "dart"), scene, "cluster")
    assert angle.max() < PRINCIPAL_SPIN_ATOL
    np.testing.assert_allclose(a["w"], exact["w"], rtol=0, atol=PRINCIPAL_SPIN_ATOL)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_ballistic_flight_is_semi_implicit_euler_exactly(integrator):
    """Under gravity the COM follows the scheme's own closed form, g t dt / 2 off the exact
    parabola (0.1 m after 2 s at dt 0.01: the test would see a different scheme)."""
    dt = 0.01
    scene = _free_scene(TILTED_CLUSTER, dt=dt, duration=2.0, gravity=(0.0, 0.0, -10.0))
    a = body_arrays(run(scene, "dart", integrator), "cluster")
    t, g = a["t"], np.array(scene.gravity)
    v0 = np.array(TILTED_CLUSTER.velocity)
    x = TILTED_CLUSTER.com + np.outer(t, v0) + 0.5 * np.outer(t * (t + dt), g)
    np.testing.assert_allclose(a["x"], x, rtol=0, atol=BALLISTIC_ATOL)
    np.testing.assert_allclose(a["v"], v0 + np.outer(t, g), rtol=0, atol=BALLISTIC_ATOL)


def test_contact_free_scenes_have_no_collision_shapes():
    scene = CATALOG["tumbling_box"]
    world, nodes, _ = de.build_world(scene, "dantzig", scene.dt)
    assert world.getNumSkeletons() == len(scene.bodies)  # no plane
    shapes = [node.getShapeNode(k) for node in nodes for k in range(node.getNumShapeNodes())]
    assert len(shapes) == sum(len(b.particles) for b in scene.bodies)
    assert not any(s.hasCollisionAspect() or s.hasDynamicsAspect() for s in shapes)
    assert not any(node.getGravityMode() for node in nodes)  # zero gravity: gravity off
    assert run(scene, "dart").meta.settings["contact"].startswith("none")


def test_contact_shapes_carry_sqrt_e_and_mu():
    """DART multiplies the two shapes' restitution and takes the smaller friction."""
    scene = CATALOG["dropped_cube"]
    e, mu = scene.contact.restitution, scene.contact.friction
    world, nodes, _ = de.build_world(scene, "dantzig", scene.dt)
    assert world.getNumSkeletons() == len(scene.bodies) + len(scene.planes)
    plane = world.getSkeleton(len(scene.bodies))
    assert not plane.isMobile()
    shapes = [node.getShapeNode(k) for node in nodes for k in range(node.getNumShapeNodes())]
    shapes.append(plane.getBodyNode(0).getShapeNode(0))
    for shape in shapes:
        assert shape.hasCollisionAspect()
        dynamics = shape.getDynamicsAspect()
        assert dynamics.getRestitutionCoeff() == math.sqrt(e)
        assert dynamics.getFrictionCoeff() == mu
    assert nodes[0].getGravityMode()


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_contact_free_bodies_pass_through_each_other(integrator):
    traj = run(head_on(1.0, contact=False), "dart", integrator)
    for name, vx in (("a", 1.0), ("b", -1.0)):
        np.testing.assert_array_equal(body_arrays(traj, name)["v"][-1], (vx, 0.0, 0.0))


def _creep(dt=0.001) -> Scene:
    """The seed cube resting on a frictionless floor, creeping along x at 5e-4 m/s."""
    return Scene(
        name="creep",
        duration=2.0,
        dt=dt,
        sample_interval=0.1,
        gravity=(0.0, 0.0, -10.0),
        contact=Contact(restitution=0.0, friction=0.0),
        planes=(floor(0.0),),
        bodies=(
            Body(
                name="c",
                particle_radius=0.2,
                particles=seed_cube_particles(offset=(0.0, 0.0, 0.2)),
                velocity=(5e-4, 0.0, 0.0),
            ),
        ),
    )


def test_sleeping_is_off_so_a_resting_body_keeps_moving():
    scene = _creep()
    traj = run(scene, "dart")
    assert traj.meta.settings["sleeping"] == "off"
    a = body_arrays(traj, "c")
    np.testing.assert_allclose(a["x"][:, 0] - a["x"][0, 0], 5e-4 * a["t"], rtol=0, atol=CREEP_ATOL)
    # The check can fail: DART's default freezes the creeping cube.
    asleep = body_arrays(de.run_dart(scene, "dantzig", scene.dt, 2.0, sleeping=True), "c")
    assert asleep["v"][-1, 0] == 0.0
    assert asleep["x"][-1, 0] - asleep["x"][0, 0] < 0.5 * 5e-4 * 2.0


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("restitution", [0.25, 0.5, 1.0])
def test_plane_rebound_is_e(integrator, restitution):
    """sqrt(e) per shape, multiplied: a cube falling flat at 3 m/s leaves at e times that."""
    scene = _plane_scene(restitution, 3.0)
    v = body_arrays(run(scene, "dart", integrator), "c")["v"][-1]
    assert v[2] / 3.0 == pytest.approx(restitution, abs=REBOUND_ATOL)
    np.testing.assert_allclose(v[:2], 0.0, atol=LATERAL_ATOL)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_inelastic_impact_leaves_at_the_error_reduction_velocity(integrator):
    v = body_arrays(run(_plane_scene(0.0, 3.0), "dart", integrator), "c")["v"][-1]
    assert 0.0 < v[2] < INELASTIC_SEPARATION


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_no_bounce_below_dart_bouncing_threshold(integrator):
    """DART bounces only when e v_in exceeds 0.1 m/s: at e = 0.5, 0.3 m/s bounces at e and
    0.19 m/s (e v_in = 0.095) does not (measured v_out 7e-4 m/s: error reduction only)."""
    fast = _plane_scene(0.5, 0.3, gap=0.005, duration=0.5)
    v = body_arrays(run(fast, "dart", integrator), "c")["v"][-1, 2]
    assert v / 0.3 == pytest.approx(0.5, abs=REBOUND_ATOL)
    slow = _plane_scene(0.5, 0.19, gap=0.005, duration=0.5)
    v = body_arrays(run(slow, "dart", integrator), "c")["v"][-1, 2]
    assert 0.0 < v < INELASTIC_SEPARATION


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("restitution", [0.0, 0.5, 1.0])
def test_head_on_conserves_momentum(integrator, restitution):
    scene = head_on(restitution)
    traj = run(scene, "dart", integrator)
    p = conserved_quantities(traj, scene)[["px", "py", "pz"]].to_numpy()
    assert np.abs(p).max() < MOMENTUM_ATOL
    va = body_arrays(traj, "a")["v"][-1]
    np.testing.assert_allclose(va, (-restitution, 0.0, 0.0), atol=REBOUND_ATOL)


def test_divergence_gives_nan_samples_not_an_exception():
    """high_spin at dt 0.01 (|omega| dt = 0.5 rad): DART's explicit gyroscopic term blows up
    within a second; the samples from there on are NaN and the earlier ones finite."""
    traj = run(CATALOG["high_spin"], "dart", duration=2.0)
    a = body_arrays(traj, "box")
    finite = np.isfinite(a["q"]).all(axis=1)
    assert finite[0] and not finite[-1]
    first_bad = int(np.argmin(finite))
    assert not np.isfinite(a["w"][first_bad:]).any()
    assert np.isfinite(a["w"][:first_bad]).all()


def test_runaway_values_are_blanked_too():
    raw = np.zeros((4, 1, 12))
    raw[2, 0, 6] = 1e12  # past MAX_VALUE, still finite
    samples = de.samples_from_raw(raw)
    assert np.isfinite(samples[:2]).all() and np.isnan(samples[2:]).all()


def test_joint_state_is_the_body_nodes_world_pose_and_velocity():
    """The samples come from the FreeJoint's positions (rotation vector, x) and velocities,
    which in dartpy 6.20 are world-frame omega and COM v; checked at a generic tumbling state
    against the body node's world transform and spatial velocity (world frame)."""
    scene = _free_scene(TILTED_CLUSTER, dt=0.01, duration=1.0)
    world, nodes, _ = de.build_world(scene, "dantzig", scene.dt)
    for _ in range(137):  # the rotation vector is 3.13 rad long here: far from identity
        world.step()
    node, world_frame = nodes[0], de.dart.dynamics.Frame.World()
    sample = de.samples_from_raw(de.read_state([node.getParentJoint()])[None])[0, 0]
    pose = node.getWorldTransform()
    np.testing.assert_allclose(sample[0:3], pose.translation(), rtol=0, atol=FRAME_ATOL)
    rotation = quat_to_matrix(sample[3:7])
    np.testing.assert_allclose(rotation, pose.rotation(), rtol=0, atol=FRAME_ATOL)
    velocity = node.getSpatialVelocity(world_frame, world_frame)  # omega, v at the COM
    np.testing.assert_allclose(sample[10:13], velocity[:3], rtol=0, atol=FRAME_ATOL)
    np.testing.assert_allclose(sample[7:10], velocity[3:], rtol=0, atol=FRAME_ATOL)
    # not the body-frame velocity, which differs by O(1) here
    assert np.abs(node.getSpatialVelocity()[:3] - velocity[:3]).max() > 0.1


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_solver_is_the_one_named_with_a_fallback(integrator):
    traj = run(CATALOG["dropped_cube"], "dart", integrator)
    s = traj.meta.settings
    assert (s["boxed_lcp_solver"], s["fallback_lcp_solver"]) == de.SOLVERS[integrator]
    assert s["split_impulse"] is False and s["matrix_free_contact_solver"] is False
    assert s["contact"]["collision_detector"] == "FCLCollisionDetector"
    assert traj.meta.solver == {"at_limit": 0}
    assert "dartpy" in traj.meta.versions


def test_pgs_without_a_fallback_zeroes_impulses_and_is_counted(capfd):
    """Why "pgs" keeps DART's second PGS as fallback: PGS alone fails a few solves on
    dropped_cube at dt 0.01 (measured 4, at 2.16 s, 2.52 s, 3.52 s, 4.52 s), DART then zeroes
    that step's contact impulses and the resting cube drops by g dt^2 = 1 mm each time. The
    adapter counts those messages (`at_limit`) instead of printing them."""
    scene = CATALOG["dropped_cube"]
    world, nodes, _ = de.build_world(scene, "pgs", scene.dt)
    world.getConstraintSolver().setSecondaryBoxedLcpSolver(None)
    messages = []
    with de._stderr_captured(messages):
        for _ in range(scene.steps(scene.dt)):
            world.step()
    assert de._solver_report(messages)["at_limit"] > 0
    assert de.LCP_FAILURE not in capfd.readouterr().err
    rest_height = scene.expected.rest_com_height
    assert nodes[0].getWorldTransform().translation()[2] < rest_height - 1e-3
