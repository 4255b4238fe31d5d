"""The broad phase finds what testing every pair finds.

- Body pairs found on the uniform grid (coarsened to its cell budget when the bodies spread
  wide, or far flung, or NaN) are exactly those found pair by pair, and a crowded scene stepped
  with either is bit-equal.
- The pair list kept between steps gives the grid's pairs at every step, and is found again
  for NaN bodies.
- The particle candidates, found only among particles that can reach the other body, are those
  of every particle pair tested in numpy.
- The step takes its frames from the search that found its body pairs, also when that search
  grows the buffers.
"""

from dataclasses import replace

import numpy as np
import pytest
from scenes import model_and_state

from cases import Body, Contact, Scene
from cases.builders import box_corners, box_lattice, box_walls
from reference_sim.contact.buffers import COUNT_PAIRS, contact_buffers, grown, largest_body
from reference_sim.contact.candidates import all_pairs, find_candidates_into
from reference_sim.contact.frames import frames_into, reach_into
from reference_sim.contact.grid import _bin, grid_pairs
from reference_sim.contact.pair_list import current_pairs, pair_list
from reference_sim.contact.settings import GRID_CELLS_PER_BODY, GRID_MIN_BODIES, candidate_margin
from reference_sim.rigid import BOUNCE_STEPS, INTEGRATOR_CODES, _body_pairs, rigid_step


def crowd(n_side: int = 4, seed: int = 7) -> Scene:
    """n_side^3 small boxes, jittered and spinning, falling into a closed box: many close pairs."""
    rng = np.random.default_rng(seed)
    spacing = 0.45
    bodies = []
    for k, (i, j, m) in enumerate(np.ndindex(n_side, n_side, n_side)):
        center = np.array([i, j, m]) * spacing + 0.4 + rng.uniform(-0.05, 0.05, 3)
        bodies.append(
            Body(
                name=f"box{k}",
                particle_radius=0.05,
                particles=box_corners((0.3, 0.3, 0.3), center=tuple(center)),
                velocity=tuple(rng.normal(0.0, 0.5, 3)),
                angular_velocity=tuple(rng.normal(0.0, 2.0, 3)),
            )
        )
    upper = n_side * spacing + 0.4
    return Scene(
        name="crowd",
        duration=0.5,
        dt=0.005,
        gravity=(0.0, 0.0, -10.0),
        contact=Contact(restitution=0.3, friction=0.5),
        planes=box_walls(upper=(upper, upper, upper + 1.0)),
        bodies=tuple(bodies),
    )


def _reach(model, state, dt):
    buf = contact_buffers(len(model.body_mass), 1, 1, largest_body(model))
    frames_into(model, state.q, state.L, buf.rot, buf.inv, buf.omega)
    reach_into(model, state.v, buf.omega, dt, (0.0, 0.0, 0.0), buf.reach)
    return buf.reach


def test_grid_finds_the_same_body_pairs():
    scene = crowd()
    model, state = model_and_state(scene)
    for dt in (0.005, 0.05, 0.5):  # from few pairs to nearly all of them
        reach = _reach(model, state, dt)
        grid = grid_pairs(model, state.x, reach)
        every = all_pairs(model, state.x, reach)
        assert len(every) > 0
        np.testing.assert_array_equal(grid, every)


def _lattice_crowd() -> Scene:
    """The crowd with every other box a 3 x 3 x 3 lattice of smaller particles: bodies of
    different particle counts and radii side by side."""
    scene = crowd()
    bodies = list(scene.bodies)
    for k in range(1, len(bodies), 2):
        centre = np.mean([row[:3] for row in bodies[k].particles], axis=0)
        particles = box_lattice((0.3, 0.3, 0.3), (3, 3, 3), center=tuple(centre))
        bodies[k] = replace(bodies[k], particles=particles, particle_radius=0.02)
    return replace(scene, bodies=tuple(bodies))


def _every_particle_pair(model, x, rot, wide, pairs):
    """The particle candidates of body `pairs` (widened reaches `wide`) with every particle
    pair tested, in numpy, as (rows, margins): rows (a, i, b, j) in key order, and each tested
    pair's squared distance over its squared bound, minus one (how near to the bound it
    fell)."""
    rows, margins = [], []
    for a, b in pairs:
        ia = np.arange(model.body_start[a], model.body_start[a + 1])
        ib = np.arange(model.body_start[b], model.body_start[b + 1])
        pa = x[a] + model.offsets[ia] @ rot[a].reshape(3, 3).T
        pb = x[b] + model.offsets[ib] @ rot[b].reshape(3, 3).T
        ri, rj = model.radius[ia][:, None], model.radius[ib][None, :]
        within = wide[a] + wide[b] + ri + rj
        squared = ((pa[:, None, :] - pb[None, :, :]) ** 2).sum(axis=2)
        margins.append((squared / within**2 - 1.0).ravel())
        for i, j in zip(*np.nonzero(squared < within**2), strict=True):
            rows.append((a, ia[i], b, ib[j]))
    return np.array(rows, dtype=np.int64).reshape(-1, 4), np.concatenate(margins)


