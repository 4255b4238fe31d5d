"""The exact motion of contact-free scenes: the reference every engine is measured against.

Without contact every body moves on its own: its centre of mass falls ballistically and it
rotates torque-free (uniform gravity exerts no torque about the COM), so its world angular
momentum L = I0 omega0 is constant. Conventions: orientation q is a unit quaternion (w, x, y, z)
taking the body's placement at t = 0 to its current one (identity at t = 0); angular velocity is
in world axes; `Body.inertia` is the inertia about the COM in world axes at t = 0.

The rotation is evaluated in closed form, never by stepping an ODE, so nothing accumulates:

* isotropic inertia: omega is constant and q(t) = exp(omega0 t);
* axisymmetric inertia: regular precession, q(t) = exp(L t / I_t) exp(-Omega t s) with s the
  symmetry axis, I_t the transverse moment and Omega = (I_s - I_t) / I_t (omega0 . s);
* otherwise Jacobi's solution (Landau & Lifshitz, Mechanics, sec. 37): in principal axes
  (1, 2, 3), with 3 the axis the polhode circles and 2 the intermediate one, the body-frame
  angular momentum is pi = (a1 cn tau, a2 sn tau, a3 dn tau), tau = tau0 + lambda t. The
  orientation follows from Euler angles (z-x-z) in a frame whose z axis is along L: the nutation
  theta and spin psi are read off pi, and the precession phi' = |L| (pi1^2/I1 + pi2^2/I2) /
  (pi1^2 + pi2^2) is integrated by Gauss-Legendre quadrature of that analytic integrand.

The elliptic functions are computed here from both the parameter m and its complement
m1 = 1 - m, each formed without cancellation from the invariants. Near the separatrix (a spin
close to the intermediate axis, like `tumbling_box`) m1 is small, and rounding m alone to a
double (as scipy.special.ellipj takes it) would shift the quarter period K by ~1e-16 / m1
and the phase after a few periods by ~1e-13.

Accuracy, checked against a 42-digit Taylor-series integration (mpmath) of the same problem:
|q - q_ref| <= 5e-15 over tumbling_box's 10 s (101 samples), and <= 5e-15 on random bodies of
either polhode family, rotated or not. scipy's DOP853 at its tightest tolerance stops at
1e-13 to 5e-13 in q on tumbling_box (roundoff amplified while the box passes the unstable axis).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import elliprf

from cases.scene import Scene
from rigidmath.inertia import EQUAL_MOMENTS_RTOL
from rigidmath.quaternion import (
    quat_from_matrix,
    quat_from_rotvec,
    quats_conjugate,
    quats_multiply,
    quats_rotate,
)

# Gauss-Legendre nodes per quadrature panel of the precession rate. A panel is no longer than
# the distance of the integrand's nearest complex pole from the real time axis, so the error
# falls like (2 + sqrt 5)^(-2 n): 1e-25 at n = 20, far below rounding.
GAUSS_NODES = 20
# Panel length as a fraction of that pole distance.
PANEL_FRACTION = 1.0
# Panels beyond one per sample interval that the precession quadrature may take: 5,000 times the
# most a catalog case needs (21: `tumbling_box` at its last sample). A body whose rate has a pole
# far closer to the real axis than its period (moments equal to 1e-13, say) would need millions:
# its exact orientation is then NaN, "no exact answer", rather than memory it cannot have.
MAX_EXTRA_PANELS = 100_000
# The arithmetic-geometric mean has converged when c_n / a_n is below the double's epsilon.
_EPS = np.finfo(float).eps
_MAX_AGM_STEPS = 64


def exact_trajectory_available(scene: Scene) -> bool:
    """True when `exact_states` can give the scene's motion: nothing to collide with."""
    return not scene.has_contact


