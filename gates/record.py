"""Record regression gates: today's measurements of cases on an engine, written as a gate file.

One gate per case and integrator of the engine, at the case's dt. Its limits: the verdict as it
is; each drift and pose error the run measures, and each outcome's error against its closed form,
at most `slack` times today's value plus the measure's noise floor (`FLOORS`); yes/no outcomes
(`slides`, `standing`) exactly as they are. A run that failed or diverged is recorded by its
verdict alone: nothing else it measured is a result.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import re
from pathlib import Path

import pandas as pd
import tomli_w

from cases.errors import InputError
from cases.scene import Scene
from comparators.cache import ResultsCache
from comparators.engine import ENGINES
from comparators.trajectory import atomic_path
from gates import DEFAULT_SLACK
from gates.evaluate import RunGroup, measure_groups
from gates.spec import WITHOUT_EXPECTED, load_gate_file
from reports.outputs import output_file

# Differences below these are noise, not a regression: a recorded limit is at least the floor.
FLOORS = {
    # relative drifts: rounding of ~1e-16 per step over up to 1e5 steps gives ~1e-11, and another
    # CPU's last bits (tests/trajectory_digests.py) as much again
    "energy_drift": 1e-10,
    "momentum_drift": 1e-10,
    "angular_momentum_drift": 1e-10,
    # a thousand times the rounding floors of the convergence fits (reports.convergence)
    "position_error": 1e-9,  # m
    "orientation_error_deg": 1e-6,
    # the floors the regression tables of tests/test_hard_cases.py held (2026-11-21)
    "rebound_ratio": 0.005,
    "stopping_distance": 1e-3,  # m
    "spin_angle": 1e-3,  # rad: a millimetre at the seed's cube's corners
    "slope_acceleration": 1e-3,  # m/s^2
    "jitter_rms": 1e-9,  # m/s
    "angular_momentum_change": 1e-12,
    "momentum_change": 1e-12,
    # a millimetre of a bounce's apex, a millisecond of a slide or a flip: well inside the
    # tolerances the closed forms are checked to (1 %)
    "apex_height": 1e-3,  # m
    "stopping_time": 1e-3,  # s
    "spin_time": 1e-3,  # s
    "flip_period": 1e-3,  # s
    # rest and sliding: a micrometre of height, lift, sideways stray or depth (soft contacts
    # settle 1e-5 m into the floor), a nanometre of creep or drift (rigid contacts stay put to
    # 1e-15 m)
    "rest_com_height": 1e-6,  # m
    "lift": 1e-6,  # m
    "sideways": 1e-6,  # m
    "penetration": 1e-6,  # m
    "max_penetration": 1e-6,  # m
    "creep": 1e-9,  # m
    "top_drift": 1e-9,  # m
}
RECORDED_RESULTS = (
    "energy_drift",
    "momentum_drift",
    "angular_momentum_drift",
    "position_error",
    "orientation_error_deg",
)
# Yes/no outcomes: recorded as they are.
EXACT_OUTCOMES = ("slides", "standing")
# Recorded limits are rounded up to this many significant digits, to read well in the file.
LIMIT_DIGITS = 3


def record(
    scenes: list[tuple[str, Scene]],
    engine: str,
    out: Path,
    cache: ResultsCache,
    slack: float = DEFAULT_SLACK,
    progress: bool = True,
    executor=None,
    console=None,
) -> int:
    """Write the gate file `out` (atomically) for `scenes` (as named on the command line, and
    the scene) on every integrator of `engine`, measured through `cache`; returns the number
    of gates. Checked before any run: the engine available, slack >= 1, `out` a .toml file in
    an existing directory."""
    check_out(out)
    if not (math.isfinite(slack) and slack >= 1):
        raise InputError(
            f"--slack {slack}: expected a number >= 1 (limits below today's values fail)"
        )
    eng = ENGINES.get(engine)
    if eng is None or eng.missing:
        why = f"expected one of {', '.join(ENGINES)}" if eng is None else eng.missing
        raise InputError(f"--engine {engine!r}: {why}")
    groups = [RunGroup(scene, engine, tuple(eng.integrators), (scene.dt,)) for _, scene in scenes]
    measured = measure_groups(groups, cache, progress, executor, console)
    blocks, versions = [], set()
    for (written, scene), group, runs in zip(scenes, groups, measured.groups, strict=True):
        if runs.refusal is not None:
            blocks.append(f"# {scene.name}: not recorded: {runs.refusal}\n")
            continue
        for integrator in group.integrators:
            result = runs.results[runs.results["integrator"] == integrator].iloc[0]
            versions.add(str(result["engine_version"]))
            at = runs.outcomes[runs.outcomes["integrator"] == integrator]
            name = _gate_name(f"{scene.name}_{integrator}")
            case = _case_reference(written, out)
            limits = _limits(result, at, slack)
            blocks.append(_gate_text(name, case, engine, integrator, scene.dt, limits))
    header = _header(engine, slack, versions)
    with atomic_path(out) as tmp:
        Path(tmp).write_text(header + "\n".join(blocks))
    return len(load_gate_file(out))


def check_out(out: Path) -> None:
    """--record OUT.toml: a .toml file in an existing writable directory."""
    output_file(str(out), "--record", (".toml",))


def _limits(result: pd.Series, outcomes: pd.DataFrame, slack: float) -> list[tuple[str, str]]:
    """(measure, TOML value with a comment saying what was measured), in file order."""
    verdict = str(result["verdict"])
    kind = "failed" if verdict.startswith("failed") else verdict
    said = " ".join(verdict.split())  # a failure's reason on one line
    limits = [("verdict", json.dumps(kind) + (f"  # {said}" if kind == "failed" else ""))]
    if kind in ("failed", "diverged"):
        return limits
    for measure in RECORDED_RESULTS:
        value = float(result[measure])
        if math.isfinite(value):
            limits.append((measure, _upper(value, slack, FLOORS[measure])))
    for row in outcomes.itertuples():
        quantity = row.quantity
        base = quantity.rsplit(".", 1)[-1]
        floor = FLOORS.get(re.sub(r"_[0-9]+$", "", base), 0.0)
        if not math.isfinite(row.measured):
            continue
        if base in EXACT_OUTCOMES:
            limits.append((quantity, f"{{ min = {row.measured!r}, max = {row.measured!r} }}"))
        elif base in WITHOUT_EXPECTED:
            limits.append((quantity, _upper(row.measured, slack, floor)))
        elif math.isfinite(row.error):
            measure = f"{quantity}.error"
            bound = _round_up(slack * abs(row.error) + floor)
            limits.append((measure, f"{{ abs_max = {bound!r} }}  # measured {row.error:.3g}"))
    return limits


def _upper(value: float, slack: float, floor: float) -> str:
    """`max` at slack times the value's size beyond it, plus the floor."""
    bound = _round_up(value + (slack - 1) * abs(value) + floor)
    return f"{{ max = {bound!r} }}  # measured {value:.3g}"


