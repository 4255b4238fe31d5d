"""The particle reference simulator (`reference_sim`) as an engine."""

import numpy as np

from cases.scene import Scene
from comparators.harness import RunTimer
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from reference_sim.contact import (
    CYCLE_AGREEMENT,
    CYCLE_MAX_PERIOD,
    CYCLE_MIN_SWEEPS,
    CYCLE_PERIODS,
    CYCLE_START,
    IDLE_MARGIN,
    MAX_ITERATIONS,
    RATE_AGREEMENT,
    RATE_MAX,
    RATE_SWEEPS,
    RESTART_MAX_BODIES,
    RESTART_SWEEPS,
    STALL_PROGRESS,
    STALL_SWEEPS,
    SUBSPACE_FIRST,
    SUBSPACE_MIN_BODIES,
    SUBSPACE_STEPS,
    TREND_AGREEMENT,
    TREND_NOISE,
    solver_tolerance,
)
from reference_sim.model import Model, build_model, rigid_initial_state, seed_initial_state
from reference_sim.simulate import INTEGRATORS, ORDERS, simulate


def model_from_scene(scene: Scene) -> Model:
    """The simulator's model of `scene`: contact only where the scene has something to hit."""
    return build_model(
        [(b.particles, b.particle_radius) for b in scene.bodies],
        scene.gravity,
        [p.point for p in scene.planes],
        [p.normal for p in scene.planes],
        scene.contact.restitution if scene.contact else 0.0,
        scene.contact.friction if scene.contact else 0.0,
        contact=scene.has_contact,
    )


class ReferenceEngine:
    name = "reference"
    integrators = INTEGRATORS
    default_integrator = "splitting"
    orders = ORDERS
    missing = None

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        timer = RunTimer(scene, self.name, integrator, dt, duration)
        model = model_from_scene(scene)
        velocity = [b.velocity for b in scene.bodies]
        omega = [b.angular_velocity for b in scene.bodies]
        # the rigid state at t = 0, also the seed's body state (cm, V, omega)
        scene_state = rigid_initial_state(model, [b.com for b in scene.bodies], velocity, omega)
        if integrator == "seed":
            positions = np.concatenate([b.positions for b in scene.bodies])
            state = seed_initial_state(model, positions, velocity, omega)
        else:
            state = scene_state
        result = simulate(model, state, integrator, dt, timer.n_steps, timer.stride)
        # simulate times its compilation warm-up (setup) and its stepping itself
        timer.add_times(setup_s=result.compile_s, wall_s=result.wall_s)
        bodies = {
            b.name: body_readback(
                model.body_mass[k],
                model.inertia0[k],
                scene_state.x[k],
                scene_state.v[k],
                model.inertia0_inv[k] @ scene_state.L[k],
            )
            for k, b in enumerate(scene.bodies)
        }
        settings = {
            "integrator": integrator,
            "timestep": dt,
            "gravity": "on" if model.gravity_on else "off",
            "restitution": model.restitution,
            "friction": model.friction,
            "inertia": "particle tensor, full 3 x 3",
            **_contact_settings(scene, integrator, dt),
        }
        meta = timer.meta(
            package_versions("numba"), settings, bodies, _solver_report(result.solver)
        )
        extra = None if result.shape_error is None else {"shape_error": result.shape_error}
        return timer.trajectory(result.steps, result.samples, meta, extra)


def _contact_settings(scene: Scene, integrator: str, dt: float) -> dict:
    if not scene.has_contact:
        return {"contact": "none"}
    if integrator == "seed":
        return {"contact": "the blog's: particles pushed apart and clamped to walls, restitution"}
    return {
        "contact": "impulses only: speculative before the drift, bounce and rest after it",
        "friction_cone": "isotropic Coulomb disc",
        "solver": "projected Gauss-Seidel, warm-started, with subspace steps and extrapolation",
        "subspace_steps": (
            f"after unconverged sweeps {SUBSPACE_FIRST} to "
            f"{SUBSPACE_FIRST + SUBSPACE_STEPS - 1} of a solve, in scenes of "
            f"{SUBSPACE_MIN_BODIES} bodies or more"
        ),
        "warm_start": (
            "last step's impulses, plus last step's change where the last two changes differ "
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


def _solver_report(solver) -> dict[str, float]:
    """`RunMeta.solver` from `run_rigid`'s statistics (solves, sweeps, solves stopped
    unconverged, subspace steps, extrapolations)."""
    if solver is None or solver[0] == 0:
        return {}
    solves, sweeps, at_limit, subspace, extrapolations = (int(n) for n in solver)
    return {
        "solves": solves,
        "sweeps_per_solve": sweeps / solves,
        "at_limit": at_limit,
        "subspace_per_solve": subspace / solves,
        "extrapolations_per_solve": extrapolations / solves,
    }
