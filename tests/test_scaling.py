"""The cube_rain family and the scaling measurement: the scenes, name resolution, the table and
the plateau rule. Small N and few steps only; nothing here asserts on speed."""

import math
import re

import numpy as np
import pandas as pd
import pytest
from scipy.spatial import cKDTree

import comparators.scaling as scaling
import comparators.timing as timing
import reports.plots as plots
from cases import CATALOG, InputError, resolve_case
from cases.catalog import CUBE_RAIN_LAYERS, CUBE_RAIN_MAX, CUBE_RAIN_PITCH, cube_rain
from comparators import ENGINES
from comparators.scaling import (
    PLATEAU_COLUMNS,
    SCALING_COLUMNS,
    choose_fastest,
    measure_scaling,
    plateau_ends,
    scaling_rows,
    trial_rows,
)
from reports.cli import EXIT_BAD_INPUT, main
from reports.sections.scaling import scaling_section

AVAILABLE = [name for name, engine in ENGINES.items() if not engine.missing]
COUNTS = (1, 2)  # the smallest runs that still have a body pair
STEPS = 2
TRIAL = (2, STEPS)  # the fastest integrator's trial: as small, nothing here asserts on speed
DEFAULTS = {name: ENGINES[name].default_integrator for name in AVAILABLE}


def particles_and_owners(scene):
    """(P, 3) particle centres of every body and (P,) the index of the body holding each."""
    centres = np.concatenate([b.positions for b in scene.bodies])
    owners = np.repeat(np.arange(len(scene.bodies)), [len(b.particles) for b in scene.bodies])
    return centres, owners


@pytest.mark.parametrize("n", [1, 3, 8, 37, CUBE_RAIN_MAX])
def test_cube_rain_starts_apart_inside_its_box(n):
    scene = cube_rain(n)
    assert scene.name == f"cube_rain_{n}" and len(scene.bodies) == n
    assert len({b.name for b in scene.bodies}) == n
    centres, owners = particles_and_owners(scene)
    radius = scene.bodies[0].particle_radius
    # no two particles of different cubes closer than two radii
    pairs = cKDTree(centres).query_pairs(2 * radius, output_type="ndarray")
    assert not (owners[pairs[:, 0]] != owners[pairs[:, 1]]).any()
    # every particle surface on the free side of every plane: inside the open box
    for plane in scene.planes:
        assert ((centres - plane.point) @ plane.unit_normal - radius).min() > 0
    assert len(scene.planes) == 5 and scene.has_gravity and scene.has_contact
    layers = np.unique(np.round([b.com[2] for b in scene.bodies], 6))
    assert len(layers) <= CUBE_RAIN_LAYERS
    np.testing.assert_allclose(np.diff(layers), CUBE_RAIN_PITCH)


def test_cube_rain_is_random_but_fixed():
    scene = cube_rain(8)
    spins = {b.angular_velocity for b in scene.bodies}
    assert len(spins) == 8  # no two cubes alike: the pile is not symmetric
    assert cube_rain.__wrapped__(8) == scene  # built again from scratch: the same scene


def test_catalog_holds_a_small_member():
    scene = CATALOG["cube_rain_8"]
    assert scene is cube_rain(8) and {"scaling", "contact", "gravity"} <= set(scene.tags)


@pytest.mark.parametrize("n", [1, 100, CUBE_RAIN_MAX])
def test_resolve_case_builds_any_member(n):
    assert resolve_case(f"cube_rain_{n}") is cube_rain(n)


@pytest.mark.parametrize(
    "name",
    ["cube_rain_0", f"cube_rain_{CUBE_RAIN_MAX + 1}", "cube_rain_", "cube_rain_x", "cube_rain_08",
     "cube_rain_-1", "cube_rain_1.5"],
)  # fmt: skip
def test_resolve_case_names_the_expected_n(name):
    expected = f"case '{name}': expected cube_rain_N with N a whole number from 1 to "
    with pytest.raises(InputError, match=f"^{re.escape(expected)}{CUBE_RAIN_MAX}"):
        resolve_case(name)


def test_a_toml_path_named_like_a_member_is_read_as_a_file():
    with pytest.raises(InputError, match="cube_rain_5.toml: cannot read file"):
        resolve_case("cube_rain_5.toml")


