"""A contact's speed along its Jacobian, and impulses applied to its two bodies' velocities:
the operations every solve is built from."""

import math

from reference_sim.jit import inlined_kernel, kernel


@kernel
def row_speed(rows, a, b, v, omega):
    """Relative velocity of a contact along the direction of its Jacobian `rows` (5, 3)."""
    # two sums of three, not one running sum of six: a Gauss-Seidel sweep waits on each speed
    # in turn (`gauss_seidel.update`), and this halves the additions in a row
    u = (rows[0, 0] * v[a, 0] + rows[0, 1] * v[a, 1] + rows[0, 2] * v[a, 2]) + (
        rows[1, 0] * omega[a, 0] + rows[1, 1] * omega[a, 1] + rows[1, 2] * omega[a, 2]
    )
    if b >= 0:
        u -= (rows[0, 0] * v[b, 0] + rows[0, 1] * v[b, 1] + rows[0, 2] * v[b, 2]) + (
            rows[3, 0] * omega[b, 0] + rows[3, 1] * omega[b, 1] + rows[3, 2] * omega[b, 2]
        )
    return u


@inlined_kernel
def push(model, jac, a, b, v, omega, p0, p1, p2):
    """Apply the impulse changes p0 (normal), p1, p2 (tangents) along a contact's Jacobian
    `jac` (3, 5, 3) to both bodies' v and omega (d omega = I^-1 (r x P)): summed per body
    first, then each changed once. A solve carries L over once at its end
    (`frames.angular_momenta`): nothing reads L during it."""
    along_a = 1.0 / model.body_mass[a]
    along_b = 1.0 / model.body_mass[b] if b >= 0 else 0.0
    for i in range(3):
        force = p0 * jac[0, 0, i] + p1 * jac[1, 0, i] + p2 * jac[2, 0, i]
        v[a, i] += along_a * force
        omega[a, i] += p0 * jac[0, 2, i] + p1 * jac[1, 2, i] + p2 * jac[2, 2, i]
        if b >= 0:
            v[b, i] -= along_b * force
            omega[b, i] -= p0 * jac[0, 4, i] + p1 * jac[1, 4, i] + p2 * jac[2, 4, i]


@kernel
def into_disc(mu, p0, p1, p2):
    """Friction impulse (p1, p2) scaled back onto the Coulomb disc |P_t| <= mu p0 if outside it."""
    limit = mu * p0
    if p1 * p1 + p2 * p2 > limit * limit:
        shrink = limit / math.sqrt(p1 * p1 + p2 * p2)
        p1, p2 = p1 * shrink, p2 * shrink
    return p1, p2


@kernel
def set_impulses(model, buf, k, p0, p1, p2, v):
    """Set contact k's impulses (normal p0, friction p1, p2) projected onto its bounds (normal
    >= 0, friction in the Coulomb disc), and apply their changes to v and omega."""
    p0 = max(p0, 0.0)
    p1, p2 = into_disc(model.friction, p0, p1, p2)
    lam = buf.lam[k]
    d0, d1, d2 = p0 - lam[0], p1 - lam[1], p2 - lam[2]
    if d0 != 0.0 or d1 != 0.0 or d2 != 0.0:
        push(model, buf.jac[k], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega, d0, d1, d2)
        lam[0], lam[1], lam[2] = p0, p1, p2
