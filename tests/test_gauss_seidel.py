"""The Gauss-Seidel solve's stopping and speed-ups (`reference_sim/contact/gauss_seidel.py`,
`warm_start.py`): the restart of a cycling landing, the warm start's trend, the stall and cycle
rules, extrapolation and quiet contacts ending where plain sweeps would, a pile's due contacts."""

from typing import NamedTuple

import numpy as np
import pytest
from scenes import model_and_state

from cases import CATALOG, resolve_case
from comparators import run
from comparators.metrics import body_arrays
from comparators.reference import model_from_scene
from reference_sim import rigid
from reference_sim.contact import buffers, frames, gauss_seidel, settings, warm_start
from reference_sim.contact import step as contact_step
from reference_sim.contact.buffers import (
    PRE_DRIFT,
    STAT_EXTRAPOLATIONS,
    STAT_QUIET,
    STAT_SOLVES,
    STAT_SWEEPS,
    STAT_UNCONVERGED,
    largest_body,
)
from reference_sim.rigid import BOUNCE_STEPS, INTEGRATOR_CODES, rigid_step

# `dropped_cube` is its own mirror image in x (its COM at x = 0, spinning about x): it can
# neither turn about y or z nor move along x. Converged solves keep it so to within the order
# of their sweeps: at most 9.3e-6 rad/s about y (`euler`, dt 0.01), 5e-10 with `splitting`.
# The cycling solves that `RESTART_SWEEPS` replaces turned it at 5e-3 rad/s.
SYMMETRY_TOLERANCE = 1e-4  # rad/s


def _off_axis_turn(w):
    """The largest angular speed (rad/s) about y or z in a run of `dropped_cube`, w (S, 3)."""
    return float(np.abs(np.asarray(w)[:, 1:]).max())


@pytest.mark.parametrize("dt", [0.005, 0.01, 0.02])
@pytest.mark.parametrize("integrator", ["euler", "splitting"])
def test_a_mirror_symmetric_landing_converges_and_stays_symmetric(integrator, dt):
    """Every solve of `dropped_cube` converges and the cube never turns off its spin axis; at dt
    0.02 (`euler`) that takes restarting a solve led astray (RESTART_SWEEPS)."""
    traj = run(CATALOG["dropped_cube"], "reference", integrator, dt=dt)
    assert traj.meta.solver["at_limit"] == 0
    turn = _off_axis_turn(body_arrays(traj, "cube")["w"])
    assert turn < SYMMETRY_TOLERANCE, f"dropped_cube {integrator} dt {dt}: {turn:.2e} rad/s"


def test_without_the_restart_the_flat_landing_cycles_and_turns(monkeypatch):
    """`dropped_cube` (`euler`, dt 0.02) stepped through the kernels' Python code without the
    restart (RESTART_MAX_BODIES 0): solves stop unconverged as it lands and it turns off
    its spin axis by more than SYMMETRY_TOLERANCE."""
    _python_solves(monkeypatch, RESTART_MAX_BODIES=0)
    scene, dt = CATALOG["dropped_cube"], 0.02
    model, (x, q, v, L) = model_and_state(scene)
    buf = buffers.contact_buffers(1, 16, 4, largest_body(model))
    threshold = BOUNCE_STEPS * np.linalg.norm(model.gravity) * dt
    w = []
    for _ in range(scene.steps(dt, scene.duration)):
        assert (
            rigid_step.py_func(model, INTEGRATOR_CODES["euler"], x, q, v, L, dt, threshold, buf)
            == 0
        )
        w.append(frames.world_omega(model, q[0], L[0], 0))
    assert buf.solver[STAT_UNCONVERGED] > 0
    assert _off_axis_turn(w) > SYMMETRY_TOLERANCE


def _history(*steps):
    """A warm-start list of one contact: its impulses (normal, two tangents) of the last three
    steps, newest first, NaN for steps it did not exist."""
    lam = np.full((1, 3, 3), np.nan)
    for age, impulses in enumerate(steps):
        lam[0, age] = impulses
    return lam


