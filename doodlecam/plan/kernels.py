"""Compiled inner loops of the planner (numba).

Both are sequential per grid interval and run at every plan, so they are
compiled: the same loops in Python would be ~100x slower. This module is
imported only when a stroke is planned (numba's import costs ~0.3 s).
"""

import numba
import numpy as np

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
def bernstein_rows(d, h, M, vmax, amax, pen2, T1, T2, tot, beta, gamma):  # pragma: no cover - compiled
    # d: (p + 1, K, 2) derivatives q^(j+1) at the interval's left end, j = 0..p
    # (the last is zero); T1, T2: power -> Bernstein matrices of degree p-1, 2p-1.
    p = d.shape[0] - 1
    K = d.shape[1]
    na = M.shape[0]
    n2 = 2 * p  # coefficients of theta'^2 b(tau)
    dq = np.zeros((2, p))
    ddq = np.zeros((2, p))
    P = np.zeros(p)
    Q = np.zeros(p)
    sq = np.zeros(n2)
    pa = np.zeros(n2)
    pb = np.zeros(n2)
    for k in range(K):
        hk = h[k]
        f = 1.0
        for j in range(p):
            if j > 0:
                f *= hk / j
            for c in range(2):
                dq[c, j] = d[j, k, c] * f
                ddq[c, j] = d[j + 1, k, c] * f if j + 1 < p else 0.0
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
                v = (tot[k, r] * b[k] + beta[k, r] * (b[k + 1] - b[k])) / g
                if v > worst:
                    worst = v
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
