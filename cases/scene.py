"""The engine-neutral scene: bodies as particle clusters, gravity, planes, contact, duration, dt.

Every engine builds its model from a `Scene` and nothing else. Scenes are frozen pydantic
dataclasses, so a scene built in Python and a scene loaded from TOML pass the same validation.
Units are SI; positions are world coordinates at t = 0.
"""

from __future__ import annotations

import math
from functools import cached_property
from typing import Annotated

import numpy as np
from pydantic import AfterValidator, ConfigDict, Field
from pydantic.dataclasses import dataclass

from rigidmath.inertia import center_of_mass, inertia_tensor

# Every number of a scene is 0 or of a size between MIN_MAGNITUDE and MAX_MAGNITUDE, and so is
# each body's principal moments, energies and momenta: the engines and the suite's metrics
# multiply up to three such quantities (I w^2, m g h, a contact impulse times dt), which then
# stay finite and normal in float64 (whose range is 1e-308 to 1e308).
MAX_MAGNITUDE = 1e100
MIN_MAGNITUDE = 1e-100


def _magnitude(value: float) -> float:
    """A number of a scene: 0, or of a size between MIN_MAGNITUDE and MAX_MAGNITUDE."""
    if value != 0 and not MIN_MAGNITUDE <= abs(value) <= MAX_MAGNITUDE:
        raise ValueError(
            f"expected 0 or a number of size between {MIN_MAGNITUDE:g} and {MAX_MAGNITUDE:g} "
            f"(beyond, products of such numbers leave float64's range), got {value!r}"
        )
    return value


# Strict: a string or a boolean is not a number; NaN and inf are rejected everywhere.
Num = Annotated[float, Field(strict=True, allow_inf_nan=False), AfterValidator(_magnitude)]
PositiveNum = Annotated[Num, Field(gt=0)]
Vec3 = tuple[Num, Num, Num]
Particle = tuple[Num, Num, Num, PositiveNum]  # x, y, z, mass
# A case's name becomes part of file names (the report's figures/<case>_work_precision.png,
# written through a temporary ".<file>.XXXXXXXX", 29 bytes more), which file systems cap at 255
# bytes: names of at most this many characters leave room for every figure's suffix.
NAME_MAX_LENGTH = 100
Name = Annotated[str, Field(strict=True, pattern=r"^[A-Za-z0-9_.-]+$", max_length=NAME_MAX_LENGTH)]

_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False)

# A body whose smallest principal moment is below this fraction of its largest has a singular
# inertia tensor: collinear particles give exactly 0 up to rounding (about 1e-16 relative).
SINGULAR_INERTIA_RATIO = 1e-12
# A plane normal shorter than this cannot be normalised meaningfully.
MIN_NORMAL_LENGTH = 1e-12

ZERO3 = (0.0, 0.0, 0.0)


def _within(body: str, quantity: str, value: float, key: str) -> None:
    """ValueError naming body, quantity and `key` (what to change) unless `value` is 0 or its
    size lies between MIN_MAGNITUDE and MAX_MAGNITUDE."""
    size = abs(float(value))
    if size != 0 and not MIN_MAGNITUDE <= size <= MAX_MAGNITUDE:
        raise ValueError(
            f"body {body!r}: its {quantity} is {size:.3g}, expected 0 or between "
            f"{MIN_MAGNITUDE:g} and {MAX_MAGNITUDE:g} (larger or smaller, the engines' products "
            f"of it leave float64's range): change '{key}'"
        )


@dataclass(frozen=True, config=_CONFIG)
class Contact:
    """Contact parameters shared by every particle pair and particle-plane pair.

    Attributes:
      restitution: coefficient e in [0, 1], ratio of separating to approaching normal speed.
      friction: Coulomb coefficient mu >= 0.
    """

    restitution: Annotated[Num, Field(ge=0, le=1)]
    friction: Annotated[Num, Field(ge=0)]


@dataclass(frozen=True, config=_CONFIG)
class Plane:
    """A static half-space boundary: `point` on the plane, `normal` pointing into the free side."""

    point: Vec3
    normal: Vec3

    def __post_init__(self):
        if math.hypot(*self.normal) < MIN_NORMAL_LENGTH:
            raise ValueError(
                f"plane normal {list(self.normal)} is zero: expected a non-zero vector"
            )

    @property
    def unit_normal(self) -> np.ndarray:
        n = np.asarray(self.normal, dtype=float)
        return n / np.linalg.norm(n)


