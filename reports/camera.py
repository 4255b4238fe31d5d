"""The fixed camera an animation draws through (`reports.animation`), and the planes it shows.

One orthographic camera per animation, oblique from above, framing every run's particles over
the whole run (`scene_extent`, `camera_for`); each plane drawn where it crosses that box on the
free side of the others (`visible_planes`), as a translucent grid (`plane_layer`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from PIL import Image, ImageDraw

from cases.scene import Plane, Scene

# The camera looks down at ELEVATION_DEG from the horizontal (up is against gravity, z without
# gravity), from AZIMUTH_DEG about the up axis: the floor is seen from above, a box's three
# faces at once.
ELEVATION_DEG, AZIMUTH_DEG = 24.0, -55.0
# A panel's aspect follows the framed scene within this range; MARGIN_PX is left on each side.
ASPECT_RANGE = (0.6, 1.7)
MARGIN_PX = 10
# Space around the runs' extent, as a fraction of its largest side: planes show as a floor
# around the bodies, not an edge under them.
PAD_FRACTION = 0.12
# The camera leaves out runs that flew off (`scene_extent`): a diverging run's extent grows by
# orders of magnitude, a sound run's stays within a few times another's.
FLY_OFF_FACTOR = 10.0
MAX_REACH = 1000.0
PLANE_FILL = (150, 170, 200, 70)
PLANE_GRID = (110, 130, 165, 110)
PLANE_EDGE = (90, 110, 150, 170)


def _box(points: np.ndarray) -> np.ndarray | None:
    """(2, 3) lower and upper corners of the finite rows of `points` (..., 3); None: none."""
    flat = points.reshape(-1, 3)
    flat = flat[np.isfinite(flat).all(axis=1)]
    return None if len(flat) == 0 else np.array([flat.min(axis=0), flat.max(axis=0)])


def _size(box: np.ndarray) -> float:
    return float(np.max(box[1] - box[0]))


def scene_extent(
    scene: Scene, runs: Sequence[list[np.ndarray]], exact: list[np.ndarray] | None = None
) -> np.ndarray:
    """(2, 3) the box the camera frames: every particle of every run over its drawn samples,
    runs that flew off aside, padded by PAD_FRACTION. A run is per body its (S, n, 3) particle
    positions; `exact`, the same for the exact motion where there is one.

    A run has flown off when its extent is over FLY_OFF_FACTOR times the smallest run's (or the
    scene's at t = 0, or the exact motion's, if larger): every other panel would shrink to a
    dot. It is drawn clipped to its panel. Nothing is framed beyond MAX_REACH times the scene's
    size at t = 0 from where it starts (a lone run that flew off).
    """
    start = _box(np.concatenate([b.positions for b in scene.bodies]))
    floor = [start] + ([_box(np.concatenate(exact, axis=1))] if exact is not None else [])
    boxes = [_box(np.concatenate(tracks, axis=1)) for tracks in runs if tracks]
    boxes = [b for b in boxes if b is not None]
    reference = max([_size(b) for b in floor] + [min(map(_size, boxes), default=0.0)])
    kept = [b for b in boxes + floor if _size(b) <= FLY_OFF_FACTOR * reference]
    lower = np.min([b[0] for b in kept], axis=0)
    upper = np.max([b[1] for b in kept], axis=0)
    centre, reach = start.mean(axis=0), MAX_REACH * max(_size(start), 1e-9)
    lower, upper = np.maximum(lower, centre - reach), np.minimum(upper, centre + reach)
    radius = max(b.particle_radius for b in scene.bodies)
    pad = radius + PAD_FRACTION * max(float(np.max(upper - lower)), 2 * radius)
    return np.array([lower - pad, upper + pad])


def _up(scene: Scene) -> np.ndarray:
    g = np.asarray(scene.gravity, dtype=float)
    return -g / np.linalg.norm(g) if np.any(g) else np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """An orthographic camera: world points to panel pixels (x right, y down) and depth.

    Attributes:
      right, up, toward: (3,) screen right, screen up and the direction to the camera.
      centre: (2,) the world's screen coordinates (m) drawn at the panel's centre.
      scale: pixels per metre.  size: (width, height) of the drawing area in pixels.
    """

    right: np.ndarray
    up: np.ndarray
    toward: np.ndarray
    centre: np.ndarray
    scale: float
    size: tuple[int, int]

    def screen(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) screen coordinates (m) of world points (..., 3)."""
        return np.stack([points @ self.right, points @ self.up], axis=-1)

    def pixels(self, points: np.ndarray) -> np.ndarray:
        """(..., 2) pixel coordinates of world points (..., 3)."""
        s = (self.screen(points) - self.centre) * self.scale
        return np.stack([self.size[0] / 2 + s[..., 0], self.size[1] / 2 - s[..., 1]], axis=-1)

    def depth(self, points: np.ndarray) -> np.ndarray:
        """(...,) distance towards the camera: larger is nearer."""
        return points @ self.toward


