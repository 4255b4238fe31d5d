"""The built-in catalog: scenes registered by name with tags (dm_control's TaggedTasks idea).

Over 500 lines because it is the catalog: one builder per case with the closed forms it states.

Tests and reports parametrize over `CATALOG`, so adding a case adds its tests. The `cube_rain`
family (`cube_rain(n)`, at the end) is built for any N by name, `cube_rain_N` (`family_scene`);
the catalog holds one small member.
"""

import dataclasses
import math
from collections.abc import Callable
from functools import cache, partial

import numpy as np

from cases import builders
from cases.errors import InputError
from cases.scene import Body, Contact, Expected, Scene
from rigidmath.inertia import principal_frame
from rigidmath.quaternion import quats_to_matrices

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
                particles=builders.seed_cube_particles(offset=(3.0, 3.0, 7.0)),
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
                particles=builders.seed_cube_particles(offset=(3.0, 3.0, 7.0)),
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
                particles=builders.seed_cube_particles(offset=(-0.5, -0.5, 2.0)),
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


def _friction_on_floor(name: str, description: str, body: Body, mu: float, expected) -> Scene:
    """A body moving on the floor until Coulomb friction mu stops it, no bounce: 2 s at dt 0.001,
    every step sampled (the stop's time is refined between samples)."""
    return Scene(
        name=name,
        description=description,
        tags=("hard", "contact-closed-form", "gravity", "contact", "rest"),
        duration=2.0,
        dt=0.001,
        sample_interval=0.001,
        gravity=GRAVITY,
        contact=Contact(restitution=0.0, friction=mu),
        planes=(builders.floor(),),
        bodies=(body,),
        expected=expected,
    )


def slide(name: str, what: str, body: Body, degrees: float) -> Scene:
    """`what` (`body`, as high as the seed's cube and standing on a face on the floor) launched
    along it at 3 m/s, `degrees` off the world's x axis. Isotropic Coulomb friction stops it on
    its starting line in any direction: every corner slides alike, so friction's moment about
    the vertical through the COM cancels (the load shifts to the leading corners along the
    velocity, by mu times the COM's height). A friction pyramid, each tangent direction bounded
    by mu N apart, stops it short and off the line; an engine that couples the two directions
    through the body's inertia turns it."""
    v0, mu = 3.0, 0.5
    heading = math.radians(degrees)
    body = dataclasses.replace(body, velocity=(v0 * math.cos(heading), v0 * math.sin(heading), 0.0))
    towards = f", {degrees:g} degrees off the x axis," if degrees else ""
    return _friction_on_floor(
        name,
        f"{what} launched along the floor at {v0:g} m/s{towards} with mu = {mu:g}: stops after "
        "v0^2 / (2 mu g) in v0 / (mu g)" + (", on its starting line." if degrees else "."),
        body,
        mu,
        Expected(
            stopping_distance=v0**2 / (2 * mu * G),
            stopping_time=v0 / (mu * G),
            rest_com_height=CUBE_REST_HEIGHT,
        ),
    )


register(partial(slide, "slide", "The seed's cube", _cube(builders.cube_above_floor()), 0.0))
# The oblique slide: a box whose footprint and inertia differ along its axes (2 x 1 x 1 m, its
# long axis on x, as high as the seed's cube), launched 30 degrees off both. Off the world's axes
# a pyramid's two bounds stop the two velocity components at different times (at 45 degrees
# only the distance would be off); off the box's axes its inertia couples the directions.
OBLIQUE_BOX = (2.0, 1.0, 1.0)  # m, between corner particles' centres
register(
    partial(
        slide,
        "slide_oblique",
        "A 2 x 1 x 1 box of 8 corner particles, long axis on x,",
        _cube(
            builders.box_corners(OBLIQUE_BOX, (0.0, 0.0, RADIUS + OBLIQUE_BOX[2] / 2)), name="box"
        ),
        30.0,
    )
)


