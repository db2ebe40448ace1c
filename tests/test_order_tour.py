"""The ordering's tour ring (doodlecam.geometry.order_tour) against a plain list doing the same moves."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from doodlecam.geometry.order_tour import (
    entry,
    exit_,
    node,
    stroke_at,
    tour_move,
    tour_read,
    tour_reverse,
    tour_ring,
)


def _list_reverse(tour, lo, hi):
    """Plain list of (stroke, flip): reverse nodes lo..hi (positions lo-1..hi-1)."""
    tour[lo - 1:hi] = [(s, not f) for s, f in reversed(tour[lo - 1:hi])]


def _list_move(tour, s, e, k, rev):
    """Plain list: move nodes s..e between nodes k and k + 1, reversed if rev."""
    run = tour[s - 1:e]
    if rev:
        run = [(i, not f) for i, f in reversed(run)]
    rest = tour[:s - 1] + tour[e:]
    at = k if k < s else k - len(run)  # positions before the insertion point, once the run is out
    tour[:] = rest[:at] + run + rest[at:]


def _check(ring, tour, P0, P1, home):
    pseq, pflip, pent, pext, pos, g = ring
    n = len(tour)
    seq, flip = np.empty(n, np.int64), np.empty(n, bool)
    tour_read(pseq, pflip, g, seq, flip)
    assert [(int(s), bool(f)) for s, f in zip(seq, flip)] == tour
    for q in (0, n + 1):
        assert entry(pent, pext, g, q, n + 1) == tuple(home) == exit_(pent, pext, g, q, n + 1)
    for p, (s, f) in enumerate(tour):
        assert stroke_at(pseq, g, p, n + 1) == s and node(g[0], g[1], pos[s], n + 1) == p + 1
        a, b = (P1[s], P0[s]) if f else (P0[s], P1[s])
        assert entry(pent, pext, g, p + 1, n + 1) == tuple(a)
        assert exit_(pent, pext, g, p + 1, n + 1) == tuple(b)


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 10**6), st.integers(1, 40), st.integers(1, 60))
def test_ring_moves_match_a_plain_list(seed, n, steps):
    """Long and short reversals (the ring rewrites the other side for long ones,
    moving home and turning the reading direction) and runs moved either way
    round the ring leave exactly the tour a plain list gives, node by node."""
    rng = np.random.default_rng(seed)
    P0, P1 = rng.random((n, 2)), rng.random((n, 2))
    home = np.array([0.25, -1.0])
    seq = rng.permutation(n).astype(np.int64)
    flip = rng.random(n) < 0.5
    tour = [(int(s), bool(f)) for s, f in zip(seq, flip)]
    ring = tour_ring(P0, P1, seq, flip, home)
    buf_s, buf_f = np.empty(n + 4, np.int64), np.empty(n + 4, bool)
    _check(ring, tour, P0, P1, home)
    for _ in range(steps):
        if rng.random() < 0.5:
            lo = int(rng.integers(1, n + 1))
            hi = int(rng.integers(lo, n + 1))
            tour_reverse(P0, P1, home, *ring, lo, hi, buf_s, buf_f)
            _list_reverse(tour, lo, hi)
        else:
            L = int(rng.integers(1, min(3, n) + 1))
            s = int(rng.integers(1, n - L + 2))
            e = s + L - 1
            ks = [k for k in range(n + 1) if not s - 1 <= k <= e]
            if not ks:
                continue
            k, rev = int(rng.choice(ks)), bool(rng.random() < 0.5)
            tour_move(P0, P1, home, *ring, s, e, k, rev, buf_s, buf_f)
            _list_move(tour, s, e, k, rev)
        _check(ring, tour, P0, P1, home)


def test_long_moves_rewrite_the_short_side():
    """Reversing all but one stroke, or moving a stroke from one end to the
    other, rewrites two slots of the ring, not n: home's slot moves instead."""
    n = 1000
    P0 = np.stack([np.arange(n), np.zeros(n)], axis=1).astype(float)
    P1 = P0 + 0.5
    seq, flip = np.arange(n), np.zeros(n, bool)
    ring = tour_ring(P0, P1, seq, flip, np.zeros(2))
    pseq, pflip, pent, pext, pos, g = ring
    before = pseq.copy()
    buf_s, buf_f = np.empty(n + 4, np.int64), np.empty(n + 4, bool)
    tour_reverse(P0, P1, np.zeros(2), *ring, 2, n, buf_s, buf_f)  # nodes 2..n: all but the first stroke
    assert (pseq != before).sum() <= 2 and g[1] == -1 and g[2] == 1
    before = pseq.copy()
    tour_move(P0, P1, np.zeros(2), *ring, 1, 1, n, False, buf_s, buf_f)  # first stroke to the end
    assert (pseq != before).sum() <= 2
    tour_read(pseq, pflip, g, seq, flip)
    assert seq.tolist() == list(range(n - 1, 0, -1)) + [0] and flip.tolist() == [True] * (n - 1) + [False]


