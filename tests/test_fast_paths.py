"""The simulator's fast paths give the results of the straightforward ones.

- Free flight: the compiled step loop (tuple arithmetic, principal-frame splitting) against a
  plain numpy transliteration of each integrator's formulas (`straightforward_step` below).
- Contact rows: a step's first assembly keeps the rows the last step's second made (the bodies
  have not moved since), and its second those of its first while no body has moved by
  POSE_ROUNDING; every row a step leaves is what assembling it afresh gives, to rounding, and a
  one-body run ends where a run whose first assemblies keep none ends.
- Idle contacts: Gauss-Seidel sweeps that skip the contacts far from acting end where sweeps
  over every contact end.
- Skipped solves: where a step skips the solve after the drift (no impulse to warm-start from,
  none that would change a speed by more than the solver's tolerance), a solve would have
  changed no contact's speed by more than a few tolerances.
- Grown buffers: a pile run whose contact buffers start too small and grow on demand is, bit for
  bit, a run whose buffers never grow.
"""

import numpy as np
import pytest
from scenes import model_and_state
from scipy.spatial.transform import Rotation

from cases import CATALOG, resolve_case
from reference_sim.contact.buffers import (
    COUNT_KEPT_ROWS,
    COUNT_POST_WARM,
    POST_DRIFT,
    STAT_SWEEPS,
    ContactBuffers,
    contact_buffers,
    largest_body,
)
from reference_sim.contact.candidates import find_candidates_into
from reference_sim.contact.frames import frames_into
from reference_sim.contact.gauss_seidel import iterate
from reference_sim.contact.impulses import row_speed
from reference_sim.contact.rows import assemble
from reference_sim.contact.settings import (
    IDLE_MARGIN,
    TOUCH_TOLERANCE,
    candidate_margin,
    solver_tolerance,
)
from reference_sim.contact.step import _pushes_nothing, solve
from reference_sim.rigid import (
    BOUNCE_STEPS,
    INTEGRATOR_CODES,
    POSE_ROUNDING,
    rigid_step,
    run_contact,
    run_rigid,
)

# Free flight: one step of either path from the same state. They differ in the order of their
# floating-point operations only (a few ulps of unit-scale numbers, ~1e-15), while any formula
# difference would show the integrators' truncation error (>= dt^3 ~ 1e-6). Compared step by
# step, not over a run: near tumbling_box's separatrix rounding differences grow by orders of
# magnitude within 1000 steps, which is the motion's conditioning, not the paths' difference.
FREE_FLIGHT_TOLERANCE = 1e-12
FREE_STEPS = 300


def _quat_mul(p, q):
    w1, v1, w2, v2 = p[0], p[1:], q[0], q[1:]
    return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])


def _rotation(q):
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


def _exp(v):
    angle = np.linalg.norm(v)
    if angle == 0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * v / angle])


def straightforward_step(model, integrator, x, q, v, L, dt):
    """One contact-free step of one body, as each integrator's docstring states it."""
    inv0 = model.inertia0_inv[0]

    def omega(qq):
        r = _rotation(qq / np.linalg.norm(qq))
        return r @ inv0 @ r.T @ L

    g = model.gravity
    if integrator == "euler":
        v = v + g * dt
        q = _quat_mul(_exp(omega(q) * dt), q)
        return x + v * dt, q / np.linalg.norm(q), v
    x = x + v * dt + 0.5 * g * dt * dt
    v = v + g * dt
    if integrator == "splitting":
        for k, frac in ((0, 0.5), (1, 0.5), (2, 1.0), (1, 0.5), (0, 0.5)):
            axis = model.principal_axes[0, k]
            body_l = _rotation(q).T @ L
            angle = axis @ body_l / model.principal_moments[0, k] * frac * dt
            q = _quat_mul(q, _exp(angle * axis))
        return x, q / np.linalg.norm(q), v

    def rate(qq):
        return 0.5 * _quat_mul(np.concatenate([[0.0], omega(qq)]), qq)

    k1 = rate(q)
    k2 = rate(q + 0.5 * dt * k1)
    k3 = rate(q + 0.5 * dt * k2)
    k4 = rate(q + dt * k3)
    q = q + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x, q / np.linalg.norm(q), v


