"""The report: convergence fits, Pareto fronts, cost to tolerance and the written files.

The sweep result is built here from a handful of real runs, without the sweep machinery:
`tumbling_box` shortened to 2 s, reference `splitting` and MuJoCo `RK4` and `Euler` at four dt.
"""

import dataclasses
import platform
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from cases import CATALOG
from cases.scene import NAME_MAX_LENGTH
from comparators import ENGINES, run
from comparators.bench import BENCH_COLUMNS, throughput_from_results
from comparators.outcomes import outcomes
from comparators.scaling import SCALING_COLUMNS
from comparators.summary import summarize
from comparators.sweep import OUTCOMES_COLUMNS, RESULT_COLUMNS, SweepResult
from reports import texts
from reports.convergence import (
    ERROR_CEILING_DEG,
    ERROR_FLOOR_DEG,
    cost_to_tolerance,
    fit_orders,
    fit_power_law,
    lowest_front,
    pareto_front,
)
from reports.html_page import missing_references
from reports.plots import run_style
from reports.report import expected_orders, write_report
from reports.sections.case import pareto_sentence

SCENE = dataclasses.replace(CATALOG["tumbling_box"], duration=2.0)
DTS = (0.02, 0.01, 0.005, 0.0025)
PAIRS = [("reference", "splitting"), ("mujoco", "RK4"), ("mujoco", "Euler")]
# A fitted order within 0.3 of the expected one: on these runs the fits give 2.00 (splitting),
# 3.97 (RK4) and 0.99 (Euler); 0.3 tells a wrong order (off by 1) from a good one with margin.
ORDER_ATOL = 0.3
# Values defined for every valid run of a case with an exact reference: never NaN in the files.
DEFINED = [
    "dt",
    "duration",
    "steps",
    "setup_s",
    "wall_s",
    "steps_per_s",
    "realtime_factor",
    "energy_drift",
    "angular_momentum_drift",
    "position_error",
    "orientation_error_deg",
]


def result_row(traj, scene) -> dict:
    """One RESULT_COLUMNS row for a run, as the sweep would make it (one repeat, no cache)."""
    meta = traj.meta
    summary = summarize(traj, scene)
    row = dict.fromkeys(RESULT_COLUMNS, np.nan)
    row |= {k: v for k, v in summary.items() if k in RESULT_COLUMNS}
    row |= {
        "duration": meta.duration,
        "repeats": 1,
        "wall_min_s": meta.wall_s,
        "wall_max_s": meta.wall_s,
        "engine_version": meta.versions.get(meta.engine, meta.versions["rigidbench"]),
        "code_version": meta.versions["rigidbench"],
        "key": f"{meta.case}-{meta.engine}-{meta.integrator}-{meta.dt:g}",
    }
    return row


def build_result(scenes, pairs, dts) -> SweepResult:
    """Run every scene x (engine, integrator) x dt directly and collect a SweepResult."""
    rows, trajectories, measured = [], {}, []
    for scene in scenes:
        for engine, integrator in pairs:
            for dt in dts:
                traj = run(scene, engine, integrator, dt=dt)
                row = result_row(traj, scene)
                rows.append(row)
                trajectories[row["key"]] = traj
                tags = {"case": scene.name, "engine": engine, "integrator": integrator, "dt": dt}
                measured.append(outcomes(traj, scene).assign(**tags)[OUTCOMES_COLUMNS])
    results = pd.DataFrame(rows, columns=RESULT_COLUMNS)
    return SweepResult(
        scenes={s.name: s for s in scenes},
        results=results,
        trajectories=trajectories,
        references={
            s.name: results[results["case"] == s.name]["reference"].iloc[0] for s in scenes
        },
        elapsed_s=1.0,
        machine={
            "cpu": platform.processor() or platform.machine(),
            "python": platform.python_version(),
        },
        executor="in-process loop (test)",
        computed=len(rows),
        orders={(e, i): ENGINES[e].orders[i] for e, i in pairs},
        outcomes=pd.concat(measured, ignore_index=True),
    )


@pytest.fixture(scope="module")
def sweep() -> SweepResult:
    for engine, _ in PAIRS:
        if ENGINES[engine].missing:
            pytest.skip(f"{engine}: {ENGINES[engine].missing}")
    return build_result([SCENE], PAIRS, DTS)


