"""The plan's batched and compiled shortcuts give what the one-at-a-time code gives, bit for bit.

model.prime_splines fills many splines' caches at once; plan_stroke's rounds and jerk solves run
in compiled calls (kernels.plan_rounds, jerk_solves) that must find the plans the Python loop
finds; path_deviation builds the executed positions inside its compiled pass; Profile.state_at
clips without np.clip. Each is compared here with the plain version.
"""

import numpy as np
import pytest

from doodlecam.errors import PlanError
from doodlecam.model import Profile, Spline, Stroke, prime_splines
from doodlecam.plan import kernels, planner
from doodlecam.plan.follow import CANDIDATES, JerkBound, jerk_limit, path_deviation
from doodlecam.plan.sample import sample_stroke


def random_splines(seed, n=60):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        degree = int(rng.integers(1, 4))
        m = degree + 1 + int(rng.integers(0, 6))
        if i % 4 == 0:  # a fitted line: evenly spaced control points on a segment
            a, b = rng.normal(0, 50, 2), rng.normal(0, 50, 2)
            c = a + np.linspace(0.0, 1.0, m)[:, None] * (b - a)
        else:
            c = rng.normal(0, 30, (m, 2))
        out.append(Spline(degree, c))
    return out


def test_prime_splines_fills_what_each_spline_computes():
    fresh, primed = random_splines(1), random_splines(1)
    prime_splines(primed, lengths=True)
    for a, b in zip(fresh, primed):
        assert "length" in b.__dict__ and "straight" in b.__dict__
        assert a.straight == b.straight and a.length == b.length
        assert len(a.derivative_controls) == len(b.derivative_controls)
        for x, y in zip(a.derivative_controls, b.derivative_controls):
            assert np.array_equal(x, y)
    assert any(s.straight for s in fresh if s.degree >= 2) and not all(s.straight for s in fresh)


def test_prime_splines_keeps_what_is_cached():
    s = random_splines(2, 1)[0]
    d = s.derivative_controls
    prime_splines([s])
    assert s.derivative_controls is d


def python_only(monkeypatch):
    monkeypatch.setattr(planner, "_compiled_rounds", lambda *a: None)
    monkeypatch.setattr(planner, "_jerk_solves", lambda rows, co, u, jm, b, b0, bN:
                        planner._jerk_python(rows, co, u, jm, b, b0, bN, "reach"))


@pytest.mark.parametrize("jerk", [False, True])
def test_compiled_rounds_plan_what_the_python_rounds_plan(limits, monkeypatch, jerk):
    splines = [s for s in random_splines(3, 40) if s.degree == 3 and not s.straight]
    bound = JerkBound(jerk_limit(0.1, 0.04)) if jerk else None
    compiled = [planner.plan_stroke(s, limits, jerk_max=bound, jerk_period=0.04) for s in splines]
    python_only(monkeypatch)
    plain = [planner.plan_stroke(s, limits, jerk_max=bound, jerk_period=0.04) for s in splines]
    assert len(splines) > 10
    for p, q in zip(compiled, plain):
        for name in "uabt":
            assert np.array_equal(getattr(p, name), getattr(q, name))
    assert any(len(p.u) > 20 for p in compiled)  # the rounds refined somewhere


def test_path_deviation_is_the_kernel_on_the_integrated_samples(limits):
    for s in [s for s in random_splines(4, 16) if s.degree == 3 and not s.straight]:
        smp = sample_stroke(Stroke(s, planner.plan_stroke(s, limits)), 0.04, limits, (80, 80))
        x, v = smp.integrate(), np.vstack([np.zeros((1, 2)), smp.velocity])
        tau = np.linspace(0.0, smp.delta_time, 17)
        c = s.derivative_controls
        want = np.empty(len(x) - 1)
        kernels.period_deviation(c[0], c[1], c[2], 3, len(s.control) - 3, x, v, tau, tau ** 2 / (2 * smp.delta_time),
                                 np.asarray(smp.sample_u, float), CANDIDATES, 4, want)
        assert np.array_equal(path_deviation(s, smp), want)


