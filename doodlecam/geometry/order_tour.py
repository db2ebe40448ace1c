"""The tour the ordering's local search edits, with moves that cost O(shorter side).

What the search sees (logical nodes): 0 is home, p + 1 the stroke at tour
position p, n + 1 home again. What is stored: a ring of N = n + 1 slots, one
of them home's, read from home's slot (``g[0]``) in a direction (``g[1]``,
+1 or -1), with a reversal bit (``g[2]``: every stroke is drawn the other way
than its slot says). A tour with a home is a cycle through home, and so is
one with a free start and end (home is then a point whose legs cost
nothing), so:

* reversing nodes lo..hi (2-opt) gives the same cycle as reversing the rest
  of the ring and reading it the other way: the shorter of the two is
  rewritten, and home's slot, the direction and the reversal bit follow;
* moving a run between nodes k and k + 1 (Or-opt) shifts either the stretch
  from the run to k or the one from k + 1 back to the run: the shorter.

The search sees exactly the tour it would see if the run itself were always
rewritten in a plain array, so it makes the same moves; a move costs
O(min(m, n - m)) instead of O(m). Compiled by numba, cached on disk.
"""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def tour_ring(P0, P1, seq, flip, home):  # pragma: no cover - compiled
    """The ring of the tour ``seq`` / ``flip``: (pseq, pflip, pent, pext, pos, g).

    pseq[slot]: stroke (-1 home); pflip: drawn backwards as stored; pent /
    pext: its entry / exit point as stored; pos[stroke]: its slot; g: home's
    slot, direction, reversal bit. Starts as the plain array: slot p + 1 is
    position p, home in slot 0.
    """
    n = seq.shape[0]
    N = n + 1
    pseq = np.empty(N, np.int64)
    pflip = np.zeros(N, np.bool_)
    pent = np.empty((N, 2))
    pext = np.empty((N, 2))
    pos = np.empty(n, np.int64)
    g = np.zeros(3, np.int64)
    g[1] = 1
    buf_s = np.empty(N, np.int64)
    buf_f = np.zeros(N, np.bool_)
    buf_s[0] = -1
    buf_s[1:] = seq
    buf_f[1:] = flip
    tour_write(P0, P1, home, pseq, pflip, pent, pext, pos, g, 0, N, buf_s, buf_f)
    return pseq, pflip, pent, pext, pos, g


@numba.njit(cache=True, nogil=True)
def tour_read(pseq, pflip, g, seq, flip):  # pragma: no cover - compiled
    """Write the ring back into the plain arrays ``seq`` / ``flip`` (tour order)."""
    n = seq.shape[0]
    tour_get(pseq, pflip, g, 1, n, n + 1, seq, flip, 0)


@numba.njit(cache=True, nogil=True, inline="always")
def slot(off, d, q, N):  # pragma: no cover - compiled
    """The slot of node q (0 <= q < 2N; node N is home again); off, d: g[0], g[1].

    Scalars, not g: a small function that takes arrays pays their reference
    counts on every call."""
    if q >= N:
        q -= N
    if d > 0:
        s = off + q
        if s >= N:
            s -= N
    else:
        s = off - q
        if s < 0:
            s += N
    return s


@numba.njit(cache=True, nogil=True, inline="always")
def _next(s, d, N):  # pragma: no cover - compiled
    """The slot one step (d = +1 or -1) from slot s around a ring of N."""
    s += d
    if s == N:
        return 0
    if s < 0:
        return N - 1
    return s


@numba.njit(cache=True, nogil=True)
def node(off, d, s, N):  # pragma: no cover - compiled
    """The node (0 = home .. n) held in slot s."""
    q = s - off if d > 0 else off - s
    if q < 0:
        q += N
    return q


@numba.njit(cache=True, nogil=True)
def entry(pent, pext, g, q, N):  # pragma: no cover - compiled
    """Where the pen enters node q: (x, y)."""
    s = slot(g[0], g[1], q, N)
    if g[2]:
        return pext[s, 0], pext[s, 1]
    return pent[s, 0], pent[s, 1]


