"""The compiled exact free rotation (`reference_sim.exact_rotation`) against independent answers.

References: `cases.exact.torque_free_rotation` (closed form with a quadrature for the
precession, from t = 0), the same closed form evaluated with 40 digits (mpmath) for the
round-off of long steps, scipy's DOP853 on Euler's equations, and closed forms written here for
the special cases. Errors are geodesic angles (rad) between orientations. "rad turned" below is
|omega0| |dt|, the angle at the initial rate.
"""

import math
from typing import NamedTuple

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from cases import builders
from cases.catalog import CATALOG
from cases.exact import torque_free_rotation
from reference_sim.exact_rotation import EQUAL_MOMENTS_RTOL, exact_rotation
from reference_sim.model import build_model, rigid_initial_state
from rigidmath.quaternion import (
    quat_angle_between,
    quat_from_rotvec,
    quat_multiply,
    quat_to_matrix,
)

EPS = np.finfo(float).eps
# cases.exact's own error grows with the angle turned: against the 40-digit closed form it is
# up to 20 ulps per rad (high_spin and flat_plate over 100 s); ours is below 1 there. 3x the
# reference's worst.
REFERENCE_ULPS_PER_RAD = 64
# Against the 40-digit closed form: the angles are rates times dt (a few roundings per rad
# turned) and the result is a product of seven quaternions (a few ulps). Measured on random
# bodies: <= 4.5 ulps for short steps, <= 8.5 per rad for long steps near a principal axis;
# the catalog's cases stay below 1. 2x the random worst.
HIGH_PRECISION_ULPS_PER_RAD = 16
# One step's rounding, in ulps, per (1 + rad turned in the step): <= 4.5 measured (above).
# Composed steps add such roundings like a random walk (sqrt(N)), each amplified by the flow
# until the end by at most the case's amplification (measured by `_amplification`); the
# catalog's 1000 to 10000 steps reach 1.5 of that budget (high_spin), so 8 leaves 5x.
STEP_ULPS = 8
# Finite-difference step (rad) for the amplification of orientation errors by the flow: small
# enough to stay linear (amplifications reach 1e4: 1e-4 rad), large enough that rounding in
# the difference (1e-15 / 1e-8) is negligible.
PERTURBATION = 1e-8
# |q| after division by its computed norm: 1 to a couple of roundings.
UNIT_NORM_TOL = 1e-15
# DOP853's local error control at rtol 1e-12 leaves a global error of 1.4e-11 |L| over
# tumbling_box's 10 s (passing the unstable axis amplifies it; 7.5e-13 at rtol 1e-13, so the
# error is the integrator's, scaling with rtol). 7x that.
EULER_RTOL = 1e-10
EULER_SOLVER_RTOL = 1e-12

FREE_CASES = ["free_spin_cube", "tumbling_box", "tumbling_box_long", "high_spin"]
FREE_CASES += ["thin_rod", "flat_plate"]
ELLIPTIC_CASES = ["tumbling_box", "high_spin", "flat_plate"]  # three distinct moments
DTS = [1e-3, 0.01, 0.1, 1.0, 10.0, 100.0]
TURN = Rotation.from_rotvec([0.3, -0.7, 0.5])  # a generic fixed rotation
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
Q0 = np.roll(TURN.as_quat(), 1)  # w first: a generic start, not the identity


class Free(NamedTuple):
    """A free body: inertia (3, 3) and omega0 (3,) in world axes at t = 0, L = inertia omega0,
    and the simulator's principal moments (3,) and axes (3, 3, rows)."""

    inertia: np.ndarray
    omega0: np.ndarray
    L: np.ndarray
    moments: np.ndarray
    axes: np.ndarray

    @property
    def rate(self) -> float:
        return float(np.linalg.norm(self.omega0))


def _from_model(model, omega) -> Free:
    omega = np.asarray(omega, dtype=float)
    state = rigid_initial_state(model, [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], [omega])
    return Free(
        model.inertia0[0], omega, state.L[0], model.principal_moments[0], model.principal_axes[0]
    )


def _catalog_body(name: str) -> Free:
    """The scene's body as the simulator models it (what comparators.reference builds for a
    contact-free scene, without importing the engines)."""
    body = CATALOG[name].bodies[0]
    model = build_model([(body.particles, body.particle_radius)], (0.0, 0.0, 0.0))
    return _from_model(model, body.angular_velocity)


