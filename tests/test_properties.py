"""Property-based tests (Hypothesis) of the promise every command makes about bad input: a
generated case file or command line never gives a traceback, exits 0 or 2, prints one line on 2
and writes nothing then; a generated scene that loads runs on every engine without an exception
(any verdict, `diverged` included, is an answer).

CI runs a fixed set of examples (the "ci" profile: derandomized, so a red run is reproducible);
`HYPOTHESIS_PROFILE=explore` searches with fresh random examples, ten times as many.
"""

import contextlib
import dataclasses
import io
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from cases import InputError, load_scene
from cases.scene import Body, Contact, Plane, Scene
from comparators import ENGINES, run
from comparators.summary import summarize
from reports.cli import main

settings.register_profile(
    "ci",
    derandomize=True,
    deadline=None,
    max_examples=40,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
settings.register_profile("explore", parent=settings.get_profile("ci"), derandomize=False,
                          max_examples=400)  # fmt: skip
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# A valid case touching every table; generated files are edits of it.
BASE = {
    "name": "probe",
    "duration": 0.05,
    "dt": 0.01,
    "sample_interval": 0.02,
    "gravity": [0.0, 0.0, -9.81],
    "contact": {"restitution": 0.5, "friction": 0.5},
    "expected": {"rebound_ratio": 0.5},
    "planes": [{"point": [0.0, 0.0, 0.0], "normal": [0.0, 0.0, 1.0]}],
    "bodies": [
        {
            "name": "tri",
            "particle_radius": 0.1,
            "particles": [[0.0, 0.0, 1.0, 1.0], [1.0, 0.0, 1.0, 1.0], [0.0, 1.0, 1.0, 2.0]],
            "velocity": [0.0, 0.0, -1.0],
            "angular_velocity": [0.0, 1.0, 0.0],
        }
    ],
}


def leaves(value, path=()):
    """Every path into `value` (dict keys and list indices), containers included."""
    yield path
    if isinstance(value, dict):
        for key, item in value.items():
            yield from leaves(item, (*path, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from leaves(item, (*path, index))


PATHS = [p for p in leaves(BASE) if p]


def nest(depth: int) -> list:
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


# Values a hostile user puts where a number, vector, name or table belongs.
hostile_values = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, -1.0, 1e308, -1e308, 1e-310, 5e-324, 1e-200, 1e101, 1e-101]),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.text(max_size=20),
    st.booleans(),
    st.lists(st.floats(allow_nan=False, width=32), max_size=6),
    st.lists(st.lists(st.integers(-3, 3), max_size=5), max_size=4),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=3),
    st.integers(1, 200).map(nest),
)


def replaced(data, path, value):
    """A copy of `data` with the item at `path` set to `value` (added where absent), or deleted
    when `value` is DELETE."""
    copy = dict(data) if isinstance(data, dict) else list(data)
    head, rest = path[0], path[1:]
    if rest:
        copy[head] = replaced(data[head], rest, value)
    elif value is DELETE:
        del copy[head]
    else:
        copy[head] = value
    return copy


DELETE = object()


@st.composite
def case_texts(draw) -> bytes:
    """A case file: BASE with one to three values replaced, deleted or added, and sometimes
    bytes inserted into its text."""
    data = BASE
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(PATHS))
        try:
            current = data
            for part in path:
                current = current[part]
        except (KeyError, IndexError, TypeError):
            continue  # an earlier edit removed or replaced what this path led to
        action = draw(st.sampled_from(["replace", "delete", "add"]))
        if action == "replace":
            data = replaced(data, path, draw(hostile_values))
        elif action == "delete":
            data = replaced(data, path, DELETE)
        elif isinstance(current, dict):
            data = replaced(data, (*path, draw(st.text(min_size=1, max_size=8))), 1.0)
    try:
        text = tomli_w.dumps(data).encode()
    except (TypeError, ValueError):
        text = b"\x00"  # a value TOML cannot hold
    if draw(st.booleans()):
        at = draw(st.integers(0, len(text)))
        text = text[:at] + draw(st.binary(min_size=1, max_size=8)) + text[at:]
    return text


@contextlib.contextmanager
def in_empty_directory():
    """A fresh empty working directory for the block; yields it."""
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)
        try:
            yield Path(tmp)
        finally:
            os.chdir(here)


