"""Hand-derivable checks of the blog transliteration (``tests/blog_seed.py``) itself."""

from __future__ import annotations

import math

import numpy as np
import pytest
from blog_seed import (
    BlogWorld,
    blog_run,
    blog_seed_cube_world,
    blog_step,
    blog_step_count,
    create_cube,
)

RADIUS = 0.2


def test_blog_step_count_float_loop():
    # t += 0.01 from 0.0: t after 9999 steps is < 100, after 10000 it is 100.00000000001425.
    assert blog_step_count(100.0, 0.01) == 10000
    # 10 x 0.1 accumulates to 0.9999999999999999 < 1.0, so Julia's loop runs an 11th step.
    assert blog_step_count(1.0, 0.1) == 11
    assert blog_step_count(0.0, 0.01) == 0


def test_create_cube_matches_blog():
    world = blog_seed_cube_world()
    corners = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
        dtype=np.float64,
    )
    np.testing.assert_array_equal(world.positions, corners + [3.0, 3.0, 7.0])
    (body,) = world.bodies
    assert body.particle_indices == list(range(8))
    np.testing.assert_array_equal(body.cm, [3.5, 3.5, 7.5])
    assert body.V.dtype == np.float64
    np.testing.assert_array_equal(body.V, [0.0, 0.0, -2.0])
    np.testing.assert_array_equal(body.omega, [2.0, 0.0, 0.0])
    np.testing.assert_array_equal(world.rigidbody, np.ones(8, dtype=np.int64))
    # Quirk: particle velocities are omega x r only -- V is NOT added.
    r = world.positions - body.cm
    np.testing.assert_array_equal(world.velocities, np.cross([2.0, 0.0, 0.0], r))
    assert not np.any(world.velocities[:, 2] == -2.0 + np.cross([2.0, 0.0, 0.0], r)[:, 2])


def test_collision_uses_corrected_positions_and_both_dv_before_update():
    """Two free particles, head-on, overlapping by 0.1; masses 1 and 3, restitution 0.

    Positions are corrected first (x1 -= 0.075, x2 += 0.025) so the impulse uses the corrected
    separation 0.4 = r1 + r2: dv1 = -(3/4)(2)(-0.4)(-0.4)/0.16 = -1.5, dv2 = +0.5 -> both end at
    the common velocity -0.5 (perfectly inelastic).  With the uncorrected separation 0.3 the
    result would be v1 = 1 - 0.84375.
    """
    world = BlogWorld(
        positions=np.array([[5.0, 5.0, 5.0], [5.3, 5.0, 5.0]]),
        velocities=np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]),
        masses=np.array([1.0, 3.0]),
        radii=np.array([RADIUS, RADIUS]),
        rigidbody=np.array([0, 0]),
    )
    blog_step(world)
    np.testing.assert_allclose(world.positions[:, 0], [4.925, 5.325], rtol=0, atol=1e-12)
    np.testing.assert_allclose(world.velocities[:, 0], [-0.5, -0.5], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(world.velocities[:, 1:], 0.0)
    # Quirk: free particles are never integrated (no x += v dt anywhere in simulate_step!).
    blog_run(world, 10)
    np.testing.assert_allclose(world.positions[:, 0], [4.925, 5.325], rtol=0, atol=1e-12)


def test_free_spin_scales_perpendicular_distance_by_sqrt_1_plus_w2dt2():
    """Explicit-Euler 'rotation' r += (w x r) dt: the component of r along w is unchanged and
    the perpendicular component grows by exactly sqrt(1 + |w|^2 dt^2) per step."""
    dt = 0.01
    world = BlogWorld()
    create_cube(world, 1, (3, 3, 7), (0, 0, 0), (2.0, 0.0, 0.0))
    body = world.bodies[0]
    for _ in range(200):
        r_old = world.positions - body.cm
        blog_step(world, dt=dt, gravity=(0.0, 0.0, 0.0), box_size=1e6)
        r_new = world.positions - body.cm
        w = body.omega.copy()  # the omega used for this step's update
        w_hat = w / np.linalg.norm(w)
        factor = math.sqrt(1.0 + float(w @ w) * dt * dt)
        for a, b in zip(r_old, r_new, strict=True):
            along_a, along_b = a @ w_hat, b @ w_hat
            perp_a = np.linalg.norm(a - along_a * w_hat)
            perp_b = np.linalg.norm(b - along_b * w_hat)
            assert along_b == pytest.approx(along_a, rel=0, abs=1e-12)
            assert perp_b / perp_a == pytest.approx(factor, rel=1e-12, abs=0)
        # L = I w on a principal axis of the symmetric cube: omega stays (2, 0, 0).
        np.testing.assert_allclose(body.omega, [2.0, 0.0, 0.0], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(body.cm, [3.5, 3.5, 7.5])
        np.testing.assert_array_equal(body.V, [0.0, 0.0, 0.0])


def _full_blog_run(same_body_pairs: bool) -> tuple[BlogWorld, int, int]:
    world = blog_seed_cube_world()
    hits = {"applied": 0, "skipped": 0}

    def on_contact(i: int, j: int, applied: bool) -> None:
        if world.rigidbody[i] != 0 and world.rigidbody[i] == world.rigidbody[j]:
            hits["applied" if applied else "skipped"] += 1

    blog_run(
        world, blog_step_count(100.0, 0.01), same_body_pairs=same_body_pairs, on_contact=on_contact
    )
    return world, hits["applied"], hits["skipped"]


def test_blog_seed_cube_full_run_ends_flattened_on_floor():
    finals = {}
    for same_body_pairs in (True, False):
        world, applied, skipped = _full_blog_run(same_body_pairs)
        body = world.bodies[0]
        z = world.positions[:, 2]
        print(
            f"same_body_pairs={same_body_pairs}: z in [{float(z.min())!r}, {float(z.max())!r}], "
            f"cm={body.cm.tolist()!r}, V={body.V.tolist()!r}, omega={body.omega.tolist()!r}, "
            f"x spread={float(np.ptp(world.positions[:, 0]))!r}, "
            f"y spread={float(np.ptp(world.positions[:, 1]))!r}, "
            f"same-body contacts applied={applied} skipped(within 2r)={skipped}"
        )
        # Flattened on the floor: every particle clamped to z = radius exactly.
        np.testing.assert_array_equal(z, RADIUS)
        # Rotation is about x only: x coordinates never change (r_x = +-0.5 is along omega).
        np.testing.assert_array_equal(np.sort(np.unique(world.positions[:, 0])), [3.0, 4.0])
        np.testing.assert_array_equal(body.cm[:2], [3.5, 3.5])
        np.testing.assert_array_equal(body.V, 0.0)  # reset by the floor every step
        # Quirk: the floor resets V but never moves cm, so cm sinks through the floor.
        assert body.cm[2] < -9.0
        # Same-body pairs do come within 2 * radius during the run.
        assert (applied if same_body_pairs else skipped) > 0
        assert (skipped if same_body_pairs else applied) == 0
        finals[same_body_pairs] = world
    # ... and resolving them matters: the final states differ.
    a, b = finals[True], finals[False]
    assert not np.array_equal(a.positions, b.positions)
    assert not np.array_equal(a.bodies[0].omega, b.bodies[0].omega)