@pytest.mark.parametrize("scene", [crowd(), _lattice_crowd()], ids=["boxes", "boxes_and_lattices"])
def test_particle_candidates_are_every_particle_pairs(scene):
    """The particle candidates, found only among particles that can reach the other body
    (`candidates._can_reach`), are those of every particle pair tested, in order: from few
    pairs to many (dt 0.005 to 0.1). Pairs within 1e-12 of the bound, where numpy's
    rounding may differ from the compiled test's, would not compare: there are none."""
    model, state = model_and_state(scene)
    nb = len(model.body_mass)
    for dt in (0.005, 0.05, 0.1):
        buf = contact_buffers(nb, 16, nb * nb, largest_body(model))
        margin = candidate_margin(dt)
        nc = len(buf.cands) + 1
        while nc > len(buf.cands):  # grown to the count asked for, as `run_rigid` does
            buf = grown(buf, nc, nb * nb)
            frames_into(model, state.q, state.L, buf.rot, buf.inv, buf.omega)
            nc = find_candidates_into(model, state.x, state.v, dt, (0.0, 0.0, 0.0), margin, buf)
        assert nc > 0
        found = buf.cands[:nc][buf.cands[:nc, 2] >= 0]
        pairs = all_pairs(model, state.x, buf.wide)
        every, margins = _every_particle_pair(model, state.x, buf.rot, buf.wide, pairs)
        assert np.abs(margins).min() > 1e-12
        assert len(every) > 0
        np.testing.assert_array_equal(found, every)


def test_a_spread_out_grid_is_coarsened_to_its_cell_budget():
    """Half the crowd moved 100 m away: cells as wide as the interaction distance would number
    far more than GRID_CELLS_PER_BODY a body; the grid keeps to that budget and still finds
    the pairwise pairs (those of the half left in place)."""
    model, state = model_and_state(crowd())
    reach = _reach(model, state, 0.005)
    x = state.x.copy()
    x[::2, 0] += 100.0
    nb = len(x)
    cells, dims = np.zeros((nb, 3), dtype=np.int64), np.ones(3, dtype=np.int64)
    n_cells = _bin(model, x, reach, cells, dims, np.empty(nb, dtype=np.int64), 10**9)
    budget = GRID_CELLS_PER_BODY * nb
    assert n_cells > budget
    assert 0 < _bin(model, x, reach, cells, dims, np.empty(nb, dtype=np.int64), budget) <= budget
    every = all_pairs(model, x, reach)
    assert len(every) > 0
    np.testing.assert_array_equal(grid_pairs(model, x, reach), every)


def test_grid_matches_pairwise_on_far_flung_and_nan_bodies():
    """A body 1e9 m away coarsens the grid to a few cells; a NaN centre or reach leaves no grid
    (every pair tested): the pairs are the pairwise ones either way."""
    model, state = model_and_state(crowd())
    reach = _reach(model, state, 0.005)
    far = state.x.copy()
    far[0] = (1e9, 0.0, 0.0)
    np.testing.assert_array_equal(grid_pairs(model, far, reach), all_pairs(model, far, reach))
    broken = state.x.copy()
    broken[3] = np.nan
    np.testing.assert_array_equal(grid_pairs(model, broken, reach), all_pairs(model, broken, reach))
    # a NaN reach (a diverged body's speed) pairs its body with every other, as pair by pair
    broken_reach = reach.copy()
    broken_reach[3] = np.nan
    every = all_pairs(model, state.x, broken_reach)
    assert np.sum((every == 3).any(axis=1)) == len(reach) - 1
    np.testing.assert_array_equal(grid_pairs(model, state.x, broken_reach), every)


