"""Pure-Python transliteration of the blog's Julia rigid-body ("seed") simulation.

Source: the "Physics simulation - rigid bodies" blog post (Julia code, ``create_cube!``,
``simulate_step!`` and friends).  This module is the *test oracle* for the compiled ``seed``
integrator: "the fast path equals the straightforward path".  It is deliberately slow and
literal.  Every quirk of the Julia code is kept on purpose; do not "fix" anything here.

Floating-point order follows Julia's generic code where it is known:

* ``cross(a, b)`` = ``(a2*b3 - a3*b2, a3*b1 - a1*b3, a1*b2 - a2*b1)`` (LinearAlgebra).
* ``norm(v)`` of a length-3 ``Vector{Float64}`` is ``generic_norm2`` (length < NRM2_CUTOFF=32):
  ``sqrt((v1*v1 + v2*v2) + v3*v3)`` (scaled by the max-abs entry only on under/overflow).
* ``dot(a, b)`` is ``BLAS.ddot`` in Julia; here it is the sequential sum
  ``(a1*b1 + a2*b2) + a3*b3`` (OpenBLAS may contract to FMA: not reproducible here).
* ``x^2`` with a literal ``2`` is ``x*x`` (``literal_pow``).
* ``inv(I)`` is ``numpy.linalg.inv`` (Julia: triangular ``trtri`` path when ``I`` is triangular,
  e.g. the axis-aligned cube's diagonal tensor, else LU ``getrf``/``getri``); ``inv(I) * L`` is
  the sequential sum ``(A[i,1]*L1 + A[i,2]*L2) + A[i,3]*L3`` (Julia: BLAS ``gemv``).
* Broadcasts (``.+=``, ``.*``) are elementwise with one rounding per Julia operator.
* ``a * b / c * d * w`` parses as ``((a*b)/c * d) * w`` -> elementwise ``((s*d) * w[k])``.

Julia has 1-based particle indices and rigid-body ids; here particle indices are 0-based, while
body ids keep the blog's convention (``world.rigidbody[i] == 0`` means "free particle").

Aliasing (Julia binds arrays by reference; the transliteration keeps the same semantics):

* ``calculate_colision!``: ``x1, x2, v1, v2`` are the particles' own position/velocity arrays,
  so the overlap correction mutates ``x1``/``x2`` *before* ``dv1``/``dv2`` are computed (the
  impulse uses the corrected separation).  ``dv1`` and ``dv2`` are both computed before either
  is added (``v1``/``v2`` are unchanged at that point).  The internal state below uses one
  Python list per particle vector, mutated in place, so ``x1 = pos[i]`` aliases exactly as in
  Julia.
* ``create_cube!``: ``RigidBody(id, indices, cm, v_init, ω_init)``.  ``v_init = [0,0,-2]`` is a
  ``Vector{Int}`` and is *converted* (copied) to ``Vector{Float64}``; ``ω_init = [2.0,0.0,0.0]``
  is already ``Vector{Float64}`` so ``rb.ω`` *is* the caller's array (no copy), and
  ``rb.ω .= inv(I) * L`` writes into it.  In the blog each call gets fresh literals, so nothing
  observable shares it; this module copies ``omega_init`` and ``v_init`` (equivalent unless a
  caller passed the same Float64 array to two cubes, in which case Julia's bodies would share
  one ω / V array -- not reproduced).
* ``update_rigidbody!``: ``cm_old = copy(rb.cm)``; ``rb.cm .+= ...`` mutates ``rb.cm`` in place
  (``cm_old`` is a separate array).  ``r = p.position .- cm_old`` allocates a new ``r`` and
  ``r .+= cross(rb.ω, r) .* dt`` evaluates the cross product of the *old* ``r`` first.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "BlogBody",
    "BlogWorld",
    "blog_run",
    "blog_seed_cube_world",
    "blog_step",
    "blog_step_count",
    "create_cube",
]

# The blog's `const` parameters.
BLOG_TMAX = 100.0
BLOG_DT = 0.01
BLOG_BOX_SIZE = 10.0
BLOG_DAMPING = 0.0
BLOG_RESTITUTION = 0.0
BLOG_GRAVITY = (0.0, 0.0, -10.0)

# create_cube! constants.
CUBE_CORNERS = (
    (0, 0, 0),
    (1, 0, 0),
    (1, 1, 0),
    (0, 1, 0),
    (0, 0, 1),
    (1, 0, 1),
    (1, 1, 1),
    (0, 1, 1),
)
CUBE_PARTICLE_MASS = 1.0
CUBE_PARTICLE_RADIUS = 0.2

# Optional observer: on_contact(i, j, applied) is called for every pair (0-based, i < j) that
# satisfies the collision test `r < r1 + r2 && r >= 0.0001`.  `applied` is False for same-body
# pairs skipped because same_body_pairs=False (they are still tested, only to report them).
ContactCallback = Callable[[int, int, bool], None]


@dataclass
class BlogBody:
    """Julia ``RigidBody`` (``id`` kept as the optional trailing ``body_id``)."""

    particle_indices: list[int]
    cm: np.ndarray
    V: np.ndarray
    omega: np.ndarray
    body_id: int = 0


def _empty_vectors() -> np.ndarray:
    return np.zeros((0, 3), dtype=np.float64)


def _empty_scalars() -> np.ndarray:
    return np.zeros(0, dtype=np.float64)


@dataclass
class BlogWorld:
    """Julia ``particles::Vector{Particle}`` + ``rigidbodies::Vector{RigidBody}``.

    ``acceleration`` and ``material`` of the Julia ``Particle`` are never read by the
    simulation (``material`` only gates a commented-out ``@printf``) and are omitted.
    """

    positions: np.ndarray = field(default_factory=_empty_vectors)
    velocities: np.ndarray = field(default_factory=_empty_vectors)
    masses: np.ndarray = field(default_factory=_empty_scalars)
    radii: np.ndarray = field(default_factory=_empty_scalars)
    rigidbody: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    bodies: list[BlogBody] = field(default_factory=list)


# -----------------------------------------------------------------------------------------------
#                                  Julia LinearAlgebra helpers
# -----------------------------------------------------------------------------------------------
def _cross(a: Sequence[float], b: Sequence[float]) -> list[float]:
    a1, a2, a3 = a
    b1, b2, b3 = b
    return [a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1]


def _dot(a: Sequence[float], b: Sequence[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _norm(v: Sequence[float]) -> float:
    """``LinearAlgebra.generic_norm2`` for a length-3 vector."""
    maxabs = max(abs(v[0]), abs(v[1]), abs(v[2]))
    if maxabs == 0.0 or math.isinf(maxabs) or math.isnan(maxabs):
        return maxabs
    if math.isfinite(3 * maxabs * maxabs) and maxabs * maxabs != 0.0:
        s = v[0] * v[0]
        s += v[1] * v[1]
        s += v[2] * v[2]
        return math.sqrt(s)
    s = (abs(v[0]) / maxabs) ** 2
    s += (abs(v[1]) / maxabs) ** 2
    s += (abs(v[2]) / maxabs) ** 2
    return maxabs * math.sqrt(s)


def _matvec(a: np.ndarray, x: Sequence[float]) -> list[float]:
    rows = a.tolist()
    return [row[0] * x[0] + row[1] * x[1] + row[2] * x[2] for row in rows]


# -----------------------------------------------------------------------------------------------
#                        Internal list-based state (exact float64, aliasable)
# -----------------------------------------------------------------------------------------------
@dataclass
class _Body:
    particle_indices: list[int]
    cm: list[float]
    V: list[float]
    omega: list[float]


@dataclass
class _State:
    pos: list[list[float]]
    vel: list[list[float]]
    mass: list[float]
    radius: list[float]
    rigidbody: list[int]
    bodies: list[_Body]


def _load(world: BlogWorld) -> _State:
    return _State(
        pos=np.asarray(world.positions, dtype=np.float64).tolist(),
        vel=np.asarray(world.velocities, dtype=np.float64).tolist(),
        mass=[float(m) for m in world.masses],
        radius=[float(r) for r in world.radii],
        rigidbody=[int(b) for b in world.rigidbody],
        bodies=[
            _Body(
                particle_indices=[int(i) for i in b.particle_indices],
                cm=[float(c) for c in b.cm],
                V=[float(c) for c in b.V],
                omega=[float(c) for c in b.omega],
            )
            for b in world.bodies
        ],
    )


def _store(state: _State, world: BlogWorld) -> None:
    """Write the state back into the world's arrays in place (float64 -> float64, exact)."""
    world.positions[...] = np.array(state.pos, dtype=np.float64).reshape(-1, 3)
    world.velocities[...] = np.array(state.vel, dtype=np.float64).reshape(-1, 3)
    for body, b in zip(world.bodies, state.bodies, strict=True):
        body.cm[...] = b.cm
        body.V[...] = b.V
        body.omega[...] = b.omega


