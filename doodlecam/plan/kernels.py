"""Compiled inner loops of the planner (numba).

They run per grid interval at every plan (rows, the two reachability passes,
the checks, the grid and the times), so they are compiled: the same loops in
Python would be ~100x slower. This module is imported only when a stroke is
planned (numba's import costs ~0.3 s).
"""

import math

import numba
import numpy as np

from doodlecam.geometry.kernels import _point, span_at, span_taylor

_EPS = 1e-12


@numba.njit(cache=True, nogil=True, inline="always")
def _product_rows(sq, T2, g, k, r, pa, pb, tot, beta, gamma):  # pragma: no cover - compiled
    n2 = sq.shape[0]
    # (1 - tau) sq and tau sq in power form, then to Bernstein
    for j in range(n2):
        pa[j] = sq[j] - (sq[j - 1] if j > 0 else 0.0)
        pb[j] = sq[j - 1] if j > 0 else 0.0
    for m in range(n2):
        a_ = 0.0
        b_ = 0.0
        for j in range(m + 1):
            a_ += T2[m, j] * pa[j]
            b_ += T2[m, j] * pb[j]
        tot[k, r] = a_ + b_  # the (1 - tau) and tau parts sum to sq
        beta[k, r] = b_
        gamma[k, r] = g
        r += 1
    return r


@numba.njit(cache=True, nogil=True)
def bernstein_rows(T, bp, mid, u, M, vmax, amax, pen2, T1, T2, tot, beta, gamma):  # pragma: no cover - compiled
    """The rows of every grid interval [u_k, u_k+1] (constraints.bernstein_rows).
    T[s, i]: Taylor coefficients of knot span s ([bp[s], bp[s+1]]) at mid[s]
    (geometry.kernels.span_taylor); u must contain every breakpoint. Each
    interval's derivatives come from its span's polynomial, shifted to u_k
    (the right side of a knot), instead of one spline evaluation per order
    and node. T1, T2: power -> Bernstein matrices of degree p-1, 2p-1."""
    p = T.shape[1] - 1
    K = u.shape[0] - 1
    nseg = T.shape[0]
    na = M.shape[0]
    n2 = 2 * p  # coefficients of theta'^2 b(tau)
    g = np.empty((2, p + 1))
    dq = np.zeros((2, p))
    ddq = np.zeros((2, p))
    P = np.zeros(p)
    Q = np.zeros(p)
    sq = np.zeros(2 * p)
    pa = np.zeros(2 * p)
    pb = np.zeros(2 * p)
    s = 0
    for k in range(K):
        while s + 1 < nseg and u[k] >= bp[s + 1]:
            s += 1
        x = u[k] - mid[s]
        hk = u[k + 1] - u[k]
        for c in range(2):
            for i in range(p + 1):
                g[c, i] = T[s, i, c]
            for i in range(p):  # Taylor shift: g[i] = q^(i)(u_k) / i!
                for j in range(p - 1, i - 1, -1):
                    g[c, j] += x * g[c, j + 1]
            f = 1.0  # h^j
            for j in range(p):
                dq[c, j] = (j + 1) * g[c, j + 1] * f
                ddq[c, j] = (j + 1) * (j + 2) * g[c, j + 2] * f if j + 2 <= p else 0.0
                f *= hk
        r = 0
        for i in range(na):
            for j in range(p):
                t1 = M[i, 0] * dq[0, j] + M[i, 1] * dq[1, j]
                Q[j] = M[i, 0] * ddq[0, j] + M[i, 1] * ddq[1, j]
                P[j] = t1
            for j in range(p - 1, 0, -1):
                P[j] += 2.0 * hk * Q[j - 1]
            # acceleration: a_k P(tau) + b(tau) Q(tau) with a_k = (b_k+1 - b_k)/(2h)
            for m in range(p):
                pb_ = 0.0
                qb_ = 0.0
                for j in range(m + 1):
                    pb_ += T1[m, j] * P[j]
                    qb_ += T1[m, j] * Q[j]
                c1 = pb_ / (2.0 * hk)
                tot[k, r] = qb_  # the coefficient of b_k itself: no 1/h cancellation
                beta[k, r] = c1
                gamma[k, r] = amax[i]
                tot[k, r + 1] = -qb_
                beta[k, r + 1] = -c1
                gamma[k, r + 1] = amax[i]
                r += 2
            # velocity: theta'(tau)^2 (b_k (1 - tau) + b_k+1 tau)
            for j in range(n2):
                sq[j] = 0.0
            for j1 in range(p):
                t1a = M[i, 0] * dq[0, j1] + M[i, 1] * dq[1, j1]
                for j2 in range(p):
                    sq[j1 + j2] += t1a * (M[i, 0] * dq[0, j2] + M[i, 1] * dq[1, j2])
            r = _product_rows(sq, T2, vmax[i] * vmax[i], k, r, pa, pb, tot, beta, gamma)
        if pen2 > 0.0:
            for j in range(n2):
                sq[j] = 0.0
            for j1 in range(p):
                for j2 in range(p):
                    sq[j1 + j2] += dq[0, j1] * dq[0, j2] + dq[1, j1] * dq[1, j2]
            r = _product_rows(sq, T2, pen2, k, r, pa, pb, tot, beta, gamma)


@numba.njit(cache=True, nogil=True)
def span_measures(T, half, gx, gw, length, turning):  # pragma: no cover - compiled
    """Arc length and total turning |kappa| ds of every knot span from its Taylor
    coefficients T (at the midpoint; half = half the span's width in u), by
    Gauss-Legendre nodes gx and weights gw on [-1, 1]."""
    p = T.shape[1] - 1
    for s in range(T.shape[0]):
        ln = 0.0
        tn = 0.0
        for m in range(gx.shape[0]):
            t = half[s] * gx[m]
            d1x = 0.0
            d1y = 0.0
            d2x = 0.0
            d2y = 0.0
            for i in range(p, 0, -1):  # Horner on q' and q''
                d1x = d1x * t + i * T[s, i, 0]
                d1y = d1y * t + i * T[s, i, 1]
                if i >= 2:
                    d2x = d2x * t + i * (i - 1) * T[s, i, 0]
                    d2y = d2y * t + i * (i - 1) * T[s, i, 1]
            sp2 = d1x * d1x + d1y * d1y
            ln += gw[m] * np.sqrt(sp2)
            if sp2 > 0.0:  # where the pen stands still (a span of equal controls) it does not turn
                tn += gw[m] * abs(d1x * d2y - d1y * d2x) / sp2
        length[s] = half[s] * ln
        turning[s] = half[s] * tn


@numba.njit(cache=True, nogil=True, inline="always")
def _newton_end(cu0, cu1, nu, cl0, cl1, nl, x, stop, direction):  # pragma: no cover - compiled
    """The end of {x : min_i (cu0 + cu1 x) >= max_j (cl0 + cl1 x)} reached from x
    moving in ``direction`` (-1: down from an upper bound, +1: up from a lower
    bound), not past ``stop``; NaN if the steps fail (the caller then
    eliminates every pair)."""
    for _ in range(16):
        ui = 0
        uv = cu0[0] + cu1[0] * x
        for i in range(1, nu):
            v = cu0[i] + cu1[i] * x
            if v < uv:
                uv = v
                ui = i
        lj = 0
        lv = cl0[0] + cl1[0] * x
        for j in range(1, nl):
            v = cl0[j] + cl1[j] * x
            if v > lv:
                lv = v
                lj = j
        if uv >= lv:
            return x
        d0 = cu0[ui] - cl0[lj]
        d1 = cu1[ui] - cl1[lj]
        if d1 * direction <= 0.0:
            return np.nan  # the active pair does not rise that way: no root there (or a tie)
        xn = -d0 / d1
        if (xn - x) * direction <= 0.0:
            return x  # the active pair's root, to rounding
        if (xn - stop) * direction > 0.0:
            return np.nan
        x = xn
    return np.nan


