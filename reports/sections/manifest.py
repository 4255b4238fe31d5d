"""The closing sections: the parity manifest (each run's model checked against the scene, and the
settings each engine used) and the machine and versions the runs were taken on."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from comparators.sweep import SweepResult
from reports import texts
from reports.sections.layout import folded, section, subsection
from reports.tables import EMPTY_CELL, escape_markdown, markdown_table


def _flatten(settings: dict, prefix: str = "") -> dict[str, str]:
    """Nested settings as {"a.b": value}; lists and scalars as compact text."""
    flat = {}
    for key, value in settings.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat |= _flatten(value, name + ".")
        else:
            flat[name] = value if isinstance(value, str) else json.dumps(value, default=str)
    return flat


def _representative(runs: pd.DataFrame, trajectories: dict) -> pd.DataFrame:
    """One run with a trajectory per integrator of one engine, all from the same case and dt
    where possible: the case and dt of the run whose manifest lists the most settings."""
    have = runs[runs["key"].isin(trajectories.keys())]
    if have.empty:
        return have
    size = [len(_flatten(trajectories[k].meta.settings)) for k in have["key"]]
    richest = have.iloc[int(np.argmax(size))]
    same = (have["case"] == richest["case"]) & (have["dt"] == richest["dt"])
    ranked = have.assign(_other=~same).sort_values("_other", kind="stable")
    return ranked.groupby("integrator", sort=False).head(1).drop(columns="_other")


def _settings_table(reps: pd.DataFrame, trajectories: dict) -> str:
    """setting | value; a value that differs between integrators is given per integrator."""
    flat = {
        rep.integrator: _flatten(trajectories[rep.key].meta.settings) for rep in reps.itertuples()
    }
    names = list(dict.fromkeys(name for settings in flat.values() for name in settings))
    rows = []
    for name in names:
        values = {i: s.get(name, EMPTY_CELL) for i, s in flat.items()}
        if len(set(values.values())) == 1:
            rows.append((name, next(iter(values.values()))))
        else:
            rows.append((name, "; ".join(f"{i}: {v}" for i, v in values.items())))
    return markdown_table(pd.DataFrame(rows, columns=["setting", "value"]))


def _parity_status(runs: pd.DataFrame) -> str:
    failed = runs[runs["verdict"].str.startswith("failed: parity")]
    if failed.empty:
        return "passed"
    return f"failed in {len(failed)} of {len(runs)} runs: {failed['verdict'].iloc[0]}"


def _engine_settings(engine: str, runs: pd.DataFrame, trajectories: dict) -> list[str]:
    """The settings subsection of one engine, read back from one run per integrator."""
    reps = _representative(runs, trajectories)
    if reps.empty:
        none = "No run produced a trajectory, so no settings were read back."
        return subsection(f"Settings: {engine}", none)
    where = ", ".join(f"{r.integrator} on `{r.case}` at dt {r.dt:.3g} s" for r in reps.itertuples())
    source = (
        f"From the runs: {where}. Settings that depend on the case (contact) or on dt "
        "differ between runs."
    )
    return subsection(f"Settings: {engine}", source, _settings_table(reps, trajectories))


def parity_section(result: SweepResult) -> list[str]:
    """Per engine/integrator the parity verdict, then per engine its settings."""
    results = result.results
    status = results.groupby(["engine", "integrator"], sort=False).apply(
        lambda runs: pd.Series({"runs": len(runs), "parity at t = 0": _parity_status(runs)}),
        include_groups=False,
    )
    lines = section("Parity manifest", texts.PARITY, markdown_table(status.reset_index()))
    settings = []
    for engine, runs in results.groupby("engine", sort=False):
        settings += _engine_settings(engine, runs, result.trajectories)
    return lines + folded("Each engine's settings", settings)


def versions_section(result: SweepResult) -> list[str]:
    """The machine, each engine's library versions, and the code versions of the runs."""
    machine = pd.DataFrame({"item": list(result.machine), "value": list(result.machine.values())})
    versions = {}
    for row in result.results.itertuples():
        traj = result.trajectories.get(row.key)
        for package, version in (traj.meta.versions if traj else {}).items():
            versions.setdefault((row.engine, package), set()).add(version)
    frame = pd.DataFrame(
        [(e, p, ", ".join(sorted(v))) for (e, p), v in versions.items()],
        columns=["engine", "package", "version"],
    )
    code = ", ".join(sorted(result.results["code_version"].dropna().astype(str).unique()))
    code_line = f"Code version(s) of the runs: {escape_markdown(code) or EMPTY_CELL}."
    return section(
        "Machine and versions",
        texts.VERSIONS,
        markdown_table(machine),
        markdown_table(frame),
        code_line,
    )
