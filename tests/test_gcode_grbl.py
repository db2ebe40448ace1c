"""The G-code post's output parsed back, for random strokes (tiny ones too) in both feed modes:
every chord within the tolerance of the spline, no F above the pen-speed cap, no segment shorter
than one motor step (GRBL drops those; a feed on one was the absurd F50226853.7)."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_gcode_dialects import _dist_to_polyline, strict_parse, write
from test_posts import MACHINE, samples_for, trapezoid_profile

from doodlecam.machine import parse_machine
from doodlecam.model import Job, Spline, Stroke, Travel

M = parse_machine(MACHINE, "test.toml")


def one_stroke_job(ctrl: np.ndarray) -> Job:
    s = Spline(3, ctrl)
    p = trapezoid_profile(s)
    travels = (Travel(start=np.zeros(2), end=s.start, duration=1.0), Travel(start=s.end, end=np.zeros(2), duration=1.0))
    return Job(machine=M, strokes=(Stroke(spline=s, profile=p),), travels=travels,
               samples=(samples_for(s, p, M.delta_time),), source="random")


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(size=st.sampled_from([0.004, 0.02, 0.3, 5.0, 120.0]), n=st.integers(4, 9), seed=st.integers(0, 10_000),
       tol=st.sampled_from([0.01, 0.05, 0.2]), feeds=st.sampled_from(["cap", "plan"]))
def test_output_parsed_back_keeps_tolerance_cap_and_steps(size, n, seed, tol, feeds):
    rng = np.random.default_rng(seed)
    ctrl = np.array([200.0, 150.0]) + rng.uniform(-size, size, (n, 2))
    job = one_stroke_job(ctrl)
    text = write(job, feeds=feeds, chord_tolerance=tol)
    (pts, fs), = strict_parse(text, "grbl", "M3 S0", "M3 S1000", "G4 P0.15")
    spline = job.strokes[0].spline
    if not pts:  # a stroke within one motor step of its start: pen down and up only, a dot
        assert (np.round(spline.end * 80.0) == np.round(np.round(spline.start, 3) * 80.0)).all()
        return
    poly = np.vstack([np.round(spline.start, 3), pts])
    dense = spline(np.linspace(0.0, 1.0, 5_001))
    assert _dist_to_polyline(dense, poly).max() <= tol + 1e-6  # the curve never strays from the chords
    assert _dist_to_polyline(poly, dense).max() <= 2e-3  # the vertices lie on the curve (3 decimals)
    assert np.abs(np.diff(np.round(poly * 80.0), axis=0)).max(1).min(initial=1) >= 1  # a step or more each
    assert max(fs, default=0.0) <= 9000.0 and min(fs, default=1.0) > 0  # F never above the pen cap
    assert np.allclose(poly[-1], spline.end, atol=6e-4)  # ends where the stroke ends


def test_a_stroke_within_one_step_writes_no_move():
    job = one_stroke_job(np.array([200.0, 150.0]) + np.random.default_rng(1).uniform(-0.002, 0.002, (5, 2)))
    for feeds in ("cap", "plan"):
        text = write(job, feeds=feeds)
        assert not [x for x in text.splitlines() if x.startswith("G1 ")]  # GRBL would drop it: no F for it
        assert "M3 S1000" in text.splitlines()  # the pen still goes down (a dot), as planned
