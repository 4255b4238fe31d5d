"""`rigidbench bench`: the throughput table's shape and invariants, failures reported in their
row, bad input refused. Never the speed itself (timings depend on the machine and its load)."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from cases import CATALOG
from comparators import ENGINES
from comparators.bench import BENCH_COLUMNS, MIN_REPEATS, bench
from comparators.closed_forms import NONE_MISSED
from comparators.sweep import warm_up
from comparators.trajectory import Trajectory
from reports.cli import main

SCENE = CATALOG["free_spin_cube"]
DTS = (0.01, 0.02)
DURATION = 0.2  # s: 10 to 20 steps per run, enough to exercise every path
AVAILABLE = [name for name, engine in ENGINES.items() if not engine.missing]
RIGID = [i for i in ENGINES["reference"].integrators if i != "seed"]


@pytest.fixture(scope="module")
def table() -> pd.DataFrame:
    if "mujoco" not in AVAILABLE:
        pytest.skip(f"mujoco: {ENGINES['mujoco'].missing}")
    warm_up(AVAILABLE)
    return bench([SCENE], AVAILABLE, DTS, DURATION, progress=False)


def test_one_row_per_case_engine_integrator_dt(table):
    assert list(table.columns) == BENCH_COLUMNS
    expected = {
        (SCENE.name, engine, integrator, dt)
        for engine in AVAILABLE
        for integrator in ENGINES[engine].integrators
        for dt in DTS
    }
    keys = list(zip(table["case"], table["engine"], table["integrator"], table["dt"], strict=True))
    assert len(keys) == len(set(keys)) and set(keys) == expected
    assert (table["verdict"] == "ok").all(), table[["engine", "integrator", "verdict"]]
    assert (table["duration"] == DURATION).all()
    assert (table["steps"] == [round(DURATION / dt) for dt in table["dt"]]).all()


def test_timings_are_a_median_with_min_and_max(table):
    assert (table["repeats"] >= MIN_REPEATS).all()
    rate = table["steps_per_s"].to_numpy(float)
    low, high = table["steps_per_s_min"].to_numpy(float), table["steps_per_s_max"].to_numpy(float)
    assert np.isfinite(rate).all() and (rate > 0).all()
    assert (low <= rate).all() and (rate <= high).all()
    assert (table["setup_s"] > 0).all()


def test_ratio_is_against_mujoco_euler_at_the_same_dt(table):
    base = table[(table["engine"] == "mujoco") & (table["integrator"] == "Euler")]
    assert (base["ratio_vs_mujoco_euler"] == 1.0).all() and len(base) == len(DTS)
    for dt in DTS:
        at = table[table["dt"] == dt]
        euler = base.loc[base["dt"] == dt, "steps_per_s"].iloc[0]
        np.testing.assert_allclose(at["ratio_vs_mujoco_euler"], at["steps_per_s"] / euler)


# A slide cut short once stopped (0.61 s), run whole by the bench: its closed forms are judged.
SLIDE = dataclasses.replace(CATALOG["slide"], duration=0.8)
# The same slide told it stops 10 % short of v0^2 / (2 mu g): every rigid integrator misses that.
SHORT = 0.9


def test_closed_forms_are_judged_on_the_case_whole_run(table):
    # free_spin_cube cut to DURATION: not its case's run, nothing judged
    assert table["closed_forms_missed"].isna().all()
    told = SLIDE.expected.stopping_distance
    wrong = dataclasses.replace(
        SLIDE,
        name="slide_told_short",
        expected=dataclasses.replace(SLIDE.expected, stopping_distance=SHORT * told),
    )
    judged = bench([SLIDE, wrong], ["reference"], None, None, progress=False)
    judged = judged.set_index(["case", "integrator"])
    assert judged.loc[("slide", "seed"), "verdict"] == "diverged"
    assert pd.isna(judged.loc[("slide", "seed"), "closed_forms_missed"])
    for integrator in RIGID:
        assert judged.loc[(SLIDE.name, integrator), "closed_forms_missed"] == NONE_MISSED
        missed = judged.loc[(wrong.name, integrator), "closed_forms_missed"]
        quantity, value = missed.split()
        # measured within 1 % of the true distance, against a closed form SHORT of it
        assert quantity == "stopping_distance", missed
        assert 0.99 / SHORT - 1 <= float(value.rstrip("%")) / 100 <= 1.01 / SHORT - 1, missed


class _Poisoned:
    """MuJoCo's run with every sample after t = 0 NaN (a divergence), or raising."""

    def __init__(self, name: str, fail: bool):
        self.name, self.fail = name, fail
        mujoco = ENGINES["mujoco"]
        self.integrators, self.default_integrator = ("Euler",), "Euler"
        self.orders, self.missing = {"Euler": 1}, mujoco.missing

    def run(self, scene, integrator, dt, duration) -> Trajectory:
        if self.fail:
            raise RuntimeError("engine exploded\nsecond line")
        traj = ENGINES["mujoco"].run(scene, integrator, dt, duration)
        table = traj.table.copy()
        table.loc[table["t"] > 0, ["x", "vx"]] = np.nan
        return Trajectory(table, dataclasses.replace(traj.meta, engine=self.name))


