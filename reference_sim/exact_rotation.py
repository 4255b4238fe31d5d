"""The exact torque-free (Euler-Poinsot) rotation of a rigid body over one step, compiled.

(Over 500 lines: one closed-form method, most of it the derivation below and the special
functions it alone uses.)

`exact_rotation(q, L, moments, axes, dt)` returns the orientation after the free flow for a
time dt, in closed form, with scalars only (no arrays are allocated), for the simulator's loop.
Conventions as in `reference_sim.rigid`: q (w, x, y, z) maps the body frame (the world frame at
t = 0) to the world, the world angular momentum L is constant, `moments` (3,) are the principal
moments ascending and the rows of `axes` (3, 3) the principal axes in the body frame (det +1).

Method. With pi = R^T L in principal coordinates (1, 2, 3), 3 the axis the polhode circles
and 2 the intermediate one, Euler's equations are solved by Jacobi's elliptic functions
(Landau & Lifshitz, Mechanics, sec. 37):

    pi(t) = (a1 cn tau, a2 sn tau, a3 dn tau),   tau = tau0 + lambda t,

with the parameter m and its complement m1 = 1 - m each formed from the invariants without
cancellation (m1 is proportional to the distance from the separatrix). The initial phase is
tau0 = F(phi0 | m) (Carlson's R_F). tau is reduced modulo 2K (the period of pi up to the sign
of pi1, pi2), so a long step costs the same as a short one; the phase is carried as j K + offset
so that a short step near a quarter period does not form K - tau by cancellation. sn, cn, dn
come from the amplitude am(x | m) by the arithmetic-geometric mean (descending Landen
transformation, A&S 16.4.3, started from sqrt(m1) to keep full precision near m = 1), with
|x| <= K/2: beyond K/2 they follow from x = K - |tau| (sn = cd, cn = sqrt(m1) sd, dn = sqrt(m1)
nd), and for small m1 dn is summed from its series of sech terms (all positive), so that cn
and dn keep their relative precision where they are small (the body near the intermediate
axis), which cos(am) would not.

The attitude is written as (principal -> world) = U Rz(phi) Rx(theta) Rz(psi), U a fixed
rotation taking z to L: theta and psi are read off pi and only the precession phi about L
needs integrating. Its rate |L| (pi1^2/I1 + pi2^2/I2) / (pi1^2 + pi2^2) is a weighted mean of
|L|/I1 and |L|/I2; it is split as |L|/I_hi + |L| (1/I_lo - 1/I_hi) w, w the weight of the
smaller of I1, I2, so that both terms are positive and nothing cancels. The integral of w is
an incomplete elliptic integral of the third kind, Pi - F, here (s^3/3) R_J(c^2, c^2 + m1 s^2,
1, c^2 + k s^2) in Carlson's form (Celledoni, Fasso, Safstrom & Zanna 2008, "The exact
computation of the free rigid body motion and its use in splitting methods", SIAM J. Sci.
Comput. 30; I. I. Kosenko 1998, "Integration of the equations of a rotational motion of a
rigid body in quaternion algebra. The Euler case", J. Appl. Math. Mech. 62). When I1 < I2
the weight of pi1 is integrated after shifting the phase by K (sn(tau + K) = cd tau), which
turns it into the same form. Carlson's R_F and R_J are evaluated by duplication (Carlson
1995, "Numerical computation of real or complex elliptic integrals", Numer. Algorithms 10).
The step is then

    q(t + dt) = q(t) P B(pi0)^-1 Rz(dphi) B(pi1) P^-1,   B(pi) = Rx(theta) Rz(psi),

with P the principal frame (as a rotation of the body frame), all as quaternion products.

Special cases, each in closed form: L = 0 or dt = 0 (q unchanged); all moments equal (rotation
about L at |L|/I); two equal moments (regular precession, no elliptic functions); pi exactly
along axis 3 or along the intermediate axis (steady spin); exactly on the separatrix (m1 = 0:
hyperbolic functions, no period).
"""

import math

import numpy as np

from reference_sim.jit import inlined_kernel, kernel
from reference_sim.quaternion import qfrom_matrix, qmul
from rigidmath.inertia import EQUAL_MOMENTS_RTOL

