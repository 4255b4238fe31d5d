"""MuJoCo as an engine: one free body per scene body, one sphere geom per particle.

Model (MJCF text compiled by `mujoco.MjModel.from_xml_string`; `mjcf` shows it)
------------------------------------------------------------------------------
* Each body's frame sits AT ITS COM with identity orientation at t = 0 and carries a
  `<freejoint/>`. So qpos[0:3] is the COM (checked against `data.xipos`), qpos[3:7] is exactly
  the suite's quaternion (w, x, y, z; placement at t = 0 -> now), qvel[0:3] the COM velocity in
  world axes, and qvel[3:6] the angular velocity in BODY axes: rows report R(q) qvel[3:6].
  `alignfree="false"` keeps MuJoCo from moving the joint frame onto the principal axes.
* Inertia: an explicit `<inertial pos="0 0 0" mass=... diaginertia=... quat=...>` holding the
  particle tensor's principal moments and axes (numpy `eigh`), with
  `inertiafromgeom="false"`, so the sphere geoms add neither mass nor inertia. Not
  `fullinertia`: a planar cluster has C = A + B exactly, MuJoCo's own eigen-solver rounds it to
  A + B < C by an ulp and the compiler rejects the body ("inertia must satisfy A + B >= C");
  here C is clamped to A + B when rounding breaks it (a 1e-16 relative change). Mass and
  inertia read back from `body_mass`, `body_inertia`, `body_iquat` equal the scene's to 1e-15.
* Only what the scene needs: no `scene.has_contact` -> `<flag contact="disable"
  constraint="disable"/>` and no planes; zero gravity -> gravity "0 0 0" and `<flag
  gravity="disable"/>`. `autoreset` is always disabled, so a diverging run ends in NaN instead
  of MuJoCo silently restarting it from qpos0. Joints have no damping, armature, stiffness or
  frictionloss (MuJoCo's defaults, read back into the settings); fluid forces are off (density
  = viscosity = 0). The pipeline stages nothing in a scene acts on (`UNUSED_STAGES`: equality,
  friction loss, limits, springs, dampers, actuation, sensors) are disabled, so MuJoCo skips
  them: the same states to the bit, 5 to 20 % faster stepping.
* Same-body geoms never collide in MuJoCo; different free bodies do (contype = conaffinity =
  1 everywhere; `filterparent` drops only parent-child pairs, and two free bodies are siblings
  under the world, which it never filters), and so does every particle with every plane.

Contact mapping (only when `scene.has_contact`): see `contact_parameters`
------------------------------------------------------------------------
Restitution is not a MuJoCo parameter. A contact is a soft constraint whose reference
acceleration is -b v - k d r with, for solref = (timeconst, dampratio) and impedance d = dmax,
d b = 2 / timeconst and d^2 k = 1 / (timeconst dampratio)^2: a spring-damper of natural
frequency w = 1 / (timeconst zeta) and damping ratio exactly zeta = dampratio.

* dampratio = zeta from e = exp(-pi zeta / sqrt(1 - zeta^2)): zeta = -ln e / sqrt(pi^2 + ln^2 e),
  and 1 (critical) for e = 0. e = 1 (zeta = 0) has no (timeconst, dampratio) form: it uses the
  direct form solref = (-w^2, 0) with the same w.
* timeconst = TIMECONST_STEPS dt / zeta with TIMECONST_STEPS = 2, i.e. w dt = 1/2 whatever e.
  2 dt is MuJoCo's floor (`refsafe` clamps anything shorter), the stiffest contact it allows:
  at dt 0.01 the cube in `dropped_cube` sinks at most 27 mm (Euler) / 41 mm (RK4) on impact,
  less than the ~60 mm it travels in one step before the contact is even detected; 3 dt gives
  44 / 63 mm and 4 dt 66 / 85 mm. Scaling timeconst with 1/zeta holds w dt fixed: a fixed
  timeconst of 2 dt makes w dt = 1 / (2 zeta), past the explicit spring's stability limit of 2
  for zeta < 0.25, and a cube dropped flat then leaves the floor 2.7x (e = 0.5), 15x
  (e = 0.75) and 112x (e = 0.9) faster than it came (Euler, dt 0.01).
* solimp = (0.99, 0.99, 0.001, 0.5, 2): dmin = dmax makes the impedance flat, so the contact
  is a linear spring-damper at every depth (MuJoCo's default 0.9 -> 0.95 over 1 mm is not) and
  the restitution depends on zeta alone. d = 0.99 lets only 1 % of the load through the
  regularisation: the steady penetration is (1 - d) g (timeconst zeta)^2 / n for n supporting
  contacts (a static stiffness w^2 / (1 - d) per unit mass, not w^2): 1.0e-5 m for the cube
  on 4 particles at dt 0.01 and 1.0e-7 m at 0.001, against g / (n w^2) = 1 mm and 0.01 mm.
* friction = (mu, 0, 0) on every geom (MuJoCo combines the two geoms' friction by max; all are
  equal), condim 3: Coulomb sliding friction only, like the reference (no torsional or rolling
  friction: a particle is a point contact; the spin/roll coefficients are unused at condim 3).
  mu = 0 uses condim 1, exactly frictionless (condim 3 would clamp mu to MuJoCo's 1e-5).
* cone elliptic: the reference's isotropic Coulomb disc (MuJoCo's default pyramid is not).
  Solver Newton, 100 iterations, tolerance 1e-8 (MuJoCo's defaults; 1e-12 moves the rest
  heights below by < 2e-14 m), impratio 1, no noslip, margin = gap = 0 (contacts start at
  touch).

How well the mapping holds across dt. Rebound ratio v_out / v_in of the seed's cube falling flat
onto the floor without gravity, over 16 impact phases (first touch at 0, 1/16, ..., 15/16 of a
step into a step), mean [min, max]; the same at 2 and 6 m/s:

    e     Euler dt 0.01      Euler dt 0.001     RK4 dt 0.01        RK4 dt 0.001       unilateral
    0.00  0.13 [0.01, 0.24]  0.14 [0.02, 0.26]  0.13 [0.10, 0.17]  0.14 [0.10, 0.18]  0.135
    0.10  0.21 [0.13, 0.31]  0.22 [0.14, 0.33]  0.25 [0.21, 0.30]  0.26 [0.21, 0.31]  0.253
    0.25  0.33 [0.26, 0.42]  0.34 [0.26, 0.43]  0.36 [0.31, 0.40]  0.36 [0.32, 0.41]  0.361
    0.50  0.53 [0.48, 0.60]  0.54 [0.48, 0.61]  0.55 [0.52, 0.59]  0.55 [0.52, 0.60]  0.550
    0.75  0.76 [0.74, 0.81]  0.76 [0.74, 0.82]  0.76 [0.74, 0.78]  0.76 [0.75, 0.79]  0.763
    0.90  0.90 [0.89, 0.92]  0.90 [0.89, 0.92]  0.90 [0.89, 0.92]  0.90 [0.89, 0.92]  0.902
    1.00  1.00 [0.98, 1.02]  1.00 [0.98, 1.02]  1.00 [0.99, 1.01]  1.00 [0.99, 1.01]  1.000

(implicit and implicitfast give Euler's numbers to the digits shown.) timeconst is proportional
to dt, so without gravity the discrete contact is the same in units of dt: the rebound does not
depend on dt (nor on speed), only on where in a step the contact starts. That phase scatters
single bounces by up to +-0.12 (Euler removes the approach speed in one step at timeconst = 2 dt;
RK4 spreads it over its stages, +-0.04). The means do not follow the formula but the
"unilateral" column: the restitution of a linear spring-damper that lets go when its force reaches
zero (integrated here in continuous time), which is what MuJoCo's contact does. The formula's
e(zeta) is the bilateral oscillator's velocity ratio at zero crossing; the two agree for e >=
0.75 and part below: at e = 0 the critical damper still returns e^-2 = 0.135 of the speed, and
no finite dampratio gives e = 0 (the unilateral e is 0.048 at zeta = 2, 0.014 at 4). Inverting
the unilateral curve instead of the formula would centre every e >= 0.14.

Rest: `dropped_cube` (e = 0, mu = 0.5) comes to rest on a face by t = 2.75 s with its COM at
0.699990 m (dt 0.01) and 0.6999999 m (dt 0.001) with every integrator (the four agree to 2e-14
m): the 1e-5 and 1e-7 m steady penetrations above.

Stepping
--------
`mujoco.rollout` (single thread) runs the steps in C and returns every state; it is 1.1 to 1.8x
faster than a Python loop of `mj_step` that copies the samples (median of 7; tumbling_box and
dropped_cube, dt 0.01 and 0.001; most for Euler with per-step samples, least for RK4 whose
steps cost most) and gives bitwise the same states (`step_loop` is kept for that check). It
runs in chunks of at most CHUNK_STEPS steps so memory stays bounded; each chunk starts from the
last state and, because rollout zeroes the warm start unless given one, from the previous
chunk's `qacc_warmstart`. Rollout uses the MjData it is given as scratch and leaves it at the
final state: everything read from `data` (the parity readback) is read before stepping. Rollout
stops stepping at the first MuJoCo warning and repeats the last state: divergence warnings
(bad qpos, qvel, qacc) turn the samples from there on into NaN; any other warning (contact or
constraint buffer full, singular inertia) raises. MuJoCo also appends each warning's text to
MUJOCO_LOG.TXT in the working directory.

The fastest honest path, with the same states:
* MuJoCo's C library leaves its profiling-timer callback `mjcb_time` NULL; the Python bindings
  install a clock there (for `MjData.timer`), read twice per pipeline stage. Stepping runs with
  it off (`profiling_timer_off`, through ctypes: the bindings' `set_mjcb_time(None)` reinstalls
  their clock) and restores it after. It is process-global: runs in concurrent threads may
  leave it off, which changes no result. On one free body this alone made stepping 1.5 to 3
  times faster.
* rollout is called unchecked (`skip_checks`) into a preallocated array: the checked call costs
  about 90 us, a tenth of a 1000-step free-body run. Its output state is always
  mjSTATE_FULLPHYSICS (the rollout API has no state spec for it); here that is exactly time,
  qpos and qvel, the least the trajectory needs. No sensor data is written (no sensors).

Speed (steps/s, stepping alone, through `comparators.engine.run` as `rigidbench bench` times
it, dt 0.01; the fastest of 75 runs, the least disturbed by other jobs on this shared 2-core
machine, whose medians varied 2 to 3x with their load; in parentheses before the two changes
above and the disabled stages): free_spin_cube Euler 8.9e5 (4.4e5), RK4 2.8e5 (1.4e5);
tumbling_box Euler 6.8e5 (3.6e5), RK4 2.0e5 (1.1e5); dropped_cube Euler 1.6e5 (1.3e5), RK4
4.3e4 (3.5e4), where contact dominates. Model building: 2.5 ms.

Accuracy on tumbling_box (largest orientation error over 10 s against `cases.exact`): RK4
4.4e-7 deg at dt 0.01 and 1.2e-10 deg at dt 0.001; Euler 20 / 2.0 deg, implicit and
implicitfast 19 / 2.0 deg (first order; on a free body implicit and implicitfast agree to
1e-12 deg and both differ from Euler).
"""