def exact_states(scene: Scene, times: np.ndarray) -> list[dict[str, np.ndarray]]:
    """Per body (scene order): {'x': (S,3), 'q': (S,4), 'v': (S,3), 'w': (S,3)} at `times` (S,).

    'x' and 'v' are the centre of mass position and velocity, 'q' the orientation quaternion
    (w, x, y, z), 'w' the angular velocity in world axes. Raises ValueError for a scene with
    contact, whose outcome has no closed form here.
    """
    if scene.has_contact:
        raise ValueError(
            f"scene {scene.name!r} has contact ({scene.modelled()}): contact outcomes have no "
            "closed form, so exact states exist only for contact-free scenes"
        )
    t = np.asarray(times, dtype=float)
    if t.ndim != 1 or not np.all(np.isfinite(t)):
        raise ValueError(f"times must be a finite 1-D array, got shape {t.shape}")
    g = np.asarray(scene.gravity, dtype=float)
    states = []
    for body in scene.bodies:
        v0 = np.asarray(body.velocity, dtype=float)
        x = body.com + np.outer(t, v0) + 0.5 * np.outer(t * t, g)
        v = v0 + np.outer(t, g)
        q, w = torque_free_rotation(body.inertia, np.asarray(body.angular_velocity, float), t)
        states.append({"x": x, "q": q, "v": v, "w": w})
    return states


def torque_free_rotation(
    inertia: np.ndarray,
    omega0: np.ndarray,
    times: np.ndarray,
    *,
    nodes: int = GAUSS_NODES,
    panel_fraction: float = PANEL_FRACTION,
) -> tuple[np.ndarray, np.ndarray]:
    """Orientation (S, 4) and world angular velocity (S, 3) of a torque-free rigid body.

    `inertia` (3, 3) and `omega0` (3,) are in world axes at t = 0, where q = identity.
    `nodes` and `panel_fraction` set the precession quadrature (for convergence checks).
    """
    inertia = np.asarray(inertia, dtype=float)
    omega0 = np.asarray(omega0, dtype=float)
    t = np.asarray(times, dtype=float)
    moments, axes = np.linalg.eigh(inertia)
    ang_mom = inertia @ omega0
    spread = moments[-1] * EQUAL_MOMENTS_RTOL
    if moments[-1] - moments[0] <= spread or not np.any(omega0):
        return _steady(omega0, t)
    low_pair = moments[1] - moments[0] <= spread
    if low_pair or moments[2] - moments[1] <= spread:
        # Symmetry axis: the eigenvector of the distinct moment.
        k = 2 if low_pair else 0
        transverse = 0.5 * (moments[1] + moments[0 if low_pair else 2])
        return _precession(ang_mom, axes[:, k], moments[k], transverse, t)
    return _jacobi(ang_mom, omega0, moments, axes, t, nodes, panel_fraction)


