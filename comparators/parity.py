"""Parity: each engine's model must be physically the scene before its numbers mean anything.

Every adapter reads back from its engine, before stepping, each body's mass, inertia tensor
(about the COM, world axes), COM position and velocity and world angular velocity
(`RunMeta.bodies`). The suite checks them against the scene: mass and inertia directly, the
initial state through the total energy, linear momentum and angular momentum it implies, so a
frame mix-up (body- against world-frame omega, a principal frame applied twice) shows as a
wrong L, and a flipped velocity, which energy cannot see, as a wrong linear momentum.
"""

import numpy as np

from cases.scene import Scene
from comparators.trajectory import RunMeta

# Everything an engine stores is a double built from the same particles; 1e-9 relative leaves
# room for an engine's own re-diagonalisation of the inertia (rounding ~1e-15) and nothing more.
PARITY_RTOL = 1e-9
# An engine that keeps L or body-frame omega reads omega back through a solve with the inertia,
# which loses up to cond(I) times the arithmetic's epsilon (the bound of a backward-stable solve;
# measured up to 0.2 of it in float64): added for the scene's worst-conditioned body, so that a
# needle or a thin plate with cond(I) near 1e12 is not an adapter error.
FLOAT64_EPSILON = float(np.finfo(float).eps)
# A single-precision engine stores every quantity rounded to its epsilon and sums a few dozen of
# them in the readback: PARITY_RTOL becomes at least this many of its epsilons (7.6e-6 for
# float32; for float64 1.4e-14, below PARITY_RTOL).
PARITY_ULPS = 64


class ParityError(RuntimeError):
    """An engine's model differs from the scene; the message names engine, body and quantity."""


def body_readback(mass, inertia, x, v, w) -> dict:
    """One body's model as read back from an engine, in the form `RunMeta.bodies` stores."""
    return {
        "mass": float(mass),
        "inertia": np.asarray(inertia, dtype=float).reshape(3, 3).tolist(),
        "x": np.asarray(x, dtype=float).tolist(),
        "v": np.asarray(v, dtype=float).tolist(),
        "w": np.asarray(w, dtype=float).tolist(),
    }


def _energy_and_momenta(scene: Scene, bodies: list[dict]):
    g = np.asarray(scene.gravity)
    energy, L = 0.0, np.zeros(3)
    total = sum(b["mass"] for b in bodies)
    com = sum(b["mass"] * np.asarray(b["x"]) for b in bodies) / total
    vcom = sum(b["mass"] * np.asarray(b["v"]) for b in bodies) / total
    for b in bodies:
        m, inertia = b["mass"], np.asarray(b["inertia"])
        x, v, w = (np.asarray(b[k]) for k in ("x", "v", "w"))
        energy += 0.5 * m * v @ v + 0.5 * w @ inertia @ w - m * g @ x
        L += inertia @ w + m * np.cross(x - com, v - vcom)
    return energy, total * vcom, L


def _relative(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = np.linalg.norm(b)
    return float(np.linalg.norm(a - b) / scale) if scale > 0 else float(np.linalg.norm(a))


def parity_tolerance(scene: Scene, epsilon: float = FLOAT64_EPSILON) -> float:
    """PARITY_RTOL, or PARITY_ULPS epsilons of the engine's arithmetic if more, plus the
    rounding of a solve with the worst-conditioned body's inertia."""
    conditioning = max(np.linalg.cond(b.inertia) for b in scene.bodies)
    return max(PARITY_RTOL, PARITY_ULPS * epsilon) + float(conditioning) * epsilon


def check_parity(scene: Scene, meta: RunMeta, epsilon: float = FLOAT64_EPSILON) -> dict[str, float]:
    """Relative mismatches of mass, inertia, energy, p and L at t = 0; ParityError above
    `parity_tolerance` for an engine computing with `epsilon`."""
    expected = [
        body_readback(b.mass, b.inertia, b.com, b.velocity, b.angular_velocity)
        for b in scene.bodies
    ]
    actual = [meta.bodies[b.name] for b in scene.bodies]
    errors = {}
    for body, want, got in zip(scene.bodies, expected, actual, strict=True):
        for quantity in ("mass", "inertia"):
            errors[f"{body.name}.{quantity}"] = _relative(got[quantity], want[quantity])
    want = _energy_and_momenta(scene, expected)
    got = _energy_and_momenta(scene, actual)
    for k, quantity in enumerate(("energy", "momentum", "angular_momentum")):
        errors[quantity] = _relative(got[k], want[k])
    tolerance = parity_tolerance(scene, epsilon)
    for quantity, err in errors.items():
        if not err <= tolerance:
            raise ParityError(
                f"engine {meta.engine!r} on {scene.name!r}: {quantity} at t = 0 differs from "
                f"the scene by {err:.3g} (relative), expected at most {tolerance:.3g}"
            )
    return errors
