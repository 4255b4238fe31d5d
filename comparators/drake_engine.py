"""Drake as an engine: one free body per scene body in a MultibodyPlant, one sphere per particle.

Each body's frame sits at its COM with identity orientation at t = 0, its spatial inertia is the
particle tensor about the COM (`SpatialInertia.MakeFromCentralInertia`, full tensor). Contact,
only when the scene has some, is Drake's compliant point contact (hydroelastic off): a sphere per
particle, a `HalfSpace` welded to the world per plane, and per geometry one contact material
(point stiffness, Hunt-Crossley dissipation, Coulomb friction). Drake has no coefficient of
restitution: `contact_material` maps the scene's e to the Hunt-Crossley dissipation that gives
rebound e at the scene's first impact speed. Without contact the plant has no SceneGraph and no
geometry at all.

Integrators: the discrete plant (time step dt) with the SAP solver ("sap", Drake's default
lagged Hunt-Crossley approximation) or TAMSI ("tamsi"), and the continuous plant advanced by the
Simulator at a fixed step dt ("semi_explicit_euler", "rk2", "rk3"). Neither the discrete step nor
semi-explicit Euler renormalises the quaternion, so poses are read through the plant's pose
evaluation, never from the raw positions. A step Drake fails on, or a non-finite state, ends the
samples in NaN; it does not raise.

The model, the mapping, its measured rebounds and the speed: docs/engines/drake.md.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from contextlib import contextmanager

import numpy as np

from cases.scene import Scene
from comparators.harness import RunTimer, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from rigidmath.quaternion import quats_from_matrices

try:
    from pydrake.geometry import (
        AddContactMaterial,
        HalfSpace,
        ProximityProperties,
        Role,
        Sphere,
    )
    from pydrake.math import RigidTransform
    from pydrake.multibody.math import SpatialVelocity
    from pydrake.multibody.plant import (
        AddMultibodyPlant,
        ApplyMultibodyPlantConfig,
        CoulombFriction,
        MultibodyPlant,
        MultibodyPlantConfig,
    )
    from pydrake.multibody.tree import RotationalInertia, SpatialInertia
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator
    from pydrake.systems.framework import DiagramBuilder, EventStatus

    UNAVAILABLE: str | None = None
except ImportError as exc:  # the module always imports; the engine says why it cannot run
    UNAVAILABLE = f"pydrake cannot be imported ({exc}): pip install 'rigidbench[drake]'"

# Discrete plants: integrator name -> MultibodyPlantConfig.discrete_contact_approximation.
DISCRETE = {"sap": "lagged", "tamsi": "tamsi"}
# Continuous plant (time_step 0): integrator name -> Drake's integration scheme, at fixed step.
CONTINUOUS = {
    "semi_explicit_euler": "semi_explicit_euler",
    "rk2": "runge_kutta2",
    "rk3": "runge_kutta3",
}
INTEGRATORS = (*DISCRETE, *CONTINUOUS)
# Convergence order in dt of the orientation error on a free body (docs/engines/drake.md): the
# discrete plant is semi-implicit Euler, the continuous schemes their textbook orders.
ORDERS = {"sap": 1, "tamsi": 1, "semi_explicit_euler": 1, "rk2": 2, "rk3": 3}

# Contact natural frequency of the heaviest body on one point contact, rad/s: the combined
# stiffness is m_max OMEGA^2, 1 mm under that body's weight at |g| = 10 (the scale of Drake's
# default penetration allowance), fixed whatever dt so that the model does not change with the
# step; four contacts (a face) sink 0.25 mm.
CONTACT_OMEGA = 100.0
# e = 0 has no finite Hunt-Crossley dissipation (e ~ 1 / (d v) for large d v): it is mapped as
# this e, the rebound a dissipation of about 1 / E_FLOOR times the impact speed leaves.
E_FLOOR = 0.05
# Impact speed used for the mapping when the scene's initial state predicts no impact faster
# than MIN_IMPACT_SPEED (bodies placed on a plane, whose clearance is 0 up to rounding, or
# moving apart), m/s: a rounding-level speed would give an unbounded dissipation.
FALLBACK_IMPACT_SPEED = 1.0
MIN_IMPACT_SPEED = 0.01
# Stribeck stiction tolerance (m/s), the slip speed at which friction reaches mu N, for TAMSI
# and the continuous plant (SAP regularises friction its own way and ignores it). TAMSI treats
# friction implicitly and keeps MultibodyPlantConfig's default. An explicit step resolves the
# Stribeck slope mu N / v_s only if mu |g| dt / v_s stays below ~2: at the default it is 50 at
# dt 0.001 and a stopped body chatters for ever, so the continuous plant gets 1e-2 m/s
# (0.5 at dt 0.001); a cube held on a slope then creeps at a few mm/s (docs/engines/drake.md).
STICTION_TOLERANCE = {"discrete": 1e-4, "continuous": 1e-2}
# Contact spheres a scene may have: registering geometries in Drake's SceneGraph grew here as
# about N^2.5 in time and N^1.7 in memory (cube_rain: 2400 spheres 9 s and 1.4 GB, 4800
# spheres 52 s and 4.4 GB; 8000 would take minutes and the 13 GB that ran a full report out of
# memory). Larger scenes are refused, saying so (docs/engines/drake.md).
MAX_CONTACT_SPHERES = 2400
# A state component beyond this magnitude is a divergence (m, m/s, rad/s), as MuJoCo's mjMAXVAL.
MAX_VALUE = 1e10


@contextmanager
def _drake_log_level(level: int):
    """Drake's Python log ("drake" logger) at `level` for the block: registering a HalfSpace
    warns that deformable contact ignores it and TAMSI warns of its deprecation, once per
    process, into every command's output (both in docs/engines/drake.md)."""
    logger = logging.getLogger("drake")
    saved = logger.level
    logger.setLevel(level)
    try:
        yield
    finally:
        logger.setLevel(saved)


