"""PyBullet as an engine: one rigid body per particle cluster, stepped in DIRECT mode.

Each run builds its world in a fresh DIRECT client, always disconnected: per scene body a
compound of sphere shapes with its base at the COM and its inertial frame on the principal axes
(mass and inertia set in one `changeDynamics` call, damping 0, sleeping off); planes only when
the scene has contact. The two integrators are Bullet's body types, "maximal" (btRigidBody) and
"multibody" (Featherstone), both semi-implicit Euler. Bullet multiplies the two touching
objects' restitution and friction, so every body and plane gets sqrt(e) and sqrt(mu). Every
solver setting is set explicitly per run (`PybulletSettings`), the process-global ones
(contactBreakingThreshold, jointFeedbackMode) included.

The mapping, its measured rebounds, the read-back frames and the process-global settings:
docs/engines/pybullet.md.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import os
import sys
from contextlib import contextmanager

import numpy as np

from cases.scene import Scene
from comparators.harness import RunTimer, check_run_call, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from rigidmath.inertia import principal_frame
from rigidmath.quaternion import quat_from_matrix, quat_to_matrix, quats_multiply


@contextmanager
def _stderr_silenced():
    """Send file descriptor 2 to /dev/null for the block: `import pybullet` writes its build
    time there, which would land in every rigidbench command's output."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            try:
                yield
            finally:
                ctypes.CDLL(None).fflush(None)  # anything waiting in C's stdio buffers
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def connect() -> int:
    """A new DIRECT client."""
    cid = p.connect(p.DIRECT)
    if cid < 0:
        raise RuntimeError("pybullet: p.connect(p.DIRECT) failed")
    return cid


try:
    with _stderr_silenced():
        import pybullet as p
except ImportError as exc:  # the module always imports; the engine reports why it cannot run
    p = None
    UNAVAILABLE: str | None = f"pybullet cannot be imported: {exc}"
else:
    UNAVAILABLE = None

BODY_TYPES = {
    "maximal": "btRigidBody (useMaximalCoordinates)",
    "multibody": "btMultiBody, floating base, no links (Featherstone)",
}
GYROSCOPIC = {
    "maximal": "implicit, body frame (BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY, Bullet default)",
    "multibody": "explicit omega x I omega in the base bias force (m_useGyroTerm, default on)",
}
CONTACT_SOLVER = {
    "maximal": "sequential impulses (PGS); penetration by split impulse (position only)",
    "multibody": "multibody PGS; penetration by Baumgarte velocity (no split impulse)",
}


@dataclasses.dataclass(frozen=True)
class PybulletSettings:
    """Every world parameter a run sets, explicitly, at its start (docs/engines/pybullet.md)."""

    # contactBreakingThreshold (process-global in Bullet) is also its speculative margin: a
    # contact found while the bodies are still up to that far apart aims its normal speed at
    # e v - gap / dt, so a bounce found early loses up to threshold / dt. `maximal` gets
    # speculative_speed * dt: at most 1 cm/s off any rebound, at any dt (1 mm ate every other
    # bounce at dt 0.001). `multibody` keeps 1 mm: its Baumgarte velocity bounces contacts found
    # only on overlap (e = 0.8 never rests at 1e-4 m). docs/engines/pybullet.md.
    speculative_speed: float = 0.01  # m/s
    multibody_breaking_threshold: float = 0.001  # m
    num_solver_iterations: int = 50
    # 0, Bullet's default: every iteration runs. The early exit's residual leaves out the
    # friction rows a step skips (their contact carries no load), so stopping early can leave a
    # friction impulse on an unloaded contact: at 1e-9 the `slide` cube stopped 1.5 % short.
    solver_residual_threshold: float = 0.0
    use_split_impulse: int = 1
    split_impulse_penetration_threshold: float = 0.0  # m; split impulse for every penetration
    erp: float = 0.2
    contact_erp: float = 0.2
    friction_erp: float = 0.2
    contact_slop: float = 0.0
    global_cfm: float = 0.0
    warm_starting_factor: float = 0.85
    enable_cone_friction: int = 1
    bounce_steps: float = 2.0  # restitutionVelocityThreshold = bounce_steps * |g| * dt

    def breaking_threshold(self, integrator: str, dt: float) -> float:
        """contactBreakingThreshold (m) of a run of `integrator` with step dt."""
        if integrator == "multibody":
            return self.multibody_breaking_threshold
        return self.speculative_speed * dt

    def engine_parameters(self, integrator: str, dt: float, gravity) -> dict:
        """Keyword arguments of setPhysicsEngineParameter for a run of `integrator` with step
        dt."""
        g = math.sqrt(sum(c * c for c in gravity))
        return {
            "fixedTimeStep": dt,
            "numSubSteps": 0,
            "numSolverIterations": self.num_solver_iterations,
            "solverResidualThreshold": self.solver_residual_threshold,
            "useSplitImpulse": self.use_split_impulse,
            "splitImpulsePenetrationThreshold": self.split_impulse_penetration_threshold,
            "erp": self.erp,
            "contactERP": self.contact_erp,
            "frictionERP": self.friction_erp,
            "contactSlop": self.contact_slop,
            "globalCFM": self.global_cfm,
            "warmStartingFactor": self.warm_starting_factor,
            "enableConeFriction": self.enable_cone_friction,
            "restitutionVelocityThreshold": self.bounce_steps * g * dt,
            "contactBreakingThreshold": self.breaking_threshold(integrator, dt),
            "jointFeedbackMode": 0,  # process-global; no joints here, set to its default
            "deterministicOverlappingPairs": 1,
            "enableSAT": 0,
            "collisionFilterMode": 1,  # collide when (groupA & maskB) or (groupB & maskA)
            "allowedCcdPenetration": 0.04,  # CCD is off (no ccdSweptSphereRadius): unused
            "numNonContactInnerIterations": 1,
            "minimumSolverIslandSize": 1024,
        }


