"""The exact solution of contact-free scenes (`cases.exact`), checked against physics.

Every check but the closed forms is independent of the elliptic-function solution: textbook
formulas written here, conservation laws, frame covariance, a numerical integration
(DOP853) and, when mpmath is installed, a 30-digit Taylor-series integration.
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from cases import builders
from cases.catalog import CATALOG
from cases.exact import exact_states, exact_trajectory_available, torque_free_rotation
from cases.scene import Body, Scene
from rigidmath.quaternion import quats_to_matrices

# Closed forms (constant spin, ballistic COM) evaluate the same few operations: a few ulps.
CLOSED_FORM_TOL = 1e-14
# The required accuracy of the reference: 1e-12 relative over the scene's duration.
REFERENCE_TOL = 1e-12
# The brief's bound for the axisymmetric check at t = 10 s, against a formula written here.
PRECESSION_TOL = 1e-10
# |q| = 1 after renormalisation, up to rounding of a 4-term sum.
UNIT_NORM_TOL = 1e-14
# Refining the precession quadrature (more nodes, shorter panels) may move q by rounding only.
QUADRATURE_CONVERGENCE_TOL = 1e-14
# DOP853 at scipy's tightest rtol (100 eps) stops at ~2e-12 in rotation-matrix entries on
# tumbling_box (roundoff amplified while the box passes its unstable axis): 5x that floor.
DOP853_TOL = 1e-11
# A 30-digit Taylor integration is exact at double precision; the solution's own rounding, ~5e-15.
HIGH_PRECISION_TOL = 1e-13
# The flip: the body y axis's world y component starts above this and later falls below minus it.
FLIP_LEVEL = 0.99

SAMPLES = np.linspace(0.0, 10.0, 101)
FIXED_ROTATION = Rotation.from_rotvec([0.3, -0.7, 0.5])


def _scene(name, particles, omega, velocity=(0.0, 0.0, 0.0), gravity=(0.0, 0.0, 0.0)):
    return Scene(
        name=name,
        duration=10.0,
        dt=0.01,
        gravity=gravity,
        bodies=(
            Body(
                name="body",
                particle_radius=0.2,
                particles=particles,
                velocity=velocity,
                angular_velocity=tuple(map(float, omega)),
            ),
        ),
    )


def _rotated(scene: Scene, rot: Rotation) -> Scene:
    """The scene's first body with its particles, velocity and omega turned by `rot`."""
    body = scene.bodies[0]
    turned = rot.apply(body.positions)
    particles = tuple((*map(float, p), float(m)) for p, m in zip(turned, body.masses, strict=True))
    return _scene(
        f"{scene.name}_rotated",
        particles,
        rot.apply(body.angular_velocity),
        velocity=tuple(map(float, rot.apply(body.velocity))),
    )


def _matrices(q):
    return quats_to_matrices(np.ascontiguousarray(q))


def _tumbling_variants():
    base = CATALOG["tumbling_box"]
    return [base, _rotated(base, FIXED_ROTATION)]


@pytest.mark.parametrize("name", sorted(CATALOG))
def test_available_exactly_without_contact(name):
    scene = CATALOG[name]
    assert exact_trajectory_available(scene) is (not scene.has_contact)


def test_contact_scene_is_rejected():
    with pytest.raises(ValueError, match="contact"):
        exact_states(CATALOG["dropped_cube"], SAMPLES)


def test_isotropic_cube_spins_uniformly():
    (state,) = exact_states(CATALOG["free_spin_cube"], SAMPLES)
    # A rotation about x by 2t: q = (cos t, sin t, 0, 0).
    expected = np.column_stack([np.cos(SAMPLES), np.sin(SAMPLES), 0 * SAMPLES, 0 * SAMPLES])
    np.testing.assert_allclose(state["q"], expected, rtol=0, atol=CLOSED_FORM_TOL)
    np.testing.assert_allclose(state["w"], np.tile([2.0, 0.0, 0.0], (len(SAMPLES), 1)), atol=0)


@pytest.mark.parametrize("scene", _tumbling_variants(), ids=lambda s: s.name)
def test_conservation(scene):
    (state,) = exact_states(scene, SAMPLES)
    body = scene.bodies[0]
    rot = _matrices(state["q"])
    inertia_t = rot @ body.inertia @ rot.transpose(0, 2, 1)
    ang_mom = np.einsum("nij,nj->ni", inertia_t, state["w"])
    energy = 0.5 * np.einsum("ni,ni->n", state["w"], np.einsum("nij,nj->ni", inertia_t, state["w"]))
    l0 = body.inertia @ np.asarray(body.angular_velocity)
    e0 = 0.5 * np.asarray(body.angular_velocity) @ l0
    assert np.abs(ang_mom - l0).max() <= REFERENCE_TOL * np.linalg.norm(l0)
    assert np.abs(energy - e0).max() <= REFERENCE_TOL * e0
    assert np.abs(np.linalg.norm(state["q"], axis=1) - 1).max() <= UNIT_NORM_TOL


