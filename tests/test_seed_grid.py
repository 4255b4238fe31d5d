"""The seed's pair search on the grid (`_collide_particles_grid`) equals the blog's loop over all
pairs (`_collide_particles`, the reference): the same collisions in the same order, so the
same trajectories, bit for bit, including when a collision pushes a particle into a pair that
did not overlap at the step's start."""

import numpy as np
import pytest

from cases import CATALOG
from cases.catalog import cube_rain
from comparators.reference import model_from_scene
from reference_sim.contact.grid import sphere_pairs
from reference_sim.model import build_model, seed_initial_state
from reference_sim.seed import (
    SEED_GRID_MIN_PARTICLES,
    _apply_walls,
    _collide_particles,
    _collide_particles_grid,
    _update_bodies,
)


def _scene_state(scene):
    model = model_from_scene(scene)
    state = seed_initial_state(
        model,
        np.concatenate([b.positions for b in scene.bodies]),
        [b.velocity for b in scene.bodies],
        [b.angular_velocity for b in scene.bodies],
    )
    return model, [np.array(a, copy=True) for a in state]


def _bits(*arrays):
    return np.concatenate([a.ravel() for a in arrays]).view(np.int64)


def _run(model, state, dt, n_steps, collide):
    """The seed's step (`seed_step`) with the given pair search; per step the particles'
    positions and velocities as bits, and how many steps had a collision."""
    pos, vel, cm, V, omega = (a.copy() for a in state)
    bits, colliding = [], 0
    for _ in range(n_steps):
        before = _bits(pos, vel)
        collide(model, pos, vel)
        colliding += not np.array_equal(before, _bits(pos, vel))
        assert _update_bodies(model, pos, vel, cm, V, omega, dt)
        _apply_walls(model, pos, vel, cm, V, omega)
        bits.append(_bits(pos, vel))
    return np.array(bits), colliding


@pytest.mark.parametrize(
    "scene, n_steps",
    [
        (CATALOG["seed_cube"], 10_000),  # the whole run: same-body pairs collide from step 379
        (cube_rain(8), 100),  # the whole second
        (cube_rain(100), 40),  # until the first landings
    ],
    ids=lambda p: p.name if hasattr(p, "name") else str(p),
)
def test_grid_pair_search_gives_the_blog_loops_trajectory_bit_for_bit(scene, n_steps):
    model, state = _scene_state(scene)
    every, colliding = _run(model, state, scene.dt, n_steps, _collide_particles)
    grid, _ = _run(model, state, scene.dt, n_steps, _collide_particles_grid)
    assert colliding > 0  # particles did collide
    differ = np.flatnonzero((every != grid).any(axis=1))
    assert len(differ) == 0, f"{scene.name}: trajectories part at step {differ[0] + 1}"


def _cascade():
    """Particles 1 to 3 (heavy, 1e6 kg) each push light particle 0 nearly a reach (1 m) along x
    in turn, pairs (0, 1), (0, 2), (0, 3) in the blog's order, so that pair (0, 4) overlaps when
    it is tested though particle 4 starts 3.5 m from particle 0: more than a reach plus twice
    the largest reach, where the grid does not look. Particle 5 keeps the body's inertia
    invertible. One body of radius-0.5 particles, no gravity, no walls."""
    rows = np.array(
        [
            [0.0, 0.0, 0.0, 1.0],
            [-0.001, 0.0, 0.0, 1e6],
            [0.997, 0.0, 0.0, 1e6],
            [1.993, 0.0, 0.0, 1e6],
            [3.5, 0.0, 0.0, 1.0],
            [0.0, 10.0, 0.0, 1.0],
        ]
    )
    model = build_model([(rows, 0.5)], (0.0, 0.0, 0.0), restitution=0.5, contact=True)
    state = seed_initial_state(model, rows[:, :3], [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.3]])
    return model, [np.array(a, copy=True) for a in state]


def test_a_cascade_into_a_pair_the_grid_did_not_find_is_followed():
    model, (pos, vel, *_) = _cascade()
    vel[4] = (-1.0, 0.0, 0.0)  # particle 4 meets particle 0: the blog's impulse changes it
    reach = 2 * 0.5
    start = np.linalg.norm(pos[0] - pos[4])
    assert start > 3 * reach  # not overlapping, and not among the pairs the grid finds
    found = sphere_pairs(model.radius, pos, np.full(len(pos), reach), 64)
    assert [0, 4] not in found.tolist()

    every_pos, every_vel = pos.copy(), vel.copy()
    _collide_particles(model, every_pos, every_vel)
    assert np.linalg.norm(every_pos[0] - every_pos[4]) < start - 1.0  # the blog's loop did push 4
    assert every_pos[4, 0] > pos[4, 0] and every_vel[4, 0] != vel[4, 0]

    grid_pos, grid_vel = pos.copy(), vel.copy()
    searches = _collide_particles_grid(model, grid_pos, grid_vel)
    assert searches > 1  # particle 0 moved past the limit: the pairs after it were found again
    np.testing.assert_array_equal(_bits(grid_pos, grid_vel), _bits(every_pos, every_vel))


def test_a_cascade_scene_runs_bit_for_bit():
    model, state = _cascade()
    every, colliding = _run(model, state, 0.01, 50, _collide_particles)
    grid, _ = _run(model, state, 0.01, 50, _collide_particles_grid)
    assert colliding > 0
    np.testing.assert_array_equal(grid, every)


def test_without_a_bounded_grid_every_pair_is_tested():
    """A NaN particle leaves no grid (`sphere_pairs` tests every pair); radii beyond the grid's
    range refuse it (`_collide_particles_grid` returns 0): the collisions are the blog's."""
    model, (pos, vel, *_) = _scene_state(cube_rain(8))
    assert len(pos) >= SEED_GRID_MIN_PARTICLES  # `seed_step` takes the grid on cube_rain_8
    pos[3] = np.nan
    results = []
    for collide in (_collide_particles, _collide_particles_grid):
        p, v = pos.copy(), vel.copy()
        collide(model, p, v)
        results.append(_bits(p, v))
    np.testing.assert_array_equal(results[0], results[1])
    huge = model._replace(radius=np.full(len(pos), 1e101))
    assert _collide_particles_grid(huge, pos.copy(), vel.copy()) == 0