def _particle_body(rows, omega, turn: Rotation | None = None) -> Free:
    """A body of particle rows (x, y, z, m), turned by `turn` (particles and omega)."""
    rows = np.asarray(rows, dtype=float)
    if turn is not None:
        rows = np.column_stack([turn.apply(rows[:, :3]), rows[:, 3]])
        omega = turn.apply(omega)
    return _from_model(build_model([(rows, 0.2)], (0.0, 0.0, 0.0)), omega)


def _diagonal_body(moments, ang_mom) -> Free:
    """Principal axes along x, y, z: R^T L and the principal components are exact at q = 1."""
    moments = np.asarray(moments, dtype=float)
    ang_mom = np.asarray(ang_mom, dtype=float)
    return Free(np.diag(moments), ang_mom / moments, ang_mom, moments, np.eye(3))


def _step(body: Free, q, dt) -> np.ndarray:
    return np.array(exact_rotation(np.asarray(q, float), body.L, body.moments, body.axes, dt))


def _reference(body: Free, t: float) -> np.ndarray:
    q, _ = torque_free_rotation(body.inertia, body.omega0, np.array([t]))
    return q[0]


def _angle(p, q) -> float:
    return float(quat_angle_between(np.asarray(p, float), np.asarray(q, float)))


def _amplification(body: Free, q, duration: float, starts: int = 1) -> float:
    """Largest growth of a small orientation error under the flow, from `starts` times in
    [0, duration) to the end: max over body axes of angle(end(q dq), end(q)) / |dq| (>= 1)."""
    worst = 1.0
    for t0 in np.arange(starts) * (duration / starts):
        q0 = _step(body, q, t0) if t0 else np.asarray(q, float)
        end = _step(body, q0, duration - t0)
        for k in range(3):
            turned = quat_multiply(q0, quat_from_rotvec(PERTURBATION * np.eye(3)[k]))
            worst = max(worst, _angle(_step(body, turned, duration - t0), end) / PERTURBATION)
    return worst


@pytest.fixture(scope="module", params=FREE_CASES)
def case(request):
    return request.param, _catalog_body(request.param)


@pytest.mark.parametrize("dt", DTS)
def test_one_step_matches_the_reference(case, dt):
    name, body = case
    q = _step(body, IDENTITY, dt)
    err = _angle(q, _reference(body, dt))
    tol = REFERENCE_ULPS_PER_RAD * EPS * (1.0 + body.rate * dt)
    assert err <= tol, f"{name}: one step of {dt:g} s off the reference by {err:.3g} rad"
    assert abs(np.linalg.norm(q) - 1.0) <= UNIT_NORM_TOL, f"{name}: |q| = {np.linalg.norm(q)!r}"


def test_composed_steps_match_the_reference(case):
    """The case's own dt over its whole duration (1000 or 10000 steps)."""
    name, body = case
    scene = CATALOG[name]
    n = round(scene.duration / scene.dt)
    q = IDENTITY
    for _ in range(n):
        q = _step(body, q, scene.dt)
    err = _angle(q, _reference(body, scene.duration))
    growth = _amplification(body, IDENTITY, scene.duration, starts=10)
    tol = EPS * (
        REFERENCE_ULPS_PER_RAD * (1.0 + body.rate * scene.duration)
        + STEP_ULPS * math.sqrt(n) * growth * (1.0 + body.rate * scene.dt)
    )
    assert err <= tol, (
        f"{name}: {n} steps of {scene.dt:g} s off the reference by {err:.3g} rad "
        f"(tolerance {tol:.3g}, error amplification {growth:.3g})"
    )


@pytest.mark.parametrize(("dt1", "dt2"), [(0.37, 2.9), (3.3, -41.7), (0.01, 100.0)])
def test_two_steps_compose_to_one(case, dt1, dt2):
    name, body = case
    middle = _step(body, Q0, dt1)  # from a general start, not the identity
    err = _angle(_step(body, middle, dt2), _step(body, Q0, dt1 + dt2))
    tol = (
        STEP_ULPS
        * EPS
        * (
            _amplification(body, middle, dt2) * (1.0 + body.rate * abs(dt1))
            + (1.0 + body.rate * abs(dt2))
            + (1.0 + body.rate * abs(dt1 + dt2))
        )
    )
    assert err <= tol, f"{name}: steps {dt1:g} then {dt2:g} s differ from one by {err:.3g} rad"


