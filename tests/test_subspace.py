"""Subspace steps (`reference_sim/contact/subspace.py`): the least-squares impulse change that
meets a settled solve's consistent targets at once, and where the solver takes none."""

import numpy as np
import pytest
from scenes import initial_state

from cases import CATALOG
from comparators import run
from comparators.reference import model_from_scene
from reference_sim.contact import buffers, candidates, frames, gauss_seidel, settings, subspace
from reference_sim.contact.buffers import largest_body
from reference_sim.contact.impulses import row_speed
from reference_sim.contact.rows import assemble


def _settled(name, friction=None):
    """A catalog scene's model and state one step in, its contacts' impulses converged to
    rounding: the gravity kick of one step at rest, targets 0."""
    scene = CATALOG[name]
    model = model_from_scene(scene)
    if friction is not None:
        model = model._replace(friction=friction)
    x, q, v, L = initial_state(model, scene)
    buf = buffers.contact_buffers(len(scene.bodies), 64, 16, largest_body(model))
    frames.frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
    margin = settings.candidate_margin(scene.dt)
    nc = candidates.find_candidates_into(model, x, v, scene.dt, (0.0, 0.0, 0.0), margin, buf)
    buf.acting[:nc] = True
    assemble(model, x, nc, settings.TOUCH_TOLERANCE, buf, 0)
    buf.target[:nc] = 0.0
    v += scene.dt * model.gravity
    assert gauss_seidel.iterate(model, x, nc, scene.dt, buf, v, 1e-14, settings.IDLE_MARGIN)[1]
    return model, nc, buf, v, L


def _row_speeds(buf, n_rows, v):
    """Each subspace row's speed minus its target (m/s)."""
    rows = buf.rows[:n_rows]
    return np.array(
        [
            row_speed(buf.jac[k, d], buf.cands[k, 0], buf.cands[k, 2], v, buf.omega)
            - (buf.target[k] if d == 0 else 0.0)
            for k, d in rows
        ]
    )


def test_subspace_step_meets_consistent_targets_at_once():
    """A resting cube nudged (1e-6 m/s, 1e-6 rad/s): its four bottom corners' normal and
    friction rows, all sticking, are redundant but consistent, and the nudge's impulse changes
    keep every impulse inside its bounds. One subspace step must then meet every row to the
    regularisation's share of the nudge (1e-8 of 1e-6 m/s, times a condition of order one:
    1e-12 allowed). Without friction the four normal rows are fewer than the body's 6
    unknowns: no subspace step."""
    model, nc, buf, v, L = _settled("resting_cube", friction=0.0)
    assert subspace.subspace_rows(model, nc, buf) == (4, -1)
    model, nc, buf, v, L = _settled("resting_cube")
    n_rows, n_bodies = subspace.subspace_rows(model, nc, buf)
    assert (n_rows, n_bodies) == (12, 1)
    v[0] += (1e-6, -2e-6, 1e-6)
    L[0] += model.inertia0[0] @ np.array([1e-6, 1e-6, 0.0])
    frames.frames_into(model, np.array([[1.0, 0.0, 0.0, 0.0]]), L, buf.rot, buf.inv, buf.omega)
    assert np.abs(_row_speeds(buf, n_rows, v)).max() > 1e-7
    assert subspace.subspace_step(model, nc, buf, v)
    assert np.abs(_row_speeds(buf, n_rows, v)).max() < 1e-12
    assert (buf.lam[:nc, 0] > 0.0).all()


def _subspace_system(model, buf, n_rows):
    """The subspace rows' Jacobian (rows, 6 B) on every body's (v, omega), and M^-1."""
    nb = buf.rot.shape[0]
    jac = np.zeros((n_rows, 6 * nb))
    for r, (k, d) in enumerate(buf.rows[:n_rows]):
        a, b, j = buf.cands[k, 0], buf.cands[k, 2], buf.jac[k, d]
        jac[r, 6 * a : 6 * a + 6] = np.concatenate([j[0], j[1]])
        if b >= 0:
            jac[r, 6 * b : 6 * b + 6] = -np.concatenate([j[0], j[3]])
    m_inv = np.zeros((6 * nb, 6 * nb))
    for b in range(nb):
        m_inv[6 * b : 6 * b + 3, 6 * b : 6 * b + 3] = np.eye(3) / model.body_mass[b]
        m_inv[6 * b + 3 : 6 * b + 6, 6 * b + 3 : 6 * b + 6] = buf.inv[b].reshape(3, 3)
    return jac, m_inv


