"""Engine-neutral cases: the `Scene` dataclasses, the built-in catalog and TOML case files."""

# Any order works: each submodule imports the submodules it needs (catalog -> scene, builders;
# toml_io -> catalog, errors, scene) and none imports from this package's namespace.
from cases.catalog import CATALOG
from cases.errors import InputError
from cases.scene import Body, Contact, Expected, Plane, Scene
from cases.toml_io import load_scene, resolve_case, scene_to_toml

__all__ = [
    "CATALOG",
    "Body",
    "Contact",
    "Expected",
    "InputError",
    "Plane",
    "Scene",
    "load_scene",
    "resolve_case",
    "scene_to_toml",
]
