"""`comparators.closed_forms`: which measurements miss their closed form, how a miss is said, and
the throughput figure's mark of a run whose physics is wrong."""

import math

import pandas as pd
import pytest

from comparators.closed_forms import (
    ABSOLUTE_TOLERANCES,
    NONE_MISSED,
    RELATIVE_TOLERANCES,
    miss,
    missed,
)
from reports.plots import wrong_physics


@pytest.mark.parametrize("quantity", sorted(RELATIVE_TOLERANCES))
def test_relative_quantities_miss_beyond_their_tolerance(quantity):
    tolerance = RELATIVE_TOLERANCES[quantity]
    assert miss(quantity, 2.0 * (1 + 0.5 * tolerance), 2.0) is None
    assert miss(quantity, 2.0 * (1 - 0.5 * tolerance), 2.0) is None
    assert miss(quantity, 2.0 * (1 + 2 * tolerance), 2.0) == pytest.approx(2 * tolerance)
    assert miss(quantity, 2.0 * (1 - 2 * tolerance), 2.0) == pytest.approx(-2 * tolerance)
    assert miss(quantity, 1.0, 0.0) is None  # a zero closed form: judged by another quantity


@pytest.mark.parametrize("quantity", sorted(ABSOLUTE_TOLERANCES))
def test_absolute_quantities_miss_beyond_their_tolerance(quantity):
    tolerance = ABSOLUTE_TOLERANCES[quantity]
    assert miss(quantity, 0.7 + 0.5 * tolerance, 0.7) is None
    assert miss(quantity, 0.7 - 2 * tolerance, 0.7) == pytest.approx(-2 * tolerance)


def test_unjudged_quantities_and_nan_never_miss():
    assert miss("jitter_rms", 1e3, 0.0) is None
    assert miss("stopping_distance", math.nan, 0.9) is None
    assert miss("stopping_distance", 0.5, math.nan) is None


def _outcomes(*rows) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["quantity", "measured", "expected", "unit"])


def test_a_run_says_each_miss_or_none():
    within = ("stopping_distance", 0.9, 0.9, "m")
    assert missed(_outcomes(within, ("jitter_rms", 1.0, 0.0, "m/s"))) == NONE_MISSED
    said = missed(_outcomes(("slope_acceleration", 1.732, 1.64, "m/s^2"), ("lift", 0.087, 0, "m")))
    assert said == "slope_acceleration +5.6%; lift +0.087 m"
    assert missed(_outcomes(("jitter_rms", 1.0, 0.0, "m/s"))) is None  # nothing judged
    assert missed(_outcomes()) is None


def test_the_throughput_figure_hollows_runs_whose_physics_is_wrong():
    table = pd.DataFrame(
        {
            "verdict": ["ok", "ok", "ok", "jitter"],
            "closed_forms_missed": [NONE_MISSED, None, "lift +0.1 m", NONE_MISSED],
        }
    )
    assert wrong_physics(table).tolist() == [False, False, True, True]
