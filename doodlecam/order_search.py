"""The compiled local search behind ``doodlecam.order``: 2-opt and Or-opt moves.

From every stroke end to each of its k nearest other ends, the moves that
create that short pen-up edge are scored (2-opt: reverse the strokes in
between, each drawn the other way; Or-opt: move a run of one to three
strokes there, forwards or reversed) and the best is applied at once
(first improvement). Strokes near a change are looked at again ("don't look
bits"), the rest are not, until nothing gains. A move costs O(1) to score
and O(moved strokes) to apply, so thousands of strokes settle in
milliseconds where a Python loop would take seconds. Compiled by numba on
first use and cached on disk; imported only when strokes are ordered.
"""

import numba
import numpy as np

_EPS = 1e-9


@numba.njit(cache=True, nogil=True)
def _reverse(seq, flip, s, e):  # pragma: no cover - compiled
    """Reverse positions s..e of the tour: their order, and each one's direction."""
    while s < e:
        t = seq[s]
        seq[s] = seq[e]
        seq[e] = t
        tf = flip[s]
        flip[s] = not flip[e]
        flip[e] = not tf
        s += 1
        e -= 1
    if s == e:
        flip[s] = not flip[s]


@numba.njit(cache=True, nogil=True)
def _refresh(P0, P1, seq, flip, pos, ent, ext, lo, hi):  # pragma: no cover - compiled
    """Entry / exit points and positions of tour positions lo..hi (node p + 1 in ent / ext)."""
    for p in range(lo, hi + 1):
        i = seq[p]
        pos[i] = p
        if flip[p]:
            ent[p + 1, 0], ent[p + 1, 1] = P1[i, 0], P1[i, 1]
            ext[p + 1, 0], ext[p + 1, 1] = P0[i, 0], P0[i, 1]
        else:
            ent[p + 1, 0], ent[p + 1, 1] = P0[i, 0], P0[i, 1]
            ext[p + 1, 0], ext[p + 1, 1] = P1[i, 0], P1[i, 1]


