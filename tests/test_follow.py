"""The executed path between sample instants (doodlecam.plan.follow)."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from doodlecam.geometry.fit import fit_pieces
from doodlecam.plan.follow import executed_points, path_deviation
from doodlecam.model import Spline, StrokeSamples, Stroke
from doodlecam.plan.planner import check_profile, plan_stroke
from doodlecam.plan.sample import TRACKING_STEPS, reference_positions, sample_stroke, whole_step_limits

from conftest import plc_strokes, report_curve


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


def test_follow_samples_converge_on_a_tsp_tour():
    # one long stroke through random points (a small TSP-art line: ~1400 control points, tight
    # turns). Re-linearised solves cost the shift from the first solve's instants, so they
    # converge; costing it from the last solve drifted ~0.05 mm per solve, added periods after
    # every 5 solves and here gave up (PlanError)
    from doodlecam.machine import load_machine
    from doodlecam.plan.planner import Limits
    from doodlecam.plugins.tsp import tsp_tour
    from doodlecam.registry import kinematics_for

    m = load_machine("doodlebot")
    limits = Limits.from_machine(m, kinematics_for(m))
    tour, _ = tsp_tour(np.random.default_rng(1).uniform(50.0, 80.0, (600, 2)))
    spline = max((p[0] for p in fit_pieces(tour, 3, 0.1)), key=lambda s: len(s.control))
    stroke = Stroke(spline, plan_stroke(spline, whole_step_limits(limits, (80, 80), 0.04)))
    smp = sample_stroke(stroke, 0.04, limits, (80, 80), follow=True)
    assert len(smp.velocity) <= 2 * stroke.profile.duration / 0.04
    x = smp.integrate()
    assert np.abs(x - reference_positions(stroke, smp)).max() <= TRACKING_STEPS / 80 + 1e-9
    assert np.allclose(x[-1], np.round(spline.end * 80) / 80, atol=1e-9)


def test_jerk_bound_holds_and_only_slows_the_pen(limits):
    spline = report_curve()
    free = plan_stroke(spline, limits)
    jmax = 2_000.0
    prof = plan_stroke(spline, limits, jerk_max=jmax)
    acc, vel = check_profile(spline, prof, limits)
    assert acc <= 1 + 1e-9 and vel <= 1 + 1e-9
    assert prof.duration > free.duration * 1.01  # it binds on this curve
    # the pen's jerk vector within an interval is sqrt(b) (q''' b + 3 q'' a) (b linear,
    # a constant): its component across the path stays within the bound at the rows' points
    u, b, a = prof.u, prof.b, prof.a
    worst = 0.0
    for tau in (0.0, 0.5, 1.0):
        # the interval's own side of a knot, where q''' jumps (a is the interval's)
        uu = u[:-1] + tau * np.diff(u) if tau < 1 else np.nextafter(u[1:], -np.inf)
        bb = b[:-1] * (1 - tau) + b[1:] * tau
        d1, d2, d3 = spline(uu, 1), spline(uu, 2), spline(uu, 3)
        normal = np.column_stack([-d1[:, 1], d1[:, 0]]) / np.linalg.norm(d1, axis=1)[:, None]
        jerk = np.sqrt(bb)[:, None] * (d3 * bb[:, None] + 3 * d2 * a[:, None])
        worst = max(worst, np.abs((jerk * normal).sum(axis=1)).max())
    assert 0.5 * jmax < worst <= jmax * (1 + 1e-6)


def test_path_tolerance_keeps_the_plc_on_the_curve_between_samples(tmp_path):
    from dataclasses import replace

    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert

    horse = Path(__file__).resolve().parent.parent / "samples" / "images" / "horse.png"
    machine = load_machine("doodlebot")
    assert machine.path_tolerance == 0.1  # the default profile keeps it
    res = convert(horse, tmp_path, Settings(machine=machine, posts=("plc",)))
    header, runs = plc_strokes(tmp_path / "horse.plc")
    # a run of DRAWs holds the pieces the pen draws without lifting (a long stroke is fitted in
    # pieces that meet exactly, Job.lifts): each piece goes on from where the last one ended
    assert len(runs) == sum(res.job.lifts)
    pieces = iter(zip(res.job.strokes, res.job.samples))
    for run in runs:
        v, at, start = np.array(run["v"]), 0, np.asarray(run["start"], float)
        while at < len(v):
            stroke, smp = next(pieces)
            n = len(smp.velocity)
            executed = StrokeSamples(start=start, velocity=v[at:at + n], delta_time=header.delta_time,
                                     sample_u=smp.sample_u)
            assert path_deviation(stroke.spline, executed).max() <= 0.1 + 1e-3  # whole steps/s: a hair
            start, at = executed.integrate()[-1], at + n
    assert next(pieces, None) is None
    assert res.job.meta["max_between_samples_mm"] <= 0.1
    off = convert(horse, tmp_path / "d", Settings(machine=replace(machine, path_tolerance=0.0), posts=("plc",)))
    assert off.job.meta["max_between_samples_mm"] > 0.1  # without it the ramps do stray


def test_jerk_bound_is_lowered_only_where_the_pen_strayed():
    from doodlecam.plan.follow import JerkBound

    su = np.linspace(0.0, 1.0, 21)  # 20 periods
    smp = StrokeSamples(start=np.zeros(2), velocity=np.zeros((20, 2)), delta_time=0.04, sample_u=su)
    dev = np.zeros(20)
    dev[[5, 6, 15]] = [0.2, 0.4, 0.12]
    bound = JerkBound(1000.0).tightened(smp, dev, 0.1, reach=1)
    # neighbours merged, one period either side; lowered in proportion to the excess (0.8 tol / dev, within 0.25..0.7)
    assert bound.scaled == ((su[4], su[8], 0.25), (su[14], su[17], 0.8 * 0.1 / 0.12))
    u = np.array([0.0, su[4], 0.3, su[8] + 1e-9, 0.75, 1.0])
    assert np.allclose(bound(u), [1000.0, 250.0, 250.0, 1000.0, 1000 * 0.8 / 1.2, 1000.0])
    again = bound.tightened(smp, dev, 0.1, reach=1)
    assert again(np.array([0.3]))[0] == 1000.0 * 0.25 * 0.25  # a second round lowers it again there


@pytest.mark.parametrize("name", ["coins.png", "text.png"])
def test_default_profile_keeps_every_stroke_within_the_fit_tolerance_between_samples(name):
    """By default the pen stays as close to the curve between samples as the fit
    is to the picture; these pictures need strokes re-planned to get there."""
    from doodlecam.trace.layout import fit_to_work_area
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, plan_job, trace

    m = load_machine("doodlebot")
    d = fit_to_work_area(trace(Path(__file__).resolve().parent.parent / "samples" / "images" / name, Settings(machine=m)), m)
    job = plan_job(d, m)
    assert job.meta["strokes_replanned"] > 0  # the re-plans are exercised
    for stroke, smp in zip(job.strokes, job.samples):
        assert path_deviation(stroke.spline, smp).max() <= m.path_tolerance == m.tolerance == 0.1
