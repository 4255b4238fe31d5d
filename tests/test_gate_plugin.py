"""The gate plugin as a user meets it: rigidbench installed into a virtual environment (nothing
of this checkout on the path), a gate file written by hand in a project of the user's own, run
by `pytest` (found through rigidbench's pytest11 entry point) and by `rigidbench gate`."""

import os
import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest
from venvs import venv_with

ROOT = Path(__file__).resolve().parent.parent
# A command's own limit: two short MuJoCo runs, and the imports of a fresh interpreter.
COMMAND_TIMEOUT_S = 300

# One gate that holds and one that does not: MuJoCo keeps a principal-axis spin's angular
# momentum to rounding, and its Euler step turns the tumbling box degrees away from the exact
# motion in a second, far beyond a microdegree.
USER_GATES = """\
# gates of my engine's CI
[[gates]]
name = "spin_keeps_L"
case = "free_spin_cube"
engine = "mujoco"
duration = 1.0

[gates.limits]
angular_momentum_drift = { max = 1e-9 }
verdict = "ok"

[[gates]]
name = "tumble_exact"
case = "tumbling_box"
engine = "mujoco"
integrator = "Euler"
duration = 1.0

[gates.limits]
orientation_error_deg = { max = 1e-6 }
"""
PASSING_IDS = [
    "spin_keeps_L[free_spin_cube-mujoco-RK4-dt=0.01-angular_momentum_drift]",
    "spin_keeps_L[free_spin_cube-mujoco-RK4-dt=0.01-verdict]",
]
FAILING_ID = "tumble_exact[tumbling_box-mujoco-Euler-dt=0.01-orientation_error_deg]"


def _source_copy(where: Path) -> Path:
    """The package's sources as a release would hold them (pyproject's packages, README)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    packages = {p.rstrip("*") for p in project["tool"]["setuptools"]["packages"]["find"]["include"]}
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc")
    for package in sorted(packages):
        shutil.copytree(ROOT / package, where / package, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, where / name)
    return where


@pytest.fixture(scope="module")
def python(tmp_path_factory) -> Path:
    """The Python of a venv that sees this environment's packages and has rigidbench installed
    from a copy of this checkout's sources (so its metadata, entry points included, is this
    checkout's, whatever rigidbench the environment has)."""
    source = _source_copy(tmp_path_factory.mktemp("rigidbench-source"))
    return venv_with(source, tmp_path_factory.mktemp("gates-venv"))


@pytest.fixture
def project(tmp_path) -> Path:
    """A user's project: its own pyproject.toml (no gate file) and a gate file in ci/gates."""
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "my-engine"\nversion = "1"\n')
    (tmp_path / "ci" / "gates").mkdir(parents=True)
    (tmp_path / "ci" / "gates" / "engine.toml").write_text(USER_GATES)
    return tmp_path


