"""Whether a measured outcome (`comparators.outcomes`) misses its closed form: how far each
quantity may sit from it, one rule for the report's findings and the bench's
`closed_forms_missed` column, so that both say the same of the same run."""

from __future__ import annotations

import math

import pandas as pd

# Closed-form outcomes and how far a measurement may sit from its closed form before a reader is
# told: the rebound ratio within 2 % of e, the stopping distance, the spin-down angle and the slope
# acceleration within 1 % (the reference simulator's own gates, tests/test_hard_cases.py, which
# every rigid integrator meets; a zero closed form, as a slope acceleration where the body sticks,
# is judged by `slides` instead); a resting height within 1 mm and a sliding body's lift off its
# plane below 1 mm (ten times the 1e-4 m by which soft contacts settle); a creep within 2 mm, the
# resting gate's limit (gates/physics/resting.toml): a contact that acts on penetration lets the
# body fall one step first, g dt^2 = 1 mm at resting_cube's dt, and a compliant one settles as much
# again; its sideways stray from the closed forms' straight line below 1 mm (a tenth of the 1 % the
# stopping distance is held to on `slide`'s 0.9 m); `slides` (1 or 0) must match.
RELATIVE_TOLERANCES = {
    "rebound_ratio": 0.02,
    "stopping_distance": 0.01,
    "spin_angle": 0.01,
    "slope_acceleration": 0.01,
}
ABSOLUTE_TOLERANCES = {
    "rest_com_height": 1e-3,
    "creep": 2e-3,
    "lift": 1e-3,
    "sideways": 1e-3,
    "slides": 0.5,
}
# The bench's cell for a run whose outcomes were judged and missed nothing.
NONE_MISSED = "none"


def miss(quantity: str, measured: float, expected: float) -> float | None:
    """How far `measured` misses the closed form `expected` of `quantity`: measured / expected
    - 1 for RELATIVE_TOLERANCES, measured - expected for ABSOLUTE_TOLERANCES; None within the
    quantity's tolerance, for a quantity judged by neither, or where either value is NaN (a
    zero closed form of a relative quantity is judged by another quantity)."""
    if math.isnan(measured) or math.isnan(expected):
        return None
    if quantity in RELATIVE_TOLERANCES:
        if expected == 0:
            return None
        value = measured / expected - 1
        return None if abs(value) <= RELATIVE_TOLERANCES[quantity] else value
    if quantity in ABSOLUTE_TOLERANCES:
        value = measured - expected
        return None if abs(value) <= ABSOLUTE_TOLERANCES[quantity] else value
    return None


def tolerance(quantity: str) -> str | None:
    """How far `quantity` may sit from its closed form, as text: "1%" (relative), "0.001" (in
    the quantity's unit); None for a quantity judged by neither table."""
    if quantity in RELATIVE_TOLERANCES:
        return f"{RELATIVE_TOLERANCES[quantity]:.0%}"
    if quantity in ABSOLUTE_TOLERANCES:
        return f"{ABSOLUTE_TOLERANCES[quantity]:g}"
    return None


def judged(outcomes: pd.DataFrame) -> bool:
    """Whether any of one run's outcome rows is a quantity with a tolerance here."""
    tolerances = RELATIVE_TOLERANCES.keys() | ABSOLUTE_TOLERANCES.keys()
    return bool(outcomes["quantity"].isin(tolerances).any())


def missed(outcomes: pd.DataFrame) -> str | None:
    """One run's misses (its `comparators.outcomes.outcomes` rows), "; "-joined as "quantity
    +1.2%" (relative) or "quantity +0.087 m" (absolute); NONE_MISSED when every judged quantity
    is within its tolerance; None when the run has no judged quantity."""
    if not judged(outcomes):
        return None
    said = []
    for row in outcomes.itertuples():
        value = miss(row.quantity, float(row.measured), float(row.expected))
        if value is not None:
            said.append(f"{row.quantity} {missed_by(row.quantity, value, row.unit)}")
    return "; ".join(said) or NONE_MISSED


def missed_by(quantity: str, value: float, unit: str) -> str:
    """A `miss` as text: "+1.2%" (relative) or "+0.087 m" (absolute)."""
    if quantity in RELATIVE_TOLERANCES:
        return f"{value:+.1%}"
    return f"{value:+.2g} {unit}".rstrip()


# A sweep's run, as its outcomes table (`comparators.sweep.OUTCOMES_COLUMNS`) keys it.
RUN_KEYS = ["case", "engine", "integrator", "dt"]


def missed_by_run(outcomes: pd.DataFrame) -> dict[tuple, str | None]:
    """`missed` of every run of a sweep's outcomes table, by its RUN_KEYS values."""
    return {run: missed(own) for run, own in outcomes.groupby(RUN_KEYS, sort=False)}


def is_miss(said) -> bool:
    """Whether a `missed` result (or a bench cell read back: NaN for None) names a miss."""
    return isinstance(said, str) and said != NONE_MISSED
