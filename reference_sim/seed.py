"""The seed's algorithm, kept faithfully with its quirks: the baseline whose drift we measure.

One step, in the blog's order (simulate_step!):
1. particle-particle collisions (calculate_colisions!) over all pairs: overlapping particles are
   pushed apart by mass ratio and get the blog's restitution impulse. Unlike the rigid
   integrators, the seed pairs particles of the same body too, as the blog does: its body
   deforms, and on `seed_cube` same-body pairs do collide once the cube has flattened on the
   floor (from step 379 on), so skipping them would change the blog's result.
2. rigid bodies (update_rigidbody!): L = sum m (p - cm) x v_p; omega = I^-1 L with I from the
   current particles; V += g dt; cm += V dt; r += (omega x r) dt, which stretches every r by
   sqrt(1 + |omega x r|^2 dt^2 / |r|^2) (the body inflates); v_p = V + omega x r.
3. walls (apply_boundary_conditions_rigidbodies!): a particle closer to a plane than its radius
   is clamped to it, the cm is not moved, and V's normal component becomes -e times itself; the
   blog's upper walls (normals along a negative axis) apply that twice. Particle velocities are
   then V + omega x (p - cm).

Friction is not part of the seed and is ignored. The seed's gravity is the scene's.

A numerical failure ends the run, not the process: when a body's inertia tensor cannot be
inverted (singular, as a thin rod's becomes once its particles collapse onto a line, or not
finite), `seed_step` reports it, the step is left unfinished, and `run_seed` fills the
remaining samples with NaN, which the suite's verdict reads as "diverged". A sample whose
particles are no longer finite is recorded as NaN likewise (the best-fit rotation's SVD raises
on them). Runs that do not fail take exactly the same arithmetic as before.

The pair search (step 1) is the blog's, pair by pair in (i, j) order, each correction seen by
the pairs after it; from SEED_GRID_MIN_PARTICLES particles on it finds the pairs that can touch
on the rigid integrators' uniform grid (`sphere_pairs`) instead of testing all of them, with
the same collisions in the same order, bit for bit (`_collide_particles_grid` says why).
"""

import numpy as np

from reference_sim.contact.grid import sphere_pairs
from reference_sim.jit import compiled, inlined
from reference_sim.quaternion import qfrom_matrix
from rigidmath import inertia

inertia_tensor = compiled(inertia.inertia_tensor)


@compiled
def quat_from_matrix(m):
    """`rigidmath.quaternion.quat_from_matrix` on the compiled `qfrom_matrix`: unit quaternion
    (w >= 0) of the rotation matrix m (3, 3)."""
    q = np.array(
        qfrom_matrix(
            (m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1], m[2, 2])
        )
    )
    return -q if q[0] < 0 else q


# Scenes of at least this many particles find the pairs on the grid; fewer are tested pair by
# pair. The collision phase, all pairs / grid time, at the state 60 steps into the run
# (2026-11-26, AMD EPYC, 2 cores, loaded): one cube (8 particles) 0.84 to 1.58 over seed_cube,
# dropped_cube and cube_rain_1, a tie within the noise; 16 particles 1.25, 32 1.9, 64 2.0, 800
# 11.6. So the blog's own one-cube scenes keep its loop, and from two cubes on the grid is faster.
SEED_GRID_MIN_PARTICLES = 16
# A particle may move this fraction of the largest reach R from where the pairs were found
# before they are found again: pairs the grid leaves out are farther than their reach + 2 R, so
# they stay more than R / 2 from touching, far beyond any rounding. Nearer 1, fewer searches.
SEED_MOVE_LIMIT = 0.75
# Room for this many pairs a particle before the grid's second pass: the catalog's cubes have
# 3.5 (their own pairs) and a pile a few more.
SEED_PAIRS_PER_PARTICLE = 8
# The grid's margin is refused outside these (m): squares of distances neither underflow nor
# overflow, so the exactness argument's relative rounding holds (all pairs are tested instead).
SEED_GRID_SMALLEST_REACH = 1e-100
SEED_GRID_LARGEST_REACH = 1e100


