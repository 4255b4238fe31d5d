"""The particle rigid-body simulator: arrays in, arrays out (imports neither cases nor comparators).

Its compiled code is cached by numba, a directory per version of its sources
(`compiled_cache`), chosen here before any of its functions is compiled.
"""

from reference_sim.compiled_cache import COMPILED_PACKAGES, SOURCE_FILES, SOURCE_HASH, source_hash
from reference_sim.compiled_cache import use_cache as _use_cache

_use_cache()

__all__ = ["COMPILED_PACKAGES", "SOURCE_FILES", "SOURCE_HASH", "source_hash"]
