"""Contact for the rigid integrators: impulses, not penalties, and nothing but impulses.

Why impulses: a penalty spring stiff enough to hold the 8 kg cube within 2 mm needs k above
4e4 N/m, and an explicit step is then unstable at the seed's dt = 0.01 (omega dt > 2). Impulses
have no stiffness, so contact costs no step-size limit and a resting body sits exactly on the
surface.

Why only impulses: every contact effect is an equal and opposite impulse at one contact point,
so total linear and angular momentum are conserved exactly in a collision. A position
correction that moves bodies without changing their velocities would change the angular
momentum sum of m x cross v; none is used.

Each step is split around the drift (the integrator's position update), like the contact force
of a kick-drift-kick scheme:

1. Candidates (`find_candidates`): particle-plane pairs, and particle pairs of *different*
   bodies whose bounding spheres can meet, whose gap could close within the step at the
   bodies' current speeds. Particles of one body are never paired.
2. Before the drift (`pre_solve`): speculative contacts on the velocity the drift will use
   (v plus the part of this step's gravity the integrator adds during the drift). A contact
   with gap g may approach by at most g / dt, so the drift ends touching, never penetrating
   (to first order in the rotation). A contact that would close within the step at more than
   the bounce threshold bounces: its normal speed becomes -e times the approach speed. Coulomb
   friction acts with every normal impulse. A gap already negative (the rotation's second-order
   overshoot) is closed at BAUMGARTE of its depth per step.
3. After the drift (`post_solve`): touching contacts get the inelastic rest of the step's
   impulse (normal speed >= 0 and friction), which removes the gravity the drift's second half
   added: a resting body ends the step with zero velocity, exactly still, without creep.

Both solves are projected Gauss-Seidel with accumulated impulses: normal impulse >= 0, friction
impulse inside the disc |P_t| <= mu P_n; impulses change the COM velocity and the world angular
momentum (dL = r x P).
"""

import numpy as np
from numba import njit

from reference_sim.quaternion import quat_to_matrix

# A contact is touching, and gets the post-drift impulse, when its gap is below this (m):
# speculative contacts end the drift touching to rounding of metre-scale coordinates (1e-15 m).
TOUCH_TOLERANCE = 1e-9
# Contacts closing within this much (m) of each other in the same step impact together: Newton's
# restitution is ill-posed for simultaneous impacts, and rounding (1e-16 m) must not decide
# which corner of a cube landing flat bounces first (the others would then set it spinning).
IMPACT_SLACK = 1e-6
# Fraction of an (already) negative gap closed per step: Baumgarte's classic 0.2, enough to
# remove the tiny second-order overshoots of rotating bodies without a visible kick.
BAUMGARTE = 0.2
# Stop Gauss-Seidel when no impulse changes a speed by more than this (m/s).
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
def _reach(model, q, v, L, b, dt):
    """How far (m) any surface point of body b can move in a step: linear plus rotational
    speed, plus the step's gravity."""
    omega = quat_to_matrix(q[b]) @ (model.inertia0_inv[b] @ (quat_to_matrix(q[b]).T @ L[b]))
    speed = np.sqrt(np.dot(v[b], v[b])) + np.sqrt(np.dot(omega, omega)) * model.bound_radius[b]
    return dt * speed + dt * dt * np.sqrt(np.dot(model.gravity, model.gravity))


