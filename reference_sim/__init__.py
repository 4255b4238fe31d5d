"""The particle rigid-body simulator: arrays in, arrays out (imports neither cases nor comparators).

Compiled code is cached by numba in a directory named after a hash of every source file of this
package, subpackages included (`SOURCE_HASH` over `SOURCE_FILES`). numba checks only the
timestamp of each function's own file, so a change to a helper in another file would otherwise
leave stale compiled callers behind.
"""

import hashlib
import os
from pathlib import Path

import numba

_HERE = Path(__file__).parent


def source_files(package: Path) -> list[Path]:
    """Every Python source file under `package`, subfolders included, in a fixed order."""
    return sorted(package.rglob("*.py"), key=lambda p: p.relative_to(package).as_posix())


def source_hash(package: Path) -> str:
    """A hash of the paths and contents of `source_files(package)`."""
    digest = hashlib.sha256()
    for path in source_files(package):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


SOURCE_FILES = source_files(_HERE)
SOURCE_HASH = source_hash(_HERE)

_base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
    os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "rigidbench", "numba"
)
numba.config.CACHE_DIR = os.path.join(_base, SOURCE_HASH)
