"""The posts format and compute many strokes per call (SVG paths, PLC DRAW targets, G-code lines, the GRBL
estimate's runs, the snapping's junction costs); each batched path must give exactly, to the bit, what the
per-stroke code gives. The references here are that per-stroke code."""

from __future__ import annotations

import numpy as np
import pytest
from test_posts import MACHINE, samples_for, trapezoid_profile

from doodlecam.errors import InputError
from doodlecam.geometry.chords import _junction_cost, _junction_row, _sqrt_reaches
from doodlecam.geometry.spline_batch import eval_many
from doodlecam.link.grbl.timing import GrblSettings, estimate_program
from doodlecam.link.plc.packetfile import (DRAW, MOVE, PAUSE, RECORD_DTYPE, _whole_step_runs, commands_array,
                                           whole_step_targets)
from doodlecam.machine import parse_machine
from doodlecam.model import Job, Spline, Stroke, Travel
from doodlecam.postprocessors import gcode
from doodlecam.postprocessors.svg import SvgPost, _path_d, _segments_d

M = parse_machine(MACHINE, "test.toml")


def random_splines(n, seed, degrees=(3,)):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        k = int(rng.choice(degrees))
        m = int(rng.integers(k + 1, k + 12))
        out.append(Spline(k, rng.uniform(-50, 250, 2) + np.cumsum(rng.uniform(-20, 20, (m, 2)), axis=0)))
    return out


def test_splines_evaluated_together_equal_each_one_evaluated_alone():
    splines = random_splines(40, 1, degrees=(1, 2, 3, 5))
    rng = np.random.default_rng(2)
    us = [np.r_[rng.uniform(-0.1, 1.1, int(rng.integers(0, 9))), s.breakpoints] for s in splines]
    # the derivative controls of splines of one shape are made together: many shapes repeat here
    assert len({(len(s.control), s.degree) for s in splines}) < len(splines)
    forgot = [Spline(s.degree, s.control) for s in splines[::2]]  # as a planned job's: made on demand
    for s in forgot:
        s.forget_derivatives()
    for der in (0, 1):
        want = np.concatenate([s(u, der) for s, u in zip(splines, us)])
        got = eval_many(splines, us, der)
        assert np.array_equal(got, want)  # bit for bit: the same kernel arithmetic
        u, off = np.concatenate(us), np.cumsum([0] + [len(u) for u in us])
        assert np.array_equal(eval_many(splines, (u, off), der), want)  # the parameters given concatenated
        assert np.array_equal(eval_many(forgot, us[::2], der), np.concatenate([s(u, der) for s, u in zip(forgot, us[::2])]))
    high = [s for s in splines if s.degree >= 2]
    assert np.array_equal(eval_many(high, [s.breakpoints for s in high], 2),
                          np.concatenate([s(s.breakpoints, 2) for s in high]))
    assert eval_many([], [], 0).shape == (0, 2)


def test_svg_paths_written_together_equal_each_one_written_alone():
    post = SvgPost()
    flip = np.array([1.0, -1.0]), np.array([0.0, 297.0])
    splines = random_splines(60, 3, degrees=(3, 3, 3, 2))
    splines.append(Spline(3, [[0.0004, -0.0004], [0.0, 0.0], [-0.0004, 0.0003], [0.0, 0.0]]))  # prints -0.000
    assert post._strokes_d(splines, 0.2, flip) == [post._stroke_d(s, 0.2, flip) for s in splines]
    a, b = np.random.default_rng(4).uniform(-10, 300, (2, 30, 2))
    a[0] = (-0.0001, 0.0)
    assert _segments_d(a, b) == [_path_d(np.array([x, y])) for x, y in zip(a, b)]
    assert _segments_d(np.zeros((0, 2)), np.zeros((0, 2))) == []


def test_draw_targets_of_all_strokes_equal_each_stroke_alone():
    rng = np.random.default_rng(5)
    vel = [rng.normal(0, 40, (int(rng.integers(1, 50)), 2)) for _ in range(30)]
    vel[3][0] = (-0.0, 0.0)
    spm = np.array([80.0, 80.0])
    off = np.concatenate([[0], np.cumsum([len(v) for v in vel])]).astype(np.int64)
    got = _whole_step_runs(np.concatenate(vel), spm, off)

    def numpy_targets(v):  # the rounded running sum's differences, as NumPy computes them
        return np.diff(np.vstack([np.zeros((1, 2)), np.round(np.cumsum(v * spm, axis=0))]), axis=0)

    want = [numpy_targets(v) for v in vel]
    assert np.array_equal(got, np.concatenate(want))
    for v, w in zip(vel, want):  # one stroke at a time (the planner's checks), also read-only and empty
        v.setflags(write=False)
        assert np.array_equal(whole_step_targets(v, spm), w) and whole_step_targets(v, list(spm)).dtype == float
    assert whole_step_targets(np.zeros((0, 2)), spm).shape == (0, 2)


