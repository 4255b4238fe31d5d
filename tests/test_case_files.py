"""TOML case files: catalog scenes round-trip, and every kind of bad input is one clear line."""

import dataclasses
import re
from pathlib import Path

import pytest
from pydantic import ValidationError

from cases import CATALOG, InputError, load_scene, resolve_case, scene_to_toml
from cases.toml_io import MAX_TOML_BYTES

# A valid case touching every table, so each invalid case below is a one-spot edit of it.
# `duration = 10` is an integer on purpose: integers are accepted where floats are expected.
BASE = """\
name = "probe"
duration = 10
dt = 0.01
gravity = [0.0, 0.0, -10.0]

[contact]
restitution = 0.0
friction = 0.5

[[planes]]
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]

[[bodies]]
name = "tri"
particle_radius = 0.2
particles = [
    [0.0, 0.0, 1.0, 1.0],
    [1.0, 0.0, 1.0, 1.0],
    [0.0, 1.0, 1.0, 1.0],
]
velocity = [0.0, 0.0, -2.0]
"""


def edit(old: str, new: str) -> str:
    """BASE with its one occurrence of `old` replaced by `new`."""
    assert BASE.count(old) == 1, old
    return BASE.replace(old, new)


def write(tmp_path, text: str | bytes, name: str = "case.toml"):
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("scene", CATALOG.values(), ids=CATALOG.keys())
def test_catalog_scene_round_trips(tmp_path, scene):
    assert load_scene(write(tmp_path, scene_to_toml(scene))) == scene


def test_written_text_omits_defaults_and_puts_one_particle_per_line():
    text = scene_to_toml(CATALOG["free_spin_cube"])
    for absent in ("[contact]", "planes", "expected", "\nvelocity = ", "None"):
        assert absent not in text
    assert "\n    [3.0, 3.0, 7.0, 1.0],\n" in text


def test_documented_example_loads(tmp_path):
    doc = (Path(__file__).parents[1] / "docs" / "case-format.md").read_text(encoding="utf-8")
    example = re.search(r"```toml\n(.*?)```", doc, re.DOTALL).group(1)
    assert load_scene(write(tmp_path, example)).expected.rest_com_height == 0.7


def test_base_case_is_valid(tmp_path):
    scene = load_scene(write(tmp_path, BASE))
    assert scene.duration == 10.0 and isinstance(scene.duration, float)


INVALID = {
    "missing key": (edit("duration = 10\n", ""), ["missing key 'duration'"]),
    "unknown top-level key": (
        edit('name = "probe"', 'name = "probe"\nbodys = 1'),
        ["unknown key 'bodys' (expected one of: name, description, tags, duration, dt, "],
    ),
    "unknown body key": (
        edit("particle_radius = 0.2", 'particle_radius = 0.2\ncolour = "red"'),
        ["unknown key 'bodies[0].colour' (expected one of: name, particle_radius, particles"],
    ),
    "string for number": (
        edit("dt = 0.01", 'dt = "0.01"'),
        ["key 'dt': expected a number, got \"0.01\""],
    ),
    "bool for number": (
        edit("friction = 0.5", "friction = true"),
        ["key 'contact.friction': expected a number, got true"],
    ),
    "velocity of 2": (
        edit("velocity = [0.0, 0.0, -2.0]", "velocity = [0.0, -2.0]"),
        ["key 'bodies[0].velocity': expected 3 numbers (x, y, z), got 2"],
    ),
    "particle row of 3": (
        edit("[1.0, 0.0, 1.0, 1.0]", "[1.0, 0.0, 1.0]"),
        ["key 'bodies[0].particles[1]': expected 4 numbers (x, y, z, mass), got 3"],
    ),
    "particle row of 5": (
        edit("[1.0, 0.0, 1.0, 1.0]", "[1.0, 0.0, 1.0, 1.0, 1.0]"),
        ["key 'bodies[0].particles[1]': expected 4 numbers (x, y, z, mass), got 5"],
    ),
    "nan": (
        edit("velocity = [0.0, 0.0, -2.0]", "velocity = [nan, 0.0, -2.0]"),
        ["key 'bodies[0].velocity[0]': expected a finite number, got nan"],
    ),
    "inf": (
        edit("gravity = [0.0, 0.0, -10.0]", "gravity = [0.0, 0.0, -inf]"),
        ["key 'gravity[2]': expected a finite number, got -inf"],
    ),
    "zero mass": (
        edit("[0.0, 1.0, 1.0, 1.0]", "[0.0, 1.0, 1.0, 0.0]"),
        ["key 'bodies[0].particles[2][3]': expected a number > 0, got 0.0"],
    ),
    "negative radius": (
        edit("particle_radius = 0.2", "particle_radius = -0.2"),
        ["key 'bodies[0].particle_radius': expected a number > 0, got -0.2"],
    ),
    "negative dt": (
        edit("dt = 0.01", "dt = -0.01"),
        ["key 'dt': expected a number > 0, got -0.01"],
    ),
    "zero duration": (
        edit("duration = 10", "duration = 0"),
        ["key 'duration': expected a number > 0, got 0"],
    ),
    "zero normal": (
        edit("normal = [0.0, 0.0, 1.0]", "normal = [0.0, 0.0, 0.0]"),
        ["key 'planes[0]': plane normal [0.0, 0.0, 0.0] is zero: expected a non-zero vector"],
    ),
    "collinear particles": (
        edit("[0.0, 1.0, 1.0, 1.0]", "[2.0, 0.0, 1.0, 1.0]"),
        ["key 'bodies[0]': body 'tri': its 3 particle(s) are all collinear", "singular"],
    ),
    "restitution above 1": (
        edit("restitution = 0.0", "restitution = 1.5"),
        ["key 'contact.restitution': expected a number <= 1, got 1.5"],
    ),
    "restitution below 0": (
        edit("restitution = 0.0", "restitution = -0.1"),
        ["key 'contact.restitution': expected a number >= 0, got -0.1"],
    ),
    "planes as a table": (
        edit("[[planes]]", "[planes]"),
        ["key 'planes': expected an array, got a table"],
    ),
    "bad name": (
        edit('name = "tri"', 'name = "my tri"'),
        ["key 'bodies[0].name': expected a name matching", 'got "my tri"'],
    ),
    "planes without contact": (
        edit("[contact]\nrestitution = 0.0\nfriction = 0.5\n", ""),
        ["planes are given but [contact] is absent"],
    ),
    "malformed TOML": (edit("dt = 0.01", "dt = "), ["malformed TOML: ", "line 3"]),
    "subnormal mass": (
        edit("[1.0, 0.0, 1.0, 1.0]", "[1.0, 0.0, 1.0, 1e-310]"),
        ["key 'bodies[0].particles[1][3]': expected 0 or a number of size between 1e-100 and"],
    ),
    "huge radius": (
        edit("particle_radius = 0.2", "particle_radius = 1e308"),
        ["key 'bodies[0].particle_radius': expected 0 or a number of size", "got 1e+308"],
    ),
    "integer beyond float64": (
        edit("duration = 10", "duration = 1" + "0" * 400),
        ["key 'duration': expected a number of magnitude below 1.8e308"],
    ),
    "kinetic energy out of range": (
        edit("velocity = [0.0, 0.0, -2.0]", "velocity = [0.0, 0.0, -1e60]"),
        ["body 'tri': its kinetic energy", "is 1.5e+120", "change 'velocity'"],
    ),
    "rotational energy out of range": (
        BASE + "angular_velocity = [1e-70, 0.0, 0.0]\n",
        ["body 'tri': its rotational energy", "change 'angular_velocity'"],
    ),
    "inertia out of range": (
        BASE.replace(", 1.0],", ", 1e-100],"),
        ["body 'tri': its smallest principal moment", "change 'particles'"],
    ),
    "weight out of range": (
        edit("gravity = [0.0, 0.0, -10.0]", "gravity = [0.0, 0.0, -1e100]"),
        ["body 'tri': its weight m |g| (N) is 3e+100", "change 'gravity'"],
    ),
}