DEFAULT_SETTINGS = PybulletSettings()


def _to_xyzw(q) -> list[float]:
    return [float(q[1]), float(q[2]), float(q[3]), float(q[0])]


def _add_body(body, maximal: bool, contact: bool, e: float, mu: float, cid: int) -> int:
    offsets = body.positions - body.com
    moments, axes = principal_frame(body.inertia)
    shape = p.createCollisionShapeArray(
        [p.GEOM_SPHERE] * len(offsets),
        radii=[body.particle_radius] * len(offsets),
        collisionFramePositions=offsets.tolist(),
        physicsClientId=cid,
    )
    uid = p.createMultiBody(
        baseMass=body.mass,
        baseCollisionShapeIndex=shape,
        basePosition=body.com.tolist(),
        baseOrientation=[0.0, 0.0, 0.0, 1.0],
        baseInertialFramePosition=[0.0, 0.0, 0.0],
        baseInertialFrameOrientation=_to_xyzw(quat_from_matrix(axes)),
        useMaximalCoordinates=maximal,
        physicsClientId=cid,
    )
    # One call: mass alone would reset the inertia to the bounding-box estimate.
    p.changeDynamics(
        uid,
        -1,
        mass=body.mass,
        localInertiaDiagonal=moments.tolist(),
        linearDamping=0.0,
        angularDamping=0.0,
        restitution=math.sqrt(e),
        lateralFriction=math.sqrt(mu),
        rollingFriction=0.0,
        spinningFriction=0.0,
        activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING,
        physicsClientId=cid,
    )
    if not contact:
        p.setCollisionFilterGroupMask(uid, -1, 0, 0, physicsClientId=cid)
    p.resetBaseVelocity(uid, list(body.velocity), list(body.angular_velocity), physicsClientId=cid)
    return uid


def _add_plane(plane, maximal: bool, e: float, mu: float, cid: int) -> int:
    shape = p.createCollisionShape(
        p.GEOM_PLANE, planeNormal=plane.unit_normal.tolist(), physicsClientId=cid
    )
    uid = p.createMultiBody(
        baseMass=0.0,
        baseCollisionShapeIndex=shape,
        basePosition=list(plane.point),
        useMaximalCoordinates=maximal,
        physicsClientId=cid,
    )
    p.changeDynamics(
        uid,
        -1,
        restitution=math.sqrt(e),
        lateralFriction=math.sqrt(mu),
        rollingFriction=0.0,
        spinningFriction=0.0,
        physicsClientId=cid,
    )
    return uid


def build_world(scene: Scene, integrator: str, params: dict, cid: int) -> list[int]:
    """Set the world parameters and gravity, then add the bodies (their ids, scene order) and,
    with contact, the planes."""
    maximal = integrator == "maximal"
    contact = scene.has_contact
    e = scene.contact.restitution if contact else 0.0
    mu = scene.contact.friction if contact else 0.0
    p.setPhysicsEngineParameter(physicsClientId=cid, **params)
    p.setGravity(*scene.gravity, physicsClientId=cid)
    ids = [_add_body(b, maximal, contact, e, mu, cid) for b in scene.bodies]
    if contact:
        for plane in scene.planes:
            _add_plane(plane, maximal, e, mu, cid)
    return ids


