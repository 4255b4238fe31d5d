"""MuJoCo as an engine: one free body per scene body, one sphere geom per particle.

Each body's frame sits at its COM with identity orientation at t = 0 and carries a free joint;
its inertia is an explicit `<inertial>` with the particle tensor's principal moments and axes
(sphere geoms add none). The model holds only what the scene needs (no contact, no planes; no
gravity, gravity off) and skips the pipeline stages no scene acts on. Restitution is not a
MuJoCo parameter: `contact_parameters` maps the scene's e to a linear spring-damper (solref,
flat solimp) at MuJoCo's stiffest timeconst. Stepping goes through `mujoco.rollout` in chunks,
with MuJoCo's profiling timer off (process-global); a divergence ends the samples in NaN.
MuJoCo's warnings go to stderr (`warnings_to_stderr`), where every run's capture records them.

The mapping, its rebound table across dt, the stepping path and what was measured:
docs/engines/mujoco.md.
"""

from __future__ import annotations

import ctypes
import math
import sys
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import numpy as np

from cases.scene import Contact, Scene
from comparators.harness import RunTimer, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions
from rigidmath.inertia import principal_frame
from rigidmath.quaternion import quats_rotate

try:
    import mujoco
    from mujoco import rollout as mj_rollout

    UNAVAILABLE = None
except ImportError as exc:  # the module still imports; the engine says why it cannot run
    mujoco = None
    mj_rollout = None
    UNAVAILABLE = f"the mujoco package cannot be imported ({exc})"

INTEGRATORS = ("Euler", "RK4", "implicit", "implicitfast")
# Order of the orientation error in dt on tumbling_box before its flip (measured slopes:
# docs/engines/mujoco.md).
ORDERS = {"Euler": 1, "RK4": 4, "implicit": 1, "implicitfast": 1}

# timeconst = TIMECONST_STEPS dt / zeta: the stiffest contact MuJoCo allows (2 dt, its `refsafe`
# floor), with w dt fixed whatever e.
TIMECONST_STEPS = 2.0
# Flat impedance 0.99: a linear spring-damper at every depth, so e depends on zeta alone; 1 % of
# the load leaks through the regularisation.
SOLIMP = (0.99, 0.99, 0.001, 0.5, 2.0)
CONE = "elliptic"
SOLVER = "Newton"
ITERATIONS = 100
TOLERANCE = 1e-8
# Steps per rollout call: 65536 states of ~14 + 13 per body doubles, a few MB.
CHUNK_STEPS = 1 << 16
# MuJoCo's own divergence threshold on qpos, qvel, qacc (mjMAXVAL), and its warnings for it.
MAX_VALUE = 1e10
# The smallest mass or principal moment MuJoCo's compiler accepts for a moving body (mjMINVAL).
MJ_MINVAL = 1e-15
DIVERGENCE_WARNINGS = {"mjWARN_BADQPOS", "mjWARN_BADQVEL", "mjWARN_BADQACC"}
# Pipeline stages no scene gives anything to act on (no equality constraints, joint limits,
# friction loss, springs, dampers, actuators or sensors are modelled), disabled so MuJoCo skips
# them; stepping gives bitwise the same states with them on (tests/test_mujoco_adapter.py).
UNUSED_STAGES = (
    "equality",
    "frictionloss",
    "limit",
    "spring",
    "damper",
    "actuation",
    "clampctrl",
    "sensor",
    "eulerdamp",
)


def damping_ratio(restitution: float) -> float:
    """zeta with exp(-pi zeta / sqrt(1 - zeta^2)) = e; 1 (critical damping) for e = 0."""
    if restitution <= 0.0:
        return 1.0
    log_e = math.log(restitution)
    return -log_e / math.sqrt(math.pi**2 + log_e**2)


def contact_parameters(contact: Contact, dt: float) -> dict:
    """MuJoCo geom contact attributes for the scene's e and mu at step dt (docs/engines/mujoco.md).

    Returns solref, solimp, friction (sliding, torsional, rolling), condim, and the damping
    ratio and natural frequency (rad/s) the solref encodes.
    """
    zeta = damping_ratio(contact.restitution)
    omega = 1.0 / (TIMECONST_STEPS * dt)
    if zeta > 0.0:
        solref = (TIMECONST_STEPS * dt / zeta, zeta)
    else:  # e = 1: undamped, only the direct (-stiffness, -damping) form can say so
        solref = (-(omega**2), 0.0)
    mu = contact.friction
    return {
        "solref": solref,
        "solimp": SOLIMP,
        "friction": (mu, 0.0, 0.0),
        "condim": 3 if mu > 0.0 else 1,
        "damping_ratio": zeta,
        "natural_frequency": omega,
    }


