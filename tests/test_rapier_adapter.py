"""The Rapier adapter: parity on every catalog case, float32 free flight against exact, the
gyroscopic term, rest on contact, the settings manifest.

Adapter-specific checks only; the cross-engine accuracy gates live elsewhere. Rapier computes
in float32, so every tolerance below is a count of float32 epsilons (EPS32) per step or
substep, or a measured figure with its margin.
"""

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rapier3d")

from cases import Body, Contact, Scene  # noqa: E402
from cases.builders import floor  # noqa: E402
from cases.catalog import CATALOG  # noqa: E402
from cases.exact import exact_states  # noqa: E402
from comparators import ENGINES, run  # noqa: E402
from comparators.engine import register  # noqa: E402
from comparators.metrics import body_arrays, conserved_quantities, rest  # noqa: E402
from comparators.rapier_engine import (  # noqa: E402
    DEFAULT_SETTINGS,
    RapierEngine,
    RapierSettings,
    run_rapier,
)
from rigidmath.inertia import principal_frame  # noqa: E402
from rigidmath.quaternion import quats_angle_between, quats_to_matrices  # noqa: E402

if "rapier" not in ENGINES or getattr(ENGINES["rapier"], "missing", None) is not None:
    register(RapierEngine())  # the installed metadata may predate the entry point

EPS32 = float(np.finfo(np.float32).eps)
SUBSTEPS = DEFAULT_SETTINGS.num_solver_iterations
# Mass and principal moments are stored as f32 (one rounding each) and the principal frame as
# an f32 quaternion: the world tensor rebuilt from them is off by a few EPS32 of its norm.
INERTIA_RTOL = 16 * EPS32
# Rapier's gyroscopic update scales omega by about (1 + EPS32) every substep, even where the
# gyroscopic torque is zero (isotropic inertia): measured |omega| +1.0e-7 per substep (0.86
# EPS32). Bound: 2 EPS32 per substep on |omega|, hence on the angle swept, |omega| T.
OMEGA_BIAS_PER_SUBSTEP = 2 * EPS32
# Energy: the same bias, 2 |omega| d|omega| plus the tumbling term; measured 6.3 EPS32 per
# substep on tumbling_box (+3.0e-3 over 4000 substeps at dt 0.01), 1.5 EPS32 on free_spin_cube.
ENERGY_BIAS_PER_SUBSTEP = 8 * EPS32
# Gyroscopic term off: omega is held in the world frame, so a free spin keeps its energy to
# rounding (measured 7e-9 on tumbling_box, 0 on free_spin_cube), which shows damping is 0.
GYRO_OFF_ENERGY_RTOL = 1e-6
# A force-free COM moves by v h each substep, rounded to f32 at |x|: EPS32 |x| per substep.
POSITION_ROUNDING_PER_SUBSTEP = EPS32
# tumbling_box at dt 0.01: measured 6.05 degrees (max over 10 s) against exact with the term
# on; 177 degrees (111 at 10 s) with it off.
TUMBLING_DEG = 8.0
TUMBLING_OFF_MIN_DEG = 90.0
# The catalog's rest height (half edge 0.5 + particle radius 0.2); soft contacts settle at
# 3.5e-5 m penetration (measured).
REST_HEIGHT_TOL = 0.005  # m
# The t = 0 rotation is the identity exactly (f32 identity, no frame product).
IDENTITY_ATOL = 0.0


def _orientation_error(traj, scene, name):
    a = body_arrays(traj, name)
    k = [b.name for b in scene.bodies].index(name)
    ex = exact_states(scene, a["t"])[k]
    angle = quats_angle_between(np.ascontiguousarray(a["q"]), np.ascontiguousarray(ex["q"]))
    return a, ex, angle


def test_engine_registered():
    engine = ENGINES["rapier"]
    assert engine.missing is None
    assert engine.integrators == ("tgs_soft",)
    assert engine.default_integrator == "tgs_soft"
    assert engine.orders == {"tgs_soft": 1}
    assert engine.epsilon == EPS32


def test_missing_says_how_to_install():
    code = (
        "import sys; sys.modules['rapier3d'] = None\n"
        "from comparators.rapier_engine import RapierEngine\n"
        "print(RapierEngine.missing)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], check=True, capture_output=True, text=True
    ).stdout
    assert "pip install rigidbench[rapier]" in out