def read_back(scene: Scene, ids: list[int], cid: int) -> tuple[dict, dict, list[np.ndarray]]:
    """The model as PyBullet holds it, before stepping: per body `RunMeta.bodies` entries, the
    inertial frames (principal moments, principal frame (w, x, y, z)) for the settings, and the
    inertial-frame orientations q_in(0) that map PyBullet's orientations to the suite's."""
    bodies, inertia_frames, q0 = {}, {}, []
    for body, uid in zip(scene.bodies, ids, strict=True):
        info = p.getDynamicsInfo(uid, -1, physicsClientId=cid)
        x, q_xyzw = p.getBasePositionAndOrientation(uid, physicsClientId=cid)
        v, w = p.getBaseVelocity(uid, physicsClientId=cid)
        q_in = np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]])
        rot = quat_to_matrix(q_in)
        inertia = rot @ np.diag(info[2]) @ rot.T
        bodies[body.name] = body_readback(info[0], inertia, x, v, w)
        inertia_frames[body.name] = {
            "principal_moments": list(info[2]),
            "principal_frame_wxyz": q_in.tolist(),
        }
        q0.append(q_in)
    return bodies, inertia_frames, q0


def step_and_sample(cid: int, ids: list[int], sampled: np.ndarray) -> list[list[tuple]]:
    """Step to each of the `sampled` step indices, recording (pose, velocity) of every body there,
    as PyBullet returns them (the timed loop: nothing else happens in it)."""
    get_pose, get_velocity, step = (
        p.getBasePositionAndOrientation,
        p.getBaseVelocity,
        p.stepSimulation,
    )
    raw = []
    done = 0
    # client id by position: as a keyword it costs ~1 us per call (docs/engines/pybullet.md)
    for k in sampled:
        for _ in range(k - done):
            step(cid)
        done = k
        raw.append([(get_pose(u, cid), get_velocity(u, cid)) for u in ids])
    return raw


def samples_from_raw(raw: list[list[tuple]], q0: list[np.ndarray]) -> np.ndarray:
    """(S, B, 13) rows x, q, v, world omega from `step_and_sample`'s records; q is the suite's
    orientation q_in(t) q_in(0)^-1 (identity at t = 0)."""
    samples = np.array(
        [[[*x, q[3], q[0], q[1], q[2], *v, *w] for (x, q), (v, w) in row] for row in raw],
        dtype=float,
    ).reshape(len(raw), len(q0), 13)
    conj0 = np.array(q0) * np.array([1.0, -1.0, -1.0, -1.0])
    samples[:, :, 3:7] = quats_multiply(samples[:, :, 3:7], conj0[None, :, :])
    return samples


def parity_manifest(scene: Scene, integrator: str, params: dict, inertia_frames: dict) -> dict:
    """The run's settings: every PyBullet setting that affects the result."""
    if scene.has_contact:
        e, mu = scene.contact.restitution, scene.contact.friction
        contact_settings = {
            "restitution": e,
            "friction": mu,
            "restitution_per_object": math.sqrt(e),
            "friction_per_object": math.sqrt(mu),
            "combination": "product of the two objects' values (friction clamped to 10): "
            "every body and plane gets sqrt(e) and sqrt(mu)",
            "rolling_friction": 0.0,
            "spinning_friction": 0.0,
            "planes": len(scene.planes),
            "solver": CONTACT_SOLVER[integrator],
        }
    else:
        contact_settings = "none: no planes, collision group and mask 0 on every body"
    return {
        "body_type": BODY_TYPES[integrator],
        "time_stepping": "semi-implicit Euler; orientation by exp(omega dt)",
        "gyroscopic": GYROSCOPIC[integrator],
        "gravity": list(scene.gravity),
        "engine_parameters": params,
        "linear_damping": 0.0,
        "angular_damping": 0.0,
        "sleeping": "disabled",
        "contact": contact_settings,
        "inertia": inertia_frames,
    }


def run_pybullet(
    scene: Scene,
    integrator: str,
    dt: float,
    duration: float,
    settings: PybulletSettings = DEFAULT_SETTINGS,
) -> Trajectory:
    """Run `scene` in a fresh DIRECT client; `integrator` is "maximal" or "multibody"."""
    check_run_call("pybullet", UNAVAILABLE, integrator, BODY_TYPES)
    params = settings.engine_parameters(integrator, dt, scene.gravity)
    timer = RunTimer(scene, "pybullet", integrator, dt, duration)
    sampled = sample_steps(timer.n_steps, timer.stride)
    with timer.setup():
        cid = connect()
    try:
        with timer.setup():
            ids = build_world(scene, integrator, params, cid)
            bodies, inertia_frames, q0 = read_back(scene, ids, cid)
        with timer.stepping():
            raw = step_and_sample(cid, ids, sampled)
    finally:
        p.disconnect(cid)
    manifest = parity_manifest(scene, integrator, params, inertia_frames)
    meta = timer.meta(package_versions("pybullet"), manifest, bodies)
    return timer.trajectory(sampled, samples_from_raw(raw, q0), meta)


class PybulletEngine:
    name = "pybullet"
    integrators = ("maximal", "multibody")
    default_integrator = "maximal"
    orders = {"maximal": 1, "multibody": 1}  # semi-implicit Euler, first-order gyroscopic terms
    missing = UNAVAILABLE

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        return run_pybullet(scene, integrator, dt, duration)
