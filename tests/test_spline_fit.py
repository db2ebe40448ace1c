import numpy as np
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays
from scipy.interpolate import BSpline

from doodlecam.geometry.fit import fit_pieces, fit_polyline
from doodlecam.model import Spline


def cox_de_boor(knots, i, k, u):
    """The report's recursive basis (appendix A), independent of scipy."""
    if k == 0:
        last = knots[i + 1] == knots[-1]
        return np.where((knots[i] <= u) & ((u < knots[i + 1]) | (last & (u <= knots[i + 1]))), 1.0, 0.0)
    out = np.zeros_like(u)
    if knots[i + k] > knots[i]:
        out += (u - knots[i]) / (knots[i + k] - knots[i]) * cox_de_boor(knots, i + 1 - 1, k - 1, u)
    if knots[i + k + 1] > knots[i + 1]:
        out += (knots[i + k + 1] - u) / (knots[i + k + 1] - knots[i + 1]) * cox_de_boor(knots, i + 1, k - 1, u)
    return out


def test_uniform_clamped_knots():
    k = Spline.uniform_knots(7, 3)
    assert np.allclose(k, [0, 0, 0, 0, 0.25, 0.5, 0.75, 1, 1, 1, 1])


def test_evaluation_matches_recursive_definition_and_scipy():
    rng = np.random.default_rng(1)
    for degree in (2, 3, 4):
        ctrl = rng.normal(size=(9, 2)) * 50
        s = Spline(degree, ctrl)
        u = np.linspace(0, 1, 401)
        basis = np.array([cox_de_boor(s.knots, i, degree, u) for i in range(len(ctrl))])
        assert np.allclose(basis.sum(axis=0), 1.0)  # partition of unity
        assert np.allclose(s(u), basis.T @ ctrl, atol=1e-9)
        ref = BSpline(s.knots, ctrl, degree)
        for der in range(1, degree + 1):
            assert np.allclose(s(u, der), ref.derivative(der)(u), atol=1e-7 * np.abs(ref.derivative(der)(u)).max())
        # derivatives are what finite differences say
        h = 1e-6
        um = np.linspace(0.05, 0.95, 50)
        assert np.allclose(s(um, 1), (s(um + h) - s(um - h)) / (2 * h), rtol=1e-4, atol=1e-4)


def test_clamped_ends_and_length():
    t = np.linspace(0, 2 * np.pi, 200)
    circle = np.c_[np.cos(t), np.sin(t)] * 30
    s, err = fit_polyline(circle, 3, 0.01)
    assert np.allclose(s(0.0), circle[0]) and np.allclose(s(1.0), circle[-1])
    assert abs(s.length - 2 * np.pi * 30) < 0.05


def exact_deviation(spline, poly, n=200_001):
    """Two-way distance by brute force: dense curve vs exact point-to-segment, and
    polyline points to the curve's nearest fine chords (nearest samples alone read
    up to 2e-4 mm high on a fit with a thousand control points)."""
    curve = spline(np.linspace(0, 1, n))
    a, b = poly[:-1], poly[1:]
    ab = b - a
    L2 = np.maximum((ab**2).sum(1), 1e-300)

    def to_poly(pts):
        t = np.clip(((pts[:, None, :] - a) * ab).sum(2) / L2, 0, 1)
        proj = a + t[..., None] * ab
        return np.sqrt(((pts[:, None, :] - proj) ** 2).sum(2)).min(1)

    d1 = max(to_poly(curve[i : i + 2000]).max() for i in range(0, len(curve), 2000))
    dense = np.concatenate([a + np.linspace(0, 1, 40)[:, None, None] * ab]).reshape(-1, 2)
    from scipy.spatial import cKDTree

    d2, k = cKDTree(curve).query(dense)
    for j in (np.clip(k - 1, 0, n - 2), np.clip(k, 0, n - 2)):
        e = curve[j + 1] - curve[j]
        t = np.clip(((dense - curve[j]) * e).sum(1) / np.maximum((e * e).sum(1), 1e-300), 0.0, 1.0)
        d2 = np.minimum(d2, np.hypot(*(curve[j] + t[:, None] * e - dense).T))
    return max(d1, d2.max())


polylines = arrays(np.float64, st.tuples(st.integers(2, 12), st.just(2)),
                   elements=st.floats(-100, 100, allow_nan=False, allow_infinity=False))


@settings(max_examples=40, deadline=None)
@given(polylines, st.sampled_from([0.05, 0.1, 0.3]), st.sampled_from([2, 3]))
def test_fit_meets_tolerance_on_random_polylines(poly, tol, degree):
    steps = np.hypot(*np.diff(poly, axis=0).T)
    if steps.max() < 1.0:  # degenerate: all points (nearly) coincide
        return
    pieces = fit_pieces(poly, degree, tol)
    assert np.allclose(pieces[0][0].start, poly[0]) and np.allclose(pieces[-1][0].end, poly[-1])
    for (a, _), (b, _) in zip(pieces, pieces[1:]):
        assert np.allclose(a.end, b.start)  # pieces split the polyline at a vertex
    for s, err in pieces:
        assert err <= tol
    if len(pieces) == 1:
        assert exact_deviation(pieces[0][0], poly[np.r_[True, steps > 1e-12]]) <= tol + 1e-6


def test_fit_of_a_polyline_that_doubles_back():
    poly = np.array([[53, 0], [53, 53], [53, -74], [53, 53], [0, 53], [53, 53.0]])
    for degree in (2, 3):
        for tol in (0.05, 0.1):
            pieces = fit_pieces(poly, degree, tol)
            assert all(err <= tol for _, err in pieces)


def test_fewest_control_points_is_actually_few():
    # a straight line needs only degree + 1 control points
    s, err = fit_polyline(np.array([[0.0, 0.0], [100.0, 50.0]]), 3, 0.1)
    assert len(s.control) == 4 and err < 0.1
    # a smooth arc sampled densely needs far fewer control points than samples
    t = np.linspace(0, np.pi, 500)
    s, err = fit_polyline(np.c_[np.cos(t), np.sin(t)] * 50, 3, 0.1)
    assert len(s.control) < 20 and err <= 0.1