def command(program: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTEST_ADDOPTS")}
    return subprocess.run(
        [str(program), *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=COMMAND_TIMEOUT_S,
        env={**env, "COLUMNS": "200"},
    )


def test_pytest_collects_the_gate_file_and_reports_each_check(python, project):
    done = command(python, "-m", "pytest", "-v", "-rf", ".", cwd=project)
    assert done.returncode == 1, done.stdout + done.stderr
    out = done.stdout
    # this checkout is nowhere on the venv's path: the plugin is the installed one's
    assert "rigidbench" in re.search(r"plugins: (.*)", out).group(1)
    assert f"{ROOT}" not in out
    # one item per check, named gate[case-engine-integrator-dt-measure]; pyproject.toml is
    # no gate file and is not collected
    assert "collected 3 items" in out
    for test_id in PASSING_IDS:
        assert f"ci/gates/engine.toml::{test_id} PASSED" in out
    assert f"ci/gates/engine.toml::{FAILING_ID} FAILED" in out
    # its failure: measured against limit, in the failure's own section of the report
    message = (
        rf"tumble_exact \[{re.escape(FAILING_ID.split('[')[1][:-1])}\]: orientation_error_deg "
        r"measured [0-9.e+-]+ against limit <= 1e-06 \(margin -[0-9.e+]+%\)"
    )
    assert re.search(rf"_ {re.escape(FAILING_ID)} _+\n{message}\n", out), out
    # the runs are cached in pytest's own cache directory
    assert any((project / ".pytest_cache").rglob("*.parquet"))


def test_a_broken_gate_file_is_one_collection_error(python, project):
    broken = USER_GATES.replace("{ max = 1e-9 }", "{ max = nan }")
    (project / "ci" / "gates" / "engine.toml").write_text(broken)
    done = command(python, "-m", "pytest", "ci", cwd=project)
    assert done.returncode == 2, done.stdout + done.stderr  # interrupted: a collection error
    assert "ERROR collecting ci/gates/engine.toml" in done.stdout
    said = "ci/gates/engine.toml: gate 'spin_keeps_L': key 'limits.angular_momentum_drift.max': "
    assert f"{said}expected a finite number, got nan" in done.stdout
    assert "Traceback" not in done.stdout


def test_rigidbench_gate_checks_the_same_file(python, project):
    rigidbench = python.parent / "rigidbench"  # the installed command
    done = command(rigidbench, "gate", "ci/gates", "--junit", "gates.xml", cwd=project)
    assert done.returncode == 1, done.stderr
    assert "3 checks of 2 gate(s): 2 passed, 1 failed" in done.stdout
    assert re.search(r"tumble_exact .*orientation_error_deg .* <= 1e-06 .* FAIL", done.stdout)
    assert (project / "gates.xml").exists() and (project / "rigidbench-report" / "cache").is_dir()


# A user's conftest adding two engines: one not installed here, one without contact.
ENGINES_CONFTEST = """
from comparators.engine import ENGINES


class Absent:
    name, integrators, default_integrator, orders = "absent", ("x",), "x", {"x": 1}
    missing = "pip install absent-engine"


class FreeOnly(Absent):
    name, missing = "free_only", None

    def unsupported(self, scene):
        return "contact is not modelled" if scene.has_contact else None


ENGINES["absent"], ENGINES["free_only"] = Absent(), FreeOnly()
"""
SKIPPED_GATES = """
[[gates]]
name = "elsewhere"
case = "free_spin_cube"
engine = "absent"
[gates.limits]
energy_drift = { max = 1e-9 }

[[gates]]
name = "no_contact"
case = "bounce"
engine = "free_only"
[gates.limits]
"rebound_ratio.error" = { abs_max = 0.01 }
"""


def test_checks_that_cannot_run_here_are_skipped_with_the_reason(python, project):
    (project / "conftest.py").write_text(ENGINES_CONFTEST)
    (project / "ci" / "gates" / "engine.toml").write_text(SKIPPED_GATES)
    done = command(python, "-m", "pytest", "-rs", "ci", cwd=project)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "2 skipped" in done.stdout
    assert "engine 'absent': pip install absent-engine" in done.stdout
    assert "engine 'free_only' cannot run 'bounce': contact is not modelled" in done.stdout


def test_gates_engine_retargets_every_gate(python, project):
    done = command(python, "-m", "pytest", "-v", "--gates-engine", "pybullet", "ci", cwd=project)
    # tumble_exact names MuJoCo's Euler: pybullet has no such integrator, so the file is bad
    # input for this engine, said in one collection error
    assert done.returncode == 2, done.stdout + done.stderr
    assert "gate 'tumble_exact': key 'integrator': unknown integrator 'Euler' for engine" in (
        done.stdout
    )
    (project / "ci" / "gates" / "engine.toml").write_text(
        USER_GATES.split('[[gates]]\nname = "tumble')[0]
    )
    done = command(python, "-m", "pytest", "-v", "--gates-engine", "pybullet", "ci", cwd=project)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (
        "spin_keeps_L[free_spin_cube-pybullet-maximal-dt=0.01-angular_momentum_drift] PASSED"
        in (done.stdout)
    )
