"""The G-code post's chord search (feeds = cap) runs over all strokes at once in compiled kernels
(doodlecam.geometry.chord_batch); it must write exactly what the search one stroke at a time wrote. The
reference below is that per-stroke search: NumPy dense points (_refine), one greedy + snap call per stroke and
level, GRBL's dropped blocks and the serial check in Python, the level walk as a generator."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from test_posts import MACHINE, trapezoid_profile

import doodlecam.postprocessors.gcode as post
from doodlecam.geometry.chords import _junction_cost, _sqrt_reaches, greedy_chords, snap_chords
from doodlecam.link.grbl.timing import GrblSettings, _segment_time
from doodlecam.machine import parse_machine
from doodlecam.model import Spline, Stroke

M = parse_machine(MACHINE, "test.toml")
SPM = np.array([M.x.steps_per_mm, M.y.steps_per_mm])


def tangent(stroke, u):
    d = stroke.spline(np.array([u]), 1)[0]
    return d / np.hypot(*d)


def reference_search(stroke, tol, feed, grbl, t_in=np.zeros(2), t_out=np.zeros(2)):
    """One stroke's search as a generator: yields candidates, is sent each one's time (inf: unusable)."""
    u = post._refine(stroke.spline, np.linspace(0.0, 1.0, max(int(np.ceil(stroke.spline.length / 0.5)) + 1, 9)),
                     0.02 * tol)
    q = np.ascontiguousarray(stroke.spline(u))
    rooms, r0, start = post.GcodePost._cap_levels(tol, SPM)
    acc = np.asarray(grbl.acceleration, float)

    def candidate(k):
        idx = greedy_chords(q, rooms[k])
        near = np.round(q[idx], 3)
        if (np.round(near * SPM) == np.round(near[0] * SPM)).all():
            return near
        p, found = snap_chords(q, idx, r0, SPM[0], SPM[1], feed / 60.0, acc[0], acc[1], grbl.junction_deviation,
                               t_in, t_out)
        return p if found else near

    best = yield candidate(start)
    k = start
    while best < np.inf and k + 1 < len(rooms):
        t = yield candidate(k + 1)
        if not t < best:
            break
        best, k = t, k + 1
    if k == start:
        while k > 0:
            t = yield candidate(k - 1)
            if best < np.inf and not t < best:
                break
            best, k = t, k - 1


def reference_paths(strokes, feeds, tol, grbl, baud, lifts):
    """Every curved stroke's chosen points: each round, every search's next candidate, made one stroke at a time,
    all timed in one call of GRBL's model (each from rest to rest, as the pen commands make them); where the pen
    goes on into the next stroke or comes from the last one, the ends snapped towards its tangent."""
    n = len(strokes)
    searches = {i: reference_search(st, tol, feeds[i], grbl,
                                    tangent(strokes[i - 1], 1.0) if i > 0 and not lifts[i] else np.zeros(2),
                                    tangent(strokes[i + 1], 0.0) if i + 1 < n and not lifts[i + 1] else np.zeros(2))
                for i, st in enumerate(strokes) if not st.spline.straight}
    sent, best = dict.fromkeys(searches), {}
    while sent:
        cand = []
        for i, t in sent.items():
            try:
                p = searches[i].send(t)
            except StopIteration:
                continue
            cand.append((i, p[post._one_step_apart(p, SPM)]))
        moving = [(i, p) for i, p in cand if len(p) > 1]
        bt, start = np.zeros(0), {}
        if moving:
            pts = np.concatenate([p for _, p in moving])
            n = np.array([len(p) for _, p in moving])
            first = np.concatenate([[0], np.cumsum(n)[:-1]])
            rest = np.zeros(len(pts) - 1, bool)
            rest[first] = True
            rest[first[1:] - 1] = True
            feed = np.repeat([feeds[i] / 60.0 for i, _ in moving], n)[:-1]
            bt = _segment_time(np.c_[pts, np.zeros(len(pts))], feed, grbl, rest)
            start = dict(zip((i for i, _ in moving), first))
        sent = {}
        for i, p in cand:
            times = bt[start[i]:start[i] + len(p) - 1] if i in start else np.zeros(0)
            usable = post._serial_keeps_up(p, times, baud)
            key = (0, float(times.sum())) if usable else (1, len(p))
            if i not in best or key < best[i][1]:
                best[i] = (p, key)
            sent[i] = float(times.sum()) if usable else np.inf
    return {i: p for i, (p, _) in best.items()}


def random_strokes(n, seed):
    """Curves of every size (a dot within one step to 100 mm), straight lines, closed loops."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        size = rng.choice([0.004, 0.05, 0.5, 3.0, 20.0, 100.0])
        kind = rng.integers(4)
        if kind == 0:  # a line: control points evenly along it
            a, b = rng.uniform(20, 180, 2), rng.uniform(-1, 1, 2) * size
            ctrl = a + np.linspace(0, 1, 4)[:, None] * b
        elif kind == 1:  # a loop
            t = np.linspace(0, 2 * np.pi, int(rng.integers(6, 14)))
            ctrl = rng.uniform(20, 180, 2) + size * np.c_[np.cos(t), np.sin(t)]
        else:
            ctrl = rng.uniform(20, 180, 2) + rng.uniform(-size, size, (int(rng.integers(4, 12)), 2))
        s = Spline(3, ctrl)
        out.append(Stroke(spline=s, profile=trapezoid_profile(s, n=20)))
    return out