def _steady(omega0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation at constant omega0: isotropic inertia or a spin about a principal axis."""
    q = np.array([quat_from_rotvec(omega0 * ti) for ti in t]).reshape(len(t), 4)
    return q, np.tile(omega0, (len(t), 1))


def _precession(ang_mom, axis, i_sym, i_trans, t) -> tuple[np.ndarray, np.ndarray]:
    """Regular precession of an axisymmetric body (moment i_sym about `axis`, i_trans across).

    The body turns about L at |L| / I_t and, relative to that, about its own symmetry axis at
    -Omega = -(I_s - I_t) / I_t * omega_s, with omega_s = L.s / I_s constant:
    R(t) = Rot(L t / I_t) Rot(-Omega t s).
    """
    l_sym = float(ang_mom @ axis)
    rate = -(i_sym - i_trans) / i_trans * (l_sym / i_sym)
    q = np.empty((len(t), 4))
    for i, ti in enumerate(t):
        q[i] = quats_multiply(
            quat_from_rotvec(ang_mom * (ti / i_trans)), quat_from_rotvec(axis * (rate * ti))
        )
    # omega = I(t)^-1 L with I(t)^-1 = (1 - s s^T) / I_t + s s^T / I_s and s(t) = R(t) s.
    s_t = quats_rotate(q, axis)
    w = ang_mom / i_trans + (1.0 / i_sym - 1.0 / i_trans) * l_sym * s_t
    return q, w


def _jacobi(ang_mom, omega0, moments, axes, t, nodes, panel_fraction):
    """Torque-free motion of a body with three distinct moments, via Jacobi elliptic functions."""
    i_a, i_b, i_c = moments
    p_a, p_c = axes[:, 0] @ ang_mom, axes[:, 2] @ ang_mom
    # M^2/I_b - 2T: its sign says which extreme axis the polhode circles (zero: the separatrix).
    sep = p_a * p_a * (1 / i_b - 1 / i_a) + p_c * p_c * (1 / i_b - 1 / i_c)
    if sep >= 0:
        e1, e3, i1, i3 = axes[:, 0], axes[:, 2], i_a, i_c
    else:
        e1, e3, i1, i3 = axes[:, 2], axes[:, 0], i_c, i_a
    i2 = i_b
    # Signs so that pi1, pi3 >= 0 at t = 0 (a rotation by pi about a principal axis is a
    # symmetry of Euler's equations); e2 completes a right-handed frame.
    e1 = e1 if e1 @ ang_mom >= 0 else -e1
    e3 = e3 if e3 @ ang_mom >= 0 else -e3
    frame = np.column_stack([e1, np.cross(e3, e1), e3])  # principal coordinates -> world
    pi0 = frame.T @ ang_mom
    if pi0[0] == 0 and (pi0[1] == 0 or pi0[2] == 0):
        return _steady(omega0, t)  # exactly along a principal axis: a steady spin
    d12, d13, d23 = 1 / i1 - 1 / i2, 1 / i1 - 1 / i3, 1 / i2 - 1 / i3
    # c0 = 2T - M^2/I3 and c1 = 2T - M^2/I1, each a sum of same-sign terms (no cancellation).
    c0 = pi0[0] ** 2 * d13 + pi0[1] ** 2 * d23
    c1 = -(pi0[1] ** 2 * d12 + pi0[2] ** 2 * d13)
    a1, a2, a3 = math.sqrt(c0 / d13), math.sqrt(c0 / d23), math.sqrt(-c1 / d13)
    # The parameter and its complement, the latter proportional to the separatrix distance.
    m = -c0 * d12 / (d23 * c1)
    m1 = -d13 * sep / (d23 * c1)
    # lambda^2 = (1/I3 - 1/I2) c1; its sign makes tau advance along pi' = pi x I^-1 pi.
    lam = math.copysign(math.sqrt(-d23 * c1), d23)
    m_ang = math.sqrt(pi0 @ pi0)

    # Initial phase: cn tau0 = pi1 / a1 >= 0 and sn tau0 = pi2 / a2, so tau0 = F(phi0 | m).
    tau0 = _elliptic_f(math.atan2(pi0[1] / a2, pi0[0] / a1), m, m1)

    def state(tt):
        """Body-frame momentum pi and the Euler angles theta, psi (unwrapped) at times tt."""
        amp = _jacobi_am(tau0 + lam * np.asarray(tt, dtype=float), m, m1)
        c, s = np.cos(amp), np.sin(amp)
        p1, p2, p3 = a1 * c, a2 * s, a3 * np.sqrt(c * c + m1 * s * s)
        theta = np.arctan2(np.hypot(p1, p2), p3)
        # psi = atan2(pi1, pi2) = pi/2 - atan2(a2 sin am, a1 cos am), unwrapped along am.
        psi = 0.5 * np.pi - amp - np.arctan2((a2 - a1) * s * c, a1 * c * c + a2 * s * s)
        return p1, p2, p3, theta, psi

    def precession_rate(tt):
        p1, p2, *_ = state(tt)
        return m_ang * (p1 * p1 / i1 + p2 * p2 / i2) / (p1 * p1 + p2 * p2)

    # The rate's nearest poles: sn^2(tau) = -r at tau = +-i v + periods, v = F(atan sqrt r | m1).
    pole = _elliptic_f(math.atan(math.sqrt(d23 / d12)), m1, m) / abs(lam)
    # The rate repeats with pi1^2, pi2^2: every 2K(m) in tau (infinite on the separatrix).
    period = 2.0 * _elliptic_f(0.5 * math.pi, m, m1) / abs(lam)
    phi = _periodic_integral(precession_rate, t, period, pole * panel_fraction, nodes)
    p1, p2, p3, theta, psi = state(t)
    _, _, _, theta0, psi0 = state(np.zeros(1))
    # A(t) = Rz(phi) Rx(theta) Rz(psi) maps principal coordinates to a frame with z along L;
    # the world rotation is R(t) = frame A(0)^T A(t) frame^T, the identity at t = 0.
    q_frame = quat_from_matrix(frame)
    q_start = quats_conjugate(_zxz_quat(np.zeros(1), theta0, psi0))
    q = quats_multiply(
        quats_multiply(q_frame, quats_multiply(q_start, _zxz_quat(phi, theta, psi))),
        quats_conjugate(q_frame),
    )
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    # omega = R(t) frame I^-1 pi(t).
    w_body = np.column_stack([p1 / i1, p2 / i2, p3 / i3]) @ frame.T
    return q, quats_rotate(q, w_body)


def _jacobi_am(u, m, m1):
    """Jacobi amplitude am(u | m) by the arithmetic-geometric mean (A&S 16.4), from m and m1.

    Starting from b0 = sqrt(m1) rather than sqrt(1 - m) keeps full precision near m = 1.
    """
    u = np.asarray(u, dtype=float)
    if m1 == 0:
        return np.arctan(np.sinh(u))  # m = 1: am is the Gudermannian
    a, b, c = 1.0, math.sqrt(m1), math.sqrt(m)
    ratios = []
    for _ in range(_MAX_AGM_STEPS):
        if c <= _EPS * a:
            break
        a, b, c = 0.5 * (a + b), math.sqrt(a * b), c * c / (2.0 * (a + b))
        ratios.append(c / a)
    amp = (2.0 ** len(ratios) * a) * u
    for ratio in reversed(ratios):
        amp = 0.5 * (amp + np.arcsin(ratio * np.sin(amp)))
    return amp


def _elliptic_f(phi, m, m1):
    """Incomplete elliptic integral F(phi | m) for |phi| <= pi/2, via Carlson's R_F and m1."""
    s, c = math.sin(phi), math.cos(phi)
    return s * float(elliprf(c * c, c * c + m1 * s * s, 1.0))


def _periodic_integral(f, t, period, max_panel, nodes):
    """integral_0^t f for every t, of an f repeating every `period`: whole periods counted,
    the rest by `_cumulative_integral`, so that the work does not grow with t / period (a spin
    of 1e30 rad/s over a second would otherwise take 1e28 panels)."""
    if not math.isfinite(period) or len(t) == 0 or np.max(t) <= period:
        return _cumulative_integral(f, t, max_panel, nodes)
    rest = np.fmod(t, period)  # exact, and within [0, period) however many periods t spans
    whole = np.round((t - rest) / period)
    parts = _cumulative_integral(f, np.concatenate([[period], rest]), max_panel, nodes)
    return whole * parts[0] + parts[1:]


def _cumulative_integral(f, t, max_panel, nodes):
    """integral_0^t f for every t, by Gauss-Legendre panels no longer than `max_panel`."""
    grid, where = np.unique(np.concatenate([[0.0], t]), return_inverse=True)
    if len(grid) == 1:
        return np.zeros(len(t))
    widths = np.diff(grid)
    counts = np.ceil(np.maximum(1.0, widths / max_panel))
    if not counts.sum() - len(widths) <= MAX_EXTRA_PANELS:  # NaN too
        return np.full(len(t), np.nan)  # no exact answer rather than an inaccurate one
    counts = counts.astype(int)
    interval = np.repeat(np.arange(len(widths)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    h = widths[interval] / counts[interval]
    lo = grid[interval] + (np.arange(len(interval)) - first) * h
    x, wts = np.polynomial.legendre.leggauss(nodes)
    mid, half = lo + 0.5 * h, 0.5 * h
    values = f((mid[:, None] + half[:, None] * x).ravel()).reshape(-1, nodes)
    panels = half * (values @ wts)
    sums = np.zeros(len(widths))
    np.add.at(sums, interval, panels)
    cumulative = np.concatenate([[0.0], np.cumsum(sums)])
    cumulative -= cumulative[where[0]]  # zero at t = 0
    return cumulative[where[1:]]


def _zxz_quat(phi, theta, psi):
    """(S, 4) quaternions of Rz(phi) Rx(theta) Rz(psi)."""
    ch, sh = np.cos(0.5 * theta), np.sin(0.5 * theta)
    plus, minus = 0.5 * (phi + psi), 0.5 * (phi - psi)
    return np.column_stack(
        [ch * np.cos(plus), sh * np.cos(minus), sh * np.sin(minus), ch * np.sin(plus)]
    )