def hunt_crossley_restitution(alpha: float) -> float:
    """Rebound e of a point contact f = k x (1 + d xdot) hit at speed v, alpha = d v.

    Integrating m v dv / (1 + d v) = -k x dx over the contact (x back to 0) gives
    alpha - ln(1 + alpha) = -alpha e - ln(1 - alpha e), independent of k, m and the number of
    identical contacts; solved for e by bisection (e < 1 / alpha: the force cannot pull).
    """
    if alpha <= 0.0:
        return 1.0
    target = alpha - math.log1p(alpha)
    lo, hi = 0.0, min(1.0, 1.0 / alpha)
    for _ in range(200):
        e = 0.5 * (lo + hi)
        if -alpha * e - math.log1p(-alpha * e) < target:
            lo = e
        else:
            hi = e
    return 0.5 * (lo + hi)


def hunt_crossley_alpha(restitution: float) -> float:
    """alpha = d v giving rebound `restitution` (inverse of `hunt_crossley_restitution`);
    e = 0 is mapped as E_FLOOR."""
    e = max(restitution, E_FLOOR)
    if e >= 1.0:
        return 0.0
    lo, hi = 0.0, 1.0
    while hunt_crossley_restitution(hi) > e:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if hunt_crossley_restitution(mid) > e:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _first_contact_speed(clearance: float, v_n: float, g_n: float) -> float:
    """Normal approach speed when a point at `clearance` along a plane's normal, moving at v_n
    with acceleration g_n along it, first reaches the plane; 0 when it never does."""
    if clearance <= 0.0:
        return max(0.0, -v_n)
    if v_n >= 0.0 and g_n >= 0.0:  # moving away and pushed away
        return 0.0
    disc = v_n * v_n - 2.0 * g_n * clearance  # c + v_n t + g_n t^2 / 2 = 0 has a root t > 0
    return math.sqrt(disc) if disc >= 0.0 else 0.0


