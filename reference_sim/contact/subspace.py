"""Subspace steps (projected Gauss-Seidel with subspace minimisation, after Silcowitz, Niebe and
Erleben 2010): the contacts that push are solved together, directly, then projected onto the
impulses' bounds. Gauss-Seidel alone removes a stack's slow modes (every level tilting
together) by well under 1 % a sweep."""

import math

from reference_sim.contact.impulses import row_speed, set_impulses
from reference_sim.contact.settings import (
    DISC_ROUNDING,
    SUBSPACE_MAX_BODIES,
    SUBSPACE_REGULARIZATION,
)
from reference_sim.dense import cholesky_into, cholesky_solve
from reference_sim.jit import inlined_kernel, kernel
from reference_sim.vec3 import conjugate_by, flat, mat, mat_vec


@kernel
def subspace_rows(model, nc, buf):
    """The subspace: rows (contact, direction) in `buf.rows` of every active contact that
    pushes, its normal, and its tangents too if it sticks; its bodies numbered in `buf.slot`.
    Returns the rows' count and the bodies' count, or -1 bodies for no subspace step: too many
    bodies, fewer rows than 6 per body, or, with friction, no contact that sticks."""
    cands, lam = buf.cands, buf.lam
    for b in range(buf.slot.shape[0]):
        buf.slot[b] = -1
    n_rows, n_bodies, any_sticks = 0, 0, False
    for k in range(nc):
        if not buf.active[k] or not lam[k, 0] > 0.0:
            continue
        limit = model.friction * lam[k, 0]
        sticks = lam[k, 1] ** 2 + lam[k, 2] ** 2 < limit * limit * (1.0 - DISC_ROUNDING)
        any_sticks = any_sticks or sticks
        for d in range(3 if sticks else 1):
            buf.rows[n_rows, 0], buf.rows[n_rows, 1] = k, d
            n_rows += 1
        for b in (cands[k, 0], cands[k, 2]):
            if b >= 0 and buf.slot[b] < 0:
                if n_bodies == SUBSPACE_MAX_BODIES:
                    return n_rows, -1
                buf.slot[b] = n_bodies
                n_bodies += 1
    # fewer rows than unknowns: bodies the subspace leaves free in some direction, moving on a
    # contact or two, where the sweeps are not slow and a step does not pay
    if model.friction > 0.0 and not any_sticks or n_rows < 6 * n_bodies:
        return n_rows, -1
    return n_rows, n_bodies


@kernel
def _subspace_speed(buf, r, du):
    """J_r du: the speed along subspace row r that the body velocity changes du (6 per slot)
    give."""
    k = buf.rows[r, 0]
    u = 0.0
    for side in range(2):
        b = buf.cands[k, 2 * side]
        if b >= 0:
            at = 6 * buf.slot[b]
            for i in range(6):
                u += buf.row_jac[r, 6 * side + i] * du[at + i]
    return u


@kernel
def _subspace_rhs(buf, n_rows, n, errors):
    """buf.rhs[:n] = J^T errors over the subspace rows."""
    for i in range(n):
        buf.rhs[i] = 0.0
    for r in range(n_rows):
        k, e = buf.rows[r, 0], errors[r]
        for side in range(2):
            b = buf.cands[k, 2 * side]
            if b >= 0:
                at = 6 * buf.slot[b]
                for i in range(6):
                    buf.rhs[at + i] += buf.row_jac[r, 6 * side + i] * e


@kernel
def _inertia(model, buf, b):
    """Body b's inertia tensor in the world frame (9,) (row major), at `buf.rot`."""
    return conjugate_by(flat(buf.rot, b), mat(model.inertia0, b))


