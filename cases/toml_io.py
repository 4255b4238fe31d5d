"""Read and write case files: one TOML file holds one `Scene`.

File format. Units are SI. Any number may be written as an integer (1 means 1.0); strings and
booleans are not numbers, `nan` / `inf` are rejected everywhere, and a number is 0 or of a size
between 1e-100 and 1e100 (`cases.scene.MAX_MAGNITUDE`). A vector is an array
[x, y, z] of 3 numbers. A name is a string of letters, digits, `_`, `.` and `-`. Any key not
listed here is an error. Positions are world coordinates at t = 0.

  Key                      Type, unit                Default    Meaning
  name                     name                      required   the case's name
  description              string                    ""         one line: what the case tests
  tags                     array of names            []         labels for selecting cases
  duration                 number > 0, s             required   simulated time
  dt                       number > 0, s             required   default time step; <= duration
  sample_interval          number > 0, s             absent     time between output samples;
                                                                absent: sample every step
  gravity                  vector, m/s^2             required   uniform gravitational acceleration
  [contact]                table                     absent     absent: no contact is modelled
  contact.restitution      number in [0, 1]          required   separating / approaching normal
                                                                speed
  contact.friction         number >= 0               required   Coulomb friction coefficient
  [expected]               table                     absent     predictions not derivable by
                                                                `cases.exact`
  expected.rest_com_height number > 0, m             absent     distance of the resting body's
                                                                COM from the plane it ends on
                                                                (normal most against gravity)
  expected.rebound_ratio   number in [0, 1]          absent     separating / approaching normal
                                                                speed of the COM at each bounce
  expected.apex_heights    array of numbers > 0, m   absent     clearance of the lowest particle
                                                                surface above the floor at the
                                                                top of bounce 1, 2, ...:
                                                                h0 e^(2k) for a drop from h0
  expected.stopping_distance
                           number > 0, m             absent     how far the COM slides along the
                                                                floor before friction stops it:
                                                                v0^2 / (2 mu g)
  expected.stopping_time   number > 0, s             absent     how long it slides: v0 / (mu g)
  expected.slope_acceleration
                           number >= 0, m/s^2        absent     the COM's acceleration down an
                                                                incline: 0 when friction holds
                                                                (tan theta <= mu), else
                                                                g (sin theta - mu cos theta)
  expected.spin_angle      number > 0, rad           absent     how far a body spun about the
                                                                normal of its plane turns before
                                                                friction stops it: w0^2 / (2 a),
                                                                a = mu g m r / I
  expected.spin_time       number > 0, s             absent     how long it spins: w0 / a
  [[planes]]               array of tables           []         static half-spaces; need [contact]
  planes.point             vector, m                 required   a point on the plane
  planes.normal            vector, non-zero          required   points into the free side; any
                                                                length (it is normalised)
  [[bodies]]               array of tables, >= 1     required   rigid bodies, unique names
  bodies.name              name                      required   the body's name
  bodies.particle_radius   number > 0, m             required   collision radius of every
                                                                particle; adds no inertia
  bodies.particles         array of [x, y, z, mass]  required   >= 1 rows; m and kg; mass > 0; not
                                                                all collinear
  bodies.velocity          vector, m/s               [0, 0, 0]  initial COM velocity
  bodies.angular_velocity  vector, rad/s             [0, 0, 0]  initial angular velocity

Every problem raises `InputError` with one line naming the file, the key and the expectation:

  FILE: cannot read file: REASON
  FILE: malformed TOML: TOMLLIB MESSAGE
  FILE: missing key 'KEY'
  FILE: unknown key 'KEY' (expected one of: KEYS)
  FILE: key 'KEY': expected WHAT, got VALUE
  FILE: key 'KEY': MESSAGE OF A CHECK IN cases.scene   (no "key" part for whole-scene checks)

KEY is a path such as `bodies[0].particles[1][3]`; indices count from 0.
"""

from __future__ import annotations

import json
import os
import re
import stat
import tomllib
from dataclasses import MISSING, fields, is_dataclass
from pathlib import Path
from typing import Any

import tomli_w
from pydantic import ValidationError

from cases.catalog import CATALOG, CUBE_RAIN_MAX, CUBE_RAIN_PREFIX, family_scene
from cases.errors import InputError
from cases.scene import Body, Contact, Expected, Plane, Scene

# Top-level keys in reading order: scalars first, then tables; used for writing files and for
# listing the allowed keys. Fields missing here follow in dataclass order.
_KEY_ORDER: dict[type, tuple[str, ...]] = {
    Scene: (
        "name",
        "description",
        "tags",
        "duration",
        "dt",
        "sample_interval",
        "gravity",
        "contact",
        "expected",
        "planes",
        "bodies",
    ),
}

# The dataclass a table key holds, to list the allowed keys when an unknown one turns up.
_TABLES: dict[str, type] = {
    "bodies": Body,
    "planes": Plane,
    "contact": Contact,
    "expected": Expected,
}

