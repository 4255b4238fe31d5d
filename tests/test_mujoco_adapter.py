"""The MuJoCo adapter: its model is the scene, its frames are the suite's, its stepping is exact.

Adapter-specific checks only; the cross-engine gates live in tests/test_engines.py.
"""

import dataclasses
import math

import numpy as np
import pytest
from scenes import TILTED_CLUSTER, head_on, rotated

from cases import CATALOG, Body, Contact, InputError, Scene
from cases.builders import box_lattice
from cases.exact import exact_states
from comparators import mujoco_engine as mj
from comparators import run
from comparators.metrics import body_arrays, conserved_quantities, pose_errors, rest
from rigidmath.quaternion import quat_to_matrix

mujoco = pytest.importorskip(
    "mujoco", reason="the mujoco package is not installed: the MuJoCo adapter cannot run"
)

# Mass and inertia pass through MJCF text at 17 digits and one 3 x 3 eigen-decomposition:
# rounding (~1e-15 relative) and nothing else.
READBACK_RTOL = 1e-12
# Isotropic inertia spins at constant omega and MuJoCo rotates the quaternion by exact
# rotations, so over 1000 steps only rounding remains (measured 6e-13 deg = 1e-14 rad); free
# flight too (one rounding per step: 7e-14 m after 2000 steps).
FREE_SPIN_ATOL = 1e-9
# The gate for RK4 at dt = 0.001 over tumbling_box's 10 s (measured 1.2e-10 deg).
TUMBLING_RK4_DEG = 1e-6
# World omega of an asymmetric body over 2 s of RK4 at dt 0.001: fourth-order truncation,
# measured 3e-14 to 2.5e-13 relative; reporting body-frame omega is off by O(1) (0.9 relative).
OMEGA_RTOL = 1e-8
# At t = 0 the body frame is the world frame: omega passes through qvel unchanged.
OMEGA0_ATOL = 1e-15
# The rest gate: the COM within 5 mm of its resting height (measured 1e-5 m).
REST_HEIGHT_TOL = 0.005
# Contact forces are equal and opposite; only rounding of the two bodies' updates remains
# (measured 1e-13 kg m/s against 8 kg m/s per body).
MOMENTUM_ATOL = 1e-11
# The post-impact speeds of two equal bodies are mirror images up to rounding.
SYMMETRY_ATOL = 1e-12
# The e -> zeta inversion and the frequency it encodes are closed forms: rounding only.
MAPPING_RTOL = 1e-12
# The same state seen through two MuJoCo code paths (qpos/qvel against xipos and
# mj_objectVelocity): a few roundings of O(1) numbers.
FRAME_ATOL = 1e-14


def _free_scene(name, body, duration=2.0, dt=0.001) -> Scene:
    return Scene(
        name=name,
        duration=duration,
        dt=dt,
        sample_interval=0.1,
        gravity=(0.0, 0.0, 0.0),
        bodies=(body,),
    )


# A tilted plate (planar: C = A + B exactly); TILTED_CLUSTER (tests/scenes.py) beside it.
TILTED_PLATE = Body(
    name="plate",
    particle_radius=0.1,
    particles=rotated(box_lattice((1.0, 2.0, 0.0), (2, 3, 1)), (0.3, 0.5, 0.7)),
    angular_velocity=(0.5, 1.0, 2.0),
)
READBACK_SCENES = [
    *(CATALOG[name] for name in ("seed_cube", "tumbling_box", "dropped_cube")),
    _free_scene("plate", TILTED_PLATE),
    _free_scene("cluster", TILTED_CLUSTER),
]


@pytest.mark.parametrize("scene", READBACK_SCENES, ids=lambda s: s.name)
def test_model_mass_and_inertia_read_back_equal_the_scene(scene):
    """The compiled model's bodies carry the particle mass and tensor: the geoms add none."""
    model, _ = mj.build(scene, "RK4", scene.dt)
    for k, body in enumerate(scene.bodies):
        b = k + 1
        assert model.body_mass[b] == pytest.approx(body.mass, rel=READBACK_RTOL)
        axes = quat_to_matrix(model.body_iquat[b].copy())
        inertia = axes @ np.diag(model.body_inertia[b]) @ axes.T
        scale = np.linalg.norm(body.inertia)
        assert np.linalg.norm(inertia - body.inertia) <= READBACK_RTOL * scale, body.name
        # body frame at the COM with identity orientation; the COM is the inertial frame origin
        np.testing.assert_array_equal(model.body_pos[b], body.com)
        np.testing.assert_array_equal(model.body_quat[b], (1.0, 0.0, 0.0, 0.0))
        np.testing.assert_array_equal(model.body_ipos[b], 0.0)
    assert model.nbody == len(scene.bodies) + 1
    assert model.ngeom == sum(len(b.particles) for b in scene.bodies) + (
        len(scene.planes) if scene.has_contact else 0
    )
    # nothing beyond the scene: no joint damping, armature, friction loss, fluid
    for field in ("dof_damping", "dof_armature", "dof_frictionloss", "jnt_stiffness"):
        np.testing.assert_array_equal(getattr(model, field), 0.0, err_msg=field)
    assert model.opt.density == 0.0 and model.opt.viscosity == 0.0


