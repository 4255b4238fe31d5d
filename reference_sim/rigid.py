"""The rigid integrators: `euler`, `splitting`, `rk4` and `exact`, compiled step loops.

State per body: COM x, orientation q, COM velocity v and world angular momentum L. The world
inertia is R(q) I0 R(q)^T and omega = I(t)^-1 L. Uniform gravity exerts no torque about the
COM, so without contact L is constant and every integrator leaves it untouched; contact enters
as impulses before and after the drift (`reference_sim.contact.step`).

- euler: semi-implicit Euler, first order: v += g dt; x += v dt; q <- exp(omega dt) q.
- splitting: kick-drift-kick (Stormer-Verlet) for translation, so constant gravity is exact;
  the free rotation over dt is the symmetric splitting of the kinetic energy into the three
  principal-axis parts, each an exact rotation about that body axis (Dullweber, Leimkuhler and
  McLachlan 1997): R1(dt/2) R2(dt/2) R3(dt) R2(dt/2) R1(dt/2). Symplectic, time-reversible,
  second order, L exact.
- rk4: classic fourth-order Runge-Kutta on (x, q, v, L) with dq/dt = (0, omega) q / 2; q is
  normalised after the step.
- exact: the splitting with the free rotation over dt in closed form
  (`reference_sim.exact_rotation`): exact to rounding without contact, second order with it.
"""

import math

import numpy as np

from reference_sim.contact.buffers import (
    COUNT_KEPT_ROWS,
    COUNT_PAIRS,
    PRE_DRIFT,
    SOLVER_STATISTICS,
    STAT_REFOUND,
    contact_buffers,
    grown,
    largest_body,
)
from reference_sim.contact.candidates import find_candidates_into
from reference_sim.contact.frames import frames_into, reach_into, world_omega
from reference_sim.contact.pair_list import current_pairs, pair_list
from reference_sim.contact.settings import GRID_MIN_BODIES, REFIND_LIMIT, candidate_margin
from reference_sim.contact.step import after_drift, before_drift
from reference_sim.exact_rotation import exact_rotation
from reference_sim.jit import compiled, inlined_kernel, kernel
from reference_sim.model import Model
from reference_sim.quaternion import qexp, qmatrix, qmul, qnormalize
from reference_sim.vec3 import dot, mat, mat_t_vec, mat_vec, row, vec

INTEGRATOR_CODES = {"euler": 0, "splitting": 1, "rk4": 2, "exact": 3}
EULER, SPLITTING, RK4, EXACT = 0, 1, 2, 3
# Impacts slower than this many steps' worth of gravity are resting contacts, not bounces:
# a body lying still gains |g| dt of approach speed every step and must not bounce on it.
BOUNCE_STEPS = 2.0
# Contact rows (Jacobians, inverse masses, gaps) are kept while no body has moved by this much (m)
# since their assembly (`_moved_from`): off by 2e-15 m at most, a fifth of `GAP_ROUNDING`.
POSE_ROUNDING = 1e-15


@kernel
def _principal_rotation(model, q, lp, b, k, angle):
    """The flow about principal axis k for `angle` (rad): q <- q exp(angle a_k) and the body's
    angular momentum in principal components lp rotated back by -angle about axis k."""
    half = 0.5 * angle
    s, c = math.sin(half), math.cos(half)
    a = model.principal_axes
    q = qmul(q, (c, s * a[b, k, 0], s * a[b, k, 1], s * a[b, k, 2]))
    cos_t, sin_t = c * c - s * s, 2.0 * s * c
    if k == 0:
        lp = (lp[0], cos_t * lp[1] + sin_t * lp[2], cos_t * lp[2] - sin_t * lp[1])
    elif k == 1:
        lp = (cos_t * lp[0] - sin_t * lp[2], lp[1], cos_t * lp[2] + sin_t * lp[0])
    else:
        lp = (cos_t * lp[0] + sin_t * lp[1], cos_t * lp[1] - sin_t * lp[0], lp[2])
    return q, lp


