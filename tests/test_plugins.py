"""Engines are plugins found through the `rigidbench.engines` entry points, the built-in ones
too, and a plugin that fails to load is listed with its reason without stopping the others."""

import dataclasses
import os
import subprocess
import sys
from importlib import metadata

import pytest

from cases import CATALOG, InputError
from comparators import Trajectory, run
from comparators import engine as registry
from comparators.bench import bench
from comparators.cache import ResultsCache
from comparators.engine import left_out
from comparators.sweep import LocalExecutor, plan, run_sweep
from reports.cli import main

BUILT_IN = {"dart", "drake", "mujoco", "physx", "pybullet", "reference"}


def test_built_in_engines_are_registered_through_entry_points():
    found = {e.name for e in metadata.entry_points(group=registry.ENTRY_POINT_GROUP)}
    assert found >= BUILT_IN
    assert set(registry.ENGINES) == found


ENGINE_PACKAGES = ("dartpy", "mujoco", "pybullet", "pydrake", "rapier3d", "sapien")


def test_an_engine_is_loaded_only_when_asked_for():
    """Every engine is listed by name at once, and loaded (its package imported) the first time
    it is asked for: a command using the reference, and drawing its runs, imports no other
    engine's package."""
    code = (
        "import sys\n"
        "from comparators.engine import ENGINES, get_engine\n"
        "names = set(ENGINES)\n"
        "from reports.plots import run_style\n"
        "get_engine('reference').run\n"
        "run_style('reference', 'euler')\n"
        f"print(sorted(names), [m for m in {ENGINE_PACKAGES!r} if m in sys.modules])\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith(" []"), done.stdout
    assert all(repr(name) in done.stdout for name in BUILT_IN), done.stdout


@pytest.fixture
def with_broken_plugins(monkeypatch):
    """The installed engines plus a plugin whose module is missing and one that calls itself by
    another name than its entry point's."""
    monkeypatch.setattr(registry, "ENGINES", registry.Registry())
    monkeypatch.setattr("reports.cli.ENGINES", registry.ENGINES)
    group = registry.ENTRY_POINT_GROUP
    broken = [
        metadata.EntryPoint("broken", "no_such_plugin_module:Engine", group),
        metadata.EntryPoint("misnamed", "comparators.reference:ReferenceEngine", group),
    ]
    registry.register_engines([*metadata.entry_points(group=group), *broken])
    return registry.ENGINES


def test_a_broken_plugin_is_one_line_with_its_reason(with_broken_plugins, capsys):
    assert main(["engines"]) == 0
    out = capsys.readouterr().out
    lines = {
        name: [line for line in out.splitlines() if f" {name} " in line]
        for name in ("broken", "misnamed", *BUILT_IN)
    }
    assert "no_such_plugin_module" in with_broken_plugins["broken"].missing
    assert "registered as 'misnamed'" in with_broken_plugins["misnamed"].missing
    for name in ("broken", "misnamed"):
        assert lines[name] and "unavailable" in lines[name][0], out
    for name in BUILT_IN:
        assert lines[name] and lines[name][0].rstrip(" │").endswith("ok"), out


def test_running_a_broken_plugin_is_a_clear_error_and_the_others_still_run(with_broken_plugins):
    scene = CATALOG["free_spin_cube"]
    with pytest.raises(InputError, match="engine 'broken' is unavailable: plugin"):
        run(scene, "broken", duration=0.1)
    assert len(run(scene, "reference", "euler", duration=0.1).table) > 0


def test_without_any_entry_point_the_error_says_to_install(monkeypatch):
    monkeypatch.setattr(registry, "ENGINES", registry.Registry())
    with pytest.raises(InputError, match="no engine is registered; install rigidbench"):
        registry.get_engine("reference")


class _WrongTables:
    """A plugin engine whose `run` returns tables that break the contract in `flaw`'s way."""

    name = "wrong_tables"
    integrators = ("no_columns", "no_body", "not_a_trajectory")
    default_integrator = "no_columns"
    orders = {i: 1 for i in integrators}
    missing = None

    def run(self, scene, integrator, dt, duration):
        good = run(scene, "reference", "euler", dt, duration)
        if integrator == "no_columns":
            return Trajectory(good.table.drop(columns=["qw", "wz"]), good.meta)
        if integrator == "no_body":
            return Trajectory(good.table[good.table["body"] != scene.bodies[0].name], good.meta)
        return good.table


@pytest.mark.parametrize(
    ("flaw", "message"),
    [
        ("no_columns", "returned a table without qw, wz: expected the columns t, body"),
        ("no_body", "returned rows for bodies"),
        ("not_a_trajectory", "returned DataFrame: expected a Trajectory"),
    ],
)
def test_a_table_that_breaks_the_contract_is_refused_by_name(monkeypatch, flaw, message):
    monkeypatch.setitem(registry.ENGINES, "wrong_tables", _WrongTables())
    with pytest.raises(registry.ContractError, match=f"engine 'wrong_tables' {message}"):
        run(CATALOG["cube_collision"], "wrong_tables", flaw, duration=0.1)


def test_the_cli_reports_a_broken_table_as_one_engine_error_line(monkeypatch, capsys):
    monkeypatch.setitem(registry.ENGINES, "wrong_tables", _WrongTables())
    args = ["run", "cube_collision", "--engine", "wrong_tables", "--integrator", "no_body"]
    assert main([*args, "--duration", "0.1"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rigidbench: engine error: engine 'wrong_tables'")


class _Faulty:
    """A plugin engine that raises in `run` ("raises") or models the scene with the wrong mass
    ("wrong_mass", caught by the t = 0 parity check), and models no contact."""

    name = "faulty"
    integrators = ("raises", "wrong_mass")
    default_integrator = "raises"
    orders = {i: 1 for i in integrators}
    missing = None

    def unsupported(self, scene):
        return "contact is not modelled" if scene.has_contact else None

    def run(self, scene, integrator, dt, duration):
        if integrator == "raises":
            raise RuntimeError("the plugin broke")
        good = run(scene, "mujoco", "Euler", dt, duration)
        bodies = {n: {**b, "mass": 2 * b["mass"]} for n, b in good.meta.bodies.items()}
        meta = dataclasses.replace(good.meta, engine=self.name, bodies=bodies)
        return Trajectory(good.table, meta)


@pytest.fixture
def with_faulty(monkeypatch):
    monkeypatch.setitem(registry.ENGINES, "faulty", _Faulty())
    return registry.ENGINES["faulty"]


def test_a_faulty_plugin_fails_its_runs_in_a_sweep_and_the_others_go_on(with_faulty, tmp_path):
    scenes = [CATALOG["free_spin_cube"], CATALOG["dropped_cube"]]
    specs = plan(scenes, ["faulty", "mujoco"], dt_factors=(1.0,), repeats=1)
    assert {(s.scene.name, s.engine) for s in specs if s.engine == "faulty"} == {
        ("free_spin_cube", "faulty")
    }
    lines = left_out(scenes, ["faulty", "mujoco"])
    result = run_sweep(specs, ResultsCache(tmp_path), LocalExecutor(1), False, lines)
    verdicts = result.results.set_index(["engine", "integrator", "case"])["verdict"]
    assert verdicts["faulty", "raises", "free_spin_cube"] == (
        "failed: RuntimeError: the plugin broke"
    )
    assert verdicts["faulty", "wrong_mass", "free_spin_cube"].startswith(
        "failed: parity: engine 'faulty' on 'free_spin_cube': cube.mass at t = 0 differs"
    )
    assert (verdicts["mujoco"] == "ok").all()
    assert result.left_out == ["faulty on dropped_cube: contact is not modelled"]


def test_a_faulty_plugin_fails_its_rows_in_a_bench_and_the_others_are_timed(with_faulty):
    table = bench([CATALOG["free_spin_cube"]], ["faulty", "mujoco"], duration=0.1, progress=False)
    rows = table.set_index(["engine", "integrator"])
    assert rows.loc[("faulty", "raises"), "verdict"].startswith("failed: RuntimeError")
    assert rows.loc[("faulty", "wrong_mass"), "verdict"].startswith("failed: parity")
    # timed: each MuJoCo row has its verdict and a measured rate (no speed is asserted)
    assert (rows.loc["mujoco", "verdict"] == "ok").all()
    assert rows.loc["mujoco", "steps_per_s"].notna().all()


def test_a_scene_the_engine_does_not_model_is_refused_with_its_reason(with_faulty, capsys):
    assert main(["run", "dropped_cube", "--engine", "faulty", "--integrator", "raises"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "rigidbench: error: engine 'faulty' cannot run 'dropped_cube': contact is not modelled"
    ]


def test_an_unsupported_check_that_raises_leaves_the_engine_out_saying_why(with_faulty):
    def broken(scene):
        raise KeyError("tags")

    with_faulty.unsupported = broken
    scene = CATALOG["free_spin_cube"]
    assert plan([scene], ["faulty"], dt_factors=(1.0,)) == []
    assert left_out([scene], ["faulty"]) == [
        "faulty on free_spin_cube: its unsupported() raised KeyError: 'tags'"
    ]


def test_left_out_lists_unavailable_engines_not_selected(monkeypatch):
    monkeypatch.setitem(
        registry.ENGINES, "absent", registry.UnloadableEngine("absent", "pip install absent")
    )
    assert left_out([CATALOG["free_spin_cube"]], ["mujoco"]) == ["absent: pip install absent"]


# A Python that cannot import pydrake, dartpy or sapien, as where the extras are not installed.
WITHOUT_EXTRAS = """
import sys
class Absent:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("pydrake", "dartpy", "sapien"):
            raise ImportError(f"No module named {name!r}")
sys.meta_path.insert(0, Absent())
from reports.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_an_engine_whose_package_is_absent_says_how_to_install_it(tmp_path):
    def rigidbench(*args):
        return subprocess.run(
            [sys.executable, "-c", WITHOUT_EXTRAS, *args],
            capture_output=True,
            text=True,
            cwd=tmp_path,
            env={**os.environ, "COLUMNS": "300"},
        )

    listed = rigidbench("engines")
    assert listed.returncode == 0, listed.stderr
    for engine, extra in (("drake", "drake"), ("dart", "dart"), ("physx", "physx")):
        line = next(x for x in listed.stdout.splitlines() if f" {engine} " in x)
        assert "unavailable" in line and f"pip install 'rigidbench[{extra}]'" in line
    refused = rigidbench("run", "free_spin_cube", "--engine", "drake")
    assert refused.returncode == 2
    assert refused.stderr.startswith("rigidbench: error: engine 'drake' is unavailable: pydrake")
    assert len(refused.stderr.strip().splitlines()) == 1
    bench = rigidbench(
        *("bench", "--cases", "free_spin_cube", "--engines", "mujoco"), "--duration", "0.05"
    )
    assert bench.returncode == 0, bench.stderr
    left = [x for x in bench.stdout.splitlines() if x.startswith("left out:")]
    assert [x.split(":")[1].strip() for x in left] == ["dart", "drake", "physx"]