def reference_commands(job):
    """The PLC commands one stroke at a time (the loop commands_array replaced)."""
    spm = np.array([M.x.steps_per_mm, M.y.steps_per_mm])
    changes = set(job.pen_pauses)
    pens = job.pen_numbers if changes else ()
    rows = []
    for k, (s, lift) in enumerate(zip(job.samples, job.lifts)):
        if k in changes and pens[k]:
            rows.append((PAUSE, pens[k], 0))
        if lift:
            rows.append((MOVE, *np.round(np.asarray(s.start) * spm)))
        rows += [(DRAW, x, y) for x, y in whole_step_targets(s.velocity, spm)]
    rows.append((MOVE, *np.round(np.asarray(job.travels[-1].end) * spm)))
    out = np.zeros(len(rows), RECORD_DTYPE)
    out["command_no"] = np.arange(1, len(rows) + 1)
    out["type"] = [r[0] for r in rows]
    out["x"], out["y"] = [r[1] for r in rows], [r[2] for r in rows]
    return out


def test_plc_commands_placed_together_equal_the_per_stroke_commands():
    """Strokes that go on from the last one's end (no MOVE), a pen change between layers (a PAUSE)."""
    a = Spline(3, [[50, 50], [80, 120], [140, -10], [180, 90]])
    b = Spline(3, [[180, 90], [200, 100], [220, 60], [230, 70]])  # starts where a ends: the pen stays down
    c = Spline(3, [[20, 20], [40, 30], [60, 10], [70, 40]])
    strokes, samples = [], []
    for s, layer in ((a, "ink"), (b, "ink"), (c, "red"), (a, "red")):
        p = trapezoid_profile(s)
        strokes.append(Stroke(spline=s, profile=p, layer=layer))
        samples.append(samples_for(s, p, M.delta_time))
    ends = [np.asarray(M.home, float), a.start, a.end, b.start, b.end, c.start, c.end, a.start, a.end,
            np.asarray(M.home, float)]
    travels = tuple(Travel(start=ends[2 * i], end=ends[2 * i + 1], duration=1.0) for i in range(5))
    job = Job(machine=M, strokes=tuple(strokes), travels=travels, samples=tuple(samples), source="t")
    assert job.lifts == (True, False, True, True) and job.pen_changes == (2,)
    _, got = commands_array(job)
    assert np.array_equal(got, reference_commands(job))
    assert (got["type"] == PAUSE).sum() == 1


def as_items(xy, fw):
    """A "G1*" run as the G1 items it stands for."""
    return [("G1", float(x), float(y), None, None if np.isnan(f) else float(f)) for (x, y), f in zip(xy, fw)]


def test_estimate_runs_time_as_their_single_moves():
    """Runs between rapids, dwells and pen commands, with F words on some blocks only: the modal feed carries
    into a run without one and out of a run into the moves after it."""
    rng = np.random.default_rng(7)
    prog, flat = [], []
    for k in range(25):
        x0 = rng.uniform(0, 200, 2)
        xy = x0 + np.cumsum(rng.uniform(-2, 2, (int(rng.integers(1, 30)), 2)), axis=0).round(3)
        fw = np.full(len(xy), np.nan)
        if k == 0 or rng.integers(3):
            fw[0] = float(rng.choice([1200.0, 3000.0, 9000.0]))
        if len(xy) > 1:
            fw[rng.integers(1, len(xy))] = 2400.0  # a feed change inside the run
        head = [("G0", *x0.tolist(), None, None), ("M", "M3 S1000"), ("G4", 0.1)]
        tail = [("G1", float(x0[0]), float(x0[1]), None, None)] if k % 4 == 1 else []  # the modal feed after a run
        tail += [("M", "M3 S0")]
        prog += head + [("G1*", xy, fw)] + tail
        flat += head + as_items(xy, fw) + tail
    s = GrblSettings.from_machine(M, 0.01, 25)
    got, want = estimate_program(prog, s), estimate_program(flat, s)
    assert np.array_equal(got.block_times, want.block_times)
    assert (got.total, got.stops, got.blocks) == (want.total, want.stops, want.blocks)
    with pytest.raises(InputError, match="feed rate"):
        estimate_program([("G1*", np.zeros((2, 2)), np.full(2, np.nan))], s)


