"""Broad phase: the contact candidates of a step, particle-plane pairs and particle pairs of
different bodies whose gap could close within the step, each body's reach widened by a margin
for what the solve before the drift may add to its speed. Particles of one body never pair."""

import math

import numpy as np

from reference_sim.contact.buffers import COUNT_PAIRS
from reference_sim.contact.frames import particle, reach_into
from reference_sim.jit import compiled, inlined_kernel, kernel
from reference_sim.vec3 import dot, row, sub

# A relative margin on the particle prefilter's bound (`_can_reach`), far above the rounding of
# its sums (~1e-16 relative): it never drops a particle the exact test would pair.
PREFILTER_SLACK = 1.0 + 1e-9


@kernel
def near(radius, x, reach, a, b):
    """Whether spheres a and b (centres `x`, radii `radius`: the bodies' bounding spheres, or
    the seed's particles) can meet, each moving at most its `reach`."""
    d = sub(row(x, a), row(x, b))
    apart = math.sqrt(dot(d, d)) - radius[a] - radius[b]
    return not apart > reach[a] + reach[b]


@kernel
def all_pairs_into(radius, x, reach, pairs):
    """Every sphere pair a < b that can meet (`near`), tested pair by pair, in order, written
    to `pairs` while it has room; returns how many there are."""
    n = 0
    for a in range(x.shape[0]):
        for b in range(a + 1, x.shape[0]):
            if near(radius, x, reach, a, b):
                if n < pairs.shape[0]:
                    pairs[n, 0], pairs[n, 1] = a, b
                n += 1
    return n


@compiled
def all_sphere_pairs(radius, x, reach):
    """(P, 2) sphere pairs a < b that can meet (`near`), sorted, tested pair by pair."""
    pairs = np.empty((2 * x.shape[0] + 16, 2), dtype=np.int64)
    n = all_pairs_into(radius, x, reach, pairs)
    if n > pairs.shape[0]:
        pairs = np.empty((n, 2), dtype=np.int64)
        all_pairs_into(radius, x, reach, pairs)
    return pairs[:n]


@compiled
def all_pairs(model, x, reach):
    """(P, 2) body pairs a < b whose bounding spheres can meet within the step (`reach`:
    `reach_into`), sorted, tested pair by pair."""
    return all_sphere_pairs(model.bound_radius, x, reach)


@kernel
def _plane_candidates_into(model, x, rot, wide, out, keys):
    """Particle-plane candidates, a particle's gap below its body's widened reach `wide`,
    written to `out` (and their keys to `keys`) while it has room, in increasing key order;
    returns how many there are."""
    npl = model.plane_points.shape[0]
    k = 0
    for b in range(x.shape[0]):
        # every particle's gap is at least `far`: none can come within the widened reach
        near_plane = False
        for j in range(npl):
            n = row(model.plane_normals, j)
            far = dot(n, sub(row(x, b), row(model.plane_points, j))) - model.bound_radius[b]
            near_plane = near_plane or far < wide[b]
        if not near_plane:
            continue
        for i in range(model.body_start[b], model.body_start[b + 1]):
            p = particle(model, x, rot, b, i)
            for j in range(npl):
                gap = dot(row(model.plane_normals, j), sub(p, row(model.plane_points, j)))
                if gap - model.radius[i] < wide[b]:
                    if k < out.shape[0]:
                        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = b, i, -1, j
                        keys[k] = i * npl + j
                    k += 1
    return k


@inlined_kernel
def _can_reach(model, x, wide, b, i, p, a):
    """Whether particle i of body b, centred at p, can be a candidate with some particle j of
    body a: their centres within both widened reaches + r_i + r_j, with j's centre within a's
    bounding radius - r_j of a's, puts p within both widened reaches + r_i + a's bounding
    radius of a's centre (the triangle inequality; PREFILTER_SLACK for rounding)."""
    d = sub(p, row(x, a))
    bound = wide[a] + wide[b] + model.radius[i] + model.bound_radius[a]
    bound *= PREFILTER_SLACK
    return dot(d, d) < bound * bound


@kernel
def _pair_candidates_into(model, x, rot, wide, pairs, n_pairs, out, keys, k, near, near_index):
    """Particle-particle candidates of the first `n_pairs` body `pairs`, written to `out` and
    `keys` from row k while there is room, in increasing key order; returns k plus how many.
    A pair is a candidate if its gap is below the bodies' widened reaches `wide`, tested on
    the squared distance (no square root for the many pairs that are not). Only
    particles that can reach the other body (`_can_reach`) are tested, b's turned into the
    world once a pair (into `near`), not once for each of a's."""
    npt = model.offsets.shape[0]
    nb = model.body_mass.shape[0]
    base = npt * model.plane_points.shape[0]
    for p in range(n_pairs):
        a, b = pairs[p, 0], pairs[p, 1]
        n_near = 0
        for j in range(model.body_start[b], model.body_start[b + 1]):
            pb = particle(model, x, rot, b, j)
            if _can_reach(model, x, wide, b, j, pb, a):
                near[n_near, 0], near[n_near, 1], near[n_near, 2] = pb
                near_index[n_near] = j
                n_near += 1
        if n_near == 0:
            continue
        for i in range(model.body_start[a], model.body_start[a + 1]):
            pa = particle(model, x, rot, a, i)
            if not _can_reach(model, x, wide, a, i, pa, b):
                continue
            for m in range(n_near):
                j = near_index[m]
                dd = sub(pa, row(near, m))
                ri, rj = model.radius[i], model.radius[j]
                within = wide[a] + wide[b] + ri + rj  # centres' distance
                if dot(dd, dd) < within * within:
                    if k < out.shape[0]:
                        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = a, i, b, j
                        # pairs come sorted by (a, b): the keys increase
                        keys[k] = base + ((a * nb + b) * npt + i) * npt + j
                    k += 1
    return k


@inlined_kernel
def find_candidates_into(model, x, v, dt, kick, margin, buf):
    """The step's contact candidates into `buf`: rows (body a, particle i, body b or -1,
    particle j or plane index) of the contacts that could touch within the step, given the
    velocity change `kick` the integrator makes before contact, each body's reach (`buf.reach`)
    widened by `margin` (m) into `buf.wide`. Returns their count, which may exceed the capacity
    (then nothing else is valid), or minus the number of body pairs if those exceed theirs.

    Body pairs: `buf.pairs[:buf.counts[COUNT_PAIRS]]` if the caller found them (`pair_list`,
    with the same widened reaches), else found here pair by pair. Needs `buf.rot` and
    `buf.omega`.
    """
    reach_into(model, v, buf.omega, dt, kick, buf.reach)
    for b in range(x.shape[0]):
        buf.wide[b] = buf.reach[b] + margin
    n_pairs = buf.counts[COUNT_PAIRS]
    if n_pairs < 0:
        n_pairs = all_pairs_into(model.bound_radius, x, buf.wide, buf.pairs)
        if n_pairs > buf.pairs.shape[0]:
            return -n_pairs
    k = _plane_candidates_into(model, x, buf.rot, buf.wide, buf.cands, buf.keys)
    return _pair_candidates_into(
        model,
        x,
        buf.rot,
        buf.wide,
        buf.pairs,
        n_pairs,
        buf.cands,
        buf.keys,
        k,
        buf.near,
        buf.near_index,
    )
