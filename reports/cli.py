"""The `rigidbench` command line.

Bad input (unknown case, engine or integrator, malformed case file, NaN dt) is reported as one
line on stderr with exit status 2 and no traceback; nothing is written.
"""

from __future__ import annotations

import argparse
import math
import sys

from rich.console import Console
from rich.table import Table

from cases import CATALOG, InputError, resolve_case, scene_to_toml
from comparators import ENGINES, run
from comparators.metrics import summarize
from comparators.parity import ParityError

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


def _cmd_list(args, console: Console) -> None:
    table = Table(title="rigidbench catalog", show_lines=False)
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
    return parser


COMMANDS = {"list": _cmd_list, "engines": _cmd_engines, "show": _cmd_show, "run": _cmd_run}


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
