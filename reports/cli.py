"""The `rigidbench` command line: one function per command; the arguments are
`reports.arguments`.

Bad input (unknown case, engine or integrator, malformed case file, NaN dt) is reported as one
line on stderr with exit status 2 and no traceback; nothing is written. Ctrl-C is one line and
exit status 130, with every worker process stopped and no file half-written.

The terminal shows progress and one closing line saying what was written where. What engines
print or warn goes into each run's record (`comparators.engine_output`), not onto the terminal:
the console writes to `terminal_stream()`, which the runs' captures of file descriptors 1 and 2
leave in place, so a progress bar or spinner refreshed during a run in this process stays on
the terminal and out of the run's record.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

from rich.console import Console
from rich.table import Table
from rich.text import Text

from cases import CATALOG, InputError, resolve_case, scene_to_toml
from cases.catalog import CUBE_RAIN_MAX, CUBE_RAIN_PREFIX, CUBE_RAIN_REPRESENTATIVE
from comparators import ENGINES, get_engine, run
from comparators.cache import CacheWarning
from comparators.engine import (
    ContractError,
    EngineFailure,
    check_engine,
    failure_reason,
    left_out,
    unsupported,
)
from comparators.engine_output import terminal_stream
from comparators.interrupt import EXIT_INTERRUPTED, catching_interrupts, check, in_child
from comparators.limits import check_run, limits_set
from comparators.outcomes import outcomes
from comparators.parity import ParityError
from comparators.progress import Bar, stage
from comparators.summary import summarize
from comparators.trajectory import atomic_path
from reports import console_tables
from reports.arguments import build_parser, one_line
from reports.outputs import output_dir, output_file
from reports.terminal import console_on, to_nowhere

EXIT_BAD_INPUT = 2
# The reader of the output left (`rigidbench bench | head`): the status a shell gives a command
# that SIGPIPE stops (128 + 13).
EXIT_BROKEN_PIPE = 141
# an engine's model or table is not the scene's, or it raised on a scene the suite accepted:
# the engine's or its adapter's fault, not the input's
EXIT_PARITY = 3


# ---- shared by the commands -------------------------------------------------------------------


def _scenes(names: list[str] | None) -> list:
    """The named cases (catalog names or .toml files), or the whole catalog; names distinct,
    also as the report's section links read them (`anchor`: letter case, '.' and repeated '-'
    dropped), which a case-insensitive disk's figure files follow."""
    from reports.sections.layout import anchor, case_title

    scenes = [resolve_case(c) for c in names] if names else list(CATALOG.values())
    by_link: dict[str, list[str]] = {}
    for scene in scenes:
        by_link.setdefault(anchor(case_title(scene.name)), []).append(scene.name)
    for link, same in by_link.items():
        if len(same) > 1 and same[0] == same[1]:
            raise InputError(
                f"--cases: more than one case is named {same[0]!r}: expected cases of distinct "
                "names"
            )
        if len(same) > 1:
            raise InputError(
                f"--cases: cases {same[0]!r} and {same[1]!r} would share the report's section "
                f"link #{link} and, on a case-insensitive disk, their figure files: expected "
                "names that differ in more than letter case, '.' and repeated '-'"
            )
    return scenes


def _distinct(values: list | None, option: str, what: str) -> None:
    """InputError when `option` names a value twice (it would run, and show, twice)."""
    seen = set()
    for value in values or []:
        if value in seen:
            raise InputError(f"{option}: {value!r} given twice: expected distinct {what}")
        seen.add(value)


def _engines(names: list[str] | None) -> list[str]:
    """The named engines (checked, distinct), or every available one."""
    _distinct(names, "--engines", "engines")
    engines = names or [name for name, engine in ENGINES.items() if not engine.missing]
    for name in engines:
        get_engine(name)
    return engines


def _print_left_out(console: Console, scenes: list, engines: list[str]) -> list[str]:
    """Print which engines and runs the command leaves out, and why; return the lines."""
    lines = left_out(scenes, engines)
    for line in lines:
        console.print(f"left out: {line}", markup=False)
    return lines


# ---- the commands ----------------------------------------------------------------------------