# Fixed-length rows by the key holding them; every other fixed-length array is a vector.
_ROW_SHAPES = {"particles": "4 numbers (x, y, z, mass)"}
_VECTOR_SHAPE = "3 numbers (x, y, z)"

# What each pydantic error type means in a case file. Fields: where ("key 'K': " or "" for the
# whole scene), key, got (the offending value), allowed, shape, count, length, error, and the
# error's ctx.
_MESSAGES = {
    "missing": "missing key '{key}'",
    "unexpected_keyword_argument": "unknown key '{key}' (expected one of: {allowed})",
    "extra_forbidden": "unknown key '{key}' (expected one of: {allowed})",
    "wrong_length": "{where}expected {shape}, got {count}",
    "float_type": "{where}expected a number, got {got}",
    "finite_number": "{where}expected a finite number, got {got}",
    "float_range": "{where}expected a number of magnitude below 1.8e308 (float64), got {got}",
    "greater_than": "{where}expected a number > {gt:g}, got {got}",
    "greater_than_equal": "{where}expected a number >= {ge:g}, got {got}",
    "less_than": "{where}expected a number < {lt:g}, got {got}",
    "less_than_equal": "{where}expected a number <= {le:g}, got {got}",
    "string_type": "{where}expected a string, got {got}",
    "string_pattern_mismatch": "{where}expected a name matching {pattern}, got {got}",
    "string_too_long": (
        "{where}expected a name of at most {max_length} characters (names become file names), "
        "got one of {length}"
    ),
    "tuple_type": "{where}expected an array, got {got}",
    "too_short": "{where}expected at least {min_length} item(s), got {got}",
    "dataclass_type": "{where}expected a table, got {got}",
    "value_error": "{where}{error}",
    "assertion_error": "{where}{error}",
}
_FALLBACK = "{where}{msg}, got {got}"

# The largest case or gate file read: 20 times the largest catalog scene as a file
# (cube_rain_1000, 0.78 MB); tomllib parses 16 MB of particles in about 3 s and 90 MB.
MAX_TOML_BYTES = 16 * 2**20


def load_scene(path: str | os.PathLike[str]) -> Scene:
    """Read and validate a TOML case file.

    Raises `InputError` with one line naming the file and the key for any problem: an unreadable
    file, malformed TOML, or a value the `Scene` dataclasses reject (only the first is reported).
    """
    path = Path(path)
    data = read_toml(path)
    if "gates" in data:
        raise InputError(
            f"{path}: a gate file (it has [[gates]]): expected a case file; gate files run with "
            "`rigidbench gate`"
        )
    try:
        return Scene(**data)
    except ValidationError as err:
        raise InputError(f"{path}: {_describe(err.errors()[0])}") from err


def read_toml(path: Path) -> dict[str, Any]:
    """The table a TOML file holds; `InputError` naming the file for anything that is not a
    regular UTF-8 file of at most MAX_TOML_BYTES holding valid TOML nested less deeply than the
    parser's recursion allows (a directory, a device or a FIFO is refused before it is opened,
    so reading can neither block nor run on)."""
    try:
        info = path.stat()
        if stat.S_ISDIR(info.st_mode):
            raise InputError(f"{path}: cannot read file: a directory, expected a TOML file")
        if not stat.S_ISREG(info.st_mode):
            raise InputError(f"{path}: cannot read file: not a regular file, expected a TOML file")
        if info.st_size > MAX_TOML_BYTES:
            raise InputError(
                f"{path}: cannot read file: {info.st_size / 2**20:.1f} MiB, over the limit of "
                f"{MAX_TOML_BYTES / 2**20:g} MiB for a case or gate file"
            )
        with path.open("rb") as file:
            raw = file.read(MAX_TOML_BYTES + 1)  # a file that grew since stat() stops here too
    except OSError as err:
        raise InputError(f"{path}: cannot read file: {err.strerror or err}") from err
    if len(raw) > MAX_TOML_BYTES:
        raise InputError(f"{path}: cannot read file: over the limit of {MAX_TOML_BYTES} bytes")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputError(
            f"{path}: cannot read file: not UTF-8 text ({err.reason} at byte {err.start})"
        ) from err
    # A byte order mark (Windows editors write one) is no part of TOML: read what follows it.
    text = text.removeprefix("\ufeff")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"{path}: malformed TOML: {err}") from err
    except RecursionError:
        raise InputError(
            f"{path}: malformed TOML: arrays or tables nested too deeply to parse"
        ) from None


def scene_to_toml(scene: Scene) -> str:
    """The case file text for `scene`: `load_scene` of it gives an equal scene.

    Keys holding their default are left out. Vectors sit on one line, particles one row per line.
    Floats are written by `repr`, the shortest text that reads back to the same float.
    """
    return "\n".join(_table_lines(scene, "", "")) + "\n"


