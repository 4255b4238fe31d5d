"""The Drake adapter: its model is the scene, its frames are the suite's, its samples are honest.

Adapter-specific checks only; the cross-engine gates live in tests/test_engines.py.
"""

import dataclasses
import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("pydrake", reason="drake is not installed: the Drake adapter cannot run")

from scenes import TILTED_CLUSTER, head_on  # noqa: E402

from cases import CATALOG, Body, Scene  # noqa: E402
from cases.catalog import cube_rain  # noqa: E402
from cases.exact import exact_states  # noqa: E402
from comparators import drake_engine as de  # noqa: E402
from comparators import run  # noqa: E402
from comparators.metrics import body_arrays, conserved_quantities, pose_errors, rest  # noqa: E402
from comparators.outcomes import bounces  # noqa: E402
from comparators.run_data import RunData  # noqa: E402
from rigidmath.quaternion import quat_to_matrix  # noqa: E402

INTEGRATORS = de.INTEGRATORS
# Mass and inertia go into Drake as doubles and come back through one shift by a zero COM
# offset and one re-expression by the identity: measured mass and COM exact, inertia 5e-17.
READBACK_RTOL = 1e-12
# Spin about a principal axis: omega is a constant of the motion, kept to rounding by every
# integrator (measured below 1.2e-14 rad/s). The orientation is a rotation about that axis whose
# angle lags by the quaternion update's truncation: (|w| dt)^3 / 12 per step for the explicit
# first-order update of the discrete step and semi-explicit Euler, half that for RK2: measured
# 4.4994e-4 and 2.2498e-4 rad after 2 s at |w| dt = 0.03, 1.4e-4 relative below the leading
# term, which is the next term of the series (3/20 (|w| dt)^2 relative); RK3 1.0e-8 rad.
STEADY_SPIN_ATOL = 1e-12  # rad/s
PHASE_LAG_RTOL = 1e-3  # the next term at |w| dt = 0.03, with a margin of 7
RK3_PHASE_ATOL = 1e-7  # rad
# Generic tumble, RK3 at dt 0.001 over 2 s: third-order truncation, measured 6.3e-10 relative
# in world omega; reporting body-frame omega would be off by O(1).
OMEGA_RTOL = 1e-6
# |q| of the returned samples: Drake's pose evaluation normalises (rounding only, ~1e-16); the
# raw state drifts: |q| - 1 = 0.130 after 10 s of tumbling_box at dt 0.01 (SAP, TAMSI and
# semi-explicit Euler alike; 0.012 at dt 0.001); required: more than half of that.
UNIT_NORM_ATOL = 1e-12
RAW_NORM_DRIFT_MIN = 0.065
# Ballistic flight: RK2/RK3 integrate a constant acceleration exactly, the discrete step and
# semi-explicit Euler give x0 + v0 t + g t (t + dt) / 2 exactly; only rounding of O(10) m sums
# over 1000 steps remains (measured at most 7.3e-14 m and 1.3e-13 m/s).
BALLISTIC_ATOL = 1e-10
# Rebound of the first bounce of `bounce` (e = 0.5) at dt 0.001, the impact the mapping is made
# for: the Hunt-Crossley relation neglects gravity during the ~16 ms contact (0.16 m/s against
# a 4.5 m/s impact) and the integrators add their own error; measured 0.490 (semi-explicit
# Euler), 0.486 (RK2), 0.489 (RK3) and 0.404 (SAP and TAMSI alike), whose implicit step damps
# the contact oscillation (omega dt = 0.2) further. Tolerance: about twice the continuous
# deviation; the discrete ones are checked one-sided (they rebound, and not above e).
FIRST_REBOUND_ATOL = 0.03
DISCRETE_FIRST_REBOUND = (0.3, 0.5)
# The rest gate of tests/test_engines.py (the COM within 5 mm of 0.7 m); Drake's compliant
# contact sinks 0.25 mm on a face (measured 0.69975 m with every integrator at dt 0.001).
REST_HEIGHT_TOL = 0.005
# The Hunt-Crossley e <-> d v relation is solved by bisection to machine precision.
MAPPING_ATOL = 1e-12
# Equal and opposite contact forces: momentum stays at rounding of the two bodies' 8 kg m/s
# (measured at most 6e-15 kg m/s for every integrator).
MOMENTUM_ATOL = 1e-9


