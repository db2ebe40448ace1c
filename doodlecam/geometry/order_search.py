"""The compiled pieces of ``doodlecam.geometry.order``: greedy tour, 2-opt / Or-opt, kicks.

Greedy uses a uniform grid of about one cell per point, searched ring by ring
until the next ring lies farther than what was found; its points die as their
strokes are drawn (the grid is rebuilt over the living ones), which a static
k-d tree cannot do. The neighbour lists are SciPy's cKDTree (``order.nearest_k``).
The local search: from every stroke end to each of its k nearest other ends
(only while that end is closer than the pen-up edge it has now), the moves
that create that short pen-up edge are scored (2-opt: reverse the strokes in
between, each drawn the other way; Or-opt: move a run of one to three
strokes there, forwards or reversed) and the best is applied at once
(first improvement). Strokes near a change are looked at again ("don't look
bits"), the rest are not, until nothing gains. A move costs O(1) to score
and O(shorter side of the tour it changes) to apply (``order_tour``: the
tour is a ring read in either direction), so thousands of strokes settle in
milliseconds where a Python loop would take seconds. Compiled by numba on
first use and cached on disk; imported only when strokes are ordered.
"""

import numba
import numpy as np

from doodlecam.geometry.order_tour import (
    node,
    slot,
    tour_get,
    tour_move,
    tour_read,
    tour_reverse,
    tour_ring,
    tour_write,
)

_EPS = 1e-9


@numba.njit(cache=True, nogil=True)
def local_search(P0, P1, seq, flip, home, nbr, allow_reverse, max_moves, seeds):  # pragma: no cover - compiled
    """Improve the tour ``seq`` / ``flip`` in place; returns the number of moves made.

    P0 / P1: (n, 2) each stroke's entry / exit point when drawn forwards;
    home: (2,), NaN for a free start and end; nbr: (2n, k) the nearest other
    ends of end 2i + side (side 0 = P0), -1 for none; seeds: the strokes to
    look at first (empty: all). Nodes: 0 is home, p + 1 the stroke at tour
    position p, n + 1 home again.
    """
    pseq, pflip, pent, pext, pos, g, free, buf_s, buf_f, active, stack = _state(P0, P1, seq, flip, home)
    n = seq.shape[0]
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
    moves = _search(P0, P1, home, nbr, allow_reverse, max_moves, n,
                    pseq, pflip, pent, pext, pos, g, free, buf_s, buf_f, active, stack, top)[0]
    tour_read(pseq, pflip, g, seq, flip)
    return moves


@numba.njit(cache=True, nogil=True)
def _state(P0, P1, seq, flip, home):  # pragma: no cover - compiled
    """Working state of the search: the tour's ring (``order_tour``), buffers."""
    n = seq.shape[0]
    pseq, pflip, pent, pext, pos, g = tour_ring(P0, P1, seq, flip, home)
    free = home[0] != home[0]
    return (pseq, pflip, pent, pext, pos, g, free, np.empty(n + 4, np.int64), np.empty(n + 4, np.bool_),
            np.zeros(n, np.bool_), np.empty(4 * n + 16, np.int64))


@numba.njit(cache=True, nogil=True)
def _view(pent, pext, g):  # pragma: no cover - compiled
    """How the scoring reads the ring: home's slot, direction, reversal bit,
    exit and entry points by slot (a reversed ring swaps them)."""
    rv = g[2] == 1
    if rv:
        return g[0], g[1], rv, pent, pext
    return g[0], g[1], rv, pext, pent


