"""One engine interface for every engine, and the registry of engines by name.

The registry `ENGINES` is filled by `register`; `register_engines` loads engines from a table of
names to "module:Class" targets, the form an entry point takes. The built-in engines are the
table `BUILT_IN_ENGINES`, loaded when this module is first imported.
"""

import importlib
import math
from collections.abc import Mapping
from typing import Protocol

from cases.errors import InputError
from cases.scene import Scene
from comparators.parity import ParityError, check_parity
from comparators.trajectory import Trajectory


class Engine(Protocol):
    """An engine runs a scene and returns the suite's trajectory table.

    `run` builds the engine's own model from the scene alone, steps it with `integrator` and
    `dt` for `duration` seconds, and reports model building and compilation as `setup_s`,
    apart from stepping (`wall_s`).
    """

    name: str
    integrators: tuple[str, ...]
    default_integrator: str
    orders: dict[str, int]  # the convergence order each integrator should show in dt
    missing: str | None  # why the engine cannot run here (its package is absent), else None

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory: ...


ENGINES: dict[str, Engine] = {}
# The engines shipped with the suite, in the order tables list them: name -> "module:Class".
BUILT_IN_ENGINES = {
    "mujoco": "comparators.mujoco_engine:MujocoEngine",
    "pybullet": "comparators.pybullet_engine:PybulletEngine",
    "reference": "comparators.reference:ReferenceEngine",
}


def failure_reason(exc: Exception) -> str:
    """One line saying why a run failed, for tables that report failures instead of raising."""
    if isinstance(exc, ParityError):
        return f"parity: {exc}"
    return f"{type(exc).__name__}: {exc}".splitlines()[0][:200]


def register(engine: Engine) -> Engine:
    """Add `engine` to `ENGINES` under its name (replacing one of the same name)."""
    ENGINES[engine.name] = engine
    return engine


def load_engine(target: str) -> Engine:
    """The engine a "module:Class" target names: the class imported and instantiated."""
    module, _, attribute = target.partition(":")
    return getattr(importlib.import_module(module), attribute)()


def register_engines(targets: Mapping[str, str]) -> None:
    """`register` the engine of every name -> "module:Class" target, in order."""
    for name, target in targets.items():
        engine = load_engine(target)
        if engine.name != name:
            raise ValueError(f"engine {target!r} is named {engine.name!r}, registered as {name!r}")
        register(engine)


def get_engine(name: str) -> Engine:
    try:
        return ENGINES[name]
    except KeyError:
        raise InputError(f"unknown engine {name!r}: expected one of {', '.join(ENGINES)}") from None


def run(
    scene: Scene,
    engine: str,
    integrator: str | None = None,
    dt: float | None = None,
    duration: float | None = None,
) -> Trajectory:
    """Run `scene` on the named engine; None means the engine's or the scene's default.

    Bad names and non-positive or non-finite dt or duration raise `InputError`; a model that
    differs from the scene at t = 0 raises `comparators.parity.ParityError`.
    """
    eng = get_engine(engine)
    integrator = eng.default_integrator if integrator is None else integrator
    if integrator not in eng.integrators:
        raise InputError(
            f"unknown integrator {integrator!r} for engine {engine!r}: "
            f"expected one of {', '.join(eng.integrators)}"
        )
    dt = scene.dt if dt is None else dt
    duration = scene.duration if duration is None else duration
    for key, value in (("dt", dt), ("duration", duration)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise InputError(f"{key}: expected a finite number > 0, got {value!r}")
    if dt > duration:
        raise InputError(f"dt {dt} is longer than duration {duration}: expected dt <= duration")
    traj = eng.run(scene, integrator, float(dt), float(duration))
    check_parity(scene, traj.meta)
    return traj


register_engines(BUILT_IN_ENGINES)
