"""Fit: polylines (mm) to clamped uniform B-splines within a tolerance.

Least squares with the end points pinned (a clamped spline passes through its
first and last control points), on chord-length parameters. The number of
control points grows until the deviation from the polyline, measured both
ways, is within the tolerance; then a bisection finds the smallest count.
The reported deviation is a certified upper bound (see ``_bound``), local:
each stretch between two neighbouring samples is bounded on its own.

Each attempt is compiled (numba): the basis functions at every data point,
the banded normal equations and their Cholesky solve, the curve and the
bound, in O(data points x degree^2) without Python in the loop. A straight
segment needs no search: its Bezier is exact.
"""

from __future__ import annotations

import numba
import numpy as np

from doodlecam.geometry.kernels import basis_at as _basis_at
from doodlecam.geometry.kernels import knot as _knot
from doodlecam.model import SAME_POINT, Spline


def _dedupe(p: np.ndarray) -> np.ndarray:
    """p without the points within model.SAME_POINT (per axis) of the last point kept: one point to
    the job as to its pen lifts, so no piece between two corners is a stroke of no length (seen: ends
    merged 1.7e-7 mm apart at a corner of a generated drawing)."""
    if np.any(np.abs(np.diff(p, axis=0)) > SAME_POINT, axis=1).all():
        return p
    keep = [0]
    for i in range(1, len(p)):  # rare: measured from the last point kept, so a dense run is not dropped whole
        if np.abs(p[i] - p[keep[-1]]).max() > SAME_POINT:
            keep.append(i)
    return p[keep]


def densify(p: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline with extra points so no segment is longer than ``spacing``."""
    seg = np.diff(p, axis=0)
    n = np.maximum(np.ceil(np.hypot(*seg.T) / spacing).astype(int), 1)
    starts = np.repeat(np.arange(len(seg)), n)
    frac = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    pts = p[starts] + seg[starts] * (frac / n[starts])[:, None]
    return np.vstack([pts, p[-1:]])


# ---------------------------------------------------------------- compiled kernels

@numba.njit(cache=True, nogil=True)
def _lsq(P, u, n, p, lam, ctrl):  # pragma: no cover - compiled
    """Least-squares control points for the data P[0::2] at u[0::2], with
    ctrl[0] and ctrl[n - 1] given (the pinned ends), plus ``lam`` x the squared
    second differences of the control points so one without data under it
    stays defined. Banded normal equations, Cholesky. Fills ctrl[1:n - 1];
    False if the system is not positive definite."""
    m = P.shape[0]
    q = n - 2
    if q <= 0:
        return True
    nseg = n - p
    N = np.empty(p + 1)
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    w = max(p, 2)  # half bandwidth: data couple p + 1 neighbours, the smoothing 3
    A = np.zeros((q, w + 1))  # A[a, d] = N[a, a + d]; unknown a is control point a + 1
    rx = np.zeros(q)
    ry = np.zeros(q)
    for i in range(0, m, 2):
        f = _basis_at(u[i], p, nseg, N, left, right)
        dx, dy = P[i, 0], P[i, 1]  # the data minus the pinned ends' share
        if f == 0:
            dx -= N[0] * ctrl[0, 0]
            dy -= N[0] * ctrl[0, 1]
        if f + p == n - 1:
            dx -= N[p] * ctrl[n - 1, 0]
            dy -= N[p] * ctrl[n - 1, 1]
        for a in range(p + 1):
            ca = f + a - 1
            if ca < 0 or ca >= q:
                continue
            va = N[a]
            rx[ca] += va * dx
            ry[ca] += va * dy
            for b in range(a, p + 1):
                cb = f + b - 1
                if cb >= q:
                    break
                A[ca, cb - ca] += va * N[b]
    coef = np.array([1.0, -2.0, 1.0])
    for k in range(n - 2):  # row k of the second differences: control points k, k + 1, k + 2
        for a in range(3):
            ca = k + a - 1
            if ca < 0 or ca >= q:
                continue
            for b in range(3):
                c = k + b
                v = lam * coef[a] * coef[b]
                if c == 0 or c == n - 1:
                    rx[ca] -= v * ctrl[c, 0]
                    ry[ca] -= v * ctrl[c, 1]
                elif c - 1 >= ca:
                    A[ca, c - 1 - ca] += v
    for j in range(q):  # A = U^T U, U upper banded, in place
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
        for k in range(max(0, j - w), j):
            rx[j] -= A[k, j - k] * rx[k]
            ry[j] -= A[k, j - k] * ry[k]
        rx[j] /= A[j, 0]
        ry[j] /= A[j, 0]
    for j in range(q - 1, -1, -1):  # U x = y
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
def _bound(P, u, cum, ctrl, p, tol, give_up, Q, a, b, arc):  # pragma: no cover - compiled
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
    Q, a, b, arc: work arrays of m, m, m and m - 1 entries.
    """
    m = P.shape[0]
    n = ctrl.shape[0]
    nseg = n - p
    N = np.empty(p + 1)
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    speed = np.zeros(nseg)  # bound on |q'(u)| on knot span s: its p derivative control points
    for j in range(n - 1):
        h = _knot(j + p + 1, p, nseg) - _knot(j + 1, p, nseg)
        d = p * np.sqrt((ctrl[j + 1, 0] - ctrl[j, 0]) ** 2 + (ctrl[j + 1, 1] - ctrl[j, 1]) ** 2) / h
        for s in range(max(0, j - p + 1), min(nseg, j + 1)):
            speed[s] = max(speed[s], d)
    s_prev = 0
    for i in range(m):
        f = _basis_at(u[i], p, nseg, N, left, right)
        x = 0.0
        y = 0.0
        for k in range(p + 1):
            x += N[k] * ctrl[f + k, 0]
            y += N[k] * ctrl[f + k, 1]
        Q[i, 0], Q[i, 1] = x, y
        a[i] = b[i] = np.sqrt((x - P[i, 0]) ** 2 + (y - P[i, 1]) ** 2)
        if i:  # run along the curve since sample i - 1
            v = 0.0
            for s in range(s_prev, f + 1):
                v = max(v, speed[s])
            arc[i - 1] = (u[i] - u[i - 1]) * v
        s_prev = f
    # a: curve sample i to the polyline; b: polyline sample i to the curve
    worst = 0.0
    for i in range(m - 1):
        worst = max(worst, _pair(a[i], a[i + 1], arc[i]), _pair(b[i], b[i + 1], cum[i + 1] - cum[i]))
    if worst <= tol:
        return worst
    for i in range(m - 1):
        ca = _pair(a[i], a[i + 1], arc[i])
        cb = _pair(b[i], b[i + 1], cum[i + 1] - cum[i])
        if ca > tol or cb > tol:
            for k in (i, i + 1):
                r = np.sqrt((Q[k, 0] - P[k, 0]) ** 2 + (Q[k, 1] - P[k, 1]) ** 2)
                a[k] = _to_polyline(Q[k, 0], Q[k, 1], P, cum, k, a[k], r)
                b[k] = _to_samples(P[k, 0], P[k, 1], Q, cum, k, b[k], r)
            if give_up and (_pair(a[i], a[i + 1], arc[i]) > tol or _pair(b[i], b[i + 1], cum[i + 1] - cum[i]) > tol):
                break  # failed for certain
    worst = 0.0
    for i in range(m - 1):
        worst = max(worst, _pair(a[i], a[i + 1], arc[i]), _pair(b[i], b[i + 1], cum[i + 1] - cum[i]))
    return worst


@numba.njit(cache=True, nogil=True)
def _attempt(P, u, cum, n, p, tol, lam, Q, a, b, arc):  # pragma: no cover - compiled
    """Fit n control points to the points P[0::2] at u[0::2] (P[1::2] are the
    midpoints, checked too); returns (control points, certified deviation),
    deviation -1 if the system could not be solved."""
    ctrl = np.zeros((n, 2))
    ctrl[0] = P[0]
    ctrl[n - 1] = P[P.shape[0] - 1]
    if not _lsq(P, u, n, p, lam, ctrl):
        return ctrl, -1.0
    return ctrl, _bound(P, u, cum, ctrl, p, tol, True, Q, a, b, arc)


# ---------------------------------------------------------------- fitting

def _check_points(p: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The polyline sampled every tolerance / 3, and at least 32 times (the data),
    with the midpoints between (checked, not fitted): points, chord-length
    parameters, path length. (A stroke only a few tolerances long had so few
    samples that the bound's run between them dwarfed the true deviation.)"""
    length = float(np.hypot(*np.diff(p, axis=0).T).sum())
    dense = densify(p, min(tolerance / 3, length / 32))
    pts = np.empty((2 * len(dense) - 1, 2))
    pts[0::2] = dense
    pts[1::2] = (dense[:-1] + dense[1:]) / 2
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    return pts, cum / cum[-1], cum


def deviation(spline: Spline, points, tolerance: float = 0.1) -> float:
    """Certified upper bound (mm) on the two-way (Hausdorff) distance between
    ``spline`` and the polyline ``points``, sampled as ``fit_polyline`` does for
    this ``tolerance`` (the bound is tight where the spline's parameter follows
    the polyline's chord length, as a fit's does)."""
    pts, u, cum = _check_points(_dedupe(np.asarray(points, dtype=float)), tolerance)
    m = len(pts)
    return float(_bound(pts, u, cum, np.asarray(spline.control, float), spline.degree, 0.0, False,
                        np.empty((m, 2)), np.empty(m), np.empty(m), np.empty(m - 1)))


def _segment(p: np.ndarray, degree: int) -> Spline:
    """A straight segment exactly: the Bezier control points evenly spaced on it
    (its Greville abscissae j / degree, where a B-spline reproduces a linear
    function), so the curve is the segment at chord-length speed."""
    return Spline(degree, p[0] + (np.arange(degree + 1) / degree)[:, None] * (p[-1] - p[0]))


def fit_polyline(points, degree: int = 3, tolerance: float = 0.1, max_control: int = 2000) -> tuple[Spline, float]:
    """The clamped uniform B-spline with the fewest control points found within
    ``tolerance`` (mm) of the polyline, and its certified deviation."""
    p = _dedupe(np.asarray(points, dtype=float))
    if len(p) < 2:
        raise ValueError("a polyline needs two distinct points")
    return _fit(p, degree, tolerance, max_control)


def _fit(p: np.ndarray, degree: int, tolerance: float, max_control: int) -> tuple[Spline, float]:
    """``fit_polyline`` of a polyline without repeated points."""
    if len(p) == 2:
        return _segment(p, degree), 0.0
    # Sample the polyline finely enough that the fit follows its segments, not
    # just its vertices, and that the deviation bound is tight.
    pts, u, cum = _check_points(p, tolerance)
    m = (len(pts) + 1) // 2  # data points
    n_min = degree + 1
    n_max = int(min(max_control, max(n_min, 2 * m)))
    cache: dict[int, tuple[np.ndarray, float]] = {}
    work = np.empty((len(pts), 2)), np.empty(len(pts)), np.empty(len(pts)), np.empty(len(pts) - 1)

    def attempt(n: int) -> tuple[np.ndarray, float]:
        if n not in cache:
            ctrl, err = _attempt(pts, u, cum, n, degree, tolerance, 1e-9 * m / n, *work)
            cache[n] = (ctrl, np.inf if err < 0 else err)
        return cache[n]

    # A polyline needs a few control points per vertex to turn its corners
    # within tolerance: start there, grow until within tolerance, then bisect.
    n = int(np.clip(2 * len(p), n_min, n_max))
    lo = n_min - 1
    while attempt(n)[1] > tolerance and n < n_max:
        lo, n = n, min(n_max, int(np.ceil(n * 1.5)))
    if attempt(n)[1] > tolerance:  # not within the cap: the caller splits (counts below it seldom do better)
        return Spline(degree, attempt(n)[0]), attempt(n)[1]
    hi = n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if attempt(mid)[1] <= tolerance:
            hi = mid
        else:
            lo = mid
    ctrl, err = attempt(hi)
    return Spline(degree, ctrl), err


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
    p = _dedupe(np.asarray(points, dtype=float))
    if len(p) < 2:
        raise ValueError("a polyline needs two distinct points")
    out: list[tuple[Spline, float]] = []
    for piece in split_corners(p, corner) if corner > 0 else (p,):
        out += _pieces(piece, degree, tolerance, max_control)
    return out


def _turns(d: np.ndarray) -> np.ndarray:
    """The angle (radians, 0..pi) the polyline with segments ``d`` turns at each inner vertex."""
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
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


def _pieces(p: np.ndarray, degree: int, tolerance: float, max_control: int) -> list[tuple[Spline, float]]:
    if len(p) == 2:
        return [(_segment(p, degree), 0.0)]
    # Cap the search: a polyline that needs far more control points than it
    # has vertices has a corner no smooth curve turns cheaply; split there.
    d = np.diff(p, axis=0)
    length = float(np.hypot(d[:, 0], d[:, 1]).sum())
    cap = min(max_control, 8 * len(p) + 20 + int(length / (4 * tolerance)))
    spline, err = _fit(p, degree, tolerance, cap)
    if err <= tolerance:
        return [(spline, err)]
    k = int(np.argmax(_turns(d))) + 1
    return _pieces(p[: k + 1], degree, tolerance, max_control) + _pieces(p[k:], degree, tolerance, max_control)
