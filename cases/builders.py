"""Builders for common particle clusters and boundaries.

Each returns plain rows (x, y, z, mass) or planes, ready for `Body(particles=...)` and
`Scene(planes=...)`.
"""

import itertools

import numpy as np

from cases.scene import Plane

Rows = tuple[tuple[float, float, float, float], ...]


def seed_cube(offset=(0.0, 0.0, 0.0), mass: float = 1.0) -> Rows:
    """The seed's 8 particles at the corners of the unit cube [0, 1]^3 shifted by `offset`."""
    corners = [
        (0, 0, 0),
        (1, 0, 0),
        (1, 1, 0),
        (0, 1, 0),
        (0, 0, 1),
        (1, 0, 1),
        (1, 1, 1),
        (0, 1, 1),
    ]
    return tuple(
        (float(offset[0] + c[0]), float(offset[1] + c[1]), float(offset[2] + c[2]), float(mass))
        for c in corners
    )


def box_corners(size, center=(0.0, 0.0, 0.0), mass: float = 1.0) -> Rows:
    """8 particles of `mass` at the corners of an a x b x c box (`size`) centred on `center`."""
    return box_lattice(size, (2, 2, 2), center, mass)


def box_lattice(size, counts, center=(0.0, 0.0, 0.0), mass: float = 1.0) -> Rows:
    """A lattice of counts[0] x counts[1] x counts[2] particles filling an a x b x c box.

    Particles sit on the box's corners and faces; an axis with count 1 puts them on the centre
    plane. Each particle has `mass`.
    """
    axes = [
        np.linspace(-s / 2, s / 2, n) if n > 1 else np.zeros(1)
        for s, n in zip(size, counts, strict=True)
    ]
    return tuple(
        (float(center[0] + x), float(center[1] + y), float(center[2] + z), float(mass))
        for x, y, z in itertools.product(*axes)
    )


def box_walls(lower=(0.0, 0.0, 0.0), upper=(10.0, 10.0, 10.0)) -> tuple[Plane, ...]:
    """Six planes enclosing the box [lower, upper] with normals pointing inwards."""
    planes = []
    for axis in range(3):
        n = [0.0, 0.0, 0.0]
        n[axis] = 1.0
        planes.append(Plane(point=tuple(map(float, lower)), normal=tuple(n)))
        n[axis] = -1.0
        planes.append(Plane(point=tuple(map(float, upper)), normal=tuple(n)))
    return tuple(planes)


def floor(height: float = 0.0) -> Plane:
    """The plane z = height facing up."""
    return Plane(point=(0.0, 0.0, float(height)), normal=(0.0, 0.0, 1.0))
