"""Gate files: limits on the suite's own measures for a case run on an engine, read from TOML.

A gate file holds one or more gates (top-level array `[[gates]]`, nothing else). Numbers may be
written as integers; strings and booleans are not numbers and `nan` / `inf` are refused. Any key
not listed here is an error.

  Key            Type                          Default         Meaning
  name           name (letters digits _ . -)   required        the gate's name, unique in its file
  case           string                        required        a catalog name, or a case file's
                                                               path relative to the gate file
  description    string                        ""              why the gate exists
  engine         string                        absent          the engine; required unless a
                                                               command retargets the gates
  integrator     string                        the engine's    an integrator of the engine, or
                                               default         "*": each of them
  dt             number > 0, or an array of    the case's dt   the time step(s), s
                 distinct numbers > 0
  duration       number > 0                    the case's      simulated time, s
  [gates.limits] table, >= 1 entry             required        measure = limit

Measures (`MEASURES_HELP`):
  a numeric column of the results table (`comparators.sweep.RESULT_COLUMNS`): energy_drift,
    angular_momentum_drift, position_error, orientation_error_deg, rest_height_error, ...;
  an outcome quantity (`comparators.outcomes`), `[<body>.]<quantity>` for its measured value,
    `<quantity>.error` for measured - expected, `<quantity>.relative_error` for that over
    |expected| (quantities with a closed form only);
  `verdict`, `order` (fitted orientation-error order over the dt list, at least
    `reports.convergence.MIN_FIT_POINTS` dt), `largest_stable_dt` (over the dt list).

Limits: a table of `max`, `min`, `abs_max` (|value| <= x), combinable; `order` takes
`declared_within` (|order - the integrator's declared order| <= x), `min`, `max`;
`largest_stable_dt` takes `min`, `max`; `verdict` is a verdict or an array of accepted verdicts
(`VERDICT_NAMES`; "failed" accepts any failed run).

Every problem raises `InputError` with one line naming the file, the gate and the key:
  FILE: gate 'NAME': key 'limits.energy_drift.max': expected a finite number, got nan
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cases.errors import InputError
from cases.scene import Scene
from cases.toml_io import MAX_TOML_BYTES, read_toml, resolve_case
from comparators.sweep import RESULT_COLUMNS
from reports.convergence import MIN_FIT_POINTS

NAME_PATTERN = re.compile(r"^[A-Za-z0-9_.-]+$")
GATE_KEYS = ("name", "case", "description", "engine", "integrator", "dt", "duration", "limits")
REQUIRED_KEYS = ("name", "case", "limits")
ALL_INTEGRATORS = "*"

# Results-table columns a gate can limit: the numeric ones (`comparators.sweep.RESULT_COLUMNS`
# without its labels and text), derived so that a new results column is a measure at once.
RESULT_LABELS = (
    "case",
    "engine",
    "integrator",
    "dt",
    "repeats",
    "reference",
    "first_engine_message",
    "verdict",
    "engine_version",
    "code_version",
    "key",
)
RESULT_MEASURES = tuple(c for c in RESULT_COLUMNS if c not in RESULT_LABELS)
# The quantities `comparators.outcomes` measures (apex heights as apex_height_<k>); the per-body
# ones are written `<body>.<quantity>` on scenes of several bodies, as the outcomes table does.
OUTCOME_QUANTITIES = (
    "rest_com_height",
    "rebound_ratio",
    "stopping_distance",
    "stopping_time",
    "spin_angle",
    "spin_time",
    "slope_acceleration",
    "slides",
    "lift",
    "sideways",
    "creep",
    "jitter_rms",
    "penetration",
    "standing",
    "top_drift",
    "max_penetration",
    "momentum_change",
    "angular_momentum_change",
    "flip_period",
)
APEX_PATTERN = re.compile(r"^apex_height_[1-9][0-9]*$")
# Quantities without a closed form (expected NaN): no `.error` or `.relative_error`.
WITHOUT_EXPECTED = ("max_penetration",)
OUTCOME_SUFFIXES = ("error", "relative_error")
# Measures over the gate's whole dt list rather than at each dt.
OVER_DT_MEASURES = ("order", "largest_stable_dt")
# Verdicts a `verdict` limit may accept (`comparators.verdict.VERDICTS`, and "failed" for any
# run that produced no trajectory, whatever its reason).
VERDICT_NAMES = ("ok", "diverged", "dissipated", "tunnelled", "jitter", "failed")
LIMIT_KINDS = ("max", "min", "abs_max", "declared_within")
KINDS_BY_MEASURE = {"order": ("declared_within", "min", "max"), "largest_stable_dt": ("min", "max")}
DEFAULT_KINDS = ("max", "min", "abs_max")
MEASURES_HELP = (
    "a numeric results column (energy_drift, angular_momentum_drift, position_error, ...), "
    "an outcome quantity ([<body>.]rebound_ratio, stopping_distance, ...) optionally with "
    ".error or .relative_error, verdict, order or largest_stable_dt"
)


@dataclass(frozen=True)
class Limit:
    """The limit on one measure: bounds that all have to hold, or the accepted verdicts.

    Attributes:
      measure: what is limited (see the module's docstring).
      max, min, abs_max: value <= max, value >= min, |value| <= abs_max; None where not set.
      declared_within: `order` only: |order - the integrator's declared order| <= this.
      verdicts: `verdict` only: the accepted verdicts.
    """

    measure: str
    max: float | None = None
    min: float | None = None
    abs_max: float | None = None
    declared_within: float | None = None
    verdicts: tuple[str, ...] = ()

    @property
    def over_dt(self) -> bool:
        """Measured once over the gate's dt list, not at each dt."""
        return self.measure in OVER_DT_MEASURES


@dataclass(frozen=True)
class Gate:
    """One gate of a gate file, validated, its case resolved.

    Attributes:
      file: the gate file it was read from; name: unique within it.
      case: the case as written (catalog name or path relative to `file`); scene: that case,
        with `duration` applied.
      engine: None when the file leaves it to the command (--engine).
      integrator: None for the engine's default, ALL_INTEGRATORS for each of its integrators.
      dts: the time steps (s), in the file's order; the case's dt when the file gives none.
      duration: simulated time (s) when the file sets it, else None (the case's).
      limits: in the file's order.
    """

    file: Path
    name: str
    case: str
    scene: Scene
    engine: str | None
    integrator: str | None
    dts: tuple[float, ...]
    duration: float | None
    limits: tuple[Limit, ...]
    description: str = ""


def load_gates(paths: list[Path]) -> list[Gate]:
    """The gates of every file in `paths`; a directory stands for its `*.toml` files, found
    recursively and read in sorted order. Raises `InputError` for the first problem."""
    gates = []
    for path in _gate_files(paths):
        gates.extend(load_gate_file(path))
    return gates


def is_gate_file(path: Path) -> bool:
    """True when `path` holds gates (a top-level `[[gates]]` array), so that other TOML files
    beside gate files are left alone. A file that does not parse counts when a line of it opens
    `[[gates]]`, so that a broken gate file is reported rather than skipped."""
    try:
        return isinstance(read_toml(path).get("gates"), list)
    except InputError:
        if not path.is_file() or path.stat().st_size > MAX_TOML_BYTES:
            return False
        text = path.read_bytes().decode("utf-8", errors="replace")
        return any(line.strip().startswith("[[gates]]") for line in text.splitlines())


def load_gate_file(path: Path) -> list[Gate]:
    """The gates of one file, validated (see the module's docstring)."""
    path = Path(path)
    data = read_toml(path)
    extra = sorted(set(data) - {"gates"})
    if extra:
        raise InputError(f"{path}: unknown key '{extra[0]}' (expected one of: gates)")
    tables = data.get("gates")
    if not isinstance(tables, list) or not tables:
        got = "none" if tables is None else "an empty array" if tables == [] else _show(tables)
        raise InputError(f"{path}: key 'gates': expected an array of tables [[gates]], got {got}")
    gates, names = [], set()
    for index, table in enumerate(tables):
        gate = _read_gate(path, index, table)
        if gate.name in names:
            raise InputError(
                f"{path}: gate '{gate.name}': key 'name': expected a name unique in the file, "
                f"got a second '{gate.name}'"
            )
        names.add(gate.name)
        gates.append(gate)
    return gates


def measure_parts(measure: str) -> tuple[str, str]:
    """An outcome measure split into (quantity as the outcomes table names it, part): part is
    "measured", "error" or "relative_error"."""
    for suffix in OUTCOME_SUFFIXES:
        if measure.endswith("." + suffix):
            return measure.removesuffix("." + suffix), suffix
    return measure, "measured"


def is_outcome_measure(measure: str) -> bool:
    return measure not in RESULT_MEASURES and measure not in ("verdict", *OVER_DT_MEASURES)


# ---- reading -----------------------------------------------------------------------------------


def _gate_files(paths: list[Path]) -> list[Path]:
    files = []
    for path in map(Path, paths):
        if path.is_dir():
            found = sorted(path.rglob("*.toml"))
            if not found:
                raise InputError(f"{path}: no gate files (*.toml) in this directory")
            files.extend(found)
        elif path.exists():
            files.append(path)
        else:
            raise InputError(f"{path}: no such gate file or directory")
    return files


class _Where:
    """Prefixes errors with the file and the gate: `FILE: gate 'NAME': key 'KEY': ...`."""

    def __init__(self, path: Path, gate: str):
        self.path, self.gate = path, gate

    def error(self, key: str | None, message: str) -> InputError:
        where = f"{self.path}: {self.gate}: "
        return InputError(where + (f"key '{key}': " if key else "") + message)


def _show(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, dict):
        return "a table" if value else "an empty table"
    text = str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _number(where: _Where, key: str, value: Any, positive: bool = False) -> float:
    """A finite number (an int is one, a bool is not); > 0 when `positive`."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if ok and isinstance(value, int) and abs(value) > sys.float_info.max:
        raise where.error(
            key, f"expected a number of magnitude below 1.8e308 (float64), got {_show(value)}"
        )
    if not ok or not math.isfinite(value):
        raise where.error(key, f"expected a finite number, got {_show(value)}")
    if positive and value <= 0:
        raise where.error(key, f"expected a number > 0, got {_show(value)}")
    return float(value)


def _string(where: _Where, key: str, value: Any) -> str:
    if not isinstance(value, str) or not value:
        raise where.error(key, f"expected a non-empty string, got {_show(value)}")
    return value


def _read_gate(path: Path, index: int, table: Any) -> Gate:
    where = _Where(path, f"gates[{index}]")
    if not isinstance(table, dict):
        raise where.error(None, f"expected a table [[gates]], got {_show(table)}")
    for key in table:
        if key not in GATE_KEYS:
            raise where.error(
                None, f"unknown key '{key}' (expected one of: {', '.join(GATE_KEYS)})"
            )
    for key in REQUIRED_KEYS:
        if key not in table:
            raise where.error(None, f"missing key '{key}'")
    name = table["name"]
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise where.error("name", f"expected a name of letters, digits, _ . -, got {_show(name)}")
    where = _Where(path, f"gate '{name}'")
    case = _string(where, "case", table["case"])
    scene = _resolve(where, path, case)
    duration = None
    if "duration" in table:
        duration = _number(where, "duration", table["duration"], positive=True)
        if duration < scene.dt:
            raise where.error(
                "duration", f"expected at least the case's dt {scene.dt:g} s, got {duration:g}"
            )
        scene = dataclasses.replace(scene, duration=duration)
    dts = _dts(where, table.get("dt"), scene)
    engine = _string(where, "engine", table["engine"]) if "engine" in table else None
    integrator = (
        _string(where, "integrator", table["integrator"]) if "integrator" in table else None
    )
    description = table.get("description", "")
    if not isinstance(description, str):
        raise where.error("description", f"expected a string, got {_show(description)}")
    limits = _limits(where, table["limits"], dts)
    return Gate(path, name, case, scene, engine, integrator, dts, duration, limits, description)


def _resolve(where: _Where, path: Path, case: str) -> Scene:
    """The catalog case, or the case file at `case` relative to the gate file."""
    relative = Path(case)
    if relative.suffix == ".toml" or len(relative.parts) > 1:
        case = str(path.parent / relative)
    try:
        return resolve_case(case)
    except InputError as err:
        raise where.error("case", str(err)) from None


def _dts(where: _Where, value: Any, scene: Scene) -> tuple[float, ...]:
    if value is None:
        return (scene.dt,)
    values = value if isinstance(value, list) else [value]
    if not values:
        raise where.error("dt", "expected a number > 0 or an array of them, got []")
    dts = tuple(
        _number(where, f"dt[{i}]" if isinstance(value, list) else "dt", v, positive=True)
        for i, v in enumerate(values)
    )
    if len(set(dts)) != len(dts):
        raise where.error("dt", f"expected distinct time steps, got {_show(value)}")
    for dt in dts:
        if dt > scene.duration:
            raise where.error("dt", f"expected dt <= the duration {scene.duration:g} s, got {dt:g}")
    return dts


def _limits(where: _Where, table: Any, dts: tuple[float, ...]) -> tuple[Limit, ...]:
    if not isinstance(table, dict) or not table:
        raise where.error("limits", f"expected a table of measure = limit, got {_show(table)}")
    return tuple(_limit(where, measure, value, dts) for measure, value in table.items())


def _limit(where: _Where, measure: str, value: Any, dts: tuple[float, ...]) -> Limit:
    key = f"limits.{measure}"
    _check_measure(where, key, measure)
    if measure == "verdict":
        return Limit(measure, verdicts=_verdicts(where, key, value))
    kinds = KINDS_BY_MEASURE.get(measure, DEFAULT_KINDS)
    if not isinstance(value, dict) or not value:
        raise where.error(key, f"expected a table of {', '.join(kinds)}, got {_show(value)}")
    bounds = {}
    for kind, bound in value.items():
        if kind not in kinds:
            raise where.error(key, f"unknown limit '{kind}' (expected one of: {', '.join(kinds)})")
        bounds[kind] = _number(where, f"{key}.{kind}", bound)
        if kind in ("abs_max", "declared_within") and bounds[kind] < 0:
            raise where.error(f"{key}.{kind}", f"expected a number >= 0, got {_show(bound)}")
    if "min" in bounds and "max" in bounds and bounds["min"] > bounds["max"]:
        raise where.error(
            key, f"expected min <= max, got min {bounds['min']:g} > max {bounds['max']:g}"
        )
    if measure == "order" and len(dts) < MIN_FIT_POINTS:
        raise where.error(
            key,
            f"expected a dt list of at least {MIN_FIT_POINTS} time steps to fit an order, "
            f"got {len(dts)}",
        )
    return Limit(measure, **bounds)


def _verdicts(where: _Where, key: str, value: Any) -> tuple[str, ...]:
    values = value if isinstance(value, list) else [value]
    expected = f"a verdict or an array of them ({', '.join(VERDICT_NAMES)})"
    if not values or not all(isinstance(v, str) and v in VERDICT_NAMES for v in values):
        raise where.error(key, f"expected {expected}, got {_show(value)}")
    return tuple(values)


def _check_measure(where: _Where, key: str, measure: str) -> None:
    """Refuse a measure the suite does not measure (whether this case measures an outcome is
    known after its run: `gates.evaluate` says so in the check's reason)."""
    if measure in RESULT_MEASURES or measure in ("verdict", *OVER_DT_MEASURES):
        return
    quantity, part = measure_parts(measure)
    base = quantity.rsplit(".", 1)[-1]
    known = base in OUTCOME_QUANTITIES or APEX_PATTERN.match(base)
    if not known:
        raise where.error(key, f"unknown measure '{measure}': expected {MEASURES_HELP}")
    if part != "measured" and base in WITHOUT_EXPECTED:
        raise where.error(
            key, f"'{base}' has no closed form to have an {part}: expected '{quantity}' itself"
        )
