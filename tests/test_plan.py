import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.model import Spline, Stroke
from doodlecam.plan.planner import Limits, check_profile, make_grid, plan_stroke
from doodlecam.plan.sample import TRACKING_STEPS, reference_positions, sample_stroke

from conftest import report_curve


def const_speed_time(spline, limits, n=200001):
    """Time of the best constant-path-speed traversal within the same limits
    (even ignoring that it cannot start or stop at rest)."""
    u = np.linspace(0, 1, n)
    d1, d2 = spline(u, 1), spline(u, 2)
    sp = np.linalg.norm(d1, axis=1)
    # unit-speed derivatives: dq/ds = d1/|d1|, d2q/ds2 = (d2 - (d2.t) t) / |d1|^2
    t = d1 / sp[:, None]
    k = (d2 - (d2 * t).sum(1)[:, None] * t) / sp[:, None] ** 2
    v_acc = np.sqrt(limits.amax / np.maximum(np.abs(k), 1e-12)).min()
    v_vel = (limits.vmax / np.maximum(np.abs(t), 1e-12)).min()
    return spline.length / min(v_acc, v_vel)


@pytest.mark.parametrize("solver", ["reach", "lp:clarabel", "lp:highs"])
def test_report_curve_rest_to_rest_within_limits_everywhere(limits, solver):
    s = report_curve()
    prof = plan_stroke(s, limits, solver=solver)
    assert prof.b[0] == 0 and prof.b[-1] == 0  # starts and ends at rest
    acc, vel = check_profile(s, prof, limits, refine=20)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9
    assert acc > 0.99  # it actually uses the machine (time-optimal is bang-bang)
    assert prof.duration < const_speed_time(s, limits)


def test_solvers_agree(limits):
    s = report_curve()
    t = [plan_stroke(s, limits, solver=x, adaptive=False).duration for x in ("reach", "lp:clarabel", "lp:highs")]
    # reach is exact where rows form a lattice; both-positive velocity rows can
    # leave the LP's "max sum b" a hair different (measured ~1e-5)
    assert max(t) - min(t) < 1e-4 * t[0]


def test_grid_contains_knots_and_follows_length():
    s = report_curve()
    g = make_grid(s, spacing=0.5)
    assert np.all(np.isin(s.breakpoints, g))
    assert np.all(np.diff(g) > 0)
    assert 0.5 * s.length / 0.5 < len(g) < 3 * s.length / 0.5
    # density follows length and turning: a 2 mm straight stroke needs a handful
    line = Spline(3, np.c_[np.linspace(0, 2, 4), np.zeros(4)])
    assert len(make_grid(line, spacing=0.5)) <= 8
    tiny = Spline(3, s.control * 0.01)  # same turns, 1/100 the length
    assert len(make_grid(tiny, spacing=0.5)) < len(g) / 3


def test_straight_line_matches_closed_form(limits):
    # along x only: trapezoid with vmax_x = 150, ax = 2000 over 100 mm
    s = Spline(3, np.c_[np.linspace(0, 100, 4), np.zeros(4)])
    prof = plan_stroke(s, limits)
    exact = 100 / 150 + 150 / 2000
    assert prof.duration == pytest.approx(exact, rel=5e-3)
    assert prof.duration >= exact * (1 - 1e-9)  # never faster than physics allows


@st.composite
def splines(draw):
    n = draw(st.integers(4, 10))
    pts = draw(st.lists(st.tuples(st.floats(0, 150), st.floats(0, 150)), min_size=n, max_size=n))
    ctrl = np.array(pts)
    if np.hypot(*np.diff(ctrl, axis=0).T).min() < 1.0:
        ctrl = ctrl + np.c_[np.arange(n) * 2.0, np.zeros(n)]
    return Spline(3, ctrl)


@settings(max_examples=30, deadline=None)
@given(splines(), st.floats(200, 5000), st.floats(20, 300))
def test_random_splines_never_violate_limits(spline, amax, vmax):
    lim = Limits(np.array([vmax, vmax * 0.8]), np.array([amax, amax * 1.3]), np.eye(2))
    prof = plan_stroke(spline, lim)
    acc, vel = check_profile(spline, prof, lim, refine=20)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9
    assert prof.b[0] == 0 and prof.b[-1] == 0
    assert np.all(np.isfinite(prof.t)) and np.all(np.diff(prof.t) > 0)
    # never faster than the reference: collocation (limits only at grid points) on a
    # fine grid is a relaxation of the continuous problem, so it bounds the optimum below
    ref = plan_stroke(spline, lim, n_points=20_000, mode="collocation", adaptive=False).duration
    assert prof.duration >= ref * (1 - 1e-9)


