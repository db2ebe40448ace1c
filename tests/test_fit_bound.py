"""The fit's certified deviation against a brute-force Hausdorff distance, and its fast paths."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from doodlecam.geometry.fit import deviation, fit_pieces, fit_polyline
from doodlecam.model import Spline


def _to_segments(pts, a, b):
    """Distance from each point to the nearest of the segments a[k] -> b[k] (all of them)."""
    best = np.full(len(pts), np.inf)
    for p, q in zip(a, b):
        e = q - p
        t = np.clip(((pts - p) @ e) / max(e @ e, 1e-300), 0.0, 1.0)
        best = np.minimum(best, np.hypot(*(p + t[:, None] * e - pts).T))
    return best


def hausdorff(spline, poly, n=200_001):
    """Two-way distance curve <-> polyline, by brute force: the curve sampled
    finely, exact distances to the polyline's segments one way and to the
    curve's fine chords the other (both err by far less than the bounds' slack)."""
    curve = spline(np.linspace(0.0, 1.0, n))
    d1 = _to_segments(curve, poly[:-1], poly[1:]).max()
    f = np.linspace(0.0, 1.0, 100)[:, None, None]
    pts = (poly[:-1] + f * (poly[1:] - poly[:-1])).reshape(-1, 2)
    k = cKDTree(curve).query(pts)[1]
    d2 = np.inf * np.ones(len(pts))
    for j in (np.clip(k - 1, 0, n - 2), np.clip(k, 0, n - 2)):
        a, b = curve[j], curve[j + 1]
        e = b - a
        t = np.clip(((pts - a) * e).sum(1) / np.maximum((e * e).sum(1), 1e-300), 0.0, 1.0)
        d2 = np.minimum(d2, np.hypot(*(a + t[:, None] * e - pts).T))
    return max(d1, d2.max())


walks = st.tuples(st.integers(0, 10_000), st.integers(3, 12), st.floats(0.3, 15.0))


@settings(max_examples=30, deadline=None)
@given(walks, st.sampled_from([2, 3, 4, 5]), st.sampled_from([0.03, 0.1, 0.3]))
def test_reported_deviation_bounds_the_true_one(walk, degree, tol):
    seed, k, scale = walk
    poly = np.cumsum(np.random.default_rng(seed).normal(size=(k, 2)) * scale, axis=0)
    spline, err = fit_polyline(poly, degree, tol)
    true = hausdorff(spline, poly)
    # the brute force measures to chords of 200 001 curve samples: on a fit with a thousand
    # control points (walk 9, 9, 14: 1192) they sag from the curve by ~1e-6 mm
    slack = 1e-4 * tol
    assert true <= err + slack  # certified
    assert true <= deviation(spline, poly, tol) + slack and deviation(spline, poly, tol) <= err + 1e-12
    if err <= tol:
        assert err < true + 0.5 * tol  # and not loose: the search's counts depend on it


def test_a_bound_on_another_spline_is_still_a_bound():
    """Not only for the fit's own curves: a perturbed spline, whose parameter no
    longer follows the polyline's chord length, is bounded too (more loosely)."""
    t = np.linspace(0, np.pi, 60)
    arc = np.c_[np.cos(t), np.sin(t)] * 20
    spline, _ = fit_polyline(arc, 3, 0.05)
    ctrl = spline.control.copy()
    ctrl[1:-1] += np.random.default_rng(2).normal(size=(len(ctrl) - 2, 2)) * 0.3
    moved = Spline(3, ctrl)
    assert hausdorff(moved, arc) <= deviation(moved, arc, 0.05) + 1e-7


def test_a_bump_between_the_samples_is_bounded():
    """A spline on a straight polyline but for one narrow bump that fits between
    two of the samples: no sample sees it, the bound on the curve's speed there
    does."""
    line = np.array([[0.0, 0.0], [10.0, 0.0]])
    n, p = 5000, 3
    knots = Spline.uniform_knots(n, p)
    greville = np.array([knots[j + 1:j + p + 1].mean() for j in range(n)])
    ctrl = np.c_[10.0 * greville, np.zeros(n)]  # the segment at chord-length speed
    du = 0.1 / 3 / 2 / 10  # the samples' spacing in u at tolerance 0.1 (every tolerance / 6 mm)
    j = int(np.argmin(np.abs(greville - 300.5 * du)))  # a bump centred between two samples
    ctrl[j, 1] = 0.3
    bump = Spline(p, ctrl)
    true = hausdorff(bump, line, n=400_001)
    assert true > 0.15
    assert true <= deviation(bump, line, 0.1)


def test_a_segment_is_fitted_exactly():
    seg = np.array([[3.0, 4.0], [103.0, -20.0]])
    for degree in (2, 3, 5):
        (s, err), = fit_pieces(seg, degree, 0.1)
        assert err == 0.0 and len(s.control) == degree + 1
        u = np.linspace(0, 1, 11)
        assert np.allclose(s(u), seg[0] + u[:, None] * (seg[1] - seg[0]))  # on it, at chord-length speed


def test_zigzag_is_split_into_pieces_within_tolerance():
    """Hatching joined by tight turns: a uniform spline needs turn-sized knots all
    along, so a low cap makes the fit split; every piece is certified and they chain."""
    rows = []
    for i in range(12):
        y = 2.0 * i
        xs = [0.0, 80.0] if i % 2 == 0 else [80.0, 0.0]
        rows += [[xs[0], y], [xs[1], y]]
    zig = np.array(rows)
    pieces = fit_pieces(zig, 3, 0.1, max_control=150)
    assert len(pieces) > 1
    assert all(err <= 0.1 for _, err in pieces)
    assert np.allclose(pieces[0][0].start, zig[0]) and np.allclose(pieces[-1][0].end, zig[-1])
    for (a, _), (b, _) in zip(pieces, pieces[1:]):
        assert np.allclose(a.end, b.start)
    for s, err in pieces:
        k = [i for i in range(len(zig)) if np.allclose(zig[i], s.start)][0]
        j = [i for i in range(k, len(zig)) if np.allclose(zig[i], s.end)][0]
        assert hausdorff(s, zig[k:j + 1]) <= err + 1e-7


@pytest.mark.parametrize("degree", [2, 3, 4])
def test_a_smooth_curve_needs_few_control_points(degree):
    """The bound is local (each pair of neighbouring samples on its own), so a
    smooth curve passes with few control points: 43-47 here, where a global
    bound (worst residual + worst gap) needed 45-49."""
    t = np.linspace(0, 2 * np.pi, 300)
    flower = np.c_[np.cos(t), np.sin(t)] * (30 + 5 * np.cos(5 * t))[:, None]
    spline, err = fit_polyline(flower, degree, 0.1)
    assert err <= 0.1 and len(spline.control) <= 48
    assert hausdorff(spline, flower, n=20_001) <= err + 1e-7
