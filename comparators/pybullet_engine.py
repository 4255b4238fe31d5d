"""PyBullet as an engine: one rigid body per particle cluster, stepped in DIRECT mode.

Model (built from the scene alone, in a fresh DIRECT client per run, always disconnected):

* body: a compound of one GEOM_SPHERE per particle at its offset from the COM; the base frame
  sits at the COM with identity orientation, and the inertial frame is rotated onto the principal
  axes: I0 = P diag(d) P^T with P a proper rotation, baseInertialFrameOrientation = quat(P)
  (PyBullet quaternions are (x, y, z, w)). Mass and localInertiaDiagonal = d are set in ONE
  changeDynamics call: a later call with `mass` alone replaces the inertia by Bullet's
  bounding-box estimate of the compound (checked: (11.5, 9.0, 5.1) instead of (26, 20, 10)
  kg m^2 for tumbling_box). Linear and angular damping are set to 0 in the same call (defaults:
  0.04 on multibodies, checked: a free sphere kept 0.924 of v and omega after 1 s; 0 on maximal
  bodies), and sleeping is disabled. getDynamicsInfo does not report damping; the tests show it
  is off by constant velocities in free flight.
* planes (only when `scene.has_contact`): static GEOM_PLANE with planeNormal, mass 0.
  Without contact: no planes, and every body gets collision group and mask 0, so nothing
  collides (particles of one body never do: a compound is never tested against itself).
* gravity: setGravity(scene.gravity), so zero gravity is (0, 0, 0).

Integrators ("body types"; Bullet has one time stepper, semi-implicit Euler: velocities from
forces and contact impulses first, then positions with the new velocities; the orientation is
advanced by the exact exponential map of omega dt in both):

* "maximal" (default): a btRigidBody (useMaximalCoordinates=True). Its gyroscopic term is
  Bullet's default flag BT_ENABLE_GYROSCOPIC_FORCE_IMPLICIT_BODY: one Newton step of an implicit
  Euler update of omega in body axes; it loses energy (tumbling_box: -5.0 % at dt 0.01,
  -0.52 % at dt 0.001 over 10 s, |L| -2.5 % / -0.26 %).
* "multibody": a btMultiBody with a floating base and no links (Featherstone). Its gyroscopic
  term is explicit (omega x I omega added to the base bias force, m_useGyroTerm, on by default);
  it gains energy (tumbling_box: +5.4 % / +0.52 %, |L| +2.7 % / +0.26 %).
  The multibody constraint solver has no split impulse: penetration is removed by velocity
  (Baumgarte, contactERP), which adds energy at every impact, see the rebound table.
Neither gyroscopic term can be switched off: no changeDynamics or createMultiBody option
exposes it. Both make the intermediate-axis
flip of tumbling_box happen at the exact times (2.6 s and 9.4 s, at the 0.1 s sampling).
The default is "maximal": identical in free flight to the accuracy that matters, and only its
contacts reproduce the scene's restitution.

Free flight against cases.exact (orientation error, max over the run):

  case            dt     multibody   maximal
  free_spin_cube  0.01   3e-15 rad   9e-14 rad
  free_spin_cube  0.001  1e-14 rad   4e-13 rad
  tumbling_box    0.01   19.9 deg    19.4 deg    (first order in dt)
  tumbling_box    0.001  1.97 deg    1.96 deg

State read back: getBasePositionAndOrientation/getBaseVelocity refer to the inertial frame:
position = COM (checked), orientation = that of the principal frame, q_in(t) = q(t) quat(P)
(checked at t = 0: it returns quat(P), not identity). The suite's orientation is therefore
q(t) = q_in(t) q_in(0)^-1, the identity at t = 0 up to the product's rounding (~1e-17).
Velocities are the COM velocity and the world angular velocity. The model recorded for the
parity check is read back from PyBullet before stepping: mass and principal moments from
getDynamicsInfo, the principal frame from the inertial-frame orientation at t = 0
(getDynamicsInfo reports the local inertial orientation for multibodies but (0, 0, 0, 0) for
maximal bodies), I = R_in diag(d) R_in^T, and x, v, omega from the getters.

Stepping (timed as wall_s): one stepSimulation per step and, per sample and body,
getBasePositionAndOrientation and getBaseVelocity, the least that returns x, q, v and omega
(PyBullet has no batched getter for bases: getLinkStates covers links only). Both pass the
client id by position: as a keyword it costs about 1 us more per call, 10 to 15 % of a free
body's stepping. The samples are converted after the timed loop.

Contact mapping (only when the scene has contact). Bullet combines the two objects'
coefficients by product (btManifoldResult::calculateCombinedRestitution = r0 r1;
calculateCombinedFriction = f0 f1, clamped to 10). Every body AND every plane gets sqrt(e) and
sqrt(mu), so body-plane and body-body pairs both get e and mu. Rolling and spinning friction 0.
Solver and contact settings are set explicitly every run (`PybulletSettings`, recorded in the
run's settings):

* contactBreakingThreshold 0.001 m. It is also the speculative margin of plane contacts: a
  contact found while still apart targets the normal speed e v - gap / dt, which eats the bounce
  (Bullet's default 0.02 m gave rebound 0.33 to 0.5 for e = 1 at dt 0.01 and below 0.01
  at dt 0.001). With 1 mm
  contacts are found on overlap, as in the reference simulator, and the bounce uses the true
  approach speed. Sphere-sphere contacts are only generated on overlap whatever the threshold.
* split impulse on for every penetrating contact (splitImpulsePenetrationThreshold 0; Bullet's
  -0.04 corrects penetrations shallower than 4 cm by Baumgarte velocity, which added +0.2 to the
  head-on rebound at dt 0.001). Penetration is removed by a position-only pseudo-velocity at
  contactERP 0.2 per step: energy-neutral for maximal bodies (0.05 to 0.8 gave the same rebounds,
  0.2 to 1 the same rest heights).
* restitutionVelocityThreshold = 2 |g| dt, the reference simulator's rule: an approach slower than
  two steps of gravity is a resting contact, not a bounce (0 without gravity).
* numSolverIterations 50, solverResidualThreshold 1e-9, warmStartingFactor 0.85, globalCFM 0,
  contactSlop 0, erp 0.2, frictionERP 0.2, enableConeFriction 1 (multibody: isotropic Coulomb
  disc; without it a diagonal slide decelerated at sqrt(2) mu g; maximal bodies align the first
  friction direction with the sliding velocity and decelerate at mu g either way).

Measured rebound ratio (separating / approaching normal speed) for the seed cube landing flat on
a floor (no gravity, 3 m/s; with gravity, dropped 0.8 m) and for the head-on impact of two cubes
(tests/test_contact.py's scene, 1 m/s each, the ratio of final to initial speeds):

  e                        0      0.5    1
  maximal    dt 0.01       0      0.500  1.000   (all three scenes)
  maximal    dt 0.001      0      0.500  1.000   (all three scenes)
  multibody  dt 0.01       0.067  0.567  1.067   floor, no gravity
                           0.100  0.612  1.125   floor, gravity
                           0      0.500  1.000   head-on
  multibody  dt 0.001      0.067  0.567  1.067   floor, no gravity
                           0.100  0.601  1.102   floor, gravity
                           0.200  0.700  1.200   head-on

The multibody excess is Baumgarte's erp * penetration / dt and grows with contactERP (0.8 gave
+0.27 to +0.8). dropped_cube (e = 0, mu = 0.5) rests on a face at COM height 0.700000 m (within
1e-6) at dt 0.01 and 0.001 with either body type; sliding friction decelerates at mu g.

Process-global state (checked in this PyBullet): contactBreakingThreshold is Bullet's global
gContactBreakingThreshold; it survives disconnect and applies to every client in the process
(a threshold set in one client made a sphere 0.1 m above a plane report a contact in the next
fresh client). jointFeedbackMode is global too. Every run sets both, so no run leaks into the
next; runs in concurrent threads would still share them. Per-world parameters start from
Bullet's defaults in each new client (checked: numSolverIterations does not leak), and are set
explicitly anyway.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import os
import sys
import time
from contextlib import contextmanager

import numpy as np

from cases.scene import Scene
from comparators.engine import register, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import RunMeta, Trajectory, package_versions
from reference_sim.inertia import principal_frame
from reference_sim.quaternion import quat_from_matrix, quat_to_matrix, quats_multiply


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
    MISSING: str | None = f"pybullet cannot be imported: {exc}"
else:
    MISSING = None

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
    """Every world parameter a run sets, explicitly, at its start (see the module docstring)."""

    contact_breaking_threshold: float = 0.001  # m; process-global in Bullet
    num_solver_iterations: int = 50
    solver_residual_threshold: float = 1e-9
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

    def engine_parameters(self, dt: float, gravity) -> dict:
        """Keyword arguments of setPhysicsEngineParameter for a run with step dt."""
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
            "contactBreakingThreshold": self.contact_breaking_threshold,
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


def run_pybullet(
    scene: Scene,
    integrator: str,
    dt: float,
    duration: float,
    settings: PybulletSettings = DEFAULT_SETTINGS,
) -> Trajectory:
    """Run `scene` in a fresh DIRECT client; `integrator` is "maximal" or "multibody"."""
    if p is None:
        raise RuntimeError(f"engine 'pybullet' is unavailable: {MISSING}")
    if integrator not in BODY_TYPES:
        raise ValueError(f"unknown integrator {integrator!r}: expected one of {tuple(BODY_TYPES)}")
    maximal = integrator == "maximal"
    contact = scene.has_contact
    e = scene.contact.restitution if contact else 0.0
    mu = scene.contact.friction if contact else 0.0
    params = settings.engine_parameters(dt, scene.gravity)
    n_steps = scene.steps(dt, duration)
    sampled = sample_steps(n_steps, scene.sample_stride(dt))

    start = time.perf_counter()
    cid = connect()
    try:
        p.setPhysicsEngineParameter(physicsClientId=cid, **params)
        p.setGravity(*scene.gravity, physicsClientId=cid)
        ids = [_add_body(b, maximal, contact, e, mu, cid) for b in scene.bodies]
        if contact:
            for plane in scene.planes:
                _add_plane(plane, maximal, e, mu, cid)
        readback, inertia_frames, q0 = {}, {}, []
        for body, uid in zip(scene.bodies, ids, strict=True):
            info = p.getDynamicsInfo(uid, -1, physicsClientId=cid)
            x, q_xyzw = p.getBasePositionAndOrientation(uid, physicsClientId=cid)
            v, w = p.getBaseVelocity(uid, physicsClientId=cid)
            q_in = np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]])
            rot = quat_to_matrix(q_in)
            inertia = rot @ np.diag(info[2]) @ rot.T
            readback[body.name] = body_readback(info[0], inertia, x, v, w)
            inertia_frames[body.name] = {
                "principal_moments": list(info[2]),
                "principal_frame_wxyz": q_in.tolist(),
            }
            q0.append(q_in)
        get_pose, get_velocity, step = (
            p.getBasePositionAndOrientation,
            p.getBaseVelocity,
            p.stepSimulation,
        )
        raw = []
        setup_s = time.perf_counter() - start
        start = time.perf_counter()
        done = 0
        # client id by position: as a keyword it costs ~1 us per call (module docstring)
        for k in sampled:
            for _ in range(k - done):
                step(cid)
            done = k
            raw.append([(get_pose(u, cid), get_velocity(u, cid)) for u in ids])
        wall_s = time.perf_counter() - start
    finally:
        p.disconnect(cid)

    samples = np.array(
        [[[*x, q[3], q[0], q[1], q[2], *v, *w] for (x, q), (v, w) in row] for row in raw],
        dtype=float,
    ).reshape(len(raw), len(ids), 13)
    conj0 = np.array(q0) * np.array([1.0, -1.0, -1.0, -1.0])
    samples[:, :, 3:7] = quats_multiply(samples[:, :, 3:7], conj0[None, :, :])

    contact_settings = (
        {
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
        if contact
        else "none: no planes, collision group and mask 0 on every body"
    )
    meta = RunMeta(
        case=scene.name,
        engine="pybullet",
        integrator=integrator,
        dt=dt,
        steps=n_steps,
        duration=n_steps * dt,
        setup_s=setup_s,
        wall_s=wall_s,
        versions=package_versions("pybullet"),
        settings={
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
        },
        bodies=readback,
    )
    times = sampled * dt
    return Trajectory.from_samples(times, [b.name for b in scene.bodies], samples, meta)


class PybulletEngine:
    name = "pybullet"
    integrators = ("maximal", "multibody")
    default_integrator = "maximal"
    orders = {"maximal": 1, "multibody": 1}  # semi-implicit Euler, first-order gyroscopic terms
    missing = MISSING

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        return run_pybullet(scene, integrator, dt, duration)


register(PybulletEngine())
