"""The contact solver's tuned constants, each with what it is and why; `describe` states them.

The measurements behind the values are in docs/contact-solver.md.
"""

from reference_sim.jit import kernel

# A contact is touching, and gets the post-drift impulse, when its gap is below this (m):
# speculative contacts end the drift touching to the rounding of metre-scale coordinates.
TOUCH_TOLERANCE = 1e-9
# Contacts closing within this much (m) of each other in one step impact together: rounding
# must not decide which corner of a cube landing flat bounces first.
IMPACT_SLACK = 1e-6
# Fraction of an already negative gap closed per step (Baumgarte's classic 0.2): removes the
# rotation's second-order overshoots without a visible kick.
BAUMGARTE = 0.2
# Before the drift a contact whose gap is within this of zero (m) aims at normal speed 0, as a
# touching one does after it, rather than at closing the gap: at rest, gaps wander by the
# solver's leftover speeds times dt (+-5e-14 m in a resting `cube_stack`), and targets that
# followed them asked a face's corners for speeds up to 5 tolerances apart.
RESTING_GAP = 1e-13
# Gauss-Seidel stops when no impulse changes a speed by more than this (m/s)...
VELOCITY_TOLERANCE = 1e-13
# ...or by GAP_ROUNDING / dt if larger: the targets -gap / dt carry the gaps' rounding (m) over
# dt, which the contacts of one face cannot all meet.
GAP_ROUNDING = 1e-14
# Sweeps a solve may take; a solve that reaches it stops unconverged.
MAX_ITERATIONS = 500
# Stall rule: a solve whose bodies' velocity change over a sweep has not fallen below
# STALL_PROGRESS of its last low for STALL_SWEEPS sweeps is cycling, and stops unconverged.
STALL_SWEEPS = 150
STALL_PROGRESS = 0.5
# Cycle rule (`gauss_seidel.cycles`): from sweep CYCLE_START a solve stops unconverged once its
# velocity change repeats within CYCLE_AGREEMENT, period <= CYCLE_MAX_PERIOD, for CYCLE_PERIODS.
CYCLE_START = 10
CYCLE_MAX_PERIOD = 32
CYCLE_PERIODS = 2
CYCLE_MIN_SWEEPS = 6  # and for at least this many sweeps
CYCLE_AGREEMENT = 1e-3
# Extrapolation: after RATE_SWEEPS sweeps whose velocity changes shrank by one ratio rho (within
# RATE_AGREEMENT), the remaining sweeps of that slow mode are added at once, rho < RATE_MAX only:
RATE_SWEEPS = 2
RATE_AGREEMENT = 0.03
# towards rho = 1 the jump (49 sweeps' worth at RATE_MAX, not tuned) and its error grow unbounded.
RATE_MAX = 0.98
# Subspace steps follow a solve's unconverged sweeps SUBSPACE_FIRST (cold start) or
# SUBSPACE_FIRST_WARM (warm start) to that + SUBSPACE_STEPS - 1: they fix a stack's slow modes.
SUBSPACE_FIRST = 2
SUBSPACE_FIRST_WARM = 1
SUBSPACE_STEPS = 5
# The subspace is solved densely, 6 unknowns per body: more bodies than this, no subspace step
# (a 96-unknown system at most; the catalog's subspaces have at most 8 bodies).
SUBSPACE_MAX_BODIES = 16
# Scenes of fewer bodies than this take no subspace step: one body's contacts settle in a few
# sweeps, and a step costs about ten sweeps.
SUBSPACE_MIN_BODIES = 2
# A warm-started solve of at most RESTART_MAX_BODIES bodies not converged in RESTART_SWEEPS
# sweeps has been led astray by its warm start: it starts again, once, from no impulse.
RESTART_SWEEPS = 50
RESTART_MAX_BODIES = 1
# Regularisation of the subspace's equalities, relative to the largest contact inverse mass:
# redundant contacts (a face's four corners) make them singular; it picks the smallest change.
SUBSPACE_REGULARIZATION = 1e-8
# A contact whose friction impulse is within this relative rounding of mu P_n slides (the
# sliding update sets it to mu P_n up to rounding); inside, it sticks.
DISC_ROUNDING = 1e-12
# The warm start continues an impulse along its trend (to second order) when its last two
# changes differ by less than TREND_AGREEMENT of the latest, and the latest moves a speed by
# > TREND_NOISE tolerances (a sliding face's impulses change by about 10 a step at dt 0.001).
TREND_AGREEMENT = 0.5
TREND_NOISE = 10.0
# Candidates are found with each body's reach widened by CANDIDATE_SPEEDUP * dt (m): the solve
# before the drift may speed a body up (a resting cube struck by a falling one), and the drift
# must bring together no particles that are not candidates. A step whose solve speeds some body
# beyond its widened reach is found and solved again with the margin it needed
# (`rigid.rigid_step`), so the margin sets how often, not whether. The piles' solves sped bodies
# by up to 3.7 m/s (docs/contact-solver.md, "The candidates' margin").
CANDIDATE_SPEEDUP = 5.0  # m/s
# A step's candidates are found again at most this many times, the margin at least doubled each
# time; a step still outrun then goes on (its missed contacts act from the next step on).
REFIND_LIMIT = 3
# Scenes with at least this many bodies find close body pairs on a uniform grid (linear in the
# number of bodies); fewer are tested pair by pair, which is faster for a handful.
GRID_MIN_BODIES = 16
# The grid has at most this many cells a body (8 bytes each): scenes spread wider get coarser
# cells, which only add candidate tests.
GRID_CELLS_PER_BODY = 8
# A pile's body pairs are found again when some body's reach plus its move exceeds its skin
# (`pair_list`): SKIN_REACHES of its reach when found plus SKIN_RADII of its bounding radius.
# Wider skins are found again less often but list more pairs, and the grid's cells grow with
# the widest: of 2 to 4 reaches and 0.05 to 0.2 radii these cost least in `cube_rain_1000`
# (docs/contact-solver.md, "Broad phase").
SKIN_REACHES = 3.0
SKIN_RADII = 0.1
# The skin test allows this much, relative to a body's coordinates (m), for the rounding of
# the distances it compares: a few ulps, about 1e-15 of the coordinates, times 100.
SKIN_ROUNDING = 1e-13
# A contact that does not push and whose normal speed exceeds its target by more than this many
# times the last sweep's largest speed change is idle: sweeps skip it until the rest converge.
IDLE_MARGIN = 10.0
# A contact is quiet, and sweeps skip it, while its last update changed a speed by less than
# this fraction of the last sweep's largest change (or the tolerance) and no update has
# changed one of its bodies by that much since; a sweep of every contact confirms convergence.
QUIET_FRACTION = 0.1
# Scenes of fewer bodies than this skip no contact: where every contact shares one body it would
# only reorder the sweep, and below a pile's size it did not pay (`cube_stack`, `cube_rain_8`).
# From this many bodies on, solves run `gauss_seidel.iterate_pile`.
QUIET_MIN_BODIES = 16


