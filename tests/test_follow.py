"""The executed path between sample instants (doodlecam.follow)."""

import numpy as np
from scipy.spatial import cKDTree

from doodlecam.fit import fit_pieces
from doodlecam.follow import executed_points, path_deviation
from doodlecam.model import Spline, StrokeSamples, Stroke
from doodlecam.plan import plan_stroke
from doodlecam.sample import sample_stroke

from conftest import report_curve


def brute_force(spline, samples, sub=64):
    curve = spline(np.linspace(0.0, 1.0, 400_000))
    return cKDTree(curve).query(executed_points(samples, sub).reshape(-1, 2))[0].max()


def test_executed_points_are_the_plc_ramps():
    smp = StrokeSamples(start=np.array([1.0, 2.0]), velocity=np.array([[10.0, 0.0], [10.0, 4.0], [0.0, 0.0]]),
                        delta_time=0.1)
    pts = executed_points(smp, 4)
    # instants agree with the trapezoidal integration the PLC does
    assert np.allclose(pts[:, 0], smp.integrate()[:-1]) and np.allclose(pts[-1, -1], smp.integrate()[-1])
    # first period: velocity ramps 0 -> 10 in x, so x(dT/2) = 10 (dT/2)^2 / (2 dT)
    assert np.isclose(pts[0, 2, 0], 1.0 + 10 * 0.05 ** 2 / 0.2)


def test_alternating_targets_swing_off_a_straight_line_by_e_dt_over_4():
    # +-e in y on top of a steady x speed keeps every instant on y = 0 after the
    # first period but swings the pen e dT / 4 off the line in the middle of each
    dt, e, n = 0.04, 50.0, 40
    vy = np.where(np.arange(1, n) % 2, e, -e)
    vy[0] = e / 2  # half a swing first: every instant from the second on lies on y = 0
    vel = np.column_stack([np.full(n - 1, 100.0), vy])
    vel = np.vstack([vel, [0.0, 0.0]])
    smp = StrokeSamples(start=np.zeros(2), velocity=vel, delta_time=dt)
    end = smp.integrate()[-1]
    line = Spline(3, np.column_stack([np.linspace(-1.0, end[0] + 1.0, 8), np.zeros(8)]))
    dev = path_deviation(line, smp)
    assert np.isclose(np.median(dev), e * dt / 4, rtol=0.02)
    assert np.isclose(dev.max(), brute_force(line, smp), rtol=0.02)


def test_matches_brute_force_on_planned_strokes(limits):
    th = np.linspace(0.0, 1.8 * np.pi, 300)
    circle = np.column_stack([100 + 4 * np.cos(th), 100 + 4 * np.sin(th)])
    for spline in (report_curve(), fit_pieces(circle, 3, 0.1)[0][0]):
        stroke = Stroke(spline, plan_stroke(spline, limits))
        smp = sample_stroke(stroke, 0.04, limits, (80, 80))
        got, ref = path_deviation(spline, smp).max(), brute_force(spline, smp)
        assert ref > 0.005  # the ramps do leave the curve between instants
        assert abs(got - ref) <= 0.02 * ref
