"""Straight strokes planned together in closed form (doodlecam.plan.lines) against the general
per-stroke pass they replace (doodlecam.plan.stroke.plan_one)."""

import numpy as np
import pytest

import doodlecam.plan.lines as lines
from doodlecam.machine import load_machine
from doodlecam.model import Drawing
from doodlecam.pipeline import Settings, pen_limits, plan_job, run_posts
from doodlecam.plan.follow import path_deviation
from doodlecam.plan.sample import TRACKING_STEPS, straight_samples, whole_step_limits, written_samples
from doodlecam.registry import kinematics_for


def _segments(n, seed):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, n)
    # from under one machine step to long ones that cruise
    length = np.exp(rng.uniform(np.log(0.004), np.log(90.0), n))
    p0 = rng.uniform(100, 120, (n, 2))
    return tuple(np.array([p, p + r * np.array([np.cos(t), np.sin(t)])]) for p, r, t in zip(p0, length, a))


@pytest.mark.parametrize("machine", ["doodlebot", "axidraw-v3"])
def test_closed_forms_give_the_general_pass_plans_samples_and_files(machine, monkeypatch):
    m = load_machine(machine)
    d = Drawing(polylines=_segments(300, 7), units="mm")
    taken = []
    real = lines.plan_lines
    monkeypatch.setattr(lines, "plan_lines", lambda *a: taken.append(r := real(*a)) or r)
    fast = plan_job(d, m, order={"merge": 0.0})
    monkeypatch.setattr(lines, "eligible", lambda ctx, s: False)
    slow = plan_job(d, m, order={"merge": 0.0})
    closed = [o is not None for o in taken[0]]
    assert sum(closed) >= 150
    assert len(fast.strokes) == len(slow.strokes) == 300
    # the ones handed back are those the general pass could not take in closed form either
    k = np.array([m.x.steps_per_mm, m.y.steps_per_mm])
    lim = whole_step_limits(pen_limits(m, m.pen_number(1), kinematics_for(m)), k, m.delta_time)
    tol = TRACKING_STEPS / k.max()
    for c, s, fs, ss in zip(closed, slow.strokes, fast.samples, slow.samples):
        straight = straight_samples(s, m.delta_time, lim, k, tol)
        if not c:
            assert straight is None or path_deviation(s.spline, written_samples(ss, k)).max() > m.path_tolerance
    for f, s, fs, ss in zip(fast.strokes, slow.strokes, fast.samples, slow.samples):
        for name in ("u", "b", "a", "t"):
            np.testing.assert_allclose(getattr(f.profile, name), getattr(s.profile, name), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fs.velocity, ss.velocity, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(fs.sample_u, ss.sample_u, rtol=1e-9, atol=1e-12)
        assert fs.time_scale == pytest.approx(ss.time_scale, rel=1e-12)
        np.testing.assert_array_equal(fs.start, ss.start)
    for key in ("worst_acceleration_ratio", "worst_velocity_ratio", "max_between_samples_mm"):
        assert fast.meta[key] == pytest.approx(slow.meta[key], rel=1e-6, abs=1e-12), key
    assert fast.meta["worst_acceleration_ratio"] <= 1.0 and fast.meta["worst_velocity_ratio"] <= 1.0
    settings = Settings(machine=m, posts=("plc", "gcode"))
    assert [o[2] for o in run_posts(fast, settings)] == [o[2] for o in run_posts(slow, settings)]


def test_a_segment_over_the_path_tolerance_is_left_to_the_general_pass(monkeypatch):
    m = load_machine("doodlebot")
    d = Drawing(polylines=_segments(40, 3), units="mm")
    taken = []
    real = lines.plan_lines

    def spy(ctx, strokes, pens):
        from dataclasses import replace
        out = real(replace(ctx, path_tolerance=1e-9), strokes, pens)  # nothing is within it
        taken.append(out)
        return out

    monkeypatch.setattr(lines, "plan_lines", spy)
    job = plan_job(d, m, order={"merge": 0.0})
    assert all(o is None for o in taken[0])  # every one went through plan_one
    assert len(job.strokes) == 40 and job.meta["max_between_samples_mm"] <= m.path_tolerance


def test_eligible_all_takes_exactly_the_strokes_eligible_takes():
    """eligible_all tests the control points of every straight stroke at once: the same strokes
    as eligible one by one, whatever the shapes, degrees and non-finite points among them."""
    from types import SimpleNamespace

    from doodlecam.model import Spline, Stroke

    rng = np.random.default_rng(4)
    strokes = []
    for i in range(60):
        deg = (1, 2, 3)[i % 3]
        n = deg + 1 + i % 4
        if i % 2:  # a segment run at constant speed (evenly spread points, one span): straight
            n = deg + 1
            c = np.linspace(0, 1, n)[:, None] * rng.normal(size=2) + rng.normal(size=2)
        else:
            c = rng.normal(size=(n, 2))
        if i % 5 == 0:
            c[i % n, i % 2] = (np.nan, np.inf, -np.inf)[i % 3]
        strokes.append(Stroke(spline=Spline(deg, c)))
    ctx = SimpleNamespace(solver="reach", nonlinear=False)
    want = [i for i, s in enumerate(strokes) if lines.eligible(ctx, s)]
    assert lines.eligible_all(ctx, strokes) == want and len(want) >= 10
    assert lines.eligible_all(ctx, strokes[:1]) == [] and lines.eligible_all(ctx, []) == []
