"""Mass properties of a particle cluster, as in the seed: I = sum m (r.r 1 - r r^T).

A particle's own sphere adds no inertia. Plain Python on numpy arrays, written so that numba can
compile them too: the seed compiles `inertia_tensor` for its step loop (`reference_sim.seed`);
scenes and models call them uncompiled, so that loading a case compiles nothing.
"""

import numpy as np

# Principal moments closer than this (relative to the largest) are taken as equal, selecting the
# isotropic or axisymmetric closed form (exactly equal moments are a 0/0 in the elliptic
# parameters). eigh's rounding of a symmetric body's inertia is ~1e-15 relative, and a body whose
# moments really differ by delta is off by at most ~delta |omega| t (1e-12 over 10 rad of
# rotation). The exact solution and the `exact` integrator share it: the same branch per body.
EQUAL_MOMENTS_RTOL = 1e-13


def center_of_mass(positions, masses):
    """(3,) mass-weighted mean of `positions` (n, 3) with `masses` (n,)."""
    c = np.zeros(3)
    for i in range(positions.shape[0]):
        c += masses[i] * positions[i]
    return c / masses.sum()


def inertia_tensor(offsets, masses):
    """(3, 3) inertia tensor of point masses at `offsets` (n, 3) from the reference point."""
    inertia = np.zeros((3, 3))
    for i in range(offsets.shape[0]):
        r = offsets[i]
        r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
        for a in range(3):
            inertia[a, a] += masses[i] * r2
            for b in range(3):
                inertia[a, b] -= masses[i] * r[a] * r[b]
    return inertia


def principal_frame(inertia):
    """Principal moments (3,) ascending and axes (3, 3) as columns, a proper rotation (det +1),
    so that inertia = axes diag(moments) axes^T."""
    moments, axes = np.linalg.eigh(np.asarray(inertia, dtype=float))
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes
