"""Order: which stroke next, in which direction, from which point, to keep pen-up travel short.

Three steps, all in millimetres (any unit works; nothing here assumes mm):

1. ``merge_ends`` joins strokes whose ends meet within a tolerance, so the
   pen is not lifted between them at all.
2. Greedy nearest neighbour from the home position over a k-d tree of every
   possible way into a stroke: either end of an open stroke (only its start
   when strokes may not be reversed) and every vertex of a closed one (a loop
   may start anywhere, so it is rotated to start where the pen arrives).
3. Improvement within a time budget, compiled (``doodlecam.order_search``):
   2-opt and Or-opt moves from every stroke end to its nearest other ends
   until no move gains, one all-pairs 2-opt pass for the long-range
   reversals neighbour lists miss, then random double-bridge kicks each
   followed by a local search around it (kept only if the tour got shorter)
   for half the time spent so far; then each loop's start vertex is chosen
   again for its new neighbours, and the search repeats while that helps.
   Without reversal only moves that keep every stroke's direction are used.

``home=None`` orders an open path (free start and end): pen-up legs to and
from home then cost nothing, as vpype's ``linesort`` counts them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

_EPS = 1e-9
_FULL_2OPT_MAX = 6000  # strokes; above this an all-pairs 2-opt pass costs more than it gains
_FULL_PASSES = 1  # all-pairs passes per round: most of their gain comes in the first
_KICK_SHARE = 0.5  # kicks run for this share of the time spent before them
_ALL = np.zeros(0, np.int64)  # local search seeds: every stroke


@dataclass(frozen=True)
class Ordering:
    """Strokes in drawing order: oriented, loops rotated, touching ones merged.

    ``source[k]`` is the index of the (first) input polyline that became
    ``polylines[k]``; ``travel`` is the pen-up length from home, between the
    strokes and back home (0-cost legs to an absent home excluded).
    """

    polylines: tuple[np.ndarray, ...]
    source: tuple[int, ...]
    travel: float
    meta: dict[str, Any] = field(default_factory=dict)


def travel_length(polylines: Sequence[np.ndarray], home=None) -> float:
    """Pen-up length of drawing ``polylines`` in the given order and directions."""
    if not len(polylines):
        return 0.0
    starts = np.array([p[0] for p in polylines], float)
    ends = np.array([p[-1] for p in polylines], float)
    total = float(np.hypot(*(starts[1:] - ends[:-1]).T).sum())
    if home is not None:
        h = np.asarray(home, float)
        total += float(np.hypot(*(starts[0] - h)) + np.hypot(*(ends[-1] - h)))
    return total


# ---------------------------------------------------------------- merging

def merge_ends(polylines: Sequence[np.ndarray], tolerance: float, allow_reverse: bool = True
               ) -> tuple[list[np.ndarray], list[int]]:
    """Join open polylines whose ends lie within ``tolerance``, closest pairs first.

    Returns (polylines, source): each output's first input index. A gap
    larger than zero becomes a short connecting segment. Closed polylines
    (ends within the tolerance of each other) are left alone; a chain is
    never joined into a loop, so no stroke grows a doubled-back segment.
    """
    from scipy.spatial import cKDTree

    polys = [np.asarray(p, float) for p in polylines]
    n = len(polys)
    if n < 2 or tolerance <= 0:
        return polys, list(range(n))
    ends = np.array([[p[0], p[-1]] for p in polys], float).reshape(2 * n, 2)
    closed = np.hypot(*(ends[0::2] - ends[1::2]).T) <= tolerance
    pairs = cKDTree(ends).query_pairs(tolerance, output_type="ndarray")
    if len(pairs) == 0:
        return polys, list(range(n))
    x, y = pairs[:, 0], pairs[:, 1]
    ok = (x // 2 != y // 2) & ~closed[x // 2] & ~closed[y // 2]
    if not allow_reverse:  # only an end onto a start keeps both directions
        ok &= (x % 2) != (y % 2)
    x, y = x[ok], y[ok]
    by = np.argsort(np.hypot(*(ends[x] - ends[y]).T), kind="stable")
    partner = np.full(2 * n, -1)
    group = list(range(n))

    def find(a):
        while group[a] != a:
            group[a] = a = group[group[a]]
        return a

    for a, b in zip(x[by].tolist(), y[by].tolist()):
        if partner[a] >= 0 or partner[b] >= 0:
            continue
        ga, gb = find(a >> 1), find(b >> 1)
        if ga == gb:
            continue  # would close a loop
        partner[a], partner[b] = b, a
        group[ga] = gb
    out, source, seen = [], [], np.zeros(n, bool)
    for c0 in range(n):
        if seen[c0]:
            continue
        # Walk back to a free end; without reversal, back to the chain's first start.
        e = 2 * c0
        while partner[e] >= 0:
            e = partner[e] ^ 1
        if not allow_reverse and e % 2 == 1:  # walked to an end: the chain runs the other way
            e = 2 * c0 + 1
            while partner[e] >= 0:
                e = partner[e] ^ 1
            e ^= 1
        pieces, first = [], e >> 1
        while True:  # enter chain e >> 1 at end e, leave by the other
            c = e >> 1
            seen[c] = True
            p = polys[c] if e % 2 == 0 else polys[c][::-1]
            if pieces and np.array_equal(pieces[-1][-1], p[0]):
                p = p[1:]
            pieces.append(p)
            if partner[e ^ 1] < 0:
                break
            e = partner[e ^ 1]
        out.append(pieces[0] if len(pieces) == 1 else np.concatenate(pieces))
        source.append(int(first))
    return out, source


# ---------------------------------------------------------------- ordering

def _dist(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Euclidean distance; a NaN point (an absent home) is at distance 0 from everything."""
    d = np.hypot(p[..., 0] - q[..., 0], p[..., 1] - q[..., 1])
    nan = np.isnan(d)
    if nan.any():
        d[nan] = 0.0
    return d


