"""The built-in catalog: scenes registered by name with tags (dm_control's TaggedTasks idea).

Tests and reports parametrize over `CATALOG`, so adding a case adds its tests.
"""

import dataclasses
import math
from collections.abc import Callable
from functools import partial

import numpy as np

from cases import builders
from cases.scene import Body, Contact, Expected, Scene
from reference_sim.inertia import principal_frame

CATALOG: dict[str, Scene] = {}

GRAVITY = (0.0, 0.0, -10.0)  # the seed's value
NO_GRAVITY = (0.0, 0.0, 0.0)
G = 10.0  # m/s^2, |GRAVITY|: the closed forms below use it
RADIUS = 0.2  # m, the seed's particle radius
CUBE_REST_HEIGHT = 0.5 + RADIUS  # m, COM of the seed's unit cube resting on a face


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


# ---------------------------------------------------------------------------------------------
# Hard cases. "stability": long runs, stiff or fast motion and contact that strains an engine;
# "contact-closed-form": contact outcomes with a closed-form answer stated in `Expected`.

STICKY = Contact(restitution=0.0, friction=0.5)  # the seed's floor contact: no bounce, Coulomb 0.5
APEX_MIN_HEIGHT = 1e-3  # m: lower apexes are within the engines' mm-scale contact penetration
APEX_COUNT = 3  # bounces whose apex `bounce` predicts
BOUNCE_MIN_DURATION = 3.0  # s
REST_MARGIN = 1.0  # s of settling after the closed-form time to rest (the rest window is 0.5 s)


def _cube(rows, velocity=(0.0, 0.0, 0.0), name: str = "cube") -> Body:
    """A body of the seed's particles (radius 0.2) without spin."""
    return Body(name=name, particle_radius=RADIUS, particles=rows, velocity=velocity)


def _principal_ratio(body: Body) -> float:
    """Largest over smallest principal moment."""
    moments, _ = principal_frame(body.inertia)
    return float(moments[-1] / moments[0])


def _free_tumbler(name: str, what: str, rows, omega) -> Scene:
    """A body tumbling off-axis in free space for 10 s; the description states its inertia ratio."""
    body = Body(name="body", particle_radius=RADIUS, particles=rows, angular_velocity=omega)
    return Scene(
        name=name,
        description=(
            f"{what} (principal inertia ratio {_principal_ratio(body):.4g}) tumbling off-axis: "
            "omega = I^-1 L amplifies any error about its smallest-inertia axis."
        ),
        tags=("hard", "stability", "free", "exact"),
        duration=10.0,
        dt=0.01,
        sample_interval=0.1,
        gravity=NO_GRAVITY,
        bodies=(body,),
    )


@register
def tumbling_box_long() -> Scene:
    return dataclasses.replace(
        tumbling_box(),
        name="tumbling_box_long",
        description="tumbling_box (the 1 x 2 x 3 box near its intermediate axis) over 100 s: "
        "long-run energy and flip-phase drift.",
        tags=("hard", "stability", "free", "exact", "tumbling"),
        duration=100.0,
        sample_interval=0.1,
    )


@register
def high_spin() -> Scene:
    dt, speed = 0.01, 50.0
    direction = np.array([1.0, 0.03, 0.02])  # mostly the largest-inertia (stable) axis, x
    omega = speed * direction / np.linalg.norm(direction)
    return Scene(
        name="high_spin",
        description=(
            f"The 1 x 2 x 3 box spun at |omega| = {speed:g} rad/s near its largest-inertia axis: "
            f"|omega| dt = {speed * dt:g} rad at the default dt, the dt sweep (2x to 1/16x) "
            f"covers {2 * speed * dt:g} to {speed * dt / 16:.2g} rad per step."
        ),
        tags=("hard", "stability", "free", "exact"),
        duration=10.0,
        dt=dt,
        sample_interval=0.01,  # the nutation period is about 0.18 s
        gravity=NO_GRAVITY,
        bodies=(
            Body(
                name="box",
                particle_radius=RADIUS,
                particles=builders.box_corners((1.0, 2.0, 3.0)),
                angular_velocity=tuple(float(w) for w in omega),
            ),
        ),
    )