# Truncation bound of Carlson's duplication (relative error of R_F and R_J before rounding):
# the unit roundoff, so truncation stays below the rounding of the result.
CARLSON_RTOL = 2.0**-53
# Carlson 1995: duplicate until 4^-n max|A0 - x_i| / |A_n| is below (3r)^(1/6) for R_F and
# (r/4)^(1/6) for R_J, r the relative truncation bound.
_RF_SCALE = (3.0 * CARLSON_RTOL) ** (-1.0 / 6.0)
_RJ_SCALE = (0.25 * CARLSON_RTOL) ** (-1.0 / 6.0)
# Never reached: each duplication divides the spread of the arguments by 4, and 4^-n spans
# 1e-308 in 512 of them; a guard against non-finite input, not a convergence criterion.
MAX_DUPLICATIONS = 600
# The arithmetic-geometric mean has converged when c_n / a_n is below the double's epsilon: a
# further level would change am by less than a rounding of its result.
AGM_TOL = 2.0**-52
# Levels needed: 5 at m = 1/2, 10 at m1 = 1e-30, 13 at the smallest m1 a double holds (b/a
# reaches O(1) in log2(ln(1/b0)) levels, then converges quadratically). A bound only.
MAX_AGM_LEVELS = 40
# Below this m1 = 1 - m, dn is summed from its series of sech terms (below) instead of being
# formed from cos(am): am is accurate to a rounding in absolute terms only, so cos(am) ~ m1^(1/4)
# near a quarter period carries a relative error of eps / m1^(1/4), 3 eps at m1 = 1e-2, and
# unbounded as m1 -> 0 (the body near the saddle of the intermediate axis).
M1_SERIES_MAX = 1e-2
# The sech series has converged when a pair of terms adds less than this, relative: the unit
# roundoff. Pair n is ~ 2 q1^(n - 1/4) for |x| <= K/2, q1 = exp(-pi K / K') the complementary
# nome (6.3e-4 at m1 = 1e-2, ~ m1 / 16 below): 6 pairs at m1 = 1e-2, 3 at 1e-6.
SERIES_RTOL = 2.0**-53
# A bound only (see above).
MAX_SERIES_TERMS = 64
# R_C(1, 1 + e) by its series in e below this |e|: the first term left out, e^6 / 13, is below
# 1e-19 there (2^-10 ~ 1e-3), and the duplication's later terms all fall in this range.
RC_SERIES_MAX = 2.0**-10
# A reduced phase j K + offset farther than this many K from 0 (it is within K up to rounding)
# means the step's phase lambda dt was too large to represent: its rounding exceeds a period.
LOST_PHASE = 1.5
# sin(a/2)/a by its Taylor series below this angle (rad): the next term, a^4/3840, is below
# 1e-19 relative there, and the division loses nothing above it.
SMALL_ANGLE = 1e-4


@kernel
def _carlson_rf(x, y, z):
    """Carlson's R_F(x, y, z) for x, y, z >= 0, at most one zero (duplication, Carlson 1995)."""
    x0, y0 = x, y
    a0 = (x + y + z) / 3.0
    a = a0
    spread = _RF_SCALE * max(abs(a0 - x), abs(a0 - y), abs(a0 - z))
    fac = 1.0  # 4^-n
    for _ in range(MAX_DUPLICATIONS):
        if fac * spread < abs(a):
            break
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * sy + sx * sz + sy * sz
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
        a = 0.25 * (a + lam)
        fac *= 0.25
    dx = (a0 - x0) * fac / a
    dy = (a0 - y0) * fac / a
    dz = -dx - dy
    e2 = dx * dy - dz * dz
    e3 = dx * dy * dz
    return (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0) / math.sqrt(a)


@kernel
def _carlson_rc1(e):
    """R_C(1, 1 + e) for e > -1: atan(sqrt e) / sqrt e, or atanh for e < 0."""
    if abs(e) < RC_SERIES_MAX:
        # sum_k (-e)^k / (2k + 1), through k = 5
        return 1.0 + e * (-1.0 / 3.0 + e * (0.2 + e * (-1.0 / 7.0 + e * (1.0 / 9.0 - e / 11.0))))
    if e > 0.0:
        r = math.sqrt(e)
        return math.atan(r) / r
    if e < 0.0:
        r = math.sqrt(-e)
        return math.atanh(r) / r
    return 1.0


