"""The PhysX (SAPIEN) adapter: parity on every catalog case, float32 free flight against the exact
solution, damping really off, the gyroscopic term on, a dropped cube at rest, the settings
manifest.

Adapter-specific checks only; the cross-engine accuracy gates live elsewhere. The engine is
registered in-process, so the tests also run where the installed metadata predates its entry
point.
"""

import dataclasses

import numpy as np
import pytest

pytest.importorskip("sapien")

from cases.catalog import CATALOG  # noqa: E402
from cases.exact import exact_states  # noqa: E402
from comparators import ENGINES, run  # noqa: E402
from comparators.engine import register  # noqa: E402
from comparators.metrics import body_arrays, conserved_quantities, rest  # noqa: E402
from comparators.parity import check_parity, parity_tolerance  # noqa: E402
from comparators.physx_engine import PhysxEngine, PhysxSettings, run_physx  # noqa: E402
from rigidmath.inertia import principal_frame  # noqa: E402
from rigidmath.quaternion import quats_angle_between  # noqa: E402

if "physx" not in ENGINES or ENGINES["physx"].missing is not None:
    register(PhysxEngine())

INTEGRATORS = PhysxEngine.integrators
EPS32 = float(np.finfo(np.float32).eps)

# Free flight, per step: x + v dt rounds x to float32, at most half an ulp of |x|; a bound of a
# whole eps |x| per step over the run (measured 2.3e-4 m over 1000 steps at |x| <= 17.5 m,
# the bound 2.1e-3 m).
POSITION_EPS_PER_STEP = 1.0
# omega of an isotropic body is constant; PGS keeps it exactly, TGS's float32 update drifts it by
# 3.9 eps |omega| per step (measured: 9.4e-4 rad/s of 2 rad/s over 1000 steps): 8 eps per step.
OMEGA_EPS_PER_STEP = 8.0
# The orientation error integrates the omega error (a linear drift: half the final error times T)
# plus the rounding of q each step (measured: 2e-6 rad PGS, 5.1e-3 rad TGS over 10 s).
# Energy of the tumbling box, damping off: float32 rounding of omega and q each step, measured
# 0.4 eps per step (PGS) and 10 eps per step (TGS, biased upwards); 32 eps per step allowed,
# 250 times less than PhysX's default angular damping 0.05 takes in 1 s (9.5 %).
ENERGY_EPS_PER_STEP = 32.0
DEFAULT_DAMPING_LOSS_1S = 0.09  # 1 - exp(-2 * 0.05 * 1 s) = 0.095, measured 0.094 to 0.095
# Mass and moments are stored as float32: a few eps relative.
INERTIA_RTOL = 4 * EPS32
# The rest height the catalog asks for (half edge 0.5 + particle radius 0.2): measured within
# 5e-7 m (rest offset 0: the spheres touch the floor at their radius).
REST_HEIGHT_TOL = 0.005  # m
# One step of high_spin against PhysX's gyroscopic update done in float64: float32 rounding of
# omega (50 rad/s) and of the principal frame; measured 2.5e-6 rad/s (pgs) and 2.1e-5 (tgs).
GYRO_STEP_ATOL = 1e-4  # rad/s; the update itself moves omega by 0.45 rad/s


def test_engine_registered():
    engine = ENGINES["physx"]
    assert engine.missing is None
    assert engine.default_integrator == "tgs"
    assert set(engine.integrators) == {"tgs", "pgs"}
    assert engine.orders == {"tgs": 1, "pgs": 1}
    assert engine.epsilon == EPS32


@pytest.mark.parametrize("integrator", INTEGRATORS)
@pytest.mark.parametrize("case", sorted(CATALOG))
def test_parity_at_t0_on_every_catalog_case(case, integrator):
    """`run` checks parity itself (with the engine's epsilon); the errors are also well inside
    the float32 tolerance, not at its edge."""
    scene = CATALOG[case]
    assert PhysxEngine().unsupported(scene) is None
    traj = run(scene, "physx", integrator, duration=scene.dt)
    errors = check_parity(scene, traj.meta, EPS32)
    assert max(errors.values()) < 0.1 * parity_tolerance(scene, EPS32)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_free_flight_matches_exact(integrator):
    """A translating, spinning cube (isotropic inertia): v exact, x, omega and q within float32
    rounding of the exact motion; q is the identity at t = 0."""
    scene = CATALOG["free_spin_cube"]
    moving = dataclasses.replace(scene.bodies[0], velocity=(0.5, -0.25, 1.0))
    scene = dataclasses.replace(scene, bodies=(moving,))
    traj = run(scene, "physx", integrator)
    n = traj.meta.steps
    a = body_arrays(traj, "cube")
    ex = exact_states(scene, a["t"])[0]
    np.testing.assert_array_equal(a["q"][0], [1, 0, 0, 0])
    np.testing.assert_allclose(a["v"], ex["v"], rtol=EPS32)
    x_tol = POSITION_EPS_PER_STEP * n * EPS32 * np.abs(ex["x"]).max()
    assert np.abs(a["x"] - ex["x"]).max() < x_tol
    w_tol = OMEGA_EPS_PER_STEP * n * EPS32 * np.linalg.norm(moving.angular_velocity)
    assert np.abs(a["w"] - ex["w"]).max() < w_tol
    angle = quats_angle_between(np.ascontiguousarray(a["q"]), np.ascontiguousarray(ex["q"]))
    assert angle.max() < 0.5 * w_tol * traj.meta.duration + n * EPS32


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_damping_is_off_energy_kept(integrator):
    """tumbling_box over 1 s at dt 0.01: energy kept to float32 rounding; with PhysX's default
    angular damping (0.05) it loses ~9.5 %, so the adapter's 0 is really in effect."""
    scene = CATALOG["tumbling_box"]
    traj = run(scene, "physx", integrator, dt=0.01, duration=1.0)
    assert traj.meta.settings["angular_damping"] == traj.meta.settings["linear_damping"] == 0.0
    assert traj.meta.settings["bodies"]["box"]["angular_damping"] == 0.0
    energy = conserved_quantities(traj, scene)["energy"].to_numpy()
    drift = np.abs(energy / energy[0] - 1).max()
    assert drift < ENERGY_EPS_PER_STEP * traj.meta.steps * EPS32
    damped = run_physx(scene, integrator, 0.01, 1.0, PhysxSettings(angular_damping=0.05))
    energy = conserved_quantities(damped, scene)["energy"].to_numpy()
    assert 1 - energy[-1] / energy[0] > DEFAULT_DAMPING_LOSS_1S


