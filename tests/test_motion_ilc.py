"""Iterative learning control with the thesis's FIR filter (§7.2.3) on a simulated servo."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.motion import MotionError
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


@pytest.fixture(scope="module")
def example_1():
    """The thesis's Example 1 (Table 5.1) at the README's 10.6 s cycle, 300 samples (ΔT = 35 ms)."""
    from pathlib import Path

    from doodlecam.motion.design import load_design, solve_design

    d = load_design(Path(__file__).resolve().parent.parent / "samples" / "motion" / "fuse.toml").scaled(10.6)
    t, axes = solve_design(d).sample()
    return t, axes


@pytest.mark.parametrize("axis", ["x", "y"])
def test_example_1_plain_learning_saturates_in_7_to_10_cycles_filtered_does_not(example_1, axis):
    t, axes = example_1
    r, peak = axes[axis][0], np.abs(axes[axis][2]).max()
    servo = ServoAxis(accel_limit=3 * peak, noise=0.0005)
    plain = learning_cycles(servo, t, r, cycles=16, gain=0.3)  # the thesis's gain
    e = np.array([s.rms_error for s in plain])
    first = next(s.cycle for s in plain if s.saturated > 0)
    assert 7 <= first <= 10  # the rig: "the servo motors achieve saturation after 7-10 cycles"
    assert e[:4].argmin() == 3 and e[3] < 0.5 * e[0]  # it learns at first ...
    assert e[-1] > 3 * e.min()  # ... then the error grows with the saturation
    ours = learning_cycles(servo, t, r, cycles=16, gain=0.3, cutoff=1 / (t[1] - t[0]))
    thesis = learning_cycles(servo, t, r, cycles=16, gain=0.3, cutoff=16.0, mode="command")
    for run in (ours, thesis):
        assert all(s.saturated == 0 for s in run)
    f = np.array([s.rms_error for s in ours])
    assert np.all(np.diff(f) <= 1e-3 * f[0]) and f[-1] < 0.25 * f[0]  # converges, monotonically
    # eq. 7.12 as printed filters the reference too: it settles, but at the filter's distortion of r
    assert thesis[-1].rms_error > 3 * ours[-1].rms_error
    assert abs(thesis[-1].rms_error - thesis[-2].rms_error) < 0.01 * thesis[-1].rms_error


def closed_loop_ode(servo, t, u):
    """The same loop in continuous time (no delay, no quantisation, no limit), by scipy's ODE solver."""
    from scipy.integrate import solve_ivp

    w = 2 * np.pi * servo.bandwidth
    kp, kd, ki = w * w, 2 * servo.damping * w, servo.integral * w**3
    tf = 1 / (servo.derivative_filter * w)
    slope = np.diff(u) / np.diff(t)

    def rhs(tt, s):
        x, v, integ, d = s
        k = min(int(np.searchsorted(t, tt, side="right")) - 1, len(slope) - 1)
        e = np.interp(tt, t, u) - x
        a = kp * e + d + ki * integ
        return [v, a - servo.friction * v, e, (kd * (slope[k] - v) - d) / tf]

    sol = solve_ivp(rhs, (t[0], t[-1]), [u[0], 0, 0, 0], t_eval=t, max_step=float(t[1] - t[0]) / 4, rtol=1e-8, atol=1e-10)
    return sol.y[0]


def test_servo_matches_the_continuous_loop_at_the_thesis_tick(example_1):
    # stable and right at 35 ms command samples: exact between ticks, controller every 416 µs
    t, axes = example_1
    r = axes["y"][0]
    servo = ServoAxis(accel_limit=1e9, resolution=0.0, delay=0)
    run = servo.run(t, r)
    ref = closed_loop_ode(servo, t, r)
    lag = np.abs(r - ref).max()
    assert lag > 0.01  # the loop lags visibly ...
    assert np.abs(run.response - ref).max() < 0.02 * lag  # ... and the simulation agrees with the ODE to 2 % of that
    assert servo.ticks_per_sample(t[1] - t[0]) == 86  # 35.45 ms / 86 = 412 µs <= 416 µs


def test_closed_cycles_run_back_to_back():
    # a circle moving at the cycle start (Example 2's kind): from rest it jolts every cycle; back to back it does not
    t = np.linspace(0, 2.0, 301)
    r = 20 * np.sin(2 * np.pi * t / 2.0)
    peak = 20 * (np.pi) ** 2
    servo = ServoAxis(accel_limit=3 * peak)
    back = learning_cycles(servo, t, r, cycles=8, gain=0.3, cutoff=1 / (t[1] - t[0]))
    rest = learning_cycles(servo, t, r, cycles=8, gain=0.3, cutoff=1 / (t[1] - t[0]), periodic=False)
    assert all(s.saturated > 0.3 for s in rest)  # restarted from rest, every cycle starts with a jolt
    assert all(s.saturated == 0 for s in back)  # run as the machine runs it, never
    assert back[0].max_error < 0.1 * rest[0].max_error
    assert back[-1].rms_error < 0.2 * back[0].rms_error


@pytest.mark.parametrize("axis", ["x", "y"])
def test_example_2_circle_back_to_back(axis):
    # Example 2's kind (samples/motion/circle.toml, the thesis gives no radius): a closed path moving at its start,
    # run at 2 s a cycle; cycles back to back as on the rig
    from pathlib import Path

    from doodlecam.motion.design import load_design, solve_design

    d = load_design(Path(__file__).resolve().parent.parent / "samples" / "motion" / "circle.toml").scaled(2.0)
    t, axes = solve_design(d).sample()
    r, peak = axes[axis][0], np.abs(axes[axis][2]).max()
    servo = ServoAxis(accel_limit=3 * peak, noise=0.0005)
    plain = learning_cycles(servo, t, r, cycles=12, gain=0.3)
    assert plain[0].saturated == 0  # no jolt at the cycle start
    assert 7 <= next(s.cycle for s in plain if s.saturated > 0) <= 10
    cut = min(1 / (t[1] - t[0]), 0.75 * 2 * np.pi * servo.bandwidth)  # what learn --simulate uses
    filt = learning_cycles(servo, t, r, cycles=12, gain=0.3, cutoff=cut)
    assert all(s.saturated == 0 for s in filt) and filt[-1].rms_error < 0.1 * filt[0].rms_error