@pytest.mark.parametrize(("text", "expected"), INVALID.values(), ids=INVALID.keys())
def test_invalid_case_file_is_one_line_naming_file_and_key(tmp_path, text, expected):
    path = write(tmp_path, text, "bad.toml")
    pattern = ".*".join(re.escape(part) for part in [f"{path}: ", *expected])
    with pytest.raises(InputError, match=pattern) as info:
        load_scene(path)
    assert "\n" not in str(info.value)


UNREADABLE = {
    "missing file": lambda tmp_path: tmp_path / "absent.toml",
    "directory": lambda tmp_path: tmp_path,
    "not UTF-8": lambda tmp_path: write(tmp_path, b'name = "caf\xe9"\n'),
    "a device": lambda tmp_path: Path("/dev/zero"),
    "over the size limit": lambda tmp_path: sparse(tmp_path / "big.toml", MAX_TOML_BYTES + 1),
}


def sparse(path: Path, size: int) -> Path:
    """A file of `size` zero bytes that takes no disk space."""
    with path.open("wb") as file:
        file.truncate(size)
    return path


@pytest.mark.parametrize("make_path", UNREADABLE.values(), ids=UNREADABLE.keys())
def test_unreadable_file(tmp_path, make_path):
    path = make_path(tmp_path)
    with pytest.raises(InputError, match=re.escape(f"{path}: cannot read file: ")):
        load_scene(path)


def test_resolve_case_by_catalog_name():
    assert resolve_case("tumbling_box") is CATALOG["tumbling_box"]


def test_resolve_case_by_path(tmp_path):
    path = write(tmp_path, scene_to_toml(CATALOG["dropped_cube"]), "mine.toml")
    assert resolve_case(str(path)) == CATALOG["dropped_cube"]


@pytest.mark.parametrize(
    ("arg", "message"),
    [
        ("nope", "unknown case 'nope': expected a catalog name (seed_cube, free_spin_cube"),
        ("nope.toml", "nope.toml: cannot read file: "),
    ],
)
def test_resolve_case_unknown(arg, message):
    with pytest.raises(InputError, match=re.escape(message)):
        resolve_case(arg)


def test_a_particle_behind_a_plane_is_named_by_its_body_and_index():
    stack = CATALOG["cube_stack"]
    body = stack.bodies[3]
    rows = [list(row) for row in body.particles]
    rows[6][2] = -0.25  # below the floor, whose normal is +z
    sunk = dataclasses.replace(body, particles=tuple(map(tuple, rows)))
    bodies = (*stack.bodies[:3], sunk, *stack.bodies[4:])
    with pytest.raises(ValidationError, match=r"bodies\[3\]\.particles\[6\].* 0\.25 m behind"):
        dataclasses.replace(stack, bodies=bodies)