def test_g1_lines_of_all_strokes_equal_each_stroke_written_alone(monkeypatch):
    """Feeds that change inside a stroke (feeds = plan) or not (cap), feeds that print alike, a stroke without
    blocks, a stroke with arcs (written by the writer's own loop)."""
    rng = np.random.default_rng(8)
    paths = []
    for k in range(20):
        p = np.round(rng.uniform(0, 200, (int(rng.integers(1, 12)), 2)), 3)
        f = np.full(len(p) - 1, 3000.0) if k % 2 else rng.choice([0.0, 1200.04, 1200.01, 2999.96], len(p) - 1)
        paths.append((p, f, {0: ((1.0, 1.0), True)} if k == 5 else {}))
    monkeypatch.setattr(gcode, "G1_CHUNK", 3)  # strokes formatted a few at a time, as 10^5 are
    got = gcode._g1_text(paths, gcode._num)
    for n, (p, feed, arc) in enumerate(paths):
        if arc or not len(feed):
            assert n not in got
            continue
        lines, fws, last = [], [], ""
        for (x, y), f in zip(p[1:].tolist(), feed.tolist()):  # the writer's per-line loop
            fs = gcode._num(max(f, 0.1), 1)
            lines.append(f"G1 X{gcode._num(x)} Y{gcode._num(y)}" + (f" F{fs}" if fs != last else ""))
            fws.append(float(fs) if fs != last else np.nan)
            last = fs
        assert got[n][0] == "\n".join(lines)
        assert np.array_equal(got[n][1], fws, equal_nan=True)


@pytest.mark.parametrize("acc", [(2000.0, 2000.0), (2000.0, 800.0)])
def test_batched_junction_costs_equal_the_junction_cost(acc):
    """A row of junctions (one incoming direction against many outgoing ones, in vector instructions) equals
    the scalar junction cost to the bit on every branch: straight on, reversals, fast and slow junctions,
    axis-aligned junction vectors (a zero component), both when the axes' accelerations are equal and when not."""
    rng = np.random.default_rng(9)
    ang = np.r_[rng.uniform(-np.pi, np.pi, 400), 0.0, 0.0, np.pi, 1e-4, -1e-4, np.pi / 2, np.pi - 1e-4]
    base = np.r_[rng.uniform(-np.pi, np.pi, 400), 0.0, np.pi / 4, 0.0, 0.3, 0.3, 0.0, 0.0]
    u = np.c_[np.cos(base), np.sin(base)]
    w = np.c_[np.cos(base + ang), np.sin(base + ang)]
    wx, wy = w[:, 0].copy(), w[:, 1].copy()
    for v in (150.0, 20.0):
        v2 = _sqrt_reaches(v)
        out = np.empty(len(w))
        got, want = [], []
        for k in list(range(0, len(u), 23)) + list(range(400, len(u))):  # the special cases' rows too
            _junction_row(u[k, 0], u[k, 1], wx, wy, len(w), v, v2, *acc, 0.01, out)
            got.append(out.copy())
            want.append([_junction_cost(u[k, 0], u[k, 1], b[0], b[1], v, v2, *acc, 0.01) for b in w])
            # the pairs the special cases were built as (straight on, reversal, ...)
            assert out[k] == _junction_cost(u[k, 0], u[k, 1], w[k, 0], w[k, 1], v, v2, *acc, 0.01)
        assert np.array_equal(np.array(got), np.array(want))
        assert (np.array(got) == 0).any() and (np.array(got) > 0).any()


def test_dense_points_of_all_strokes_equal_each_stroke_refined_alone():
    """The compiled refinement (each point evaluated once, its value carried to the next round) against the
    NumPy one (postprocessors.gcode._refine, every segment's ends evaluated again each round)."""
    strokes = [Stroke(spline=s, profile=None) for s in random_splines(40, 11, degrees=(2, 3, 3))]
    tol = 0.05
    q, off, fine = gcode.GcodePost._dense(strokes, tol)
    for k, st in enumerate(strokes):
        u0 = np.linspace(0.0, 1.0, max(int(np.ceil(st.spline.length / 0.5)) + 1, 9))
        assert np.array_equal(q[off[k]:off[k + 1]], st.spline(gcode._refine(st.spline, u0, fine))), k


def test_linspaces_together_equal_numpys_linspace_of_each():
    n = np.r_[2, 3, 9, 10, 11, 17, 49, np.random.default_rng(5).integers(2, 3000, 200)]
    u, off = gcode._linspaces(n)
    for k, m in enumerate(n):
        assert np.array_equal(u[off[k]:off[k + 1]], np.linspace(0.0, 1.0, m)), m


def test_numbers_formatted_together_equal_each_one_formatted_alone():
    rng = np.random.default_rng(6)
    v = np.r_[0.0, -0.0, 0.0004, -0.0004, 0.0005, -0.0005, 1.0, -1.0, 10.0, 100.5, 123.45, -123.4, 1e20, -1e-20,
              np.nan, np.inf, -np.inf, 0.1, 0.01, 0.001, np.round(rng.uniform(-500, 500, 3000), 3),
              rng.uniform(-500, 500, 3000), rng.integers(-1000, 1000, 300) / 8.0]
    assert gcode._nums(v) == [gcode._num(x) for x in v.tolist()]
    assert gcode._nums(np.zeros(0)) == []