@register
def spin_down() -> Scene:
    """The seed's cube standing on the floor, spun about the vertical through its COM. Its four
    bottom corners slide on one circle of radius r about that axis, each against its own motion:
    friction mu N_i at each, tangential, so no net force and no tipping moment, and a torque
    mu m g r however the load is shared between them (all four are at r). It turns at a uniform
    deceleration a = mu m g r / I and stops after w0^2 / (2 a) in w0 / a."""
    w0, mu = 5.0, 0.5
    body = dataclasses.replace(_cube(builders.cube_above_floor()), angular_velocity=(0, 0, w0))
    bottom = body.positions[body.positions[:, 2] == body.positions[:, 2].min()]
    r = float(np.hypot(*(bottom - body.com)[:, :2].T).mean())  # the four's one radius
    a = mu * body.mass * G * r / body.inertia[2, 2]
    return _friction_on_floor(
        "spin_down",
        f"The seed's cube standing on the floor, spun at {w0:g} rad/s about the vertical, mu = "
        f"{mu:g}: its corners' friction stops it after w0^2 / (2 a) in w0 / a, a = mu m g r / I "
        f"= {a:.3g} rad/s^2.",
        body,
        mu,
        Expected(spin_angle=w0**2 / (2 * a), spin_time=w0 / a, rest_com_height=CUBE_REST_HEIGHT),
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
        planes=(builders.incline_plane(theta),),
        bodies=(_cube(builders.rotated(builders.cube_above_floor(), builders.rotation_y(theta))),),
        expected=Expected(slope_acceleration=acceleration),
    )


register(partial(incline, "incline", 35.0))
register(partial(incline, "incline_stick", 20.0))


# ---------------------------------------------------------------------------------------------
# Scaling: the cube_rain family, N cubes raining into an open box (`comparators.scaling` times
# it against N). Any `cube_rain_N` with 1 <= N <= CUBE_RAIN_MAX resolves by name.

CUBE_RAIN_MAX = 1000
CUBE_RAIN_PREFIX = "cube_rain_"
CUBE_RAIN_EDGE = 0.5  # m, between the centres of a cube's corner particles
# m: above edge / (2 sqrt 2) = 0.18 m, so a face's four particles close it: the face's centre is
# 0.35 m from its corners, under two radii, and no particle of another cube passes through.
CUBE_RAIN_RADIUS = 0.2
CUBE_RAIN_PARTICLE_MASS = 1.0  # kg, the seed's
# m: the farthest particle surface from a cube's centre, whatever its orientation.
CUBE_RAIN_REACH = CUBE_RAIN_EDGE * math.sqrt(3) / 2 + CUBE_RAIN_RADIUS
# m between grid centres: two reaches are 1.27 m, so neighbours start at least 0.23 m apart and
# the outer cubes 0.12 m from the walls, in any orientation.
CUBE_RAIN_PITCH = 1.5
# The grid is at most this many layers high and its footprint grows as sqrt(N): from a few tens
# of cubes on, every N falls as far and lands on about as many cubes, so the work per body is
# alike; fewer make a lower, narrower pile (a lone cube touches only the floor).
CUBE_RAIN_LAYERS = 4
CUBE_RAIN_CLEARANCE = 0.5  # m from the floor to the lowest reach of the bottom layer
# Bounds of the uniform random initial velocity (m/s) and angular velocity (rad/s, the seed's
# 2 rad/s) components: enough that neighbours meet in the air and the pile is not symmetric.
CUBE_RAIN_SPEED = 0.5
CUBE_RAIN_SPIN = 2.0
CUBE_RAIN_SEED = 7  # numpy's default_rng seed: one fixed pile for every N
CUBE_RAIN_CONTACT = Contact(restitution=0.3, friction=0.5)
# s between samples: what a verdict looks for (a non-finite state, runaway energy, a particle
# behind a plane) persists once it happens, so 0.1 s samples still catch it; the suite's
# per-body metrics (`comparators.metrics.body_arrays`) scan the whole table once per body, so
# their cost grows as N x samples x N.
CUBE_RAIN_SAMPLE_INTERVAL = 0.1


