"""Iterative learning control with the thesis's FIR filter (§7.2.3) on a simulated servo."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.motion import MotionError
from doodlecam.motion import laws as L
from doodlecam.motion.ilc import fir_coefficients, fir_filter, learn_step
from doodlecam.motion.servo import ServoAxis, learning_cycles


@settings(max_examples=80, deadline=None)
@given(st.floats(0.01, 3.1))
def test_fir_length_is_where_the_coefficients_first_sum_to_one(wc):
    c = fir_coefficients(wc)
    m = (len(c) - 1) // 2
    k = np.arange(1, m + 1)
    raw = np.concatenate([np.sin(wc * k[::-1]) / (k[::-1] * np.pi), [wc / np.pi], np.sin(wc * k) / (k * np.pi)])  # eq. 7.7
    assert raw.sum() >= 1.0  # eq. 7.9: summed until >= 1 ...
    if m > 0:
        shorter = raw[1:-1].sum()
        assert shorter < 1.0  # ... and no further
    assert np.allclose(c, raw / raw.sum())  # eq. 7.10-7.11: remainder compensated
    assert c.sum() == pytest.approx(1.0)
    assert np.allclose(c, c[::-1])


def test_filter_passes_constants_and_slow_signals_and_stops_fast_ones():
    n = 600
    i = np.arange(n)
    c = fir_coefficients(0.3)
    assert np.allclose(fir_filter(np.full(n, 7.0), c), 7.0)
    slow = np.sin(2 * np.pi * i / (n - 1))  # one cycle over the data: periodic
    fast = 0.5 * np.sin(2 * np.pi * 240 * i / (n - 1))  # 2.5 rad/sample, near Nyquist, also periodic
    out = fir_filter(slow + fast, c)
    assert np.abs(out - slow).max() < 0.02
    # a ramp that is not a closed cycle keeps its ends (held, not wrapped)
    ramp = np.linspace(0, 10, n)
    r = fir_filter(ramp, c)
    assert r[0] == pytest.approx(0.0, abs=0.2) and r[-1] == pytest.approx(10.0, abs=0.2)
    assert np.allclose(r[50:-50], ramp[50:-50])


def test_learn_step_is_eq_7_5_and_7_12():
    rng = np.random.default_rng(1)
    r = np.sin(np.linspace(0, 2 * np.pi, 200))
    u = r + 0.1 * rng.normal(size=200)
    y = 0.9 * r
    assert np.allclose(learn_step(u, r, y, 0.3), u + 0.3 * (r - y))  # plain
    c = fir_coefficients(0.5)
    printed = learn_step(u, r, y, 0.3, c, mode="command")
    assert np.allclose(printed, fir_filter(u + 0.3 * (r - y), c, periodic=True))  # eq. 7.12 as printed (r is a closed cycle)
    corr = learn_step(u, r, y, 0.3, c)
    assert np.allclose(corr, r + fir_filter(u - r + 0.3 * (r - y), c, periodic=True))
    assert np.allclose(corr - printed, r - fir_filter(r, c, periodic=True))  # they differ by the filter's distortion of r only


def test_bad_learning_parameters():
    with pytest.raises(MotionError, match="between 0 and 1"):
        learn_step([0, 1], [0, 1], [0, 1], gain=1.5)
    with pytest.raises(MotionError, match="differ in length"):
        learn_step([0, 1], [0, 1, 2], [0, 1], gain=0.3)
    with pytest.raises(MotionError, match="between 0 and π"):
        fir_coefficients(4.0)


def reference(n=300, T=1.0, h=20.0):
    """A closed cycle: cycloidal rise in 0.4 T, dwell, cycloidal return, dwell (mm, s)."""
    t = np.linspace(0, T, n)
    a = 0.4 * T
    r = np.full(n, h)
    up, down = t < a, (t >= 0.5 * T) & (t < 0.9 * T)
    r[up] = L.evaluate("cycloidal", t[up], h, a)[0]
    r[down] = h - L.evaluate("cycloidal", t[down] - 0.5 * T, h, a)[0]
    r[t >= 0.9 * T] = 0.0
    peak = 2 * np.pi * h / a**2
    return t, r, peak


def test_plain_learning_saturates_and_filtered_learning_keeps_improving():
    # the thesis's observation: plain learning improves the tracking for a few cycles, then the
    # command roughens and the actuator saturates (after 7-10 cycles); filtered learning does not
    t, r, peak = reference()
    axis = ServoAxis(accel_limit=3 * peak, noise=0.0005)
    plain = learning_cycles(axis, t, r, cycles=16, gain=0.5)
    filt = learning_cycles(axis, t, r, cycles=16, gain=0.5, cutoff=300.0)
    e_plain = np.array([s.rms_error for s in plain])
    e_filt = np.array([s.rms_error for s in filt])
    best = int(np.argmin(e_plain))
    assert 3 <= best <= 10  # it does learn at first ...
    assert e_plain[best] < 0.2 * e_plain[0]
    assert plain[0].effort < 1 and max(s.effort for s in plain[: best + 1]) < 1
    assert any(s.saturated > 0 for s in plain)  # ... until the actuator saturates
    assert e_plain[-1] > 3 * e_plain[best]  # and the error grows again
    # with the filter: never saturates, and the error keeps falling to well below plain learning's best
    assert all(s.effort < 1 and s.saturated == 0 for s in filt)
    assert np.all(e_filt[1:] <= 1.2 * np.minimum.accumulate(e_filt)[:-1])
    assert e_filt[-1] < 0.05 * e_filt[0]
    assert e_filt[-1] < e_plain[best]


def test_servo_without_learning_lags_and_with_a_weak_actuator_saturates():
    t, r, peak = reference()
    run = ServoAxis(accel_limit=3 * peak).run(t, r)
    assert run.effort < 1 and 0 < np.abs(r - run.response).max() < 0.1
    weak = ServoAxis(accel_limit=0.5 * peak).run(t, r)
    assert weak.saturated > 0 and np.abs(r - weak.response).max() > np.abs(r - run.response).max()