def _free_scene(body: Body, gravity=(0.0, 0.0, 0.0), duration=2.0, dt=0.001) -> Scene:
    return Scene(
        name=body.name,
        duration=duration,
        dt=dt,
        sample_interval=0.1,
        gravity=gravity,
        bodies=(body,),
    )


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_readback_of_a_rotated_asymmetric_body_is_the_scene(integrator):
    """Mass, full inertia tensor about the COM, COM state and world omega at t = 0 as the plant
    holds them (comparators.run also checks them to 1e-9 through energy and momenta)."""
    traj = run(_free_scene(TILTED_CLUSTER), "drake", integrator, duration=0.01)
    got = traj.meta.bodies["cluster"]
    assert got["mass"] == pytest.approx(TILTED_CLUSTER.mass, rel=READBACK_RTOL)
    inertia = np.asarray(got["inertia"])
    assert (
        np.abs(inertia - TILTED_CLUSTER.inertia).max()
        <= READBACK_RTOL * np.abs(TILTED_CLUSTER.inertia).max()
    )
    assert abs(inertia[0, 1]) > 0.1 * inertia[0, 0]  # the off-diagonal terms are really there
    np.testing.assert_allclose(got["x"], TILTED_CLUSTER.com, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(got["v"], TILTED_CLUSTER.velocity)
    np.testing.assert_array_equal(got["w"], TILTED_CLUSTER.angular_velocity)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_spin_about_a_principal_axis_stays_steady(integrator):
    """The tilted cluster spun about its largest principal axis (tilted in the world): omega
    stays that world vector, and the orientation lags the rotation about it by |w| t only by
    the integrator's known truncation."""
    inertia = TILTED_CLUSTER.inertia
    moments, axes = np.linalg.eigh(inertia)
    w0 = 3.0 * axes[:, 2]
    body = dataclasses.replace(TILTED_CLUSTER, velocity=(0.0, 0.0, 0.0), angular_velocity=tuple(w0))
    scene = _free_scene(body, dt=0.01)
    a = body_arrays(run(scene, "drake", integrator), "cluster")
    assert np.abs(a["w"] - w0).max() < STEADY_SPIN_ATOL
    errors = pose_errors(run(scene, "drake", integrator), exact_states(scene, a["t"]), scene)
    lag = np.radians(errors["orientation_error_deg"].max())
    per_step = (np.linalg.norm(w0) * scene.dt) ** 3 / 12
    n = scene.steps(scene.dt)
    if integrator == "rk3":
        assert lag < RK3_PHASE_ATOL
    else:
        expected = n * per_step / (2 if integrator == "rk2" else 1)
        assert lag == pytest.approx(expected, rel=PHASE_LAG_RTOL)


def test_angular_velocity_is_reported_in_world_axes():
    """A generic tumble: omega follows the exact world-frame omega (RK3, dt 0.001)."""
    scene = _free_scene(TILTED_CLUSTER)
    a = body_arrays(run(scene, "drake", "rk3"), "cluster")
    exact = exact_states(scene, a["t"])[0]
    scale = np.linalg.norm(TILTED_CLUSTER.angular_velocity)
    assert np.abs(a["w"] - exact["w"]).max() < OMEGA_RTOL * scale
    body_frame = np.einsum("sji,sj->si", [quat_to_matrix(q) for q in a["q"]], a["w"])
    assert np.abs(body_frame - exact["w"]).max() > 0.1 * scale  # the other frame would show


@pytest.mark.parametrize("integrator", ["sap", "tamsi", "semi_explicit_euler"])
def test_quaternion_read_back_is_unit_norm_where_the_state_drifts(integrator):
    """tumbling_box for 10 s at dt 0.01: the state's quaternion grows off the unit sphere (the
    trap), the samples, read through the plant's pose evaluation, stay on it."""
    scene = CATALOG["tumbling_box"]
    traj = run(scene, "drake", integrator)
    q = body_arrays(traj, "box")["q"]
    assert np.abs(np.linalg.norm(q, axis=1) - 1.0).max() < UNIT_NORM_ATOL
    model = de.build(scene, integrator, scene.dt)
    model.simulator.AdvanceTo(scene.duration)
    raw = model.plant.GetPositions(model.context)[:4]
    assert abs(np.linalg.norm(raw) - 1.0) > RAW_NORM_DRIFT_MIN


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_ballistic_flight_is_exact(integrator):
    """Under gravity without contact the COM follows the closed form of its integrator: the
    parabola for RK2/RK3, the semi-implicit Euler parabola x0 + v0 t + g t (t + dt) / 2 for
    the discrete step and semi-explicit Euler."""
    body = dataclasses.replace(TILTED_CLUSTER, velocity=(1.0, -2.0, 5.0))
    scene = _free_scene(body, gravity=(0.0, 0.0, -10.0), duration=1.0)
    a = body_arrays(run(scene, "drake", integrator), "cluster")
    t, g, dt = a["t"][:, None], np.array(scene.gravity), scene.dt
    lag = 0.0 if integrator in ("rk2", "rk3") else dt
    expected = TILTED_CLUSTER.com + np.outer(a["t"], body.velocity) + 0.5 * g * t * (t + lag)
    assert np.abs(a["x"] - expected).max() < BALLISTIC_ATOL
    assert np.abs(a["v"] - (np.array(body.velocity) + g * t)).max() < BALLISTIC_ATOL


def test_contact_free_scenes_have_no_geometry():
    """No contact: no SceneGraph and no geometry; zero gravity: a zero gravity vector.
    With contact: one sphere per particle and one half-space per plane."""
    free = de.build(CATALOG["tumbling_box"], "sap", 0.01)
    assert free.scene_graph is None and free.plant.num_collision_geometries() == 0
    np.testing.assert_array_equal(free.plant.gravity_field().gravity_vector(), 0.0)
    ballistic = de.build(_free_scene(TILTED_CLUSTER, gravity=(0.0, 0.0, -10.0)), "rk2", 0.01)
    assert ballistic.plant.num_collision_geometries() == 0
    scene = CATALOG["dropped_cube"]
    dropped = de.build(scene, "sap", 0.01)
    assert dropped.plant.num_collision_geometries() == 8 + 1
    np.testing.assert_array_equal(dropped.plant.gravity_field().gravity_vector(), scene.gravity)
    two = de.build(head_on(0.5), "rk3", 0.01)  # contact without planes: body-body only
    assert two.plant.num_collision_geometries() == 16
    assert run(scene, "drake", "sap", duration=0.01).meta.settings["proximity_geometries"] == 9


def test_hunt_crossley_mapping_inverts():
    for e in (0.1, 0.3, 0.5, 0.8, 0.99):
        alpha = de.hunt_crossley_alpha(e)
        assert de.hunt_crossley_restitution(alpha) == pytest.approx(e, abs=MAPPING_ATOL)
    assert de.hunt_crossley_alpha(1.0) == 0.0
    assert de.hunt_crossley_alpha(0.0) == de.hunt_crossley_alpha(de.E_FLOOR)
    # small d v: the classic first-order relation e = 1 - (2/3) d v
    assert de.hunt_crossley_restitution(1e-3) == pytest.approx(1 - 2e-3 / 3, abs=1e-6)
    # the impact speed: falling 1 m from rest, thrown down, thrown up and falling back, moving
    # away without gravity, never arriving against gravity pointing away from the plane
    assert de._first_contact_speed(1.0, 0.0, -10.0) == pytest.approx(math.sqrt(20.0))
    assert de._first_contact_speed(1.0, -3.0, 0.0) == 3.0
    assert de._first_contact_speed(1.0, 2.0, -10.0) == pytest.approx(math.sqrt(24.0))
    assert de._first_contact_speed(1.0, 2.0, 0.0) == 0.0
    assert de._first_contact_speed(1.0, 2.0, 10.0) == 0.0
    assert de._first_contact_speed(1.0, -2.0, 10.0) == 0.0  # turned back before arriving
    assert de.impact_speed(CATALOG["resting_cube"]) == de.FALLBACK_IMPACT_SPEED
    bounce = CATALOG["bounce"]
    m = de.contact_material(bounce)
    assert m.impact_speed == pytest.approx(math.sqrt(2 * 10.0 * 1.0), rel=1e-12)  # 1 m drop
    assert m.dissipation * m.impact_speed == pytest.approx(de.hunt_crossley_alpha(0.5))


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_first_bounce_rebounds_at_the_mapped_restitution(integrator):
    """bounce (e = 0.5) at dt 0.001 for 1.5 s: the first impact, the one the mapping is made
    for, rebounds at e (continuous) or below it (discrete, extra numerical damping)."""
    scene = CATALOG["bounce"]
    traj = run(scene, "drake", integrator, duration=1.5)
    first = bounces(RunData(traj, scene), 0, scene.planes[0])["ratio"].iloc[0]
    if integrator in de.DISCRETE:
        assert DISCRETE_FIRST_REBOUND[0] < first <= DISCRETE_FIRST_REBOUND[1], first
    else:
        assert abs(first - 0.5) < FIRST_REBOUND_ATOL, first


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_head_on_impact_conserves_momentum(integrator):
    """Body-body contact acts, conserves momentum and rebounds as the mapping says: two cubes
    meeting at 2 m/s, the speed the mapping is made for, at dt 0.001 (measured rebound speeds
    0.504, 0.498, 0.499 m/s for semi-explicit Euler, RK2, RK3; 0.415 for SAP and TAMSI). At
    dt 0.01 the stiff pair contact (omega dt = 2.8 on four contacts) is what the integrators
    resolve, not the mapping: SAP and TAMSI 0.074 m/s, the explicit ones gain energy."""
    scene = head_on(0.5)
    traj = run(scene, "drake", integrator, dt=0.001)
    p = conserved_quantities(traj, scene)[["px", "py", "pz"]].to_numpy()
    assert np.abs(p).max() < MOMENTUM_ATOL
    va, vb = body_arrays(traj, "a")["v"][-1], body_arrays(traj, "b")["v"][-1]
    np.testing.assert_allclose(va, -vb, rtol=0, atol=MOMENTUM_ATOL)
    if integrator in de.DISCRETE:
        assert DISCRETE_FIRST_REBOUND[0] < -va[0] <= DISCRETE_FIRST_REBOUND[1], va
    else:
        assert abs(-va[0] - 0.5) < FIRST_REBOUND_ATOL, va


@pytest.mark.parametrize("integrator", ["semi_explicit_euler", "rk2"])
def test_fixed_steps_are_exactly_n_steps(integrator):
    """The continuous plant takes exactly the run's steps, sampled or not (no spurious
    rounding steps at the sample times)."""
    traj = run(CATALOG["tumbling_box"], "drake", integrator, dt=0.003)
    assert traj.meta.solver["steps_taken"] == traj.meta.steps


def test_divergence_ends_in_nan_samples_not_an_exception():
    """dropped_cube with RK2 at dt 0.01: the stiff contact (omega dt = 2 on a face) blows up;
    the run returns, finite at first and NaN from the divergence on."""
    scene = CATALOG["dropped_cube"]
    traj = run(scene, "drake", "rk2")
    a = body_arrays(traj, "cube")
    finite = np.isfinite(a["x"]).all(axis=1)
    assert finite[0] and not finite[-1]
    first_bad = int(np.argmin(finite))
    assert not finite[first_bad:].any()  # NaN from there on
    assert traj.meta.solver["diverged_at_s"] == pytest.approx(a["t"][first_bad])


def test_drake_failure_is_caught_but_adapter_errors_raise(monkeypatch):
    """A RuntimeError thrown by Drake while advancing is a divergence (the samples already
    taken stay, the rest are NaN); a wrong integrator name is the caller's error and raises."""
    scene = CATALOG["tumbling_box"]
    model = de.build(scene, "sap", 0.01)

    class FailingSimulator:
        """Drake's Simulator, whose AdvanceTo takes 15 steps and then throws."""

        def __init__(self, simulator):
            self.simulator = simulator

        def __getattr__(self, name):
            return getattr(self.simulator, name)

        def AdvanceTo(self, t):  # noqa: N802 (Drake's name)
            self.simulator.AdvanceTo(0.15)
            raise RuntimeError("MultibodyPlant's discrete update failed")

    monkeypatch.setattr(model, "simulator", FailingSimulator(model.simulator))
    steps = np.array([0, 10, 20, 30])
    poses, spatial, at = de.step_and_sample(model, steps, 0.01, 0.3)
    samples = de.samples_from_records(poses, spatial)
    assert np.isfinite(samples[:2]).all() and np.isnan(samples[2:]).all()
    assert at == pytest.approx(0.2)
    with pytest.raises(ValueError):
        de.DrakeEngine().run(scene, "euler", 0.01, 1.0)


@pytest.mark.parametrize("integrator", list(de.CONTINUOUS))
def test_continuous_plant_comes_to_rest_at_a_fine_step(integrator):
    """dropped_cube at dt 0.001: with the continuous plant's stiction tolerance the explicit
    step resolves the Stribeck slope and the cube stops (at MultibodyPlantConfig's default,
    1e-4 m/s, it chattered at up to 5 mm/s for ever)."""
    scene = CATALOG["dropped_cube"]
    traj = run(scene, "drake", integrator, dt=0.001)
    assert traj.meta.settings["stiction_tolerance"] == de.STICTION_TOLERANCE["continuous"]
    r = rest(traj, scene, "cube")
    assert r["at_rest"], r
    assert abs(r["com_height"] - scene.expected.rest_com_height) < REST_HEIGHT_TOL, r


def test_module_imports_without_pydrake():
    """With pydrake absent the module still imports and the engine says how to install it."""
    code = textwrap.dedent(
        """
        import sys
        sys.modules["pydrake"] = None  # any import of pydrake now fails
        from comparators.drake_engine import DrakeEngine
        print(DrakeEngine().missing)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "pip install 'rigidbench[drake]'" in out.stdout


def test_scenes_past_the_sphere_limit_are_refused_saying_why():
    engine = de.DrakeEngine()
    assert engine.unsupported(cube_rain(300)) is None  # 2400 spheres, the limit
    assert "8000 contact spheres, over 2400" in engine.unsupported(cube_rain(1000))
    free = dataclasses.replace(cube_rain(1000), contact=None, planes=())
    assert engine.unsupported(free) is None  # no contact: no geometry registered