@pytest.mark.parametrize("turn", [None, FIXED_ROTATION], ids=["aligned", "rotated"])
@pytest.mark.parametrize("omega", [(0.6, -0.3, 2.0), (1.5, 0.4, -0.2)])
def test_axisymmetric_regular_precession(omega, turn):
    base = _scene("square_box", builders.box_corners((1.0, 1.0, 3.0)), omega)
    scene = base if turn is None else _rotated(base, turn)
    body = scene.bodies[0]
    t_end = 10.0
    (state,) = exact_states(scene, np.array([0.0, t_end]))

    # Textbook: with I1 = I2 (transverse) and I3 about the symmetry axis e3, omega in the body
    # frame turns about e3 at Omega = (I3 - I1)/I1 w3, while e3 precesses about L at |L|/I1.
    # Hence R(t) = Rot(L_hat, |L| t / I1) Rot(e3, -Omega t).
    e3 = np.array([0.0, 0.0, 1.0]) if turn is None else turn.apply([0.0, 0.0, 1.0])
    i1 = 8 * (0.5**2 + 1.5**2)  # unit masses at (+-0.5, +-0.5, +-1.5)
    i3 = 8 * (0.5**2 + 0.5**2)
    w0 = np.asarray(body.angular_velocity)
    ang_mom = body.inertia @ w0
    omega_spin = (i3 - i1) / i1 * (w0 @ e3)
    textbook = Rotation.from_rotvec(ang_mom * t_end / i1) * Rotation.from_rotvec(
        -omega_spin * t_end * e3
    )
    rot = _matrices(state["q"])[-1]
    axis_error = np.linalg.norm(rot @ e3 - textbook.apply(e3))
    assert axis_error <= PRECESSION_TOL, f"symmetry axis off by {axis_error:.2e}"
    assert np.abs(rot - textbook.as_matrix()).max() <= PRECESSION_TOL


def test_tumbling_box_flips_its_intermediate_axis():
    times = np.linspace(0.0, 10.0, 1001)
    (state,) = exact_states(CATALOG["tumbling_box"], times)
    y_of_body_y = _matrices(state["q"])[:, 1, 1]
    crossed = np.flatnonzero(y_of_body_y < 0)
    flip = times[crossed[0]] if len(crossed) else None
    assert y_of_body_y[0] > FLIP_LEVEL
    assert flip is not None and y_of_body_y.min() < -FLIP_LEVEL, (
        f"no flip within 10 s: body y axis world-y component min {y_of_body_y.min():.3f}"
    )
    assert 0 < flip < 10.0, f"first flip (world y of body y crosses 0) at t = {flip:.3f} s"
    print(f"tumbling_box first flip at t = {flip:.3f} s")


def test_rotated_body_has_the_same_relative_motion():
    base = CATALOG["tumbling_box"]
    turned = _rotated(base, FIXED_ROTATION)
    (plain,) = exact_states(base, SAMPLES)
    (rotated,) = exact_states(turned, SAMPLES)
    fix = FIXED_ROTATION.as_matrix()
    # R_rotated(t) = Rfix R(t) Rfix^T and omega_rotated(t) = Rfix omega(t).
    expected = fix @ _matrices(plain["q"]) @ fix.T
    assert np.abs(_matrices(rotated["q"]) - expected).max() <= REFERENCE_TOL
    w_scale = np.linalg.norm(base.bodies[0].angular_velocity)
    assert np.abs(rotated["w"] - plain["w"] @ fix.T).max() <= REFERENCE_TOL * w_scale
    # The COM is the rotation's fixed point here (box centred on the origin).
    np.testing.assert_allclose(rotated["x"], plain["x"] @ fix.T, atol=CLOSED_FORM_TOL)


def test_gravity_gives_a_ballistic_com():
    v0, g = (1.0, -2.0, 3.0), (0.0, 0.0, -10.0)
    scene = _scene("thrown", builders.box_corners((1, 2, 3), (4, 5, 6)), (0.1, 3, 0.1), v0, g)
    (state,) = exact_states(scene, SAMPLES)
    t = SAMPLES[:, None]
    x = np.array([4.0, 5.0, 6.0]) + np.array(v0) * t + 0.5 * np.array(g) * t**2
    scale = np.abs(x).max()
    np.testing.assert_allclose(state["x"], x, rtol=0, atol=CLOSED_FORM_TOL * scale)
    v = np.array(v0) + np.array(g) * t
    np.testing.assert_allclose(state["v"], v, rtol=0, atol=CLOSED_FORM_TOL * np.abs(v).max())
    # Uniform gravity exerts no torque about the COM: the rotation is the tumbling box's.
    (free,) = exact_states(CATALOG["tumbling_box"], SAMPLES)
    np.testing.assert_allclose(state["q"], free["q"], rtol=0, atol=CLOSED_FORM_TOL)


