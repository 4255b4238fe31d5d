"""The report's prose: each section's "How to read" paragraph and notes, each written once.

Texts that depend on the run (repeats, the baseline pair, scaling windows) are functions of it;
the others are constants, with the thresholds they quote read from where those are defined.
"""

from __future__ import annotations

from comparators.run_data import FINAL_FRACTION, FINAL_WINDOW_S
from comparators.scaling import PLATEAU_FACTOR
from comparators.verdict import ENERGY_GROWTH_LIMIT, ENERGY_LOSS_LIMIT, JITTER_SPEED
from reports.convergence import ERROR_CEILING_DEG, ERROR_FLOOR_DEG, MIN_FIT_POINTS, POSITION_FLOOR_M
from reports.tables import EMPTY_CELL


def data_files(scaling: bool) -> str:
    """Where the report's numbers are, under its title."""
    scaled = ", `scaling.csv` (one row per scaling run)" if scaling else ""
    return (
        f"All numbers are in `results.csv` (one row per run){scaled} and `outcomes.csv` (one "
        "row per run and measured quantity)."
    )


SUMMARY = (
    "Each case (linked to its section) by engine: the verdict of every integrator at the "
    "case's default dt (off where it missed a closed form), and the engine most accurate at "
    "equal cost."
)
SUMMARY_LEGEND = (
    "How to read: each verdict (ok, diverged, dissipated, tunnelled, jitter, failed) is "
    "defined, with its bound, in [Verdicts](#verdicts) below. "
    "off: the verdict is ok, but a closed form is missed by more than its tolerance (the "
    "findings below say which and by how much). "
    "Where an engine's integrators differ, each verdict names its integrators. Most accurate at "
    "equal cost: the engine with the smallest orientation error at the most time budgets of "
    "the case's work-precision plot (at how many, of how many); self-convergence where the "
    "case has no exact motion and each engine's error is against its own run at the finest dt, "
    "which ranks how little its runs change with dt, not how close they come to the physics; "
    "– where fewer than two engines have valid runs with an error to compare (a case swept at "
    "one dt has none)."
)
SUMMARY_OUTCOMES = (
    "How to read: per case, the closed-form outcome that says most about it, and what each "
    "engine measures with its default integrator at the case's default dt, with its relative "
    "error (its absolute error against a closed form of 0), and the run's verdict where it is "
    "not ok (alone where the run diverged or failed). Every quantity, integrator and dt: "
    "Contact validation and each case's Outcomes."
)
VERDICTS = (
    "Every run gets one verdict, read from its states the same way for every engine "
    "(`comparators/verdict.py`), the first that applies in this order. Energies are relative "
    "to the energy scale: the initial kinetic energy plus, per body, m |g| times its height "
    "above the support plane (without one, its ballistic drop over the run)."
)


def verdict_bounds() -> list[tuple[str, str, str]]:
    """(verdict, what it says, bound) of every verdict in precedence order, then ok and failed,
    the bounds read from where they are defined."""
    final = f"the final window: the last {FINAL_FRACTION:.0%} of the run, at most "
    final += f"{FINAL_WINDOW_S:g} s"
    return [
        (
            "diverged",
            "a non-finite state, or total energy grown above its initial value",
            f"energy gain > {ENERGY_GROWTH_LIMIT:g} × energy scale (`ENERGY_GROWTH_LIMIT`)",
        ),
        (
            "dissipated",
            "a scene without contact (no case has damping) whose total energy fell below its "
            "initial value: the engine took energy away",
            f"energy loss > {ENERGY_LOSS_LIMIT:g} × energy scale (`ENERGY_LOSS_LIMIT`)",
        ),
        (
            "tunnelled",
            "a body passed through a plane",
            "at some sample a particle's centre behind a plane: penetration > particle radius",
        ),
        (
            "jitter",
            "a body that should rest (the case states its rest height) still moves",
            f"some particle faster than {JITTER_SPEED:g} m/s (`JITTER_SPEED`) in {final}",
        ),
        ("ok", "none of the above", EMPTY_CELL),
        ("failed", "no run: the engine raised (its reason is in `results.csv`)", EMPTY_CELL),
    ]


FINDINGS = (
    "Generated from the results at each case's default dt by the rules in "
    "`reports/findings.py` (verdicts other than ok, closed forms missed by more than their "
    "tolerance, energy drift without contact, convergence orders below the expected); each "
    "links to the cases it comes from."
)


