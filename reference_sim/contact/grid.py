"""The broad phase of many bodies: close body pairs found on a uniform grid (a counting sort of
the bodies into cells), the same pairs in the same order as testing every pair, in linear time.

The grid bins spheres (centres, radii, reaches): the rigid integrators' bodies by their bounding
spheres grown by their skins (`pair_list`, which keeps the pairs between steps; `grid_pairs` at
the step's reach is what it must equal), and the seed's particles (`sphere_pairs`,
`reference_sim.seed`)."""

import math

import numpy as np

from reference_sim.contact.candidates import all_sphere_pairs, near
from reference_sim.contact.settings import GRID_CELLS_PER_BODY
from reference_sim.jit import compiled, kernel


@kernel
def _extent(x, k):
    """The smallest and largest coordinate k of the bodies."""
    lo, hi = x[0, k], x[0, k]
    for b in range(x.shape[0]):
        lo, hi = min(lo, x[b, k]), max(hi, x[b, k])
    return lo, hi


@kernel
def _bin_spheres(radius, x, reach, cells, dims, keys, max_cells):
    """Each sphere's grid cell and its key (cells numbered along z, then y, then x), on cubic
    cells as wide as the largest interaction distance, doubled until there are at most
    `max_cells`; returns the number of cells, or 0 if the grid would be unbounded (NaN or
    infinite coordinates, radii or reaches: `max` would pass over a NaN one)."""
    nb = x.shape[0]
    cell = 0.0
    for b in range(nb):
        width = 2.0 * (radius[b] + reach[b])
        if not math.isfinite(width):
            return 0
        cell = max(cell, width)
    if not cell > 0.0:
        return 0
    for k in range(3):
        for b in range(nb):
            if not math.isfinite(x[b, k]):
                return 0
    (lo0, hi0), (lo1, hi1), (lo2, hi2) = _extent(x, 0), _extent(x, 1), _extent(x, 2)
    lo, span = (lo0, lo1, lo2), (hi0 - lo0, hi1 - lo1, hi2 - lo2)
    for k in range(3):
        if not math.isfinite(span[k]):
            return 0
    while (math.floor(span[0] / cell) + 1.0) * (math.floor(span[1] / cell) + 1.0) * (
        math.floor(span[2] / cell) + 1.0
    ) > max_cells:
        cell *= 2.0
    for k in range(3):
        dims[k] = int(math.floor(span[k] / cell)) + 1
        for b in range(nb):
            cells[b, k] = min(int((x[b, k] - lo[k]) / cell), dims[k] - 1)
    for b in range(nb):
        keys[b] = (cells[b, 0] * dims[1] + cells[b, 1]) * dims[2] + cells[b, 2]
    return dims[0] * dims[1] * dims[2]


@kernel
def _bin(model, x, reach, cells, dims, keys, max_cells):
    """`_bin_spheres` of the bodies' bounding spheres."""
    return _bin_spheres(model.bound_radius, x, reach, cells, dims, keys, max_cells)


@kernel
def _sort_by_cell(keys, cell_start, order):
    """Counting sort: the bodies of cell c are order[cell_start[c]:cell_start[c + 1]], in
    index order (`cell_start` zeroed, one longer than the number of cells)."""
    for b in range(keys.shape[0]):
        cell_start[keys[b] + 1] += 1
    for c in range(1, cell_start.shape[0]):
        cell_start[c] += cell_start[c - 1]
    for b in range(keys.shape[0]):  # cell_start[c] counts the bodies of cell c placed so far
        order[cell_start[keys[b]]] = b
        cell_start[keys[b]] += 1
    for c in range(cell_start.shape[0] - 1, 0, -1):
        cell_start[c] = cell_start[c - 1]
    cell_start[0] = 0


@kernel
def _grid_pairs_into(radius, x, reach, cells, dims, order, cell_start, found, pairs):
    """The pairs of `all_pairs_into`, in the same order, testing only bodies in neighbouring
    grid cells (`cells`: each body's cell; the bodies of cell c are `order[cell_start[c]:
    cell_start[c + 1]]`). Cells are numbered along z first, so the three neighbouring cells of
    an (x, y) column are one run of `order`."""
    nb = x.shape[0]
    n = 0
    for a in range(nb):
        m = 0
        z_lo, z_hi = max(cells[a, 2] - 1, 0), min(cells[a, 2] + 1, dims[2] - 1)
        for dx in range(-1, 2):
            cx = cells[a, 0] + dx
            if cx < 0 or cx >= dims[0]:
                continue
            for dy in range(-1, 2):
                cy = cells[a, 1] + dy
                if cy < 0 or cy >= dims[1]:
                    continue
                column = (cx * dims[1] + cy) * dims[2]
                for at_b in range(cell_start[column + z_lo], cell_start[column + z_hi + 1]):
                    b = order[at_b]
                    if b > a and near(radius, x, reach, a, b):
                        # insertion keeps found[:m] sorted: pairs come out in index order
                        at = m
                        while at > 0 and found[at - 1] > b:
                            found[at] = found[at - 1]
                            at -= 1
                        found[at] = b
                        m += 1
        for k in range(m):
            if n < pairs.shape[0]:
                pairs[n, 0], pairs[n, 1] = a, found[k]
            n += 1
    return n


@compiled
def sphere_pairs(radius, x, reach, capacity):
    """`all_sphere_pairs`, found on a uniform grid: spheres are binned into cubic cells at least
    as wide as the largest interaction distance (`_bin_spheres`) and only spheres in
    neighbouring cells are tested, so the cost grows linearly with their number. Same result
    (tested), so the simulation is bit-equal either way. Without a bounded grid (NaN or infinite
    coordinates or reaches) it tests every pair. `capacity`: the pairs expected (more take a
    second pass).
    """
    nb = x.shape[0]
    dims = np.ones(3, dtype=np.int64)
    cells = np.zeros((nb, 3), dtype=np.int64)
    keys = np.empty(nb, dtype=np.int64)
    n_cells = (
        0
        if nb == 0
        else _bin_spheres(radius, x, reach, cells, dims, keys, GRID_CELLS_PER_BODY * nb)
    )
    if n_cells == 0:
        return all_sphere_pairs(radius, x, reach)
    order = np.empty(nb, dtype=np.int64)
    cell_start = np.zeros(n_cells + 1, dtype=np.int64)
    _sort_by_cell(keys, cell_start, order)
    found = np.empty(nb, dtype=np.int64)
    pairs = np.empty((capacity, 2), dtype=np.int64)
    n = _grid_pairs_into(radius, x, reach, cells, dims, order, cell_start, found, pairs)
    if n > pairs.shape[0]:
        pairs = np.empty((n, 2), dtype=np.int64)
        _grid_pairs_into(radius, x, reach, cells, dims, order, cell_start, found, pairs)
    return pairs[:n]


@compiled
def grid_pairs(model, x, reach):
    """`all_pairs`, found on a uniform grid (`sphere_pairs` of the bodies' bounding spheres):
    the cost grows linearly with the number of bodies, the pairs are the same."""
    return sphere_pairs(model.bound_radius, x, reach, 2 * x.shape[0] + 16)