@inlined_kernel
def _row_errors(buf, n_rows, v, errors):
    """Each subspace row's Jacobian on the bodies' (v, omega) into `buf.row_jac` (body a's,
    then body b's) and its speed error (target minus speed) into `errors`; returns the
    regularisation eps (SUBSPACE_REGULARIZATION times the largest normal inverse mass)."""
    eps = 0.0
    for r in range(n_rows):
        k, d = buf.rows[r, 0], buf.rows[r, 1]
        jac, jr = buf.jac[k, d], buf.row_jac[r]  # on (v, omega) of body a, then of body b
        for i in range(3):
            jr[i], jr[3 + i] = jac[0, i], jac[1, i]
            jr[6 + i], jr[9 + i] = -jac[0, i], -jac[3, i]
        aim = buf.target[k] if d == 0 else 0.0
        errors[r] = aim - row_speed(jac, buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
        eps = max(eps, SUBSPACE_REGULARIZATION * buf.kn[k])
    return eps


@inlined_kernel
def _regularised_normal(model, buf, n_rows, n, eps, a):
    """a[:n, :n] (upper triangle) = A = eps M + J^T J over the subspace rows."""
    for i in range(n):
        for j in range(n):
            a[i, j] = 0.0
    for r in range(n_rows):  # the upper triangle of J^T J
        jr, k = buf.row_jac[r], buf.rows[r, 0]
        for s in range(2):
            bs = buf.cands[k, 2 * s]
            for t in range(2):
                bt = buf.cands[k, 2 * t]
                if bs < 0 or bt < 0 or buf.slot[bt] < buf.slot[bs]:
                    continue
                at_s, at_t = 6 * buf.slot[bs], 6 * buf.slot[bt]
                for i in range(6):
                    f = jr[6 * s + i]
                    for j in range(i if s == t else 0, 6):
                        a[at_s + i, at_t + j] += f * jr[6 * t + j]
    for b in range(buf.slot.shape[0]):
        if buf.slot[b] < 0:
            continue
        at = 6 * buf.slot[b]
        inertia = _inertia(model, buf, b)
        for i in range(3):
            a[at + i, at + i] += eps * model.body_mass[b]
            for j in range(i, 3):
                a[at + 3 + i, at + 3 + j] += eps * inertia[3 * i + j]


@inlined_kernel
def _mass_times_rhs(model, buf):
    """buf.rhs <- M buf.rhs, body by body (mass, then world inertia)."""
    for b in range(buf.slot.shape[0]):
        if buf.slot[b] < 0:
            continue
        at = 6 * buf.slot[b]
        turn = mat_vec(_inertia(model, buf, b), (buf.rhs[at + 3], buf.rhs[at + 4], buf.rhs[at + 5]))
        for i in range(3):
            buf.rhs[at + i] *= model.body_mass[b]
            buf.rhs[at + 3 + i] = turn[i]


@inlined_kernel
def _apply_changes(model, nc, buf, n_rows, v, changes):
    """Add the rows' impulse changes `changes` to their contacts' impulses, projected onto the
    bounds, and apply them to v and omega; False, changing nothing, if a change is not finite."""
    for r in range(n_rows):
        if not math.isfinite(changes[r]):
            return False
    r = 0
    for k in range(nc):
        if r == n_rows:
            break
        if buf.rows[r, 0] != k:
            continue
        p0, p1, p2 = buf.lam[k, 0] + changes[r], buf.lam[k, 1], buf.lam[k, 2]
        if r + 1 < n_rows and buf.rows[r + 1, 0] == k:  # sticks: the tangents are rows too
            p1, p2 = p1 + changes[r + 1], p2 + changes[r + 2]
            r += 2
        r += 1
        set_impulses(model, buf, k, p0, p1, p2, v)
    return True


@kernel
def subspace_step(model, nc, buf, v):
    """Solve the subspace's equalities together (`subspace_rows`: each row's speed at its
    target), then project the impulses onto their bounds and apply the changes.

    Regularised by eps (SUBSPACE_REGULARIZATION): the impulse changes are dP = (W + eps)^-1 e'
    for the rows' speed errors e, W = J M^-1 J^T, where e' = J du1, du1 = A^-1 J^T e and
    A = eps M + J^T J (one system of 6 unknowns per body), is the part of e a motion of the
    bodies can meet, so that targets no rigid motion meets at once do not set impulses of order
    (their disagreement) / eps. Since (W + eps)^-1 J = J A^-1 M, dP is J A^-1 M du1: a second
    solve with the same factor, and no division by eps (which would lose about 8 of its 16
    digits to cancellation). Returns False, changing no impulse, if there is no subspace
    (`subspace_rows`) or the solve fails.
    """
    n_rows, n_bodies = subspace_rows(model, nc, buf)
    if n_rows == 0 or n_bodies < 0:
        return False
    n = 6 * n_bodies
    errors, a = buf.row_lam, buf.normal
    eps = _row_errors(buf, n_rows, v, errors)
    _regularised_normal(model, buf, n_rows, n, eps, a)
    if not cholesky_into(a, n):
        return False
    _subspace_rhs(buf, n_rows, n, errors)
    cholesky_solve(a, n, buf.rhs)  # du1
    _mass_times_rhs(model, buf)
    cholesky_solve(a, n, buf.rhs)
    for r in range(n_rows):  # the impulse changes
        errors[r] = _subspace_speed(buf, r, buf.rhs)
    return _apply_changes(model, nc, buf, n_rows, v, errors)
