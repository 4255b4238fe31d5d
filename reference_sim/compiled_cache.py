"""Where numba keeps the simulator's compiled code: one directory per version of its sources.

The directory is named after a hash of every source file the simulator compiles: this
package's, subpackages included, and `rigidmath`'s, whose formulas the kernels compile
(`SOURCE_HASH` over `SOURCE_FILES`). numba checks only the timestamp of each function's own
file, so a change to a helper in another file would otherwise leave stale compiled callers
behind.

A version's compiled code takes 25 to 100 MB, and every edit or update makes a new version. So
each import marks its version's directory used (its modification time), and the first import of
a version new to this cache removes the directories of all but the `KEPT_VERSIONS` most
recently used versions.
"""

import hashlib
import os
import re
import shutil
from pathlib import Path

import numba

_HERE = Path(__file__).parent

COMPILED_PACKAGES = (_HERE, _HERE.parent / "rigidmath")
# Versions kept side by side, this one included: checkouts, branches or installs sharing the
# cache each keep their compiled code while they are among the most recently used.
KEPT_VERSIONS = 4
_VERSION_NAME = re.compile(r"[0-9a-f]{16}")  # what `source_hash` names a directory


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
CACHE_BASE = Path(
    os.environ.get("NUMBA_CACHE_DIR")
    or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rigidbench" / "numba"
)
CACHE_DIR = CACHE_BASE / SOURCE_HASH


def mark_or_prune(base: Path, version: str, kept: int = KEPT_VERSIONS) -> list[Path]:
    """Mark `version`'s directory under `base` used; where it does not exist yet, remove the
    directories of all but the `kept` - 1 most recently used other versions, and return them.
    Only directories named like a version are touched: `base` may be a NUMBA_CACHE_DIR that
    other projects share."""
    current = base / version
    if current.is_dir():
        os.utime(current)
        return []
    if not base.is_dir():
        return []
    others = [p for p in base.iterdir() if _VERSION_NAME.fullmatch(p.name) and p.is_dir()]
    others.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    removed = others[kept - 1 :]
    for path in removed:
        shutil.rmtree(path, ignore_errors=True)
    return removed


def is_compiled() -> bool:
    """Whether this version's directory holds compiled code (numba's index files): if not, the
    simulator's first use compiles it, about 2 minutes on 2 cores."""
    return CACHE_DIR.is_dir() and any(CACHE_DIR.rglob("*.nbi"))


def use_cache() -> None:
    """Point numba at this version's directory, and `mark_or_prune`."""
    numba.config.CACHE_DIR = str(CACHE_DIR)
    try:
        mark_or_prune(CACHE_BASE, SOURCE_HASH)
    except OSError:  # a read-only cache, or another process pruning it: nothing to keep up
        pass
