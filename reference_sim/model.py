"""The simulator's static model and state: struct-of-arrays float64, particles packed per body.

Particles of body b are rows `body_start[b]:body_start[b + 1]` of the particle arrays
(JAX MD's RigidPointUnion layout). The body frame is the world frame at t = 0 with its origin at
the body's centre of mass, so `offsets` are the particles' t = 0 positions minus the COM.
"""

from typing import NamedTuple

import numpy as np

from reference_sim.vec3 import tangents
from rigidmath.inertia import center_of_mass, inertia_tensor, principal_frame


class Model(NamedTuple):
    """Everything that does not change during a run.

    Attributes:
      body_start: (B + 1,) particle offsets per body.
      body_mass: (B,) kg.  inertia0, inertia0_inv: (B, 3, 3) about the COM, body frame.
      principal_axes: (B, 3, 3) rows are principal axes (body frame), det +1.
      principal_moments: (B, 3) ascending.  bound_radius: (B,) farthest particle surface (m).
      offsets: (N, 3) particle positions from the COM, body frame.  particle_mass, radius: (N,).
      particle_body: (N,) owning body.  gravity: (3,) m/s^2.
      plane_points, plane_normals: (P, 3), normals unit length, pointing into the free side.
      plane_tangents: (P, 2, 3) the two tangents (`vec3.tangents`) completing each normal to
        the contact frame of that plane's contacts.
      restitution, friction: contact e and mu.  contact: model contact at all.
      gravity_on: gravity is non-zero.
    """

    body_start: np.ndarray
    body_mass: np.ndarray
    inertia0: np.ndarray
    inertia0_inv: np.ndarray
    principal_axes: np.ndarray
    principal_moments: np.ndarray
    bound_radius: np.ndarray
    offsets: np.ndarray
    particle_mass: np.ndarray
    radius: np.ndarray
    particle_body: np.ndarray
    gravity: np.ndarray
    plane_points: np.ndarray
    plane_normals: np.ndarray
    plane_tangents: np.ndarray
    restitution: float
    friction: float
    contact: bool
    gravity_on: bool


class RigidState(NamedTuple):
    """Rigid-body state (B bodies): COM x, orientation q (w, x, y, z), COM velocity v, world L."""

    x: np.ndarray
    q: np.ndarray
    v: np.ndarray
    L: np.ndarray


class SeedState(NamedTuple):
    """The seed's state: particle positions and velocities plus its per-body cm, V and omega."""

    pos: np.ndarray
    vel: np.ndarray
    cm: np.ndarray
    V: np.ndarray
    omega: np.ndarray


def build_model(
    bodies,
    gravity,
    plane_points=None,
    plane_normals=None,
    restitution: float = 0.0,
    friction: float = 0.0,
    contact: bool = False,
) -> Model:
    """Pack bodies into a `Model`.

    Args:
      bodies: sequence of (particles (n, 4) rows x, y, z, mass at t = 0; particle radius).
      gravity: (3,).  plane_points, plane_normals: (P, 3); normals are normalised here.
      contact: whether contact is modelled (planes and particles of different bodies).
    """
    starts, masses, inertias, inv, axes, moments, bounds = [0], [], [], [], [], [], []
    offsets, pmass, radii, owner = [], [], [], []
    for b, (rows, radius) in enumerate(bodies):
        rows = np.asarray(rows, dtype=float)
        pos, m = rows[:, :3], rows[:, 3]
        r0 = pos - center_of_mass(pos, m)
        inertia = inertia_tensor(r0, m)
        w, p = principal_frame(inertia)
        starts.append(starts[-1] + len(rows))
        masses.append(m.sum())
        inertias.append(inertia)
        inv.append(np.linalg.inv(inertia))
        axes.append(np.ascontiguousarray(p.T))
        moments.append(w)
        bounds.append(np.linalg.norm(r0, axis=1).max() + radius)
        offsets.append(r0)
        pmass.append(m)
        radii.append(np.full(len(rows), float(radius)))
        owner.append(np.full(len(rows), b, dtype=np.int64))
    if plane_points is None or len(plane_points) == 0:
        plane_points = np.zeros((0, 3))
        plane_normals = np.zeros((0, 3))
    normals = np.asarray(plane_normals, dtype=float)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    g = np.asarray(gravity, dtype=float)
    return Model(
        body_start=np.asarray(starts, dtype=np.int64),
        body_mass=np.asarray(masses),
        inertia0=np.asarray(inertias),
        inertia0_inv=np.asarray(inv),
        principal_axes=np.asarray(axes),
        principal_moments=np.asarray(moments),
        bound_radius=np.asarray(bounds),
        offsets=np.concatenate(offsets),
        particle_mass=np.concatenate(pmass),
        radius=np.concatenate(radii),
        particle_body=np.concatenate(owner),
        gravity=g,
        plane_points=np.asarray(plane_points, dtype=float).reshape(-1, 3),
        plane_normals=normals.reshape(-1, 3),
        plane_tangents=np.array([tangents(tuple(n)) for n in normals]).reshape(-1, 2, 3),
        restitution=float(restitution),
        friction=float(friction),
        contact=bool(contact),
        gravity_on=bool(np.any(g != 0.0)),
    )


def rigid_initial_state(model: Model, com, velocity, angular_velocity) -> RigidState:
    """State at t = 0 from per-body COM (B, 3), velocity (B, 3), world angular velocity (B, 3)."""
    nb = len(model.body_mass)
    q = np.zeros((nb, 4))
    q[:, 0] = 1.0
    w = np.asarray(angular_velocity, dtype=float).reshape(nb, 3)
    return RigidState(
        x=np.array(com, dtype=float).reshape(nb, 3),
        q=q,
        v=np.array(velocity, dtype=float).reshape(nb, 3),
        L=np.einsum("bij,bj->bi", model.inertia0, w),
    )


def seed_initial_state(model: Model, positions, velocity, angular_velocity) -> SeedState:
    """The seed's t = 0 state from particle positions (N, 3) and per-body V, omega (B, 3).

    Particle velocities are omega x r *without* V, as the seed's create_cube! sets them.
    """
    nb = len(model.body_mass)
    pos = np.array(positions, dtype=float).reshape(-1, 3)
    cm = np.array(
        [
            center_of_mass(
                pos[model.body_start[b] : model.body_start[b + 1]],
                model.particle_mass[model.body_start[b] : model.body_start[b + 1]],
            )
            for b in range(nb)
        ]
    )
    w = np.array(angular_velocity, dtype=float).reshape(nb, 3)
    owner = model.particle_body
    return SeedState(
        pos=pos,
        vel=np.cross(w[owner], pos - cm[owner]),
        cm=cm,
        V=np.array(velocity, dtype=float).reshape(nb, 3),
        omega=w.copy(),
    )