@numba.njit(cache=True, nogil=True, inline="always")  # a call of its own runs at half speed
def _search(P0, P1, home, nbr, allow_reverse, max_moves, max_span,
            pseq, pflip, pent, pext, pos, g, free, buf_s, buf_f, active, stack, top):  # pragma: no cover - compiled
    """The local search on the state from ``_state``, from the ``top`` strokes on
    its stack, with moves between tour positions at most ``max_span`` apart.
    Returns (moves, travel saved, first and last tour position changed)."""
    n = pos.shape[0]
    N = n + 1
    moves = 0
    gain = 0.0
    lo_t = n
    hi_t = -1
    off, d, rv, ex, en = _view(pent, pext, g)
    while top > 0 and moves < max_moves:
        top -= 1
        i = stack[top]
        active[i] = False
        found = True
        while found and moves < max_moves:  # keep improving around stroke i while it pays
            found = False
            for side in range(2):
                a = 2 * i + side
                pa = node(off, d, pos[i], N)
                a_exit = (side == 1) != (pflip[pos[i]] != rv)
                # Neighbour-list pruning (as in Lin-Kernighan): a move that adds the
                # edge a-b is looked for only while b is closer than the pen-up edge
                # a has now; the lists are sorted, so the first farther b ends the scan.
                ax, ay = (P1[i, 0], P1[i, 1]) if side == 1 else (P0[i, 0], P0[i, 1])
                reach = _e(ex, en, off, d, pa, pa + 1, n, free) if a_exit else _e(ex, en, off, d, pa - 1, pa, n, free)
                for kk in range(nbr.shape[1]):
                    b = nbr[a, kk]
                    if b < 0:
                        continue
                    j = b // 2
                    if j == i:
                        continue
                    if b % 2 == 1:
                        if _dist(ax, ay, P1[j, 0], P1[j, 1]) >= reach:
                            break
                    elif _dist(ax, ay, P0[j, 0], P0[j, 1]) >= reach:
                        break
                    pb = node(off, d, pos[j], N)
                    if abs(pa - pb) > max_span:  # a kick's repair stays near the kick
                        continue
                    b_exit = (b % 2 == 1) != (pflip[pos[j]] != rv)
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
                                g_ = _rev_gain(ex, en, off, d, lo, hi, n, free)
                                if g_ > best:
                                    best, kind, x1, x2 = g_, 1, lo, hi
                            for L in range(1, 4):
                                g_ = _gor(ex, en, off, d, pb - L + 1, pb, pa, True, n, free)
                                if g_ > best:
                                    best, kind, x1, x2, x3, xr = g_, 2, pb - L + 1, pb, pa, True
                                g_ = _gor(ex, en, off, d, pa - L + 1, pa, pb, True, n, free)
                                if g_ > best:
                                    best, kind, x1, x2, x3, xr = g_, 2, pa - L + 1, pa, pb, True
                    elif a_exit or b_exit:  # exit(px) - entry(qn)
                        px, qn = (pa, pb) if a_exit else (pb, pa)
                        for L in range(1, 4):
                            g_ = _gor(ex, en, off, d, qn, qn + L - 1, px, False, n, free)
                            if g_ > best:
                                best, kind, x1, x2, x3, xr = g_, 2, qn, qn + L - 1, px, False
                            g_ = _gor(ex, en, off, d, px - L + 1, px, qn - 1, False, n, free)
                            if g_ > best:
                                best, kind, x1, x2, x3, xr = g_, 2, px - L + 1, px, qn - 1, False
                    elif allow_reverse:  # entry - entry
                        lo, hi = (pa, pb - 1) if pa < pb else (pb, pa - 1)
                        if lo <= hi:
                            g_ = _rev_gain(ex, en, off, d, lo, hi, n, free)
                            if g_ > best:
                                best, kind, x1, x2 = g_, 1, lo, hi
                        for L in range(1, 4):
                            g_ = _gor(ex, en, off, d, pb, pb + L - 1, pa - 1, True, n, free)
                            if g_ > best:
                                best, kind, x1, x2, x3, xr = g_, 2, pb, pb + L - 1, pa - 1, True
                            g_ = _gor(ex, en, off, d, pa, pa + L - 1, pb - 1, True, n, free)
                            if g_ > best:
                                best, kind, x1, x2, x3, xr = g_, 2, pa, pa + L - 1, pb - 1, True
                    if kind == 0:
                        continue
                    # lo_p..hi_p: the tour positions whose stroke changed
                    if kind == 1:  # reverse nodes x1..x2
                        tour_reverse(P0, P1, home, pseq, pflip, pent, pext, pos, g, x1, x2, buf_s, buf_f)
                        lo_p, hi_p = x1 - 1, x2 - 1
                    else:  # move nodes x1..x2 after node x3
                        tour_move(P0, P1, home, pseq, pflip, pent, pext, pos, g, x1, x2, x3, xr, buf_s, buf_f)
                        lo_p, hi_p = (x3, x2 - 1) if x3 < x1 else (x1 - 1, x3 - 1)
                    off, d, rv, ex, en = _view(pent, pext, g)
                    moves += 1
                    gain += best
                    lo_t = min(lo_t, lo_p)
                    hi_t = max(hi_t, hi_p)
                    found = True
                    # wake the strokes beside every changed edge
                    for p in (lo_p - 1, lo_p, hi_p, hi_p + 1, x1 - 2, x1 - 1, x2 - 1, x2, x3 - 1, x3):
                        if 0 <= p < n:
                            w = pseq[slot(off, d, p + 1, N)]
                            if not active[w] and top < stack.shape[0]:
                                active[w] = True
                                stack[top] = w
                                top += 1
                    break
                if found:
                    break
    while top > 0:  # out of moves: leave no stroke marked
        top -= 1
        active[stack[top]] = False
    return moves, gain, lo_t, hi_t


