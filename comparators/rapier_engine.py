"""Rapier as an engine: one dynamic rigid body per particle cluster, through `rapier3d`.

Each run builds a fresh `PhysicsWorld`: per scene body a dynamic body at the COM with identity
rotation, its mass, COM and principal inertia (with its frame) set explicitly as additional mass
properties; with contact, one compound collider of the particles' balls with zero mass
properties (so Rapier keeps the explicit ones exactly) and a fixed half-space per plane. Rapier
is single precision (this build's `Real` is f32): `epsilon` is float32's, and scenes whose
numbers f32 cannot hold are `unsupported`. Every setting that changes results is set explicitly
and recorded in the parity manifest (`RapierSettings`): the gyroscopic term on, damping 0,
sleeping off, no angular speed cap, CCD off, friction and restitution combined by MAX so a
contact gets exactly the scene's values. Rapier has one time stepper: the TGS-soft solver's
substeps of semi-implicit Euler, named "tgs_soft".

The mapping, the defaults overridden and their measured effect: docs/engines/rapier.md.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from cases.scene import Scene
from comparators.harness import RunTimer, check_run_call, outside_float32, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from rigidmath.inertia import principal_frame
from rigidmath.quaternion import quat_from_matrix, quat_to_matrix

try:
    import rapier3d as r
except ImportError as exc:  # the module always imports; the engine reports why it cannot run
    r = None
    UNAVAILABLE: str | None = f"rapier3d cannot be imported ({exc}): pip install rigidbench[rapier]"
else:
    UNAVAILABLE = None

FLOAT32_EPSILON = float(np.finfo(np.float32).eps)

TIME_STEPPING = {
    "tgs_soft": "TGS-soft: per step, num_solver_iterations substeps of dt / n, each semi-implicit "
    "Euler (velocities from gravity and contact impulses, then positions; orientation by the "
    "exponential map of omega h)",
}


@dataclasses.dataclass(frozen=True)
class RapierSettings:
    """Every world and body parameter a run sets explicitly (docs/engines/rapier.md)."""

    num_solver_iterations: int = 4  # substeps per step; Rapier's default
    num_internal_pgs_iterations: int = 4  # Rapier's 1 rebounds a 50 m/s e = 0 impact at 3.7 m/s
    num_internal_stabilization_iterations: int = 1
    gyroscopic_forces: bool = True  # the scene is a rigid body: Euler's equations in full
    can_sleep: bool = False
    allow_fast_rotation: bool = True  # no clamp of |omega| h at ~45 degrees per substep
    ccd: bool = False
    soft_ccd_prediction: float = 0.0
    contact_skin: float = 0.0  # m
    prediction_distance: float = 0.002  # m; Rapier's 0.02 bounces at 0.544 for e = 0.5
    allowed_linear_error: float = 0.005  # m, Rapier's default
    max_corrective_velocity: float = 3.0  # m/s, Rapier's default
    # Rapier's default: one friction row at each clustered patch's centre. COULOMB's per-point
    # solve caps each point's impulse along K^-1 v, off the slip: a sliding cube decelerates at
    # 0.98 mu g (docs/engines/rapier.md, "Friction").
    friction_model: str = "SIMPLIFIED"
    warmstart_coefficient: float = 1.0
    contact_natural_frequency: float = 30.0  # Hz, Rapier's default
    contact_damping_ratio: float = 10.0  # Rapier's default
    static_contact_natural_frequency: float = 60.0  # Hz, against fixed bodies; Rapier's default
    static_contact_damping_ratio: float = 10.0  # Rapier's default
    contact_recycling: bool = True  # Rapier's default; off changed no outcome
    max_linear_velocity: float = 1e30  # m/s per substep cap (Rapier's 400 would clip)

    def apply(self, params, dt: float) -> None:
        params.dt = dt
        params.length_unit = 1.0
        params.num_solver_iterations = self.num_solver_iterations
        params.num_internal_pgs_iterations = self.num_internal_pgs_iterations
        params.num_internal_stabilization_iterations = self.num_internal_stabilization_iterations
        params.normalized_prediction_distance = self.prediction_distance
        params.normalized_allowed_linear_error = self.allowed_linear_error
        params.normalized_max_corrective_velocity = self.max_corrective_velocity
        params.normalized_max_linear_velocity = self.max_linear_velocity
        params.friction_model = getattr(r.FrictionModel, self.friction_model)
        params.warmstart_coefficient = self.warmstart_coefficient
        params.contact_softness = r.SpringCoefficients(
            self.contact_natural_frequency, self.contact_damping_ratio
        )
        params.static_contact_softness = r.SpringCoefficients(
            self.static_contact_natural_frequency, self.static_contact_damping_ratio
        )
        params.friction_in_bias_pass = False
        params.contact_recycling = self.contact_recycling
        params.contact_clustering = True


DEFAULT_SETTINGS = RapierSettings()


def _vec(v) -> object:
    return r.Vec3(*(float(c) for c in v))


def _add_body(world, body, contact: bool, e: float, mu: float, settings: RapierSettings):
    moments, axes = principal_frame(body.inertia)
    frame = r.Rotation3(*(float(c) for c in quat_from_matrix(axes)))  # (w, x, y, z)
    mass_properties = r.MassProperties(
        _vec((0.0, 0.0, 0.0)), float(body.mass), _vec(moments), frame
    )
    builder = (
        r.RigidBody.dynamic()
        .translation(_vec(body.com))
        .linvel(_vec(body.velocity))
        .angvel(_vec(body.angular_velocity))  # world frame
        .additional_mass_properties(mass_properties)
        .gyroscopic_forces(settings.gyroscopic_forces)
        .allow_fast_rotation(settings.allow_fast_rotation)
        .linear_damping(0.0)
        .angular_damping(0.0)
        .gravity_scale(1.0)
        .can_sleep(settings.can_sleep)
        .ccd_enabled(settings.ccd)
        .soft_ccd_prediction(settings.soft_ccd_prediction)
    )
    colliders = [_particles(body, e, mu, settings)] if contact else None
    handle = world.add_body(builder, colliders=colliders)
    # Mass properties are otherwise only summed at the first step: the read-back needs them now.
    world.rigid_bodies[handle].recompute_mass_properties_from_colliders(world.colliders)
    return handle


def _material(builder, e: float, mu: float, settings: RapierSettings):
    return (
        builder.friction(mu)
        .restitution(e)
        .friction_combine_rule(r.CoefficientCombineRule.MAX)
        .restitution_combine_rule(r.CoefficientCombineRule.MAX)
        .contact_skin(settings.contact_skin)
    )


def _particles(body, e: float, mu: float, settings: RapierSettings):
    """One compound collider of the particles' balls at the body's origin (the COM), with zero
    mass properties: Rapier then keeps the explicit ones exactly. Separate zero-density balls
    would not: each has its own centre, so summing them re-diagonalises the tensor in f32 (a
    degenerate pair of moments came back 1e-4 off)."""
    ball = r.SharedShape.ball(float(body.particle_radius))
    parts = [
        (r.Isometry3(_vec(offset), r.Rotation3.identity()), ball)
        for offset in body.positions - body.com
    ]
    builder = r.Collider.compound(parts).mass_properties(r.MassProperties.zero())
    return _material(builder, e, mu, settings)


def _add_plane(world, plane, e: float, mu: float, settings: RapierSettings) -> None:
    builder = r.Collider.halfspace(_vec(plane.unit_normal)).translation(_vec(plane.point))
    world.add_collider(_material(builder, e, mu, settings))


def build_world(scene: Scene, dt: float, settings: RapierSettings):
    """A fresh world with the scene's gravity, bodies (handles in scene order) and, with contact,
    planes."""
    world = r.PhysicsWorld(gravity=tuple(float(g) for g in scene.gravity))
    world.set_num_threads(1)  # inline on the calling thread: runs are timed on shared cores
    settings.apply(world.integration_parameters, dt)
    contact = scene.has_contact
    e = scene.contact.restitution if contact else 0.0
    mu = scene.contact.friction if contact else 0.0
    handles = [_add_body(world, b, contact, e, mu, settings) for b in scene.bodies]
    if contact:
        for plane in scene.planes:
            _add_plane(world, plane, e, mu, settings)
    return world, handles


def _quat_wxyz(rotation) -> np.ndarray:
    x, y, z, w = rotation.to_tuple()
    return np.array([w, x, y, z])


def read_back(scene: Scene, world, handles) -> tuple[dict, dict]:
    """The model as Rapier holds it, before stepping: per body `RunMeta.bodies` entries and its
    mass properties as stored (f32) for the settings."""
    bodies, stored = {}, {}
    for body, handle in zip(scene.bodies, handles, strict=True):
        rb = world.rigid_bodies[handle]
        mp = rb.mass_properties
        rot = quat_to_matrix(_quat_wxyz(rb.rotation))
        frame = quat_to_matrix(_quat_wxyz(mp.principal_inertia_local_frame))
        moments = np.array(mp.principal_inertia.to_tuple(), dtype=float)
        axes = rot @ frame
        inertia = axes @ np.diag(moments) @ axes.T
        com = rb.center_of_mass.to_tuple()
        bodies[body.name] = body_readback(
            mp.mass, inertia, com, rb.linvel.to_tuple(), rb.angvel.to_tuple()
        )
        stored[body.name] = {
            "mass": float(mp.mass),
            "principal_moments": moments.tolist(),
            "principal_frame_wxyz": _quat_wxyz(mp.principal_inertia_local_frame).tolist(),
            "local_com": list(mp.local_com.to_tuple()),
        }
    return bodies, stored


def step_and_sample(world, handles, sampled: np.ndarray) -> list[list[tuple]]:
    """Step to each of the `sampled` step indices, recording every body's (COM, rotation
    (x, y, z, w), linvel, angvel) there as Rapier returns them (the timed loop)."""
    views = [world.rigid_bodies[h] for h in handles]  # live views into the set
    step = world.step
    raw = []
    done = 0
    for k in sampled:
        for _ in range(k - done):
            step()
        done = k
        raw.append(
            [
                (
                    v.center_of_mass.to_tuple(),
                    v.rotation.to_tuple(),
                    v.linvel.to_tuple(),
                    v.angvel.to_tuple(),
                )
                for v in views
            ]
        )
    return raw


def samples_from_raw(raw: list[list[tuple]], n_bodies: int) -> np.ndarray:
    """(S, B, 13) rows x, q (w, x, y, z), v, world omega. The body's rotation is the suite's
    orientation: the body frame is the world's at t = 0."""
    samples = np.array(
        [[[*x, q[3], q[0], q[1], q[2], *v, *w] for x, q, v, w in row] for row in raw],
        dtype=float,
    ).reshape(len(raw), n_bodies, 13)
    return samples