@numba.njit(cache=True, nogil=True)
def reach_passes(tot, beta, gamma, ub, b0, bN, b, lo, hi):  # pragma: no cover - compiled
    K, R = tot.shape
    lo[K] = bN
    hi[K] = bN
    cu0 = np.empty(R + 1)
    cu1 = np.empty(R + 1)
    cl0 = np.empty(R + 1)
    cl1 = np.empty(R + 1)
    for k in range(K - 1, -1, -1):
        # bounds on y = b_k+1 as affine functions of x = b_k
        nu = 0
        nl = 0
        xmin = 0.0
        xmax = ub[k]
        # Bounds on y = b_k+1 written as y = x + c0 + c1 x: rows give slopes
        # 1 + c1 with c1 = -tot / beta tiny on fine grids, so c1 is kept apart
        # from the 1 (no cancellation); the set bounds hi, lo have c1 = -1.
        cu0[nu] = hi[k + 1]
        cu1[nu] = -1.0
        nu += 1
        cl0[nl] = lo[k + 1]
        cl1[nl] = -1.0
        nl += 1
        for r in range(R):
            # tot x + bb (y - x) <= g  ->  y <= (bb > 0) or >= (bb < 0) x + (g - tot x) / bb
            t = tot[k, r]
            bb = beta[k, r]
            g = gamma[k, r]
            if bb > _EPS or bb < -_EPS:
                if bb > 0:
                    cu0[nu] = g / bb
                    cu1[nu] = -t / bb
                    nu += 1
                else:
                    cl0[nl] = g / bb
                    cl1[nl] = -t / bb
                    nl += 1
            elif t > _EPS:
                xmax = min(xmax, g / t)
            elif t < -_EPS:
                xmin = max(xmin, g / t)
        # The feasible x are where g(x) = min upper - max lower >= 0: g is concave
        # and piecewise linear, so Newton steps on its active pieces reach the
        # ends of that interval exactly in a few evaluations of the nu + nl
        # lines (not nu * nl pairs). Anything unusual (no root, a tie with no
        # progress, many steps) takes the Fourier-Motzkin elimination of every
        # pair, which the steps equal when they succeed.
        hi_x = _newton_end(cu0, cu1, nu, cl0, cl1, nl, xmax, xmin, -1.0)
        lo_x = _newton_end(cu0, cu1, nu, cl0, cl1, nl, xmin, xmax, 1.0)
        if hi_x == hi_x and lo_x == lo_x and lo_x <= hi_x:  # (NaN: the steps failed)
            xmin, xmax = lo_x, hi_x
        else:
            for i in range(nu):
                for j in range(nl):
                    d0 = cu0[i] - cl0[j]
                    d1 = cu1[i] - cl1[j]
                    if d1 < 0.0:
                        xmax = min(xmax, -d0 / d1)
                    elif d1 > 0.0:
                        xmin = max(xmin, -d0 / d1)
                    elif d0 < 0.0:
                        return k + 1  # infeasible interval
        if xmax < xmin:
            if xmax < xmin - 1e-9 * max(1.0, abs(xmin)):
                return k + 1
            xmax = xmin
        lo[k] = xmin
        hi[k] = xmax
    if b0 > hi[0] * (1 + 1e-9) + 1e-300 or b0 < lo[0] * (1 - 1e-9) - 1e-300:
        return -1  # the start state cannot reach the end
    b[0] = b0
    for k in range(K):
        x = b[k]
        y = hi[k + 1]
        ylo = lo[k + 1]
        for r in range(R):
            bb = beta[k, r]
            if bb > _EPS:
                y = min(y, x + (gamma[k, r] - tot[k, r] * x) / bb)
            elif bb < -_EPS:
                ylo = max(ylo, x + (gamma[k, r] - tot[k, r] * x) / bb)
        if y < ylo:  # rounding only: x is controllable, so the range is not empty
            y = ylo
        # Stay inside the controllable set: where the profile rides a limit
        # curve the lower bounds have slopes > 1, and a rounding-level excess
        # left outside it would grow geometrically step after step.
        b[k + 1] = max(min(y, hi[k + 1]), 0.0)
    b[K] = bN
    return 0


@numba.njit(cache=True, nogil=True)
def max_ratio(tot, beta, gamma, b):  # pragma: no cover - compiled
    """max over rows of (tot b_k + beta (b_k+1 - b_k)) / gamma (gamma = inf skipped)."""
    K, R = tot.shape
    worst = 0.0
    for k in range(K):
        for r in range(R):
            g = gamma[k, r]
            if g < np.inf:
                v = tot[k, r] * b[k] + beta[k, r] * (b[k + 1] - b[k])
                if v > worst * g:  # divide only when it may be the worst (g > 0)
                    worst = v / g
    return worst


@numba.njit(cache=True, nogil=True)
def interval_worst(b, h, t1, t2, sp, amax, vmax, pen, refine):  # pragma: no cover - compiled
    """Worst (acceleration, velocity, pen speed) / limit per grid interval (width
    h) from the actuator derivatives t1, t2 ((K (refine + 1), n_act)) and |q'|
    (sp) at refine + 1 evenly spaced points of each; b is linear in between.
    One pass without temporaries: the numpy version spent 3/4 of planning here."""
    K = b.shape[0] - 1
    R = refine + 1
    na = t1.shape[1]
    wa = np.zeros(K)
    wv = np.zeros(K)
    wp = np.zeros(K)
    for k in range(K):
        a = (b[k + 1] - b[k]) / (2.0 * h[k])
        for r in range(R):
            tt = r / refine
            bb = b[k] * (1.0 - tt) + b[k + 1] * tt
            sb = np.sqrt(max(bb, 0.0))
            i = k * R + r
            for j in range(na):
                acc = abs(t1[i, j] * a + t2[i, j] * bb) / amax[j]
                vel = abs(t1[i, j]) * sb / vmax[j]
                if acc > wa[k]:
                    wa[k] = acc
                if vel > wv[k]:
                    wv[k] = vel
            if pen > 0.0:
                p = sp[i] * sb / pen
                if p > wp[k]:
                    wp[k] = p
    return wa, wv, wp


@numba.njit(cache=True, nogil=True)
def grid_fill(bp, n, out):  # pragma: no cover - compiled
    """out = every breakpoint bp[s] and n[s] - 1 evenly spaced points after it
    in its span, then 1 (planner.make_grid)."""
    i = 0
    for s in range(n.shape[0]):
        w = (bp[s + 1] - bp[s]) / n[s]
        for j in range(n[s]):
            out[i] = bp[s] + w * j
            i += 1
    out[i] = 1.0


@numba.njit(cache=True, nogil=True)
def times(u, b, t):  # pragma: no cover - compiled
    """t[k] = time (s) at node k when b = u-dot^2 is linear in u between nodes:
    each interval takes 2 h / (sqrt b_k + sqrt b_k+1) (inf where both are 0)."""
    t[0] = 0.0
    s0 = np.sqrt(max(b[0], 0.0))
    for k in range(u.shape[0] - 1):
        s1 = np.sqrt(max(b[k + 1], 0.0))
        den = s0 + s1
        t[k + 1] = t[k] + (2.0 * (u[k + 1] - u[k]) / den if den > 0.0 else np.inf)
        s0 = s1


@numba.njit(cache=True, nogil=True)
def spline_interval_worst(c1, c2, k, nseg, u, tau, b, M, amax, vmax, pen):  # pragma: no cover - compiled
    """interval_worst for linear kinematics (theta = M q) straight from the spline: q' and
    q'' (control points c1, c2 of degrees k - 1, k - 2 over nseg spans) evaluated at
    u_k + tau h_k (the last point: the float below u_k+1, the interval's side of a knot) inside the loop, so the 20x check grid is never
    stored (its arrays cost more than the arithmetic). The same points as the numpy version
    (tests/test_plan_kernels.py compares them)."""
    return spline_interval_worst_where(c1, c2, k, nseg, u, tau, b, M, amax, vmax, pen, np.empty(0, np.bool_))


