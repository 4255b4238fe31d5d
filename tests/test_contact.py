"""Contact between bodies: closed-form outcomes of a head-on impact; no self-contact; contact
frames; the Gauss-Seidel solve ends on targets no rigid motion meets; contacts the solve swings a
body into are found; no subnormal remainders. (The solve's subspace steps: test_subspace.py; its
stopping rules and speed-ups: test_gauss_seidel.py.)"""

import dataclasses

import numpy as np
import pytest
from scenes import head_on, model_and_state

from cases import CATALOG, Body, Contact, Plane, Scene
from cases.builders import box_corners, floor
from cases.exact import exact_states
from comparators import run
from comparators.metrics import body_arrays, conserved_quantities, pose_errors
from comparators.reference import model_from_scene
from reference_sim.contact import buffers, candidates, frames, gauss_seidel, settings
from reference_sim.contact.buffers import COUNT_PRE_WARM, STAT_REFOUND, largest_body
from reference_sim.contact.frames import flush_subnormal
from reference_sim.contact.impulses import row_speed
from reference_sim.contact.rows import assemble
from reference_sim.quaternion import qmatrix
from reference_sim.rigid import INTEGRATOR_CODES, rigid_step

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


# A frame of three unit vectors built in float64: orthonormal to a few ulps.
FRAME_ATOL = 1e-15


def test_plane_contacts_frames_are_orthonormal_and_right_handed():
    """Each plane's fixed contact frame (normal, `Model.plane_tangents`) in every catalog scene,
    floors, box walls and the inclines' tilted planes: orthonormal, with t1 x t2 = n."""
    planes = 0
    for scene in CATALOG.values():
        model = model_from_scene(scene)
        for n, (t1, t2) in zip(model.plane_normals, model.plane_tangents, strict=True):
            frame = np.array([n, t1, t2])
            np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=FRAME_ATOL)
            np.testing.assert_allclose(np.cross(t1, t2), n, atol=FRAME_ATOL)
            planes += 1
    assert planes > 0


