"""The ordering's tour ring (doodlecam.geometry.order_tour) against a plain list doing the same moves."""

import numpy as np
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
