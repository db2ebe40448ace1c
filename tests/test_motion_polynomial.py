"""Power-form and arbitrary-power polynomials (Kirecci eq. 3.1–3.11)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from doodlecam.motion import MotionError
from doodlecam.motion.polynomial import Condition as C, optimise_powers, solve

REST_TO_REST = [C(0, 0, 0), C(0, 1, 0), C(0, 2, 0), C(1, 0, 1), C(1, 1, 0), C(1, 2, 0)]  # Fig. 3.13
FINE = np.linspace(0.0, 1.0, 200_001)


def met(seg, conds):
    """Largest residual of the conditions in the segment's scaled time (d^k/dτ^k = T^k d^k/dt^k),
    relative to the largest scaled value: the sense in which they are met to 1e-9."""
    T = seg.duration
    scale = max(1.0, max(abs(c.value) * T**c.order for c in conds))
    return max(abs(seg.evaluate([c.t])[c.order, 0] - c.value) * T**c.order for c in conds) / scale


def peak(seg, k, t0=0.0, t1=1.0):
    return float(np.abs(seg.evaluate(t0 + FINE * (t1 - t0))[k]).max())


def test_quintic_is_the_textbook_polynomial():
    q = solve(REST_TO_REST, 0.0, 1.0)
    powers, c = q.power_form()
    assert np.allclose(c, [0, 0, 0, 10, -15, 6], atol=1e-9)  # d = 10t^3 - 15t^4 + 6t^5
    assert peak(q, 1) == pytest.approx(1.875, abs=1e-9)
    assert peak(q, 2) == pytest.approx(10 / np.sqrt(3), abs=1e-6)


def test_runge_with_dummy_constraints_table_3_1():
    # eleven Runge points plus ten dummy derivative constraints: a 20-degree polynomial (Fig. 3.3)
    xs = np.arange(-5.0, 6.0)
    conds = [C(x, 0, 1 / (1 + x * x)) for x in xs]
    conds += [C(-5, 1, 0), C(-5, 2, 0), C(-5, 3, 0), C(-4, 1, 0.05), C(-4, 2, 0.07),
              C(4, 1, -0.05), C(4, 2, 0.07), C(5, 1, 0), C(5, 2, 0), C(5, 3, 0)]
    seg = solve(conds, -5.0, 10.0)
    assert seg.degree == 20
    assert met(seg, conds) < 1e-9


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_random_boundary_conditions_are_met(data):
    T = data.draw(st.floats(0.01, 50.0))
    t0 = data.draw(st.floats(-100.0, 100.0))
    n_inner = data.draw(st.integers(0, 3))
    value = st.floats(-1000.0, 1000.0)
    conds = [C(t0, k, data.draw(value)) for k in range(data.draw(st.integers(1, 4)))]
    conds += [C(t0 + T, k, data.draw(value)) for k in range(data.draw(st.integers(1, 4)))]
    inner = sorted({round(f, 3) for f in data.draw(st.lists(st.floats(0.1, 0.9), min_size=n_inner, max_size=n_inner))})
    conds += [C(t0 + f * T, 0, data.draw(value)) for f in inner]
    seg = solve(conds, t0, T)
    assert met(seg, conds) < 1e-9


def test_arbitrary_powers_meet_the_conditions_and_the_thesis_powers_beat_the_quintic():
    # Fig. 3.13: powers (0, 1, 2, 2.52, 2.54, 39) give the lowest peak velocity of the laws compared
    seg = solve(REST_TO_REST, 0.0, 1.0, powers=[0, 1, 2, 2.52, 2.54, 39])
    assert met(seg, REST_TO_REST) < 1e-9
    assert peak(seg, 1) < 1.875 * 0.85
    assert peak(seg, 1) < 2.0  # below cycloidal, modified trapezoid and bang-bang (all 2.0)


def test_optimiser_beats_the_plain_quintic():
    v = optimise_powers(REST_TO_REST, 0.0, 1.0, "velocity")
    a = optimise_powers(REST_TO_REST, 0.0, 1.0, "acceleration")
    for seg in (v, a):
        assert seg.powers is not None
        assert met(seg, REST_TO_REST) < 1e-9
        free = np.sort(seg.powers)[3:]
        assert free.min() > 2.5 - 1e-12  # eq. 3.10: q > m + 0.5 for continuity up to acceleration
    assert peak(v, 1) < 0.85 * 1.875  # quintic: 1.875
    assert peak(v, 1) <= 1.5782  # at least as good as the thesis's own choice (1.5782)
    assert peak(a, 2) < 0.95 * 10 / np.sqrt(3)  # quintic: 5.774
    assert np.all(np.isfinite(v.evaluate(FINE[::101])[:3]))


def test_reduced_powers_cure_meandering_table_3_6():
    # Table 3.6 / Fig. 3.12: starts at 2 moving down and decelerating; the plain quintic overshoots below 0,
    # raising the powers makes it worse, reducing them "gives a much better curve"
    conds = [C(0, 0, 2.0), C(0, 1, -12.0), C(0, 2, 10.0), C(1, 0, 0.0), C(1, 1, 0.0), C(1, 2, 0.0)]
    low = lambda seg: float(seg.evaluate(FINE[::10])[0].min())  # noqa: E731
    plain = solve(conds, 0.0, 1.0)
    raised = solve(conds, 0.0, 1.0, powers=[0, 1, 2, 6, 7, 8])
    assert low(plain) < -0.5 and low(raised) < low(plain)
    better = optimise_powers(conds, 0.0, 1.0, "velocity", envelope=(0.0, 2.0))
    assert low(better) > 0.1 * low(plain)  # the excursion shrinks more than tenfold
    assert np.all(np.sort(better.powers)[3:] < 3.0)  # by reducing the powers
    assert met(better, conds) < 1e-9


def test_segment_is_scaled_time_invariant():
    # the same conditions in other units of time give the same curve, scaled
    a = solve(REST_TO_REST, 0.0, 1.0)
    k = 250.0
    conds = [C(c.t * k + 7.0, c.order, c.value / k**c.order) for c in REST_TO_REST]
    b = solve(conds, 7.0, k)
    fa, fb = a.evaluate(FINE[::1000]), b.evaluate(7.0 + k * FINE[::1000])
    for o in range(4):
        assert np.allclose(fb[o] * k**o, fa[o], rtol=1e-9, atol=1e-9)


def test_errors_name_the_segment_and_the_condition():
    with pytest.raises(MotionError, match="seg 2: inconsistent conditions .*pos = 1.*pos = 2"):
        solve([C(0, 0, 1.0), C(0, 0, 2.0), C(1, 0, 3.0)], 0.0, 1.0, where="seg 2")
    with pytest.raises(MotionError, match="no position condition"):
        solve([C(0, 1, 1.0), C(1, 1, 0.0)], 0.0, 1.0)
    with pytest.raises(MotionError, match="duration is 0 s"):
        solve([C(0, 0, 1.0)], 0.0, 0.0)
    with pytest.raises(MotionError, match="under-determined: 3 conditions but only 2 independent"):
        solve([C(0, 0, 0.0), C(0, 2, 1.0), C(1, 2, 1.0)], 0.0, 1.0)  # a parabola: the slope is never pinned
    with pytest.raises(MotionError, match="inconsistent conditions: .*acc"):
        solve([C(0, 0, 0.0), C(0, 2, 1.0), C(1, 2, 2.0)], 0.0, 1.0)  # a parabola has one acceleration
    with pytest.raises(MotionError, match="too low for .*acc"):
        solve([C(0, 0, 0), C(0, 2, 1.0), C(1, 0, 1)], 0.0, 1.0, powers=[0, 1.5, 3])
    with pytest.raises(MotionError, match="outside the segment"):
        solve([C(0, 0, 0), C(2, 0, 1)], 0.0, 1.0)
    with pytest.raises(MotionError, match="one power per condition"):
        solve(REST_TO_REST, 0.0, 1.0, powers=[0, 1, 2])


def test_singular_birkhoff_system_is_reported():
    # pos at 0 and 1 and the velocity at the midpoint of a quadratic: v(1/2) is fixed by the ends
    with pytest.raises(MotionError, match="inconsistent|under-determined"):
        solve([C(0, 0, 0.0), C(1, 0, 1.0), C(0.5, 1, 3.0)], 0.0, 1.0)