from __future__ import annotations

import ctypes
import math
import time
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import numpy as np

from cases.scene import Contact, Scene
from comparators.engine import register, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import RunMeta, Trajectory, package_versions
from reference_sim.inertia import principal_frame

try:
    import mujoco
    from mujoco import rollout as mj_rollout

    MISSING = None
except ImportError as exc:  # the module still imports; the engine says why it cannot run
    mujoco = None
    mj_rollout = None
    MISSING = f"the mujoco package cannot be imported ({exc})"

INTEGRATORS = ("Euler", "RK4", "implicit", "implicitfast")
# Order of the orientation error in dt on tumbling_box before its flip (measured: 1.00, 3.98,
# 1.00, 1.00).
ORDERS = {"Euler": 1, "RK4": 4, "implicit": 1, "implicitfast": 1}

# timeconst = TIMECONST_STEPS dt / zeta: the stiffest contact MuJoCo allows (see above).
TIMECONST_STEPS = 2.0
# Flat impedance 0.99: a linear spring-damper at every depth, 1 % load leak (see above).
SOLIMP = (0.99, 0.99, 0.001, 0.5, 2.0)
CONE = "elliptic"
SOLVER = "Newton"
ITERATIONS = 100
TOLERANCE = 1e-8
# Steps per rollout call: 65536 states of ~14 + 13 per body doubles, a few MB.
CHUNK_STEPS = 1 << 16
# MuJoCo's own divergence threshold on qpos, qvel, qacc (mjMAXVAL), and its warnings for it.
MAX_VALUE = 1e10
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
    """MuJoCo geom contact attributes for the scene's e and mu at step dt (module docstring).

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
    `MjData.timer`), which MuJoCo then reads twice per pipeline stage: measured 1.5 to 3 times
    slower stepping of one free body.
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
                if not set(warned) <= DIVERGENCE_WARNINGS:
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


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate v (S, 3) by the unit quaternions q (S, 4): v + 2 w (u x v) + 2 u x (u x v)."""
    w, u = q[:, :1], q[:, 1:]
    uv = np.cross(u, v)
    return v + 2.0 * w * uv + 2.0 * np.cross(u, uv)


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
        out[:, k, 10:13] = _rotate(q, states[:, va + 3 : va + 6])
    return out


