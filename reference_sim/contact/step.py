"""A step's contact impulses, split around the drift (the integrator's position update):
speculative contacts before it (`before_drift`), bounce and rest after it (`after_drift`)."""

import numpy as np

from reference_sim.contact.buffers import (
    COUNT_KEPT_ROWS,
    COUNT_POST_WARM,
    COUNT_PRE_WARM,
    POST_DRIFT,
    PRE_DRIFT,
    STAT_SOLVES,
    STAT_SWEEPS,
    STAT_UNCONVERGED,
)
from reference_sim.contact.frames import (
    angular_momenta,
    flush_subnormal,
    frames_into,
    reach_into,
)
from reference_sim.contact.gauss_seidel import iterate, iterate_pile, sticking
from reference_sim.contact.impulses import row_speed, set_impulses
from reference_sim.contact.rows import assemble
from reference_sim.contact.settings import (
    BAUMGARTE,
    IDLE_MARGIN,
    IMPACT_SLACK,
    MAX_ITERATIONS,
    QUIET_MIN_BODIES,
    RESTART_MAX_BODIES,
    RESTART_SWEEPS,
    RESTING_GAP,
    SUBSPACE_FIRST,
    SUBSPACE_FIRST_WARM,
    SUBSPACE_MIN_BODIES,
    TOUCH_TOLERANCE,
    solver_tolerance,
)
from reference_sim.contact.warm_start import remember, warm_start
from reference_sim.jit import inlined_kernel, shared_kernel