@kernel
def _free_rotation_split(model, q, L, b, dt):
    """Exact flows about the principal axes composed as R1(h/2) R2(h/2) R3(h) R2(h/2) R1(h/2).

    The body's angular momentum is carried along in principal components (each flow rotates it
    about one coordinate axis), so the matrix of q is formed once per step.
    """
    # principal components: the rows of principal_axes[b] are the axes
    lp = mat_vec(mat(model.principal_axes, b), mat_t_vec(qmatrix(q), L))
    moments = row(model.principal_moments, b)
    for k, frac in ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5)):
        q, lp = _principal_rotation(model, q, lp, b, k, lp[k] / moments[k] * frac * dt)
    return qnormalize(q)


@kernel
def _quat_rate(model, q, L, b):
    w = world_omega(model, qnormalize(q), L, b)
    r = qmul((0.0, w[0], w[1], w[2]), q)
    return (0.5 * r[0], 0.5 * r[1], 0.5 * r[2], 0.5 * r[3])


@kernel
def _axpy(q, h, k):
    """q + h k for 4-tuples."""
    return (q[0] + h * k[0], q[1] + h * k[1], q[2] + h * k[2], q[3] + h * k[3])


@kernel
def _rk4_rotation(model, q, L, b, dt):
    """Classic RK4 on dq/dt = (0, omega) q / 2, normalised after the step. (dx/dt = v and
    dv/dt = g are integrated exactly by RK4, polynomials: the caller does them directly.)"""
    k1 = _quat_rate(model, q, L, b)
    k2 = _quat_rate(model, _axpy(q, 0.5 * dt, k1), L, b)
    k3 = _quat_rate(model, _axpy(q, 0.5 * dt, k2), L, b)
    k4 = _quat_rate(model, _axpy(q, dt, k3), L, b)
    total = _axpy(_axpy(_axpy(k1, 2.0, k2), 2.0, k3), 1.0, k4)
    return qnormalize(_axpy(q, dt / 6.0, total))


@kernel
def _store_quat(out, b, q):
    out[b, 0], out[b, 1], out[b, 2], out[b, 3] = q


@inlined_kernel
def _drift(model, integrator, x, q, v, L, dt):
    """The integrator's contact-free update of every body, in place (inlined: `jit`)."""
    g = model.gravity
    for b in range(x.shape[0]):
        qb, lb = (q[b, 0], q[b, 1], q[b, 2], q[b, 3]), row(L, b)
        if integrator == EULER:
            for i in range(3):
                x[b, i] += dt * v[b, i]
            w = world_omega(model, qb, lb, b)
            _store_quat(q, b, qnormalize(qmul(qexp((dt * w[0], dt * w[1], dt * w[2])), qb)))
            continue
        for i in range(3):
            # kick-drift-kick: constant gravity exact (RK4's polynomial stages agree)
            v[b, i] += 0.5 * dt * g[i]
            x[b, i] += dt * v[b, i]
            v[b, i] += 0.5 * dt * g[i]
        if integrator == SPLITTING:
            _store_quat(q, b, _free_rotation_split(model, qb, lb, b, dt))
        elif integrator == EXACT:
            moments, axes = model.principal_moments[b], model.principal_axes[b]
            _store_quat(q, b, exact_rotation(qb, lb, moments, axes, dt))
        else:
            _store_quat(q, b, _rk4_rotation(model, qb, lb, b, dt))


@kernel
def _pose_into(x, q, pose):
    """Each body's x and q into `pose` (B, 7)."""
    for b in range(x.shape[0]):
        for i in range(3):
            pose[b, i] = x[b, i]
        for i in range(4):
            pose[b, 3 + i] = q[b, i]