@numba.njit(cache=True, nogil=True)
def _dist(ax, ay, bx, by):  # pragma: no cover - compiled
    dx = ax - bx
    dy = ay - by
    return np.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True, nogil=True)
def _e(ex, en, off, d, p, q, n, free):  # pragma: no cover - compiled
    """exit(node p) -> entry(node q)."""
    if free and (p == 0 or p == n + 1 or q == 0 or q == n + 1):
        return 0.0
    a = slot(off, d, p, n + 1)
    b = slot(off, d, q, n + 1)
    return _dist(ex[a, 0], ex[a, 1], en[b, 0], en[b, 1])


@numba.njit(cache=True, nogil=True)
def _xx(ex, off, d, p, q, n, free):  # pragma: no cover - compiled
    """exit(node p) -> exit(node q)."""
    if free and (p == 0 or p == n + 1 or q == 0 or q == n + 1):
        return 0.0
    a = slot(off, d, p, n + 1)
    b = slot(off, d, q, n + 1)
    return _dist(ex[a, 0], ex[a, 1], ex[b, 0], ex[b, 1])


@numba.njit(cache=True, nogil=True)
def _nn(en, off, d, p, q, n, free):  # pragma: no cover - compiled
    """entry(node p) -> entry(node q)."""
    if free and (p == 0 or p == n + 1 or q == 0 or q == n + 1):
        return 0.0
    a = slot(off, d, p, n + 1)
    b = slot(off, d, q, n + 1)
    return _dist(en[a, 0], en[a, 1], en[b, 0], en[b, 1])


@numba.njit(cache=True, nogil=True, inline="always")
def _rev_gain(ex, en, off, d, lo, hi, n, free):  # pragma: no cover - compiled
    """Travel saved by reversing nodes lo..hi (2-opt): edges (lo-1, lo) and (hi, hi+1)
    become exit(lo-1) -> exit(hi) and entry(lo) -> entry(hi+1)."""
    return (_e(ex, en, off, d, lo - 1, lo, n, free) + _e(ex, en, off, d, hi, hi + 1, n, free)
            - _xx(ex, off, d, lo - 1, hi, n, free) - _nn(en, off, d, lo, hi + 1, n, free))


