"""Ctrl-C stops a command at once with exit 130, leaving no worker and no half-written file; a
parent killed outright takes its workers with it."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cases import CATALOG, scene_to_toml
from comparators import Trajectory
from comparators.interrupt import EXIT_INTERRUPTED, TERM_GRACE_S, in_child, worker_pool

ROOT = Path(__file__).resolve().parent.parent

# Until the command has started its workers: importing the engines, and the first compilation
# of the simulator, which happens inside the warm-up's workers, so they exist from its start.
STARTUP_S = 60.0
# From SIGINT to exit. The mechanism's own bound is TERM_GRACE_S (a worker inside a compiled
# call is SIGKILLed after it) plus reaping, measured 0.6 s; 5 s leaves room for a loaded 2-core
# host and is still far below what ignoring Ctrl-C costs here: the slow case's runs take minutes.
INTERRUPT_EXIT_S = 5.0
# From the parent's SIGKILL to its workers' exit: the kernel sends them SIGKILL as the parent
# dies (PR_SET_PDEATHSIG), so only scheduling stands between; without it they never exit.
ORPHAN_EXIT_S = 5.0


def slow_case(directory: Path) -> Path:
    """free_spin_cube for 1e6 s (1e8 steps at its dt) with 100 samples: every run of it takes
    minutes inside one compiled call, and little memory."""
    scene = CATALOG["free_spin_cube"]
    text = scene_to_toml(scene).replace('name = "free_spin_cube"', 'name = "slow_spin"')
    text = text.replace("duration = 10.0", "duration = 1e6")
    text = text.replace("sample_interval = 0.1", "sample_interval = 1e4")
    path = directory / "slow_spin.toml"
    path.write_text(text)
    return path


def from_sources() -> dict[str, str]:
    """The environment of a Python that imports this checkout's sources."""
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path}