@kernel
def candidate_margin(dt):
    """How far (m) candidates reach beyond each body's reach: CANDIDATE_SPEEDUP over dt."""
    return CANDIDATE_SPEEDUP * dt


@kernel
def solver_tolerance(dt):
    """Where Gauss-Seidel stops (m/s): VELOCITY_TOLERANCE, or GAP_ROUNDING / dt if larger."""
    return max(VELOCITY_TOLERANCE, GAP_ROUNDING / dt)


def describe(dt: float) -> dict:
    """The solver's formulation and every setting that affects its results, as prose for a run
    manifest at step dt (s)."""
    return {
        "contact": "impulses only: speculative before the drift, bounce and rest after it",
        "friction_cone": "isotropic Coulomb disc",
        "solver": "projected Gauss-Seidel, warm-started, with subspace steps and extrapolation",
        "subspace_steps": (
            f"after unconverged sweeps {SUBSPACE_FIRST} to "
            f"{SUBSPACE_FIRST + SUBSPACE_STEPS - 1} of a solve, in scenes of "
            f"{SUBSPACE_MIN_BODIES} bodies or more"
        ),
        "resting_gap": (
            f"before the drift, a contact whose gap is within {RESTING_GAP:g} m of zero aims "
            f"at normal speed 0, else at closing it (an overlap by {BAUMGARTE:g} of it a step)"
        ),
        "post_drift_skip": (
            "a solve after the drift is skipped when, from no impulse, it would change no "
            "speed by more than the tolerance"
        ),
        "warm_start": (
            "last step's impulses, continued to second order where the last two changes differ "
            f"by less than {TREND_AGREEMENT} of it and it exceeds {TREND_NOISE:g} tolerances"
        ),
        "idle_contacts": (
            f"skipped by sweeps while not pushing and more than {IDLE_MARGIN:g} times the last "
            "sweep's largest speed change from their target, until the rest converge"
        ),
        "extrapolation": (
            f"after {RATE_SWEEPS} sweeps whose velocity changes shrank by a steady ratio rho "
            f"(within {RATE_AGREEMENT} of it, rho < {RATE_MAX}), the next sweep's impulse "
            "change times rho / (1 - rho) is added"
        ),
        "restart": (
            f"a warm-started solve in a scene of at most {RESTART_MAX_BODIES} body not converged "
            f"in {RESTART_SWEEPS} sweeps starts again from no impulse, once"
        ),
        "candidates": (
            f"particles whose gap could close within the step with each body's reach widened by "
            f"{CANDIDATE_SPEEDUP:g} m/s x dt; a step whose solve outruns that is found again"
        ),
        "iterations": MAX_ITERATIONS,
        "stall": (
            f"stops unconverged after {STALL_SWEEPS} sweeps in which the bodies' velocity "
            f"change has not fallen below {STALL_PROGRESS} of its last low"
        ),
        "cycle": (
            f"from sweep {CYCLE_START} on, stops unconverged once the velocity change of "
            f"{CYCLE_PERIODS} periods' worth of sweeps (at least {CYCLE_MIN_SWEEPS}), for a "
            f"period up to {CYCLE_MAX_PERIOD}, repeats within {CYCLE_AGREEMENT:g}"
        ),
        # m/s; the kernel's Python code: stating a setting should compile nothing
        "tolerance": solver_tolerance.py_func(dt),
    }