@numba.njit(cache=True, nogil=True)
def exit_(pent, pext, g, q, N):  # pragma: no cover - compiled
    """Where the pen leaves node q: (x, y)."""
    return entry(pext, pent, g, q, N)


@numba.njit(cache=True, nogil=True)
def stroke_at(pseq, g, p, N):  # pragma: no cover - compiled
    """The stroke at tour position p (node p + 1)."""
    return pseq[slot(g[0], g[1], p + 1, N)]


@numba.njit(cache=True, nogil=True)
def tour_get(pseq, pflip, g, q0, m, N, out_s, out_f, at):  # pragma: no cover - compiled
    """Nodes q0 .. q0 + m - 1 (around the ring) into out_s / out_f from index at, tour flips."""
    s = slot(g[0], g[1], q0 % N, N)
    d = g[1]
    r = g[2] == 1
    for t in range(m):
        out_s[at + t] = pseq[s]
        out_f[at + t] = pflip[s] != r
        s = _next(s, d, N)


@numba.njit(cache=True, nogil=True)
def tour_write(P0, P1, home, pseq, pflip, pent, pext, pos, g, q0, m, buf_s, buf_f):  # pragma: no cover - compiled
    """Nodes q0 .. q0 + m - 1 become buf_s / buf_f[:m] (tour flips); home may move."""
    N = pseq.shape[0]
    h = _store(P0, P1, home, pseq, pflip, pent, pext, pos, slot(g[0], g[1], q0 % N, N), g[1], g[2] == 1, m,
               buf_s, buf_f)
    if h >= 0:
        g[0] = h


@numba.njit(cache=True, nogil=True)
def _store(P0, P1, home, pseq, pflip, pent, pext, pos, s, d, r, m, buf_s, buf_f):  # pragma: no cover - compiled
    """Slots s, s + d, ... (m of them) get buf_s / buf_f[:m] (tour flips, reversal bit r).
    Returns the slot home went to, -1 if not among them."""
    N = pseq.shape[0]
    h = -1
    for t in range(m):  # written out: a call per stroke costs more than the store
        i = buf_s[t]
        pf = buf_f[t] != r
        pseq[s] = i
        pflip[s] = pf
        if i < 0:
            h = s
            pent[s, 0] = pext[s, 0] = home[0]
            pent[s, 1] = pext[s, 1] = home[1]
        else:
            pos[i] = s
            if pf:
                pent[s, 0], pent[s, 1], pext[s, 0], pext[s, 1] = P1[i, 0], P1[i, 1], P0[i, 0], P0[i, 1]
            else:
                pent[s, 0], pent[s, 1], pext[s, 0], pext[s, 1] = P0[i, 0], P0[i, 1], P1[i, 0], P1[i, 1]
        s = _next(s, d, N)
    return h


@numba.njit(cache=True, nogil=True)
def _turn(buf_s, buf_f, a, m):  # pragma: no cover - compiled
    """Reverse buf[a : a + m] in place, each one drawn the other way."""
    lo = a
    hi = a + m - 1
    while lo < hi:
        t = buf_s[lo]
        buf_s[lo] = buf_s[hi]
        buf_s[hi] = t
        tf = buf_f[lo]
        buf_f[lo] = not buf_f[hi]
        buf_f[hi] = not tf
        lo += 1
        hi -= 1
    if lo == hi:
        buf_f[lo] = not buf_f[lo]


@numba.njit(cache=True, nogil=True)
def _flip_slots(pseq, pflip, pent, pext, pos, g, q0, m):  # pragma: no cover - compiled
    """Reverse the m slots from node q0 on, in place, each stroke turned round:
    its entry and exit points swap, so nothing is looked up again."""
    N = pseq.shape[0]
    d = g[1]
    a = slot(g[0], d, q0 % N, N)
    b = slot(g[0], d, (q0 + m - 1) % N, N)
    h = -1
    for _ in range(m // 2):
        i, j = pseq[b], pseq[a]
        pseq[a], pseq[b] = i, j
        pflip[a], pflip[b] = not pflip[b], not pflip[a]
        ex, ey, nx, ny = pext[a, 0], pext[a, 1], pent[a, 0], pent[a, 1]
        pent[a, 0], pent[a, 1], pext[a, 0], pext[a, 1] = pext[b, 0], pext[b, 1], pent[b, 0], pent[b, 1]
        pent[b, 0], pent[b, 1], pext[b, 0], pext[b, 1] = ex, ey, nx, ny
        if i >= 0:
            pos[i] = a
        else:
            h = a
        if j >= 0:
            pos[j] = b
        else:
            h = b
        a = _next(a, d, N)
        b = _next(b, -d, N)
    if m % 2 == 1:  # the middle one turns round where it is
        pflip[a] = not pflip[a]
        pent[a, 0], pent[a, 1], pext[a, 0], pext[a, 1] = pext[a, 0], pext[a, 1], pent[a, 0], pent[a, 1]
    if h >= 0:
        g[0] = h


@numba.njit(cache=True, nogil=True)
def _shift(pseq, pflip, pent, pext, pos, g, q0, m, by):  # pragma: no cover - compiled
    """Move the m slots from node q0 on by ``by`` slots along the ring (in place)."""
    N = pseq.shape[0]
    d = g[1]
    h = -1
    step = d if by < 0 else -d  # copy the leading end first
    src = slot(g[0], d, q0 % N, N) if by < 0 else slot(g[0], d, (q0 + m - 1) % N, N)
    dst = src + d * by
    if dst >= N:
        dst -= N
    elif dst < 0:
        dst += N
    for _ in range(m):
        i = pseq[src]
        pseq[dst] = i
        pflip[dst] = pflip[src]
        pent[dst, 0], pent[dst, 1], pext[dst, 0], pext[dst, 1] = pent[src, 0], pent[src, 1], pext[src, 0], pext[src, 1]
        if i >= 0:
            pos[i] = dst
        else:
            h = dst
        src = _next(src, step, N)
        dst = _next(dst, step, N)
    if h >= 0:
        g[0] = h


@numba.njit(cache=True, nogil=True)
def tour_reverse(P0, P1, home, pseq, pflip, pent, pext, pos, g, lo, hi, buf_s, buf_f):  # pragma: no cover - compiled
    """Reverse nodes lo..hi (1 <= lo <= hi <= n), each stroke drawn the other way (2-opt)."""
    N = pseq.shape[0]
    m = hi - lo + 1
    if 2 * m <= N:
        _flip_slots(pseq, pflip, pent, pext, pos, g, lo, m)
        return
    # The rest of the ring reversed as stored, then read the other way round.
    _flip_slots(pseq, pflip, pent, pext, pos, g, hi + 1, N - m)
    g[1] = -g[1]
    g[2] = 1 - g[2]


@numba.njit(cache=True, nogil=True)
def tour_move(P0, P1, home, pseq, pflip, pent, pext, pos, g, s, e, k, rev, buf_s, buf_f):  # pragma: no cover - compiled
    """Move nodes s..e (at most 3) between nodes k and k + 1 (k outside s - 1..e), reversed if rev (Or-opt).

    The ring is run R, then Y (up to node k), then Z (from k + 1 back to R):
    R Y Z becomes Y R Z, either Y shifted back over R or Z shifted on over it."""
    N = pseq.shape[0]
    m = e - s + 1
    ly = (k - e) % N
    lz = (s - 1 - k) % N
    d = g[1]
    tour_get(pseq, pflip, g, s, m, N, buf_s, buf_f, 0)  # keep the run
    if rev:
        _turn(buf_s, buf_f, 0, m)
    if ly <= lz:
        a = slot(g[0], d, (s + ly) % N, N)  # where the run goes, before home may move
        _shift(pseq, pflip, pent, pext, pos, g, e + 1, ly, -m)
    else:
        a = slot(g[0], d, (k + 1) % N, N)
        _shift(pseq, pflip, pent, pext, pos, g, k + 1, lz, m)
    _store(P0, P1, home, pseq, pflip, pent, pext, pos, a, g[1], g[2] == 1, m, buf_s, buf_f)  # the run: no home
