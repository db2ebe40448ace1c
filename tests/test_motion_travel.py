"""Pen-up travel laws: the time-optimal trapezoid and smooth laws with the same peak acceleration."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.errors import MachineError
from doodlecam.machine import parse_machine
from doodlecam.model import Travel
from doodlecam.plan.travel import (TRAVEL_LAWS, _ramp, axis_move_state, axis_move_time, make_travel, travel_state, travel_time_by_law)

from conftest import PROFILE  # tests/ is on sys.path under pytest

SMOOTH = [law for law in TRAVEL_LAWS if law != "trapezoid"]


def old_trapezoid(d, vmax, amax):  # the behaviour before travel laws existed
    d = np.abs(d)
    return np.where(d < vmax * vmax / amax, 2 * np.sqrt(d / amax), d / vmax + vmax / amax)


def test_trapezoid_is_the_previous_behaviour_and_the_default(machine):
    d = np.linspace(0, 500, 2001)
    assert np.allclose(axis_move_time(d, 150.0, 2000.0), old_trapezoid(d, 150.0, 2000.0), rtol=1e-14, atol=0)
    assert machine.travel_law == "trapezoid"
    tr = make_travel([0, 0], [120, 30], machine)
    vx, vy = machine.move_speed
    assert tr.duration == pytest.approx(max(old_trapezoid(120, vx, machine.x.max_acceleration),
                                            old_trapezoid(30, vy, machine.y.max_acceleration)))


@settings(max_examples=40, deadline=None)
@given(law=st.sampled_from(TRAVEL_LAWS), d=st.floats(-400, 400).filter(lambda v: abs(v) > 1e-3),
       vmax=st.floats(10, 300), amax=st.floats(100, 10000))
def test_every_law_lands_at_rest_within_the_limits(law, d, vmax, amax):
    T = float(axis_move_time(d, vmax, amax, law))
    t = np.linspace(0, T, 20001)
    f = axis_move_state(d, vmax, amax, law, t)
    assert f[0, -1] == pytest.approx(d, abs=1e-9 * max(1, abs(d)))
    assert abs(f[1, -1]) < 1e-6 * vmax and abs(f[1, 0]) < 1e-9 * vmax
    assert np.abs(f[1]).max() <= vmax * (1 + 1e-9)
    assert np.abs(f[2]).max() <= amax * (1 + 1e-9)
    # position is the integral of velocity (no gaps between ramp, cruise and ramp)
    integral = np.concatenate([[0], np.cumsum((f[1][1:] + f[1][:-1]) / 2 * np.diff(t))])
    assert np.abs(integral - f[0]).max() < 1e-5 * max(1, abs(d)) + vmax * (t[1] - t[0])  # the rule's error at kinks
    tau, h = _ramp(vmax, amax, law)
    joints = [tau, T - tau] if abs(d) > h else [T / 2]  # where ramp meets cruise, or the two halves meet
    eps = 1e-9 * tau
    for tj in joints:
        v, a = axis_move_state(d, vmax, amax, law, [tj - eps, tj + eps])[1:3]
        assert abs(v[1] - v[0]) < 1e-6 * vmax  # the ramp ends exactly at the cruise speed
        if law != "trapezoid":
            assert abs(a[1] - a[0]) < 1e-5 * amax  # smooth: the acceleration never jumps
    if law != "trapezoid":
        assert abs(f[2, 0]) < 1e-9 * amax and abs(f[2, -1]) < 1e-6 * amax  # and starts and ends at zero


@pytest.mark.parametrize("law", SMOOTH)
def test_smooth_laws_use_the_same_peak_acceleration_and_cost_some_time(law):
    for d in (2.0, 40.0, 300.0):
        T = float(axis_move_time(d, 150.0, 2000.0, law))
        f = axis_move_state(d, 150.0, 2000.0, law, np.linspace(0, T, 200_001))
        assert np.abs(f[2]).max() == pytest.approx(2000.0, rel=1e-6)  # the same peak acceleration
        assert T > float(axis_move_time(d, 150.0, 2000.0))  # smoothness is never free
    # for a long move only the ramps differ: the extra time tends to a constant
    extra = [float(axis_move_time(d, 150.0, 2000.0, law) - axis_move_time(d, 150.0, 2000.0)) for d in (100.0, 400.0)]
    assert extra[0] == pytest.approx(extra[1], abs=1e-12)


def test_modified_sine_short_move_takes_sqrt_ca_over_4_longer():
    # short moves never reach the speed: T = sqrt(Ca d / a) against 2 sqrt(d / a); Ca = 5.528 for b = 1/8
    ratio = float(axis_move_time(1.0, 150.0, 2000.0, "modified-sine") / axis_move_time(1.0, 150.0, 2000.0))
    assert ratio == pytest.approx(np.sqrt(np.pi**2 / (np.pi / 4 + 1) / 4), rel=1e-12)


def test_profile_key_selects_the_law_and_unknown_laws_are_errors():
    m = parse_machine({**PROFILE, "travel": {"law": "smooth"}}, "p.toml")
    assert m.travel_law == "modified-sine"
    assert make_travel([0, 0], [200, 0], m).duration > make_travel([0, 0], [200, 0], m, "trapezoid").duration
    with pytest.raises(MachineError, match=r"p.toml: travel.law = 'modified-sin' is unknown \(did you mean 'modified-sine'\?\); use one of "):
        parse_machine({**PROFILE, "travel": {"law": "modified-sin"}}, "p.toml")


def test_travel_state_and_the_cost_report(machine):
    tr = make_travel([10, 20], [150, 60], machine, "modified-sine")
    f = travel_state(tr, machine, np.linspace(0, tr.duration, 501), "modified-sine")
    assert np.allclose(f[0, 0], [10, 20]) and np.allclose(f[0, -1], [150, 60])
    cost = travel_time_by_law([Travel([0, 0], [100, 0]), Travel([100, 0], [101, 3])], machine)
    assert set(cost) == set(TRAVEL_LAWS)
    assert all(cost[law] > cost["trapezoid"] for law in SMOOTH)
