"""Output paths, checked before any work starts: every command's files (`run`, `bench`,
`animate`, `gate --junit`, `gate --record`) and directories (`report --out`, `--cache`).

A bad path is one `InputError` naming the option, the path and what was expected: a missing
parent, a directory where a file is meant or a file where a directory is, a place this process
cannot write (probed by creating and removing a temporary file there: permissions alone do not
say whether /proc or a read-only mount takes a file). Nothing is created on the way.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from cases.errors import InputError


def _writable(directory: Path, option: str, text: str) -> None:
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as exc:
        raise InputError(
            f"{option} {text!r}: cannot write in {str(directory)!r} ({exc.strerror or exc}): "
            "expected a writable directory"
        ) from None


def output_file(text: str | None, option: str, suffixes: tuple[str, ...]) -> Path | None:
    """`option`'s FILE (None when not given): ending in one of `suffixes`, not a directory, in
    an existing writable directory."""
    if text is None:
        return None
    out = Path(text)
    if out.suffix.lower() not in suffixes:
        raise InputError(
            f"{option} {text!r}: expected a file name ending in {' or '.join(suffixes)}"
        )
    if out.is_dir():
        raise InputError(f"{option} {text!r}: is a directory: expected a file name")
    if out.parent.exists() and not out.parent.is_dir():
        raise InputError(f"{option} {text!r}: {str(out.parent)!r} is a file: expected a directory")
    if not out.parent.is_dir():
        raise InputError(f"{option} {text!r}: directory {str(out.parent)!r} missing")
    _writable(out.parent, option, text)
    return out


def output_dir(text: str, option: str) -> Path:
    """`option`'s DIR: an existing writable directory, or a new one in an existing writable
    directory."""
    if not text:
        raise InputError(f"{option} {text!r}: expected a directory name")
    out = Path(text)
    if out.exists() and not out.is_dir():
        raise InputError(f"{option} {text!r}: is a file: expected a directory")
    if out.is_dir():
        _writable(out, option, text)
        return out
    if out.parent.exists() and not out.parent.is_dir():
        raise InputError(f"{option} {text!r}: {str(out.parent)!r} is a file: expected a directory")
    if not out.parent.is_dir():
        raise InputError(f"{option} {text!r}: directory {str(out.parent)!r} missing")
    _writable(out.parent, option, text)
    return out
