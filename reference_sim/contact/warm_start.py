"""The warm start: a contact that pushed last step starts from its impulses, continued along
their trend (to second order) where they change smoothly; the contacts that pushed are
remembered for the next."""

import math

from reference_sim.contact.impulses import into_disc, push
from reference_sim.contact.rows import wake_one
from reference_sim.contact.settings import TREND_AGREEMENT, TREND_NOISE
from reference_sim.jit import inlined_kernel, kernel


@kernel
def trend(model, warm_lam, at, kn, tolerance):
    """Warm-start impulses (normal, two tangents) from a contact's impulses of the last three
    steps, warm_lam[at] (age, direction), NaN where it had none: last step's, continued to
    second order (last step's change plus its change from the one before) if the last two
    changes agree (TREND_AGREEMENT) and are not rounding jitter (TREND_NOISE), projected onto
    the impulses' bounds."""
    last = (warm_lam[at, 0, 0], warm_lam[at, 0, 1], warm_lam[at, 0, 2])
    if math.isnan(warm_lam[at, 2, 0]):
        return last
    change, curve = 0.0, 0.0
    for d in range(3):
        latest = warm_lam[at, 0, d] - warm_lam[at, 1, d]
        change = max(change, abs(latest))
        curve = max(curve, abs(latest - (warm_lam[at, 1, d] - warm_lam[at, 2, d])))
    if not (curve < TREND_AGREEMENT * change and change * kn > TREND_NOISE * tolerance):
        return last
    # last + change + (change - previous change), the quadratic through the three steps
    p0 = max(3.0 * (last[0] - warm_lam[at, 1, 0]) + warm_lam[at, 2, 0], 0.0)
    p1 = 3.0 * (last[1] - warm_lam[at, 1, 1]) + warm_lam[at, 2, 1]
    p2 = 3.0 * (last[2] - warm_lam[at, 1, 2]) + warm_lam[at, 2, 2]
    p1, p2 = into_disc(model.friction, p0, p1, p2)
    return p0, p1, p2


@inlined_kernel
def warm_start(model, x, nc, buf, v, warm_keys, warm_lam, n_warm, tolerance):
    """Each contact that matches one of last step's starts from its impulses, continued along
    their trend (`trend`), applied; the impulses of the steps before go into `buf.hist` for
    `remember` (NaN: none). Both key lists are in increasing order: one merge pass matches
    them. Returns how many contacts matched."""
    at, warm = 0, 0
    for k in range(nc):
        buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2] = 0.0, 0.0, 0.0
        for age in range(2):
            for d in range(3):
                buf.hist[k, age, d] = math.nan
        while at < n_warm and warm_keys[at] < buf.keys[k]:
            at += 1
        if buf.active[k] and at < n_warm and warm_keys[at] == buf.keys[k]:
            for age in range(2):
                for d in range(3):
                    buf.hist[k, age, d] = warm_lam[at, age, d]
            warm += 1
            if buf.standby[k]:  # it pushed last step: it needs its rows
                wake_one(model, x, buf, k)
            p0, p1, p2 = trend(model, warm_lam, at, buf.kn[k], tolerance)
            buf.lam[k, 0], buf.lam[k, 1], buf.lam[k, 2] = p0, p1, p2
            if p0 != 0.0 or p1 != 0.0 or p2 != 0.0:
                a, b = buf.cands[k, 0], buf.cands[k, 2]
                push(model, buf.jac[k], a, b, v, buf.omega, p0, p1, p2)
    return warm


@inlined_kernel
def remember(nc, buf, keys, lam):
    """Keys and impulses of the contacts that pushed (normal impulse > 0), in key order, for
    the next step, with their impulses of the two steps before (`buf.hist`); returns how many.
    A contact without impulse would start from none either way."""
    n = 0
    for k in range(nc):
        if buf.lam[k, 0] > 0.0:
            keys[n] = buf.keys[k]
            for d in range(3):
                lam[n, 0, d] = buf.lam[k, d]
                lam[n, 1, d] = buf.hist[k, 0, d]
                lam[n, 2, d] = buf.hist[k, 1, d]
            n += 1
    return n