@numba.njit(cache=True, nogil=True)
def local_search(P0, P1, seq, flip, home, nbr, allow_reverse, max_moves, seeds):  # pragma: no cover - compiled
    """Improve the tour ``seq`` / ``flip`` in place; returns the number of moves made.

    P0 / P1: (n, 2) each stroke's entry / exit point when drawn forwards;
    home: (2,), NaN for a free start and end; nbr: (2n, k) the nearest other
    ends of end 2i + side (side 0 = P0), -1 for none; seeds: the strokes to
    look at first (empty: all). Nodes: 0 is home, p + 1 the stroke at tour
    position p, n + 1 home again.
    """
    n = seq.shape[0]
    ent = np.empty((n + 2, 2))
    ext = np.empty((n + 2, 2))
    ent[0], ext[0], ent[n + 1], ext[n + 1] = home, home, home, home
    pos = np.empty(n, np.int64)
    _refresh(P0, P1, seq, flip, pos, ent, ext, 0, n - 1)
    free = home[0] != home[0]
    buf_s = np.empty(n, np.int64)
    buf_f = np.empty(n, np.bool_)
    active = np.zeros(n, np.bool_)
    stack = np.empty(4 * n + 16, np.int64)
    top = 0
    if seeds.shape[0] == 0:
        for i in range(n - 1, -1, -1):
            stack[top] = i
            top += 1
            active[i] = True
    else:
        for i in seeds:
            if 0 <= i < n and not active[i]:
                stack[top] = i
                top += 1
                active[i] = True
    moves = 0

    while top > 0 and moves < max_moves:
        top -= 1
        i = stack[top]
        active[i] = False
        found = True
        while found and moves < max_moves:  # keep improving around stroke i while it pays
            found = False
            for side in range(2):
                a = 2 * i + side
                for kk in range(nbr.shape[1]):
                    b = nbr[a, kk]
                    if b < 0:
                        continue
                    j = b // 2
                    if j == i:
                        continue
                    pa = pos[i] + 1  # nodes
                    pb = pos[j] + 1
                    a_exit = (side == 1) != flip[pa - 1]
                    b_exit = (b % 2 == 1) != flip[pb - 1]
                    best = _EPS
                    kind = 0
                    x1 = 0
                    x2 = 0
                    x3 = 0
                    xr = False
                    # edge[m]: node m -> m + 1 (0 when it touches an absent home)
                    if a_exit and b_exit:
                        if allow_reverse:
                            # 2-opt: reverse nodes lo..hi, new edges exit(lo-1)-exit(hi), entry(lo)-entry(hi+1)
                            lo, hi = (pa + 1, pb) if pa < pb else (pb + 1, pa)
                            if lo <= hi:
                                g = (_e(ext, ent, lo - 1, lo, n, free) + _e(ext, ent, hi, hi + 1, n, free)
                                     - _xx(ext, lo - 1, hi, n, free) - _nn(ent, lo, hi + 1, n, free))
                                if g > best:
                                    best, kind, x1, x2 = g, 1, lo, hi
                            for L in range(1, 4):
                                g = _gor(ext, ent, pb - L + 1, pb, pa, True, n, free)
                                if g > best:
                                    best, kind, x1, x2, x3, xr = g, 2, pb - L + 1, pb, pa, True
                                g = _gor(ext, ent, pa - L + 1, pa, pb, True, n, free)
                                if g > best:
                                    best, kind, x1, x2, x3, xr = g, 2, pa - L + 1, pa, pb, True
                    elif a_exit or b_exit:  # exit(px) - entry(qn)
                        px, qn = (pa, pb) if a_exit else (pb, pa)
                        for L in range(1, 4):
                            g = _gor(ext, ent, qn, qn + L - 1, px, False, n, free)
                            if g > best:
                                best, kind, x1, x2, x3, xr = g, 2, qn, qn + L - 1, px, False
                            g = _gor(ext, ent, px - L + 1, px, qn - 1, False, n, free)
                            if g > best:
                                best, kind, x1, x2, x3, xr = g, 2, px - L + 1, px, qn - 1, False
                    elif allow_reverse:  # entry - entry
                        lo, hi = (pa, pb - 1) if pa < pb else (pb, pa - 1)
                        if lo <= hi:
                            g = (_e(ext, ent, lo - 1, lo, n, free) + _e(ext, ent, hi, hi + 1, n, free)
                                 - _xx(ext, lo - 1, hi, n, free) - _nn(ent, lo, hi + 1, n, free))
                            if g > best:
                                best, kind, x1, x2 = g, 1, lo, hi
                        for L in range(1, 4):
                            g = _gor(ext, ent, pb, pb + L - 1, pa - 1, True, n, free)
                            if g > best:
                                best, kind, x1, x2, x3, xr = g, 2, pb, pb + L - 1, pa - 1, True
                            g = _gor(ext, ent, pa, pa + L - 1, pb - 1, True, n, free)
                            if g > best:
                                best, kind, x1, x2, x3, xr = g, 2, pa, pa + L - 1, pb - 1, True
                    if kind == 0:
                        continue
                    if kind == 1:  # reverse positions x1-1..x2-1
                        _reverse(seq, flip, x1 - 1, x2 - 1)
                        lo_p, hi_p = x1 - 1, x2 - 1
                    else:  # move positions x1-1..x2-1 after position x3-1
                        s, e, k = x1 - 1, x2 - 1, x3 - 1
                        m = 0
                        if k < s:
                            lo_p, hi_p = k + 1, e
                        else:
                            lo_p, hi_p = s, k
                            for p in range(e + 1, k + 1):
                                buf_s[m] = seq[p]
                                buf_f[m] = flip[p]
                                m += 1
                        for t in range(e - s + 1):
                            p = e - t if xr else s + t
                            buf_s[m] = seq[p]
                            buf_f[m] = (not flip[p]) if xr else flip[p]
                            m += 1
                        if k < s:
                            for p in range(k + 1, s):
                                buf_s[m] = seq[p]
                                buf_f[m] = flip[p]
                                m += 1
                        for t in range(m):
                            seq[lo_p + t] = buf_s[t]
                            flip[lo_p + t] = buf_f[t]
                    _refresh(P0, P1, seq, flip, pos, ent, ext, lo_p, hi_p)
                    moves += 1
                    found = True
                    # wake the strokes beside every changed edge
                    for p in (lo_p - 1, lo_p, hi_p, hi_p + 1, x1 - 2, x1 - 1, x2 - 1, x2, x3 - 1, x3):
                        if 0 <= p < n:
                            w = seq[p]
                            if not active[w] and top < stack.shape[0]:
                                active[w] = True
                                stack[top] = w
                                top += 1
                    break
                if found:
                    break
    return moves


@numba.njit(cache=True, nogil=True)
def _dist(ax, ay, bx, by):  # pragma: no cover - compiled
    dx = ax - bx
    dy = ay - by
    return np.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True, nogil=True)
def _e(ext, ent, p, q, n, free):  # pragma: no cover - compiled
    """exit(node p) -> entry(node q)."""
    if free and (p == 0 or p == n + 1 or q == 0 or q == n + 1):
        return 0.0
    return _dist(ext[p, 0], ext[p, 1], ent[q, 0], ent[q, 1])


@numba.njit(cache=True, nogil=True)
def _xx(ext, p, q, n, free):  # pragma: no cover - compiled
    """exit(node p) -> exit(node q)."""
    if free and (p == 0 or p == n + 1 or q == 0 or q == n + 1):
        return 0.0
    return _dist(ext[p, 0], ext[p, 1], ext[q, 0], ext[q, 1])


@numba.njit(cache=True, nogil=True)
def _nn(ent, p, q, n, free):  # pragma: no cover - compiled
    """entry(node p) -> entry(node q)."""
    if free and (p == 0 or p == n + 1 or q == 0 or q == n + 1):
        return 0.0
    return _dist(ent[p, 0], ent[p, 1], ent[q, 0], ent[q, 1])


