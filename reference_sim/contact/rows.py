"""Assembly: each candidate's gap, Jacobian rows and inverse masses; rows kept while the bodies
have not moved; candidates beyond reach left on standby until a solve needs them.

`jac[k, d]` (5, 3), d = 0 the normal and 1, 2 the tangents: the direction, then for body a the
lever arm r_a x d and the turn I_a^-1 (r_a x d), then for body b the same (zeros for a plane).
"""

import math

from reference_sim.contact.buffers import COUNT_STANDBY
from reference_sim.contact.frames import particle, reach_into
from reference_sim.contact.settings import IMPACT_SLACK
from reference_sim.jit import inlined_kernel, kernel
from reference_sim.vec3 import add, cross, dot, flat, mat_vec, row, scale, sub, tangents


@kernel
def contact_geometry(model, x, rot, cands, k):
    """Normal n (from b towards a), gap (m), lever arms r_a, r_b from each COM to contact k.

    `rot` holds the bodies' rotation matrices (`frames_into`).
    """
    a, i, b, j = cands[k, 0], cands[k, 1], cands[k, 2], cands[k, 3]
    pa = particle(model, x, rot, a, i)
    if b < 0:
        n = row(model.plane_normals, j)
        gap = dot(n, sub(pa, row(model.plane_points, j))) - model.radius[i]
        point = sub(pa, scale(model.radius[i], n))
        return n, gap, sub(point, row(x, a)), (0.0, 0.0, 0.0)
    pb = particle(model, x, rot, b, j)
    d = sub(pa, pb)
    dist = math.sqrt(dot(d, d))
    n = scale(1.0 / dist, d) if dist > 0 else (0.0, 0.0, 1.0)
    gap = dist - model.radius[i] - model.radius[j]
    point = scale(0.5, add(sub(pa, scale(model.radius[i], n)), add(pb, scale(model.radius[j], n))))
    return n, gap, sub(point, row(x, a)), sub(point, row(x, b))


@kernel
def _invert3(m):
    """Invert the symmetric 3 x 3 matrix m (9,) (row major) in place, by cofactors."""
    c00 = m[4] * m[8] - m[5] * m[7]
    c01 = m[5] * m[6] - m[3] * m[8]
    c02 = m[3] * m[7] - m[4] * m[6]
    c11 = m[0] * m[8] - m[2] * m[6]
    c12 = m[2] * m[3] - m[0] * m[5]
    c22 = m[0] * m[4] - m[1] * m[3]
    scale = 1.0 / (m[0] * c00 + m[1] * c01 + m[2] * c02)
    m[0], m[1], m[2] = c00 * scale, c01 * scale, c02 * scale
    m[3], m[4], m[5] = c01 * scale, c11 * scale, c12 * scale
    m[6], m[7], m[8] = c02 * scale, c12 * scale, c22 * scale


@inlined_kernel
def assemble(model, x, nc, gate, buf, kept, standby=False):
    """Per candidate k < nc of `buf`: its gap, whether it acts (`buf.acting[k]`, or its gap is
    at most `gate`), its Jacobian rows and its normal and tangent inverse masses.

    A row k < `kept` that already holds them for the same contact (`buf.made[k] ==
    buf.keys[k]`) keeps them: the caller vouches that rows below `kept` were assembled at the
    bodies' current pose to within rounding (`rigid.POSE_ROUNDING`), so they are what this
    would compute to within rounding. (A row past them may hold the same contact assembled at
    an older pose.) Records in `buf.made` which rows it assembled. With `standby`, an active
    contact whose gap its bodies' reach cannot close (`closes`) is left on standby
    (`buf.standby[k]`): gap only, no rows, until `wake` finds it needed."""
    buf.counts[COUNT_STANDBY] = 0
    for k in range(nc):
        buf.standby[k] = False
        if k < kept and buf.made[k] == buf.keys[k]:
            buf.active[k] = buf.acting[k] or buf.gap[k] <= gate
            continue
        n, buf.gap[k], ra, rb = contact_geometry(model, x, buf.rot, buf.cands, k)
        buf.active[k] = buf.acting[k] or buf.gap[k] <= gate
        buf.standby[k] = standby and buf.active[k] and not closes(buf, buf.reach, k)
        buf.made[k] = buf.keys[k] if buf.active[k] and not buf.standby[k] else -1
        buf.counts[COUNT_STANDBY] += buf.standby[k]
        if buf.made[k] >= 0:
            assemble_rows(model, buf, k, n, ra, rb)


@kernel
def closes(buf, reach, k):
    """Whether contact k's bodies, each moving at most its `reach` (m) in the step, could
    close its gap (to within IMPACT_SLACK, the impact test's)."""
    a, b = buf.cands[k, 0], buf.cands[k, 2]
    return not buf.gap[k] > reach[a] + (reach[b] if b >= 0 else 0.0) + IMPACT_SLACK