def test_state_at_is_the_clipped_formula():
    rng = np.random.default_rng(5)
    u = np.concatenate([[0.0], np.sort(rng.random(30)), [1.0]])
    b = rng.random(32) * 4
    b[0] = b[-1] = 0.0
    t = np.empty(32)
    kernels.times(u, b, t)
    p = Profile(u=u, b=b, a=np.diff(b) / (2 * np.diff(u)), t=t)
    q = np.concatenate([rng.uniform(-1, t[-1] + 1, 200), t, [-0.0, 0.0, t[-1], np.inf, -np.inf]])
    # the previous formula, with np.clip
    tt = np.clip(q, 0.0, p.duration)
    k = np.clip(np.searchsorted(p.t, tt, side="right") - 1, 0, len(p.a) - 1)
    tau = tt - p.t[k]
    v0 = np.sqrt(np.maximum(p.b[k], 0.0))
    want_u = np.minimum(p.u[k] + v0 * tau + 0.5 * p.a[k] * tau * tau, p.u[k + 1])
    got_u, got_ud, got_a = p.state_at(q)
    assert np.array_equal(got_u.view(np.int64), want_u.view(np.int64))
    assert np.array_equal(got_ud, np.maximum(v0 + p.a[k] * tau, 0.0)) and np.array_equal(got_a, p.a[k])
    assert isinstance(p.state_at(0.3)[2], np.ndarray)  # a scalar time: a 0-d array, as before


def test_with_profile_is_replace():
    from dataclasses import replace

    s = Stroke(random_splines(6, 1)[0], None, source_index=7, fit_error=0.01, layer="red")
    prof = Profile(u=[0.0, 1.0], b=[0.0, 0.0], a=[0.0], t=[0.0, 1.0])
    got, want = s.with_profile(prof), replace(s, profile=prof)
    assert type(got) is Stroke and s.profile is None
    assert all(getattr(got, f) is getattr(want, f) for f in ("spline", "profile", "source_index", "fit_error", "layer"))



def test_forgotten_derivatives_give_the_same_bits_and_stay_unkept():
    """A planned job's splines drop their derivative controls before the posts (memory at 10^5
    strokes): evaluating them afterwards gives the same numbers and keeps nothing."""
    from doodlecam.geometry.spline_batch import eval_many
    from doodlecam.model import Spline

    rng = np.random.default_rng(5)
    splines = [Spline(3, rng.normal(size=(int(rng.integers(4, 12)), 2)) * 20) for _ in range(30)]
    u = np.linspace(0, 1, 17)
    before = [(s(u), s(u, 1), s(u, 2), s.length) for s in splines]
    batch = [eval_many(splines, [u] * len(splines), d) for d in (0, 1)]
    fresh = [Spline(s.degree, s.control) for s in splines]
    for s in fresh:
        s.forget_derivatives()
    for s, (q, d1, d2, length) in zip(fresh, before):
        np.testing.assert_array_equal(s(u), q)
        np.testing.assert_array_equal(s(u, 1), d1)
        np.testing.assert_array_equal(s(u, 2), d2)
        assert s.length == length
        assert "derivative_controls" not in s.__dict__
    for d in (0, 1):
        np.testing.assert_array_equal(eval_many(fresh, [u] * len(fresh), d), batch[d])
    assert all("derivative_controls" not in s.__dict__ for s in fresh)


def separate(spline, limits, check, jerk, grid):
    """plan_stroke, then check_profile: what plan_checked's compiled calls must give."""
    prof = planner.plan_stroke(spline, limits, jerk_max=jerk, grid=grid, jerk_period=0.04)
    return prof, planner.check_profile(spline, prof, check)


def bounds():
    base = jerk_limit(0.1, 0.04)
    return [None, base, JerkBound(base), JerkBound(base, ((0.1, 0.4, 0.5), (0.3, 0.9, 0.25))), 0.3 * base]


