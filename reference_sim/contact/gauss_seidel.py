"""Projected Gauss-Seidel on the contact impulses: one contact's update, the sweeps, their
stopping rules (converged, stalled, cycling), idle and quiet contacts, and extrapolation along a
steady rate of convergence."""

import math

import numpy as np
from numba.core.extending import overload
from numba.cpython.unsafe.numbers import trailing_zeros

from reference_sim.contact.buffers import (
    COUNT_SWEEP,
    PRE_DRIFT,
    STAT_EXTRAPOLATIONS,
    STAT_QUIET,
    STAT_SUBSPACE_STEPS,
)
from reference_sim.contact.impulses import push, row_speed, set_impulses
from reference_sim.contact.rows import wake
from reference_sim.contact.settings import (
    CYCLE_AGREEMENT,
    CYCLE_MAX_PERIOD,
    CYCLE_MIN_SWEEPS,
    CYCLE_PERIODS,
    CYCLE_START,
    MAX_ITERATIONS,
    QUIET_FRACTION,
    RATE_AGREEMENT,
    RATE_MAX,
    RATE_SWEEPS,
    STALL_PROGRESS,
    STALL_SWEEPS,
    SUBSPACE_FIRST,
    SUBSPACE_STEPS,
)
from reference_sim.contact.subspace import subspace_step
from reference_sim.jit import inlined_kernel, kernel


@inlined_kernel
def sticking(model, buf, k, v, vn, l0, l1, l2):
    """The change (d0, d1, d2) of contact k's impulses from l0, l1, l2 that meets its normal
    target (`buf.target`, at normal speed vn now) and stops its sliding, through its inverse
    3 x 3 mass, the impulses it leads to (n0, n1, n2), whether they are in bounds (normal
    >= 0, friction in the Coulomb disc): the contact then sticks (`update`), and its tangent
    speeds u1, u2 now."""
    a, b = buf.cands[k, 0], buf.cands[k, 2]
    u1 = row_speed(buf.jac[k, 1], a, b, v, buf.omega)
    u2 = row_speed(buf.jac[k, 2], a, b, v, buf.omega)
    ki = buf.k_inv[k]
    e0, e1, e2 = buf.target[k] - vn, -u1, -u2
    # the changes first, pushed as computed: the push need not wait for the new impulses and
    # their differences from the old
    d0 = ki[0] * e0 + (ki[1] * e1 + ki[2] * e2)
    d1 = ki[3] * e0 + (ki[4] * e1 + ki[5] * e2)
    d2 = ki[6] * e0 + (ki[7] * e1 + ki[8] * e2)
    n0, n1, n2 = l0 + d0, l1 + d1, l2 + d2
    sticks = n0 >= 0.0 and n1 * n1 + n2 * n2 <= (model.friction * n0) ** 2
    return d0, d1, d2, n0, n1, n2, sticks, u1, u2