@register
def thin_rod() -> Scene:
    return _free_tumbler(
        "thin_rod",
        "A 0.2 x 0.2 x 4 m rod of 8 particles",
        builders.box_corners((0.2, 0.2, 4.0)),
        (1.0, 0.6, 2.0),
    )


@register
def flat_plate() -> Scene:
    return _free_tumbler(
        "flat_plate",
        "A planar 2 x 11 particle plate, 0.1 x 4 m",
        builders.box_lattice((0.1, 4.0, 0.0), (2, 11, 1)),
        (0.8, 2.0, 1.2),
    )


@register
def resting_cube() -> Scene:
    return Scene(
        name="resting_cube",
        description="The seed's cube resting on a face, touching exactly, for 60 s: creep, jitter "
        "and steady penetration.",
        tags=("hard", "stability", "gravity", "contact", "rest"),
        duration=60.0,
        dt=0.01,
        sample_interval=0.01,
        gravity=GRAVITY,
        contact=STICKY,
        planes=(builders.floor(),),
        bodies=(_cube(builders.cube_above_floor()),),
        expected=Expected(rest_com_height=CUBE_REST_HEIGHT),
    )


@register
def fast_impact() -> Scene:
    return Scene(
        name="fast_impact",
        description="The seed's cube hitting the floor flat at 50 m/s from 0.5 m up: 0.5 m per "
        "step at dt 0.01, so contact can be missed or met deep.",
        tags=("hard", "stability", "gravity", "contact", "rest"),
        duration=2.0,
        dt=0.01,
        sample_interval=0.01,
        gravity=GRAVITY,
        contact=STICKY,
        planes=(builders.floor(),),
        bodies=(_cube(builders.cube_above_floor(gap=0.5), velocity=(0.0, 0.0, -50.0)),),
        expected=Expected(rest_com_height=CUBE_REST_HEIGHT),
    )


@register
def cube_stack() -> Scene:
    count, pitch = 5, 1.0 + 2 * RADIUS  # edge plus two radii: each cube touches the one below
    stack = builders.stacked(builders.cube_above_floor(), count, pitch)
    return Scene(
        name="cube_stack",
        description=f"{count} of the seed's cubes stacked on the floor, each touching the one "
        f"below (pitch {pitch:g} m), at rest for 10 s: the stack must hold.",
        tags=("hard", "stability", "gravity", "contact", "rest", "multibody"),
        duration=10.0,
        dt=0.01,
        sample_interval=0.01,
        gravity=GRAVITY,
        contact=STICKY,
        planes=(builders.floor(),),
        bodies=tuple(_cube(rows, name=f"cube{k}") for k, rows in enumerate(stack)),
    )


@register
def cube_collision() -> Scene:
    # The cubes are 8 particles each, not solids. An offset of 0.4 to 0.6 m along y alone misses:
    # every particle pair is then at least two radii (0.4 m) apart across the motion, and the
    # columns pass between each other. Below 0.4 m two columns hit symmetrically, above 0.6 m one
    # column; both stay in the x-y plane. 0.8 m along y and z brings a single corner pair within
    # 0.28 m across the motion: a glancing hit, normal at 45 degrees to x, off-centre on two axes,
    # so both cubes spin in 3D.
    offset = 0.8
    return Scene(
        name="cube_collision",
        description="Two cubes colliding corner on corner in free space, 2 m/s along x with "
        f"{offset:g} m offsets in y and z: the glancing hit spins both; momentum is conserved.",
        tags=("hard", "stability", "contact", "multibody"),
        duration=3.0,
        dt=0.01,
        sample_interval=0.01,
        gravity=NO_GRAVITY,
        contact=Contact(restitution=0.5, friction=0.3),
        bodies=(
            _cube(builders.box_corners((1.0, 1.0, 1.0)), name="target"),
            _cube(
                builders.box_corners((1.0, 1.0, 1.0), center=(-2.0, offset, offset)),
                velocity=(2.0, 0.0, 0.0),
                name="projectile",
            ),
        ),
    )