@pytest.mark.parametrize("dt", [0.01, 1.0, 10.0, 100.0])
def test_step_back_returns(case, dt):
    name, body = case
    there = _step(body, Q0, dt)
    err = _angle(_step(body, there, -dt), Q0)
    turned = 1.0 + body.rate * dt
    tol = STEP_ULPS * EPS * (_amplification(body, there, -dt) * turned + turned)
    assert err <= tol, f"{name}: {dt:g} s forward and back misses q0 by {err:.3g} rad"


def test_unit_quaternion_out_of_an_unnormalised_one(case):
    name, body = case
    for dt in DTS:
        q = _step(body, 1.25 * Q0, dt)
        assert abs(np.linalg.norm(q) - 1.0) <= UNIT_NORM_TOL, f"{name}, dt {dt:g}: |q| - 1"


@pytest.mark.parametrize("dt", [5e-324, 1e16, -1e20, 1e300])
def test_any_step_length_gives_a_unit_quaternion(case, dt):
    """Beyond ~1e16 periods the phase is below rounding, but the result is still a rotation."""
    name, body = case
    q = _step(body, Q0, dt)
    assert np.all(np.isfinite(q)), f"{name}: dt {dt:g} gives {q}"
    assert abs(np.linalg.norm(q) - 1.0) <= UNIT_NORM_TOL, f"{name}: dt {dt:g}, |q| - 1"


def test_body_momentum_follows_eulers_equations():
    """pi = R^T L from single steps of 0..10 s against DOP853 on dpi/dt = pi x I0^-1 pi."""
    body = _catalog_body("tumbling_box")
    times = np.linspace(0.0, 10.0, 21)
    inv = np.linalg.inv(body.inertia)
    scale = np.linalg.norm(body.L)
    sol = solve_ivp(
        lambda t, y: np.cross(y, inv @ y),
        (0.0, times[-1]),
        body.L,
        method="DOP853",
        rtol=EULER_SOLVER_RTOL,
        atol=EULER_SOLVER_RTOL * scale,
        t_eval=times,
    )
    ours = np.array([quat_to_matrix(_step(body, IDENTITY, t)).T @ body.L for t in times])
    err = np.abs(ours - sol.y.T).max() / scale
    assert err <= EULER_RTOL, f"body angular momentum off DOP853 by {err:.3g} |L|"


# ---------------------------------------------------------------------------------------------
# The same closed form in 40 digits, from the same double inputs: checks round-off, not the
# formula (the reference and DOP853 above do that).