@numba.njit(cache=True, nogil=True)
def _gor(ex, en, off, d, s, e, k, rev, n, free):  # pragma: no cover - compiled
    """Travel saved by moving nodes s..e between nodes k and k + 1 (reversed if rev)."""
    if s < 1 or e > n or s > e or k < 0 or k > n or (s - 1 <= k and k <= e):
        return -1.0
    g_ = (_e(ex, en, off, d, s - 1, s, n, free) + _e(ex, en, off, d, e, e + 1, n, free)
          - _e(ex, en, off, d, s - 1, e + 1, n, free) + _e(ex, en, off, d, k, k + 1, n, free))
    if rev:
        return g_ - _xx(ex, off, d, k, e, n, free) - _nn(en, off, d, s, k + 1, n, free)
    return g_ - _e(ex, en, off, d, k, s, n, free) - _e(ex, en, off, d, e, k + 1, n, free)


@numba.njit(cache=True, nogil=True)
def full_two_opt(P0, P1, seq, flip, home, max_passes):  # pragma: no cover - compiled
    """2-opt over every pair of pen-up edges (not only near ones), best move per edge.

    O(n^2) per pass, which compiled is tens of milliseconds for thousands of
    strokes; it finds the long-range reversals the neighbour lists miss.
    Returns the number of moves made.
    """
    n = seq.shape[0]
    pseq, pflip, pent, pext, pos, g, free, buf_s, buf_f = _state(P0, P1, seq, flip, home)[:9]
    off, d, rv, ex, en = _view(pent, pext, g)
    moves = 0
    for _ in range(max_passes):
        improved = False
        for lo in range(1, n + 1):  # reverse nodes lo..hi: edges (lo-1, lo) and (hi, hi+1) change
            old_a = _e(ex, en, off, d, lo - 1, lo, n, free)
            best = _EPS
            best_hi = -1
            # the same sums as _e / _xx / _nn, walking the ring's slots (hi's: s, hi + 1's: t)
            a = slot(off, d, lo - 1, n + 1)
            s = slot(off, d, lo, n + 1)
            ax, ay, bx, by = ex[a, 0], ex[a, 1], en[s, 0], en[s, 1]
            head = free and lo == 1  # legs to an absent home cost nothing
            for hi in range(lo, n + 1):
                t = s + d
                if t > n:
                    t = 0
                elif t < 0:
                    t = n
                xx = 0.0 if head else _dist(ax, ay, ex[s, 0], ex[s, 1])
                if free and hi == n:
                    g_ = old_a + 0.0 - xx - 0.0
                else:
                    g_ = (old_a + _dist(ex[s, 0], ex[s, 1], en[t, 0], en[t, 1])
                          - xx - _dist(bx, by, en[t, 0], en[t, 1]))
                if g_ > best:
                    best = g_
                    best_hi = hi
                s = t
            if best_hi > 0:
                tour_reverse(P0, P1, home, pseq, pflip, pent, pext, pos, g, lo, best_hi, buf_s, buf_f)
                off, d, rv, ex, en = _view(pent, pext, g)
                moves += 1
                improved = True
        if not improved:
            break
    tour_read(pseq, pflip, g, seq, flip)
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
def perturb(P0, P1, seq, flip, home, nbr, allow_reverse, iterations, window, seed, stall, since,
            max_span):  # pragma: no cover - compiled
    """Iterated local search: a random double bridge within ``window`` positions
    (runs B and C of A B C D swapped), the local search from the strokes at the
    cuts, kept only if the whole tour got shorter. Stops after ``iterations``
    kicks or once ``stall`` kicks in a row (``since`` of them before this
    call) gained nothing. The repair moves stay within ``max_span`` positions,
    so a kick is local in the tour as well as in the plane. Each kick costs
    O(positions it changed), not O(n): gains are summed from the moves, and a
    rejected kick restores only the positions it touched.
    Returns (kicks made, travel saved, kicks in a row without gain)."""
    n = seq.shape[0]
    N = n + 1
    if n < 8:
        return 0, 0.0, since
    np.random.seed(seed)
    pseq, pflip, pent, pext, pos, g, free, buf_s, buf_f, active, stack = _state(P0, P1, seq, flip, home)
    keep_s = seq.copy()
    keep_f = flip.copy()
    saved = 0.0
    it = 0
    while it < iterations and since < stall:
        it += 1
        since += 1
        off, d, rv, ex, en = _view(pent, pext, g)
        span = min(window, n - 1)
        a = np.random.randint(1, n - span + 1) if n - span >= 1 else 1
        b = a + np.random.randint(1, span - 1)
        c = b + np.random.randint(1, max(2, a + span - b))
        if c > n:
            c = n
        if not (a < b < c):
            continue
        # node p + 1 is position p: edges (a-1, a), (b-1, b), (c-1, c) are replaced
        # by (a-1, b), (c-1, a), (b-1, c)
        delta = (_e(ex, en, off, d, a, b + 1, n, free) + _e(ex, en, off, d, c, a + 1, n, free)
                 + _e(ex, en, off, d, b, c + 1, n, free) - _e(ex, en, off, d, a, a + 1, n, free)
                 - _e(ex, en, off, d, b, b + 1, n, free) - _e(ex, en, off, d, c, c + 1, n, free))
        tour_get(pseq, pflip, g, b + 1, c - b, N, buf_s, buf_f, 0)
        tour_get(pseq, pflip, g, a + 1, b - a, N, buf_s, buf_f, c - b)
        tour_write(P0, P1, home, pseq, pflip, pent, pext, pos, g, a + 1, c - a, buf_s, buf_f)
        top = 0
        for p in (a - 1, a, a + c - b - 1, a + c - b, c - 1, min(c, n - 1)):
            w = pseq[slot(off, d, p + 1, N)]
            if not active[w]:
                active[w] = True
                stack[top] = w
                top += 1
        _, gain, lo, hi = _search(P0, P1, home, nbr, allow_reverse, 20 * window + 100, max_span,
                                  pseq, pflip, pent, pext, pos, g, free, buf_s, buf_f, active, stack, top)
        lo = min(lo, a)
        hi = max(hi, c - 1)
        if gain - delta > 1e-9:
            saved += gain - delta
            since = 0
            tour_get(pseq, pflip, g, lo + 1, hi - lo + 1, N, keep_s, keep_f, lo)
        else:
            tour_write(P0, P1, home, pseq, pflip, pent, pext, pos, g, lo + 1, hi - lo + 1, keep_s[lo:], keep_f[lo:])
    tour_read(pseq, pflip, g, seq, flip)
    return it, saved, since