@pytest.mark.parametrize("tol, baud, seed, joined", [(0.05, 115200, 1, False), (0.02, 115200, 2, False),
                                                     (0.2, 9600, 3, False), (0.05, 0, 4, False), (0.05, 115200, 5, True)])
def test_batched_chord_search_writes_what_the_per_stroke_search_wrote(tol, baud, seed, joined):
    strokes = random_strokes(60, seed)
    feeds = [3000.0 if i % 3 else 1200.0 for i in range(len(strokes))]  # two pens: two feeds
    grbl = GrblSettings.from_machine(M, 0.01, 25)
    # joined: the pen goes on without lifting from some strokes into the next (the hints need only the tangents)
    lifts = tuple(i == 0 or not joined or bool(np.random.default_rng(seed + i).integers(2)) for i in range(60))
    batched = post.GcodePost()._cap_paths(strokes, feeds, tol, M, grbl, baud, lifts)
    reference = reference_paths(strokes, feeds, tol, grbl, baud, lifts)
    assert len(reference) > 30  # most are curves
    for i, p in reference.items():
        assert np.array_equal(batched[i][0], p), i
        assert np.array_equal(batched[i][1], np.full(len(p) - 1, feeds[i]))


def _dist_to_segment(p, a, b):
    d = b - a
    s = np.clip(((p - a) @ d) / (d @ d), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * d), axis=1)


def path_cost(pts, v, acc, dev, t_in=(0.0, 0.0), t_out=(0.0, 0.0)):
    """The snapping's objective for chosen points (printed, as snap_chords returns them): the sum of the
    junction costs of GRBL's step-rounded chords, and of the junctions into and out of them where the pen
    arrives or leaves moving (t_in, t_out non-zero)."""
    x = np.sign(pts * SPM) * np.floor(np.abs(pts * SPM) + 0.5) / SPM
    d = np.diff(x, axis=0)
    u = list(d / np.linalg.norm(d, axis=1)[:, None])
    u = ([np.asarray(t_in)] if any(t_in) else []) + u + ([np.asarray(t_out)] if any(t_out) else [])
    v2 = _sqrt_reaches(v)
    return sum(_junction_cost(a[0], a[1], b[0], b[1], v, v2, acc, acc, dev) for a, b in zip(u[:-1], u[1:]))


@pytest.mark.parametrize("seed, t_in, t_out", [(s, (0.0, 0.0), (0.0, 0.0)) for s in range(4)]
                         + [(4, (0.6, 0.8), (0.0, 0.0)), (5, (0.0, 0.0), (-0.28, 0.96)), (6, (0.8, -0.6), (0.0, 1.0))])
def test_snapping_finds_the_cheapest_choice_of_steps(seed, t_in, t_out):
    """The dynamic programme (which skips predecessors that cannot win) against every choice of the step
    positions of the inner vertices of a short curve: the same least cost, with the junctions into and out of
    the piece where the pen passes its ends without stopping (a kept corner: there the vertex next to the end
    chooses among positions 2 steps apart)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, 400)
    bend = rng.uniform(0.5, 3.0)
    q = np.ascontiguousarray(np.c_[50 + 3 * t, 50 + bend * np.sin(2.5 * t) + 0.002 * rng.standard_normal(len(t))])
    idx = greedy_chords(q, 0.01)[:5]  # 3 inner vertices: 9^3 choices
    room, v, acc, dev = 0.045, 150.0, 2000.0, 0.01
    pts, found = snap_chords(q, idx, room, SPM[0], SPM[1], v, acc, acc, dev, np.array(t_in), np.array(t_out))
    assert found
    assert np.array_equal(pts[[0, -1]], np.round(np.floor(q[idx[[0, -1]]] * SPM + 0.5) / SPM, 3))  # ends: nearest
    stride = np.ones(len(idx), int)
    stride[1] = 2 if any(t_in) else 1
    stride[-2] = 2 if any(t_out) else 1
    best = np.inf
    near = np.floor(q[idx] * SPM + 0.5)
    for choice in itertools.product(range(9), repeat=len(idx) - 2):
        steps = near.copy()
        for k, c in enumerate(choice, 1):
            steps[k] += (stride[k] * (c // 3 - 1), stride[k] * (c % 3 - 1))
        cand = np.round(steps / SPM, 3)
        x = np.floor(cand * SPM + 0.5) / SPM
        if (np.linalg.norm(x - q[idx], axis=1) > room).any() or (np.diff(x, axis=0) == 0).all(1).any():
            continue
        covered = all(_dist_to_segment(q[idx[k]:idx[k + 1] + 1], x[k], x[k + 1]).max() <= room
                      for k in range(len(idx) - 1))
        if covered:
            best = min(best, path_cost(cand, v, acc, dev, t_in, t_out))
    assert path_cost(pts, v, acc, dev, t_in, t_out) == pytest.approx(best, rel=1e-12, abs=0.0)
