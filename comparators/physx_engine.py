"""PhysX 5 (through SAPIEN) as an engine: one rigid dynamic per particle cluster, CPU system.

Each run builds a fresh `sapien.Scene` on a `PhysxCpuSystem` (without it SAPIEN asks for a render
device): per scene body a `PhysxRigidDynamicComponent` whose actor frame sits at the COM with
identity orientation, its collision shapes one sphere per particle (only when the scene has
contact), its mass, principal moments and principal frame (the cmass local pose) set explicitly
from the particles; static planes only with contact. PhysX computes in single precision
(`epsilon` = float32's). The two integrators are PhysX's solvers, "tgs" (SAPIEN's default) and
"pgs" (the PhysX SDK's), both semi-implicit Euler. PhysX's defaults that change results are
overridden and stated in the parity manifest: angular damping 0.05 -> 0, max angular velocity
100 rad/s -> 1e7, sleeping off, the bounce threshold 2 m/s -> 2 |g| dt. SAPIEN turns PhysX's
gyroscopic term on (eENABLE_GYROSCOPIC_FORCES, off in PhysX by default) and does not expose it:
an explicit step of Euler's equations whose angular momentum is rescaled to its magnitude before
the step, so |L| is kept and the energy is not.

The mapping and the measured effect of each default: docs/engines/physx.md.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np

from cases.scene import Scene
from comparators.harness import RunTimer, check_run_call, outside_float32, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from rigidmath.inertia import principal_frame
from rigidmath.quaternion import quat_from_matrix, quat_to_matrix

try:
    with warnings.catch_warnings():  # "Failed to find system libvulkan": irrelevant on CPU
        warnings.simplefilter("ignore")
        import sapien
        from sapien import physx
except ImportError as exc:  # the module always imports; the engine reports why it cannot run
    sapien = physx = None
    UNAVAILABLE: str | None = f"sapien cannot be imported ({exc}): pip install 'rigidbench[physx]'"
else:
    UNAVAILABLE = None

SOLVERS = {
    "tgs": "temporal Gauss-Seidel (enable_tgs, SAPIEN's default)",
    "pgs": "projected Gauss-Seidel (the PhysX SDK's default)",
}
EPSILON = float(np.finfo(np.float32).eps)


@dataclasses.dataclass(frozen=True)
class PhysxSettings:
    """Every PhysX parameter a run sets, explicitly, at its start (docs/engines/physx.md)."""

    linear_damping: float = 0.0  # PhysX default 0
    angular_damping: float = 0.0  # PhysX default 0.05
    max_angular_velocity: float = 1e7  # rad/s; PhysX default 100 (a clamp, not a damping)
    max_linear_velocity: float = 1e16  # m/s; PhysX default
    max_depenetration_velocity: float = 1e32  # m/s; PhysX default: unbounded
    sleep_threshold: float = 0.0  # PhysX default 0.005 (energy per unit mass): never sleeps
    solver_position_iterations: int = 10
    solver_velocity_iterations: int = 1
    contact_offset: float = 0.01  # m; PhysX default 0.02 x scale, SAPIEN's 0.01
    rest_offset: float = 0.0  # m: spheres touch at the particle radius
    bounce_steps: float = 2.0  # bounce threshold = bounce_steps * |g| * dt (PhysX's: 2 m/s)
    min_bounce_threshold: float = 1e-3  # m/s; PhysX wants a positive threshold
    enable_pcm: bool = True
    enable_ccd: bool = False
    enable_enhanced_determinism: bool = True
    enable_friction_every_iteration: bool = True

    def bounce_threshold(self, dt: float, gravity) -> float:
        g = math.sqrt(sum(c * c for c in gravity))
        return max(self.bounce_steps * g * dt, self.min_bounce_threshold)


DEFAULT_SETTINGS = PhysxSettings()


def _pose(p, q_wxyz=(1.0, 0.0, 0.0, 0.0)):
    return sapien.Pose(np.asarray(p, dtype=np.float32), np.asarray(q_wxyz, dtype=np.float32))


def _plane_rotation(normal: np.ndarray) -> np.ndarray:
    """A proper rotation whose first column is `normal`: PhysX planes are x = 0, normal +x."""
    n = normal / np.linalg.norm(normal)
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    return np.column_stack([n, u, np.cross(n, u)])


def _material(scene: Scene):
    """Every shape gets the scene's mu (static and dynamic) and e; PhysX combines the two
    shapes' values by their average (the default combine mode), so each pair gets exactly them."""
    mu, e = scene.contact.friction, scene.contact.restitution
    return physx.PhysxMaterial(mu, mu, e)