@cache
def cube_rain(n: int) -> Scene:
    """`n` cubes of 8 particles on a grid at most CUBE_RAIN_LAYERS high, randomly oriented and
    moving (CUBE_RAIN_SEED), dropped into an open box (floor z = 0 and four walls) around the
    grid's footprint; 1 s at dt 0.01: the bottom layer lands after about 0.3 s, the top one
    by the end."""
    if not (isinstance(n, int) and 1 <= n <= CUBE_RAIN_MAX):
        raise ValueError(f"cube_rain: expected a whole number of cubes from 1 to {CUBE_RAIN_MAX}")
    side = math.ceil(math.sqrt(n / CUBE_RAIN_LAYERS))  # cubes along x and y
    per_layer = side * side
    width = side * CUBE_RAIN_PITCH
    rng = np.random.default_rng(CUBE_RAIN_SEED)
    quaternions = rng.normal(size=(n, 4))  # normalised: uniform over the rotations
    rotations = quats_to_matrices(quaternions / np.linalg.norm(quaternions, axis=1)[:, None])
    velocities = rng.uniform(-CUBE_RAIN_SPEED, CUBE_RAIN_SPEED, size=(n, 3))
    spins = rng.uniform(-CUBE_RAIN_SPIN, CUBE_RAIN_SPIN, size=(n, 3))
    cube = builders.box_corners((CUBE_RAIN_EDGE,) * 3, mass=CUBE_RAIN_PARTICLE_MASS)
    bodies = []
    for k in range(n):
        layer, cell = divmod(k, per_layer)
        row, column = divmod(cell, side)
        centre = (
            (column + 0.5) * CUBE_RAIN_PITCH,
            (row + 0.5) * CUBE_RAIN_PITCH,
            CUBE_RAIN_CLEARANCE + CUBE_RAIN_REACH + layer * CUBE_RAIN_PITCH,
        )
        rows = builders.shifted(builders.rotated(cube, rotations[k]), centre)
        bodies.append(
            Body(
                name=f"cube{k}",
                particle_radius=CUBE_RAIN_RADIUS,
                particles=tuple(tuple(float(c) for c in row) for row in rows),
                velocity=tuple(float(c) for c in velocities[k]),
                angular_velocity=tuple(float(c) for c in spins[k]),
            )
        )
    layers = math.ceil(n / per_layer)
    return Scene(
        name=f"{CUBE_RAIN_PREFIX}{n}",
        description=f"{n} cube(s) of 8 particles (edge {CUBE_RAIN_EDGE:g} m, radius "
        f"{CUBE_RAIN_RADIUS:g} m), randomly turned, moving and spinning, raining from a "
        f"{side} x {side} x {layers} grid into an open {width:g} m box: cost per step against N.",
        tags=("scaling", "contact", "gravity", *(("multibody",) if n > 1 else ())),
        duration=1.0,
        dt=0.01,
        sample_interval=CUBE_RAIN_SAMPLE_INTERVAL,
        gravity=GRAVITY,
        contact=CUBE_RAIN_CONTACT,
        planes=builders.open_box((0.0, 0.0, 0.0), (width, width, width)),
        bodies=tuple(bodies),
    )


def family_scene(name: str) -> Scene | None:
    """The scene called `name` in a family (`cube_rain_N`), None when `name` names no family.

    Raises `InputError` for a family name whose N is not a whole number from 1 to
    CUBE_RAIN_MAX, written without leading zeros.
    """
    if not name.startswith(CUBE_RAIN_PREFIX):
        return None
    text = name.removeprefix(CUBE_RAIN_PREFIX)
    canonical = text.isascii() and text.isdigit() and text == str(int(text))
    if not (canonical and 1 <= int(text) <= CUBE_RAIN_MAX):
        raise InputError(
            f"case {name!r}: expected {CUBE_RAIN_PREFIX}N with N a whole number from 1 to "
            f"{CUBE_RAIN_MAX} (the number of cubes)"
        )
    return cube_rain(int(text))


CUBE_RAIN_REPRESENTATIVE = 8  # two layers of 2 x 2: cubes land on cubes, cheap in every sweep
register(partial(cube_rain, CUBE_RAIN_REPRESENTATIVE))