def test_cli_runs_a_member_and_rejects_a_bad_n(capsys):
    assert main(["list"]) == 0
    assert f"cube_rain_N for any N from 1 to {CUBE_RAIN_MAX}" in capsys.readouterr().out
    assert main(["run", "cube_rain_3", "--engine", "reference", "--duration", "0.02"]) == 0
    assert "cube_rain_3" in capsys.readouterr().out
    assert main(["run", "cube_rain_0"]) == EXIT_BAD_INPUT
    assert "expected cube_rain_N" in capsys.readouterr().err


@pytest.fixture(scope="module")
def measurement():
    return measure_scaling(COUNTS, windows=(STEPS,), repeats=2, fastest_trial=TRIAL)


@pytest.fixture(scope="module")
def table(measurement):
    """The default integrators' rows: every engine's at every N."""
    own = scaling_rows(measurement)
    return own[own["series"].str.startswith("default")].reset_index(drop=True)


def test_one_row_per_engine_and_n_with_a_finite_cost(table):
    assert list(table.columns) == SCALING_COLUMNS
    assert len(table) == len(AVAILABLE) * len(COUNTS)
    assert sorted(zip(table["engine"], table["n_bodies"], strict=True)) == sorted(
        (e, n) for e in AVAILABLE for n in COUNTS
    )
    assert (table["integrator"] == [ENGINES[e].default_integrator for e in table["engine"]]).all()
    assert (table["verdict"] == "ok").all() and (table["steps"] == STEPS).all()
    costs = table[["wall_s", "cost_per_step_s", "cost_per_body_step_s", "setup_s"]]
    assert np.isfinite(costs.to_numpy()).all() and (costs.to_numpy() > 0).all()
    np.testing.assert_allclose(table["cost_per_step_s"], table["wall_s"] / STEPS, rtol=1e-15)
    np.testing.assert_allclose(
        table["cost_per_body_step_s"], table["cost_per_step_s"] / table["n_bodies"], rtol=1e-15
    )
    assert (
        (table["wall_min_s"] <= table["wall_s"]) & (table["wall_s"] <= table["wall_max_s"])
    ).all()
    assert (table["case"] == [f"cube_rain_{n}" for n in table["n_bodies"]]).all()


def test_the_trial_tries_every_integrator_and_its_fastest_runs_beside_the_default(measurement):
    trial = trial_rows(measurement)
    assert sorted(zip(trial["engine"], trial["integrator"], strict=True)) == sorted(
        (e, i) for e in AVAILABLE for i in ENGINES[e].integrators
    )
    assert (trial["case"] == f"cube_rain_{TRIAL[0]}").all() and (trial["steps"] == TRIAL[1]).all()
    fastest = choose_fastest(trial, DEFAULTS)  # which one is noise at 2 steps: not asserted
    measured = scaling_rows(measurement)
    assert len(measured) + len(trial) == len(measurement)
    for engine in AVAILABLE:
        own = measured[measured["engine"] == engine]
        chosen = fastest.get(engine)
        expected = {
            DEFAULTS[engine]: "default, fastest" if chosen == DEFAULTS[engine] else "default"
        }
        if chosen not in (None, DEFAULTS[engine]):
            expected[chosen] = "fastest"
        assert dict(zip(own["integrator"], own["series"], strict=True)) == expected
        assert len(own) == len(expected) * len(COUNTS)
    assert (plateau_ends(measurement)["steps"] == STEPS).all()  # the trial's N and steps: apart


def test_without_a_trial_each_engine_runs_its_default_only():
    table = measure_scaling(COUNTS, engines=["mujoco"], windows=(STEPS,), repeats=1,
                            fastest_trial=None)  # fmt: skip
    assert (table["integrator"] == "RK4").all() and (table["series"] == "default").all()


def test_the_chosen_fastest_is_measured_at_every_n(monkeypatch):
    monkeypatch.setattr(scaling, "choose_fastest", lambda runs, defaults: {"mujoco": "Euler"})
    table = measure_scaling(COUNTS, engines=["mujoco"], windows=(STEPS,), repeats=1,
                            fastest_trial=TRIAL)  # fmt: skip
    measured = scaling_rows(table).sort_values(["n_bodies", "integrator"])
    assert list(zip(measured["integrator"], measured["series"], strict=True)) == [
        ("Euler", "fastest"), ("RK4", "default")
    ] * len(COUNTS)  # fmt: skip
    assert sorted(trial_rows(table)["integrator"]) == sorted(ENGINES["mujoco"].integrators)