@numba.njit(cache=True, nogil=True)
def spline_interval_worst_where(c1, c2, k, nseg, u, tau, b, M, amax, vmax, pen, which):  # pragma: no cover - compiled
    """spline_interval_worst on the intervals i where which[i] (all where ``which`` is empty), 0 elsewhere."""
    K = u.shape[0] - 1
    R = tau.shape[0]
    refine = R - 1
    na = M.shape[0]
    N = np.empty(k + 1)
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    wa = np.zeros(K)
    wv = np.zeros(K)
    wp = np.zeros(K)
    kt = knot_table(k, nseg)
    top_a = np.empty(na)
    top_v = np.empty(na)
    for i in range(K):
        if which.shape[0] > 0 and not which[i]:
            continue
        h = u[i + 1] - u[i]
        a = (b[i + 1] - b[i]) / (2.0 * h)
        top_a[:] = 0.0
        top_v[:] = 0.0
        top_p = 0.0
        for r in range(R):
            x = np.nextafter(u[i + 1], -np.inf) if r == refine else u[i] + tau[r] * h
            x = min(max(x, 0.0), 1.0)
            sp = min(max(int(x * nseg), 0), nseg - 1)
            if k == 3 and 2 <= sp < nseg - 2:
                # a cubic's inner span: q' and q'' in closed form (uniform quadratic and
                # linear bases), 3x cheaper than Cox-de Boor; the edges and other degrees use it
                t = x * nseg - sp
                n0, n2 = 0.5 * (1.0 - t) * (1.0 - t), 0.5 * t * t
                n1 = 1.0 - n0 - n2
                d1x = n0 * c1[sp, 0] + n1 * c1[sp + 1, 0] + n2 * c1[sp + 2, 0]
                d1y = n0 * c1[sp, 1] + n1 * c1[sp + 1, 1] + n2 * c1[sp + 2, 1]
                d2x = (1.0 - t) * c2[sp, 0] + t * c2[sp + 1, 0]
                d2y = (1.0 - t) * c2[sp, 1] + t * c2[sp + 1, 1]
            elif k == 3:  # _point's values: the basis written out for the degrees (constants), the knots from a table
                s = span_at(x, nseg)
                n0, n1, n2, _, _, _, _ = _basis2(x, kt, s + 3)
                d1x, d1y = _sum3(c1, s, n0, n1, n2)
                n0, n1, _, _ = _basis1(x, kt, s + 3)
                d2x, d2y = _sum2(c2, s, n0, n1)
            else:
                d1x, d1y = spline_point(c1, k - 1, nseg, x, kt, k, N, left, right)
                d2x, d2y = spline_point(c2, k - 2, nseg, x, kt, k, N, left, right)
            tt = r / refine
            bb = b[i] * (1.0 - tt) + b[i + 1] * tt
            sb = np.sqrt(max(bb, 0.0))
            for j in range(na):
                t1 = d1x * M[j, 0] + d1y * M[j, 1]
                t2 = d2x * M[j, 0] + d2y * M[j, 1]
                acc = abs(t1 * a + t2 * bb)
                vel = abs(t1) * sb
                if acc > top_a[j]:
                    top_a[j] = acc
                if vel > top_v[j]:
                    top_v[j] = vel
            if pen > 0.0:
                p = np.hypot(d1x, d1y) * sb
                if p > top_p:
                    top_p = p
        # divided once per interval and actuator: a correctly rounded x / c grows with x, so the
        # largest quotient is the largest numerator's (the same bits as dividing at every point)
        for j in range(na):
            if top_a[j] / amax[j] > wa[i]:
                wa[i] = top_a[j] / amax[j]
            if top_v[j] / vmax[j] > wv[i]:
                wv[i] = top_v[j] / vmax[j]
        if pen > 0.0:
            wp[i] = top_p / pen
    return wa, wv, wp


@numba.njit(cache=True, nogil=True)
def knot_table(p, nseg):  # pragma: no cover - compiled
    """kt[j] = geometry.kernels.knot(j, p, nseg) for j = 0 .. nseg + 2 p: the same
    divisions done once per spline instead of twice per basis step."""
    kt = np.empty(nseg + 2 * p + 1)
    for j in range(kt.shape[0]):
        kt[j] = min(max(j - p, 0), nseg) / nseg
    return kt


@numba.njit(cache=True, nogil=True, inline="always")
def _split(n, r, l):  # pragma: no cover - compiled
    """One term of a Cox-de Boor step: n shared out in proportion to r and l."""
    t = n / (r + l)
    return r * t, l * t


@numba.njit(cache=True, nogil=True, inline="always")
def _basis1(x, kt, ks):  # pragma: no cover - compiled
    """geometry.kernels.basis_at's Cox-de Boor basis of degree 1 on scalars, the knots from
    kt = knot_table(P, nseg) (ks = s + P): its operations in its order, so the same bits."""
    l1 = x - kt[ks]
    r1 = kt[ks + 1] - x
    a, b = _split(1.0, r1, l1)
    return 0.0 + a, b, l1, r1


@numba.njit(cache=True, nogil=True, inline="always")
def _basis2(x, kt, ks):  # pragma: no cover - compiled
    """... of degree 2: one more step on _basis1."""
    n0, n1, l1, r1 = _basis1(x, kt, ks)
    l2 = x - kt[ks - 1]
    r2 = kt[ks + 2] - x
    a0, b0 = _split(n0, r1, l2)
    a1, b1 = _split(n1, r2, l1)
    return 0.0 + a0, b0 + a1, b1, l1, l2, r1, r2


@numba.njit(cache=True, nogil=True, inline="always")
def _basis3(x, kt, ks):  # pragma: no cover - compiled
    """... of degree 3: one more step on _basis2."""
    n0, n1, n2, l1, l2, r1, r2 = _basis2(x, kt, ks)
    l3 = x - kt[ks - 2]
    r3 = kt[ks + 3] - x
    a0, b0 = _split(n0, r1, l3)
    a1, b1 = _split(n1, r2, l2)
    a2, b2 = _split(n2, r3, l1)
    return 0.0 + a0, b0 + a1, b1 + a2, b2


