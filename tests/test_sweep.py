"""Sweeps: one row per run, the results cache, failures recorded, local and Dask executors."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from cases import CATALOG
from comparators.cache import ResultsCache
from comparators.engine import ENGINES
from comparators.summary import summarize
from comparators.sweep import (
    FULL_DT_FACTORS,
    FULL_LONG_DT_FACTORS,
    LONG_CASE_S,
    OUTCOMES_COLUMNS,
    QUICK_DT_FACTORS,
    QUICK_HARD_DT_FACTORS,
    RESULT_COLUMNS,
    LocalExecutor,
    execute,
    plan,
    run_sweep,
)
from gates.spec import RESULT_LABELS, RESULT_MEASURES

SHORT = [
    dataclasses.replace(CATALOG["tumbling_box"], duration=1.0),
    dataclasses.replace(CATALOG["dropped_cube"], duration=1.0),
]
FACTORS = (2.0, 1.0)


class SerialExecutor:
    """Runs in this process; `stop_after` simulates a sweep killed after that many runs."""

    name = "serial"

    def __init__(self, stop_after=None):
        self.stop_after = stop_after

    def map_unordered(self, fn, items):
        for n, item in enumerate(items):
            if n == self.stop_after:
                raise KeyboardInterrupt
            yield item, fn(item)


def test_one_row_per_run_and_values_where_defined(tmp_path):
    specs = plan(SHORT, ["reference", "mujoco"], repeats=1, dt_factors=FACTORS)
    result = run_sweep(specs, ResultsCache(tmp_path), LocalExecutor(2), progress=False)
    df = result.results
    assert list(df.columns) == RESULT_COLUMNS
    # a gate limits any column but the labels: each of those holds numbers
    numeric = {c for c in df.columns if pd.api.types.is_numeric_dtype(df[c])}
    assert set(RESULT_MEASURES) <= numeric and set(df.columns) - numeric <= set(RESULT_LABELS)
    assert "energy_gain" in RESULT_MEASURES
    assert (
        len(df) == len(specs) == len({(s.scene.name, s.engine, s.integrator, s.dt) for s in specs})
    )
    # dropped_cube, cut at 1 s, is still settling (it rests after 2 to 3 s): it expects rest,
    # so its verdict is jitter; the free tumble is ok
    settling = df["case"] == "dropped_cube"
    assert (df.loc[settling, "verdict"] == "jitter").all()
    assert (df.loc[~settling, "verdict"] == "ok").all()
    always = ["steps", "setup_s", "wall_s", "steps_per_s", "realtime_factor", "energy_drift",
              "angular_momentum_drift", "momentum_drift"]  # fmt: skip
    assert not df[always].isna().any().any()
    exact = df[df["case"] == "tumbling_box"]
    assert not exact[["position_error", "orientation_error_deg"]].isna().any().any()
    contact = df[df["case"] == "dropped_cube"]
    coarse = contact[contact["dt"] > contact["dt"].min()]
    assert not coarse[["orientation_error_deg", "rest_com_height"]].isna().any().any()
    # the finest run is its own reference: no error to report, said so
    finest = contact[contact["dt"] == contact["dt"].min()]
    assert finest["orientation_error_deg"].isna().all()
    assert set(result.trajectories) == set(df["key"])
    # outcomes: one row per run and quantity; dropped_cube states a rest height, so every run
    # of it measures rest; the 1 s tumble flips fewer than twice, so it measures nothing
    out = result.outcomes
    assert list(out.columns) == OUTCOMES_COLUMNS
    assert set(out["case"]) == {"dropped_cube"}
    rest = out[out["quantity"] == "rest_com_height"]
    runs = contact[["engine", "integrator", "dt"]].sort_values(["engine", "integrator", "dt"])
    measured = rest[["engine", "integrator", "dt"]].sort_values(["engine", "integrator", "dt"])
    assert measured.to_numpy().tolist() == runs.to_numpy().tolist()
    assert (rest["expected"] == 0.7).all() and rest["error"].notna().all()


def test_quick_sweep_runs_hard_cases_at_their_default_dt_only():
    hard = dataclasses.replace(SHORT[1], name="hard_one", tags=("hard",))
    specs = plan([SHORT[0], hard], ["reference"], quick=True, repeats=1)
    factors = {
        name: sorted({s.dt / s.scene.dt for s in specs if s.scene.name == name})
        for name in ("tumbling_box", "hard_one")
    }
    assert factors["tumbling_box"] == pytest.approx(sorted(QUICK_DT_FACTORS))
    assert factors["hard_one"] == pytest.approx(sorted(QUICK_HARD_DT_FACTORS))


def test_full_sweep_stops_long_cases_two_octaves_finer():
    long = dataclasses.replace(SHORT[1], name="long_one", duration=2 * LONG_CASE_S)
    specs = plan([SHORT[0], long], ["reference"], repeats=1)
    factors = {
        name: sorted({s.dt / s.scene.dt for s in specs if s.scene.name == name})
        for name in ("tumbling_box", "long_one")
    }
    assert factors["tumbling_box"] == pytest.approx(sorted(FULL_DT_FACTORS))
    assert factors["long_one"] == pytest.approx(sorted(FULL_LONG_DT_FACTORS))


def test_cache_resumes_an_interrupted_sweep(tmp_path):
    specs = plan(SHORT[:1], ["reference"], repeats=1, dt_factors=FACTORS)
    cache = ResultsCache(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(specs, cache, SerialExecutor(stop_after=3), progress=False)
    assert len(list(tmp_path.glob("*.parquet"))) == 3
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no partial file
    result = run_sweep(specs, cache, SerialExecutor(), progress=False)
    assert (result.computed, result.cached) == (len(specs) - 3, 3)
    again = run_sweep(specs, cache, SerialExecutor(), progress=False)
    assert (again.computed, again.cached) == (0, len(specs))
    cols = ["orientation_error_deg", "energy_drift", "key"]
    assert again.results[cols].equals(result.results[cols])


def test_a_failing_run_is_recorded_not_raised(tmp_path, monkeypatch):
    class Broken:
        name = "broken"
        integrators = ("x",)
        default_integrator = "x"
        orders = {"x": 1}
        missing = None

        def run(self, scene, integrator, dt, duration):
            raise FloatingPointError("step blew up")

    monkeypatch.setitem(ENGINES, "broken", Broken())
    specs = plan(SHORT[:1], ["reference", "broken"], repeats=1, dt_factors=(1.0,))
    result = run_sweep(specs, ResultsCache(tmp_path), SerialExecutor(), progress=False)
    row = result.results.set_index("engine").loc["broken"]
    assert row["verdict"] == "failed: FloatingPointError: step blew up"
    ok = result.results[result.results["engine"] == "reference"]
    assert (ok["verdict"] == "ok").all()


def test_repeats_time_fast_runs_and_keep_every_timing():
    (spec,) = plan(SHORT[:1], ["reference"], repeats=3, dt_factors=(1.0,))[:1]
    traj, error, (summary, measured) = execute(spec)
    assert error is None
    assert summary["energy_drift"] == summarize(traj, spec.scene)["energy_drift"]
    assert len(traj.meta.wall_runs) == 3
    assert traj.meta.wall_s == np.median(traj.meta.wall_runs)


def test_dask_executor_on_a_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed", reason="dask extra not installed")
    from comparators.sweep import DaskExecutor

    specs = plan(SHORT[:1], ["reference", "pybullet"], repeats=1, dt_factors=(1.0,))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        executor = DaskExecutor(cluster.scheduler_address)
        try:
            result = run_sweep(specs, ResultsCache(tmp_path), executor, progress=False)
        finally:
            executor.client.close()
    assert len(result.results) == len(specs)
    assert (result.results["verdict"] == "ok").all()
    local = run_sweep(specs, ResultsCache(tmp_path / "local"), SerialExecutor(), progress=False)
    cols = ["case", "engine", "integrator", "dt", "orientation_error_deg", "energy_drift"]
    left = result.results[cols].sort_values(cols[:4]).reset_index(drop=True)
    right = local.results[cols].sort_values(cols[:4]).reset_index(drop=True)
    assert left.equals(right)  # same physics wherever it ran


def test_fitted_orders_on_tumbling_box_from_the_results_table(tmp_path):
    """The issue's gate: about 1 for MuJoCo Euler, 4 for MuJoCo RK4, 2 for reference splitting."""
    from reports.convergence import fit_orders

    scene = CATALOG["tumbling_box"]
    runs = {
        ("mujoco", "Euler"): (0.4, 0.2, 0.1),  # dt 0.004 to 0.001: errors 8 to 2 deg
        ("mujoco", "RK4"): (2.0, 1.0, 0.5),
        ("reference", "splitting"): (2.0, 1.0, 0.5),
    }
    specs = [
        spec
        for (engine, integrator), factors in runs.items()
        for spec in plan([scene], [engine], repeats=1, dt_factors=factors)
        if spec.integrator == integrator
    ]
    result = run_sweep(specs, ResultsCache(tmp_path), LocalExecutor(2), progress=False)
    fits = fit_orders(result.results, result.orders).set_index(["engine", "integrator"])
    for (engine, integrator), expected in [
        (("mujoco", "Euler"), 1),
        (("mujoco", "RK4"), 4),
        (("reference", "splitting"), 2),
    ]:
        order = fits.loc[(engine, integrator), "order"]
        assert abs(order - expected) < ORDER_SLACK, f"{engine}/{integrator}: fitted {order:.3f}"


# Fitted orders must lie within this of the nominal ones (as in tests/test_engines.py).
ORDER_SLACK = 0.3
