"""`rigidbench gate`: exit 0 when every check passes, 1 when one fails, 2 on bad input with one
line and nothing written; JUnit XML with a test case per check; `--record` writes gates that
pass on the same code and fail when the code gets worse."""

import re
import xml.etree.ElementTree as ET

import pytest
from test_cli import rigidbench

import gates
from cases import CATALOG, scene_to_toml
from gates.record import FLOORS
from gates.spec import load_gates
from reports.cli import main

SPIN = """
[[gates]]
name = "blog"
case = "free_spin_cube"
engine = "reference"
integrator = "seed"
duration = 1.0
[gates.limits]
energy_drift = { max = LIMIT }
verdict = "ok"

[[gates]]
name = "mj"
case = "free_spin_cube"
engine = "mujoco"
duration = 1.0
[gates.limits]
energy_drift = { max = 1e-3 }
"""
PASSING = SPIN.replace("LIMIT", "1.0")  # the blog's scheme gains 8 % of its energy in 1 s
FAILING = SPIN.replace("LIMIT", "1e-3")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("gate-command-cache")


def test_every_check_passes_exit_0(tmp_path, cache, capsys):
    path = tmp_path / "spin.toml"
    path.write_text(PASSING)
    assert main(["gate", str(path), "--cache", str(cache)]) == 0
    out = capsys.readouterr().out
    assert "FAIL" not in out and len(re.findall(r"\bpass\b", out)) == 3
    assert re.search(r"gate: 3 checks of 2 gate\(s\): 3 passed, 0 failed \(\d runs computed", out)


def test_a_failing_check_exits_1_and_junit_has_a_case_per_check(tmp_path, cache, capsys):
    path = tmp_path / "spin.toml"
    path.write_text(FAILING)
    junit = tmp_path / "gates.xml"
    assert main(["gate", str(tmp_path), "--cache", str(cache), "--junit", str(junit)]) == 1
    out = capsys.readouterr().out
    assert out.count("FAIL") == 1 and "3 checks of 2 gate(s): 2 passed, 1 failed (0 runs" in out
    suite = ET.parse(junit).getroot().find("testsuite")
    assert suite.get("tests") == "3" and suite.get("failures") == "1"
    cases = suite.findall("testcase")
    assert [c.get("name") for c in cases] == [
        "free_spin_cube-reference-seed-dt=0.01-energy_drift",
        "free_spin_cube-reference-seed-dt=0.01-verdict",
        "free_spin_cube-mujoco-RK4-dt=0.01-energy_drift",  # the engine's default integrator
    ]
    (failure,) = [c.find("failure") for c in cases if c.find("failure") is not None]
    assert re.fullmatch(
        r"blog \[free_spin_cube-reference-seed-dt=0.01-energy_drift\]: energy_drift measured "
        r"0\.0\d+ against limit <= 0\.001 \(margin -\d+\.\d%\)",
        failure.get("message"),
    )


def test_the_command_as_a_user_runs_it(tmp_path, cache):
    (tmp_path / "spin.toml").write_text(FAILING)
    done = rigidbench("gate", "spin.toml", "--cache", str(cache), cwd=tmp_path)
    assert done.returncode == 1, done.stderr
    assert "energy_drift" in done.stdout and done.stderr == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spin.toml"]  # the cache is elsewhere


BAD = [
    (["gate"], "gate: expected gate files or directories"),
    (["gate", "nope.toml"], "nope.toml: no such gate file or directory"),
    (["gate", "bad.toml"], "bad.toml: gate 'mj': key 'limits.energy_drift.max': expected a finite"),
    (["gate", "spin.toml", "--engine", "warp"], "error: unknown engine 'warp': expected one of"),
    (["gate", "spin.toml", "--engine", "pybullet"], "key 'integrator': unknown integrator 'seed'"),
    (["gate", "spin.toml", "--junit", "out.txt"], "--junit 'out.txt': expected a file name ending"),
    (["gate", "spin.toml", "--junit", "no/out.xml"], "--junit 'no/out.xml': directory 'no' "),
    (["gate", "spin.toml", "--cases", "bounce"], "--cases: only with --record OUT.toml"),
    (["gate", "--record", "out.txt", "--cases", "bounce", "--engine", "mujoco"],
     "--record 'out.txt': expected a file name ending in .toml"),
    (["gate", "--record", "out.toml", "--engine", "mujoco"], "expected --cases CASE... and"),
    (["gate", "--record", "out.toml", "--cases", "nope", "--engine", "mujoco"], "unknown case"),
    (["gate", "--record", "out.toml", "--cases", "bounce", "--engine", "mujoco", "--slack", "0.5"],
     "argument --slack: expected a number >= 1, got '0.5'"),
    (["gate", "spin.toml", "--record", "out.toml", "--cases", "bounce", "--engine", "mujoco"],
     "--record writes gates: expected no FILE_OR_DIR"),
]  # fmt: skip