def _cmd_list(args, console: Console) -> None:
    caption = (
        f"also {CUBE_RAIN_PREFIX}N for any N from 1 to {CUBE_RAIN_MAX} "
        f"({CUBE_RAIN_PREFIX}{CUBE_RAIN_REPRESENTATIVE} above)"
    )
    table = Table(title="rigidbench catalog", caption=caption, show_lines=False)
    for col in ("case", "tags", "models", "description"):
        table.add_column(col, overflow="fold")
    for scene in CATALOG.values():
        table.add_row(scene.name, ", ".join(scene.tags), scene.modelled(), scene.description)
    console.print(table)


def _cmd_engines(args, console: Console) -> None:
    table = Table(title="engines")
    for col in ("engine", "integrators", "default", "status"):
        table.add_column(col)
    for engine in ENGINES.values():
        status = f"unavailable: {engine.missing}" if engine.missing else "ok"
        cells = (engine.name, ", ".join(engine.integrators), engine.default_integrator, status)
        table.add_row(*map(Text, cells))  # Text: "[drake]" in a status is no markup
    console.print(table)


def _cmd_show(args, console: Console) -> None:
    sys.stdout.write(scene_to_toml(resolve_case(args.case)))


def _cmd_run(args, console: Console) -> None:
    scene = resolve_case(args.case)
    output_file(args.out, "--out", (".csv", ".parquet"))
    dt = scene.dt if args.dt is None else args.dt
    _, integrator = check_engine(scene, args.engine, args.integrator)  # before the stage's line
    check_run(scene, dt, scene.duration if args.duration is None else args.duration)
    _compile_first(console, [args.engine])
    with stage(console, f"running {scene.name} on {args.engine} {integrator}"):
        try:
            traj = in_child(run, scene, args.engine, integrator, args.dt, args.duration)
        except (InputError, ParityError, ContractError):
            raise
        except Exception as exc:  # the engine's own failure on an accepted scene: one line
            raise EngineFailure(
                f"{args.engine} failed on {scene.name!r}: {failure_reason(exc)}"
            ) from exc
    summary = summarize(traj, scene)
    if args.out:
        traj.write(args.out)
    console.print(f"{scene.name}: {scene.modelled()}", markup=False)  # a title would wrap
    console.print(console_tables.metrics_table(summary))
    if not (said := outcomes(traj, scene)).empty:
        console.print(console_tables.outcomes_table(said, summary["verdict"]))
    if args.out:
        console.print(f"run: wrote {len(traj.table)} rows to {args.out}", markup=False)


def _compile_first(console: Console, engines: list[str]) -> None:
    """Compile the reference simulator in parallel processes before a run that needs it, where
    numba's cache lacks its code (`warm_up`); where cached, a run loads only what it uses."""
    if "reference" not in engines:  # nor import the simulator
        return
    from comparators.sweep import warm_up
    from reference_sim.compiled_cache import is_compiled

    if not is_compiled():
        warm_up(engines, console)


def _animated_runs(args, scene, console: Console) -> list[tuple[str, str]]:
    """(engine, integrator) of every panel, checked before any run: each engine (every
    available one that models the case by default, leaving the others out with a line saying
    why) with each of --integrator, or its default."""
    engines = _engines(args.engines)
    _distinct(args.integrator, "--integrator", "integrators")
    if not args.engines:
        _print_left_out(console, [scene], engines)
        engines = [name for name in engines if not unsupported(ENGINES[name], scene)]
    pairs = [
        (name, check_engine(scene, name, integrator)[1])
        for name in engines
        for integrator in args.integrator or [None]
    ]
    if not pairs:
        raise InputError(f"no engine here models {scene.name!r}: nothing to animate")
    return pairs


def _cached_runs(scene, pairs, dt: float, duration: float, cache) -> list:
    """Each (engine, integrator)'s run from the results cache: a report's run of it (timed
    SWEEP_REPEATS times) or an earlier single run, else None. Looked up before anything is
    compiled, so that an animation of cached runs compiles nothing."""
    from comparators.cache import run_key
    from comparators.timing import SWEEP_REPEATS

    def cached(engine: str, integrator: str):
        for repeats in (SWEEP_REPEATS, 1):
            traj = cache.get(run_key(scene, engine, integrator, dt, repeats, duration))
            if traj is not None:
                return traj
        return None

    return [cached(engine, integrator) for engine, integrator in pairs]