def _flag_names(enum, bits: int) -> list[str]:
    """Names of the mjDSBL_ / mjENBL_ bits set in `bits`."""
    names = [n for n in dir(enum) if n.startswith(("mjDSBL_", "mjENBL_"))]
    return sorted(n for n in names if bits & int(getattr(enum, n)))


def settings(model, scene: Scene) -> dict[str, object]:
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
    missing = MISSING

    def run(self, scene: Scene, integrator: str, dt: float, duration: float) -> Trajectory:
        if self.missing:
            raise RuntimeError(f"engine 'mujoco' unavailable: {self.missing}")
        t0 = time.perf_counter()
        model, data = build(scene, integrator, dt)
        bodies = readback(model, data, scene)  # before stepping: rollout overwrites data
        manifest = settings(model, scene)
        setup_s = time.perf_counter() - t0
        n_steps = scene.steps(dt, duration)
        t0 = time.perf_counter()
        steps, states = step_rollout(model, data, n_steps, scene.sample_stride(dt))
        wall_s = time.perf_counter() - t0
        meta = RunMeta(
            case=scene.name,
            engine=self.name,
            integrator=integrator,
            dt=dt,
            steps=n_steps,
            duration=n_steps * dt,
            setup_s=setup_s,
            wall_s=wall_s,
            versions=package_versions("mujoco"),
            settings=manifest,
            bodies=bodies,
        )
        samples = samples_from_states(model, states, len(scene.bodies))
        return Trajectory.from_samples(steps * dt, [b.name for b in scene.bodies], samples, meta)


register(MujocoEngine())
