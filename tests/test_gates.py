"""Gate files: validation (one line naming file, gate and key), and evaluation through the
results cache: limits that pass and fail, failed and diverged runs, retargeting, orders."""

import dataclasses
import math
from pathlib import Path

import pytest

from cases import CATALOG, InputError, scene_to_toml
from comparators import run
from comparators.cache import ResultsCache
from comparators.engine import ENGINES
from comparators.outcomes import outcomes
from comparators.summary import summarize
from comparators.sweep import RunSpec, run_sweep
from comparators.timing import SWEEP_REPEATS
from gates.evaluate import CHECK_COLUMNS, evaluate, plan_checks
from gates.spec import ALL_INTEGRATORS, is_gate_file, load_gates

GOOD = """
[[gates]]
name = "spin"
case = "free_spin_cube"
engine = "reference"
integrator = "splitting"
dt = [0.02, 0.01]
duration = 1.0
[gates.limits]
angular_momentum_drift = { max = 1e-12 }
verdict = "ok"
"""


def write(tmp_path: Path, text: str, name: str = "gates.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_gate_file_loads_with_its_defaults(tmp_path):
    (gate,) = load_gates([write(tmp_path, GOOD)])
    assert (gate.name, gate.engine, gate.integrator) == ("spin", "reference", "splitting")
    assert gate.dts == (0.02, 0.01) and gate.scene.duration == 1.0 and gate.duration == 1.0
    assert [limit.measure for limit in gate.limits] == ["angular_momentum_drift", "verdict"]
    assert gate.limits[0].max == 1e-12 and gate.limits[1].verdicts == ("ok",)
    # defaults: the case's dt and duration, the engine's default integrator (None)
    bare = GOOD.replace('integrator = "splitting"\n', "").replace("dt = [0.02, 0.01]\n", "")
    (gate,) = load_gates([write(tmp_path, bare.replace("duration = 1.0\n", ""))])
    assert gate.dts == (CATALOG["free_spin_cube"].dt,) and gate.integrator is None
    assert gate.scene == CATALOG["free_spin_cube"] and gate.duration is None


def test_a_case_file_is_found_beside_the_gate_file(tmp_path):
    cases = tmp_path / "cases"
    cases.mkdir()
    (cases / "mine.toml").write_text(scene_to_toml(CATALOG["bounce"]).replace("bounce", "mine"))
    path = write(tmp_path, GOOD.replace('"free_spin_cube"', '"cases/mine.toml"'))
    (gate,) = load_gates([path])
    assert gate.case == "cases/mine.toml" and gate.scene.name == "mine"


def test_directories_are_read_recursively_in_sorted_order(tmp_path):
    (tmp_path / "b").mkdir()
    write(tmp_path / "b", GOOD.replace('"spin"', '"second"'), "x.toml")
    write(tmp_path, GOOD.replace('"spin"', '"first"'), "a.toml")
    write(tmp_path, "not a gate", "notes.txt")
    assert [g.name for g in load_gates([tmp_path])] == ["first", "second"]


def test_only_gate_files_are_gate_files(tmp_path):
    assert is_gate_file(write(tmp_path, GOOD))
    assert not is_gate_file(write(tmp_path, '[project]\nname = "x"\n', "pyproject.toml"))
    assert not is_gate_file(write(tmp_path, "name = 'x'\n[[bodies]]\n", "case.toml"))
    # a broken gate file is one, so that collecting it reports the problem
    assert is_gate_file(write(tmp_path, "[[gates]]\nname = \n", "broken.toml"))


# (what the file says, the one line expected: file, gate and key named)
BAD = [
    ("", "key 'gates': expected an array of tables [[gates]]"),
    ("title = 'x'\n" + GOOD, "unknown key 'title' (expected one of: gates)"),
    (GOOD + "\n[[gates]\n", "malformed TOML"),
    (GOOD.replace('name = "spin"', 'name = "a b"'), "gates[0]: key 'name': expected a name"),
    (GOOD.replace('name = "spin"\n', ""), "gates[0]: missing key 'name'"),
    (GOOD.replace("[gates.limits]", "colour = 1\n[gates.limits]"), "gates[0]: unknown key"),
    (
        GOOD.replace("[gates.limits]\n", "[gates.limits]\n").split("[gates.limits]")[0],
        "gates[0]: missing key 'limits'",
    ),
    (GOOD + GOOD, "gate 'spin': key 'name': expected a name unique in the file"),
    (GOOD.replace('"free_spin_cube"', '"no_such_case"'), "gate 'spin': key 'case': unknown case"),
    (
        GOOD.replace('"free_spin_cube"', '"missing.toml"'),
        "gate 'spin': key 'case': {dir}/missing.toml: cannot read file",
    ),
    (GOOD.replace('"free_spin_cube"', "3"), "gate 'spin': key 'case': expected a non-empty string"),
    (GOOD.replace("dt = [0.02, 0.01]", "dt = nan"), "key 'dt': expected a finite number, got nan"),
    (GOOD.replace("dt = [0.02, 0.01]", "dt = [0.02, -1]"), "key 'dt[1]': expected a number > 0"),
    (GOOD.replace("dt = [0.02, 0.01]", "dt = [0.01, 0.01]"), "key 'dt': expected distinct"),
    (GOOD.replace("dt = [0.02, 0.01]", "dt = 2"), "key 'dt': expected dt <= the duration 1 s"),
    (GOOD.replace("dt = [0.02, 0.01]", "dt = []"), "key 'dt': expected a number > 0"),
    (GOOD.replace("duration = 1.0", 'duration = "1"'), "key 'duration': expected a finite number"),
    (GOOD.replace("duration = 1.0", "duration = 0.001"), "key 'duration': expected at least"),
    (GOOD.replace('engine = "reference"', "engine = true"), "key 'engine': expected a non-empty"),
    (
        GOOD.replace("angular_momentum_drift =", "angular_momentum_drfit ="),
        "gate 'spin': key 'limits.angular_momentum_drfit': unknown measure 'angular_momentum_",
    ),
    (
        GOOD.replace("{ max = 1e-12 }", "{ max = nan }"),
        "gate 'spin': key 'limits.angular_momentum_drift.max': expected a finite number, got nan",
    ),
    (
        GOOD.replace("{ max = 1e-12 }", "{ max = true }"),
        "key 'limits.angular_momentum_drift.max': expected a finite number, got true",
    ),
    (
        GOOD.replace("{ max = 1e-12 }", "{ below = 1 }"),
        "key 'limits.angular_momentum_drift': unknown limit 'below' (expected one of: max, min, "
        "abs_max)",
    ),
    (GOOD.replace("{ max = 1e-12 }", "{ declared_within = 0.1 }"), "unknown limit 'declared_"),
    (GOOD.replace("{ max = 1e-12 }", "1e-12"), "key 'limits.angular_momentum_drift': expected a"),
    (GOOD.replace("{ max = 1e-12 }", "{}"), "key 'limits.angular_momentum_drift': expected a"),
    (GOOD.replace("{ max = 1e-12 }", "{ min = 2, max = 1 }"), "expected min <= max"),
    (GOOD.replace("{ max = 1e-12 }", "{ abs_max = -1 }"), "expected a number >= 0, got -1"),
    (
        GOOD.replace('verdict = "ok"', 'verdict = "fine"'),
        "key 'limits.verdict': expected a verdict or an array of them (ok, diverged, "
        "dissipated, tunnelled, jitter, failed), got 'fine'",
    ),
    (GOOD.replace('verdict = "ok"', "verdict = []"), "key 'limits.verdict': expected a verdict"),
    (
        GOOD.replace('verdict = "ok"', "order = { declared_within = 0.15 }"),
        "key 'limits.order': expected a dt list of at least 3 time steps to fit an order, got 2",
    ),
    (
        GOOD.replace('verdict = "ok"', '"max_penetration.error" = { max = 1 }'),
        "'max_penetration' has no closed form to have an error",
    ),
    (
        GOOD.replace('verdict = "ok"', '"rebound_ratio.eror" = { max = 1 }'),
        "unknown measure 'rebound_ratio.eror'",
    ),
]


@pytest.mark.parametrize(("text", "message"), BAD)
def test_a_bad_gate_file_is_one_line_naming_file_gate_and_key(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(InputError) as raised:
        load_gates([path])
    said = str(raised.value)
    assert said.startswith(f"{path}: ") and "\n" not in said
    assert message.format(dir=tmp_path) in said


def test_missing_paths_and_empty_directories_are_bad_input(tmp_path):
    with pytest.raises(InputError, match="no such gate file or directory"):
        load_gates([tmp_path / "nope.toml"])
    with pytest.raises(InputError, match=r"no gate files \(\*\.toml\) in this directory"):
        load_gates([tmp_path])


def test_planning_names_the_gate_of_a_missing_engine_or_integrator(tmp_path):
    gates = load_gates([write(tmp_path, GOOD.replace('engine = "reference"\n', ""))])
    with pytest.raises(InputError, match=r"gate 'spin': missing key 'engine' \(expected an"):
        plan_checks(gates)
    with pytest.raises(InputError, match=r"gate 'spin': key 'engine': unknown engine 'warp'"):
        plan_checks(gates, engine="warp")
    with pytest.raises(InputError, match=r"gate 'spin': key 'integrator': unknown integrator "):
        plan_checks(gates, engine="mujoco")  # splitting is the reference's


def test_planning_expands_every_integrator_and_retargets(tmp_path):
    text = GOOD.replace('"splitting"', f'"{ALL_INTEGRATORS}"')
    gates = load_gates([write(tmp_path, text)])
    checks = plan_checks(gates)
    # per integrator: the drift at each of the two dt, and the verdict at each
    assert [(c.integrator, c.dt, c.limit.measure) for c in checks[:4]] == [
        ("seed", 0.02, "angular_momentum_drift"),
        ("seed", 0.01, "angular_momentum_drift"),
        ("seed", 0.02, "verdict"),
        ("seed", 0.01, "verdict"),
    ]
    assert {c.integrator for c in checks} == set(ENGINES["reference"].integrators)
    retargeted = plan_checks(gates, engine="mujoco")
    assert {c.engine for c in retargeted} == {"mujoco"}
    assert {c.integrator for c in retargeted} == set(ENGINES["mujoco"].integrators)
    assert retargeted[0].id == "free_spin_cube-mujoco-Euler-dt=0.02-angular_momentum_drift"


# ---- evaluation ---------------------------------------------------------------------------------


class SerialExecutor:
    """Runs in this process (the engines a test registers need no fork); `refuse` fails the
    test when anything is run at all."""

    name = "serial"

    def __init__(self, refuse: bool = False):
        self.refuse = refuse

    def map_unordered(self, fn, items):
        for item in items:
            assert not self.refuse, f"{item.label} was run again: it should come from the cache"
            yield item, fn(item)


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> ResultsCache:
    """One results cache for the module: tests share the runs they have in common."""
    return ResultsCache(tmp_path_factory.mktemp("gate-cache"))


BLOG_SPIN = """
[[gates]]
name = "blog"
case = "free_spin_cube"
engine = "reference"
integrator = "seed"
duration = 1.0
[gates.limits]
energy_drift = { max = 1e-3 }
steps = { min = 100, max = 100 }
verdict = "ok"
"""
MJ_SPIN = """
[[gates]]
name = "mj"
case = "free_spin_cube"
engine = "mujoco"
integrator = "Euler"
duration = 1.0
[gates.limits]
energy_drift = { max = 1e-3 }
steps = { max = 50 }
"""
SPIN = BLOG_SPIN + MJ_SPIN


def test_limits_pass_and_fail_on_the_suites_own_measures(tmp_path, cache):
    gates = load_gates([write(tmp_path, SPIN)])
    table = evaluate(gates, cache, progress=False)
    assert list(table.columns) == CHECK_COLUMNS
    rows = table.set_index(["gate", "measure"])
    # the blog's scheme gains energy (its rotation stretches the body); MuJoCo's Euler
    # keeps a principal-axis spin's energy: each measured as `summarize` measures it
    short = dataclasses.replace(CATALOG["free_spin_cube"], duration=1.0)
    for gate, engine, integrator in (("blog", "reference", "seed"), ("mj", "mujoco", "Euler")):
        drift = summarize(run(short, engine, integrator), short)["energy_drift"]
        assert rows.loc[(gate, "energy_drift"), "measured"] == drift
    blog, mj = rows.loc[("blog", "energy_drift")], rows.loc[("mj", "energy_drift")]
    assert blog["measured"] > 1e-3 and not blog["passed"] and blog["margin"] < 0
    assert mj["measured"] < 1e-3 and mj["passed"] and 0 < mj["margin"] <= 1
    assert blog["limit"] == "<= 0.001" and blog["dt"] == 0.01 and blog["reason"] == ""
    # 100 steps of 0.01 s: on the limit (margin 0) passes, twice the limit is a margin of -1
    steps = rows.loc[("blog", "steps")]
    assert steps["passed"] and steps["margin"] == 0 and steps["limit"] == ">= 100, <= 100"
    assert not rows.loc[("mj", "steps"), "passed"] and rows.loc[("mj", "steps"), "margin"] == -1
    assert rows.loc[("blog", "verdict"), "measured"] == "ok"
    assert rows.loc[("blog", "verdict"), "passed"]
    assert table.attrs["computed"] == 2
    # again: every run from the cache, the same table
    again = evaluate(gates, cache, progress=False, executor=SerialExecutor(refuse=True))
    assert again.attrs == {"computed": 0, "cached": 2}
    assert again.drop(columns="margin").equals(table.drop(columns="margin"))


def test_engine_retargets_every_gate_and_expands_every_integrator(tmp_path, cache):
    text = SPIN.replace('integrator = "seed"', 'integrator = "*"')
    table = evaluate(load_gates([write(tmp_path, text)]), cache, engine="mujoco", progress=False)
    assert set(table["engine"]) == {"mujoco"}
    blog = table[table["gate"] == "blog"]
    assert list(dict.fromkeys(blog["integrator"])) == list(ENGINES["mujoco"].integrators)
    # the retargeted gate measures what the mujoco gate measures on the same run
    mine = table[(table["gate"] == "mj") & (table["measure"] == "energy_drift")]
    theirs = blog[(blog["integrator"] == "Euler") & (blog["measure"] == "energy_drift")]
    assert mine["measured"].item() == theirs["measured"].item()


ROD = """
[[gates]]
name = "rod"
case = "thin_rod"
engine = "reference"
integrator = "euler"
dt = [0.02, 0.01]
duration = 2.0
[gates.limits]
energy_drift = { max = 1e6 }
largest_stable_dt = { min = 0.01 }
verdict = ["ok", "diverged"]
"""


def test_a_diverged_run_fails_its_checks_with_the_reason(tmp_path, cache):
    # euler's explicit rotation blows up the rod's energy at dt 0.02 (the verdict "diverged")
    # and holds it at 0.01 over 2 s
    table = evaluate(load_gates([write(tmp_path, ROD)]), cache, progress=False)
    drift = table[table["measure"] == "energy_drift"].set_index("dt")
    assert not drift.loc[0.02, "passed"] and drift.loc[0.02, "reason"] == "the run diverged"
    assert drift.loc[0.02, "measured"] < 1e6  # under the limit: failed for diverging alone
    assert drift.loc[0.01, "passed"] and drift.loc[0.01, "reason"] == ""
    verdicts = table[table["measure"] == "verdict"].set_index("dt")
    assert list(verdicts["measured"]) == ["diverged", "ok"] and verdicts["passed"].all()
    stable = table[table["measure"] == "largest_stable_dt"].iloc[0]
    assert stable["measured"] == 0.01 and stable["passed"] and math.isnan(stable["dt"])


def test_order_over_the_dt_list(tmp_path, cache):
    text = """
[[gates]]
name = "tumble"
case = "tumbling_box"
engine = "reference"
integrator = "rk4"
dt = [0.04, 0.02, 0.01]
duration = 1.0
[gates.limits]
order = { declared_within = 0.15 }

[[gates]]
name = "tight"
case = "tumbling_box"
engine = "reference"
integrator = "rk4"
dt = [0.04, 0.02, 0.01]
duration = 1.0
[gates.limits]
order = { declared_within = 0.001 }
"""
    table = evaluate(load_gates([write(tmp_path, text)]), cache, progress=False)
    loose, tight = table.itertuples()
    assert abs(loose.measured - 4) <= 0.15 and loose.passed and loose.limit == "within 0.15 of 4"
    assert tight.measured == loose.measured and not tight.passed and tight.margin < 0


BOUNCE = """
[[gates]]
name = "bounce"
case = "bounce"
engine = "reference"
integrator = "euler"
duration = 1.5
[gates.limits]
rebound_ratio = { min = 0 }
"rebound_ratio.error" = { abs_max = 0.01 }
"rebound_ratio.relative_error" = { abs_max = 0.02 }
stopping_distance = { max = 1 }
position_error = { max = 1 }
"""


def test_outcome_measures_and_what_a_case_does_not_measure(tmp_path, cache):
    table = evaluate(load_gates([write(tmp_path, BOUNCE)]), cache, progress=False)
    rows = table.set_index("measure")
    scene = dataclasses.replace(CATALOG["bounce"], duration=1.5)
    o = outcomes(run(scene, "reference", "euler"), scene).set_index("quantity")
    measured, expected = o.loc["rebound_ratio", ["measured", "expected"]]
    assert rows.loc["rebound_ratio", "measured"] == measured
    assert rows.loc["rebound_ratio.error", "measured"] == measured - expected
    assert rows.loc["rebound_ratio.relative_error", "measured"] == (measured - expected) / expected
    assert rows.loc[["rebound_ratio", "rebound_ratio.error"], "passed"].all()
    missing = rows.loc["stopping_distance"]
    assert not missing["passed"] and missing["reason"].startswith(
        "case 'bounce' measures no 'stopping_distance' (it measures rest_com_height, rebound_ratio"
    )
    # one dt of a case without an exact solution: its own reference, no pose error
    assert rows.loc["position_error", "reason"] == (
        "position_error is not measured on this run (errors against self-convergence (dt=0.001))"
    )


class Broken:
    """An engine whose every run raises, and that models no contact."""

    name = "broken"
    integrators = ("only",)
    default_integrator = "only"
    orders = {"only": 1}
    missing = None

    def unsupported(self, scene):
        return "contact is not modelled" if scene.has_contact else None

    def run(self, scene, integrator, dt, duration):
        raise RuntimeError("the solver exploded")


@pytest.fixture
def broken(monkeypatch):
    monkeypatch.setitem(ENGINES, "broken", Broken())
    return "broken"


def test_a_failed_run_fails_its_checks_and_never_raises(tmp_path, cache, broken):
    text = ROD.replace('"reference"', '"broken"').replace('"euler"', '"only"')
    text = text.replace('verdict = ["ok", "diverged"]', 'verdict = "failed"')
    table = evaluate(
        load_gates([write(tmp_path, text)]), cache, progress=False, executor=SerialExecutor()
    )
    rows = table.set_index(["measure", "dt"])
    said = "the run failed: RuntimeError: the solver exploded"
    assert (rows.loc["energy_drift", "reason"] == said).all()
    assert not rows.loc["energy_drift", "passed"].any()
    stable = table[table["measure"] == "largest_stable_dt"].iloc[0]
    assert not stable["passed"]
    assert stable["reason"] == "the run at dt=0.02 failed: RuntimeError: the solver exploded"
    verdicts = table[table["measure"] == "verdict"]
    assert (verdicts["measured"] == "failed").all() and verdicts["passed"].all()
    assert (verdicts["reason"] == "RuntimeError: the solver exploded").all()


def test_a_case_the_engine_does_not_model_is_not_checked(tmp_path, cache, broken):
    text = BOUNCE.replace('"reference"', '"broken"').replace('"euler"', '"only"')
    table = evaluate(
        load_gates([write(tmp_path, text)]), cache, progress=False, executor=SerialExecutor()
    )
    assert table["passed"].isna().all()
    assert set(table["reason"]) == {"engine 'broken' cannot run 'bounce': contact is not modelled"}


def test_an_unavailable_engine_is_bad_input(tmp_path, cache, broken, monkeypatch):
    monkeypatch.setattr(ENGINES["broken"], "missing", "pip install broken", raising=False)
    text = SPIN.replace('"reference"', '"broken"').replace('"seed"', '"only"')
    with pytest.raises(InputError, match="engine 'broken' is unavailable: pip install broken"):
        evaluate(load_gates([write(tmp_path, text)]), cache, executor=SerialExecutor(refuse=True))


def test_a_run_the_report_made_is_read_not_run_again(tmp_path):
    cache = ResultsCache(tmp_path / "cache")
    short = dataclasses.replace(CATALOG["free_spin_cube"], duration=1.0)
    spec = RunSpec(short, "mujoco", "Euler", short.dt, SWEEP_REPEATS)  # timed as a report times
    run_sweep([spec], cache, SerialExecutor(), progress=False)
    gates = load_gates([write(tmp_path, MJ_SPIN)])
    table = evaluate(gates, cache, progress=False, executor=SerialExecutor(refuse=True))
    assert table.attrs == {"computed": 0, "cached": 1} and len(table) == 2


EXACT_ORDER = """
[[gates]]
name = "exact_order"
case = "tumbling_box"
engine = "reference"
integrator = "{integrator}"
duration = 2.0
dt = [0.02, 0.01, 0.005]
[gates.limits]
order = {{ declared_within = 0.15 }}
"""


@pytest.mark.parametrize("integrator, passed", [("exact", True), ("splitting", True)])
def test_an_order_gate_passes_when_every_error_is_rounding(tmp_path, cache, integrator, passed):
    """The exact integrator has no truncation error in free flight: nothing to fit, and it
    converges faster than any declared order; splitting's order is fitted."""
    gates = load_gates([write(tmp_path, EXACT_ORDER.format(integrator=integrator))])
    (row,) = evaluate(gates, cache, progress=False).itertuples()
    assert row.passed == passed
    if integrator == "exact":
        assert math.isnan(row.measured) and row.reason.startswith("rounding")
    else:
        assert abs(row.measured - 2) < 0.15