@pytest.mark.parametrize(("args", "message"), BAD)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, monkeypatch, capsys, args,
                                                           message):  # fmt: skip
    (tmp_path / "spin.toml").write_text(PASSING)
    (tmp_path / "bad.toml").write_text(PASSING.replace("max = 1e-3", "max = nan"))
    monkeypatch.chdir(tmp_path)
    try:
        status = main(args)
    except SystemExit as done:  # argparse's own errors leave through SystemExit
        status = done.code
    assert status == 2
    said = capsys.readouterr()
    lines = said.err.splitlines()
    assert len(lines) == 1 and "error:" in lines[0] and message in lines[0], said.err
    assert "Traceback" not in said.err and said.out == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml", "spin.toml"]


def test_physics_without_shipped_gates_is_bad_input(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(gates, "PHYSICS_DIR", tmp_path / "physics")
    assert main(["gate", "--physics", "--engine", "mujoco"]) == 2
    assert "--physics: this rigidbench ships no physics gates" in capsys.readouterr().err


def test_recorded_gates_pass_on_the_same_code_and_fail_when_it_gets_worse(
    tmp_path, cache, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cases").mkdir()
    short = scene_to_toml(CATALOG["bounce"]).replace("duration = 3.0", "duration = 1.5")
    (tmp_path / "cases" / "short_bounce.toml").write_text(short)
    out = tmp_path / "recorded" / "mujoco.toml"
    out.parent.mkdir()
    args = ["--cases", "cases/short_bounce.toml", "--engine", "mujoco", "--cache", str(cache)]
    assert main(["gate", "--record", str(out), *args]) == 0
    said = capsys.readouterr().out
    recorded = load_gates([out])
    assert [g.name for g in recorded] == [f"bounce_{i}" for i in ("Euler", "RK4", "implicit",
                                                                   "implicitfast")]  # fmt: skip
    assert {g.case for g in recorded} == {"../cases/short_bounce.toml"}  # beside the gate file
    assert {g.engine for g in recorded} == {"mujoco"} and recorded[0].dts == (0.001,)
    measures = [limit.measure for limit in recorded[0].limits]
    assert measures[:2] == ["verdict", "energy_drift"] and "rebound_ratio.error" in measures
    # the record then checks what it wrote, from the cache: every check passes
    assert f"gate: recorded 4 gates in {out.as_posix()}" in said
    assert re.search(r"\d+ checks of 4 gate\(s\): \d+ passed, 0 failed \(0 runs computed", said)
    # a limit at 1.5 times the measured error plus the floor, rounded up to 3 digits
    text = out.read_text()
    measured, limit = re.search(
        r'"rebound_ratio.error" = \{ abs_max = ([-0-9.e]+) \}  # measured ([-0-9.e]+)', text
    ).group(2, 1)
    bound = 1.5 * abs(float(measured)) + FLOORS["rebound_ratio"]
    assert bound <= float(limit) <= bound * 1.01 + 1e-3 * abs(float(measured))
    # the same gates, once an engine does worse than recorded: they fail
    worse = re.sub(r"abs_max = [-0-9.e]+", "abs_max = 1e-9", text, count=1)
    (tmp_path / "worse.toml").write_text(worse.replace("../cases", "cases"))
    assert main(["gate", "worse.toml", "--cache", str(cache)]) == 1