def test_subspace_step_is_the_least_squares_impulse_change():
    """On a stack of five cubes, one cube pushed sideways: the step's impulse changes on its 60
    rows (before projection onto the bounds, left in `row_lam`) are the minimum-norm solution
    of J M^-1 J^T dP = e, computed here independently with numpy's pseudo-inverse, to the
    regularisation's bias."""
    model, nc, buf, v, L = _settled("cube_stack")
    v[-1, 0] += 1e-6
    n_rows, n_bodies = subspace.subspace_rows(model, nc, buf)
    assert (n_rows, n_bodies) == (60, 5)  # 20 contacts, all sticking
    jac, m_inv = _subspace_system(model, buf, n_rows)
    error = -_row_speeds(buf, n_rows, v)
    delassus = jac @ m_inv @ jac.T
    expected = np.linalg.pinv(delassus, rcond=1e-10) @ error
    eigenvalues = np.linalg.eigvalsh(delassus)
    smallest = eigenvalues[eigenvalues > 1e-10 * eigenvalues.max()].min()
    eps = settings.SUBSPACE_REGULARIZATION * buf.kn[:nc].max()
    assert subspace.subspace_step(model, nc, buf, v)
    # each of the step's two solves shrinks the component along eigenvalue s by eps / (s + eps)
    # (Tikhonov): 2 eps / smallest in all, here 1.2e-5 (measured 1.27e-5); twice that allowed
    bias = 4.0 * eps / smallest
    assert np.abs(buf.row_lam[:n_rows] - expected).max() < bias * np.abs(expected).max()


@pytest.mark.parametrize("name", ["resting_cube", "cube_stack"])
def test_subspace_step_is_its_regularised_solve_to_rounding(name):
    """The step's impulse changes before projection (`row_lam`) are dP = (W + eps)^-1 J du1,
    du1 = (eps M + J^T J)^-1 J^T e (`_subspace_step`), here in 40-digit arithmetic, to 1e-12
    relative: the step computes them as J A^-1 M du1, to rounding (measured 3e-16 on the cube,
    7e-15 on the stack); forming them as (J du1 - J A^-1 J^T J du1) / eps, as it once did,
    cancels 8 digits (1.8e-8 off on the cube)."""
    mp = pytest.importorskip("mpmath")
    model, nc, buf, v, L = _settled(name)
    v[-1, 0] += 1e-6
    n_rows, _ = subspace.subspace_rows(model, nc, buf)
    jac, m_inv = _subspace_system(model, buf, n_rows)
    error = -_row_speeds(buf, n_rows, v)
    eps = float(settings.SUBSPACE_REGULARIZATION * buf.kn[:nc].max())
    assert subspace.subspace_step(model, nc, buf, v)
    mp.mp.dps = 40
    j, m_inv, e = (mp.matrix(a.tolist()) for a in (jac, m_inv, error))
    du1 = mp.lu_solve(eps * m_inv**-1 + j.T * j, j.T * e)
    change = mp.lu_solve(j * m_inv * j.T + eps * mp.eye(n_rows), j * du1)
    expected = np.array([float(x) for x in change])
    assert np.abs(buf.row_lam[:n_rows] - expected).max() < 1e-12 * np.abs(expected).max()


# Subspace steps a solve in the second half of `cube_stack` (at rest): 0.009 to 0.01 measured
# with every integrator; 0.15 to 0.28 when targets before the drift followed gaps of rounding.
RESTING_STACK_SUBSPACE = 0.02


@pytest.mark.parametrize("integrator", ["euler", "splitting", "exact"])
def test_a_resting_stack_needs_no_subspace_steps(integrator):
    """RESTING_GAP: at rest the stack's gaps wander by the solver's leftover speeds times dt;
    aiming its touching contacts at normal speed 0 rather than at those gaps, its warm-started
    solves converge in a sweep and take hardly any subspace step (the second half of the run,
    from the difference of a whole run's counts and its first half's)."""
    scene = CATALOG["cube_stack"]
    whole, half = (
        run(scene, "reference", integrator, duration=d).meta.solver
        for d in (scene.duration, scene.duration / 2)
    )
    solves = whole["solves"] - half["solves"]
    steps = (
        whole["subspace_per_solve"] * whole["solves"] - half["subspace_per_solve"] * half["solves"]
    )
    assert whole["at_limit"] == 0
    assert steps / solves <= RESTING_STACK_SUBSPACE, f"{integrator}: {steps / solves:.3f}"


def test_one_body_scenes_take_no_subspace_steps():
    """SUBSPACE_MIN_BODIES: a single cube's contacts are left to the sweeps (`dropped_cube` took
    265 steps in 930 solves before), and they still converge. (A stack's steps:
    `test_reference_stack_stands`.)"""
    one = run(CATALOG["dropped_cube"], "reference", "euler").meta.solver
    assert one["solves"] > 0 and one["subspace_per_solve"] == 0 and one["at_limit"] == 0
