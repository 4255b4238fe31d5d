"""The rigid integrators: `euler`, `splitting` and `rk4`, compiled step loops.

State per body: COM x, orientation q, COM velocity v and world angular momentum L. The world
inertia is R(q) I0 R(q)^T and omega = I(t)^-1 L. Uniform gravity exerts no torque about the
COM, so without contact L is constant and every integrator leaves it untouched; contact enters
as impulses before and after the drift (`reference_sim.contact`).

- euler: semi-implicit Euler, first order: v += g dt; x += v dt; q <- exp(omega dt) q.
- splitting: kick-drift-kick (Stormer-Verlet) for translation, so constant gravity is exact;
  the free rotation over dt is the symmetric splitting of the kinetic energy into the three
  principal-axis parts, each an exact rotation about that body axis (Dullweber, Leimkuhler and
  McLachlan 1997): R1(dt/2) R2(dt/2) R3(dt) R2(dt/2) R1(dt/2). Symplectic, time-reversible,
  second order, L exact.
- rk4: classic fourth-order Runge-Kutta on (x, q, v, L) with dq/dt = (0, omega) q / 2; q is
  normalised after the step.
"""

import numpy as np
from numba import njit

from reference_sim.contact import find_candidates, post_solve, pre_solve, remember, world_omega
from reference_sim.quaternion import quat_from_rotvec, quat_multiply, quat_normalize, quat_to_matrix

INTEGRATORS = {"euler": 0, "splitting": 1, "rk4": 2}
EULER, SPLITTING, RK4 = 0, 1, 2
# Impacts slower than this many steps' worth of gravity are resting contacts, not bounces:
# a body lying still gains |g| dt of approach speed every step and must not bounce on it.
BOUNCE_STEPS = 2.0


@njit(cache=True)
def _free_rotation_split(model, q, L, b, dt):
    """Exact flows about the principal axes composed as R1(h/2) R2(h/2) R3(h) R2(h/2) R1(h/2)."""
    for k, frac in ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5)):
        axis = model.principal_axes[b, k]
        body_l = quat_to_matrix(q).T @ L
        angle = np.dot(axis, body_l) / model.principal_moments[b, k] * frac * dt
        # a rotation about a body-frame axis multiplies on the right
        q = quat_normalize(quat_multiply(q, quat_from_rotvec(angle * axis)))
    return q


@njit(cache=True)
def _quat_rate(model, q, L, b):
    w = world_omega(model, quat_normalize(q), L, b)
    return 0.5 * quat_multiply(np.array([0.0, w[0], w[1], w[2]]), q)


@njit(cache=True)
def _rk4_body(model, x, q, v, L, b, dt):
    g = model.gravity
    # dx/dt = v, dv/dt = g are integrated exactly by RK4 (polynomial); only q needs stages.
    k1 = _quat_rate(model, q, L, b)
    k2 = _quat_rate(model, q + 0.5 * dt * k1, L, b)
    k3 = _quat_rate(model, q + 0.5 * dt * k2, L, b)
    k4 = _quat_rate(model, q + dt * k3, L, b)
    x_new = x + dt * v + 0.5 * dt * dt * g
    v_new = v + dt * g
    q_new = quat_normalize(q + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4))
    return x_new, q_new, v_new


@njit(cache=True)
def rigid_step(model, integrator, x, q, v, L, dt, bounce_threshold, memory):
    """Advance every body by dt in place; contact impulses before and after the drift.

    `memory` holds last step's contact impulses (keys and values, before and after the drift)
    for the warm start; the updated memory is returned.
    """
    half = 0.5 * dt * model.gravity
    if integrator == EULER and model.gravity_on:
        for b in range(x.shape[0]):
            v[b] += dt * model.gravity
    cands = np.empty((0, 4), dtype=np.int64)
    if model.contact:
        cands = find_candidates(model, x, q, v, L, dt)
    lam, bounce = np.zeros((0, 3)), np.zeros(0)
    pre_keys, pre_lam = memory[0], memory[1]
    if cands.shape[0]:
        # the drift moves euler's bodies with v, the others' with v + g dt / 2
        drift_gravity = np.zeros(3) if integrator == EULER else half
        _, lam, pushed, bounce = pre_solve(
            model, x, q, v, L, cands, dt, drift_gravity, bounce_threshold, memory[0], memory[1]
        )
        pre_keys, pre_lam = remember(model, cands, lam, pushed & (lam[:, 0] > 0.0))
    for b in range(x.shape[0]):
        if integrator == EULER:
            x[b] += dt * v[b]
            w = world_omega(model, q[b], L[b], b)
            q[b] = quat_normalize(quat_multiply(quat_from_rotvec(dt * w), q[b]))
        elif integrator == SPLITTING:
            if model.gravity_on:
                v[b] += half
            x[b] += dt * v[b]
            q[b] = _free_rotation_split(model, q[b], L[b], b, dt)
            if model.gravity_on:
                v[b] += half
        else:
            x[b], q[b], v[b] = _rk4_body(model, x[b], q[b], v[b], L[b], b, dt)
    if cands.shape[0] == 0:
        return memory
    _, lam, active = post_solve(
        model,
        x,
        q,
        v,
        L,
        cands,
        dt,
        bounce,
        (lam[:, 0] > 0.0) | (bounce > 0.0),
        memory[2],
        memory[3],
    )
    post_keys, post_lam = remember(model, cands, lam, active)
    return pre_keys, pre_lam, post_keys, post_lam


@njit(cache=True)
def _record(model, x, q, v, L, out):
    for b in range(x.shape[0]):
        out[b, 0:3] = x[b]
        out[b, 3:7] = q[b]
        out[b, 7:10] = v[b]
        out[b, 10:13] = world_omega(model, q[b], L[b], b)


@njit(cache=True)
def run_rigid(model, integrator, x, q, v, L, dt, n_steps, stride):
    """Step n_steps times in place; return samples (S, B, 13): x, q, v, omega per body.

    Samples are taken at step 0, every `stride` steps, and at the last step.
    """
    n_samples = n_steps // stride + 1 + (1 if n_steps % stride else 0)
    out = np.empty((n_samples, x.shape[0], 13))
    steps = np.empty(n_samples, dtype=np.int64)
    bounce_threshold = BOUNCE_STEPS * np.sqrt(np.dot(model.gravity, model.gravity)) * dt
    none = np.empty(0, dtype=np.int64)
    memory = (none, np.empty((0, 3)), none, np.empty((0, 3)))
    _record(model, x, q, v, L, out[0])
    steps[0] = 0
    s = 1
    for n in range(1, n_steps + 1):
        memory = rigid_step(model, integrator, x, q, v, L, dt, bounce_threshold, memory)
        if n % stride == 0 or n == n_steps:
            _record(model, x, q, v, L, out[s])
            steps[s] = n
            s += 1
    return steps, out
