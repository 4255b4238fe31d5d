"""Contact for the rigid integrators: impulses, not penalties.

Why impulses: a penalty spring stiff enough to hold the 8 kg cube within 2 mm needs k above
4e4 N/m, and an explicit step is then unstable at the seed's dt = 0.01 (omega dt > 2). Impulses
have no stiffness, so contact costs no step-size limit and a resting body sits exactly on the
surface.

After each smooth step (free flight and gravity) the integrators call `resolve_contacts`:

1. Candidates: particle-plane pairs, and particle pairs of *different* bodies whose bounding
   spheres overlap, closer than one particle radius. Particles of one body are never paired.
2. Position projection (non-linear Gauss-Seidel): each penetrating contact moves its bodies
   apart along the normal, through the contact's effective mass, until no penetration exceeds
   `POSITION_TOLERANCE`. This is the resting body's height to that tolerance, with no creep.
3. Velocity impulses (projected Gauss-Seidel with accumulated impulses) on touching contacts:
   normal impulse >= 0 reaching the target normal speed -e * v_n (impacts faster than the bounce
   threshold) or 0 (resting contacts); Coulomb friction impulse inside the disc |P_t| <= mu P_n.
   Impulses change the COM velocity and the world angular momentum (dL = r x P).
"""

import numpy as np
from numba import njit

from reference_sim.quaternion import quat_from_rotvec, quat_multiply, quat_normalize, quat_to_matrix

# Penetration left by the position projection (m): far below the 2 mm rest-height tolerance
# and far above rounding of metre-scale coordinates (1e-16 m).
POSITION_TOLERANCE = 1e-10
# A contact is touching, and gets velocity impulses, when its gap is below this (m): ten times
# the projection tolerance, so every projected contact counts and no separated one does.
TOUCH_TOLERANCE = 1e-9
# Stop Gauss-Seidel when no impulse changes a normal speed by more than this (m/s).
VELOCITY_TOLERANCE = 1e-13
MAX_ITERATIONS = 500


@njit(cache=True)
def _update_frame(model, q, rot, inv, b):
    """Rotation matrix and world inverse inertia of body b from its quaternion."""
    rot[b] = quat_to_matrix(q[b])
    inv[b] = rot[b] @ model.inertia0_inv[b] @ rot[b].T


@njit(cache=True)
def body_frames(model, q):
    """(B, 3, 3) rotation matrices and world inverse inertias of every body."""
    nb = q.shape[0]
    rot = np.empty((nb, 3, 3))
    inv = np.empty((nb, 3, 3))
    for b in range(nb):
        _update_frame(model, q, rot, inv, b)
    return rot, inv


@njit(cache=True)
def find_candidates(model, x, q):
    """Contacts to consider this step: (body a, particle i, body b or -1, particle j or plane)."""
    nb = model.body_mass.shape[0]
    npl = model.plane_points.shape[0]
    npt = model.offsets.shape[0]
    cap = npt * npl + 16
    out = np.empty((cap, 4), dtype=np.int64)
    k = 0
    for b in range(nb):
        rot = quat_to_matrix(q[b])
        for i in range(model.body_start[b], model.body_start[b + 1]):
            p = x[b] + rot @ model.offsets[i]
            for j in range(npl):
                n = model.plane_normals[j]
                gap = np.dot(n, p - model.plane_points[j]) - model.radius[i]
                if gap < model.radius[i]:
                    out[k] = (b, i, -1, j)
                    k += 1
    for a in range(nb):
        for b in range(a + 1, nb):
            d = x[a] - x[b]
            if np.sqrt(np.dot(d, d)) > model.bound_radius[a] + model.bound_radius[b]:
                continue
            ra = quat_to_matrix(q[a])
            rb = quat_to_matrix(q[b])
            for i in range(model.body_start[a], model.body_start[a + 1]):
                pa = x[a] + ra @ model.offsets[i]
                for j in range(model.body_start[b], model.body_start[b + 1]):
                    pb = x[b] + rb @ model.offsets[j]
                    dd = pa - pb
                    gap = np.sqrt(np.dot(dd, dd)) - model.radius[i] - model.radius[j]
                    if gap < min(model.radius[i], model.radius[j]):
                        if k == out.shape[0]:
                            grown = np.empty((2 * k, 4), dtype=np.int64)
                            grown[:k] = out
                            out = grown
                        out[k] = (a, i, b, j)
                        k += 1
    return out[:k]


