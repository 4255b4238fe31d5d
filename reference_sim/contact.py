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

import math
from typing import NamedTuple

import numpy as np

from reference_sim.jit import compiled, kernel
from reference_sim.quaternion import qmatrix
from reference_sim.vec3 import (
    add,
    conjugate_by,
    cross,
    dot,
    flat,
    mat,
    mat_t_vec,
    mat_vec,
    row,
    scale,
    sub,
    vec,
)

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
# Scenes with at least this many bodies find close body pairs on a uniform grid (linear in the
# number of bodies); fewer are tested pair by pair, which is faster for a handful.
GRID_MIN_BODIES = 16


@kernel
def world_omega(model, q, L, b):
    """World angular velocity omega = R I0^-1 R^T L of body b (q, L: that body's rows), a tuple."""
    r = qmatrix(q)
    return mat_vec(r, mat_vec(mat(model.inertia0_inv, b), mat_t_vec(r, L)))


@kernel
def frames_into(model, q, L, rot, inv, omega):
    for b in range(q.shape[0]):
        r = qmatrix((q[b, 0], q[b, 1], q[b, 2], q[b, 3]))
        i_world = conjugate_by(r, mat(model.inertia0_inv, b))
        w = mat_vec(i_world, row(L, b))
        for k in range(9):
            rot[b, k] = r[k]
            inv[b, k] = i_world[k]
        omega[b, 0], omega[b, 1], omega[b, 2] = w


@compiled
def body_frames(model, q, L):
    """(B, 9) rotation matrices (row major), (B, 9) world inverse inertias and (B, 3) world
    angular velocities of every body."""
    nb = q.shape[0]
    rot, inv, omega = np.empty((nb, 9)), np.empty((nb, 9)), np.empty((nb, 3))
    frames_into(model, q, L, rot, inv, omega)
    return rot, inv, omega


@kernel
def _particle(model, x, rot, b, i):
    """World position of particle i of body b."""
    return add(row(x, b), mat_vec(flat(rot, b), row(model.offsets, i)))


@kernel
def reach_into(model, v, omega, dt, kick, reach):
    """How far (m) any surface point of each body can move in a step: linear speed (after the
    velocity change `kick` the integrator makes before contact) plus rotational speed, plus the
    step's gravity."""
    fall = dt * dt * math.sqrt(dot(vec(model.gravity), vec(model.gravity)))
    for b in range(v.shape[0]):
        vb = add(row(v, b), kick)
        speed = math.sqrt(dot(vb, vb)) + model.bound_radius[b] * math.sqrt(
            dot(row(omega, b), row(omega, b))
        )
        reach[b] = dt * speed + fall


@kernel
def _near(model, x, reach, a, b):
    """Whether the bounding spheres of bodies a and b can meet within the step."""
    d = sub(row(x, a), row(x, b))
    apart = math.sqrt(dot(d, d)) - model.bound_radius[a] - model.bound_radius[b]
    return not apart > reach[a] + reach[b]


@kernel
def _all_pairs_into(model, x, reach, pairs):
    """Every body pair a < b that can meet, tested pair by pair, in order, written to `pairs`
    while it has room; returns how many there are."""
    n = 0
    for a in range(x.shape[0]):
        for b in range(a + 1, x.shape[0]):
            if _near(model, x, reach, a, b):
                if n < pairs.shape[0]:
                    pairs[n, 0], pairs[n, 1] = a, b
                n += 1
    return n


@kernel
def _grid_pairs_into(model, x, reach, cells, dims, order, sorted_keys, found, pairs):
    """The pairs of `_all_pairs_into`, in the same order, testing only bodies in neighbouring
    grid cells (`cells`: each body's cell; `sorted_keys`: cell keys in `order`)."""
    nb = x.shape[0]
    n = 0
    for a in range(nb):
        m = 0
        for dx in range(-1, 2):
            cx = cells[a, 0] + dx
            for dy in range(-1, 2):
                cy = cells[a, 1] + dy
                for dz in range(-1, 2):
                    cz = cells[a, 2] + dz
                    if min(cx, cy, cz) < 0 or cx >= dims[0] or cy >= dims[1] or cz >= dims[2]:
                        continue
                    key = (cx * dims[1] + cy) * dims[2] + cz
                    lo, hi = 0, nb  # first position with sorted_keys >= key
                    while lo < hi:
                        mid = (lo + hi) // 2
                        if sorted_keys[mid] < key:
                            lo = mid + 1
                        else:
                            hi = mid
                    while lo < nb and sorted_keys[lo] == key:
                        b = order[lo]
                        if b > a and _near(model, x, reach, a, b):
                            # insertion keeps found[:m] sorted: pairs come out in index order
                            at = m
                            while at > 0 and found[at - 1] > b:
                                found[at] = found[at - 1]
                                at -= 1
                            found[at] = b
                            m += 1
                        lo += 1
        for k in range(m):
            if n < pairs.shape[0]:
                pairs[n, 0], pairs[n, 1] = a, found[k]
            n += 1
    return n


