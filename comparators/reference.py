"""The particle reference simulator (`reference_sim`) as an engine."""

import numpy as np

from cases.scene import Scene
from comparators.harness import RunTimer
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from reference_sim.contact.buffers import (
    STAT_EXTRAPOLATIONS,
    STAT_REFOUND,
    STAT_SOLVES,
    STAT_SUBSPACE_STEPS,
    STAT_SWEEPS,
    STAT_UNCONVERGED,
)
from reference_sim.contact.settings import describe
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
        return timer.trajectory(result.steps, result.samples, meta, extra, result.particles)


def _contact_settings(scene: Scene, integrator: str, dt: float) -> dict:
    if not scene.has_contact:
        return {"contact": "none"}
    if integrator == "seed":
        return {"contact": "the blog's: particles pushed apart and clamped to walls, restitution"}
    return describe(dt)


def _solver_report(solver) -> dict[str, float]:
    """`RunMeta.solver` from `run_rigid`'s statistics, read by their `STAT_*` names."""
    if solver is None or solver[STAT_SOLVES] == 0:
        return {}
    solves = int(solver[STAT_SOLVES])
    return {
        "solves": solves,
        "sweeps_per_solve": int(solver[STAT_SWEEPS]) / solves,
        "at_limit": int(solver[STAT_UNCONVERGED]),
        "subspace_per_solve": int(solver[STAT_SUBSPACE_STEPS]) / solves,
        "extrapolations_per_solve": int(solver[STAT_EXTRAPOLATIONS]) / solves,
        "refound": int(solver[STAT_REFOUND]),
    }
