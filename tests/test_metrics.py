"""Metrics are computed by the suite from states; checked on states whose answers are known."""

import dataclasses

import numpy as np
import pytest

from cases import CATALOG
from comparators import RunMeta, Trajectory, run
from comparators.metrics import conserved_quantities, relative_drift, rest
from comparators.summary import summarize
from rigidmath.quaternion import quat_angle_between, quat_from_rotvec

META = RunMeta("x", "test", "none", 0.1, 1, 0.1, 0.0, 1.0)


@pytest.mark.parametrize("angle", [1e-12, 1e-9, 3e-8, 1e-4, 1.0, 3.0])
def test_orientation_error_is_exact_near_zero(angle):
    """2 atan2(|v|, |w|) keeps small angles that acos(w) would round to zero."""
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    q = quat_from_rotvec(angle * axis)
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    assert quat_angle_between(ident, q) == pytest.approx(angle, rel=1e-12)
    assert quat_angle_between(ident, -q) == pytest.approx(angle, rel=1e-12)  # q ~ -q


def _table(scene, x, q, v, w, t=(0.0,)):
    samples = np.array([[[*x, *q, *v, *w]]] * len(t))
    return Trajectory.from_samples(t, [scene.bodies[0].name], samples, META)


def test_energy_and_momentum_of_a_known_state():
    scene = CATALOG["seed_cube"]  # mass 8, inertia diag(4, 4, 4), gravity (0, 0, -10)
    traj = _table(scene, (0, 0, 2.0), (1, 0, 0, 0), (0, 3.0, 0), (2.0, 0, 0))
    c = conserved_quantities(traj, scene).iloc[0]
    assert c["kinetic_translational"] == pytest.approx(0.5 * 8 * 9)
    assert c["kinetic_rotational"] == pytest.approx(0.5 * 4 * 4)
    assert c["potential"] == pytest.approx(8 * 10 * 2)
    assert (c["px"], c["py"], c["pz"]) == pytest.approx((0, 24, 0))
    assert (c["Lx"], c["Ly"], c["Lz"]) == pytest.approx((8, 0, 0))


def test_angular_momentum_uses_the_rotated_inertia():
    """A box turned 90 deg about x has its y and z moments swapped in world axes."""
    scene = CATALOG["tumbling_box"]  # inertia diag(26, 20, 10)
    q = quat_from_rotvec(np.array([np.pi / 2, 0, 0]))
    traj = _table(scene, (0, 0, 0), q, (0, 0, 0), (0, 1.0, 1.0))
    c = conserved_quantities(traj, scene).iloc[0]
    assert (c["Lx"], c["Ly"], c["Lz"]) == pytest.approx((0, 10, 20))


def test_relative_drift():
    assert relative_drift(np.array([2.0, 2.5, 1.0])) == pytest.approx(0.5)
    assert relative_drift(np.array([0.0, 1e-3])) == pytest.approx(1e-3)  # absolute when 0
    v = np.array([[3.0, 4.0, 0.0], [3.0, 4.0, 1.0]])
    assert relative_drift(v) == pytest.approx(0.2)


# Splitting integrates free fall exactly; what is left is rounding: 1000 steps adding ulps of a
# 40 kJ kinetic energy, about 66 times the initial energy (608 J): ~1000 * 66 * 1.1e-16 = 7e-12.
FREE_FALL_RTOL = 1e-10


def test_free_fall_has_no_momentum_drift():
    scene = dataclasses.replace(CATALOG["free_spin_cube"], gravity=(0.0, 0.0, -10.0))
    s = summarize(run(scene, "reference", "splitting"), scene)
    assert s["momentum_drift"] < FREE_FALL_RTOL
    assert s["energy_drift"] < FREE_FALL_RTOL


def test_rest_detection_sees_motion():
    scene = CATALOG["dropped_cube"]
    traj = run(scene, "reference", "splitting", duration=0.5)  # still falling
    assert not rest(traj, scene, "cube")["at_rest"]


def test_a_non_finite_state_is_reported_as_diverged():
    scene = CATALOG["free_spin_cube"]
    traj = _table(scene, (0, 0, np.nan), (1, 0, 0, 0), (0, 0, 0), (2, 0, 0), t=(0.0, 0.1))
    assert summarize(traj, scene)["verdict"] == "diverged"