@inlined
def _collide_pair(model, pos, vel, i, j):
    """One pair of the blog's loop (`_collide_particles`), the same code: if particles i and j
    overlap (and are not within 0.1 mm, the blog's guard), push them apart by mass ratio and
    give them the blog's restitution impulse, in place. Returns whether it did. The loop keeps
    its own copy, unchanged: calling this, even inlined, made seed_cube's collision phase about
    8 % slower (4.5 against 4.1 us, the host loaded); tests/test_seed_grid.py checks the two
    copies agree bit for bit."""
    e = model.restitution
    d = pos[i] - pos[j]
    r = np.sqrt(np.dot(d, d))
    reach = model.radius[i] + model.radius[j]
    if r < reach and r >= 0.0001:
        m1, m2 = model.particle_mass[i], model.particle_mass[j]
        normal = d / r
        overlap = reach - r
        pos[i] += overlap * normal * (m2 / (m1 + m2))
        pos[j] -= overlap * normal * (m1 / (m1 + m2))
        # the blog uses the corrected positions and the radius sum for |x1 - x2|
        d = pos[i] - pos[j]
        dv1 = -(1 + e) * m2 / (m1 + m2) * np.dot(vel[i] - vel[j], d) * d / reach**2
        dv2 = -(1 + e) * m1 / (m1 + m2) * np.dot(vel[j] - vel[i], -d) * (-d) / reach**2
        vel[i] += dv1
        vel[j] += dv2
        return True
    return False


@compiled
def _collide_particles(model, pos, vel):
    """The blog's pair loop over all pairs i < j in order, each seeing the corrections of those
    before it: the reference the grid's pair search (`_collide_particles_grid`) equals."""
    e = model.restitution
    n = pos.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            d = pos[i] - pos[j]
            r = np.sqrt(np.dot(d, d))
            reach = model.radius[i] + model.radius[j]
            if r < reach and r >= 0.0001:
                m1, m2 = model.particle_mass[i], model.particle_mass[j]
                normal = d / r
                overlap = reach - r
                pos[i] += overlap * normal * (m2 / (m1 + m2))
                pos[j] -= overlap * normal * (m1 / (m1 + m2))
                # the blog uses the corrected positions and the radius sum for |x1 - x2|
                d = pos[i] - pos[j]
                dv1 = -(1 + e) * m2 / (m1 + m2) * np.dot(vel[i] - vel[j], d) * d / reach**2
                dv2 = -(1 + e) * m1 / (m1 + m2) * np.dot(vel[j] - vel[i], -d) * (-d) / reach**2
                vel[i] += dv1
                vel[j] += dv2


@inlined
def _moved_far(pos, base, i, limit):
    """Whether particle i is farther than `limit` from `base[i]` (or not finite)."""
    d = pos[i] - base[i]
    return not np.dot(d, d) <= limit * limit


