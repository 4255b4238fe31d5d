"""`ContactBuffers`: everything a contact step writes, allocated once per run.

Counters are read by name: `buf.counts[COUNT_...]`, `buf.solver[STAT_...]`, `buf.rates[...]`
with PRE_DRIFT or POST_DRIFT.
"""

from typing import NamedTuple

import numpy as np

from reference_sim.contact.settings import CYCLE_MAX_PERIOD, SUBSPACE_MAX_BODIES
from reference_sim.jit import compiled, kernel

# `ContactBuffers.counts`, one int64 each:
COUNT_PRE_WARM = 0  # contacts that pushed before the last drift (`pre_keys`, `pre_lam`)
COUNT_POST_WARM = 1  # contacts that pushed after the last drift (`post_keys`, `post_lam`)
# rows of `pairs` the caller filled for this step, having made its frames (`rot`, `inv`, `omega`
# at the step's pose); -1: pairs found pair by pair and frames made in `rigid.rigid_step`
COUNT_PAIRS = 2
COUNT_KEPT_ROWS = 3  # rows below this hold their contact's gap, Jacobian and masses at this pose
COUNT_STANDBY = 4  # candidates left on standby (`standby`)
COUNT_SWEEP = 5  # sweeps so far (`mark`)
N_COUNTS = 6

# `ContactBuffers.solver`, the contact solver's statistics summed over a run:
STAT_SOLVES = 0
STAT_SWEEPS = 1  # Gauss-Seidel sweeps
STAT_UNCONVERGED = 2  # solves stopped at MAX_ITERATIONS, stalled or cycling
STAT_SUBSPACE_STEPS = 3
STAT_EXTRAPOLATIONS = 4
STAT_QUIET = 5  # updates skipped as quiet (`gauss_seidel._pile_sweep`)
STAT_REFOUND = 6  # steps whose candidates were found again: the solve outran them (`rigid_step`)
SOLVER_STATISTICS = 7

# `ContactBuffers.rates` and the solves' `slot`: the solve before the drift and the one after.
PRE_DRIFT = 0
POST_DRIFT = 1