@pytest.mark.parametrize(
    ("history", "expected"),
    [
        # a steady trend: continued by its last change
        (((3.0, 0.5, -0.25), (2.0, 0.25, -0.125), (1.0, 0.0, 0.0)), (4.0, 0.75, -0.375)),
        # a trend speeding up steadily: continued by its last change and that change's growth
        (((3.0, 0.0, 0.0), (1.875, 0.0, 0.0), (1.0, 0.0, 0.0)), (4.375, 0.0, 0.0)),
        # changes that disagree in sign (jitter about a value): last step's impulses
        (((2.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0)), (2.0, 0.0, 0.0)),
        # a contact two steps old has no trend yet
        (((2.0, 0.0, 0.0), (1.0, 0.0, 0.0)), (2.0, 0.0, 0.0)),
        # a normal impulse trending below zero stops at zero, and its friction with it
        (((0.5, 0.25, 0.0), (1.5, 0.25, 0.0), (2.5, 0.25, 0.0)), (0.0, 0.0, 0.0)),
        # friction trending out of the Coulomb disc (mu = 0.5) ends on its edge
        (((1.0, 0.45, 0.0), (1.0, 0.3, 0.0), (1.0, 0.15, 0.0)), (1.0, 0.5, 0.0)),
    ],
)
def test_warm_start_continues_a_steady_trend_within_the_bounds(history, expected):
    model = model_from_scene(CATALOG["dropped_cube"])  # mu = 0.5
    assert model.friction == 0.5
    start = warm_start.trend(model, _history(*history), 0, 1.0, settings.VELOCITY_TOLERANCE)
    np.testing.assert_allclose(start, expected, rtol=1e-15)


def test_warm_start_does_not_extrapolate_rounding_jitter():
    """A steady trend whose changes move a speed by less than TREND_NOISE tolerances is left
    alone: rounding, not motion."""
    model = model_from_scene(CATALOG["dropped_cube"])
    tolerance = settings.VELOCITY_TOLERANCE
    change = 0.5 * settings.TREND_NOISE * tolerance  # with kn = 1, a speed change of this much
    history = _history((1.0 + 2 * change, 0, 0), (1.0 + change, 0, 0), (1.0, 0, 0))
    assert warm_start.trend(model, history, 0, 1.0, tolerance) == (1.0 + 2 * change, 0.0, 0.0)
    # with kn = 4 it moves a speed by twice TREND_NOISE: continued (to the rounding of 1.0)
    expected = 1.0 + 3 * change
    assert warm_start.trend(model, history, 0, 4.0, tolerance)[0] == pytest.approx(
        expected, abs=1e-3 * change
    )


class _RainStep(NamedTuple):
    """A step of `cube_rain_8` (`euler`): the state and buffers before it, the state after it
    and what the solver counted in it (`ContactBuffers.solver`)."""

    model: object
    state: list
    buf: buffers.ContactBuffers
    after: list
    counted: np.ndarray


def _first_rain_step_counting(counter, converged=False, scene=CATALOG["cube_rain_8"]):
    """The first step of `scene` (a `cube_rain_N`) in which the solver statistic `counter`
    grows (and, if `converged`, every solve converges)."""
    model, (x, q, v, L) = model_and_state(scene)
    nb = len(scene.bodies)
    buf = buffers.contact_buffers(nb, 64 * nb, nb**2, largest_body(model))
    for _ in range(scene.steps(scene.dt, scene.duration)):
        before = [a.copy() for a in (x, q, v, L)], buffers.ContactBuffers(*(a.copy() for a in buf))
        assert _rain_step(model, (x, q, v, L), buf) == 0
        counted = buf.solver - before[1].solver
        if counted[counter] > 0 and not (converged and counted[STAT_UNCONVERGED] > 0):
            after = [a.copy() for a in (x, q, v, L)]
            return _RainStep(model, *before, after, counted)
    pytest.fail(f"no step counted solver statistic {counter}")