def impact_speed(scene: Scene) -> float:
    """The largest normal speed of the first impacts the scene's initial state predicts: each
    body's lowest particle falling ballistically onto each plane (rotation ignored), and each
    pair of bodies approaching along the line of their COMs; FALLBACK_IMPACT_SPEED if none is
    faster than MIN_IMPACT_SPEED."""
    g = np.asarray(scene.gravity, dtype=float)
    speeds = [0.0]
    for body in scene.bodies:
        for plane in scene.planes:
            n = plane.unit_normal
            clearance = float(np.min((body.positions - plane.point) @ n)) - body.particle_radius
            speeds.append(
                _first_contact_speed(clearance, float(np.dot(body.velocity, n)), float(g @ n))
            )
    for i, a in enumerate(scene.bodies):
        for b in scene.bodies[i + 1 :]:
            line = b.com - a.com
            u = line / np.linalg.norm(line)
            speeds.append(max(0.0, -float(np.dot(np.subtract(b.velocity, a.velocity), u))))
    speed = max(speeds)
    return speed if speed >= MIN_IMPACT_SPEED else FALLBACK_IMPACT_SPEED


@dataclasses.dataclass(frozen=True)
class ContactMaterial:
    """The contact material every geometry gets (all equal, so Drake's combinations give back
    the pair values): stiffness 2k (two in series give k), dissipation d, friction mu, mu."""

    point_stiffness: float  # per geometry, N/m; a pair combines to half of it
    dissipation: float  # Hunt-Crossley d, s/m; equal on both sides, the pair's d is the same
    friction: float  # static = dynamic; Drake's 2 mu1 mu2 / (mu1 + mu2) gives it back
    impact_speed: float  # m/s, the v of the mapping
    alpha: float  # d v
    target_restitution: float  # the e the mapping aims at (E_FLOOR for e = 0)


def contact_material(scene: Scene) -> ContactMaterial:
    """The material of every geometry for `scene` (which has contact)."""
    m_max = max(b.mass for b in scene.bodies)
    v = impact_speed(scene)
    e = scene.contact.restitution
    alpha = hunt_crossley_alpha(e)
    return ContactMaterial(
        point_stiffness=2.0 * m_max * CONTACT_OMEGA**2,
        dissipation=alpha / v,
        friction=scene.contact.friction,
        impact_speed=v,
        alpha=alpha,
        target_restitution=max(e, E_FLOOR) if e < 1.0 else 1.0,
    )


def _properties(material: ContactMaterial) -> ProximityProperties:
    props = ProximityProperties()
    mu = material.friction
    AddContactMaterial(
        dissipation=material.dissipation,
        point_stiffness=material.point_stiffness,
        friction=CoulombFriction(mu, mu),
        properties=props,
    )
    return props


def plant_config(integrator: str, dt: float) -> MultibodyPlantConfig:
    """The plant's configuration: discrete at dt with the integrator's contact approximation,
    or continuous (time_step 0); point contact; every other field explicit."""
    discrete = integrator in DISCRETE
    return MultibodyPlantConfig(
        time_step=dt if discrete else 0.0,
        discrete_contact_approximation=DISCRETE[integrator] if discrete else "",
        contact_model="point",
        penetration_allowance=0.001,  # unused: every geometry carries its own stiffness
        stiction_tolerance=STICTION_TOLERANCE["discrete" if discrete else "continuous"],
        sap_near_rigid_threshold=1.0,
        adjacent_bodies_collision_filters=True,
        use_sampled_output_ports=False,
    )


@dataclasses.dataclass
class DrakeModel:
    """A built model: the plant, the Simulator over it, the plant's context inside the
    Simulator's, the rigid bodies in scene order, and what the settings report."""

    plant: object
    simulator: object
    context: object
    bodies: list
    config: object
    material: ContactMaterial | None
    integrator: object | None  # the Simulator's integrator (continuous plant only)
    scene_graph: object | None


def _add_body(plant, body):
    """A free rigid body: frame at the COM, the particles' mass and central inertia."""
    i = body.inertia
    inertia = RotationalInertia(i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])
    return plant.AddRigidBody(
        body.name, SpatialInertia.MakeFromCentralInertia(body.mass, np.zeros(3), inertia)
    )