# -----------------------------------------------------------------------------------------------
#                                         Initialization
# -----------------------------------------------------------------------------------------------
def _calculate_center_of_mass(
    positions: list[list[float]], masses: list[float]
) -> tuple[list[float], float]:
    total_mass = 0.0
    cm_x = 0.0
    cm_y = 0.0
    cm_z = 0.0
    for p, m in zip(positions, masses, strict=True):
        total_mass += m
        cm_x += m * p[0]
        cm_y += m * p[1]
        cm_z += m * p[2]
    return [cm_x / total_mass, cm_y / total_mass, cm_z / total_mass], total_mass


def create_cube(
    world: BlogWorld,
    body_id: int,
    offset: Sequence[float],
    v_init: Sequence[float],
    omega_init: Sequence[float],
) -> None:
    """``create_cube!``: 8 unit-cube corner particles (mass 1, radius 0.2) at ``offset``.

    Particle velocities are ``cross(omega_init, r)`` with ``r = position - cm`` -- WITHOUT
    ``v_init`` (blog quirk).  The body stores ``cm``, ``V = float(v_init)``, ``omega``.
    """
    omega = [float(c) for c in omega_init]
    new_pos: list[list[float]] = []
    for corner in CUBE_CORNERS:
        # `offset .+ pos`: Int .+ Int for the blog's Int offset, converted to Float64 by the
        # Particle constructor; Float offsets add in Float64.  Both equal float(o + c) here.
        new_pos.append([float(offset[k] + corner[k]) for k in range(3)])
    new_mass = [CUBE_PARTICLE_MASS] * len(CUBE_CORNERS)

    cm, _ = _calculate_center_of_mass(new_pos, new_mass)

    new_vel = []
    for p in new_pos:
        r = [p[0] - cm[0], p[1] - cm[1], p[2] - cm[2]]
        new_vel.append(_cross(omega, r))

    first = world.positions.shape[0]
    n_new = len(CUBE_CORNERS)
    indices = list(range(first, first + n_new))
    world.positions = np.vstack([world.positions, np.array(new_pos, dtype=np.float64)])
    world.velocities = np.vstack([world.velocities, np.array(new_vel, dtype=np.float64)])
    world.masses = np.concatenate([world.masses, np.array(new_mass, dtype=np.float64)])
    world.radii = np.concatenate(
        [world.radii, np.full(n_new, CUBE_PARTICLE_RADIUS, dtype=np.float64)]
    )
    world.rigidbody = np.concatenate(
        [world.rigidbody, np.full(n_new, int(body_id), dtype=np.int64)]
    )
    world.bodies.append(
        BlogBody(
            particle_indices=indices,
            cm=np.array(cm, dtype=np.float64),
            V=np.array([float(c) for c in v_init], dtype=np.float64),
            omega=np.array(omega, dtype=np.float64),
            body_id=int(body_id),
        )
    )