def _rain_step(model, state, buf, step=rigid_step):
    """One `euler` step of `cube_rain_N` at the family's dt, in place (`step`: `rigid_step` or
    its Python code)."""
    dt = CATALOG["cube_rain_8"].dt
    threshold = BOUNCE_STEPS * np.linalg.norm(model.gravity) * dt
    return step(model, INTEGRATOR_CODES["euler"], *state, dt, threshold, buf)


def _python_solves(monkeypatch, **changed):
    """Make the contact solves run the kernels' Python code, which reads the solver settings
    `changed` here in the modules that use them (compiled code has its constants built in)."""
    for name, value in changed.items():
        users = [m for m in (gauss_seidel, contact_step) if hasattr(m, name)]
        assert users, f"no solve reads {name}"
        for module in users:
            monkeypatch.setattr(module, name, value)
    monkeypatch.setattr(gauss_seidel, "_follow_rate", gauss_seidel._follow_rate.py_func)
    monkeypatch.setattr(gauss_seidel, "_sweep", gauss_seidel._sweep.py_func)
    monkeypatch.setattr(contact_step, "iterate", gauss_seidel.iterate.py_func)
    monkeypatch.setattr(contact_step, "solve", contact_step.solve.py_func)
    for name in ("before_drift", "after_drift"):
        monkeypatch.setattr(rigid, name, getattr(contact_step, name).py_func)
    for name in ("_contact_before_drift", "_refind"):  # the step's callers of `before_drift`
        monkeypatch.setattr(rigid, name, getattr(rigid, name).py_func)


def _rerun_in_python(monkeypatch, step, **changed):
    """Step `step` again from its state (in place), through the kernels' Python code with the
    solver settings `changed`; returns what the solver counted."""
    _python_solves(monkeypatch, **changed)
    solver = step.buf.solver.copy()
    _rain_step(step.model, step.state, step.buf, rigid_step.py_func)
    return step.buf.solver - solver


def _copy(step):
    """`step` with its state and buffers copied (a rerun changes them in place)."""
    buf = buffers.ContactBuffers(*(a.copy() for a in step.buf))
    return step._replace(state=[a.copy() for a in step.state], buf=buf)


def test_a_solve_stopped_unconverged_is_one_the_iteration_limit_would_not_have_seen_converge(
    monkeypatch,
):
    """`cube_rain_8`'s first solve that stops unconverged stops on the cycle rule, before the
    stall rule would have stopped it and before MAX_ITERATIONS, and is one that cycles: the same
    step, its solves run again from the same state without the rules (the kernels' Python code,
    CYCLE_START and STALL_SWEEPS out of reach), still ends with a solve at MAX_ITERATIONS."""
    step = _first_rain_step_counting(STAT_UNCONVERGED)
    solves, sweeps = step.counted[[STAT_SOLVES, STAT_SWEEPS]].tolist()
    assert sweeps < solves * settings.MAX_ITERATIONS  # stopped early
    stall_rule_only = _rerun_in_python(monkeypatch, _copy(step), CYCLE_START=10**9)
    assert stall_rule_only[STAT_UNCONVERGED] > 0
    assert sweeps < stall_rule_only[STAT_SWEEPS] < solves * settings.MAX_ITERATIONS
    monkeypatch.undo()
    without_rules = _rerun_in_python(monkeypatch, step, STALL_SWEEPS=10**9, CYCLE_START=10**9)
    assert without_rules[STAT_UNCONVERGED] > 0
    assert without_rules[STAT_SWEEPS] >= settings.MAX_ITERATIONS