@compiled
def _collide_particles_grid(model, pos, vel):
    """`_collide_particles`, testing only the pairs found on the grid: the same collisions in the
    same order, bit for bit; returns how many times the pairs were found (1 + rebuilds), 0 when
    the grid was refused and every pair tested.

    Why it is exact. Let R be the largest reach (twice the largest radius). The grid finds, in
    (i, j) order, every pair whose distance is at most its reach + 2 R at the time it looks
    (`near`, each particle's reach R). Pairs are then tested in that order; after each
    collision, if one of its two particles has moved more than L = SEED_MOVE_LIMIT R since the
    pairs were found, the pairs after it are found again from the current positions. So when a
    pair the grid left out is reached by the blog's loop, both its particles are within L of
    where they were when the search left it out, and its distance is more than reach + 2 R -
    2 L = reach + R / 2: the blog's test `r < reach` fails for it, and it is skipped by both.
    Only positions move a pair's test (particles move only in collisions), and roundings of the
    distances are relative (a few 1e-16 of them: far from R / 2 with reaches between
    SEED_GRID_SMALLEST_REACH and SEED_GRID_LARGEST_REACH). Every pair found is tested by the
    blog's own code in the blog's order, so the collisions and their arithmetic are the same.
    """
    n = pos.shape[0]
    largest = 0.0
    for i in range(n):
        largest = max(largest, 2.0 * model.radius[i])
    if not (SEED_GRID_SMALLEST_REACH <= largest <= SEED_GRID_LARGEST_REACH):
        _collide_particles(model, pos, vel)
        return 0
    limit = SEED_MOVE_LIMIT * largest
    reach = np.full(n, largest)
    base = np.empty_like(pos)
    last_i, last_j = -1, -1  # the last pair tested
    searches = 0
    while True:
        base[:] = pos
        pairs = sphere_pairs(model.radius, pos, reach, SEED_PAIRS_PER_PARTICLE * n + 16)
        searches += 1
        moved = False
        for p in range(pairs.shape[0]):
            i, j = pairs[p, 0], pairs[p, 1]
            if i < last_i or (i == last_i and j <= last_j):
                continue  # tested before the search
            last_i, last_j = i, j
            if _collide_pair(model, pos, vel, i, j) and (
                _moved_far(pos, base, i, limit) or _moved_far(pos, base, j, limit)
            ):
                moved = True
                break
        if not moved:
            return searches


@compiled
def _update_bodies(model, pos, vel, cm, V, omega, dt):
    """The rigid-body update of every body; False (state partly updated) when a body's inertia
    tensor cannot be inverted."""
    for b in range(cm.shape[0]):
        lo, hi = model.body_start[b], model.body_start[b + 1]
        cm_old = cm[b].copy()
        L = np.zeros(3)
        for i in range(lo, hi):
            L += model.particle_mass[i] * np.cross(pos[i] - cm_old, vel[i])
        inertia = inertia_tensor(pos[lo:hi] - cm[b], model.particle_mass[lo:hi])
        # numba's inv raises LinAlgError on a singular or non-finite matrix: that is the failure
        try:
            inverse = np.linalg.inv(inertia)
        except Exception:
            return False
        omega[b] = inverse @ L
        if model.gravity_on:
            V[b] += model.gravity * dt
        cm[b] += V[b] * dt
        for i in range(lo, hi):
            r = pos[i] - cm_old
            r += np.cross(omega[b], r) * dt
            pos[i] = cm[b] + r
            vel[i] = V[b] + np.cross(omega[b], r)
    return True


@compiled
def _apply_walls(model, pos, vel, cm, V, omega):
    e = model.restitution
    for b in range(cm.shape[0]):
        lo, hi = model.body_start[b], model.body_start[b + 1]
        for i in range(lo, hi):
            for k in range(model.plane_points.shape[0]):
                n = model.plane_normals[k]
                s = np.dot(n, pos[i] - model.plane_points[k])
                if s < model.radius[i]:
                    pos[i] += (model.radius[i] - s) * n
                    upper = n[np.argmax(np.abs(n))] < 0
                    for _ in range(2 if upper else 1):
                        V[b] -= (1 + e) * np.dot(V[b], n) * n
        for i in range(lo, hi):
            vel[i] = V[b] + np.cross(omega[b], pos[i] - cm[b])


@compiled
def seed_step(model, pos, vel, cm, V, omega, dt):
    """One step of the blog's simulate_step!, in place; False, the step unfinished, when it
    failed numerically (a body's inertia could not be inverted)."""
    if model.contact:
        if pos.shape[0] >= SEED_GRID_MIN_PARTICLES:
            _collide_particles_grid(model, pos, vel)
        else:
            _collide_particles(model, pos, vel)
    if not _update_bodies(model, pos, vel, cm, V, omega, dt):
        return False
    if model.contact:
        _apply_walls(model, pos, vel, cm, V, omega)
    return True


