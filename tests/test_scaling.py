"""The cube_rain family and the scaling measurement: the scenes, name resolution, the table and
the plateau rule. Small N and few steps only; nothing here asserts on speed."""

import math
import re

import numpy as np
import pandas as pd
import pytest
from scipy.spatial import cKDTree

import comparators.timing as timing
from cases import CATALOG, InputError, resolve_case
from cases.catalog import CUBE_RAIN_LAYERS, CUBE_RAIN_MAX, CUBE_RAIN_PITCH, cube_rain
from comparators import ENGINES
from comparators.scaling import PLATEAU_COLUMNS, SCALING_COLUMNS, measure_scaling, plateau_ends
from reports.cli import EXIT_BAD_INPUT, main

AVAILABLE = [name for name, engine in ENGINES.items() if not engine.missing]
COUNTS = (1, 2)  # the smallest runs that still have a body pair
STEPS = 2


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
def table():
    return measure_scaling(COUNTS, windows=(STEPS,), repeats=2)


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


def test_a_failing_run_is_a_row_not_an_exception(monkeypatch):
    real_run = timing.run  # every measurement's runs go through comparators.timing

    def flaky(scene, engine, *args, **kwargs):
        if len(scene.bodies) == 2 and engine == "reference":
            raise RuntimeError("boom\nsecond line")
        return real_run(scene, engine, *args, **kwargs)

    monkeypatch.setattr(timing, "run", flaky)
    table = measure_scaling(COUNTS, engines=["reference"], windows=(STEPS,), repeats=1)
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
        row |= {"engine": engine, "integrator": "x", "steps": 10, "n_bodies": n}
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
    assert ends.loc["dead"].drop(["integrator", "steps"]).isna().all()
    assert plateau_ends(table, factor=1.5).loc[1, "ends_at"] == 100  # quadratic: 2x at 100


def test_an_engine_over_the_run_limit_is_not_run_at_larger_n():
    table = measure_scaling(COUNTS, engines=["mujoco"], windows=(STEPS,), repeats=1, run_limit_s=0)
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
    table = measure_scaling(COUNTS, engines=["mujoco"], windows=(STEPS,), repeats=1)
    verdicts = table.set_index("n_bodies")["verdict"]
    assert verdicts[1] == "ok" and verdicts[2] == "not run: too many bodies"