@numba.njit(cache=True, nogil=True)
def _gor(ext, ent, s, e, k, rev, n, free):  # pragma: no cover - compiled
    """Travel saved by moving nodes s..e between nodes k and k + 1 (reversed if rev)."""
    if s < 1 or e > n or s > e or k < 0 or k > n or (s - 1 <= k and k <= e):
        return -1.0
    g = _e(ext, ent, s - 1, s, n, free) + _e(ext, ent, e, e + 1, n, free) - _e(ext, ent, s - 1, e + 1, n, free) + _e(ext, ent, k, k + 1, n, free)
    if rev:
        return g - _xx(ext, k, e, n, free) - _nn(ent, s, k + 1, n, free)
    return g - _e(ext, ent, k, s, n, free) - _e(ext, ent, e, k + 1, n, free)


@numba.njit(cache=True, nogil=True)
def full_two_opt(P0, P1, seq, flip, home, max_passes):  # pragma: no cover - compiled
    """2-opt over every pair of pen-up edges (not only near ones), best move per edge.

    O(n^2) per pass, which compiled is tens of milliseconds for thousands of
    strokes; it finds the long-range reversals the neighbour lists miss.
    Returns the number of moves made.
    """
    n = seq.shape[0]
    ent = np.empty((n + 2, 2))
    ext = np.empty((n + 2, 2))
    ent[0], ext[0], ent[n + 1], ext[n + 1] = home, home, home, home
    pos = np.empty(n, np.int64)
    _refresh(P0, P1, seq, flip, pos, ent, ext, 0, n - 1)
    free = home[0] != home[0]
    moves = 0
    for _ in range(max_passes):
        improved = False
        for lo in range(1, n + 1):  # reverse nodes lo..hi: edges (lo-1, lo) and (hi, hi+1) change
            old_a = _e(ext, ent, lo - 1, lo, n, free)
            best = _EPS
            best_hi = -1
            for hi in range(lo, n + 1):
                g = (old_a + _e(ext, ent, hi, hi + 1, n, free)
                     - _xx(ext, lo - 1, hi, n, free) - _nn(ent, lo, hi + 1, n, free))
                if g > best:
                    best = g
                    best_hi = hi
            if best_hi > 0:
                _reverse(seq, flip, lo - 1, best_hi - 1)
                _refresh(P0, P1, seq, flip, pos, ent, ext, lo - 1, best_hi - 1)
                moves += 1
                improved = True
        if not improved:
            break
    return moves


@numba.njit(cache=True, nogil=True)
def tour_cost(P0, P1, seq, flip, home):  # pragma: no cover - compiled
    """Pen-up length of the tour (legs to an absent, NaN, home cost nothing)."""
    n = seq.shape[0]
    free = home[0] != home[0]
    total = 0.0
    px, py = home[0], home[1]
    for p in range(n):
        i = seq[p]
        if flip[p]:
            ax, ay, bx, by = P1[i, 0], P1[i, 1], P0[i, 0], P0[i, 1]
        else:
            ax, ay, bx, by = P0[i, 0], P0[i, 1], P1[i, 0], P1[i, 1]
        if not (free and p == 0):
            total += _dist(px, py, ax, ay)
        px, py = bx, by
    if not free and n:
        total += _dist(px, py, home[0], home[1])
    return total


@numba.njit(cache=True, nogil=True)
def perturb(P0, P1, seq, flip, home, nbr, allow_reverse, iterations, window, seed):  # pragma: no cover - compiled
    """Iterated local search: a random double bridge within ``window`` positions
    (runs B and C of A B C D swapped), the local search from the strokes at the
    cuts, kept only if the whole tour got shorter. Returns the tour's length."""
    n = seq.shape[0]
    np.random.seed(seed)
    cost = tour_cost(P0, P1, seq, flip, home)
    if n < 8:
        return cost
    keep_s = seq.copy()
    keep_f = flip.copy()
    buf_s = np.empty(n, np.int64)
    buf_f = np.empty(n, np.bool_)
    seeds = np.empty(6, np.int64)
    for _ in range(iterations):
        span = min(window, n - 1)
        a = np.random.randint(1, n - span + 1) if n - span >= 1 else 1
        b = a + np.random.randint(1, span - 1)
        c = b + np.random.randint(1, max(2, a + span - b))
        if c > n:
            c = n
        if not (a < b < c):
            continue
        m = 0
        for p in range(b, c):
            buf_s[m] = seq[p]
            buf_f[m] = flip[p]
            m += 1
        for p in range(a, b):
            buf_s[m] = seq[p]
            buf_f[m] = flip[p]
            m += 1
        for t in range(m):
            seq[a + t] = buf_s[t]
            flip[a + t] = buf_f[t]
        k = 0
        for p in (a - 1, a, a + c - b - 1, a + c - b, c - 1, min(c, n - 1)):
            seeds[k] = seq[p]
            k += 1
        local_search(P0, P1, seq, flip, home, nbr, allow_reverse, 20 * window + 100, seeds)
        new = tour_cost(P0, P1, seq, flip, home)
        if new < cost - 1e-9:
            cost = new
            keep_s[:] = seq
            keep_f[:] = flip
        else:
            seq[:] = keep_s
            flip[:] = keep_f
    return cost
