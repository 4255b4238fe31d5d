"""Animations of the motion: each body's particles as shaded spheres and the scene's planes, one
panel per run (engine/integrator) on one time axis, the exact motion as a ghost where there is
one (contact-free scenes, `cases.exact`).

Written as GIF with Pillow (which ships with matplotlib): a GIF plays inline in report.md on
GitHub and in index.html with no player, script or codec. Frames are drawn directly with
`PIL.ImageDraw` through one fixed camera per animation (`reports.camera`): matplotlib's 3D axes
take far longer per frame than the quick report's budget allows.

Particles are drawn where `comparators.run_data.particle_tracks` places them: recorded by an
engine whose bodies deform (the reference's `seed`), else placed rigidly from each sample's pose.
A run whose samples turn non-finite is drawn up to its last finite sample and marked "diverged
at t = ..." from then on; a run that failed is a panel saying why.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from cases.exact import exact_states, exact_trajectory_available
from cases.scene import Body, Scene
from comparators.run_data import particle_tracks
from comparators.trajectory import Trajectory, atomic_path
from reports.camera import Camera, camera_for, plane_layer, scene_extent, visible_planes
from rigidmath.inertia import EQUAL_MOMENTS_RTOL, principal_frame
from rigidmath.quaternion import quats_to_matrices

# Size: panels of about PANEL_PX x PANEL_PX (their aspect follows the scene's within
# `reports.camera.ASPECT_RANGE`), at most MAX_COLUMNS side by side, at most MAX_FRAMES frames,
# each a whole number of samples apart. Most of a GIF's bytes are the edges that move, so edges
# are not antialiased: drawing at twice the size and reducing made tumbling_box's 5 panels 40%
# larger.
PANEL_PX = 240
MAX_COLUMNS = 3
MAX_FRAMES = 81
LOOP_S = 8.0  # a loop plays in about this long, each frame FRAME_MS_RANGE ms
FRAME_MS_RANGE = (60, 200)
LAST_FRAME_MS = 1500  # a pause on the final state before the loop starts again
HEADER_PX, LABEL_PX = 24, 18
NOTE_LINES = 3  # a failed run's reason, at most this many lines at the foot of its panel
# Particles are joined by bonds (`bonds`): the shape reads at a glance, and a deforming body's
# bonds show it deform. A particle on a bond's ball, to rounding of metre-scale coordinates,
# blocks it; clusters past MAX_BONDED_PARTICLES would be a tangle of lines.
BALL_RTOL = 1e-9
BOND_PX = 1
MAX_BONDED_PARTICLES = 64

MARK_LIGHTEN = 0.5  # `marked_particles` are their body's colour this far towards white
BACKGROUND = (255, 255, 255)
TEXT = (30, 30, 30)
DIVERGED = (200, 30, 30)
GHOST = (90, 90, 90)
BODY_COLOURS = (
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (188, 189, 34),
    (23, 190, 207),
)


@dataclass(frozen=True)
class Panel:
    """One run as drawn: its label, per body (S, n, 3) particle positions at its sample times
    (S,), the time its samples turn non-finite (None: never), or why it failed (no samples)."""

    label: str
    tracks: list[np.ndarray]
    times: np.ndarray
    diverged_at: float | None = None
    failure: str | None = None


def panel_of(label: str, run: Trajectory | str, scene: Scene) -> Panel:
    """The `Panel` of one run: a trajectory, or the reason it failed."""
    if isinstance(run, str):
        return Panel(label, [], np.zeros(0), failure=run)
    tracks = particle_tracks(run, scene)
    times = run.state_by_body[scene.bodies[0].name][:, 0]
    finite = np.all([np.isfinite(p).all(axis=(1, 2)) for p in tracks], axis=0)
    diverged_at = None if finite.all() else float(times[np.argmin(finite)])
    return Panel(label, tracks, times, diverged_at)


def frame_times(panels: Sequence[Panel], duration: float) -> np.ndarray:
    """The frames' times: every k-th sample time of the most finely sampled run, k the least
    that keeps to MAX_FRAMES, and its last; `duration` (s) split evenly when nothing ran."""
    clock = max((p.times for p in panels), key=len)
    if len(clock) < 2:
        return np.array([0.0, duration])
    stride = math.ceil((len(clock) - 1) / (MAX_FRAMES - 1))
    times = clock[::stride]
    return times if times[-1] == clock[-1] else np.append(times, clock[-1])


def ghost_tracks(scene: Scene, times: np.ndarray) -> list[np.ndarray] | None:
    """Per body, (F, n, 3) particle positions of the exact motion at `times`; None when the
    scene has no exact solution (contact)."""
    if not exact_trajectory_available(scene):
        return None
    tracks = []
    for body, state in zip(scene.bodies, exact_states(scene, times), strict=True):
        r = quats_to_matrices(np.ascontiguousarray(state["q"]))
        tracks.append(
            state["x"][:, None, :] + np.einsum("sij,nj->sni", r, body.positions - body.com)
        )
    return tracks


def _sample_index(times: np.ndarray, t: float) -> int:
    """The sample shown at time t: the last one at or before it (to within rounding of t)."""
    return max(0, int(np.searchsorted(times, t + 1e-9 * max(1.0, t), side="right")) - 1)


# ---- bodies ----------------------------------------------------------------------------------


def bonds(positions: np.ndarray) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of the Gabriel graph of the positions at t = 0: i and j are joined
    when no other particle lies in the ball whose diameter is the segment ij, boundary
    included. For a box's corners these are exactly its 12 edges (a face diagonal has the
    face's other corners on its ball)."""
    n = len(positions)
    if n < 2 or n > MAX_BONDED_PARTICLES:
        return []
    middle = (positions[:, None] + positions[None]) / 2  # (n, n, 3)
    reach = np.sum((positions[:, None] - positions[None]) ** 2, axis=-1) / 4  # squared radius
    inside = np.sum((positions[None, None] - middle[:, :, None]) ** 2, axis=-1)  # (n, n, n)
    blocked = inside <= reach[:, :, None] * (1 + BALL_RTOL)
    own = np.eye(n, dtype=bool)
    blocked &= ~own[:, None, :] & ~own[None, :, :]  # i and j themselves do not block
    return [(i, j) for i in range(n) for j in range(i + 1, n) if not blocked[i, j].any()]