@compiled
def body_pairs(model, x, reach, grid):
    """(P, 2) body pairs a < b whose bounding spheres can meet within the step, sorted.

    With `grid`, bodies are binned into cubic cells as wide as the largest interaction
    distance and only bodies in neighbouring cells are tested: cost linear in the number of
    bodies. The result is the same as testing every pair (tested), so the simulation is
    bit-equal either way. Without a bounded grid (NaN or far-flung bodies) every pair is tested.
    """
    nb = x.shape[0]
    cell = 2.0 * (model.bound_radius + reach).max() if nb else 1.0
    dims = np.ones(3, dtype=np.int64)
    cells = np.zeros((nb, 3), dtype=np.int64)
    for k in range(3):
        lo = x[:, k].min() if nb else 0.0
        span = (x[:, k].max() - lo) / cell if nb else 0.0
        if not span < 2.0**20:  # NaN, inf, or more cells than an int64 key can number
            grid = False
            break
        dims[k] = int(span) + 1
        for b in range(nb):
            cells[b, k] = min(int((x[b, k] - lo) / cell), dims[k] - 1)
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    order = np.argsort(keys)
    sorted_keys = keys[order]
    found = np.empty(nb, dtype=np.int64)
    pairs = np.empty((2 * nb + 16, 2), dtype=np.int64)
    while True:
        if grid:
            n = _grid_pairs_into(model, x, reach, cells, dims, order, sorted_keys, found, pairs)
        else:
            n = _all_pairs_into(model, x, reach, pairs)
        if n <= pairs.shape[0]:
            return pairs[:n]
        pairs = np.empty((n, 2), dtype=np.int64)


@kernel
def _plane_candidates_into(model, x, rot, reach, out, keys):
    """Particle-plane candidates written to `out` (and their `contact_key`s to `keys`) while
    it has room, in increasing key order; returns how many there are."""
    npl = model.plane_points.shape[0]
    k = 0
    for b in range(x.shape[0]):
        # every particle's gap is at least `far`: none can come within its reach + radius
        near = False
        for j in range(npl):
            n = row(model.plane_normals, j)
            far = dot(n, sub(row(x, b), row(model.plane_points, j))) - model.bound_radius[b]
            near = near or far < reach[b] + model.bound_radius[b]
        if not near:
            continue
        for i in range(model.body_start[b], model.body_start[b + 1]):
            p = _particle(model, x, rot, b, i)
            for j in range(npl):
                gap = dot(row(model.plane_normals, j), sub(p, row(model.plane_points, j)))
                if gap - model.radius[i] < reach[b] + model.radius[i]:
                    if k < out.shape[0]:
                        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = b, i, -1, j
                        keys[k] = i * npl + j
                    k += 1
    return k


@kernel
def _pair_candidates_into(model, x, rot, reach, pairs, n_pairs, out, keys, k):
    """Particle-particle candidates of the first `n_pairs` body `pairs`, written to `out` and
    `keys` from row k while there is room, in increasing key order; returns k plus how many."""
    npt = model.offsets.shape[0]
    nb = model.body_mass.shape[0]
    base = npt * model.plane_points.shape[0]
    for p in range(n_pairs):
        a, b = pairs[p, 0], pairs[p, 1]
        for i in range(model.body_start[a], model.body_start[a + 1]):
            pa = _particle(model, x, rot, a, i)
            for j in range(model.body_start[b], model.body_start[b + 1]):
                dd = sub(pa, _particle(model, x, rot, b, j))
                gap = math.sqrt(dot(dd, dd)) - model.radius[i] - model.radius[j]
                if gap < reach[a] + reach[b] + min(model.radius[i], model.radius[j]):
                    if k < out.shape[0]:
                        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = a, i, b, j
                        # pairs come sorted by (a, b): the keys increase
                        keys[k] = base + ((a * nb + b) * npt + i) * npt + j
                    k += 1
    return k


