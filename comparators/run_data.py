"""One run's trajectory and scene, read the way every verdict and outcome reads them: the
arrays computed once per run (`RunData`), particles placed rigidly, distances to planes, the
final window, and what the scene implies (which planes it touches, whether it expects rest).

Particles are placed rigidly from x, q and each body's t = 0 offsets (`particle_positions`). A
deforming engine (the seed) adds a `shape_error` column: at samples where its shape has changed
by more than RIGID_SHAPE_RTOL the rigid placement is not where its particles are, so their
distances to planes are unknown there (NaN, left out of every measurement) and only the COM is
tested for tunnelling (the COM of a cluster lies inside its particles' hull, so a COM behind a
plane means particles behind it too). `particle_tracks`, what an animation draws, places them
where the engine recorded them instead (`Trajectory.particles`), where it did.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cases.scene import Body, Plane, Scene
from comparators.metrics import body_arrays, conserved_quantities
from comparators.trajectory import Trajectory
from rigidmath.quaternion import quats_to_matrices

# Relative change of inter-particle distances (`shape_error`) below which a sample's rigid
# placement of the particles is theirs to 1e-6 of the body's size: micrometres, against
# particle radii of centimetres.
RIGID_SHAPE_RTOL = 1e-6
# A body starts in contact when a particle surface is this close to a plane or another body (m):
# placed touching, to rounding of metre-scale coordinates, with room for a placement by hand.
TOUCH_DISTANCE = 1e-6
# The final window, where a body that should rest must be resting: the last quarter of the run,
# at most 10 s. Cases give their bodies most of the run to settle; 10 s covers a 60 s rest.
FINAL_FRACTION = 0.25
FINAL_WINDOW_S = 10.0


class RunData:
    """One run's trajectory and scene, with the arrays every measurement reads computed once:
    per body the sample arrays (`arrays`: t, x, q, v, w), the rigidly placed particles, their
    distances to planes, and the conserved quantities."""

    def __init__(self, traj: Trajectory, scene: Scene):
        self.traj, self.scene = traj, scene
        self._memo: dict = {}

    def _cached(self, key, compute):
        if key not in self._memo:
            self._memo[key] = compute()
        return self._memo[key]

    def arrays(self, k: int) -> dict[str, np.ndarray]:
        """`comparators.metrics.body_arrays` of body `k` (scene order)."""
        return self._cached(
            ("arrays", k), lambda: body_arrays(self.traj, self.scene.bodies[k].name)
        )

    def rigid(self, k: int) -> np.ndarray:
        """(S,) True where the rigid placement is body k's particles (see the module doc)."""

        def compute():
            table = self.traj.table
            if "shape_error" not in table:
                return np.ones(len(self.arrays(k)["t"]), dtype=bool)
            rows = table["body"].to_numpy() == self.scene.bodies[k].name
            return table["shape_error"].to_numpy()[rows] <= RIGID_SHAPE_RTOL

        return self._cached(("rigid", k), compute)

    def particles(self, k: int) -> np.ndarray:
        """(S, n, 3) world positions of body k's particles, placed rigidly from x and q."""

        def compute():
            body, a = self.scene.bodies[k], self.arrays(k)
            r = quats_to_matrices(np.ascontiguousarray(a["q"]))
            return a["x"][:, None, :] + np.einsum("sij,nj->sni", r, body.positions - body.com)

        return self._cached(("particles", k), compute)

    def distances(self, k: int, plane: Plane) -> np.ndarray:
        """(S, n) signed distance (m) of body k's particle centres from `plane`, positive on its
        free side; NaN at deforming samples."""

        def compute():
            d = (self.particles(k) - plane.point) @ plane.unit_normal
            d[~self.rigid(k)] = np.nan
            return d

        return self._cached(("distances", k, plane), compute)

    def clearance(self, k: int, plane: Plane) -> np.ndarray:
        """(S,) gap (m) between `plane` and body k's lowest particle surface; negative when it
        penetrates; NaN at deforming samples."""
        radius = self.scene.bodies[k].particle_radius
        return self._cached(
            ("clearance", k, plane), lambda: self.distances(k, plane).min(axis=1) - radius
        )

    def conserved(self) -> pd.DataFrame:
        """`comparators.metrics.conserved_quantities` of the run."""
        return self._cached("conserved", lambda: conserved_quantities(self.traj, self.scene))

    def finite(self) -> bool:
        """True when every value of the table is finite."""

        def compute():
            values = self.traj.table.drop(columns=["body"]).to_numpy(dtype=float)
            return bool(np.isfinite(values).all())

        return self._cached("finite", compute)