@numba.njit(cache=True, nogil=True)
def _grid(pts, live):  # pragma: no cover - compiled
    """Bucket the points ``pts[live]`` into a uniform grid of about one cell per point.

    Returns (x0, y0, x1, y1, cell size, nx, ny, cell start offsets, items, live count per cell, cell of each point
    (-1 if not in the grid))."""
    m = live.shape[0]
    x0 = y0 = np.inf
    x1 = y1 = -np.inf
    for q in live:
        x0 = min(x0, pts[q, 0])
        x1 = max(x1, pts[q, 0])
        y0 = min(y0, pts[q, 1])
        y1 = max(y1, pts[q, 1])
    w = x1 - x0
    h = y1 - y0
    # about m cells over the bounding box; a thin box gets a line of cells
    cell = max(np.sqrt(w * h / m), max(w, h) / m, 1e-12)
    nx = min(int(w / cell) + 1, m + 1)
    ny = min(int(h / cell) + 1, m + 1)
    cell_of = np.full(pts.shape[0], -1, np.int64)
    count = np.zeros(nx * ny, np.int64)
    for q in live:
        cx = min(int((pts[q, 0] - x0) / cell), nx - 1)
        cy = min(int((pts[q, 1] - y0) / cell), ny - 1)
        cell_of[q] = cy * nx + cx
        count[cy * nx + cx] += 1
    start = np.zeros(nx * ny + 1, np.int64)
    for c in range(nx * ny):
        start[c + 1] = start[c] + count[c]
    fill = start[:-1].copy()
    items = np.empty(m, np.int64)
    for q in live:
        c = cell_of[q]
        items[fill[c]] = q
        fill[c] += 1
    return x0, y0, x1, y1, cell, nx, ny, start, items, count, cell_of