class ContactBuffers(NamedTuple):
    """Everything a contact step writes, allocated once per run and grown when a step needs
    more room, so that steps allocate nothing. B bodies, C candidates (capacity), P body pairs,
    S = min(B, SUBSPACE_MAX_BODIES) bodies in a subspace step, Q particles in the largest body.
    Matrices are row major.

    Attributes:
      rot, inv: (B, 9) each body's rotation matrix and world inverse inertia.
      omega: (B, 3) world angular velocities. reach: (B,) how far a body can move in the step (m).
      wide: (B,) the reach the candidates were found with (`candidate_margin` wider).
      start: (B, 6) each body's v and L at the step's start, for a step found again.
      pairs: (P, 2) body pairs that can meet.
      cands: (C, 4) candidates: body a, particle i, body b or -1, particle j or plane index.
      keys: (C,) each candidate's key, increasing (it identifies the contact across steps).
      jac: (C, 3, 5, 3) per direction (normal, two tangents) the Jacobian rows (`rows.py`).
      kn: (C,) normal inverse mass. kt, kt_inv: (C, 4) the tangents' 2 x 2 and its inverse.
        kc: (C, 2) the tangents' speeds per unit normal impulse (K's normal-tangent entries).
      k_inv: (C, 9) the inverse 3 x 3 mass of normal and tangents.
      gap, target, bounce: (C,) gap (m), target normal speed and bounce speed (m/s).
      active, acting: (C,) solved in this solve; pushed or bounces before the drift.
      lam: (C, 3) impulses (normal, two tangents). hist: (C, 2, 3) those of the two steps
        before (NaN: none).
      made: (C,) the key of the contact whose gap, rows and masses row k holds (-1: none).
      busy: (2C,) the sweeps' contacts: busy ones from the start, idle ones from the end.
      slack: (C,) normal speed above target of a contact that does not push (-inf: it pushes).
      bodies: (B, 6) v and omega at a sweep's start. lam_sweep: (C, 3) impulses at a sweep's
        start (`gauss_seidel.extrapolate` follows their change).
      pre_keys, pre_lam: (C,), (C, 3, 3) (age, direction) keys and impulses of the last three
        steps of the contacts that pushed before the drift, in key order; post_keys, post_lam:
        after it. The warm start.
      counts: (N_COUNTS,) the COUNT_* counters. solver: (SOLVER_STATISTICS,) the STAT_* sums.
      rows: (3C, 2) a subspace step's rows (contact, direction); row_jac: (3C, 12) each row's
        Jacobian on (v, omega) of body a then b; row_lam: (3C,) its speed error, then impulse.
      slot: (B,) each body's place in the subspace (-1: not in it).
      normal: (6S, 6S) the subspace's matrix and its factor; rhs: (6S,).
      cycle: (2, CYCLE_MAX_PERIOD) the cycle rule's record (`gauss_seidel.cycles`).
      pose: (B, 7) each body's x and q where the kept rows were assembled (`rigid.rigid_step`).
      rates: (2,) at PRE_DRIFT and POST_DRIFT, the rate of the last extrapolation that ended
        its solve (0: none).
      standby: (C,) candidates left on standby before the drift (`rows.assemble`).
      due, idle: (C // 64 + 1,) bit sets over the candidates of a pile's solve: due for an
        update, idle (`gauss_seidel._pile_sweep`). link_first: (B + 1,) and links: (2C,) each
        body's swept contacts, links[link_first[b]:link_first[b + 1]]. visited: (C,) the
        contacts the last sweep of a pile updated, in order.
      mark: (B,) the sweep (COUNT_SWEEP) that last touched each body; touched: (B,) the bodies
        the current sweep has touched, in order (their velocities at its start in `bodies`).
      near, near_index: (Q, 3), (Q,) world positions and indices of the particles of a body pair's
        second body that can reach the first (`candidates._pair_candidates_into`).
    """

    rot: np.ndarray
    inv: np.ndarray
    omega: np.ndarray
    reach: np.ndarray
    wide: np.ndarray
    start: np.ndarray
    pairs: np.ndarray
    cands: np.ndarray
    keys: np.ndarray
    jac: np.ndarray
    kn: np.ndarray
    kt: np.ndarray
    kt_inv: np.ndarray
    kc: np.ndarray
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
    due: np.ndarray
    idle: np.ndarray
    link_first: np.ndarray
    links: np.ndarray
    visited: np.ndarray
    mark: np.ndarray
    touched: np.ndarray
    near: np.ndarray
    near_index: np.ndarray


@kernel
def largest_body(model):
    """The most particles of one body of `model`: the room `ContactBuffers.near` needs."""
    n = 0
    for b in range(model.body_mass.shape[0]):
        n = max(n, model.body_start[b + 1] - model.body_start[b])
    return n