def build(scene: Scene, integrator: str, dt: float) -> DrakeModel:
    """The finalised plant of `scene` at its t = 0 state, in a Simulator set for `integrator`."""
    config = plant_config(integrator, dt)
    contact = scene.has_contact
    material = contact_material(scene) if contact else None
    scene_graph = None
    with _drake_log_level(logging.ERROR):
        if contact:
            builder = DiagramBuilder()
            plant, scene_graph = AddMultibodyPlant(config, builder)
        else:  # no geometry at all: no SceneGraph either
            plant = MultibodyPlant(config.time_step)
            ApplyMultibodyPlantConfig(config, plant)
        plant.mutable_gravity_field().set_gravity_vector(np.asarray(scene.gravity, dtype=float))
        bodies = [_add_body(plant, b) for b in scene.bodies]
        if contact:
            props = _properties(material)
            for body, rigid in zip(scene.bodies, bodies, strict=True):
                sphere = Sphere(body.particle_radius)
                for k, offset in enumerate(body.positions - body.com):
                    plant.RegisterCollisionGeometry(
                        rigid, RigidTransform(offset), sphere, f"{body.name}.{k}", props
                    )
            for k, plane in enumerate(scene.planes):
                pose = HalfSpace.MakePose(plane.unit_normal, np.asarray(plane.point, dtype=float))
                plant.RegisterCollisionGeometry(
                    plant.world_body(), pose, HalfSpace(), f"plane{k}", props
                )
        plant.Finalize()
        system = builder.Build() if contact else plant
        simulator = Simulator(system)  # its context is where the HalfSpace warning comes from
    root = simulator.get_mutable_context()
    context = plant.GetMyMutableContextFromRoot(root) if contact else root
    for body, rigid in zip(scene.bodies, bodies, strict=True):
        plant.SetFreeBodyPose(context, rigid, RigidTransform(body.com))
        velocity = SpatialVelocity(
            np.asarray(body.angular_velocity, dtype=float), np.asarray(body.velocity, dtype=float)
        )
        plant.SetFreeBodySpatialVelocity(context, rigid, velocity)
    stepper = None
    if integrator in CONTINUOUS:
        stepper = ResetIntegratorFromFlags(simulator, CONTINUOUS[integrator], dt)
        stepper.set_fixed_step_mode(True)
    simulator.Initialize()
    return DrakeModel(plant, simulator, context, bodies, config, material, stepper, scene_graph)


def readback(model: DrakeModel, scene: Scene) -> dict[str, dict]:
    """Each body as the plant holds it before stepping (`RunMeta.bodies`): mass and inertia
    about the COM in world axes from the body's spatial inertia in the context, COM position
    and velocity and world angular velocity from the plant's kinematics."""
    plant, context = model.plant, model.context
    out = {}
    for body, rigid in zip(scene.bodies, model.bodies, strict=True):
        pose = plant.EvalBodyPoseInWorld(context, rigid)
        spatial = rigid.CalcSpatialInertiaInBodyFrame(context)  # about Bo, body axes
        com_b = spatial.get_com()
        central = spatial.Shift(com_b).ReExpress(pose.rotation())  # about the COM, world axes
        inertia = central.CalcRotationalInertia().CopyToFullMatrix3()
        velocity = plant.EvalBodySpatialVelocityInWorld(context, rigid)
        w = velocity.rotational()
        com_w = pose.rotation().multiply(com_b)
        v = velocity.translational() + np.cross(w, com_w)
        out[body.name] = body_readback(
            spatial.get_mass(), inertia, pose.translation() + com_w, v, w
        )
    return out


def end_time(model: DrakeModel, n_steps: int, dt: float) -> float:
    """The time n_steps steps of dt reach. The discrete plant updates at k dt. The Simulator's
    fixed-step integrator adds dt to its clock step by step, so its clock after n steps is that
    running sum (np.add.accumulate adds in order): advancing to n dt instead, a few ulp off it,
    would cost a spurious last step of ~1e-17 s."""
    if model.integrator is None:
        return n_steps * dt
    return float(np.add.accumulate(np.full(n_steps, dt))[-1])


