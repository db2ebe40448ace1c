"""Generated drawings at scale (issue 29): the same files with any number of workers,
the closed-form straight strokes against the QP they replace, the path tolerance
always met, touching segments drawn as one stroke. Correctness, not time
(benchmarks/bench_scale.py times it against vpype)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from doodlecam.machine import load_machine
from doodlecam.model import Drawing, Stroke
from doodlecam.pipeline import Settings, convert, plan_job
from doodlecam.plan import sample as sampling
from doodlecam.plan import stroke as stroke_plan
from doodlecam.plan.planner import Limits, plan_stroke
from doodlecam.plan.sample import TRACKING_STEPS, sample_stroke, whole_step_limits
from doodlecam.registry import kinematics_for
from generated_art import generated_svg
from test_executed import _check, executed_ratios


def _convert(tmp_path, svg, workers, name):
    out = tmp_path / name
    res = convert(svg, out, Settings(machine=load_machine("doodlebot"), layout={"scale": 1.0}, workers=workers))
    return res, {p.suffix: p.read_bytes() for p in map(type(out), res.outputs)}


def test_two_workers_write_the_same_files_and_every_limit_holds(tmp_path):
    svg = tmp_path / "art.svg"
    svg.write_text(generated_svg(stroke_plan.PARALLEL_MIN + 300, "mixed", seed=7))
    one, files_one = _convert(tmp_path, svg, 1, "one")
    two, files_two = _convert(tmp_path, svg, 2, "two")
    assert len(one.job.strokes) >= stroke_plan.PARALLEL_MIN  # the workers really ran
    assert set(files_one) == {".plc", ".gcode", ".svg"}
    for ext, data in files_one.items():
        assert files_two[ext] == data, ext  # byte for byte
    m = one.job.machine
    r = executed_ratios(files_one[".plc"], one.job, m.path_tolerance)  # read back from the file's bytes
    _check(r, m.path_tolerance)


def _line(a, b, degree=3):
    from doodlecam.geometry.fit import fit_pieces

    (spline, _), = fit_pieces(np.array([a, b], float), degree, 0.1)
    return spline


@pytest.mark.parametrize("profile", ["doodlebot", "axidraw-v3"])
def test_straight_strokes_in_closed_form_keep_every_limit_and_are_not_slower_than_the_qp(profile, monkeypatch):
    m = load_machine(profile)
    kin = kinematics_for(m)
    lim = Limits.from_machine(m, kin)
    k = np.array([m.x.steps_per_mm, m.y.steps_per_mm])
    plan_lim = whole_step_limits(lim, k, m.delta_time)
    low = whole_step_limits(lim, k, m.delta_time)
    rng = np.random.default_rng(3)
    M = np.asarray(lim.M, float)
    fast_used = 0
    for n in range(60):
        a = rng.uniform(20, 150, 2)
        length = [0.05, 0.3, 2.0, 10.0, 60.0, 200.0][n % 6]
        ang = [0.0, np.pi / 2, np.pi / 4][n % 3] if n % 4 == 0 else rng.uniform(0, 2 * np.pi)
        b = a + length * np.array([np.cos(ang), np.sin(ang)])
        spline = _line(a, b)
        stroke = Stroke(spline, plan_stroke(spline, plan_lim))
        fast = sampling.straight_samples(stroke, m.delta_time, low, k, TRACKING_STEPS / k.max())
        got = sample_stroke(stroke, m.delta_time, lim, k)
        with monkeypatch.context() as mp:
            mp.setattr(sampling, "straight_samples", lambda *a: None)
            qp = sample_stroke(stroke, m.delta_time, lim, k)
        if fast is None:
            assert len(got.velocity) == len(qp.velocity)
            continue
        fast_used += 1
        assert np.array_equal(got.velocity, fast.velocity)
        assert len(fast.velocity) <= len(qp.velocity)  # the optimum: never more periods than the QP
        v = np.vstack([[0.0, 0.0], fast.velocity]) @ M.T  # actuator velocities at the instants
        assert (np.abs(v) <= lim.vmax * (1 + 1e-9)).all()
        assert (np.abs(np.diff(v, axis=0)) / m.delta_time <= lim.amax * (1 + 1e-9)).all()
        if lim.pen_speed:
            assert (np.linalg.norm(fast.velocity, axis=1) <= lim.pen_speed * (1 + 1e-9)).all()
        x = fast.integrate()
        assert np.allclose(x[-1] * k, np.round(spline.end * k), atol=1e-6)  # lands on the end's whole step
        assert np.allclose(x[0] * k, np.round(spline.start * k))
        off = np.abs(x - spline(fast.sample_u))
        # each instant within the tracking tolerance or half a step less the written rounding of its aim;
        # the ends: the nearest whole step
        assert (off[1:-1] <= sampling.straight_bound(TRACKING_STEPS / k.max(), k, m.delta_time) + 1e-12).all()
        assert (off[[0, -1]] * k <= 0.5 + 1e-9).all()
        assert fast.velocity[-1].tolist() == [0.0, 0.0]
    assert fast_used >= 30  # most lines take the closed form


def test_a_curve_is_left_to_the_qp():
    m = load_machine("doodlebot")
    lim = Limits.from_machine(m, kinematics_for(m))
    k = np.array([80.0, 80.0])
    from doodlecam.geometry.fit import fit_pieces

    t = np.linspace(0, np.pi, 40)
    (spline, _), = fit_pieces(np.c_[50 + 20 * np.cos(t), 50 + 20 * np.sin(t)], 3, 0.1)
    stroke = Stroke(spline, plan_stroke(spline, lim))
    assert sampling.straight_samples(stroke, m.delta_time, lim, k, 0.005) is None


def _walk(n=200, seed=1):
    rng = np.random.default_rng(seed)
    return np.clip(140 + np.cumsum(rng.normal(0, 2, (n, 2)), axis=0) * [1, 0.6], [5, 5], [275, 175])


def test_slowing_a_stroke_always_ends_within_the_path_tolerance(monkeypatch):
    """Without any jerk re-plan the slowing alone must bring a wandering stroke within the
    tolerance (the default run never ends 'over the path tolerance')."""
    m = replace(load_machine("doodlebot"), path_tolerance=0.02)
    monkeypatch.setattr(stroke_plan, "REPLANS", 0)
    job = plan_job(Drawing(polylines=(_walk(),), units="mm"), m)
    assert job.meta["strokes_slowed_for_path"] >= 1  # the slowing did the work
    assert job.meta["max_between_samples_mm"] <= 0.02 + 1e-9
    from test_executed import _plc

    r = executed_ratios(_plc(job), job, m.path_tolerance)
    _check(r, m.path_tolerance)


def test_touching_segments_are_drawn_as_one_stroke_with_their_exact_length(tmp_path):
    svg = tmp_path / "grid.svg"
    svg.write_text(generated_svg(800, "grid"))
    res = convert(svg, tmp_path / "out", Settings(machine=load_machine("doodlebot"), layout={"scale": 1.0},
                                                   posts=("plc",)))
    s = res.summary()
    assert s["pen_lifts"] <= 45  # 800 segments on 40 lines of the grid (pen lifts, not segments)
    exact = 800 * min(270 / 20, 186 / 20)
    assert abs(s["pen_down_mm"] - exact) <= 1e-3 * exact


def test_ends_merged_a_hair_apart_at_a_corner_leave_no_stroke_of_no_length(tmp_path):
    # 100 000 generated paths once failed after 3 minutes on this: a path starting 1.7e-7 mm behind where
    # the previous one ends, at a corner; the merged ends' hair of a segment became a stroke of its own
    svg = tmp_path / "hair.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">'
                   '<path d="M10,10 L30,10" fill="none" stroke="black"/>'
                   '<path d="M29.99999983,10 L30,30" fill="none" stroke="black"/></svg>')
    res = convert(svg, tmp_path / "out", Settings(machine=load_machine("doodlebot"), layout={"scale": 1.0},
                                                   posts=("plc",)))
    s = res.summary()
    assert (s["strokes"], s["pen_lifts"]) == (2, 1)  # the two segments, drawn without lifting
    assert 20 < s["peak_memory_mb"] < 100_000  # reported: the process's own peak resident memory
    assert abs(s["pen_down_mm"] - 40.0) <= 1e-3


def test_a_degenerate_jerk_plan_is_replaced_by_a_bounded_one():
    """A 6 mm stroke of a generated drawing turning very tightly near its end over 264 control
    points: its first jerk-bounded plan took 1.5e5 s (and the sampler asked for 1 GB). It is planned
    within bounded time and still meets the path tolerance."""
    from pathlib import Path

    from doodlecam.model import Spline

    m = load_machine("doodlebot")
    control = np.loadtxt(Path(__file__).parent / "data" / "near_cusp_stroke.txt")
    spline = Spline(3, control)
    job = plan_job(Drawing(polylines=(spline(np.linspace(0, 1, 50)),), units="mm"), m,
                   fitted=[Stroke(spline, source_index=0)])
    least = stroke_plan._least_time(spline, Limits.from_machine(m, kinematics_for(m)))
    assert job.draw_time <= stroke_plan.ABSURD * least + 1.0 and job.draw_time < 10.0
    assert job.meta["max_between_samples_mm"] <= m.path_tolerance + 1e-9


def test_a_conversion_collects_garbage_rarely_and_restores_the_collector(tmp_path, monkeypatch):
    """convert raises the cyclic collector's thresholds while it runs (10^5 strokes' objects walked
    again by every full collection) and puts the caller's back, also when it fails."""
    import gc

    from doodlecam import pipeline
    from doodlecam.errors import InputError

    seen = []
    real = pipeline.trace
    monkeypatch.setattr(pipeline, "trace", lambda *a: seen.append(gc.get_threshold()) or real(*a))
    svg = tmp_path / "art.svg"
    svg.write_text(generated_svg(20, "mixed", seed=3))
    before = gc.get_threshold()
    convert(svg, tmp_path / "out", Settings(machine=load_machine("doodlebot")))
    assert seen == [pipeline.GC_THRESHOLDS] and gc.get_threshold() == before
    svg.write_text("<svg xmlns='http://www.w3.org/2000/svg' width='10mm' height='10mm'/>")
    with pytest.raises(InputError):
        convert(svg, tmp_path / "out2", Settings(machine=load_machine("doodlebot")))
    assert gc.get_threshold() == before