def marked_particles(body: Body) -> np.ndarray:
    """(n,) True for the particles drawn lighter: those on the positive side of the body's
    intermediate principal axis at t = 0, so that a flip (that axis reversing, `tumbling_box`)
    shows as the light and dark ends trading places, and a spin shows on a symmetric body. When
    two moments are equal that axis is any of a plane: then the world axis most nearly
    perpendicular to the initial spin (a cube spinning about x: y)."""
    moments, axes = principal_frame(body.inertia)
    axis = axes[:, 1]
    if np.min(np.diff(moments)) <= EQUAL_MOMENTS_RTOL * moments[-1]:
        axis = np.eye(3)[np.argmin(np.abs(body.angular_velocity))]
    return (body.positions - body.com) @ axis > 0


def _mix(colour, other, w: float) -> tuple[int, int, int]:
    return tuple(round(a + (b - a) * w) for a, b in zip(colour, other, strict=True))


def _sphere(draw: ImageDraw.ImageDraw, x: float, y: float, r: float, colour) -> None:
    """A disc shaded as a sphere lit from the upper left: a dark rim, the body colour, a lighter
    cap and a small highlight."""

    def disc(cx, cy, radius, fill):
        draw.ellipse((cx - radius, cy - radius, cx + radius, cy + radius), fill=fill)

    disc(x, y, r, _mix(colour, (0, 0, 0), 0.45))
    disc(x - 0.07 * r, y - 0.07 * r, 0.86 * r, colour)
    disc(x - 0.24 * r, y - 0.24 * r, 0.48 * r, _mix(colour, (255, 255, 255), 0.3))
    disc(x - 0.36 * r, y - 0.36 * r, 0.17 * r, _mix(colour, (255, 255, 255), 0.8))


