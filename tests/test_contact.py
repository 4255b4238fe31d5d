"""Contact between bodies: closed-form outcomes of a head-on impact; no self-contact; the
Gauss-Seidel solve ends on targets no rigid motion meets."""

import dataclasses

import numpy as np
import pytest
from scenes import head_on

from cases import CATALOG, Body, Contact, Scene
from cases.builders import box_corners, floor
from cases.exact import exact_states
from comparators import run
from comparators.metrics import body_arrays, conserved_quantities, pose_errors
from comparators.reference import model_from_scene
from reference_sim import contact
from reference_sim.model import rigid_initial_state

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


def test_gauss_seidel_ends_on_targets_no_rigid_motion_meets():
    """The four corners of a resting cube's face asked for normal speeds 0, 0, 0 and 1e-5 m/s: a
    rigid face's corner speeds satisfy v0 + v3 = v1 + v2, so these disagree by 1e-5 m/s. Once
    the velocities stop changing the impulses only push the corners against each other, and
    would until one reached 0, at a rate proportional to the disagreement: with this one, after
    more than MAX_ITERATIONS sweeps. The solve must end when the velocities stop, every corner
    within the disagreement of its target, and one more sweep must leave them as they are."""
    scene = CATALOG["resting_cube"]
    model = model_from_scene(scene)
    body = scene.bodies[0]
    x, q, v, L = rigid_initial_state(model, [body.com], [body.velocity], [body.angular_velocity])
    buf = contact.contact_buffers(1, 16, 4)
    contact.frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    nc = contact.find_candidates_into(model, x, v, scene.dt, (0.0, 0.0, 0.0), buf)
    assert nc == 4  # the bottom face's corners
    buf.acting[:nc] = True
    contact._assemble(model, x, nc, contact.TOUCH_TOLERANCE, buf)
    disagreement = 1e-5
    buf.target[:nc] = (0.0, 0.0, 0.0, disagreement)
    v += scene.dt * model.gravity
    tolerance = contact.VELOCITY_TOLERANCE
    sweeps = contact._iterate(model, nc, buf, v, L, tolerance)
    assert sweeps < contact.MAX_ITERATIONS
    for k in range(nc):
        speed = contact._speed(buf.jac[k, 0], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
        assert speed > buf.target[k] - disagreement
    before = np.concatenate([v.ravel(), buf.omega.ravel()])
    contact._iterate(model, nc, buf, v, L, np.inf)  # one sweep
    after = np.concatenate([v.ravel(), buf.omega.ravel()])
    # |dv| + bound radius |d omega|, as the stopping test measures it
    assert np.abs(after - before).max() * (1.0 + model.bound_radius[0]) < tolerance