@settings(max_examples=20, deadline=None)
@given(splines(), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_random_start_and_end_speeds_hold_or_are_refused_in_one_line(spline, fs, fe):
    from doodlecam.errors import PlanError

    lim = Limits(np.array([150.0, 150.0]), np.array([2000.0, 2000.0]), np.eye(2))
    v0, v1 = 40.0 * fs, 40.0 * fe
    try:
        prof = plan_stroke(spline, lim, v_start=v0, v_end=v1)
    except PlanError as e:
        assert "\n" not in str(e) and "speed" in str(e)
        return
    speed = np.linalg.norm(spline(np.array([0.0, 1.0]), 1), axis=1) * np.sqrt(prof.b[[0, -1]])
    assert np.allclose(speed, [v0, v1], rtol=1e-6, atol=1e-9)
    acc, vel = check_profile(spline, prof, lim)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9


def test_samples_reproduce_the_stroke(limits):
    s = report_curve()
    stroke = Stroke(s, plan_stroke(s, limits))
    smp = sample_stroke(stroke, 0.04, limits, (80, 80))
    reached = smp.integrate()
    ref = reference_positions(stroke, smp)
    # on the curve at every sample instant, per axis within the tracking tolerance
    assert np.abs(reached - ref)[:-1].max() <= TRACKING_STEPS / 80 + 1e-9
    # starts and lands exactly on whole steps next to the curve's ends, and stops there
    assert np.allclose(reached[0] * 80, np.round(s.start * 80), atol=1e-9)
    assert np.allclose(reached[-1] * 80, np.round(s.end * 80), atol=1e-6)
    assert np.all(smp.velocity[-1] == 0)
    v = np.vstack([[0, 0], smp.velocity])
    assert np.all(np.abs(np.diff(v, axis=0)) / 0.04 <= limits.amax * (1 + 1e-9))
    assert np.all(np.abs(v) <= limits.vmax * (1 + 1e-9))
    # the sampled stroke is at most a few periods slower than the plan
    assert len(smp.velocity) * 0.04 <= stroke.duration * 1.1 + 0.08


def test_profile_state_is_consistent(limits):
    s = report_curve()
    prof = plan_stroke(s, limits)
    t = np.linspace(0, prof.duration, 2001)
    u, ud, _ = prof.state_at(t)
    assert np.all(np.diff(u) >= -1e-12) and u[0] == 0 and abs(u[-1] - 1) < 1e-9
    # u-dot is the derivative of u(t)
    mid = (u[2:] - u[:-2]) / (t[2:] - t[:-2])
    # exact for quadratics; where u-ddot jumps a central difference errs by <= |a| dt
    assert np.allclose(mid, ud[1:-1], rtol=0, atol=np.abs(prof.a).max() * (t[1] - t[0]))


def test_fivebar_plan_is_verified_on_the_fine_grid():
    from doodlecam.machine import load_machine
    from doodlecam.registry import kinematics_for

    m = load_machine("fivebar")
    kin = kinematics_for(m)
    lim = Limits.from_machine(m, kin)
    assert lim.M is None  # nonlinear: sampled rows, verified and refined
    c = report_curve().control
    c = (c - c.min(0)) / np.ptp(c, axis=0) * [m.width - 60, m.height - 60] + 30
    s = Spline(3, c)
    kin.check_reachable(s(np.linspace(0, 1, 200)))
    prof = plan_stroke(s, lim)
    acc, vel = check_profile(s, prof, lim, refine=20)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9 and max(acc, vel) > 0.95
    assert prof.b[0] == 0 and prof.b[-1] == 0


def test_impossible_start_speed_is_a_one_line_error(limits):
    from doodlecam.errors import PlanError

    s = report_curve()
    with pytest.raises(PlanError) as e:
        plan_stroke(s, limits, v_start=5000.0)  # far above the 150 mm/s axis limit
    assert "\n" not in str(e.value)
    prof = plan_stroke(s, limits, v_start=20.0, v_end=10.0)  # reachable start/end speeds hold
    sp = np.linalg.norm(s(np.array([0.0, 1.0]), 1), axis=1) * np.sqrt(prof.b[[0, -1]])
    assert np.allclose(sp, [20.0, 10.0])
    acc, vel = check_profile(s, prof, limits)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9


def test_straight_strokes_get_the_exact_trapezoid():
    """A fitted segment (q'' = 0) is planned in closed form: never slower than the
    general solver on a fine grid, within every limit on the 20x finer check, and
    refusing what the general solver refuses."""
    from doodlecam.errors import PlanError
    from doodlecam.plan.planner import is_straight

    lim = Limits(np.array([150.0, 120.0]), np.array([2000.0, 1500.0]), np.eye(2), 200.0)
    rng = np.random.default_rng(0)
    for k in range(60):
        p0, p1 = rng.random(2) * 200, rng.random(2) * 200
        p1 = p0 + (p1 - p0) * rng.choice([1.0, 0.01, 0.001])
        s = Spline(3, p0 + np.arange(4)[:, None] / 3 * (p1 - p0))
        assert is_straight(s, lim)
        vs, ve = (0.0, 0.0) if k % 3 else (rng.random() * 30, rng.random() * 30)
        try:
            general = plan_stroke(s, lim, v_start=vs, v_end=ve, n_points=20001)
        except PlanError:
            with pytest.raises(PlanError):
                plan_stroke(s, lim, v_start=vs, v_end=ve)
            continue
        fast = plan_stroke(s, lim, v_start=vs, v_end=ve)
        assert len(fast.u) <= 4
        ra, rv = check_profile(s, fast, lim)
        assert ra <= 1 + 1e-9 and rv <= 1 + 1e-9
        assert fast.duration <= general.duration * (1 + 1e-9)
    assert not is_straight(Spline(3, np.array([[0.0, 0], [1, 1], [2, 0], [3, 1]])), lim)
