"""What an engine says while it runs, kept off the terminal and in the run's record.

`captured_output` wraps every engine run (`comparators.engine.run`): the process's file
descriptors 1 and 2 go to a temporary file (C and C++ output too: MuJoCo's warnings, DART's and
Drake's logs), and so do Python's `sys.stdout`, `sys.stderr` and warnings (one line each,
every time, not only the first at each place). When the block ends, each distinct line is
counted (`EngineOutput`), in order of first appearance; the run's `RunMeta.messages` keeps
them, and a run that fails keeps them in its failure reason (`EngineOutput.note`).

A terminal that must stay visible while runs are captured (a progress bar refreshed from a
thread) writes to `terminal_stream()`, which no capture redirects.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import tempfile
import threading
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field

# Distinct messages kept per run, and characters kept per message: a run that floods its output
# keeps a record of a few kB. Further distinct messages are counted under OTHER_MESSAGES.
MAX_MESSAGES = 10
MAX_MESSAGE_CHARS = 300
OTHER_MESSAGES = "(other messages)"
# Output read back per run; what a run writes beyond it is one message saying how much.
MAX_OUTPUT_BYTES = 1 << 20
NOTE_PREFIX = "engine output: "
# The file descriptors are the process's: runs in threads of one process take turns capturing.
_LOCK = threading.RLock()


@dataclass
class EngineOutput:
    """What one run said: `messages` maps each distinct line (at most MAX_MESSAGE_CHARS) to how
    often it came, in order of first appearance; filled when the capture ends."""

    messages: dict[str, int] = field(default_factory=dict)

    def add(self, line: str, count: int = 1) -> None:
        line = line.strip()[:MAX_MESSAGE_CHARS]
        if not line:
            return
        if line not in self.messages and len(self.messages) >= MAX_MESSAGES:
            line = OTHER_MESSAGES
        self.messages[line] = self.messages.get(line, 0) + count

    def note(self) -> str:
        """One line for a failure reason: NOTE_PREFIX and `summary`."""
        return NOTE_PREFIX + summary(self.messages)


def message_count(messages: dict[str, int]) -> int:
    """How many lines a run's `messages` record."""
    return sum(messages.values())


def first_message(messages: dict[str, int]) -> str | None:
    """The first distinct message of a run, None when it said nothing."""
    return next(iter(messages), None)


def summary(messages: dict[str, int]) -> str:
    """ "2 lines (1 distinct), first: ..." for tables and failure reasons; "" when none."""
    if not messages:
        return ""
    count, distinct = message_count(messages), len(messages)
    return f"{count} line(s) ({distinct} distinct), first: {first_message(messages)}"


def _flush_c_streams() -> None:
    """Anything waiting in C's stdio buffers (printf output on a pipe is block-buffered)."""
    with contextlib.suppress(OSError, AttributeError, TypeError):
        ctypes.CDLL(None).fflush(None)


def _flush_python_streams(*streams) -> None:
    for stream in streams:
        with contextlib.suppress(Exception):
            stream.flush()


@contextlib.contextmanager
def captured_output() -> Iterator[EngineOutput]:
    """Capture everything the block writes to file descriptors 1 and 2, to `sys.stdout` and
    `sys.stderr`, and every Python warning it raises; yield the `EngineOutput` that holds it
    once the block ends (also when it raises). Set up and read back outside the block, so a
    timed region inside it is not slowed: during it, output goes to a file instead of a
    terminal."""
    output = EngineOutput()
    with _LOCK, tempfile.TemporaryFile() as sink:
        streams = (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__)
        _flush_python_streams(*streams)
        _flush_c_streams()
        saved = {fd: os.dup(fd) for fd in (1, 2)}
        # Python's writes into the same file, line by line, so lines keep their order
        text = open(os.dup(sink.fileno()), "w", buffering=1, encoding="utf-8", errors="replace")
        try:
            for fd in saved:
                os.dup2(sink.fileno(), fd)
            with (
                warnings.catch_warnings(),
                contextlib.redirect_stdout(text),
                contextlib.redirect_stderr(text),
            ):
                warnings.simplefilter("always")

                def record_warning(message, category, *args, **kwargs):
                    first = (str(message).splitlines() or [""])[0]
                    text.write(f"{category.__name__}: {first}\n")

                warnings.showwarning = record_warning
                yield output
        finally:
            text.close()
            _flush_python_streams(*streams)  # a logging handler may hold the original ones
            _flush_c_streams()
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
            size = sink.seek(0, os.SEEK_END)
            sink.seek(0)
            for line in sink.read(MAX_OUTPUT_BYTES).decode(errors="replace").splitlines():
                output.add(line)
            if size > MAX_OUTPUT_BYTES:
                output.messages[f"({size - MAX_OUTPUT_BYTES} more bytes of output not read)"] = 1


def terminal_stream():
    """A text stream onto what `sys.stdout` is now, which later captures leave in place: a
    duplicate of file descriptor 1, or `sys.stdout` itself where it has none (a test's
    capture)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return sys.stdout
    _flush_python_streams(sys.stdout)
    encoding = getattr(sys.stdout, "encoding", None) or "utf-8"
    return os.fdopen(os.dup(fd), "w", buffering=1, encoding=encoding, errors="replace")