class _Tour:
    """Stroke sequence with entry/exit points, framed by home at both ends."""

    def __init__(self, starts, ends, closed, ring_pts, ring_off, home):
        self.starts, self.ends, self.closed = starts, ends, closed
        self.ring_pts, self.ring_off = ring_pts, ring_off  # loops' vertices, concatenated
        self.home = home
        self.seq = np.zeros(0, int)
        self.flip = np.zeros(0, bool)
        self.rot = np.zeros(len(starts), int)  # start vertex of each loop (index into its ring)

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """entry, exit of nodes 0..n+1 (node 0 and n+1 are home)."""
        s, f = self.seq, self.flip
        a = np.where(f[:, None], self.ends[s], self.starts[s])
        b = np.where(f[:, None], self.starts[s], self.ends[s])
        c = self.closed[s]
        if c.any():
            v = self.ring_pts[self.ring_off[s[c]] + self.rot[s[c]]]
            a[c] = b[c] = v
        h = self.home[None, :]
        return np.vstack([h, a, h]), np.vstack([h, b, h])

    def cost(self) -> float:
        a, b = self.points()
        return float(_dist(b[:-1], a[1:]).sum())


def _greedy(t: _Tour, allow_reverse: bool) -> None:
    """Nearest neighbour over a k-d tree of every way into every stroke."""
    from scipy.spatial import cKDTree

    n = len(t.starts)
    open_ = np.flatnonzero(~t.closed)
    cl = np.flatnonzero(t.closed)
    ring_len = np.diff(t.ring_off)
    # Candidate ways in: (point, stroke, kind) with kind -1 forwards, -2 reversed,
    # k >= 0 a loop entered at its vertex k; exit[c] is where the pen leaves.
    cand_pts, exit_pts = [t.starts[open_]], [t.ends[open_]]
    owner = [open_]
    kind = [np.full(len(open_), -1)]
    if allow_reverse:
        cand_pts.append(t.ends[open_])
        exit_pts.append(t.starts[open_])
        owner.append(open_)
        kind.append(np.full(len(open_), -2))
    if len(cl):
        cand_pts.append(t.ring_pts)
        exit_pts.append(t.ring_pts)
        owner.append(np.repeat(cl, ring_len[cl]))
        kind.append(np.arange(len(t.ring_pts)) - np.repeat(t.ring_off[cl], ring_len[cl]))
    pts, exits = np.vstack(cand_pts), np.vstack(exit_pts)
    owner, kind = np.concatenate(owner), np.concatenate(kind)
    m = len(pts)
    seq, flip = np.empty(n, int), np.zeros(n, bool)
    tree = cKDTree(pts)
    # Every exit's nearest ways in, found at once; the loop below only falls
    # back to a query when all of them are taken.
    kk = min(12, m)
    # Open strokes' exits are queried at once; a loop's many vertices only when
    # the pen actually leaves from one (most never are).
    n_open = m - len(t.ring_pts)
    near: list = tree.query(exits[:n_open], k=kk)[1].reshape(n_open, kk).tolist() if n_open else []
    near += [None] * (m - n_open)
    owner_l, kind_l = owner.tolist(), kind.tolist()
    ring_l, closed_l = ring_len.tolist(), t.closed.tolist()
    used = [False] * n
    live = np.arange(m)
    live_tree, dead = tree, 0
    per_use = 2 if allow_reverse else 1
    rot = t.rot
    if np.isfinite(t.home).all():
        hit = int(np.atleast_1d(tree.query(t.home, k=1)[1])[0])
    else:  # a free start: the lowest-left way in
        hit = int(np.lexsort((pts[:, 1], pts[:, 0]))[0])
    hit_prev = -1  # the way in used last: the pen leaves from its exit
    for step in range(n):
        if step:
            hit = -1
            if near[hit_prev] is None:
                near[hit_prev] = np.atleast_1d(tree.query(exits[hit_prev], k=kk)[1]).tolist()
            for c in near[hit_prev]:
                if not used[owner_l[c]]:
                    hit = c
                    break
            if hit < 0:
                if dead > len(live) // 2:  # drop used points, keep queries short
                    live = live[~np.array(used)[owner[live]]]
                    live_tree, dead = cKDTree(pts[live]), 0
                # the nearest ways in are often the vertices of the loop just
                # drawn: look past all of them in the first query
                sp = owner_l[hit_prev]
                k = 8 + (ring_l[sp] if closed_l[sp] else 0)
                while hit < 0:
                    k = min(k, len(live))
                    _, idx = live_tree.query(exits[hit_prev], k=k)
                    for j in np.atleast_1d(idx).tolist():
                        if j < len(live) and not used[owner_l[live[j]]]:
                            hit = int(live[j])
                            break
                    else:
                        if k >= len(live):  # cannot happen while strokes remain
                            raise RuntimeError("ordering lost track of strokes")
                        k *= 4
        s, kd = owner_l[hit], kind_l[hit]
        used[s] = True
        seq[step] = s
        if kd >= 0:
            rot[s] = kd
        else:
            flip[step] = kd == -2
        dead += ring_l[s] if closed_l[s] else per_use
        hit_prev = hit
    t.seq, t.flip = seq, flip