@compiled
def best_fit_rotation(reference, current, masses):
    """Rotation matrix R minimising sum m |R reference_i - current_i|^2 (Kabsch); both centred."""
    h = np.zeros((3, 3))
    for i in range(reference.shape[0]):
        h += masses[i] * np.outer(reference[i], current[i])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    fix = np.eye(3)
    fix[2, 2] = d if d != 0 else 1.0
    return vt.T @ fix @ u.T


@compiled
def _record_particles(model, pos, vel, out, shape_error):
    """Body observables of the deforming particle cluster.

    x, v: mass-weighted means of particle positions and velocities; q: best-fit rotation of the
    particles from their t = 0 offsets; omega: I_rigid(q)^-1 L with L the particles' angular
    momentum about their mean, so the suite's L is exactly the particles' L; shape_error: the
    largest relative change of an inter-particle distance. A body whose particles' positions or
    velocities are not all finite is recorded as NaN.
    """
    for b in range(out.shape[0]):
        lo, hi = model.body_start[b], model.body_start[b + 1]
        if not (np.isfinite(pos[lo:hi]).all() and np.isfinite(vel[lo:hi]).all()):
            out[b] = np.nan
            shape_error[b] = np.nan
            continue
        m = model.particle_mass[lo:hi]
        mass = m.sum()
        x = np.zeros(3)
        v = np.zeros(3)
        for i in range(lo, hi):
            x += m[i - lo] * pos[i]
            v += m[i - lo] * vel[i]
        x /= mass
        v /= mass
        rel = pos[lo:hi] - x
        L = np.zeros(3)
        for i in range(lo, hi):
            L += m[i - lo] * np.cross(rel[i - lo], vel[i] - v)
        rot = best_fit_rotation(model.offsets[lo:hi], rel, m)
        out[b, 0:3] = x
        out[b, 3:7] = quat_from_matrix(rot)
        out[b, 7:10] = v
        out[b, 10:13] = rot @ (model.inertia0_inv[b] @ (rot.T @ L))
        worst = 0.0
        for i in range(lo, hi):
            for j in range(i + 1, hi):
                d0 = model.offsets[i] - model.offsets[j]
                d = pos[i] - pos[j]
                worst = max(worst, abs(np.sqrt(np.dot(d, d) / np.dot(d0, d0)) - 1.0))
        shape_error[b] = worst


@compiled
def run_seed(model, pos, vel, cm, V, omega, dt, n_steps, stride):
    """Step n_steps times in place; return (steps, samples (S, B, 13), shape_error (S, B),
    particles (S, N, 3)): the particles' world positions at each sample, since the seed's body
    deforms and its pose alone cannot place them. After a step that failed (`seed_step`) the
    run stops: the remaining samples, at the steps they were due, are NaN."""
    nb = cm.shape[0]
    n_samples = n_steps // stride + 1 + (1 if n_steps % stride else 0)
    out = np.empty((n_samples, nb, 13))
    shape = np.empty((n_samples, nb))
    particles = np.empty((n_samples, pos.shape[0], 3))
    steps = np.empty(n_samples, dtype=np.int64)
    _record_particles(model, pos, vel, out[0], shape[0])
    particles[0] = pos
    steps[0] = 0
    s = 1
    for n in range(1, n_steps + 1):
        if not seed_step(model, pos, vel, cm, V, omega, dt):
            for m in range(n, n_steps + 1):
                if m % stride == 0 or m == n_steps:
                    out[s] = np.nan
                    shape[s] = np.nan
                    particles[s] = np.nan
                    steps[s] = m
                    s += 1
            break
        if n % stride == 0 or n == n_steps:
            _record_particles(model, pos, vel, out[s], shape[s])
            particles[s] = pos
            steps[s] = n
            s += 1
    return steps, out, shape, particles
