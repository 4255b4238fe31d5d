"""DART (dartpy) as an engine: one FreeJoint skeleton per scene body, one sphere per particle.

Each body node's frame sits at its COM with identity orientation at t = 0, so DART's world
rotation of the node is the suite's orientation directly; mass and the particle tensor are set
with `setMass` and `setMomentOfInertia` (shapes add none). Spheres and planes get collision and
dynamics aspects only when the scene has contact; gravity is the scene's; joint damping is 0 and
DART's sleeping (world deactivation, on by default) is off. DART steps semi-implicit Euler; the
"integrator" is the contact solver: "dantzig" (DART's default boxed LCP, with its PGS fallback)
or "pgs" (projected Gauss-Seidel, with a second PGS as fallback, as DART's own constructor sets
it up: without one DART zeroes the impulses of every failed solve). DART multiplies the two
shapes' restitution and takes the smaller friction, so every shape gets sqrt(e) and mu. A
divergence ends the samples in NaN.

The model, the contact mapping and its measured rebounds, sleeping and the traps:
docs/engines/dart.md.
"""

from __future__ import annotations

import ctypes
import math
import os
import sys
import tempfile
from contextlib import contextmanager

import numpy as np

from cases.scene import Scene
from comparators.harness import RunTimer, check_run_call, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from rigidmath.quaternion import quats_from_rotvecs

try:
    import dartpy as dart

    UNAVAILABLE: str | None = None
except ImportError as exc:  # the module always imports; the engine says why it cannot run
    dart = None
    UNAVAILABLE = f"dartpy cannot be imported ({exc}): pip install 'rigidbench[dart]'"

# Contact solver per "integrator": (primary boxed LCP solver, fallback run when the primary
# fails). "pgs" is what DART's own BoxedLcpConstraintSolver(pgs) constructor sets up: a second
# PGS as fallback, whose result DART uses whenever it is finite. Without a fallback DART zeroes
# every contact impulse of a step whose solve failed (docs/engines/dart.md).
SOLVERS = {
    "dantzig": ("DantzigBoxedLcpSolver", "PgsBoxedLcpSolver"),
    "pgs": ("PgsBoxedLcpSolver", "PgsBoxedLcpSolver"),
}
# Semi-implicit Euler whatever the contact solver: first order in dt.
ORDERS = {"dantzig": 1, "pgs": 1}
# FCL: plane shapes become FCL half-spaces, spheres are exact primitives (docs/engines/dart.md).
COLLISION_DETECTOR = "FCL"
# PGS options, set explicitly (DART's defaults): iterations, |dx| tolerance, relative |dx|
# tolerance, division epsilon, constraint order not randomised (deterministic runs).
PGS_OPTIONS = (30, 1e-6, 1e-3, 1e-9, False)
# What DART's ContactConstraint hard-codes (not exposed in dartpy 6.20), for the manifest.
CONTACT_CONSTANTS = {
    "error_reduction_parameter": 0.01,
    "max_error_reduction_velocity": 1e-3,  # m/s
    "error_allowance": 0.0,  # m
    "constraint_force_mixing": 1e-5,  # relative, on the LCP diagonal
    "restitution_threshold": 1e-3,  # combined e below this: no bounce at all
    "bouncing_velocity_threshold": 0.1,  # m/s: e v_in below this gets no bounce
    "max_bouncing_velocity": 100.0,  # m/s
    "friction_model": "pyramid: two tangent directions, each |f| <= mu f_n",
}
# Values past this (|x|, |v|, |omega|) count as diverged, like MuJoCo's mjMAXVAL.
MAX_VALUE = 1e10


# DART's messages when a step's contact solve failed for good (the primary without a fallback, or
# a fallback whose result has NaN): all contact impulses of that step are set to zero.
LCP_FAILURE = "zero for safety"


