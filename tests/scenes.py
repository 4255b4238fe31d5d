"""Scenes shared by several test files (not catalog cases: they exist to check one thing)."""

from cases import Body, Contact, Scene
from cases.builders import seed_cube_particles
from reference_sim.model import rigid_initial_state


def initial_state(model, scene: Scene):
    """The reference simulator's rigid state (x, q, v, L) of `scene`'s bodies at t = 0."""
    return rigid_initial_state(
        model,
        [b.com for b in scene.bodies],
        [b.velocity for b in scene.bodies],
        [b.angular_velocity for b in scene.bodies],
    )


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
