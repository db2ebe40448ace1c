"""Fit: polylines (mm) to clamped uniform B-splines within a tolerance.

Least squares with the end points pinned (a clamped spline passes through its
first and last control points), on chord-length parameters. The number of
control points grows until the deviation from the polyline, measured both
ways, is within the tolerance; then a bisection finds the smallest count.
The reported deviation is a certified upper bound (see ``_bound``), local:
each stretch between two neighbouring samples is bounded on its own.

Everything is compiled (numba), the search too: ``fit_many`` fits a batch of
polylines (a generated drawing has thousands of short paths) in one call,
each attempt the basis functions at every sample, the banded normal
equations and their Cholesky solve, the curve and the bound, in O(samples x
degree^2). A straight segment needs no search: its Bezier is exact. The
splines are those of the search as first written, a polyline at a time in
Python, to the last bit (tests/test_fit_batch.py): the shortcuts are the
same arithmetic in another order of independent steps, or tell a failed
attempt sooner.
"""

from __future__ import annotations

import numba
import numpy as np

from doodlecam.geometry.kernels import cubic_inner as _cubic_inner
from doodlecam.geometry.kernels import knot as _knot
from doodlecam.geometry.kernels import span_at as _span_at
from doodlecam.model import SAME_POINT, Spline


def _dedupe(p: np.ndarray) -> np.ndarray:
    """p without the points within model.SAME_POINT (per axis) of the last point kept: one point to
    the job as to its pen lifts, so no piece between two corners is a stroke of no length (seen: ends
    merged 1.7e-7 mm apart at a corner of a generated drawing)."""
    if np.any(np.abs(np.diff(p, axis=0)) > SAME_POINT, axis=1).all():
        return p
    return p[_kept(p, SAME_POINT)]


@numba.njit(cache=True, nogil=True)
def _kept(p, near):  # pragma: no cover - compiled
    """Which points of p are farther than ``near`` (per axis) from the last one kept before them:
    measured from the last point kept, so a dense run is not dropped whole (compiled: a long
    curve with one repeated point was a Python loop over all its points)."""
    keep = np.zeros(p.shape[0], np.bool_)
    keep[0] = True
    last = 0
    for i in range(1, p.shape[0]):
        if max(abs(p[i, 0] - p[last, 0]), abs(p[i, 1] - p[last, 1])) > near:
            keep[i] = True
            last = i
    return keep