def _num(values) -> str:
    """Doubles as MJCF text, exactly (17 significant digits round-trip)."""
    return " ".join(f"{float(v):.17g}" for v in np.atleast_1d(values))


def principal_inertia(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (ascending) and the quaternion (w, x, y, z) of the principal axes.

    A + B >= C is restored where rounding broke it (planar clusters have C = A + B exactly).
    """
    moments, axes = principal_frame(inertia)
    if moments[2] > moments[0] + moments[1]:
        moments[2] = moments[0] + moments[1]
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, axes.flatten())
    return moments, quat


def mjcf(scene: Scene, integrator: str, dt: float) -> str:
    """The MJCF model of `scene` stepped by `integrator` at `dt`."""
    flags = ['autoreset="disable"', *(f'{stage}="disable"' for stage in UNUSED_STAGES)]
    if not scene.has_contact:
        flags += ['contact="disable"', 'constraint="disable"']  # nothing to constrain
    if not scene.has_gravity:
        flags.append('gravity="disable"')
    lines = [
        f'<mujoco model="{scene.name}">',
        '  <compiler angle="radian" inertiafromgeom="false" alignfree="false"'
        ' balanceinertia="false" boundmass="0" boundinertia="0"/>',
        f'  <option timestep="{dt:.17g}" integrator="{integrator}"'
        f' gravity="{_num(scene.gravity)}" cone="{CONE}" solver="{SOLVER}"'
        f' iterations="{ITERATIONS}" tolerance="{TOLERANCE:.17g}" impratio="1"'
        ' noslip_iterations="0" density="0" viscosity="0">',
        f"    <flag {' '.join(flags)}/>",
        "  </option>",
    ]
    if scene.has_contact:
        p = contact_parameters(scene.contact, dt)
        lines += [
            "  <default>",
            f'    <geom condim="{p["condim"]}" friction="{_num(p["friction"])}"'
            f' solref="{_num(p["solref"])}" solimp="{_num(p["solimp"])}"'
            ' margin="0" gap="0" solmix="1" priority="0"/>',
            "  </default>",
        ]
    lines.append("  <worldbody>")
    if scene.has_contact:
        for k, plane in enumerate(scene.planes):
            lines.append(
                f'    <geom name="plane{k}" type="plane" pos="{_num(plane.point)}"'
                f' zaxis="{_num(plane.unit_normal)}" size="0 0 1"/>'
            )
    for body in scene.bodies:
        moments, iquat = principal_inertia(body.inertia)
        lines += [
            f'    <body name="{body.name}" pos="{_num(body.com)}">',
            f'      <freejoint name="{body.name}"/>',
            f'      <inertial pos="0 0 0" mass="{body.mass:.17g}" diaginertia="{_num(moments)}"'
            f' quat="{_num(iquat)}"/>',
        ]
        lines += [
            f'      <geom type="sphere" size="{body.particle_radius:.17g}" pos="{_num(offset)}"/>'
            for offset in body.positions - body.com
        ]
        lines.append("    </body>")
    lines += ["  </worldbody>", "</mujoco>"]
    return "\n".join(lines)


def free_joint_addresses(model, body: int) -> tuple[int, int]:
    """(qpos, qvel) addresses of the free joint of scene body `body` (MuJoCo body body + 1)."""
    joint = model.body_jntadr[body + 1]
    return int(model.jnt_qposadr[joint]), int(model.jnt_dofadr[joint])


def build(scene: Scene, integrator: str, dt: float):
    """Compiled model and data at the scene's t = 0 state, after `mj_forward`."""
    model = mujoco.MjModel.from_xml_string(mjcf(scene, integrator, dt))
    data = mujoco.MjData(model)
    for k, body in enumerate(scene.bodies):
        qa, va = free_joint_addresses(model, k)
        data.qpos[qa : qa + 3] = body.com
        data.qpos[qa + 3 : qa + 7] = (1.0, 0.0, 0.0, 0.0)
        data.qvel[va : va + 3] = body.velocity
        # body axes coincide with world axes at t = 0
        data.qvel[va + 3 : va + 6] = body.angular_velocity
    mujoco.mj_forward(model, data)
    return model, data


def readback(model, data, scene: Scene) -> dict[str, dict]:
    """Each body as MuJoCo holds it (`RunMeta.bodies`): mass and world inertia about the COM
    from the compiled model, COM (`xipos`) and COM velocities (`mj_objectVelocity`, world)."""
    bodies = {}
    for k, body in enumerate(scene.bodies):
        b = k + 1
        rot, irot = np.empty(9), np.empty(9)
        mujoco.mju_quat2Mat(rot, data.xquat[b])
        mujoco.mju_quat2Mat(irot, model.body_iquat[b])
        axes = rot.reshape(3, 3) @ irot.reshape(3, 3)
        inertia = axes @ np.diag(model.body_inertia[b]) @ axes.T
        velocity = np.empty(6)  # (angular, linear) at the COM, world axes
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, velocity, 0)
        bodies[body.name] = body_readback(
            model.body_mass[b], inertia, data.xipos[b], velocity[3:], velocity[:3]
        )
    return bodies


