"""One engine interface for every engine, and the registry of engines by name.

Engines are discovered through the entry-point group `rigidbench.engines` (name = "module:Class"),
the built-in ones included (rigidbench's own `pyproject.toml` declares them), when this module is
first imported, and each is loaded the first time it is asked for. A plugin that fails to load
is registered as an `UnloadableEngine`: listed with its reason, never run, and never in the way
of the others.
"""

import dataclasses
from collections.abc import MutableMapping
from importlib import metadata
from typing import Protocol

from cases.errors import InputError
from cases.scene import Scene
from comparators.engine_output import NOTE_PREFIX, captured_output
from comparators.limits import check_run
from comparators.parity import FLOAT64_EPSILON, ParityError, check_parity
from comparators.trajectory import COLUMNS, Trajectory


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

    # Optional: `unsupported(scene) -> str | None`, why the engine cannot model `scene` (for
    # example contact), else None. Sweeps, benches and scaling leave such runs out and say so.
    # Optional: `epsilon: float`, the machine epsilon of the engine's arithmetic (float32's for a
    # single-precision engine); float64's when absent. The parity check's tolerance scales with it.

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory: ...


class Registry(MutableMapping):
    """Engines by name, in the order they were added. An entry point is loaded (its module
    imported, its engine made) the first time its engine is asked for, so that a command using
    one engine, or none, does not import the others' packages (Drake, DART, SAPIEN, MuJoCo and
    their adapters took 0.6 s of every command's start)."""

    def __init__(self):
        self._engines: dict[str, Engine | None] = {}  # None: not loaded yet
        self._entry_points: dict[str, metadata.EntryPoint] = {}

    def add(self, entry_point: metadata.EntryPoint) -> None:
        self._engines[entry_point.name] = None
        self._entry_points[entry_point.name] = entry_point

    def __getitem__(self, name: str) -> Engine:
        engine = self._engines[name]
        if engine is None:
            engine = self._engines[name] = load_engine(self._entry_points.pop(name))
        return engine

    def __setitem__(self, name: str, engine: Engine) -> None:
        self._engines[name] = engine
        self._entry_points.pop(name, None)

    def __delitem__(self, name: str) -> None:
        del self._engines[name]
        self._entry_points.pop(name, None)

    def __iter__(self):
        return iter(self._engines)

    def __len__(self) -> int:
        return len(self._engines)

    def __contains__(self, name: object) -> bool:  # without loading it
        return name in self._engines


ENGINES = Registry()
ENTRY_POINT_GROUP = "rigidbench.engines"


class ContractError(RuntimeError):
    """An engine returned something other than the suite's trajectory table for the scene: a bug
    in its adapter (or plugin), not in the input; the message names the engine and what is off."""


def check_contract(scene: Scene, engine: str, traj: object) -> None:
    """Raise `ContractError` unless `traj` is a `Trajectory` with every column of `COLUMNS` and
    rows for exactly the scene's bodies."""
    if not isinstance(traj, Trajectory):
        raise ContractError(
            f"engine {engine!r} returned {type(traj).__name__}: expected a Trajectory"
        )
    absent = [c for c in COLUMNS if c not in traj.table.columns]
    if absent:
        raise ContractError(
            f"engine {engine!r} returned a table without {', '.join(absent)}: "
            f"expected the columns {', '.join(COLUMNS)}"
        )
    bodies, expected = set(traj.bodies), {b.name for b in scene.bodies}
    if bodies != expected:
        raise ContractError(
            f"engine {engine!r} returned rows for bodies {sorted(bodies)}: "
            f"expected the scene's {sorted(expected)}"
        )


class EngineFailure(RuntimeError):
    """An engine raised while running a scene the suite accepted: its own limit or a bug in it
    or its adapter; the message names engine, case and `failure_reason`."""


class UnloadableEngine:
    """A plugin that failed to load: `missing` says which and why; it has nothing to run."""

    integrators: tuple[str, ...] = ()
    default_integrator = "-"
    orders: dict[str, int] = {}

    def __init__(self, name: str, missing: str):
        self.name, self.missing = name, missing

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        raise RuntimeError(self.missing)


def failure_reason(exc: Exception) -> str:
    """One line saying why a run failed, for tables that report failures instead of raising,
    followed by what the engine said before it failed (`run`'s note), where it said anything."""
    if isinstance(exc, ParityError):
        reason = f"parity: {exc}"
    else:
        reason = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
    said = [n for n in getattr(exc, "__notes__", ()) if n.startswith(NOTE_PREFIX)]
    return "; ".join([reason, *said])


def register(engine: Engine) -> Engine:
    """Add `engine` to `ENGINES` under its name (replacing one of the same name)."""
    ENGINES[engine.name] = engine
    return engine