def timing(repeats: str) -> str:
    """How the timings were measured; `repeats` is the number of repeats (or "3 to 5")."""
    return (
        "Times are stepping only (`wall_s`): building the engine's model and JIT compilation "
        "are timed apart as `setup_s` (below). Each `wall_s` is the median of "
        f"{repeats} repeat(s) (min and max in `results.csv` as `wall_min_s`, `wall_max_s`), "
        "engines are interleaved so that machine load falls on all of them alike, and only "
        "valid runs (finite, not diverged) are timed. steps/s = steps / `wall_s`; realtime "
        "factor = simulated seconds per stepping second (above 1 is faster than real time)."
    )


def throughput(engine: str, integrator: str) -> str:
    """The throughput table and figure, ratios to the baseline `engine` `integrator`."""
    return (
        "How to read: per case at its default dt (rows) and engine/integrator (columns), steps "
        "per second of stepping from this sweep's timings (medians, measured as above; higher "
        f"is faster), in parentheses its ratio to {engine} {integrator} on the same case and dt; "
        "the figure adds each run's [min, max] over its repeats, and draws hollow a run whose "
        "physics is wrong (a verdict other than ok, or a closed form missed: the speed of "
        "other physics). Runs went through the "
        "executor's workers, which share the machine; `rigidbench bench` times the same side "
        "by side in one process, at least 5 repeats each."
    )


CASE_CATALOG = (
    "How to read: what each case is, what an engine has to model for it, and what its errors "
    "are measured against (exact: closed form; self-convergence: the same engine and "
    "integrator at the finest dt)."
)

# ---- a case's sections -----------------------------------------------------------------------

MOTION = (
    "How to read: one panel per run at the case's default dt, labelled engine/integrator, the "
    "time above them; each body's particles as spheres joined to their neighbours, the "
    "lighter ones on one side of the body so that a spin or a flip shows; "
    "planes as grids; grey rings are the exact motion, where there is one; a run whose state "
    "turns non-finite stops there, marked diverged."
)
METRICS = (
    "How to read: drifts are relative maxima over the run (0 is exact conservation), errors "
    "the largest over the run against the reference; steps/s and realtime factor are "
    "stepping only, higher is faster; the verdict as [Verdicts](#verdicts) defines it."
)
SOLVER_NOTE = (
    " Solver columns are what an engine reports of its own contact solver, where it reports "
    "anything: the reference's Gauss-Seidel sweeps per solve (two solves a step with contact), "
    "the solves it stopped unconverged (at its iteration limit, or stalled), its subspace steps "
    "per solve (a direct solve of the contacts that push, each costing more than a sweep) and "
    "its extrapolations per solve (a jump along the sweeps' steady rate of convergence)."
)
MESSAGES_NOTE = (
    " Engine messages are what an engine printed or warned while it ran (lines, and the first "
    "of them; every one is in its trajectory's record): they stand beside the verdict, which "
    "is measured from the states alone."
)
DRIFT = (
    "How to read: relative error of total energy and angular momentum against time at the "
    "case's default dt (or the closest swept); a bounded wobble is what a symplectic "
    "integrator gives, a steady climb is secular drift."
)
PATH = (
    "How to read: the centre of mass within the plane the body slides on, along the straight "
    "line the closed forms have it follow (m) and across it (mm, magnified); the shaded band is "
    "the stray the findings allow. Isotropic Coulomb friction keeps a body on the line and, on "
    "a level plane, stops it at the dotted closed form; a friction pyramid bends the path "
    "where one of its two directions stops first, and friction turned off the slip by the "
    "body's inertia curves it."
)
SPIN = (
    "How to read: the body's spin about the normal of the plane it stands on against time; "
    "Coulomb friction at contacts on one circle about the axis slows it uniformly, down the "
    "dotted closed form to zero; a friction pyramid slows it faster where its contacts slide "
    "off the pyramid's axes."
)
CONVERGENCE = (
    "How to read: on log-log axes an error ~ dt^p is a straight line of slope p, the "
    "fitted order; fits use valid runs with errors between "
    f"{ERROR_FLOOR_DEG:g} deg (rounding below) and {ERROR_CEILING_DEG:g} deg (saturation "
    f"above) and need {MIN_FIT_POINTS} such dt. R² near 1: a clean power law. Position "
    f'order "exact": every position error is below {POSITION_FLOOR_M:g} m (rounding). A '
    "single-precision engine (PhysX, Rapier: float32) has a precision floor of its own: where "
    "its errors stop falling as dt shrinks, rounding has overtaken truncation; the fit stops at "
    'its smallest error and its note says "precision floor" and below which dt.'
)
CONTACT_ORDER_NOTE = (
    " With contact, impacts are resolved once per step, so no integrator converges faster "
    "than first order overall; the expected orders are those of the smooth motion between "
    "contacts, and a low R² says the error is not a power law of dt at all (a contact "
    "sequence that changes with dt)."
)
WORK_PRECISION = (
    "How to read: lower left is better, less error for less stepping time; each engine's "
    "Pareto front is its best error for a given time."
)
STABILITY_MAP = (
    "How to read: where each engine and integrator breaks as dt grows, coloured by verdict "
    "([Verdicts](#verdicts) has each one's bound): red diverged, brown dissipated, orange "
    "tunnelled, pink jitter, dark grey failed (no run); valid runs are coloured by their "
    "orientation error, light grey where none is measured."
)

