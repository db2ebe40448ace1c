"""The thesis's cam laws (Kirecci §2.7) against its own printed figures."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.motion import MotionError
from doodlecam.motion import laws as L

X = np.linspace(0.0, 1.0, 400_001)


def test_cycloidal_thesis_figures():
    # "if ω/β = 1: peak acceleration = 6.28 at θ = 0.25β, 0.75β; initial jerk = 39.47; cross-over jerk = -39.47"
    f = L.normalised("cycloidal", X)
    assert np.abs(f[2]).max() == pytest.approx(2 * np.pi, abs=1e-9)
    assert X[np.argmax(f[2])] == pytest.approx(0.25, abs=1e-5)
    assert X[np.argmin(f[2])] == pytest.approx(0.75, abs=1e-5)
    assert f[3, 0] == pytest.approx(39.47, abs=0.01)
    assert L.normalised("cycloidal", [0.5])[3, 0] == pytest.approx(-39.47, abs=0.01)


@pytest.mark.parametrize("h,T", [(1.0, 1.0), (20.0, 0.3), (0.5, 2.0)])
def test_cycloidal_peak_scales_with_rise_and_time(h, T):
    # peak acceleration 2π h (ω/β)^2 with ω/β = 1/T (eq. 2.53)
    f = L.evaluate("cycloidal", np.linspace(0, T, 100_001), h, T)
    assert np.abs(f[2]).max() == pytest.approx(2 * np.pi * h / T**2, rel=1e-9)
    assert f[0, -1] == pytest.approx(h, abs=1e-12)


def test_modified_trapezoid_thesis_figures():
    # "Peak acceleration = 4.88 for 0.125β < θ < 0.375β, -4.88 for 0.625β < θ < 0.875β"
    f = L.normalised("modified-trapezoid", X)
    assert f[2].max() == pytest.approx(4.88, abs=0.01)
    assert f[2].min() == pytest.approx(-4.88, abs=0.01)
    plateau = (X > 0.125) & (X < 0.375)
    assert np.allclose(f[2][plateau], 8 * np.pi / (2 + np.pi), atol=1e-12)  # eq. 2.54, 2.60
    # eq. 2.57 gives an initial jerk of 4πA = 61.43 (the scan prints 76.42)
    assert f[3, 0] == pytest.approx(4 * np.pi * 8 * np.pi / (2 + np.pi), rel=1e-12)


@pytest.mark.parametrize("b", [0.1, 0.125, 0.2, 0.3])
def test_modified_sine_thesis_formulas(b):
    f = L.normalised("modified-sine", X, b=b)
    A = np.pi**2 / (2 * np.pi * b + 2 - 8 * b)  # eq. 2.70
    assert f[2].max() == pytest.approx(A, rel=1e-9)
    assert X[np.argmax(f[2])] == pytest.approx(b, abs=1e-5)  # "b is the angle at the peak acceleration"
    assert f[3, 0] == pytest.approx(np.pi**3 / (4 * np.pi * b * b + 4 * b - 16 * b * b), rel=1e-9)  # initial jerk
    mid = L.normalised("modified-sine", [0.5], b=b)[3, 0]
    assert mid == pytest.approx(-np.pi**3 / ((2 - 4 * b) * (np.pi * b + 1 - 4 * b)), rel=1e-9)  # cross-over jerk


def test_modified_sine_with_quarter_b_is_cycloidal():
    assert np.allclose(L.normalised("modified-sine", X[::97], b=0.25), L.normalised("cycloidal", X[::97]), atol=1e-9)


def test_triple_harmonic_constraint_and_jerks():
    a1, a2 = 5.0, 1.5
    a3 = L.triple_a3(a1, a2)
    assert a1 + a2 / 2 + a3 / 3 == pytest.approx(2 * np.pi)  # eq. 2.83
    f = L.normalised("triple-harmonic", [0.0, 0.5, 1.0], a1=a1, a2=a2)
    assert f[3, 0] == pytest.approx(2 * np.pi * (a1 + 2 * a2 + 3 * a3))  # initial jerk as printed
    assert f[3, 1] == pytest.approx(2 * np.pi * (-a1 + 2 * a2 - 3 * a3))  # cross-over jerk from eq. 2.82
    # cancelling the 2nd and 3rd harmonics gives the cycloidal law
    assert np.allclose(L.normalised("triple-harmonic", X[::97], a1=2 * np.pi, a2=0.0), L.normalised("cycloidal", X[::97]))


def test_bang_bang_has_the_least_peak_acceleration():
    # §2.7.1.4: "for a given rise and time it produces the smallest possible acceleration"
    bb = L.coefficients("bang-bang")["acceleration"]
    assert bb == pytest.approx(4.0)
    for name in L.LAWS:
        if name not in ("dwell", "constant-velocity"):
            assert L.coefficients(name)["acceleration"] >= bb - 1e-9


@pytest.mark.parametrize("name", [n for n in L.LAWS if n != "dwell"])
def test_every_law_is_a_rise_with_consistent_derivatives(name):
    f = L.normalised(name, X)
    assert f[0, 0] == pytest.approx(0.0, abs=1e-12) and f[0, -1] == pytest.approx(1.0, abs=1e-9)
    assert np.all(np.diff(f[0]) >= -1e-12), "a rise never goes back"
    # each derivative integrates to the previous one (catches a typo in any piece)
    for k in range(3):
        if np.abs(np.diff(f[k])).max() > 1e-3:
            continue  # f[k] jumps inside the rise (bang-bang, cubic #1): its derivative has an impulse there
        integral = np.concatenate([[0], np.cumsum((f[k + 1][1:] + f[k + 1][:-1]) / 2 * np.diff(X))])
        tol = 1e-7 + np.abs(np.diff(f[k + 1])).max() * (X[1] - X[0])  # the trapezoid rule across a jump
        assert np.abs(f[k][0] + integral - f[k]).max() < tol, f"{name}: derivative {k + 1} does not integrate to {k}"


@pytest.mark.parametrize("name", [n for n in L.LAWS if L.LAWS[n].continuity >= 1 and n != "dwell"])
def test_dwell_rise_dwell_continuity(name):
    law = L.LAWS[name]
    f = L.normalised(name, [0.0, 1.0])
    for k in range(1, law.continuity + 1):  # joins a dwell (all zero) without a jump
        assert np.abs(f[k]).max() < 1e-9, f"{name}: derivative {k} is not zero at the ends"
    if law.continuity < 2 and name != "constant-velocity":
        inner = L.normalised(name, X)[2]
        jumps = np.abs(np.diff(inner)).max()
        assert np.abs(f[2]).max() > 1e-6 or jumps > 1e-3  # really a low-speed law (§2.7.1)


@settings(max_examples=60, deadline=None)
@given(name=st.sampled_from([n for n in L.LAWS if n != "dwell"]),
       h=st.floats(-500, 500).filter(lambda v: abs(v) > 1e-3), T=st.floats(1e-3, 100))
def test_boundary_conditions_met(name, h, T):
    f = L.evaluate(name, [0.0, T], h, T)
    assert f[0, 0] == pytest.approx(0.0, abs=1e-9 * abs(h))
    assert f[0, 1] == pytest.approx(h, rel=1e-9)
    if L.LAWS[name].continuity >= 1:
        assert np.abs(f[1]).max() <= 1e-9 * abs(h) / T


def test_bad_law_and_parameters():
    with pytest.raises(MotionError, match="did you mean 'cycloidal'"):
        L.get_law("cycloidl")
    with pytest.raises(MotionError, match="between 0 and 0.5"):
        L.normalised("modified-sine", [0.5], b=0.5)
    with pytest.raises(MotionError, match="no parameter 'c'"):
        L.check_params(L.LAWS["cycloidal"], {"c": 1})
    with pytest.raises(MotionError, match="duration must be positive"):
        L.evaluate("cycloidal", [0.0], 1.0, 0.0)
