"""Each run's verdict, from its trajectory and the scene, the same way for every engine.

Verdict, in precedence order:
  "diverged"   a non-finite state, or total energy above its initial value by more than
               ENERGY_GROWTH_LIMIT times the scene's energy scale (`energy_scale`);
  "dissipated" a scene without contact (`Scene.has_contact` false; no scene has damping) whose
               total energy fell below its initial value by more than ENERGY_LOSS_LIMIT times
               the energy scale: the engine took energy away that nothing in the scene can
               (damping, velocity clamping);
  "tunnelled"  at some sample a particle deeper below a plane than its radius: its centre on the
               wrong side of the plane;
  "jitter"     a scene that expects rest (`Expected.rest_com_height`) whose body still moves,
               some particle faster than JITTER_SPEED, in the final window (`final_window`);
  "ok"         none of these.

What an engine printed or warned during the run (`RunMeta.messages`) is recorded beside the
verdict (`engine_messages`), not in it: the verdict reads the states alone, the same way for
every engine, and a message does not say by itself that the physics is invalid. Where one does,
the adapter acts on it: MuJoCo's "Nan, Inf or huge value" warnings end its samples in NaN (so
"diverged", whatever other warnings come with them), and its other warnings alone fail the run
(`comparators.mujoco_engine.step_rollout`).
"""

from __future__ import annotations

import numpy as np

from cases.scene import Scene
from comparators.metrics import REST_SPEED, support_plane
from comparators.run_data import (
    RunData,
    contact_planes,
    expects_rest,
    final_window,
    particle_speeds,
)
from comparators.trajectory import Trajectory

# Besides "failed: <reason>" (no run).
VERDICTS = ("ok", "diverged", "dissipated", "tunnelled", "jitter")
# Energy growth past which a run has diverged, relative to `energy_scale`: an order of magnitude,
# a blow-up rather than an error; correct integrators stay far below it (figures behind this and
# the next thresholds: docs/measurement.md).
ENERGY_GROWTH_LIMIT = 10.0
# Energy loss past which a contact-free run has dissipated, relative to `energy_scale`: more than
# 90 %, an order of magnitude down as ENERGY_GROWTH_LIMIT is one up. Over the contact-free catalog
# at 2, 1 and 0.5 times the default dt, the reference's integrators lose at most 2.5e-4 and every
# engine's explicit ones 0.30 (Drake rk2, high_spin); the first-order implicit schemes (MuJoCo
# implicit and implicitfast, PyBullet maximal) damp, converging with dt: 0.54 / 0.32 / 0.18 on
# thin_rod. A rod spun at 1e4 rad/s loses 0.986 in those and 0.9996 in PyBullet multibody.
ENERGY_LOSS_LIMIT = 0.9
# A body that should rest "jitters" when some particle still moves faster than this in the final
# window: metrics.REST_SPEED, the suite's definition of rest, far above any engine's resting noise.
JITTER_SPEED = REST_SPEED


def energy_scale(run: RunData) -> float:
    """The energy the scene can put into motion (J): the initial kinetic energy plus, per body,
    m |g| h, with h the body's COM height above the support plane (measured along gravity) or,
    without one, its ballistic drop over the run. When that is 0 (nothing moves and nothing can
    fall) it is the kinetic energy of the whole system moving at REST_SPEED."""
    scene = run.scene
    c = run.conserved()
    t = c["t"].to_numpy()
    kinetic = float(c["kinetic_translational"].iloc[0] + c["kinetic_rotational"].iloc[0])
    g = np.asarray(scene.gravity, dtype=float)
    g_norm = float(np.linalg.norm(g))
    mass = sum(b.mass for b in scene.bodies)
    floor = 0.5 * mass * REST_SPEED**2
    if g_norm == 0.0:
        return kinetic if kinetic > 0 else floor
    down = g / g_norm
    plane = support_plane(scene) if scene.contact is not None else None
    up = -float(np.dot(plane.unit_normal, down)) if plane is not None else 0.0
    duration = t[-1] - t[0]
    drop = 0.0
    for k, body in enumerate(scene.bodies):
        a = run.arrays(k)
        if up > 0:
            h = float(np.dot(a["x"][0] - plane.point, plane.unit_normal)) / up
        else:
            h = max(0.0, float(np.dot(a["v"][0], down))) * duration + 0.5 * g_norm * duration**2
        drop += body.mass * g_norm * max(h, 0.0)
    scale = kinetic + drop
    return scale if scale > 0 else floor


def energy_growth(traj: Trajectory, scene: Scene, run: RunData | None = None) -> float:
    """Largest gain of total energy over its initial value, relative to `energy_scale`."""
    run = run or RunData(traj, scene)
    energy = run.conserved()["energy"].to_numpy()
    return float((energy.max() - energy[0]) / energy_scale(run))


def energy_loss(traj: Trajectory, scene: Scene, run: RunData | None = None) -> float:
    """Largest fall of total energy below its initial value, relative to `energy_scale`."""
    run = run or RunData(traj, scene)
    energy = run.conserved()["energy"].to_numpy()
    return float((energy[0] - energy.min()) / energy_scale(run))


def dissipated(run: RunData) -> bool:
    """True when the scene has no contact and its total energy fell below its initial value by
    more than ENERGY_LOSS_LIMIT times `energy_scale`."""
    if run.scene.has_contact:
        return False
    return energy_loss(run.traj, run.scene, run) > ENERGY_LOSS_LIMIT


def tunnelled(run: RunData) -> bool:
    """True when at some sample a particle's centre is behind a plane (its depth below the plane
    exceeds its radius); at deforming samples, when the COM is."""
    for k in range(len(run.scene.bodies)):
        com = run.arrays(k)["x"][~run.rigid(k)]
        for plane in contact_planes(run.scene):
            if (run.distances(k, plane) < 0).any():
                return True
            if ((com - plane.point) @ plane.unit_normal < 0).any():
                return True
    return False


def jitters(run: RunData) -> bool:
    """True when the scene expects rest and some body's particle moves faster than JITTER_SPEED
    in the final window."""
    if not expects_rest(run.scene):
        return False
    for k in range(len(run.scene.bodies)):
        window = final_window(run.arrays(k)["t"])
        if (particle_speeds(run, k)[window] > JITTER_SPEED).any():
            return True
    return False


def verdict(traj: Trajectory, scene: Scene, run: RunData | None = None) -> str:
    """ "diverged", "dissipated", "tunnelled", "jitter" or "ok", in that precedence (see the
    module doc)."""
    run = run or RunData(traj, scene)
    if not run.finite():
        return "diverged"
    with np.errstate(over="ignore", invalid="ignore"):  # a blown-up run's energy overflows
        if not energy_growth(traj, scene, run) <= ENERGY_GROWTH_LIMIT:
            return "diverged"
    if dissipated(run):
        return "dissipated"
    if tunnelled(run):
        return "tunnelled"
    if jitters(run):
        return "jitter"
    return "ok"