def _round_up(value: float) -> float:
    """`value` rounded up (towards +inf) to LIMIT_DIGITS significant digits."""
    if value == 0 or not math.isfinite(value):
        return value
    scale = 10 ** (math.floor(math.log10(abs(value))) - LIMIT_DIGITS + 1)
    return float(f"{math.ceil(value / scale) * scale:.{LIMIT_DIGITS}g}")


def _gate_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", text)


def _case_reference(written: str, out: Path) -> str:
    """The case as the gate file names it: a catalog name as is, a case file relative to the
    gate file's directory."""
    path = Path(written)
    if path.suffix != ".toml" and len(path.parts) == 1:  # as `cases.resolve_case` reads it
        return written
    return Path(os.path.relpath(path.resolve(), out.resolve().parent)).as_posix()


def _gate_text(name, case, engine, integrator, dt, limits) -> str:
    head = {"name": name, "case": case, "engine": engine, "integrator": integrator, "dt": dt}
    lines = ["[[gates]]", *(tomli_w.dumps({k: v}).strip() for k, v in head.items()), ""]
    lines.append("[gates.limits]")
    lines += [f"{_key(measure)} = {value}" for measure, value in limits]
    return "\n".join(lines) + "\n"


def _key(measure: str) -> str:
    return measure if re.fullmatch(r"[A-Za-z0-9_-]+", measure) else json.dumps(measure)


def _header(engine: str, slack: float, versions: set[str]) -> str:
    today = datetime.date.today().isoformat()
    with_versions = "; ".join(sorted(v for v in versions if v and v != "nan")) or "versions unknown"
    return (
        f"# Regression gates recorded by `rigidbench gate --record` on {today} for {engine}\n"
        f"# {with_versions}. Limits: today's value x {slack:g} plus a noise floor\n"
        "# (gates.record.FLOORS); verdicts and yes/no outcomes as they were.\n\n"
    )