@dataclass(frozen=True, config=_CONFIG)
class Body:
    """A rigid cluster of point-mass particles.

    Attributes:
      particles: (n, 4) rows x, y, z, mass: world positions at t = 0 (m) and masses (kg).
      particle_radius: collision radius of every particle (m); adds no inertia.
      velocity: (3,) initial centre-of-mass velocity, world frame (m/s).
      angular_velocity: (3,) initial angular velocity, world frame (rad/s).
    """

    name: Name
    particle_radius: PositiveNum
    particles: Annotated[tuple[Particle, ...], Field(min_length=1)]
    velocity: Vec3 = ZERO3
    angular_velocity: Vec3 = ZERO3

    def __post_init__(self):
        moments = np.linalg.eigvalsh(self.inertia)
        if moments[-1] <= 0 or moments[0] < SINGULAR_INERTIA_RATIO * moments[-1]:
            raise ValueError(
                f"body {self.name!r}: its {len(self.particles)} particle(s) are all collinear, "
                "so the inertia tensor is singular "
                f"(principal moments {moments.round(12).tolist()}) "
                "and omega = I^-1 L is undefined: expected at least three non-collinear particles"
            )
        v, w = np.asarray(self.velocity), np.asarray(self.angular_velocity)
        _within(self.name, "smallest principal moment (kg m^2)", moments[0], "particles")
        _within(self.name, "largest principal moment (kg m^2)", moments[-1], "particles")
        _within(self.name, "kinetic energy 1/2 m |v|^2 (J)", 0.5 * self.mass * v @ v, "velocity")
        _within(self.name, "momentum m |v| (kg m/s)", self.mass * np.linalg.norm(v), "velocity")
        rotational = 0.5 * w @ self.inertia @ w
        _within(self.name, "rotational energy 1/2 w.I.w (J)", rotational, "angular_velocity")
        spin = np.linalg.norm(self.inertia @ w)
        _within(self.name, "angular momentum |I w| (kg m^2/s)", spin, "angular_velocity")
        orbital = self.mass * np.linalg.norm(np.cross(self.com, v))
        _within(
            self.name, "angular momentum about the origin m |x v| (kg m^2/s)", orbital, "velocity"
        )

    @cached_property
    def positions(self) -> np.ndarray:
        """(n, 3) particle positions at t = 0."""
        return np.array([p[:3] for p in self.particles], dtype=float)

    @cached_property
    def masses(self) -> np.ndarray:
        """(n,) particle masses."""
        return np.array([p[3] for p in self.particles], dtype=float)

    @property
    def mass(self) -> float:
        return float(self.masses.sum())

    @cached_property
    def com(self) -> np.ndarray:
        """(3,) centre of mass at t = 0."""
        return center_of_mass(self.positions, self.masses)

    @cached_property
    def inertia(self) -> np.ndarray:
        """(3, 3) inertia tensor about the COM in world axes at t = 0 (the body frame)."""
        return inertia_tensor(self.positions - self.com, self.masses)


@dataclass(frozen=True, config=_CONFIG)
class Expected:
    """What physics predicts for a scene beyond what `cases.exact` derives from it.

    Closed-form contact outcomes, each stated by the case that checks it; all optional.

    Attributes:
      rest_com_height: distance (m) of the resting body's COM from the plane it ends on
        (the plane whose normal points most against gravity).
      rebound_ratio: separating over approaching normal speed of the COM at each bounce (e).
      apex_heights: clearance (m) of the lowest particle surface above the floor at the top of
        the first bounces, h0 e^(2k) for k = 1, 2, ...
      stopping_distance, stopping_time: how far (m) and how long (s) a body launched along the
        floor slides before friction stops it: v0^2 / (2 mu g) and v0 / (mu g).
      slope_acceleration: the COM's acceleration (m/s^2) down an incline: 0 when friction holds
        it (tan theta <= mu), else g (sin theta - mu cos theta).
      spin_angle, spin_time: how far (rad) and how long (s) a body spun about the normal of the
        plane it stands on turns before friction at its contacts stops it: w0^2 / (2 a) and
        w0 / a, a = mu g m r / I for contacts at distance r from the spin axis.
    """

    rest_com_height: PositiveNum | None = None
    rebound_ratio: Annotated[Num, Field(ge=0, le=1)] | None = None
    apex_heights: tuple[PositiveNum, ...] | None = None
    stopping_distance: PositiveNum | None = None
    stopping_time: PositiveNum | None = None
    slope_acceleration: Annotated[Num, Field(ge=0)] | None = None
    spin_angle: PositiveNum | None = None
    spin_time: PositiveNum | None = None


