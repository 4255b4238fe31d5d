"""The `rigidbench` command line's arguments: one parser per command, and the argparse types
that refuse bad numbers with the option's name."""

from __future__ import annotations

import argparse
import math
import os
import re
from pathlib import Path

from cases.scene import MAX_MAGNITUDE, MIN_MAGNITUDE
from comparators.bench import BENCH_DURATION_S, MIN_REPEATS
from comparators.limits import MAX_STEPS, whole_number
from gates import DEFAULT_SLACK

# The report's folder, in the directory the command runs in: all a report writes (the results
# cache too, in OUT/cache) goes there and nowhere else.
DEFAULT_OUT = Path("rigidbench-report")


_CONTROL_CHARACTERS = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def one_line(message: str) -> str:
    """`message` with its control characters written as escapes (a newline as \\n, a terminal
    escape as \\x1b), so that a path or argument holding them cannot break the error line in
    two or rewrite the terminal."""
    return _CONTROL_CHARACTERS.sub(lambda match: repr(match.group())[1:-1], message)


class OneLineParser(argparse.ArgumentParser):
    """A parser whose errors are one line, as every other error of the CLI: what is wrong and
    where the usage is, without argparse's usage lines before it (exit status 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {one_line(message)} (usage: {self.prog} --help)\n")


def parse_positive_number(text: str) -> float:
    """argparse type: a finite number > 0 (NaN and inf are refused with the option's name)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def parse_time(text: str) -> float:
    """argparse type of --dt and --duration: a finite number > 0 of a size a case file may hold
    (`cases.scene.MIN_MAGNITUDE` to `MAX_MAGNITUDE`), since it stands for the case's own."""
    value = parse_positive_number(text)
    if not MIN_MAGNITUDE <= value <= MAX_MAGNITUDE:
        raise argparse.ArgumentTypeError(
            f"expected a number of size between {MIN_MAGNITUDE:g} and {MAX_MAGNITUDE:g}, as "
            f"every number of a case, got {text!r}"
        )
    return value


def _parse_whole(text: str, least: int) -> int:
    value = whole_number(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}")
    if value < least:
        raise argparse.ArgumentTypeError(f"expected a number >= {least}, got {text!r}")
    return value


def parse_count(text: str) -> int:
    """argparse type: a whole number >= 1."""
    return _parse_whole(text, 1)


# Workers per CPU that `--jobs` may ask for: the runs are CPU-bound, so more gain nothing, and
# the fork pool starts every worker at once, so an unbounded count forks without end.
MAX_JOBS_PER_CPU = 4


def parse_jobs(text: str) -> int:
    """argparse type: a whole number of worker processes, from 1 to MAX_JOBS_PER_CPU per CPU."""
    value = _parse_whole(text, 1)
    most = MAX_JOBS_PER_CPU * (os.cpu_count() or 1)
    if value > most:
        raise argparse.ArgumentTypeError(
            f"expected at most {most} ({MAX_JOBS_PER_CPU} per CPU of this machine), got {text!r}"
        )
    return value


def parse_repeats(text: str) -> int:
    """argparse type: a whole number >= MIN_REPEATS (a median with min and max)."""
    return _parse_whole(text, MIN_REPEATS)


def _add_limits(parser) -> None:
    """The options that raise the limits of a run's size (`comparators.limits`)."""
    parser.add_argument(
        "--max-steps",
        type=parse_count,
        metavar="N",
        help=f"refuse a run of more steps (default {MAX_STEPS:.0e})",
    )
    parser.add_argument(
        "--max-recorded",
        type=parse_count,
        metavar="N",
        help="refuse a run recording more particle positions, samples x particles "
        "(default: a quarter of this machine's memory)",
    )


def _add_show(sub) -> None:
    show = sub.add_parser("show", help="a case as TOML (loads back to the same scene)")
    show.add_argument("case", help="catalog name or path to a .toml case file")


def _add_run(sub) -> None:
    run_p = sub.add_parser("run", help="run one case on one engine and print its metrics")
    run_p.add_argument("case", help="catalog name or path to a .toml case file")
    run_p.add_argument("--engine", default="reference", help="engine name (default: reference)")
    run_p.add_argument("--integrator", help="integrator name (default: the engine's default)")
    run_p.add_argument("--dt", type=parse_time, help="time step in s (default: the case's)")
    run_p.add_argument(
        "--duration", type=parse_time, help="simulated time in s (default: the case's)"
    )
    run_p.add_argument(
        "--out",
        metavar="FILE.csv|FILE.parquet",
        help="write the trajectory table to FILE.csv or FILE.parquet",
    )
    _add_limits(run_p)


def _add_selection(parser) -> None:
    """The cases and engines a report or a bench covers."""
    parser.add_argument(
        "--cases", nargs="+", help="catalog names or .toml files (default: catalog)"
    )
    parser.add_argument("--engines", nargs="+", help="engine names (default: every available one)")


def _add_report(sub) -> None:
    rep = sub.add_parser("report", help="sweep case x engine x integrator x dt; write the report")
    _add_selection(rep)
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
    rep.add_argument(
        "--out", default=str(DEFAULT_OUT), help=f"output directory (default: ./{DEFAULT_OUT})"
    )
    rep.add_argument("--cache", help="results cache directory (default: OUT/cache)")
    rep.add_argument("--executor", choices=("local", "dask"), default="local")
    rep.add_argument("--scheduler", help="Dask scheduler address, with --executor dask")
    rep.add_argument(
        "--jobs", type=parse_jobs, default=os.cpu_count() or 1, help="local worker processes"
    )
    _add_limits(rep)


def _add_animate(sub) -> None:
    anim = sub.add_parser(
        "animate", help="a GIF of a case's motion, engines side by side, the exact one as a ghost"
    )
    anim.add_argument("case", help="catalog name or path to a .toml case file")
    anim.add_argument("--engines", nargs="+", help="engine names (default: every available one)")
    anim.add_argument(
        "--integrator",
        nargs="+",
        help="integrator name(s), each run on every engine (default: each engine's default)",
    )
    anim.add_argument("--dt", type=parse_time, help="time step in s (default: the case's)")
    anim.add_argument(
        "--duration", type=parse_time, help="simulated time in s (default: the case's)"
    )
    anim.add_argument("--out", required=True, metavar="FILE.gif", help="the animation, FILE.gif")
    anim.add_argument(
        "--cache", help=f"results cache directory (default: ./{DEFAULT_OUT}/cache, the report's)"
    )
    _add_limits(anim)


def _add_bench(sub) -> None:
    ben = sub.add_parser("bench", help="steps/s of case x engine x integrator, side by side")
    _add_selection(ben)
    ben.add_argument(
        "--dt",
        type=parse_time,
        nargs="+",
        help="time step(s) in s (default: each case's own)",
    )
    ben.add_argument(
        "--duration",
        type=parse_time,
        help=f"simulated time per run in s (default: the case's, at most {BENCH_DURATION_S:g})",
    )
    ben.add_argument(
        "--repeats",
        type=parse_repeats,
        default=MIN_REPEATS,
        help=f"timed repeats per run, at least {MIN_REPEATS} (default {MIN_REPEATS})",
    )
    ben.add_argument(
        "--out", metavar="FILE.csv", help="write the table to FILE.csv and its plot to FILE.png"
    )
    _add_limits(ben)


def parse_slack(text: str) -> float:
    """argparse type: a finite number >= 1 (a limit below today's value fails today)."""
    value = parse_positive_number(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a number >= 1, got {text!r}")
    return value


def _add_gate(sub) -> None:
    gate = sub.add_parser(
        "gate",
        help="check the limits of gate files on the suite's measures; exit 1 when any fails",
    )
    gate.add_argument(
        "paths", nargs="*", metavar="FILE_OR_DIR", help="gate files, or directories of them"
    )
    gate.add_argument(
        "--engine", metavar="NAME", help="run every gate on this engine (default: each gate's)"
    )
    gate.add_argument(
        "--physics",
        action="store_true",
        help="also the physics gates shipped with rigidbench (any correct engine passes them)",
    )
    gate.add_argument(
        "--junit", metavar="FILE.xml", help="also write every check as a JUnit XML test case"
    )
    gate.add_argument(
        "--record",
        metavar="OUT.toml",
        help="instead, write gates from today's measurements of --cases on --engine",
    )
    gate.add_argument(
        "--cases", nargs="+", metavar="CASE", help="with --record: catalog names or .toml files"
    )
    gate.add_argument(
        "--slack",
        type=parse_slack,
        default=DEFAULT_SLACK,
        help=f"with --record: limits at today's value times this plus a noise floor "
        f"(default {DEFAULT_SLACK:g})",
    )
    gate.add_argument(
        "--cache", help=f"results cache directory (default: ./{DEFAULT_OUT}/cache, the report's)"
    )
    gate.add_argument(
        "--jobs", type=parse_jobs, default=os.cpu_count() or 1, help="local worker processes"
    )
    _add_limits(gate)


def build_parser() -> argparse.ArgumentParser:
    """The parser of every command: list, engines, show, run, animate, report, bench, gate."""
    parser = OneLineParser(
        prog="rigidbench", description="Validation and benchmark suite for rigid-body physics."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the case catalog with tags and what each models")
    sub.add_parser("engines", help="engines and their integrators")
    _add_show(sub)
    _add_run(sub)
    _add_animate(sub)
    _add_report(sub)
    _add_bench(sub)
    _add_gate(sub)
    return parser
