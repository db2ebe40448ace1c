"""Compiled chord search: the fewest chords through a dense polyline, each within a tolerance.

The G-code post runs this for every stroke and several tolerances (GRBL's planner
is timed on each), so it is compiled: a generated drawing has 10^4-10^5 strokes.
"""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def chord_ok(q, i, j, tol2):  # pragma: no cover - compiled
    """Every point of q strictly between i and j is within sqrt(tol2) of the segment q[i]-q[j]."""
    ax, ay = q[i, 0], q[i, 1]
    dx, dy = q[j, 0] - ax, q[j, 1] - ay
    dd = dx * dx + dy * dy
    for k in range(i + 1, j):
        px, py = q[k, 0] - ax, q[k, 1] - ay
        s = px * dx + py * dy
        if dd > 0:
            s = min(max(s / dd, 0.0), 1.0)
        rx, ry = px - s * dx, py - s * dy
        if rx * rx + ry * ry > tol2:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _furthest(q, i, tol2, lo, n, step):  # pragma: no cover - compiled
    """The largest j < n with chord_ok(i, j), searching up from lo (ok) by doubling steps, then bisecting."""
    while lo + step < n and chord_ok(q, i, lo + step, tol2):
        lo += step
        step *= 2
    hi = min(lo + step, n)  # ok at lo, not at hi (or hi = n)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if chord_ok(q, i, mid, tol2):
            lo = mid
        else:
            hi = mid
    return lo


@numba.njit(cache=True, nogil=True)
def greedy_chords(q, tol):  # pragma: no cover - compiled
    """Indices of the vertices of the longest chords through q (n, 2) from q[0] to q[-1], each within ``tol``.

    From each vertex the chord reaches as far along q as it can (a search that
    starts from the previous chord's reach, grows it exponentially, then bisects),
    so the polyline has the fewest vertices whenever a chord within the tolerance
    has every sub-chord within it too (pieces without an inflection).
    """
    n = q.shape[0]
    out = np.empty(max(n, 1), np.int64)
    out[0] = 0
    k = 1
    i = 0
    tol2 = tol * tol
    reach = 1
    while i < n - 1:
        guess = min(i + reach, n - 1)
        if chord_ok(q, i, guess, tol2):  # always for i + 1: no point between
            lo = _furthest(q, i, tol2, guess, n, max(reach // 2, 1))
        else:
            lo = _furthest(q, i, tol2, i + 1, guess, 1)
        out[k] = lo
        k += 1
        reach = lo - i
        i = lo
    return out[:k]


@numba.njit(cache=True, nogil=True)
def one_step_apart(st):  # pragma: no cover - compiled
    """Keep-mask of points (n, 2) in whole steps that differ from the last kept one (sequential)."""
    n = st.shape[0]
    keep = np.ones(n, np.bool_)
    lx, ly = st[0, 0], st[0, 1]
    for k in range(1, n):
        if st[k, 0] == lx and st[k, 1] == ly:
            keep[k] = False
        else:
            lx, ly = st[k, 0], st[k, 1]
    return keep
