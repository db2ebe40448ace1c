"""The batched, compiled fit (fit_many) gives exactly the splines of the search written
plainly: one polyline at a time, its samples made with numpy, every attempt's bound
tightened in order. A shortcut that changed one control point's last bit fails here."""

import numpy as np
import pytest
from generated_art import generated_svg

from doodlecam.geometry import fit as F
from doodlecam.plugins.vector import VectorTracer


def _reference_samples(p, tol):
    """fit's samples with numpy, as the fitter made them before it was compiled."""
    length = float(np.hypot(*np.diff(p, axis=0).T).sum())
    dense = F.densify(p, min(tol / 3, length / 32))
    pts = np.empty((2 * len(dense) - 1, 2))
    pts[0::2] = dense
    pts[1::2] = (dense[:-1] + dense[1:]) / 2
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    return pts, cum / cum[-1], cum, length


def _reference_fit(p, degree, tol, max_control, start=None, tried=None):
    """The search in Python: grow from the guess (two control points per vertex if the
    vertices are corners, else a knot span per half radian of turning), then bisect; each
    attempt without the quick exit for a failure. ``start``: another guess; ``tried`` gets the
    attempts."""
    pts, u, cum, _ = _reference_samples(p, tol)
    m = (len(pts) + 1) // 2
    w = F._work(len(pts), degree)
    tried = {} if tried is None else tried

    def attempt(n):
        if n not in tried:
            ctrl, err = F._attempt(pts, u, cum, n, degree, tol, 1e-9 * m / n, False, w)
            tried[n] = (ctrl, np.inf if err < 0 else err)
        return tried[n]

    n_min = degree + 1
    n_max = int(min(max_control, max(n_min, 2 * m)))

    def search(n):  # (control points, deviation), times grown, within tolerance
        n, lo, grew = int(np.clip(n, n_min, n_max)), n_min - 1, 0
        while attempt(n)[1] > tol and n < n_max:
            lo, n, grew = n, min(n_max, int(np.ceil(n * 1.5))), grew + 1
        if attempt(n)[1] > tol:
            return attempt(n), grew, False
        hi = n
        while hi - lo > 1:
            mid = (lo + hi) // 2
            hi, lo = (mid, lo) if attempt(mid)[1] <= tol else (hi, mid)
        return attempt(hi), grew, True

    turning = F.turn_angles(p).sum()
    cornered = turning > F.CORNERED * (len(p) - 2)
    guess = 2 * len(p) if cornered else degree + int(F.SPANS_PER_RADIAN * turning)
    best, grew, ok = search(guess if start is None else start)
    if ok and start is None and not cornered and grew >= 3:  # far off: the vertex rule's search too
        other, _, ok2 = search(2 * len(p))
        if ok2 and len(other[0]) < len(best[0]):
            best = other
    return best


def _reference_pieces(p, degree, tol, max_control):
    if len(p) == 2:
        return [(p[0] + (np.arange(degree + 1) / degree)[:, None] * (p[1] - p[0]), 0.0)]
    length = _reference_samples(p, tol)[3]
    ctrl, err = _reference_fit(p, degree, tol, min(max_control, 8 * len(p) + 20 + int(length / (4 * tol))))
    if err <= tol:
        return [(ctrl, err)]
    k = int(np.argmax(F._turns(np.diff(p, axis=0)))) + 1
    return _reference_pieces(p[:k + 1], degree, tol, max_control) + _reference_pieces(p[k:], degree, tol, max_control)


def _reference(polylines, degree, tol, max_control, corner):
    out = []
    for p in polylines:
        p = F._dedupe(np.asarray(p, float))
        out.append([f for q in (F.split_corners(p, corner) if corner > 0 else (p,))
                    for f in _reference_pieces(q, degree, tol, max_control)])
    return out


def _drawing(tmp_path, n, seed):
    path = tmp_path / "art.svg"
    path.write_text(generated_svg(n, "mixed", seed=seed))
    polys = list(VectorTracer().trace(path, {}).polylines)
    rng = np.random.default_rng(seed)
    # and what generated art seldom has: repeated points, walks that double back, zig-zags
    polys += [np.repeat(np.cumsum(rng.normal(size=(k, 2)) * 3, axis=0), 2, axis=0) for k in (3, 7, 20)]
    polys.append(np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 0.3], [40.0, 0.6], [0.0, 0.9]]))
    return polys


@pytest.mark.parametrize("degree, tol, corner, max_control", [(3, 0.1, 30.0, 2000), (3, 0.05, 0.0, 2000),
                                                               (2, 0.1, 0.0, 60), (4, 0.3, 45.0, 2000)])
def test_fit_many_gives_the_reference_splines_bit_for_bit(tmp_path, degree, tol, corner, max_control):
    polys = _drawing(tmp_path, 120, seed=degree)
    want = _reference(polys, degree, tol, max_control, corner)
    got = F.fit_many(polys, degree, tol, max_control, corner)
    assert [len(g) for g in got] == [len(w) for w in want]
    if corner > 0 or max_control < 100:  # corners, or fits failed within the cap, did split some
        assert sum(len(g) for g in got) > len(polys)
    for g, w in zip(got, want):
        for (spline, err), (ctrl, err_want) in zip(g, w):
            assert spline.degree == degree
            assert np.array_equal(spline.control, ctrl) and err == err_want
    # one at a time, and the quick exit for failed attempts off: the same again
    assert [[(s.control.tobytes(), e) for s, e in F.fit_pieces(p, degree, tol, max_control, corner)] for p in polys] \
        == [[(s.control.tobytes(), e) for s, e in g] for g in got]
    slow = F.fit_many(polys, degree, tol, max_control, corner, quick=False)
    assert [[(s.control.tobytes(), e) for s, e in g] for g in slow] == [[(s.control.tobytes(), e) for s, e in g]
                                                                        for g in got]


def test_the_compiled_samples_and_length_are_numpys():
    rng = np.random.default_rng(5)
    for k in (2, 3, 9, 130, 300, 2000):
        p = np.cumsum(rng.normal(size=(k, 2)) * rng.choice([0.01, 1.0, 30.0]), axis=0)
        length = F._length(p)
        assert length == np.hypot(*np.diff(p, axis=0).T).sum()  # numpy's pairwise sum, to the bit
        for a, b in zip(F._samples(p, 0.1, length), _reference_samples(p, 0.1)[:3]):
            assert np.array_equal(a, b)


def test_a_tightened_distance_searched_again_is_the_same():
    """What lets each sample be tightened once (and failures be found out of order): a
    search started from its own result returns that result."""
    t = np.linspace(0, 3 * np.pi, 40)
    p = np.c_[t * 10, 8 * np.sin(t)]
    pts, u, cum, _ = _reference_samples(p, 0.1)
    w = F._work(len(pts), 3)
    m = (len(pts) + 1) // 2
    ctrl, err = F._attempt(pts, u, cum, 6, 3, 0.1, 1e-9 * m / 6, False, w)  # a poor fit: much to tighten
    assert err > 0.1
    Q = w[0]
    for k in range(0, len(pts), 7):
        r = np.hypot(*(Q[k] - pts[k]))
        a = F._to_polyline(Q[k, 0], Q[k, 1], pts, cum, k, r, r)
        b = F._to_samples(pts[k, 0], pts[k, 1], Q, cum, k, r, r)
        assert a <= r and b <= r
        assert F._to_polyline(Q[k, 0], Q[k, 1], pts, cum, k, a, r) == a
        assert F._to_samples(pts[k, 0], pts[k, 1], Q, cum, k, b, r) == b


def test_dedupe_measures_from_the_last_point_kept():
    """A dense run of points each within SAME_POINT of the previous is thinned, not dropped whole;
    the compiled pass keeps exactly the points the plain rule keeps."""
    from doodlecam.model import SAME_POINT

    rng = np.random.default_rng(3)
    p = np.cumsum(rng.uniform(-0.7, 0.7, (5000, 2)) * SAME_POINT, axis=0)
    p[::50] += rng.uniform(0, 1, (100, 2))  # some real steps among the crumbs
    keep = [0]
    for i in range(1, len(p)):
        if np.abs(p[i] - p[keep[-1]]).max() > SAME_POINT:
            keep.append(i)
    got = F._dedupe(p)
    assert 100 < len(keep) < len(p) - 100  # both rules in play: points dropped, points kept within runs
    np.testing.assert_array_equal(got, p[keep])


