"""The particle reference simulator (`reference_sim`) as an engine."""

import numpy as np

from cases.scene import Scene
from comparators.engine import register
from comparators.parity import body_readback
from comparators.trajectory import RunMeta, Trajectory, package_versions
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
        n_steps = scene.steps(dt, duration)
        result = simulate(model, state, integrator, dt, n_steps, scene.sample_stride(dt))
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
        meta = RunMeta(
            case=scene.name,
            engine=self.name,
            integrator=integrator,
            dt=dt,
            steps=n_steps,
            duration=n_steps * dt,
            setup_s=result.compile_s,
            wall_s=result.wall_s,
            versions=package_versions("numba"),
            settings={
                "integrator": integrator,
                "timestep": dt,
                "gravity": "on" if model.gravity_on else "off",
                "restitution": model.restitution,
                "friction": model.friction,
                "inertia": "particle tensor, full 3 x 3",
                **_contact_settings(scene, integrator, dt),
            },
            bodies=bodies,
            solver=_solver_report(result.solver),
        )
        extra = None if result.shape_error is None else {"shape_error": result.shape_error}
        return Trajectory.from_samples(
            result.steps * dt, [b.name for b in scene.bodies], result.samples, meta, extra
        )


def _contact_settings(scene: Scene, integrator: str, dt: float) -> dict:
    if not scene.has_contact:
        return {"contact": "none"}
    if integrator == "seed":
        return {"contact": "the blog's: particles pushed apart and clamped to walls, restitution"}
    return describe(dt)


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


register(ReferenceEngine())