@pytest.mark.parametrize("case", sorted(CATALOG))
def test_parity_on_every_catalog_case(case):
    """`run` checks the t = 0 read-back against the scene with float32's epsilon; it raises
    on a mismatch."""
    scene = CATALOG[case]
    traj = run(scene, "rapier", duration=10 * scene.dt)
    assert set(traj.meta.bodies) == {b.name for b in scene.bodies}
    for body in scene.bodies:
        got = traj.meta.bodies[body.name]
        assert got["mass"] == pytest.approx(body.mass, rel=EPS32)
        inertia = np.asarray(got["inertia"])
        assert np.linalg.norm(inertia - body.inertia) <= INERTIA_RTOL * np.linalg.norm(body.inertia)
        a = body_arrays(traj, body.name)
        np.testing.assert_array_equal(a["q"][0], [1.0, 0.0, 0.0, 0.0])


def test_free_flight_without_damping():
    """A translating, spinning cube (isotropic inertia: no gyroscopic torque) keeps v exactly
    and |omega| within the gyroscopic update's f32 bias; the COM moves on x0 + v t."""
    scene = CATALOG["free_spin_cube"]
    moving = dataclasses.replace(scene.bodies[0], velocity=(0.5, -0.25, 1.0))
    scene = dataclasses.replace(scene, bodies=(moving,))
    traj = run(scene, "rapier")
    a, ex, angle = _orientation_error(traj, scene, "cube")
    v0, w0 = np.array(moving.velocity), np.array(moving.angular_velocity)
    substeps = SUBSTEPS * round(scene.duration / scene.dt)
    np.testing.assert_array_equal(a["v"], np.broadcast_to(v0, a["v"].shape))  # f32-exact values
    w_drift = np.abs(np.linalg.norm(a["w"], axis=1) / np.linalg.norm(w0) - 1).max()
    assert w_drift <= substeps * OMEGA_BIAS_PER_SUBSTEP
    assert np.allclose(a["w"] / np.linalg.norm(a["w"], axis=1)[:, None], w0 / np.linalg.norm(w0))
    x_tol = substeps * POSITION_ROUNDING_PER_SUBSTEP * np.abs(a["x"]).max()
    np.testing.assert_allclose(a["x"], ex["x"], rtol=0, atol=x_tol)
    swept = np.linalg.norm(w0) * scene.duration
    assert angle.max() <= swept * substeps * OMEGA_BIAS_PER_SUBSTEP


@pytest.mark.parametrize("case", ["free_spin_cube", "tumbling_box"])
def test_energy_kept_in_free_flight(case):
    """No damping: energy moves only by the f32 bias of the gyroscopic update (per substep),
    and not at all beyond rounding with the term off."""
    scene = CATALOG[case]
    substeps = SUBSTEPS * round(scene.duration / scene.dt)
    energy = conserved_quantities(run(scene, "rapier"), scene)["energy"].to_numpy()
    assert np.abs(energy / energy[0] - 1).max() <= substeps * ENERGY_BIAS_PER_SUBSTEP
    off = run_rapier(
        scene,
        "tgs_soft",
        scene.dt,
        scene.duration,
        dataclasses.replace(DEFAULT_SETTINGS, gyroscopic_forces=False),
    )
    energy = conserved_quantities(off, scene)["energy"].to_numpy()
    assert np.abs(energy / energy[0] - 1).max() <= GYRO_OFF_ENERGY_RTOL


def test_gyroscopic_term_is_on():
    """tumbling_box at dt 0.01: within TUMBLING_DEG of exact and the intermediate axis flips
    against L at the exact solution's samples; without the term it is off by > 90 degrees."""
    scene = CATALOG["tumbling_box"]
    traj = run(scene, "rapier", dt=0.01)
    assert traj.meta.settings["gyroscopic"] is True
    a, ex, angle = _orientation_error(traj, scene, "box")
    assert np.degrees(angle.max()) < TUMBLING_DEG
    body = scene.bodies[0]
    middle = principal_frame(body.inertia)[1][:, 1]
    momentum = body.inertia @ np.array(body.angular_velocity)

    def flips(q):
        along = quats_to_matrices(np.ascontiguousarray(q)) @ middle @ momentum
        return a["t"][np.flatnonzero(np.diff(np.sign(along)))]

    exact_flips = flips(ex["q"])
    assert len(exact_flips) >= 2
    np.testing.assert_allclose(flips(a["q"]), exact_flips, atol=0.1 + 1e-9)

    off = run_rapier(
        scene, "tgs_soft", 0.01, scene.duration, RapierSettings(gyroscopic_forces=False)
    )
    assert off.meta.settings["gyroscopic"] is False
    _, _, angle_off = _orientation_error(off, scene, "box")
    assert np.degrees(angle_off.max()) > TUMBLING_OFF_MIN_DEG