def _draw_bodies(
    draw, camera: Camera, scene: Scene, positions: list[np.ndarray], links, marks
) -> None:
    """Every body's bonds and particles, nearest last (painter's order); `links` per body its
    `bonds`, `marks` its `marked_particles`."""
    items = []
    limit = 4 * max(camera.size)  # beyond this a point is far outside the panel
    for k, (body, points) in enumerate(zip(scene.bodies, positions, strict=True)):
        colour = BODY_COLOURS[k % len(BODY_COLOURS)]
        pixels, depth = camera.pixels(points), camera.depth(points)
        shown = np.isfinite(pixels).all(axis=1) & (np.abs(pixels) < limit).all(axis=1)
        radius = body.particle_radius * camera.scale
        light = _mix(colour, (255, 255, 255), MARK_LIGHTEN)
        for i in np.flatnonzero(shown):
            items.append((depth[i], 1, pixels[i], radius, light if marks[k][i] else colour))
        bond_colour = _mix(colour, (0, 0, 0), 0.3)
        for i, j in links[k]:
            if shown[i] and shown[j]:
                line = (tuple(pixels[i]), tuple(pixels[j]))
                items.append(((depth[i] + depth[j]) / 2, 0, line, BOND_PX, bond_colour))
    for _, kind, where, size, colour in sorted(items, key=lambda item: (item[0], item[1])):
        if kind == 0:
            draw.line(where, fill=colour, width=size)
        else:
            _sphere(draw, where[0], where[1], size, colour)


def _draw_ghost(draw, camera: Camera, scene: Scene, positions: list[np.ndarray]) -> None:
    """The exact motion's particles as thin rings, over everything."""
    for body, points in zip(scene.bodies, positions, strict=True):
        r = body.particle_radius * camera.scale
        for x, y in camera.pixels(points):
            draw.ellipse((x - r, y - r, x + r, y + r), outline=GHOST, width=1)


# ---- frames ----------------------------------------------------------------------------------


def _font(size: int) -> ImageFont.ImageFont:
    return ImageFont.load_default(size=size)


@dataclass(frozen=True)
class _Layout:
    """Where panels go in a frame (pixels)."""

    columns: int
    rows: int
    panel: tuple[int, int]  # drawing area, width and height

    @property
    def size(self) -> tuple[int, int]:
        return (
            self.columns * self.panel[0],
            HEADER_PX + self.rows * (LABEL_PX + self.panel[1]),
        )

    def origin(self, k: int) -> tuple[int, int]:
        """Top left of panel k's label strip."""
        row, column = divmod(k, self.columns)
        return column * self.panel[0], HEADER_PX + row * (LABEL_PX + self.panel[1])


def _wrap(draw: ImageDraw.ImageDraw, text: str, font, width: float) -> list[str]:
    """`text` in lines no wider than `width` pixels, broken at spaces (a longer word alone)."""
    lines: list[str] = []
    for word in text.split():
        if lines and draw.textlength(f"{lines[-1]} {word}", font=font) <= width:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return lines


def _time_text(t: float, duration: float) -> str:
    return f"t = {t:.1f} s" if duration >= 10 else f"t = {t:.2f} s"


