"""The built-in catalog: scenes registered by name with tags (dm_control's TaggedTasks idea).

Tests and reports parametrize over `CATALOG`, so adding a case adds its tests.
"""

from collections.abc import Callable

from cases import builders
from cases.scene import Body, Contact, Expected, Scene

CATALOG: dict[str, Scene] = {}

GRAVITY = (0.0, 0.0, -10.0)  # the seed's value
NO_GRAVITY = (0.0, 0.0, 0.0)


def register(build: Callable[[], Scene]) -> Callable[[], Scene]:
    scene = build()
    if scene.name in CATALOG:
        raise ValueError(f"case {scene.name!r} registered twice")
    CATALOG[scene.name] = scene
    return build


@register
def seed_cube() -> Scene:
    return Scene(
        name="seed_cube",
        description="The blog's scene: a unit cube of 8 particles thrown spinning into a 10 m box.",
        tags=("seed", "contact", "gravity"),
        duration=100.0,
        dt=0.01,
        sample_interval=0.1,
        gravity=GRAVITY,
        contact=Contact(restitution=0.0, friction=0.0),
        planes=builders.box_walls(),
        bodies=(
            Body(
                name="cube",
                particle_radius=0.2,
                particles=builders.seed_cube(offset=(3.0, 3.0, 7.0)),
                velocity=(0.0, 0.0, -2.0),
                angular_velocity=(2.0, 0.0, 0.0),
            ),
        ),
    )


@register
def free_spin_cube() -> Scene:
    return Scene(
        name="free_spin_cube",
        description="The seed's cube spinning freely about x: isotropic inertia, exact rotation.",
        tags=("free", "exact"),
        duration=10.0,
        dt=0.01,
        sample_interval=0.1,
        gravity=NO_GRAVITY,
        bodies=(
            Body(
                name="cube",
                particle_radius=0.2,
                particles=builders.seed_cube(offset=(3.0, 3.0, 7.0)),
                angular_velocity=(2.0, 0.0, 0.0),
            ),
        ),
    )


@register
def tumbling_box() -> Scene:
    return Scene(
        name="tumbling_box",
        description="A 1 x 2 x 3 box spun near its intermediate axis: the Dzhanibekov flip.",
        tags=("free", "exact", "tumbling"),
        duration=10.0,
        dt=0.01,
        sample_interval=0.1,
        gravity=NO_GRAVITY,
        bodies=(
            Body(
                name="box",
                particle_radius=0.2,
                particles=builders.box_corners((1.0, 2.0, 3.0)),
                angular_velocity=(0.1, 3.0, 0.1),
            ),
        ),
    )


@register
def dropped_cube() -> Scene:
    return Scene(
        name="dropped_cube",
        description="The seed's cube dropped spinning onto a floor; it must rest on a face.",
        tags=("contact", "gravity", "rest"),
        duration=5.0,
        dt=0.01,
        sample_interval=0.01,
        gravity=GRAVITY,
        contact=Contact(restitution=0.0, friction=0.5),
        planes=(builders.floor(0.0),),
        bodies=(
            Body(
                name="cube",
                particle_radius=0.2,
                particles=builders.seed_cube(offset=(-0.5, -0.5, 2.0)),
                velocity=(0.0, 0.0, -2.0),
                angular_velocity=(2.0, 0.0, 0.0),
            ),
        ),
        # Half the cube's edge (0.5 m) plus the particle radius (0.2 m).
        expected=Expected(rest_com_height=0.7),
    )