# -----------------------------------------------------------------------------------------------
#                                         Collisions
# -----------------------------------------------------------------------------------------------
def _collision_test(s: _State, i: int, j: int) -> bool:
    x1 = s.pos[i]
    x2 = s.pos[j]
    r = _norm([x1[0] - x2[0], x1[1] - x2[1], x1[2] - x2[2]])
    return r < s.radius[i] + s.radius[j] and r >= 0.0001


def _calculate_colision(s: _State, i: int, j: int, restitution: float) -> bool:
    """``calculate_colision!(particles[i], particles[j])``; returns whether it fired."""
    x1 = s.pos[i]  # alias: mutated below, exactly like Julia's `x1 = particle1.position`
    x2 = s.pos[j]
    r_vec = [x1[0] - x2[0], x1[1] - x2[1], x1[2] - x2[2]]
    r = _norm(r_vec)

    rad1 = s.radius[i]
    rad2 = s.radius[j]
    if r < rad1 + rad2 and r >= 0.0001:
        v1 = s.vel[i]  # alias
        v2 = s.vel[j]  # alias
        m1 = s.mass[i]
        m2 = s.mass[j]

        normal = [(x1[0] - x2[0]) / r, (x1[1] - x2[1]) / r, (x1[2] - x2[2]) / r]
        overlap = rad1 + rad2 - r
        total_mass = m1 + m2
        # particle1.position .+= overlap * normal * (m2 / total_mass)
        f1 = m2 / total_mass
        corr1 = [overlap * normal[0] * f1, overlap * normal[1] * f1, overlap * normal[2] * f1]
        x1[0] += corr1[0]
        x1[1] += corr1[1]
        x1[2] += corr1[2]
        # particle2.position .-= overlap * normal * (m1 / total_mass)
        f2 = m1 / total_mass
        corr2 = [overlap * normal[0] * f2, overlap * normal[1] * f2, overlap * normal[2] * f2]
        x2[0] -= corr2[0]
        x2[1] -= corr2[1]
        x2[2] -= corr2[2]

        r = rad1 + rad2  # quirk: r is reassigned to the radius sum before dv
        r2 = r * r  # r^2 (literal_pow)
        # dv1 = -(1 + e) * m2 / (m1 + m2) * dot(v1 - v2, x1 - x2) * (x1 - x2) / r^2
        # (x1, x2 are the CORRECTED positions through the alias)
        d12 = [x1[0] - x2[0], x1[1] - x2[1], x1[2] - x2[2]]
        c1 = -(1.0 + restitution) * m2 / (m1 + m2)
        s1 = c1 * _dot([v1[0] - v2[0], v1[1] - v2[1], v1[2] - v2[2]], d12)
        dv1 = [s1 * d12[0] / r2, s1 * d12[1] / r2, s1 * d12[2] / r2]
        # dv2 = -(1 + e) * m1 / (m1 + m2) * dot(v2 - v1, x2 - x1) * (x2 - x1) / r^2
        # (computed BEFORE dv1 is added: v1, v2 unchanged here)
        d21 = [x2[0] - x1[0], x2[1] - x1[1], x2[2] - x1[2]]
        c2 = -(1.0 + restitution) * m1 / (m1 + m2)
        s2 = c2 * _dot([v2[0] - v1[0], v2[1] - v1[1], v2[2] - v1[2]], d21)
        dv2 = [s2 * d21[0] / r2, s2 * d21[1] / r2, s2 * d21[2] / r2]
        v1[0] += dv1[0]
        v1[1] += dv1[1]
        v1[2] += dv1[2]
        v2[0] += dv2[0]
        v2[1] += dv2[1]
        v2[2] += dv2[2]
        return True
    return False