@njit(cache=True)
def contact_geometry(model, x, rot, c):
    """Normal n (from b towards a), gap (m), lever arms r_a, r_b from each COM to the contact.

    `rot` holds the bodies' rotation matrices (`body_frames`).
    """
    a, i, b, j = c[0], c[1], c[2], c[3]
    pa = x[a] + rot[a] @ model.offsets[i]
    if b < 0:
        n = model.plane_normals[j].copy()
        gap = np.dot(n, pa - model.plane_points[j]) - model.radius[i]
        point = pa - model.radius[i] * n
        return n, gap, point - x[a], np.zeros(3)
    pb = x[b] + rot[b] @ model.offsets[j]
    d = pa - pb
    dist = np.sqrt(np.dot(d, d))
    n = d / dist if dist > 0 else np.array([0.0, 0.0, 1.0])
    gap = dist - model.radius[i] - model.radius[j]
    point = 0.5 * (pa - model.radius[i] * n + pb + model.radius[j] * n)
    return n, gap, point - x[a], point - x[b]


@njit(cache=True)
def _inverse_mass_along(model, inv_a, inv_b, a, b, ra, rb, n):
    """Effective inverse mass of the contact along direction n."""
    rn = np.cross(ra, n)
    k = 1.0 / model.body_mass[a] + np.dot(rn, inv_a @ rn)
    if b >= 0:
        rn = np.cross(rb, n)
        k += 1.0 / model.body_mass[b] + np.dot(rn, inv_b @ rn)
    return k


@njit(cache=True)
def _move_apart(model, x, q, rot, inv, a, b, ra, rb, push):
    """Displace bodies a and b by the position impulse `push` (along n) at lever arms ra, rb."""
    x[a] += push / model.body_mass[a]
    q[a] = quat_normalize(quat_multiply(quat_from_rotvec(inv[a] @ np.cross(ra, push)), q[a]))
    _update_frame(model, q, rot, inv, a)
    if b >= 0:
        x[b] -= push / model.body_mass[b]
        q[b] = quat_normalize(quat_multiply(quat_from_rotvec(-(inv[b] @ np.cross(rb, push))), q[b]))
        _update_frame(model, q, rot, inv, b)


@njit(cache=True)
def _project_positions(model, x, q, cands):
    """Solve gap >= 0 with accumulated position impulses >= 0 (projected Gauss-Seidel).

    Accumulating lets a contact give back an earlier push, so contacts sharing a load (a cube
    on its face) end exactly touching instead of being over-pushed one after another.
    """
    rot, inv = body_frames(model, q)
    acc = np.zeros(cands.shape[0])
    for it in range(MAX_ITERATIONS):
        moved = 0.0
        for k in range(cands.shape[0]):
            c = cands[k]
            n, gap, ra, rb = contact_geometry(model, x, rot, c)
            if gap >= 0.0 and acc[k] == 0.0:
                continue
            a, b = c[0], c[2]
            kn = _inverse_mass_along(model, inv[a], inv[max(b, 0)], a, b, ra, rb, n)
            new = max(acc[k] - gap / kn, 0.0)
            dl = new - acc[k]
            acc[k] = new
            if dl != 0.0:
                _move_apart(model, x, q, rot, inv, a, b, ra, rb, dl * n)
                moved = max(moved, abs(dl) * kn)
        if moved < POSITION_TOLERANCE:
            return it + 1
    return MAX_ITERATIONS