def call(argv: list[str]) -> tuple[int, str, str]:
    """`main(argv)` in this process: (status, stdout, stderr); argparse's exits included."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main(argv)
        except SystemExit as done:
            status = done.code
    return status, out.getvalue(), err.getvalue()


def assert_clean_refusal(status: int, err: str, workdir: Path, before: set[str]) -> None:
    """Exit 0 or 2; on 2 one line naming the error and no file written."""
    assert status in (0, 2), err
    assert "Traceback" not in err
    if status == 2:
        lines = err.splitlines()
        assert len(lines) == 1 and "error:" in lines[0], err
        assert {p.name for p in workdir.iterdir()} == before


@given(text=case_texts())
def test_a_generated_case_file_loads_or_is_refused_in_one_line(text):
    with in_empty_directory() as workdir:
        (workdir / "case.toml").write_bytes(text)
        status, out, err = call(["show", "case.toml"])
        assert_clean_refusal(status, err, workdir, {"case.toml"})
        if status == 0:  # what `show` prints is the same scene
            (workdir / "again.toml").write_text(out)
            assert load_scene(workdir / "again.toml") == load_scene(workdir / "case.toml")


NUMBERS = ["0.02", "0.05", "1", "0", "-1", "nan", "inf", "1e-300", "5e-324", "1e308", "abc", ""]
CASES = ["free_spin_cube", "bounce", "case.toml", "nope", "cube_rain_0", "", "/proc/self/mem"]
ENGINE_NAMES = ["reference", "mujoco", "pybullet", "nope", ""]
OUTS = ["out.csv", "out.gif", "out.txt", "/proc/x.csv", "/sys/x.gif", "missing/dir/x.csv", "."]


@st.composite
def command_lines(draw) -> list[str]:
    """A command line: a command and a few options, each from pools of valid and hostile
    values. `report` always gets a refused option (a valid report takes too long here), a
    `bench` without cases or engines one of each."""
    command = draw(st.sampled_from(["show", "run", "bench", "animate", "report", "gate", "x"]))
    argv = [command]
    if command in ("show", "run", "animate"):
        argv.append(draw(st.sampled_from(CASES)))
    options = {
        "--engine": st.sampled_from(ENGINE_NAMES),
        "--engines": st.sampled_from(ENGINE_NAMES),
        "--cases": st.sampled_from(CASES),
        "--integrator": st.sampled_from(["euler", "RK4", "nope", ""]),
        "--dt": st.sampled_from(NUMBERS),
        "--duration": st.sampled_from(NUMBERS),
        "--repeats": st.sampled_from(["0", "3", "-2", "x"]),
        "--jobs": st.sampled_from(["0", "-1", "x", "1e3"]),
        "--out": st.sampled_from(OUTS),
        "--max-steps": st.sampled_from(["0", "1", "x", "100"]),
        "--bogus": st.just("1"),
    }
    for name in draw(st.lists(st.sampled_from(sorted(options)), max_size=4, unique=True)):
        argv += [name, draw(options[name])]
    if command == "report":
        argv += ["--jobs", "0"]
    if command in ("run", "bench", "animate") and "--duration" not in argv:
        argv += ["--duration", "0.05"]  # a valid run stays short
    if command == "bench":  # and a valid bench small: one case, one engine
        argv += [] if "--cases" in argv else ["--cases", "free_spin_cube"]
        argv += [] if "--engines" in argv else ["--engines", "reference"]
    return argv


@given(argv=command_lines())
def test_a_generated_command_line_runs_or_is_refused_in_one_line(argv):
    with in_empty_directory() as workdir:
        (workdir / "case.toml").write_text(tomli_w.dumps(BASE))
        status, _, err = call(argv)
        assert_clean_refusal(status, err, workdir, {"case.toml"})


# ---- generated valid scenes on every engine ---------------------------------------------------


def magnitudes(low: int, high: int):
    """0, or a signed number of a size 10^low to 10^high, spread over the exponents."""
    exponents = st.floats(low, high, allow_nan=False)
    signs = st.sampled_from([1.0, -1.0])
    return st.one_of(st.just(0.0), st.builds(lambda s, e: s * 10.0**e, signs, exponents))


def vectors(low: int, high: int):
    return st.tuples(*[magnitudes(low, high)] * 3)


@st.composite
def scenes(draw) -> Scene:
    """A scene the format accepts, from one or two bodies of 3 to 6 particles spread over
    magnitudes (SI) from tiny to huge, with or without a floor and contact. Scenes refused at
    load (a product out of range) are rejected by `assume`: refusing is the format's answer."""
    exponent = st.integers(-30, 30)
    size = 10.0 ** draw(exponent)
    bodies = []
    for k in range(draw(st.integers(1, 2))):
        count = draw(st.integers(3, 6))
        offsets = draw(st.lists(st.tuples(*[st.floats(-1, 1)] * 3), min_size=count, max_size=count))
        centre = np.array(draw(vectors(-30, 30)))
        masses = [10.0 ** draw(st.floats(-20, 20)) for _ in range(count)]
        particles = tuple(
            (*(centre + size * np.array(o) + 3 * size * k).tolist(), m)
            for o, m in zip(offsets, masses, strict=True)
        )
        bodies.append(
            dict(
                name=f"b{k}",
                particle_radius=size * 10.0 ** draw(st.floats(-3, 0)),
                particles=particles,
                velocity=draw(vectors(-30, 30)),
                angular_velocity=draw(vectors(-30, 30)),
            )
        )
    contact = draw(st.booleans())
    dt = 10.0 ** draw(st.floats(-5, -1))
    try:
        return Scene(
            name="generated",
            duration=3 * dt,
            dt=dt,
            gravity=draw(vectors(-30, 30)),
            bodies=tuple(Body(**b) for b in bodies),
            contact=Contact(restitution=draw(st.floats(0, 1)), friction=draw(st.floats(0, 2)))
            if contact
            else None,
            planes=(Plane(point=(0.0, 0.0, -size), normal=(0.0, 0.0, 1.0)),) if contact else (),
        )
    except ValidationError:
        assume(False)


