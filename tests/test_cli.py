"""The rigidbench command line: commands work, bad input exits 2 with one line and no traceback."""

import io
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from rich.console import Console

from cases import CATALOG, load_scene
from comparators import COLUMNS, Trajectory
from comparators.sweep import LOADING
from reports.cli import EXIT_BROKEN_PIPE, main
from reports.console_tables import outcomes_table

ROOT = Path(__file__).resolve().parent.parent


def _command_env() -> dict:
    """The environment that runs this checkout's sources, with no COLUMNS: output to a pipe."""
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "PYTHONPATH": path}
    env.pop("COLUMNS", None)
    return env


def rigidbench(*args: str, cwd=None) -> subprocess.CompletedProcess:
    """The command as a user runs it, from this checkout's sources whatever `cwd` is."""
    return subprocess.run(
        [sys.executable, "-m", "reports.cli", *args],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=cwd,
        env=_command_env(),
    )


def test_list_shows_every_case(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for name in CATALOG:
        assert name in out


def test_a_table_sent_to_a_file_keeps_each_cell_on_its_line():
    """Piped or logged, a table is not folded to 80 columns: a row stays one line to grep."""
    proc = rigidbench("list")
    assert proc.returncode == 0, proc.stderr
    row = next(line for line in proc.stdout.splitlines() if "seed_cube" in line)
    assert CATALOG["seed_cube"].modelled() in row


def test_a_reader_that_leaves_ends_the_command_without_a_traceback():
    """`rigidbench list | head`: the pipe closed before the command writes stops it with the
    status a shell gives a command SIGPIPE stops, and nothing on stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "reports.cli", "list"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=_command_env(),
        text=True,
    )
    proc.stdout.close()  # before the interpreter has started: the first write finds no reader
    said = proc.stderr.read()
    assert proc.wait(timeout=600) == EXIT_BROKEN_PIPE, said
    assert said == ""


@pytest.mark.parametrize("case", sorted(CATALOG))
def test_show_round_trips(case, capsys, tmp_path):
    assert main(["show", case]) == 0
    path = tmp_path / f"{case}.toml"
    path.write_text(capsys.readouterr().out)
    assert load_scene(path) == CATALOG[case]


@pytest.mark.parametrize("suffix", ["csv", "parquet"])
def test_run_writes_the_trajectory_table(tmp_path, suffix):
    out = tmp_path / f"t.{suffix}"
    proc = rigidbench(
        "run", "tumbling_box", "--engine", "reference", "--integrator", "splitting",
        "--dt", "0.01", "--out", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    # piped, so no spinner: the stage's line says what ran
    assert proc.stdout.startswith("running tumbling_box on reference splitting\n")
    assert "angular_momentum_drift" in proc.stdout
    traj = Trajectory.read(out)
    assert list(traj.table.columns) == COLUMNS
    assert len(traj.table) == 101  # samples every 0.1 s over 10 s, both ends included
    assert traj.meta.integrator == "splitting" and traj.meta.steps == 1000


def test_run_accepts_a_toml_file(tmp_path, capsys):
    assert main(["show", "free_spin_cube"]) == 0
    path = tmp_path / "mine.toml"
    path.write_text(capsys.readouterr().out.replace('"free_spin_cube"', '"mine"'))
    assert main(["run", str(path), "--integrator", "rk4", "--duration", "1"]) == 0
    assert "mine" in capsys.readouterr().out


BAD_TOML = 'name = "x"\nduration = 1.0\ndt = 0.01\ngravity = [0.0, 0.0]\n'


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "no_such_case"], "unknown case 'no_such_case'"),
        (["run", "tumbling_box", "--engine", "warp"], "unknown engine 'warp'"),
        (["run", "tumbling_box", "--integrator", "leapfrog"], "unknown integrator 'leapfrog'"),
        (["run", "tumbling_box", "--dt", "nan"], "expected a finite number > 0"),
        (["run", "tumbling_box", "--dt", "-1"], "expected a finite number > 0"),
        (["run", "tumbling_box", "--dt", "20"], "dt 20 is longer than duration 10"),
        (["run", "tumbling_box", "--out", "t.txt"], "expected a file name ending in .csv"),
        (["run", "{bad}"], "key 'gravity': expected 3 numbers"),
        (["show", "{bad}"], "key 'gravity': expected 3 numbers"),
    ],
)
def test_bad_input_exits_2_with_one_line(args, message, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(BAD_TOML)
    proc = rigidbench(*[a.replace("{bad}", str(bad)) for a in args], cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert message in proc.stderr
    assert proc.stdout == ""
    assert not list(tmp_path.glob("t.*"))


def test_report_end_to_end(tmp_path):
    out = tmp_path / "out"
    proc = rigidbench(
        "report", "--cases", "free_spin_cube", "--engines", "reference", "pybullet", "--quick",
        "--out", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    for name in ("results.csv", "results.parquet", "report.md", "index.html"):
        assert (out / name).is_file(), name
    again = rigidbench(
        "report", "--cases", "free_spin_cube", "--engines", "reference", "pybullet", "--quick",
        "--out", str(out),
    )  # fmt: skip
    assert "0 computed" in again.stdout


def test_a_report_is_quiet_and_writes_only_its_folder(tmp_path):
    """MuJoCo Euler diverges on high_spin at its dt and warns: the warning is in that run's
    record, not on the terminal, nor in a MUJOCO_LOG.TXT; the terminal shows the progress and
    one closing line; the working directory gets rigidbench-report/ and nothing else."""
    proc = rigidbench(
        "report", "--cases", "free_spin_cube", "high_spin", "--engines", "reference", "mujoco",
        "--no-scaling", "--quick", cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    stage, *progress, closing = proc.stdout.strip().splitlines()
    assert stage == LOADING  # the session compiled it; piped: the stage's text, no spinner
    assert closing.startswith("report: rigidbench-report/ (open rigidbench-report/index.html); ")
    assert all("━" in line for line in progress), proc.stdout  # the bar's lines, nothing else
    for text in ("QACC", "WARNING", "warning", "unstable", "wrote"):
        assert text not in proc.stdout, proc.stdout
    assert [p.name for p in tmp_path.iterdir()] == ["rigidbench-report"]
    out = tmp_path / "rigidbench-report"
    assert (out / "index.html").is_file() and any((out / "cache").iterdir())
    results = pd.read_csv(out / "results.csv")
    run = results.set_index(["case", "engine", "integrator"]).loc[("high_spin", "mujoco", "Euler")]
    assert run["verdict"] == "diverged" and run["engine_messages"] == 1
    assert "Nan, Inf or huge value in QACC" in run["first_engine_message"]
    assert "1 with engine messages" in closing
    report = (out / "report.md").read_text()
    assert "Nan, Inf or huge value in QACC" in report  # in high_spin's metrics table


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--engines", "warp"], "unknown engine 'warp'"),
        (["--cases", "nope"], "unknown case 'nope'"),
        (["--executor", "dask"], "expected --scheduler ADDRESS"),
        (["--jobs", "0"], "expected a number >= 1"),
    ],
)
def test_report_bad_input(args, message, tmp_path):
    proc = rigidbench("report", "--quick", "--out", str(tmp_path / "out"), *args)
    assert proc.returncode == 2
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out" / "report.md").exists()


def test_run_judges_each_outcome_against_its_closed_form(capsys):
    """`run` prints the outcomes table: the reference's slide stops within 1 % of the closed
    form; a quantity without a tolerance (stopping_time) is shown but not judged."""
    assert main(["run", "slide"]) == 0
    rows = {}
    for line in capsys.readouterr().out.splitlines():
        cells = [cell.strip() for cell in line.split("│")[1:-1]]
        if len(cells) == 6:  # quantity, unit, measured, closed form, tolerance, judged
            rows[cells[0]] = cells
    assert rows["stopping_distance"][3:] == ["0.9", "1%", "within"]
    assert rows["stopping_time"][3:] == ["0.6", "", ""]


def test_the_outcomes_of_a_run_that_is_not_ok_say_the_report_does_not_judge_them(capsys):
    """The seed's slide diverges: its outcomes are shown, with a caption under them."""
    assert main(["run", "slide", "--integrator", "seed"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "the run's verdict is diverged: the report's findings judge only ok runs" in out


def test_the_outcomes_table_says_by_how_much_a_run_missed():
    said = pd.DataFrame(
        {
            "quantity": ["stopping_distance", "lift", "flip_period"],
            "measured": [0.85, 0.073, 6.8],
            "expected": [0.9, 0.0, 6.84],
            "error": [-0.05, 0.073, -0.04],
            "unit": ["m", "m", "s"],
        }
    )
    out = io.StringIO()
    Console(file=out, width=200).print(outcomes_table(said))
    rows = [[c.strip() for c in line.split("│")[1:-1]] for line in out.getvalue().splitlines()]
    rows = [cells for cells in rows if len(cells) == 6]
    assert [cells[4:] for cells in rows] == [
        ["1%", "missed by -5.6%"],
        ["0.001", "missed by +0.073 m"],
        ["", ""],
    ]