@pytest.mark.parametrize("enabled", [True, False])
def test_a_convert_leaves_the_garbage_collector_as_it_found_it(tmp_path, enabled):
    """The convert turns the collector off after the trace and collects rarely before: after it, ended or
    failed, the collector is on or off as it was, with the caller's thresholds."""
    import gc

    from doodlecam.errors import DoodleError

    svg = tmp_path / "art.svg"
    svg.write_text(generated_svg(20, "mixed", seed=3))
    was, thresholds = gc.isenabled(), gc.get_threshold()
    try:
        (gc.enable if enabled else gc.disable)()
        gc.set_threshold(700, 10, 10)
        _convert(tmp_path, svg, 1, "ok")
        assert gc.isenabled() == enabled and gc.get_threshold() == (700, 10, 10)
        m = load_machine("doodlebot")
        with pytest.raises(DoodleError):  # a drawing far outside the work area: refused after the trace
            convert(svg, tmp_path / "bad", Settings(machine=m, layout={"scale": 100.0}))
        assert gc.isenabled() == enabled and gc.get_threshold() == (700, 10, 10)
    finally:
        (gc.enable if was else gc.disable)()
        gc.set_threshold(*thresholds)


def test_each_outcome_carries_its_largest_deviation(tmp_path, monkeypatch):
    """plan_strokes' outcomes (closed-form lines and planned curves alike) carry deviation.max(initial=0)
    as worst_deviation, which the job reports as its largest distance between samples."""
    svg = tmp_path / "art.svg"
    svg.write_text(generated_svg(150, "mixed", seed=3))
    seen = []
    real = stroke_plan.plan_strokes
    monkeypatch.setattr(stroke_plan, "plan_strokes", lambda *a, **k: seen.extend(r := real(*a, **k)) or r)
    res, _ = _convert(tmp_path, svg, 1, "o")
    assert len(seen) == len(res.job.strokes) >= 150
    assert {o.replans == 0 and len(o.stroke.profile.u) <= 4 for o in seen} == {True, False}  # lines and curves
    for o in seen:
        assert o.worst_deviation == float(o.deviation.max(initial=0.0))
    assert res.job.meta["max_between_samples_mm"] == max(o.worst_deviation for o in seen) > 0


def test_outcome_of_is_the_dataclass_with_every_field():
    from dataclasses import fields

    values = [object() for _ in fields(stroke_plan.Outcome)]
    made, fast = stroke_plan.Outcome(*values), stroke_plan.Outcome.of(*values)
    assert [getattr(fast, f.name) for f in fields(fast)] == [getattr(made, f.name) for f in fields(made)] == values
    assert fast == made and vars(fast) == vars(made)