@compiled
def contact_buffers(n_bodies, capacity, pair_capacity, body_particles):
    """Empty buffers for `capacity` candidates and `pair_capacity` body pairs, of bodies of at
    most `body_particles` particles."""
    c, s = capacity, min(n_bodies, SUBSPACE_MAX_BODIES)
    counts = np.zeros(N_COUNTS, dtype=np.int64)
    counts[COUNT_PAIRS] = -1
    return ContactBuffers(
        rot=np.empty((n_bodies, 9)),
        inv=np.empty((n_bodies, 9)),
        omega=np.empty((n_bodies, 3)),
        reach=np.empty(n_bodies),
        wide=np.empty(n_bodies),
        start=np.empty((n_bodies, 6)),
        pairs=np.empty((pair_capacity, 2), dtype=np.int64),
        cands=np.empty((c, 4), dtype=np.int64),
        keys=np.empty(c, dtype=np.int64),
        jac=np.zeros((c, 3, 5, 3)),
        kn=np.ones(c),
        kt=np.zeros((c, 4)),
        kt_inv=np.zeros((c, 4)),
        kc=np.zeros((c, 2)),
        gap=np.zeros(c),
        target=np.zeros(c),
        bounce=np.zeros(c),
        active=np.zeros(c, dtype=np.bool_),
        acting=np.zeros(c, dtype=np.bool_),
        lam=np.zeros((c, 3)),
        hist=np.zeros((c, 2, 3)),
        made=np.full(c, -1, dtype=np.int64),
        busy=np.zeros(2 * c, dtype=np.int64),
        slack=np.zeros(c),
        k_inv=np.zeros((c, 9)),
        bodies=np.zeros((n_bodies, 6)),
        lam_sweep=np.zeros((c, 3)),
        pre_keys=np.empty(c, dtype=np.int64),
        pre_lam=np.zeros((c, 3, 3)),
        post_keys=np.empty(c, dtype=np.int64),
        post_lam=np.zeros((c, 3, 3)),
        counts=counts,
        solver=np.zeros(SOLVER_STATISTICS, dtype=np.int64),
        rows=np.zeros((3 * c, 2), dtype=np.int64),
        row_jac=np.zeros((3 * c, 12)),
        row_lam=np.zeros(3 * c),
        slot=np.full(n_bodies, -1, dtype=np.int64),
        normal=np.zeros((6 * s, 6 * s)),
        rhs=np.zeros(6 * s),
        cycle=np.zeros((2, CYCLE_MAX_PERIOD)),
        pose=np.zeros((n_bodies, 7)),
        rates=np.zeros(2),
        standby=np.zeros(c, dtype=np.bool_),
        due=np.zeros(c // 64 + 1, dtype=np.int64),
        idle=np.zeros(c // 64 + 1, dtype=np.int64),
        link_first=np.zeros(n_bodies + 1, dtype=np.int64),
        links=np.zeros(2 * c, dtype=np.int64),
        visited=np.zeros(c, dtype=np.int64),
        mark=np.zeros(n_bodies, dtype=np.int64),
        touched=np.zeros(n_bodies, dtype=np.int64),
        near=np.zeros((body_particles, 3)),
        near_index=np.zeros(body_particles, dtype=np.int64),
    )


@kernel
def _carry_over(old, new):
    """The warm start, the pairs' count and the frames it vouches for (COUNT_PAIRS), the
    statistics and the trusted rates of `old`, into `new` (not the kept rows' count: `new`
    holds no assembled rows)."""
    for k in range(old.counts[COUNT_PRE_WARM]):
        new.pre_keys[k] = old.pre_keys[k]
        for age in range(3):
            for d in range(3):
                new.pre_lam[k, age, d] = old.pre_lam[k, age, d]
    for k in range(old.counts[COUNT_POST_WARM]):
        new.post_keys[k] = old.post_keys[k]
        for age in range(3):
            for d in range(3):
                new.post_lam[k, age, d] = old.post_lam[k, age, d]
    for k in (COUNT_PRE_WARM, COUNT_POST_WARM, COUNT_PAIRS):
        new.counts[k] = old.counts[k]
    for b in range(old.rot.shape[0]):
        for i in range(9):
            new.rot[b, i], new.inv[b, i] = old.rot[b, i], old.inv[b, i]
        for i in range(3):
            new.omega[b, i] = old.omega[b, i]
    for k in range(SOLVER_STATISTICS):
        new.solver[k] = old.solver[k]
    for k in range(2):
        new.rates[k] = old.rates[k]


@compiled
def grown(buf, capacity, pair_capacity):
    """Buffers with at least these capacities, carrying over the warm start of `buf`."""
    nb, c, p = buf.rot.shape[0], buf.cands.shape[0], buf.pairs.shape[0]
    new = contact_buffers(nb, max(capacity, c), max(pair_capacity, p), buf.near.shape[0])
    _carry_over(buf, new)
    return new
