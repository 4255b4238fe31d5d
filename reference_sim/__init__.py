"""The particle rigid-body simulator: arrays in, arrays out (imports neither cases nor comparators).

Compiled code is cached by numba in a directory named after a hash of this package's sources
(`SOURCE_HASH`). numba checks only the timestamp of each function's own file, so a change to a
helper in another file would otherwise leave stale compiled callers behind.
"""

import hashlib
import os
from pathlib import Path

import numba

_HERE = Path(__file__).parent
SOURCE_HASH = hashlib.sha256(
    b"".join(p.read_bytes() for p in sorted(_HERE.glob("*.py")))
).hexdigest()[:16]

_base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
    os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "rigidbench", "numba"
)
numba.config.CACHE_DIR = os.path.join(_base, SOURCE_HASH)