@pytest.mark.parametrize("integrator", ["euler", "splitting"])
def test_pair_list_gives_the_grids_pairs_at_every_step(integrator):
    """The crowd stepped with body pairs from a `PairList`: every step's pairs are the grid's
    at that step's reach, in order, while the list is both kept for some steps and found again
    for others (both paths run)."""
    scene = crowd()
    model, state = model_and_state(scene)
    nb = len(model.body_mass)
    threshold = BOUNCE_STEPS * 10.0 * scene.dt
    code = INTEGRATOR_CODES[integrator]
    x, q, v, L = (a.copy() for a in state)
    buf = contact_buffers(nb, 64 * nb, nb * nb, largest_body(model))
    found, kept, listed = pair_list(nb), 0, 0
    for _ in range(100):
        frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
        kick = tuple(scene.dt * model.gravity) if integrator == "euler" else (0.0,) * 3
        reach = np.empty(nb)
        reach_into(model, v, buf.omega, scene.dt, kick, reach)
        reach += candidate_margin(scene.dt)  # as `rigid_step` widens it
        last = found
        found, n = current_pairs(model.bound_radius, x, reach, last, buf.pairs)
        kept += found.x0 is last.x0
        listed += n
        np.testing.assert_array_equal(buf.pairs[:n], grid_pairs(model, x, reach))
        buf.counts[COUNT_PAIRS] = n
        assert rigid_step(model, code, x, q, v, L, scene.dt, threshold, buf) == 0
    assert listed > 0 and 0 < kept < 99


def test_pair_list_is_found_again_for_nan_bodies():
    """A NaN centre or reach fits no list: it is found again (every pair, as the grid's)."""
    model, state = model_and_state(crowd())
    reach = _reach(model, state, 0.005)
    nb = len(model.body_mass)
    out = np.empty((nb * nb, 2), dtype=np.int64)
    found, _ = current_pairs(model.bound_radius, state.x, reach, pair_list(nb), out)
    assert current_pairs(model.bound_radius, state.x, reach, found, out)[0].x0 is found.x0
    nan_x, nan_reach = state.x.copy(), reach.copy()
    nan_x[3, 0], nan_reach[3] = np.nan, np.nan
    for broken_x, broken_reach in ((nan_x, reach), (state.x, nan_reach)):
        again, n = current_pairs(model.bound_radius, broken_x, broken_reach, found, out)
        assert again.x0 is not found.x0
        np.testing.assert_array_equal(out[:n], grid_pairs(model, broken_x, broken_reach))


@pytest.mark.parametrize("integrator", ["euler", "splitting"])
def test_grid_and_pairwise_steps_are_bit_equal(integrator):
    scene = crowd()
    model, state = model_and_state(scene)
    nb = len(model.body_mass)
    assert nb >= GRID_MIN_BODIES
    threshold = BOUNCE_STEPS * 10.0 * scene.dt
    code = INTEGRATOR_CODES[integrator]
    results = []
    for use_grid in (True, False):
        x, q, v, L = (a.copy() for a in state)
        buf = contact_buffers(nb, 64 * nb, nb * nb, largest_body(model))
        touched = 0
        for _ in range(100):
            if use_grid:
                frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
                kick = tuple(scene.dt * model.gravity) if integrator == "euler" else (0.0,) * 3
                reach = np.empty(nb)
                reach_into(model, v, buf.omega, scene.dt, kick, reach)
                reach += candidate_margin(scene.dt)  # as `rigid_step` widens it
                pairs = grid_pairs(model, x, reach)
                buf.pairs[: len(pairs)] = pairs
                buf.counts[COUNT_PAIRS] = len(pairs)
                touched += len(pairs)
            assert rigid_step(model, code, x, q, v, L, scene.dt, threshold, buf) == 0
        results.append((x, q, v, L))
        if use_grid:
            assert touched > 0  # bodies did come close
    for fast, plain in zip(*results, strict=True):
        np.testing.assert_array_equal(fast, plain)


@pytest.mark.parametrize("dt", [0.001, 0.05], ids=["fits", "outgrows"])
def test_body_pairs_come_with_this_poses_frames(dt):
    """`rigid_step` takes the frames (rotations, world inverse inertias, omega) from the
    caller that found the body pairs (`_body_pairs`). Its buffers start with room for 4 N + 16
    pairs: at dt 0.05 the crowd has more, the buffers are grown, and the new ones must hold
    the frames too."""
    model, state = model_and_state(crowd())
    nb = len(model.body_mass)
    buf = contact_buffers(nb, 8 * nb + 16, 4 * nb + 16, largest_body(model))  # as `run_rigid`'s
    fresh = contact_buffers(nb, 1, 1, largest_body(model))
    frames_into(model, state.q, state.L, fresh.rot, fresh.inv, fresh.omega)
    code = INTEGRATOR_CODES["euler"]
    got, _ = _body_pairs(model, code, *state, dt, buf, pair_list(nb))
    assert (len(got.pairs) > len(buf.pairs)) == (dt == 0.05)  # grown
    for field in ("rot", "inv", "omega"):
        np.testing.assert_array_equal(getattr(got, field), getattr(fresh, field))
