"""The `seed` integrator is the blog's algorithm: checked against a literal transliteration."""

import dataclasses

import numpy as np
import pytest
from blog_seed import blog_seed_cube_world, blog_step, blog_step_count

from cases import CATALOG
from comparators import run
from comparators.engine import get_engine
from comparators.reference import model_from_scene
from comparators.verdict import verdict
from reference_sim.model import seed_initial_state
from reference_sim.seed import seed_step

# The compiled seed and the pure-Python transliteration do the same float64 operations in
# nearly the same order (numpy vs. sequential dot products): they may differ by a few ulps per
# step, and the seed's wall clamps re-synchronise them. 1e-12 m is 1e4 ulps of a 10 m box.
SEED_MATCH = 1e-12
# Per-step growth of a particle's distance from the rotation axis: exact up to rounding.
INFLATION_RTOL = 1e-12


def _seed_model(scene):
    body = scene.bodies[0]
    model = model_from_scene(scene)
    state = seed_initial_state(model, body.positions, [body.velocity], [body.angular_velocity])
    return model, [a.copy() for a in state]


@pytest.fixture(scope="module")
def seed_cube_runs():
    """Compiled seed and blog transliteration side by side on seed_cube, sampled every 500 steps."""
    scene = CATALOG["seed_cube"]
    model, (pos, vel, cm, V, omega) = _seed_model(scene)
    world = blog_seed_cube_world()
    n_steps = blog_step_count(scene.duration, scene.dt)
    worst = []
    for n in range(1, n_steps + 1):
        seed_step(model, pos, vel, cm, V, omega, scene.dt)
        blog_step(world, dt=scene.dt)
        if n % 500 == 0 or n == n_steps:
            worst.append((n, np.abs(world.positions - pos).max()))
    return worst, pos, world


def test_seed_matches_blog_transliteration(seed_cube_runs):
    worst, _, _ = seed_cube_runs
    for step, err in worst:
        assert err < SEED_MATCH, (
            f"seed_cube: particle positions differ by {err:.3g} m at step {step}"
        )


def test_seed_cube_ends_flattened_on_the_floor(seed_cube_runs):
    _, pos, world = seed_cube_runs
    radius = CATALOG["seed_cube"].bodies[0].particle_radius
    np.testing.assert_allclose(pos[:, 2], radius, rtol=0, atol=SEED_MATCH)
    np.testing.assert_allclose(world.positions[:, 2], radius, rtol=0, atol=SEED_MATCH)
    spread = np.ptp(pos[:, :2], axis=0)
    assert spread.min() > 0.5, f"flattened cube should still spread in x and y, got {spread}"


def test_free_spin_inflates_by_the_blog_factor():
    """Each step scales a particle's distance from the spin axis by sqrt(1 + |w|^2 dt^2)."""
    scene = CATALOG["free_spin_cube"]
    model, (pos, vel, cm, V, omega) = _seed_model(scene)
    axis = omega[0] / np.linalg.norm(omega[0])
    factor = np.sqrt(1 + np.dot(omega[0], omega[0]) * scene.dt**2)

    def radial(p):
        r = p - cm[0]
        return np.linalg.norm(r - np.outer(r @ axis, axis), axis=1)

    for step in range(1, 51):
        before = radial(pos)
        seed_step(model, pos, vel, cm, V, omega, scene.dt)
        np.testing.assert_allclose(
            radial(pos), before * factor, rtol=INFLATION_RTOL, err_msg=f"step {step}"
        )


def test_seed_trajectory_reports_its_deformation():
    """The table's shape_error grows as the seed inflates; rigid integrators have none."""
    scene = CATALOG["free_spin_cube"]
    traj = run(scene, "reference", "seed")
    shape = traj.table["shape_error"].to_numpy()
    assert shape[0] == 0.0
    assert np.all(np.diff(shape) > 0), "free spin must inflate the seed's cube monotonically"
    # radial distance grows by factor**n; the cube's edges along x do not stretch
    n = traj.meta.steps
    expected = (1 + (2.0 * scene.dt) ** 2) ** (n / 2) - 1
    np.testing.assert_allclose(shape[-1], expected, rtol=1e-9)
    assert "shape_error" not in run(scene, "reference", "splitting").table
    assert "seed" in get_engine("reference").integrators


def spun_rod(speed: float):
    """thin_rod spun at `speed` rad/s about its catalog axis, sampled every step."""
    scene = CATALOG["thin_rod"]
    body = scene.bodies[0]
    w = np.asarray(body.angular_velocity) * speed / np.linalg.norm(body.angular_velocity)
    spun = dataclasses.replace(body, angular_velocity=tuple(float(x) for x in w))
    return dataclasses.replace(scene, bodies=(spun,), sample_interval=None)


def test_a_singular_inertia_ends_the_step():
    """Particles collapsed onto a line have no inertia about it: the step reports the failure
    instead of raising numpy's LinAlgError, and a sound step still succeeds."""
    model, (pos, vel, cm, V, omega) = _seed_model(CATALOG["thin_rod"])
    assert seed_step(model, pos, vel, cm, V, omega, 0.01)
    pos[:] = cm[0] + np.outer(np.linspace(-2.0, 2.0, len(pos)), [0.0, 0.0, 1.0])
    assert not seed_step(model, pos, vel, cm, V, omega, 0.01)


def test_a_rod_spun_to_overflow_is_diverged():
    """At 1e4 rad/s the seed's inflation overflows within 80 steps of 0.01 s (it raised a
    LinAlgError): the run ends, its later samples NaN at their times, and the verdict is
    diverged."""
    scene = spun_rod(1e4)
    traj = run(scene, "reference", "seed", duration=1.0)
    states = traj.state_by_body[scene.bodies[0].name]
    finite = np.isfinite(states).all(axis=1)
    assert len(states) == 101 and finite[0] and not finite[-1]
    np.testing.assert_allclose(traj.table["t"], np.arange(101) * scene.dt, rtol=1e-12)
    assert verdict(traj, scene) == "diverged"
