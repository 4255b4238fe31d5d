"""Engines behind one interface, the trajectory table, and the metrics computed from it."""

from comparators import mujoco_engine as _mujoco_engine  # noqa: F401
from comparators import pybullet_engine as _pybullet_engine  # noqa: F401
from comparators import reference as _reference  # noqa: F401  (registers the engine)
from comparators.engine import ENGINES, Engine, get_engine, run
from comparators.trajectory import COLUMNS, RunMeta, Trajectory

__all__ = ["COLUMNS", "ENGINES", "Engine", "RunMeta", "Trajectory", "get_engine", "run"]
