"""GRBL's planner model (doodlecam.link.grbl.timing._segment_time_numpy) compiled, block by block.

The G-code post times every chord level of every stroke with it (~2·10^6 blocks for a 20 000-path drawing):
NumPy's passes over all blocks at once cost ~40 arrays of temporaries and 0.3 s. Each number here is made
by the same operations in the same order as the NumPy version (sums of the axes left to right, as NumPy
reduces a row of three; np.minimum/np.maximum/np.clip's NaN rules), so the times are the same to the bit
(tests/test_grbl_kernel.py holds them to it). Imported only when a program is timed (numba is heavy).
"""

import numba
import numpy as np

SOME_LARGE_VALUE = 1.0e38


@numba.njit(cache=True, nogil=True, inline="always")
def _min(a, b):  # pragma: no cover - compiled
    """np.minimum of two floats (a NaN wins)."""
    return a if (a <= b or a != a) else b


@numba.njit(cache=True, nogil=True, inline="always")
def _max(a, b):  # pragma: no cover - compiled
    """np.maximum of two floats (a NaN wins)."""
    return a if (a >= b or a != a) else b


@numba.njit(cache=True, nogil=True, inline="always")
def _limit(values, u, k, den):  # pragma: no cover - compiled
    """timing._axis_limit of row k of u / den (GRBL's limit_value_by_axis_maximum)."""
    out = 0.0
    for j in range(u.shape[1]):
        x = u[k, j] / den
        r = values[j] / abs(x) if x != 0 else SOME_LARGE_VALUE
        out = r if j == 0 else _min(out, r)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def block_times(points, feeds, rest, spm, rate, acc, dev, W):  # pragma: no cover - compiled
    """The time of each block points[i] -> points[i + 1] (timing._segment_time_numpy, the same arithmetic)."""
    m, D = points.shape
    nb = m - 1
    out = np.zeros(nb)
    # targets on whole steps (timing.to_steps), then each block's delta and length
    P = np.empty((m, D))
    for i in range(m):
        for j in range(D):
            x = points[i, j] * spm[j]
            sg = 1.0 if x > 0 else (-1.0 if x < 0 else (0.0 if x == 0 else x))  # np.sign
            P[i, j] = sg * np.floor(abs(x) + 0.5) / spm[j]
    kidx = np.empty(nb, np.int64)
    starts = np.zeros(nb, np.bool_)
    L = np.empty(nb)
    u = np.empty((nb, D))
    n = 0
    run = 0
    last = -1
    for i in range(nb):
        if rest[i]:
            run += 1
        s2 = 0.0
        for j in range(D):
            dj = P[i + 1, j] - P[i, j]
            u[n, j] = dj
            s2 = dj * dj if j == 0 else s2 + dj * dj
        length = np.sqrt(s2)
        if length > 0:  # GRBL drops zero-length blocks
            kidx[n] = i
            L[n] = length
            starts[n] = n == 0 or run != last  # a rest start passes on to the next kept block
            last = run
            n += 1
    if n == 0:
        return out
    a = np.empty(n)
    nominal = np.empty(n)
    n2 = np.empty(n)
    for k in range(n):
        for j in range(D):
            u[k, j] = u[k, j] / L[k]
        a[k] = _limit(acc, u, k, 1.0)
        nominal[k] = _min(feeds[kidx[k]], _limit(rate, u, k, 1.0))
        n2[k] = nominal[k] * nominal[k]
    # junction limits: block k's entry, from u[k-1] and u[k]; the first block starts at rest
    me = np.empty(n)
    me[0] = 0.0
    ju = np.empty((1, D))
    for k in range(1, n):
        c = 0.0
        jn2 = 0.0
        for j in range(D):
            p = u[k - 1, j] * u[k, j]
            c = p if j == 0 else c + p
            ju[0, j] = u[k, j] - u[k - 1, j]
            jn2 = ju[0, j] * ju[0, j] if j == 0 else jn2 + ju[0, j] * ju[0, j]
        cos = -c
        jn = np.sqrt(jn2)
        ja = _limit(acc, ju, 0, jn if jn > 0 else 1.0)
        t = 0.5 * (1.0 - cos)
        t = t if t != t else (t if t > 0.0 else 0.0)  # np.clip(t, 0, 1)
        t = t if t != t else (t if t < 1.0 else 1.0)
        sin_d2 = np.sqrt(t)
        vj2 = _max(0.0, ja * dev * sin_d2 / (1.0 - sin_d2))
        if cos > 0.999999:
            vj2 = 0.0
        elif cos < -0.999999:
            vj2 = SOME_LARGE_VALUE
        me[k] = _min(vj2, _min(n2[k], n2[k - 1]))
    for k in range(n):
        if starts[k]:
            me[k] = 0.0
    # backward pass over every window: block i's exit at most the entry of block i+1 from which blocks up to
    # i+W-1 can still stop (past the program's end: rest)
    two_aL = np.empty(n)
    for k in range(n):
        two_aL[k] = 2.0 * a[k] * L[k]
    limit = np.empty(n)
    for i in range(n):
        cur = 0.0
        for kk in range(W - 1, 0, -1):
            r = i + kk
            cur = _min(me[r] if r < n else 0.0, cur + (two_aL[r] if r < n else 0.0))
        limit[i] = cur
    # forward pass: exit_i^2 = min(limit_i, exit_{i-1}^2 + 2 a_i L_i) from rest, as the min-plus scan
    C = 0.0
    low = 0.0
    exit2 = np.empty(n)
    for k in range(n):
        C = two_aL[k] if k == 0 else C + two_aL[k]
        low = limit[k] - C if k == 0 else _min(low, limit[k] - C)
        exit2[k] = _max(C + _min(0.0, low), 0.0)
    for k in range(n):
        entry2 = 0.0 if (k == 0 or starts[k]) else exit2[k - 1]
        vi, vf, vn = np.sqrt(entry2), np.sqrt(exit2[k]), nominal[k]
        d1 = (n2[k] - entry2) / (2 * a[k])
        d2 = (n2[k] - exit2[k]) / (2 * a[k])
        cruise = L[k] - d1 - d2
        if cruise >= 0:
            out[kidx[k]] = (vn - vi) / a[k] + (vn - vf) / a[k] + (cruise / vn if cruise > 0 else 0.0)
        else:
            vp = np.sqrt(_max((2 * a[k] * L[k] + entry2 + exit2[k]) / 2, _max(entry2, exit2[k])))
            out[kidx[k]] = (vp - vi) / a[k] + (vp - vf) / a[k]
    return out
