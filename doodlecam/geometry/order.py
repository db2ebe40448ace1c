"""Order: which stroke next, in which direction, from which point, to keep pen-up travel short.

Three steps, all in millimetres (any unit works; nothing here assumes mm):

1. ``merge_ends`` joins strokes whose ends meet within a tolerance, so the
   pen is not lifted between them at all.
2. Greedy nearest neighbour from the home position over a grid of every
   possible way into a stroke: either end of an open stroke (only its start
   when strokes may not be reversed) and every vertex of a closed one (a loop
   may start anywhere, so it is rotated to start where the pen arrives).
3. Improvement, compiled (``doodlecam.geometry.order_search``): 2-opt and Or-opt
   moves from every stroke end to its nearest other ends until no move
   gains, one all-pairs 2-opt pass for the long-range reversals neighbour
   lists miss, then random double-bridge kicks, each followed by a local
   search around it and kept only if the tour got shorter: one per stroke
   at most, fewer once a run of them gains nothing. Then each loop's start
   vertex is chosen again for its new neighbours, and the search repeats
   while that helps. The work is sized by the number of strokes, not by the
   clock, so the result does not depend on the machine's speed; the time
   budget only caps it. Without reversal only moves that keep every
   stroke's direction are used.

``home=None`` orders an open path (free start and end): pen-up legs to and
from home then cost nothing, as vpype's ``linesort`` counts them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

_FULL_2OPT_MAX = 6000  # strokes; above this an all-pairs 2-opt pass costs more than it gains
_KICKS = 1  # double-bridge kicks per stroke at most
_KICKS_MIN = 20  # ... plus this many: a few strokes have few kicks to try (text.png: 45 strokes, travel 1071 -> 1036)
_STALL = 0.5  # ... ended after this many per stroke (+ 100) in a row gained nothing
_WINDOW = 15  # tour positions a kick spans
_SPAN = 1000  # ... and its repair moves at most
_ALL = np.zeros(0, np.int64)  # local search seeds: every stroke
MOVES = 200.0  # improving moves per stroke at most (local search settles in far fewer; a cap, not a target)
MOVES_MIN = 10_000  # ... plus this many


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

def _end_points(polys: list[np.ndarray], lens: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each polyline's first and last point ((n, 2) each; the polylines non-empty float (k, 2) arrays,
    ``lens`` their lengths), from one concatenation rather than a NumPy array built from a list of n
    small ones."""
    last = np.cumsum(lens) - 1
    pts = np.concatenate(polys).reshape(-1, 2)
    return pts[last - lens + 1], pts[last]


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
    ends = np.empty((2 * n, 2))
    ends[0::2], ends[1::2] = _end_points(polys, np.array([len(p) for p in polys]))
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
    partner = [-1] * (2 * n)  # Python lists: read an element at a time below
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
    out, source, seen = [], [], [False] * n
    for c0 in range(n):
        if seen[c0]:
            continue
        if partner[2 * c0] < 0 and partner[2 * c0 + 1] < 0:  # joined to nothing (most): what the walk gives
            out.append(polys[c0])
            source.append(c0)
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

def nearest_k(pts: np.ndarray, k: int) -> np.ndarray:
    """(m, k): each point's k nearest other points, nearest first; -1 where there are fewer."""
    from scipy.spatial import cKDTree

    m = len(pts)
    out = np.full((m, k), -1, np.int64)
    if m < 2 or k < 1:
        return out
    kk = min(k + 1, m)
    idx = cKDTree(pts).query(pts, k=kk)[1].reshape(m, kk)
    # drop the point itself: not always the first column (coincident points tie at distance 0), and
    # missing when more than kk points coincide (then any of them, the last, goes)
    keep = idx != np.arange(m)[:, None]
    keep[keep.all(axis=1), -1] = False
    out[:, :kk - 1] = idx[keep].reshape(m, kk - 1)
    return out


def _neighbours(p0: np.ndarray, p1: np.ndarray, k: int) -> np.ndarray:
    """(2n, k) the k nearest other stroke ends of end 2i + side (side 0 = p0), nearest first."""
    ends = np.empty((2 * len(p0), 2))
    ends[0::2], ends[1::2] = p0, p1
    return nearest_k(ends, k)


