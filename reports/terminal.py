"""The console every `rigidbench` command writes to: its width where no terminal gives one,
and a reader that leaves the pipe (`rigidbench bench | head`)."""

from __future__ import annotations

import errno
import os

from rich.console import Console

# Columns for output that goes to a file or a log, which has no width of its own: rich's 80
# would fold the tables' cells there (`cube_rain_8` over two lines). COLUMNS, if set, rules.
PIPED_WIDTH = 200


class _Console(Console):
    """rich's console, except that a reader leaving raises BrokenPipeError to the command,
    where rich would exit on its own with status 1."""

    def on_broken_pipe(self) -> None:
        raise BrokenPipeError(errno.EPIPE, "the reader of the output closed it")


def console_on(terminal) -> Console:
    """The console writing to the text stream `terminal`, PIPED_WIDTH wide unless it is a
    terminal or COLUMNS is set."""
    piped = not terminal.isatty() and "COLUMNS" not in os.environ
    return _Console(file=terminal, width=PIPED_WIDTH if piped else None)


def to_nowhere(*streams) -> None:
    """Point the streams' file descriptors at /dev/null: what is still buffered for a reader
    that left is then dropped on close, not raised again."""
    nowhere = os.open(os.devnull, os.O_WRONLY)
    for stream in streams:
        try:
            os.dup2(nowhere, stream.fileno())
        except (AttributeError, OSError, ValueError):  # a test's capture has no descriptor
            pass
    os.close(nowhere)
