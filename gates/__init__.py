"""Accuracy gates: limits on the suite's measures of a case run on an engine, in gate files
(`spec`), checked through the results cache (`evaluate`), recorded from today's measurements
(`record`), run by `rigidbench gate` and by pytest (`pytest_plugin`)."""

from pathlib import Path

# The physics gates shipped with the package (`rigidbench gate --physics`): expectations any
# correct engine of a kind meets.
PHYSICS_DIR = Path(__file__).resolve().parent / "physics"
# `rigidbench gate --record`'s regression factor (`gates.record`): an engine may get this much
# worse than recorded before its gate fails.
DEFAULT_SLACK = 1.5