def test_the_cycle_rule_flags_a_repeating_velocity_change_and_not_a_shrinking_one():
    """Period 3 is flagged once two periods' worth of sweeps repeat the one before (the 6th
    repeat, at the 9th sweep); changes shrinking by 0.9 a sweep, or by more than
    CYCLE_AGREEMENT, never are; shrinking by less counts as repeating (a change that takes
    over 690 sweeps to halve: the stall rule stops it after STALL_SWEEPS)."""
    record = np.zeros((2, settings.CYCLE_MAX_PERIOD))
    period = (0.5, 0.3, 0.1)
    flags = [gauss_seidel.cycles(record, n, period[n % 3]) for n in range(12)]
    assert flags.index(True) == 8
    for rate in (0.9, 1.0 - 2.0 * settings.CYCLE_AGREEMENT):
        assert not any(gauss_seidel.cycles(record, n, rate**n) for n in range(200))
    slow = 1.0 - 0.5 * settings.CYCLE_AGREEMENT
    flags = [gauss_seidel.cycles(record, n, slow**n) for n in range(20)]
    assert flags.index(True) == settings.CYCLE_MIN_SWEEPS


# Both solves stop once a sweep changes no speed by the solver tolerance; Gauss-Seidel at a
# rate up to RATE_MAX (0.98) is then within rate / (1 - rate) = 49 tolerances of its limit.
SAME_MOTION_TOLERANCES = 50


def _assert_same_motion(step):
    """The bodies' velocities after `step` (`step.after`) and after its rerun (`step.state`)
    agree within SAME_MOTION_TOLERANCES solver tolerances, turning at the speed of each body's
    farthest surface point."""
    model = step.model
    tolerance = SAME_MOTION_TOLERANCES * settings.solver_tolerance(CATALOG["cube_rain_8"].dt)
    np.testing.assert_allclose(step.after[2], step.state[2], rtol=0, atol=tolerance)
    for b in range(len(step.state[2])):
        w, w_rerun = (
            model.bound_radius[b] * np.array(frames.world_omega(model, s[1][b], s[3][b], b))
            for s in (step.after, step.state)
        )
        np.testing.assert_allclose(w, w_rerun, rtol=0, atol=tolerance)


def test_an_extrapolated_solve_ends_where_the_sweeps_alone_would(monkeypatch):
    """`cube_rain_8`'s first step with an extrapolation (`gauss_seidel.extrapolate`), run again
    from the same state without extrapolating (the kernels' Python code, RATE_MAX 0): both
    converge, to the same velocities within SAME_MOTION_TOLERANCES solver tolerances, the
    extrapolated one in fewer sweeps."""
    step = _first_rain_step_counting(STAT_EXTRAPOLATIONS)
    assert step.counted[STAT_UNCONVERGED] == 0  # converged
    plain = _rerun_in_python(monkeypatch, step, RATE_MAX=0.0)
    assert plain[STAT_EXTRAPOLATIONS] == 0 and plain[STAT_UNCONVERGED] == 0
    assert step.counted[STAT_SWEEPS] < plain[STAT_SWEEPS]
    _assert_same_motion(step)


