"""The example engine plugin (`examples/engine_plugin/`), installed as a user would install
theirs: into a virtual environment beside rigidbench, with no line of rigidbench changed. Every
command then knows the engine: `engines`, `run`, `report` (tables and plots) and `bench`."""

import os
import re
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from venvs import venv_with

ROOT = Path(__file__).resolve().parent.parent
PLUGIN = ROOT / "examples" / "engine_plugin"
# Fitted slopes of an order-4 scheme on tumbling_box at dt 0.005 to 0.02: 4.01 measured.
ORDER_TOLERANCE = 0.2
# A command's own time limit: the report below is a few thousand small steps.
COMMAND_TIMEOUT_S = 300


@pytest.fixture(scope="module")
def plugin_python(tmp_path_factory) -> Path:
    """The Python of a venv that sees this environment's packages (rigidbench among them) and
    has the example plugin installed."""
    return venv_with(PLUGIN, tmp_path_factory.mktemp("plugin-venv"))


def rigidbench(python: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(python), "-m", "reports.cli", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=COMMAND_TIMEOUT_S,
        env={**os.environ, "COLUMNS": "200"},  # wide enough for one line per engine
    )


def test_the_plugin_is_listed(plugin_python, tmp_path):
    done = rigidbench(plugin_python, "engines", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    line = next(x for x in done.stdout.splitlines() if " example " in x)
    assert "euler, rk4" in line and line.rstrip(" │").endswith("ok")


def test_run_passes_parity_and_refuses_contact_in_one_line(plugin_python, tmp_path):
    done = rigidbench(
        plugin_python, "run", "tumbling_box", "--engine", "example", "--out", "t.csv", cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    table = pd.read_csv(tmp_path / "t.csv")
    assert len(table) > 0 and set(table["body"]) == {"box"}
    refused = rigidbench(plugin_python, "run", "dropped_cube", "--engine", "example", cwd=tmp_path)
    assert refused.returncode == 2
    assert refused.stderr.strip() == (
        "rigidbench: error: engine 'example' cannot run 'dropped_cube': "
        "contact is not modelled (free bodies only)"
    )


def test_report_and_bench_include_the_plugin(plugin_python, tmp_path):
    done = rigidbench(
        plugin_python,
        *("report", "--quick", "--no-scaling", "--out", "out"),
        *("--engines", "example", "--cases", "tumbling_box", "dropped_cube"),
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert "left out: example on dropped_cube: contact is not modelled" in done.stdout
    results = pd.read_csv(tmp_path / "out" / "results.csv")
    example = results[results["engine"] == "example"]
    assert set(example["case"]) == {"tumbling_box"}
    assert set(example["integrator"]) == {"euler", "rk4"}
    assert (example["verdict"] == "ok").all()
    report = (tmp_path / "out" / "report.md").read_text().replace("\\_", "_")
    assert "- example on dropped_cube: contact is not modelled (free bodies only)" in report
    # the fitted-order table shows the plugin's RK4 at its order (its errors fall as dt^4)
    fitted = re.search(r"\| example +\| rk4 +\| +([0-9.]+) +\| +4 +\|", report)
    assert fitted and abs(float(fitted[1]) - 4) < ORDER_TOLERANCE, report
    assert (tmp_path / "out" / "figures" / "tumbling_box_convergence.png").stat().st_size > 0

    bench = rigidbench(
        plugin_python,
        *("bench", "--engines", "example", "mujoco", "--cases", "tumbling_box"),
        *("--duration", "0.2", "--out", "bench.csv"),
        cwd=tmp_path,
    )
    assert bench.returncode == 0, bench.stderr
    rows = pd.read_csv(tmp_path / "bench.csv").set_index(["engine", "integrator"])
    assert rows.loc[("example", "rk4"), "ratio_vs_mujoco_euler"] > 0