def bounce_apex_heights(h0: float, e: float, duration: float) -> tuple[float, ...]:
    """Clearances h0 e^(2k) at the apexes of the first APEX_COUNT bounces of a body dropped from
    rest with clearance h0, keeping those reached within `duration` and at least APEX_MIN_HEIGHT
    high. The k-th rebound leaves at e^k v0 (v0 = sqrt(2 g h0)) and peaks e^k v0 / g later."""
    v0 = math.sqrt(2 * G * h0)
    t, heights = v0 / G, []  # t: time of the next impact
    for k in range(1, APEX_COUNT + 1):
        rebound = e**k * v0
        height = h0 * e ** (2 * k)
        if t + rebound / G > duration or height < APEX_MIN_HEIGHT:
            break
        heights.append(height)
        t += 2 * rebound / G
    return tuple(heights)


def bounce(name: str, e: float) -> Scene:
    h0 = 1.0
    # The bounces take t0 (1 + e) / (1 - e) in all (t0 = sqrt(2 h0 / g), the fall): run past it.
    rest_time = math.sqrt(2 * h0 / G) * (1 + e) / (1 - e)
    duration = max(BOUNCE_MIN_DURATION, float(math.ceil(rest_time + REST_MARGIN)))
    return Scene(
        name=name,
        description=f"The seed's cube dropped flat from {h0:g} m onto a frictionless floor, "
        f"e = {e:g}: rebound speed ratio and apex heights h0 e^2k, then rest.",
        tags=("hard", "contact-closed-form", "gravity", "contact", "rest"),
        duration=duration,
        dt=0.001,
        sample_interval=0.001,
        gravity=GRAVITY,
        contact=Contact(restitution=e, friction=0.0),
        planes=(builders.floor(),),
        bodies=(_cube(builders.cube_above_floor(gap=h0)),),
        expected=Expected(
            rebound_ratio=e,
            apex_heights=bounce_apex_heights(h0, e, duration),
            rest_com_height=CUBE_REST_HEIGHT,
        ),
    )


register(partial(bounce, "bounce", 0.5))
register(partial(bounce, "bounce_e0.3", 0.3))
register(partial(bounce, "bounce_e0.8", 0.8))


@register
def slide() -> Scene:
    v0, mu = 3.0, 0.5
    return Scene(
        name="slide",
        description=f"The seed's cube launched along the floor at {v0:g} m/s with mu = {mu:g}: "
        "stops after v0^2 / (2 mu g) in v0 / (mu g).",
        tags=("hard", "contact-closed-form", "gravity", "contact", "rest"),
        duration=2.0,
        dt=0.001,
        sample_interval=0.001,
        gravity=GRAVITY,
        contact=Contact(restitution=0.0, friction=mu),
        planes=(builders.floor(),),
        bodies=(_cube(builders.cube_above_floor(), velocity=(v0, 0.0, 0.0)),),
        expected=Expected(
            stopping_distance=v0**2 / (2 * mu * G),
            stopping_time=v0 / (mu * G),
            rest_com_height=CUBE_REST_HEIGHT,
        ),
    )


def incline(name: str, degrees: float) -> Scene:
    theta, mu = math.radians(degrees), STICKY.friction
    slides = math.tan(theta) > mu
    acceleration = G * (math.sin(theta) - mu * math.cos(theta)) if slides else 0.0
    outcome = "slides" if slides else "sticks"
    return Scene(
        name=name,
        description=f"The seed's cube at rest on a {degrees:g} degree incline, mu = {mu:g}: "
        f"tan theta = {math.tan(theta):.2f}, it {outcome} (a = {acceleration:.3g} m/s^2).",
        tags=("hard", "contact-closed-form", "gravity", "contact", *(() if slides else ("rest",))),
        duration=2.0,
        dt=0.001,
        sample_interval=0.01,
        gravity=GRAVITY,
        contact=STICKY,
        planes=(builders.incline(theta),),
        bodies=(_cube(builders.rotated(builders.cube_above_floor(), builders.rotation_y(theta))),),
        expected=Expected(slope_acceleration=acceleration),
    )


register(partial(incline, "incline", 35.0))
register(partial(incline, "incline_stick", 20.0))