@contextmanager
def _stderr_captured(lines: list[str]):
    """File descriptor 2 into a temporary file for the block; its lines are appended to `lines`.
    DART reports failed contact solves there (C++ streams), which `run_dart` counts."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield
        finally:
            ctypes.CDLL(None).fflush(None)  # anything waiting in C's stdio buffers
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            lines.extend(capture.read().decode(errors="replace").splitlines())


def _solver_report(lines: list[str]) -> dict[str, float]:
    """`RunMeta.solver`: contact solves DART gave up on, zeroing their impulses (`at_limit`);
    every other line DART wrote goes on to stderr, unhidden."""
    failed = sum(LCP_FAILURE in line for line in lines)
    others = [line for line in lines if LCP_FAILURE not in line]
    if others:
        print("\n".join(others), file=sys.stderr)
    return {"at_limit": failed}


def _world_frame():
    return dart.dynamics.Frame.World()


def _new_pgs():
    """A PgsBoxedLcpSolver with `PGS_OPTIONS`: dartpy binds no constructor for the boxed LCP
    solvers, so it is the fallback instance a new world holds."""
    pgs = dart.simulation.World().getConstraintSolver().getSecondaryBoxedLcpSolver()
    pgs.setOption(dart.constraint.PgsBoxedLcpSolverOption(*PGS_OPTIONS))
    return pgs


def _set_solver(world, integrator: str) -> dict:
    """Install the contact solver `integrator` names, checked; its settings for the manifest."""
    solver = world.getConstraintSolver()
    if integrator == "pgs":
        primary = _new_pgs()  # not the world's fallback: DART refuses primary == secondary
        solver.setSecondaryBoxedLcpSolver(_new_pgs())
        solver.setBoxedLcpSolver(primary)
    else:
        solver.setSecondaryBoxedLcpSolver(_new_pgs())  # DART's default, with our options
    primary, secondary = solver.getBoxedLcpSolver(), solver.getSecondaryBoxedLcpSolver()
    got = (primary.getType(), None if secondary is None else secondary.getType())
    if got != SOLVERS[integrator]:
        raise RuntimeError(f"dartpy: solver {got} installed, expected {SOLVERS[integrator]}")
    return {
        "constraint_solver": type(solver).__name__,
        "boxed_lcp_solver": got[0],
        "fallback_lcp_solver": got[1],
        "fallback_use": "when the primary fails; its result is used when finite",
        "pgs_options": dict(
            zip(
                (
                    "max_iterations",
                    "delta_x_tolerance",
                    "relative_delta_x_tolerance",
                    "epsilon_for_division",
                    "randomize_constraint_order",
                ),
                PGS_OPTIONS,
                strict=True,
            )
        ),
        "split_impulse": bool(solver.isSplitImpulseEnabled()),
        "matrix_free_contact_solver": bool(solver.getMatrixFreeContactSolverOptions().mEnabled),
    }


def _sleeping_off(world, enabled: bool = False) -> None:
    """World deactivation (DART's sleeping) on or off, checked."""
    options = world.getDeactivationOptions()
    options.mEnabled = enabled
    world.setDeactivationOptions(options)
    if world.getDeactivationOptions().mEnabled != enabled:
        raise RuntimeError("dartpy: world deactivation could not be switched")


def _dynamics(shape_node, restitution: float, friction: float) -> None:
    """Collision and dynamics aspects of a contact shape: per-shape e and mu."""
    shape_node.createCollisionAspect()
    aspect = shape_node.createDynamicsAspect()
    aspect.setRestitutionCoeff(restitution)
    aspect.setFrictionCoeff(friction)


def _add_body(world, body, contact: bool, gravity: bool, e_shape: float, mu: float):
    """A FreeJoint skeleton for `body`: frame at the COM, identity at t = 0; its body node."""
    skeleton = dart.dynamics.Skeleton(body.name)
    joint, node = skeleton.createFreeJointAndBodyNodePair()
    for k in range(joint.getNumDofs()):
        joint.setDampingCoefficient(k, 0.0)
    node.setMass(body.mass)
    i = body.inertia  # about the COM in world axes = body axes at t = 0
    node.setMomentOfInertia(i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])
    node.setGravityMode(gravity)
    for offset in body.positions - body.com:
        shape = node.createShapeNode(dart.dynamics.SphereShape(body.particle_radius))
        shape.setRelativeTranslation(offset)
        if contact:
            _dynamics(shape, e_shape, mu)
    pose = dart.math.Isometry3()
    pose.set_translation(body.com)
    joint.setTransform(pose)
    world_frame = _world_frame()
    # Velocities given as world vectors, whatever frame the joint's coordinates use.
    joint.setLinearVelocity(np.asarray(body.velocity, dtype=float), world_frame, world_frame)
    joint.setAngularVelocity(
        np.asarray(body.angular_velocity, dtype=float), world_frame, world_frame
    )
    world.addSkeleton(skeleton)
    return node