def _plain_search(P0, P1, seq, flip, home, nbr, allow_reverse):
    """The local search of order_search._search, move for move, on plain lists
    (every move rewrites the run it changes, as before the ring): the reference."""
    n, eps = len(seq), 1e-9
    tour = [(int(s), bool(f)) for s, f in zip(seq, flip)]
    free = bool(np.isnan(home[0]))

    def pt(q, out):  # entry (out=False) / exit point of node q
        if q == 0 or q == n + 1:
            return home
        s, f = tour[q - 1]
        return (P0 if f == out else P1)[s]

    def e(p, q, op=True, oq=False):
        if free and (p in (0, n + 1) or q in (0, n + 1)):
            return 0.0
        a, b = pt(p, op), pt(q, oq)
        return float(np.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2))

    def rev_gain(lo, hi):
        return e(lo - 1, lo) + e(hi, hi + 1) - e(lo - 1, hi, True, True) - e(lo, hi + 1, False, False)

    def gor(s, e_, k, rev):
        if s < 1 or e_ > n or s > e_ or k < 0 or k > n or (s - 1 <= k <= e_):
            return -1.0
        g = e(s - 1, s) + e(e_, e_ + 1) - e(s - 1, e_ + 1) + e(k, k + 1)
        if rev:
            return g - e(k, e_, True, True) - e(s, k + 1, False, False)
        return g - e(k, s) - e(e_, k + 1)

    def where(i):
        return next(p for p, (s, _) in enumerate(tour) if s == i)

    stack, active, moves = list(range(n - 1, -1, -1)), [True] * n, 0
    while stack:
        i = stack.pop()
        active[i] = False
        found = True
        while found:
            found = False
            for side in range(2):
                a = 2 * i + side
                pa = where(i) + 1
                a_exit = (side == 1) != tour[pa - 1][1]
                ax = (P1 if side == 1 else P0)[i]
                reach = e(pa, pa + 1) if a_exit else e(pa - 1, pa)
                for b in nbr[a]:
                    j = b // 2
                    if b < 0 or j == i:
                        continue
                    bx = (P1 if b % 2 == 1 else P0)[j]
                    if float(np.sqrt((ax[0] - bx[0]) ** 2 + (ax[1] - bx[1]) ** 2)) >= reach:
                        break
                    pb = where(j) + 1
                    b_exit = (b % 2 == 1) != tour[pb - 1][1]
                    best, kind = eps, 0
                    cands = []
                    if a_exit and b_exit:
                        if allow_reverse:
                            lo, hi = (pa + 1, pb) if pa < pb else (pb + 1, pa)
                            if lo <= hi:
                                cands.append((rev_gain(lo, hi), 1, lo, hi, 0, False))
                            for L in range(1, 4):
                                cands.append((gor(pb - L + 1, pb, pa, True), 2, pb - L + 1, pb, pa, True))
                                cands.append((gor(pa - L + 1, pa, pb, True), 2, pa - L + 1, pa, pb, True))
                    elif a_exit or b_exit:
                        px, qn = (pa, pb) if a_exit else (pb, pa)
                        for L in range(1, 4):
                            cands.append((gor(qn, qn + L - 1, px, False), 2, qn, qn + L - 1, px, False))
                            cands.append((gor(px - L + 1, px, qn - 1, False), 2, px - L + 1, px, qn - 1, False))
                    elif allow_reverse:
                        lo, hi = (pa, pb - 1) if pa < pb else (pb, pa - 1)
                        if lo <= hi:
                            cands.append((rev_gain(lo, hi), 1, lo, hi, 0, False))
                        for L in range(1, 4):
                            cands.append((gor(pb, pb + L - 1, pa - 1, True), 2, pb, pb + L - 1, pa - 1, True))
                            cands.append((gor(pa, pa + L - 1, pb - 1, True), 2, pa, pa + L - 1, pb - 1, True))
                    for c in cands:
                        if c[0] > best:
                            best, kind, x1, x2, x3, xr = c
                    if kind == 0:
                        continue
                    if kind == 1:
                        _list_reverse(tour, x1, x2)
                        lo_p, hi_p = x1 - 1, x2 - 1
                    else:
                        _list_move(tour, x1, x2, x3, xr)
                        lo_p, hi_p = (x3, x2 - 1) if x3 < x1 else (x1 - 1, x3 - 1)
                    moves += 1
                    found = True
                    for p in (lo_p - 1, lo_p, hi_p, hi_p + 1, x1 - 2, x1 - 1, x2 - 1, x2, x3 - 1, x3):
                        if 0 <= p < n and not active[tour[p][0]]:
                            active[tour[p][0]] = True
                            stack.append(tour[p][0])
                    break
                if found:
                    break
    return moves, tour


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10**6), st.integers(2, 30), st.booleans(), st.booleans(), st.sampled_from([3, 8, 60]))
def test_local_search_on_the_ring_makes_the_plain_arrays_moves(seed, n, free, allow_reverse, k):
    """The compiled search on the ring (long reversals rewrite the other side,
    home moves round the ring) makes exactly the moves the same search makes
    on a plain list, to the same tour."""
    from doodlecam.geometry.order import nearest_k
    from doodlecam.geometry.order_search import local_search

    rng = np.random.default_rng(seed)
    P0, P1 = rng.uniform(0, 50, (n, 2)), rng.uniform(0, 50, (n, 2))
    if rng.random() < 0.3:  # ties: coincident ends
        P1[: n // 2] = P0[n // 2: 2 * (n // 2)]
    home = np.full(2, np.nan) if free else np.array([-5.0, 20.0])
    seq = rng.permutation(n).astype(np.int64)
    flip = (rng.random(n) < 0.5) & allow_reverse
    ends = np.empty((2 * n, 2))
    ends[0::2], ends[1::2] = P0, P1
    nbr = nearest_k(ends, min(k, 2 * n - 1))
    want = _plain_search(P0, P1, seq, flip, home, nbr, allow_reverse)
    got = local_search(P0, P1, seq, flip, home, nbr, allow_reverse, 10**6, np.zeros(0, np.int64))
    assert (got, [(int(s), bool(f)) for s, f in zip(seq, flip)]) == want