def test_a_fastest_slower_than_its_default_is_not_run_at_larger_n(monkeypatch):
    real = scaling._measure_count

    def euler_slow(scene, pairs, steps, repeats, report):  # Euler 3x RK4 at N = 1 and after
        rows = real(scene, pairs, steps, repeats, report)
        rk4 = next((r["wall_min_s"] for r in rows if r["integrator"] == "RK4"), np.nan)
        return [r | {"wall_min_s": 3 * rk4} if r["integrator"] == "Euler" else r for r in rows]

    monkeypatch.setattr(scaling, "choose_fastest", lambda runs, defaults: {"mujoco": "Euler"})
    monkeypatch.setattr(scaling, "_measure_count", euler_slow)
    table = measure_scaling(COUNTS, engines=["mujoco"], windows=(STEPS,), repeats=1,
                            fastest_trial=TRIAL)  # fmt: skip
    euler = scaling_rows(table).query("integrator == 'Euler'").set_index("n_bodies")
    assert euler.loc[1, "verdict"] == "ok"
    assert euler.loc[2, "verdict"].startswith("not run: at N = 1 3 times its default's cost")
    assert (scaling_rows(table).query("integrator == 'RK4'")["verdict"] == "ok").all()


def trial_table(rates: dict[tuple[str, str], float], verdicts=None) -> pd.DataFrame:
    """Trial rows whose fastest repeats run `rates` steps/s by (engine, integrator)."""
    rows = []
    for (engine, integrator), rate in rates.items():
        row = dict.fromkeys(SCALING_COLUMNS, np.nan)
        row |= {"case": "cube_rain_8", "engine": engine, "integrator": integrator, "steps": 100}
        row |= {"series": "trial", "n_bodies": 8, "dt": 0.01, "repeats": 5}
        row |= {"verdict": (verdicts or {}).get((engine, integrator), "ok")}
        if row["verdict"] == "ok":
            row |= {"wall_min_s": 100 / rate, "wall_s": 110 / rate}
        rows.append(row)
    return pd.DataFrame(rows, columns=SCALING_COLUMNS)


def test_choose_fastest_takes_the_most_steps_per_second_among_valid_runs():
    rates = {
        # the default 4x slower: the fastest valid one, not the runner-up
        ("mujoco", "RK4"): 400, ("mujoco", "Euler"): 1600, ("mujoco", "implicit"): 1500,
        # within the margin of the default: the default stays; seed faster but diverged
        ("reference", "splitting"): 1000, ("reference", "exact"): 1090,
        ("reference", "seed"): 5000,
        # the default fastest already
        ("pybullet", "maximal"): 800, ("pybullet", "multibody"): 700,
        # the default failed: the fastest valid one; the continuous plant diverged
        ("drake", "sap"): 100, ("drake", "tamsi"): 90, ("drake", "rk2"): 900,
        # nothing valid: no fastest
        ("dart", "dantzig"): 50,
    }  # fmt: skip
    broken = {("reference", "seed"): "diverged", ("drake", "sap"): "failed: boom",
              ("drake", "rk2"): "diverged", ("dart", "dantzig"): "failed: boom"}  # fmt: skip
    defaults = {"mujoco": "RK4", "reference": "splitting", "pybullet": "maximal",
                "drake": "sap", "dart": "dantzig"}  # fmt: skip
    runs = trial_table(rates, broken)
    assert choose_fastest(runs, defaults) == {
        "mujoco": "Euler", "reference": "splitting", "pybullet": "maximal", "drake": "tamsi"
    }  # fmt: skip
    # past the margin, or valid: the faster one, the blog's all-pairs seed included
    assert choose_fastest(runs, defaults, margin=1.05)["reference"] == "exact"
    valid_seed = trial_table(rates, {k: v for k, v in broken.items() if k[1] != "seed"})
    assert choose_fastest(valid_seed, defaults)["reference"] == "seed"
    # the median is not what counts: the fastest repeat is
    slow_median = runs.assign(wall_s=np.where(runs["integrator"] == "Euler", 1.0, runs["wall_s"]))
    assert choose_fastest(slow_median, defaults)["mujoco"] == "Euler"