def _add_plane(world, plane, index: int, e_shape: float, mu: float) -> None:
    """A fixed (welded) skeleton holding a PlaneShape through `plane.point` along its normal."""
    skeleton = dart.dynamics.Skeleton(f"plane{index}")
    skeleton.setMobile(False)
    _, node = skeleton.createWeldJointAndBodyNodePair()
    n = plane.unit_normal
    shape = node.createShapeNode(dart.dynamics.PlaneShape(n, float(n @ np.asarray(plane.point))))
    _dynamics(shape, e_shape, mu)
    world.addSkeleton(skeleton)


def build_world(scene: Scene, integrator: str, dt: float, sleeping: bool = False):
    """The DART world of `scene` at t = 0 and its body nodes (scene order); the solver's
    settings for the manifest. `sleeping` is for measuring what DART's default does."""
    world = dart.simulation.World(scene.name)
    world.setTimeStep(dt)
    world.setGravity(np.asarray(scene.gravity, dtype=float))
    world.setCollisionDetector(getattr(dart.simulation.CollisionDetectorType, COLLISION_DETECTOR))
    _sleeping_off(world, sleeping)
    solver = _set_solver(world, integrator)
    contact = scene.has_contact
    e_shape = math.sqrt(scene.contact.restitution) if contact else 0.0
    mu = scene.contact.friction if contact else 0.0
    nodes = [_add_body(world, b, contact, scene.has_gravity, e_shape, mu) for b in scene.bodies]
    if contact:
        for k, plane in enumerate(scene.planes):
            _add_plane(world, plane, k, e_shape, mu)
    return world, nodes, solver


def read_state(joints) -> np.ndarray:
    """(B, 12) per FreeJoint: its positions (rotation vector, COM x) and velocities (omega, COM
    v, world axes in dartpy 6.20), the two cheapest reads of a body's state in dartpy (about
    3 us against 27 us for the body node's world transform and spatial velocity). That they
    are the body node's world pose and velocities is checked in tests/test_dart_adapter.py."""
    out = np.empty((len(joints), 12))
    for k, joint in enumerate(joints):
        out[k, 0:6] = joint.getPositions()
        out[k, 6:12] = joint.getVelocities()
    return out


def read_back(scene: Scene, nodes) -> dict[str, dict]:
    """Each body as DART holds it before stepping (`RunMeta.bodies`): mass, inertia about the
    COM rotated to world axes, COM, COM velocity, world omega."""
    world_frame = _world_frame()
    bodies = {}
    for body, node in zip(scene.bodies, nodes, strict=True):
        inertia = node.getInertia()
        rot = node.getWorldTransform().rotation()
        com = node.getCOM(world_frame)
        moment = rot @ inertia.getMoment() @ rot.T
        bodies[body.name] = body_readback(
            inertia.getMass(),
            moment,
            com,
            node.getCOMLinearVelocity(world_frame, world_frame),
            node.getAngularVelocity(world_frame, world_frame),
        )
    return bodies


def step_and_sample(world, joints, sampled: np.ndarray) -> np.ndarray:
    """Step to each of the `sampled` step indices, reading every body's joint state there:
    (S, B, 12) as `read_state`. Stops at the first sample that is not finite or runs away
    (diverged); the samples after it stay NaN."""
    out = np.full((len(sampled), len(joints), 12), np.nan)
    step = world.step
    done = 0
    for s, k in enumerate(sampled):
        for _ in range(k - done):
            step()
        done = k
        row = read_state(joints)
        out[s] = row
        if not (np.abs(row) < MAX_VALUE).all():
            break
    return out