@inlined_kernel
def _bounces(model, v, nc, dt, bounce_threshold, buf):
    """-e times the approach speed of every contact that impacts within the step, else 0, into
    `buf.bounce` (needs `assemble`'s gaps and Jacobians)."""
    for k in range(nc):
        buf.bounce[k] = 0.0
        # on standby, its gap is beyond reach: no impact within the step. With no restitution
        # an impact leaves at normal speed 0, as a resting contact does
        if buf.standby[k] or model.restitution == 0.0:
            continue
        vn = row_speed(buf.jac[k, 0], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
        if vn < -bounce_threshold and buf.gap[k] + dt * vn < IMPACT_SLACK:
            buf.bounce[k] = -model.restitution * vn


@shared_kernel
def solve(model, x, v, L, nc, dt, buf, warm_keys, warm_lam, n_warm, slot):
    """Projected Gauss-Seidel on the normal and friction impulses of the active contacts
    (`assemble`), in place, towards `buf.target` normal speeds, to `solver_tolerance(dt)`.
    Impulses start from those of the same contacts in the previous steps (`warm_keys`,
    `warm_lam`, `warm_start`): a body resting on a plane converges in one sweep. The first
    subspace step may follow the first sweep if some contact matched (SUBSPACE_FIRST_WARM),
    else the second; none in a scene of fewer than SUBSPACE_MIN_BODIES bodies. `slot`:
    PRE_DRIFT or POST_DRIFT (its trusted extrapolation rate, `iterate`). A warm-started solve
    of at most RESTART_MAX_BODIES bodies not converged in RESTART_SWEEPS sweeps starts again
    from no impulse, once, within MAX_ITERATIONS in all. The sweeps change v and `buf.omega`;
    L follows once at the end (`angular_momenta`), and subnormal remainders of both are flushed
    to zero (`flush_subnormal`). Counts the solve in `buf.solver`."""
    tolerance = solver_tolerance(dt)
    warm = warm_start(model, x, nc, buf, v, warm_keys, warm_lam, n_warm, tolerance)
    first = SUBSPACE_FIRST_WARM if warm > 0 else SUBSPACE_FIRST
    if v.shape[0] < SUBSPACE_MIN_BODIES:
        first = MAX_ITERATIONS + 1  # after no sweep
    restart = warm > 0 and v.shape[0] <= RESTART_MAX_BODIES
    budget = RESTART_SWEEPS if restart else MAX_ITERATIONS
    sweeps = 0
    while True:  # one call site: `iterate` is inlined
        if v.shape[0] >= QUIET_MIN_BODIES:
            used, converged = iterate_pile(
                model, x, nc, dt, buf, v, tolerance, IDLE_MARGIN, first, slot, budget
            )
        else:
            used, converged = iterate(
                model, x, nc, dt, buf, v, tolerance, IDLE_MARGIN, first, slot, budget
            )
        sweeps += used
        if converged or not restart:
            break
        # astray (RESTART_SWEEPS): once more from no impulse, with the sweeps left
        restart, budget = False, MAX_ITERATIONS - sweeps
        for k in range(nc):
            if buf.active[k]:
                set_impulses(model, buf, k, 0.0, 0.0, 0.0, v)
    angular_momenta(model, L, buf.rot, buf.inv, buf.omega)
    flush_subnormal(v, L)
    buf.solver[STAT_SOLVES] += 1
    buf.solver[STAT_SWEEPS] += sweeps
    buf.solver[STAT_UNCONVERGED] += not converged


@inlined_kernel
def _outrun(model, v, dt, buf):
    """How far (m) the solve has sped some body beyond the reach its candidates were found with
    (`buf.wide`): its reach at the velocities the drift will use (into `buf.reach`, as `wake`
    makes it) minus that, the largest over the bodies; at most 0 if the candidates hold every
    contact of the drift."""
    reach_into(model, v, buf.omega, dt, (0.0, 0.0, 0.0), buf.reach)
    excess = -np.inf
    for b in range(v.shape[0]):
        excess = max(excess, buf.reach[b] - buf.wide[b])
    return excess


@shared_kernel
def before_drift(model, x, v, L, nc, dt, drift_gravity, bounce_threshold, buf, refind):
    """Speculative impulses on the first nc candidates of `buf`, on the velocity the drift will
    use: v + drift_gravity (m/s), the part of this step's gravity the integrator adds during the
    drift. Every candidate acts, with target normal speed -gap / dt (a gap already negative is
    closed at BAUMGARTE of its depth per step; one within RESTING_GAP of zero is left as it
    is, target 0). Changes v and L; needs `buf.rot`, `buf.inv`, `buf.omega` of the step's
    start.

    Leaves in `buf.bounce` the normal speed each contact must leave with after the drift: -e
    times its approach speed for an impact (a contact closing within the step faster than
    `bounce_threshold`), else 0 (the bounce is applied after the drift, when the contact has
    arrived), and in `buf.acting` the contacts that pushed or bounce.

    If the solve sped some body beyond the reach the candidates were found with (`_outrun`)
    and the caller will `refind` them, it stops there (v and L changed, the warm start for the
    next step not kept) and returns by how much (m); else it returns 0.
    """
    for b in range(v.shape[0]):
        for i in range(3):
            v[b, i] += drift_gravity[i]
    for k in range(nc):
        buf.acting[k] = True
    # the bodies have not moved since the last step's `after_drift` assembled its contacts
    assemble(model, x, nc, TOUCH_TOLERANCE, buf, buf.counts[COUNT_KEPT_ROWS], True)
    _bounces(model, v, nc, dt, bounce_threshold, buf)
    for k in range(nc):
        gap = buf.gap[k]
        if abs(gap) <= RESTING_GAP:
            buf.target[k] = 0.0
        else:
            buf.target[k] = -gap / dt if gap > 0.0 else -BAUMGARTE * gap / dt
    n_warm = buf.counts[COUNT_PRE_WARM]
    solve(model, x, v, L, nc, dt, buf, buf.pre_keys, buf.pre_lam, n_warm, np.int64(PRE_DRIFT))
    excess = _outrun(model, v, dt, buf)
    if refind and excess > 0.0:
        return excess
    buf.counts[COUNT_PRE_WARM] = remember(nc, buf, buf.pre_keys, buf.pre_lam)
    for k in range(nc):
        buf.acting[k] = buf.lam[k, 0] > 0.0 or buf.bounce[k] > 0.0
    for b in range(v.shape[0]):
        for i in range(3):
            v[b, i] -= drift_gravity[i]
    return 0.0


@inlined_kernel
def _pushes_nothing(model, nc, buf, v, tolerance):
    """Whether a solve of the first nc contacts' active ones, from no impulse, would change no
    speed by more than `tolerance`, the solver's own convergence test: each one's normal speed
    is at most that below its target and, with friction, sticking (`sticking`) would not
    change its tangent speeds by more."""
    for k in range(nc):
        if buf.active[k]:
            vn = row_speed(buf.jac[k, 0], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
            if buf.target[k] - vn > tolerance:
                return False
            if model.friction > 0.0:
                block = sticking(model, buf, k, v, vn, 0.0, 0.0, 0.0)
                if block[6] and max(abs(block[7]), abs(block[8])) > tolerance:
                    return False
    return True


@inlined_kernel
def _moves_nothing(nc, buf, tolerance):
    """Whether no contact's normal impulse moves its normal speed by more than `tolerance`
    (its friction, at most mu times that impulse, then moves little more)."""
    for k in range(nc):
        if buf.lam[k, 0] * buf.kn[k] > tolerance:
            return False
    return True


@shared_kernel
def after_drift(model, x, q, v, L, nc, dt, buf):
    """Impulses after the drift on the contacts that pushed before it or bounce
    (`buf.acting`) or touch now (gap below TOUCH_TOLERANCE): the bounce targets of
    `before_drift`, else inelastic (normal speed >= 0, and friction). Changes v and L.
    Keeps the rows below `buf.counts[COUNT_KEPT_ROWS]`: the caller vouches that no body has
    moved by more than rounding (`rigid.POSE_ROUNDING`) since they were assembled.

    A solve with no impulse to warm-start from and none that would change a speed by more than
    the solver's tolerance (`_pushes_nothing`) would end after one sweep having changed no
    speed by more: it is counted, as a solve of no sweep, and skipped (a body at rest, a pivot,
    a ball leaving the floor). Impulses that move no speed by more (`_moves_nothing`) are not
    warm-started from."""
    frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    assemble(model, x, nc, TOUCH_TOLERANCE, buf, buf.counts[COUNT_KEPT_ROWS])
    buf.counts[COUNT_KEPT_ROWS] = nc  # rows for the current pose, until the next drift
    for k in range(nc):
        buf.target[k] = buf.bounce[k]
    tolerance = solver_tolerance(dt)
    if buf.counts[COUNT_POST_WARM] == 0 and _pushes_nothing(model, nc, buf, v, tolerance):
        for k in range(nc):
            buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2] = 0.0, 0.0, 0.0
        buf.solver[STAT_SOLVES] += 1
        return
    n_warm = buf.counts[COUNT_POST_WARM]
    solve(model, x, v, L, nc, dt, buf, buf.post_keys, buf.post_lam, n_warm, np.int64(POST_DRIFT))
    buf.counts[COUNT_POST_WARM] = remember(nc, buf, buf.post_keys, buf.post_lam)
    if _moves_nothing(nc, buf, tolerance):
        buf.counts[COUNT_POST_WARM] = 0
