"""Process pools that stop when the user stops: Ctrl-C, or the parent killed outright.

Every pool of the suite (the sweep's, the compile warm-up's, the figures') is a `worker_pool`.
Its workers ignore SIGINT, so the parent alone decides what an interrupt means, and on Linux
ask the kernel to SIGKILL them when their parent dies (`prctl(PR_SET_PDEATHSIG)`): a parent
killed with SIGKILL leaves no orphans. When anything, KeyboardInterrupt included, leaves the
`with` block, the pool's queued work is cancelled and its workers are stopped at once instead of
waiting for the running tasks (`ProcessPoolExecutor.__exit__` would wait for them): SIGTERM
first, which lets a worker writing a file through `atomic_path` remove its temporary, then
SIGKILL for any still there after `TERM_GRACE_S` (a worker inside a compiled call runs no Python
signal handler until the call returns).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import process as futures_process
from contextlib import contextmanager

EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for a command stopped by Ctrl-C
TERM_GRACE_S = 0.5  # a drawing worker finishes its current Python statement in milliseconds
_PR_SET_PDEATHSIG = 1  # linux/prctl.h
# s from an interrupt Python dropped to SIGINT sent again, for the hook that dropped it to
# return first; one that lands in a hook again is dropped and sent again.
RESEND_S = 0.01
# Source files of Python functions native code calls back into (see `_on_sigint`).
NATIVE_CALLBACKS = ("llvmlite", os.path.join("numba", "core", "serialize.py"))
_interrupted = False  # Ctrl-C came within `catching_interrupts`
_catching = False  # within `catching_interrupts`
_dropped = False  # its KeyboardInterrupt was dropped by Python and not raised since


@contextmanager
def catching_interrupts():
    """Within the block Ctrl-C raises KeyboardInterrupt as usual and is remembered for `check`
    (in the main thread; elsewhere signals cannot be handled and nothing changes).

    Python drops, with a traceback on stderr, an exception raised in a function it calls from C
    code: a Ctrl-C that lands in an at-fork hook (logging's locks, while a pool forks its
    workers) would print a traceback and stop the command only at the next `check`. Within the
    block such a KeyboardInterrupt is dropped quietly and SIGINT sent again RESEND_S later, out
    of the hook (`_interrupt_dropped`)."""
    global _interrupted, _catching
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _interrupted, _catching = False, True
    previous = signal.signal(signal.SIGINT, _on_sigint)
    previous_hook = sys.unraisablehook

    def unraisable(dropped) -> None:
        if not _interrupt_dropped(dropped):
            previous_hook(dropped)

    sys.unraisablehook = unraisable
    try:
        yield
    finally:
        _catching = False
        signal.signal(signal.SIGINT, previous)
        sys.unraisablehook = previous_hook


def _interrupt_dropped(dropped) -> bool:
    """If `dropped` (what `sys.unraisablehook` receives) is the KeyboardInterrupt `_on_sigint`
    raised, have SIGINT sent again RESEND_S later, from another thread (sent from here, its
    handler would run, and raise, before the hook returns), and return True."""
    global _dropped
    if not (_interrupted and issubclass(dropped.exc_type, KeyboardInterrupt)):
        return False
    _dropped = True
    resend = threading.Timer(RESEND_S, _resend)
    resend.daemon = True
    resend.start()
    return True


def _resend() -> None:
    """SIGINT again for an interrupt that was dropped and not raised since (`check` raises it
    too), while the block that handles it lasts."""
    if _catching and _dropped:
        os.kill(os.getpid(), signal.SIGINT)


def _on_sigint(signum, frame):
    global _interrupted, _dropped
    _interrupted = True
    # Where native code has called back into Python, only remember it (`check` raises it): an
    # exception raised in numba's compiler's ctypes callbacks (llvmlite's object cache) is
    # printed and dropped, and one raised while compiled code rebuilds a constant
    # (`numba.core.serialize._numba_unpickle`) comes out as a SystemError.
    while frame is not None:
        if any(part in frame.f_code.co_filename for part in NATIVE_CALLBACKS):
            return
        frame = frame.f_back
    _dropped = False  # raised now; `_interrupt_dropped` sets it again if this one is dropped too
    raise KeyboardInterrupt


def check() -> None:
    """Raise KeyboardInterrupt if Ctrl-C came while it could not be raised (see `_on_sigint`)."""
    global _dropped
    if _interrupted:
        _dropped = False
        raise KeyboardInterrupt


def die_with_parent() -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux; elsewhere nothing)."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    parent = os.getppid()
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)


def _leave(signum, frame):
    """SIGTERM in a worker: unwind quietly (what the unwinding interrupts, a compilation for
    one, would print its traceback onto the user's terminal)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    sys.stderr = open(devnull, "w")  # noqa: SIM115 (the process is ending)
    raise SystemExit(EXIT_INTERRUPTED)


class _Mutable:
    """A pool worker's `sys.stderr`, which drops what is written once the parent has set
    `muted` (shared memory, set before the workers are sent SIGTERM). A worker whose SIGTERM
    comes late can meet the pool's broken call queue first: another worker, killed halfway
    through reading a call, leaves the rest of that call in the pipe, and this worker reads
    it as the next call (`EOFError: Ran out of input`) and prints its traceback before its own
    SIGTERM silences it (docs/measurement.md, "Interrupts")."""

    def __init__(self, stream, muted):
        self._stream = stream
        self._muted = muted

    def write(self, text: str) -> int:
        return len(text) if self._muted.value else self._stream.write(text)

    def flush(self) -> None:
        if not self._muted.value:
            self._stream.flush()

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _worker_init(initializer, initargs, muted=None) -> None:
    """Runs first in every worker: the parent handles Ctrl-C; SIGTERM unwinds (finally blocks
    and `atomic_path` clean up); the worker dies with its parent; a pool's worker writes to
    stderr until the pool's `muted` is set (`_Mutable`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _leave)
    if muted is not None:
        sys.stderr = _Mutable(sys.stderr, muted)
    die_with_parent()
    if initializer is not None:
        initializer(*initargs)


@contextmanager
def worker_pool(jobs: int, initializer=None, initargs=()):
    """A fork `ProcessPoolExecutor` of `jobs` workers as described above; on leaving the block
    by an exception its workers are muted (`_Mutable`) and stopped without waiting for their
    tasks."""
    context = multiprocessing.get_context("fork")
    muted = context.RawValue(ctypes.c_bool, False)
    pool = ProcessPoolExecutor(
        max_workers=jobs,
        mp_context=context,
        initializer=_worker_init,
        initargs=(initializer, initargs, muted),
    )
    try:
        yield pool
    except BaseException:
        muted.value = True
        stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """End `pool`'s workers now and cancel its queued work (`stop_processes`). SIGTERM goes
    first, so that each worker has silenced its stderr (`_leave`) before the shutdown closes
    the queues it may be reading."""
    processes = list((pool._processes or {}).values())  # no public accessor for the workers
    manager = pool._executor_manager_thread
    _terminate(processes)
    pool.shutdown(wait=False, cancel_futures=True)
    _reap(processes)
    if manager is not None:
        # Python 3.11's exit hook wakes every pool's manager thread it knows, also one that has
        # closed its wake-up pipe after its workers died: "Bad file descriptor" at exit. Wait
        # for the thread to finish and forget it.
        manager.join(TERM_GRACE_S)
        if not manager.is_alive():
            futures_process._threads_wakeups.pop(manager, None)


def stop_processes(processes) -> None:
    """SIGTERM each of `processes`, SIGKILL those still alive after `TERM_GRACE_S`; returns when
    every one has been reaped."""
    _terminate(processes)
    _reap(processes)


def _terminate(processes) -> None:
    """SIGTERM each of `processes` still alive (`_leave` unwinds it)."""
    for process in processes:
        if process.is_alive():
            process.terminate()


def _reap(processes) -> None:
    """SIGKILL those of `processes` (SIGTERM sent) still alive after `TERM_GRACE_S`; reap all."""
    deadline = time.monotonic() + TERM_GRACE_S
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
    for process in processes:
        if process.is_alive():
            process.kill()
        process.join()


def in_child(fn, *args, **kwargs):
    """`fn(*args, **kwargs)` in a forked child (a worker as above); its result, or its exception
    raised here.

    For long work the main process would do in compiled calls (the reference simulator steps a
    whole run in one numba call, which runs no Python signal handler until it returns): in a
    child, Ctrl-C stops it at once. Forked, so `fn` and its arguments (a console, a closure) are
    not pickled; the result and exception are.
    """
    context = multiprocessing.get_context("fork")
    receiver, sender = context.Pipe(duplex=False)

    def child() -> None:
        _worker_init(None, ())
        try:
            outcome = (True, fn(*args, **kwargs))
        except Exception as exc:
            outcome = (False, exc)
        sender.send(outcome)

    process = context.Process(target=child)
    process.start()
    sender.close()
    try:
        succeeded, value = receiver.recv()
    except EOFError:
        raise RuntimeError(
            f"{fn.__name__} ended without a result: exit {process.exitcode}"
        ) from None
    except BaseException:
        stop_processes([process])
        raise
    finally:
        receiver.close()
    process.join()
    if succeeded:
        return value
    raise value
