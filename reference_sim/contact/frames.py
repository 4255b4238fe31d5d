"""The bodies as contact sees them at a step's start: rotation matrices, world inverse inertias
and angular velocities, particle positions, and how far each body can move in the step; and
the angular momenta a solve's new angular velocities give, without subnormal remainders."""

import math

import numpy as np

from reference_sim.jit import inlined_kernel, kernel
from reference_sim.quaternion import qmatrix
from reference_sim.vec3 import add, conjugate_by, dot, flat, mat, mat_t_vec, mat_vec, row, vec

# The smallest normal double (2.2e-308): below it a float is subnormal, and every operation on
# one costs about a hundred cycles on x86. No physical speed or momentum is that small.
NORMAL_MIN = np.finfo(np.float64).tiny


@kernel
def world_omega(model, q, L, b):
    """World angular velocity omega = R I0^-1 R^T L of body b (q, L: that body's rows), a tuple."""
    r = qmatrix(q)
    return mat_vec(r, mat_vec(mat(model.inertia0_inv, b), mat_t_vec(r, L)))


@inlined_kernel
def frames_into(model, q, L, rot, inv, omega):
    """Each body's rotation matrix, world inverse inertia (B, 9) and world omega (B, 3)."""
    for b in range(q.shape[0]):
        r = qmatrix((q[b, 0], q[b, 1], q[b, 2], q[b, 3]))
        i_world = conjugate_by(r, mat(model.inertia0_inv, b))
        w = mat_vec(i_world, row(L, b))
        for k in range(9):
            rot[b, k] = r[k]
            inv[b, k] = i_world[k]
        omega[b, 0], omega[b, 1], omega[b, 2] = w


@inlined_kernel
def angular_momenta(model, L, rot, inv, omega):
    """L += R I0 R^T (omega - inv L) for each body, after a solve that changed omega alone:
    inv L is the omega it started from (as `frames_into` made it, bit for bit), so a body it
    did not touch keeps its L exactly. One product a body, not three more a contact update."""
    for b in range(L.shape[0]):
        start = mat_vec(flat(inv, b), row(L, b))
        dw = (omega[b, 0] - start[0], omega[b, 1] - start[1], omega[b, 2] - start[2])
        if dw[0] != 0.0 or dw[1] != 0.0 or dw[2] != 0.0:
            r = flat(rot, b)
            dl = mat_vec(r, mat_vec(mat(model.inertia0, b), mat_t_vec(r, dw)))
            for i in range(3):
                L[b, i] += dl[i]


@inlined_kernel
def flush_subnormal(v, L):
    """Set each body's velocity and angular momentum components below NORMAL_MIN to zero. A
    solve can leave a body at rest with a subnormal remainder that stays for good, every step's
    arithmetic on it slowed (docs/contact-solver.md, "Subnormal remainders")."""
    for b in range(v.shape[0]):
        for i in range(3):
            if abs(v[b, i]) < NORMAL_MIN:
                v[b, i] = 0.0
            if abs(L[b, i]) < NORMAL_MIN:
                L[b, i] = 0.0


@kernel
def particle(model, x, rot, b, i):
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