def _mp_rotation(mp, body: Free, dt: float):
    """R(dt) (mp 3 x 3) from R(0) = 1, for three distinct moments (Jacobi + Pi(n; am | m))."""

    def rot(axis, angle):
        c, s = mp.cos(angle), mp.sin(angle)
        if axis == "x":
            return mp.matrix([[1, 0, 0], [0, c, -s], [0, s, c]])
        return mp.matrix([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    def euler_b(p):  # Rx(theta) Rz(psi), taking p to |p| z
        return rot("x", mp.atan2(mp.sqrt(p[0] ** 2 + p[1] ** 2), p[2])) * rot(
            "z", mp.atan2(p[0], p[1])
        )

    moments = [mp.mpf(float(v)) for v in body.moments]
    axes = mp.matrix([[mp.mpf(float(v)) for v in row] for row in body.axes])
    p = axes * mp.matrix([mp.mpf(float(v)) for v in body.L])
    ia, ib, ic = moments
    if p[0] ** 2 * (1 / ib - 1 / ia) + p[2] ** 2 * (1 / ib - 1 / ic) >= 0:
        order, signs = (0, 1, 2), (1, 1, 1)
    else:
        order, signs = (2, 1, 0), (1, -1, 1)
    pi = [signs[k] * p[order[k]] for k in range(3)]
    flips = [1 if pi[0] >= 0 else -1, 0, 1 if pi[2] >= 0 else -1]
    flips[1] = flips[0] * flips[2]
    pi = [flips[k] * pi[k] for k in range(3)]
    frame = mp.matrix(3, 3)  # columns: the principal axes 1, 2, 3 in the body frame
    for k in range(3):
        for i in range(3):
            frame[i, k] = flips[k] * signs[k] * axes[order[k], i]
    i1, i2, i3 = (moments[k] for k in order)
    d12, d13, d23 = 1 / i1 - 1 / i2, 1 / i1 - 1 / i3, 1 / i2 - 1 / i3
    c0 = pi[0] ** 2 * d13 + pi[1] ** 2 * d23
    c1 = -(pi[1] ** 2 * d12 + pi[2] ** 2 * d13)
    a1, a2, a3 = mp.sqrt(c0 / d13), mp.sqrt(c0 / d23), mp.sqrt(-c1 / d13)
    m, n = -c0 * d12 / (d23 * c1), -d12 / d23
    lam = mp.sqrt(-d23 * c1) * mp.sign(d23)
    phi0 = mp.atan2(pi[1] / a2, pi[0] / a1)
    quarter = mp.ellipk(m)
    tau = mp.ellipf(phi0, m) + lam * mp.mpf(dt)
    turns = mp.nint(tau / (2 * quarter))
    rest = tau - 2 * quarter * turns
    sn, cn, dn = (mp.ellipfun(f, rest, m=m) for f in ("sn", "cn", "dn"))
    sign = -1 if int(turns) % 2 else 1
    l_norm = mp.sqrt(sum(v**2 for v in pi))
    third_kind = (
        mp.ellippi(n, mp.atan2(sn, cn), m) + 2 * turns * mp.ellippi(n, m) - mp.ellippi(n, phi0, m)
    )
    dphi = l_norm * mp.mpf(dt) / i3 + l_norm * d13 / lam * third_kind
    pi1 = [sign * a1 * cn, sign * a2 * sn, a3 * dn]
    return frame * euler_b(pi).T * rot("z", dphi) * euler_b(pi1) * frame.T


@pytest.mark.parametrize("dt", [1.0, 10.0, 100.0])
@pytest.mark.parametrize("name", ELLIPTIC_CASES)
def test_long_steps_at_round_off(name, dt):
    mp = pytest.importorskip("mpmath")
    body = _catalog_body(name)
    with mp.workdps(40):
        exact = _mp_rotation(mp, body, dt)
        q = [mp.mpf(float(v)) for v in _step(body, IDENTITY, dt)]
        w, x, y, z = q
        ours = mp.matrix(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        d = exact.T * ours  # the error rotation; its angle from the skew part (exact near 0)
        skew = mp.sqrt(
            (d[2, 1] - d[1, 2]) ** 2 + (d[0, 2] - d[2, 0]) ** 2 + (d[1, 0] - d[0, 1]) ** 2
        )
        err = float(mp.atan2(skew / 2, (d[0, 0] + d[1, 1] + d[2, 2] - 1) / 2))
    tol = HIGH_PRECISION_ULPS_PER_RAD * EPS * (1.0 + body.rate * dt)
    assert err <= tol, f"{name}: one step of {dt:g} s off 40 digits by {err:.3g} rad"


# ---------------------------------------------------------------------------------------------
# Regimes with their own closed forms or branches.

SYMMETRIC = {
    # box (1, 1, 3): two equal large moments, the symmetry axis has the smallest (prolate)
    "prolate": builders.box_corners((1.0, 1.0, 3.0)),
    # box (2, 2, 1): two equal small moments, the symmetry axis has the largest (oblate)
    "oblate": builders.box_corners((2.0, 2.0, 1.0)),
}


@pytest.mark.parametrize("dt", [0.1, 10.0, 100.0])
@pytest.mark.parametrize("shape", sorted(SYMMETRIC))
def test_symmetric_bodies_precess_regularly(shape, dt):
    body = _particle_body(SYMMETRIC[shape], (0.6, -0.3, 2.0), TURN)
    err = _angle(_step(body, IDENTITY, dt), _reference(body, dt))
    tol = REFERENCE_ULPS_PER_RAD * EPS * (1.0 + body.rate * dt)
    assert err <= tol, f"{shape}: one step of {dt:g} s off the reference by {err:.3g} rad"


@pytest.mark.parametrize("pair", ["low", "high"])
def test_moments_equal_within_tolerance_or_not_give_the_same_motion(pair):
    """Either side of EQUAL_MOMENTS_RTOL (closed-form precession or elliptic functions), the
    motions differ by the moments' difference times the angle turned, plus rounding."""
    dt, ang_mom = 10.0, np.array([0.7, -0.4, 1.1])
    bodies = []
    for factor in (0.5, 2.0):
        spread = 1.0 + factor * EQUAL_MOMENTS_RTOL
        moments = [1.0, spread, 2.0] if pair == "low" else [1.0, 2.0, 2.0 * spread]
        bodies.append(_diagonal_body(moments, ang_mom))
    err = _angle(_step(bodies[0], IDENTITY, dt), _step(bodies[1], IDENTITY, dt))
    turned = 1.0 + bodies[0].rate * dt
    tol = 2.0 * EQUAL_MOMENTS_RTOL * turned + 2 * STEP_ULPS * EPS * turned
    assert err <= tol, f"{pair} pair: the two sides of the tolerance differ by {err:.3g} rad"


@pytest.mark.parametrize("dt", [0.3, 1e3])
def test_isotropic_body_turns_about_l(dt):
    body = _diagonal_body([4.0, 4.0, 4.0], [1.2, -8.0, 4.4])
    expected = quat_multiply(quat_from_rotvec(body.L / 4.0 * dt), Q0)  # omega = L / I, world
    err = _angle(_step(body, Q0, dt), expected)
    assert err <= STEP_ULPS * EPS * (1.0 + body.rate * dt), f"off exp(omega dt) q0 by {err:.3g}"


def test_zero_angular_momentum_leaves_q():
    body = _catalog_body("tumbling_box")._replace(L=np.zeros(3))
    np.testing.assert_allclose(_step(body, Q0, 123.4), Q0, rtol=0, atol=UNIT_NORM_TOL)


@pytest.mark.parametrize("axis", [0, 1, 2], ids=["minor", "intermediate", "major"])
@pytest.mark.parametrize("dt", [0.3, 1e3])
def test_spin_about_a_principal_axis_is_steady(axis, dt):
    """L exactly along a principal axis, the unstable intermediate one included."""
    ang_mom = np.zeros(3)
    ang_mom[axis] = 2.5
    body = _diagonal_body([1.0, 2.0, 3.0], ang_mom)
    expected = quat_from_rotvec(body.omega0 * dt)  # about the body axis
    err = _angle(_step(body, IDENTITY, dt), expected)
    assert err <= STEP_ULPS * EPS * (1.0 + body.rate * dt), f"off the steady spin by {err:.3g}"


@pytest.mark.parametrize(
    "omega",
    [(0.1, 3.0, 0.12), (0.1, 3.0, 0.13)],
    ids=["around_major", "around_minor"],
)
@pytest.mark.parametrize("dt", [0.1, 1.0, 10.0])
def test_both_sides_of_the_separatrix(omega, dt):
    """The 1 x 2 x 3 box spun near its intermediate axis (y), its polhode circling either the
    major axis (x: L^2 / 2E > I_y) or the minor one (z: L^2 / 2E < I_y)."""
    body = _particle_body(builders.box_corners((1.0, 2.0, 3.0)), omega, TURN)
    err = _angle(_step(body, IDENTITY, dt), _reference(body, dt))
    tol = REFERENCE_ULPS_PER_RAD * EPS * (1.0 + body.rate * dt)
    assert err <= tol, f"{omega}: one step of {dt:g} s off the reference by {err:.3g} rad"


@pytest.mark.parametrize("dt", [0.5, 3.0, 10.0])
def test_exactly_on_the_separatrix(dt):
    """Moments (3, 6, 8) and L = (1, 0.5, 2): |L|^2 / I_2 - 2T = -1/6 + 4/24 is exactly 0 in
    doubles, the motion is aperiodic (m = 1, hyperbolic functions)."""
    body = _diagonal_body([3.0, 6.0, 8.0], [1.0, 0.5, 2.0])
    err = _angle(_step(body, IDENTITY, dt), _reference(body, dt))
    tol = REFERENCE_ULPS_PER_RAD * EPS * (1.0 + body.rate * dt)
    assert err <= tol, f"one step of {dt:g} s on the separatrix off the reference by {err:.3g}"


@pytest.mark.parametrize("offset", [1e-15, 1e-10, 1e-5])
def test_short_step_near_the_intermediate_axis(offset):
    """pi = (e, 1, e): m1 ~ e^2, the quarter period K = ln(4 / sqrt(m1)) long. A short step
    must still be exp(omega dt) (first order exact to (omega dt)^2 ~ 1e-19); the precession
    integrals are ~K in size and round to eps K each."""
    dt = 1e-9
    body = _diagonal_body([1.0, 2.0, 3.0], [offset, 1.0, offset])
    expected = quat_from_rotvec(body.omega0 * dt)  # about the body's angular velocity
    err = _angle(_step(body, IDENTITY, dt), expected)
    quarter = math.log(4.0 / offset)
    assert err <= STEP_ULPS * EPS * (1.0 + quarter), f"short step off by {err:.3g} rad"