def _calculate_colisions(
    s: _State,
    restitution: float,
    same_body_pairs: bool,
    on_contact: ContactCallback | None,
) -> None:
    n = len(s.pos)
    for i in range(n):
        for j in range(i + 1, n):
            if not same_body_pairs and s.rigidbody[i] != 0 and s.rigidbody[i] == s.rigidbody[j]:
                if on_contact is not None and _collision_test(s, i, j):
                    on_contact(i, j, False)
                continue
            if _calculate_colision(s, i, j, restitution) and on_contact is not None:
                on_contact(i, j, True)


# -----------------------------------------------------------------------------------------------
#                                         Rigid bodies
# -----------------------------------------------------------------------------------------------
def _calculate_inertia_tensor(s: _State, rb: _Body) -> np.ndarray:
    it = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    for i in rb.particle_indices:
        p = s.pos[i]
        m = s.mass[i]
        r = [p[0] - rb.cm[0], p[1] - rb.cm[1], p[2] - rb.cm[2]]  # rb.cm == cm_old here
        r2 = _dot(r, r)
        for a in range(3):
            for b in range(3):
                # I_tensor .+= p.mass .* (r2 .* I3 .- rrT)
                it[a][b] += m * (r2 * (1.0 if a == b else 0.0) - r[a] * r[b])
    return np.array(it, dtype=np.float64)


