"""Compile the reference simulator once per session, before any test: its `COMPILE_GROUPS` in
parallel processes (`comparators.sweep.warm_up`), rather than stage after stage in whichever
test first needs each. With numba's cache warm this only loads the compiled code."""

import pytest

import gates.pytest_plugin
from comparators.sweep import warm_up


def pytest_configure(config):
    """The gate files under tests/gates/ run through the gate plugin: an installed rigidbench
    registers it (its pytest11 entry point); a checkout installed before the plugin existed
    does not, so register it here."""
    if not config.pluginmanager.is_registered(gates.pytest_plugin):
        config.pluginmanager.register(gates.pytest_plugin, "rigidbench-gates")


@pytest.fixture(scope="session", autouse=True)
def _compiled_reference_simulator():
    warm_up(["reference"])