def densify(p: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline with extra points so no segment is longer than ``spacing``."""
    seg = np.diff(p, axis=0)
    n = np.maximum(np.ceil(np.hypot(*seg.T) / spacing).astype(int), 1)
    starts = np.repeat(np.arange(len(seg)), n)
    frac = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    pts = p[starts] + seg[starts] * (frac / n[starts])[:, None]
    return np.vstack([pts, p[-1:]])


# ---------------------------------------------------------------- compiled kernels

@numba.njit(cache=True, nogil=True, inline="always")
def _span3(P, B, F, i, A, rx, ry, ctrl, S):  # pragma: no cover - compiled
    """``_lsq``'s sums over the data points from i on in i's knot span, for a
    cubic: the same additions in the same order, in registers rather than in
    memory (each sum starts from its entry and goes back to it; a sum for an
    unknown that is not one, a pinned end's, is made and dropped). S: 4 x 6
    scratch (the span's entries of A by control point, then rx, ry). Returns the
    first data point after the span."""
    f = F[i]
    c = f - 1  # the span's first unknown (control point f)
    q, n = A.shape[0], ctrl.shape[0]
    for a in range(4):
        free = 0 <= c + a < q
        for b in range(a, 4):
            S[a, b] = A[c + a, b - a] if free and c + b < q else 0.0
        S[a, 4], S[a, 5] = (rx[c + a], ry[c + a]) if free else (0.0, 0.0)
    a00, a01, a02, a03, x0, y0 = S[0, 0], S[0, 1], S[0, 2], S[0, 3], S[0, 4], S[0, 5]
    a11, a12, a13, x1, y1 = S[1, 1], S[1, 2], S[1, 3], S[1, 4], S[1, 5]
    a22, a23, x2, y2 = S[2, 2], S[2, 3], S[2, 4], S[2, 5]
    a33, x3, y3 = S[3, 3], S[3, 4], S[3, 5]
    first, last = f == 0, f + 3 == n - 1  # the span of a pinned end
    m = P.shape[0]
    while i < m and F[i] == f:
        n0, n1, n2, n3 = B[0, i], B[1, i], B[2, i], B[3, i]
        dx, dy = P[i, 0], P[i, 1]  # the data minus the pinned ends' share
        if first:
            dx -= n0 * ctrl[0, 0]
            dy -= n0 * ctrl[0, 1]
        if last:
            dx -= n3 * ctrl[n - 1, 0]
            dy -= n3 * ctrl[n - 1, 1]
        x0 += n0 * dx
        y0 += n0 * dy
        a00 += n0 * n0
        a01 += n0 * n1
        a02 += n0 * n2
        a03 += n0 * n3
        x1 += n1 * dx
        y1 += n1 * dy
        a11 += n1 * n1
        a12 += n1 * n2
        a13 += n1 * n3
        x2 += n2 * dx
        y2 += n2 * dy
        a22 += n2 * n2
        a23 += n2 * n3
        x3 += n3 * dx
        y3 += n3 * dy
        a33 += n3 * n3
        i += 2
    S[0, 0], S[0, 1], S[0, 2], S[0, 3], S[0, 4], S[0, 5] = a00, a01, a02, a03, x0, y0
    S[1, 1], S[1, 2], S[1, 3], S[1, 4], S[1, 5] = a11, a12, a13, x1, y1
    S[2, 2], S[2, 3], S[2, 4], S[2, 5] = a22, a23, x2, y2
    S[3, 3], S[3, 4], S[3, 5] = a33, x3, y3
    for a in range(4):
        if 0 <= c + a < q:
            for b in range(a, 4):
                if c + b < q:
                    A[c + a, b - a] = S[a, b]
            rx[c + a], ry[c + a] = S[a, 4], S[a, 5]
    return i


@numba.njit(cache=True, nogil=True)
def _lsq(P, B, F, n, p, lam, ctrl):  # pragma: no cover - compiled
    """Least-squares control points for the data P[0::2] (basis functions
    B[:, 0::2] from span F[0::2], ``_basis_table``), with
    ctrl[0] and ctrl[n - 1] given (the pinned ends), plus ``lam`` x the squared
    second differences of the control points so one without data under it
    stays defined. Banded normal equations, Cholesky. Fills ctrl[1:n - 1];
    False if the system is not positive definite."""
    m = P.shape[0]
    q = n - 2
    if q <= 0:
        return True
    w = max(p, 2)  # half bandwidth: data couple p + 1 neighbours, the smoothing 3
    A = np.zeros((q, w + 1))  # A[a, d] = N[a, a + d]; unknown a is control point a + 1
    rx = np.zeros(q)
    ry = np.zeros(q)
    S = np.empty((4, 6))
    i = 0
    while i < m:
        f = F[i]
        if p == 3:
            i = _span3(P, B, F, i, A, rx, ry, ctrl, S)
            continue
        dx, dy = P[i, 0], P[i, 1]  # the data minus the pinned ends' share
        if f == 0:
            dx -= B[0, i] * ctrl[0, 0]
            dy -= B[0, i] * ctrl[0, 1]
        if f + p == n - 1:
            dx -= B[p, i] * ctrl[n - 1, 0]
            dy -= B[p, i] * ctrl[n - 1, 1]
        for a in range(p + 1):
            ca = f + a - 1
            if ca < 0 or ca >= q:
                continue
            va = B[a, i]
            rx[ca] += va * dx
            ry[ca] += va * dy
            for b in range(a, p + 1):
                cb = f + b - 1
                if cb >= q:
                    break
                A[ca, cb - ca] += va * B[b, i]
        i += 2
    coef = np.array([1.0, -2.0, 1.0])
    v = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            v[a, b] = lam * coef[a] * coef[b]
    for k in range(n - 2):  # row k of the second differences: control points k, k + 1, k + 2
        if 1 <= k <= n - 4:  # all three free: what the loops below add, without their tests
            A[k - 1, 0] += v[0, 0]
            A[k - 1, 1] += v[0, 1]
            A[k - 1, 2] += v[0, 2]
            A[k, 0] += v[1, 1]
            A[k, 1] += v[1, 2]
            A[k + 1, 0] += v[2, 2]
            continue
        for a in range(3):
            ca = k + a - 1
            if ca < 0 or ca >= q:
                continue
            for b in range(3):
                c = k + b
                if c == 0 or c == n - 1:
                    rx[ca] -= v[a, b] * ctrl[c, 0]
                    ry[ca] -= v[a, b] * ctrl[c, 1]
                elif c - 1 >= ca:
                    A[ca, c - 1 - ca] += v[a, b]
    for j in range(q):  # A = U^T U, U upper banded, in place
        if w == 3 and 3 <= j < q - 3:  # the loops below for a full row of a cubic's band, unrolled
            s = A[j, 0] - A[j - 3, 3] * A[j - 3, 3]
            s -= A[j - 2, 2] * A[j - 2, 2]
            s -= A[j - 1, 1] * A[j - 1, 1]
            if not s > 0.0:
                return False
            d = np.sqrt(s)
            A[j, 0] = d
            A[j, 1] = (A[j, 1] - A[j - 2, 2] * A[j - 2, 3] - A[j - 1, 1] * A[j - 1, 2]) / d
            A[j, 2] = (A[j, 2] - A[j - 1, 1] * A[j - 1, 3]) / d
            A[j, 3] = A[j, 3] / d
            continue
        s = A[j, 0]
        for k in range(max(0, j - w), j):
            s -= A[k, j - k] * A[k, j - k]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        A[j, 0] = d
        for col in range(j + 1, min(q, j + w + 1)):
            s = A[j, col - j]
            for k in range(max(0, col - w), j):
                s -= A[k, j - k] * A[k, col - k]
            A[j, col - j] = s / d
    for j in range(q):  # U^T y = r
        if w == 3 and j >= 3:  # unrolled, as above
            rx[j] = (rx[j] - A[j - 3, 3] * rx[j - 3] - A[j - 2, 2] * rx[j - 2] - A[j - 1, 1] * rx[j - 1]) / A[j, 0]
            ry[j] = (ry[j] - A[j - 3, 3] * ry[j - 3] - A[j - 2, 2] * ry[j - 2] - A[j - 1, 1] * ry[j - 1]) / A[j, 0]
            continue
        for k in range(max(0, j - w), j):
            rx[j] -= A[k, j - k] * rx[k]
            ry[j] -= A[k, j - k] * ry[k]
        rx[j] /= A[j, 0]
        ry[j] /= A[j, 0]
    for j in range(q - 1, -1, -1):  # U x = y
        if w == 3 and j < q - 3:
            rx[j] = (rx[j] - A[j, 1] * rx[j + 1] - A[j, 2] * rx[j + 2] - A[j, 3] * rx[j + 3]) / A[j, 0]
            ry[j] = (ry[j] - A[j, 1] * ry[j + 1] - A[j, 2] * ry[j + 2] - A[j, 3] * ry[j + 3]) / A[j, 0]
            continue
        for col in range(j + 1, min(q, j + w + 1)):
            rx[j] -= A[j, col - j] * rx[col]
            ry[j] -= A[j, col - j] * ry[col]
        rx[j] /= A[j, 0]
        ry[j] /= A[j, 0]
    for j in range(q):
        ctrl[j + 1, 0] = rx[j]
        ctrl[j + 1, 1] = ry[j]
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def _pair(a, b, run):  # pragma: no cover - compiled
    """Farthest a point between two samples can be from a set, the samples being
    within a and b of it and ``run`` apart along the path between them (the
    distance is 1-Lipschitz along the path)."""
    return max(max(a, b), 0.5 * (a + b + run))


@numba.njit(cache=True, nogil=True)
def _to_polyline(x, y, P, cum, i, start, limit):  # pragma: no cover - compiled
    """Distance from (x, y) to the polyline P's segments near vertex i, at most
    ``start``: outwards from i until the path has run ``limit`` beyond the best."""
    best = start
    m = P.shape[0]
    for step in (-1, 1):
        j = i if step == 1 else i - 1  # segment j: P[j] -> P[j + 1]
        while 0 <= j < m - 1 and abs(cum[j + (1 if step == -1 else 0)] - cum[i]) <= best + limit:
            ax, ay = P[j, 0], P[j, 1]
            ex, ey = P[j + 1, 0] - ax, P[j + 1, 1] - ay
            ll = ex * ex + ey * ey
            t = 0.0 if ll == 0.0 else min(max(((x - ax) * ex + (y - ay) * ey) / ll, 0.0), 1.0)
            dx, dy = ax + t * ex - x, ay + t * ey - y
            best = min(best, np.sqrt(dx * dx + dy * dy))
            j += step
    return best


@numba.njit(cache=True, nogil=True)
def _to_samples(x, y, Q, cum, i, start, limit):  # pragma: no cover - compiled
    """Distance from (x, y) to the nearest of the samples Q near index i, at most
    ``start`` (outwards until ``cum`` has run ``limit`` beyond the best)."""
    best = start
    m = Q.shape[0]
    for step in (-1, 1):
        j = i
        while 0 <= j < m and abs(cum[j] - cum[i]) <= best + limit:
            dx, dy = Q[j, 0] - x, Q[j, 1] - y
            best = min(best, np.sqrt(dx * dx + dy * dy))
            j += step
    return best



@numba.njit(cache=True, nogil=True)
def _tighten(k, P, Q, cum, ta, tb, done):  # pragma: no cover - compiled
    """Sample k's distance to the nearby polyline (ta[k]) and to the nearby curve
    samples (tb[k]), searched from r = |Q_k - P_k| once: a search started again
    from its own result reaches a part of the same segments (the reach shrinks
    with the start), so it would return the same value."""
    if not done[k]:
        r = np.sqrt((Q[k, 0] - P[k, 0]) ** 2 + (Q[k, 1] - P[k, 1]) ** 2)
        ta[k] = _to_polyline(Q[k, 0], Q[k, 1], P, cum, k, r, r)
        tb[k] = _to_samples(P[k, 0], P[k, 1], Q, cum, k, r, r)
        done[k] = True


QUICK_TRIES = 4  # stretches tried first when an attempt is likely to fail (the first nearly always tells)


@numba.njit(cache=True, nogil=True, inline="always")
def _across(P, Q, i):  # pragma: no cover - compiled
    """How far the curve sample Q_i is off P_i across the polyline's direction there."""
    j = min(i, P.shape[0] - 2)
    ex, ey = P[j + 1, 0] - P[j, 0], P[j + 1, 1] - P[j, 1]
    return abs((Q[i, 0] - P[i, 0]) * ey - (Q[i, 1] - P[i, 1]) * ex) / np.sqrt(ex * ex + ey * ey)


@numba.njit(cache=True, nogil=True)
def _bound(P, u, cum, ctrl, p, tol, give_up, quick, w):  # pragma: no cover - compiled
    """Certified upper bound on the two-way (Hausdorff) distance between the
    spline and the polyline through P (whose consecutive points lie on one
    segment, so the polyline between them is straight).

    At each parameter u_i the curve point Q_i is within r_i = |Q_i - P_i| of the
    polyline, and P_i within r_i of the curve. Between two samples the
    distance changes no faster than the path runs: |P_i+1 - P_i| along the
    polyline, and along the curve at most (u_i+1 - u_i) x the largest speed of
    the spline there (bounded by its derivative's control points, the convex
    hull property). ``_pair`` turns both ends and the run into a bound for
    every point between. Only where that exceeds ``tol`` are the r_i
    tightened (distance to the nearby polyline segments, and to nearby curve
    samples), and with ``give_up`` only until one place stays above ``tol``:
    the attempt has failed then, and the bound returned is still an upper bound.

    A sample's tightened values do not depend on when it is tightened
    (``_tighten``), so the attempt fails exactly when some stretch stays over
    ``tol`` with both its ends tightened, wherever it is. With ``quick`` the
    stretches over ``tol`` where the curve strays farthest across the polyline
    (not along it, as a drifting parameter does) are tried first: a failing
    attempt is nearly always known at the first, instead of after every
    tightening before its failure. Only the value returned for a failure
    differs (still an upper bound, over ``tol``); a success is measured exactly
    as without it.
    w: work arrays Q, a, b, arc, ta, tb, done, worst of each stretch (m, m, m,
    m - 1, m, m, m, m - 1 entries), the basis functions at u (p + 1 rows of m) and their spans
    (``_basis_table``, filled by the caller), and its own work arrays.
    """
    Q, a, b, arc, ta, tb, done, c0, B, F, _, _ = w
    m = P.shape[0]
    n = ctrl.shape[0]
    nseg = n - p
    speed = np.zeros(nseg)  # bound on |q'(u)| on knot span s: its p derivative control points
    for j in range(n - 1):
        h = _knot(j + p + 1, p, nseg) - _knot(j + 1, p, nseg)
        d = p * np.sqrt((ctrl[j + 1, 0] - ctrl[j, 0]) ** 2 + (ctrl[j + 1, 1] - ctrl[j, 1]) ** 2) / h
        for s in range(max(0, j - p + 1), min(nseg, j + 1)):
            speed[s] = max(speed[s], d)
    s_prev = 0
    worst = 0.0
    for i in range(m):
        f = F[i]
        if p == 3:  # the loop below, unrolled: the same sums in the same order
            x = 0.0 + B[0, i] * ctrl[f, 0] + B[1, i] * ctrl[f + 1, 0] + B[2, i] * ctrl[f + 2, 0] + B[3, i] * ctrl[f + 3, 0]
            y = 0.0 + B[0, i] * ctrl[f, 1] + B[1, i] * ctrl[f + 1, 1] + B[2, i] * ctrl[f + 2, 1] + B[3, i] * ctrl[f + 3, 1]
        else:
            x = 0.0
            y = 0.0
            for k in range(p + 1):
                x += B[k, i] * ctrl[f + k, 0]
                y += B[k, i] * ctrl[f + k, 1]
        Q[i, 0], Q[i, 1] = x, y
        # a: curve sample i to the polyline; b (the same until tightened): polyline sample i to the curve
        a[i] = np.sqrt((x - P[i, 0]) ** 2 + (y - P[i, 1]) ** 2)
        if i:  # run along the curve since sample i - 1
            v = 0.0
            for s in range(s_prev, f + 1):
                v = max(v, speed[s])
            arc[i - 1] = (u[i] - u[i - 1]) * v
            # both ways' bounds at once (_pair grows with the run)
            c0[i - 1] = _pair(a[i - 1], a[i], max(arc[i - 1], cum[i] - cum[i - 1]))
            worst = max(worst, c0[i - 1])
        s_prev = f
    if worst <= tol:
        return worst
    b[:] = a
    done[:] = False
    if give_up and quick:
        # where the curve strays across the polyline, not along it (the parameter drifting),
        # is where it fails: the stretches over tol in the order of that offset
        e_prev = -1.0  # _across at i, where known (only the ends of stretches over tol need it)
        for i in range(m - 1):
            if c0[i] > tol:
                if e_prev < 0.0:
                    e_prev = _across(P, Q, i)
                e = _across(P, Q, i + 1)
                c0[i] = max(e_prev, e)
                e_prev = e
            else:
                c0[i] = -1.0
                e_prev = -1.0
        for _ in range(QUICK_TRIES):
            i = np.argmax(c0)
            if not c0[i] > tol:
                break
            c0[i] = -1.0
            _tighten(i, P, Q, cum, ta, tb, done)
            _tighten(i + 1, P, Q, cum, ta, tb, done)
            if _pair(ta[i], ta[i + 1], arc[i]) > tol or _pair(tb[i], tb[i + 1], cum[i + 1] - cum[i]) > tol:
                return worst  # failed for certain
    for i in range(m - 1):
        ca = _pair(a[i], a[i + 1], arc[i])
        cb = _pair(b[i], b[i + 1], cum[i + 1] - cum[i])
        if ca > tol or cb > tol:
            for k in (i, i + 1):
                _tighten(k, P, Q, cum, ta, tb, done)
                a[k] = ta[k]
                b[k] = tb[k]
            if give_up and (_pair(a[i], a[i + 1], arc[i]) > tol or _pair(b[i], b[i + 1], cum[i + 1] - cum[i]) > tol):
                break  # failed for certain
    worst = 0.0
    for i in range(m - 1):
        worst = max(worst, _pair(a[i], a[i + 1], arc[i]), _pair(b[i], b[i + 1], cum[i + 1] - cum[i]))
    return worst


@numba.njit(cache=True, nogil=True)
def _work(m, p):  # pragma: no cover - compiled
    """``_bound``'s work arrays for m samples and degree p."""
    return (np.empty((m, 2)), np.empty(m), np.empty(m), np.empty(m - 1), np.empty(m), np.empty(m),
            np.empty(m, np.bool_), np.empty(m - 1), np.empty((p + 1, m)), np.empty(m, np.int64),
            np.empty((m, p + 1)), np.empty((m, p + 1)))


@numba.njit(cache=True, nogil=True)
def _basis_table(u, n, p, w):  # pragma: no cover - compiled
    """``basis_at`` (the same numbers) for n control points at every u[i]: the
    basis functions into the work array B[:, i], their span into F[i], evaluated
    once for the fit and its bound. Span by span, each step of the recurrence
    for all the span's points before the next: the points' divisions overlap
    (a cubic's spans in vector instructions, ``_cubic_rows``, ``_clamped_rows``)."""
    B, F, left, right = w[8], w[9], w[10], w[11]
    nseg = n - p
    m = u.size
    for i in range(m):
        F[i] = _span_at(u[i], nseg)
    i0 = 0
    while i0 < m:
        s = F[i0]
        i1 = i0
        while i1 < m and F[i1] == s:
            i1 += 1
        if p == 3 and p <= s < nseg - p:
            _cubic_rows(u[i0:i1], B[0, i0:i1], B[1, i0:i1], B[2, i0:i1], B[3, i0:i1], nseg, s)
            i0 = i1
            continue
        k = s + p  # Cox-de Boor as basis_at
        if p == 3:
            _clamped_rows(u[i0:i1], B[0, i0:i1], B[1, i0:i1], B[2, i0:i1], B[3, i0:i1], _knot(k, p, nseg),
                          _knot(k + 1, p, nseg), _knot(k - 1, p, nseg), _knot(k + 2, p, nseg), _knot(k - 2, p, nseg),
                          _knot(k + 3, p, nseg))
            i0 = i1
            continue
        for i in range(i0, i1):
            B[0, i] = 1.0
        for j in range(1, p + 1):
            kl, kr = _knot(k + 1 - j, p, nseg), _knot(k + j, p, nseg)
            for i in range(i0, i1):
                left[i, j] = u[i] - kl
                right[i, j] = kr - u[i]
                saved = 0.0
                for r in range(j):
                    t = B[r, i] / (right[i, r + 1] + left[i, j - r])
                    B[r, i] = saved + right[i, r + 1] * t
                    saved = left[i, j - r] * t
                B[j, i] = saved
        i0 = i1


@numba.njit(cache=True, nogil=True)
def _cubic_rows(x, b0, b1, b2, b3, nseg, s):  # pragma: no cover - compiled
    """``cubic_inner`` at every x (all in the inner span s) into b0..b3 (contiguous rows: vector instructions)."""
    for i in range(x.shape[0]):
        b0[i], b1[i], b2[i], b3[i] = _cubic_inner(x[i], nseg, s)


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _cdb(value, saved, right, left):  # pragma: no cover - compiled
    """One step of Cox-de Boor's inner loop (``basis_at``): the new value and the carried ``saved``."""
    t = value / (right + left)
    return saved + right * t, left * t


# numpy's error model: a division is not tested for zero (its divisors are knot spans, never zero), the
# test that kept the loop from running in vector instructions; the same IEEE divisions otherwise
@numba.njit(cache=True, nogil=True, error_model="numpy")
def _clamped_rows(x, b0, b1, b2, b3, kl1, kr1, kl2, kr2, kl3, kr3):  # pragma: no cover - compiled
    """``basis_at``'s Cox-de Boor for a cubic at every x (all in one span, whose knot k - j + 1 is klj and
    knot k + j krj), unrolled: the same operations in the same order, into the rows b0..b3."""
    for i in range(x.shape[0]):
        xi = x[i]
        l1, r1 = xi - kl1, kr1 - xi
        l2, r2 = xi - kl2, kr2 - xi
        l3, r3 = xi - kl3, kr3 - xi
        n0, n1 = _cdb(1.0, 0.0, r1, l1)  # j = 1
        n0, saved = _cdb(n0, 0.0, r1, l2)  # j = 2
        n1, n2 = _cdb(n1, saved, r2, l1)
        n0, saved = _cdb(n0, 0.0, r1, l3)  # j = 3
        n1, saved = _cdb(n1, saved, r2, l2)
        b2[i], b3[i] = _cdb(n2, saved, r3, l1)
        b0[i] = n0
        b1[i] = n1


@numba.njit(cache=True, nogil=True)
def _measure(P, u, cum, ctrl, p, tol, give_up, quick, w):  # pragma: no cover - compiled
    """``_bound`` of any spline."""
    _basis_table(u, ctrl.shape[0], p, w)
    return _bound(P, u, cum, ctrl, p, tol, give_up, quick, w)


@numba.njit(cache=True, nogil=True)
def _attempt(P, u, cum, n, p, tol, lam, quick, w):  # pragma: no cover - compiled
    """Fit n control points to the points P[0::2] at u[0::2] (P[1::2] are the
    midpoints, checked too); returns (control points, certified deviation),
    deviation -1 if the system could not be solved."""
    ctrl = np.zeros((n, 2))
    ctrl[0] = P[0]
    ctrl[n - 1] = P[P.shape[0] - 1]
    _basis_table(u, n, p, w)
    if not _lsq(P, w[8], w[9], n, p, lam, ctrl):
        return ctrl, -1.0
    return ctrl, _bound(P, u, cum, ctrl, p, tol, True, quick, w)


# ---------------------------------------------------------------- fitting, compiled

@numba.njit(cache=True, nogil=True)
def _block_sum(a, lo, n):  # pragma: no cover - compiled
    """numpy's sum of a[lo:lo + n] for n <= 128: eight running sums."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r = a[lo:lo + 8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(cache=True, nogil=True)
def _sum(a):  # pragma: no cover - compiled
    """a.sum() as numpy adds (pairwise: halves, each cut at a multiple of 8, down
    to blocks of 128), to the last bit: the fit's sampling and search cap depend
    on the length. Without recursion (numba's cache does not keep recursive
    functions)."""
    lo = np.empty(64, np.int64)  # the halves still to add up, depth first
    size = np.empty(64, np.int64)
    state = np.zeros(64, np.int64)  # 0: neither half summed, 1: the first, 2: both
    value = np.empty(64)
    lo[0], size[0], top, v = 0, a.size, 0, 0
    while top >= 0:
        n = size[top]
        n2 = n // 2 - (n // 2) % 8
        if n <= 128:
            value[v] = _block_sum(a, lo[top], n)
            v += 1
            top -= 1
        elif state[top] < 2:
            state[top] += 1
            lo[top + 1] = lo[top] if state[top] == 1 else lo[top] + n2
            size[top + 1] = n2 if state[top] == 1 else n - n2
            state[top + 1] = 0
            top += 1
        else:
            value[v - 2] += value[v - 1]
            v -= 1
            top -= 1
    return value[0]


@numba.njit(cache=True, nogil=True)
def _length(p):  # pragma: no cover - compiled
    seg = np.empty(p.shape[0] - 1)
    for s in range(seg.size):
        seg[s] = np.hypot(p[s + 1, 0] - p[s, 0], p[s + 1, 1] - p[s, 1])
    return _sum(seg)


@numba.njit(cache=True, nogil=True)
def _samples(p, tolerance, length):  # pragma: no cover - compiled
    """The polyline sampled every tolerance / 3, and at least 32 times (the data),
    with the midpoints between (checked, not fitted): points, chord-length
    parameters, path length. (A stroke only a few tolerances long had so few
    samples that the bound's run between them dwarfed the true deviation.)
    Each point is computed as ``densify`` computes it."""
    spacing = min(tolerance / 3, length / 32)
    count = np.empty(p.shape[0] - 1, np.int64)
    for s in range(count.size):
        count[s] = max(int(np.ceil(np.hypot(p[s + 1, 0] - p[s, 0], p[s + 1, 1] - p[s, 1]) / spacing)), 1)
    pts = np.empty((2 * count.sum() + 1, 2))
    k = 0
    for s in range(count.size):
        for j in range(count[s]):
            for c in range(2):
                pts[k, c] = p[s, c] + (p[s + 1, c] - p[s, c]) * (j / count[s])
            k += 2
    pts[k] = p[p.shape[0] - 1]
    for k in range(1, pts.shape[0], 2):
        for c in range(2):
            pts[k, c] = (pts[k - 1, c] + pts[k + 1, c]) / 2
    cum = np.empty(pts.shape[0])
    cum[0] = 0.0
    for k in range(1, pts.shape[0]):
        cum[k] = cum[k - 1] + np.hypot(pts[k, 0] - pts[k - 1, 0], pts[k, 1] - pts[k - 1, 1])
    return pts, cum / cum[-1], cum


CORNERED = 0.1  # radians a vertex turns on average, above which a polyline's vertices are its corners
SPANS_PER_RADIAN = 2.0  # a flattened curve's first guess: a knot span per half radian it turns


@numba.njit(cache=True, nogil=True)
def _turning(p):  # pragma: no cover - compiled
    """The total angle (radians) the polyline p turns through at its vertices."""
    total = 0.0
    for i in range(1, p.shape[0] - 1):
        ax, ay = p[i, 0] - p[i - 1, 0], p[i, 1] - p[i - 1, 1]
        bx, by = p[i + 1, 0] - p[i, 0], p[i + 1, 1] - p[i, 1]
        total += abs(np.arctan2(ax * by - ay * bx, ax * bx + ay * by))
    return total


@numba.njit(cache=True, nogil=True)
def _search(p, degree, tolerance, max_control, length, quick):  # pragma: no cover - compiled
    """The fewest control points found within ``tolerance`` of the polyline p
    (at least two points, none repeated): (control points, certified deviation)."""
    # Sample the polyline finely enough that the fit follows its segments, not
    # just its vertices, and that the deviation bound is tight.
    pts, u, cum = _samples(p, tolerance, length)
    m = (pts.shape[0] + 1) // 2  # data points
    w = _work(pts.shape[0], degree)
    n_min = degree + 1
    n_max = min(max_control, max(n_min, 2 * m))
    # Start from a guess, grow until within tolerance, then bisect (_grow_bisect). A
    # polyline whose vertices are corners (a traced outline) needs a few control points
    # per vertex to turn them; a curve flattened into many vertices, each turning a
    # little, about a knot span per half radian it turns.
    turning = _turning(p)
    cornered = turning > CORNERED * (p.shape[0] - 2)
    n = 2 * p.shape[0] if cornered else degree + int(SPANS_PER_RADIAN * turning)
    tried = [(0, np.empty((0, 2)), 0.0)][:0]  # every attempt's (count, control points, deviation): none twice
    ctrl, err, grew, ok = _grow_bisect(pts, u, cum, min(max(n, n_min), n_max), n_min - 1, n_max, degree, tolerance,
                                       quick, w, m, tried)
    if not ok:  # not within the cap: the caller splits (counts below it seldom do better)
        if quick and err < np.inf:  # the value the search without the shortcut reports
            err = _measure(pts, u, cum, ctrl, degree, tolerance, True, False, w)
        return ctrl, err
    if not cornered and grew >= 3:
        # The guess was far too low: a curve with cusps among its flattened vertices, where whether
        # a count fits need not be monotone (the bisection lands on one boundary of several). The
        # search from two control points per vertex is run too, and the fewer control points kept.
        c2, e2, _, ok2 = _grow_bisect(pts, u, cum, min(max(2 * p.shape[0], n_min), n_max), n_min - 1, n_max, degree,
                                      tolerance, quick, w, m, tried)
        if ok2 and c2.shape[0] < ctrl.shape[0]:
            ctrl, err = c2, e2
    return ctrl, err


@numba.njit(cache=True, nogil=True)
def _tried(P, u, cum, n, p, tol, lam, quick, w, tried):  # pragma: no cover - compiled
    """``_attempt``, or its result kept in ``tried`` when n was tried before (the second search of
    ``_search`` meets some counts of the first: an attempt depends on n alone, so it is the same)."""
    for k in range(len(tried)):
        if tried[k][0] == n:
            return tried[k][1], tried[k][2]
    ctrl, err = _attempt(P, u, cum, n, p, tol, lam, quick, w)
    tried.append((n, ctrl, err))
    return ctrl, err


@numba.njit(cache=True, nogil=True)
def _grow_bisect(pts, u, cum, n, lo, n_max, degree, tolerance, quick, w, m, tried):  # pragma: no cover - compiled
    """_search from n control points (lo: a count known not to fit): grow by half until within
    tolerance or at n_max, then bisect down to one above the last count that did not fit.
    (control points, deviation, times grown, within tolerance)."""
    ctrl, err = _tried(pts, u, cum, n, degree, tolerance, 1e-9 * m / n, quick, w, tried)
    err = np.inf if err < 0 else err
    grew = 0
    while err > tolerance and n < n_max:
        lo, n = n, min(n_max, int(np.ceil(n * 1.5)))
        ctrl, err = _tried(pts, u, cum, n, degree, tolerance, 1e-9 * m / n, quick, w, tried)
        err = np.inf if err < 0 else err
        grew += 1
    if err > tolerance:
        return ctrl, err, grew, False
    hi = n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        c, e = _tried(pts, u, cum, mid, degree, tolerance, 1e-9 * m / mid, quick, w, tried)
        if e >= 0 and e <= tolerance:
            hi, ctrl, err = mid, c, e
        else:
            lo = mid
    return ctrl, err, grew, True


@numba.njit(cache=True, nogil=True)
def _segment(p, degree):  # pragma: no cover - compiled
    """A straight segment p[0] -> p[1] exactly: the Bezier control points evenly
    spaced on it (its Greville abscissae j / degree, where a B-spline reproduces
    a linear function), so the curve is the segment at chord-length speed."""
    ctrl = np.empty((degree + 1, 2))
    for j in range(degree + 1):
        for c in range(2):
            ctrl[j, c] = p[0, c] + (j / degree) * (p[1, c] - p[0, c])
    return ctrl


@numba.njit(cache=True, nogil=True)
def _fit_all(pts, first, last, degree, tolerance, max_control, quick):  # pragma: no cover - compiled
    """Fit each piece pts[first[k]:last[k] + 1] (no repeated points): all their
    control points one after another, how many each has, and each certified
    deviation. A straight segment is exact (``_segment``). A longer piece's search is capped: a polyline that needs far more
    control points than it has vertices has a corner no smooth curve turns
    cheaply (the caller splits it there)."""
    out = np.empty((4 * first.size + 64, 2))
    count = np.empty(first.size, np.int64)
    err = np.zeros(first.size)
    k0 = 0
    for k in range(first.size):
        p = pts[first[k]:last[k] + 1]
        if p.shape[0] == 2:
            ctrl = _segment(p, degree)
        else:
            length = _length(p)
            cap = min(max_control, 8 * p.shape[0] + 20 + int(length / (4 * tolerance)))
            ctrl, err[k] = _search(p, degree, tolerance, cap, length, quick)
        while k0 + ctrl.shape[0] > out.shape[0]:
            grown = np.empty((2 * out.shape[0], 2))
            grown[:k0] = out[:k0]
            out = grown
        out[k0:k0 + ctrl.shape[0]] = ctrl
        count[k] = ctrl.shape[0]
        k0 += ctrl.shape[0]
    return out[:k0], count, err


# ---------------------------------------------------------------- fitting

def _check_points(p: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return _samples(p, tolerance, _length(p))


def deviation(spline: Spline, points, tolerance: float = 0.1) -> float:
    """Certified upper bound (mm) on the two-way (Hausdorff) distance between
    ``spline`` and the polyline ``points``, sampled as ``fit_polyline`` does for
    this ``tolerance`` (the bound is tight where the spline's parameter follows
    the polyline's chord length, as a fit's does)."""
    pts, u, cum = _check_points(_dedupe(np.asarray(points, dtype=float)), tolerance)
    return float(_measure(pts, u, cum, np.asarray(spline.control, float), spline.degree, 0.0, False, False,
                          _work(len(pts), spline.degree)))


def fit_polyline(points, degree: int = 3, tolerance: float = 0.1, max_control: int = 2000,
                 quick: bool = True) -> tuple[Spline, float]:
    """The clamped uniform B-spline with the fewest control points found within
    ``tolerance`` (mm) of the polyline, and its certified deviation. (``quick``:
    tell failed attempts early, see ``_bound``; the result is the same without.)"""
    p = _dedupe(np.asarray(points, dtype=float))
    if len(p) < 2:
        raise ValueError("a polyline needs two distinct points")
    return _fit(p, degree, tolerance, max_control, quick)


def _fit(p: np.ndarray, degree: int, tolerance: float, max_control: int, quick: bool = True) -> tuple[Spline, float]:
    """``fit_polyline`` of a polyline without repeated points."""
    if len(p) == 2:
        return Spline(degree, _segment(p, degree)), 0.0
    ctrl, err = _search(p, degree, tolerance, max_control, _length(p), quick)
    return Spline(degree, ctrl), float(err)


def fit_pieces(points, degree: int = 3, tolerance: float = 0.1, max_control: int = 2000,
               corner: float = 0.0) -> list[tuple[Spline, float]]:
    """Like ``fit_polyline``, but never returns a fit outside the tolerance:
    a polyline no spline of up to ``max_control`` points follows (it doubles
    back on itself, say) is split at its sharpest corner and the halves are
    fitted separately. With ``corner`` > 0 (degrees) the polyline is first cut
    at every vertex where it turns by more than that: a zig-zag (joined
    hatching) becomes straight pieces, each exact at once, where one spline
    would need a long search to turn corners the pen stops at anyway. The
    pieces meet exactly, in order (the pen stays down between them, Job.lifts)."""
    return fit_many([points], degree, tolerance, max_control, corner)[0]


def fit_many(polylines, degree: int = 3, tolerance: float = 0.1, max_control: int = 2000,
             corner: float = 0.0, quick: bool = True) -> list[list[tuple[Spline, float]]]:
    """``fit_pieces`` of each polyline, the same pieces, in one compiled call for all
    of them (a generated drawing has thousands of short paths: no Python per attempt)."""
    polys = [np.asarray(p, dtype=float) for p in polylines]
    if not polys:
        return []
    if any(p.ndim != 2 or p.shape[1] != 2 or len(p) < 2 for p in polys):
        raise ValueError("a polyline needs two distinct points")
    pts = np.concatenate(polys)
    starts = np.cumsum([0] + [len(p) for p in polys])
    # _dedupe of each polyline: a point as good as repeating the previous one of its own polyline goes
    near = np.zeros(len(pts), bool)
    d = np.abs(np.diff(pts, axis=0))
    near[1:] = ~((d[:, 0] > SAME_POINT) | (d[:, 1] > SAME_POINT))  # np.any over the two axes, without its reduce
    near[starts[:-1]] = False
    if near.any():  # rare: those polylines one by one (measured from the last point kept)
        for i in np.unique(np.searchsorted(starts, np.flatnonzero(near), side="right") - 1):
            polys[i] = _dedupe(polys[i])
        pts = np.concatenate(polys)
        starts = np.cumsum([0] + [len(p) for p in polys])
    if np.any(np.diff(starts) < 2):
        raise ValueError("a polyline needs two distinct points")
    # the pieces: between each polyline's ends and (split_corners) its vertices turning by more than corner
    ends = starts[1:] - 1
    cut = np.zeros(len(pts), bool)
    cut[starts[:-1]] = cut[ends] = True
    if corner > 0 and len(pts) > 2:
        inner = np.flatnonzero(np.degrees(_turns(np.diff(pts, axis=0))) > corner) + 1
        cut[inner] = True  # turns across two polylines too: harmless, their ends are cut already
    marks = np.flatnonzero(cut)
    within = ~np.isin(marks[:-1], ends)  # a stretch from a polyline's end to the next one's start is none
    first, last = marks[:-1][within], marks[1:][within]
    owner = np.searchsorted(starts, first, side="right") - 1
    ctrl, count, err = _fit_all(pts, first, last, degree, tolerance, max_control, quick)
    out: list[list[tuple[Spline, float]]] = [[] for _ in polys]
    stop = np.cumsum(count)
    # Python numbers: no NumPy scalar per piece
    for k, (a, b, e, o) in enumerate(zip((stop - count).tolist(), stop.tolist(), err.tolist(), owner.tolist())):
        if e <= tolerance:
            out[o].append((Spline(degree, ctrl[a:b]), e))
        else:  # no spline within the cap follows it: split at the sharpest corner
            p = pts[first[k]:last[k] + 1]
            out[o] += _split(p, degree, tolerance, max_control, quick)
    return out


def _turns(d: np.ndarray) -> np.ndarray:
    """The angle (radians, 0..pi) the polyline with segments ``d`` turns at each inner vertex."""
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    # numpy's sum, not d[:-1, 0] * d[1:, 0] + d[:-1, 1] * d[1:, 1]: its reduction starts from +0.0, so two
    # signed zeros sum to +0.0 where the plain addition gives -0.0, and arctan2 turns that into 0 or pi
    return np.abs(np.arctan2(cross, (d[:-1] * d[1:]).sum(axis=1)))


def turn_angles(p: np.ndarray) -> np.ndarray:
    """The angle (radians, 0..pi) the polyline through the points ``p`` turns at each inner point."""
    return _turns(np.diff(np.asarray(p, dtype=float), axis=0))


def split_corners(p: np.ndarray, corner: float) -> list[np.ndarray]:
    """The polyline cut at every vertex turning by more than ``corner`` degrees
    (pieces share the vertex)."""
    cut = np.flatnonzero(np.degrees(_turns(np.diff(p, axis=0))) > corner) + 1
    bounds = np.r_[0, cut, len(p) - 1]
    return [p[a:b + 1] for a, b in zip(bounds[:-1], bounds[1:])]


def _pieces(p: np.ndarray, degree: int, tolerance: float, max_control: int, quick: bool) -> list[tuple[Spline, float]]:
    """The piece p fitted (``_fit_all``), or split at its sharpest corner until each part fits."""
    ctrl, _, err = _fit_all(p, np.array([0]), np.array([len(p) - 1]), degree, tolerance, max_control, quick)
    if err[0] <= tolerance:
        return [(Spline(degree, ctrl), float(err[0]))]
    return _split(p, degree, tolerance, max_control, quick)


def _split(p: np.ndarray, degree: int, tolerance: float, max_control: int, quick: bool) -> list[tuple[Spline, float]]:
    k = int(np.argmax(_turns(np.diff(p, axis=0)))) + 1
    return (_pieces(p[: k + 1], degree, tolerance, max_control, quick)
            + _pieces(p[k:], degree, tolerance, max_control, quick))
