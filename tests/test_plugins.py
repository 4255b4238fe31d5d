"""Engines are plugins found through the `rigidbench.engines` entry points, the built-in ones
too, and a plugin that fails to load is listed with its reason without stopping the others."""

from importlib import metadata

import pytest

from cases import CATALOG, InputError
from comparators import engine as registry
from comparators import run
from reports.cli import main

BUILT_IN = {"mujoco", "pybullet", "reference"}


def test_built_in_engines_are_registered_through_entry_points():
    found = {e.name for e in metadata.entry_points(group=registry.ENTRY_POINT_GROUP)}
    assert found >= BUILT_IN
    assert set(registry.ENGINES) == found


@pytest.fixture
def with_broken_plugins(monkeypatch):
    """The installed engines plus a plugin whose module is missing and one that calls itself by
    another name than its entry point's."""
    monkeypatch.setattr(registry, "ENGINES", {})
    monkeypatch.setattr("reports.cli.ENGINES", registry.ENGINES)
    group = registry.ENTRY_POINT_GROUP
    broken = [
        metadata.EntryPoint("broken", "no_such_plugin_module:Engine", group),
        metadata.EntryPoint("misnamed", "comparators.reference:ReferenceEngine", group),
    ]
    registry.register_engines([*metadata.entry_points(group=group), *broken])
    return registry.ENGINES


def test_a_broken_plugin_is_one_line_with_its_reason(with_broken_plugins, capsys):
    assert main(["engines"]) == 0
    out = capsys.readouterr().out
    lines = {
        name: [line for line in out.splitlines() if f" {name} " in line]
        for name in ("broken", "misnamed", *BUILT_IN)
    }
    assert "no_such_plugin_module" in with_broken_plugins["broken"].missing
    assert "registered as 'misnamed'" in with_broken_plugins["misnamed"].missing
    for name in ("broken", "misnamed"):
        assert lines[name] and "unavailable" in lines[name][0], out
    for name in BUILT_IN:
        assert lines[name] and lines[name][0].rstrip(" │").endswith("ok"), out


def test_running_a_broken_plugin_is_a_clear_error_and_the_others_still_run(with_broken_plugins):
    scene = CATALOG["free_spin_cube"]
    with pytest.raises(InputError, match="engine 'broken' is unavailable: plugin"):
        run(scene, "broken", duration=0.1)
    assert len(run(scene, "reference", "euler", duration=0.1).table) > 0


def test_without_any_entry_point_the_error_says_to_install(monkeypatch):
    monkeypatch.setattr(registry, "ENGINES", {})
    with pytest.raises(InputError, match="no engine is registered; install rigidbench"):
        registry.get_engine("reference")
