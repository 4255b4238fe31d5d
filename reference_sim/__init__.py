"""The particle rigid-body simulator: arrays in, arrays out (imports neither cases nor comparators).

Compiled code is cached by numba in a directory named after a hash of every source file it
compiles: this package's, subpackages included, and `rigidmath`'s, whose formulas the kernels
compile (`SOURCE_HASH` over `SOURCE_FILES`). numba checks only the
timestamp of each function's own file, so a change to a helper in another file would otherwise
leave stale compiled callers behind.
"""

import hashlib
import os
from pathlib import Path

import numba

_HERE = Path(__file__).parent


COMPILED_PACKAGES = (_HERE, _HERE.parent / "rigidmath")


def source_files(*packages: Path) -> list[Path]:
    """Every Python source file under `packages`, subfolders included, in a fixed order."""
    return [path for package in packages for path in sorted(package.rglob("*.py"))]


def source_hash(*packages: Path) -> str:
    """A hash of the paths (from each package's parent) and contents of their source files."""
    digest = hashlib.sha256()
    for package in packages:
        for path in source_files(package):
            digest.update(path.relative_to(package.parent).as_posix().encode() + b"\0")
            digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


SOURCE_FILES = source_files(*COMPILED_PACKAGES)
SOURCE_HASH = source_hash(*COMPILED_PACKAGES)

_base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
    os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "rigidbench", "numba"
)
numba.config.CACHE_DIR = os.path.join(_base, SOURCE_HASH)
