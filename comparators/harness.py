"""What an engine adapter calls to run a scene the suite's way: `RunTimer` times model building
apart from stepping and assembles the run's `RunMeta` and `Trajectory`; `sample_steps` gives the
step indices every engine samples.

An adapter's `Engine.run` follows this outline::

    timer = RunTimer(scene, "my_engine", integrator, dt, duration)
    with timer.setup():  # model building, compilation, the parity readback
        model = build(scene, integrator, dt)
        bodies = read_back(model)  # `comparators.parity.body_readback` per body, before stepping
    steps = sample_steps(timer.n_steps, timer.stride)
    with timer.stepping():  # stepping and recording samples, nothing else
        states = step(model, steps)
    meta = timer.meta(package_versions("my_engine"), settings(model), bodies)
    return timer.trajectory(steps, samples_from(states), meta)
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from cases.scene import Scene
from comparators.trajectory import RunMeta, Trajectory

# A single-precision engine multiplies up to three of a scene's quantities (m r^2, I w^2): each
# within FLOAT32_SPAN of 1 (or 0), the products stay within float32's range (1.2e-38 to 3.4e38).
FLOAT32_SPAN = 1e12


def outside_float32(scene: Scene) -> str | None:
    """Why a single-precision engine cannot hold `scene`, else None: a number of the scene or
    a body's principal moment or energy, not 0, outside 1 / FLOAT32_SPAN to FLOAT32_SPAN. For an
    adapter's `unsupported`."""
    numbers = {"gravity": scene.gravity}
    numbers.update({f"plane {k} point": p.point for k, p in enumerate(scene.planes)})
    for b in scene.bodies:
        w = np.asarray(b.angular_velocity)
        numbers.update(
            {
                f"body {b.name!r} particles": np.asarray(b.particles).ravel(),
                f"body {b.name!r} particle radius": b.particle_radius,
                f"body {b.name!r} velocity": b.velocity,
                f"body {b.name!r} angular velocity": w,
                f"body {b.name!r} principal moments": np.linalg.eigvalsh(b.inertia),
                f"body {b.name!r} kinetic energy": 0.5 * b.mass * np.dot(b.velocity, b.velocity),
                f"body {b.name!r} rotational energy": 0.5 * w @ b.inertia @ w,
            }
        )
    for what, values in numbers.items():
        sizes = np.abs(np.atleast_1d(np.asarray(values, dtype=float)))
        sizes = sizes[sizes > 0]
        if sizes.size and not (1 / FLOAT32_SPAN <= sizes.min() and sizes.max() <= FLOAT32_SPAN):
            worst = sizes.max() if sizes.max() > FLOAT32_SPAN else sizes.min()
            return (
                f"its {what} include {worst:.3g}, outside 1e-12 to 1e12: single precision "
                "cannot hold the products the engine forms of it"
            )
    return None


def check_run_call(engine: str, unavailable: str | None, integrator: str, integrators) -> None:
    """What an adapter's run function checks first: its engine imported (`unavailable`, the
    reason if not) and `integrator` one of `integrators`."""
    if unavailable is not None:
        raise RuntimeError(f"engine {engine!r} is unavailable: {unavailable}")
    if integrator not in integrators:
        raise ValueError(f"unknown integrator {integrator!r}: expected one of {tuple(integrators)}")


def sample_steps(n_steps: int, stride: int) -> np.ndarray:
    """The step indices every engine samples: 0, every `stride` steps, and the last one."""
    steps = np.arange(0, n_steps + 1, stride)
    return steps if steps[-1] == n_steps else np.append(steps, n_steps)


class RunTimer:
    """One run of `scene` on an engine: its step count and sampling, the time spent building
    (`setup_s`: model building and compilation) and stepping (`wall_s`), and its `RunMeta`.

    Attributes:
      n_steps: steps of `dt` the run takes to cover `duration` (`Scene.steps`).
      stride: steps between samples (`Scene.sample_stride`).
      setup_s, wall_s: seconds spent in `setup()` and in `stepping()` blocks (summed).
    """

    def __init__(self, scene: Scene, engine: str, integrator: str, dt: float, duration: float):
        self.scene, self.engine, self.integrator, self.dt = scene, engine, integrator, dt
        self.n_steps = scene.steps(dt, duration)
        self.stride = scene.sample_stride(dt)
        self.setup_s = 0.0
        self.wall_s = 0.0

    def setup(self):
        """Time the block as model building (`setup_s`)."""
        return self._timed("setup_s")

    def stepping(self):
        """Time the block as stepping (`wall_s`)."""
        return self._timed("wall_s")

    @contextmanager
    def _timed(self, attribute: str) -> Iterator[None]:
        """Add the block's wall time to `attribute`, also when the block raises."""
        start = time.perf_counter()
        try:
            yield
        finally:
            setattr(self, attribute, getattr(self, attribute) + time.perf_counter() - start)

    def add_times(self, setup_s: float, wall_s: float) -> None:
        """Add times an engine measured itself (the reference simulator times its compilation
        warm-up and its stepping inside one call)."""
        self.setup_s += setup_s
        self.wall_s += wall_s

    def meta(
        self,
        versions: dict[str, str],
        settings: dict[str, object],
        bodies: dict[str, dict],
        solver: dict[str, float] | None = None,
    ) -> RunMeta:
        """The run's `RunMeta`: the times so far, the parity manifest `settings`, the model read
        back from the engine before stepping (`bodies`) and the contact solver's report."""
        return RunMeta(
            case=self.scene.name,
            engine=self.engine,
            integrator=self.integrator,
            dt=self.dt,
            steps=self.n_steps,
            duration=self.n_steps * self.dt,
            setup_s=self.setup_s,
            wall_s=self.wall_s,
            versions=versions,
            settings=settings,
            bodies=bodies,
            solver=solver or {},
        )

    def trajectory(
        self,
        steps: np.ndarray,
        samples: np.ndarray,
        meta: RunMeta,
        extra: dict | None = None,
        particles: np.ndarray | None = None,
    ) -> Trajectory:
        """The trajectory table from the sampled step indices (S,) and the samples (S, B, 13)
        in `comparators.trajectory.STATE` order, per body in scene order; t = step * dt.

        `extra` maps optional columns to (S, B) arrays; `particles` (S, N, 3) are the world
        positions of every particle, bodies packed in scene order, for an engine whose bodies
        deform (`Trajectory.particles`)."""
        names = [b.name for b in self.scene.bodies]
        by_body = None
        if particles is not None:
            ends = np.cumsum([len(b.particles) for b in self.scene.bodies])
            parts = np.split(np.asarray(particles), ends[:-1], axis=1)
            by_body = dict(zip(names, parts, strict=True))
        return Trajectory.from_samples(steps * self.dt, names, samples, meta, extra, by_body)
