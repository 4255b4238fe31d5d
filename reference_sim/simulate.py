"""Run the particle simulator: one entry point for every integrator, arrays in, arrays out."""

import time
from typing import NamedTuple

import numpy as np

from reference_sim.contact.buffers import contact_buffers, grown, largest_body
from reference_sim.contact.candidates import find_candidates_into
from reference_sim.contact.frames import frames_into
from reference_sim.contact.pair_list import pair_list
from reference_sim.contact.settings import candidate_margin
from reference_sim.contact.step import after_drift, before_drift
from reference_sim.model import (
    Model,
    RigidState,
    SeedState,
    build_model,
    rigid_initial_state,
    seed_initial_state,
)
from reference_sim.rigid import INTEGRATOR_CODES, _body_pairs, _free_steps, run_rigid_fields
from reference_sim.seed import run_seed

INTEGRATORS = ("seed", *INTEGRATOR_CODES)
# The order each integrator's error should show in dt. `exact` has no truncation error without
# contact (its error is rounding at every dt); with contact its kick-drift-kick is second order.
ORDERS = {"seed": 1, "euler": 1, "splitting": 2, "rk4": 4, "exact": 2}


class SimResult(NamedTuple):
    """Samples of a run.

    Attributes:
      steps: (S,) step index of each sample; t = steps * dt.
      samples: (S, B, 13) per body x (3), q (4, w first), v (3), world omega (3).
      shape_error: (S, B) largest relative change of an inter-particle distance (seed only).
      particles: (S, N, 3) world positions of every particle, bodies packed as in the model
        (seed only: its body deforms, so its pose does not place its particles).
      solver: the contact solver's statistics (rigid integrators only): solves, Gauss-Seidel
        sweeps, solves stopped unconverged (at MAX_ITERATIONS, stalled or cycling), subspace
        steps, extrapolations and updates skipped as quiet, over the run.
      state: the final state.  compile_s: time spent compiling or loading compiled code (s).
      wall_s: time spent stepping alone (s).
    """

    steps: np.ndarray
    samples: np.ndarray
    shape_error: np.ndarray | None
    particles: np.ndarray | None
    solver: np.ndarray | None
    state: RigidState | SeedState
    compile_s: float
    wall_s: float


def _call(model, integrator, state, dt, n_steps, stride):
    """(steps, samples, shape_error, particles, solver) of a run, None where the integrator
    has none."""
    if integrator == "seed":
        return (*run_seed(model, *state, dt, n_steps, stride), None)
    steps, samples, solver = run_rigid_fields(
        tuple(model), INTEGRATOR_CODES[integrator], *state, dt, n_steps, stride
    )
    return steps, samples, None, None, solver


def simulate(
    model: Model, state: RigidState | SeedState, integrator: str, dt: float, n_steps: int, stride=1
) -> SimResult:
    """Advance `state` (a copy; the argument is not modified) by n_steps of dt.

    `state` is a `SeedState` for "seed" and a `RigidState` otherwise. Compilation is done by a
    one-step warm-up on a copy and timed apart from the run.
    """
    if integrator not in INTEGRATORS:
        raise ValueError(f"unknown integrator {integrator!r}: expected one of {INTEGRATORS}")
    expected = SeedState if integrator == "seed" else RigidState
    if not isinstance(state, expected):
        raise TypeError(f"integrator {integrator!r} needs a {expected.__name__}")
    start = time.perf_counter()
    _call(model, integrator, type(state)(*(a.copy() for a in state)), dt, 1, 1)
    compile_s = time.perf_counter() - start
    work = type(state)(*(a.copy() for a in state))
    start = time.perf_counter()
    steps, samples, shape, particles, solver = _call(
        model, integrator, work, dt, int(n_steps), int(stride)
    )
    wall_s = time.perf_counter() - start
    return SimResult(steps, samples, shape, particles, solver, work, compile_s, wall_s)


# Parts of the simulator that compile independently; the stages of one group run in order
# (the later ones load the earlier ones' code from numba's cache), the groups in parallel
# processes. "rigid" needs the code of "free" and "contact": "free" compiles in the other
# process while "contact" does, the longest stage (docs/contact-solver.md, Compiled code).
COMPILE_GROUPS = (("free", "seed"), ("contact", "rigid"))
COMPILE_STAGES = tuple(stage for group in COMPILE_GROUPS for stage in group)


def compile_stages(stages) -> None:
    """`compile_stage` each of `stages`, in order."""
    for stage in stages:
        compile_stage(stage)


def compile_stage(stage: str) -> None:
    """Compile (or load from numba's cache) one part of the simulator on a tiny scene.

    "contact" compiles the contact impulses (`before_drift`, `after_drift` and what they
    call), "free" the rigid integrators' contact-free steps and the contact buffers, "seed"
    the seed integrator, whose pair search uses the grid "free" compiles (so it follows it in
    one process of `COMPILE_GROUPS`, beside "contact" in the other). "rigid" then loads their
    code from the cache and compiles only the step loops around it.
    """
    corners = np.array([[x, y, z, 1.0] for x in (0, 1) for y in (0, 1) for z in (0.2, 1.2)])
    model = build_model(
        [(corners, 0.2)], (0.0, 0.0, -10.0), [[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], 0.5, 0.5, True
    )
    com, velocity, omega = [[0.5, 0.5, 0.7]], [[0.0, 0.0, -1.0]], [[1.0, 0.0, 0.0]]
    state = rigid_initial_state(model, com, velocity, omega)
    dt = 0.01
    if stage == "contact":
        x, q, v, L = (a.copy() for a in state)
        # the buffers and the candidates by the Python functions: compiling them is "free"'s
        # part (the candidates compile inlined in the step, calling the kernels compiled here)
        buf = contact_buffers.py_func(1, 16, 4, largest_body.py_func(model))
        frames_into(model, q, L, buf.rot, buf.inv, buf.omega)
        margin = candidate_margin.py_func(dt)
        nc = find_candidates_into.py_func(model, x, v, dt, (0.0, 0.0, 0.0), margin, buf)
        before_drift(model, x, v, L, nc, dt, (0.0, 0.0, -0.05), 0.2, buf, np.bool_(True))
        after_drift(model, x, q, v, L, nc, dt, buf)
    elif stage == "free":
        x, q, v, L = (a.copy() for a in state)
        out, steps = np.empty((2, 1, 13)), np.empty(2, dtype=np.int64)
        _free_steps(model, INTEGRATOR_CODES["splitting"], x, q, v, L, dt, 1, 1, out, steps)
        buf = grown(contact_buffers(1, 8, 4, largest_body(model)), 16, 4)
        _body_pairs(model, INTEGRATOR_CODES["splitting"], x, q, v, L, dt, buf, pair_list(1))
    elif stage == "seed":
        simulate(model, seed_initial_state(model, corners[:, :3], velocity, omega), "seed", dt, 2)
    elif stage == "rigid":
        simulate(model, state, "splitting", dt, 2)
    else:
        raise ValueError(f"unknown compile stage {stage!r}: expected one of {COMPILE_STAGES}")