def test_skipping_quiet_contacts_ends_where_sweeps_of_every_contact_would(monkeypatch):
    """`cube_rain_16`'s first step whose solves skip quiet contacts and converge, run again
    from the same state skipping none (the kernels' Python code, QUIET_MIN_BODIES out of
    reach): both converge, to the same velocities within SAME_MOTION_TOLERANCES solver
    tolerances."""
    assert settings.QUIET_MIN_BODIES <= 16
    step = _first_rain_step_counting(STAT_QUIET, True, resolve_case("cube_rain_16"))
    every = _rerun_in_python(monkeypatch, step, QUIET_MIN_BODIES=10**9)
    assert every[STAT_QUIET] == 0 and every[STAT_UNCONVERGED] == 0
    _assert_same_motion(step)


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "python"])
def test_a_piles_sweep_finds_its_due_contacts_in_order_and_each_bodys_contacts(compiled):
    """The bit sets of a pile's sweep (`gauss_seidel._pile_sweep`): `_next_due` returns the due
    contacts from a given one on, busy or idle, across words and at bit 63 (the sign bit of
    an int64 word); `_link` lists each body's swept contacts and makes them all due, none idle;
    `_due_on` makes a body's contacts due. Compiled and as the kernels' Python code."""

    def kernel(f):
        return f if compiled else f.py_func

    next_due, link, due_on = (
        kernel(f) for f in (gauss_seidel._next_due, gauss_seidel._link, gauss_seidel._due_on)
    )
    buf = buffers.contact_buffers(4, 200, 8, 1)
    swept = [0, 5, 63, 64, 130, 191]
    bodies = {0: (0, -1), 5: (1, 0), 63: (2, 1), 64: (3, -1), 130: (1, 2), 191: (0, 3)}
    for k, (a, b) in bodies.items():
        buf.cands[k] = (a, 0, b, 0)
    buf.busy[: len(swept)] = swept
    link(buf, len(swept))

    def listed(idle=False):
        found, k = [], 0
        while (k := next_due(buf, k, idle)) >= 0:
            found.append(k)
            k += 1
        return found

    assert listed() == swept and listed(idle=True) == []
    for b in range(4):
        on_b = sorted(buf.links[buf.link_first[b] : buf.link_first[b + 1]])
        assert on_b == [k for k, pair in bodies.items() if b in pair]
    buf.due[:] = 0
    buf.idle[63 >> 6] |= np.int64(1) << np.int64(63)
    due_on(buf, 2)  # contacts 63 (idle) and 130
    assert listed() == [130] and listed(idle=True) == [63]
    assert next_due(buf, 131, False) == -1


def test_a_trusted_rate_extrapolates_sooner_to_the_same_motion():
    """`dropped_cube` (`euler`) rocking on an edge: the first step that starts with a rate
    trusted before the drift (`ContactBuffers.rates`) and extrapolates, run again from the same
    state with no rate trusted: both converge, to the same velocities within
    SAME_MOTION_TOLERANCES solver tolerances, the trusting one in fewer sweeps."""
    scene = CATALOG["dropped_cube"]
    model, state = model_and_state(scene)
    buf = buffers.contact_buffers(1, 64, 4, largest_body(model))
    threshold = BOUNCE_STEPS * np.linalg.norm(model.gravity) * scene.dt
    for _ in range(scene.steps(scene.dt, scene.duration)):
        before = [a.copy() for a in state], buffers.ContactBuffers(*(a.copy() for a in buf))
        assert rigid_step(model, INTEGRATOR_CODES["euler"], *state, scene.dt, threshold, buf) == 0
        trusted = before[1].rates[PRE_DRIFT] > 0.0
        if trusted and buf.solver[STAT_EXTRAPOLATIONS] > before[1].solver[STAT_EXTRAPOLATIONS]:
            break
    else:
        pytest.fail("no step extrapolated with a trusted rate")
    assert buf.solver[STAT_UNCONVERGED] == before[1].solver[STAT_UNCONVERGED]  # converged
    untrusted = buffers.ContactBuffers(*(a.copy() for a in before[1]))
    untrusted.rates[:] = 0.0
    again = [a.copy() for a in before[0]]
    assert rigid_step(model, INTEGRATOR_CODES["euler"], *again, scene.dt, threshold, untrusted) == 0
    assert untrusted.solver[STAT_UNCONVERGED] == before[1].solver[STAT_UNCONVERGED]
    sweeps = buf.solver[STAT_SWEEPS] - before[1].solver[STAT_SWEEPS]
    assert sweeps < untrusted.solver[STAT_SWEEPS] - before[1].solver[STAT_SWEEPS]
    tolerance = SAME_MOTION_TOLERANCES * settings.solver_tolerance(scene.dt)
    np.testing.assert_allclose(state[2], again[2], rtol=0, atol=tolerance)
    w, w_again = (
        model.bound_radius[0] * np.array(frames.world_omega(model, s[1][0], s[3][0], 0))
        for s in (state, again)
    )
    np.testing.assert_allclose(w, w_again, rtol=0, atol=tolerance)
