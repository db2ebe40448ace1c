"""The compiled pieces of the ordering: grid greedy, k nearest, kicks, loop rotation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from doodlecam.geometry.order import order_strokes
from doodlecam.geometry.order import nearest_k
from doodlecam.geometry.order_search import greedy, local_search, perturb, rotate_loops, tour_cost


def _strokes(rng, n, loops=0.3, grid=None):
    polys = []
    for _ in range(n):
        p = rng.uniform(0, 50, (int(rng.integers(2, 7)), 2))
        if grid:  # coarse coordinates: many ties and coincident points
            p = np.round(p / grid) * grid
        if rng.random() < loops and len(p) >= 3:
            p = np.vstack([p, p[:1]])
        polys.append(p)
    return polys


def _arrays(polys):
    n = len(polys)
    starts = np.array([p[0] for p in polys])
    ends = np.array([p[-1] for p in polys])
    lens = np.array([len(p) for p in polys])
    closed = (lens >= 4) & (starts == ends).all(axis=1)
    ring_off = np.zeros(n + 1, np.int64)
    np.cumsum(np.where(closed, lens - 1, 0), out=ring_off[1:])
    rings = [polys[i][:-1] for i in np.flatnonzero(closed)]
    ring_pts = np.concatenate(rings) if rings else np.zeros((0, 2))
    return starts, ends, closed, ring_pts, ring_off


def _ways_in(s, starts, ends, closed, ring_pts, ring_off, reverse):
    """(entry point, exit point, kind) of every way into stroke s."""
    if closed[s]:
        return [(v, v, ("rot", k)) for k, v in enumerate(ring_pts[ring_off[s]:ring_off[s + 1]])]
    out = [(starts[s], ends[s], ("fwd", 0))]
    return out + [(ends[s], starts[s], ("rev", 0))] if reverse else out


def _check_nearest_each_step(arrays, home, reverse, seq, flip, rot):
    """Every step enters the stroke whose nearest way in is nearest (ties may go either way)."""
    starts, ends, closed, ring_pts, ring_off = arrays
    used = np.zeros(len(starts), bool)
    cur = home
    for s, f in zip(seq, flip):
        ways = [a for t in np.flatnonzero(~used) for a, _, _ in _ways_in(t, *arrays, reverse)]
        if closed[s]:
            a = b = ring_pts[ring_off[s] + rot[s]]
        else:
            a, b = (ends[s], starts[s]) if f else (starts[s], ends[s])
        if np.isnan(cur).any():  # free start: the lowest-left way in
            assert tuple(a) == min(tuple(w) for w in ways)
        else:
            assert np.hypot(*(a - cur)) <= min(np.hypot(*(w - cur)) for w in ways) + 1e-12
        used[s], cur = True, b


def _points(arrays, rot):
    starts, ends, closed, ring_pts, ring_off = arrays
    p0, p1 = starts.copy(), ends.copy()
    c = np.flatnonzero(closed)
    p0[c] = p1[c] = ring_pts[ring_off[c] + rot[c]]
    return p0, p1


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 30), st.booleans(), st.booleans(), st.sampled_from([None, 5.0]))
def test_grid_greedy_is_nearest_neighbour(seed, n, reverse, free, grid):
    rng = np.random.default_rng(seed)
    arrays = _arrays(_strokes(rng, n, grid=grid))
    home = np.full(2, np.nan) if free else np.array([-20.0, 70.0])
    seq, flip, rot = greedy(*arrays, home, reverse)
    assert sorted(seq.tolist()) == list(range(n))
    assert reverse or not flip.any()
    _check_nearest_each_step(arrays, home, reverse, seq, flip, rot)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 300), st.integers(1, 20), st.sampled_from([None, 1.0, 0.0]))
def test_nearest_k_matches_brute_force(seed, m, k, grid):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0, 30, (m, 2))
    if grid == 0.0:  # all on one line: a one-row grid
        pts[:, 1] = 3.0
    elif grid:
        pts = np.round(pts)
    k = min(k, m - 1)
    got = nearest_k(pts, k)
    assert (got >= 0).all() and (got != np.arange(m)[:, None]).all()
    d = np.hypot(*(pts[got] - pts[:, None, :]).transpose(2, 0, 1))
    assert (np.diff(d, axis=1) >= 0).all()  # nearest first: the search's pruning relies on it
    full = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(full, np.inf)
    assert np.allclose(d, np.sort(full, axis=1)[:, :k])


@pytest.mark.parametrize("free", [True, False])
def test_kicks_report_what_they_saved_and_keep_a_tour(free):
    rng = np.random.default_rng(5)
    arrays = _arrays(_strokes(rng, 300))
    home = np.full(2, np.nan) if free else np.zeros(2)
    seq, flip, rot = greedy(*arrays, home, True)
    p0, p1 = _points(arrays, rot)
    ends = np.empty((600, 2))
    ends[0::2], ends[1::2] = p0, p1
    nbr = nearest_k(ends, 8)
    local_search(p0, p1, seq, flip, home, nbr, True, 10**6, np.zeros(0, np.int64))
    before = tour_cost(p0, p1, seq, flip, home)
    kicks, saved, _ = perturb(p0, p1, seq, flip, home, nbr, True, 400, 15, 3, 10**6, 0, 1000)
    assert kicks == 400 and saved > 0  # a 2-opt / Or-opt optimum still has room for kicks
    assert sorted(seq.tolist()) == list(range(300))
    assert tour_cost(p0, p1, seq, flip, home) == pytest.approx(before - saved, rel=1e-9)
    # a stall limit ends them early
    assert perturb(p0, p1, seq, flip, home, nbr, True, 400, 15, 4, 10, 0, 1000)[0] < 400


def test_loops_restart_at_the_vertex_between_their_neighbours():
    square = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    arrays = (np.zeros((3, 2)), np.zeros((3, 2)), np.array([False, True, False]), square, np.array([0, 0, 4, 4]))
    starts, ends = arrays[0], arrays[1]
    starts[0], ends[0] = [20.0, 0.0], [12.0, 11.0]  # leaves near (10, 10)
    starts[2], ends[2] = [11.0, 12.0], [30.0, 30.0]  # and the next starts near it too
    p0, p1 = _points(arrays, np.zeros(3, np.int64))
    rot = np.zeros(3, np.int64)
    seq, flip = np.arange(3), np.zeros(3, bool)
    before = tour_cost(p0, p1, seq, flip, np.zeros(2))
    saved = rotate_loops(p0, p1, seq, flip, arrays[2], square, arrays[4], rot, np.zeros(2))
    assert rot[1] == 2 and np.array_equal(p0[1], [10, 10]) and np.array_equal(p1[1], [10, 10])
    assert tour_cost(p0, p1, seq, flip, np.zeros(2)) == pytest.approx(before - saved)


def test_same_strokes_same_order_and_work_sized_by_count():
    rng = np.random.default_rng(11)
    polys = _strokes(rng, 400)
    a = order_strokes(polys, (0.0, 0.0), budget=30.0)
    b = order_strokes(polys, (0.0, 0.0), budget=30.0)
    assert a.source == b.source and a.travel == b.travel  # not the clock: the count of strokes
    from doodlecam.geometry.order import _KICKS_MIN

    assert 0 < a.meta["kicks"] <= len(polys) + _KICKS_MIN


def test_empty_polylines_keep_their_source_indices():
    a = np.array([[5.0, 5.0], [6.0, 5.0]])
    b = np.array([[1.0, 1.0], [2.0, 1.0]])
    o = order_strokes([np.zeros((0, 2)), a, np.zeros((0, 2)), b], (0.0, 0.0))
    assert o.source == (3, 1)
    assert np.array_equal(o.polylines[0], b) and np.array_equal(o.polylines[1], a[::-1])  # back home from (5, 5)


def test_a_cold_numba_cache_does_not_change_the_order(tmp_path):
    """The first run after an install compiles the ordering kernels (seconds);
    the budget starts after that, so it orders exactly as every later run."""
    import subprocess
    import sys

    code = (
        "import numpy as np, time\n"
        "from doodlecam.geometry.order import order_strokes\n"
        "rng = np.random.default_rng(5)\n"
        "polys = [np.cumsum(rng.normal(size=(4, 2)), axis=0) + rng.random(2) * 200 for _ in range(60)]\n"
        "t = time.perf_counter()\n"
        "first = order_strokes(polys, (0.0, 0.0), budget=0.2).source\n"
        "print(time.perf_counter() - t > 0.2, first == order_strokes(polys, (0.0, 0.0), budget=30.0).source)\n"
    )
    env = {**__import__("os").environ, "NUMBA_CACHE_DIR": str(tmp_path)}  # empty: everything compiles
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True).stdout.split()
    assert out == ["True", "True"]  # the first call took longer than its budget, and still ordered the same


def test_neighbour_lists_are_made_again_only_for_moved_ends(monkeypatch):
    """Each round after the first makes the lists again only if re-starting a
    loop moved an end; the lists then match the ends the search starts from."""
    import doodlecam.geometry.order as order

    calls = []
    real = order._neighbours

    def spy(p0, p1, k):
        calls.append(np.concatenate([p0, p1]))
        return real(p0, p1, k)

    monkeypatch.setattr(order, "_neighbours", spy)
    rng = np.random.default_rng(3)
    o = order_strokes(_strokes(rng, 300, loops=0.6), (0.0, 0.0), budget=None)
    assert o.meta["rounds"] >= 2 and 1 <= len(calls) <= o.meta["rounds"]
    assert all(not np.array_equal(a, b) for a, b in zip(calls, calls[1:]))  # no list made twice for the same ends