@compiled
def find_candidates(model, x, q, v, L, dt):
    """Contacts that could touch within the step: rows (body a, particle i, body b or -1,
    particle j or plane index). A particle radius of slack on top of the reach keeps contacts
    that rotation brings a little closer than the linear estimate. (The step loop finds them
    in its own buffers, `ContactBuffers`; this is the same search, allocating.)"""
    nb = model.body_mass.shape[0]
    rot, _, omega = body_frames(model, q, L)
    reach = np.empty(nb)
    reach_into(model, v, omega, dt, (0.0, 0.0, 0.0), reach)
    pairs = body_pairs(model, x, reach, nb >= GRID_MIN_BODIES)
    out = np.empty((64, 4), dtype=np.int64)
    while True:
        keys = np.empty(out.shape[0], dtype=np.int64)
        k = _plane_candidates_into(model, x, rot, reach, out, keys)
        k = _pair_candidates_into(model, x, rot, reach, pairs, pairs.shape[0], out, keys, k)
        if k <= out.shape[0]:
            return out[:k]
        out = np.empty((k, 4), dtype=np.int64)


@kernel
def contact_geometry(model, x, rot, cands, k):
    """Normal n (from b towards a), gap (m), lever arms r_a, r_b from each COM to contact k.

    `rot` holds the bodies' rotation matrices (`body_frames`).
    """
    a, i, b, j = cands[k, 0], cands[k, 1], cands[k, 2], cands[k, 3]
    pa = _particle(model, x, rot, a, i)
    if b < 0:
        n = row(model.plane_normals, j)
        gap = dot(n, sub(pa, row(model.plane_points, j))) - model.radius[i]
        point = sub(pa, scale(model.radius[i], n))
        return n, gap, sub(point, row(x, a)), (0.0, 0.0, 0.0)
    pb = _particle(model, x, rot, b, j)
    d = sub(pa, pb)
    dist = math.sqrt(dot(d, d))
    n = scale(1.0 / dist, d) if dist > 0 else (0.0, 0.0, 1.0)
    gap = dist - model.radius[i] - model.radius[j]
    point = scale(0.5, add(sub(pa, scale(model.radius[i], n)), add(pb, scale(model.radius[j], n))))
    return n, gap, sub(point, row(x, a)), sub(point, row(x, b))


@kernel
def _tangents(n):
    """Two unit vectors completing n to a right-handed orthonormal basis."""
    helper = (1.0, 0.0, 0.0) if abs(n[0]) < 0.57735 else (0.0, 1.0, 0.0)
    t1 = cross(n, helper)
    t1 = scale(1.0 / math.sqrt(dot(t1, t1)), t1)
    return t1, cross(n, t1)


@kernel
def _speed(jac, a, b, v, omega, k, d):
    """Relative velocity of contact k along its direction d (0 normal, 1 and 2 tangents)."""
    u = 0.0
    for i in range(3):
        u += jac[k, d, 0, i] * v[a, i] + jac[k, d, 1, i] * omega[a, i]
        if b >= 0:
            u -= jac[k, d, 0, i] * v[b, i] + jac[k, d, 3, i] * omega[b, i]
    return u


@kernel
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


@kernel
def _set_row(jac, k, d, slot, value):
    jac[k, d, slot, 0], jac[k, d, slot, 1], jac[k, d, slot, 2] = value


@kernel
def _row_dot(jac, k, d, e, s1, s2):
    """jac[k, d, s1] . jac[k, e, s2]."""
    return (
        jac[k, d, s1, 0] * jac[k, e, s2, 0]
        + jac[k, d, s1, 1] * jac[k, e, s2, 1]
        + jac[k, d, s1, 2] * jac[k, e, s2, 2]
    )