def start(*args: str, cwd: Path) -> subprocess.Popen:
    """The command as a user runs it, from this checkout's sources."""
    return subprocess.Popen(
        [sys.executable, "-m", "reports.cli", *args],
        cwd=cwd,
        env=from_sources(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def running(pid: int) -> bool:
    """Whether `pid` is a live process (a zombie has exited)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def descendants(pid: int) -> set[int]:
    """Every live process below `pid`, from /proc."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def forks(pid: int) -> set[int]:
    """The processes below `pid` forked from it (the same command line): its workers, not what
    an import runs on the side (glfw runs a subprocess to check its library's version)."""

    def command(process: int) -> bytes:
        try:
            return Path(f"/proc/{process}/cmdline").read_bytes()
        except OSError:
            return b""

    return {child for child in descendants(pid) if command(child) == command(pid)}


def wait_for_workers(process: subprocess.Popen, count: int) -> set[int]:
    deadline = time.monotonic() + STARTUP_S
    while time.monotonic() < deadline:
        workers = forks(process.pid)
        if len(workers) >= count:
            return workers
        assert process.poll() is None, f"ended before its workers started: {process.stderr.read()}"
        time.sleep(0.05)
    raise AssertionError(f"fewer than {count} workers after {STARTUP_S} s")


def interrupt(process: subprocess.Popen) -> tuple[int, float, str]:
    """SIGINT, then (exit status, seconds to exit, stderr)."""
    sent = time.monotonic()
    process.send_signal(signal.SIGINT)
    try:
        status = process.wait(INTERRUPT_EXIT_S)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        raise AssertionError(f"still running {INTERRUPT_EXIT_S} s after SIGINT") from None
    return status, time.monotonic() - sent, process.stderr.read()


def temporaries(directory: Path) -> list[Path]:
    """`atomic_path`'s temporaries (hidden files) anywhere under `directory`."""
    return [p for p in directory.rglob(".*") if p.is_file()]


def test_report_interrupted_stops_workers_and_keeps_cache_whole(tmp_path):
    out = tmp_path / "report"
    report = start(
        "report", "--quick", "--no-scaling", "--engines", "reference",
        "--cases", "dropped_cube", str(slow_case(tmp_path)), "--out", str(out),
        cwd=tmp_path,
    )  # fmt: skip
    workers = wait_for_workers(report, 2)
    time.sleep(1.0)  # into the warm-up or the sweep: an interrupt anywhere must be clean
    workers |= forks(report.pid)
    status, _, stderr = interrupt(report)
    assert status == EXIT_INTERRUPTED, stderr
    assert stderr.strip().splitlines()[-1].startswith("rigidbench: interrupted:"), stderr
    assert "Traceback" not in stderr, stderr
    left = [pid for pid in workers if running(pid)]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert not left, "workers left after the interrupt"
    assert not temporaries(out), temporaries(out)
    for entry in (out / "cache").glob("*"):  # only whole entries: each one reads back
        Trajectory.read(entry)


# The commands that step in the main process's child (`comparators.interrupt.in_child`): each of
# them is inside one compiled call of minutes when interrupted. CASE is `slow_case`'s file.
SINGLE_RUN_COMMANDS = {
    "run": ("run", "CASE", "--engine", "reference", "--out", "out.csv"),
    "bench": ("bench", "--cases", "CASE", "--engines", "reference", "--duration", "1e6",
              "--max-steps", "1e9", "--out", "out.csv"),  # warm-up and repeats: 6e8 steps
    "animate": ("animate", "CASE", "--engines", "reference", "--out", "out.gif"),
}  # fmt: skip


@pytest.mark.parametrize("command", sorted(SINGLE_RUN_COMMANDS))
def test_command_interrupted_inside_a_compiled_call(command, tmp_path):
    case = str(slow_case(tmp_path))
    args = [case if arg == "CASE" else arg for arg in SINGLE_RUN_COMMANDS[command]]
    process = start(*args, cwd=tmp_path)
    workers = wait_for_workers(process, 1)
    time.sleep(1.0)  # into the run
    workers |= forks(process.pid)
    status, _, stderr = interrupt(process)
    assert status == EXIT_INTERRUPTED, stderr
    assert "Traceback" not in stderr, stderr
    assert not [pid for pid in workers if running(pid)], "workers left after the interrupt"
    assert not list(tmp_path.glob("out.*")), "an output of an interrupted command"
    assert not temporaries(tmp_path), temporaries(tmp_path)


def test_workers_exit_when_their_parent_is_killed(tmp_path):
    report = start(
        "report", "--quick", "--no-scaling", "--engines", "reference",
        "--cases", str(slow_case(tmp_path)), "--out", str(tmp_path / "report"),
        cwd=tmp_path,
    )  # fmt: skip
    workers = wait_for_workers(report, 2)
    report.kill()
    report.wait()
    deadline = time.monotonic() + ORPHAN_EXIT_S
    while time.monotonic() < deadline and any(running(pid) for pid in workers):
        time.sleep(0.05)
    orphans = [pid for pid in workers if running(pid)]
    for pid in orphans:  # leave none behind on the test machine either
        os.kill(pid, signal.SIGKILL)
    assert not orphans, "workers outlived their parent"


def test_pool_left_by_an_exception_does_not_wait_for_its_tasks():
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt), worker_pool(1) as pool:
        pool.submit(time.sleep, 60)
        time.sleep(0.2)  # the worker has the task
        raise KeyboardInterrupt
    # TERM_GRACE_S at most (time.sleep unwinds at SIGTERM), and the pool's teardown
    assert time.monotonic() - started < TERM_GRACE_S + 3.0


def test_in_child_returns_the_result_and_raises_the_exception():
    assert in_child(sorted, [3, 1, 2], reverse=True) == [3, 2, 1]
    with pytest.raises(ZeroDivisionError):
        in_child(divmod, 1, 0)


# A Ctrl-C that lands in an at-fork hook (here one that interrupts itself; in a command, logging's
# lock release while a pool forks its workers) raises KeyboardInterrupt where Python drops it,
# with a traceback. Within `catching_interrupts` it must still stop the block, and quietly.
INTERRUPTED_IN_A_FORK_HOOK = """
import os, signal, time
from comparators.interrupt import catching_interrupts

def hook():
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(10000):  # the handler runs here, inside the hook
        pass

os.register_at_fork(after_in_parent=hook)
try:
    with catching_interrupts():
        child = os.fork()
        if child == 0:
            os._exit(0)
        os.waitpid(child, 0)
        time.sleep(30)
    print("not interrupted")
except KeyboardInterrupt:
    print("interrupted")
"""


def _python(script: str) -> subprocess.CompletedProcess:
    """`script` run by a fresh Python on the project's sources, its output captured."""
    return subprocess.run(
        [sys.executable, "-c", script],
        env=from_sources(),
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_interrupt_dropped_in_a_fork_hook_still_stops_quietly():
    done = _python(INTERRUPTED_IN_A_FORK_HOOK)
    assert done.stdout.strip() == "interrupted", done.stderr
    assert done.stderr == ""


# Compiled code calls back into Python to rebuild a constant (`_numba_unpickle`, here called
# directly, its constant interrupting itself as it is rebuilt); a KeyboardInterrupt raised there
# comes out of the compiled call as a SystemError with a traceback. Within `catching_interrupts`
# the callback must finish and `check` raise the interrupt after it.
INTERRUPTED_IN_A_NUMBA_CALLBACK = """
import os, pickle, signal
from numba.core.serialize import _numba_unpickle
from comparators.interrupt import catching_interrupts, check

def interrupted():
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(10000):  # the handler runs here, under _numba_unpickle
        pass
    return "rebuilt"

class Constant:
    def __reduce__(self):
        return (interrupted, ())

try:
    with catching_interrupts():
        print(_numba_unpickle(0, pickle.dumps(Constant()), b"constant"))
        check()
    print("not interrupted")
except KeyboardInterrupt:
    print("interrupted")
"""


def test_interrupt_in_a_numba_callback_waits_for_it():
    done = _python(INTERRUPTED_IN_A_NUMBA_CALLBACK)
    assert done.stdout.split() == ["rebuilt", "interrupted"], done.stderr
    assert done.stderr == ""


# A pool worker whose SIGTERM comes late (here: blocked, then taken by sigwaitinfo) and which
# writes to stderr meanwhile, as one that reads the broken call queue of a stopped pool prints
# its EOFError (docs/measurement.md, "Interrupts"). Muted before the workers are sent SIGTERM,
# the pool's workers write nothing once it stops.
WRITTEN_AFTER_THE_STOP = """
import multiprocessing, signal, sys
from comparators.interrupt import worker_pool

started = multiprocessing.get_context("fork").Event()

def late_writer():
    signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGTERM])
    started.set()
    signal.sigwaitinfo([signal.SIGTERM])  # the parent is stopping the pool
    sys.stderr.write("written after the stop\\n")
    sys.stderr.flush()

try:
    with worker_pool(1) as pool:
        pool.submit(late_writer)
        started.wait(30)
        raise KeyboardInterrupt
except KeyboardInterrupt:
    print("stopped")
"""


def test_a_stopped_pools_workers_write_nothing_to_stderr():
    done = _python(WRITTEN_AFTER_THE_STOP)
    assert done.stdout.split() == ["stopped"], done.stderr
    assert done.stderr == ""