def camera_for(scene: Scene, extent: np.ndarray, planes: list[np.ndarray], area_px: int) -> Camera:
    """The camera framing `extent` (2, 3) and the clipped `planes` (their polygons) in a panel
    of about `area_px` squared pixels whose aspect follows the framed scene."""
    up = _up(scene)
    helper = np.eye(3)[np.argmin(np.abs(up))]  # x when up is z
    east = helper - (helper @ up) * up
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    el, az = math.radians(ELEVATION_DEG), math.radians(AZIMUTH_DEG)
    toward = math.cos(el) * (math.cos(az) * east + math.sin(az) * north) + math.sin(el) * up
    right = np.cross(up, toward)
    right /= np.linalg.norm(right)
    screen_up = np.cross(toward, right)
    corners = np.array(
        [[extent[i][0], extent[j][1], extent[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    )
    points = np.concatenate([corners, *planes]) if planes else corners
    flat = np.stack([points @ right, points @ screen_up], axis=-1)
    low, high = flat.min(axis=0), flat.max(axis=0)
    span = np.maximum(high - low, 1e-9)
    aspect = float(np.clip(span[0] / span[1], *ASPECT_RANGE))
    size = (round(area_px * math.sqrt(aspect)), round(area_px / math.sqrt(aspect)))
    scale = min(
        (size[0] - 2 * MARGIN_PX) / span[0],
        (size[1] - 2 * MARGIN_PX) / span[1],
    )
    return Camera(right, screen_up, toward, (low + high) / 2, scale, size)


def _tangents(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.eye(3)[np.argmin(np.abs(normal))]
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(normal, t1)


def clip_plane(plane: Plane, extent: np.ndarray) -> np.ndarray | None:
    """(k, 3) the convex polygon where `plane` crosses the box `extent` (2, 3), vertices in
    order around it; None when it misses the box."""
    n, p0 = plane.unit_normal, np.asarray(plane.point, dtype=float)
    corners = np.array(
        [[extent[i][0], extent[j][1], extent[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    )
    side = (corners - p0) @ n
    points = []
    for a in range(8):
        for b in range(a + 1, 8):
            if bin(a ^ b).count("1") != 1:  # not an edge of the box
                continue
            if side[a] * side[b] < 0:
                w = side[a] / (side[a] - side[b])
                points.append(corners[a] + w * (corners[b] - corners[a]))
    points += [c for c, s in zip(corners, side, strict=True) if s == 0]
    if len(points) < 3:
        return None
    points = np.array(points)
    t1, t2 = _tangents(n)
    rel = points - points.mean(axis=0)
    return points[np.argsort(np.arctan2(rel @ t2, rel @ t1))]


def clip_to_free_side(polygon: np.ndarray, plane: Plane) -> np.ndarray | None:
    """The part of the convex `polygon` (k, 3) on `plane`'s free side (Sutherland-Hodgman);
    None when nothing is left."""
    n, p0 = plane.unit_normal, np.asarray(plane.point, dtype=float)
    side = (polygon - p0) @ n
    kept = []
    ends, end_sides = np.roll(polygon, -1, axis=0), np.roll(side, -1)
    for a, b, sa, sb in zip(polygon, ends, side, end_sides, strict=True):
        if sa >= 0:
            kept.append(a)
        if sa * sb < 0:
            kept.append(a + sa / (sa - sb) * (b - a))
    return np.array(kept) if len(kept) >= 3 else None


def visible_planes(scene: Scene, extent: np.ndarray) -> list[tuple[Plane, np.ndarray]]:
    """Each plane of the scene with the polygon drawn for it: where it crosses the box
    `extent` on the free side of every other plane (a wall stands on the floor, and the floor
    ends at the wall). Planes act only with contact."""
    planes = scene.planes if scene.contact is not None else ()
    shown = []
    for plane in planes:
        polygon = clip_plane(plane, extent)
        for other in planes:
            if polygon is not None and other is not plane:
                polygon = clip_to_free_side(polygon, other)
        if polygon is not None:
            shown.append((plane, polygon))
    return shown


def _grid_step(span: float) -> float:
    """A round spacing (1, 2 or 5 times a power of ten) giving about 8 lines over `span`."""
    raw = span / 8
    power = 10 ** math.floor(math.log10(raw))
    return next(f * power for f in (1, 2, 5, 10) if f * power >= raw)


def _grid_lines(plane: Plane, polygon: np.ndarray) -> list[np.ndarray]:
    """(2, 3) segments of a square grid on `plane`, clipped to its convex `polygon`."""
    p0 = np.asarray(plane.point, dtype=float)
    t1, t2 = _tangents(plane.unit_normal)
    uv = np.stack([(polygon - p0) @ t1, (polygon - p0) @ t2], axis=-1)
    step = _grid_step(float(np.max(uv.max(axis=0) - uv.min(axis=0))))
    segments = []
    for axis, (along, across) in enumerate(((t1, t2), (t2, t1))):
        for c in (
            np.arange(math.ceil(uv[:, axis].min() / step), math.floor(uv[:, axis].max() / step) + 1)
            * step
        ):
            hits = []
            for a, b in zip(uv, np.roll(uv, -1, axis=0), strict=True):
                if (a[axis] - c) * (b[axis] - c) < 0:
                    w = (c - a[axis]) / (b[axis] - a[axis])
                    hits.append(a[1 - axis] + w * (b[1 - axis] - a[1 - axis]))
            if len(hits) == 2:
                segments.append(np.array([p0 + c * along + h * across for h in hits]))
    return segments


def plane_layer(camera: Camera, plane: Plane, polygon: np.ndarray) -> Image.Image:
    """A transparent layer with the plane drawn: a light translucent fill, a grid and its edge."""
    layer = Image.new("RGBA", camera.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    outline = [tuple(p) for p in camera.pixels(polygon)]
    draw.polygon(outline, fill=PLANE_FILL)
    for segment in _grid_lines(plane, polygon):
        draw.line([tuple(p) for p in camera.pixels(segment)], fill=PLANE_GRID, width=1)
    draw.line([*outline, outline[0]], fill=PLANE_EDGE, width=1)
    return layer