@kernel
def _carlson_rj(x, y, z, p):
    """Carlson's R_J(x, y, z, p) for x, y, z >= 0 (at most one zero), p > 0 (Carlson 1995)."""
    x0, y0, z0 = x, y, z
    a0 = (x + y + z + 2.0 * p) / 5.0
    a = a0
    delta = (p - x) * (p - y) * (p - z)
    spread = _RJ_SCALE * max(abs(a0 - x), abs(a0 - y), abs(a0 - z), abs(a0 - p))
    fac = 1.0  # 4^-n
    total = 0.0
    for _ in range(MAX_DUPLICATIONS):
        if fac * spread < abs(a):
            break
        sx, sy, sz, sp = math.sqrt(x), math.sqrt(y), math.sqrt(z), math.sqrt(p)
        lam = sx * sy + sx * sz + sy * sz
        d = (sp + sx) * (sp + sy) * (sp + sz)
        total += fac * _carlson_rc1(delta * fac * fac * fac / (d * d)) / d
        x, y, z, p = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam), 0.25 * (p + lam)
        a = 0.25 * (a + lam)
        fac *= 0.25
    dx = (a0 - x0) * fac / a
    dy = (a0 - y0) * fac / a
    dz = (a0 - z0) * fac / a
    dp = -0.5 * (dx + dy + dz)
    xyz = dx * dy * dz
    e2 = dx * dy + dx * dz + dy * dz - 3.0 * dp * dp
    e3 = xyz + 2.0 * e2 * dp + 4.0 * dp * dp * dp
    e4 = (2.0 * xyz + e2 * dp + 3.0 * dp * dp * dp) * dp
    e5 = xyz * dp * dp
    series = (
        1.0
        - 3.0 * e2 / 14.0
        + e3 / 6.0
        + 9.0 * e2 * e2 / 88.0
        - 3.0 * e4 / 22.0
        - 9.0 * e2 * e3 / 52.0
        + 3.0 * e5 / 26.0
    )
    return fac * series / (a * math.sqrt(a)) + 6.0 * total


@kernel
def _agm_step(a, b, c):
    """One level of the arithmetic-geometric mean (a, b) and c = (a - b) / 2, without a - b."""
    a_next = 0.5 * (a + b)
    return a_next, math.sqrt(a * b), 0.25 * c * c / a_next


@kernel
def _agm_levels(m, m1):
    """(levels, a_N): the AGM of 1 and sqrt(m1) has converged after `levels` steps; K = pi/2a_N."""
    a, b, c = 1.0, math.sqrt(m1), math.sqrt(m)
    levels = 0
    while c > AGM_TOL * a and levels < MAX_AGM_LEVELS:
        a, b, c = _agm_step(a, b, c)
        levels += 1
    return levels, a


@kernel
def _jacobi_am(u, m, m1, levels, a_last):
    """Jacobi amplitude am(u | m) by the descending AGM (A&S 16.4.3), from m and m1 = 1 - m.

    The backward recurrence needs c_n / a_n in reverse order; they are recomputed from the
    start for each level instead of stored, which keeps this free of allocation (numba's
    cached recursion was not an option: it crashed on reload). With 5 to 10 levels the
    quadratic cost is 15 to 55 AGM steps, one square root each.
    """
    amp = math.ldexp(a_last * u, levels)
    for level in range(levels, 0, -1):
        a, b, c = 1.0, math.sqrt(m1), math.sqrt(m)
        for _ in range(level):
            a, b, c = _agm_step(a, b, c)
        amp = 0.5 * (amp + math.asin(c / a * math.sin(amp)))
    return amp