def parity_manifest(
    scene: Scene, integrator: str, dt: float, settings: RapierSettings, stored: dict
) -> dict:
    """The run's settings: every Rapier setting that affects the result."""
    if scene.has_contact:
        contact_settings = {
            "restitution": scene.contact.restitution,
            "friction": scene.contact.friction,
            "combine_rule": "MAX for friction and restitution on every collider: both sides "
            "hold the scene's value, so every pair gets exactly it (rounded to f32)",
            "colliders": "one ball per particle, density 0 (mass from the explicit properties)",
            "planes": f"{len(scene.planes)} fixed half-space(s)",
            "contact_skin": settings.contact_skin,
            "prediction_distance": settings.prediction_distance,
            "allowed_linear_error": settings.allowed_linear_error,
            "max_corrective_velocity": settings.max_corrective_velocity,
            "friction_model": settings.friction_model,
            "contact_softness": {
                "natural_frequency": settings.contact_natural_frequency,
                "damping_ratio": settings.contact_damping_ratio,
            },
            "static_contact_softness": {
                "natural_frequency": settings.static_contact_natural_frequency,
                "damping_ratio": settings.static_contact_damping_ratio,
            },
            "friction_in_bias_pass": False,
            "contact_recycling": settings.contact_recycling,
            "contact_clustering": True,
            "warmstart_coefficient": settings.warmstart_coefficient,
            "num_internal_pgs_iterations": settings.num_internal_pgs_iterations,
            "num_internal_stabilization_iterations": (
                settings.num_internal_stabilization_iterations
            ),
        }
    else:
        contact_settings = "none: no colliders, no planes"
    return {
        "precision": "float32 (rapier3d is built with f32 Real)",
        "time_stepping": TIME_STEPPING[integrator],
        "dt": dt,
        "num_solver_iterations": settings.num_solver_iterations,
        "substep": dt / settings.num_solver_iterations,
        "gyroscopic": settings.gyroscopic_forces,
        "allow_fast_rotation": settings.allow_fast_rotation,
        "max_linear_velocity": settings.max_linear_velocity,
        "gravity": list(scene.gravity),
        "linear_damping": 0.0,
        "angular_damping": 0.0,
        "sleeping": "enabled (Rapier's thresholds)"
        if settings.can_sleep
        else "disabled (can_sleep false)",
        "ccd": settings.ccd,
        "soft_ccd_prediction": settings.soft_ccd_prediction,
        "threads": 1,
        "contact": contact_settings,
        "mass_properties": stored,
    }