@njit(cache=True)
def _tangents(n):
    """Two unit vectors completing n to a right-handed orthonormal basis."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.57735 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, helper)
    t1 /= np.sqrt(np.dot(t1, t1))
    return t1, np.cross(n, t1)


@njit(cache=True)
def _speed(jac, a, b, v, omega, k, d):
    """Relative velocity of contact k along its direction d (0 normal, 1 and 2 tangents)."""
    u = 0.0
    for i in range(3):
        u += jac[k, d, 0, i] * v[a, i] + jac[k, d, 1, i] * omega[a, i]
        if b >= 0:
            u -= jac[k, d, 0, i] * v[b, i] + jac[k, d, 3, i] * omega[b, i]
    return u


@njit(cache=True)
def _push(model, jac, a, b, v, L, omega, k, d, lam):
    """Apply the impulse lam along direction d of contact k to both bodies (dL = r x P)."""
    for i in range(3):
        v[a, i] += lam * jac[k, d, 0, i] / model.body_mass[a]
        L[a, i] += lam * jac[k, d, 1, i]
        omega[a, i] += lam * jac[k, d, 2, i]
        if b >= 0:
            v[b, i] -= lam * jac[k, d, 0, i] / model.body_mass[b]
            L[b, i] -= lam * jac[k, d, 3, i]
            omega[b, i] -= lam * jac[k, d, 4, i]


@njit(cache=True)
def _solve_velocities(model, x, q, v, L, cands, bounce_threshold):
    """Projected Gauss-Seidel on the touching contacts' normal and friction impulses.

    Per contact and direction (normal, two tangents) the Jacobian rows are precomputed:
    jac[k, d] = (direction, r_a x dir, I_a^-1 (r_a x dir), r_b x dir, I_b^-1 (r_b x dir)), so a
    sweep allocates nothing. Friction is solved as a 2 x 2 block and projected onto the disc.
    """
    nb = model.body_mass.shape[0]
    rot, inv = body_frames(model, q)
    omega = np.empty((nb, 3))
    for b in range(nb):
        omega[b] = inv[b] @ L[b]
    nc = cands.shape[0]
    active = np.zeros(nc, dtype=np.bool_)
    jac = np.zeros((nc, 3, 5, 3))
    kn = np.ones(nc)
    kt_inv = np.zeros((nc, 2, 2))
    target = np.zeros(nc)
    for k in range(nc):
        a, b = cands[k, 0], cands[k, 2]
        n, gap, ra, rb = contact_geometry(model, x, rot, cands[k])
        if gap > TOUCH_TOLERANCE:
            continue
        active[k] = True
        t1, t2 = _tangents(n)
        for d, direction in enumerate((n, t1, t2)):
            jac[k, d, 0] = direction
            jac[k, d, 1] = np.cross(ra, direction)
            jac[k, d, 2] = inv[a] @ jac[k, d, 1]
            if b >= 0:
                jac[k, d, 3] = np.cross(rb, direction)
                jac[k, d, 4] = inv[b] @ jac[k, d, 3]
        inv_mass = 1.0 / model.body_mass[a] + (1.0 / model.body_mass[b] if b >= 0 else 0.0)
        kmat = np.empty((3, 3))
        for d in range(3):
            for e in range(3):
                kmat[d, e] = (
                    inv_mass * np.dot(jac[k, d, 0], jac[k, e, 0])
                    + np.dot(jac[k, d, 1], jac[k, e, 2])
                    + np.dot(jac[k, d, 3], jac[k, e, 4])
                )
        kn[k] = kmat[0, 0]
        kt_inv[k] = np.linalg.inv(kmat[1:, 1:])
        vn = _speed(jac, a, b, v, omega, k, 0)
        if vn < -bounce_threshold:
            target[k] = -model.restitution * vn
    lam_n = np.zeros(nc)
    lam_t = np.zeros((nc, 2))
    for it in range(MAX_ITERATIONS):
        change = 0.0
        for k in range(nc):
            if not active[k]:
                continue
            a, b = cands[k, 0], cands[k, 2]
            # normal impulse, accumulated and kept >= 0
            vn = _speed(jac, a, b, v, omega, k, 0)
            new = max(lam_n[k] + (target[k] - vn) / kn[k], 0.0)
            dl = new - lam_n[k]
            if dl != 0.0:
                lam_n[k] = new
                _push(model, jac, a, b, v, L, omega, k, 0, dl)
                change = max(change, abs(dl) * kn[k])
            if model.friction == 0.0:
                continue
            # friction impulse stopping the sliding, kept inside the Coulomb disc
            u1 = _speed(jac, a, b, v, omega, k, 1)
            u2 = _speed(jac, a, b, v, omega, k, 2)
            f1 = lam_t[k, 0] - (kt_inv[k, 0, 0] * u1 + kt_inv[k, 0, 1] * u2)
            f2 = lam_t[k, 1] - (kt_inv[k, 1, 0] * u1 + kt_inv[k, 1, 1] * u2)
            limit = model.friction * lam_n[k]
            mag = np.sqrt(f1 * f1 + f2 * f2)
            if mag > limit:
                f1 *= limit / mag
                f2 *= limit / mag
            d1, d2 = f1 - lam_t[k, 0], f2 - lam_t[k, 1]
            lam_t[k, 0], lam_t[k, 1] = f1, f2
            if d1 != 0.0 or d2 != 0.0:
                _push(model, jac, a, b, v, L, omega, k, 1, d1)
                _push(model, jac, a, b, v, L, omega, k, 2, d2)
                # kn, the normal's inverse mass, scales impulses to speeds like the tangents' would
                change = max(change, np.sqrt(d1 * d1 + d2 * d2) * kn[k])
        if change < VELOCITY_TOLERANCE:
            return it + 1
    return MAX_ITERATIONS


@njit(cache=True)
def resolve_contacts(model, x, q, v, L, bounce_threshold):
    """Project penetrations out, then apply contact and friction impulses, in place.

    Returns the Gauss-Seidel sweeps used by the position and the velocity solves.
    """
    cands = find_candidates(model, x, q)
    if cands.shape[0] == 0:
        return 0, 0
    return (
        _project_positions(model, x, q, cands),
        _solve_velocities(model, x, q, v, L, cands, bounce_threshold),
    )