@kernel
def _moved_from(model, x, q, pose):
    """Whether some body has moved by POSE_ROUNDING or more since `pose` (`_pose_into`): its
    COM's displacement plus its bound radius times the rotation angle, 2 |dq| to first order."""
    for b in range(x.shape[0]):
        dx, dq = 0.0, 0.0
        for i in range(3):
            dx += (x[b, i] - pose[b, i]) ** 2
        for i in range(4):
            dq += (q[b, i] - pose[b, 3 + i]) ** 2
        if not math.sqrt(dx) + 2.0 * model.bound_radius[b] * math.sqrt(dq) < POSE_ROUNDING:
            return True
    return False


@kernel
def _kick(model, integrator, v, dt):
    """Euler's velocity update before the contacts and the drift (the others kick in it)."""
    if integrator == EULER and model.gravity_on:
        for b in range(v.shape[0]):
            for i in range(3):
                v[b, i] += dt * model.gravity[i]


@kernel
def _keep_start(v, L, start):
    """Each body's v and L into `start` (B, 6)."""
    for b in range(v.shape[0]):
        for i in range(3):
            start[b, i], start[b, 3 + i] = v[b, i], L[b, i]


@kernel
def _back_to_start(v, L, start):
    """Each body's v and L from `start` (`_keep_start`)."""
    for b in range(v.shape[0]):
        for i in range(3):
            v[b, i], L[b, i] = start[b, i], start[b, 3 + i]


@inlined_kernel
def _contact_before_drift(model, integrator, x, q, v, L, dt, threshold, margin, refind, buf):
    """The contact part of a step up to the drift, candidates reaching `margin` (m) beyond each
    body's reach: find them (with the frames, unless the caller made them with the body
    pairs), Euler's kick, and `before_drift`. Returns the candidates' count (see `rigid_step`)
    and 0, or, if `refind`, how far the solve sped some body beyond them (v and L changed: the
    step must start again)."""
    if buf.counts[COUNT_PAIRS] < 0:  # else `_body_pairs` made them at this pose
        frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    kick = (0.0, 0.0, 0.0)
    if integrator == EULER and model.gravity_on:
        kick = (dt * model.gravity[0], dt * model.gravity[1], dt * model.gravity[2])
    nc = find_candidates_into(model, x, v, dt, kick, margin, buf)
    if nc <= 0 or nc > buf.cands.shape[0]:
        return nc, 0.0
    _keep_start(v, L, buf.start)
    _kick(model, integrator, v, dt)
    # the drift moves euler's bodies with v, the others' with v + g dt / 2
    drift_gravity = (0.0, 0.0, 0.0)
    if integrator != EULER:
        drift_gravity = (
            0.5 * dt * model.gravity[0],
            0.5 * dt * model.gravity[1],
            0.5 * dt * model.gravity[2],
        )
    # `buf.pose`: the pose the kept rows were assembled at, within POSE_ROUNDING; with no
    # row kept from the last step, the first assembly makes them all here
    if buf.counts[COUNT_KEPT_ROWS] == 0:
        _pose_into(x, q, buf.pose)
    excess = before_drift(model, x, v, L, nc, dt, drift_gravity, threshold, buf, refind)
    return nc, excess


@kernel
def _refind(model, integrator, x, q, v, L, dt, threshold, margin, excess, rate, buf):
    """A step whose solve sped a body `excess` (m) beyond candidates found `margin` beyond each
    body's reach, started again from its start (`buf.start`, and the solve's trusted rate
    `rate`) with the margin more than doubled to cover it, every body pair tested at the wider
    reach; up to REFIND_LIMIT times, each counted in STAT_REFOUND. Returns the candidates'
    count (see `rigid_step`)."""
    for attempt in range(REFIND_LIMIT):
        _back_to_start(v, L, buf.start)
        buf.rates[PRE_DRIFT] = rate
        margin = 2.0 * (margin + excess)
        buf.counts[COUNT_PAIRS] = -1  # and the frames made again: the solve changed omega
        buf.solver[STAT_REFOUND] += 1
        refind = attempt + 1 < REFIND_LIMIT
        nc, excess = _contact_before_drift(
            model, integrator, x, q, v, L, dt, threshold, margin, refind, buf
        )
        if not excess > 0.0:
            return nc
    return nc