@pytest.mark.parametrize("integrator", ["euler", "splitting", "rk4"])
@pytest.mark.parametrize("case", ["tumbling_box", "thin_rod"])
def test_free_flight_loop_matches_the_straightforward_step(case, integrator):
    scene = CATALOG[case]
    model, state = model_and_state(scene)
    x, q, v = state.x[0].copy(), state.q[0].copy(), state.v[0].copy()
    L = state.L[0].copy()
    code = INTEGRATOR_CODES[integrator]
    worst = 0.0
    for _ in range(FREE_STEPS):
        start = (x[None], q[None], v[None], L[None])
        _, samples, _ = run_rigid(model, code, *(a.copy() for a in start), scene.dt, 1, 1)
        x, q, v = straightforward_step(model, integrator, x, q, v, L, scene.dt)
        worst = max(worst, np.max(np.abs(samples[-1, 0, 0:10] - np.concatenate([x, q, v]))))
    assert worst < FREE_FLIGHT_TOLERANCE


# what an assembly writes per row
ROW_FIELDS = ("gap", "jac", "kn", "kt", "kt_inv", "k_inv")
# Kept rows were assembled at most 2 POSE_ROUNDING from the current pose (`rigid_step`): gaps
# and lever arms differ from fresh ones by up to that (2e-15 m) plus rounding, the entries
# built from them (turns, inverse masses) by about that over the lever arms (0.1 to 1 m):
# 1e-14 relative, against the fast-path bar of 1e-12.
ROW_ATOL = 4 * POSE_ROUNDING
ROW_RTOL = 1e-12
# `dropped_cube`, one body: a run that keeps rows ends within this of one that assembles every
# step's first rows afresh (measured 2.4e-14: rounding, which nothing amplifies). A stack's
# redundant contacts share its weight differently at that rounding (`cube_stack`: 8e-12 m) and
# a pile's paths part, so only the one-body run is compared.
RUN_ATOL = 1e-12


def _assembled_afresh(model, x, buf, n):
    """A copy of `buf` with its first n candidates assembled at the bodies' pose, every one
    acting and no row kept."""
    fresh = ContactBuffers(*(a.copy() for a in buf))
    fresh.acting[:n] = True
    fresh.made[:] = -1
    assemble(model, x, n, TOUCH_TOLERANCE, fresh, 0)
    return fresh


def _assert_rows_hold_the_pose(model, x, buf):
    """The rows a step leaves for the next one to keep (those below counts[COUNT_KEPT_ROWS] that
    hold a contact) are what assembling that contact afresh at the bodies' pose gives, to within the
    rounding of the pose they were assembled at (ROW_RTOL, ROW_ATOL)."""
    n = buf.counts[COUNT_KEPT_ROWS]
    fresh = _assembled_afresh(model, x, buf, n)
    held = buf.made[:n] == buf.keys[:n]
    for field in ROW_FIELDS:
        np.testing.assert_allclose(
            getattr(buf, field)[:n][held],
            getattr(fresh, field)[:n][held],
            rtol=ROW_RTOL,
            atol=ROW_ATOL,
            err_msg=field,
        )


@pytest.mark.parametrize("integrator", ["euler", "splitting"])
@pytest.mark.parametrize("case", ["dropped_cube", "cube_stack", "cube_rain_8"])
def test_reused_contact_rows_are_fresh_ones_to_rounding(case, integrator):
    """A step's first assembly keeps the rows the last step assembled after its drift, and its
    second the rows of its first while no body has moved by POSE_ROUNDING (a body at rest):
    the rows a step leaves are checked against fresh ones every step, and `dropped_cube`'s run
    against one whose first assemblies keep none. In `cube_rain_8` contacts come and go, so a
    row often holds another contact than before."""
    scene = CATALOG[case]
    model, state = model_and_state(scene)
    nb = len(model.body_mass)
    threshold = BOUNCE_STEPS * np.linalg.norm(model.gravity) * scene.dt  # as `run_rigid`'s
    results, reused, resting = [], 0, 0
    n_steps = min(500, round(scene.duration / scene.dt))
    for reuse in (True, False):
        x, q, v, L = (a.copy() for a in state)
        # room for every step: never grown
        buf = contact_buffers(nb, 64 * nb, nb * nb, largest_body(model))
        for _ in range(n_steps):
            if reuse:
                reused += buf.counts[COUNT_KEPT_ROWS] > 0
                since = buf.pose.copy()  # where the kept rows were assembled
            else:
                buf.counts[COUNT_KEPT_ROWS] = 0  # the first assembly keeps no row: every one afresh
            assert (
                rigid_step(
                    model, INTEGRATOR_CODES[integrator], x, q, v, L, scene.dt, threshold, buf
                )
                == 0
            )
            if reuse:
                _assert_rows_hold_the_pose(model, x, buf)
                # the second assembly kept the rows: buf.pose still where they were assembled
                resting += np.array_equal(buf.pose, since)
        results.append((x, q, v, L))
    # rows were kept in much of the run (cube_rain_8 lands a third of the way through its run)
    assert reused > n_steps // 3
    if case == "dropped_cube":
        assert resting > n_steps // 3  # at rest from about its step 250
        for fast, plain in zip(*results, strict=True):
            np.testing.assert_allclose(fast, plain, rtol=0, atol=RUN_ATOL)


