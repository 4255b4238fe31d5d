"""3-vectors and 3 x 3 matrices as tuples, for the compiled step loops.

A tuple lives in registers or on the stack: the step loops do their small linear algebra with
these functions instead of `@`, `np.cross` or `np.array`, each of which allocates a heap array
(and `@` calls BLAS) for three numbers. Matrices are 9-tuples, row major.
"""

import math

from reference_sim.jit import kernel


@kernel
def vec(a):
    """A (3,) array as a tuple."""
    return (a[0], a[1], a[2])


@kernel
def row(a, i):
    """Row i of an (n, 3) array as a tuple.

    Indexing the element, not the row, creates no array view: a view costs a reference-count
    update, which in a step loop costs more than the arithmetic.
    """
    return (a[i, 0], a[i, 1], a[i, 2])


@kernel
def mat(a, i):
    """a[i] of an (n, 3, 3) array as a row-major 9-tuple (no view, as `row`)."""
    return (
        a[i, 0, 0],
        a[i, 0, 1],
        a[i, 0, 2],
        a[i, 1, 0],
        a[i, 1, 1],
        a[i, 1, 2],
        a[i, 2, 0],
        a[i, 2, 1],
        a[i, 2, 2],
    )


@kernel
def flat(a, i):
    """Row i of an (n, 9) array (a row-major 3 x 3 matrix per row) as a 9-tuple."""
    return (a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5], a[i, 6], a[i, 7], a[i, 8])


@kernel
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@kernel
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@kernel
def scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


@kernel
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@kernel
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel
def tangents(n):
    """Two unit vectors completing the unit vector n to a right-handed orthonormal basis."""
    helper = (1.0, 0.0, 0.0) if abs(n[0]) < 0.57735 else (0.0, 1.0, 0.0)
    t1 = cross(n, helper)
    t1 = scale(1.0 / math.sqrt(dot(t1, t1)), t1)
    return t1, cross(n, t1)


@kernel
def mat_vec(m, v):
    """m v."""
    return (
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
        m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
    )


@kernel
def mat_t_vec(m, v):
    """m^T v."""
    return (
        m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
        m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
        m[2] * v[0] + m[5] * v[1] + m[8] * v[2],
    )


@kernel
def conjugate_by(r, m):
    """r m r^T, the body-frame matrix m in the world frame of rotation r."""
    # columns of m r^T are m (rows of r); r times each
    c0 = mat_vec(r, mat_vec(m, (r[0], r[1], r[2])))
    c1 = mat_vec(r, mat_vec(m, (r[3], r[4], r[5])))
    c2 = mat_vec(r, mat_vec(m, (r[6], r[7], r[8])))
    return (c0[0], c1[0], c2[0], c0[1], c1[1], c2[1], c0[2], c1[2], c2[2])