@inlined_kernel
def update(model, buf, k, v, change):
    """One Gauss-Seidel update of contact k's impulses (`iterate`), applied to v and omega;
    returns `change`, raised to the largest speed the update changed, and whether the contact
    sticks (solved as one 3 x 3 block)."""
    cands, jac, kn, kt, kt_inv = buf.cands, buf.jac, buf.kn, buf.kt, buf.kt_inv
    target, omega, lam = buf.target, buf.omega, buf.lam
    a, b = cands[k, 0], cands[k, 2]
    vn = row_speed(jac[k, 0], a, b, v, omega)
    u1, u2 = 0.0, 0.0
    if model.friction > 0.0:
        # sticking: the impulse that meets the normal target and stops the sliding, all three
        # at once, if it is in the disc. Normal then friction converges slowly where they
        # couple (a corner below the centre of mass: pressing it turns the body, sliding it).
        d0, d1, d2, n0, n1, n2, sticks, u1, u2 = sticking(
            model, buf, k, v, vn, lam[k, 0], lam[k, 1], lam[k, 2]
        )
        if sticks:
            lam[k, 0], lam[k, 1], lam[k, 2] = n0, n1, n2
            push(model, jac[k], a, b, v, omega, d0, d1, d2)
            change = max(change, math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) * kn[k])
            buf.slack[k] = -math.inf
            return change, True
    # normal impulse, accumulated and kept >= 0
    new = max(lam[k, 0] + (target[k] - vn) / kn[k], 0.0)
    buf.slack[k] = vn - target[k] if new == 0.0 else -math.inf
    dl = new - lam[k, 0]
    lam[k, 0] = new
    change = max(change, abs(dl) * kn[k])
    # a contact that does not push and had no friction keeps none: its disc is a point
    if model.friction == 0.0 or new == 0.0 and lam[k, 1] == 0.0 and lam[k, 2] == 0.0:
        if dl != 0.0:
            push(model, jac[k], a, b, v, omega, dl, 0.0, 0.0)
        return change, False
    # friction: the impulse that stops the sliding if it fits in the Coulomb disc; else
    # mu P_n against the sliding velocity the contact would have without its own friction
    # (docs/contact-solver.md compares it with maximum dissipation). Clipping the stopping
    # impulse instead would aim the friction along K_t^-1 u, off the sliding direction
    # whenever K_t is anisotropic: a sliding cube would yaw and decelerate by less than mu g.
    # The tangent speeds after the normal change, through K (`kc`): normal and friction
    # changes are then pushed at once.
    g1 = u1 + buf.kc[k, 0] * dl - (kt[k, 0] * lam[k, 1] + kt[k, 1] * lam[k, 2])
    g2 = u2 + buf.kc[k, 1] * dl - (kt[k, 2] * lam[k, 1] + kt[k, 3] * lam[k, 2])
    f1 = -(kt_inv[k, 0] * g1 + kt_inv[k, 1] * g2)
    f2 = -(kt_inv[k, 2] * g1 + kt_inv[k, 3] * g2)
    limit = model.friction * lam[k, 0]
    if f1 * f1 + f2 * f2 > limit * limit:
        slide = math.sqrt(g1 * g1 + g2 * g2)
        f1, f2 = -limit * g1 / slide, -limit * g2 / slide
    d1, d2 = f1 - lam[k, 1], f2 - lam[k, 2]
    lam[k, 1], lam[k, 2] = f1, f2
    if dl != 0.0 or d1 != 0.0 or d2 != 0.0:
        push(model, jac[k], a, b, v, omega, dl, d1, d2)
        # kn, the normal's inverse mass, scales impulses to speeds like the tangents' would
        change = max(change, math.sqrt(d1 * d1 + d2 * d2) * kn[k])
    return change, False


@kernel
def _moved(model, v, omega, bodies, touched, n):
    """The largest velocity change of the first n bodies of `touched` since `bodies` (v, omega)
    was taken: |dv| + bound radius |d omega|, its fastest surface point's."""
    moved = 0.0
    for m in range(n):
        b = touched[m]
        dv = 0.0
        dw = 0.0
        for i in range(3):
            dv = max(dv, abs(v[b, i] - bodies[b, i]))
            dw = max(dw, abs(omega[b, i] - bodies[b, 3 + i]))
        moved = max(moved, dv + model.bound_radius[b] * dw)
    return moved


@kernel
def _touch(buf, v, body, sweep, n):
    """Body `body` about to be changed by an update of sweep `sweep`: if it is the first, keep
    its velocities (`buf.bodies`) and list it in `buf.touched`; returns the count listed."""
    if body >= 0 and buf.mark[body] != sweep:
        buf.mark[body] = sweep
        for i in range(3):
            buf.bodies[body, i], buf.bodies[body, 3 + i] = v[body, i], buf.omega[body, i]
        buf.touched[n] = body
        n += 1
    return n


def lowest_bit(word):
    """The index of the lowest set bit of a nonzero int64 `word` (compiled: one instruction)."""
    w = int(word)
    return (w & -w).bit_length() - 1


@overload(lowest_bit)
def _lowest_bit_compiled(word):
    return lambda word: trailing_zeros(word)


@kernel
def _bit(k):
    """Contact k's word in a bit set and its bit there."""
    return k >> 6, np.int64(1) << np.int64(k & 63)


@kernel
def _next_due(buf, k, idle):
    """The first contact from k on that is due (`buf.due`) and idle (`buf.idle`) if `idle`,
    else busy; -1 if there is none."""
    w = k >> 6
    if w >= buf.due.shape[0]:
        return -1
    word = buf.due[w] & (buf.idle[w] if idle else ~buf.idle[w])
    word &= np.int64(-1) << np.int64(k & 63)
    while word == 0:
        w += 1
        if w >= buf.due.shape[0]:
            return -1
        word = buf.due[w] & (buf.idle[w] if idle else ~buf.idle[w])
    return (w << 6) + lowest_bit(word)


@kernel
def _due_on(buf, body):
    """Every swept contact on `body` is due (`buf.links`)."""
    for m in range(buf.link_first[body], buf.link_first[body + 1]):
        w, bit = _bit(buf.links[m])
        buf.due[w] |= bit


@kernel
def _all_due(buf, n_swept):
    """Every swept contact (the first n_swept of `buf.busy`) is due."""
    for m in range(n_swept):
        w, bit = _bit(buf.busy[m])
        buf.due[w] |= bit


@kernel
def _link(buf, n_swept):
    """Each body's swept contacts (the first n_swept of `buf.busy`) into `buf.links`, body b's
    from `buf.link_first[b]`, all due and none idle (`iterate_pile`)."""
    first, links, nb = buf.link_first, buf.links, buf.link_first.shape[0] - 1
    for w in range(buf.due.shape[0]):
        buf.due[w], buf.idle[w] = 0, 0
    for b in range(nb + 1):
        first[b] = 0
    for m in range(n_swept):  # counted, summed, then filled from each body's end
        k = buf.busy[m]
        first[buf.cands[k, 0]] += 1
        if buf.cands[k, 2] >= 0:
            first[buf.cands[k, 2]] += 1
    for b in range(1, nb + 1):
        first[b] += first[b - 1]
    for m in range(n_swept):
        k = buf.busy[m]
        for b in (buf.cands[k, 0], buf.cands[k, 2]):
            if b >= 0:
                first[b] -= 1
                links[first[b]] = k
    _all_due(buf, n_swept)


@kernel
def _regroup_visited(buf, n_visited, n_busy, n_idle, margin):
    """A pile's `_regroup`: the contacts the last sweep updated (`buf.visited`) become busy
    or idle (`_busy`); the others keep their group. Returns the new counts of each."""
    for m in range(n_visited):
        k = buf.visited[m]
        w, bit = _bit(k)
        was_idle = (buf.idle[w] & bit) != 0
        if _busy(buf, k, margin):
            if was_idle:
                buf.idle[w] &= ~bit
                n_busy, n_idle = n_busy + 1, n_idle - 1
        elif not was_idle:
            buf.idle[w] |= bit
            n_busy, n_idle = n_busy - 1, n_idle + 1
    return n_busy, n_idle


@kernel
def _busy(buf, k, margin):
    """Whether contact k is busy: it pushes, or its normal speed is within `margin` (m/s) of
    its target (`buf.slack`)."""
    return buf.lam[k, 0] > 0.0 or buf.slack[k] <= margin