def test_planar_clusters_compile_and_read_back():
    """Planar clusters have C = A + B exactly; eigh rounds about a third of them to C > A + B,
    which MuJoCo's compiler rejects unless the adapter restores the equality."""
    rng = np.random.default_rng(7)
    for k in range(24):
        n = int(rng.integers(3, 7))
        axes = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        points = np.column_stack([rng.normal(size=(n, 2)), np.zeros(n)]) @ axes.T
        masses = rng.uniform(0.5, 2.0, n)
        rows = tuple((*p, m) for p, m in zip(points.tolist(), masses.tolist(), strict=True))
        body = Body(name=f"planar{k}", particle_radius=0.1, particles=rows)
        moments, _ = mj.principal_inertia(body.inertia)
        assert moments[2] <= moments[0] + moments[1]
        model, _ = mj.build(_free_scene(body.name, body), "Euler", 0.01)
        axes_b = quat_to_matrix(model.body_iquat[1].copy())
        inertia = axes_b @ np.diag(model.body_inertia[1]) @ axes_b.T
        assert np.linalg.norm(inertia - body.inertia) <= READBACK_RTOL * np.linalg.norm(
            body.inertia
        )


def test_only_what_the_scene_needs_is_switched_on():
    disabled = mujoco.mjtDisableBit
    free, _ = mj.build(CATALOG["tumbling_box"], "RK4", 0.01)
    assert free.opt.disableflags & disabled.mjDSBL_CONTACT
    assert free.opt.disableflags & disabled.mjDSBL_GRAVITY
    np.testing.assert_array_equal(free.opt.gravity, 0.0)
    assert not (free.geom_type == mujoco.mjtGeom.mjGEOM_PLANE).any()
    dropped, _ = mj.build(CATALOG["dropped_cube"], "RK4", 0.01)
    assert not dropped.opt.disableflags & (disabled.mjDSBL_CONTACT | disabled.mjDSBL_GRAVITY)
    np.testing.assert_array_equal(dropped.opt.gravity, CATALOG["dropped_cube"].gravity)
    assert (dropped.geom_type == mujoco.mjtGeom.mjGEOM_PLANE).sum() == 1
    two, _ = mj.build(head_on(0.5), "RK4", 0.01)  # contact without planes: body-body only
    assert not two.opt.disableflags & disabled.mjDSBL_CONTACT
    assert (two.geom_contype & two.geom_conaffinity).all()
    for model in (free, dropped, two):  # a divergence must show, not restart from qpos0
        assert model.opt.disableflags & disabled.mjDSBL_AUTORESET


def test_contact_parameters_map_restitution_and_friction():
    dt = 0.01
    for e in (0.1, 0.5, 0.9):
        p = mj.contact_parameters(Contact(restitution=e, friction=0.5), dt)
        timeconst, zeta = p["solref"]
        restitution = math.exp(-math.pi * zeta / math.sqrt(1 - zeta**2))
        assert restitution == pytest.approx(e, rel=MAPPING_RTOL)
        assert timeconst >= 2 * dt  # MuJoCo's refsafe floor: never silently clamped
        assert 1 / (timeconst * zeta) == pytest.approx(p["natural_frequency"], rel=MAPPING_RTOL)
        assert p["condim"] == 3 and p["friction"] == (0.5, 0.0, 0.0)
    inelastic = mj.contact_parameters(Contact(restitution=0.0, friction=0.0), dt)
    assert inelastic["solref"] == (2 * dt, 1.0) and inelastic["condim"] == 1
    elastic = mj.contact_parameters(Contact(restitution=1.0, friction=0.0), dt)
    assert elastic["solref"] == (-(elastic["natural_frequency"] ** 2), 0.0)  # direct, undamped
    model, _ = mj.build(CATALOG["dropped_cube"], "Euler", dt)
    np.testing.assert_array_equal(model.geom_solref, [[2 * dt, 1.0]] * model.ngeom)
    np.testing.assert_array_equal(model.geom_friction, [[0.5, 0.0, 0.0]] * model.ngeom)
    assert model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC


@pytest.mark.parametrize("integrator", mj.INTEGRATORS)
def test_free_spin_cube_is_exact(integrator):
    scene = CATALOG["free_spin_cube"]
    traj = run(scene, "mujoco", integrator)
    times = body_arrays(traj, "cube")["t"]
    errors = pose_errors(traj, exact_states(scene, times), scene)
    assert errors["position_error"].max() < FREE_SPIN_ATOL
    assert np.radians(errors["orientation_error_deg"].max()) < FREE_SPIN_ATOL


def test_tumbling_box_rk4_tracks_the_exact_flip():
    scene = CATALOG["tumbling_box"]
    traj = run(scene, "mujoco", "RK4", dt=0.001)
    times = body_arrays(traj, "box")["t"]
    worst = pose_errors(traj, exact_states(scene, times), scene)["orientation_error_deg"].max()
    assert worst < TUMBLING_RK4_DEG, f"tumbling_box RK4 dt 0.001: {worst:.3g} deg"


@pytest.mark.parametrize("body", [TILTED_CLUSTER, TILTED_PLATE], ids=lambda b: b.name)
def test_angular_velocity_is_reported_in_world_axes(body):
    """A body spinning about a tilted axis: omega is exact at t = 0 and follows the exact
    world-frame omega later, where the body-frame one would differ by O(1)."""
    scene = _free_scene(body.name, body)
    traj = run(scene, "mujoco", "RK4")
    a = body_arrays(traj, body.name)
    exact = exact_states(scene, a["t"])[0]
    np.testing.assert_allclose(a["w"][0], body.angular_velocity, rtol=0, atol=OMEGA0_ATOL)
    scale = np.linalg.norm(body.angular_velocity)
    assert np.abs(a["w"] - exact["w"]).max() < OMEGA_RTOL * scale
    np.testing.assert_allclose(a["v"], exact["v"], rtol=0, atol=FRAME_ATOL)
    np.testing.assert_allclose(a["x"], exact["x"], rtol=0, atol=FREE_SPIN_ATOL)


def test_free_joint_state_is_the_com_state():
    """After stepping, qpos[0:3] is MuJoCo's own COM (xipos), qvel[0:3] the COM velocity and
    R(q) qvel[3:6] the world angular velocity, as mj_objectVelocity computes them."""
    scene = _free_scene("cluster", TILTED_CLUSTER)
    model, data = mj.build(scene, "RK4", 0.001)
    for _ in range(500):
        mujoco.mj_step(model, data)
    mujoco.mj_forward(model, data)
    velocity = np.empty(6)
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, 1, velocity, 0)
    np.testing.assert_allclose(data.qpos[:3], data.xipos[1], rtol=0, atol=FRAME_ATOL)
    np.testing.assert_allclose(data.qvel[:3], velocity[3:], rtol=0, atol=FRAME_ATOL)
    world = quat_to_matrix(data.qpos[3:7].copy()) @ data.qvel[3:6]
    np.testing.assert_allclose(world, velocity[:3], rtol=0, atol=FRAME_ATOL)


@pytest.mark.parametrize("dt", [0.01, 0.001])
@pytest.mark.parametrize("integrator", mj.INTEGRATORS)
def test_dropped_cube_rests_on_a_face(integrator, dt):
    scene = CATALOG["dropped_cube"]
    r = rest(run(scene, "mujoco", integrator, dt=dt), scene, "cube")
    assert r["at_rest"], r
    assert abs(r["com_height"] - scene.expected.rest_com_height) < REST_HEIGHT_TOL, r


@pytest.mark.parametrize("integrator", mj.INTEGRATORS)
@pytest.mark.parametrize("restitution", [0.0, 0.5, 1.0])
def test_head_on_impact_conserves_momentum(restitution, integrator):
    """Body-body contact acts (the cubes turn back for e > 0) and conserves momentum."""
    scene = head_on(restitution)
    traj = run(scene, "mujoco", integrator)
    p = conserved_quantities(traj, scene)[["px", "py", "pz"]].to_numpy()
    assert np.abs(p).max() < MOMENTUM_ATOL
    va, vb = body_arrays(traj, "a")["v"][-1], body_arrays(traj, "b")["v"][-1]
    np.testing.assert_allclose(va, -vb, atol=SYMMETRY_ATOL)
    assert va[0] < (-0.3 if restitution > 0 else 0.2)  # turned back, or stopped (e = 0)