def run_rapier(
    scene: Scene,
    integrator: str,
    dt: float,
    duration: float,
    settings: RapierSettings = DEFAULT_SETTINGS,
) -> Trajectory:
    """Run `scene` in a fresh Rapier world; `integrator` is "tgs_soft"."""
    check_run_call("rapier", UNAVAILABLE, integrator, TIME_STEPPING)
    timer = RunTimer(scene, "rapier", integrator, dt, duration)
    sampled = sample_steps(timer.n_steps, timer.stride)
    with timer.setup():
        world, handles = build_world(scene, dt, settings)
        bodies, stored = read_back(scene, world, handles)
    with timer.stepping():
        raw = step_and_sample(world, handles, sampled)
    manifest = parity_manifest(scene, integrator, dt, settings, stored)
    meta = timer.meta(package_versions("rapier3d"), manifest, bodies)
    return timer.trajectory(sampled, samples_from_raw(raw, len(handles)), meta)


class RapierEngine:
    name = "rapier"
    integrators = ("tgs_soft",)
    default_integrator = "tgs_soft"
    orders = {"tgs_soft": 1}  # semi-implicit Euler substeps
    missing = UNAVAILABLE
    epsilon = FLOAT32_EPSILON

    def unsupported(self, scene: Scene) -> str | None:
        """Scenes whose numbers single precision cannot hold (`harness.outside_float32`)."""
        return outside_float32(scene)

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        return run_rapier(scene, integrator, dt, duration)