def _add_body(scene_, body, material, settings: PhysxSettings):
    moments, axes = principal_frame(body.inertia)
    rigid = physx.PhysxRigidDynamicComponent()
    if material is not None:
        for offset in body.positions - body.com:
            shape = physx.PhysxCollisionShapeSphere(body.particle_radius, material)
            shape.set_local_pose(_pose(offset))
            shape.set_contact_offset(settings.contact_offset)
            shape.set_rest_offset(settings.rest_offset)
            rigid.attach(shape)
    rigid.set_mass(body.mass)  # also turns SAPIEN's auto_compute_mass off
    rigid.set_inertia(np.asarray(moments, dtype=np.float32))
    rigid.set_cmass_local_pose(_pose((0.0, 0.0, 0.0), quat_from_matrix(axes)))
    rigid.set_linear_damping(settings.linear_damping)
    rigid.set_angular_damping(settings.angular_damping)
    rigid.set_max_angular_velocity(settings.max_angular_velocity)
    rigid.set_max_linear_velocity(settings.max_linear_velocity)
    rigid.set_max_depenetration_velocity(settings.max_depenetration_velocity)
    rigid.set_sleep_threshold(settings.sleep_threshold)
    rigid.set_solver_position_iterations(settings.solver_position_iterations)
    rigid.set_solver_velocity_iterations(settings.solver_velocity_iterations)
    entity = sapien.Entity()
    entity.set_name(body.name)
    entity.add_component(rigid)
    entity.set_pose(_pose(body.com))
    scene_.add_entity(entity)
    rigid.set_linear_velocity(np.asarray(body.velocity, dtype=np.float32))
    rigid.set_angular_velocity(np.asarray(body.angular_velocity, dtype=np.float32))
    rigid.wake_up()
    return rigid


def _add_plane(scene_, plane, material, settings: PhysxSettings) -> None:
    shape = physx.PhysxCollisionShapePlane(material)
    shape.set_contact_offset(settings.contact_offset)
    shape.set_rest_offset(settings.rest_offset)
    static = physx.PhysxRigidStaticComponent()
    static.attach(shape)
    entity = sapien.Entity()
    entity.add_component(static)
    entity.set_pose(_pose(plane.point, quat_from_matrix(_plane_rotation(plane.unit_normal))))
    scene_.add_entity(entity)


def build_world(scene: Scene, integrator: str, dt: float, settings: PhysxSettings):
    """A fresh CPU PhysX system with the process-global scene config set first (SAPIEN reads it
    when the system is made), the bodies (scene order) and, with contact, the planes."""
    physx.set_scene_config(
        gravity=np.asarray(scene.gravity, dtype=np.float32),
        bounce_threshold=settings.bounce_threshold(dt, scene.gravity),
        enable_pcm=settings.enable_pcm,
        enable_tgs=integrator == "tgs",
        enable_ccd=settings.enable_ccd,
        enable_enhanced_determinism=settings.enable_enhanced_determinism,
        enable_friction_every_iteration=settings.enable_friction_every_iteration,
        cpu_workers=0,
    )
    system = physx.PhysxCpuSystem()
    scene_ = sapien.Scene(systems=[system])
    system.set_timestep(dt)
    material = _material(scene) if scene.has_contact else None
    rigids = [_add_body(scene_, b, material, settings) for b in scene.bodies]
    if material is not None:
        for plane in scene.planes:
            _add_plane(scene_, plane, material, settings)
    return scene_, system, rigids


def read_back(scene: Scene, rigids) -> tuple[dict, dict]:
    """The model as PhysX holds it, before stepping: `RunMeta.bodies` entries and, for the
    settings, each body's principal moments and principal frame (w, x, y, z) as stored."""
    bodies, frames = {}, {}
    for body, rigid in zip(scene.bodies, rigids, strict=True):
        pose, cmass = rigid.entity_pose, rigid.cmass_local_pose
        actor = quat_to_matrix(np.asarray(pose.q, dtype=float))
        rot = actor @ quat_to_matrix(np.asarray(cmass.q, dtype=float))
        moments = np.asarray(rigid.inertia, dtype=float)
        x = np.asarray(pose.p, dtype=float) + actor @ np.asarray(cmass.p, dtype=float)
        bodies[body.name] = body_readback(
            rigid.mass,
            rot @ np.diag(moments) @ rot.T,
            x,
            np.asarray(rigid.linear_velocity, dtype=float),
            np.asarray(rigid.angular_velocity, dtype=float),
        )
        frames[body.name] = {
            "principal_moments": moments.tolist(),
            "principal_frame_wxyz": np.asarray(cmass.q, dtype=float).tolist(),
        }
    return bodies, frames


def body_settings(rigid) -> dict:
    """The per-body settings as PhysX reports them back (float32 rounded)."""
    return {
        "linear_damping": float(rigid.linear_damping),
        "angular_damping": float(rigid.angular_damping),
        "max_angular_velocity": float(rigid.max_angular_velocity),
        "max_linear_velocity": float(rigid.max_linear_velocity),
        "max_depenetration_velocity": float(rigid.max_depenetration_velocity),
        "sleep_threshold": float(rigid.sleep_threshold),
        "solver_position_iterations": int(rigid.solver_position_iterations),
        "solver_velocity_iterations": int(rigid.solver_velocity_iterations),
    }