def _new_run(scene, engine: str, integrator: str, dt: float, duration: float, cache):
    """Run once now and store it as a single run. Returns the `Trajectory`, or the reason
    the run failed."""
    from comparators.cache import run_key
    from comparators.timing import attempt_run

    traj, error = in_child(attempt_run, scene, engine, integrator, dt, duration)
    if traj is None:
        return error
    cache.put(run_key(scene, engine, integrator, dt, 1, duration), traj)
    return traj


def _cmd_animate(args, console: Console) -> None:
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

    from comparators.cache import ResultsCache
    from reports.animation import animate
    from reports.arguments import DEFAULT_OUT

    scene = resolve_case(args.case)
    out = output_file(args.out, "--out", (".gif",))
    pairs = _animated_runs(args, scene, console)
    dt = scene.dt if args.dt is None else args.dt
    duration = scene.duration if args.duration is None else args.duration
    check_run(scene, dt, duration)
    cache = ResultsCache(
        output_dir(args.cache, "--cache") if args.cache is not None else DEFAULT_OUT / "cache"
    )
    trajs = _cached_runs(scene, pairs, dt, duration, cache)
    missing = [pair for pair, traj in zip(pairs, trajs, strict=True) if traj is None]
    _compile_first(console, [engine for engine, _ in missing])
    if missing:  # no "running" line where every run is cached
        with stage(console, f"running {scene.name}") as status:
            for k, (engine, integrator) in enumerate(pairs):
                if trajs[k] is None:
                    status.update(f"running {scene.name} on {engine} {integrator}")
                    trajs[k] = _new_run(scene, engine, integrator, dt, duration, cache)
    runs = [(f"{e}/{i}", traj) for (e, i), traj in zip(pairs, trajs, strict=True)]
    for label, traj in runs:
        if isinstance(traj, str):
            console.print(f"{label} failed: {traj}", markup=False)
    columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn()]
    with Bar(*columns, TimeElapsedColumn(), console=console) as bar:
        task = bar.add_task(f"drawing {scene.name}", total=None)

        def drawn(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        animate(scene, runs, out, progress=drawn)
        frames = bar.tasks[0].completed
    closing = (
        f"animate: wrote {out.as_posix()} ({out.stat().st_size / 1e3:.0f} kB, {len(runs)} "
        f"panels, {frames:.0f} frames); runs cached in {cache.root.as_posix()}/"
    )
    console.print(closing, markup=False, soft_wrap=True)


def _cmd_bench(args, console: Console) -> None:
    from comparators.bench import bench, plan_bench
    from comparators.sweep import warm_up
    from reports.plots import plot_throughput

    out = output_file(args.out, "--out", (".csv",))
    scenes = _scenes(args.cases)
    engines = _engines(args.engines)
    _distinct(args.dt, "--dt", "time steps")
    plan_bench(scenes, engines, args.dt, args.duration, args.repeats)  # bad dt, duration, repeats
    _print_left_out(console, scenes, engines)
    start = time.perf_counter()
    warm_up(engines, console)
    table = in_child(bench, scenes, engines, args.dt, args.duration, args.repeats, console=console)
    console.print(
        console_tables.throughput_table(table, "stepping throughput (steps/s, stepping only)")
    )
    closing = f"bench: {len(table)} rows in {time.perf_counter() - start:.1f} s"
    if out is not None:
        with atomic_path(out) as tmp:
            table.to_csv(tmp, index=False)
        figure = plot_throughput(table, out.with_suffix(".png"))
        closing += f"; wrote {out} and {figure}"
    console.print(closing, markup=False, soft_wrap=True)


def _executor(args):
    """The sweep's executor: local worker processes, or a Dask scheduler."""
    from comparators.sweep import DaskExecutor, LocalExecutor

    if args.executor != "dask" and args.scheduler is not None:
        raise InputError(
            f"--scheduler {args.scheduler!r}: only with --executor dask: expected --executor dask "
            "or no --scheduler"
        )
    if args.executor == "dask":
        if not args.scheduler:
            raise InputError("--executor dask: expected --scheduler ADDRESS (e.g. tcp://host:8786)")
        return DaskExecutor(args.scheduler)
    return LocalExecutor(args.jobs)


def _measure_scaling(args, engines: list[str], console: Console):
    """The scaling table of `cube_rain_N` (quick or full counts and windows)."""
    from comparators import scaling

    counts = scaling.QUICK_COUNTS if args.quick else scaling.FULL_COUNTS
    windows = scaling.QUICK_WINDOWS if args.quick else scaling.FULL_WINDOWS
    started = time.perf_counter()
    with stage(console, "scaling") as status:
        table = scaling.measure_scaling(
            counts,
            engines,
            windows,
            # a label before every repeat of every run: hundreds, too many for a log
            progress=lambda label: status.update(f"scaling: {label}", logged=False),
        )
    fastest = table[table["series"] == scaling.FASTEST].drop_duplicates(["engine"])
    named = ", ".join(f"{r.engine} {r.integrator}" for r in fastest.itertuples()) or "none"
    console.print(
        f"scaling: cube_rain_N for N in {', '.join(map(str, counts))}, "
        f"{len(table)} measurements in {time.perf_counter() - started:.1f} s; "
        f"fastest other than the default: {named}"
    )
    return table


def _cmd_report(args, console: Console) -> None:
    from comparators.cache import ResultsCache
    from comparators.sweep import plan, run_sweep, warm_up
    from reports.figures import animated_cases
    from reports.report import write_report

    start = time.perf_counter()
    scenes = _scenes(args.cases)
    engines = _engines(args.engines)
    executor = _executor(args)
    out = output_dir(args.out, "--out")
    cache_dir = output_dir(args.cache, "--cache") if args.cache is not None else out / "cache"
    specs = plan(scenes, engines, quick=args.quick)  # a run over the limits: before compiling
    cache = ResultsCache(cache_dir)
    warm_up(engines, console)
    lines = _print_left_out(console, scenes, engines)
    result = run_sweep(specs, cache, executor, left_out=lines, console=console)
    # scaling after the sweep: none of the sweep's workers competes for the cores
    table = _measure_scaling(args, engines, console) if args.scaling else None
    command = " ".join(["rigidbench", *sys.argv[1:]])
    animated = animated_cases(result.scenes, full=not args.quick)
    write_report(result, out, command=command, scaling=table, animated=animated)
    closing = _report_closing(result, out, time.perf_counter() - start)
    console.print(closing, markup=False, soft_wrap=True)  # one line, also on a narrow terminal


def _report_closing(result, out: Path, elapsed_s: float) -> str:
    """The report's one closing line: the folder, the file to open, and what the runs gave."""
    verdicts = result.results["verdict"]
    failed = verdicts.str.startswith("failed").sum()
    diverged = (verdicts == "diverged").sum()
    said = (result.results["engine_messages"].fillna(0) > 0).sum()
    return (
        f"report: {out.as_posix()}/ (open {(out / 'index.html').as_posix()}); "
        f"{len(result.results)} runs ({result.computed} computed, {result.cached} cached; "
        f"{diverged} diverged, {failed} failed, {said} with engine messages) "
        f"in {elapsed_s:.1f} s"
    )


def _gate_paths(args) -> list[Path]:
    """The gate files and directories to check: FILE_OR_DIR..., and with --physics the
    package's physics gates."""
    from gates import PHYSICS_DIR

    paths = [Path(p) for p in args.paths]
    if args.physics:
        if not PHYSICS_DIR.is_dir():
            raise InputError(f"--physics: this rigidbench ships no physics gates ({PHYSICS_DIR})")
        paths.append(PHYSICS_DIR)
    if not paths:
        raise InputError(
            "gate: expected gate files or directories (FILE_OR_DIR...), --physics, "
            "or --record OUT.toml --cases ... --engine NAME"
        )
    return paths


def _cmd_gate(args, console: Console) -> int:
    from gates.spec import load_gates

    start = time.perf_counter()
    if args.record:
        return _record_gates(args, console, start)
    if args.cases:
        raise InputError("--cases: only with --record OUT.toml (the gates name their cases)")
    junit = output_file(args.junit, "--junit", (".xml",))
    if args.engine is not None:
        get_engine(args.engine)  # an unknown --engine is the option's fault, not the files'
    gates = load_gates(_gate_paths(args))
    return _check_gates(args, console, gates, junit, start)


def _check_gates(args, console: Console, gates: list, junit: Path | None, start: float) -> int:
    """Evaluate `gates`, print the table and the closing line; 1 when a check failed."""
    from comparators.cache import ResultsCache
    from comparators.sweep import LocalExecutor
    from gates.evaluate import evaluate, plan_checks
    from gates.output import closing_line, write_junit
    from reports.arguments import DEFAULT_OUT

    plan_checks(gates, args.engine)  # a missing engine or integrator: before any run
    cache = ResultsCache(
        output_dir(args.cache, "--cache") if args.cache is not None else DEFAULT_OUT / "cache"
    )
    executor = LocalExecutor(args.jobs)
    checks = evaluate(gates, cache, args.engine, executor=executor, console=console)
    console.print(console_tables.gate_table(checks))
    for line in console_tables.gate_reasons(checks):
        console.print(line, markup=False, soft_wrap=True)
    closing = closing_line(checks, time.perf_counter() - start)
    if junit is not None:
        write_junit(checks, junit)
        closing += f"; wrote {junit.as_posix()}"
    console.print(closing, markup=False, soft_wrap=True)
    return 1 if (checks["passed"] == False).any() else 0  # noqa: E712 (None: not checked)


def _record_gates(args, console: Console, start: float) -> int:
    """gate --record OUT.toml --cases ... --engine NAME [--slack S]: write the gates, then
    check them as `gate OUT.toml` would (today's values are within their limits)."""
    from comparators.cache import ResultsCache
    from comparators.sweep import LocalExecutor
    from gates.record import check_out, record
    from gates.spec import load_gates
    from reports.arguments import DEFAULT_OUT

    out = Path(args.record)
    check_out(out)
    if args.paths or args.physics or args.junit:
        raise InputError("--record writes gates: expected no FILE_OR_DIR, --physics or --junit")
    if not args.cases or not args.engine:
        raise InputError("--record OUT.toml: expected --cases CASE... and --engine NAME")
    if get_engine(args.engine).missing:
        raise InputError(f"engine {args.engine!r} is unavailable: {ENGINES[args.engine].missing}")
    scenes = list(zip(args.cases, _scenes(args.cases), strict=True))
    cache = ResultsCache(
        output_dir(args.cache, "--cache") if args.cache is not None else DEFAULT_OUT / "cache"
    )
    executor = LocalExecutor(args.jobs)
    count = record(scenes, args.engine, out, cache, args.slack, executor=executor, console=console)
    console.print(f"gate: recorded {count} gates in {out.as_posix()}", markup=False, soft_wrap=True)
    args.engine = None  # the recorded gates name their engine
    return _check_gates(args, console, load_gates([out]), None, start)


COMMANDS = {
    "list": _cmd_list,
    "engines": _cmd_engines,
    "show": _cmd_show,
    "run": _cmd_run,
    "animate": _cmd_animate,
    "report": _cmd_report,
    "bench": _cmd_bench,
    "gate": _cmd_gate,
}


def _one_line_cache_warnings(shown):
    """`warnings.showwarning` that prints a `CacheWarning` as one line on stderr (the file and
    why it was discarded) and passes every other warning to `shown`."""

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, CacheWarning):
            print(f"rigidbench: warning: {one_line(str(message))}", file=sys.stderr, flush=True)
        else:
            shown(message, category, filename, lineno, file, line)

    return show


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    terminal = terminal_stream()
    console = console_on(terminal)
    try:
        limits = (getattr(args, "max_steps", None), getattr(args, "max_recorded", None))
        with warnings.catch_warnings(), catching_interrupts(), limits_set(*limits):
            warnings.showwarning = _one_line_cache_warnings(warnings.showwarning)
            status = COMMANDS[args.command](args, console) or 0
            check()  # a Ctrl-C that came inside a compiler callback and could not stop the command
    except InputError as exc:
        print(f"rigidbench: error: {one_line(str(exc))}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ParityError as exc:
        print(f"rigidbench: parity error: {one_line(str(exc))}", file=sys.stderr)
        return EXIT_PARITY
    except (ContractError, EngineFailure) as exc:
        print(f"rigidbench: engine error: {one_line(str(exc))}", file=sys.stderr)
        return EXIT_PARITY
    except KeyboardInterrupt:
        # The pools have stopped their workers on the way out (`comparators.interrupt`) and
        # every file is written through `atomic_path`: nothing half-written, no worker left.
        print(
            f"rigidbench: interrupted: {args.command} stopped, nothing half-written",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # files are written through `atomic_path` and pools stop on the way out, as above
        to_nowhere(terminal, sys.stdout)
        return EXIT_BROKEN_PIPE
    finally:
        if terminal is not sys.stdout:
            terminal.close()
    return status


if __name__ == "__main__":
    sys.exit(main())
