"""Compile the reference simulator once per session, before any test: its `COMPILE_GROUPS` in
parallel processes (`comparators.sweep.warm_up`), rather than stage after stage in whichever
test first needs each. With numba's cache warm this only loads the compiled code."""

import pytest

from comparators.sweep import warm_up


@pytest.fixture(scope="session", autouse=True)
def _compiled_reference_simulator():
    warm_up(["reference"])
