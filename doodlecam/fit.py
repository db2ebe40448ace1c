"""Fit: polylines (mm) to clamped uniform B-splines within a tolerance.

Least squares with the end points pinned (a clamped spline passes through its
first and last control points), on chord-length parameters. The number of
control points grows until the deviation from the polyline, measured both
ways, is within the tolerance; then a bisection finds the smallest count.
The reported deviation is a certified upper bound (see ``deviation``).
"""

from __future__ import annotations

import numpy as np

from .model import Spline


def _dedupe(p: np.ndarray) -> np.ndarray:
    keep = np.ones(len(p), bool)
    keep[1:] = np.any(np.abs(np.diff(p, axis=0)) > 1e-12, axis=1)
    return p[keep]


def densify(p: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline with extra points so no segment is longer than ``spacing``."""
    seg = np.diff(p, axis=0)
    n = np.maximum(np.ceil(np.hypot(*seg.T) / spacing).astype(int), 1)
    starts = np.repeat(np.arange(len(seg)), n)
    frac = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    pts = p[starts] + seg[starts] * (frac / n[starts])[:, None]
    return np.vstack([pts, p[-1:]])


def chord_params(p: np.ndarray) -> np.ndarray:
    d = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    return d / d[-1]


def lsq_spline(points: np.ndarray, u: np.ndarray, n_control: int, degree: int) -> Spline:
    """Least-squares clamped uniform spline through data (u_i, points_i), ends pinned.

    scipy's banded least squares, with the two end points weighted so heavily
    that the fit passes through them (then set exactly: a clamped spline's end
    control points are its end points).
    """
    from scipy.interpolate import make_lsq_spline

    knots = Spline.uniform_knots(n_control, degree)
    w = np.ones(len(u))
    w[0] = w[-1] = 1e4
    try:
        ctrl = make_lsq_spline(u, points, knots, degree, w=w, method="norm-eq").c.copy()
    except (ValueError, np.linalg.LinAlgError):  # too few data under some basis function
        return _lsq_regularised(points, u, n_control, degree)
    ctrl[0], ctrl[-1] = points[0], points[-1]
    return Spline(degree, ctrl)


def _lsq_regularised(points: np.ndarray, u: np.ndarray, n_control: int, degree: int) -> Spline:
    """Fallback: normal equations with a whisper of second-difference smoothing,
    so control points without data under their support stay well defined."""
    import scipy.sparse as sp
    from scipy.interpolate import BSpline
    from scipy.sparse.linalg import spsolve

    knots = Spline.uniform_knots(n_control, degree)
    B = BSpline.design_matrix(u, knots, degree).tocsc()
    p0, p1 = points[0], points[-1]
    ctrl = np.empty((n_control, 2))
    ctrl[0], ctrl[-1] = p0, p1
    if n_control > 2:
        rhs = points - B[:, [0]].toarray() * p0 - B[:, [n_control - 1]].toarray() * p1
        Bi = B[:, 1:-1]
        D = sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n_control - 2, n_control)).tocsc()
        lam = 1e-9 * len(u) / n_control
        N = (Bi.T @ Bi + lam * (D[:, 1:-1].T @ D[:, 1:-1])).tocsc()
        r = Bi.T @ rhs - lam * D[:, 1:-1].T @ (D[:, [0]] @ p0[None, :] + D[:, [n_control - 1]] @ p1[None, :])
        ctrl[1:-1] = spsolve(N, np.asarray(r)).reshape(n_control - 2, 2)
    return Spline(degree, ctrl)


def deviation(spline: Spline, dense_poly: np.ndarray, u: np.ndarray, tolerance: float = 0.0, poly_tree=None) -> float:
    """Upper bound (mm) on the two-way (Hausdorff) distance spline <-> polyline.

    Cheap bound first: every data point P_i is within r_i = |q(u_i) - P_i| of
    the curve and vice versa, and a point between two samples is within half
    their gap of one of them. If that bound is not already within
    ``tolerance``, nearest-sample distances (KD-trees, both ways) give a
    tighter one: they over-estimate the distance to a set, and the same
    half-gap term covers the points between samples. Only the points whose
    cheap bound fails are looked up, and the polyline's tree is reused across
    attempts (``poly_tree``).
    """
    from scipy.spatial import cKDTree

    curve = spline(u)
    gap = lambda p: np.hypot(*np.diff(p, axis=0).T).max()  # noqa: E731
    half = max(gap(curve), gap(dense_poly)) / 2
    r = np.hypot(*(curve - dense_poly).T) + half
    cheap = float(r.max())
    if cheap <= tolerance:
        return cheap
    bad = r > tolerance  # only these can fail; the rest are within tolerance already
    tree = poly_tree if poly_tree is not None else cKDTree(dense_poly)
    d1 = tree.query(curve[bad])[0].max()
    d2 = cKDTree(curve).query(dense_poly[bad])[0].max()
    return min(cheap, float(max(d1, d2, float(r[~bad].max(initial=0.0)) - half) + half))


def fit_polyline(points, degree: int = 3, tolerance: float = 0.1, max_control: int = 2000) -> tuple[Spline, float]:
    """The clamped uniform B-spline with the fewest control points found within
    ``tolerance`` (mm) of the polyline, and its certified deviation."""
    p = _dedupe(np.asarray(points, dtype=float))
    if len(p) < 2:
        raise ValueError("a polyline needs two distinct points")
    # Sample the polyline finely enough that the fit follows its segments, not
    # just its vertices, and that the deviation bound is tight.
    dense = densify(p, tolerance / 3)
    u = chord_params(dense)
    n_min = degree + 1
    n_max = int(min(max_control, max(n_min, 2 * len(dense))))

    from scipy.spatial import cKDTree

    cache: dict[int, tuple[Spline, float]] = {}
    tree: list = []  # the polyline's KD-tree, built on first need

    def attempt(n: int) -> tuple[Spline, float]:
        if n not in cache:
            s = lsq_spline(dense, u, n, degree)
            if not tree:
                tree.append(cKDTree(dense))
            cache[n] = (s, deviation(s, dense, u, tolerance, tree[0]))
        return cache[n]

    # A polyline needs a few control points per vertex to turn its corners
    # within tolerance: start there, grow until within tolerance, then bisect.
    n = int(np.clip(2 * len(p), n_min, n_max))
    lo = n_min - 1
    while attempt(n)[1] > tolerance and n < n_max:
        lo, n = n, min(n_max, int(np.ceil(n * 1.5)))
    hi = n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if attempt(mid)[1] <= tolerance:
            hi = mid
        else:
            lo = mid
    return attempt(hi)


def fit_pieces(points, degree: int = 3, tolerance: float = 0.1, max_control: int = 2000) -> list[tuple[Spline, float]]:
    """Like ``fit_polyline``, but never returns a fit outside the tolerance:
    a polyline no spline of up to ``max_control`` points follows (it doubles
    back on itself, say) is split at its sharpest corner and the halves are
    fitted separately."""
    p = _dedupe(np.asarray(points, dtype=float))
    # Cap the search: a polyline that needs far more control points than it
    # has vertices has a corner no smooth curve turns cheaply; split there.
    length = float(np.hypot(*np.diff(p, axis=0).T).sum())
    cap = min(max_control, 8 * len(p) + 20 + int(length / (4 * tolerance)))
    spline, err = fit_polyline(p, degree, tolerance, cap)
    if err <= tolerance or len(p) < 3:
        return [(spline, err)]
    d = np.diff(p, axis=0)
    cross = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    turn = np.abs(np.arctan2(cross, (d[:-1] * d[1:]).sum(axis=1)))
    k = int(np.argmax(turn)) + 1
    return fit_pieces(p[: k + 1], degree, tolerance, max_control) + fit_pieces(p[k:], degree, tolerance, max_control)