def quantity_label(scene: Scene, body: Body, quantity: str) -> str:
    """An outcome's name for one body: `<body>.<quantity>` in a scene of several bodies."""
    return quantity if len(scene.bodies) == 1 else f"{body.name}.{quantity}"


def particle_positions(traj: Trajectory, scene: Scene, body_index: int) -> np.ndarray:
    """(S, n, 3) world positions of one body's particles at every sample, placed rigidly from
    its COM x, orientation q and the particles' offsets from the COM at t = 0."""
    return RunData(traj, scene).particles(body_index)


def particle_tracks(traj: Trajectory, scene: Scene) -> list[np.ndarray]:
    """Per body (scene order), (S, n, 3) world positions of its particles at every sample: as
    recorded where the engine records them (`Trajectory.particles`: a deforming body such as the
    seed's), else placed rigidly from the pose (`particle_positions`). What an animation draws."""
    recorded = traj.particles or {}
    run = RunData(traj, scene)
    return [
        recorded[body.name] if body.name in recorded else run.particles(k)
        for k, body in enumerate(scene.bodies)
    ]


def clearance(traj: Trajectory, scene: Scene, body_index: int, plane: Plane) -> np.ndarray:
    """(S,) gap (m) between `plane` and the body's lowest particle surface (`RunData.clearance`)."""
    return RunData(traj, scene).clearance(body_index, plane)


def particle_speeds(run: RunData, k: int) -> np.ndarray:
    """(S, n) speed (m/s) of each particle of rigidly moving body k: |v + omega x r|."""
    a = run.arrays(k)
    r = run.particles(k) - a["x"][:, None, :]
    return np.linalg.norm(a["v"][:, None, :] + np.cross(a["w"][:, None, :], r), axis=-1)


def contact_planes(scene: Scene) -> tuple[Plane, ...]:
    return scene.planes if scene.contact is not None else ()


def plane_under(scene: Scene, body: Body) -> Plane | None:
    """The plane a body starts nearest to among those facing against gravity: what it slides on."""
    g = np.asarray(scene.gravity)
    facing = [p for p in contact_planes(scene) if np.dot(p.unit_normal, g) < 0]
    if not facing:
        return None
    return min(facing, key=lambda p: ((body.positions - p.point) @ p.unit_normal).min())


def final_window(t: np.ndarray) -> np.ndarray:
    """(S,) True for the samples in the run's final window (FINAL_FRACTION, FINAL_WINDOW_S)."""
    span = min(FINAL_WINDOW_S, FINAL_FRACTION * (t[-1] - t[0]))
    return t >= t[-1] - span


def touching(scene: Scene, body: Body) -> bool:
    """True when the body starts in contact: a particle surface within TOUCH_DISTANCE of a plane
    or of another body's particle."""
    for plane in contact_planes(scene):
        gap = ((body.positions - plane.point) @ plane.unit_normal).min() - body.particle_radius
        if abs(gap) <= TOUCH_DISTANCE:
            return True
    for other in scene.bodies:
        if other is not body:
            d = np.linalg.norm(body.positions[:, None] - other.positions[None], axis=-1)
            if d.min() - body.particle_radius - other.particle_radius <= TOUCH_DISTANCE:
                return True
    return False


def starts_at_rest(scene: Scene, body: Body) -> bool:
    """Placed still and in contact: where it should stay, unlike a body dropped from rest."""
    still = not any(body.velocity) and not any(body.angular_velocity)
    return still and touching(scene, body)


def expects_rest(scene: Scene) -> bool:
    return scene.expected is not None and scene.expected.rest_com_height is not None
