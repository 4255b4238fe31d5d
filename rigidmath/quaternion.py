"""Unit quaternions, scalar first (w, x, y, z): the formulas, in plain Python and numpy.

The tuple functions (`qmul`, `qnormalize`, `qexp`, `qmatrix`, `qfrom_matrix`) take and return
tuples so that numba can compile them unchanged into allocation-free kernels
(`reference_sim.quaternion`); the array functions apply the same formulas to numpy arrays (the
plural names to (n, 4) batches) for the scenes, the engines and the metrics.
"""

import math

import numpy as np


def qmul(p, q):
    """Hamilton product p q of 4-tuples (or rows): the rotation q followed by p."""
    return (
        p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
        p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
        p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
        p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0],
    )


def qnormalize(q):
    """q / |q| as a 4-tuple."""
    s = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (s * q[0], s * q[1], s * q[2], s * q[3])


def qexp(v):
    """Exponential map as a 4-tuple: the rotation by angle |v| about v / |v|."""
    angle = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    half = 0.5 * angle
    # sin(half)/angle, with its Taylor series where the division would lose precision
    if angle < 1e-4:
        s = 0.5 - angle * angle / 48.0
    else:
        s = math.sin(half) / angle
    return (math.cos(half), s * v[0], s * v[1], s * v[2])


def qmatrix(q):
    """Rotation matrix of the unit quaternion q as a row-major 9-tuple."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return (
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )


def qfrom_matrix(m):
    """Unit quaternion of the rotation matrix m (a row-major 9-tuple, as `qmatrix` gives) as a
    4-tuple of either sign, by Shepperd's stable method."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m
    tr = m00 + m11 + m22
    if tr >= m00 and tr >= m11 and tr >= m22:
        s = 2.0 * math.sqrt(1.0 + tr)
        w, x, y, z = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        w, x, y, z = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif m11 >= m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        w, x, y, z = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        w, x, y, z = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


def quat_multiply(p, q):
    """Hamilton product p q: the rotation q followed by p."""
    return np.array(qmul(p, q))


def quat_conjugate(q):
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_normalize(q):
    return np.array(qnormalize(q))


def quat_from_rotvec(v):
    """Exponential map: the rotation by angle |v| about v / |v|."""
    return np.array(qexp(v))


def quat_to_matrix(q):
    """(3, 3) rotation matrix of the unit quaternion q."""
    return np.array(qmatrix(q)).reshape(3, 3)


def quat_from_matrix(m):
    """Unit quaternion (w >= 0) of the rotation matrix m (3, 3) (`qfrom_matrix`)."""
    q = np.array(
        qfrom_matrix(
            (m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1], m[2, 2])
        )
    )
    return -q if q[0] < 0 else q


def quat_angle_between(p, q):
    """Geodesic angle (rad) of p^-1 q, in [0, pi]; q and -q count as the same rotation.

    2 atan2(|vector part|, |scalar part|) keeps full precision near zero, where acos does not.
    """
    return float(quats_angle_between(np.asarray(p)[None], np.asarray(q)[None])[0])


def quats_to_matrices(qs):
    """(n, 3, 3) rotation matrices of (n, 4) quaternions."""
    qs = np.asarray(qs, dtype=float)
    return np.stack(qmatrix(qs.T), axis=-1).reshape(len(qs), 3, 3)


def quats_angle_between(ps, qs):
    """(n,) geodesic angles (rad) between (n, 4) quaternion arrays (`quat_angle_between`)."""
    d = qmul(quats_conjugate(ps).T, np.asarray(qs, dtype=float).T)
    return 2.0 * np.arctan2(np.sqrt(d[1] * d[1] + d[2] * d[2] + d[3] * d[3]), np.abs(d[0]))


def quats_multiply(p, q):
    """Hamilton products of (..., 4) quaternion arrays, broadcasting over the leading axes."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quats_conjugate(q):
    """Conjugates (inverses of unit quaternions) of a (..., 4) array."""
    return np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])


def quats_rotate(q, v):
    """Rotate v (3,) or (S, 3) by the unit quaternions q (S, 4): v + 2 w (u x v) + 2 u x (u x v)."""
    w, u = q[:, :1], q[:, 1:]
    uv = np.cross(u, v)
    return v + 2.0 * w * uv + 2.0 * np.cross(u, uv)


def quats_from_rotvecs(r: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w >= 0 for angles up to pi) of (..., 3) rotation vectors."""
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(angle / 2) / angle, by its series below 1e-4 rad (error < 1e-18 there)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(angle < 1e-4, 0.5 - angle**2 / 48.0, np.sin(half) / angle)
    return np.concatenate([np.cos(half), scale * r], axis=-1)


def quats_from_matrices(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), w >= 0, of rotation matrices (..., 3, 3), by Shepperd's
    method (the branch of the largest of trace, r00, r11, r22); NaN in, NaN out."""
    m = r.reshape(-1, 3, 3)
    q = np.full((len(m), 4), np.nan)
    diag = np.stack([m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2], m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]])
    finite = np.isfinite(diag).all(axis=0)
    branch = np.where(finite, np.argmax(np.where(finite, diag, 0.0), axis=0), -1)
    d = m[:, [2, 0, 1], [1, 2, 0]] - m[:, [1, 2, 0], [2, 0, 1]]  # r21-r12, r02-r20, r10-r01
    for k in range(4):
        rows = branch == k
        if not rows.any():
            continue
        a = m[rows]
        if k == 0:
            s = 2.0 * np.sqrt(1.0 + diag[0, rows])
            q[rows] = np.column_stack([0.25 * s, *(d[rows] / s[:, None]).T])
            continue
        i, j, n = k - 1, k % 3, (k + 1) % 3  # the axis of the branch and the two after it
        s = 2.0 * np.sqrt(1.0 + a[:, i, i] - a[:, j, j] - a[:, n, n])
        out = np.empty((len(a), 4))
        out[:, 0] = d[rows, i] / s
        out[:, 1 + i] = 0.25 * s
        out[:, 1 + j] = (a[:, i, j] + a[:, j, i]) / s
        out[:, 1 + n] = (a[:, i, n] + a[:, n, i]) / s
        q[rows] = out
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(*r.shape[:-2], 4)
