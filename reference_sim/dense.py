"""Dense symmetric positive definite solves in preallocated arrays, for the compiled step loops.

The contact solver's subspace step (`reference_sim.contact.subspace`) solves a system of at most
a few dozen unknowns several times a step; kernels allocate nothing, so `np.linalg` is not an
option. The factor is upper triangular (a = U^T U) and computed a row at a time, so that every
inner loop runs along contiguous rows of the row-major array rather than as chains of dependent
additions down strided columns (the textbook lower-triangular form).
"""

import math

from reference_sim.jit import kernel


@kernel
def _row_end(factor, i, n):
    """One past the last nonzero of row i of the factor (at least i + 1)."""
    end = n
    while end > i + 1 and factor[i, end - 1] == 0.0:
        end -= 1
    return end


@kernel
def cholesky_into(a, n):
    """Overwrite the upper triangle of a[:n, :n] (symmetric, only the upper triangle is read)
    with its Cholesky factor U (a = U^T U); False, with a[:n, :n] partly overwritten, if a is
    not positive definite. Row j's entries past its last nonzero are skipped: they are zeros
    and stay zeros (no fill-in outside a row's extent), which a chain of bodies (a stack)
    leaves for most of the row."""
    for j in range(n):
        if not a[j, j] > 0.0:
            return False
        d = math.sqrt(a[j, j])
        a[j, j] = d
        end = _row_end(a, j, n)  # row j is final here
        for k in range(j + 1, end):
            a[j, k] /= d
        for i in range(j + 1, end):
            f = a[j, i]
            if f != 0.0:  # bodies that share no contact: their block stays zero
                for k in range(i, end):
                    a[i, k] -= f * a[j, k]
    return True


@kernel
def cholesky_solve(factor, n, b):
    """Overwrite b[:n] with the solution x of U^T U x = b, U the upper triangle of `factor`
    (`cholesky_into`), skipping each row's zeros past its last nonzero."""
    for j in range(n):  # U^T y = b
        y = b[j] / factor[j, j]
        b[j] = y
        for i in range(j + 1, _row_end(factor, j, n)):
            b[i] -= factor[j, i] * y
    for i in range(n - 1, -1, -1):  # U x = y
        s = b[i]
        for k in range(i + 1, _row_end(factor, i, n)):
            s -= factor[i, k] * b[k]
        b[i] = s / factor[i, i]