def step_and_sample(system, rigids, sampled: np.ndarray) -> np.ndarray:
    """Step to each of the `sampled` step indices, recording x, q, v, world omega of every body
    (the timed loop: nothing else happens in it). The actor frame is the COM with the body's
    t = 0 orientation, so the pose is the suite's directly."""
    out = np.empty((len(sampled), len(rigids), 13))
    step = system.step
    done = 0
    for i, k in enumerate(sampled):
        for _ in range(k - done):
            step()
        done = k
        for j, rigid in enumerate(rigids):
            pose = rigid.entity_pose
            out[i, j, 0:3] = pose.p
            out[i, j, 3:7] = pose.q
            out[i, j, 7:10] = rigid.linear_velocity
            out[i, j, 10:13] = rigid.angular_velocity
    return out


def parity_manifest(
    scene: Scene, integrator: str, dt: float, settings: PhysxSettings, system, rigids, frames
) -> dict:
    """The run's settings: every PhysX setting that affects the result, read back where PhysX
    reports it."""
    config = system.config
    if scene.has_contact:
        e, mu = scene.contact.restitution, scene.contact.friction
        contact = {
            "restitution": e,
            "friction": mu,
            "static_friction": mu,
            "dynamic_friction": mu,
            "combination": "average of the two shapes' values (PhysX default combine mode); "
            "every shape gets the scene's e and mu, so every pair gets exactly them",
            "contact_offset": settings.contact_offset,
            "rest_offset": settings.rest_offset,
            "bounce_threshold": float(config.bounce_threshold),
            "bounce_rule": f"{settings.bounce_steps} |g| dt, at least "
            f"{settings.min_bounce_threshold} m/s (PhysX default 2 m/s)",
            "pcm": bool(config.enable_pcm),
            "ccd": bool(config.enable_ccd),
            "friction_every_iteration": bool(config.enable_friction_every_iteration),
            "planes": len(scene.planes),
        }
    else:
        contact = "none: no collision shapes, no planes"
    per_body = {r.entity.name: body_settings(r) for r in rigids}
    return {
        "solver": SOLVERS[integrator],
        "time_stepping": "semi-implicit Euler; orientation by the exponential map of omega dt",
        "precision": "float32",
        "epsilon": EPSILON,
        "dt": dt,
        "gyroscopic": "explicit, |L| rescaled to its value before the step: "
        "eENABLE_GYROSCOPIC_FORCES, on in every SAPIEN 3.0.3 body (off in PhysX by default)",
        "gravity": [float(g) for g in config.gravity],
        "enhanced_determinism": bool(config.enable_enhanced_determinism),
        "cpu_workers": 0,
        "sleeping": f"off (sleep threshold {settings.sleep_threshold}, woken at the start)",
        **{k: v for k, v in dataclasses.asdict(settings).items() if k in _BODY_FIELDS},
        "bodies": per_body,
        "contact": contact,
        "inertia": frames,
    }


_BODY_FIELDS = (
    "linear_damping",
    "angular_damping",
    "max_angular_velocity",
    "max_linear_velocity",
    "max_depenetration_velocity",
    "sleep_threshold",
    "solver_position_iterations",
    "solver_velocity_iterations",
)


def run_physx(
    scene: Scene,
    integrator: str,
    dt: float,
    duration: float,
    settings: PhysxSettings = DEFAULT_SETTINGS,
) -> Trajectory:
    """Run `scene` in a fresh CPU PhysX system; `integrator` is "tgs" or "pgs"."""
    check_run_call("physx", UNAVAILABLE, integrator, SOLVERS)
    timer = RunTimer(scene, "physx", integrator, dt, duration)
    sampled = sample_steps(timer.n_steps, timer.stride)
    with timer.setup():
        scene_, system, rigids = build_world(scene, integrator, dt, settings)
        bodies, frames = read_back(scene, rigids)
    with timer.stepping():
        samples = step_and_sample(system, rigids, sampled)
    manifest = parity_manifest(scene, integrator, dt, settings, system, rigids, frames)
    meta = timer.meta(package_versions("sapien"), manifest, bodies)
    return timer.trajectory(sampled, samples, meta)


def unsupported_reason(scene: Scene) -> str | None:
    """PhysX computes in float32 (`outside_float32`), and reads a zero principal moment as
    infinite inertia (that axis locked)."""
    beyond = outside_float32(scene)
    if beyond:
        return beyond
    for body in scene.bodies:
        moments = principal_frame(body.inertia)[0]
        if moments.min() <= EPSILON * moments.max():
            return (
                f"body {body.name!r} has a zero principal moment of inertia, which PhysX "
                "takes as infinite (rotation about that axis locked)"
            )
    return None


class PhysxEngine:
    name = "physx"
    integrators = ("tgs", "pgs")
    default_integrator = "tgs"
    orders = {"tgs": 1, "pgs": 1}  # semi-implicit Euler, explicit gyroscopic term
    missing = UNAVAILABLE
    epsilon = EPSILON

    def unsupported(self, scene: Scene) -> str | None:
        return unsupported_reason(scene)

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        return run_physx(scene, integrator, dt, duration)
