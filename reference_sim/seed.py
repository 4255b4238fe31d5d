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
"""

import numpy as np

from reference_sim.jit import compiled
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


@compiled
def _collide_particles(model, pos, vel):
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
