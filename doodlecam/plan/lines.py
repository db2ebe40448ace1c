"""Straight strokes of a job planned, sampled and checked together, in closed form.

Generated drawings are mostly short straight segments. Each one's optimum is a
trapezoid (planner._trapezoid), its fewest-period samples a discrete trapezoid
(sample.straight_samples) and its executed path a line the pen can only leave by
whole-step rounding (follow.path_deviation): per stroke that is ~100 small numpy
calls, ~0.5 ms. Here the same formulas run over arrays of strokes in two
compiled loops, and the per-stroke work left is building the result objects.

A stroke the closed forms do not cover (under one step long, whole-step ends
tilting it past the tracking tolerance, over the path tolerance) is handed back
as None for plan_stroke's general pass (doodlecam.plan.stroke.plan_one), which
decides the same way; tests/test_lines.py compares the two on random segments.
"""

from __future__ import annotations

import numba
import numpy as np

from doodlecam.geometry.spline_batch import offsets
from doodlecam.model import Profile, StrokeSamples
from doodlecam.plan.kernels import times
from doodlecam.plan.sample import TRACKING_STEPS, straight_bound

SUB = 16  # follow.SUB: points per period of the executed-path check


def eligible(ctx, stroke) -> bool:
    """Whether ``stroke`` is a straight stroke whose plan_one would take the closed forms."""
    sp = stroke.spline
    return (ctx.solver == "reach" and not ctx.nonlinear and sp.degree >= 2 and bool(np.isfinite(sp.control).all())
            and sp.straight)


def eligible_all(ctx, strokes) -> list[int]:
    """The indices of the ``eligible`` strokes, their splines' straightness found all at once
    (model.prime_splines)."""
    from doodlecam.model import prime_splines

    if ctx.solver != "reach" or ctx.nonlinear:
        return []
    splines = [s.spline for s in strokes]
    prime_splines(splines)
    straight = [i for i, sp in enumerate(splines) if sp.degree >= 2 and sp.straight]
    if not straight:
        return []
    # their control points all finite: tested on all of them at once
    controls = [splines[i].control for i in straight]
    first = offsets([len(c) for c in controls])[:-1]
    finite = np.logical_and.reduceat(np.isfinite(np.concatenate(controls)).all(axis=1), first)
    return [i for i, ok in zip(straight, finite.tolist()) if ok]


