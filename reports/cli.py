"""The `rigidbench` command line.

Bad input (unknown case, engine or integrator, malformed case file, NaN dt) is reported as one
line on stderr with exit status 2 and no traceback; nothing is written.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from cases import CATALOG, InputError, resolve_case, scene_to_toml
from cases.catalog import CUBE_RAIN_MAX, CUBE_RAIN_PREFIX, CUBE_RAIN_REPRESENTATIVE
from comparators import ENGINES, get_engine, run
from comparators.bench import BENCH_DURATION_S, MIN_REPEATS
from comparators.metrics import summarize
from comparators.parity import ParityError
from comparators.trajectory import atomic_path

EXIT_BAD_INPUT = 2
EXIT_PARITY = 3  # an engine's model is not the scene: a bug in an adapter, not in the input


def _number(text: str) -> float:
    """argparse type: a finite number (NaN and inf are refused with the option's name)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def _whole(text: str, least: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"expected a number >= {least}, got {text!r}")
    return value


def _count(text: str) -> int:
    """argparse type: a whole number >= 1."""
    return _whole(text, 1)


def _repeats(text: str) -> int:
    """argparse type: a whole number >= MIN_REPEATS (a median with min and max)."""
    return _whole(text, MIN_REPEATS)


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
        table.add_row(engine.name, ", ".join(engine.integrators), engine.default_integrator, status)
    console.print(table)


def _cmd_show(args, console: Console) -> None:
    sys.stdout.write(scene_to_toml(resolve_case(args.case)))


def _format(value) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return "n/a"
        return f"{value:.4g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.3e}"
    return str(value)


def _cmd_run(args, console: Console) -> None:
    scene = resolve_case(args.case)
    if args.out is not None and not args.out.lower().endswith((".csv", ".parquet")):
        raise InputError(f"--out {args.out!r}: expected a file name ending in .csv or .parquet")
    with console.status(f"running {scene.name} on {args.engine}", spinner="dots"):
        traj = run(scene, args.engine, args.integrator, args.dt, args.duration)
    summary = summarize(traj, scene)
    if args.out:
        traj.write(args.out)
    table = Table(title=f"{scene.name}: {scene.modelled()}", show_header=False)
    table.add_column("metric", style="bold")
    table.add_column("value", justify="right")
    for key, value in summary.items():
        table.add_row(key, _format(value))
    console.print(table)
    if args.out:
        console.print(f"wrote {len(traj.table)} rows to {args.out}")


DEFAULT_OUT = Path(__file__).resolve().parent / "out"


def _scenes(names: list[str] | None) -> list:
    """The named cases (catalog names or .toml files), or the whole catalog; names distinct."""
    scenes = [resolve_case(c) for c in names] if names else list(CATALOG.values())
    if len({s.name for s in scenes}) != len(scenes):
        raise InputError("--cases: two cases have the same name: expected distinct cases")
    return scenes


def _engines(names: list[str] | None) -> list[str]:
    """The named engines (checked), or every available one."""
    engines = names or [name for name, engine in ENGINES.items() if not engine.missing]
    for name in engines:
        get_engine(name)
    return engines


def _rate(value: float) -> str:
    return "n/a" if math.isnan(value) else f"{value:.3g}"


THROUGHPUT_HEADERS = ("case", "engine", "integrator", "dt", "steps/s [min, max]", "vs MuJoCo Euler")


def _throughput_table(table, title: str) -> Table:
    """The bench table for the terminal: steps/s median [min, max], the ratio, the verdict."""
    out = Table(title=title)
    for col in THROUGHPUT_HEADERS:
        out.add_column(col, justify="left" if col in ("case", "engine", "integrator") else "right")
    out.add_column("verdict", overflow="fold")
    for row in table.itertuples():
        rate = _rate(row.steps_per_s)
        if not math.isnan(row.steps_per_s):
            rate += f" [{_rate(row.steps_per_s_min)}, {_rate(row.steps_per_s_max)}]"
        ratio = _rate(row.ratio_vs_mujoco_euler)
        out.add_row(row.case, row.engine, row.integrator, f"{row.dt:g}", rate, ratio, row.verdict)
    return out


def _cmd_bench(args, console: Console) -> None:
    from comparators.bench import bench, plan_bench
    from comparators.sweep import warm_up
    from reports.plots import plot_throughput

    out = Path(args.out) if args.out else None
    if out is not None:
        if out.suffix.lower() != ".csv":
            raise InputError(f"--out {args.out!r}: expected a file name ending in .csv")
        if not out.parent.is_dir():
            raise InputError(f"--out {args.out!r}: directory {str(out.parent)!r} missing")
    scenes = _scenes(args.cases)
    engines = _engines(args.engines)
    plan_bench(scenes, engines, args.dt, args.duration)  # bad dt or duration: before any run
    start = time.perf_counter()
    with console.status("compiling the reference simulator", spinner="dots"):
        warm_up(engines)
    table = bench(scenes, engines, args.dt, args.duration, args.repeats)
    console.print(_throughput_table(table, "stepping throughput (steps/s, stepping only)"))
    if out is not None:
        with atomic_path(out) as tmp:
            table.to_csv(tmp, index=False)
        figure = plot_throughput(table, out.with_suffix(".png"))
        console.print(f"wrote {out}")
        console.print(f"wrote {figure}")
    console.print(f"{len(table)} rows in {time.perf_counter() - start:.1f} s")


def _cmd_report(args, console: Console) -> None:
    from comparators import scaling
    from comparators.cache import ResultsCache
    from comparators.sweep import DaskExecutor, LocalExecutor, plan, run_sweep, warm_up
    from reports.report import write_report

    start = time.perf_counter()
    scenes = _scenes(args.cases)
    engines = _engines(args.engines)
    if args.executor == "dask":
        if not args.scheduler:
            raise InputError("--executor dask: expected --scheduler ADDRESS (e.g. tcp://host:8786)")
        executor = DaskExecutor(args.scheduler)
    else:
        executor = LocalExecutor(args.jobs)
    out = Path(args.out)
    cache = ResultsCache(Path(args.cache) if args.cache else out / "cache")
    with console.status("compiling the reference simulator", spinner="dots"):
        warm_up(engines)
    specs = plan(scenes, engines, quick=args.quick)
    result = run_sweep(specs, cache, executor)
    table = None
    if args.scaling:  # here, after the sweep: none of its workers competes for the cores
        counts = scaling.QUICK_COUNTS if args.quick else scaling.FULL_COUNTS
        windows = scaling.QUICK_WINDOWS if args.quick else scaling.FULL_WINDOWS
        started = time.perf_counter()
        with console.status("scaling", spinner="dots") as status:
            table = scaling.measure_scaling(
                counts, engines, windows, progress=lambda label: status.update(f"scaling: {label}")
            )
        console.print(
            f"scaling: cube_rain_N for N in {', '.join(map(str, counts))}, "
            f"{len(table)} measurements in {time.perf_counter() - started:.1f} s"
        )
    command = " ".join(["rigidbench", *sys.argv[1:]])
    files = write_report(result, out, command=command, scaling=table)
    failed = result.results["verdict"].str.startswith("failed").sum()
    diverged = (result.results["verdict"] == "diverged").sum()
    console.print(
        f"{len(specs)} runs ({result.computed} computed, {result.cached} cached, "
        f"{diverged} diverged, {failed} failed) in {time.perf_counter() - start:.1f} s"
    )
    for path in files.values():
        console.print(f"wrote {path}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rigidbench", description="Validation and benchmark suite for rigid-body physics."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the case catalog with tags and what each models")
    sub.add_parser("engines", help="engines and their integrators")
    show = sub.add_parser("show", help="a case as TOML (loads back to the same scene)")
    show.add_argument("case", help="catalog name or path to a .toml case file")
    run_p = sub.add_parser("run", help="run one case on one engine and print its metrics")
    run_p.add_argument("case", help="catalog name or path to a .toml case file")
    run_p.add_argument("--engine", default="reference", help="engine name (default: reference)")
    run_p.add_argument("--integrator", help="integrator name (default: the engine's default)")
    run_p.add_argument("--dt", type=_number, help="time step in s (default: the case's)")
    run_p.add_argument("--duration", type=_number, help="simulated time in s (default: the case's)")
    run_p.add_argument("--out", help="write the trajectory table to FILE.csv or FILE.parquet")
    rep = sub.add_parser("report", help="sweep case x engine x integrator x dt; write the report")
    rep.add_argument("--cases", nargs="+", help="catalog names or .toml files (default: catalog)")
    rep.add_argument("--engines", nargs="+", help="engine names (default: every available one)")
    rep.add_argument(
        "--quick",
        action="store_true",
        help="a reduced dt sweep (3 steps per case) and a reduced scaling measurement",
    )
    rep.add_argument(
        "--scaling",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="measure the cost per step of cube_rain_N against N (default: on)",
    )
    rep.add_argument("--out", default=str(DEFAULT_OUT), help=f"output directory ({DEFAULT_OUT})")
    rep.add_argument("--cache", help="results cache directory (default: OUT/cache)")
    rep.add_argument("--executor", choices=("local", "dask"), default="local")
    rep.add_argument("--scheduler", help="Dask scheduler address, with --executor dask")
    rep.add_argument(
        "--jobs", type=_count, default=os.cpu_count() or 1, help="local worker processes"
    )
    ben = sub.add_parser("bench", help="steps/s of case x engine x integrator, side by side")
    ben.add_argument("--cases", nargs="+", help="catalog names or .toml files (default: catalog)")
    ben.add_argument("--engines", nargs="+", help="engine names (default: every available one)")
    ben.add_argument(
        "--dt", type=_number, nargs="+", help="time step(s) in s (default: each case's own)"
    )
    ben.add_argument(
        "--duration",
        type=_number,
        help=f"simulated time per run in s (default: the case's, at most {BENCH_DURATION_S:g})",
    )
    ben.add_argument(
        "--repeats",
        type=_repeats,
        default=MIN_REPEATS,
        help=f"timed repeats per run, at least {MIN_REPEATS} (default {MIN_REPEATS})",
    )
    ben.add_argument("--out", help="write the table to FILE.csv and its plot to FILE.png")
    return parser


COMMANDS = {
    "list": _cmd_list,
    "engines": _cmd_engines,
    "show": _cmd_show,
    "run": _cmd_run,
    "report": _cmd_report,
    "bench": _cmd_bench,
}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    console = Console()
    try:
        COMMANDS[args.command](args, console)
    except InputError as exc:
        print(f"rigidbench: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ParityError as exc:
        print(f"rigidbench: parity error: {exc}", file=sys.stderr)
        return EXIT_PARITY
    return 0


if __name__ == "__main__":
    sys.exit(main())