@kernel
def _dn_series(x, quarter, quarter_c):
    """dn(x | m) = pi / (2 K') sum_n sech(pi (x - 2 n K) / (2 K')), all terms positive.

    quarter = K(m), quarter_c = K' = K(m1). Used for small m1, where the terms fall fast.
    """
    f = 0.5 * math.pi / quarter_c
    total = 1.0 / math.cosh(f * x)
    for n in range(1, MAX_SERIES_TERMS):
        shift = 2.0 * n * quarter
        pair = 1.0 / math.cosh(f * (x - shift)) + 1.0 / math.cosh(f * (x + shift))
        total += pair
        if pair <= SERIES_RTOL * total:
            break
    return f * total


@kernel
def _jacobi_sncndn(j, offset, m, m1, quarter, quarter_c, levels, a_last):
    """sn, cn, dn (r | m) at r = j K + offset, |r| <= K, each to a few roundings of itself.

    Beyond K/2 they come from u = K - |r| (sn = cd u, cn = sqrt(m1) sd u, dn = sqrt(m1) nd u),
    formed as (1 -+ j) K -+ offset so that j = +-1 cancels exactly, and cn near its zero at K is
    not the cosine of an amplitude close to pi/2. For small m1, dn(x) is summed from its sech
    series and cn(x) = sqrt(dn^2 - m1 sn^2) (dn^2 >= sqrt(m1) >> m1 sn^2 for |x| <= K/2: no
    cancellation), so that cd x, sd x and nd x are all relatively accurate too.
    quarter = K, quarter_c = K' (read only when m1 < M1_SERIES_MAX).
    """
    r = j * quarter + offset
    far = abs(r) > 0.5 * quarter
    if far:
        x = (1.0 - j) * quarter - offset if r >= 0.0 else (1.0 + j) * quarter + offset
    else:
        x = r
    amp = _jacobi_am(x, m, m1, levels, a_last)
    sx, cx = math.sin(amp), math.cos(amp)
    if m1 < M1_SERIES_MAX:
        dx = _dn_series(x, quarter, quarter_c)
        cx = math.sqrt(max(dx * dx - m1 * sx * sx, 0.0))
    else:
        dx = math.sqrt(cx * cx + m1 * sx * sx)
    if far:
        rm1 = math.sqrt(m1)
        return math.copysign(cx / dx, r), rm1 * sx / dx, rm1 / dx
    return sx, cx, dx


@kernel
def _weight_integral(s, c, m1, k):
    """(s^3 / 3) R_J(c^2, c^2 + m1 s^2, 1, c^2 + k s^2): integral_0^u sn^2 / (1 - (1 - k) sn^2).

    u = F(am | m) with sin am = s, cos am = c >= 0; the arguments are sums of same-sign terms.
    """
    cc, ss = c * c, s * s
    return s * ss * _carlson_rj(cc, cc + m1 * ss, 1.0, cc + k * ss) / 3.0


@kernel
def _qexp(vx, vy, vz):
    """The rotation by angle |v| about v / |v| (any |v|: sin and cos reduce the angle)."""
    angle = math.sqrt(vx * vx + vy * vy + vz * vz)
    if math.isinf(angle):  # squares overflowed (|v| > 1e154): the norm of the scaled vector
        big = max(abs(vx), abs(vy), abs(vz))
        angle = big * math.sqrt((vx / big) ** 2 + (vy / big) ** 2 + (vz / big) ** 2)
    if angle < SMALL_ANGLE:
        s = 0.5 - angle * angle / 48.0
    else:
        s = math.sin(0.5 * angle) / angle
    return math.cos(0.5 * angle), s * vx, s * vy, s * vz


@kernel
def _euler_b(p1, p2, p3):
    """Quaternion of B(pi) = Rx(theta) Rz(psi), the rotation taking pi to |pi| z."""
    theta = math.atan2(math.sqrt(p1 * p1 + p2 * p2), p3)
    psi = math.atan2(p1, p2)
    ct, st = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cp, sp = math.cos(0.5 * psi), math.sin(0.5 * psi)
    # (ct, st, 0, 0) (cp, 0, 0, sp)
    return ct * cp, st * cp, -st * sp, ct * sp


