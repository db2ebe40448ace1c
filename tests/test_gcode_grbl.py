"""The G-code post's output parsed back, for random strokes (tiny ones too) in both feed modes:
every chord within the tolerance of the spline, no F above the pen-speed cap, no segment shorter
than one motor step (GRBL drops those; a feed on one was the absurd F50226853.7)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_gcode_dialects import _dist_to_polyline, strict_parse, write
from test_grbl import emu_factory  # noqa: F401  (fixture)
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
    g0 = [x for x in text.splitlines() if x.startswith("G0 ")][0].split()  # where the pen goes down
    start = np.array([float(g0[1][1:]), float(g0[2][1:])])
    if not pts:  # a stroke within one motor step of its start: pen down and up only, a dot
        assert (np.round(spline.end * 80.0) == np.round(np.round(spline.start, 3) * 80.0)).all()
        return
    poly = np.vstack([start, pts])
    dense = spline(np.linspace(0.0, 1.0, 5_001))
    assert _dist_to_polyline(dense, poly).max() <= tol + 1e-6  # the curve never strays from the chords
    if feeds == "plan":
        assert _dist_to_polyline(poly, dense).max() <= 2e-3  # the vertices lie on the curve (3 decimals)
    else:  # cap: vertices on GRBL's step positions near the curve, the chords within the tolerance of it
        along = poly[:-1, None] + np.linspace(0.0, 1.0, 20)[:, None] * np.diff(poly, axis=0)[:, None]
        assert _dist_to_polyline(along.reshape(-1, 2), dense).max() <= tol + 1e-6
        steps = np.sign(poly) * np.floor(np.abs(poly) * 80.0 + 0.5) / 80.0  # as GRBL rounds the targets
        assert _dist_to_polyline(dense, steps).max() <= tol + 0.5 * np.sqrt(2) / 80.0 + 1e-6
    assert np.abs(np.diff(np.round(poly * 80.0), axis=0)).max(1).min(initial=1) >= 1  # a step or more each
    assert max(fs, default=0.0) <= 9000.0 and min(fs, default=1.0) > 0  # F never above the pen cap
    assert np.allclose(poly[[0, -1]], [spline.start, spline.end], atol=tol + 1e-6)  # its ends, within the tolerance


def test_a_stroke_within_one_step_writes_no_move():
    job = one_stroke_job(np.array([200.0, 150.0]) + np.random.default_rng(1).uniform(-0.002, 0.002, (5, 2)))
    for feeds in ("cap", "plan"):
        text = write(job, feeds=feeds)
        assert not [x for x in text.splitlines() if x.startswith("G1 ")]  # GRBL would drop it: no F for it
        assert "M3 S1000" in text.splitlines()  # the pen still goes down (a dot), as planned


def test_grbl_cuts_arcs_as_mc_arc_does():
    from doodlecam.link.grbl.timing import GrblSettings, arc_points, estimate_gcode

    # quarter circle r = 10: floor(0.5·(π/2)·10 / sqrt(0.002·(20 - 0.002))) = 39 lines, the last to the target
    p = arc_points((10.0, 0.0), (0.0, 10.0), (0.0, 0.0), clockwise=False)
    assert len(p) == 39 and np.allclose(p[-1], (0.0, 10.0))
    assert np.allclose(np.hypot(p[:, 0], p[:, 1]), 10.0)
    cw = arc_points((10.0, 0.0), (0.0, 10.0), (0.0, 0.0), clockwise=True)  # the long way round: 3/4 circle
    assert len(cw) == 117 and np.hypot(*(cw - (0.0, -10.0)).T).min() < 0.2 and cw[:, 0].min() < -9.9
    # a full circle when start and target meet; the estimate walks the same lines
    assert len(arc_points((10.0, 0.0), (10.0, 0.0), (0.0, 0.0), clockwise=True)) == 157
    s = GrblSettings((1e3,) * 3, (1000.0,) * 3, 0.01, idle_delay_ms=255)
    lines = "\n".join(f"G1 X{x:.6f} Y{y:.6f}" for x, y in p)
    assert estimate_gcode("G0 X10 Y0\nG3 X0 Y10 I-10 J0 F600\n", s).total == pytest.approx(
        estimate_gcode(f"G0 X10 Y0\nG1 F600\n{lines}\n", s).total, rel=1e-6)


def test_arcs_option_writes_arcs_within_tolerance_that_grbl_accepts(emu_factory, tmp_path):
    from test_grbl import bounded

    from doodlecam.link.grbl.streamer import send_gcode
    from doodlecam.link.grbl.timing import arc_points

    ang = np.linspace(0.0, 1.5 * np.pi, 40)
    job = one_stroke_job(np.c_[200.0 + 20.0 * np.cos(ang), 150.0 + 20.0 * np.sin(ang)])  # a near-circle, r ≈ 20
    spline = job.strokes[0].spline
    # At 115200 baud chords a quarter of the tolerance apart run as fast as arcs (GRBL cuts those into
    # 0.002 mm chords anyway): no arc pays. At 9600 baud only the coarsest chords can be fed, and they
    # turn 8° at each junction; one arc line then runs faster.
    assert "G3 " not in write(job, arcs=True) and "G3 " not in write(job)
    text = write(job, arcs=True, baud=9600)
    assert "G3 " in text and "G3 " not in write(job, baud=9600)  # only when asked
    # the path GRBL executes: arcs cut as mc_arc cuts them, lines as they are
    pos, path = None, []
    for line in text.splitlines():
        g = line.split()[0]
        w = dict((x[0], float(x[1:])) for x in line.split()[1:]) if g in ("G0", "G1", "G2", "G3") else {}
        if g == "G0":
            pos = np.array([w["X"], w["Y"]])
            path = [pos]
        elif g in ("G2", "G3"):
            path.extend(arc_points(pos, (w["X"], w["Y"]), pos + (w["I"], w["J"]), g == "G2"))
            pos = np.array([w["X"], w["Y"]])
        elif g == "G1":
            pos = np.array([w["X"], w["Y"]])
            path.append(pos)
        if line == "M3 S0" and len(path) > 1:
            break
    path = np.array(path)
    dense = spline(np.linspace(0.0, 1.0, 4001))
    assert _dist_to_polyline(dense, path).max() <= 0.05 + 1e-6
    assert _dist_to_polyline(path, dense).max() <= 0.05 + 1e-6
    emu = emu_factory(speed=100.0)
    job_file = tmp_path / "arcs.gcode"
    job_file.write_text(text)
    r = bounded(lambda: send_gcode(emu.port, job_file, state_file=None))
    assert r["lines"] == len([x for x in text.splitlines() if not x.startswith(";")])
    assert emu.pos[:2] == [0.0, 0.0] and any(x.startswith("G3") for x in emu.received)


def test_strokes_that_meet_are_drawn_through_their_shared_point_within_the_tolerance():
    """Pen down across two strokes that meet (a split outline): the chords run from one into the other with no
    point skipped, every chord within the tolerance of the two curves, though the vertices sit on GRBL's steps."""
    t = np.linspace(0.0, 30.0, 61)
    a = Spline(3, np.c_[100.0 + t, 80.0 + 5.0 * np.sin(t / 4.0) + 0.05 * np.sin(3.1 * t)])
    b = Spline(3, np.c_[a.end[0] + 0.4 * t, a.end[1] + t + 0.05 * np.sin(2.3 * t)])  # from where a ends
    pa, pb = trapezoid_profile(a), trapezoid_profile(b)
    travels = (Travel(start=np.zeros(2), end=a.start, duration=1.0), Travel(start=a.end, end=b.start, duration=0.0),
               Travel(start=b.end, end=np.zeros(2), duration=1.0))
    job = Job(machine=M, strokes=(Stroke(spline=a, profile=pa), Stroke(spline=b, profile=pb)), travels=travels,
              samples=(samples_for(a, pa, M.delta_time), samples_for(b, pb, M.delta_time)), source="two")
    assert job.lifts == (True, False)
    text = write(job)
    assert text.count("M3 S1000") == 1
    moves = [x.split() for x in text.splitlines() if x.startswith(("G0 X", "G1 X"))][:-1]  # the last: home
    poly = np.array([[float(w[1][1:]), float(w[2][1:])] for w in moves])
    dense = np.vstack([a(np.linspace(0.0, 1.0, 4001)), b(np.linspace(0.0, 1.0, 4001))])
    assert _dist_to_polyline(dense, poly).max() <= 0.05 + 1e-6  # both curves near the chords, the joint too
    along = poly[:-1, None] + np.linspace(0.0, 1.0, 20)[:, None] * np.diff(poly, axis=0)[:, None]
    assert _dist_to_polyline(along.reshape(-1, 2), dense).max() <= 0.05 + 1e-6
    # the shared point: a vertex on its nearest step, where one stroke ends and the other starts
    assert np.abs(poly - np.round(a.end * 80.0) / 80.0).max(1).min() <= 1e-3