def load_engine(entry_point: metadata.EntryPoint) -> Engine:
    """The engine an entry point names, instantiated; an `UnloadableEngine` saying why when
    importing or instantiating it raises, or when it calls itself by another name."""
    where = f"plugin {entry_point.value!r}"
    try:
        engine = entry_point.load()()
    except Exception as exc:  # a broken plugin must not stop the suite: say why, go on
        return UnloadableEngine(entry_point.name, f"{where} failed to load: {failure_reason(exc)}")
    name = getattr(engine, "name", None)
    if name != entry_point.name:
        return UnloadableEngine(
            entry_point.name, f"{where} is named {name!r}, registered as {entry_point.name!r}"
        )
    return engine


def register_engines(entry_points) -> None:
    """Add every entry point to `ENGINES`, by name (the order tables list them), to be loaded
    when its engine is first asked for."""
    for entry_point in sorted(entry_points, key=lambda e: e.name):
        ENGINES.add(entry_point)


def unsupported(engine: Engine, scene: Scene) -> str | None:
    """Why `engine` cannot model `scene` (its optional `unsupported` method), else None; a
    method that raises counts as a refusal, with its reason."""
    check = getattr(engine, "unsupported", None)
    if check is None:
        return None
    try:
        return check(scene)
    except Exception as exc:  # a broken plugin must not stop a sweep's planning
        return f"its unsupported() raised {failure_reason(exc)}"


def left_out(scenes: list[Scene], engines: list[str]) -> list[str]:
    """One line per engine the registry holds but cannot run here (why: its `missing`), and per
    selected engine and reason the cases it cannot model."""
    lines = [f"{n}: {e.missing}" for n, e in ENGINES.items() if n not in engines and e.missing]
    for name in engines:
        refused: dict[str, list[str]] = {}
        for scene in scenes:
            reason = unsupported(ENGINES[name], scene)
            if reason:
                refused.setdefault(reason, []).append(scene.name)
        lines += [f"{name} on {', '.join(c)}: {reason}" for reason, c in refused.items()]
    return lines


def get_engine(name: str) -> Engine:
    if not ENGINES:  # no entry points: the package's metadata is missing or predates them
        raise InputError(
            f"unknown engine {name!r}: no engine is registered; install rigidbench "
            f"(pip install -e .) so that its entry points {ENTRY_POINT_GROUP!r} exist"
        )
    try:
        return ENGINES[name]
    except KeyError:
        raise InputError(f"unknown engine {name!r}: expected one of {', '.join(ENGINES)}") from None


def check_engine(scene: Scene, engine: str, integrator: str | None = None) -> tuple[Engine, str]:
    """The named engine and integrator (None: its default) for `scene`, or `InputError` for
    an unknown name, an unavailable engine (`missing`: its package absent, or a plugin that
    failed to load) or a scene the engine does not model (`unsupported`): what `run` checks
    before it starts, for commands that check before they say they are running."""
    eng = get_engine(engine)
    if eng.missing:
        raise InputError(f"engine {engine!r} is unavailable: {eng.missing}")
    refusal = unsupported(eng, scene)
    if refusal:
        raise InputError(f"engine {engine!r} cannot run {scene.name!r}: {refusal}")
    integrator = eng.default_integrator if integrator is None else integrator
    if integrator not in eng.integrators:
        raise InputError(
            f"unknown integrator {integrator!r} for engine {engine!r}: "
            f"expected one of {', '.join(eng.integrators)}"
        )
    return eng, integrator


def run(
    scene: Scene,
    engine: str,
    integrator: str | None = None,
    dt: float | None = None,
    duration: float | None = None,
) -> Trajectory:
    """Run `scene` on the named engine; None means the engine's or the scene's default.

    What `check_engine` refuses, and a dt or duration that is not a finite number > 0 or makes
    the run larger than its limits (`comparators.limits`), raise `InputError`; a result that
    is not the trajectory table of the scene's bodies raises `ContractError`, and a model that
    differs from the scene at t = 0 `comparators.parity.ParityError`.

    What the engine prints or warns while it runs is captured
    (`comparators.engine_output.captured_output`, around the engine's whole run, so outside its
    timed regions) into the trajectory's `RunMeta.messages`; when the run raises, into a note
    on the exception, which `failure_reason` keeps.
    """
    eng, integrator = check_engine(scene, engine, integrator)
    dt = scene.dt if dt is None else dt
    duration = scene.duration if duration is None else duration
    check_run(scene, dt, duration)
    output = None
    try:
        with captured_output() as output:
            traj = eng.run(scene, integrator, float(dt), float(duration))
        check_contract(scene, engine, traj)
        said = {**traj.meta.messages, **output.messages}
        traj = dataclasses.replace(traj, meta=dataclasses.replace(traj.meta, messages=said))
        check_parity(scene, traj.meta, getattr(eng, "epsilon", FLOAT64_EPSILON))
    except Exception as exc:
        if output is not None and output.messages:
            exc.add_note(output.note())
        raise
    return traj


register_engines(metadata.entry_points(group=ENTRY_POINT_GROUP))