def resolve_case(name_or_path: str) -> Scene:
    """The catalog scene called `name_or_path`, a family member (`cube_rain_N`), or else the
    case file at that path.

    An argument that is neither but looks like a path (it exists, ends in .toml or has a
    directory part) is read as a file, so a mistyped path reports the file's problem. A family
    name with a bad N (`cube_rain_0`) raises `InputError` saying which N are expected.
    """
    if name_or_path in CATALOG:
        return CATALOG[name_or_path]
    path = Path(name_or_path)
    looks_like_a_file = path.suffix == ".toml" or len(path.parts) > 1
    if not looks_like_a_file:
        scene = family_scene(name_or_path)
        if scene is not None:
            return scene
    if looks_like_a_file or (name_or_path and path.exists()):
        return load_scene(path)
    raise InputError(
        f"unknown case {name_or_path!r}: expected a catalog name ({', '.join(CATALOG)}), "
        f"{CUBE_RAIN_PREFIX}N (N from 1 to {CUBE_RAIN_MAX}) or a path to a .toml file"
    )


def _describe(error: dict[str, Any]) -> str:
    """One pydantic error as a message about the case file."""
    kind, loc, value = error["type"], error["loc"], error["input"]
    # A fixed-length tuple reports a short row as a missing index and a long one as too_long;
    # both are about the row's length, so name the row itself.
    if kind == "missing" and loc and isinstance(loc[-1], int):
        kind, loc = "wrong_length", loc[:-1]
    elif kind == "too_long":
        kind = "wrong_length"
    elif kind == "float_type" and isinstance(value, int) and not isinstance(value, bool):
        kind = "float_range"  # an integer too large for a float64
    names = [part for part in loc if isinstance(part, str)]
    key = _key_path(loc)
    fill = {
        **error.get("ctx", {}),
        "where": f"key '{key}': " if key else "",
        "key": key,
        "got": _show(value),
        "count": len(value) if isinstance(value, list | tuple) else _show(value),
        "length": len(value) if isinstance(value, str) else None,
        "shape": _ROW_SHAPES.get(names[-1] if names else "", _VECTOR_SHAPE),
        "allowed": ", ".join(_keys(_TABLES.get(names[-2] if len(names) > 1 else "", Scene))),
        "msg": error["msg"],
    }
    return _MESSAGES.get(kind, _FALLBACK).format(**fill)


def _key_path(loc: tuple[str | int, ...]) -> str:
    """('bodies', 0, 'particles', 1) -> 'bodies[0].particles[1]'. A key that is not a bare TOML
    key is quoted as TOML quotes it, so that a key named "contact.friction" is not taken for the
    friction of [contact]."""
    path = ""
    for part in loc:
        if isinstance(part, int):
            path += f"[{part}]"
        else:
            if not _BARE_KEY.fullmatch(part):
                part = json.dumps(part, ensure_ascii=False)
            path += f".{part}" if path else part
    return path


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _show(value: Any) -> str:
    """`value` as it would appear in the file, clipped so the message stays one short line."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value)  # quoted and escaped, so a newline cannot break the line
    elif isinstance(value, dict):
        text = "a table"
    elif isinstance(value, list | tuple):
        text = "[" + ", ".join(_show(item) for item in value) + "]"
    else:
        text = str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _keys(cls: type) -> list[str]:
    """The keys of the table holding a `cls`, in file order."""
    order = _KEY_ORDER.get(cls, ())
    names = [f.name for f in fields(cls)]
    return sorted(names, key=lambda n: order.index(n) if n in order else len(order))


def _table_lines(obj: Any, path: str, header: str) -> list[str]:
    """Lines for dataclass `obj` at dotted `path`: `header`, its values, then its sub-tables."""
    lines = [header] if header else []
    tables = []
    defaults = {f.name: f.default for f in fields(obj)}
    for name in _keys(type(obj)):
        value = getattr(obj, name)
        if defaults[name] is not MISSING and value == defaults[name]:
            continue
        sub = f"{path}.{name}" if path else name
        if is_dataclass(value):
            tables.append((value, sub, f"[{sub}]"))
        elif isinstance(value, tuple) and value and is_dataclass(value[0]):
            tables.extend((item, sub, f"[[{sub}]]") for item in value)
        else:
            lines.append(f"{name} = {_literal(value)}")
    for value, sub, sub_header in tables:
        lines += ["", *_table_lines(value, sub, sub_header)]
    return lines


def _literal(value: Any) -> str:
    """A TOML value: arrays of arrays one row per line, other arrays on one line."""
    if isinstance(value, tuple) and value and isinstance(value[0], tuple):
        return "[\n" + "".join(f"    {_literal(row)},\n" for row in value) + "]"
    if isinstance(value, tuple):
        return "[" + ", ".join(_literal(item) for item in value) + "]"
    # tomli_w escapes strings and writes floats by repr; its arrays put every item on a line.
    return tomli_w.dumps({"v": value}).removeprefix("v = ").rstrip("\n")