def samples_from_raw(raw: np.ndarray) -> np.ndarray:
    """(S, B, 13) rows x, q, v, world omega from `step_and_sample`'s records; every sample
    from the first non-finite or runaway one on is NaN."""
    samples = np.empty((*raw.shape[:2], 13))
    samples[..., 0:3] = raw[..., 3:6]
    samples[..., 3:7] = quats_from_rotvecs(raw[..., 0:3])
    samples[..., 7:10] = raw[..., 9:12]
    samples[..., 10:13] = raw[..., 6:9]
    bad = ~(np.abs(raw) < MAX_VALUE).reshape(len(raw), -1).all(axis=1)
    if bad.any():
        samples[int(np.argmax(bad)) :] = np.nan
    return samples


def parity_manifest(scene: Scene, world, solver: dict, sleeping: bool = False) -> dict:
    """The run's settings: every DART setting that affects the result."""
    detector = world.getCollisionDetector()
    option = world.getConstraintSolver().getCollisionOption()
    out: dict[str, object] = {
        "time_stepping": "semi-implicit Euler (velocity, then positions by the FreeJoint's "
        "exponential map); first order",
        "timestep": float(world.getTimeStep()),
        "gravity": np.asarray(world.getGravity(), dtype=float).tolist(),
        "gravity_mode": scene.has_gravity,
        "model": "one FreeJoint skeleton per body; body node frame at the COM, identity at "
        "t = 0; setMass + setMomentOfInertia (particle tensor), shapes add no inertia",
        "joint_damping": 0.0,
        "sleeping": "on (world deactivation, DART's default)" if sleeping else "off",
        **solver,
    }
    if scene.has_contact:
        e, mu = scene.contact.restitution, scene.contact.friction
        out["contact"] = {
            "collision_detector": type(detector).__name__,
            "shapes": f"{sum(len(b.particles) for b in scene.bodies)} spheres, "
            f"{len(scene.planes)} PlaneShape(s) on fixed skeletons",
            "restitution": e,
            "restitution_per_shape": math.sqrt(e),
            "restitution_combination": "product of the two shapes' coefficients",
            "friction": mu,
            "friction_per_shape": mu,
            "friction_combination": "min of the two shapes' coefficients",
            "max_contacts": int(option.maxNumContacts),
            "max_contacts_per_pair": int(option.getEffectiveMaxNumContactsPerPair()),
            "self_collision": False,
            **CONTACT_CONSTANTS,
        }
    else:
        out["contact"] = "none: no collision aspects, no planes"
    return out


def run_dart(
    scene: Scene, integrator: str, dt: float, duration: float, sleeping: bool = False
) -> Trajectory:
    """Run `scene` in a new DART world; `integrator` is the contact solver's name (SOLVERS).
    `sleeping=True` keeps DART's default deactivation (for the doc's measurement only)."""
    check_run_call("dart", UNAVAILABLE, integrator, SOLVERS)
    timer = RunTimer(scene, "dart", integrator, dt, duration)
    sampled = sample_steps(timer.n_steps, timer.stride)
    with timer.setup():
        world, nodes, solver = build_world(scene, integrator, dt, sleeping)
        bodies = read_back(scene, nodes)
        joints = [node.getParentJoint() for node in nodes]
    messages: list[str] = []
    with _stderr_captured(messages), timer.stepping():
        raw = step_and_sample(world, joints, sampled)
    manifest = parity_manifest(scene, world, solver, sleeping)
    report = _solver_report(messages)  # passes DART's other messages on, contact or not
    meta = timer.meta(
        package_versions("dartpy"), manifest, bodies, report if scene.has_contact else None
    )
    return timer.trajectory(sampled, samples_from_raw(raw), meta)


class DartEngine:
    name = "dart"
    integrators = tuple(SOLVERS)
    default_integrator = "dantzig"
    orders = ORDERS
    missing = UNAVAILABLE

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        return run_dart(scene, integrator, dt, duration)