@pytest.mark.parametrize("case", ["dropped_cube", "fast_impact"])
def test_cube_comes_to_rest(case):
    scene = CATALOG[case]
    r = rest(run(scene, "rapier"), scene, "cube")
    assert r["at_rest"]
    assert abs(r["com_height"] - scene.expected.rest_com_height) < REST_HEIGHT_TOL


def test_settings_manifest():
    free = run(CATALOG["tumbling_box"], "rapier", duration=0.1).meta.settings
    contact = run(CATALOG["dropped_cube"], "rapier", duration=0.1).meta.settings
    for settings in (free, contact):
        assert settings["precision"].startswith("float32")
        assert settings["gyroscopic"] is True
        assert settings["linear_damping"] == settings["angular_damping"] == 0.0
        assert settings["sleeping"].startswith("disabled")
        assert settings["allow_fast_rotation"] is True
        assert settings["ccd"] is False
        assert settings["num_solver_iterations"] == SUBSTEPS
        assert "time_stepping" in settings
    assert free["contact"].startswith("none")
    assert free["gravity"] == [0.0, 0.0, 0.0]
    c = contact["contact"]
    scene = CATALOG["dropped_cube"]
    assert (c["friction"], c["restitution"]) == (
        scene.contact.friction,
        scene.contact.restitution,
    )
    assert "MAX" in c["combine_rule"]
    for key in ("contact_skin", "prediction_distance", "friction_model", "contact_softness"):
        assert key in c
    moments = contact["mass_properties"]["cube"]["principal_moments"]
    np.testing.assert_allclose(
        moments, principal_frame(scene.bodies[0].inertia)[0], rtol=INERTIA_RTOL
    )


def test_degenerate_moments_are_kept_with_contact():
    """A tetrahedron's tensor has a pair of equal moments, so its principal frame is arbitrary in
    that plane. Zero-density ball colliders made Rapier re-diagonalise the sum in f32 (moments
    back 1e-4 off, failing parity); the compound of balls with zero mass properties keeps the
    explicit ones."""
    tetra = Body(
        name="b0",
        particle_radius=1.0,
        particles=((0, 0, 0, 1.0), (0, 0, 10, 1.0), (0, 10, 0, 1.0), (10, 0, 0, 1.0)),
    )
    scene = Scene(
        name="tetra",
        duration=0.3,
        dt=0.1,
        gravity=(0.0, 0.0, 0.0),
        contact=Contact(restitution=0.0, friction=0.0),
        planes=(floor(-10.0),),
        bodies=(tetra,),
    )
    traj = run(scene, "rapier")  # parity checked inside
    moments = traj.meta.settings["mass_properties"]["b0"]["principal_moments"]
    np.testing.assert_allclose(moments, principal_frame(tetra.inertia)[0], rtol=INERTIA_RTOL)


def test_numbers_beyond_float32_are_unsupported():
    scene = CATALOG["free_spin_cube"]
    far = dataclasses.replace(scene.bodies[0], velocity=(1e39, 0.0, 0.0))
    reason = ENGINES["rapier"].unsupported(dataclasses.replace(scene, bodies=(far,)))
    assert "velocity include 1e+39" in reason
    tiny = dataclasses.replace(scene.bodies[0], angular_velocity=(1e-40, 0.0, 0.0))
    reason = ENGINES["rapier"].unsupported(dataclasses.replace(scene, bodies=(tiny,)))
    assert "angular velocity include 1e-40" in reason
    assert all(ENGINES["rapier"].unsupported(s) is None for s in CATALOG.values())