@inlined_kernel
def _separatrix_flow(sn0, cn0, lam, n, dt):
    """On the separatrix (m1 = 0): sn = tanh, cn = dn = sech, no period. Here I3 is the largest,
    so I1 < I2 and w1 = sech^2 / (1 + nu tanh^2), whose integral is atan(sqrt(nu) tanh)/sqrt(nu).
    Returns sn, cn, dn after the step, the sign flip of pi1, pi2 (none) and the integral of w."""
    tau0 = math.asinh(sn0 / cn0)
    tau1 = tau0 + lam * dt
    sn1, cn1 = math.tanh(tau1), 1.0 / math.cosh(tau1)
    dn1 = cn1
    flip = 1.0
    r = math.sqrt(-n)
    dw = (math.atan(r * sn1) - math.atan(r * sn0)) / r
    return sn1, cn1, dn1, flip, dw


@inlined_kernel
def _phase_after(sn0, cn0, dn0, ee, m1, quarter, lam, dt):
    """The phase after the step as j1 K + offset (j1 an integer, |phase| <= K up to rounding),
    and the half periods `turns` it was reduced by. Kept so, not as tau, so that a short step
    near a quarter period (near the intermediate axis, m1 small) never forms K - tau by
    cancellation. |tau0| > K/2 when sn(K - |tau0|) = cd tau0 < sn(K/2)."""
    if cn0 * cn0 * (1.0 + math.sqrt(m1)) < ee:
        # tau0 = +-(K - u0), sn u0 = cn0 / dn0, cn u0 = sqrt(m1) |sn0| / dn0
        su, cu = cn0 / dn0, math.sqrt(m1) * abs(sn0) / dn0
        j0 = math.copysign(1.0, sn0)
        offset = -j0 * su * _carlson_rf(cu * cu, cu * cu + m1 * su * su, 1.0)
    else:
        j0 = 0.0
        offset = sn0 * _carlson_rf(cn0 * cn0, ee, 1.0)  # F(phi0 | m), |phi0| <= pi/2
    offset += lam * dt
    turns = np.floor((j0 * quarter + offset) / (2.0 * quarter) + 0.5)
    j1 = j0 - 2.0 * turns
    rest = j1 * quarter + offset
    if abs(rest) > LOST_PHASE * quarter:
        # |lambda dt| so large that its rounding exceeds a period (dt ~ 1e16 periods): the
        # phase is lost anyway; reduce what is left so the functions stay in range.
        j1, offset = 0.0, rest - 2.0 * quarter * np.floor(rest / (2.0 * quarter) + 0.5)
    return j1, offset, turns


@inlined_kernel
def _weight_change(sn0, cn0, dn0, sn1, cn1, dn1, m1, n, turns, lo_is_1):
    """The integral over the step of the weight w of the smaller of I1, I2 (in tau)."""
    if lo_is_1:
        # w1(tau) = k sn^2(v) / (1 - (1 - k) sn^2(v)), v = tau + K, k = m1 / (1 - n):
        # sn v = cn tau / dn tau, |cn v| = sqrt(m1) |sn tau| / dn tau, and cn v < 0 for
        # tau > 0, where the integral from 0 to v is 2 G(K) - G(2K - v).
        k = m1 / (1.0 - n)
        rm1 = math.sqrt(m1)
        w0 = _weight_integral(cn0 / dn0, rm1 * abs(sn0) / dn0, m1, k)
        w1 = _weight_integral(cn1 / dn1, rm1 * abs(sn1) / dn1, m1, k)
        if sn0 > 0.0:
            w0 = -w0
            turns_w = turns - 1.0
        else:
            turns_w = turns
        if sn1 > 0.0:
            w1 = -w1
            turns_w += 1.0
    else:
        # w2(tau) = k sn^2 / (1 - n sn^2), k = 1 - n = a2^2 / a1^2.
        k = 1.0 - n
        w0 = _weight_integral(sn0, cn0, m1, k)
        w1 = _weight_integral(sn1, cn1, m1, k)
        turns_w = turns
    # Each half period adds 2 G(K); G(K) only when needed (one R_J fewer).
    complete = _weight_integral(1.0, 0.0, m1, k) if turns_w != 0.0 else 0.0
    return k * (w1 - w0 + 2.0 * turns_w * complete)