@inlined_kernel
def assemble_rows(model, buf, k, n, ra, rb):
    """Contact k's Jacobian rows and inverse masses, from its normal n and lever arms ra, rb
    (`contact_geometry`)."""
    cands, inv, jac = buf.cands, buf.inv, buf.jac
    a, b = cands[k, 0], cands[k, 2]
    # a plane contact's tangents are its plane's, fixed (`Model.plane_tangents`): no square
    # root and division ahead of the rows
    if b < 0:
        pt, j = model.plane_tangents, cands[k, 3]
        t1, t2 = (
            (pt[j, 0, 0], pt[j, 0, 1], pt[j, 0, 2]),
            (pt[j, 1, 0], pt[j, 1, 1], pt[j, 1, 2]),
        )
    else:
        t1, t2 = tangents(n)
    for d in range(3):
        direction = n if d == 0 else (t1 if d == 1 else t2)
        rows = jac[k, d]
        arm_a = cross(ra, direction)
        arm_b = cross(rb, direction)
        turn_a = mat_vec(flat(inv, a), arm_a)
        turn_b = mat_vec(flat(inv, b), arm_b) if b >= 0 else (0.0, 0.0, 0.0)
        for i in range(3):
            rows[0, i] = direction[i]
            rows[1, i] = arm_a[i]
            rows[2, i] = turn_a[i]
            rows[3, i] = arm_b[i] if b >= 0 else 0.0
            rows[4, i] = turn_b[i]
    _inverse_masses(model, buf, k, a, b)


@inlined_kernel
def _inverse_masses(model, buf, k, a, b):
    """Contact k's inverse 3 x 3 mass K = J M^-1 J^T from its rows: its normal entry `kn`, its
    tangents' 2 x 2 `kt` and their inverse `kt_inv`, the normal-tangent entries `kc`, and
    the inverse of K, `k_inv`."""
    jac, kn, kt, kt_inv, k_inv = buf.jac, buf.kn, buf.kt, buf.kt_inv, buf.k_inv
    inv_mass = 1.0 / model.body_mass[a] + (1.0 / model.body_mass[b] if b >= 0 else 0.0)
    for d in range(3):
        for e in range(d, 3):
            rd, re = jac[k, d], jac[k, e]
            entry = 0.0
            for i in range(3):
                entry += inv_mass * rd[0, i] * re[0, i] + rd[1, i] * re[2, i]
                if b >= 0:  # a plane's rows 3 and 4 are zeros
                    entry += rd[3, i] * re[4, i]
            k_inv[k, 3 * d + e] = entry  # K itself, inverted below
            k_inv[k, 3 * e + d] = entry
            if d == 0 and e == 0:
                kn[k] = entry
            elif d == 0:
                buf.kc[k, e - 1] = entry
            else:
                kt[k, 2 * (d - 1) + (e - 1)] = entry
                kt[k, 2 * (e - 1) + (d - 1)] = entry
    det = kt[k, 0] * kt[k, 3] - kt[k, 1] * kt[k, 2]
    kt_inv[k, 0], kt_inv[k, 1] = kt[k, 3] / det, -kt[k, 1] / det
    kt_inv[k, 2], kt_inv[k, 3] = -kt[k, 2] / det, kt[k, 0] / det
    _invert3(k_inv[k])


@inlined_kernel
def wake_one(model, x, buf, k):
    """Take contact k off standby: its rows assembled, busy until its first update."""
    n, buf.gap[k], ra, rb = contact_geometry(model, x, buf.rot, buf.cands, k)
    assemble_rows(model, buf, k, n, ra, rb)
    buf.made[k], buf.standby[k], buf.slack[k] = buf.keys[k], False, -math.inf
    buf.counts[COUNT_STANDBY] -= 1


@inlined_kernel
def wake(model, x, nc, dt, buf, v, n_busy):
    """Wake the contacts on standby (`assemble`) whose gap the bodies, at their velocities now
    (as the solve has changed them), could close within the step (`closes`): they join the
    busy ones in `buf.busy`. Returns the new count of busy contacts. A contact left on standby
    has a normal speed above its target -gap / dt: a normal update would leave it no impulse."""
    if buf.counts[COUNT_STANDBY] == 0:
        return n_busy
    reach_into(model, v, buf.omega, dt, (0.0, 0.0, 0.0), buf.reach)  # as the drift will use
    for k in range(nc):
        if buf.standby[k]:
            if closes(buf, buf.reach, k):
                wake_one(model, x, buf, k)
                buf.busy[n_busy] = k
                n_busy += 1
    return n_busy