def plan_lines(ctx, strokes: list, pens: list) -> list:
    """For every stroke (all ``eligible``), what plan_one finds for it: (the planned stroke, its
    (acceleration, velocity) ratios, samples, per-period deviation, its largest), or None where the general pass is
    needed."""
    n = len(strokes)
    if n == 0:
        return []
    # (2,) rows joined by concatenate: np.array's discovery of the nesting costs twice as much
    a0 = np.concatenate([s.spline.start for s in strokes]).reshape(n, 2)
    a1 = np.concatenate([s.spline.end for s in strokes]).reshape(n, 2)
    q1 = np.concatenate([s.spline.derivative_controls[1][0] for s in strokes]).reshape(n, 2)  # q', as _trapezoid
    keys = sorted(set(pens))
    pen_idx = np.array([keys.index(p) for p in pens], np.int64)
    # per pen: the limits the plan keeps (whole-step lowered) and the ones it is checked against
    M = np.array([np.asarray(ctx.pens[p][1].M, float) for p in keys])
    lim = [(ctx.pens[p][1], ctx.pens[p][0]) for p in keys]
    cap = lambda v: np.inf if v is None else float(v)  # noqa: E731
    plan_v = np.array([lo.vmax for lo, _ in lim], float)
    plan_a = np.array([lo.amax for lo, _ in lim], float)
    plan_pen = np.array([cap(lo.pen_speed) for lo, _ in lim])
    chk_v = np.array([hi.vmax for _, hi in lim], float)
    chk_a = np.array([hi.amax for _, hi in lim], float)
    chk_pen = np.array([cap(hi.pen_speed) for _, hi in lim])
    k = np.asarray(ctx.steps, float)
    dt = float(ctx.delta_time)
    tol = TRACKING_STEPS / float(k.max())  # per axis, as sample_stroke
    if not all((x > 0).all() for x in (plan_v, plan_a, plan_pen, chk_v, chk_a, chk_pen)) or \
            not all(np.isfinite(x).all() for x in (plan_v, plan_a, chk_v, chk_a)):
        return [None] * n  # plan_stroke's own checks say what is wrong
    u = np.zeros((n, 4))
    b = np.zeros((n, 4))
    nodes = np.zeros(n, np.int64)
    ratios = np.zeros((n, 2))
    periods = np.zeros(n, np.int64)
    scale = np.zeros(n)
    _trapezoids(a0, a1, q1, pen_idx, M, plan_v, plan_a, plan_pen, chk_v, chk_a, chk_pen, k, dt, u, b, nodes, ratios,
                periods, scale)
    ok = periods > 0
    offs = np.zeros(n + 1, np.int64)
    offs[1:] = np.cumsum(periods)
    vel = np.zeros((offs[-1], 2))
    written = np.zeros((offs[-1], 2))
    su = np.zeros(offs[-1] + n)
    dev = np.zeros(offs[-1])
    tilt_ok = np.zeros(n, np.bool_)
    _samples(a0, a1, pen_idx, M, plan_v, plan_a, plan_pen, k, dt, straight_bound(tol, k, dt), periods, scale, offs, vel, written, su, dev,
             tilt_ok, SUB)
    ok &= tilt_ok
    worst = np.full(n, -np.inf)  # each stroke's largest deviation (rows of its own: periods > 0)
    has = periods > 0
    if offs[-1]:
        worst[has] = np.maximum.reduceat(dev, offs[:-1][has])
    if ctx.jerk is not None:
        ok &= worst <= ctx.path_tolerance
    worst = np.maximum(worst, 0.0).tolist()  # as deviation.max(initial=0.0)
    out: list = [None] * n
    # every profile's a and t, and every start in whole steps, at once (each row as for one stroke)
    with np.errstate(invalid="ignore", divide="ignore"):  # (the padding of 3-node rows and the rows not kept)
        acc = (b[:, 1:] - b[:, :-1]) / (2 * (u[:, 1:] - u[:, :-1]))
    t = np.zeros((n, 4))
    _times(u, b, nodes, ok, t)
    start = np.round(a0 * k) / k
    for i, q, m, o, ts, (ra, rv) in zip(np.flatnonzero(ok).tolist(), nodes[ok].tolist(), periods[ok].tolist(),
                                         offs[:-1][ok].tolist(), scale[ok].tolist(), ratios[ok].tolist()):
        # rows of arrays made here, handed over (read-only views instead of copies)
        prof = Profile.handed(u[i, :q], b[i, :q], acc[i, :q - 1], t[i, :q], "reach")
        smp = StrokeSamples.handed(start[i], vel[o:o + m], dt, ts, su[o + i:o + i + m + 1])
        out[i] = (strokes[i].with_profile(prof), (ra, rv), smp, dev[o:o + m].copy(), worst[i])
    return out


@numba.njit(cache=True, nogil=True)
def _times(u, b, nodes, ok, t):  # pragma: no cover - compiled
    """kernels.times of every kept row's nodes."""
    for i in range(u.shape[0]):
        if ok[i]:
            q = nodes[i]
            times(u[i, :q], b[i, :q], t[i, :q])