@inlined_kernel
def _elliptic_flow(sn0, cn0, m, m1, lam, n, lo_is_1, dt):
    """Off the separatrix: sn, cn, dn after the step, the sign flip of pi1, pi2 (-1 after an odd
    number of half periods) and the integral of the weight w."""
    ee = cn0 * cn0 + m1 * sn0 * sn0
    dn0 = math.sqrt(ee)
    levels, a_last = _agm_levels(m, m1)
    quarter = 0.5 * math.pi / a_last  # K; pi -> (-pi1, -pi2, pi3) over 2K
    j1, offset, turns = _phase_after(sn0, cn0, dn0, ee, m1, quarter, lam, dt)
    quarter_c = 0.0
    if m1 < M1_SERIES_MAX:
        quarter_c = 0.5 * math.pi / _agm_levels(m1, m)[1]  # K' = K(m1)
    sn1, cn1, dn1 = _jacobi_sncndn(j1, offset, m, m1, quarter, quarter_c, levels, a_last)
    flip = -1.0 if turns % 2.0 != 0.0 else 1.0
    dw = _weight_change(sn0, cn0, dn0, sn1, cn1, dn1, m1, n, turns, lo_is_1)
    return sn1, cn1, dn1, flip, dw


@kernel
def _principal_step(p1, p2, p3, i1, i2, i3, sep, l_norm, dt):
    """Rotation (w, x, y, z) in principal coordinates over dt: B(pi0)^-1 Rz(dphi) B(pi1).

    pi = (p1, p2, p3) with p1 >= 0, p3 > 0 and p1, p2 not both zero; (1, 2, 3) a right-handed
    principal frame with 3 the axis the polhode circles; sep = |L|^2 / I2 - 2T (>= 0 when
    I3 is the largest moment, < 0 when the smallest).
    """
    # 1/Ii - 1/Ij from the differences of the moments, exact for close moments.
    d12 = (i2 - i1) / (i1 * i2)
    d13 = (i3 - i1) / (i1 * i3)
    d23 = (i3 - i2) / (i2 * i3)
    # c0 = 2T - L^2/I3 and c1 = 2T - L^2/I1, each a sum of same-sign terms (no cancellation).
    c0 = p1 * p1 * d13 + p2 * p2 * d23
    c1 = -(p2 * p2 * d12 + p3 * p3 * d13)
    a1 = math.sqrt(c0 / d13)
    a2 = math.sqrt(c0 / d23)
    a3 = math.sqrt(-c1 / d13)
    m = -c0 * d12 / (d23 * c1)
    m1 = -d13 * sep / (d23 * c1)
    # lambda^2 = (1/I3 - 1/I2) c1; its sign makes tau advance along pi' = pi x I^-1 pi.
    lam = math.copysign(math.sqrt(-d23 * c1), d23)
    n = -d12 / d23  # the characteristic: 1 - n sn^2 = (pi1^2 + pi2^2) / a1^2, n < 0
    # Phase: cn tau0 = pi1 / a1 >= 0, sn tau0 = pi2 / a2 (renormalised against rounding).
    cn0, sn0 = p1 / a1, p2 / a2
    h = math.sqrt(cn0 * cn0 + sn0 * sn0)
    cn0, sn0 = cn0 / h, sn0 / h
    lo_is_1 = i1 < i2  # the smaller of I1, I2; its weight is integrated
    i_hi = i2 if lo_is_1 else i1
    if m1 == 0.0:
        sn1, cn1, dn1, flip, dw = _separatrix_flow(sn0, cn0, lam, n, dt)
    else:
        sn1, cn1, dn1, flip, dw = _elliptic_flow(sn0, cn0, m, m1, lam, n, lo_is_1, dt)
    # dphi/dt = |L| / I_hi + |L| (1/I_lo - 1/I_hi) w_lo, with d tau = lambda dt.
    dphi = l_norm * (dt / i_hi + abs(d12) * dw / lam)
    q1 = _euler_b(flip * a1 * cn1, flip * a2 * sn1, a3 * dn1)
    b0 = _euler_b(p1, p2, p3)
    cz, sz = math.cos(0.5 * dphi), math.sin(0.5 * dphi)
    # Rz(dphi) B(pi1), then B(pi0)^-1 on the left.
    t = qmul((cz, 0.0, 0.0, sz), q1)
    return qmul((b0[0], -b0[1], -b0[2], -b0[3]), t)