@numba.njit(cache=True, nogil=True, inline="always")
def _cubic(x, kt, nseg, s, P):  # pragma: no cover - compiled
    """The four cubic basis values of span s at x as geometry.kernels.basis_at makes them:
    its closed form on an inner span, else Cox-de Boor (_basis3)."""
    if 3 <= s < nseg - 3:
        t = x * nseg - s
        t2 = t * t
        t3 = t2 * t
        return (1.0 - t) ** 3 / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0, (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0, t3 / 6.0
    return _basis3(x, kt, s + P)


@numba.njit(cache=True, nogil=True, inline="always")
def _sum4(c, s, n0, n1, n2, n3):  # pragma: no cover - compiled
    """The point from its basis values, summed as geometry.kernels._point sums them."""
    sx, sy = _sum3(c, s, n0, n1, n2)
    return sx + n3 * c[s + 3, 0], sy + n3 * c[s + 3, 1]


@numba.njit(cache=True, nogil=True, inline="always")
def _sum3(c, s, n0, n1, n2):  # pragma: no cover - compiled
    sx = 0.0 + n0 * c[s, 0]
    sy = 0.0 + n0 * c[s, 1]
    sx += n1 * c[s + 1, 0]
    sy += n1 * c[s + 1, 1]
    sx += n2 * c[s + 2, 0]
    sy += n2 * c[s + 2, 1]
    return sx, sy


@numba.njit(cache=True, nogil=True, inline="always")
def _sum2(c, s, n0, n1):  # pragma: no cover - compiled
    return (0.0 + n0 * c[s, 0]) + n1 * c[s + 1, 0], (0.0 + n0 * c[s, 1]) + n1 * c[s + 1, 1]


@numba.njit(cache=True, nogil=True)
def spline_point(c, k, nseg, x, kt, P, N, left, right):  # pragma: no cover - compiled
    """geometry.kernels._point (the same bits), its basis written out on scalars for
    degrees 1 to 3 and the knots read from kt = knot_table(P, nseg), P >= k."""
    return value_in_span(c, k, nseg, span_at(x, nseg), x, kt, P, N, left, right)


@numba.njit(cache=True, nogil=True, inline="always")
def value_in_span(c, k, nseg, s, x, kt, P, N, left, right):  # pragma: no cover - compiled
    """spline_point with the knot span s of x known (other degrees: _point itself)."""
    if k == 3:
        n0, n1, n2, n3 = _cubic(x, kt, nseg, s, P)
        return _sum4(c, s, n0, n1, n2, n3)
    if k == 2:
        n0, n1, n2, _, _, _, _ = _basis2(x, kt, s + P)
        return _sum3(c, s, n0, n1, n2)
    if k == 1:
        n0, n1, _, _ = _basis1(x, kt, s + P)
        return _sum2(c, s, n0, n1)
    return _point(c, k, nseg, x, N, left, right)


@numba.njit(cache=True, nogil=True)
def distance_to_stretch(c0, c1, c2, k, nseg, x, lo, hi, candidates, iterations, out):  # pragma: no cover - compiled
    """out[i] = distance from x[i] to the spline (control points c0, its first and
    second derivatives' c1, c2; degree k, nseg spans) on u in [lo[i], hi[i]]: the
    nearest of ``candidates`` evenly spread parameters, then Newton steps on
    (q(u) - x) . q'(u) = 0 kept within one spacing of it (follow.distance_to_stretch)."""
    N = np.empty(k + 1)
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    kt = knot_table(k, nseg)
    for i in range(x.shape[0]):
        out[i] = _distance(c0, c1, c2, k, nseg, kt, N, left, right, x[i, 0], x[i, 1], lo[i], hi[i],
                           candidates, iterations)


@numba.njit(cache=True, nogil=True)
def _distance(c0, c1, c2, k, nseg, kt, N, left, right, px, py, lo, hi, candidates, iterations):  # pragma: no cover - compiled
    """distance_to_stretch of one point; the fitted cubic through its own copy with the degrees
    written in (4x faster: spline_point's dispatch on a degree known only at run time cost
    more than the arithmetic), the same values."""
    if k == 3:
        return _cubic_distance(c0, c1, c2, nseg, kt, px, py, lo, hi, candidates, iterations)
    return _any_distance(c0, c1, c2, k, nseg, kt, N, left, right, px, py, lo, hi, candidates, iterations)


@numba.njit(cache=True, nogil=True, inline="always")
def _newton(u, rx, ry, d1x, d1y, d2x, d2y, a, b):  # pragma: no cover - compiled
    """One Newton step on (q(u) - x) . q'(u) = 0 (r = q(u) - x), kept in [a, b]."""
    g = d1x * rx + d1y * ry
    h = d1x * d1x + d1y * d1y + d2x * rx + d2y * ry
    if h > 1e-12:
        u -= g / h
    return min(max(u, a), b)


@numba.njit(cache=True, nogil=True, inline="always")
def _cubic_distance(c0, c1, c2, nseg, kt, px, py, lo, hi, candidates, iterations):  # pragma: no cover - compiled
    cx = np.empty(candidates)
    cy = np.empty(candidates)
    cu = np.empty(candidates)
    step = _cubic_candidates(c0, nseg, kt, lo, hi, cx, cy, cu)
    return _cubic_from(c0, c1, c2, nseg, kt, px, py, lo, cx, cy, cu, step, iterations)


@numba.njit(cache=True, nogil=True, inline="always")
def _cubic_candidates(c0, nseg, kt, lo, hi, cx, cy, cu):  # pragma: no cover - compiled
    """The cubic's points (cx, cy) at len(cu) parameters cu evenly spread over [lo, hi]
    (_cubic_distance's candidates: the same for every point of a period); returns the spacing."""
    candidates = cu.shape[0]
    step = (hi - lo) / (candidates - 1)
    for j in range(candidates):
        u = lo + step * j
        s = span_at(u, nseg)
        n0, n1, n2, n3 = _cubic(u, kt, nseg, s, 3)
        cx[j], cy[j] = _sum4(c0, s, n0, n1, n2, n3)
        cu[j] = u
    return step


@numba.njit(cache=True, nogil=True, inline="always")
def _cubic_from(c0, c1, c2, nseg, kt, px, py, lo, cx, cy, cu, step, iterations):  # pragma: no cover - compiled
    """_cubic_distance of (px, py) from its candidates: the nearest, then the Newton steps. The
    square root only where the squared distance drops below the best one's (a correctly rounded
    root does not fall where its argument does not), so the same best as rooting every one."""
    best, ub, best2 = np.inf, lo, np.inf
    for j in range(cu.shape[0]):
        d2 = (cx[j] - px) ** 2 + (cy[j] - py) ** 2
        if d2 < best2:
            d = np.sqrt(d2)
            if d < best:
                best, ub, best2 = d, cu[j], d2
    a, b = max(ub - step, 0.0), min(ub + step, 1.0)
    u = ub
    for it in range(iterations + 1):  # the last pass only evaluates q at the final u
        s = span_at(u, nseg)
        n0, n1, n2, n3 = _cubic(u, kt, nseg, s, 3)
        qx, qy = _sum4(c0, s, n0, n1, n2, n3)
        if it == iterations:
            break
        n0, n1, n2, _, _, _, _ = _basis2(u, kt, s + 3)
        d1x, d1y = _sum3(c1, s, n0, n1, n2)
        n0, n1, _, _ = _basis1(u, kt, s + 3)
        d2x, d2y = _sum2(c2, s, n0, n1)
        u = _newton(u, qx - px, qy - py, d1x, d1y, d2x, d2y, a, b)
    return min(np.sqrt((qx - px) ** 2 + (qy - py) ** 2), best)


@numba.njit(cache=True, nogil=True)
def _any_distance(c0, c1, c2, k, nseg, kt, N, left, right, px, py, lo, hi, candidates, iterations):  # pragma: no cover - compiled
    step = (hi - lo) / (candidates - 1)
    best, ub = np.inf, lo
    for j in range(candidates):
        u = lo + step * j
        qx, qy = spline_point(c0, k, nseg, u, kt, k, N, left, right)
        d = np.sqrt((qx - px) ** 2 + (qy - py) ** 2)
        if d < best:
            best, ub = d, u
    a, b = max(ub - step, 0.0), min(ub + step, 1.0)
    u = ub
    for _ in range(iterations):
        qx, qy = spline_point(c0, k, nseg, u, kt, k, N, left, right)
        d1x, d1y = spline_point(c1, k - 1, nseg, u, kt, k, N, left, right)
        d2x, d2y = (0.0, 0.0) if k < 2 else spline_point(c2, k - 2, nseg, u, kt, k, N, left, right)
        u = _newton(u, qx - px, qy - py, d1x, d1y, d2x, d2y, a, b)
    qx, qy = spline_point(c0, k, nseg, u, kt, k, N, left, right)
    return min(np.sqrt((qx - px) ** 2 + (qy - py) ** 2), best)


@numba.njit(cache=True, nogil=True)
def period_deviation(c0, c1, c2, k, nseg, x, v, tau, c, su, candidates, iterations, out):  # pragma: no cover - compiled
    """follow.path_deviation of a curve in one pass: per period i, the executed parabola
    x_i + v_i tau + (v_i+1 - v_i) c (c = tau^2 / 2 dT) at the points tau, each point's
    distance to the stretch [su_i - w / 2, su_i+1 + w / 2] (w = su_i+1 - su_i, at least 1e-9)
    and the peak recovered by a parabola through the largest and its neighbours; the
    array version's operations in its order (NaN kept as numpy keeps it)."""
    N = np.empty(k + 1)
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    kt = knot_table(k, nseg)
    R = tau.shape[0]
    dist = np.empty(R)
    cx = np.empty(candidates)
    cy = np.empty(candidates)
    cu = np.empty(candidates)
    for i in range(out.shape[0]):
        w = su[i + 1] - su[i]
        w = w if (w >= 1e-9 or w != w) else 1e-9
        lo = su[i] - w / 2
        lo = lo if (lo >= 0.0 or lo != lo) else 0.0
        hi = su[i + 1] + w / 2
        hi = hi if (hi <= 1.0 or hi != hi) else 1.0
        top = 0
        step = _cubic_candidates(c0, nseg, kt, lo, hi, cx, cy, cu) if k == 3 else 0.0  # once per period
        for r in range(R):
            px = x[i, 0] + v[i, 0] * tau[r] + (v[i + 1, 0] - v[i, 0]) * c[r]
            py = x[i, 1] + v[i, 1] * tau[r] + (v[i + 1, 1] - v[i, 1]) * c[r]
            if k == 3:
                dist[r] = _cubic_from(c0, c1, c2, nseg, kt, px, py, lo, cx, cy, cu, step, iterations)
            else:
                dist[r] = _distance(c0, c1, c2, k, nseg, kt, N, left, right, px, py, lo, hi, candidates, iterations)
        for r in range(R):  # numpy's argmax: the first largest (the first NaN)
            if dist[r] != dist[r]:
                top = r
                break
            if dist[r] > dist[top]:
                top = r
        f0max = dist[top]
        kk = min(max(top, 1), R - 2)
        fm, f0, fp = dist[kk - 1], dist[kk], dist[kk + 1]
        curv = 2 * f0 - fm - fp
        peak = f0 + ((fp - fm) ** 2 / (8 * curv) if curv > 1e-15 else 0.0)
        bound = f0 + abs(fp - fm)
        lim = peak if (peak <= bound or peak != peak) else bound
        out[i] = f0max if (f0max >= lim or f0max != f0max) else lim


@numba.njit(cache=True, nogil=True)
def jerk_terms(c1, c2, c3, k, nseg, uu, sp, c12, c13, dot12):  # pragma: no cover - compiled
    """At every point uu (clipped to [0, 1]) of constraints.jerk_coefficients: |q'| (at
    least 1e-12), q' x q'', q' x q''' and q'.q'' from the control points c1, c2, c3 of
    q', q'', q''' (degree k, nseg spans; a derivative above k is 0), the same bits as
    Spline.__call__ and numpy's products give (one pass instead of three evaluations
    and a dozen array operations)."""
    T, K = uu.shape
    N = np.empty(k + 1)
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    kt = knot_table(k, nseg)
    for t in range(T):
        for i in range(K):
            x = min(max(uu[t, i], 0.0), 1.0)
            if k == 3:
                s = span_at(x, nseg)
                n0, n1, n2, _, _, _, _ = _basis2(x, kt, s + 3)
                d1x, d1y = _sum3(c1, s, n0, n1, n2)
                n0, n1, _, _ = _basis1(x, kt, s + 3)
                d2x, d2y = _sum2(c2, s, n0, n1)
                d3x, d3y = 0.0 + 1.0 * c3[s, 0], 0.0 + 1.0 * c3[s, 1]  # degree 0: _point's sum
            else:
                d1x, d1y = spline_point(c1, k - 1, nseg, x, kt, k, N, left, right)
                d2x, d2y = (0.0, 0.0) if k < 2 else spline_point(c2, k - 2, nseg, x, kt, k, N, left, right)
                d3x, d3y = (0.0, 0.0) if k < 3 else spline_point(c3, k - 3, nseg, x, kt, k, N, left, right)
            n = np.sqrt(d1x * d1x + d1y * d1y)
            sp[t, i] = n if (n >= 1e-12 or n != n) else 1e-12  # np.maximum (NaN kept)
            c12[t, i] = d1x * d2y - d1y * d2x
            c13[t, i] = d1x * d3y - d1y * d3x
            dot12[t, i] = d1x * d2x + d1y * d2y


@numba.njit(cache=True, nogil=True)
def jerk_finish(sp, sp3, sp6, c12, c13, dot12, c1, c2):  # pragma: no cover - compiled
    """c1 = 3 kappa |q'|^2, c2 = 3 kappa q'.q'' + |q'|^3 dkappa/ds (constraints.jerk_coefficients),
    with numpy's |q'|^3 and |q'|^6 (sp3, sp6: its power is not the compiled one)."""
    T, K = sp.shape
    for t in range(T):
        for i in range(K):
            sp2 = sp[t, i] * sp[t, i]
            kappa = c12[t, i] / sp3[t, i]
            kappa_s = (c13[t, i] * sp2 - 3 * c12[t, i] * dot12[t, i]) / sp6[t, i]
            c1[t, i] = 3 * kappa * sp2
            c2[t, i] = 3 * kappa * dot12[t, i] + sp3[t, i] * kappa_s


@numba.njit(cache=True, nogil=True)
def with_jerk_rows(tot0, beta0, gamma0, c1, c2, taus, u, b_hat, jm, tot, beta, gamma):  # pragma: no cover - compiled
    """tot, beta, gamma (K, R0 + 2T) = the rows tot0, beta0, gamma0 (K, R0), then per
    interval the jerk rows of constraints.with_jerk: for each tau, +-(c2, c2 tau + c1 / 2h)
    <= jm / sqrt(b_hat(tau)), the operations of the numpy version in its order."""
    K, R0 = tot0.shape
    T = taus.shape[0]
    for k in range(K):
        for r in range(R0):
            tot[k, r] = tot0[k, r]
            beta[k, r] = beta0[k, r]
            gamma[k, r] = gamma0[k, r]
        h2 = 2 * (u[k + 1] - u[k])
        for t in range(T):
            tau = taus[t]
            bh = b_hat[k] * (1 - tau) + b_hat[k + 1] * tau
            g = jm[t, k] / np.sqrt(bh if (bh >= 1e-300 or bh != bh) else 1e-300)
            be = c2[t, k] * tau + c1[t, k] / h2
            r = R0 + 2 * t
            tot[k, r] = c2[t, k]
            beta[k, r] = be
            gamma[k, r] = g
            tot[k, r + 1] = -c2[t, k]
            beta[k, r + 1] = -be
            gamma[k, r + 1] = g


@numba.njit(cache=True, nogil=True)
def row_ratios(tot, beta, gamma, b, first, out):  # pragma: no cover - compiled
    """out[k] = max over the rows r >= first of interval k of (tot b_k + beta (b_k+1 - b_k)) /
    gamma (0 where gamma is not finite): constraints.Rows.ratios(b)[:, first:].max(axis=1),
    NaN kept as numpy keeps it."""
    K, R = tot.shape
    for k in range(K):
        d = b[k + 1] - b[k]
        worst = -np.inf
        for r in range(first, R):
            g = gamma[k, r]
            v = tot[k, r] * b[k] + beta[k, r] * d
            v = v / g if np.isfinite(g) else 0.0
            if v > worst or v != v:
                worst = v
                if v != v:
                    break
        out[k] = worst


@numba.njit(cache=True, nogil=True)
def qp_fill(tang, tagged, signs, inst, axes, adata, pind, pdata, dx, dy, cross, nrm, w, lam, v_plan, shifted,
            p, tol, L, end, amax, vmax, dt, trust, cap, q, b):  # pragma: no cover - compiled
    """The sampler's QP data in one pass (sample._qp, whose array steps these are in the
    same order): the tracking rows' tangent entries of A, the objective's values (its
    diagonal, and with normals nrm (n, 2) the penalty across the curve), q and the
    right-hand side b. Empty amax: no actuator rows; empty trust: no trust rows;
    cap < 0: no pen-speed cones."""
    m = p.shape[0]
    n = m - 1
    nv = 2 * n
    nx = 2 * m
    for j in range(tagged.shape[0]):
        adata[tagged[j]] = -signs[j] * tang[inst[j], axes[j]]
    for j in range(pdata.shape[0]):
        c = pind[j]
        pdata[j] = (lam if c < nv else (0.0 if c < nv + nx else 1.0)) + 1e-12
    for j in range(n):
        pdata[cross[j]] = 0.0
    if nrm.shape[0] > 0:
        for j in range(n):
            pdata[dx[j]] += w * nrm[j, 0] * nrm[j, 0]
            pdata[dy[j]] += w * nrm[j, 1] * nrm[j, 1]
            pdata[cross[j]] = w * nrm[j, 0] * nrm[j, 1]
    for j in range(n):
        q[j] = -lam * v_plan[j, 0]
        q[n + j] = -lam * v_plan[j, 1]
    for j in range(nx):
        q[nv + j] = 0.0
    for j in range(m):
        q[nv + nx + j] = shifted[j]
    o = 0
    for j in range(2 * m):
        b[o + j] = 0.0
    o += 2 * m
    b[o] = end[0]
    b[o + 1] = end[1]
    o += 2
    for sign in (1.0, -1.0):
        for a in range(2):
            for j in range(m - 1):
                b[o + j] = sign * p[j, a] + tol
            o += m - 1
    for j in range(m - 1):
        b[o + j] = L * (p[j + 1, 2] - p[j, 2])
    o += m - 1
    for _ in range(2):
        for i in range(amax.shape[0]):
            ab = amax[i] * dt * (1 - 1e-6)
            vb = vmax[i] * (1 - 1e-6)
            for j in range(m):
                b[o + j] = ab
            o += m
            for j in range(n):
                b[o + j] = vb
            o += n
    if trust.shape[0] > 0:
        for _ in range(2):
            for j in range(m):
                b[o + j] = trust[j]
            o += m
    if cap >= 0.0:
        cb = cap * (1 - 1e-6)
        for j in range(n):
            b[o] = cb
            b[o + 1] = 0.0
            b[o + 2] = 0.0
            o += 3


@numba.njit(cache=True, nogil=True)
def curve_frame(c0, c1, k, nseg, u, start, L, pu, tang, nrm, trust, trust_mm, speed,
                v_plan):  # pragma: no cover - compiled
    """What the sampler linearises at the parameters u (clipped to [0, 1] as Spline.__call__
    clips them), in one pass with the same bits as its array steps: pu = (q(u) - start, u),
    tang = q'(u) / L and, where nrm has rows, the unit normal q'^perp / |q'| (|q'| at least
    1e-12) and trust = trust_mm L / |q'|; where speed has entries (du/dt), the velocity
    v_plan = q'(u) speed. c0, c1: the control points of q and q' (degree k)."""
    N = np.empty(k + 1)
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    kt = knot_table(k, nseg)
    follow = nrm.shape[0] > 0
    for j in range(u.shape[0]):
        x = min(max(u[j], 0.0), 1.0)
        if k == 3:
            s = span_at(x, nseg)
            n0, n1, n2, n3 = _cubic(x, kt, nseg, s, 3)
            qx, qy = _sum4(c0, s, n0, n1, n2, n3)
            n0, n1, n2, _, _, _, _ = _basis2(x, kt, s + 3)
            d1x, d1y = _sum3(c1, s, n0, n1, n2)
        else:
            qx, qy = spline_point(c0, k, nseg, x, kt, k, N, left, right)
            d1x, d1y = spline_point(c1, k - 1, nseg, x, kt, k, N, left, right)
        pu[j, 0] = qx - start[0]
        pu[j, 1] = qy - start[1]
        pu[j, 2] = u[j]
        tang[j, 0] = d1x / L
        tang[j, 1] = d1y / L
        if follow:
            sp = np.sqrt(d1x * d1x + d1y * d1y)
            sp = sp if (sp >= 1e-12 or sp != sp) else 1e-12
            nrm[j, 0] = -d1y / sp
            nrm[j, 1] = d1x / sp
            trust[j] = trust_mm * L / sp
        if speed.shape[0] > 0:
            v_plan[j, 0] = d1x * speed[j]
            v_plan[j, 1] = d1y * speed[j]


@numba.njit(cache=True, nogil=True, inline="always")
def _np_max(x, y):  # pragma: no cover - compiled
    """numpy.maximum's element: NaN wins, else y unless x > y (so the sign of an equal zero is y's)."""
    if x != x:
        return x
    return x if x > y else y


@numba.njit(cache=True, nogil=True, inline="always")
def _np_min(x, y):  # pragma: no cover - compiled
    """numpy.minimum's element, likewise."""
    if x != x:
        return x
    return x if x < y else y


@numba.njit(cache=True, nogil=True)
def sample_aim(pt, pu_, pb, pa, c, dt, c0, c1, k, nseg, start, L, u, v_plan, pu, tang, nrm, trust,
               trust_mm):  # pragma: no cover - compiled
    """The sampler's first linearisation for m = len(u) periods of the plan slowed by c: at
    t_j = c j dT (j = 1 .. m) the plan's parameter u_j (Profile.state_at on its grid pt, pu_, pb,
    pa, with the same bits; the last one 1), its velocity v_plan = q'(u) c du/dt (the last
    zero), then curve_frame there."""
    m = u.shape[0]
    nt = pt.shape[0]
    speed = np.empty(m)
    for j in range(m):
        t = _np_min(pt[nt - 1], _np_max(0.0, c * (dt * (j + 1))))
        lo, hi = 0, nt  # searchsorted(pt, t, side="right"): the first index with pt > t
        while lo < hi:
            mid = (lo + hi) >> 1
            if t < pt[mid]:
                hi = mid
            else:
                lo = mid + 1
        i = min(pa.shape[0] - 1, max(0, lo - 1))
        tau = t - pt[i]
        v0 = np.sqrt(_np_max(pb[i], 0.0))
        a = pa[i]
        speed[j] = c * _np_max(v0 + a * tau, 0.0)
        u[j] = _np_min(pu_[i] + v0 * tau + 0.5 * a * tau * tau, pu_[i + 1])
    u[m - 1] = 1.0
    curve_frame(c0, c1, k, nseg, u, start, L, pu, tang, nrm, trust, trust_mm, speed, v_plan)
    v_plan[m - 1, 0] = 0.0
    v_plan[m - 1, 1] = 0.0


@numba.njit(cache=True, nogil=True)
def relinearise(c0, c1, k, nseg, u, d, L, x, start, tol, pu, tang, nrm, trust, trust_mm, u_new,
                u_mono):  # pragma: no cover - compiled
    """After a linearised solve of the sampler (shifts d in mm of arc, reached positions x from
    the start): u_new = clip(u + d / L, 0, 1) with the last 1, and curve_frame there. True where
    every instant but the last is within tol of its point per axis. Else u_mono = the running
    maximum of u_new (the shifted parameter made monotone, numpy.maximum.accumulate's bits), and
    the frame is remade there where it differs. Array steps of sample.sample_stroke, fused."""
    m = u.shape[0]
    for j in range(m):
        y = u[j] + d[j] / L
        if y == y:  # numpy.clip's element (NaN stays; an equal zero keeps its sign)
            y = 0.0 if y < 0.0 else (1.0 if y > 1.0 else y)
        u_new[j] = y
    u_new[m - 1] = 1.0
    _E = np.empty(0)
    curve_frame(c0, c1, k, nseg, u_new, start, L, pu, tang, nrm, trust, trust_mm, _E, pu)
    ok = True
    for j in range(m - 1):
        for a in range(2):
            if not abs(x[j, a] - pu[j, a]) <= tol:  # NaN: not within
                ok = False
    if ok:
        return True
    same = True
    r = u_new[0]
    u_mono[0] = r
    for j in range(1, m):
        r = _np_max(r, u_new[j])
        u_mono[j] = r
        if not r == u_new[j]:
            same = False
    if not same:
        curve_frame(c0, c1, k, nseg, u_mono, start, L, pu, tang, nrm, trust, trust_mm, _E, pu)
    return False


@numba.njit(cache=True, nogil=True)
def sample_qp(tang, p, v_plan, shifted, nrm, w, lam, tol, L, end, M, amax, vmax, dt, trust, H, g, C, b,
              T):  # pragma: no cover - compiled
    """The sampler's linearised QP (sample._pattern, kernels.qp_fill: the same objective, rows and
    bounds) with the positions eliminated, x_i = dT (v_1 + ... + v_i-1) + dT / 2 v_i, as dense
    arrays for a dense solver: min 1/2 z'Hz + g'z, C[:2] z = b[:2], C[2:] z <= b[2:] over
    z = (vx, vy, d); T (m, n): x = T v per axis. Empty M: no actuator rows; empty trust: no
    trust rows; empty nrm: no penalty across the curve. Fills H (nz, nz), g (nz,), C (nc, nz),
    b (nc,) and T (m, n) (nc: sample._dense_arrays) with H, -g, -C, -b and T: quadprog's arguments
    (min 1/2 z'Hz - a'z subject to C' z >= b; C.T is its C, in the column order it copies).
    Filled in place, as returning five new arrays costs more than building them."""
    m = p.shape[0]
    n = m - 1
    T[:] = 0.0  # x_k+1 = T[k] . v per axis
    for k in range(m):
        for j in range(min(k, n)):
            T[k, j] = dt
        if k < n:
            T[k, k] = 0.5 * dt
    H[:] = 0.0
    g[:] = 0.0
    for i in range(n):  # objective: as qp_fill, the 1e-12 on the positions carried through T
        for a in range(2):
            g[a * n + i] = -lam * v_plan[i, a]
            H[a * n + i, a * n + i] += lam + 1e-12
            for j in range(n):
                s = 0.0
                for k in range(m):
                    s += T[k, i] * T[k, j]
                H[a * n + i, a * n + j] += 1e-12 * s
        if nrm.shape[0] > 0:
            H[i, i] += w * nrm[i, 0] * nrm[i, 0]
            H[n + i, n + i] += w * nrm[i, 1] * nrm[i, 1]
            H[i, n + i] = w * nrm[i, 0] * nrm[i, 1]
            H[n + i, i] = H[i, n + i]
    for j in range(m):
        H[2 * n + j, 2 * n + j] = 1.0 + 1e-12
        g[2 * n + j] = shifted[j]
    na = M.shape[0]
    C[:] = 0.0
    b[:] = 0.0
    for a in range(2):  # the end, reached exactly
        for j in range(n):
            C[a, a * n + j] = dt
        b[a] = end[a]
    o = 2
    for sign in (1.0, -1.0):  # tracking boxes at instants 1 .. m-1
        for a in range(2):
            for k in range(m - 1):
                for j in range(n):
                    C[o, a * n + j] = sign * T[k, j]
                C[o, 2 * n + k] = -sign * tang[k, a]
                b[o] = sign * p[k, a] + tol
                o += 1
    for k in range(m - 1):  # monotone shifted parameter
        C[o, 2 * n + k] = 1.0
        C[o, 2 * n + k + 1] = -1.0
        b[o] = L * (p[k + 1, 2] - p[k, 2])
        o += 1
    for sign in (1.0, -1.0):  # per actuator: a period's change, then the velocity
        for i in range(na):
            for r in range(m):
                for a in range(2):
                    c = sign * M[i, a]
                    if r < n:
                        C[o, a * n + r] += c
                    if r > 0:
                        C[o, a * n + r - 1] -= c
                b[o] = amax[i] * dt * (1 - 1e-6)
                o += 1
            for r in range(n):
                for a in range(2):
                    C[o, a * n + r] = sign * M[i, a]
                b[o] = vmax[i] * (1 - 1e-6)
                o += 1
    if trust.shape[0] > 0:
        for sign in (1.0, -1.0):
            for j in range(m):
                C[o, 2 * n + j] = sign
                b[o] = trust[j]
                o += 1
    for i in range(g.shape[0]):  # quadprog's signs (exact)
        g[i] = -g[i]
    for i in range(b.shape[0]):
        b[i] = -b[i]
        for j in range(C.shape[1]):
            C[i, j] = -C[i, j]


@numba.njit(cache=True, nogil=True)
def plan_rounds(T, bp, mid, u, M, vmax, amax, pen2, R, B1, B2, c1, c2, k, nseg, tau, pen, b0, bN, max_rounds,
                adaptive):  # pragma: no cover - compiled
    """planner.plan_stroke's rounds for linear kinematics, the reach solver and Bernstein rows
    with no knot caps (degree >= 3): rows on the grid u (bernstein_rows), solve (reach_passes),
    and while refining pays, split the intervals where a row binds but the bound is loose.
    The same kernels and numpy's operations in the same order, so the same plan. Returns
    (status, u, b, tot, beta, gamma): status 0, reach_passes' status (!= 0) where it fails, or
    -2 where b is not finite (a standing-still span: planner's Python path handles it).
    R: rows per interval (constraints.bernstein_rows)."""
    best_t = np.inf
    K = u.shape[0] - 1
    tot = np.empty((K, R))
    beta = np.empty((K, R))
    gamma = np.empty((K, R))
    b = np.empty(K + 1)
    for round_ in range(max_rounds):
        K = u.shape[0] - 1
        tot = np.empty((K, R))
        beta = np.empty((K, R))
        gamma = np.empty((K, R))
        bernstein_rows(T, bp, mid, u, M, vmax, amax, pen2, B1, B2, tot, beta, gamma)
        ub = np.full(K + 1, np.inf)
        b = np.empty(K + 1)
        status = reach_passes(tot, beta, gamma, ub, b0, bN, b, np.empty(K + 1), np.empty(K + 1))
        if status != 0:
            return status, u, b, tot, beta, gamma
        if not np.isfinite(b).all():
            return -2, u, b, tot, beta, gamma
        if not adaptive:
            break
        used = np.empty(K)
        row_ratios(tot, beta, gamma, b, 0, used)
        t = np.empty(K + 1)
        times(u, b, t)
        if not np.isfinite(t[K]) or t[K] > best_t * (1 - 1e-4):
            break  # refinement no longer pays
        best_t = t[K]
        binding = used > 1 - 1e-6
        # the check only where a row binds (the rest are not split whatever it finds)
        wa, wv, wp = spline_interval_worst_where(c1, c2, k, nseg, u, tau, b, M, amax, vmax, pen, binding)
        worst = np.maximum(np.maximum(wa, wv), wp)
        split = binding & (worst < 1 - 2e-3)  # binding, but the bound is loose
        if not split.any() or u.shape[0] + split.sum() > 200_000 or round_ == max_rounds - 1:
            break
        u = np.sort(np.concatenate((u, ((u[:-1] + u[1:])[split]) / 2)))
    return 0, u, b, tot, beta, gamma


@numba.njit(cache=True, nogil=True)
def jerk_solves(tot0, beta0, gamma0, ub0, c1, c2, taus, u, jm, b, grows, b0, bN):  # pragma: no cover - compiled
    """planner.plan_stroke's solves with the jerk rows (reach solver): for each grow, b_hat =
    min(b_free, grow b) (1 + 1e-12), the rows tot0.. and the jerk rows (with_jerk_rows), the
    node bounds min(ub0, b_hat), and solve; the first grow ends it where b_free keeps the jerk
    rows already. Returns (status, b, tot, beta, gamma, ub): the last rows made."""
    K, R0 = tot0.shape
    R = R0 + 2 * taus.shape[0]
    tot = np.empty((K, R))
    beta = np.empty((K, R))
    gamma = np.empty((K, R))
    ub = ub0.copy()
    b_free = b
    for g in range(grows.shape[0]):
        b_hat = np.minimum(b_free, grows[g] * b) * (1 + 1e-12)
        with_jerk_rows(tot0, beta0, gamma0, c1, c2, taus, u, b_hat, jm, tot, beta, gamma)
        ub = np.minimum(ub0, b_hat)
        if g == 0:
            used = np.empty(K)
            row_ratios(tot, beta, gamma, b_free, R0, used)
            top = 0.0  # numpy's max(initial=0.0): NaN wins
            for x in used:
                if x != x:
                    top = x
                    break
                if x > top:
                    top = x
            if top <= 1.0:
                break  # the plan already keeps the bound
        bn = np.empty(K + 1)
        status = reach_passes(tot, beta, gamma, ub, b0, bN, bn, np.empty(K + 1), np.empty(K + 1))
        if status != 0:
            return status, b, tot, beta, gamma, ub
        b = bn
    return 0, b, tot, beta, gamma, ub


@numba.njit(cache=True, nogil=True)
def executed_deviation(c0, c1, c2, k, nseg, start, velocity, half_dt, tau, c, su, candidates, iterations,
                       out):  # pragma: no cover - compiled
    """period_deviation of the samples (start, velocity) as executed: the instants' positions
    StrokeSamples.integrate makes (start + the running sum of half_dt (v_j + v_j+1), v_0 = 0)
    and the targets after a zero, made here instead of by five numpy calls per stroke."""
    m = velocity.shape[0]
    v = np.zeros((m + 1, 2))
    v[1:] = velocity
    x = np.empty((m + 1, 2))
    for d in range(2):
        run = 0.0
        for i in range(m + 1):
            if i > 0:
                step = half_dt * (v[i, d] + v[i - 1, d])
                run = step if i == 1 else run + step  # numpy's cumsum starts from the first step
            x[i, d] = start[d] + (run if i > 0 else 0.0)
    period_deviation(c0, c1, c2, k, nseg, x, v, tau, c, su, candidates, iterations, out)



@numba.njit(cache=True, nogil=True)
def written_velocity(velocity, k, out):  # pragma: no cover - compiled
    """link.plc.packetfile.whole_step_targets(velocity, k) / k (mm/s): the targets (M, 2) as the PLC
    post writes them in whole steps/s, with the same products, running sums (numpy's cumsum
    starts from the first term), roundings (half to even), differences and divisions, so the
    same numbers without six numpy calls per stroke."""
    for a in range(2):
        acc = 0.0
        last = 0.0
        for r in range(velocity.shape[0]):
            x = velocity[r, a] * k[a]
            acc = x if r == 0 else acc + x
            cum = np.rint(acc)
            out[r, a] = (cum - last) / k[a]
            last = cum


@numba.njit(cache=True, nogil=True)
def curve_rounds(c0, c1, c2, c3, C, bp, gx, gw, spacing, turn_step, max_points, u_given, M, vmax, amax, pen2, R,
                 B1, B2, tau, pen, b0, bN, max_rounds, jerk_taus):  # pragma: no cover - compiled
    """planner.plan_checked's first compiled call for a cubic (control points c0 and the
    derivatives' c1, c2, c3): planner.check_inputs' tests of the control points, the span
    polynomials (constraints.spans), the grid (planner.make_grid; u_given instead where it is
    not empty), the rounds (plan_rounds, adaptive unless u_given) and, with jerk_taus, the jerk
    terms at those taus of every interval (constraints.jerk_coefficients before numpy's powers).
    The same operations in the same order. Returns (bad, status, u, b, tot, beta, gamma, uu, sp,
    c12, c13, dot12): bad 1 = a control point not finite, 2 = all of them equal (nothing else
    done); status as plan_rounds."""
    p = 3
    n = c0.shape[0]
    nseg = bp.shape[0] - 1
    e = np.empty((0, 0))
    lo = np.empty(2)
    hi = np.empty(2)
    for d in range(2):
        lo[d] = c0[0, d]
        hi[d] = c0[0, d]
        for i in range(n):
            x = c0[i, d]
            if not np.isfinite(x):
                return 1, 0, u_given, u_given, e, e, e, e, e, e, e, e
            lo[d] = min(lo[d], x)
            hi[d] = max(hi[d], x)
    top = 1.0  # Python's max(1.0, *|lo|, *|hi|) and max(hi - lo) <= 1e-9 that
    for d in range(2):
        top = max(top, abs(lo[d]))
    for d in range(2):
        top = max(top, abs(hi[d]))
    if max(hi[0] - lo[0], hi[1] - lo[1]) <= 1e-9 * top:
        return 2, 0, u_given, u_given, e, e, e, e, e, e, e, e
    D = np.zeros((p + 1, n, 2))  # constraints._padded_derivatives
    D[0] = c0
    D[1, : n - 1] = c1
    D[2, : n - 2] = c2
    D[3, : n - 3] = c3
    mid = (bp[:-1] + bp[1:]) / 2
    T = np.empty((nseg, p + 1, 2))
    span_taylor(D, p, nseg, mid, C, T)
    adaptive = u_given.shape[0] == 0
    if adaptive:
        length = np.empty(nseg)
        turning = np.empty(nseg)
        span_measures(T, (bp[1:] - bp[:-1]) / 2, gx, gw, length, turning)
        cnt = np.empty(nseg, np.int64)
        total = 0
        for s in range(nseg):
            cnt[s] = max(int(np.ceil(length[s] / spacing + turning[s] / turn_step)), 2)
            total += cnt[s]
        if total > max_points:
            for s in range(nseg):
                cnt[s] = max(int(cnt[s] * max_points / total), 1)
        u = np.empty(cnt.sum() + 1)
        grid_fill(bp, cnt, u)
    else:
        u = u_given
    status, u, b, tot, beta, gamma = plan_rounds(T, bp, mid, u, M, vmax, amax, pen2, R, B1, B2, c1, c2, p, nseg, tau,
                                                 pen, b0, bN, max_rounds, adaptive)
    if status != 0 or jerk_taus.shape[0] == 0:
        return 0, status, u, b, tot, beta, gamma, e, e, e, e, e
    K = u.shape[0] - 1
    nt = jerk_taus.shape[0]
    uu = np.empty((nt, K))
    for t in range(nt):
        for i in range(K):
            # the interval's own side of a knot at tau >= 1
            uu[t, i] = np.nextafter(u[i + 1], -np.inf) if jerk_taus[t] >= 1 else u[i] + jerk_taus[t] * (u[i + 1] - u[i])
    sp = np.empty((nt, K))
    c12 = np.empty((nt, K))
    c13 = np.empty((nt, K))
    dot12 = np.empty((nt, K))
    jerk_terms(c1, c2, c3, p, nseg, uu, sp, c12, c13, dot12)
    return 0, status, u, b, tot, beta, gamma, uu, sp, c12, c13, dot12


@numba.njit(cache=True, nogil=True)
def python_square(x, two):  # pragma: no cover - compiled
    """x ** 2 as Python computes it: the C library's pow (glibc's pow(x, 2) is not always x * x),
    with ``two`` = 2.0 given at run time so that the compiler cannot turn it into x * x."""
    return math.pow(x, two)


@numba.njit(cache=True, nogil=True)
def curve_finish(u, b, tot, beta, gamma, uu, sp, sp3, sp6, c12, c13, dot12, taus, jbase, jstretch, grows, b0, bN,
                 two, c1, c2, nseg, tau, M, amax, vmax, pen):  # pragma: no cover - compiled
    """planner.plan_checked's second compiled call, after curve_rounds (and numpy's |q'|^3 and
    |q'|^6 of its sp as sp3, sp6; uu empty: no jerk bound): the jerk rows' coefficients
    (jerk_finish), the bound at uu (follow.JerkBound: jbase times the factor of every stretch
    (lo, hi, f) of jstretch holding the point, in order), the jerk solves (jerk_solves),
    planner._certify (``two`` = 2.0, given at run time so that the square is the C library's
    pow as in Python), a, t and planner.check_profile on the cubic q' = c1, q'' = c2 within M,
    amax, vmax, pen (tau: the check's points per interval). Returns (bad, status, b, a, t, acc,
    vel): bad 1 = a jerk solve failed (status: reach_passes'), 2 = the end speeds cannot be
    met, 3 = the plan stops mid-stroke."""
    K = u.shape[0] - 1
    ub = np.full(K + 1, np.inf)
    e = np.empty(0)
    if uu.shape[0] > 0:
        nt = uu.shape[0]
        j1 = np.empty((nt, K))
        j2 = np.empty((nt, K))
        jerk_finish(sp, sp3, sp6, c12, c13, dot12, j1, j2)
        jm = np.empty((nt, K))
        for t in range(nt):
            for i in range(K):
                x = uu[t, i]
                f = 1.0
                for m in range(jstretch.shape[0]):
                    if x >= jstretch[m, 0] and x <= jstretch[m, 1]:
                        f *= jstretch[m, 2]
                jm[t, i] = jbase * f
        status, b, tot, beta, gamma, ub = jerk_solves(tot, beta, gamma, ub, j1, j2, taus, u, jm, b, grows, b0, bN)
        if status != 0:
            return 1, status, b, e, e, 0.0, 0.0
    # _certify: the worst row ratio, then b over its finite positive node bounds (a NaN there
    # is left out, as Python's max leaves out numpy's NaN maximum)
    r = max_ratio(tot, beta, gamma, b)
    m = -np.inf
    seen = False
    nan = False
    for i in range(K + 1):
        x = ub[i]
        if np.isfinite(x) and x > 0:
            seen = True
            v = b[i] / x
            if v != v:
                nan = True
            elif v > m:
                m = v
    if seen and not nan and m > r:
        r = m
    vel_r = np.sqrt(r if r >= 0.0 else 0.0)
    c = 1.0 / (r if r >= 1e-300 else 1e-300)
    cv = python_square(vel_r, two)
    cv = 1.0 / (cv if cv >= 1e-300 else 1e-300)
    if cv < c:
        c = cv
    if c < 1.0:
        if (b0 > 0 or bN > 0) and c < 1 - 1e-6:
            return 2, 0, b, e, e, 0.0, 0.0
        b = b * c * (1 - 1e-12)
    a = (b[1:] - b[:-1]) / (2 * (u[1:] - u[:-1]))
    t = np.empty(K + 1)
    times(u, b, t)
    if not np.isfinite(t).all():
        return 3, 0, b, a, t, 0.0, 0.0
    wa, wv, wp = spline_interval_worst(c1, c2, 3, nseg, u, tau, b, M, amax, vmax, pen)
    return 0, 0, b, a, t, wa.max(), max(wv.max(), wp.max())