def _state_spec() -> int:
    return int(mujoco.mjtState.mjSTATE_FULLPHYSICS)


def full_state(model, data) -> np.ndarray:
    """The full physics state vector: time, qpos, qvel, then the rest (act, mocap, ...)."""
    out = np.empty(mujoco.mj_stateSize(model, _state_spec()))
    mujoco.mj_getState(model, data, out, _state_spec())
    return out


@cache
def _warning_indices() -> tuple[tuple[str, int], ...]:
    """(name, index) of every MuJoCo warning, looked up once."""
    names = [n for n in dir(mujoco.mjtWarning) if n.startswith("mjWARN_")]
    return tuple((n, int(getattr(mujoco.mjtWarning, n))) for n in names)


def _warnings(data) -> dict[str, int]:
    """MuJoCo's warning counters that are set, by name."""
    counts = {}
    for name, index in _warning_indices():
        n = data.warning[index].number
        if n:
            counts[name] = int(n)
    return counts


@cache
def _timer_callback():
    """libmujoco's global `mjcb_time` as a ctypes pointer, or None where it cannot be reached.

    MuJoCo's C library leaves it NULL; the Python bindings install a clock there (for
    `MjData.timer`), which MuJoCo then reads twice per pipeline stage, slowing stepping.
    """
    folder = Path(mujoco.__file__).parent
    for pattern in ("libmujoco.so*", "libmujoco*.dylib", "mujoco.dll"):
        for path in sorted(folder.glob(pattern)):
            try:
                return ctypes.c_void_p.in_dll(ctypes.CDLL(str(path)), "mjcb_time")
            except (OSError, ValueError):
                continue
    return None


@contextmanager
def profiling_timer_off():
    """MuJoCo's profiling timer callback off for the block (MjData.timer durations stay 0),
    restored after. Process-global, like the callback itself."""
    callback = _timer_callback()
    saved = None if callback is None else callback.value
    if callback is not None:
        callback.value = None
    try:
        yield
    finally:
        if callback is not None:
            callback.value = saved


def _print_warning(message: str) -> None:
    print(f"MuJoCo warning: {message}", file=sys.stderr)


@contextmanager
def warnings_to_stderr():
    """MuJoCo's warnings printed to stderr for the block, restored after (process-global, like
    the handler itself). Its default handler also appends each one to MUJOCO_LOG.TXT in the
    working directory; on stderr the run's capture (`comparators.engine_output`) records it
    and nothing is written beside the user's files."""
    saved = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(_print_warning)
    try:
        yield
    finally:
        mujoco.set_mju_user_warning(saved)