def _update_rigidbody(s: _State, rb: _Body, dt: float, gravity: Sequence[float]) -> None:
    cm_old = list(rb.cm)

    # angular momentum
    L = [0.0, 0.0, 0.0]
    for i in rb.particle_indices:
        p = s.pos[i]
        v = s.vel[i]
        m = s.mass[i]
        r = [p[0] - cm_old[0], p[1] - cm_old[1], p[2] - cm_old[2]]
        c = _cross(r, v)
        L[0] += m * c[0]
        L[1] += m * c[1]
        L[2] += m * c[2]

    inertia = _calculate_inertia_tensor(s, rb)
    omega = _matvec(np.linalg.inv(inertia), L)
    rb.omega[0] = omega[0]  # rb.ω .= inv(I) * L
    rb.omega[1] = omega[1]
    rb.omega[2] = omega[2]

    # translation (the blog hard-codes a = [0.0, 0.0, -10.0])
    a = gravity
    rb.V[0] += a[0] * dt
    rb.V[1] += a[1] * dt
    rb.V[2] += a[2] * dt
    rb.cm[0] += rb.V[0] * dt
    rb.cm[1] += rb.V[1] * dt
    rb.cm[2] += rb.V[2] * dt

    # update particles
    for i in rb.particle_indices:
        p = s.pos[i]
        # old relative position
        r = [p[0] - cm_old[0], p[1] - cm_old[1], p[2] - cm_old[2]]
        # rotate (explicit Euler: NOT a rotation, |r_perp| grows by sqrt(1 + |w|^2 dt^2))
        c = _cross(rb.omega, r)
        r[0] += c[0] * dt
        r[1] += c[1] * dt
        r[2] += c[2] * dt
        p[0] = rb.cm[0] + r[0]
        p[1] = rb.cm[1] + r[1]
        p[2] = rb.cm[2] + r[2]
        w = _cross(rb.omega, r)
        v = s.vel[i]
        v[0] = rb.V[0] + w[0]
        v[1] = rb.V[1] + w[1]
        v[2] = rb.V[2] + w[2]


def _calculate_rigidbodies(s: _State, dt: float, gravity: Sequence[float]) -> None:
    for rb in s.bodies:
        _update_rigidbody(s, rb, dt, gravity)


# -----------------------------------------------------------------------------------------------
#                                     Boundary conditions
# -----------------------------------------------------------------------------------------------
def _apply_boundary_conditions(s: _State, box_size: float, damping: float) -> None:
    for idx in range(len(s.pos)):
        if s.rigidbody[idx] == 0:
            p = s.pos[idx]
            v = s.vel[idx]
            rad = s.radius[idx]
            for d in range(3):
                if p[d] < rad:
                    p[d] = rad
                    v[d] *= -damping
                elif p[d] > box_size - rad:
                    p[d] = box_size - rad
                    v[d] *= -damping