# Scenes the property test found, kept as explicit examples: what each broke.
FOUND = [
    # masses over 38 orders, cond(I) 5e9: omega read back through a solve (parity tolerance)
    Scene(
        name="generated",
        duration=0.03,
        dt=0.01,
        gravity=(-1.0, 0.0, 0.0),
        bodies=(
            Body(
                name="b0",
                particle_radius=5442034.597075652,
                particles=(
                    (583989777.5788745, 692041465.507086, -1.0, 1.7216512840248844e19),
                    (1e-05, -918752113.5176303, -1.0, 1194051.086067518),
                    (100000000.0, -281353230.0563743, -901474972.6301535, 3639832576484854.5),
                    (
                        -211131816.28157985,
                        6.309573444801933,
                        -23316307.437698,
                        2.510719078584058e-19,
                    ),
                ),
                velocity=(0.0, 0.0, 0.0),
                angular_velocity=(0.0, 0.0, 1.1597814978092625e-28),
            ),
        ),
        description="",
        tags=(),
        sample_interval=None,
        contact=None,
        planes=(),
        expected=None,
    ),
    # a division by zero in the compiled contact step (numba's ZeroDivisionError)
    Scene(
        name="generated",
        duration=0.00023493799609364035,
        dt=7.831266536454679e-05,
        gravity=(0.0, 0.0, 0.0),
        bodies=(
            Body(
                name="b0",
                particle_radius=9.933339685441012e19,
                particles=(
                    (-1.5197372469146964e19, -1.0, 6.531144428034645e19, 88157263969723.8),
                    (-4.3038657175574313e18, 9.095287967806099e19, 3e18, 1.0),
                    (
                        -7.228313831656164e19,
                        -6.860075332546627e19,
                        5.478297376225494e19,
                        3.498682695130772e-07,
                    ),
                    (1.8267181667073262e19, -1.0, -4.939546989194662e19, 23425032970971.816),
                    (-3.613187830057861e19, -11920928960001.0, 3.965144415751243e18, 1.0),
                    (1e20, -5.961549056586664e19, 8.590362176708975e19, 317317403908.9864),
                ),
                velocity=(0.0, 1.6603905701794096e16, 1.0),
                angular_velocity=(-1000000000.0, 9.471416986693166e-08, 0.0),
            ),
            Body(
                name="b1",
                particle_radius=8.368629267176124e17,
                particles=(
                    (2.2884922132534316e20, 3e20, 2.4209256249859955e20, 1.0),
                    (3e20, 3e20, 2.18876046823636e20, 1.0),
                    (
                        3.0000001794319234e20,
                        2.7080655025624134e20,
                        3.47873622902092e20,
                        6.3328563843442e-13,
                    ),
                    (3.57735e20, 3.9867961051942643e20, 3.6280733044981236e20, 100000000000.0),
                    (3e20, 3.4732340666101406e20, 3.957857301966692e20, 7.875934670235237e-11),
                    (3.9867961051942643e20, 3.978862307359568e20, 3e20, 1.7648571782648992e16),
                ),
                velocity=(0.0, 1.2369693637926944e28, 0.0),
                angular_velocity=(0.0, 0.0, 0.0),
            ),
        ),
        description="",
        tags=(),
        sample_interval=None,
        contact=Contact(restitution=0.8294464929138292, friction=0.8608217417660284),
        planes=(Plane(point=(0.0, 0.0, -1e20), normal=(0.0, 0.0, 1.0)),),
        expected=None,
    ),
]
# 1e16 rad/s: 1e22 precession periods in the exact solution (its memory): the contact scene's
# first body alone, free, spun about a second axis
FOUND.append(
    dataclasses.replace(
        FOUND[1],
        duration=3e-05,
        dt=1e-05,
        contact=None,
        planes=(),
        bodies=(
            dataclasses.replace(
                FOUND[1].bodies[0], angular_velocity=(-1e9, 1.6603905701794096e16, 0.0)
            ),
        ),
    )
)


def found_examples(test):
    for scene in FOUND:
        test = example(scene=scene)(test)
    return test


@pytest.mark.parametrize("engine", [n for n, e in ENGINES.items() if not e.missing])
@settings(max_examples=15)
@given(scene=scenes())
@found_examples
def test_a_generated_scene_runs_on_every_engine(engine, scene):
    try:
        traj = run(scene, engine)
    except InputError as refusal:  # the engine does not model it (`unsupported`), said in a line
        assert "\n" not in str(refusal)
        return
    summary = summarize(traj, scene)  # the verdict and every metric, no exception
    assert summary["verdict"] in ("ok", "diverged", "dissipated", "tunnelled", "jitter")
    assert math.isfinite(summary["steps"])