def step_and_sample(
    model: DrakeModel, steps: np.ndarray, dt: float, end: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Advance to `end` in one `AdvanceTo`, recording each body's pose (the plant's
    `EvalBodyPoseInWorld`, its 3 x 4 [R | x]) and spatial velocity in the world (w, v) at the
    sampled step indices `steps`, from a Simulator monitor (called once after every step,
    whatever the plant: one AdvanceTo per sample would cost an extra ~0.1 ms each).

    A step Drake fails on (it throws) or a non-finite or runaway state at a sample ends the
    run: the samples from there on are NaN. Returns poses (S, B, 3, 4), spatial velocities
    (S, B, 6) and the time of the first NaN sample (NaN if none).
    """
    plant, context, simulator, bodies = model.plant, model.context, model.simulator, model.bodies
    pose, velocity = plant.EvalBodyPoseInWorld, plant.EvalBodySpatialVelocityInWorld
    poses = np.full((len(steps), len(bodies), 3, 4), np.nan)
    spatial = np.full((len(steps), len(bodies), 6), np.nan)
    sampled = {int(k): s for s, k in enumerate(steps)}
    state = plant.GetPositionsAndVelocities
    # steps done; the sample being recorded (None between samples); the first bad sample
    done, recording, bad = [0], [None], [None]
    succeeded = EventStatus.Succeeded()

    def record(root) -> object:
        s = sampled.get(done[0])
        done[0] += 1
        if s is None:
            return succeeded
        # the raw state, quaternion included: its norm runs away before the pose does
        if not (np.abs(state(context)) < MAX_VALUE).all():  # NaN compares False
            bad[0] = s
            return EventStatus.ReachedTermination(plant, "diverged")
        recording[0] = s
        for b, rigid in enumerate(bodies):
            poses[s, b] = pose(context, rigid).GetAsMatrix4()[:3]
            spatial[s, b] = velocity(context, rigid).get_coeffs()
        recording[0] = None
        return succeeded

    record(simulator.get_context())  # step 0, the initial state
    simulator.set_monitor(record)
    try:
        simulator.AdvanceTo(end)
    except RuntimeError:  # Drake's failed step (NaN, solver failure): a result
        if recording[0] is not None:  # failed reading a sample
            bad[0] = recording[0]
        else:  # failed taking step done[0]
            bad[0] = int(np.searchsorted(steps, done[0]))
    finally:
        simulator.clear_monitor()
    if bad[0] is None:
        return poses, spatial, math.nan
    poses[bad[0] :] = np.nan
    spatial[bad[0] :] = np.nan
    return poses, spatial, float(steps[min(bad[0], len(steps) - 1)] * dt)


def samples_from_records(poses: np.ndarray, spatial: np.ndarray) -> np.ndarray:
    """(S, B, 13) rows x, q, v, world omega from `step_and_sample`'s poses and velocities."""
    out = np.empty((*poses.shape[:2], 13))
    out[..., 0:3] = poses[..., 3]
    out[..., 3:7] = quats_from_matrices(poses[..., :3])
    out[..., 7:10] = spatial[..., 3:]
    out[..., 10:13] = spatial[..., :3]
    return out


def steps_taken(model: DrakeModel) -> int:
    """Steps Drake took: discrete updates, or the integrator's steps (fixed-step: n_steps)."""
    if model.integrator is not None:
        return int(model.integrator.get_num_steps_taken())
    return int(model.simulator.get_num_discrete_updates())