def _apply_boundary_conditions_rigidbodies(s: _State, box_size: float, damping: float) -> None:
    for rb in s.bodies:
        for i in rb.particle_indices:
            p = s.pos[i]
            rad = s.radius[i]
            for d in range(3):
                if p[d] < rad:
                    p[d] = rad
                    rb.V[d] *= -damping
                elif p[d] > box_size - rad:
                    p[d] = box_size - rad
                    rb.V[d] *= -damping
                    rb.V[d] *= -damping  # quirk: applied twice on the upper walls

        # particle velocities from rigid body (cm is NOT moved by the clamping)
        for i in rb.particle_indices:
            p = s.pos[i]
            r = [p[0] - rb.cm[0], p[1] - rb.cm[1], p[2] - rb.cm[2]]
            w = _cross(rb.omega, r)
            v = s.vel[i]
            v[0] = rb.V[0] + w[0]
            v[1] = rb.V[1] + w[1]
            v[2] = rb.V[2] + w[2]


# -----------------------------------------------------------------------------------------------
#                                      Main simulation step
# -----------------------------------------------------------------------------------------------
def _simulate_step(
    s: _State,
    dt: float,
    gravity: Sequence[float],
    box_size: float,
    damping: float,
    restitution: float,
    same_body_pairs: bool,
    on_contact: ContactCallback | None,
) -> None:
    _calculate_colisions(s, restitution, same_body_pairs, on_contact)
    _calculate_rigidbodies(s, dt, gravity)
    _apply_boundary_conditions(s, box_size, damping)
    _apply_boundary_conditions_rigidbodies(s, box_size, damping)


def _params(
    dt: float,
    gravity: Sequence[float],
    box_size: float,
    damping: float,
    restitution: float,
) -> tuple[float, tuple[float, float, float], float, float, float]:
    g = tuple(float(c) for c in gravity)
    if len(g) != 3:
        raise ValueError("gravity must be a 3-vector")
    return float(dt), g, float(box_size), float(damping), float(restitution)


def blog_step(world: BlogWorld, **params) -> None:
    """One ``simulate_step!``; mutates ``world`` in place. Keywords as for :func:`blog_run`."""
    blog_run(world, 1, **params)


def blog_run(
    world: BlogWorld,
    n_steps: int,
    *,
    dt: float = BLOG_DT,
    gravity: Sequence[float] = BLOG_GRAVITY,
    box_size: float = BLOG_BOX_SIZE,
    damping: float = BLOG_DAMPING,
    restitution: float = BLOG_RESTITUTION,
    same_body_pairs: bool = True,
    on_contact: ContactCallback | None = None,
) -> None:
    """``n_steps`` calls of ``simulate_step!``; mutates ``world`` in place.

    Bit-identical to ``n_steps`` separate :func:`blog_step` calls (the state is converted to
    Python floats once, which is exact).
    """
    dt_, g, box, damp, rest = _params(dt, gravity, box_size, damping, restitution)
    s = _load(world)
    for _ in range(int(n_steps)):
        _simulate_step(s, dt_, g, box, damp, rest, same_body_pairs, on_contact)
    _store(s, world)


def blog_seed_cube_world() -> BlogWorld:
    """The blog's ``main()`` scene: one cube at (3,3,7), v (0,0,-2), omega (2,0,0)."""
    world = BlogWorld()
    create_cube(world, 1, (3, 3, 7), (0, 0, -2), (2.0, 0.0, 0.0))
    return world


def blog_step_count(tmax: float = BLOG_TMAX, dt: float = BLOG_DT) -> int:
    """Steps taken by ``t = 0.0; while t < tmax; simulate_step!; t += dt; end`` (float64)."""
    t = 0.0
    n = 0
    tmax = float(tmax)
    dt = float(dt)
    while t < tmax:
        t += dt
        n += 1
    return n