# ---- outcomes ------------------------------------------------------------------------------

FLIP_PERIOD = (
    "flip_period: mean time between sign changes of the intermediate principal axis's component "
    "along the angular momentum (the flips of a spin near that axis; half the nutation period "
    "of a spin near another), against the exact solution's at the same sample times."
)
CASE_OUTCOMES = (
    "How to read: per quantity (unit), its closed form and per engine/integrator the value "
    "measured at the case's default dt, its error (measured - closed form) in parentheses "
    "and, with several dts swept, the error's range over them in brackets. " + FLIP_PERIOD
)
CONTACT_VALIDATION = (
    "What every engine does on the cases with contact, measured from its trajectories the "
    "same way for all (`comparators.outcomes`), against what physics predicts in closed form "
    "where the case states it."
)
CONTACT_OUTCOMES = (
    "How to read: per quantity (unit), its closed form and per engine/integrator the value "
    "measured at the case's default dt from the trajectory, its error (measured - closed form) "
    "in parentheses and, when several dts were swept, the range of that error over them in "
    f"brackets; {EMPTY_CELL} where there is no closed form or no measurement. rebound_ratio: "
    "mean over the first bounces of the COM's normal rebound over approach speed, each carried "
    "ballistically to the floor; apex_height_k: clearance of the lowest particle surface at the "
    "k-th apex; stopping distance and time: until the COM speed stays below 1 mm/s; "
    "spin_angle and spin_time: the turn about the plane's normal until the spin about it stays "
    "below 1 mrad/s; "
    "slope_acceleration: least-squares fit of the downhill COM displacement, slides 1 or sticks "
    "0; lift: the highest a sliding body's lowest particle surface rose above the plane it "
    "starts on (0: it slides in contact throughout, as both closed forms assume); sideways: "
    "the furthest its COM strayed, within that plane, from the straight line both closed forms "
    "have it slide along (downhill, or along its starting velocity on a level plane); creep: "
    "the COM's largest displacement from where a body placed at rest started (from the start "
    "of the final window for one that comes to rest), jitter_rms (RMS COM speed) and "
    "penetration (deepest particle surface below the floor) over the final window (the last "
    f"{FINAL_FRACTION:.0%} of the run, at most {FINAL_WINDOW_S:g} s), each of whose closed "
    "form at rest is 0; standing 1 or fallen 0 and "
    "top_drift of a stack; momentum changes relative to the bodies' summed momenta; "
    "max_penetration: the deepest any particle surface went below a plane (no closed form; "
    "beyond the particle radius is a tunnel); " + FLIP_PERIOD
)

# ---- across cases --------------------------------------------------------------------------

LARGEST_STABLE = (
    "How to read: per case (rows) and engine/integrator (columns), the largest swept dt (s) "
    "whose run and every run at a smaller dt have the verdict ok, with in parentheses the "
    "verdict ([Verdicts](#verdicts)) and dt of the first run that is not; ≥ dt: every swept "
    "dt is ok, the limit lies beyond the sweep; none: even the smallest swept dt fails. A "
    "case swept at one dt only (the quick report's hard cases) says ok or not at its default "
    "dt."
)
PHYSICS_GATES = (
    "What `rigidbench gate --physics --engine NAME` checks, read from this report's own runs: "
    "the physics gates shipped with rigidbench (`gates/physics/`, each limit justified there), "
    "expectations any correct engine meets: angular momentum conserved in free flight, no "
    "energy gain beyond 1 %, the fitted order within 0.15 of the declared one on smooth free "
    "flight, rebound within 2 % of e, slide distance and incline acceleration within 1 % with "
    "the sliding cube on its plane and its straight line, "
    "resting contact without creep or jitter, the stack standing. How to read: a row per "
    "gate and measure (at its dt; the order over the gate's dt list), its limit, and per "
    "engine/integrator pass or fail with the measured value (why, where a run failed or "
    "diverged); not measured: this report's sweep lacks the gate's runs (a quick report "
    "sweeps the hard cases at their default dt only); not modelled: the engine does not run "
    "the case. The order gate reads the first 2 s of the tumbling box's runs, before its "
    "first flip: a fixed-step run's first 2 s are the 2 s run's own."
)
COST_TO_TOLERANCE = (
    "How to read: per case and engine, the least stepping time per simulated second (s/s) "
    "among its valid runs (any integrator, any dt) whose orientation error stays within "
    "the tolerance, and which run achieved it; only cases with an exact reference."
)


