"""pytest plugin (entry point `pytest11`): gate files collected as tests.

`pytest path/to/gates/` collects every gate file (a TOML file with a top-level `[[gates]]`
array; other TOML files are left alone) as one test item per check: per gate, engine,
integrator, limit and dt, named `GATE[case-engine-integrator-dt=DT-measure]`. A failing item
says what was measured against which limit, or why there is no measurement; a malformed file is
one collection error naming the file, the gate and the key. Checks on an engine that is not
installed are skipped, as are cases the engine does not model.

The first item of a file runs the file's gates (all at once, on a worker per core); the runs
go through a results cache kept in pytest's cache directory (`.pytest_cache`) unless
`--gates-cache DIR` says otherwise, so an unchanged run is not computed twice. `--gates-engine
NAME` retargets every gate at another engine, as `rigidbench gate --engine` does.

This module imports nothing heavy until a gate file turns up: pytest loads it in every session
of an environment where rigidbench is installed.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest

GATES_MARK = "[[gates]]"  # a file without this text is no gate file: not parsed at all


def pytest_addoption(parser):
    group = parser.getgroup("rigidbench", "rigidbench gate files")
    group.addoption("--gates-engine", help="run every gate of the gate files on this engine")
    group.addoption(
        "--gates-cache", help="results cache directory for gate runs (default: in .pytest_cache)"
    )


def pytest_collect_file(file_path: Path, parent):
    if file_path.suffix != ".toml":
        return None
    try:
        if GATES_MARK not in file_path.read_text(encoding="utf-8", errors="replace"):
            return None
    except OSError:
        return None
    from gates.spec import is_gate_file

    return GateFile.from_parent(parent, path=file_path) if is_gate_file(file_path) else None


class GateCheckFailed(AssertionError):
    """A check that failed: the message says measured against limit, or why not measured."""


class GateFile(pytest.File):
    """A gate file: its checks as items, evaluated together on the first one's turn."""

    def collect(self):
        from cases.errors import InputError
        from gates.evaluate import plan_checks
        from gates.spec import load_gate_file

        try:
            checks = plan_checks(load_gate_file(self.path), _option(self.config, "gates_engine"))
        except InputError as err:
            raise self.CollectError(str(err)) from None
        self.checks, self.runnable, self.results = checks, [], None
        for index, check in enumerate(checks):
            name = f"{check.gate.name}[{check.id}]"
            item = GateItem.from_parent(self, name=name, index=index, check=check)
            why_not = _cannot_run_here(check)
            if why_not:
                item.add_marker(pytest.mark.skip(reason=why_not))
            else:
                self.runnable.append(index)
            yield item

    def row(self, index: int):
        """The evaluated row of check `index`: the file's checks that can run here are
        evaluated together on the first call."""
        if self.results is None:
            from comparators.cache import ResultsCache
            from gates.evaluate import evaluate_checks

            runnable = [self.checks[i] for i in self.runnable]
            cache = ResultsCache(_cache_dir(self.config))
            table = evaluate_checks(runnable, cache, progress=False)
            self.results = dict(zip(self.runnable, table.itertuples(), strict=True))
        return self.results[index]


class GateItem(pytest.Item):
    """One check of a gate file."""

    def __init__(self, *, index: int, check, **kwargs):
        super().__init__(**kwargs)
        self.index, self.check = index, check

    def runtest(self):
        from gates.output import failure_message

        row = self.parent.row(self.index)
        if not row.passed:
            raise GateCheckFailed(failure_message(row))

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, GateCheckFailed):
            return str(excinfo.value)
        return super().repr_failure(excinfo, style)

    def reportinfo(self):
        return self.path, 0, self.name  # a line (the file's first): pytest places skips by it


def _cannot_run_here(check) -> str | None:
    """Why a check is skipped here: its engine is not installed, or does not model the case."""
    from comparators.engine import ENGINES, unsupported

    engine = ENGINES[check.engine]
    if engine.missing:
        return f"engine {check.engine!r}: {engine.missing}"
    refusal = unsupported(engine, check.gate.scene)
    if refusal:
        return f"engine {check.engine!r} cannot run {check.gate.scene.name!r}: {refusal}"
    return None


def _option(config, name: str):
    """A plugin option's value; None when the plugin was registered after the command line was
    parsed (a conftest that registers it for a checkout run without installing rigidbench)."""
    return getattr(config.option, name, None)


def _cache_dir(config) -> Path:
    """--gates-cache, else a directory in pytest's cache, else (no cache plugin) a temporary
    one for this session."""
    chosen = _option(config, "gates_cache")
    if chosen:
        return Path(chosen)
    if getattr(config, "cache", None) is not None:
        return config.cache.mkdir("rigidbench-gates")
    if not hasattr(config, "_rigidbench_gates_tmp"):
        config._rigidbench_gates_tmp = tempfile.TemporaryDirectory(prefix="rigidbench-gates-")
    return Path(config._rigidbench_gates_tmp.name)