@kernel
def _assemble(model, x, rot, inv, cands, dt, post, acting, active, jac, kn, kt, kt_inv, target):
    """Per contact: whether it acts, its Jacobian rows, normal and tangent inverse masses,
    and (before the drift) its target normal speed."""
    nc = cands.shape[0]
    for k in range(nc):
        a, b = cands[k, 0], cands[k, 2]
        n, gap, ra, rb = contact_geometry(model, x, rot, cands, k)
        active[k] = not (post and gap > TOUCH_TOLERANCE and not acting[k])
        if not active[k]:
            continue
        t1, t2 = _tangents(n)
        inv_a = flat(inv, a)
        for d in range(3):
            direction = n if d == 0 else (t1 if d == 1 else t2)
            arm = cross(ra, direction)
            _set_row(jac, k, d, 0, direction)
            _set_row(jac, k, d, 1, arm)
            _set_row(jac, k, d, 2, mat_vec(inv_a, arm))
            if b >= 0:
                arm = cross(rb, direction)
                _set_row(jac, k, d, 3, arm)
                _set_row(jac, k, d, 4, mat_vec(flat(inv, b), arm))
        inv_mass = 1.0 / model.body_mass[a] + (1.0 / model.body_mass[b] if b >= 0 else 0.0)
        for d in range(3):
            for e in range(d, 3):
                entry = (
                    inv_mass * _row_dot(jac, k, d, e, 0, 0)
                    + _row_dot(jac, k, d, e, 1, 2)
                    + _row_dot(jac, k, d, e, 3, 4)
                )
                if d == 0 and e == 0:
                    kn[k] = entry
                elif d > 0:
                    kt[k, 2 * (d - 1) + (e - 1)] = entry
                    kt[k, 2 * (e - 1) + (d - 1)] = entry
        det = kt[k, 0] * kt[k, 3] - kt[k, 1] * kt[k, 2]
        kt_inv[k, 0], kt_inv[k, 1] = kt[k, 3] / det, -kt[k, 1] / det
        kt_inv[k, 2], kt_inv[k, 3] = -kt[k, 2] / det, kt[k, 0] / det
        if not post:
            target[k] = -gap / dt if gap >= 0.0 else -BAUMGARTE * gap / dt


@kernel
def _iterate(model, cands, active, jac, kn, kt, kt_inv, target, v, L, omega, lam):
    """Gauss-Seidel sweeps until no impulse changes a speed by VELOCITY_TOLERANCE; returns
    the sweeps used."""
    nc = cands.shape[0]
    for it in range(MAX_ITERATIONS):
        change = 0.0
        for k in range(nc):
            if not active[k]:
                continue
            a, b = cands[k, 0], cands[k, 2]
            # normal impulse, accumulated and kept >= 0
            vn = _speed(jac, a, b, v, omega, k, 0)
            new = max(lam[k, 0] + (target[k] - vn) / kn[k], 0.0)
            dl = new - lam[k, 0]
            if dl != 0.0:
                lam[k, 0] = new
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
            g1 -= kt[k, 0] * lam[k, 1] + kt[k, 1] * lam[k, 2]
            g2 -= kt[k, 2] * lam[k, 1] + kt[k, 3] * lam[k, 2]
            f1 = -(kt_inv[k, 0] * g1 + kt_inv[k, 1] * g2)
            f2 = -(kt_inv[k, 2] * g1 + kt_inv[k, 3] * g2)
            limit = model.friction * lam[k, 0]
            if f1 * f1 + f2 * f2 > limit * limit:
                slide = math.sqrt(g1 * g1 + g2 * g2)
                f1, f2 = -limit * g1 / slide, -limit * g2 / slide
            d1, d2 = f1 - lam[k, 1], f2 - lam[k, 2]
            lam[k, 1], lam[k, 2] = f1, f2
            if d1 != 0.0 or d2 != 0.0:
                _push(model, jac, a, b, v, L, omega, k, 1, d1)
                _push(model, jac, a, b, v, L, omega, k, 2, d2)
                # kn, the normal's inverse mass, scales impulses to speeds like the tangents' would
                change = max(change, math.sqrt(d1 * d1 + d2 * d2) * kn[k])
        if change < VELOCITY_TOLERANCE:
            return it + 1
    return MAX_ITERATIONS


@kernel
def _bounces(model, x, rot, v, omega, cands, dt, bounce_threshold, bounce):
    """-e times the approach speed of every contact that impacts within the step."""
    for k in range(cands.shape[0]):
        n, gap, ra, rb = contact_geometry(model, x, rot, cands, k)
        a, b = cands[k, 0], cands[k, 2]
        u = add(row(v, a), cross(row(omega, a), ra))
        if b >= 0:
            u = sub(u, add(row(v, b), cross(row(omega, b), rb)))
        vn = dot(n, u)
        if vn < -bounce_threshold and gap + dt * vn < IMPACT_SLACK:
            bounce[k] = -model.restitution * vn