@numba.njit(cache=True, nogil=True)
def _ring(cx, cy, r, nx, ny, buf):  # pragma: no cover - compiled
    """Fill ``buf`` with the grid cells at Chebyshev distance r from (cx, cy); returns how many."""
    if r == 0:
        buf[0] = cy * nx + cx
        return 1
    m = 0
    i0, i1 = max(cx - r, 0), min(cx + r, nx - 1)
    for j in (cy - r, cy + r):
        if 0 <= j < ny:
            for i in range(i0, i1 + 1):
                buf[m] = j * nx + i
                m += 1
    j0, j1 = max(cy - r + 1, 0), min(cy + r - 1, ny - 1)
    for i in (cx - r, cx + r):
        if 0 <= i < nx:
            for j in range(j0, j1 + 1):
                buf[m] = j * nx + i
                m += 1
    return m


@numba.njit(cache=True, nogil=True)
def _cell(x, y, x0, y0, x1, y1, cell, nx, ny):  # pragma: no cover - compiled
    """Grid cell (cx, cy) of (x, y) clamped into the box: projecting onto the
    box moves no grid point closer, so ring r + 1 is at least r cells away."""
    cx = min(max(int((min(max(x, x0), x1) - x0) / cell), 0), nx - 1)
    cy = min(max(int((min(max(y, y0), y1) - y0) / cell), 0), ny - 1)
    return cx, cy


@numba.njit(cache=True, nogil=True)
def _nearest(x, y, pts, owner, used, x0, y0, x1, y1, cell, nx, ny, start, items, count,
             buf):  # pragma: no cover - compiled
    """The grid point nearest (x, y) whose owner is not used, -1 if none: rings of
    cells around it until the next ring lies farther than the best point found."""
    cx, cy = _cell(x, y, x0, y0, x1, y1, cell, nx, ny)
    best = np.inf
    hit = -1
    for r in range(max(cx, nx - 1 - cx, cy, ny - 1 - cy) + 1):
        for u in range(_ring(cx, cy, r, nx, ny, buf)):
            c = buf[u]
            if count[c] > 0:
                for t in range(start[c], start[c + 1]):
                    q = items[t]
                    if not used[owner[q]]:
                        dx = pts[q, 0] - x
                        dy = pts[q, 1] - y
                        d = dx * dx + dy * dy
                        if d < best:
                            best = d
                            hit = q
        if hit >= 0 and best <= (r * cell) * (r * cell):
            break
    return hit


