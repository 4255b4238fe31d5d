"""Evaluate gates: run what they need through the results cache, measure, compare with limits.

Each gate on an engine and integrator is a set of checks, one per limit and dt (one per limit for
the measures over the dt list, `order` and `largest_stable_dt`). The runs of one gate on one
engine are swept together (`comparators.sweep.run_sweep`), so that the errors of a case without
an exact solution are measured against the finest dt of that gate's own list, whatever other
gates ask for; every run is computed once and stored in the results cache, so evaluating again
recomputes nothing.

A run that fails or diverges fails the checks that depend on it (`reason` says so), except a
`verdict` check accepting that verdict and `largest_stable_dt`, which is measured from the
verdicts. Nothing about a run raises: bad input (an unknown or unavailable engine, an integrator
the engine does not have, a gate without an engine) raises `InputError` before any run.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import pandas as pd
from rich.console import Console

from cases.errors import InputError
from cases.scene import Scene
from comparators.cache import ResultsCache, run_key
from comparators.engine import ENGINES, get_engine, unsupported
from comparators.limits import check_run
from comparators.sweep import QUICK_HARD_REPEATS, LocalExecutor, RunSpec, run_sweep, warm_up
from comparators.timing import SWEEP_REPEATS
from gates.spec import ALL_INTEGRATORS, RESULT_MEASURES, Gate, Limit, measure_parts
from reports.convergence import fit_orders, largest_stable_dt

CHECK_COLUMNS = [
    "file",
    "gate",
    "case",
    "engine",
    "integrator",
    "dt",  # s; NaN for the measures over the gate's dt list
    "measure",
    "measured",  # a number, or the verdict for `verdict`
    "limit",  # text: "<= 0.001", "|x| <= 0.02", "within 0.15 of 2", "ok or jitter"
    "margin",  # fraction of the limit left (negative: failed); NaN for verdicts and no value
    "passed",  # True, False, or None: not checked (the engine cannot model the case)
    "reason",  # why a check failed or was not checked without a measurement, else ""
]
# Timings per run a gate computes: gates measure physics, and one run gives every measure (its
# timing columns are then a single timing). A run the report already timed is read as it is.
GATE_REPEATS = 1


@dataclass(frozen=True)
class Check:
    """One limit of a gate, on one engine, integrator and dt (NaN: over the gate's dt list)."""

    gate: Gate
    engine: str
    integrator: str
    dt: float
    limit: Limit

    @property
    def id(self) -> str:
        """case-engine-integrator-dt-measure, for test ids and JUnit names."""
        dt = "all-dt" if math.isnan(self.dt) else f"dt={self.dt:g}"
        return f"{self.gate.scene.name}-{self.engine}-{self.integrator}-{dt}-{self.limit.measure}"

    @property
    def declared_order(self) -> float:
        """The order the engine declares for the integrator (NaN: none)."""
        return float(getattr(ENGINES[self.engine], "orders", {}).get(self.integrator, math.nan))

    @property
    def limit_text(self) -> str:
        limit = self.limit
        if limit.verdicts:
            return " or ".join(limit.verdicts)
        parts = []
        if limit.min is not None:
            parts.append(f">= {limit.min:g}")
        if limit.max is not None:
            parts.append(f"<= {limit.max:g}")
        if limit.abs_max is not None:
            parts.append(f"|x| <= {limit.abs_max:g}")
        if limit.declared_within is not None:
            parts.append(f"within {limit.declared_within:g} of {self.declared_order:g}")
        return ", ".join(parts)


def target_engine(gate: Gate, engine: str | None) -> str:
    """The engine a gate runs on: `engine` when the command retargets, else the gate's own."""
    name = engine or gate.engine
    if name is None:
        raise InputError(
            f"{gate.file}: gate '{gate.name}': missing key 'engine' "
            "(expected an engine in the gate, or --engine NAME)"
        )
    try:
        get_engine(name)
    except InputError as err:
        raise InputError(f"{gate.file}: gate '{gate.name}': key 'engine': {err}") from None
    return name


def integrators(gate: Gate, engine: str) -> tuple[str, ...]:
    """The gate's integrators on `engine`: its own, each of the engine's ("*"), or the
    engine's default; an unavailable engine's are not checked (it runs nothing)."""
    eng = ENGINES[engine]
    if gate.integrator == ALL_INTEGRATORS:
        return tuple(eng.integrators) or (ALL_INTEGRATORS,)
    name = gate.integrator or eng.default_integrator
    if not eng.missing and name not in eng.integrators:
        raise InputError(
            f"{gate.file}: gate '{gate.name}': key 'integrator': unknown integrator {name!r} "
            f"for engine {engine!r}: expected one of {', '.join(eng.integrators)} or '*'"
        )
    return (name,)


def plan_checks(gates: list[Gate], engine: str | None = None) -> list[Check]:
    """Every check of `gates` in order (gate, integrator, limit, dt), on `engine` when given;
    raises `InputError` for a gate without an engine, an unknown engine or integrator, or a
    run over the limits (`comparators.limits`)."""
    checks = []
    for gate in gates:
        for dt in gate.dts:
            try:
                check_run(gate.scene, dt, gate.scene.duration)
            except InputError as err:
                raise InputError(f"{gate.file}: gate '{gate.name}': {err}") from None
        name = target_engine(gate, engine)
        for integrator in integrators(gate, name):
            for limit in gate.limits:
                dts = (math.nan,) if limit.over_dt else gate.dts
                checks.extend(Check(gate, name, integrator, dt, limit) for dt in dts)
    return checks


def evaluate(
    gates: list[Gate],
    cache: ResultsCache,
    engine: str | None = None,
    progress: bool = True,
    executor=None,
    console: Console | None = None,
) -> pd.DataFrame:
    """One row per check (`CHECK_COLUMNS`), in `plan_checks` order, `engine` retargeting every
    gate. Runs go through `cache` on `executor` (default: a local pool, a worker per core);
    `progress` shows a bar on `console`. An unavailable engine is bad input here."""
    checks = plan_checks(gates, engine)
    for name in dict.fromkeys(c.engine for c in checks):
        if ENGINES[name].missing:
            raise InputError(f"engine {name!r} is unavailable: {ENGINES[name].missing}")
    return evaluate_checks(checks, cache, progress, executor, console)


def evaluate_checks(
    checks: list[Check],
    cache: ResultsCache,
    progress: bool = True,
    executor=None,
    console: Console | None = None,
) -> pd.DataFrame:
    """`evaluate` of planned checks on available engines (a pytest item is one check)."""
    used: dict[tuple[Gate, str], set[str]] = {}  # the integrators of each gate and engine
    for check in checks:
        used.setdefault((check.gate, check.engine), set()).add(check.integrator)
    runs = [RunGroup.of(gate, engine, names) for (gate, engine), names in used.items()]
    measured = measure_groups(runs, cache, progress, executor, console)
    by_group = dict(zip(used, measured.groups, strict=True))
    rows = [_check_row(check, by_group[(check.gate, check.engine)]) for check in checks]
    table = pd.DataFrame(rows, columns=CHECK_COLUMNS)
    table.attrs.update(computed=measured.computed, cached=measured.cached)
    return table


# ---- running ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunGroup:
    """Runs measured together: a scene on one engine, some integrators, at each dt."""

    scene: Scene
    engine: str
    integrators: tuple[str, ...]
    dts: tuple[float, ...]

    @classmethod
    def of(cls, gate: Gate, engine: str, integrators: set[str]) -> RunGroup:
        ordered = tuple(sorted(integrators))
        return cls(gate.scene, engine, ordered, gate.dts)

    @property
    def refusal(self) -> str | None:
        """Why the engine does not run the scene, else None."""
        reason = unsupported(ENGINES[self.engine], self.scene)
        if reason is None:
            return None
        return f"engine {self.engine!r} cannot run {self.scene.name!r}: {reason}"


@dataclass
class Measured:
    """What a group's runs gave: the sweep's results and outcomes tables (None: not run)."""

    results: pd.DataFrame | None
    outcomes: pd.DataFrame | None
    refusal: str | None = None


@dataclass
class Measurements:
    """Every group's `Measured`, in order, and how many distinct runs were computed now and
    read from the results cache."""

    groups: list[Measured]
    computed: int
    cached: int


def run_spec(cache: ResultsCache, scene: Scene, engine: str, integrator: str, dt: float):
    """The run of a gate: a report's run of it where the cache holds one (timed as the report
    times runs), else one of GATE_REPEATS timings."""
    for repeats in (SWEEP_REPEATS, QUICK_HARD_REPEATS):
        spec = RunSpec(scene, engine, integrator, dt, repeats)
        if cache.has(_key(spec)):
            return spec
    return RunSpec(scene, engine, integrator, dt, GATE_REPEATS)


class _Once:
    """An executor that runs each spec at most once across sweeps: a run that failed (and so is
    not in the results cache) is replayed from memory rather than run again."""

    def __init__(self, inner):
        self.inner, self.name, self.failed = inner, inner.name, {}

    def map_unordered(self, fn, items):
        yield from ((item, self.failed[item]) for item in items if item in self.failed)
        fresh = [item for item in items if item not in self.failed]
        for item, out in self.inner.map_unordered(fn, fresh):
            trajectory, _, _ = out  # `comparators.sweep.execute`'s (trajectory, error, analysis)
            if trajectory is None:
                self.failed[item] = out
            yield item, out


def measure_groups(
    groups: list[RunGroup],
    cache: ResultsCache,
    progress: bool = True,
    executor=None,
    console: Console | None = None,
) -> Measurements:
    """Each group's results and outcomes. Every run not in `cache` is computed once, all of
    them in one sweep (the executor's workers busy throughout); then each group is read back
    from the cache as a sweep of its own, so its self-convergence references are its own
    finest dt."""
    runnable = [g for g in groups if g.refusal is None]
    specs = {
        g: [run_spec(cache, g.scene, g.engine, i, dt) for i in g.integrators for dt in g.dts]
        for g in runnable
    }
    engines = sorted({g.engine for g in runnable})
    warm_up(engines, console)
    once = _Once(executor or LocalExecutor(os.cpu_count() or 1))
    everything = list(dict.fromkeys(s for group in specs.values() for s in group))
    missing = [spec for spec in everything if not cache.has(_key(spec))]
    computed = run_sweep(missing, cache, once, progress=progress, console=console).computed
    out = []
    for group in groups:
        if group.refusal is not None:
            out.append(Measured(None, None, group.refusal))
            continue
        own = run_sweep(specs[group], cache, once, progress=False)
        out.append(Measured(own.results, own.outcomes))
    return Measurements(out, computed, len(everything) - computed)


def _key(spec: RunSpec) -> str:
    return run_key(spec.scene, spec.engine, spec.integrator, spec.dt, spec.repeats)


# ---- checking -----------------------------------------------------------------------------------


def check_labels(check: Check) -> dict:
    """The `CHECK_COLUMNS` row of `check` before it is judged: what it checks, failed."""
    return {
        "file": str(check.gate.file),
        "gate": check.gate.name,
        "case": check.gate.scene.name,
        "engine": check.engine,
        "integrator": check.integrator,
        "dt": check.dt,
        "measure": check.limit.measure,
        "measured": np.nan,
        "limit": check.limit_text,
        "margin": np.nan,
        "passed": False,
        "reason": "",
    }


def _check_row(check: Check, measured: Measured) -> dict:
    row = check_labels(check)
    if measured.refusal is not None:
        return row | {"passed": None, "reason": measured.refusal}
    runs = measured.results[measured.results["integrator"] == check.integrator]
    if check.limit.over_dt:
        value, reason = _over_dt(check, runs)
        return row | _judged(check, value, reason)
    run = runs[runs["dt"] == check.dt].iloc[0]
    verdict = str(run["verdict"])
    kind = "failed" if verdict.startswith("failed") else verdict
    failure = verdict.removeprefix("failed: ") if kind == "failed" else ""
    if check.limit.verdicts:
        return row | {"measured": kind, "passed": kind in check.limit.verdicts, "reason": failure}
    if kind == "failed":
        return row | {"reason": f"the run failed: {failure}"}
    outcomes = measured.outcomes
    at = outcomes[(outcomes["integrator"] == check.integrator) & (outcomes["dt"] == check.dt)]
    value, reason = _value(check, run, at)
    judged = _judged(check, value, reason)
    if kind == "diverged":
        judged |= {"passed": False, "reason": "the run diverged", "margin": np.nan}
    return row | judged


def _value(check: Check, run: pd.Series, outcomes: pd.DataFrame) -> tuple[float, str]:
    """(value, why there is none) of a per-dt measure: a results column or an outcome."""
    measure = check.limit.measure
    if measure in RESULT_MEASURES:
        value = float(run[measure])
        if math.isnan(value):
            note = f" (errors against {run['reference']})" if "error" in measure else ""
            return value, f"{measure} is not measured on this run{note}"
        return value, ""
    quantity, part = measure_parts(measure)
    found = outcomes[outcomes["quantity"] == quantity]
    if found.empty:
        known = ", ".join(outcomes["quantity"])
        known = f"it measures {known}" if known else "nor any outcome"
        return math.nan, f"case {check.gate.scene.name!r} measures no {quantity!r} ({known})"
    measured, expected, error = found.iloc[0][["measured", "expected", "error"]].astype(float)
    if math.isnan(measured):
        return math.nan, f"{quantity} is not measured on this run"
    if part == "measured":
        return measured, ""
    if math.isnan(expected):
        return math.nan, f"{quantity} has no expected value on this case"
    if part == "error":
        return error, ""
    if expected == 0:
        return math.nan, f"{quantity} is expected to be 0: no relative error; limit its .error"
    return error / abs(expected), ""


def _over_dt(check: Check, runs: pd.DataFrame) -> tuple[float, str]:
    """(value, why there is none) of `order` or `largest_stable_dt` over the gate's dt list."""
    verdicts = runs.sort_values("dt", ascending=False)[["dt", "verdict"]].itertuples()
    for run in verdicts:
        if run.verdict.startswith("failed"):
            return math.nan, f"the run at dt={run.dt:g} {run.verdict}"
        if check.limit.measure == "order" and run.verdict == "diverged":
            return math.nan, f"the run at dt={run.dt:g} diverged"
    if check.limit.measure == "largest_stable_dt":
        stable = largest_stable_dt(runs).iloc[0]
        value = float(stable["largest_stable_dt"])
        if math.isnan(value):
            first = f"dt={stable['first_unstable_dt']:g}: {stable['first_unstable_verdict']}"
            return value, f"no dt of the list is stable ({first})"
        return value, ""
    if math.isnan(check.declared_order) and check.limit.declared_within is not None:
        return math.nan, f"engine {check.engine!r} declares no order for {check.integrator!r}"
    fit = fit_orders(runs, {(check.engine, check.integrator): check.declared_order}).iloc[0]
    return float(fit["order"]), str(fit["note"])


def _judged(check: Check, value: float, reason: str) -> dict:
    """measured, margin, passed and reason of a numeric check."""
    limit = check.limit
    if not math.isfinite(value):
        if limit.measure == "order" and limit.max is None and reason.startswith("rounding"):
            # no truncation error at all (the exact integrator in free flight): it converges
            # at least as fast as any lower bound on the order asks
            return {"measured": value, "margin": math.nan, "passed": True, "reason": reason}
        return {"measured": value, "reason": reason or f"no finite value ({value})"}
    left = []  # (room left, the bound it is measured against)
    if limit.max is not None:
        left.append((limit.max - value, limit.max))
    if limit.min is not None:
        left.append((value - limit.min, limit.min))
    if limit.abs_max is not None:
        left.append((limit.abs_max - abs(value), limit.abs_max))
    if limit.declared_within is not None:
        deviation = abs(value - check.declared_order)
        left.append((limit.declared_within - deviation, limit.declared_within))
    margin = min(_fraction(room, bound) for room, bound in left)
    passed = all(room >= 0 for room, _ in left)
    return {"measured": value, "margin": margin, "passed": passed, "reason": ""}


def _fraction(room: float, bound: float) -> float:
    """Room left as a fraction of the bound; a bound of 0 has no fraction: +-inf, or 0 on it."""
    if bound != 0:
        return room / abs(bound)
    return 0.0 if room == 0 else math.copysign(math.inf, room)


def check_from_runs(check: Check, results: pd.DataFrame, outcomes: pd.DataFrame) -> dict:
    """One `CHECK_COLUMNS` row of `check` judged on runs already made: `results` and
    `outcomes` rows of a sweep (`comparators.sweep.SweepResult`) holding the check's case,
    engine and integrator at each dt of its gate (the report reads its own sweep this way)."""
    return _check_row(check, Measured(results, outcomes))