def test_gauss_seidel_ends_on_targets_no_rigid_motion_meets():
    """The four corners of a resting cube's face asked for normal speeds 0, 0, 0 and 1e-5 m/s: a
    rigid face's corner speeds satisfy v0 + v3 = v1 + v2, so these disagree by 1e-5 m/s. Once
    the velocities stop changing the impulses only push the corners against each other, and
    would until one reached 0, at a rate proportional to the disagreement: with this one, after
    more than MAX_ITERATIONS sweeps. The solve must end when the velocities stop, every corner
    within the disagreement of its target, and one more sweep must leave them as they are."""
    scene = CATALOG["resting_cube"]
    model, (x, q, v, L) = model_and_state(scene)
    buf = buffers.contact_buffers(1, 16, 4, largest_body(model))
    frames.frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    margin = settings.candidate_margin(scene.dt)
    nc = candidates.find_candidates_into(model, x, v, scene.dt, (0.0, 0.0, 0.0), margin, buf)
    assert nc == 4  # the bottom face's corners
    buf.acting[:nc] = True
    assemble(model, x, nc, settings.TOUCH_TOLERANCE, buf, 0)
    disagreement = 1e-5
    buf.target[:nc] = (0.0, 0.0, 0.0, disagreement)
    v += scene.dt * model.gravity
    tolerance = settings.VELOCITY_TOLERANCE
    sweeps, converged = gauss_seidel.iterate(
        model, x, nc, scene.dt, buf, v, tolerance, settings.IDLE_MARGIN
    )
    assert converged and sweeps < settings.MAX_ITERATIONS
    for k in range(nc):
        speed = row_speed(buf.jac[k, 0], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
        assert speed > buf.target[k] - disagreement
    before = np.concatenate([v.ravel(), buf.omega.ravel()])
    one_sweep = np.inf
    gauss_seidel.iterate(model, x, nc, scene.dt, buf, v, one_sweep, settings.IDLE_MARGIN)
    after = np.concatenate([v.ravel(), buf.omega.ravel()])
    # |dv| + bound radius |d omega|, as the stopping test measures it
    assert np.abs(after - before).max() * (1.0 + model.bound_radius[0]) < tolerance


def _one_stopping_step(name, dt, planes, bodies) -> Scene:
    """A scene of one step of dt without gravity whose contacts only stop (e = 0, mu = 0)."""
    return Scene(
        name=name,
        duration=dt,
        dt=dt,
        gravity=(0.0, 0.0, 0.0),
        contact=Contact(restitution=0.0, friction=0.0),
        planes=planes,
        bodies=bodies,
    )


def test_a_contact_on_standby_wakes_when_the_solve_swings_its_body_into_it():
    """A rod falling flat at 5 m/s, its near end touching the floor, its far end 6 cm up, its
    mass mostly at its middle: at the step's velocities the far end moves 5 cm, so its
    contacts start on standby, but stopping the near end pivots the rod and swings the far end
    down at about 7.8 m/s. The solve must wake them: they push, and the step ends with the far
    end on the floor (to the drift's second order in the rotation), not 1.8 cm into it."""
    radius, lift, dt = 0.05, 0.06, 0.01
    rows = [
        (x, y, radius + z + (lift if x > 0 else 0.0), 1.0)
        for x in (-1.0, 1.0)
        for y in (-0.1, 0.1)
        for z in (0.0, 0.2)
    ]
    rows += [(0.0, y, radius + 0.2 + lift / 2, 10.0) for y in (-0.1, 0.1)]  # out of reach
    rod = Body(name="rod", particle_radius=radius, particles=rows, velocity=(0.0, 0.0, -5.0))
    scene = _one_stopping_step("swung_rod", dt, (floor(0.0),), (rod,))
    model, (x, q, v, L) = model_and_state(scene)
    buf = buffers.contact_buffers(1, 16, 4, largest_body(model))
    frames.frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    frames.reach_into(model, v, buf.omega, dt, (0.0, 0.0, 0.0), buf.reach)
    assert buf.reach[0] < lift  # the far end is beyond the step's reach at its start
    assert rigid_step(model, INTEGRATOR_CODES["euler"], x, q, v, L, dt, 0.0, buf) == 0
    far = [i for i, row in enumerate(rows) if row[0] > 0 and row[2] == radius + lift]
    # the contacts that pushed before the drift, by key: particle i's is i
    n = buf.counts[COUNT_PRE_WARM]
    pushed = dict(zip(buf.pre_keys[:n].tolist(), buf.pre_lam[:n, 0, 0], strict=True))
    assert all(pushed.get(i, 0.0) > 0.0 for i in far)
    rotation = np.reshape(qmatrix(tuple(q[0])), (3, 3))
    gaps = (x[0] + model.offsets @ rotation.T)[:, 2] - radius
    omega = np.linalg.norm(frames.world_omega(model, tuple(q[0]), tuple(L[0]), 0))
    overshoot = model.bound_radius[0] * (omega * dt) ** 2 / 2  # the drift's second order
    assert gaps[far].min() > -overshoot
    assert overshoot < 0.1 * (7.8 - lift / dt) * dt  # a tenth of a missed contact's 1.8 cm


def test_a_body_the_solve_speeds_beyond_its_candidates_reach_is_found_again():
    """Cube a rests 7.5 cm from a wall; cube b, touching it, strikes it at 20 m/s (no gravity,
    e = 0). a's candidates are found within its reach at rest (0) widened by
    `candidate_margin` (5 cm at dt 0.01): the wall's contacts are not among them. The solve
    sends a on at 10 m/s, 10 cm in the step: the step must be found again with the wall's
    contacts (STAT_REFOUND) and end with a on the wall and b on a, not 2.5 cm into them."""
    dt, radius, edge, gap, speed = 0.01, 0.1, 0.5, 0.075, 20.0
    assert settings.candidate_margin(dt) < gap < speed / 2 * dt
    wall = edge / 2 + radius + gap  # a's right face at x = edge / 2
    struck = Body(name="a", particle_radius=radius, particles=box_corners((edge,) * 3))
    striking = Body(
        name="b",
        particle_radius=radius,
        particles=box_corners((edge,) * 3, center=(-edge - 2 * radius, 0.0, 0.0)),
        velocity=(speed, 0.0, 0.0),
    )
    wall_plane = Plane(point=(wall, 0.0, 0.0), normal=(-1.0, 0.0, 0.0))
    scene = _one_stopping_step("struck_into_a_wall", dt, (wall_plane,), (struck, striking))
    model, (x, q, v, L) = model_and_state(scene)
    buf = buffers.contact_buffers(2, 64, 4, largest_body(model))
    assert rigid_step(model, INTEGRATOR_CODES["euler"], x, q, v, L, dt, 0.0, buf) == 0
    assert buf.solver[STAT_REFOUND] == 1
    particles = [
        x[k] + model.offsets[model.body_start[k] : model.body_start[k + 1]] for k in (0, 1)
    ]
    # the cubes only translate along x: gaps exact to the rounding of the coordinates
    rounding = 1e-12
    assert (wall - particles[0][:, 0] - radius).min() > -rounding
    assert particles[0][:, 0].min() - particles[1][:, 0].max() - 2 * radius > -rounding


def test_a_solve_leaves_no_subnormal_remainder():
    """`flush_subnormal` zeroes what lies below the smallest normal double (a box at rest kept
    its angular momentum at 1e-320 for the rest of a run, slowing every step) and keeps the
    rest to the bit, however small, with its sign."""
    normal_min = np.finfo(np.float64).tiny
    v = np.array([[5e-324, -1e-300, -3e-310], [normal_min, 0.0, 2.0]])
    L = np.array([[-1e-320, -normal_min, 1e-200], [-0.0, 1e-308, 3.0]])
    flush_subnormal(v, L)
    np.testing.assert_array_equal(v, [[0.0, -1e-300, 0.0], [normal_min, 0.0, 2.0]])
    np.testing.assert_array_equal(L, [[0.0, -normal_min, 1e-200], [0.0, 0.0, 3.0]])