def section_table() -> pd.DataFrame:
    """A measure_scaling table of MuJoCo's RK4 (default) and Euler (fastest), PyBullet's maximal
    (both), two N, after its trial."""
    rates = {("mujoco", "RK4"): 400, ("mujoco", "Euler"): 1600, ("pybullet", "maximal"): 800,
             ("pybullet", "multibody"): 700, ("reference", "splitting"): 1000,
             ("reference", "seed"): 300}  # fmt: skip
    rows = trial_table(rates).to_dict("records")
    series = {("mujoco", "RK4"): "default", ("mujoco", "Euler"): "fastest",
              ("pybullet", "maximal"): "default, fastest",
              ("reference", "splitting"): "default, fastest"}  # fmt: skip
    for n in (1, 10):
        for (engine, integrator), label in series.items():
            cost = 1 / rates[engine, integrator]
            row = dict.fromkeys(SCALING_COLUMNS, np.nan)
            row |= {"case": f"cube_rain_{n}", "engine": engine, "integrator": integrator}
            row |= {"series": label, "n_bodies": n, "dt": 0.01, "steps": 10, "repeats": 5}
            row |= {"wall_s": 10 * cost, "wall_min_s": 10 * cost, "wall_max_s": 10 * cost}
            row |= {"cost_per_step_s": cost, "cost_per_body_step_s": cost / n}
            row |= {"setup_s": 0.01, "verdict": "ok"}
            rows.append(row)
    return pd.DataFrame(rows, columns=SCALING_COLUMNS)


def table_rows(text: str, first: str) -> list[dict]:
    """The rows of the markdown table in `text` whose header starts with `first`."""
    lines = text.splitlines()
    start = next(k for k, line in enumerate(lines) if line.startswith(f"| {first} |"))
    header = [c.strip() for c in lines[start].split("|")[1:-1]]
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(header, [c.strip() for c in line.split("|")[1:-1]], strict=True)))
    return rows


def test_the_section_labels_default_and_fastest_and_says_how(tmp_path):
    text = "\n".join(scaling_section(section_table(), {}, tmp_path))
    runs = table_rows(text, "steps")
    labels = {(r["engine"], r["integrator"]): r["series"] for r in runs}
    assert labels == {("mujoco", "RK4"): "default", ("mujoco", "Euler"): "fastest",
                      ("pybullet", "maximal"): "default, fastest",
                      ("reference", "splitting"): "default, fastest"}  # fmt: skip
    assert len(runs) == 8  # two N, four series: the trial's rows are apart
    trial = {(r["engine"], r["integrator"]): r for r in table_rows(text, "engine")[:6]}
    assert trial["mujoco", "Euler"]["series"] == "fastest"
    assert trial["pybullet", "multibody"]["series"] in ("", "–")
    assert trial["mujoco", "Euler"]["steps/s (fastest repeat)"].startswith("1.6")
    assert 'How "fastest" was chosen: by measurement' in text and "`cube_rain_8`" in text
    assert "more than 10%" in text and "here it was not the fastest (300 steps/s" in text
    plateau = table_rows(text.split("Where cost per body-step")[1], "engine")
    assert {r["series"] for r in plateau} == {"default", "fastest", "default, fastest"}


def test_the_plot_labels_default_and_fastest(tmp_path, monkeypatch):
    drawn = []
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.append(fig) or path)
    plots.plot_scaling(section_table(), tmp_path / "scaling.png")
    labels = {t.get_text() for t in drawn[0].legends[0].get_texts()}
    assert {"mujoco RK4 (default)", "mujoco Euler (fastest)",
            "pybullet maximal (default, fastest)"} <= labels  # fmt: skip
    assert not any("multibody" in label for label in labels)  # the trial's rows: not drawn


def test_a_failing_run_is_a_row_not_an_exception(monkeypatch):
    real_run = timing.run  # every measurement's runs go through comparators.timing

    def flaky(scene, engine, *args, **kwargs):
        if len(scene.bodies) == 2 and engine == "reference":
            raise RuntimeError("boom\nsecond line")
        return real_run(scene, engine, *args, **kwargs)

    monkeypatch.setattr(timing, "run", flaky)
    table = measure_scaling(COUNTS, engines=["reference"], windows=(STEPS,), repeats=1,
                            fastest_trial=None)  # fmt: skip
    failed = table.set_index("n_bodies").loc[2]
    assert failed["verdict"] == "failed: RuntimeError: boom" and failed["repeats"] == 0
    assert math.isnan(failed["cost_per_step_s"])
    assert table.set_index("n_bodies").loc[1, "verdict"] == "ok"


