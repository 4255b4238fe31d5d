"""Contact between bodies: closed-form outcomes of a head-on impact; no self-contact."""

import dataclasses

import numpy as np
import pytest
from scenes import head_on

from cases import Body, Contact, Scene
from cases.builders import box_corners, floor
from cases.exact import exact_states
from comparators import run
from comparators.metrics import body_arrays, conserved_quantities, pose_errors

# Gauss-Seidel impulses stop when no impulse changes a speed by more than 1e-13 m/s; a few
# sweeps of that leave the outcome exact to well below this.
IMPULSE_ATOL = 1e-9


@pytest.mark.parametrize("integrator", ["euler", "splitting", "rk4"])
@pytest.mark.parametrize(
    ("restitution", "after"), [(1.0, (-1.0, 1.0)), (0.0, (0.0, 0.0)), (0.5, (-0.5, 0.5))]
)
def test_head_on_impact(integrator, restitution, after):
    """Equal masses, central impact: velocities after are -e and +e times the approach speed."""
    scene = head_on(restitution)
    traj = run(scene, "reference", integrator)
    for name, vx in zip(("a", "b"), after, strict=True):
        a = body_arrays(traj, name)
        np.testing.assert_allclose(a["v"][-1], (vx, 0, 0), atol=IMPULSE_ATOL, err_msg=name)
        np.testing.assert_allclose(a["w"][-1], 0.0, atol=IMPULSE_ATOL, err_msg=name)
    c = conserved_quantities(traj, scene)
    np.testing.assert_allclose(c[["px", "py", "pz"]].to_numpy(), 0.0, atol=1e-12)


def test_particles_of_one_body_never_collide():
    """Overlapping particles of one body, contact on, floor far away: still exact free flight."""
    scene = Scene(
        name="fat_particles",
        duration=5.0,
        dt=0.001,
        sample_interval=0.1,
        gravity=(0.0, 0.0, 0.0),
        contact=Contact(restitution=0.5, friction=0.5),
        planes=(floor(-100.0),),
        bodies=(
            Body(
                name="box",
                particle_radius=0.8,  # neighbours 1 m apart overlap by 0.6 m
                particles=box_corners((1.0, 2.0, 3.0)),
                angular_velocity=(0.3, 0.2, 3.0),
            ),
        ),
    )
    traj = run(scene, "reference", "rk4")
    times = body_arrays(traj, "box")["t"]
    free = dataclasses.replace(scene, contact=None, planes=())
    errors = pose_errors(traj, exact_states(free, times), scene)
    assert errors["orientation_error_deg"].max() < 1e-6