def _rotate_loops(t: _Tour) -> None:
    """Start each loop at the vertex nearest its neighbours (even, then odd positions)."""
    pos_closed = np.flatnonzero(t.closed[t.seq])
    if not len(pos_closed):
        return
    ring_len = np.diff(t.ring_off)
    for parity in (0, 1):
        a, b = t.points()
        p = pos_closed[pos_closed % 2 == parity]
        if not len(p):
            continue
        s = t.seq[p]
        cnt = ring_len[s]
        idx = np.repeat(t.ring_off[s], cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        v = t.ring_pts[idx]
        prev = np.repeat(b[p], cnt, axis=0)  # node p is the exit of position p-1
        nxt = np.repeat(a[p + 2], cnt, axis=0)
        c = _dist(prev, v) + _dist(v, nxt)
        first = np.r_[0, np.cumsum(cnt)[:-1]]
        best = np.minimum.reduceat(c, first)
        # first vertex reaching the minimum in each ring
        hit = c <= np.repeat(best, cnt) + 1e-12
        grp = np.repeat(np.arange(len(s)), cnt)
        k = np.full(len(s), -1)
        hi = np.flatnonzero(hit)[::-1]
        k[grp[hi]] = idx[hi] - t.ring_off[s][grp[hi]]
        t.rot[s] = k


def _improve(t: _Tour, allow_reverse: bool, deadline: float, k_near: int, spent_before: float = 0.0
             ) -> tuple[int, int]:
    """2-opt / Or-opt local search (compiled), then loops re-started, until settled or out of time."""
    from scipy.spatial import cKDTree

    from .order_search import full_two_opt, local_search, perturb

    n = len(t.seq)
    rounds = moves = 0
    started = time.perf_counter() - spent_before
    # Few strokes: look further (every move is cheap); many: the k nearest ends suffice.
    k = min(max(k_near, 3000 // max(n, 1)), 2 * n - 1, 16)
    while True:
        p0, p1 = t.starts.copy(), t.ends.copy()
        c = np.flatnonzero(t.closed)
        if len(c):
            p0[c] = p1[c] = t.ring_pts[t.ring_off[c] + t.rot[c]]
        ends = np.empty((2 * n, 2))
        ends[0::2], ends[1::2] = p0, p1
        nbr = cKDTree(ends).query(ends, k=k + 1)[1][:, 1:].astype(np.int64)
        nbr[nbr >= 2 * n] = -1
        before = t.cost()
        chunk = 5 * n + 100  # moves per call: the budget is checked between calls
        while True:
            m = local_search(p0, p1, t.seq, t.flip, t.home, nbr, allow_reverse, chunk, _ALL)
            moves += m
            if m < chunk or time.perf_counter() > deadline:
                break
            # Then reversals between any two pen-up edges (a pass is O(n^2): only
            # while it stays cheap), and the neighbour search again after them.
        for _ in range(_FULL_PASSES):
            if not (allow_reverse and n <= _FULL_2OPT_MAX and time.perf_counter() < deadline):
                break
            m = full_two_opt(p0, p1, t.seq, t.flip, t.home, 1)
            if not m:
                break
            moves += m + local_search(p0, p1, t.seq, t.flip, t.home, nbr, allow_reverse, chunk, _ALL)
        # Kicks: random double bridges, each followed by a local search around it,
        # for a share of the time the ordering has taken so far (within the budget).
        spent = time.perf_counter() - started
        stop = min(deadline, time.perf_counter() + _KICK_SHARE * spent)
        seed, iters = 0, 4
        while rounds == 0 and n >= 8:
            t0 = time.perf_counter()
            if t0 >= stop:
                break
            perturb(p0, p1, t.seq, t.flip, t.home, nbr, allow_reverse, iters, 30, seed)
            seed += 1
            each = (time.perf_counter() - t0) / iters  # size the next call to the time left
            iters = int(np.clip((stop - time.perf_counter()) / max(each, 1e-7) / 2, 1, 200))
        rounds += 1
        _rotate_loops(t)
        if (t.cost() >= before - 1e-9 * max(1.0, before) or time.perf_counter() > deadline or not len(c)
                or rounds >= 3):  # loops re-started a few times: later rounds gain little
            return rounds, moves


def order_strokes(polylines: Sequence[np.ndarray], home=(0.0, 0.0), allow_reverse: bool = True,
                  merge: float = 0.0, budget: float = 1.0, neighbours: int = 16) -> Ordering:
    """Order, orient and rotate strokes to keep pen-up travel short.

    ``merge``: join strokes whose ends meet within this distance first (0 = never).
    ``budget``: seconds of improvement after the greedy tour (0 = greedy only).
    ``home``: where the pen starts and ends; ``None`` for a free start and end.
    """
    t_start = time.perf_counter()
    polys = [np.asarray(p, float) for p in polylines]
    polys = [p for p in polys if len(p)]
    if merge > 0:
        polys, source = merge_ends(polys, merge, allow_reverse)
    else:
        source = list(range(len(polys)))
    n = len(polys)
    home_pt = np.full(2, np.nan) if home is None else np.asarray(home, float)
    if n == 0:
        return Ordering((), (), 0.0, {"strokes_in": len(polylines), "merged": 0})
    starts = np.array([p[0] for p in polys])
    ends = np.array([p[-1] for p in polys])
    closed = np.array([len(p) >= 4 and np.array_equal(p[0], p[-1]) for p in polys])
    rings = [polys[i][:-1] for i in np.flatnonzero(closed)]
    ring_off = np.zeros(n + 1, int)
    lens = np.zeros(n, int)
    lens[closed] = [len(r) for r in rings]
    ring_off[1:] = np.cumsum(lens)
    ring_pts = np.vstack(rings) if rings else np.zeros((0, 2))
    tour = _Tour(starts, ends, closed, ring_pts, ring_off, home_pt)
    _greedy(tour, allow_reverse)
    greedy_cost = tour.cost()
    rounds = moves = 0
    if budget > 0 and n >= 2:
        _rotate_loops(tour)
        rounds, moves = _improve(tour, allow_reverse, t_start + budget, neighbours, time.perf_counter() - t_start)
    out = []
    for s, f in zip(tour.seq, tour.flip):
        p = polys[s]
        if closed[s]:
            r = p[:-1]
            k = tour.rot[s]
            p = np.vstack([r[k:], r[:k], r[k:k + 1]]) if k else p
        out.append(p[::-1] if f else p)
    cost = tour.cost()
    meta = {"strokes_in": len(polylines), "merged": len(polylines) - n, "greedy_travel": greedy_cost,
            "rounds": rounds, "moves": moves, "seconds": time.perf_counter() - t_start}
    return Ordering(tuple(out), tuple(source[s] for s in tour.seq), cost, meta)


def order_polylines(polylines, home=(0.0, 0.0), allow_reverse: bool = True, budget: float = 1.0):
    """(order, reversed_flags): indices into ``polylines`` and whether to flip each.

    The index-only form of ``order_strokes`` (no merging, loops not rotated).
    """
    polys = [np.asarray(p, float) for p in polylines]
    starts = np.array([p[0] for p in polys], float).reshape(-1, 2)
    ends = np.array([p[-1] for p in polys], float).reshape(-1, 2)
    n = len(polys)
    if n == 0:
        return [], []
    no_rings = np.zeros(n, bool)
    tour = _Tour(starts, ends, no_rings, np.zeros((0, 2)), np.zeros(n + 1, int),
                 np.full(2, np.nan) if home is None else np.asarray(home, float))
    _greedy(tour, allow_reverse)
    if budget > 0 and n >= 2:
        _improve(tour, allow_reverse, time.perf_counter() + budget, 8)
    return tour.seq.tolist(), tour.flip.tolist()