@pytest.mark.parametrize("pen", [None, 90.0])
def test_plan_checked_is_plan_stroke_then_check_profile(limits, pen):
    """The plan and its ratios from the compiled calls equal plan_stroke's and check_profile's, bit for
    bit: fresh grids and given ones (a re-plan), every kind of jerk bound, check limits other than
    the plan's, a pen-speed cap."""
    from dataclasses import replace

    lim = replace(limits, pen_speed=pen)
    check = replace(limits, vmax=limits.vmax * 1.1, amax=limits.amax * 0.9, pen_speed=pen and pen * 1.2)
    splines = [s for s in random_splines(7, 80) if s.degree == 3 and not s.straight]
    splines += [Spline(3, np.array([[0, 0], [1, 2], [3, 2.5], [40, 3], [41, 9], [60, 0]], float) * k) for k in (0.05, 1, 8)]
    seen = 0
    for i, s in enumerate(splines):
        jerk = bounds()[i % 5]
        for grid in (None, np.union1d(separate(s, lim, check, None, None)[0].u[::3], s.breakpoints)):
            got, want = planner.plan_checked(s, lim, check, jerk_max=jerk, grid=grid, jerk_period=0.04), \
                separate(s, lim, check, jerk, grid)
            for name in "uabt":
                assert np.array_equal(getattr(got[0], name), getattr(want[0], name), equal_nan=True)
            assert got[0].solver == want[0].solver and got[1] == want[1]
            seen += 1
    assert seen > 60


def test_plan_checked_takes_the_compiled_calls(limits, monkeypatch):
    """plan_checked plans a curved cubic without plan_stroke (else the test above compares nothing)."""
    s = next(s for s in random_splines(8, 20) if s.degree == 3 and not s.straight)
    monkeypatch.setattr(planner, "plan_stroke", lambda *a, **k: pytest.fail("plan_stroke called"))
    prof, (acc, vel) = planner.plan_checked(s, limits, limits, jerk_max=JerkBound(jerk_limit(0.1, 0.04)))
    assert prof.duration > 0 and 0.9 < max(acc, vel) <= 1.0 + 1e-9


@pytest.mark.parametrize("control, message", [
    ([[0, 0], [1, 1], [np.nan, 2], [3, 0], [4, 4]], "non-finite control points"),
    ([[2, 3]] * 5, "zero length"),
])
def test_plan_checked_says_what_plan_stroke_says(limits, control, message):
    s = Spline(3, np.array(control, float))
    for f in (lambda: planner.plan_checked(s, limits, limits), lambda: planner.plan_stroke(s, limits)):
        with pytest.raises(PlanError, match=message):
            f()


def test_plan_checked_standing_still_span(limits):
    """A span of equal control points (the pen stands still there): the compiled rounds hand it to
    plan_stroke's Python rounds, which cap b there; the same plan either way."""
    s = Spline(3, np.array([[0, 0], [10, 5], [20, 0], [20, 0], [20, 0], [20, 0], [30, 10], [40, 0]], float))
    got, want = planner.plan_checked(s, limits, limits), separate(s, limits, limits, None, None)
    assert np.isfinite(got[0].b).all()
    for name in "uabt":
        assert np.array_equal(getattr(got[0], name), getattr(want[0], name))
    assert got[1] == want[1]


def test_certify_square_is_pythons():
    """curve_finish squares the velocity ratio as planner._certify's ``**`` does: the C library's
    pow, which is not always x * x (so x * x in the kernel would change a few plans)."""
    x = np.random.default_rng(9).uniform(0.5, 2.0, 40000)
    got = np.array([kernels.python_square(v, 2.0) for v in x])
    assert np.array_equal(got, [np.float64(v) ** 2 for v in x]) and np.array_equal(got, [float(v) ** 2 for v in x])
    assert (got != x * x).any()


def test_certify_leaves_a_standing_profile_alone(limits):
    """b = 0 everywhere gives all-zero ratios: nothing to scale (the velocity ratio's square used to
    underflow to 0 and divide by it)."""
    from doodlecam.plan.constraints import bernstein_rows

    s = Spline(3, np.array([[0.0, 0.0], [10.0, 5.0], [20.0, -5.0], [30.0, 0.0]]))
    u = np.linspace(0.0, 1.0, 9)
    rows = bernstein_rows(s, u, limits.M, limits.vmax, limits.amax)
    for r in (rows, None):
        assert np.array_equal(planner._certify(s, u, np.zeros(9), limits, 0.0, 0.0, r), np.zeros(9))


def deviation_reference(s, x, v, tau, c, su):
    """period_deviation with each point's distance from _any_distance (every candidate rooted, the
    cubic evaluated through the general spline_point: the values the cubic path must give)."""
    k, nseg = s.degree, len(s.control) - s.degree
    d = s.derivative_controls
    kt, N, left, right = kernels.knot_table(k, nseg), np.empty(k + 1), np.empty(k + 1), np.empty(k + 1)
    out = []
    for i in range(len(x) - 1):
        w = max(su[i + 1] - su[i], 1e-9)
        lo, hi = max(su[i] - w / 2, 0.0), min(su[i + 1] + w / 2, 1.0)
        p = x[i] + v[i] * tau[:, None] + (v[i + 1] - v[i]) * c[:, None]
        dist = np.array([kernels._any_distance(d[0], d[1], d[2], k, nseg, kt, N, left, right, px, py, lo, hi,
                                               CANDIDATES, 4) for px, py in p])
        top = int(dist.argmax())
        kk = min(max(top, 1), len(dist) - 2)
        fm, f0, fp = dist[kk - 1], dist[kk], dist[kk + 1]
        curv = 2 * f0 - fm - fp
        peak = f0 + ((fp - fm) * (fp - fm) / (8 * curv) if curv > 1e-15 else 0.0)
        out.append(max(dist[top], min(peak, f0 + abs(fp - fm))))
    return np.array(out)


def test_period_deviation_shares_the_candidates_of_a_period():
    """The cubic's candidate points are made once per period and rooted only where they are nearer:
    the same distances as rooting every candidate of every point, also where two candidates are
    (to rounding) equally far, as from the axis of a symmetric curve."""
    rng = np.random.default_rng(10)
    tau = np.linspace(0.0, 0.04, 17)
    c = tau ** 2 / (2 * 0.04)
    cases = []
    for _ in range(30):
        s = Spline(3, rng.normal(0, 10, (int(rng.integers(4, 10)), 2)))
        m = int(rng.integers(2, 12))
        x = s(np.linspace(0, 1, m + 1)) + rng.normal(0, 0.3, (m + 1, 2))
        v = rng.normal(0, 50, (m + 1, 2))
        cases.append((s, x, v, np.linspace(0, 1, m + 1)))
    arc = Spline(3, np.array([[-10, 0], [-8, 6], [0, 9], [8, 6], [10, 0]], float))  # mirrored about x = 0
    x = np.column_stack([np.zeros(400), np.linspace(-20, 20, 400)])  # each period: its point, stretch [0, 1]
    cases.append((arc, x, np.zeros((400, 2)), np.arange(400) % 2.0))
    for s, x, v, su in cases:
        got = np.empty(len(x) - 1)
        d = s.derivative_controls
        kernels.period_deviation(d[0], d[1], d[2], 3, len(s.control) - 3, x, v, tau, c, su, CANDIDATES, 4, got)
        assert np.array_equal(got, deviation_reference(s, x, v, tau, c, su))


def test_interval_check_where_is_the_full_check_there(limits):
    """plan_rounds checks only the intervals where a row binds: there the same ratios as the full check."""
    s = next(s for s in random_splines(11, 20) if s.degree == 3 and not s.straight)
    prof = planner.plan_stroke(s, limits)
    c, M = s.derivative_controls, np.ascontiguousarray(limits.M, float)
    args = (c[1], c[2], 3, len(s.control) - 3, prof.u, planner._taus(8), prof.b, M, limits.amax, limits.vmax, 50.0)
    full = kernels.spline_interval_worst(*args)
    which = np.random.default_rng(12).random(len(prof.u) - 1) < 0.5
    part = kernels.spline_interval_worst_where(*args, which)
    for f, p in zip(full, part):
        assert np.array_equal(p[which], f[which]) and not p[~which].any() and f[~which].all()