def step_rollout(model, data, n_steps: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Step with `mujoco.rollout`: (sample steps (S,), full states (S, nstate)).

    `data` is MuJoCo's scratch: it must hold the initial state and is left at the final one.
    After a divergence the states are NaN; any other MuJoCo warning raises RuntimeError.
    Runs with the profiling timer off, through rollout's unchecked call into preallocated
    arrays (the shapes are right by construction); the model has no sensors, so no sensor data
    is written.
    """
    steps = sample_steps(n_steps, stride)
    state = full_state(model, data)
    out = np.full((len(steps), state.size), np.nan)
    out[0] = state
    chunk = max(stride, CHUNK_STEPS // stride * stride)
    buffer = np.empty((1, min(chunk, n_steps), state.size))
    warmstart = data.qacc_warmstart[None].copy()
    done = 0
    with profiling_timer_off(), mj_rollout.Rollout(nthread=0) as roller:
        while done < n_steps:
            n = min(chunk, n_steps - done)
            states = buffer[:, :n]
            # one thread (no data list), so the states are the ones a mj_step loop gives
            roller.rollout(
                [model],
                [data],
                state[None],
                skip_checks=True,
                nstep=n,
                initial_warmstart=warmstart,
                state=states,
                sensordata=None,
            )
            states = states[0]
            first = int(np.searchsorted(steps, done + 1))
            last = int(np.searchsorted(steps, done + n, side="right"))
            out[first:last] = states[steps[first:last] - done - 1]
            warned = _warnings(data)
            if warned:
                # a divergence brings other warnings along (a huge state makes the inertia
                # matrix singular, mjWARN_INERTIA): any divergence warning is a divergence
                if not set(warned) & DIVERGENCE_WARNINGS:
                    raise RuntimeError(f"MuJoCo warned {warned} while stepping: results invalid")
                _blank_after_divergence(out, steps, states[:, 0], done)
                break
            state = states[-1].copy()  # the buffer is overwritten by the next chunk
            warmstart = data.qacc_warmstart[None].copy()  # rollout would start from zero
            done += n
    return steps, out


def _blank_after_divergence(out, steps, times, done) -> None:
    """NaN every sample from the step that diverged on (rollout repeats that state after it)."""
    stalled = np.flatnonzero(np.diff(times) == 0)
    bad_step = done + (int(stalled[0]) + 1 if len(stalled) else len(times))
    values = np.abs(out[:, 1:])
    bad = (steps >= bad_step) | ~(values < MAX_VALUE).all(axis=1)
    if bad.any():
        out[int(np.argmax(bad)) :] = np.nan


def step_loop(model, data, n_steps: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """The same as `step_rollout` with a Python loop of `mj_step` (for checks and timing)."""
    steps = sample_steps(n_steps, stride)
    out = np.empty((len(steps), mujoco.mj_stateSize(model, _state_spec())))
    out[0] = full_state(model, data)
    k = 1
    for n in range(1, n_steps + 1):
        mujoco.mj_step(model, data)
        if n == steps[k]:
            out[k] = full_state(model, data)
            k += 1
    return steps, out


def samples_from_states(model, states: np.ndarray, n_bodies: int) -> np.ndarray:
    """(S, B, 13) rows x, q, v, world omega from full states (S, nstate)."""
    out = np.empty((states.shape[0], n_bodies, 13))
    for k in range(n_bodies):
        qa, va = free_joint_addresses(model, k)
        qa, va = 1 + qa, 1 + model.nq + va  # the state starts with time, then qpos, qvel
        q = states[:, qa + 3 : qa + 7]
        out[:, k, 0:3] = states[:, qa : qa + 3]
        out[:, k, 3:7] = q
        out[:, k, 7:10] = states[:, va : va + 3]
        out[:, k, 10:13] = quats_rotate(q, states[:, va + 3 : va + 6])
    return out


def _flag_names(enum, bits: int) -> list[str]:
    """Names of the mjDSBL_ / mjENBL_ bits set in `bits`."""
    names = [n for n in dir(enum) if n.startswith(("mjDSBL_", "mjENBL_"))]
    return sorted(n for n in names if bits & int(getattr(enum, n)))


def parity_manifest(model, scene: Scene) -> dict[str, object]:
    """The parity manifest: every MuJoCo setting that affects the result, read from `model`."""
    opt = model.opt
    out: dict[str, object] = {
        "integrator": mujoco.mjtIntegrator(int(opt.integrator)).name,
        "timestep": float(opt.timestep),
        "gravity": opt.gravity.tolist(),
        "disabled": _flag_names(mujoco.mjtDisableBit, int(opt.disableflags)),
        "enabled": _flag_names(mujoco.mjtEnableBit, int(opt.enableflags)),
        "solver": mujoco.mjtSolver(int(opt.solver)).name,
        "iterations": int(opt.iterations),
        "tolerance": float(opt.tolerance),
        "ls_iterations": int(opt.ls_iterations),
        "ls_tolerance": float(opt.ls_tolerance),
        "cone": mujoco.mjtCone(int(opt.cone)).name,
        "impratio": float(opt.impratio),
        "noslip_iterations": int(opt.noslip_iterations),
        "density": float(opt.density),
        "viscosity": float(opt.viscosity),
        "inertia": "explicit <inertial> from the particles: principal moments + axes "
        "(diaginertia, quat), inertiafromgeom=false",
        "frame": "body frame at the COM, identity at t = 0, free joint, alignfree=false",
        "dof_damping_max": float(np.abs(model.dof_damping).max()),
        "dof_armature_max": float(np.abs(model.dof_armature).max()),
        "dof_frictionloss_max": float(np.abs(model.dof_frictionloss).max()),
        "stepping": "mujoco.rollout, one thread",
        "profiling_timer": "off while stepping (mjcb_time, installed by the Python bindings)"
        if _timer_callback() is not None
        else "on (mjcb_time not reachable)",
    }
    if scene.has_contact:
        p = contact_parameters(scene.contact, float(opt.timestep))
        out.update(
            {
                "contact": f"soft: {model.ngeom - len(scene.planes)} sphere geoms, "
                f"{len(scene.planes)} plane geoms",
                "restitution": scene.contact.restitution,
                "damping_ratio": p["damping_ratio"],
                "natural_frequency": p["natural_frequency"],
                "solref": model.geom_solref[0].tolist(),
                "solimp": model.geom_solimp[0].tolist(),
                "friction": model.geom_friction[0].tolist(),
                "condim": int(model.geom_condim[0]),
                "friction_combination": "max of the two geoms (all geoms equal)",
                "solref_solimp_combination": "solmix-weighted mean (all geoms equal)",
                "margin": float(np.abs(model.geom_margin).max()),
                "gap": float(np.abs(model.geom_gap).max()),
            }
        )
    else:
        out["contact"] = "none"
    return out


class MujocoEngine:
    name = "mujoco"
    integrators = INTEGRATORS
    default_integrator = "RK4"
    orders = ORDERS
    missing = UNAVAILABLE

    def unsupported(self, scene: Scene) -> str | None:
        """Bodies lighter or with a principal moment smaller than MuJoCo's mjMINVAL (its
        compiler refuses them: "mass and inertia of moving bodies must be larger than
        mjMINVAL"), or starting with a position or speed above its mjMAXVAL (MuJoCo resets
        such a state at once as diverged)."""
        for body in scene.bodies:
            smallest = min(body.mass, float(np.linalg.eigvalsh(body.inertia)[0]))
            if smallest < MJ_MINVAL:
                return (
                    f"body {body.name!r} has a mass or principal moment of {smallest:.3g}, "
                    f"below MuJoCo's mjMINVAL ({MJ_MINVAL:g}), which its compiler refuses"
                )
            start = (body.positions, body.velocity, body.angular_velocity)
            largest = max(float(np.max(np.abs(v))) for v in start)
            if largest > MAX_VALUE:
                return (
                    f"body {body.name!r} starts with a position or speed of {largest:.3g}, above "
                    f"MuJoCo's mjMAXVAL ({MAX_VALUE:g}), where it resets the state as diverged"
                )
        return None

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        if self.missing:
            raise RuntimeError(f"engine 'mujoco' unavailable: {self.missing}")
        timer = RunTimer(scene, self.name, integrator, dt, duration)
        with warnings_to_stderr():
            with timer.setup():
                model, data = build(scene, integrator, dt)
                bodies = readback(model, data, scene)  # before stepping: rollout overwrites data
                manifest = parity_manifest(model, scene)
            with timer.stepping():
                steps, states = step_rollout(model, data, timer.n_steps, timer.stride)
        meta = timer.meta(package_versions("mujoco"), manifest, bodies)
        return timer.trajectory(steps, samples_from_states(model, states, len(scene.bodies)), meta)