@kernel
def _regroup(buf, n_busy, n_idle, margin, rejoin):
    """Regroup the contacts of `buf.busy` (`iterate`): busy ones (`_busy`) at its start, idle
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
def cycles(cycle, n, moved):
    """Record `moved`, the velocity change of a solve's sweep n (counted from CYCLE_START), in
    `cycle` (2, CYCLE_MAX_PERIOD): the last changes by sweep, and for each period p the run of
    sweeps whose change agreed with the one p sweeps before (CYCLE_AGREEMENT). Returns whether
    some run has reached CYCLE_PERIODS periods (and CYCLE_MIN_SWEEPS sweeps)."""
    # the constant, not cycle.shape[1]: the ring's index is then a mask, not a division
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
def extrapolate(model, buf, order, n, v, factor):
    """Add `factor` times the last sweep's impulse change (since `buf.lam_sweep`) to each of the
    first n contacts of `order`, projected onto its bounds (normal >= 0, friction in the
    Coulomb disc), and apply the changes to v and omega. The sweeps go on from there and still
    decide convergence."""
    for m in range(n):
        k = order[m]
        lam, last = buf.lam[k], buf.lam_sweep[k]
        p0 = lam[0] + factor * (lam[0] - last[0])
        p1 = lam[1] + factor * (lam[1] - last[1])
        p2 = lam[2] + factor * (lam[2] - last[2])
        set_impulses(model, buf, k, p0, p1, p2, v)


@inlined_kernel
def _list_busy(nc, buf):
    """The active contacts not on standby, at the start of `buf.busy`, all busy; their count."""
    n_busy = 0
    for k in range(nc):
        if buf.active[k] and not buf.standby[k]:
            buf.busy[n_busy] = k
            n_busy += 1
    return n_busy


@inlined_kernel
def _sweep_start(buf, n_busy, armed):
    """If `armed` (an extrapolation may follow the sweep), keep the impulses of its busy
    contacts (`buf.lam_sweep`)."""
    if armed:
        for m in range(n_busy):
            k = buf.busy[m]
            for d in range(3):
                buf.lam_sweep[k, d] = buf.lam[k, d]


@inlined_kernel
def _sweep(model, buf, v, n_busy, n_idle, tolerance, sticking_seen):
    """One sweep: the busy contacts, then the idle ones if the busy ones pass the stopping test
    (one loop: `update` is inlined once). Returns the largest speed an update changed, the
    largest body velocity change (`_moved`), whether the sweep converged, whether it visited
    the idle contacts, and `sticking_seen`, or-ed with whether some contact stuck."""
    order = buf.busy
    end = order.shape[0] - 1
    change = 0.0
    sweep = buf.counts[COUNT_SWEEP] + 1
    buf.counts[COUNT_SWEEP] = sweep
    rejoin, m, stop, n_touched = False, 0, n_busy, 0
    while True:
        while m < stop:
            k = order[m] if m < n_busy else order[end - (m - n_busy)]
            m += 1
            a, b = buf.cands[k, 0], buf.cands[k, 2]
            n_touched = _touch(buf, v, a, sweep, n_touched)
            n_touched = _touch(buf, v, b, sweep, n_touched)
            own, sticks = update(model, buf, k, v, 0.0)
            change = max(change, own)
            sticking_seen = sticking_seen or sticks
        moved = _moved(model, v, buf.omega, buf.bodies, buf.touched, n_touched)
        converged = change < tolerance or moved < tolerance
        if rejoin or not converged or n_idle == 0:
            break
        rejoin, stop = True, n_busy + n_idle
    return change, moved, converged, rejoin, sticking_seen


@inlined_kernel
def _pile_sweep(model, buf, v, n_busy, n_idle, tolerance, sticking_seen, quiet, armed):
    """A pile's sweep (`_sweep`), of the contacts that are due only (`buf.due`): a contact
    whose last update changed a speed by less than `quiet` and whose bodies no update has
    changed by that much since is quiet, and skipped, as an update would change it little more
    than it did. The updated ones are listed in `buf.visited`, their impulses first kept in
    `buf.lam_sweep` if `armed`. Returns what `_sweep` does, then whether it skipped quiet
    contacts (a convergence then needs a sweep of them all to confirm it, `iterate_pile`) and how
    many contacts it updated."""
    change = 0.0
    sweep = buf.counts[COUNT_SWEEP] + 1
    buf.counts[COUNT_SWEEP] = sweep
    rejoin, n_touched, visits = False, 0, 0
    while True:
        k = _next_due(buf, 0, rejoin)
        while k >= 0:
            w, bit = _bit(k)
            buf.due[w] &= ~bit
            buf.visited[visits] = k
            visits += 1
            if armed:
                for d in range(3):
                    buf.lam_sweep[k, d] = buf.lam[k, d]
            a, b = buf.cands[k, 0], buf.cands[k, 2]
            n_touched = _touch(buf, v, a, sweep, n_touched)
            n_touched = _touch(buf, v, b, sweep, n_touched)
            own, sticks = update(model, buf, k, v, 0.0)
            change = max(change, own)
            sticking_seen = sticking_seen or sticks
            if own >= quiet:  # its bodies moved: every contact on them is due
                _due_on(buf, a)
                if b >= 0:
                    _due_on(buf, b)
            k = _next_due(buf, k + 1, rejoin)
        moved = _moved(model, v, buf.omega, buf.bodies, buf.touched, n_touched)
        converged = change < tolerance or moved < tolerance
        if rejoin or not converged or n_idle == 0:
            break
        rejoin = True
    quiet_ones = n_busy + (n_idle if rejoin else 0) - visits
    buf.solver[STAT_QUIET] += quiet_ones
    return change, moved, converged, rejoin, sticking_seen, quiet_ones > 0, visits


@inlined_kernel
def _follow_rate(model, buf, order, n, v, moved, last, rate, steady, armed, trusted, tried):
    """The sweeps' rate of convergence after a sweep whose velocity change is `moved`; once
    steady (RATE_SWEEPS) or agreeing with the `trusted` one, and `armed`, the last sweep's
    impulse change is extrapolated (`extrapolate`) and `tried` set to its rate. Returns the new
    (last, rate, steady, armed, tried). The extrapolation moves the first n contacts of
    `order`: the busy ones, in a pile those the sweep updated."""
    ratio = moved / last
    steady = steady + 1 if abs(ratio - rate) < RATE_AGREEMENT * ratio else 0
    rate, last = ratio, moved
    known = abs(ratio - trusted) < RATE_AGREEMENT * ratio
    if armed and (steady >= RATE_SWEEPS - 1 or known) and rate < RATE_MAX:
        extrapolate(model, buf, order, n, v, rate / (1.0 - rate))
        buf.solver[STAT_EXTRAPOLATIONS] += 1
        tried = rate
        last, rate, steady = math.inf, 0.0, 0
    armed = (steady >= RATE_SWEEPS - 2 or trusted > 0.0) and 0.0 < rate < RATE_MAX
    return last, rate, steady, armed, tried


@inlined_kernel
def iterate(
    model,
    x,
    nc,
    dt,
    buf,
    v,
    tolerance,
    idle_margin,
    first=SUBSPACE_FIRST,
    slot=PRE_DRIFT,
    limit=MAX_ITERATIONS,
):
    """Gauss-Seidel sweeps until no impulse changes a speed by `tolerance` (m/s), or no body's
    velocity changes by that much over a sweep; returns the sweeps used and whether the solve
    converged (else it reached `limit` sweeps, stalled (STALL_SWEEPS) or cycled (`cycles`)).

    Sweeps skip idle contacts (`_busy`, margin `idle_margin` times the last sweep's largest
    speed change) until the busy ones pass the stopping test (`_sweep`). The velocity test ends
    the sweeps once the motion has converged while redundant contacts' impulses (a face's four
    corners) still push against each other. Subspace steps follow the unconverged sweeps
    `first` to `first` + SUBSPACE_STEPS - 1 in which a contact stuck; extrapolation follows a
    steady rate, or the one trusted for this `slot` (`_follow_rate`). Once the sweeps converge,
    the contacts on standby that the velocities now reach are woken (`wake`) and swept too."""
    n_busy, n_idle = _list_busy(nc, buf), 0
    progress, since = math.inf, 0  # the velocity change at its last fall (STALL_PROGRESS)
    last, rate, steady, armed = math.inf, 0.0, 0, False
    trusted, tried = buf.rates[slot], 0.0
    for it in range(limit):
        _sweep_start(buf, n_busy, armed)
        stuck = model.friction == 0.0  # a subspace step needs a sticking contact
        change, moved, converged, rejoin, stuck = _sweep(
            model, buf, v, n_busy, n_idle, tolerance, stuck
        )
        if converged:
            awake = wake(model, x, nc, dt, buf, v, n_busy)
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
        if it >= CYCLE_START and cycles(buf.cycle, it - CYCLE_START, moved):
            return it + 1, False
        last, rate, steady, armed, tried = _follow_rate(
            model, buf, buf.busy, n_busy, v, moved, last, rate, steady, armed, trusted, tried
        )
        n_busy, n_idle = _regroup(buf, n_busy, n_idle, idle_margin * change, rejoin)
        if stuck and first <= it + 1 < first + SUBSPACE_STEPS:
            buf.solver[STAT_SUBSPACE_STEPS] += subspace_step(model, nc, buf, v)
    return limit, False


@kernel
def iterate_pile(model, x, nc, dt, buf, v, tolerance, idle_margin, first, slot, limit):
    """`iterate` for a pile (QUIET_MIN_BODIES bodies or more), whose sweeps skip quiet contacts
    too (`_pile_sweep`). Called, not inlined: the single bodies' step has none of its code. Its
    stall and cycle rules repeat `iterate`'s: shared as a helper, they made the single bodies'
    build up to 14 % slower (docs/contact-solver.md, "Due contacts")."""
    n_busy, n_idle = _list_busy(nc, buf), 0
    n_swept = n_busy  # busy and idle, the first n_swept of `buf.busy`
    _link(buf, n_swept)
    progress, since = math.inf, 0
    last, rate, steady, armed = math.inf, 0.0, 0, False
    trusted, tried = buf.rates[slot], 0.0
    change = 0.0  # the first sweep's quiet threshold is the tolerance
    for it in range(limit):
        stuck = model.friction == 0.0
        quiet = max(tolerance, QUIET_FRACTION * change)  # of the sweep before
        change, moved, converged, rejoin, stuck, skipped, visits = _pile_sweep(
            model, buf, v, n_busy, n_idle, tolerance, stuck, quiet, armed
        )
        if converged and skipped:  # confirmed by a sweep of every contact
            _all_due(buf, n_swept)
            continue
        if converged:
            awake = wake(model, x, nc, dt, buf, v, n_swept)
            if awake == n_swept:
                if tried > 0.0:
                    buf.rates[slot] = tried
                return it + 1, True
            n_busy, n_idle, n_swept = awake, 0, awake  # the woken contacts too, all due
            _link(buf, n_swept)
            last, rate, steady, armed, tried = math.inf, 0.0, 0, False, 0.0
            continue
        if tried > 0.0:
            trusted, tried = 0.0, 0.0
            buf.rates[slot] = 0.0
        if moved < STALL_PROGRESS * progress:
            progress, since = moved, it
        elif it - since >= STALL_SWEEPS:
            return it + 1, False
        if it >= CYCLE_START and cycles(buf.cycle, it - CYCLE_START, moved):
            return it + 1, False
        last, rate, steady, armed, tried = _follow_rate(
            model, buf, buf.visited, visits, v, moved, last, rate, steady, armed, trusted, tried
        )
        n_busy, n_idle = _regroup_visited(buf, visits, n_busy, n_idle, idle_margin * change)
        stepped = stuck and first <= it + 1 < first + SUBSPACE_STEPS
        stepped = stepped and subspace_step(model, nc, buf, v)
        buf.solver[STAT_SUBSPACE_STEPS] += stepped
        if stepped or last == math.inf:  # impulses changed outside the updates
            _all_due(buf, n_swept)
    return limit, False
