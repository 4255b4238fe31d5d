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
def _world_inverse_inertia(model, q, b):
    r = quat_to_matrix(q[b])
    return r @ model.inertia0_inv[b] @ r.T


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
def contact_geometry(model, x, q, c):
    """Normal n (from b towards a), gap (m), lever arms r_a, r_b from each COM to the contact."""
    a, i, b, j = c[0], c[1], c[2], c[3]
    pa = x[a] + quat_to_matrix(q[a]) @ model.offsets[i]
    if b < 0:
        n = model.plane_normals[j].copy()
        gap = np.dot(n, pa - model.plane_points[j]) - model.radius[i]
        point = pa - model.radius[i] * n
        return n, gap, point - x[a], np.zeros(3)
    pb = x[b] + quat_to_matrix(q[b]) @ model.offsets[j]
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
def _move_apart(model, x, q, inv_a, inv_b, a, b, ra, rb, push):
    """Displace bodies a and b by the position impulse `push` (along n) at lever arms ra, rb."""
    x[a] += push / model.body_mass[a]
    q[a] = quat_normalize(quat_multiply(quat_from_rotvec(inv_a @ np.cross(ra, push)), q[a]))
    if b >= 0:
        x[b] -= push / model.body_mass[b]
        q[b] = quat_normalize(quat_multiply(quat_from_rotvec(-(inv_b @ np.cross(rb, push))), q[b]))


@njit(cache=True)
def _project_positions(model, x, q, cands):
    """Solve gap >= 0 with accumulated position impulses >= 0 (projected Gauss-Seidel).

    Accumulating lets a contact give back an earlier push, so contacts sharing a load (a cube
    on its face) end exactly touching instead of being over-pushed one after another.
    """
    acc = np.zeros(cands.shape[0])
    for it in range(MAX_ITERATIONS):
        moved = 0.0
        for k in range(cands.shape[0]):
            c = cands[k]
            n, gap, ra, rb = contact_geometry(model, x, q, c)
            if gap >= 0.0 and acc[k] == 0.0:
                continue
            a, b = c[0], c[2]
            inv_a = _world_inverse_inertia(model, q, a)
            inv_b = _world_inverse_inertia(model, q, b) if b >= 0 else inv_a
            kn = _inverse_mass_along(model, inv_a, inv_b, a, b, ra, rb, n)
            new = max(acc[k] - gap / kn, 0.0)
            dl = new - acc[k]
            acc[k] = new
            if dl != 0.0:
                _move_apart(model, x, q, inv_a, inv_b, a, b, ra, rb, dl * n)
                moved = max(moved, abs(dl) * kn)
        if moved < POSITION_TOLERANCE:
            return it + 1
    return MAX_ITERATIONS


@njit(cache=True)
def _relative_velocity(model, v, omega, a, b, ra, rb):
    u = v[a] + np.cross(omega[a], ra)
    if b >= 0:
        u -= v[b] + np.cross(omega[b], rb)
    return u


@njit(cache=True)
def _apply_impulse(model, v, L, omega, inv, a, b, ra, rb, p):
    v[a] += p / model.body_mass[a]
    L[a] += np.cross(ra, p)
    omega[a] = inv[a] @ L[a]
    if b >= 0:
        v[b] -= p / model.body_mass[b]
        L[b] -= np.cross(rb, p)
        omega[b] = inv[b] @ L[b]


@njit(cache=True)
def _solve_velocities(model, x, q, v, L, cands, bounce_threshold):
    nb = model.body_mass.shape[0]
    inv = np.empty((nb, 3, 3))
    omega = np.empty((nb, 3))
    for b in range(nb):
        inv[b] = _world_inverse_inertia(model, q, b)
        omega[b] = inv[b] @ L[b]
    # touching contacts, their geometry and their target normal speeds
    nc = cands.shape[0]
    active = np.zeros(nc, dtype=np.bool_)
    normal = np.empty((nc, 3))
    arm_a = np.empty((nc, 3))
    arm_b = np.empty((nc, 3))
    target = np.zeros(nc)
    kn = np.empty(nc)
    for k in range(nc):
        c = cands[k]
        n, gap, ra, rb = contact_geometry(model, x, q, c)
        if gap > TOUCH_TOLERANCE:
            continue
        active[k] = True
        normal[k], arm_a[k], arm_b[k] = n, ra, rb
        vn = np.dot(n, _relative_velocity(model, v, omega, c[0], c[2], ra, rb))
        if vn < -bounce_threshold:
            target[k] = -model.restitution * vn
        kn[k] = _inverse_mass_along(model, inv[c[0]], inv[max(c[2], 0)], c[0], c[2], ra, rb, n)
    lam_n = np.zeros(nc)
    lam_t = np.zeros((nc, 3))
    for it in range(MAX_ITERATIONS):
        change = 0.0
        for k in range(nc):
            if not active[k]:
                continue
            a, b = cands[k, 0], cands[k, 2]
            n, ra, rb = normal[k], arm_a[k], arm_b[k]
            # normal impulse, accumulated and kept >= 0
            vn = np.dot(n, _relative_velocity(model, v, omega, a, b, ra, rb))
            new = max(lam_n[k] + (target[k] - vn) / kn[k], 0.0)
            dl = new - lam_n[k]
            lam_n[k] = new
            if dl != 0.0:
                _apply_impulse(model, v, L, omega, inv, a, b, ra, rb, dl * n)
                change = max(change, abs(dl) * kn[k])
            # friction impulse against the sliding velocity, kept inside the Coulomb disc
            if model.friction > 0.0:
                u = _relative_velocity(model, v, omega, a, b, ra, rb)
                ut = u - np.dot(u, n) * n
                speed = np.sqrt(np.dot(ut, ut))
                if speed > 0.0:
                    t = ut / speed
                    kt = _inverse_mass_along(model, inv[a], inv[max(b, 0)], a, b, ra, rb, t)
                    acc = lam_t[k] - (speed / kt) * t
                    limit = model.friction * lam_n[k]
                    mag = np.sqrt(np.dot(acc, acc))
                    if mag > limit:
                        acc *= limit / mag
                    dp = acc - lam_t[k]
                    lam_t[k] = acc
                    _apply_impulse(model, v, L, omega, inv, a, b, ra, rb, dp)
                    change = max(change, np.sqrt(np.dot(dp, dp)) * kt)
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