@inlined_kernel
def rigid_step(model, integrator, x, q, v, L, dt, bounce_threshold, buf):
    """Advance every body by dt in place; contact impulses before and after the drift.

    `buf` (`ContactBuffers`) holds the contacts' work space, the body pairs and the frames if
    the caller found them (`_body_pairs`, COUNT_PAIRS), and last step's impulses for the warm
    start. Returns 0, or (if `buf` is too small, before changing anything) the candidates'
    count it needs, or minus the body pairs' count.

    Candidates reach `candidate_margin` beyond each body's reach; a step whose solve before the
    drift speeds a body further starts again with a wider margin (`_refind`): the drift then
    meets no particle that is not a candidate.
    """
    nc = 0
    if model.contact:
        rate = buf.rates[PRE_DRIFT]
        margin = candidate_margin(dt)
        nc, excess = _contact_before_drift(
            model, integrator, x, q, v, L, dt, bounce_threshold, margin, np.bool_(True), buf
        )
        if excess > 0.0:
            nc = _refind(
                model, integrator, x, q, v, L, dt, bounce_threshold, margin, excess, rate, buf
            )
        if nc < 0 or nc > buf.cands.shape[0]:
            return nc
    if nc == 0:
        _kick(model, integrator, v, dt)
    _drift(model, integrator, x, q, v, L, dt)
    # `before_drift` assembled every candidate's rows; they serve after the drift while no body
    # has moved by POSE_ROUNDING since `buf.pose` (a body at rest)
    kept = nc > 0 and not _moved_from(model, x, q, buf.pose)
    buf.counts[COUNT_KEPT_ROWS] = nc if kept else 0
    if nc > 0:
        after_drift(model, x, q, v, L, nc, dt, buf)
        if not kept:  # every row assembled afresh at this pose
            _pose_into(x, q, buf.pose)
    return 0


@kernel
def _steps(
    model, integrator, x, q, v, L, dt, threshold, buf, progress, last, n_steps, stride, out, steps
):
    """Steps progress[0]..last of n_steps, recording samples from slot progress[1] (both
    advanced in place); returns 0, or stops before a step `buf` is too small for and returns
    what it needs (`rigid_step`)."""
    while progress[0] <= last:
        n = progress[0]
        needed = rigid_step(model, integrator, x, q, v, L, dt, threshold, buf)
        if needed != 0:
            return needed
        if n % stride == 0 or n == n_steps:
            _record_state(model, x, q, v, L, out[progress[1]])
            steps[progress[1]] = n
            progress[1] += 1
        progress[0] += 1
    return 0


@compiled
def _body_pairs(model, integrator, x, q, v, L, dt, buf, found):
    """Body pairs of the coming step from the list `found` (`current_pairs`: the grid's pairs,
    searched again only when the bodies have moved out of its skins), copied into `buf` (grown
    if needed) for `rigid_step` with the frames at this pose; returns the buffers and the list."""
    frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    g = model.gravity if integrator == EULER and model.gravity_on else np.zeros(3)
    reach = np.empty(x.shape[0])  # widened as `find_candidates_into` widens it
    reach_into(model, v, buf.omega, dt, (dt * g[0], dt * g[1], dt * g[2]), reach)
    reach += candidate_margin(dt)
    found, n = current_pairs(model.bound_radius, x, reach, found, buf.pairs)
    if n > buf.pairs.shape[0]:
        buf = grown(buf, buf.cands.shape[0], 2 * n)
        found, n = current_pairs(model.bound_radius, x, reach, found, buf.pairs)
    buf.counts[COUNT_PAIRS] = n
    return buf, found


@kernel
def _record_state(model, x, q, v, L, out):
    """One sample (B, 13): x, q, v and world omega of every body."""
    for b in range(x.shape[0]):
        qb = (q[b, 0], q[b, 1], q[b, 2], q[b, 3])
        for i in range(3):
            out[b, i], out[b, 7 + i] = x[b, i], v[b, i]
        for i in range(4):
            out[b, 3 + i] = qb[i]
        out[b, 10], out[b, 11], out[b, 12] = world_omega(model, qb, row(L, b), b)