class ContactBuffers(NamedTuple):
    """Everything a contact step writes, allocated once per run and grown when a step needs
    more room, so that steps allocate nothing.

    Per body: rot, inv (B, 9) rotation matrices and world inverse inertias (row major), omega
    (B, 3), reach (B,). Body pairs that can meet: pairs (P, 2). Per candidate (capacity C):
    cands (C, 4), keys (C,) (`contact_key` order), jac (C, 3, 5, 3), kn (C,), kt and kt_inv
    (C, 4) (2 x 2 row major), target, bounce (C,), active, acting (C,), lam (C, 3). The warm
    start: the previous step's impulses before and after the drift, keys and impulses of
    counts[0] and counts[1] contacts, in key order.
    """

    rot: np.ndarray
    inv: np.ndarray
    omega: np.ndarray
    reach: np.ndarray
    pairs: np.ndarray
    cands: np.ndarray
    keys: np.ndarray
    jac: np.ndarray
    kn: np.ndarray
    kt: np.ndarray
    kt_inv: np.ndarray
    target: np.ndarray
    bounce: np.ndarray
    active: np.ndarray
    acting: np.ndarray
    lam: np.ndarray
    pre_keys: np.ndarray
    pre_lam: np.ndarray
    post_keys: np.ndarray
    post_lam: np.ndarray
    counts: np.ndarray


@compiled
def contact_buffers(n_bodies, capacity, pair_capacity):
    """Empty buffers for `capacity` candidates and `pair_capacity` body pairs."""
    c = capacity
    return ContactBuffers(
        np.empty((n_bodies, 9)),
        np.empty((n_bodies, 9)),
        np.empty((n_bodies, 3)),
        np.empty(n_bodies),
        np.empty((pair_capacity, 2), dtype=np.int64),
        np.empty((c, 4), dtype=np.int64),
        np.empty(c, dtype=np.int64),
        np.zeros((c, 3, 5, 3)),
        np.ones(c),
        np.zeros((c, 4)),
        np.zeros((c, 4)),
        np.zeros(c),
        np.zeros(c),
        np.zeros(c, dtype=np.bool_),
        np.zeros(c, dtype=np.bool_),
        np.zeros((c, 3)),
        np.empty(c, dtype=np.int64),
        np.zeros((c, 3)),
        np.empty(c, dtype=np.int64),
        np.zeros((c, 3)),
        np.zeros(2, dtype=np.int64),
    )


@compiled
def grown(buf, capacity, pair_capacity):
    """Buffers with at least these capacities, carrying over the warm start of `buf`."""
    new = contact_buffers(
        buf.rot.shape[0],
        max(capacity, buf.cands.shape[0]),
        max(pair_capacity, buf.pairs.shape[0]),
    )
    n_pre, n_post = buf.counts[0], buf.counts[1]
    new.pre_keys[:n_pre] = buf.pre_keys[:n_pre]
    new.pre_lam[:n_pre] = buf.pre_lam[:n_pre]
    new.post_keys[:n_post] = buf.post_keys[:n_post]
    new.post_lam[:n_post] = buf.post_lam[:n_post]
    new.counts[:] = buf.counts
    return new


@kernel
def find_candidates_into(model, x, v, dt, kick, n_pairs, buf):
    """The step's candidates into `buf` (`find_candidates`, with the integrator's `kick` to v
    before contact): their count, which may exceed the capacity (then nothing else is valid),
    or minus the number of body pairs if they exceed theirs.

    n_pairs < 0: the body pairs are found here, pair by pair; else `buf.pairs[:n_pairs]` holds
    them (found by the caller on the grid, `body_pairs`). Needs `buf.rot` and `buf.omega`.
    """
    reach_into(model, v, buf.omega, dt, kick, buf.reach)
    if n_pairs < 0:
        n_pairs = _all_pairs_into(model, x, buf.reach, buf.pairs)
        if n_pairs > buf.pairs.shape[0]:
            return -n_pairs
    k = _plane_candidates_into(model, x, buf.rot, buf.reach, buf.cands, buf.keys)
    return _pair_candidates_into(
        model, x, buf.rot, buf.reach, buf.pairs, n_pairs, buf.cands, buf.keys, k
    )


@kernel
def _warm_start(model, nc, buf, v, L, warm_keys, warm_lam, n_warm):
    """Impulses (normal, two tangents) of last step's matching contacts, applied again. Both
    key lists are in increasing order: one merge pass matches them."""
    at = 0
    for k in range(nc):
        buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2] = 0.0, 0.0, 0.0
        while at < n_warm and warm_keys[at] < buf.keys[k]:
            at += 1
        if buf.active[k] and at < n_warm and warm_keys[at] == buf.keys[k]:
            for d in range(3):
                lam = warm_lam[at, d]
                buf.lam[k, d] = lam
                if lam != 0.0:
                    a, b = buf.cands[k, 0], buf.cands[k, 2]
                    _push(model, buf.jac, a, b, v, L, buf.omega, k, d, lam)


