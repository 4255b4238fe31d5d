"""Builders for common particle clusters and boundaries.

Each returns plain rows (x, y, z, mass) or planes, ready for `Body(particles=...)` and
`Scene(planes=...)`.
"""

import itertools

import numpy as np

from cases.scene import Plane

Rows = tuple[tuple[float, float, float, float], ...]


def seed_cube_particles(offset=(0.0, 0.0, 0.0), mass: float = 1.0) -> Rows:
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


def open_box(lower=(0.0, 0.0, 0.0), upper=(10.0, 10.0, 10.0)) -> tuple[Plane, ...]:
    """`box_walls` without its ceiling: the floor z = lower[2] and four side walls, open above."""
    return tuple(p for p in box_walls(lower, upper) if p.normal != (0.0, 0.0, -1.0))


def floor(height: float = 0.0) -> Plane:
    """The plane z = height facing up."""
    return Plane(point=(0.0, 0.0, float(height)), normal=(0.0, 0.0, 1.0))


def rotation_y(theta: float) -> np.ndarray:
    """(3, 3) rotation by `theta` (rad) about the y axis: it maps z to (sin theta, 0, cos theta)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotated(rows: Rows, rotation, about=(0.0, 0.0, 0.0)) -> Rows:
    """`rows` rotated by the (3, 3) matrix `rotation` about the point `about`; masses kept."""
    data = np.asarray(rows, dtype=float)
    pivot = np.asarray(about, dtype=float)
    positions = (data[:, :3] - pivot) @ np.asarray(rotation, dtype=float).T + pivot
    return tuple(
        (float(x), float(y), float(z), float(m))
        for (x, y, z), m in zip(positions, data[:, 3], strict=True)
    )


def shifted(rows: Rows, offset) -> Rows:
    """`rows` translated by `offset`; masses kept."""
    return tuple((x + offset[0], y + offset[1], z + offset[2], m) for x, y, z, m in rows)


def cube_above_floor(gap: float = 0.0, radius: float = 0.2, center_xy=(0.0, 0.0)) -> Rows:
    """The seed's cube centred over `center_xy`, faces axis-aligned, its lowest particles' surfaces
    `gap` above the floor z = 0 (centres at z = radius + gap): gap 0 touches exactly, and the COM
    sits at 0.5 + radius + gap."""
    return seed_cube_particles(offset=(center_xy[0] - 0.5, center_xy[1] - 0.5, radius + gap))


def stacked(rows: Rows, count: int, pitch: float) -> tuple[Rows, ...]:
    """`count` copies of `rows`, the k-th (from 0) raised by k * `pitch` along z."""
    return tuple(shifted(rows, (0.0, 0.0, k * pitch)) for k in range(count))


def incline_plane(theta: float) -> Plane:
    """The plane through the origin tilted by `theta` (rad) about y, normal (sin theta, 0,
    cos theta): its surface descends towards +x, downhill unit vector (cos theta, 0, -sin theta).
    `rotated(rows, rotation_y(theta))` carries a body resting on the floor z = 0 onto it."""
    return Plane(point=(0.0, 0.0, 0.0), normal=(float(np.sin(theta)), 0.0, float(np.cos(theta))))