def test_rows_past_the_last_assembly_are_assembled_afresh():
    """An assembly keeps only rows below `kept`, the count the last one made at the current
    pose (`counts[COUNT_KEPT_ROWS]`). A row past them (the last step had fewer candidates) may
    hold the same contact as an older step's row, assembled at that step's pose: it is assembled
    afresh."""
    scene = CATALOG["resting_cube"]
    model, state = model_and_state(scene)
    x, q, v, L = (a.copy() for a in state)
    buf = contact_buffers(1, 64, 16, largest_body(model))
    frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    nc = find_candidates_into(
        model, x, v, scene.dt, (0.0, 0.0, 0.0), candidate_margin(scene.dt), buf
    )
    assert nc >= 2  # the corners on the floor
    buf.acting[:nc] = True
    assemble(model, x, nc, TOUCH_TOLERANCE, buf, 0)  # every row, at this pose
    # the cube moves; a step assembles its one candidate; the next has them all again, with the
    # keys they had before
    x[0, 2] += 0.01
    q[0] = q[0] + np.array([0.0, 0.01, 0.0, 0.0])
    q[0] /= np.linalg.norm(q[0])
    frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    assemble(model, x, 1, TOUCH_TOLERANCE, buf, 0)
    assemble(model, x, nc, TOUCH_TOLERANCE, buf, 1)
    fresh = _assembled_afresh(model, x, buf, nc)
    for field in ROW_FIELDS:
        np.testing.assert_array_equal(getattr(buf, field)[:nc], getattr(fresh, field)[:nc])


@pytest.mark.parametrize("steps", [40, 70, 100])
def test_sweeps_that_skip_idle_contacts_end_where_full_sweeps_end(steps):
    """`cube_rain_8` after `steps` steps, its cubes landing on the floor and on each other: every
    candidate contact solved from zero impulses towards its speculative target -gap / dt, as
    before a drift. Most candidates are far from acting; the sweeps that skip them (and visit
    them again every few sweeps and before stopping) reach the impulses and velocities of
    sweeps over every contact, bit for bit."""
    scene = CATALOG["cube_rain_8"]
    model, state = model_and_state(scene)
    x, q, v, L = (a.copy() for a in state)
    nb = len(model.body_mass)
    buf = contact_buffers(nb, 64 * nb, nb * nb, largest_body(model))
    threshold = BOUNCE_STEPS * np.linalg.norm(model.gravity) * scene.dt
    for _ in range(steps):
        assert (
            rigid_step(model, INTEGRATOR_CODES["euler"], x, q, v, L, scene.dt, threshold, buf) == 0
        )
    frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    nc = find_candidates_into(
        model, x, v, scene.dt, (0.0, 0.0, 0.0), candidate_margin(scene.dt), buf
    )
    buf.acting[:nc] = True
    assemble(model, x, nc, TOUCH_TOLERANCE, buf, 0)
    gap = buf.gap[:nc]
    buf.target[:nc] = np.where(gap >= 0.0, -gap / scene.dt, 0.0)
    buf.lam[:nc] = 0.0
    v += scene.dt * model.gravity
    results = []
    for margin in (IDLE_MARGIN, np.inf):  # np.inf: no contact is idle
        work = ContactBuffers(*(a.copy() for a in buf))
        vv = v.copy()
        sweeps, _ = iterate(model, x, nc, scene.dt, work, vv, solver_tolerance(scene.dt), margin)
        results.append((vv, work.lam[:nc], work.omega, sweeps))
    # most candidates were far from acting: the skipping sweeps had contacts to skip
    pushing = int(np.count_nonzero(results[1][1][:, 0]))
    assert pushing < nc // 2
    for fast, plain in zip(*results, strict=True):
        np.testing.assert_array_equal(fast, plain)


# A skipped solve's contacts each start within the solver's tolerance of their targets, and its
# one sweep's updates of contacts sharing a body add up: at most 1.05 tolerances measured here.
SKIP_SPEEDS = 2.0