def test_chords_at_a_kept_corner_lean_towards_the_next_piece_and_grbl_passes_it_faster(monkeypatch):
    """Where the pen passes a corner without lifting (two pieces of one traced line), each piece's end chords are
    snapped with the junction into the other piece costed: GRBL's model runs the job faster than with the
    corner treated as a stop, the pen still passes the corner's step and every chord stays within the tolerance
    of the curves."""
    import doodlecam.postprocessors.gcode as post
    from doodlecam.link.grbl.timing import GrblSettings, estimate_gcode

    jobs = []
    for turn in (25.0, 40.0, 70.0):
        t = np.linspace(0.0, 20.0, 41)
        a = Spline(3, np.c_[60.0 + t, 80.0 + 2.0 * np.sin(t / 5.0)])
        h = np.radians(turn) + np.arctan2(*a(np.array([1.0]), 1)[0][::-1])
        b = Spline(3, a.end + np.c_[np.cos(h) * t, np.sin(h) * t] + np.c_[np.zeros_like(t), 0.3 * np.sin(t / 4.0)])
        pa, pb = trapezoid_profile(a), trapezoid_profile(b)
        travels = (Travel(start=np.zeros(2), end=a.start, duration=1.0), Travel(start=a.end, end=b.start, duration=0.0),
                   Travel(start=b.end, end=np.zeros(2), duration=1.0))
        jobs.append(Job(machine=M, strokes=(Stroke(spline=a, profile=pa), Stroke(spline=b, profile=pb)),
                        travels=travels, samples=(samples_for(a, pa, M.delta_time), samples_for(b, pb, M.delta_time)),
                        source="corner"))
    settings = GrblSettings.from_machine(M, 0.01, 25)
    leaning = [write(job) for job in jobs]
    with monkeypatch.context() as mp:
        mp.setattr(post, "_pass_through", lambda strokes, which, lifts: (np.zeros((len(which), 2)),) * 2)
        stopping = [write(job) for job in jobs]
    lean_t = sum(estimate_gcode(text, settings).total for text in leaning)
    stop_t = sum(estimate_gcode(text, settings).total for text in stopping)
    assert leaning != stopping and lean_t < stop_t, (lean_t, stop_t)
    for job, text in zip(jobs, leaning):
        a, b = (s.spline for s in job.strokes)
        moves = [x.split() for x in text.splitlines() if x.startswith(("G0 X", "G1 X"))][:-1]
        poly = np.array([[float(w[1][1:]), float(w[2][1:])] for w in moves])
        dense = np.vstack([a(np.linspace(0.0, 1.0, 4001)), b(np.linspace(0.0, 1.0, 4001))])
        along = poly[:-1, None] + np.linspace(0.0, 1.0, 20)[:, None] * np.diff(poly, axis=0)[:, None]
        assert _dist_to_polyline(along.reshape(-1, 2), dense).max() <= 0.05 + 1e-6
        assert _dist_to_polyline(dense, poly).max() <= 0.05 + 1e-6
        assert np.abs(poly - np.round(a.end * 80.0) / 80.0).max(1).min() <= 1e-3  # through the corner's step