@pytest.mark.parametrize("integrator", mj.INTEGRATORS)
def test_rollout_equals_an_mj_step_loop_bitwise(integrator, monkeypatch):
    """Chunked rollout (7 // 3 * 3 = 6 steps per call, so warm starts cross chunk borders)
    gives exactly the states of a plain mj_step loop, contacts included."""
    scene = CATALOG["dropped_cube"]
    monkeypatch.setattr(mj, "CHUNK_STEPS", 7)
    steps, states = mj.step_rollout(*mj.build(scene, integrator, 0.01), 300, 3)
    loop_steps, loop_states = mj.step_loop(*mj.build(scene, integrator, 0.01), 300, 3)
    np.testing.assert_array_equal(steps, loop_steps)
    np.testing.assert_array_equal(states, loop_states)
    assert steps[-1] == 300 and len(steps) == 101


def test_a_diverging_run_ends_in_nan_not_a_reset(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo appends its warning to MUJOCO_LOG.TXT in the cwd
    model, data = mj.build(CATALOG["dropped_cube"], "Euler", 0.01)
    model.opt.gravity[:] = (0.0, 0.0, -1e14)  # qacc past MuJoCo's 1e10 divergence threshold
    _, states = mj.step_rollout(model, data, 50, 1)
    assert np.isfinite(states[0]).all()
    assert np.isnan(states[1:]).all()


def test_run_meta_carries_the_manifest_and_the_readback():
    scene = CATALOG["dropped_cube"]
    meta = run(scene, "mujoco", "Euler").meta
    s = meta.settings
    assert s["integrator"] == "mjINT_EULER" and s["timestep"] == scene.dt
    assert s["solref"] == [2 * scene.dt, 1.0] and s["condim"] == 3
    assert s["cone"] == "mjCONE_ELLIPTIC" and s["solver"] == "mjSOL_NEWTON"
    assert "mujoco" in meta.versions
    cube, body = meta.bodies["cube"], scene.bodies[0]
    assert cube["mass"] == body.mass
    np.testing.assert_allclose(cube["x"], body.com, rtol=0, atol=FRAME_ATOL)
    np.testing.assert_allclose(cube["w"], body.angular_velocity, rtol=0, atol=OMEGA0_ATOL)


def _disable_bits(names) -> int:
    bits = 0
    for name in names:
        bits |= int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{name.upper()}"))
    return bits


@pytest.mark.parametrize("integrator", mj.INTEGRATORS)
@pytest.mark.parametrize("scene", [CATALOG["tumbling_box"], CATALOG["dropped_cube"], head_on(0.5)])
def test_skipping_unused_stages_changes_nothing(scene, integrator):
    """The stages the adapter disables (nothing in any scene for them to act on, and the
    constraint solver without contact) give bitwise the same states when switched back on."""
    skipped = mj.UNUSED_STAGES + (() if scene.has_contact else ("constraint",))
    bits = _disable_bits(skipped)
    fast = mj.build(scene, integrator, scene.dt)
    assert fast[0].opt.disableflags & bits == bits
    full = mj.build(scene, integrator, scene.dt)
    full[0].opt.disableflags &= ~bits
    _, fast_states = mj.step_rollout(*fast, 200, 1)
    _, full_states = mj.step_rollout(*full, 200, 1)
    np.testing.assert_array_equal(fast_states, full_states)


def test_profiling_timer_is_off_while_stepping_only():
    """rollout steps without MuJoCo's profiling clock (the steps are counted, not timed); the
    bindings' clock is back afterwards."""
    if mj._timer_callback() is None:
        pytest.skip("libmujoco's mjcb_time cannot be reached here: the timer stays on")
    model, data = mj.build(CATALOG["free_spin_cube"], "Euler", 0.01)
    step = int(mujoco.mjtTimer.mjTIMER_STEP)
    mj.step_rollout(model, data, 50, 10)
    assert data.timer[step].number == 50 and data.timer[step].duration == 0.0
    mujoco.mj_step(model, data)
    assert data.timer[step].number == 51 and data.timer[step].duration > 0.0


def test_bodies_below_mjminval_are_refused_before_mujoco_compiles():
    """MuJoCo's compiler rejects a moving body lighter than mjMINVAL; the suite refuses the
    scene first, as input the engine cannot model, instead of failing in the adapter."""
    cube = CATALOG["free_spin_cube"]
    body = cube.bodies[0]
    light = dataclasses.replace(
        body, particles=tuple((x, y, z, 1e-17) for x, y, z, _ in body.particles)
    )
    scene = dataclasses.replace(cube, bodies=(light,))
    assert "below MuJoCo's mjMINVAL (1e-15)" in mj.MujocoEngine().unsupported(scene)
    assert mj.MujocoEngine().unsupported(cube) is None
    with pytest.raises(InputError, match="cannot run 'free_spin_cube': body 'cube' has a mass"):
        run(scene, "mujoco")
