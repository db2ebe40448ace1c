"""The public planning functions refuse inputs they cannot plan with one line
(PlanError), never a ZeroDivisionError, a NaN plan or a silently dropped limit;
degree 1 stops at corners (issue 14)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import PROFILE, report_curve
from doodlecam.errors import PlanError
from doodlecam.machine import parse_machine
from doodlecam.model import Spline
from doodlecam.plan.planner import Limits, check_profile, plan_stroke
from doodlecam.registry import kinematics_for

_MACHINE = parse_machine(PROFILE, "test.toml")
LIMITS = Limits.from_machine(_MACHINE, kinematics_for(_MACHINE))

BAD = [np.nan, np.inf, -np.inf, 0.0, -1.0, -2000.0]


def _one_line(e):
    msg = str(e.value)
    assert msg and "\n" not in msg
    return msg


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(BAD), st.integers(0, 1), st.sampled_from(["vmax", "amax"]))
def test_bad_limits_are_refused(bad, axis, which):
    lim = replace(LIMITS, **{which: np.where(np.arange(2) == axis, bad, getattr(LIMITS, which))})
    with pytest.raises(PlanError) as e:
        plan_stroke(report_curve(), lim)
    assert "limit" in _one_line(e)


@settings(max_examples=20, deadline=None)
@given(st.sampled_from(BAD))
def test_bad_pen_cap_is_refused(bad):
    with pytest.raises(PlanError) as e:
        plan_stroke(report_curve(), replace(LIMITS, pen_speed=bad))
    assert "pen" in _one_line(e)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([np.nan, np.inf, -np.inf]), st.integers(0, 7), st.integers(0, 1))
def test_non_finite_control_points_are_refused(bad, row, col):
    ctrl = np.array(report_curve().control)
    ctrl[row, col] = bad
    with pytest.raises(PlanError) as e:
        plan_stroke(Spline(3, ctrl), LIMITS)
    assert "non-finite" in _one_line(e)


@settings(max_examples=20, deadline=None)
@given(st.tuples(st.floats(-1e4, 1e4), st.floats(-1e4, 1e4)), st.integers(1, 5))
def test_a_stroke_without_length_is_refused(point, degree):
    with pytest.raises(PlanError) as e:
        plan_stroke(Spline(degree, np.tile(point, (degree + 3, 1))), LIMITS)
    assert "zero length" in _one_line(e)


def test_degree_0_and_bad_speeds_and_grids_are_refused():
    with pytest.raises(PlanError):
        plan_stroke(Spline(0, [[0, 0], [10, 0]]), LIMITS)
    for kw in ({"v_start": -1.0}, {"v_end": np.nan}, {"spacing": 0.0}, {"n_points": 1},
               {"grid": [0.0, 0.7, 0.5, 1.0]}, {"grid": [0.0, np.nan, 1.0]}):
        with pytest.raises(PlanError):
            plan_stroke(report_curve(), LIMITS, **kw)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.floats(-200, 200), st.floats(-200, 200)), min_size=2, max_size=12), st.integers(1, 4))
def test_any_finite_stroke_plans_finite_within_limits(points, degree):
    """Either a finite plan within the limits or a one-line PlanError; always a
    plan when no two neighbouring control points are closer than 0.01 mm."""
    ctrl = np.array(points, float)
    if len(ctrl) < degree + 1:
        return
    try:
        prof = plan_stroke(Spline(degree, ctrl), LIMITS)
    except PlanError as e:
        assert "\n" not in str(e)
        assert np.linalg.norm(np.diff(ctrl, axis=0), axis=1).min() < 0.01
        return
    assert np.isfinite(prof.duration) and prof.duration > 0 and np.isfinite(prof.b).all()
    acc, vel = check_profile(Spline(degree, ctrl), prof, LIMITS)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9


def test_degree_1_stops_at_a_corner_and_keeps_its_limits():
    """A 90 degree corner: the velocity would jump there, so the pen stops."""
    s = Spline(1, [[0, 0], [100, 0], [100, 100]])
    prof = plan_stroke(s, LIMITS)
    corner = np.flatnonzero(np.isclose(prof.u, 0.5))
    assert len(corner) == 1 and prof.b[corner[0]] == 0.0
    assert prof.b.max() > 0 and np.isfinite(prof.duration)
    acc, vel = check_profile(s, prof, LIMITS)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9
    # a straight degree-1 stroke with a knot in line does not stop there
    straight = plan_stroke(Spline(1, [[0, 0], [50, 0], [100, 0]]), LIMITS)
    assert straight.b[np.isclose(straight.u, 0.5)].min() > 0


def test_degree_2_check_reads_each_side_of_a_knot():
    """The acceleration ratio of a degree-2 plan (within limits) reads <= 1: at a
    knot q'' jumps and each interval is checked on its own side."""
    s = Spline(2, report_curve().control)
    prof = plan_stroke(s, LIMITS)
    acc, vel = check_profile(s, prof, LIMITS)
    assert 0.99 <= acc <= 1 + 1e-9 and vel <= 1 + 1e-9


def test_sample_stroke_refuses_bad_periods_and_steps():
    from doodlecam.model import Stroke
    from doodlecam.plan.sample import sample_stroke

    s = report_curve()
    stroke = Stroke(spline=s, profile=plan_stroke(s, LIMITS))
    for dt, k in ((0.0, (80, 80)), (np.nan, (80, 80)), (0.04, (0, 80)), (0.04, (np.inf, 80))):
        with pytest.raises(PlanError) as e:
            sample_stroke(stroke, dt, LIMITS, k)
        _one_line(e)
    with pytest.raises(PlanError):
        sample_stroke(Stroke(spline=s), 0.04, LIMITS)
