"""An example rigidbench engine: free rigid bodies in plain numpy, registered as the plugin
`example` (this package's pyproject.toml, entry-point group `rigidbench.engines`).

Each body's state is its COM position and velocity (world frame), the unit quaternion
(w, x, y, z) that maps its placement at t = 0 to the current one, and its angular velocity in
its own frame at t = 0 axes, moved by Euler's equations I w' = -w x I w. Two fixed-step schemes:
explicit Euler (order 1) and classical Runge-Kutta 4 (order 4), the quaternion renormalised
after every step. Gravity acts; contact is not modelled, and a scene with contact is refused.
"""

from __future__ import annotations

import numpy as np

from comparators.harness import RunTimer, sample_steps
from comparators.parity import body_readback
from comparators.trajectory import Trajectory, package_versions

SCHEMES = {"euler": "explicit Euler", "rk4": "classical Runge-Kutta 4"}


def _quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products of (B, 4) quaternions, scalar first."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=1,
    )


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b of (B, 3) arrays (np.cross costs several times this on small arrays)."""
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(B, 3) vectors rotated by (B, 4) unit quaternions: q v q*."""
    qv = _quat_multiply(q, np.concatenate([np.zeros((len(v), 1)), v], axis=1))
    return _quat_multiply(qv, q * np.array([1.0, -1.0, -1.0, -1.0]))[:, 1:]


class FreeBodies:
    """Free rigid bodies under gravity; `derivative` is the right-hand side of the ODE in the
    state y = (x, v, q, w) of shapes (B, 3), (B, 3), (B, 4), (B, 3)."""

    def __init__(self, inertia: np.ndarray, gravity: np.ndarray):
        self.inertia = inertia  # (B, 3, 3) about each COM, world axes at t = 0
        self.inverse = np.linalg.inv(inertia)
        self.gravity = gravity

    def derivative(self, y):
        x, v, q, w = y
        spin = (self.inertia @ w[:, :, None])[:, :, 0]
        dw = (self.inverse @ _cross(spin, w)[:, :, None])[:, :, 0]
        dq = 0.5 * _quat_multiply(q, np.concatenate([np.zeros((len(w), 1)), w], axis=1))
        return v, np.broadcast_to(self.gravity, v.shape), dq, dw

    def step(self, y, dt: float, scheme: str):
        """One step of `scheme`; the quaternion renormalised after it."""
        if scheme == "euler":
            new = _add(y, self.derivative(y), dt)
        else:
            k1 = self.derivative(y)
            k2 = self.derivative(_add(y, k1, dt / 2))
            k3 = self.derivative(_add(y, k2, dt / 2))
            k4 = self.derivative(_add(y, k3, dt))
            slope = tuple(
                (a + 2 * b + 2 * c + d) / 6 for a, b, c, d in zip(k1, k2, k3, k4, strict=True)
            )
            new = _add(y, slope, dt)
        x, v, q, w = new
        return x, v, q / np.linalg.norm(q, axis=1, keepdims=True), w

    def sample(self, y) -> np.ndarray:
        """(B, 13) rows x, q, v, world-frame angular velocity, as the trajectory table wants."""
        x, v, q, w = y
        return np.concatenate([x, q, v, _rotate(q, w)], axis=1)


def _add(y, slope, h: float):
    return tuple(a + h * b for a, b in zip(y, slope, strict=True))


class ExampleEngine:
    """The rigidbench engine contract: name, integrators, default, orders, missing, run."""

    name = "example"
    integrators = tuple(SCHEMES)
    default_integrator = "rk4"
    orders = {"euler": 1, "rk4": 4}
    missing = None  # plain numpy: always available

    def unsupported(self, scene) -> str | None:
        """Why this engine cannot run `scene`, or None: it has no contact model."""
        return "contact is not modelled (free bodies only)" if scene.has_contact else None

    def run(self, scene, integrator: str, dt: float, duration: float) -> Trajectory:
        reason = self.unsupported(scene)
        if reason:
            raise ValueError(f"engine 'example' cannot run {scene.name!r}: {reason}")
        timer = RunTimer(scene, self.name, integrator, dt, duration)
        with timer.setup():  # the model, and what it holds at t = 0 for the parity check
            model = FreeBodies(
                np.array([b.inertia for b in scene.bodies]), np.array(scene.gravity, float)
            )
            y = (
                np.array([b.com for b in scene.bodies], dtype=float),
                np.array([b.velocity for b in scene.bodies], dtype=float),
                np.tile([1.0, 0.0, 0.0, 0.0], (len(scene.bodies), 1)),
                np.array([b.angular_velocity for b in scene.bodies], dtype=float),
            )
            bodies = {
                body.name: body_readback(body.mass, model.inertia[k], y[0][k], y[1][k], y[3][k])
                for k, body in enumerate(scene.bodies)
            }
        steps = sample_steps(timer.n_steps, timer.stride)
        samples = np.empty((len(steps), len(scene.bodies), 13))
        with timer.stepping():
            done = 0
            for row, k in enumerate(steps):
                for _ in range(k - done):
                    y = model.step(y, dt, integrator)
                done = k
                samples[row] = model.sample(y)
        settings = {
            "scheme": SCHEMES[integrator],
            "state": "x, v (world); q (t = 0 placement to now); w (body frame, t = 0 axes)",
            "quaternion": "renormalised after every step",
            "gravity": list(scene.gravity),
            "contact": "none (scenes with contact are refused)",
        }
        meta = timer.meta(package_versions("rigidbench-example-engine"), settings, bodies)
        return timer.trajectory(steps, samples, meta)