@njit(cache=True)
def find_candidates(model, x, q, v, L, dt):
    """Contacts that could touch within the step: rows (body a, particle i, body b or -1,
    particle j or plane index). A particle radius of slack on top of the reach keeps contacts
    that rotation brings a little closer than the linear estimate."""
    nb = model.body_mass.shape[0]
    npl = model.plane_points.shape[0]
    npt = model.offsets.shape[0]
    reach = np.empty(nb)
    for b in range(nb):
        reach[b] = _reach(model, q, v, L, b, dt)
    out = np.empty((npt * npl + 16, 4), dtype=np.int64)
    k = 0
    for b in range(nb):
        rot = quat_to_matrix(q[b])
        for i in range(model.body_start[b], model.body_start[b + 1]):
            p = x[b] + rot @ model.offsets[i]
            for j in range(npl):
                gap = np.dot(model.plane_normals[j], p - model.plane_points[j]) - model.radius[i]
                if gap < reach[b] + model.radius[i]:
                    out[k] = (b, i, -1, j)
                    k += 1
    for a in range(nb):
        for b in range(a + 1, nb):
            d = x[a] - x[b]
            apart = np.sqrt(np.dot(d, d)) - model.bound_radius[a] - model.bound_radius[b]
            if apart > reach[a] + reach[b]:
                continue
            ra = quat_to_matrix(q[a])
            rb = quat_to_matrix(q[b])
            for i in range(model.body_start[a], model.body_start[a + 1]):
                pa = x[a] + ra @ model.offsets[i]
                for j in range(model.body_start[b], model.body_start[b + 1]):
                    dd = pa - x[b] - rb @ model.offsets[j]
                    gap = np.sqrt(np.dot(dd, dd)) - model.radius[i] - model.radius[j]
                    if gap < reach[a] + reach[b] + min(model.radius[i], model.radius[j]):
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
def _solve(model, x, q, v, L, cands, dt, post, targets, acting, warm_keys, warm_lam):
    """Projected Gauss-Seidel on the contacts' normal and friction impulses, in place.

    Before the drift (post False) every candidate is speculative, with target normal speed
    -gap / dt; after it (post True) the contacts that pushed before the drift (`acting`) or
    touch now act, with normal speed target `targets` (the bounce, or 0). Impulses start from
    those of the same contacts in the previous step (`warm_keys`, sorted, and `warm_lam`), so a
    resting stack converges in a few sweeps instead of hundreds.
    Per contact and direction (normal, two tangents) the Jacobian rows are precomputed:
    jac[k, d] = (direction, r_a x dir, I_a^-1 (r_a x dir), r_b x dir, I_b^-1 (r_b x dir)), so a
    sweep allocates nothing. Friction is solved as a 2 x 2 block and projected onto the disc.
    Returns the sweeps used, each contact's impulses (normal, two tangents) and whether it was
    active.
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
    kt = np.zeros((nc, 2, 2))
    kt_inv = np.zeros((nc, 2, 2))
    target = targets.copy()
    for k in range(nc):
        a, b = cands[k, 0], cands[k, 2]
        n, gap, ra, rb = contact_geometry(model, x, rot, cands[k])
        if post and gap > TOUCH_TOLERANCE and not acting[k]:
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
        kt[k] = kmat[1:, 1:]
        kt_inv[k] = np.linalg.inv(kt[k])
        if not post:
            target[k] = -gap / dt if gap >= 0.0 else -BAUMGARTE * gap / dt
    lam = _warm_start(model, cands, active, jac, v, L, omega, warm_keys, warm_lam)
    lam_n = lam[:, 0]
    lam_t = lam[:, 1:]
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
            # friction: the impulse that stops the sliding if it fits in the Coulomb disc; else
            # mu P_n against the sliding velocity this contact's own friction leaves (maximum
            # dissipation). Clipping the stopping impulse instead would aim the friction along
            # K_t^-1 u, off the sliding direction whenever K_t is anisotropic: a sliding cube
            # would yaw and decelerate by less than mu g.
            g1 = _speed(jac, a, b, v, omega, k, 1)
            g2 = _speed(jac, a, b, v, omega, k, 2)
            g1 -= kt[k, 0, 0] * lam_t[k, 0] + kt[k, 0, 1] * lam_t[k, 1]
            g2 -= kt[k, 1, 0] * lam_t[k, 0] + kt[k, 1, 1] * lam_t[k, 1]
            f1 = -(kt_inv[k, 0, 0] * g1 + kt_inv[k, 0, 1] * g2)
            f2 = -(kt_inv[k, 1, 0] * g1 + kt_inv[k, 1, 1] * g2)
            limit = model.friction * lam_n[k]
            if f1 * f1 + f2 * f2 > limit * limit:
                slide = np.sqrt(g1 * g1 + g2 * g2)
                f1, f2 = -limit * g1 / slide, -limit * g2 / slide
            d1, d2 = f1 - lam_t[k, 0], f2 - lam_t[k, 1]
            lam_t[k, 0], lam_t[k, 1] = f1, f2
            if d1 != 0.0 or d2 != 0.0:
                _push(model, jac, a, b, v, L, omega, k, 1, d1)
                _push(model, jac, a, b, v, L, omega, k, 2, d2)
                # kn, the normal's inverse mass, scales impulses to speeds like the tangents' would
                change = max(change, np.sqrt(d1 * d1 + d2 * d2) * kn[k])
        if change < VELOCITY_TOLERANCE:
            return it + 1, lam, active
    return MAX_ITERATIONS, lam, active


@njit(cache=True)
def contact_keys(model, cands):
    """A number per contact, the same from step to step: particle i and plane or particle j."""
    stride = model.plane_points.shape[0] + model.offsets.shape[0]
    keys = np.empty(cands.shape[0], dtype=np.int64)
    for k in range(cands.shape[0]):
        other = cands[k, 3] if cands[k, 2] < 0 else model.plane_points.shape[0] + cands[k, 3]
        keys[k] = cands[k, 1] * stride + other
    return keys


@njit(cache=True)
def _warm_start(model, cands, active, jac, v, L, omega, warm_keys, warm_lam):
    """Impulses (normal, two tangents) of last step's matching contacts, applied again."""
    lam = np.zeros((cands.shape[0], 3))
    if warm_keys.shape[0] == 0:
        return lam
    keys = contact_keys(model, cands)
    for k in range(cands.shape[0]):
        if not active[k]:
            continue
        at = np.searchsorted(warm_keys, keys[k])
        if at < warm_keys.shape[0] and warm_keys[at] == keys[k]:
            lam[k] = warm_lam[at]
            for d in range(3):
                if lam[k, d] != 0.0:
                    _push(model, jac, cands[k, 0], cands[k, 2], v, L, omega, k, d, lam[k, d])
    return lam