@kernel
def _signed_unit(p, qw, qx, qy, qz):
    """p normalised, and negated if it points away from q (q and -q are the same rotation)."""
    n = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3])
    if p[0] * qw + p[1] * qx + p[2] * qy + p[3] * qz < 0.0:
        n = -n
    return p[0] / n, p[1] / n, p[2] / n, p[3] / n


@inlined_kernel
def _isotropic(qw, qx, qy, qz, lx, ly, lz, ia, ib, ic, dt):
    """All moments equal: omega = L / I is constant in the world."""
    s = dt * 3.0 / (ia + ib + ic)
    e = _qexp(s * lx, s * ly, s * lz)
    out = qmul(e, (qw, qx, qy, qz))
    return _signed_unit(out, qw, qx, qy, qz)


@inlined_kernel
def _body_momentum(qw, qx, qy, qz, lx, ly, lz):
    """Body-frame angular momentum R^T L: L rotated by the conjugate of q."""
    ux, uy, uz = -qx, -qy, -qz
    tx = 2.0 * (uy * lz - uz * ly)
    ty = 2.0 * (uz * lx - ux * lz)
    tz = 2.0 * (ux * ly - uy * lx)
    bx = lx + qw * tx + (uy * tz - uz * ty)
    by = ly + qw * ty + (uz * tx - ux * tz)
    bz = lz + qw * tz + (ux * ty - uy * tx)
    return bx, by, bz


@inlined_kernel
def _axisymmetric(qw, qx, qy, qz, lx, ly, lz, bx, by, bz, moments, axes, low_pair, dt):
    """Two moments equal (the lower pair if `low_pair`): R(t + dt) = Rot(L dt / I_t) R(t)
    Rot_body(s, rate dt), s the symmetry axis, rate = (1/I_s - 1/I_t) (L . s), the spin
    relative to the precessing frame."""
    ia, ib, ic = moments[0], moments[1], moments[2]
    k = 2 if low_pair else 0
    i_sym = moments[k]
    i_trans = 0.5 * (ia + ib) if low_pair else 0.5 * (ib + ic)
    sx, sy, sz = axes[k, 0], axes[k, 1], axes[k, 2]
    rate = (i_trans - i_sym) / (i_sym * i_trans) * (sx * bx + sy * by + sz * bz) * dt
    spin = _qexp(rate * sx, rate * sy, rate * sz)
    f = dt / i_trans
    e = _qexp(f * lx, f * ly, f * lz)
    t = qmul((qw, qx, qy, qz), spin)
    out = qmul(e, t)
    return _signed_unit(out, qw, qx, qy, qz)


@inlined_kernel
def _steady_spin(qw, qx, qy, qz, p1, p2, p3, i2, i3, f2, f3, e2, e3, dt):
    """pi along axis 3 (p1 = p2 = 0), or at the saddle, axis 2 (p1 = p3 = 0): a steady spin
    omega = I^-1 pi in the body; a rotation about a body-frame axis multiplies on the right."""
    if p1 * p1 + p2 * p2 == 0.0:
        w = p3 / i3 * dt
        e = _qexp(w * f3 * e3[0], w * f3 * e3[1], w * f3 * e3[2])
    else:
        w = p2 / i2 * dt
        e = _qexp(w * f2 * e2[0], w * f2 * e2[1], w * f2 * e2[2])
    out = qmul((qw, qx, qy, qz), e)
    return _signed_unit(out, qw, qx, qy, qz)