@numba.njit(cache=True, nogil=True)
def greedy(starts, ends, closed, ring_pts, ring_off, home, allow_reverse):  # pragma: no cover - compiled
    """Nearest neighbour over every way into every stroke: either end of an open
    stroke (only its start without reversal), any vertex of a closed one.

    A grid of those points answers "nearest way in of a stroke not yet drawn";
    points of drawn strokes are skipped, and the grid is rebuilt over the rest
    when more than half of its points are dead. Returns (seq, flip, rot): the
    order, which strokes run backwards, the vertex each loop starts at. A NaN
    home starts at the lowest-left way in.
    """
    n = starts.shape[0]
    coff = np.zeros(n + 1, np.int64)  # stroke s owns points coff[s]..coff[s + 1] - 1
    for s in range(n):
        coff[s + 1] = coff[s] + (ring_off[s + 1] - ring_off[s] if closed[s] else (2 if allow_reverse else 1))
    m = coff[n]
    pts = np.empty((m, 2))
    owner = np.empty(m, np.int64)
    for s in range(n):
        q = coff[s]
        if closed[s]:
            for v in range(ring_off[s], ring_off[s + 1]):
                pts[q] = ring_pts[v]
                owner[q] = s
                q += 1
        else:
            pts[q] = starts[s]
            owner[q] = s
            if allow_reverse:
                pts[q + 1] = ends[s]
                owner[q + 1] = s
    used = np.zeros(n, np.bool_)
    seq = np.empty(n, np.int64)
    flip = np.zeros(n, np.bool_)
    rot = np.zeros(n, np.int64)
    x0, y0, x1, y1, cell, nx, ny, start, items, count, cell_of = _grid(pts, np.arange(m))
    buf = np.empty(8 * max(nx, ny) + 8, np.int64)
    in_grid = m
    dead = 0
    x, y = home[0], home[1]
    for step in range(n):
        if step == 0 and x != x:  # free start: lowest-left way in
            hit = 0
            for q in range(1, m):
                if pts[q, 0] < pts[hit, 0] or (pts[q, 0] == pts[hit, 0] and pts[q, 1] < pts[hit, 1]):
                    hit = q
        else:
            hit = _nearest(x, y, pts, owner, used, x0, y0, x1, y1, cell, nx, ny, start, items, count, buf)
        s = owner[hit]
        k = hit - coff[s]
        used[s] = True
        seq[step] = s
        if closed[s]:
            rot[s] = k
            x, y = pts[hit, 0], pts[hit, 1]
        else:
            flip[step] = k == 1
            x, y = (starts[s, 0], starts[s, 1]) if k == 1 else (ends[s, 0], ends[s, 1])
        for q in range(coff[s], coff[s + 1]):
            if cell_of[q] >= 0:
                count[cell_of[q]] -= 1
                dead += 1
        if 2 * dead > in_grid and step < n - 1:
            live = np.empty(in_grid - dead, np.int64)
            j = 0
            for q in range(m):
                if cell_of[q] >= 0 and not used[owner[q]]:
                    live[j] = q
                    j += 1
            x0, y0, x1, y1, cell, nx, ny, start, items, count, cell_of = _grid(pts, live[:j])
            buf = np.empty(8 * max(nx, ny) + 8, np.int64)
            in_grid = j
            dead = 0
    return seq, flip, rot


@numba.njit(cache=True, nogil=True)
def rotate_loops(P0, P1, seq, flip, closed, ring_pts, ring_off, rot, home):  # pragma: no cover - compiled
    """Start every loop at the vertex nearest its neighbours in the tour (in
    tour order, each seeing its predecessor's new choice); P0 / P1 of a loop,
    both its start vertex, are updated. Returns the travel saved."""
    n = seq.shape[0]
    free = home[0] != home[0]
    saved = 0.0
    for p in range(n):
        s = seq[p]
        if not closed[s]:
            continue
        has_prev = p > 0 or not free
        has_next = p < n - 1 or not free
        if p > 0:
            q = seq[p - 1]
            ax, ay = (P0[q, 0], P0[q, 1]) if flip[p - 1] else (P1[q, 0], P1[q, 1])
        else:
            ax, ay = home[0], home[1]
        if p < n - 1:
            q = seq[p + 1]
            bx, by = (P1[q, 0], P1[q, 1]) if flip[p + 1] else (P0[q, 0], P0[q, 1])
        else:
            bx, by = home[0], home[1]
        off = ring_off[s]
        best = np.inf
        now = 0.0
        k = rot[s]
        for v in range(off, ring_off[s + 1]):
            c = 0.0
            if has_prev:
                c += _dist(ax, ay, ring_pts[v, 0], ring_pts[v, 1])
            if has_next:
                c += _dist(ring_pts[v, 0], ring_pts[v, 1], bx, by)
            if c < best - 1e-12:
                best = c
                k = v - off
            if v - off == rot[s]:
                now = c
        saved += now - best
        rot[s] = k
        P0[s, 0] = P1[s, 0] = ring_pts[off + k, 0]
        P0[s, 1] = P1[s, 1] = ring_pts[off + k, 1]
    return saved