@numba.njit(cache=True, nogil=True)
def _trapezoids(a0, a1, q1, pen_idx, M, plan_v, plan_a, plan_pen, chk_v, chk_a, chk_pen, k, dt, u, b, nodes, ratios,
                periods, scale):  # pragma: no cover - compiled
    """planner._trapezoid (rest to rest) of every segment a0 -> a1 (q' = q1), its check_profile ratios
    against the unlowered limits, and sample.straight_samples' number of periods (0: under one
    step long) and time scale."""
    n = a0.shape[0]
    na = M.shape[1]
    for i in range(n):
        p = pen_idx[i]
        qx, qy = q1[i, 0], q1[i, 1]
        acc = np.inf
        cap = np.inf
        for j in range(na):
            d = abs(M[p, j, 0] * qx + M[p, j, 1] * qy)
            if d > 0.0:
                acc = min(acc, plan_a[p, j] / d)
                cap = min(cap, plan_v[p, j] ** 2 / d ** 2)
        qq = qx * qx + qy * qy
        cap = min(cap, plan_pen[p] ** 2 / qq)
        u1 = cap / (2 * acc)
        u2 = 1.0 - cap / (2 * acc)
        if u1 < u2:
            q = 4
            u[i, 1], u[i, 2], u[i, 3] = u1, u2, 1.0
        else:
            q = 3
            u[i, 1], u[i, 2] = 0.5, 1.0
        nodes[i] = q
        for c in range(1, q - 1):
            b[i, c] = min(min(2 * acc * u[i, c], 2 * acc * (1.0 - u[i, c])), cap) * (1 - 1e-12)
        # the ratios on the check grid: q'' = 0, so acceleration is theta' a and speed theta' sqrt(b)
        ra = 0.0
        rv = 0.0
        for c in range(q - 1):
            ak = (b[i, c + 1] - b[i, c]) / (2 * (u[i, c + 1] - u[i, c]))
            for j in range(na):
                d = abs(M[p, j, 0] * qx + M[p, j, 1] * qy)
                ra = max(ra, d * abs(ak) / chk_a[p, j])
        for c in range(q):
            sb = np.sqrt(b[i, c])
            for j in range(na):
                d = abs(M[p, j, 0] * qx + M[p, j, 1] * qy)
                rv = max(rv, sb * d / chk_v[p, j])
            rv = max(rv, sb * np.sqrt(qq) / chk_pen[p])
        ratios[i, 0], ratios[i, 1] = ra, rv
        # its duration, as kernels.times
        dur = 0.0
        s0 = 0.0
        for c in range(q - 1):
            s1 = np.sqrt(max(b[i, c + 1], 0.0))
            dur += 2.0 * (u[i, c + 1] - u[i, c]) / (s0 + s1)
            s0 = s1
        # straight_samples: the least m whose greatest feasible speeds reach the rounded end
        e0 = np.round(a1[i, 0] * k[0]) / k[0] - np.round(a0[i, 0] * k[0]) / k[0]
        e1 = np.round(a1[i, 1] * k[1]) / k[1] - np.round(a0[i, 1] * k[1]) / k[1]
        D = np.hypot(e0, e1)
        if D * max(k[0], k[1]) < 1.0:
            periods[i] = 0
            continue
        vcap, dv = _caps(M[p], plan_v[p], plan_a[p], plan_pen[p], e0 / D, e1 / D, dt)
        m = max(int(np.ceil(dur / dt - 1e-9)), 2)
        while True:
            reach = 0.0
            for j in range(1, m):
                reach += min(min(dv * j, dv * (m - j)), vcap)
            reach *= dt
            if reach >= D:
                break
            m += 1
        periods[i] = m
        scale[i] = dur / (m * dt)


@numba.njit(cache=True, nogil=True)
def _caps(M, vmax, amax, pen, e0, e1, dt):  # pragma: no cover - compiled
    """(largest speed, largest speed change per period) along the direction e (straight_samples)."""
    vcap = np.inf
    dv = np.inf
    for j in range(M.shape[0]):
        along = abs(M[j, 0] * e0 + M[j, 1] * e1)
        if along > 0.0:
            vcap = min(vcap, vmax[j] / along)
            dv = min(dv, amax[j] / along)
    vcap *= 1 - 1e-6
    if pen < np.inf:
        vcap = min(vcap, pen * (1 - 1e-6))
    return vcap, dv * dt * (1 - 1e-6)