@kernel
def _remember(nc, buf, keep, keys, lam, slot):
    """Keys and impulses of the contacts flagged in `keep`, in key order, for the next step."""
    n = 0
    for k in range(nc):
        if keep[k]:
            keys[n] = buf.keys[k]
            lam[n, 0], lam[n, 1], lam[n, 2] = buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2]
            n += 1
    buf.counts[slot] = n


@kernel
def _solve(model, x, v, L, nc, dt, post, buf, warm_keys, warm_lam, n_warm):
    """Projected Gauss-Seidel on the contacts' normal and friction impulses, in place.

    Before the drift (post False) every candidate is speculative, with target normal speed
    -gap / dt; after it (post True) the contacts that pushed before the drift (`buf.acting`) or
    touch now act, with normal speed target `buf.target` (the bounce, or 0). Impulses start
    from those of the same contacts in the previous step (`warm_keys`, `warm_lam`), so a
    resting stack converges in a few sweeps instead of hundreds. Per contact and direction
    (normal, two tangents) the Jacobian rows are precomputed: jac[k, d] = (direction, r_a x dir,
    I_a^-1 (r_a x dir), r_b x dir, I_b^-1 (r_b x dir)). Friction is solved as a 2 x 2 block and
    projected onto the disc. Needs `buf.rot`, `buf.inv`, `buf.omega` of the current q and L.
    Returns the sweeps used.
    """
    c = buf.cands[:nc]
    _assemble(
        model,
        x,
        buf.rot,
        buf.inv,
        c,
        dt,
        post,
        buf.acting,
        buf.active,
        buf.jac,
        buf.kn,
        buf.kt,
        buf.kt_inv,
        buf.target,
    )
    _warm_start(model, nc, buf, v, L, warm_keys, warm_lam, n_warm)
    return _iterate(
        model,
        c,
        buf.active,
        buf.jac,
        buf.kn,
        buf.kt,
        buf.kt_inv,
        buf.target,
        v,
        L,
        buf.omega,
        buf.lam,
    )


@kernel
def before_drift(model, x, v, L, nc, dt, drift_gravity, bounce_threshold, buf):
    """Speculative impulses on the first nc candidates of `buf`, on the velocity the drift will
    use: v + drift_gravity (m/s), the part of this step's gravity the integrator adds during the
    drift. Changes v and L; needs `buf.rot`, `buf.inv`, `buf.omega` of the step's start.

    Leaves in `buf.bounce` the normal speed each contact must leave with after the drift: -e
    times its approach speed for an impact (a contact closing within the step faster than
    `bounce_threshold`), else 0 (the bounce is applied after the drift, when the contact has
    arrived), and in `buf.acting` the contacts that pushed or bounce.
    """
    for b in range(v.shape[0]):
        for i in range(3):
            v[b, i] += drift_gravity[i]
    for k in range(nc):
        buf.bounce[k] = 0.0
        buf.acting[k] = False
    _bounces(model, x, buf.rot, v, buf.omega, buf.cands[:nc], dt, bounce_threshold, buf.bounce)
    _solve(model, x, v, L, nc, dt, False, buf, buf.pre_keys, buf.pre_lam, buf.counts[0])
    for k in range(nc):
        buf.acting[k] = buf.lam[k, 0] > 0.0
    _remember(nc, buf, buf.acting, buf.pre_keys, buf.pre_lam, 0)
    for k in range(nc):
        buf.acting[k] = buf.acting[k] or buf.bounce[k] > 0.0
    for b in range(v.shape[0]):
        for i in range(3):
            v[b, i] -= drift_gravity[i]


@kernel
def after_drift(model, x, q, v, L, nc, dt, buf):
    """Impulses after the drift on the contacts that pushed before it or bounce
    (`buf.acting`) or touch now: the bounce targets of `before_drift`, else inelastic.
    Changes v and L."""
    frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    for k in range(nc):
        buf.target[k] = buf.bounce[k]
    _solve(model, x, v, L, nc, dt, True, buf, buf.post_keys, buf.post_lam, buf.counts[1])
    _remember(nc, buf, buf.active, buf.post_keys, buf.post_lam, 1)