def test_angular_velocity_clamp_is_raised():
    """PhysX clamps |omega| to max_angular_velocity (default 100 rad/s); the adapter's 1e7 lets a
    150 rad/s spin through."""
    scene = CATALOG["free_spin_cube"]
    fast = dataclasses.replace(scene.bodies[0], angular_velocity=(150.0, 0.0, 0.0))
    scene = dataclasses.replace(scene, bodies=(fast,))
    free = body_arrays(run(scene, "physx", "pgs", duration=0.1), "cube")["w"]
    np.testing.assert_allclose(np.linalg.norm(free, axis=1), 150.0, rtol=EPS32)
    clamped = run_physx(scene, "pgs", 0.01, 0.1, PhysxSettings(max_angular_velocity=100.0))
    w = body_arrays(clamped, "cube")["w"]
    np.testing.assert_allclose(np.linalg.norm(w[1:], axis=1), 100.0, rtol=1e-5)


def _physx_gyroscopic_step(moments, axes, omega, dt):
    """PhysX's eENABLE_GYROSCOPIC_FORCES update: an explicit step of Euler's equations in the
    principal frame, the angular momentum then rescaled to its magnitude before the step."""
    local = axes.T @ omega
    momentum = moments * local
    stepped = momentum - np.cross(local, momentum) * dt
    stepped *= np.linalg.norm(momentum) / np.linalg.norm(stepped)
    return axes @ (stepped / moments)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_gyroscopic_term_is_on(integrator):
    """SAPIEN turns PhysX's gyroscopic term on (PhysX's default is off) and does not expose it:
    high_spin's first step is PhysX's update, and over the first second |L| stays while the
    energy climbs (the explicit step)."""
    scene = CATALOG["high_spin"]
    traj = run(scene, "physx", integrator, duration=1.0)
    w = body_arrays(traj, "box")["w"]
    moments, axes = principal_frame(scene.bodies[0].inertia)
    expected = _physx_gyroscopic_step(moments, axes, w[0], scene.dt)
    np.testing.assert_allclose(w[1], expected, atol=GYRO_STEP_ATOL)
    c = conserved_quantities(traj, scene)
    L = np.linalg.norm(c[["Lx", "Ly", "Lz"]].to_numpy(), axis=1)
    assert abs(L[-1] / L[0] - 1) < ENERGY_EPS_PER_STEP * traj.meta.steps * EPS32
    assert (
        c["energy"].iloc[-1] / c["energy"].iloc[0] - 1
        > ENERGY_EPS_PER_STEP * traj.meta.steps * EPS32
    )


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_dropped_cube_comes_to_rest(integrator):
    scene = CATALOG["dropped_cube"]
    traj = run(scene, "physx", integrator, dt=0.01)
    r = rest(traj, scene, "cube")
    assert r["at_rest"]
    assert abs(r["com_height"] - scene.expected.rest_com_height) < REST_HEIGHT_TOL


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_settings_manifest(integrator):
    """Every setting that changes results is in the manifest, read back from PhysX where it
    reports it; contact settings only with contact."""
    scene = CATALOG["dropped_cube"]
    traj = run(scene, "physx", integrator, duration=scene.dt)
    s = traj.meta.settings
    assert s["precision"] == "float32" and s["epsilon"] == EPS32
    assert s["solver"].startswith({"tgs": "temporal", "pgs": "projected"}[integrator])
    assert s["gravity"] == pytest.approx(list(scene.gravity))
    assert s["sleep_threshold"] == 0.0 and s["sleeping"].startswith("off")
    assert "gyroscopic" in s
    body = s["bodies"]["cube"]
    assert body["max_angular_velocity"] == pytest.approx(1e7, rel=EPS32)
    assert body["sleep_threshold"] == 0.0
    assert body["solver_position_iterations"] == PhysxSettings().solver_position_iterations
    contact = s["contact"]
    assert contact["restitution"] == scene.contact.restitution
    assert contact["static_friction"] == contact["dynamic_friction"] == scene.contact.friction
    g = np.linalg.norm(scene.gravity)
    assert contact["bounce_threshold"] == pytest.approx(2 * g * scene.dt, rel=EPS32)
    assert contact["rest_offset"] == 0.0 and contact["ccd"] is False
    moments = s["inertia"]["cube"]["principal_moments"]
    np.testing.assert_allclose(
        moments, principal_frame(scene.bodies[0].inertia)[0], rtol=INERTIA_RTOL
    )
    free = run(CATALOG["tumbling_box"], "physx", integrator, duration=0.01).meta.settings
    assert free["contact"].startswith("none")
    assert traj.meta.versions.get("sapien")