@numba.njit(cache=True, nogil=True)
def _samples(a0, a1, pen_idx, M, plan_v, plan_a, plan_pen, k, dt, bound, periods, scale, offs, vel, written, su, dev,
             tilt_ok, sub):  # pragma: no cover - compiled
    """straight_samples' targets (vel), the instants' curve parameters (su, m + 1 per stroke),
    the targets as written in whole steps/s (written) and follow.path_deviation of the executed
    ramps (dev, per period); tilt_ok False where an instant is over ``bound`` (per axis) off its aim."""
    n = a0.shape[0]
    tau = np.linspace(0.0, dt, sub + 1)
    dist = np.empty(sub + 1)
    for i in range(n):
        m = periods[i]
        if m == 0:
            continue
        p = pen_idx[i]
        o = offs[i]
        s0 = np.round(a0[i, 0] * k[0]) / k[0]
        s1 = np.round(a0[i, 1] * k[1]) / k[1]
        e0 = np.round(a1[i, 0] * k[0]) / k[0] - s0
        e1 = np.round(a1[i, 1] * k[1]) / k[1] - s1
        D = np.hypot(e0, e1)
        vcap, dv = _caps(M[p], plan_v[p], plan_a[p], plan_pen[p], e0 / D, e1 / D, dt)
        reach = 0.0
        for j in range(1, m):
            reach += min(min(dv * j, dv * (m - j)), vcap)
        reach *= dt
        f = D / reach
        d0 = a1[i, 0] - a0[i, 0]
        d1 = a1[i, 1] - a0[i, 1]
        dd = d0 * d0 + d1 * d1
        # instants: where the targets' trapezoidal sum puts the pen, each aimed at the point as
        # far along the line (sample.straight_samples)
        tilt = 0.0
        prev = 0.0
        cum = 0.0
        base = o + i  # su holds m + 1 values per stroke
        su[base] = 0.0
        for j in range(1, m + 1):
            sp = min(min(dv * j, dv * (m - j)), vcap) * f if j < m else 0.0
            cum += 0.5 * dt * (prev + sp)
            prev = sp
            fr = min(cum / D, 1.0)
            su[base + j] = fr
            if j < m:
                tilt = max(tilt, max(abs(s0 + fr * e0 - (a0[i, 0] + fr * d0)) - bound[0],
                                     abs(s1 + fr * e1 - (a0[i, 1] + fr * d1)) - bound[1]))
                vel[o + j - 1, 0] = sp * (e0 / D)
                vel[o + j - 1, 1] = sp * (e1 / D)
        tilt_ok[i] = tilt <= 0.0
        # written in whole steps/s: the running sum rounded (packetfile.whole_step_targets)
        c0 = 0.0
        c1 = 0.0
        r0 = 0.0
        r1 = 0.0
        for j in range(m):
            c0 += vel[o + j, 0] * k[0]
            c1 += vel[o + j, 1] * k[1]
            n0, n1 = np.round(c0), np.round(c1)
            written[o + j, 0] = (n0 - r0) / k[0]
            written[o + j, 1] = (n1 - r1) / k[1]
            r0, r1 = n0, n1
        # the executed ramps against the line (follow.path_deviation's straight case)
        x0, x1 = s0, s1
        c0 = 0.0
        c1 = 0.0
        v0, v1 = 0.0, 0.0
        for j in range(m):
            w0, w1 = written[o + j, 0], written[o + j, 1]
            lo = su[base + j]
            hi = su[base + j + 1]
            span = max(hi - lo, 1e-9)
            lo, hi = max(lo - span / 2, 0.0), min(hi + span / 2, 1.0)
            for t in range(sub + 1):
                tt = tau[t]
                y0 = x0 + v0 * tt + (w0 - v0) * (tt * tt / (2 * dt))
                y1 = x1 + v1 * tt + (w1 - v1) * (tt * tt / (2 * dt))
                uu = min(max(((y0 - a0[i, 0]) * d0 + (y1 - a0[i, 1]) * d1) / dd, lo), hi)
                dist[t] = np.hypot(y0 - a0[i, 0] - uu * d0, y1 - a0[i, 1] - uu * d1)
            # the peak between the points: a parabola through the largest and its neighbours
            kk = min(max(np.argmax(dist), 1), sub - 1)
            fm, f0, fp = dist[kk - 1], dist[kk], dist[kk + 1]
            curv = 2 * f0 - fm - fp
            peak = f0 + ((fp - fm) ** 2 / (8 * max(curv, 1e-15)) if curv > 1e-15 else 0.0)
            dev[o + j] = max(dist.max(), min(peak, f0 + abs(fp - fm)))
            c0 += 0.5 * dt * (v0 + w0)
            c1 += 0.5 * dt * (v1 + w1)
            x0, x1 = s0 + c0, s1 + c1
            v0, v1 = w0, w1