def _row_speeds(buf, nc, v, omega):
    """Every active contact's speed along each of its three rows (m/s), (nc, 3)."""
    return np.array(
        [
            [row_speed(buf.jac[k, r], buf.cands[k, 0], buf.cands[k, 2], v, omega) for r in range(3)]
            for k in range(nc)
            if buf.active[k]
        ]
    ).reshape(-1, 3)


@pytest.mark.parametrize("integrator", ["euler", "splitting"])
@pytest.mark.parametrize(
    "case", ["dropped_cube", "bounce", "cube_collision", "cube_rain_8", "cube_stack", "incline"]
)
def test_a_skipped_post_drift_solve_would_change_no_speed_by_the_tolerance(case, integrator):
    """After the drift a step skips the solve when no contact pushed after the last drift by
    more than the solver's tolerance and none would start to (`_pushes_nothing`): wherever that
    holds on the state a step leaves (its post-drift rows, targets and velocities), a solve
    from no impulse must end after one sweep, every contact's speeds within SKIP_SPEEDS
    tolerances of where they were. Skips must happen (bodies leaving the floor or each other,
    pivoting, resting or sliding with `euler`; with `splitting` the drift's half kick of
    gravity makes a resting or pivoting body's contacts approach, and `dropped_cube` skips 4 of
    its 500)."""
    scene = CATALOG[case]
    model, state = model_and_state(scene)
    nb = len(model.body_mass)
    threshold = BOUNCE_STEPS * np.linalg.norm(model.gravity) * scene.dt  # as `run_rigid`'s
    tolerance = solver_tolerance(scene.dt)
    x, q, v, L = (a.copy() for a in state)
    buf = contact_buffers(nb, 64 * nb, nb * nb, largest_body(model))
    n_steps = min(1000, round(scene.duration / scene.dt))
    skipped, largest = 0, 0.0
    for _ in range(n_steps):
        remembered = buf.counts[COUNT_POST_WARM]
        assert (
            rigid_step(model, INTEGRATOR_CODES[integrator], x, q, v, L, scene.dt, threshold, buf)
            == 0
        )
        nc = buf.counts[COUNT_KEPT_ROWS]  # the candidates after the drift, assembled at this pose
        if nc == 0 or not _pushes_nothing(model, nc, buf, v, tolerance):
            continue
        skipped += remembered == 0
        work = ContactBuffers(*(a.copy() for a in buf))
        vv, LL = v.copy(), L.copy()
        solve(model, x, vv, LL, nc, scene.dt, work, work.post_keys, work.post_lam, 0, POST_DRIFT)
        assert work.solver[STAT_SWEEPS] - buf.solver[STAT_SWEEPS] == 1  # one sweep
        before = _row_speeds(buf, nc, v, buf.omega)
        after = _row_speeds(work, nc, vv, work.omega)
        largest = max(largest, float(np.abs(after - before).max(initial=0.0)) / tolerance)
    assert largest <= SKIP_SPEEDS, f"{case} {integrator}: {largest:.3g} tolerances"
    assert skipped > 0


@pytest.mark.parametrize("integrator", ["euler", "exact"])
@pytest.mark.parametrize("case", ["cube_rain_8", "cube_rain_32"])
def test_grown_buffers_give_the_run_of_buffers_never_grown(case, integrator):
    """`grown` carries the warm start, the trusted rates and the statistics over, and leaves
    the kept rows behind (the next assembly makes them afresh, the same numbers): a pile run
    is the same, bit for bit, from buffers too small for candidates and body pairs alike as
    from buffers never grown, and as `run_rigid`'s."""
    scene = resolve_case(case)
    model, state = model_and_state(scene)
    nb = len(model.body_mass)
    code, n_steps = INTEGRATOR_CODES[integrator], round(scene.duration / scene.dt)
    runs = []
    # too small for both, so grown twice at least (each growth grows one of them), or never
    for capacity, pair_capacity in ((4 * nb, nb // 2), (64 * nb, nb * nb)):
        buf = contact_buffers(nb, capacity, pair_capacity, largest_body(model))
        copies = (a.copy() for a in state)
        _, samples, end = run_contact(model, code, *copies, scene.dt, n_steps, 1, buf)
        runs.append((samples, len(end.cands) > capacity, len(end.pairs) > pair_capacity))
    (small, small_cands, small_pairs), (large, large_cands, large_pairs) = runs
    assert small_cands and small_pairs and not (large_cands or large_pairs)
    _, samples, _ = run_rigid(model, code, *(a.copy() for a in state), scene.dt, n_steps, 1)
    np.testing.assert_array_equal(small, samples)
    np.testing.assert_array_equal(large, samples)
