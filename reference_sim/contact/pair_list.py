"""Body pairs kept from step to step (a Verlet list): the grid's pairs found once at a wider
reach, each body's skin, and reused while no body's reach plus its move since then exceeds its
skin; each step filters them by its own reach (`near`). The pairs are the grid's, in the same
order (tested), so runs are bit-equal; the grid's search runs only when the list is found again.

Why it holds: a pair that can meet this step is apart by at most reach_a + reach_b now, so was
apart by at most that plus both moves when the list was found, within skin_a + skin_b."""

import math
from typing import NamedTuple

import numpy as np

from reference_sim.contact.candidates import near
from reference_sim.contact.grid import sphere_pairs
from reference_sim.contact.settings import SKIN_RADII, SKIN_REACHES, SKIN_ROUNDING
from reference_sim.jit import compiled, kernel


class PairList(NamedTuple):
    pairs: np.ndarray  # (P, 2) sorted pairs a < b whose spheres grown by their skins met at x0
    x0: np.ndarray  # (B, 3) the centres the pairs were found at
    skin: np.ndarray  # (B,) each body's skin (m)


@compiled
def pair_list(n_bodies):
    """An empty list, which no reach fits: the first use finds it."""
    return PairList(
        np.empty((0, 2), dtype=np.int64), np.full((n_bodies, 3), np.nan), np.zeros(n_bodies)
    )


@kernel
def _holds(x, reach, found):
    """Whether every body's reach plus its move since `found.x0` is within its skin, less the
    rounding of the distances between bodies at its coordinates (SKIN_ROUNDING); False for NaN."""
    for b in range(x.shape[0]):
        moved, scale = 0.0, 1.0
        for i in range(3):
            moved += (x[b, i] - found.x0[b, i]) ** 2
            scale += abs(x[b, i])
        if not reach[b] + math.sqrt(moved) <= found.skin[b] - SKIN_ROUNDING * scale:
            return False
    return True


@compiled
def current_pairs(radius, x, reach, found, out):
    """The pairs `grid_pairs` finds for spheres `radius` at `x` moving `reach`, written to `out`
    while it has room, from the list `found` (`PairList`), found again first if it no longer
    holds them; returns the list and the pairs' count."""
    if not _holds(x, reach, found):
        skin = SKIN_REACHES * reach + SKIN_RADII * radius
        pairs = sphere_pairs(radius, x, skin, max(out.shape[0], 2 * x.shape[0] + 16))
        found = PairList(pairs, x.copy(), skin)
    n = 0
    for p in range(found.pairs.shape[0]):
        a, b = found.pairs[p, 0], found.pairs[p, 1]
        if near(radius, x, reach, a, b):
            if n < out.shape[0]:
                out[n, 0], out[n, 1] = a, b
            n += 1
    return found, n