@dataclass(frozen=True, config=_CONFIG)
class Scene:
    """One engine-neutral case.

    Attributes:
      duration: simulated time (s); dt: default step (s).
      sample_interval: time between output samples (s); None samples every step.
      gravity: (3,) uniform gravitational acceleration (m/s^2).
      contact: contact parameters, or None: no contact of any kind is modelled.
      planes: static planes; they only act when `contact` is given.
    """

    name: Name
    duration: PositiveNum
    dt: PositiveNum
    gravity: Vec3
    bodies: Annotated[tuple[Body, ...], Field(min_length=1)]
    description: str = ""
    tags: tuple[Name, ...] = ()
    sample_interval: PositiveNum | None = None
    contact: Contact | None = None
    planes: tuple[Plane, ...] = ()
    expected: Expected | None = None

    def __post_init__(self):
        if self.dt > self.duration:
            raise ValueError(f"dt {self.dt} is longer than duration {self.duration}")
        if self.planes and self.contact is None:
            raise ValueError(
                "planes are given but [contact] is absent, so they would have no effect: "
                "expected a [contact] table (restitution, friction) or no planes"
            )
        names = [b.name for b in self.bodies]
        if len(set(names)) != len(names):
            raise ValueError(f"body names must be unique, got {names}")
        self._check_particles_in_front_of_planes()
        g = np.linalg.norm(self.gravity)
        for body in self.bodies:
            weight = body.mass * g
            _within(body.name, "weight m |g| (N)", weight, "gravity")
            _within(
                body.name,
                "potential energy m |g| |x| (J)",
                weight * np.linalg.norm(body.com),
                "gravity",
            )

    def _check_particles_in_front_of_planes(self) -> None:
        """ValueError naming the first particle whose centre starts behind a plane: every engine
        would then be judged to have tunnelled (`comparators.verdict`), for the scene's fault."""
        if not self.planes:
            return
        points = np.concatenate([body.positions for body in self.bodies])
        counts = [len(body.particles) for body in self.bodies]
        first = np.cumsum([0, *counts])  # each body's first row in `points`
        for j, plane in enumerate(self.planes):
            side = (points - plane.point) @ plane.unit_normal
            behind = np.flatnonzero(side < 0)
            if behind.size:
                k = int(np.searchsorted(first, behind[0], side="right")) - 1
                i = int(behind[0] - first[k])
                raise ValueError(
                    f"key 'bodies[{k}].particles[{i}]': the centre of a particle of body "
                    f"{self.bodies[k].name!r} starts {-side[behind[0]]:.3g} m behind planes[{j}] "
                    f"(point {list(plane.point)}, normal {list(plane.normal)}): expected every "
                    "particle's centre on the side its normal points to"
                )

    @property
    def has_contact(self) -> bool:
        """True when the scene has something to collide with: planes or a second body."""
        return self.contact is not None and (bool(self.planes) or len(self.bodies) > 1)

    @property
    def has_gravity(self) -> bool:
        return any(g != 0.0 for g in self.gravity)

    def sample_stride(self, dt: float) -> int:
        """Steps between output samples when stepping with `dt`."""
        if self.sample_interval is None:
            return 1
        # clipped where it exceeds any step count (then only the first and last step are
        # sampled), so that a tiny dt cannot make it overflow
        return max(1, round(min(self.sample_interval / dt, 2.0**62)))

    def steps(self, dt: float, duration: float | None = None) -> int:
        """Number of steps of size `dt` covering `duration` (default: the scene's)."""
        return max(1, round((self.duration if duration is None else duration) / dt))

    def modelled(self) -> str:
        """One line saying what an engine has to model for this scene."""
        parts = [f"{len(self.bodies)} bod{'y' if len(self.bodies) == 1 else 'ies'}"]
        parts.append(f"{sum(len(b.particles) for b in self.bodies)} particles")
        parts.append("gravity" if self.has_gravity else "no gravity")
        if self.has_contact:
            c = self.contact
            parts.append(
                f"{len(self.planes)} plane(s), contact e={c.restitution:g} mu={c.friction:g}"
            )
        else:
            parts.append("no contact")
        return ", ".join(parts)