@pytest.fixture(scope="module")
def report(sweep, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    return out, write_report(sweep, out, "pytest tests/test_report.py")


@pytest.mark.parametrize("engine, integrator", PAIRS)
def test_fitted_order_matches_the_expected_order(sweep, engine, integrator):
    fits = fit_orders(sweep.results, expected_orders(sweep)).set_index(["engine", "integrator"])
    fit = fits.loc[(engine, integrator)]
    assert fit["points"] >= 3, fit["note"]
    assert fit["order"] == pytest.approx(fit["expected_order"], abs=ORDER_ATOL), (
        f"tumbling_box {engine} {integrator}: fitted order {fit['order']:.3f} over dt "
        f"{fit['dt_min']}..{fit['dt_max']}, expected {fit['expected_order']}"
    )
    assert fit["r2"] > 0.999
    # no gravity, no initial velocity: the COM stays put in every engine
    assert fit["position_note"].startswith("exact")


def test_fit_uses_only_the_asymptotic_range():
    dt = np.array([0.1, 0.05, 0.02, 0.01, 0.005, 0.001])
    error = 1e3 * dt**2  # order 2 ...
    error[0] = 170.0  # ... saturated above the ceiling
    error[-1] = ERROR_FLOOR_DEG / 10  # ... rounding below the floor
    fit = fit_power_law(dt, error, ERROR_FLOOR_DEG, ERROR_CEILING_DEG)
    assert fit["order"] == pytest.approx(2.0, abs=1e-12)
    assert (fit["points"], fit["dt_min"], fit["dt_max"]) == (4, 0.005, 0.05)


def test_errors_all_at_rounding_are_labelled_rounding():
    runs = pd.DataFrame(
        {
            "case": "c",
            "engine": "e",
            "integrator": ["exact"] * 3 + ["euler"] * 4,
            "dt": [0.1, 0.05, 0.02, 0.1, 0.05, 0.02, 1e-12],
            "verdict": "ok",
            "orientation_error_deg": [3e-10, 1e-10, 2e-10, 10.0, 5.0, 2.0, 1e-11],
            "position_error": 0.0,
        }
    )
    fits = fit_orders(runs, {}).set_index("integrator")
    assert np.isnan(fits.at["exact", "order"])
    assert fits.at["exact", "note"].startswith("rounding")
    # one error at rounding among fitted ones is only left out of the fit
    assert fits.at["euler", "note"] == "" and fits.at["euler", "points"] == 3


def test_a_single_precision_engine_is_fitted_above_its_precision_floor(monkeypatch):
    """Errors that fall with dt and rise again below some dt: a float32 engine's rounding has
    overtaken its truncation error there; the fit stops at the smallest error and says so. The
    same errors from a float64 engine are fitted whole (a rise there is no precision floor)."""
    monkeypatch.setitem(ENGINES, "single", SimpleNamespace(epsilon=float(np.finfo(np.float32).eps)))
    monkeypatch.setitem(ENGINES, "double", SimpleNamespace())
    runs = pd.DataFrame(
        {
            "case": "c",
            "engine": ["single"] * 5 + ["double"] * 5,
            "integrator": "x",
            "dt": [0.02, 0.01, 0.005, 0.0025, 0.00125] * 2,
            "verdict": "ok",
            "orientation_error_deg": [8.0, 4.0, 2.0, 3.0, 5.0] * 2,
            "position_error": np.nan,
        }
    )
    fits = fit_orders(runs, {}).set_index("engine")
    assert fits.at["single", "order"] == pytest.approx(1.0)
    assert fits.at["single", "dt_min"] == 0.005 and fits.at["single", "points"] == 3
    assert (
        "precision floor: float32 errors stop falling below dt 0.005 s" in fits.at["single", "note"]
    )
    assert fits.at["double", "points"] == 5 and "precision" not in fits.at["double", "note"]


def test_no_fit_with_fewer_than_three_points():
    fit = fit_power_law(np.array([0.1, 0.01, 0.001]), np.array([100.0, 1.0, 1e-12]), 1e-9, 30.0)
    assert np.isnan(fit["order"]) and fit["points"] == 1
    assert "need 3" in fit["note"]


def test_pareto_front():
    df = pd.DataFrame(
        {
            "cost": [1.0, 2.0, 2.0, 3.0, 4.0, 5.0, 0.5, 4.0],
            "error": [5.0, 3.0, 4.0, 3.0, 1.0, 2.0, np.nan, 1.0],
        },
        index=list("abcdefgh"),
    )
    # c: same cost as b, more error; d: same error as b, more cost; f: more of both than e;
    # g: no error; h: a duplicate of e
    assert list(pareto_front(df, "cost", "error").index) == ["a", "b", "e"]


# Runs of two engines, each costing one budget: the reference is lowest alone above the
# rounding floor, mujoco alone at cost 3, and at cost 4 both are below ERROR_FLOOR_DEG.
FRONT_RUNS = pd.DataFrame(
    {
        "engine": ["reference", "mujoco", "mujoco", "reference"],
        "integrator": ["splitting", "Euler", "RK4", "exact"],
        "dt": [0.01, 0.01, 0.001, 0.01],
        "cost": [1.0, 2.0, 3.0, 4.0],
        "error": [1e-3, 1e-2, 1e-11, 5e-10],
    }
)


def test_lowest_front_counts_errors_below_the_floor_as_ties():
    front = lowest_front(FRONT_RUNS, "cost", "error", "engine", ERROR_FLOOR_DEG)
    assert list(front.index) == [1.0, 2.0, 3.0, 4.0]
    # at cost 1 mujoco has no run: it is not lowest there
    assert front["reference"].tolist() == [True, True, False, True]
    assert front["mujoco"].tolist() == [False, False, True, True]
    # without a floor the smaller rounding error wins
    bare = lowest_front(FRONT_RUNS, "cost", "error", "engine")
    assert bare["reference"].tolist() == [True, True, False, False]


def test_pareto_sentence_names_the_ties():
    runs = FRONT_RUNS.rename(columns={"error": "orientation_error_deg"}).assign(
        verdict="ok", duration=1.0, wall_s=FRONT_RUNS["cost"]
    )
    sentence = pareto_sentence(runs)
    assert "**reference**" in sentence
    assert "at 3 of 4 time budgets, 1 of them tied with mujoco" in sentence


def test_cost_to_tolerance():
    def runs(case, reference, rows):
        cols = ["integrator", "dt", "wall_s", "orientation_error_deg", "verdict"]
        df = pd.DataFrame(rows, columns=cols)
        return df.assign(case=case, engine="e", reference=reference, duration=10.0)

    results = pd.concat(
        [
            runs(
                "c",
                "exact",
                [
                    ("A", 0.01, 1.0, 1e-3, "ok"),
                    ("A", 0.001, 10.0, 1e-5, "ok"),
                    ("B", 0.01, 2.0, 1e-7, "ok"),
                    ("B", 0.1, 0.1, 0.0, "diverged"),  # cheap, but not valid
                ],
            ),
            runs("s", "self-convergence (dt=0.001)", [("A", 0.01, 0.1, 1e-9, "ok")]),
        ]
    )
    costs = cost_to_tolerance(results, (1e-2, 1e-4, 1e-6, 1e-8)).set_index("tolerance_deg")
    assert set(costs["case"]) == {"c"}
    assert costs.loc[1e-2, ["cost_s_per_s", "integrator", "dt"]].tolist() == [0.1, "A", 0.01]
    assert costs.loc[1e-4, ["cost_s_per_s", "integrator", "dt"]].tolist() == [0.2, "B", 0.01]
    assert costs.loc[1e-6, "cost_s_per_s"] == 0.2
    assert np.isnan(costs.loc[1e-8, "cost_s_per_s"])


def test_report_files(sweep, report):
    out, written = report
    files = ("results.parquet", "results.csv", "outcomes.parquet", "outcomes.csv", "report.md")
    for name in (*files, "index.html"):
        assert written[name] == out / name and (out / name).is_file()
    figures = [name for name in written if name.startswith("figures/")]
    kinds = ("drift", "convergence", "work_precision", "stability")
    expected = [f"figures/tumbling_box_{kind}.png" for kind in kinds] + ["figures/throughput.png"]
    expected.append("figures/tumbling_box_motion.gif")  # a core case: animated
    assert sorted(figures) == sorted(expected)
    assert all((out / name).stat().st_size > 10_000 for name in figures)
    assert not [p.name for p in out.iterdir() if p.name.startswith(".")], "temporary files left"


def test_no_two_integrators_of_an_engine_look_alike():
    """In every figure an engine is one colour, so each of its integrators needs a marker of its
    own (in a scatter plot the marker is all that tells them apart); an integrator's name gets
    the same marker in every engine that has it (MuJoCo's `RK4`, the reference's `rk4`) unless
    another of that engine's holds it."""
    for engine in ENGINES:
        integrators = ENGINES[engine].integrators
        markers = [run_style(engine, i)["marker"] for i in integrators]
        assert len(set(markers)) == len(integrators), (engine, markers)
        assert {run_style(engine, i)["color"] for i in integrators} == {
            run_style(engine, "")["color"]
        }
    assert run_style("mujoco", "RK4")["marker"] == run_style("reference", "rk4")["marker"]


def test_an_unlisted_engine_has_a_colour_no_listed_engine_has():
    """Runs cached by a plugin since removed still get drawn: in a colour of their own while
    the palette has colours the registered engines leave free."""
    listed = {run_style(engine, "")["color"] for engine in ENGINES}
    assert len(listed) == len(ENGINES)
    for name in ("removed_plugin", "warp", "genesis", "brax", "isaac"):
        assert run_style(name, "")["color"] not in listed, name


def test_a_sliding_case_gets_the_path_on_its_plane(tmp_path):
    """A case that states a slide's closed form (`slide_oblique`) gets the path figure, in its
    section with its how-to-read; tumbling_box above does not (`test_report_files`)."""
    scene = CATALOG["slide_oblique"]
    written = write_report(build_result([scene], PAIRS[:2], (scene.dt,)), tmp_path, "pytest")
    assert (tmp_path / "figures" / "slide_oblique_path.png").stat().st_size > 10_000
    text = written["report.md"].read_text()
    section = text[text.index("### Path on its plane") :]
    assert section.index(texts.PATH) < section.index("figures/slide_oblique_path.png")
    assert "Metrics, drift, path on its plane, convergence in dt" in text


def test_a_spun_case_gets_its_spin_against_time(tmp_path):
    """`spin_down` states a spin closed form: its section has the spin figure, and no path (its
    COM has no line to follow)."""
    scene = CATALOG["spin_down"]
    written = write_report(build_result([scene], PAIRS[:1], (scene.dt,)), tmp_path, "pytest")
    assert (tmp_path / "figures" / "spin_down_spin.png").stat().st_size > 10_000
    assert not (tmp_path / "figures" / "spin_down_path.png").exists()
    text = written["report.md"].read_text()
    section = text[text.index("### Spin against time") :]
    assert section.index(texts.SPIN) < section.index("figures/spin_down_spin.png")
    assert "Metrics, drift, spin against time, convergence in dt" in text


def test_a_case_of_the_longest_name_allowed_gets_its_figures(tmp_path):
    """Figures are named after their case and written through a temporary file: at
    NAME_MAX_LENGTH characters both names still fit the file systems' 255 bytes."""
    scene = dataclasses.replace(SCENE, name="x" * NAME_MAX_LENGTH)
    written = write_report(build_result([scene], PAIRS[:1], DTS[:3]), tmp_path, "pytest")
    kinds = ("drift", "convergence", "work_precision", "stability")
    figures = [name for name in written if name.startswith(f"figures/{scene.name}_")]
    assert sorted(figures) == sorted(f"figures/{scene.name}_{kind}.png" for kind in kinds)


def test_results_files_have_one_row_per_run(sweep, report):
    out, _ = report
    for table in (pd.read_csv(out / "results.csv"), pd.read_parquet(out / "results.parquet")):
        assert list(table.columns) == RESULT_COLUMNS
        assert len(table) == len(PAIRS) * len(DTS)
        assert (table["verdict"] == "ok").all()
        nan = table[DEFINED].isna()
        assert not nan.any().any(), f"NaN in {list(table[DEFINED].columns[nan.any()])}"
        assert table["key"].tolist() == sweep.results["key"].tolist()


def test_report_text(sweep, report):
    out, _ = report
    text = (out / "report.md").read_text()
    for name in [*sweep.scenes, *sweep.results["engine"].unique()]:
        assert name in text
    for name in ("RK4", "Euler", "splitting", "Lowest front", "| passed "):
        assert name in text
    assert missing_references(out / "index.html") == []
    html = (out / "index.html").read_text()
    assert html.count("<img") == 6 and html.count("<table>") >= 6  # 5 figures, 1 animation
    assert '<td class="num">' in html  # numbers right-aligned


def test_throughput_at_the_default_dt(sweep, report):
    """The sweep's own timings as the bench's table: one row per engine/integrator at the
    case's default dt, min <= median <= max, the MuJoCo Euler ratio 1; and as a section."""
    table = throughput_from_results(sweep.results, sweep.scenes, sweep.outcomes)
    assert list(table.columns) == BENCH_COLUMNS
    assert len(table) == len(PAIRS) and (table["dt"] == SCENE.dt).all()
    rate = table["steps_per_s"]
    assert (table["steps_per_s_min"] <= rate).all() and (rate <= table["steps_per_s_max"]).all()
    base = table[(table["engine"] == "mujoco") & (table["integrator"] == "Euler")]
    assert base["ratio_vs_mujoco_euler"].tolist() == [1.0]
    out, _ = report
    section = (out / "report.md").read_text().split("## Throughput")[1].split("\n## ")[0]
    assert "figures/throughput.png" in section
    header = next(line for line in section.splitlines() if line.startswith("| case"))
    row = next(line for line in section.splitlines() if line.startswith(r"| tumbling\_box"))
    cells = {h.strip(): c.strip() for h, c in zip(header.split("|"), row.split("|"), strict=True)}
    assert cells["mujoco Euler"].endswith("(1.00)")  # MuJoCo Euler against itself


def test_missing_references_finds_a_missing_figure(tmp_path):
    (tmp_path / "figures").mkdir()
    (tmp_path / "figures" / "a.png").write_bytes(b"")
    page = tmp_path / "index.html"
    page.write_text(
        '<img src="figures/a.png"><img src="figures/b.png">'
        '<a href="#x">x</a><a href="https://example.org/c.png">c</a>'
    )
    assert missing_references(page) == ["figures/b.png"]


def test_report_with_failed_and_diverged_runs(sweep, tmp_path):
    """Runs without a trajectory or numbers still show: in the tables and on the map."""
    base = sweep.results.iloc[0]
    broken = pd.DataFrame(
        [
            base.copy().to_dict() | {"dt": 0.04, "verdict": "diverged", "key": "d"},
            base.copy().to_dict() | {"dt": 0.08, "verdict": "failed: parity mass", "key": "f"},
            base.copy().to_dict() | {"dt": 0.16, "verdict": "tunnelled", "key": "t"},
            base.copy().to_dict() | {"dt": 0.32, "verdict": "jitter", "key": "j"},
        ]
    )
    for col in ["wall_s", "steps_per_s", "orientation_error_deg", "energy_drift"]:
        broken[col] = np.nan
    result = dataclasses.replace(
        sweep, results=pd.concat([sweep.results, broken], ignore_index=True)
    )
    written = write_report(result, tmp_path, "test")
    text = written["report.md"].read_text()
    assert "diverged" in text and "failed in 1 of 8 runs: failed: parity mass" in text
    assert "figures/tumbling_box_stability.png" in written
    assert missing_references(written["index.html"]) == []
    # largest stable dt: 0.02 for the pair with the broken runs, every swept dt for the others
    stable = text.split("## Largest stable dt")[1].split("\n## ")[0]
    row = next(line for line in stable.splitlines() if line.startswith(r"| tumbling\_box"))
    base_pair = f"{base['engine']} {base['integrator']}"
    header = next(line for line in stable.splitlines() if line.startswith("| case"))
    cells = {h.strip(): c.strip() for h, c in zip(header.split("|"), row.split("|"), strict=True)}
    assert cells.pop(base_pair) == "0.02 (diverged at 0.04)"
    assert {c for k, c in cells.items() if k not in ("", "case")} == {"≥ 0.02"}


def test_largest_stable_dt():
    from reports.convergence import largest_stable_dt

    def results(verdicts):
        return pd.DataFrame(
            {"case": "c", "engine": "e", "integrator": "i", "dt": [0.001, 0.002, 0.004, 0.008]}
        ).assign(verdict=verdicts)

    def first(verdicts):
        return largest_stable_dt(results(verdicts)).iloc[0]

    stable = first(["ok", "ok", "jitter", "ok"])  # ok again above the first failure: not stable
    assert (stable["largest_stable_dt"], stable["all_stable"]) == (0.002, False)
    assert (stable["first_unstable_dt"], stable["first_unstable_verdict"]) == (0.004, "jitter")
    every = first(["ok"] * 4)
    assert (every["largest_stable_dt"], every["all_stable"], every["dt_max"]) == (
        0.008,
        True,
        0.008,
    )
    assert np.isnan(first(["tunnelled", "ok", "ok", "ok"])["largest_stable_dt"])


def test_contact_validation_section(tmp_path):
    """A contact case with a closed-form outcome gets a table: quantity, closed form, and each
    engine/integrator's measurement (error) at the default dt, [error range] over the sweep."""
    scene = CATALOG["dropped_cube"]
    result = build_result([scene], [("reference", "splitting")], (0.02, 0.01))
    written = write_report(result, tmp_path, "test")
    for name in ("outcomes.csv", "outcomes.parquet"):
        table = (
            pd.read_csv(tmp_path / name)
            if name.endswith("csv")
            else pd.read_parquet(tmp_path / name)
        )
        assert list(table.columns) == OUTCOMES_COLUMNS
        assert len(table) == len(result.outcomes) > 0
    text = written["report.md"].read_text()
    section = text.split("## Contact validation")[1].split("\n## ")[0]
    assert "### `dropped_cube`" in section and "How to read" in section
    rest = r"| rest\_com\_height (m)"  # Markdown-escaped
    row = next(line for line in section.splitlines() if line.startswith(rest))
    closed_form, measured = (cell.strip() for cell in row.split("|")[2:4])
    assert closed_form == "0.7"
    assert measured.startswith("0.7 (") and "[" in measured  # value (error) [range over dts]
    assert "≥ 0.02" in text.split("## Largest stable dt")[1]


def scaling_table() -> pd.DataFrame:
    """A measure_scaling table without measuring: two windows, three N, one failed run."""
    rows = []
    for steps in (10, 100):
        for n in (1, 10, 100):
            for engine, integrator, per_body in (("reference", "splitting", 3e-5 * n**0.5),
                                                 ("mujoco", "RK4", 1e-5)):  # fmt: skip
                row = dict.fromkeys(SCALING_COLUMNS, np.nan)
                wall = per_body * n * steps
                row |= {"case": f"cube_rain_{n}", "engine": engine, "integrator": integrator}
                row |= {"n_bodies": n, "dt": 0.01, "steps": steps, "repeats": 5, "wall_s": wall}
                row |= {"wall_min_s": wall, "wall_max_s": wall, "setup_s": 0.01, "verdict": "ok"}
                row |= {"cost_per_step_s": wall / steps, "cost_per_body_step_s": per_body}
                rows.append(row)
    rows[-1] |= {"verdict": "failed: boom", "repeats": 0, "cost_per_step_s": np.nan}
    return pd.DataFrame(rows, columns=SCALING_COLUMNS)


def test_report_with_scaling(sweep, tmp_path):
    table = scaling_table()
    written = write_report(sweep, tmp_path, "test", scaling=table)
    assert written["scaling.csv"] == tmp_path / "scaling.csv"
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "scaling.csv"), table)
    assert (tmp_path / "figures" / "scaling.png").stat().st_size > 10_000
    text = written["report.md"].read_text()
    section = text.split("## Scaling")[1].split("\n## ")[0]
    assert "figures/scaling.png" in section and "failed: boom" in section
    assert "10 steps (0.1 s): free fall; 100 steps (1 s): landings and the pile" in section
    rows = [[c.strip() for c in line.split("|")[1:-1]] for line in section.splitlines()]
    header = next(r for r in rows if "ends at N" in r)
    plateau = [dict(zip(header, r, strict=True)) for r in rows if len(r) == len(header)][2:]
    # reference: sqrt(N) per body, past 2x the plateau at N = 10 in both windows; mujoco: flat
    ends = {(r["engine"], r["steps"]): r["ends at N"] for r in plateau}
    assert ends == {
        ("reference", "10"): "10",
        ("reference", "100"): "10",
        ("mujoco", "10"): "–",
        ("mujoco", "100"): "–",
    }
    assert missing_references(written["index.html"]) == []
    figures = [name for name in written if name.endswith((".png", ".gif"))]
    assert "figures/scaling.png" in figures
    assert written["index.html"].read_text().count("<img") == len(figures)


def test_no_scaling_figure_without_a_valid_run(sweep, tmp_path):
    table = scaling_table().assign(verdict="diverged")
    text = write_report(sweep, tmp_path, "test", scaling=table)["report.md"].read_text()
    assert "No scaling figure" in text and not (tmp_path / "figures" / "scaling.png").exists()