def scaling(landing_s: float, windows: str, fastest: bool = False) -> str:
    """The scaling figure and table; `landing_s` is when the bottom layer lands, `windows`
    describes the measured windows; `fastest`: each engine's fastest integrator ran too."""
    which = (
        "each engine with its default integrator (series `default`) and its fastest for "
        "contact scenes (`fastest`, chosen as below; `default, fastest` where they are one)"
        if fastest
        else "each engine with its default integrator"
    )
    return (
        "How to read: the stepping cost of `cube_rain_N`, N cubes raining into an open box "
        f"(`cases.catalog.cube_rain`), against N, {which}, run "
        "from t = 0 through the same path as every run (trajectory recorded). Times are "
        "stepping only, the median of the repeats (min and max in `scaling.csv`), engines "
        "interleaved; setup (model building and compilation) is apart. On the log-log plot a "
        "cost growing as N runs parallel to the dashed line; a steeper line grows faster than "
        "N. The bottom layer lands after "
        f"about {landing_s:.1g} s, so a window shorter than that is free fall: the same work "
        "per body at every N, a cost per body that grows is the engine's collision detection. "
        "A longer window adds contact solving, and the work per body then grows with the pile "
        f"as well (a lone cube touches only the floor). Windows: {windows}."
    )


def fastest(case: str, steps: int, dt: float, margin: float, drop: float, seed: str) -> str:
    """How each engine's fastest integrator was chosen: the trial on `case` over `steps` steps
    of `dt`, the default kept within `margin` times, a fastest over `drop` times its default's
    cost not run at larger N; `seed` says whether the reference's `seed` was chosen."""
    return (
        'How "fastest" was chosen: by measurement, not by a list. Every integrator of each '
        f"engine ran `{case}` over its first {steps} steps ({steps * dt:g} s: landings and the "
        "pile, contact solving included), interleaved as above; the table below gives each "
        "one's steps/s in its fastest repeat (other processes only ever add time). An "
        "engine's fastest is the valid run (verdict ok) with the most steps/s, but its default "
        f"unless another exceeds the default's rate by more than {margin - 1:.0%} (near-equal "
        "integrators would otherwise swap between measurements). Users compare against the "
        "fastest setting of the engine they would otherwise pick, hence both series. The "
        f"fastest on `{case}` need not be at larger N: a fastest costing over {drop:g} times its "
        "default's at some N is not run at larger N in that window (its rows say so). The "
        "reference's candidates are all five integrators; `seed`, the blog's scheme, tests "
        f"every pair of particles and counts only when it is the fastest valid one: {seed}."
    )


PLATEAU = (
    "Where cost per body-step stops being flat: per engine and window, the plateau is the "
    "smallest cost per body-step over the smaller N, and it ends at the first N whose cost "
    f"per body-step exceeds {PLATEAU_FACTOR:g} times it ({EMPTY_CELL}: flat up to the largest "
    "N measured). Both are read from the fastest repeat: other processes only ever add "
    "time, and a burst of load must not end a plateau."
)
PARITY = (
    "How to read: the parity check confirms, before stepping, that each run's model has the "
    "scene's mass, inertia, energy, momentum and angular momentum (1e-9 relative); a run "
    "that fails it has the verdict `failed: parity ...`. Below it, per engine, every "
    "setting that affects the result, read back from the engine's model (`meta.settings`) "
    "of one run per integrator."
)
VERSIONS = (
    "How to read: where the timings were taken, and the library versions each engine's runs "
    "recorded (`meta.versions`); several versions in one cell mean runs came from different "
    "installs (for instance from the results cache)."
)