def test_times_in_any_order():
    times = np.array([3.0, -1.5, 0.0, 3.0, 7.25])
    (state,) = exact_states(CATALOG["tumbling_box"], times)
    for i, ti in enumerate(times):
        (single,) = exact_states(CATALOG["tumbling_box"], np.array([ti]))
        np.testing.assert_allclose(state["q"][i], single["q"][0], rtol=0, atol=CLOSED_FORM_TOL)
    # Backwards in time is the motion with omega reversed: R(-t; w0) = R(t; -w0).
    body = CATALOG["tumbling_box"].bodies[0]
    back, _ = torque_free_rotation(body.inertia, -np.array(body.angular_velocity), [1.5])
    assert np.abs(_matrices(back) - _matrices(state["q"][1:2])).max() <= REFERENCE_TOL


@pytest.mark.parametrize("scene", _tumbling_variants(), ids=lambda s: s.name)
def test_quadrature_converged(scene):
    body = scene.bodies[0]
    w0 = np.asarray(body.angular_velocity)
    q, w = torque_free_rotation(body.inertia, w0, SAMPLES)
    q_fine, w_fine = torque_free_rotation(body.inertia, w0, SAMPLES, nodes=32, panel_fraction=0.25)
    assert np.abs(q - q_fine).max() <= QUADRATURE_CONVERGENCE_TOL
    assert np.abs(w - w_fine).max() <= QUADRATURE_CONVERGENCE_TOL * np.linalg.norm(w0)


def _dop853(inertia, omega0, times, rtol):
    """Body-frame momentum and orientation integrated by DOP853: no eigen-decomposition."""
    inv = np.linalg.inv(inertia)

    def rhs(_, y):
        pi, (a0, a1, a2, a3) = y[:3], y[3:]
        b1, b2, b3 = inv @ pi
        dq = [
            -a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1,
        ]
        return np.concatenate([np.cross(pi, inv @ pi), 0.5 * np.array(dq)])

    l0 = inertia @ omega0
    atol = rtol * np.r_[np.full(3, np.linalg.norm(l0)), np.ones(4)] * 1e-2
    y0 = np.r_[l0, 1.0, 0.0, 0.0, 0.0]
    sol = solve_ivp(rhs, (0, times[-1]), y0, "DOP853", t_eval=times, rtol=rtol, atol=atol)
    q = sol.y[3:].T
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.mark.parametrize("scene", _tumbling_variants(), ids=lambda s: s.name)
def test_agrees_with_numerical_integration(scene):
    body = scene.bodies[0]
    (state,) = exact_states(scene, SAMPLES)
    q_num = _dop853(body.inertia, np.asarray(body.angular_velocity), SAMPLES, rtol=2.5e-14)
    # Compare rotations (sign-free): the integrated quaternion is continuous from +1 as well.
    diff = np.abs(_matrices(state["q"]) - _matrices(q_num)).max()
    assert diff <= DOP853_TOL, f"exact vs DOP853: {diff:.2e}"


def test_agrees_with_high_precision_integration():
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 30
    body = CATALOG["tumbling_box"].bodies[0]
    inertia = [mp.mpf(float(v)) for v in np.diag(body.inertia)]
    assert not np.any(body.inertia - np.diag(np.diag(body.inertia)))  # principal axes = world
    pi0 = [i * mp.mpf(float(w)) for i, w in zip(inertia, body.angular_velocity, strict=True)]

    def rhs(_, y):
        pi, (a0, a1, a2, a3) = y[:3], y[3:]
        b1, b2, b3 = (p / i for p, i in zip(pi, inertia, strict=True))
        return [
            pi[1] * b3 - pi[2] * b2,
            pi[2] * b1 - pi[0] * b3,
            pi[0] * b2 - pi[1] * b1,
            (-a1 * b1 - a2 * b2 - a3 * b3) / 2,
            (a0 * b1 + a2 * b3 - a3 * b2) / 2,
            (a0 * b2 - a1 * b3 + a3 * b1) / 2,
            (a0 * b3 + a1 * b2 - a2 * b1) / 2,
        ]

    times = np.array([0.0, 2.5, 5.0, 7.5, 10.0])
    taylor = mp.odefun(rhs, 0, [*pi0, mp.mpf(1), 0, 0, 0], tol=mp.mpf(10) ** -24, degree=24)
    q_ref = np.array([[float(v) for v in taylor(mp.mpf(t))[3:]] for t in times])
    (state,) = exact_states(CATALOG["tumbling_box"], times)
    diff = np.abs(state["q"] - q_ref).max()
    print(f"exact vs 30-digit integration: {diff:.1e}")
    assert diff <= HIGH_PRECISION_TOL, f"exact vs 30-digit integration: {diff:.2e}"
