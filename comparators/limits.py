"""What a run may ask for, checked before any engine allocates: a finite dt and duration with
dt <= duration, at most `max_steps` steps and at most `max_recorded` recorded particle positions
(samples times particles, what a run and its analyses hold in memory).

The defaults fit this machine; a larger run asks for it with `--max-steps` / `--max-recorded` on
the command line, which set the environment variables below so that worker processes and forked
children apply the same limits.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from cases.errors import InputError
from cases.scene import Scene

# 1,000 times the most steps of any run of the full report (bounce_e0.8 at dt/16: 96,000); the
# reference steps a single body about 10^6 times a second, so it is minutes of stepping at most.
MAX_STEPS = 10**8
# Peak memory of a run and its analyses per recorded particle position, rounded up from the 178 B
# measured on `dropped_cube` (2 million samples of 8 particles, run and summary;
# docs/measurement.md).
BYTES_PER_RECORDED = 200
# Share of physical memory one run may fill: the report runs two workers beside its own process.
MEMORY_SHARE = 0.25

STEPS_ENV = "RIGIDBENCH_MAX_STEPS"
RECORDED_ENV = "RIGIDBENCH_MAX_RECORDED"


@dataclass(frozen=True)
class Limits:
    """The largest run allowed: `steps` steps, `recorded` particle positions."""

    steps: int
    recorded: int


def default_recorded() -> int:
    """MEMORY_SHARE of this machine's physical memory, in recorded particle positions."""
    memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    return int(memory * MEMORY_SHARE / BYTES_PER_RECORDED)


def current_limits() -> Limits:
    """The limits in force: the environment's (set by the command line's options), else the
    defaults."""
    return Limits(
        steps=_from_env(STEPS_ENV, "--max-steps", MAX_STEPS),
        recorded=_from_env(RECORDED_ENV, "--max-recorded", default_recorded()),
    )


@contextmanager
def limits_set(steps: int | None, recorded: int | None) -> Iterator[None]:
    """Within the block, the limits given (None: as they were) hold for this process and every
    process it starts; afterwards the environment is as it was."""
    saved = {env: os.environ.get(env) for env in (STEPS_ENV, RECORDED_ENV)}
    for env, value in ((STEPS_ENV, steps), (RECORDED_ENV, recorded)):
        if value is not None:
            os.environ[env] = str(value)
    try:
        yield
    finally:
        for env, value in saved.items():
            if value is None:
                os.environ.pop(env, None)
            else:
                os.environ[env] = value


def check_run(scene: Scene, dt: float, duration: float) -> None:
    """Raise `InputError` unless running `scene` with `dt` for `duration` is within the limits:
    dt and duration finite numbers > 0, dt <= duration, steps and recorded particle positions
    at most `current_limits()`. Counted in floats first, so that no count can overflow."""
    for key, value in (("dt", dt), ("duration", duration)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            raise InputError(f"{key}: expected a finite number > 0, got {value!r}")
    if dt > duration:
        raise InputError(f"dt {dt:g} is longer than duration {duration:g}: expected dt <= duration")
    limits = current_limits()
    steps = duration / dt  # inf when it overflows, and then over any limit
    where = f"{scene.name!r} with dt {dt:g} for {duration:g} s"
    if not steps <= limits.steps + 0.5:
        raise InputError(
            f"{where} takes {steps:.3g} steps, over the limit of {limits.steps:.3g}: "
            f"expected a larger dt or a shorter duration, or raise it with --max-steps "
            f"(or {STEPS_ENV})"
        )
    samples = steps / scene.sample_stride(dt) + 2
    particles = sum(len(b.particles) for b in scene.bodies)
    recorded = samples * particles
    if recorded > limits.recorded:
        source = (
            f"a quarter of this machine's memory at {BYTES_PER_RECORDED} B each"
            if os.environ.get(RECORDED_ENV) is None
            else f"set by --max-recorded or {RECORDED_ENV}"
        )
        raise InputError(
            f"{where} records {samples:.3g} samples x {particles} particles = {recorded:.3g} "
            f"positions, over the limit of {limits.recorded:.3g} ({source}): expected a "
            f"sample_interval, a shorter duration, or raise it with --max-recorded "
            f"(or {RECORDED_ENV})"
        )


def whole_number(text: str) -> int | None:
    """`text` as a whole number, in digits or in float notation (1e9, as the defaults are
    shown); None when it is not one."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        return None
    return int(value) if math.isfinite(value) and value.is_integer() else None


def _from_env(env: str, option: str, default: int) -> int:
    text = os.environ.get(env)
    if text is None:
        return default
    value = whole_number(text)
    if value is None or value < 1:
        raise InputError(f"{option} ({env}): expected a whole number >= 1, got {text!r}")
    return value