def parity_manifest(model: DrakeModel, scene: Scene, integrator: str) -> dict[str, object]:
    """Every Drake setting that affects the result, read back from the plant where it can be."""
    plant, config = model.plant, model.config
    out: dict[str, object] = {
        "plant": "discrete" if plant.time_step() > 0 else "continuous",
        "time_step": float(plant.time_step()),
        "gravity": np.asarray(plant.gravity_field().gravity_vector()).tolist(),
        "inertia": "SpatialInertia.MakeFromCentralInertia(m, 0, full particle tensor)",
        "frame": "body frame at the COM, identity at t = 0, quaternion free body",
        "damping": "none (MultibodyPlant adds none; no joints)",
        "readout": "EvalBodyPoseInWorld (normalised rotation), EvalBodySpatialVelocityInWorld",
        "publishing": "none (no system declares a publish event)",
    }
    if plant.time_step() > 0:
        out["discrete_contact_approximation"] = str(plant.get_discrete_contact_approximation())
        out["discrete_contact_solver"] = str(plant.get_discrete_contact_solver())
        out["sap_near_rigid_threshold"] = float(plant.get_sap_near_rigid_threshold())
        out["integrator"] = "discrete step (semi-implicit Euler in the contact solver)"
    else:
        stepper = model.integrator
        out["integrator"] = f"{CONTINUOUS[integrator]} ({type(stepper).__name__})"
        out["fixed_step_mode"] = bool(stepper.get_fixed_step_mode())
        out["maximum_step_size"] = float(stepper.get_maximum_step_size())
    if scene.has_contact:
        m = model.material
        inspector = model.scene_graph.model_inspector()
        spheres = sum(len(b.particles) for b in scene.bodies)
        out.update(
            {
                "contact_model": str(plant.get_contact_model()),
                "geometries": f"{spheres} spheres, {len(scene.planes)} half-spaces",
                "proximity_geometries": int(inspector.NumGeometriesWithRole(Role.kProximity)),
                "point_stiffness_per_geometry": m.point_stiffness,
                "point_stiffness_pair": m.point_stiffness / 2.0,
                "contact_omega": CONTACT_OMEGA,
                "hunt_crossley_dissipation": m.dissipation,
                "restitution": scene.contact.restitution,
                "restitution_mapping": "Hunt-Crossley: alpha - ln(1 + alpha) = "
                "-alpha e - ln(1 - alpha e), alpha = d v at the first impact speed v",
                "mapped_restitution": m.target_restitution,
                "impact_speed": m.impact_speed,
                "alpha": m.alpha,
                "friction_static_dynamic": m.friction,
                "friction_combination": "2 mu1 mu2 / (mu1 + mu2) (all geometries equal)",
                "stiffness_combination": "in series (k / 2 per pair of equal geometries)",
                "dissipation_combination": "stiffness-weighted mean (all equal)",
                "stiction_tolerance": config.stiction_tolerance,
                "friction_regularisation": "SAP's own (stiction tolerance unused)"
                if integrator == "sap"
                else "Stribeck, stiction tolerance",
                "penetration_allowance": "unused (stiffness per geometry)",
            }
        )
    else:
        out["contact_model"] = "none (no SceneGraph, no geometry)"
    return out


class DrakeEngine:
    name = "drake"
    integrators = INTEGRATORS
    default_integrator = "sap"
    orders = ORDERS
    missing = UNAVAILABLE

    def unsupported(self, scene: Scene) -> str | None:
        """Scenes with more than MAX_CONTACT_SPHERES contact spheres: too slow to build here."""
        spheres = sum(len(b.particles) for b in scene.bodies) if scene.has_contact else 0
        if spheres > MAX_CONTACT_SPHERES:
            return (
                f"{spheres} contact spheres, over {MAX_CONTACT_SPHERES}: Drake's geometry "
                "registration grows as N^2.5 (minutes and over 10 GB at 8000)"
            )
        return None

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        if self.missing:
            raise RuntimeError(f"engine 'drake' unavailable: {self.missing}")
        if integrator not in INTEGRATORS:
            raise ValueError(f"unknown Drake integrator {integrator!r}: one of {INTEGRATORS}")
        timer = RunTimer(scene, self.name, integrator, dt, duration)
        with timer.setup():
            model = build(scene, integrator, dt)
            bodies = readback(model, scene)
            manifest = parity_manifest(model, scene, integrator)
        steps = sample_steps(timer.n_steps, timer.stride)
        end = end_time(model, timer.n_steps, dt)
        with timer.stepping():
            poses, spatial, diverged_at = step_and_sample(model, steps, dt, end)
        samples = samples_from_records(poses, spatial)
        solver = {"steps_taken": float(steps_taken(model)), "diverged_at_s": diverged_at}
        meta = timer.meta(package_versions("drake"), manifest, bodies, solver)
        return timer.trajectory(steps, samples, meta)