def test_failed_and_diverged_runs_are_reported_not_raised(monkeypatch):
    if "mujoco" not in AVAILABLE:
        pytest.skip(f"mujoco: {ENGINES['mujoco'].missing}")
    monkeypatch.setitem(ENGINES, "diverging", _Poisoned("diverging", fail=False))
    monkeypatch.setitem(ENGINES, "failing", _Poisoned("failing", fail=True))
    table = bench([SCENE], ["mujoco", "diverging", "failing"], None, DURATION, progress=False)
    by_engine = table.set_index(["engine", "integrator"])
    assert by_engine.loc[("diverging", "Euler"), "verdict"] == "diverged"
    assert by_engine.loc[("failing", "Euler"), "verdict"] == "failed: RuntimeError: engine exploded"
    for engine in ("diverging", "failing"):
        row = by_engine.loc[(engine, "Euler")]
        assert np.isnan(row["steps_per_s"]) and np.isnan(row["ratio_vs_mujoco_euler"])
        assert row["repeats"] == 0
    assert (by_engine.loc["mujoco", "verdict"] == "ok").all()


def test_cli_writes_the_table_and_its_plot(tmp_path, capsys):
    if "mujoco" not in AVAILABLE:
        pytest.skip(f"mujoco: {ENGINES['mujoco'].missing}")
    out = tmp_path / "bench.csv"
    args = ["bench", "--cases", SCENE.name, "--engines", "mujoco", "--duration", str(DURATION)]
    assert main([*args, "--out", str(out)]) == 0
    written = pd.read_csv(out)
    assert list(written.columns) == BENCH_COLUMNS
    assert len(written) == len(ENGINES["mujoco"].integrators)
    assert (tmp_path / "bench.png").stat().st_size > 10_000
    assert "stepping throughput" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench.csv", "bench.png"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--engines", "warp"], "unknown engine 'warp'"),
        (["--cases", "nope"], "unknown case 'nope'"),
        (["--cases", "tumbling_box", "--dt", "20"], "dt 20 is longer than duration 10"),
        (["--out", "{tmp}/bench.txt"], "expected a file name ending in .csv"),
        (["--out", "{tmp}/missing/bench.csv"], "missing"),
    ],
)
def test_bad_input_exits_2_and_writes_nothing(args, message, tmp_path, capsys):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "bench.csv")]
    assert main(["bench", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--repeats", "4"], f"expected a number >= {MIN_REPEATS}"),
        (["--dt", "nan"], "expected a finite number > 0"),
        (["--duration", "-1"], "expected a finite number > 0"),
    ],
)
def test_bad_numbers_exit_2_and_write_nothing(args, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["bench", *args, "--out", str(tmp_path / "bench.csv")])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
