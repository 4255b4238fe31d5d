"""Scenes shared by several test files (not catalog cases: they exist to check one thing)."""

import math

import numpy as np

from cases import Body, Contact, Scene
from cases.builders import seed_cube_particles
from comparators.reference import model_from_scene
from reference_sim.model import rigid_initial_state
from rigidmath.quaternion import quat_to_matrix


def initial_state(model, scene: Scene):
    """The reference simulator's rigid state (x, q, v, L) of `scene`'s bodies at t = 0."""
    return rigid_initial_state(
        model,
        [b.com for b in scene.bodies],
        [b.velocity for b in scene.bodies],
        [b.angular_velocity for b in scene.bodies],
    )


def model_and_state(scene: Scene):
    """The reference simulator's model of `scene` and its rigid state at t = 0."""
    model = model_from_scene(scene)
    return model, initial_state(model, scene)


def head_on(restitution: float, contact: bool = True) -> Scene:
    """Two seed cubes, faces aligned, approaching along x at 1 m/s each; no gravity.

    Equal masses in a central impact: afterwards they move at -e and +e m/s.
    """
    return Scene(
        name="head_on",
        duration=1.0,
        dt=0.01,
        gravity=(0.0, 0.0, 0.0),
        contact=Contact(restitution=restitution, friction=0.0) if contact else None,
        bodies=(
            Body(
                name="a", particle_radius=0.2, particles=seed_cube_particles(), velocity=(1.0, 0, 0)
            ),
            Body(
                name="b",
                particle_radius=0.2,
                particles=seed_cube_particles(offset=(1.5, 0.0, 0.0)),
                velocity=(-1.0, 0, 0),
            ),
        ),
    )


def rotated(rows, rotvec) -> tuple:
    """Particle rows (x, y, z, m) rotated about the origin by the rotation vector `rotvec`."""
    angle = np.linalg.norm(rotvec)
    q = np.concatenate([[math.cos(angle / 2)], np.sin(angle / 2) * np.asarray(rotvec) / angle])
    r = quat_to_matrix(q)
    return tuple((*(r @ np.asarray(p[:3])).tolist(), p[3]) for p in rows)


# An asymmetric tilted cluster of unequal masses: a full, non-diagonal inertia tensor, so that a
# frame mix-up in an adapter (body- against world-frame omega, principal axes) shows.
TILTED_CLUSTER = Body(
    name="cluster",
    particle_radius=0.1,
    particles=rotated(
        ((0.0, 0.0, 0.0, 1.0), (1.0, 0.2, 0.0, 2.0), (0.1, 1.5, 0.3, 0.5), (0.4, 0.3, 2.0, 1.5)),
        (-0.4, 0.9, 0.2),
    ),
    velocity=(0.3, -0.2, 0.1),
    angular_velocity=(1.0, -2.0, 0.5),
)
