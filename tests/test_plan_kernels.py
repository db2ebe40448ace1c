"""The planner's compiled shortcuts against plain references written here.

The span polynomials (constraints.spans) must be the spline itself on every
knot span, both sides of every knot included; the Bernstein rows built from
them must equal, at the ends of each interval, the limits evaluated straight
from the spline; and the reachability pass, which finds each controllable
interval by Newton steps, must give the sets that eliminating every pair of
bounds (Fourier-Motzkin, as TOPP-RA does) gives.
"""

from math import factorial

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.model import Spline
from doodlecam.plan import constraints, reach
from doodlecam.plan.planner import Limits, build_rows, make_grid


def span_value(sp, s, u, j):
    """q^(j)(u) from span s's Taylor coefficients (a plain sum, no Horner)."""
    x = u - sp.mid[s]
    p = sp.T.shape[1] - 1
    return sum(sp.T[s, i] * factorial(i) / factorial(i - j) * x ** (i - j) for i in range(j, p + 1))


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("extra", [0, 1, 3, 7, 40])
def test_span_polynomials_are_the_spline_on_every_span(degree, extra):
    rng = np.random.default_rng(degree * 100 + extra)
    s = Spline(degree, rng.normal(0.0, 30.0, (degree + 1 + extra, 2)))
    sp = constraints.spans(s)
    assert np.array_equal(sp.bp, s.breakpoints) and len(sp.mid) == len(sp.bp) - 1
    for k in range(len(sp.mid)):
        lo, hi = sp.bp[k], sp.bp[k + 1]
        # the span's own side of both of its knots: a derivative may jump there
        for u in (lo, lo + 0.37 * (hi - lo), np.nextafter(hi, -np.inf)):
            for j in range(degree + 1):
                ref = s(np.array([u]), j)[0]
                scale = np.abs(s(np.linspace(0, 1, 101), j)).max() + np.abs(ref).max()
                assert np.abs(span_value(sp, k, u, j) - ref).max() <= 1e-12 * scale, (k, u, j)


@pytest.mark.parametrize("degree", [2, 3, 4])
def test_bernstein_rows_meet_the_limits_from_the_spline_at_interval_ends(degree):
    """A Bernstein polynomial's first and last coefficients are its values at the
    ends: each row must be the exact actuator acceleration / velocity^2 / pen
    speed^2 there, for any b (here random), with derivatives evaluated by de Boor."""
    rng = np.random.default_rng(degree)
    s = Spline(degree, np.cumsum(rng.normal(0.0, 10.0, (12, 2)), axis=0))
    M = np.array([[1.0, 1.0], [1.0, -1.0], [0.3, 2.0]])
    vmax, amax = np.array([100.0, 80.0, 120.0]), np.array([1000.0, 1500.0, 900.0])
    lim = Limits(vmax, amax, M, pen_speed=70.0)
    u = make_grid(s, n_points=300)
    rows = build_rows(s, u, lim)
    b = rng.uniform(0.0, 5.0, len(u))
    lhs = rows.tot * b[:-1, None] + rows.beta * np.diff(b)[:, None]  # row value before / gamma
    a = np.diff(b) / (2 * np.diff(u))
    left, right = u[:-1], np.nextafter(u[1:], -np.inf)
    p, na = degree, len(vmax)
    for end, uu, bb in ((0, left, b[:-1]), (1, right, b[1:])):
        t1, t2 = s(uu, 1) @ M.T, s(uu, 2) @ M.T
        for i in range(na):
            base = i * 4 * p  # 2p acceleration rows (+, - per coefficient), then 2p velocity rows
            acc = t1[:, i] * a + t2[:, i] * bb
            col = base + (0 if end == 0 else 2 * (p - 1))
            scale = np.abs(t1[:, i] * a).max() + np.abs(t2[:, i] * bb).max()
            assert np.abs(lhs[:, col] - acc).max() <= 1e-9 * scale
            assert np.abs(lhs[:, col + 1] + acc).max() <= 1e-9 * scale
            vel = t1[:, i] ** 2 * bb
            vcol = base + 2 * p + (0 if end == 0 else 2 * p - 1)
            assert np.abs(lhs[:, vcol] - vel).max() <= 1e-9 * vel.max()
            assert np.all(rows.gamma[:, col] == amax[i]) and np.all(rows.gamma[:, vcol] == vmax[i] ** 2)
        pen = (s(uu, 1) ** 2).sum(axis=1) * bb
        pcol = na * 4 * p + (0 if end == 0 else 2 * p - 1)
        assert np.abs(lhs[:, pcol] - pen).max() <= 1e-9 * pen.max()


def pairwise_sets(tot, beta, gamma, ub, bN, eps=1e-12):
    """The controllable sets [lo_k, hi_k] by eliminating b_k+1 from every pair of
    an upper and a lower bound on it (plain Python, for the reference)."""
    K, R = tot.shape
    lo, hi = np.empty(K + 1), np.empty(K + 1)
    lo[K] = hi[K] = bN
    for k in range(K - 1, -1, -1):
        ups, lows = [(hi[k + 1], -1.0)], [(lo[k + 1], -1.0)]  # y - x = c0 + c1 x
        xmin, xmax = 0.0, ub[k]
        for t, bb, g in zip(tot[k], beta[k], gamma[k]):
            if not np.isfinite(g):
                continue
            if abs(bb) > eps:
                (ups if bb > 0 else lows).append((g / bb, -t / bb))
            elif t > eps:
                xmax = min(xmax, g / t)
            elif t < -eps:
                xmin = max(xmin, g / t)
        for cu0, cu1 in ups:
            for cl0, cl1 in lows:
                d0, d1 = cu0 - cl0, cu1 - cl1
                if d1 < 0:
                    xmax = min(xmax, -d0 / d1)
                elif d1 > 0:
                    xmin = max(xmin, -d0 / d1)
                elif d0 < 0:
                    return None
        if xmax < xmin - 1e-9 * max(1.0, abs(xmin)):
            return None
        lo[k], hi[k] = xmin, max(xmax, xmin)
    return lo, hi


def solve_sets(rows, b0=0.0, bN=0.0):
    from doodlecam.plan.kernels import reach_passes

    K = rows.tot.shape[0]
    b, lo, hi = np.empty(K + 1), np.empty(K + 1), np.empty(K + 1)
    status = reach_passes(rows.tot, rows.beta, np.ascontiguousarray(rows.gamma), rows.ub, b0, bN, b, lo, hi)
    return status, b, lo, hi


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 3), st.integers(0, 30), st.sampled_from([20, 200, 2000]), st.floats(0.05, 200.0),
       st.booleans(), st.integers(0, 2**32 - 1))
def test_reach_sets_equal_the_pairwise_elimination(degree, extra, n, size, pen, seed):
    rng = np.random.default_rng(seed)
    s = Spline(degree, size * rng.normal(0.0, 1.0, (degree + 1 + extra, 2)))
    if float(np.ptp(s.control, axis=0).max()) < 1e-6 * size:
        return
    lim = Limits(np.array([150.0, 90.0]), np.array([2000.0, 700.0]), np.array([[1.0, 1.0], [1.0, -1.0]]),
                 pen_speed=60.0 if pen else None)
    u = make_grid(s, n_points=n)
    rows = build_rows(s, u, lim)
    status, b, lo, hi = solve_sets(rows)
    ref = pairwise_sets(rows.tot, rows.beta, rows.gamma, rows.ub, 0.0)
    assert status == 0 and ref is not None
    assert np.allclose(lo, ref[0], rtol=1e-9, atol=0) and np.allclose(hi, ref[1], rtol=1e-9, atol=0)
    assert 0.0 <= b.min() and np.all(b <= hi * (1 + 1e-12))
    assert np.array_equal(b, reach.solve(rows.tot, rows.beta, rows.gamma, rows.ub))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8), st.booleans(), st.sampled_from([0.0, 0.003, 0.02]),
       st.sampled_from([0.0, 0.5, 30.0]))
def test_reach_sets_on_arbitrary_rows_equal_the_pairwise_elimination(seed, R, unused, demanding, bN):
    """Rows of any signs and sizes (slopes of both signs, beta ~ 0, unused rows,
    rows no state at rest keeps, a moving end state): the same sets, or the same
    refusal (the Newton steps fail there and the pairs decide)."""
    rng = np.random.default_rng(seed)
    K = 30
    tot = rng.normal(0.0, 1.0, (K, R)) * rng.choice([1e-3, 1.0, 1e3], (K, R))
    beta = rng.normal(0.0, 1.0, (K, R)) * rng.choice([0.0, 1e-2, 1.0, 1e2], (K, R))
    gamma = rng.uniform(0.1, 10.0, (K, R))
    gamma[rng.random((K, R)) < demanding] *= -0.01
    if unused:
        gamma[rng.random((K, R)) < 0.2] = np.inf
    ub = rng.uniform(1.0, 100.0, K + 1)
    rows = constraints.Rows(tot, beta, gamma, ub)
    ref = pairwise_sets(tot, beta, gamma, ub, bN)
    status, b, lo, hi = solve_sets(rows, 0.0, bN)
    if ref is None:
        assert status > 0
        return
    # (-1: the sets are kept, but the start at rest lies outside the first)
    assert status in (0, -1), f"refused an interval the pairwise elimination keeps (status {status})"
    assert (status == -1) == (ref[0][0] > 1e-300)
    assert np.allclose(lo, ref[0], rtol=1e-9, atol=1e-12) and np.allclose(hi, ref[1], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("control,degree", [
    ([[0.0, 1.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]], 2),  # found by the explore profile: a span standing still
    ([[0.0, 0.0], [5.0, 0.0], [5.0, 0.0], [5.0, 0.0], [5.0, 0.0], [9.0, 3.0]], 3),
])
def test_a_span_where_the_pen_stands_still_is_planned_within_limits(control, degree):
    from doodlecam.plan.planner import check_profile, plan_stroke

    s = Spline(degree, np.array(control))
    lim = Limits(np.array([150.0, 120.0]), np.array([2000.0, 1500.0]), np.eye(2))
    u = make_grid(s)
    assert np.all(np.isfinite(u)) and np.all(np.diff(u) > 0)
    prof = plan_stroke(s, lim)
    acc, vel = check_profile(s, prof, lim)
    assert np.isfinite(prof.duration) and prof.duration > 0
    assert np.isfinite(prof.b).all() and np.isfinite(prof.a).all()  # (b was inf there before: explore profile)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9


@pytest.mark.parametrize("degree", [2, 3, 4])
@pytest.mark.parametrize("extra", [0, 3, 40])
def test_compiled_check_is_the_spline_evaluated_point_by_point(degree, extra):
    # planner.interval_ratios evaluates q', q'' inside one compiled loop (closed forms on a
    # cubic's inner spans); the reference: every point of the 20x grid through Spline.__call__
    from doodlecam.plan.kernels import interval_worst
    from doodlecam.plan.planner import interval_ratios

    rng = np.random.default_rng(degree * 10 + extra)
    s = Spline(degree, rng.normal(0.0, 30.0, (degree + 1 + extra, 2)))
    M = np.array([[1.0, 1.0], [1.0, -1.0]])
    lim = Limits(np.array([300.0, 250.0]), np.array([2000.0, 1500.0]), M, pen_speed=150.0)
    u = np.unique(np.concatenate([make_grid(s, 0.7), rng.uniform(0, 1, 50)]))
    b = rng.uniform(0.0, 1e-4, len(u))
    got = interval_ratios(s, u, b, lim)
    h, tau = np.diff(u), np.linspace(0.0, 1.0, 21)
    uu = u[:-1, None] + tau[None, :] * h[:, None]
    uu[:, -1] = np.nextafter(u[1:], -np.inf)
    d1, d2 = s(uu.ravel(), 1), s(uu.ravel(), 2)
    ref = interval_worst(b, h, d1 @ M.T, d2 @ M.T, np.linalg.norm(d1, axis=1), lim.amax, lim.vmax, 150.0, 20)
    for g, r in zip(got, ref):
        assert np.allclose(g, r, rtol=1e-9, atol=1e-12 * r.max())


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("nseg", [1, 2, 3, 7, 12])
def test_written_out_basis_gives_the_same_bits_as_de_boor(degree, nseg):
    # the planner's kernels evaluate degrees 1-3 with the basis written out on scalars and the
    # knots from a table; the files must not change by one byte, so the values must be the
    # same bits as geometry.kernels' Cox-de Boor (bspline_eval), knots and span ends included
    import numba

    from doodlecam.geometry.kernels import bspline_eval
    from doodlecam.plan.kernels import knot_table, spline_point

    @numba.njit
    def evaluate(c, k, nseg, x, P, out):
        N, left, right = np.empty(P + 1), np.empty(P + 1), np.empty(P + 1)
        kt = knot_table(P, nseg)
        for j in range(x.shape[0]):
            out[j, 0], out[j, 1] = spline_point(c, k, nseg, x[j], kt, P, N, left, right)

    rng = np.random.default_rng(degree * 100 + nseg)
    c = rng.normal(0.0, 30.0, (nseg + degree, 2))
    knots = np.linspace(0.0, 1.0, nseg + 1)
    x = np.concatenate([rng.uniform(0, 1, 2000), knots, np.nextafter(knots, -np.inf)[1:],
                        np.nextafter(knots, np.inf)[:-1]])
    ref, got = np.empty((len(x), 2)), np.empty((len(x), 2))
    bspline_eval(c, degree, nseg, x, ref)
    for P in {degree, 5}:  # the table of the spline's own degree, or of a higher one (its derivatives)
        evaluate(c, degree, nseg, x, P, got)
        assert np.array_equal(got.view(np.int64), ref.view(np.int64))


@pytest.mark.parametrize("nseg", [1, 3, 9])
def test_cubic_distance_gives_the_generic_bits(nseg):
    # follow measures a cubic through its own compiled copy; it must measure exactly what
    # the copy for any degree (spline_point, the same bits as de Boor) measures, and the
    # fused per-period pass (period_deviation) exactly what the array version does
    from doodlecam.model import StrokeSamples
    from doodlecam.plan.follow import CANDIDATES, SUB, executed_points, path_deviation
    from doodlecam.plan.kernels import _any_distance, distance_to_stretch, knot_table

    rng = np.random.default_rng(nseg)
    s = Spline(3, rng.normal(0.0, 20.0, (nseg + 3, 2)))
    c = s.derivative_controls
    lo = np.sort(rng.uniform(0, 1, (2, 500)), axis=0)
    x = s(rng.uniform(lo[0], lo[1])) + rng.normal(0.0, 0.5, (500, 2))
    kt, work = knot_table(3, nseg), np.empty(4)
    for iterations in (0, 4):
        got = np.empty(500)
        distance_to_stretch(c[0], c[1], c[2], 3, nseg, x, lo[0], lo[1], CANDIDATES, iterations, got)
        ref = [_any_distance(c[0], c[1], c[2], 3, nseg, kt, work, work.copy(), work.copy(), p[0], p[1], a, b,
                             CANDIDATES, iterations) for p, a, b in zip(x, lo[0], lo[1])]
        assert np.array_equal(got, ref) and np.all(got >= 0)

    # samples wobbling along the curve: the deviation per period, fused, against the arrays
    m = 40
    su = np.sort(np.concatenate([[0.0, 1.0], rng.uniform(0, 1, m - 1)]))
    pos = s(su)
    smp = StrokeSamples(start=pos[0], velocity=np.vstack([np.diff(pos, axis=0)[:-1] / 0.04, np.zeros((1, 2))])
                        + np.vstack([rng.normal(0, 2.0, (m - 1, 2)), np.zeros((1, 2))]), delta_time=0.04,
                        time_scale=1.0, sample_u=su)
    pts = executed_points(smp).reshape(-1, 2)
    span = np.maximum(np.diff(su), 1e-9)
    dist = np.empty(len(pts))
    distance_to_stretch(c[0], c[1], c[2], 3, nseg, pts, np.repeat(np.maximum(su[:-1] - span / 2, 0.0), SUB + 1),
                        np.repeat(np.minimum(su[1:] + span / 2, 1.0), SUB + 1), CANDIDATES, 4, dist)
    dist = dist.reshape(m, SUB + 1)
    k = np.clip(dist.argmax(axis=1), 1, SUB - 1)
    fm, f0, fp = (dist[np.arange(m), k + j] for j in (-1, 0, 1))
    curv = 2 * f0 - fm - fp
    peak = f0 + np.where(curv > 1e-15, (fp - fm) ** 2 / (8 * np.maximum(curv, 1e-15)), 0.0)
    assert np.array_equal(path_deviation(s, smp), np.maximum(dist.max(axis=1), np.minimum(peak, f0 + np.abs(fp - fm))))


@pytest.mark.parametrize("degree", [2, 3, 4])
def test_compiled_jerk_rows_are_the_numpy_formulas_bit_for_bit(degree):
    # the jerk rows are built in compiled loops; the plans (and so the files) stay the same
    # only if every coefficient is the same double as the array formulas give
    from doodlecam.plan import constraints
    from doodlecam.plan.follow import JerkBound

    rng = np.random.default_rng(degree)
    s = Spline(degree, rng.normal(0.0, 20.0, (degree + 6, 2)))
    u = make_grid(s, 0.5)
    taus, uu, c1, c2 = constraints.jerk_coefficients(s, u)
    d1, d2, d3 = s(uu, 1), s(uu, 2), s(uu, 3)
    sp = np.maximum(np.linalg.norm(d1, axis=-1), 1e-12)
    c12 = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    c13 = d1[..., 0] * d3[..., 1] - d1[..., 1] * d3[..., 0]
    dot12 = (d1 * d2).sum(axis=-1)
    kappa = c12 / sp ** 3
    kappa_s = (c13 * sp ** 2 - 3 * c12 * dot12) / sp ** 6
    assert np.array_equal(c1, 3 * kappa * sp ** 2) and np.array_equal(c2, 3 * kappa * dot12 + sp ** 3 * kappa_s)

    base = constraints.bernstein_rows(s, u, np.eye(2), np.array([150.0, 150.0]), np.array([2000.0, 2000.0]))
    b_hat = rng.uniform(1e-6, 1e-3, len(u))
    bound = JerkBound(3e4, ((0.2, 0.4, 0.5),))
    rows = constraints.with_jerk(base, (taus, uu, c1, c2), u, b_hat, constraints.jerk_bound((taus, uu, c1, c2), bound))
    tau = taus[:, None]
    bh = b_hat[None, :-1] * (1 - tau) + b_hat[None, 1:] * tau
    g = bound(uu) / np.sqrt(np.maximum(bh, 1e-300))
    beta = c2 * tau + c1 / (2 * np.diff(u))[None, :]

    def columns(x):
        return np.stack([x, -x], axis=-1).transpose(1, 0, 2).reshape(x.shape[1], -1)

    R = base.tot.shape[1]
    assert np.array_equal(rows.tot, np.concatenate([base.tot, columns(c2)], 1))
    assert np.array_equal(rows.beta, np.concatenate([base.beta, columns(beta)], 1))
    assert np.array_equal(rows.gamma, np.concatenate([base.gamma, np.abs(columns(g))], 1))
    assert np.array_equal(rows.ub, np.minimum(base.ub, b_hat))
    b = rng.uniform(0.0, 2e-3, len(u))
    assert np.array_equal(constraints.worst_ratios(rows, b), rows.ratios(b).max(axis=1))
    assert np.array_equal(constraints.worst_ratios(rows, b, R), rows.ratios(b)[:, R:].max(axis=1))