def _flattened_curves(seed, count):
    """Cubic Beziers as an SVG reader flattens them: many vertices, each turning a little."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, 60)[:, None]
    for _ in range(count):
        a, b, c, d = np.cumsum(rng.normal(0, rng.uniform(2, 8), (4, 2)), axis=0)
        yield (1 - t) ** 3 * a + 3 * (1 - t) ** 2 * t * b + 3 * (1 - t) * t ** 2 * c + t ** 3 * d


def test_the_turning_guess_starts_the_search_at_the_answer_of_a_flattened_curve():
    """What the guess is for: on flattened curves the search from a knot span per half radian of
    turning ends where the search from two control points per vertex ended, or lower (nearly
    always the fewest that fit), with half the attempts or fewer; the count fits and one fewer
    does not."""
    degree, tol = 3, 0.1
    now, before, fewest = [], [], []
    tries_now = tries_before = 0
    for p in _flattened_curves(7, 40):
        assert F._turning(p) <= F.CORNERED * (len(p) - 2)  # taken for a flattened curve
        assert np.isclose(F._turning(p), F.turn_angles(p).sum())
        spline, err = F.fit_polyline(p, degree, tol)
        tried = {}
        ctrl, err_ref = _reference_fit(p, degree, tol, 2000, tried=tried)
        assert np.array_equal(spline.control, ctrl) and err == err_ref <= tol
        n = len(ctrl)
        assert n == degree + 1 or tried[n - 1][1] > tol  # one fewer does not fit
        old = {}
        ctrl_old, _ = _reference_fit(p, degree, tol, 2000, start=2 * len(p), tried=old)
        now.append(n)
        before.append(len(ctrl_old))
        tries_now, tries_before = tries_now + len(tried), tries_before + len(old)
        pts, u, cum, _ = _reference_samples(p, tol)
        m = (len(pts) + 1) // 2
        w = F._work(len(pts), degree)
        fewest.append(next(k for k in range(degree + 1, n + 1)  # the plain scan from the fewest up
                           if 0 <= F._attempt(pts, u, cum, k, degree, tol, 1e-9 * m / k, False, w)[1] <= tol))
    now, before, fewest = map(np.array, (now, before, fewest))
    assert now.max() > 8  # curves that need more than one or two spans
    print(f"{now.sum()} control points ({before.sum()} before), {tries_now} attempts ({tries_before}),"
          f" the fewest that fit on {(now == fewest).mean():.0%} of the curves")
    assert now.sum() <= before.sum() and (now <= before).mean() >= 0.9 and (now == fewest).mean() >= 0.85
    assert 2 * tries_now <= tries_before


def test_a_flattened_curve_with_cusps_takes_no_more_control_points_than_the_vertex_rule():
    """A curve clipped to the work area turns back on itself along the edge (cusps nothing split):
    hundreds of control points, where whether a count fits is not monotone. The turning guess is far
    off there, so the search from two control points per vertex runs too and the fewer are kept."""
    t = np.linspace(0, 1, 400)[:, None]
    p = np.clip(140 + np.c_[100 * np.cos(3 * t) + 8 * np.sin(40 * t), 70 * np.sin(2 * t)], 5, [275, 175])
    p = F._dedupe(p)
    assert F._turning(p) <= F.CORNERED * (len(p) - 2)  # taken for a flattened curve
    spline, err = F.fit_polyline(p, 3, 0.1)
    ctrl, err_ref = _reference_fit(p, 3, 0.1, 100000)
    vertex_rule, _ = _reference_fit(p, 3, 0.1, 100000, start=2 * len(p))
    turning_only, _ = _reference_fit(p, 3, 0.1, 100000, start=3 + int(F.SPANS_PER_RADIAN * F._turning(p)))
    assert np.array_equal(spline.control, ctrl) and err == err_ref <= 0.1
    assert len(ctrl) == min(len(vertex_rule), len(turning_only)) < len(turning_only)
