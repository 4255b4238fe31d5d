"""Engines behind one interface, the trajectory table, and the metrics computed from it."""

from comparators.engine import ENGINES, Engine, get_engine, run
from comparators.trajectory import COLUMNS, RunMeta, Trajectory

__all__ = ["COLUMNS", "ENGINES", "Engine", "RunMeta", "Trajectory", "get_engine", "run"]