@compiled
def run_rigid(model, integrator, x, q, v, L, dt, n_steps, stride):
    """Step n_steps times in place; return the sampled steps (S,), samples (S, B, 13): x, q, v,
    omega per body, and the contact solver's statistics (`buffers.STAT_*`): solves,
    Gauss-Seidel sweeps, solves stopped unconverged (at MAX_ITERATIONS, stalled or cycling),
    subspace steps, extrapolations and updates skipped as quiet (zeros without contact).

    Samples are taken at step 0, every `stride` steps, and at the last step.
    """
    if not model.contact:
        out, steps = _sample_arrays(x, n_steps, stride)
        _free_steps(model, integrator, x, q, v, L, dt, n_steps, stride, out, steps)
        return steps, out, np.zeros(SOLVER_STATISTICS, dtype=np.int64)
    nb = x.shape[0]
    buf = contact_buffers(nb, 8 * nb + 16, 4 * nb + 16, largest_body(model))
    steps, out, buf = run_contact(model, integrator, x, q, v, L, dt, n_steps, stride, buf)
    return steps, out, buf.solver.copy()


@compiled
def _sample_arrays(x, n_steps, stride):
    """Room for the samples of a run: step 0, every `stride` steps and the last."""
    n_samples = n_steps // stride + 1 + (1 if n_steps % stride else 0)
    return np.empty((n_samples, x.shape[0], 13)), np.empty(n_samples, dtype=np.int64)


@compiled
def run_contact(model, integrator, x, q, v, L, dt, n_steps, stride, buf):
    """`run_rigid` of a scene with contact, from the contact buffers `buf`, grown whenever a
    step asks for more room; returns the sampled steps, the samples and the buffers at the
    end."""
    out, steps = _sample_arrays(x, n_steps, stride)
    threshold = BOUNCE_STEPS * math.sqrt(dot(vec(model.gravity), vec(model.gravity))) * dt
    nb = x.shape[0]
    _record_state(model, x, q, v, L, out[0])
    steps[0] = 0
    progress = np.ones(2, dtype=np.int64)  # the next step and the next sample's slot
    found = pair_list(nb)
    while progress[0] <= n_steps:
        last = n_steps
        if nb >= GRID_MIN_BODIES:  # body pairs from the grid's list, one step at a time
            buf, found = _body_pairs(model, integrator, x, q, v, L, dt, buf, found)
            last = progress[0]
        needed = _steps(
            model,
            integrator,
            x,
            q,
            v,
            L,
            dt,
            threshold,
            buf,
            progress,
            last,
            n_steps,
            stride,
            out,
            steps,
        )
        if needed < 0:
            buf = grown(buf, buf.cands.shape[0], -2 * needed)
        elif needed > 0:
            buf = grown(buf, 2 * needed, buf.pairs.shape[0])
    return steps, out, buf


@compiled
def run_rigid_fields(fields, integrator, x, q, v, L, dt, n_steps, stride):
    """`run_rigid` with the model passed as a plain tuple of its fields, `tuple(model)`: numba
    types a NamedTuple argument in Python on every call, a plain tuple in C, which makes the
    call itself several times cheaper."""
    return run_rigid(Model(*fields), integrator, x, q, v, L, dt, n_steps, stride)


@kernel
def _free_steps(model, integrator, x, q, v, L, dt, n_steps, stride, out, steps):
    """`run_rigid` without contact: every step is `rigid_step`'s drift (and euler's kick)
    alone, in one kernel, so a step makes no counted call."""
    _record_state(model, x, q, v, L, out[0])
    steps[0] = 0
    s = 1
    for n in range(1, n_steps + 1):
        _kick(model, integrator, v, dt)
        _drift(model, integrator, x, q, v, L, dt)
        if n % stride == 0 or n == n_steps:
            _record_state(model, x, q, v, L, out[s])
            steps[s] = n
            s += 1
