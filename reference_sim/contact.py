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

1. Candidates (`find_candidates_into`): particle-plane pairs, and particle pairs of *different*
   bodies whose bounding spheres can meet (`all_pairs`, or `grid_pairs` for many bodies),
   whose gap could close within the step at the bodies' current speeds. Particles of one body
   are never paired.
2. Before the drift (`before_drift`): speculative contacts on the velocity the drift will use
   (v plus the part of this step's gravity the integrator adds during the drift). A contact
   with gap g may approach by at most g / dt, so the drift ends touching, never penetrating
   (to first order in the rotation). A candidate whose gap is beyond what its bodies can
   move in the step at these velocities (their `reach`) stands by, unassembled and unsolved,
   unless the solve speeds the bodies up enough to close it (`_wake`): at a rocking cube's
   lifted corners, a falling ball's floor, a pile's neighbours. A contact that would close
   within the step at more than the bounce threshold bounces: its normal speed becomes -e
   times the approach speed. Coulomb friction acts with every normal impulse. A gap already
   negative (the rotation's second-order overshoot) is closed at BAUMGARTE of its depth per
   step.
3. After the drift (`after_drift`): touching contacts get the inelastic rest of the step's
   impulse (normal speed >= 0 and friction), which removes the gravity the drift's second half
   added: a resting body ends the step with zero velocity, exactly still, without creep.

Both solves are projected Gauss-Seidel with accumulated impulses: normal impulse >= 0, friction
impulse inside the disc |P_t| <= mu P_n; impulses change the COM velocity and the world angular
momentum (dL = r x P). A contact that sticks is solved as one 3 x 3 block (normal and friction
together); one that slides, normal first, then friction. Sweeps skip the contacts far from
acting until the rest have converged (IDLE_MARGIN). Early in a solve a few subspace steps
solve the contacts that push all together, directly (`_subspace_step`), for the slow modes of
stacks (scenes of two bodies or more); once the sweeps converge at a steady rate, the impulses
are extrapolated along it (`_extrapolate`). A warm-started solve of one body that the sweeps
have not converged in RESTART_SWEEPS starts again from no impulse. They work in
`ContactBuffers`, allocated once per run.
"""

import math
from typing import NamedTuple

import numpy as np

from reference_sim.dense import cholesky_into, cholesky_solve
from reference_sim.jit import compiled, inlined_kernel, kernel
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
    tangents,
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
# Stop Gauss-Seidel when no impulse changes a speed by more than this (m/s), or by more than
# GAP_ROUNDING / dt if that is larger: the speculative targets -gap / dt carry the gaps' rounding
# (a few ulps of coordinates up to ~10 m, ~1e-14 m) divided by dt, and four contacts of one face
# asking for speeds that differ by that much cannot all be met: Gauss-Seidel then cycles at
# that amplitude instead of converging (measured on `incline` at dt 0.001: a cycle of
# 1.0014e-13 m/s held 72 of its 2000 steps at MAX_ITERATIONS).
VELOCITY_TOLERANCE = 1e-13
GAP_ROUNDING = 1e-14
MAX_ITERATIONS = 500
# A solve stalls, and stops unconverged, when its bodies' velocity change over a sweep has not
# fallen below STALL_PROGRESS of its value at the last such fall for STALL_SWEEPS sweeps: it is
# cycling, not converging (a rate worse than 0.5 in 150 sweeps would need thousands of sweeps
# to reach the tolerance). Measured on every contact case of the catalog (`euler` and
# `splitting`): only `cube_rain_8`'s solves at MAX_ITERATIONS stall, all 5 of them (`euler`)
# and 16 of 18 (`splitting`), each cycling after an impact in the pile: between sticking and
# sliding, the speeds changing by 0.5 m/s every sweep, or stationary at 1e-6 m/s. Stopping
# them saves 18 % and 32 % of the run's sweeps. With 100 sweeps one solve that converged after
# 243 sweeps would have stalled at 151. The runs part after the first stalled solve (a pile is
# chaotic): `euler` 8,417 sweeps instead of 9,238 with 9 solves stalled instead of 5 at the
# limit, in the same time; `splitting` 11,116 instead of 15,965, 18 stalled, 30 % less time a
# step; every stalled solve, run on without the rule, reached MAX_ITERATIONS (tested).
STALL_SWEEPS = 150
STALL_PROGRESS = 0.5
# A solve cycles, and stops unconverged, when from its sweep CYCLE_START on, the velocity change
# of each of CYCLE_PERIODS periods' worth of sweeps (at least CYCLE_MIN_SWEEPS) has been within
# CYCLE_AGREEMENT (relative) of the one a period earlier, for some period up to
# CYCLE_MAX_PERIOD sweeps. `cube_rain_8`'s stalled solves cycle with periods of 1 to 23
# sweeps (their changes repeat to 3 digits or more, never bit for bit), and the stall rule takes
# 150 sweeps to stop them. With this rule `cube_rain_8` takes 4,522 sweeps instead of 4,918 with
# 10 solves stopped unconverged instead of 6 (`euler`; its pile takes another path) and 5,356
# instead of 6,422 with 12 instead of 11 (`splitting`): medians of interleaved whole runs 14 %
# faster with `splitting` in two A/Bs, 8 % faster and 4 % slower with `euler`. No other catalog
# run changes (`euler`, bit-equal). The first solve it stops, run on without either rule,
# reaches MAX_ITERATIONS (tested). A change shrinking by less than CYCLE_AGREEMENT a sweep
# counts as repeating: it would take over 690 sweeps to halve, and the stall rule stops it too.
CYCLE_START = 10
CYCLE_MAX_PERIOD = 32
CYCLE_PERIODS = 2
CYCLE_MIN_SWEEPS = 6
CYCLE_AGREEMENT = 1e-3
# Extrapolation (`_extrapolate`): when the bodies' velocity change over a sweep has shrunk by
# the same ratio rho (to within RATE_AGREEMENT of it) over the last RATE_SWEEPS sweeps, one slow
# mode is left, and the sweeps would go on changing the impulses by rho times their last change,
# sweep after sweep: that sweep's change times rho / (1 - rho), the sum of them all, is added at
# once. Only below RATE_MAX (not tuned): towards rho = 1 the jump, and the error an inexact rho
# makes in it, grow without bound; at RATE_MAX the jump is 49 sweeps' worth.
# A pile converges that way: one of `cube_rain_8`'s solves shrank by 0.894 a sweep from its
# 20th sweep to its 205th. The same 100 states of `cube_rain_8` (a run on the sweeps alone),
# each stepped once, took 5,280 sweeps instead of 8,039 (`euler`) and 6,819 instead of 11,026
# (`splitting`) with RATE_SWEEPS 3; 4 with RATE_AGREEMENT 0.01, 5,456 and 7,062; 2 with 0.03,
# 5,356 and 6,782; 3 with 0.1, 5,651 and 6,889 (extrapolating a sweep after the rate showed).
# The extrapolation follows the very sweep that shows the rate (the impulses it started from
# are kept when the sweep before left it one agreement short), and a rate whose extrapolation
# ended its solve at the next sweep is trusted by the next solve on the same side of the drift
# (`ContactBuffers.rates`): a sweep whose ratio agrees with it extrapolates at once. A body
# rocking on an edge converges in one mode, at the same rate step after step (`dropped_cube`,
# 0.45 a sweep from its third sweep on): its pre-drift solves took 7 sweeps, now 4. Whole runs,
# sweeps (`euler` / `splitting`): `dropped_cube` 2,400 / 3,606 extrapolating a sweep later with
# RATE_SWEEPS 3; 2,190 / 3,186 at once; 1,956 / 2,773 with RATE_SWEEPS 2; 1,755 / 2,362 with
# the trusted rate; `seed_cube` 2,295 / 2,530 -> 2,069 / 2,192, `cube_stack` 3,298 / 2,258 ->
# 3,353 / 2,251, `incline` 6,395 / 9,513 -> 6,394 / 9,593, `cube_rain_8` 4,522 / 5,356 ->
# 4,263 / 5,072. Interleaved A/B (3 rounds, medians of 31 whole runs, with the shorter update
# chain of `_update`, 1 / 4 % of it): `dropped_cube` 14 / 20 % less time, `seed_cube` 5 / 13 %,
# the other contact cases within +-3 %.
RATE_SWEEPS = 2
RATE_AGREEMENT = 0.03
RATE_MAX = 0.98
# Subspace steps (projected Gauss-Seidel with subspace minimisation, after Silcowitz, Niebe and
# Erleben 2010): Gauss-Seidel removes a stack's tilting mode, where every level turns at the same
# rate, by well under 1 % a sweep. After each of a solve's sweeps SUBSPACE_FIRST to
# SUBSPACE_FIRST + SUBSPACE_STEPS - 1 that has not converged, the contacts that push (normal,
# and friction too where it sticks) are solved together, directly, then projected onto the
# impulses' bounds; sweeps go on and still decide convergence. Measured on `cube_stack`
# (`euler`, dt 0.01), sweeps and steps in the whole run: 218,700 sweeps and 41 solves at
# MAX_ITERATIONS without steps; a step after every third sweep, at most 5: 8,200 and 767 steps;
# after sweeps 2 to 6: 5,400 and 705 (dt 0.0025: 21,000 sweeps instead of 34,800; 5,083 and 628
# since the step's impulse changes carry no cancellation), and `dropped_cube` 1,800 sweeps
# instead of 6,400 without steps. Not after a cold start's first sweep: the step then fixes
# that sweep's lopsided impulses, and a cube set on a floor rests on two diagonal corners, their
# friction pushing them together at 60 % of the cone (3,300 sweeps and 564 steps; with 2
# steps, 3,500 and 428, but the stack's cold start no longer converges to 1e-14). A solve in
# which some contact starts from last step's impulses has no such sweep and takes its first
# step after sweep SUBSPACE_FIRST_WARM: `cube_stack` 3,414 sweeps and 622 steps instead of
# 5,083 and 628 (`euler`), 2,247 and 242 instead of 3,321 and 567 (`splitting`), 10 % less
# time; `dropped_cube` 1,596 sweeps instead of 1,805 (it now takes none: SUBSPACE_MIN_BODIES);
# a cube set on a floor rests as before.
# Without a cap, post-drift solves could cycle between a step and its projection up to the limit
# (4 solves). No step when every pushing contact slides: their friction is held fixed, and it
# is what the sweeps are still adjusting (`incline`: 14 % fewer sweeps, each step 1.3x slower).
SUBSPACE_FIRST = 2
SUBSPACE_FIRST_WARM = 1
SUBSPACE_STEPS = 5
# The subspace is solved densely, 6 unknowns per body; more bodies than this, no subspace step.
# It bounds the system at 96 unknowns (a 74 kB matrix, about 1.5e5 multiply-adds to factor);
# the catalog's subspaces have at most 8 bodies (`cube_rain_8`), its stack 5.
SUBSPACE_MAX_BODIES = 16
# Scenes of fewer bodies than this take no subspace step: one body's contacts (an edge's two
# corners, a face's four) pin its 6 unknowns, which Gauss-Seidel settles in a few sweeps, and a
# step costs about ten sweeps (one body: 670 to 900 ns, against 33 to 118 ns for a sweep of 2 to
# 4 contacts). `dropped_cube` takes 2,400 sweeps without steps instead of 1,464 and 265 steps
# (`euler`), 3,606 instead of 1,823 and 468 (`splitting`). Medians of interleaved whole runs,
# builds without its steps against with: `euler` 7 to 27 % faster in 8 of 9 comparisons (5 %
# slower in one), `splitting` 22 to 30 % faster in all 7 (1.35 against 1.86 us a step in the
# last). The other single-body cases took at most 24 steps a run. Decided per scene, before any
# call: a call alone, passing every buffer, costs about 100 ns.
SUBSPACE_MIN_BODIES = 2
# A warm-started solve in a scene of at most RESTART_MAX_BODIES bodies that has not converged
# in RESTART_SWEEPS sweeps starts again, once, from no impulse (`_solve`): one body's contacts
# settle in a few sweeps, from last step's impulses or from none, so such a solve has been led
# astray by its warm start. `dropped_cube` (`euler`, dt 0.02) as it lands flat, one edge
# sliding onto the floor while the other pivots: from last step's impulses the friction
# updates cycle (194 and 223 sweeps, stopped unconverged, the cube turning at up to 5e-3 rad/s
# about an axis its mirror-symmetric landing cannot turn it about, and resting 1.1e-5 m off
# its plane of symmetry); from none the first converges in 48 sweeps to the symmetric motion.
# The run takes 859 sweeps instead of 1,580, none unconverged (977 restarting only the solves
# the stall and cycle rules stop). Of the single-body contact cases at dt 0.005, 0.01, 0.02
# and their own (`euler`, `splitting`, `exact`), only `dropped_cube` has warm solves past 50
# sweeps: that one, and one at dt 0.01 (`splitting`, `exact`: 5 more sweeps in the run). With
# 30, `slide`, `fast_impact` and `dropped_cube` restart solves that were converging (up to 15 %
# more sweeps). A pile's warm solves take long without being astray: restarting them took
# `cube_rain_8` 5,314 sweeps instead of 4,233 (`euler`).
RESTART_SWEEPS = 50
RESTART_MAX_BODIES = 1
# Regularisation of the subspace's equalities, relative to the largest contact inverse mass:
# the four corners of a face make them redundant (singular), and the regularised solve picks
# the smallest impulse change. It leaves about this fraction, over the smallest nonzero
# eigenvalue (relative), of the speed errors; the sweeps after the step remove it.
SUBSPACE_REGULARIZATION = 1e-8
# A contact whose friction impulse is within this relative rounding of mu P_n slides (the
# sliding update sets it to mu P_n up to rounding); inside, it sticks.
DISC_ROUNDING = 1e-12
# The warm start continues a contact's impulse along its trend when its last two changes differ
# by less than TREND_AGREEMENT of the latest, and the latest moves a speed by more than
# TREND_NOISE solver tolerances. A sliding cube's impulses change smoothly from step to step:
# `incline` (`euler`) takes 6,400 sweeps in all instead of 12,900, `slide` 6,100 instead of
# 7,400. Resting contacts only jitter: extrapolating every contact took `dropped_cube` 1.8 and
# `incline_stick` 2.3 times the pre-drift sweeps; with the agreement test alone, `cube_stack`
# took 1.35 times the post-drift sweeps.
TREND_AGREEMENT = 0.5
TREND_NOISE = 100.0
# The contact solver's statistics over a run (`ContactBuffers.solver`): solves, sweeps, solves
# stopped unconverged, subspace steps and extrapolations.
SOLVER_STATISTICS = 5
# Scenes with at least this many bodies find close body pairs on a uniform grid (linear in the
# number of bodies); fewer are tested pair by pair, which is faster for a handful.
GRID_MIN_BODIES = 16
# The grid has at most this many cells a body (its cell table is 8 bytes a cell): scenes spread
# wider get coarser cells, which only add candidate tests. `cube_rain_1000`'s grid has 1,296
# cells at t = 0, within its budget of 8,000.
GRID_CELLS_PER_BODY = 8
# A contact that does not push and whose normal speed exceeds its target by more than this many
# times the last sweep's largest speed change is idle: sweeps skip it until the busy contacts
# have converged, and then one pass over the idle ones decides whether the solve has (the
# stopping test is a full sweep's). Speculative candidates reach a particle radius beyond what
# the step can close, so most of a pile's are idle: `cube_rain_8` (`euler`) made 352,600
# contact updates in its solves, 100,400 with idle ones skipped, and every run checked (13
# cases, `euler` and `splitting`) is bit-equal: no idle contact would have pushed meanwhile.
IDLE_MARGIN = 10.0


@kernel
def solver_tolerance(dt):
    """Where Gauss-Seidel stops (m/s): VELOCITY_TOLERANCE, or GAP_ROUNDING / dt if larger."""
    return max(VELOCITY_TOLERANCE, GAP_ROUNDING / dt)


@kernel
def world_omega(model, q, L, b):
    """World angular velocity omega = R I0^-1 R^T L of body b (q, L: that body's rows), a tuple."""
    r = qmatrix(q)
    return mat_vec(r, mat_vec(mat(model.inertia0_inv, b), mat_t_vec(r, L)))


@inlined_kernel
def frames_into(model, q, L, rot, inv, omega):
    for b in range(q.shape[0]):
        r = qmatrix((q[b, 0], q[b, 1], q[b, 2], q[b, 3]))
        i_world = conjugate_by(r, mat(model.inertia0_inv, b))
        w = mat_vec(i_world, row(L, b))
        for k in range(9):
            rot[b, k] = r[k]
            inv[b, k] = i_world[k]
        omega[b, 0], omega[b, 1], omega[b, 2] = w


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
def _grid_pairs_into(model, x, reach, cells, dims, order, cell_start, found, pairs):
    """The pairs of `_all_pairs_into`, in the same order, testing only bodies in neighbouring
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
                    if b > a and _near(model, x, reach, a, b):
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
def all_pairs(model, x, reach):
    """(P, 2) body pairs a < b whose bounding spheres can meet within the step (`reach`:
    `reach_into`), sorted, tested pair by pair."""
    pairs = np.empty((2 * x.shape[0] + 16, 2), dtype=np.int64)
    n = _all_pairs_into(model, x, reach, pairs)
    if n > pairs.shape[0]:
        pairs = np.empty((n, 2), dtype=np.int64)
        _all_pairs_into(model, x, reach, pairs)
    return pairs[:n]


@kernel
def _bin(model, x, reach, cells, dims, keys, max_cells):
    """Each body's grid cell and its key (cells numbered along z, then y, then x), on cubic
    cells as wide as the largest interaction distance, doubled until there are at most
    `max_cells`; returns the number of cells, or 0 if the grid would be unbounded (NaN or
    infinite coordinates)."""
    nb = x.shape[0]
    cell = 0.0
    for b in range(nb):
        cell = max(cell, 2.0 * (model.bound_radius[b] + reach[b]))
    if not (cell > 0.0 and math.isfinite(cell)):
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
def _extent(x, k):
    """The smallest and largest coordinate k of the bodies."""
    lo, hi = x[0, k], x[0, k]
    for b in range(x.shape[0]):
        lo, hi = min(lo, x[b, k]), max(hi, x[b, k])
    return lo, hi


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


@compiled
def grid_pairs(model, x, reach):
    """`all_pairs`, found on a uniform grid: bodies are binned into cubic cells at least as wide
    as the largest interaction distance (`_bin`) and only bodies in neighbouring cells are
    tested, so the cost grows linearly with the number of bodies. Same result (tested), so the
    simulation is bit-equal either way. Without a bounded grid (NaN or infinite coordinates) it
    tests every pair.
    """
    nb = x.shape[0]
    dims = np.ones(3, dtype=np.int64)
    cells = np.zeros((nb, 3), dtype=np.int64)
    keys = np.empty(nb, dtype=np.int64)
    n_cells = 0 if nb == 0 else _bin(model, x, reach, cells, dims, keys, GRID_CELLS_PER_BODY * nb)
    if n_cells == 0:
        return all_pairs(model, x, reach)
    order = np.empty(nb, dtype=np.int64)
    cell_start = np.zeros(n_cells + 1, dtype=np.int64)
    _sort_by_cell(keys, cell_start, order)
    found = np.empty(nb, dtype=np.int64)
    pairs = np.empty((2 * nb + 16, 2), dtype=np.int64)
    n = _grid_pairs_into(model, x, reach, cells, dims, order, cell_start, found, pairs)
    if n > pairs.shape[0]:
        pairs = np.empty((n, 2), dtype=np.int64)
        _grid_pairs_into(model, x, reach, cells, dims, order, cell_start, found, pairs)
    return pairs[:n]


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
def _speed(rows, a, b, v, omega):
    """Relative velocity of a contact along the direction of its Jacobian `rows` (5, 3)."""
    # summed as two sums of three, not one running sum of six: a Gauss-Seidel sweep waits on
    # each speed in turn (`_update`), and this halves the additions in a row
    u = (rows[0, 0] * v[a, 0] + rows[0, 1] * v[a, 1] + rows[0, 2] * v[a, 2]) + (
        rows[1, 0] * omega[a, 0] + rows[1, 1] * omega[a, 1] + rows[1, 2] * omega[a, 2]
    )
    if b >= 0:
        u -= (rows[0, 0] * v[b, 0] + rows[0, 1] * v[b, 1] + rows[0, 2] * v[b, 2]) + (
            rows[3, 0] * omega[b, 0] + rows[3, 1] * omega[b, 1] + rows[3, 2] * omega[b, 2]
        )
    return u


@inlined_kernel
def _push(model, jac, a, b, v, L, omega, p0, p1, p2):
    """Apply the impulse changes p0 (normal), p1, p2 (tangents) along a contact's Jacobian
    `jac` (3, 5, 3) to both bodies (dL = r x P): summed per body first, then each of v, L and
    omega changed once. (One push per direction, each changing them: `dropped_cube` 1.02 against
    0.97 us a step, `euler`, 1.42 against 1.35 `splitting`, medians of interleaved whole runs.)
    Inlined: a call passing `Model` by value made `dropped_cube` 1.6 times slower."""
    along_a = 1.0 / model.body_mass[a]
    along_b = 1.0 / model.body_mass[b] if b >= 0 else 0.0
    for i in range(3):
        force = p0 * jac[0, 0, i] + p1 * jac[1, 0, i] + p2 * jac[2, 0, i]
        v[a, i] += along_a * force
        L[a, i] += p0 * jac[0, 1, i] + p1 * jac[1, 1, i] + p2 * jac[2, 1, i]
        omega[a, i] += p0 * jac[0, 2, i] + p1 * jac[1, 2, i] + p2 * jac[2, 2, i]
        if b >= 0:
            v[b, i] -= along_b * force
            L[b, i] -= p0 * jac[0, 3, i] + p1 * jac[1, 3, i] + p2 * jac[2, 3, i]
            omega[b, i] -= p0 * jac[0, 4, i] + p1 * jac[1, 4, i] + p2 * jac[2, 4, i]


@kernel
def _invert3(m):
    """Invert the symmetric 3 x 3 matrix m (9,) (row major) in place, by cofactors."""
    c00 = m[4] * m[8] - m[5] * m[7]
    c01 = m[5] * m[6] - m[3] * m[8]
    c02 = m[3] * m[7] - m[4] * m[6]
    c11 = m[0] * m[8] - m[2] * m[6]
    c12 = m[2] * m[3] - m[0] * m[5]
    c22 = m[0] * m[4] - m[1] * m[3]
    scale = 1.0 / (m[0] * c00 + m[1] * c01 + m[2] * c02)
    m[0], m[1], m[2] = c00 * scale, c01 * scale, c02 * scale
    m[3], m[4], m[5] = c01 * scale, c11 * scale, c12 * scale
    m[6], m[7], m[8] = c02 * scale, c12 * scale, c22 * scale


@inlined_kernel
def _assemble(model, x, nc, gate, buf, kept, standby=False):
    """Per candidate k < nc of `buf`: its gap, whether it acts (`buf.acting[k]`, or its gap is
    at most `gate`), its Jacobian rows and its normal and tangent inverse masses.

    A row k < `kept` that already holds them for the same contact (`buf.made[k] ==
    buf.keys[k]`) keeps them: the caller vouches that rows below `kept` were assembled at the
    bodies' current pose to within rounding (`rigid.POSE_ROUNDING`), so they are what this
    would compute to within rounding. (A row past them may hold the same contact assembled at
    an older pose.) Records in `buf.made` which rows it assembled. With `standby`, an active
    contact whose gap its bodies' reach cannot close (`_closes`) is left on standby
    (`buf.standby[k]`): gap only, no rows, until `_wake` finds it needed."""
    buf.counts[4] = 0
    for k in range(nc):
        buf.standby[k] = False
        if k < kept and buf.made[k] == buf.keys[k]:
            buf.active[k] = buf.acting[k] or buf.gap[k] <= gate
            continue
        n, buf.gap[k], ra, rb = contact_geometry(model, x, buf.rot, buf.cands, k)
        buf.active[k] = buf.acting[k] or buf.gap[k] <= gate
        buf.standby[k] = standby and buf.active[k] and not _closes(buf, buf.reach, k)
        buf.made[k] = buf.keys[k] if buf.active[k] and not buf.standby[k] else -1
        buf.counts[4] += buf.standby[k]
        if buf.made[k] >= 0:
            _assemble_rows(model, buf, k, n, ra, rb)


# Standby (`_assemble`, `_wake`): the candidates a particle radius beyond reach are there in
# case the solve speeds their bodies up; most never push. Measured against solving them all:
# `dropped_cube` (`euler`) 752 -> 707 ns a step while it rocks on an edge (its two lifted
# corners on standby), whole runs (medians of interleaved runs) `bounce` -7 %, `cube_rain_8`
# -6 %, `dropped_cube` -2 %, `incline`, `seed_cube`, `resting_cube` within +-2 % (none on
# standby: the flag tests alone). 21 of the catalog's 24 contact runs (`euler`, `splitting`)
# are bit-equal; in `dropped_cube` (`splitting`) and `cube_rain_8` a woken contact joins the
# sweeps later, and the runs differ by rounding (5.6e-17, and 2.2e-11 in the pile).
@kernel
def _closes(buf, reach, k):
    """Whether contact k's bodies, each moving at most its `reach` (m) in the step, could
    close its gap (to within IMPACT_SLACK, the impact test's)."""
    a, b = buf.cands[k, 0], buf.cands[k, 2]
    return not buf.gap[k] > reach[a] + (reach[b] if b >= 0 else 0.0) + IMPACT_SLACK


@inlined_kernel
def _assemble_rows(model, buf, k, n, ra, rb):
    """Contact k's Jacobian rows and inverse masses, from its normal n and lever arms ra, rb
    (`contact_geometry`)."""
    cands, inv, jac, kn, kt, kt_inv = buf.cands, buf.inv, buf.jac, buf.kn, buf.kt, buf.kt_inv
    k_inv = buf.k_inv
    a, b = cands[k, 0], cands[k, 2]
    # a plane contact's tangents are its plane's, fixed (`Model.plane_tangents`): no square
    # root and division ahead of the rows (`dropped_cube`'s 4 contacts assembled in 145
    # instead of 169 ns; bit-equal)
    if b < 0:
        pt, j = model.plane_tangents, cands[k, 3]
        t1, t2 = (
            (pt[j, 0, 0], pt[j, 0, 1], pt[j, 0, 2]),
            (pt[j, 1, 0], pt[j, 1, 1], pt[j, 1, 2]),
        )
    else:
        t1, t2 = tangents(n)
    for d in range(3):
        direction = n if d == 0 else (t1 if d == 1 else t2)
        rows = jac[k, d]
        arm_a = cross(ra, direction)
        arm_b = cross(rb, direction)
        turn_a = mat_vec(flat(inv, a), arm_a)
        turn_b = mat_vec(flat(inv, b), arm_b) if b >= 0 else (0.0, 0.0, 0.0)
        for i in range(3):
            rows[0, i] = direction[i]
            rows[1, i] = arm_a[i]
            rows[2, i] = turn_a[i]
            rows[3, i] = arm_b[i] if b >= 0 else 0.0
            rows[4, i] = turn_b[i]
    inv_mass = 1.0 / model.body_mass[a] + (1.0 / model.body_mass[b] if b >= 0 else 0.0)
    for d in range(3):
        for e in range(d, 3):
            rd, re = jac[k, d], jac[k, e]
            entry = 0.0
            for i in range(3):
                entry += inv_mass * rd[0, i] * re[0, i] + rd[1, i] * re[2, i]
                # a plane's rows 3 and 4 are zeros: adding their products changed nothing
                # and cost `dropped_cube`, `incline` and `slide` 3.5 to 4 % of a run
                if b >= 0:
                    entry += rd[3, i] * re[4, i]
            k_inv[k, 3 * d + e] = entry  # K itself, inverted below
            k_inv[k, 3 * e + d] = entry
            if d == 0 and e == 0:
                kn[k] = entry
            elif d > 0:
                kt[k, 2 * (d - 1) + (e - 1)] = entry
                kt[k, 2 * (e - 1) + (d - 1)] = entry
    det = kt[k, 0] * kt[k, 3] - kt[k, 1] * kt[k, 2]
    kt_inv[k, 0], kt_inv[k, 1] = kt[k, 3] / det, -kt[k, 1] / det
    kt_inv[k, 2], kt_inv[k, 3] = -kt[k, 2] / det, kt[k, 0] / det
    _invert3(k_inv[k])


@kernel
def _into_disc(mu, p0, p1, p2):
    """Friction impulse (p1, p2) scaled back onto the Coulomb disc |P_t| <= mu p0 if outside it."""
    limit = mu * p0
    if p1 * p1 + p2 * p2 > limit * limit:
        shrink = limit / math.sqrt(p1 * p1 + p2 * p2)
        p1, p2 = p1 * shrink, p2 * shrink
    return p1, p2


@kernel
def _set_impulses(model, buf, k, p0, p1, p2, v, L):
    """Set contact k's impulses (normal p0, friction p1, p2) projected onto its bounds (normal
    >= 0, friction in the Coulomb disc), and apply their changes to v and L."""
    p0 = max(p0, 0.0)
    p1, p2 = _into_disc(model.friction, p0, p1, p2)
    lam = buf.lam[k]
    d0, d1, d2 = p0 - lam[0], p1 - lam[1], p2 - lam[2]
    if d0 != 0.0 or d1 != 0.0 or d2 != 0.0:
        _push(model, buf.jac[k], buf.cands[k, 0], buf.cands[k, 2], v, L, buf.omega, d0, d1, d2)
        lam[0], lam[1], lam[2] = p0, p1, p2


@kernel
def _subspace_rows(model, nc, buf):
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
    # contact or two, where the sweeps are not slow (`cube_rain_8`: 450 steps saved 8 % of the
    # sweeps and made a step 1.6 times slower)
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


@kernel
def _subspace_step(model, nc, buf, v, L):
    """Solve the subspace's equalities together (`_subspace_rows`: each row's speed at its
    target; their Jacobians on the bodies' (v, omega) into `buf.row_jac`), then project the
    impulses onto their bounds and apply the changes.

    Regularised by eps (SUBSPACE_REGULARIZATION): the impulse changes are dP = (W + eps)^-1 e'
    for the rows' speed errors e, W = J M^-1 J^T, where e' = J du1, du1 = A^-1 J^T e and
    A = eps M + J^T J (one system of 6 unknowns per body), is the part of e a motion of the
    bodies can meet, so that targets no rigid motion meets at once (`_iterate`) do not set
    impulses of order (their disagreement) / eps. Since (W + eps)^-1 J = J A^-1 M, dP is
    J A^-1 M du1: a second solve with the same factor, and no division by eps. (Computing dP as
    (e' - J A^-1 J^T e') / eps instead loses about 8 of its 16 digits to cancellation: 1e-8
    relative error, against 1e-15 this way, checked in 50-digit arithmetic.) Returns False,
    changing no impulse, if there is no subspace (`_subspace_rows`) or the solve fails.
    """
    n_rows, n_bodies = _subspace_rows(model, nc, buf)
    if n_rows == 0 or n_bodies < 0:
        return False
    n = 6 * n_bodies
    errors, a = buf.row_lam, buf.normal
    eps = 0.0
    for r in range(n_rows):
        k, d = buf.rows[r, 0], buf.rows[r, 1]
        jac, jr = buf.jac[k, d], buf.row_jac[r]  # on (v, omega) of body a, then of body b
        for i in range(3):
            jr[i], jr[3 + i] = jac[0, i], jac[1, i]
            jr[6 + i], jr[9 + i] = -jac[0, i], -jac[3, i]
        aim = buf.target[k] if d == 0 else 0.0
        errors[r] = aim - _speed(jac, buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
        eps = max(eps, SUBSPACE_REGULARIZATION * buf.kn[k])
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
    if not cholesky_into(a, n):
        return False
    _subspace_rhs(buf, n_rows, n, errors)
    cholesky_solve(a, n, buf.rhs)  # du1
    for b in range(buf.slot.shape[0]):  # M du1
        if buf.slot[b] < 0:
            continue
        at = 6 * buf.slot[b]
        turn = mat_vec(_inertia(model, buf, b), (buf.rhs[at + 3], buf.rhs[at + 4], buf.rhs[at + 5]))
        for i in range(3):
            buf.rhs[at + i] *= model.body_mass[b]
            buf.rhs[at + 3 + i] = turn[i]
    cholesky_solve(a, n, buf.rhs)
    for r in range(n_rows):  # the impulse changes
        errors[r] = _subspace_speed(buf, r, buf.rhs)
    for r in range(n_rows):
        if not math.isfinite(errors[r]):
            return False
    r = 0
    for k in range(nc):
        if r == n_rows:
            break
        if buf.rows[r, 0] != k:
            continue
        p0, p1, p2 = buf.lam[k, 0] + errors[r], buf.lam[k, 1], buf.lam[k, 2]
        if r + 1 < n_rows and buf.rows[r + 1, 0] == k:  # sticks: the tangents are rows too
            p1, p2 = p1 + errors[r + 1], p2 + errors[r + 2]
            r += 2
        r += 1
        _set_impulses(model, buf, k, p0, p1, p2, v, L)
    return True


@inlined_kernel
def _sticking(model, buf, k, v, vn, l0, l1, l2):
    """The change (d0, d1, d2) of contact k's impulses from l0, l1, l2 that meets its normal
    target (`buf.target`, at normal speed vn now) and stops its sliding, through its inverse
    3 x 3 mass, the impulses it leads to (n0, n1, n2), and whether they are in bounds (normal
    >= 0, friction in the Coulomb disc): the contact then sticks (`_update`)."""
    a, b = buf.cands[k, 0], buf.cands[k, 2]
    u1 = _speed(buf.jac[k, 1], a, b, v, buf.omega)
    u2 = _speed(buf.jac[k, 2], a, b, v, buf.omega)
    ki = buf.k_inv[k]
    e0, e1, e2 = buf.target[k] - vn, -u1, -u2
    # the changes first, pushed as computed: the push need not wait for the new impulses and
    # their differences from the old (with `_speed`'s sums, `dropped_cube` 1 to 4 % less time,
    # `incline` and `cube_stack` 2 %)
    d0 = ki[0] * e0 + (ki[1] * e1 + ki[2] * e2)
    d1 = ki[3] * e0 + (ki[4] * e1 + ki[5] * e2)
    d2 = ki[6] * e0 + (ki[7] * e1 + ki[8] * e2)
    n0, n1, n2 = l0 + d0, l1 + d1, l2 + d2
    sticks = n0 >= 0.0 and n1 * n1 + n2 * n2 <= (model.friction * n0) ** 2
    return d0, d1, d2, n0, n1, n2, sticks


@inlined_kernel
def _update(model, buf, k, v, L, change):
    """One Gauss-Seidel update of contact k's impulses (`_iterate`), applied to v and L;
    returns `change`, raised to the largest speed the update changed, and whether the contact
    sticks (solved as one 3 x 3 block)."""
    cands, jac, kn, kt, kt_inv = buf.cands, buf.jac, buf.kn, buf.kt, buf.kt_inv
    target, omega, lam = buf.target, buf.omega, buf.lam
    a, b = cands[k, 0], cands[k, 2]
    normal, tangent1, tangent2 = jac[k, 0], jac[k, 1], jac[k, 2]
    vn = _speed(normal, a, b, v, omega)
    if model.friction > 0.0:
        # sticking: the impulse that meets the normal target and stops the sliding, all
        # three at once through the contact's inverse 3 x 3 mass, if it is in the disc.
        # Solving normal and friction one after the other instead converges slowly when
        # they couple (a corner below the centre of mass: pressing it turns the body and
        # slides the corner): `dropped_cube` takes 6400 sweeps in all instead of 10100.
        d0, d1, d2, n0, n1, n2, sticks = _sticking(
            model, buf, k, v, vn, lam[k, 0], lam[k, 1], lam[k, 2]
        )
        if sticks:
            lam[k, 0], lam[k, 1], lam[k, 2] = n0, n1, n2
            _push(model, jac[k], a, b, v, L, omega, d0, d1, d2)
            change = max(change, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) * kn[k])
            buf.slack[k] = -math.inf
            return change, True
    # normal impulse, accumulated and kept >= 0
    new = max(lam[k, 0] + (target[k] - vn) / kn[k], 0.0)
    buf.slack[k] = vn - target[k] if new == 0.0 else -math.inf
    dl = new - lam[k, 0]
    if dl != 0.0:
        lam[k, 0] = new
        _push(model, jac[k], a, b, v, L, omega, dl, 0.0, 0.0)
        change = max(change, abs(dl) * kn[k])
    # a contact that does not push and had no friction keeps none: its disc is a point. (22 %
    # of the updates from 100 states of `cube_rain_8`, whose candidates mostly do not push;
    # skipping their tangential speeds took 13 % off stepping those states, `euler`, and
    # changed no run.)
    if model.friction == 0.0 or new == 0.0 and lam[k, 1] == 0.0 and lam[k, 2] == 0.0:
        return change, False
    # friction: the impulse that stops the sliding if it fits in the Coulomb disc; else
    # mu P_n against the sliding velocity this contact's own friction leaves (maximum
    # dissipation). Clipping the stopping impulse instead would aim the friction along
    # K_t^-1 u, off the sliding direction whenever K_t is anisotropic: a sliding cube
    # would yaw and decelerate by less than mu g.
    g1 = _speed(tangent1, a, b, v, omega)
    g2 = _speed(tangent2, a, b, v, omega)
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
        _push(model, jac[k], a, b, v, L, omega, 0.0, d1, d2)
        # kn, the normal's inverse mass, scales impulses to speeds like the tangents' would
        change = max(change, math.sqrt(d1 * d1 + d2 * d2) * kn[k])
    return change, False


@kernel
def _moved(model, v, omega, bodies):
    """The largest velocity change of a body since `bodies` (v, omega) was taken: |dv| + bound
    radius |d omega|, its fastest surface point's."""
    moved = 0.0
    for b in range(v.shape[0]):
        dv = 0.0
        dw = 0.0
        for i in range(3):
            dv = max(dv, abs(v[b, i] - bodies[b, i]))
            dw = max(dw, abs(omega[b, i] - bodies[b, 3 + i]))
        moved = max(moved, dv + model.bound_radius[b] * dw)
    return moved


@kernel
def _busy(buf, k, margin):
    """Whether contact k is busy: it pushes, or its normal speed is within `margin` (m/s) of
    its target (`buf.slack`)."""
    return buf.lam[k, 0] > 0.0 or buf.slack[k] <= margin


@kernel
def _regroup(buf, n_busy, n_idle, margin, rejoin):
    """Regroup the contacts of `buf.busy` (`_iterate`): busy ones (`_busy`) at its start, idle
    ones at its end, backwards, each group in its order; returns how many of each. Idle ones
    may rejoin the busy ones only if `rejoin` (they have been visited since last grouped)."""
    order = buf.busy
    end = order.shape[0] - 1
    if rejoin:
        kept = 0
        for m in range(n_idle):
            k = order[end - m]
            if _busy(buf, k, margin):
                order[n_busy] = k
                n_busy += 1
            else:
                order[end - kept] = k
                kept += 1
        n_idle = kept
    n = 0
    for m in range(n_busy):
        k = order[m]
        if _busy(buf, k, margin):
            order[n] = k
            n += 1
        else:
            order[end - n_idle] = k
            n_idle += 1
    return n, n_idle


@kernel
def _cycles(cycle, n, moved):
    """Record `moved`, the velocity change of a solve's sweep n (counted from CYCLE_START), in
    `cycle` (2, CYCLE_MAX_PERIOD): the last changes by sweep, and for each period p the run of
    sweeps whose change agreed with the one p sweeps before (CYCLE_AGREEMENT). Returns whether
    some run has reached CYCLE_PERIODS periods (and CYCLE_MIN_SWEEPS sweeps)."""
    # the constant, not cycle.shape[1]: the ring's index is then a mask, not an integer
    # division (78 against 28 ns a call, from sweep CYCLE_START of every solve on)
    size = CYCLE_MAX_PERIOD
    if n == 0:
        for p in range(size):
            cycle[1, p] = 0.0
    found = False
    for p in range(1, min(n, size) + 1):
        earlier = cycle[0, (n - p) % size]
        if abs(moved - earlier) <= CYCLE_AGREEMENT * earlier:
            cycle[1, p - 1] += 1.0
            found = found or cycle[1, p - 1] >= max(CYCLE_PERIODS * p, CYCLE_MIN_SWEEPS)
        else:
            cycle[1, p - 1] = 0.0
    cycle[0, n % size] = moved
    return found


@kernel
def _extrapolate(model, buf, n, v, L, factor):
    """Add `factor` times the last sweep's impulse change (since `buf.lam_sweep`) to each of the
    first n contacts of `buf.busy`, projected onto its bounds (normal >= 0, friction in the
    Coulomb disc), and apply the changes to v and L. The sweeps go on from there and still
    decide convergence."""
    for m in range(n):
        k = buf.busy[m]
        lam, last = buf.lam[k], buf.lam_sweep[k]
        p0 = lam[0] + factor * (lam[0] - last[0])
        p1 = lam[1] + factor * (lam[1] - last[1])
        p2 = lam[2] + factor * (lam[2] - last[2])
        _set_impulses(model, buf, k, p0, p1, p2, v, L)


@inlined_kernel
def _wake_one(model, x, buf, k):
    """Take contact k off standby: its rows assembled, busy until its first update."""
    n, buf.gap[k], ra, rb = contact_geometry(model, x, buf.rot, buf.cands, k)
    _assemble_rows(model, buf, k, n, ra, rb)
    buf.made[k], buf.standby[k], buf.slack[k] = buf.keys[k], False, -math.inf
    buf.counts[4] -= 1


@inlined_kernel
def _wake(model, x, nc, dt, buf, v, n_busy):
    """Wake the contacts on standby (`_assemble`) whose gap the bodies, at their velocities now
    (as the solve has changed them), could close within the step (`_closes`): they join the
    busy ones in `buf.busy`. Returns the new count of busy contacts. A contact left on standby
    has a normal speed above its target -gap / dt: a normal update would leave it no impulse."""
    if buf.counts[4] == 0:
        return n_busy
    reach_into(model, v, buf.omega, dt, (0.0, 0.0, 0.0), buf.reach)  # as the drift will use
    for k in range(nc):
        if buf.standby[k]:
            if _closes(buf, buf.reach, k):
                _wake_one(model, x, buf, k)
                buf.busy[n_busy] = k
                n_busy += 1
    return n_busy


@inlined_kernel
def _iterate(
    model,
    x,
    nc,
    dt,
    buf,
    v,
    L,
    tolerance,
    idle_margin,
    first=SUBSPACE_FIRST,
    slot=0,
    limit=MAX_ITERATIONS,
):
    """Gauss-Seidel sweeps until no impulse changes a speed by `tolerance` (m/s), or no body's
    velocity changes by that much over a sweep; returns the sweeps used and whether the solve
    converged (else it reached `limit` sweeps, stalled (STALL_SWEEPS) or cycled (`_cycles`)).

    Sweeps visit the busy contacts only (`_busy`, with margin `idle_margin` times the last
    sweep's largest speed change; IDLE_MARGIN), and the idle ones too once the busy ones pass
    the stopping test: the solve stops only when a sweep over every contact passes it. With
    `idle_margin` infinite every sweep visits every contact.

    The second test ends the sweeps once the motion has converged but the impulses of redundant
    contacts (the four corners of a face) still move: internal forces that change no velocity.
    They move when the targets ask for speeds no rigid motion meets at once (a face whose gaps
    straddle zero gets -gap / dt on one side and -BAUMGARTE gap / dt on the other), and then
    keep moving until one impulse reaches a bound, hundreds of sweeps later (measured on
    `dropped_cube`: 10 of its 500 steps ran to MAX_ITERATIONS with the velocities converged to
    1e-18 m/s; it takes 10100 sweeps in all instead of 14800). The velocities then meet each
    contact's target to within that disagreement.
    A body's velocity change is |dv| + bound radius |d omega|, its fastest surface point's.
    A subspace step (`_subspace_step`) follows each of the sweeps `first` to
    `first` + SUBSPACE_STEPS - 1 if it has not converged and a contact stuck in it.
    After RATE_SWEEPS sweeps whose velocity changes shrank by a steady ratio, or one whose
    ratio agrees with the rate trusted for this `slot` (`buf.rates`: 0 before the drift, 1
    after), the impulse changes of the last sweep are extrapolated (`_extrapolate`); if the
    next sweep converges, the next solve of this slot trusts the rate.
    Contacts on standby (`_assemble`) are not swept; once the sweeps converge, those the
    velocities now reach are woken (`_wake`) and the sweeps go on with them."""
    omega, bodies, order = buf.omega, buf.bodies, buf.busy
    end = order.shape[0] - 1
    n_busy, n_idle = 0, 0
    for k in range(nc):
        if buf.active[k] and not buf.standby[k]:
            order[n_busy] = k
            n_busy += 1
    progress, since = math.inf, 0  # the velocity change at its last fall (STALL_PROGRESS)
    last, rate, steady, armed = math.inf, 0.0, 0, False
    trusted, tried = buf.rates[slot], 0.0
    for it in range(limit):
        change = 0.0
        sticking = model.friction == 0.0  # a subspace step needs a sticking contact
        for b in range(v.shape[0]):
            for i in range(3):
                bodies[b, i], bodies[b, 3 + i] = v[b, i], omega[b, i]
        if armed:  # the impulses this sweep starts from
            for m in range(n_busy):
                k = order[m]
                for d in range(3):
                    buf.lam_sweep[k, d] = buf.lam[k, d]
        # the busy contacts, then the idle ones if the busy ones pass the stopping test (one
        # loop: `_update` is inlined once)
        rejoin, m, stop = False, 0, n_busy
        while True:
            while m < stop:
                k = order[m] if m < n_busy else order[end - (m - n_busy)]
                change, sticks = _update(model, buf, k, v, L, change)
                sticking = sticking or sticks
                m += 1
            moved = _moved(model, v, omega, bodies)
            converged = change < tolerance or moved < tolerance
            if rejoin or not converged or n_idle == 0:
                break
            rejoin, stop = True, n_busy + n_idle
        if converged:
            awake = _wake(model, x, nc, dt, buf, v, n_busy)
            if awake == n_busy:
                if tried > 0.0:  # the extrapolation ended the solve: the next may trust its rate
                    buf.rates[slot] = tried
                return it + 1, True
            n_busy = awake  # sweeps go on with the woken contacts
            last, rate, steady, armed, tried = math.inf, 0.0, 0, False, 0.0
            continue
        if tried > 0.0:  # it did not: no rate is trusted
            trusted, tried = 0.0, 0.0
            buf.rates[slot] = 0.0
        if moved < STALL_PROGRESS * progress:
            progress, since = moved, it
        elif it - since >= STALL_SWEEPS:
            return it + 1, False
        if it >= CYCLE_START and _cycles(buf.cycle, it - CYCLE_START, moved):
            return it + 1, False
        ratio = moved / last
        steady = steady + 1 if abs(ratio - rate) < RATE_AGREEMENT * ratio else 0
        rate, last = ratio, moved
        known = abs(ratio - trusted) < RATE_AGREEMENT * ratio
        if armed and (steady >= RATE_SWEEPS - 1 or known) and rate < RATE_MAX:
            _extrapolate(model, buf, n_busy, v, L, rate / (1.0 - rate))
            buf.solver[4] += 1
            tried = rate
            last, rate, steady = math.inf, 0.0, 0
        armed = (steady >= RATE_SWEEPS - 2 or trusted > 0.0) and 0.0 < rate < RATE_MAX
        n_busy, n_idle = _regroup(buf, n_busy, n_idle, idle_margin * change, rejoin)
        if sticking and first <= it + 1 < first + SUBSPACE_STEPS:
            buf.solver[3] += _subspace_step(model, nc, buf, v, L)
    return limit, False


@inlined_kernel
def _bounces(model, v, nc, dt, bounce_threshold, buf):
    """-e times the approach speed of every contact that impacts within the step, else 0, into
    `buf.bounce` (needs `_assemble`'s gaps and Jacobians)."""
    for k in range(nc):
        buf.bounce[k] = 0.0
        # on standby, its gap is beyond reach: no impact within the step. With no restitution
        # an impact leaves at normal speed 0, as a resting contact does (`dropped_cube` at rest
        # 385 -> 380 ns a step, bit-equal)
        if buf.standby[k] or model.restitution == 0.0:
            continue
        vn = _speed(buf.jac[k, 0], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
        if vn < -bounce_threshold and buf.gap[k] + dt * vn < IMPACT_SLACK:
            buf.bounce[k] = -model.restitution * vn


class ContactBuffers(NamedTuple):
    """Everything a contact step writes, allocated once per run and grown when a step needs
    more room, so that steps allocate nothing.

    Per body: rot, inv (B, 9) rotation matrices and world inverse inertias (row major), omega
    (B, 3), reach (B,). Body pairs that can meet: pairs (P, 2). Per candidate (capacity C):
    cands (C, 4), keys (C,) (increasing), jac (C, 3, 5, 3), kn (C,), kt and kt_inv (C, 4)
    (2 x 2 row major), k_inv (C, 9) (the inverse 3 x 3 mass of normal and tangents, row major),
    gap, target, bounce (C,), active, acting (C,), lam (C, 3), hist (C, 2, 3) (its impulses of
    the two steps before, NaN: none), made (C,) (the key of the contact whose gap, rows and
    inverse masses row k holds, -1: none; rows below counts[3] hold them for the current pose:
    `after_drift` sets it, a drift clears it unless it moved no body by rigid.POSE_ROUNDING),
    slack (C,) (its normal speed above its target when it does not push, -inf when it does),
    busy (2C,) (`_iterate`'s contacts: busy ones from the start, idle ones from the end);
    bodies (B, 6), v and omega at a sweep's start; lam_sweep (C, 3), the impulses at the start
    of a sweep that `_extrapolate` follows. The warm start: keys and impulses of the last
    three steps (C, 3, 3) (age, direction) before and after the drift, of the counts[0] and
    counts[1] contacts that pushed, in key order. counts[2]: how many rows of `pairs` the
    caller filled for this step, or -1 to have them found pair by pair. standby (C,): the
    candidates left on standby before the drift (`_assemble`), counts[4] of them.
    solver (5,): solves, sweeps, solves stopped unconverged (at MAX_ITERATIONS, stalled:
    STALL_SWEEPS, or cycling: `_cycles`), subspace steps and extrapolations, summed over the run.
    The subspace step (`_subspace_step`): rows (3C, 2) (contact, direction), row_jac (3C, 12)
    and row_lam (3C,) per row, slot (B,) each body's place in it (-1: not in it), normal
    (6S, 6S) and rhs (6S,), S = min(B, SUBSPACE_MAX_BODIES). cycle (2, CYCLE_MAX_PERIOD): the
    cycle test's record (`_cycles`). pose (B, 7): each body's x and q where the kept rows were
    assembled (`rigid.rigid_step`). rates (2,): the rate of the last extrapolation that ended
    its solve, before and after the drift (0: none; `_iterate`).
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
    gap: np.ndarray
    target: np.ndarray
    bounce: np.ndarray
    active: np.ndarray
    acting: np.ndarray
    lam: np.ndarray
    hist: np.ndarray
    made: np.ndarray
    busy: np.ndarray
    slack: np.ndarray
    k_inv: np.ndarray
    bodies: np.ndarray
    lam_sweep: np.ndarray
    pre_keys: np.ndarray
    pre_lam: np.ndarray
    post_keys: np.ndarray
    post_lam: np.ndarray
    counts: np.ndarray
    solver: np.ndarray
    rows: np.ndarray
    row_jac: np.ndarray
    row_lam: np.ndarray
    slot: np.ndarray
    normal: np.ndarray
    rhs: np.ndarray
    cycle: np.ndarray
    pose: np.ndarray
    rates: np.ndarray
    standby: np.ndarray


@compiled
def contact_buffers(n_bodies, capacity, pair_capacity):
    """Empty buffers for `capacity` candidates and `pair_capacity` body pairs."""
    c, s = capacity, min(n_bodies, SUBSPACE_MAX_BODIES)
    counts = np.zeros(5, dtype=np.int64)
    counts[2] = -1
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
        np.zeros(c),
        np.zeros(c, dtype=np.bool_),
        np.zeros(c, dtype=np.bool_),
        np.zeros((c, 3)),
        np.zeros((c, 2, 3)),
        np.full(c, -1, dtype=np.int64),
        np.zeros(2 * c, dtype=np.int64),
        np.zeros(c),
        np.zeros((c, 9)),
        np.zeros((n_bodies, 6)),
        np.zeros((c, 3)),
        np.empty(c, dtype=np.int64),
        np.zeros((c, 3, 3)),
        np.empty(c, dtype=np.int64),
        np.zeros((c, 3, 3)),
        counts,
        np.zeros(SOLVER_STATISTICS, dtype=np.int64),
        np.zeros((3 * c, 2), dtype=np.int64),
        np.zeros((3 * c, 12)),
        np.zeros(3 * c),
        np.full(n_bodies, -1, dtype=np.int64),
        np.zeros((6 * s, 6 * s)),
        np.zeros(6 * s),
        np.zeros((2, CYCLE_MAX_PERIOD)),
        np.zeros((n_bodies, 7)),
        np.zeros(2),
        np.zeros(c, dtype=np.bool_),
    )


@kernel
def _carry_over(old, new):
    for k in range(old.counts[0]):
        new.pre_keys[k] = old.pre_keys[k]
        for age in range(3):
            for d in range(3):
                new.pre_lam[k, age, d] = old.pre_lam[k, age, d]
    for k in range(old.counts[1]):
        new.post_keys[k] = old.post_keys[k]
        for age in range(3):
            for d in range(3):
                new.post_lam[k, age, d] = old.post_lam[k, age, d]
    for k in range(3):  # not counts[3]: the new buffers hold no assembled rows
        new.counts[k] = old.counts[k]
    for k in range(SOLVER_STATISTICS):
        new.solver[k] = old.solver[k]
    for k in range(2):
        new.rates[k] = old.rates[k]


@compiled
def grown(buf, capacity, pair_capacity):
    """Buffers with at least these capacities, carrying over the warm start of `buf`."""
    nb, c, p = buf.rot.shape[0], buf.cands.shape[0], buf.pairs.shape[0]
    new = contact_buffers(nb, max(capacity, c), max(pair_capacity, p))
    _carry_over(buf, new)
    return new


@inlined_kernel
def find_candidates_into(model, x, v, dt, kick, buf):
    """The step's contact candidates into `buf`: rows (body a, particle i, body b or -1,
    particle j or plane index) of the contacts that could touch within the step, given the
    velocity change `kick` the integrator makes before contact. A particle radius of slack on
    top of the reach keeps contacts that rotation brings a little closer than the linear
    estimate. Returns their count, which may exceed the capacity (then nothing else is valid),
    or minus the number of body pairs if those exceed theirs.

    Body pairs: `buf.pairs[:buf.counts[2]]` if the caller found them (`grid_pairs`), else found
    here pair by pair. Needs `buf.rot` and `buf.omega`.
    """
    reach_into(model, v, buf.omega, dt, kick, buf.reach)
    n_pairs = buf.counts[2]
    if n_pairs < 0:
        n_pairs = _all_pairs_into(model, x, buf.reach, buf.pairs)
        if n_pairs > buf.pairs.shape[0]:
            return -n_pairs
    k = _plane_candidates_into(model, x, buf.rot, buf.reach, buf.cands, buf.keys)
    return _pair_candidates_into(
        model, x, buf.rot, buf.reach, buf.pairs, n_pairs, buf.cands, buf.keys, k
    )


@kernel
def _trend(model, warm_lam, at, kn, tolerance):
    """Warm-start impulses (normal, two tangents) from a contact's impulses of the last three
    steps, warm_lam[at] (age, direction), NaN where it had none: last step's, continued by
    last step's change if the last two changes agree (TREND_AGREEMENT) and are not rounding
    jitter (TREND_NOISE), projected onto the impulses' bounds."""
    last = (warm_lam[at, 0, 0], warm_lam[at, 0, 1], warm_lam[at, 0, 2])
    if math.isnan(warm_lam[at, 2, 0]):
        return last
    change, curve = 0.0, 0.0
    for d in range(3):
        latest = warm_lam[at, 0, d] - warm_lam[at, 1, d]
        change = max(change, abs(latest))
        curve = max(curve, abs(latest - (warm_lam[at, 1, d] - warm_lam[at, 2, d])))
    if not (curve < TREND_AGREEMENT * change and change * kn > TREND_NOISE * tolerance):
        return last
    p0 = max(2.0 * last[0] - warm_lam[at, 1, 0], 0.0)
    p1 = 2.0 * last[1] - warm_lam[at, 1, 1]
    p2 = 2.0 * last[2] - warm_lam[at, 1, 2]
    p1, p2 = _into_disc(model.friction, p0, p1, p2)
    return p0, p1, p2


@inlined_kernel
def _warm_start(model, x, nc, buf, v, L, warm_keys, warm_lam, n_warm, tolerance):
    """Each contact that matches one of last step's starts from its impulses, continued along
    their trend (`_trend`), applied; the impulses of the steps before go into `buf.hist` for
    `_remember` (NaN: none). Both key lists are in increasing order: one merge pass matches
    them. Returns how many contacts matched."""
    at, warm = 0, 0
    for k in range(nc):
        buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2] = 0.0, 0.0, 0.0
        for age in range(2):
            for d in range(3):
                buf.hist[k, age, d] = math.nan
        while at < n_warm and warm_keys[at] < buf.keys[k]:
            at += 1
        if buf.active[k] and at < n_warm and warm_keys[at] == buf.keys[k]:
            for age in range(2):
                for d in range(3):
                    buf.hist[k, age, d] = warm_lam[at, age, d]
            warm += 1
            if buf.standby[k]:  # it pushed last step: it needs its rows
                _wake_one(model, x, buf, k)
            p0, p1, p2 = _trend(model, warm_lam, at, buf.kn[k], tolerance)
            buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2] = p0, p1, p2
            if p0 != 0.0 or p1 != 0.0 or p2 != 0.0:
                a, b = buf.cands[k, 0], buf.cands[k, 2]
                _push(model, buf.jac[k], a, b, v, L, buf.omega, p0, p1, p2)
    return warm


@inlined_kernel
def _remember(nc, buf, keys, lam):
    """Keys and impulses of the contacts that pushed (normal impulse > 0), in key order, for
    the next step, with their impulses of the two steps before (`buf.hist`); returns how many.
    A contact without impulse would start from none either way. (After the drift every active
    contact was remembered before 4a2ff45: every catalog run but `dropped_cube` (`euler`,
    2.2e-16 apart) is bit-equal to that, with the same sweeps.)"""
    n = 0
    for k in range(nc):
        if buf.lam[k, 0] > 0.0:
            keys[n] = buf.keys[k]
            for d in range(3):
                lam[n, 0, d] = buf.lam[k, d]
                lam[n, 1, d] = buf.hist[k, 0, d]
                lam[n, 2, d] = buf.hist[k, 1, d]
            n += 1
    return n


@inlined_kernel
def _solve(model, x, v, L, nc, dt, buf, warm_keys, warm_lam, n_warm, slot):
    """Projected Gauss-Seidel on the normal and friction impulses of the active contacts
    (`_assemble`), in place, towards `buf.target` normal speeds, to `solver_tolerance(dt)`.
    Impulses start from those of the same contacts in the previous steps (`warm_keys`,
    `warm_lam`, `_trend`): a body resting on a plane converges in one sweep. The first subspace
    step may follow the first sweep if some contact matched (SUBSPACE_FIRST_WARM), else the
    second; none in a scene of fewer than SUBSPACE_MIN_BODIES bodies. `slot`: 0 before the
    drift, 1 after (its trusted extrapolation rate, `_iterate`). A warm-started solve of at
    most RESTART_MAX_BODIES bodies not converged in RESTART_SWEEPS sweeps starts again from no
    impulse, once, within MAX_ITERATIONS in all. Counts the solve in `buf.solver`."""
    tolerance = solver_tolerance(dt)
    warm = _warm_start(model, x, nc, buf, v, L, warm_keys, warm_lam, n_warm, tolerance)
    first = SUBSPACE_FIRST_WARM if warm > 0 else SUBSPACE_FIRST
    if v.shape[0] < SUBSPACE_MIN_BODIES:
        first = MAX_ITERATIONS + 1  # after no sweep
    restart = warm > 0 and v.shape[0] <= RESTART_MAX_BODIES
    budget = RESTART_SWEEPS if restart else MAX_ITERATIONS
    sweeps = 0
    while True:  # one call site: `_iterate` is inlined
        used, converged = _iterate(
            model, x, nc, dt, buf, v, L, tolerance, IDLE_MARGIN, first, slot, budget
        )
        sweeps += used
        if converged or not restart:
            break
        # astray (RESTART_SWEEPS): once more from no impulse, with the sweeps left
        restart, budget = False, MAX_ITERATIONS - sweeps
        for k in range(nc):
            if buf.active[k]:
                _set_impulses(model, buf, k, 0.0, 0.0, 0.0, v, L)
    buf.solver[0] += 1
    buf.solver[1] += sweeps
    buf.solver[2] += not converged


@inlined_kernel
def before_drift(model, x, v, L, nc, dt, drift_gravity, bounce_threshold, buf):
    """Speculative impulses on the first nc candidates of `buf`, on the velocity the drift will
    use: v + drift_gravity (m/s), the part of this step's gravity the integrator adds during the
    drift. Every candidate acts, with target normal speed -gap / dt (a gap already negative is
    closed at BAUMGARTE of its depth per step). Changes v and L; needs `buf.rot`, `buf.inv`,
    `buf.omega` of the step's start.

    Leaves in `buf.bounce` the normal speed each contact must leave with after the drift: -e
    times its approach speed for an impact (a contact closing within the step faster than
    `bounce_threshold`), else 0 (the bounce is applied after the drift, when the contact has
    arrived), and in `buf.acting` the contacts that pushed or bounce.
    """
    for b in range(v.shape[0]):
        for i in range(3):
            v[b, i] += drift_gravity[i]
    for k in range(nc):
        buf.acting[k] = True
    # the bodies have not moved since the last step's `after_drift` assembled its contacts
    _assemble(model, x, nc, TOUCH_TOLERANCE, buf, buf.counts[3], True)
    _bounces(model, v, nc, dt, bounce_threshold, buf)
    for k in range(nc):
        gap = buf.gap[k]
        buf.target[k] = -gap / dt if gap >= 0.0 else -BAUMGARTE * gap / dt
    _solve(model, x, v, L, nc, dt, buf, buf.pre_keys, buf.pre_lam, buf.counts[0], 0)
    buf.counts[0] = _remember(nc, buf, buf.pre_keys, buf.pre_lam)
    for k in range(nc):
        buf.acting[k] = buf.lam[k, 0] > 0.0 or buf.bounce[k] > 0.0
    for b in range(v.shape[0]):
        for i in range(3):
            v[b, i] -= drift_gravity[i]


@inlined_kernel
def _pushes_nothing(model, nc, buf, v):
    """Whether a solve of the first nc contacts' active ones, from no impulse, would push
    nothing: the first update of each (`_update`) leaves it without impulse, its normal speed
    at or above its target and, with friction, its sticking block out of bounds. The first
    sweep then changes nothing and ends the solve."""
    for k in range(nc):
        if buf.active[k]:
            vn = _speed(buf.jac[k, 0], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
            if not buf.target[k] - vn <= 0.0:
                return False
            if model.friction > 0.0 and _sticking(model, buf, k, v, vn, 0.0, 0.0, 0.0)[6]:
                return False
    return True


@inlined_kernel
def after_drift(model, x, q, v, L, nc, dt, buf):
    """Impulses after the drift on the contacts that pushed before it or bounce
    (`buf.acting`) or touch now (gap below TOUCH_TOLERANCE): the bounce targets of
    `before_drift`, else inelastic (normal speed >= 0, and friction). Changes v and L; skips
    a solve known to push nothing (`_pushes_nothing`). Keeps the rows below `buf.counts[3]`:
    the caller vouches that no body has moved by more than rounding (`rigid.POSE_ROUNDING`)
    since they were assembled."""
    frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    _assemble(model, x, nc, TOUCH_TOLERANCE, buf, buf.counts[3])
    buf.counts[3] = nc  # rows for the current pose, until the next drift
    for k in range(nc):
        buf.target[k] = buf.bounce[k]
    # With no impulse to warm-start from (none pushed after the last drift) and none that an
    # update would start, the solve would end after one sweep without impulses, changing nothing:
    # it is counted, as a solve of no sweep, and skipped. That is where no touching contact
    # approaches: a body at rest (`euler`: nothing changed its velocity since the solve before
    # the drift), one pivoting (the drift's rotation turns a pivot's velocity upwards), a ball
    # leaving the floor. Every catalog contact run is bit-equal with and without it (`euler`,
    # `splitting`, `exact`). Skipped: 427 of `dropped_cube`'s 930 solves (`euler`), 733 of
    # `bounce`'s 4,812, 209 of `cube_collision`'s 426; medians of interleaved whole runs
    # (5 rounds of 31): `dropped_cube` 6 % less time (at rest 442 -> 381 ns a step), `bounce`
    # 5 %, `cube_collision` 3 %, `resting_cube` (whose solves push) within noise.
    if buf.counts[1] == 0 and _pushes_nothing(model, nc, buf, v):
        for k in range(nc):
            buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2] = 0.0, 0.0, 0.0
        buf.solver[0] += 1
        return
    _solve(model, x, v, L, nc, dt, buf, buf.post_keys, buf.post_lam, buf.counts[1], 1)
    buf.counts[1] = _remember(nc, buf, buf.post_keys, buf.post_lam)
