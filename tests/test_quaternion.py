"""rigidmath.quaternion's array conversions against its scalar ones."""

import math

import numpy as np

from rigidmath.quaternion import (
    quat_from_matrix,
    quat_from_rotvec,
    quat_to_matrix,
    quats_from_matrices,
    quats_from_rotvecs,
)

# Both Shepperd's method, the same operations up to their order (measured 2.2e-16); the rotation
# vector's small-angle series is below 1e-18 where it is used.
QUAT_ATOL = 1e-15


def test_quaternions_from_matrices_match_the_scalar_conversion():
    """Random rotations and the half-turns about each axis (every Shepperd branch)."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(500, 4))
    q[:4] = [[1e-9, 1, 0, 0], [1e-9, 0, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0]]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    r = np.array([quat_to_matrix(x) for x in q])
    expected = np.array([quat_from_matrix(m) for m in r])
    np.testing.assert_allclose(quats_from_matrices(r), expected, rtol=0, atol=QUAT_ATOL)
    assert np.isnan(quats_from_matrices(np.full((2, 3, 3), np.nan))).all()


def test_quaternions_from_rotation_vectors_match_the_exponential_map():
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(64, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([[0.0, 1e-9, 1e-5, 2e-4, math.pi], rng.uniform(0, math.pi, 59)])
    rotvecs = axes * angles[:, None]
    want = np.array([quat_from_rotvec(r) for r in rotvecs])
    np.testing.assert_allclose(quats_from_rotvecs(rotvecs), want, rtol=0, atol=QUAT_ATOL)