class _Renderer:
    """Draws the frames of one animation; the camera, planes and panels fixed once."""

    def __init__(self, scene: Scene, panels: Sequence[Panel], ghost, times: np.ndarray):
        self.scene, self.panels, self.ghost, self.times = scene, panels, ghost, times
        extent = scene_extent(scene, [p.tracks for p in panels], ghost)
        clipped = visible_planes(scene, extent)
        self.camera = camera_for(scene, extent, [poly for _, poly in clipped], PANEL_PX)
        columns = min(MAX_COLUMNS, len(panels))
        self.layout = _Layout(columns, math.ceil(len(panels) / columns), self.camera.size)
        # planes facing the camera are behind the bodies (which are on their free side), the
        # others in front of them
        self.back = Image.new("RGBA", self.camera.size, BACKGROUND + (255,))
        self.front = Image.new("RGBA", self.camera.size, (0, 0, 0, 0))
        for plane, polygon in clipped:
            layer = plane_layer(self.camera, plane, polygon)
            if plane.unit_normal @ self.camera.toward >= 0:
                self.back.alpha_composite(layer)
            else:
                self.front.alpha_composite(layer)
        self.back = self.back.convert("RGB")
        self.links = [bonds(b.positions) for b in scene.bodies]
        self.marks = [marked_particles(b) for b in scene.bodies]
        self.fonts = {"header": _font(14), "label": _font(12)}

    def frame(self, f: int) -> Image.Image:
        """Frame f (time `times[f]`), RGB."""
        image = Image.new("RGB", self.layout.size, BACKGROUND)
        draw = ImageDraw.Draw(image)
        t, duration = float(self.times[f]), float(self.times[-1])
        header = f"{self.scene.name}   {_time_text(t, duration)}"
        draw.text((8, 4), header, fill=TEXT, font=self.fonts["header"])
        if self.ghost is not None:
            note = "rings: exact solution"
            width = draw.textlength(note, font=self.fonts["label"])
            draw.text(
                (self.layout.size[0] - width - 8, 6), note, fill=GHOST, font=self.fonts["label"]
            )
        for k, panel in enumerate(self.panels):
            x0, y0 = self.layout.origin(k)
            image.paste(self._panel(panel, f), (x0, y0 + LABEL_PX))
            draw.text((x0 + 6, y0 + 2), panel.label, fill=TEXT, font=self.fonts["label"])
            note = self._note(panel, t)
            if note:
                font = self.fonts["label"]
                lines = _wrap(draw, note, font, self.layout.panel[0] - 12)[:NOTE_LINES]
                bottom = y0 + LABEL_PX + self.layout.panel[1]
                for row, line in enumerate(lines):
                    top = bottom - 16 * (len(lines) - row) - 2
                    draw.text((x0 + 6, top), line, fill=DIVERGED, font=font)
        return image

    def _note(self, panel: Panel, t: float) -> str | None:
        """What went wrong with the panel's run, by time t: it failed, or it diverged."""
        if panel.failure is not None:
            return f"failed: {panel.failure}"
        if panel.diverged_at is not None and t >= panel.diverged_at - 1e-9:
            return f"diverged at t = {panel.diverged_at:.3g} s"
        return None

    def _panel(self, panel: Panel, f: int) -> Image.Image:
        """The panel's drawing area at frame f."""
        canvas = self.back.copy()
        draw = ImageDraw.Draw(canvas)
        if panel.tracks:
            t = float(self.times[f])
            if panel.diverged_at is not None:
                t = min(t, panel.diverged_at)
            s = _sample_index(panel.times, t)
            if panel.diverged_at is not None and panel.times[s] >= panel.diverged_at:
                s = max(0, s - 1)  # the last finite sample
            positions = [p[s] for p in panel.tracks]
            _draw_bodies(draw, self.camera, self.scene, positions, self.links, self.marks)
        if self.ghost is not None:
            _draw_ghost(draw, self.camera, self.scene, [g[f] for g in self.ghost])
        if self.front.getbbox() is not None:
            canvas = Image.alpha_composite(canvas.convert("RGBA"), self.front).convert("RGB")
        return canvas


def _palette(frames: list[Image.Image]) -> Image.Image:
    """One palette for every frame, from a few frames side by side: colours stay the same from
    frame to frame and the file needs one global palette (Pillow writes only the part of each
    frame that changed)."""
    picks = [frames[k] for k in np.linspace(0, len(frames) - 1, min(6, len(frames))).astype(int)]
    w, h = picks[0].size
    sheet = Image.new("RGB", (w, h * len(picks)))
    for k, im in enumerate(picks):
        sheet.paste(im, (0, k * h))
    return sheet.quantize(colors=256, method=Image.Quantize.MEDIANCUT)


def animate(
    scene: Scene,
    runs: Sequence[tuple[str, Trajectory | str]],
    path: str | Path,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Write the GIF of `runs` of `scene` to `path`: one panel per (label, run), a run being a
    `Trajectory` or the reason it failed, in order, at most MAX_COLUMNS side by side.

    `progress(done, total)` is called after each frame. Returns `path`.
    """
    if not runs:
        raise ValueError("animate needs at least one run")
    panels = [panel_of(label, run, scene) for label, run in runs]
    times = frame_times(panels, scene.duration)
    renderer = _Renderer(scene, panels, ghost_tracks(scene, times), times)
    frames = []
    for f in range(len(times)):
        frames.append(renderer.frame(f))
        if progress is not None:
            progress(f + 1, len(times))
    palette = _palette(frames)
    indexed = [im.quantize(palette=palette, dither=Image.Dither.NONE) for im in frames]
    frame_ms = round(np.clip(1000 * LOOP_S / len(indexed), *FRAME_MS_RANGE))
    durations = [frame_ms] * (len(indexed) - 1) + [LAST_FRAME_MS]
    path = Path(path)
    with atomic_path(path) as tmp:
        indexed[0].save(
            tmp,
            format="GIF",
            save_all=True,
            append_images=indexed[1:],
            duration=durations,
            loop=0,
        )
    return path