@inlined_kernel
def _triaxial(qw, qx, qy, qz, bx, by, bz, moments, axes, l_norm, dt):
    """Three distinct moments: the elliptic flow (`_principal_step`) in the principal frame of
    the axis the polhode circles, composed with the body's orientation."""
    ia, ib, ic = moments[0], moments[1], moments[2]
    a0 = (axes[0, 0], axes[0, 1], axes[0, 2])
    a1 = (axes[1, 0], axes[1, 1], axes[1, 2])
    a2 = (axes[2, 0], axes[2, 1], axes[2, 2])
    pa = a0[0] * bx + a0[1] * by + a0[2] * bz
    pb = a1[0] * bx + a1[1] * by + a1[2] * bz
    pc = a2[0] * bx + a2[1] * by + a2[2] * bz
    # |L|^2 / I_b - 2T: its sign says which extreme axis the polhode circles (0: separatrix).
    sep = pa * pa * (ia - ib) / (ia * ib) + pc * pc * (ic - ib) / (ib * ic)
    if sep >= 0.0:  # around the largest moment: (1, 2, 3) = (a, b, c)
        e1, e2, e3 = a0, a1, a2
        p1, p2, p3, i1, i2, i3 = pa, pb, pc, ia, ib, ic
    else:  # around the smallest: (1, 2, 3) = (c, -b, a), still right-handed
        e1, e2, e3 = a2, (-a1[0], -a1[1], -a1[2]), a0
        p1, p2, p3, i1, i2, i3 = pc, -pb, pa, ic, ib, ia
    # A rotation by pi about a principal axis maps solutions to solutions: pick the signs of the
    # axes (an even number of flips keeps the frame right-handed) so that p1 >= 0 and p3 >= 0.
    f1 = 1.0 if p1 >= 0.0 else -1.0
    f3 = 1.0 if p3 >= 0.0 else -1.0
    f2 = f1 * f3
    p1, p2, p3 = f1 * p1, f2 * p2, f3 * p3
    # Squares, not components: the elliptic path divides by a1 ~ sqrt(p1^2 + p2^2).
    if p1 * p1 + p2 * p2 == 0.0 or p1 * p1 + p3 * p3 == 0.0:
        return _steady_spin(qw, qx, qy, qz, p1, p2, p3, i2, i3, f2, f3, e2, e3, dt)
    d = _principal_step(p1, p2, p3, i1, i2, i3, sep, l_norm, dt)
    # The principal frame P as a rotation of the body frame: columns f1 e1, f2 e2, f3 e3.
    pw, px, py, pz = qfrom_matrix(
        (
            f1 * e1[0],
            f2 * e2[0],
            f3 * e3[0],
            f1 * e1[1],
            f2 * e2[1],
            f3 * e3[1],
            f1 * e1[2],
            f2 * e2[2],
            f3 * e3[2],
        )
    )
    t = qmul(d, (pw, -px, -py, -pz))
    t = qmul((pw, px, py, pz), t)
    out = qmul((qw, qx, qy, qz), t)
    return _signed_unit(out, qw, qx, qy, qz)


@kernel
def exact_rotation(q, L, moments, axes, dt):
    """Orientation (w, x, y, z) after the torque-free flow for time dt, in closed form.

    q: (4,) orientation (w, x, y, z), normalised here. L: (3,) world angular momentum (kg m^2/s),
    constant during the step. moments: (3,) principal moments ascending (kg m^2). axes: (3, 3)
    rows are the principal axes in the body frame, det +1. dt: s, any sign and size.
    The result is a unit quaternion, signed to lie on the same side as q (w0 w + x0 x + ... >= 0).
    """
    n0 = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    qw, qx, qy, qz = q[0] / n0, q[1] / n0, q[2] / n0, q[3] / n0
    lx, ly, lz = L[0], L[1], L[2]
    l_norm = math.sqrt(lx * lx + ly * ly + lz * lz)
    if l_norm == 0.0 or dt == 0.0:
        return qw, qx, qy, qz
    ia, ib, ic = moments[0], moments[1], moments[2]
    spread = EQUAL_MOMENTS_RTOL * ic
    if ic - ia <= spread:
        return _isotropic(qw, qx, qy, qz, lx, ly, lz, ia, ib, ic, dt)
    bx, by, bz = _body_momentum(qw, qx, qy, qz, lx, ly, lz)
    low_pair = ib - ia <= spread
    if low_pair or ic - ib <= spread:
        return _axisymmetric(qw, qx, qy, qz, lx, ly, lz, bx, by, bz, moments, axes, low_pair, dt)
    return _triaxial(qw, qx, qy, qz, bx, by, bz, moments, axes, l_norm, dt)