def _improve(tour: dict, allow_reverse: bool, deadline: float, k_near: int, max_moves: int = 2**62
             ) -> tuple[int, int, int]:
    """2-opt / Or-opt local search, kicks, loops re-started, until settled, out of moves or out of time.

    ``tour`` holds the arrays (modified in place): p0 / p1 entry / exit points
    (a loop's both its start vertex), seq, flip, rot and the loops' rings.
    Returns (rounds, moves, kicks).
    """
    from doodlecam.geometry.order_search import (
        full_two_opt,
        local_search,
        perturb,
        rotate_loops,
        tour_cost,
    )

    p0, p1, seq, flip, home = tour["p0"], tour["p1"], tour["seq"], tour["flip"], tour["home"]
    closed = tour["closed"]
    loops = bool(closed.any())
    n = len(seq)
    rounds = moves = kicks = 0
    # Few strokes: look further (every move is cheap); many: the k nearest ends suffice.
    k = min(max(k_near, 3000 // max(n, 1)), 2 * n - 1, 16)
    cost = tour_cost(p0, p1, seq, flip, home)
    seen = None  # the stroke ends the neighbour lists were made for
    while True:
        if seen is None or not (np.array_equal(seen[0], p0) and np.array_equal(seen[1], p1)):
            nbr = _neighbours(p0, p1, k)  # again only if a loop's start moved
            seen = (p0.copy(), p1.copy())
        before = cost
        chunk = min(5 * n + 100, 5000)  # moves per call: the budget is checked between calls
        while True:
            m = local_search(p0, p1, seq, flip, home, nbr, allow_reverse, chunk, _ALL)
            moves += m
            if m < chunk or moves >= max_moves or time.perf_counter() > deadline:
                break
        # Then reversals between any two pen-up edges (a pass is O(n^2): only
        # while it stays cheap), and the neighbour search again after them.
        if allow_reverse and n <= _FULL_2OPT_MAX and moves < max_moves and time.perf_counter() < deadline:
            m = full_two_opt(p0, p1, seq, flip, home, 1)
            if m:
                moves += m + local_search(p0, p1, seq, flip, home, nbr, allow_reverse, chunk, _ALL)
        if rounds == 0 and n >= 8:
            # Kicks: random double bridges, each followed by a local search around
            # it; a number that grows with n, ended early once they stop paying.
            limit, stall = int(_KICKS * n) + _KICKS_MIN, int(_STALL * n) + 100
            since, seed = 0, 0
            step = max(500, n // 4)  # kicks per call: the budget is checked between calls, each costs O(n) to set up
            while kicks < limit and since < stall and time.perf_counter() < deadline:
                it, _, since = perturb(p0, p1, seq, flip, home, nbr, allow_reverse, min(step, limit - kicks),
                                       _WINDOW, seed, stall, since, _SPAN)
                kicks += it
                seed += 1
        if loops:
            rotate_loops(p0, p1, seq, flip, closed, tour["ring_pts"], tour["ring_off"], tour["rot"], home)
        rounds += 1
        cost = tour_cost(p0, p1, seq, flip, home)
        if (cost >= before - 1e-9 * max(1.0, before) or time.perf_counter() > deadline or not loops
                or moves >= max_moves
                or rounds >= 3):  # loops re-started a few times: later rounds gain little
            return rounds, moves, kicks


def _order(starts, ends, closed, ring_pts, ring_off, home, allow_reverse, budget, neighbours, t_start,
           moves_per_stroke: float = 0.0):
    """Greedy tour, then its improvement: the tour dict (see ``_improve``) and meta."""
    from doodlecam.geometry.order_search import greedy, rotate_loops, tour_cost

    seq, flip, rot = greedy(starts, ends, closed, ring_pts, ring_off, home, allow_reverse)
    p0, p1 = starts.copy(), ends.copy()
    c = np.flatnonzero(closed)
    if len(c):
        p0[c] = p1[c] = ring_pts[ring_off[c] + rot[c]]
    tour = {"p0": p0, "p1": p1, "seq": seq, "flip": flip, "rot": rot, "home": home, "closed": closed,
            "ring_pts": ring_pts, "ring_off": ring_off}
    greedy_cost = tour_cost(p0, p1, seq, flip, home)
    rounds = moves = kicks = 0
    n = len(seq)
    if (budget is None or budget > 0) and n >= 2:
        if len(c):
            rotate_loops(p0, p1, seq, flip, closed, ring_pts, ring_off, rot, home)
        deadline = np.inf if budget is None else t_start + budget
        cap = int(moves_per_stroke * n) + MOVES_MIN if moves_per_stroke > 0 else 2**62
        rounds, moves, kicks = _improve(tour, allow_reverse, deadline, neighbours, cap)
    tour["cost"] = tour_cost(p0, p1, seq, flip, home)
    return tour, {"greedy_travel": greedy_cost, "rounds": rounds, "moves": moves, "kicks": kicks}


_COMPILED = False


def _compile_once() -> None:
    """Compile (or load from numba's cache) every ordering kernel once per
    process, before any budget clock starts: with an empty cache (the first run
    after an install) compiling takes seconds, and a budget that counted it
    gave that run a different, worse order than every later run."""
    global _COMPILED
    if _COMPILED:
        return
    _COMPILED = True
    rng = np.random.default_rng(0)
    polys = [rng.random((3, 2)) * 100 for _ in range(10)]
    ring = rng.random((4, 2)) * 100
    polys += [np.vstack([ring, ring[:1]]), np.vstack([ring[::-1], ring[-1:]]) + 50]  # closed: any start
    order_strokes(polys, (0.0, 0.0), budget=None)


def order_strokes(polylines: Sequence[np.ndarray], home=(0.0, 0.0), allow_reverse: bool = True,
                  merge: float = 0.0, budget: float | None = 1.0, neighbours: int = 16,
                  moves: float = MOVES) -> Ordering:
    """Order, orient and rotate strokes to keep pen-up travel short.

    ``merge``: join strokes whose ends meet within this distance first (0 = never).
    ``moves``: improving moves per stroke at most (plus MOVES_MIN): the
    deterministic cap on the improvement. ``budget``: seconds after which the
    improvement stops as well (0 = greedy only, None = no clock: the order
    then never depends on the machine's speed or load, as in a conversion),
    counted from the call and checked between compiled steps, so very large
    sets may overrun it a little; small sets settle in milliseconds and stop
    there. The clock starts after numba has compiled or loaded the kernels, so
    the same strokes get the same order on the first run after an install too.
    ``home``: where the pen starts and ends; ``None`` for a free start and end.
    """
    _compile_once()
    t_start = time.perf_counter()
    polys = [np.asarray(p, float) for p in polylines]
    kept = [i for i, p in enumerate(polys) if len(p)]
    polys = [polys[i] for i in kept]
    if merge > 0:
        polys, source = merge_ends(polys, merge, allow_reverse)
    else:
        source = list(range(len(polys)))
    n = len(polys)
    if n == 0:
        return Ordering((), (), 0.0, {"strokes_in": len(polylines), "merged": 0})
    home_pt = np.full(2, np.nan) if home is None else np.asarray(home, float).reshape(2)
    lens = np.array([len(p) for p in polys])
    starts, ends = _end_points(polys, lens)
    closed = (lens >= 4) & (starts == ends).all(axis=1)
    ring_len = np.where(closed, lens - 1, 0)
    ring_off = np.zeros(n + 1, np.int64)
    np.cumsum(ring_len, out=ring_off[1:])
    ci = np.flatnonzero(closed)
    ring_pts = np.concatenate([polys[i][:-1] for i in ci]) if len(ci) else np.zeros((0, 2))
    tour, meta = _order(starts, ends, closed, ring_pts, ring_off, home_pt, allow_reverse, budget, neighbours, t_start,
                        moves)
    out = []
    rot = tour["rot"]
    for s, f in zip(tour["seq"].tolist(), tour["flip"].tolist()):
        p = polys[s]
        if closed[s] and rot[s]:
            k = rot[s]
            r = p[:-1]
            p = np.concatenate([r[k:], r[:k + 1]])
        out.append(p[::-1] if f else p)
    meta = {"strokes_in": len(polylines), "merged": len(kept) - n, **meta,
            "seconds": time.perf_counter() - t_start}
    return Ordering(tuple(out), tuple(kept[source[s]] for s in tour["seq"].tolist()), tour["cost"], meta)


def order_polylines(polylines, home=(0.0, 0.0), allow_reverse: bool = True, budget: float = 1.0):
    """(order, reversed_flags): indices into ``polylines`` and whether to flip each.

    The index-only form of ``order_strokes`` (no merging, loops not rotated).
    """
    polys = [np.asarray(p, float) for p in polylines]
    n = len(polys)
    if n == 0:
        return [], []
    starts = np.array([p[0] for p in polys], float).reshape(-1, 2)
    ends = np.array([p[-1] for p in polys], float).reshape(-1, 2)
    home_pt = np.full(2, np.nan) if home is None else np.asarray(home, float).reshape(2)
    _compile_once()
    tour, _ = _order(starts, ends, np.zeros(n, bool), np.zeros((0, 2)), np.zeros(n + 1, np.int64), home_pt,
                     allow_reverse, budget, 8, time.perf_counter())
    return tour["seq"].tolist(), tour["flip"].tolist()