def synthetic(engine: str, costs_per_body: dict[int, float], verdicts=None) -> pd.DataFrame:
    """A measure_scaling table for one engine whose fastest repeat costs `costs_per_body` per
    body-step by N, and whose medians are 10 times that (a burst of load): the plateau reads
    the fastest repeat."""
    rows = []
    for n, cost in costs_per_body.items():
        row = dict.fromkeys(SCALING_COLUMNS, np.nan)
        row |= {"engine": engine, "integrator": "x", "series": "default", "steps": 10}
        row |= {"n_bodies": n}
        row |= {"wall_min_s": cost * 10 * n, "cost_per_body_step_s": 10 * cost}
        row |= {"verdict": (verdicts or {}).get(n, "ok")}
        rows.append(row)
    return pd.DataFrame(rows, columns=SCALING_COLUMNS)


def test_plateau_ends_where_cost_per_body_doubles():
    counts = (1, 3, 10, 30, 100, 300, 1000)
    table = pd.concat(
        [
            # a fixed cost per step shared by more bodies, then flat: never ends
            synthetic("linear", {n: 1e-5 * (1 + 4 / n) for n in counts}),
            # a quadratic part equal to the linear one at N = 100: past 2x first at 300
            synthetic("quadratic", {n: 1e-5 * (1 + n / 100) for n in counts}),
            # the failed and diverged runs do not count: the rise is seen at 1000, not 100
            synthetic(
                "broken",
                {1: 1e-5, 10: 1e-5, 100: 5e-5, 1000: 3e-5},
                verdicts={100: "diverged"},
            ),
            synthetic("dead", {1: np.nan}, verdicts={1: "failed: boom"}),
        ],
        ignore_index=True,
    )
    ends = plateau_ends(table).set_index("engine")
    assert list(ends.reset_index().columns) == PLATEAU_COLUMNS
    assert math.isnan(ends.loc["linear", "ends_at"]) and ends.loc["linear", "flat_up_to"] == 1000
    assert ends.loc["linear", "plateau_n"] == 1000
    assert ends.loc["linear", "plateau_cost_per_body_step_s"] == pytest.approx(1e-5 * 1.004)
    noisy = synthetic("noisy", {1: 1e-5, 10: 1e-5}).assign(cost_per_body_step_s=[1e-5, 1e-4])
    assert math.isnan(plateau_ends(noisy).loc[0, "ends_at"])  # a slow median, a fast minimum
    assert ends.loc["quadratic", ["flat_up_to", "ends_at", "plateau_n"]].tolist() == [100, 300, 1]
    assert ends.loc["broken", ["flat_up_to", "ends_at"]].tolist() == [10, 1000]
    assert ends.loc["dead"].drop(["integrator", "series", "steps"]).isna().all()
    assert plateau_ends(table, factor=1.5).loc[1, "ends_at"] == 100  # quadratic: 2x at 100


def test_an_engine_over_the_run_limit_is_not_run_at_larger_n():
    table = measure_scaling(COUNTS, engines=["mujoco"], windows=(STEPS,), repeats=1, run_limit_s=0,
                            fastest_trial=None)  # fmt: skip
    first, *rest = table.sort_values("n_bodies").itertuples()
    assert first.verdict == "ok" and first.repeats == 1
    assert [row.verdict.split(" a run")[0] for row in rest] == [
        f"not run: at N = {first.n_bodies}"
    ] * len(rest)
    assert all(row.repeats == 0 and math.isnan(row.wall_s) for row in rest)


def test_an_n_the_engine_does_not_model_is_a_row_saying_so(monkeypatch):
    def unsupported(scene):
        return "too many bodies" if len(scene.bodies) > 1 else None

    monkeypatch.setattr(ENGINES["mujoco"], "unsupported", unsupported, raising=False)
    table = measure_scaling(COUNTS, engines=["mujoco"], windows=(STEPS,), repeats=1,
                            fastest_trial=None)  # fmt: skip
    verdicts = table.set_index("n_bodies")["verdict"]
    assert verdicts[1] == "ok" and verdicts[2] == "not run: too many bodies"