@njit(cache=True)
def remember(model, cands, lam, active):
    """Sorted keys and impulses of the active contacts, for the next step's warm start."""
    keys = contact_keys(model, cands)[active]
    kept = lam[active]
    order = np.argsort(keys)
    return keys[order], kept[order]


@njit(cache=True)
def world_omega(model, q, L, b):
    """World angular velocity omega = R I0^-1 R^T L of body b (q, L: that body's rows)."""
    r = quat_to_matrix(q)
    return r @ (model.inertia0_inv[b] @ (r.T @ L))


@njit(cache=True)
def pre_solve(model, x, q, v, L, cands, dt, drift_gravity, bounce_threshold, warm_keys, warm_lam):
    """Speculative impulses on the velocity the drift will use: v + drift_gravity (m/s), the
    part of this step's gravity the integrator adds during the drift. Changes v and L.

    Returns the sweeps, the impulses and active flags (for `remember`), and per contact the
    normal speed it must leave with after the drift: -e times its approach speed for an impact
    (a contact closing within the step faster than `bounce_threshold`), else 0. The bounce is
    applied after the drift, when the contact has arrived at the surface.
    """
    nc = cands.shape[0]
    for b in range(v.shape[0]):
        v[b] += drift_gravity
    rot, _ = body_frames(model, q)
    bounce = np.zeros(nc)
    for k in range(nc):
        n, gap, ra, rb = contact_geometry(model, x, rot, cands[k])
        a, b = cands[k, 0], cands[k, 2]
        u = v[a] + np.cross(world_omega(model, q[a], L[a], a), ra)
        if b >= 0:
            u -= v[b] + np.cross(world_omega(model, q[b], L[b], b), rb)
        vn = np.dot(n, u)
        if vn < -bounce_threshold and gap + dt * vn < IMPACT_SLACK:
            bounce[k] = -model.restitution * vn
    unused = np.zeros(nc, dtype=np.bool_)
    sweeps, lam, active = _solve(
        model, x, q, v, L, cands, dt, False, np.zeros(nc), unused, warm_keys, warm_lam
    )
    for b in range(v.shape[0]):
        v[b] -= drift_gravity
    return sweeps, lam, active, bounce


@njit(cache=True)
def post_solve(model, x, q, v, L, cands, dt, bounce, pushed, warm_keys, warm_lam):
    """Impulses after the drift on the contacts that pushed before it (`pushed`) or touch now:
    the bounce targets of `pre_solve`, else inelastic. Changes v and L.

    Returns the sweeps, the impulses and the active flags (for `remember`).
    """
    return _solve(model, x, q, v, L, cands, dt, True, bounce, pushed, warm_keys, warm_lam)
