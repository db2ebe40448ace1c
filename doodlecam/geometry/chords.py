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


# --- chords on GRBL's step lattice -------------------------------------------------------------------------
# GRBL plans every block from its target rounded to whole steps, so on 0.2-0.5 mm chords a half step of
# rounding turns a junction by a degree or two and its junction-deviation planner slows there. Choosing each
# vertex among the step positions around it, so that the rounded chords turn smoothly, removes that loss.


@numba.njit(cache=True, nogil=True, inline="always")
def _lround(x):  # pragma: no cover - compiled
    """GRBL's lround: to the nearest, halves away from zero."""
    return np.floor(abs(x) + 0.5) * (1.0 if x >= 0 else -1.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _off2(q, k, ax, ay, dx, dy, dd):  # pragma: no cover - compiled
    """The squared distance of q[k] from the segment from a along d (dd = |d|^2)."""
    px, py = q[k, 0] - ax, q[k, 1] - ay
    s = 0.0
    if dd > 0:
        s = min(max((px * dx + py * dy) / dd, 0.0), 1.0)
    rx, ry = px - s * dx, py - s * dy
    return rx * rx + ry * ry


@numba.njit(cache=True, nogil=True, inline="always")
def _covers(q, i, j, ax, ay, bx, by, room2):  # pragma: no cover - compiled
    """Every point q[i..j] is within sqrt(room2) of the segment a-b."""
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    for k in range(i, j + 1):
        if _off2(q, k, ax, ay, dx, dy, dd) > room2:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _stray(q, i, j):  # pragma: no cover - compiled
    """The largest distance of q[i..j] from the segment q[i]-q[j]."""
    dx, dy = q[j, 0] - q[i, 0], q[j, 1] - q[i, 1]
    worst = 0.0
    for k in range(i, j + 1):
        worst = max(worst, _off2(q, k, q[i, 0], q[i, 1], dx, dy, dx * dx + dy * dy))
    return np.sqrt(worst)


@numba.njit(cache=True, nogil=True)
def _sqrt_reaches(v):  # pragma: no cover - compiled
    """The least x >= 0 whose square root (as rounded) is >= v: sqrt(x) >= v exactly when x >= it."""
    x = v * v
    if np.sqrt(x) >= v:
        while x > 0.0 and np.sqrt(np.nextafter(x, 0.0)) >= v:
            x = np.nextafter(x, 0.0)
    else:
        while np.sqrt(x) < v:
            x = np.nextafter(x, np.inf)
    return x


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _junction_cost(ux, uy, wx, wy, v, v2, acc_x, acc_y, dev):  # pragma: no cover - compiled
    """(1/v_j - 1/v)^4 for GRBL's junction speed v_j (planner.c) between unit directions u and w, 0 when
    v_j >= v: a high power, so one slow junction costs more than several slightly slow ones (close
    junctions share one slow-down). v2 = _sqrt_reaches(v): v_j >= v is v_j^2 >= v2, one root fewer."""
    cos = -(ux * wx + uy * wy)
    if cos < -0.999999:  # straight on
        return 0.0
    vj = 0.0  # a reversal stops
    if cos <= 0.999999:
        jx, jy = wx - ux, wy - uy
        jn = np.sqrt(jx * jx + jy * jy)
        if acc_x == acc_y:  # the smaller of the two quotients below: one division
            ja = acc_x * jn / max(abs(jx), abs(jy))
        else:
            ja = 1e38  # limit_value_by_axis_maximum along the junction vector
            if jx != 0.0:
                ja = min(ja, acc_x * jn / abs(jx))
            if jy != 0.0:
                ja = min(ja, acc_y * jn / abs(jy))
        sd = np.sqrt(max(0.5 * (1.0 - cos), 0.0))
        vj2 = max(ja * dev * sd / (1.0 - sd), 0.0)
        if vj2 >= v2:
            return 0.0
        vj = np.sqrt(vj2)
    return (1.0 / max(vj, 1e-3) - 1.0 / v) ** 4


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _junction_row(ux, uy, wx, wy, n, v, v2, acc_x, acc_y, dev, out):  # pragma: no cover - compiled
    """out[k] = _junction_cost(u, w[k], ...) for k < n, one incoming direction u against n outgoing ones, to
    the bit: every branch of it computed and the result selected (no branch in the loop, and w contiguous, so
    it runs in vector instructions: a junction costs 3 square roots and 3 divisions). The lanes a branch
    would have skipped may divide by zero; their values are not taken."""
    r1v = 1.0 / v
    for k in range(n):
        cos = -(ux * wx[k] + uy * wy[k])
        jx, jy = wx[k] - ux, wy[k] - uy
        jn = np.sqrt(jx * jx + jy * jy)
        if acc_x == acc_y:
            ja = acc_x * jn / max(abs(jx), abs(jy))
        else:
            ja = min(1e38, acc_x * jn / abs(jx)) if jx != 0.0 else 1e38
            ja = min(ja, acc_y * jn / abs(jy)) if jy != 0.0 else ja
        sd = np.sqrt(max(0.5 * (1.0 - cos), 0.0))
        vj2 = max(ja * dev * sd / (1.0 - sd), 0.0)
        turn = cos <= 0.999999  # not a reversal
        vj = np.sqrt(vj2) if turn else 0.0
        c = (1.0 / max(vj, 1e-3) - r1v) ** 4
        out[k] = 0.0 if cos < -0.999999 or (turn and vj2 >= v2) else c


@numba.njit(cache=True, nogil=True, error_model="numpy")  # no division can be by zero (see below)
def snap_chords(q, idx, room, sx, sy, v, acc_x, acc_y, dev, t_in, t_out):  # pragma: no cover - compiled
    """Vertices for the chords q[idx[k]] -> q[idx[k+1]] among GRBL's step positions: (points (m, 2) as
    printed to 3 decimals, found).

    Each vertex is one of the 3 x 3 step positions around its point (the first and last: the nearest one;
    as GRBL rounds the printed value:
    steps/mm ``sx``, ``sy``), within ``room`` of it; each chord, as GRBL rounds its ends, passes within
    ``room`` of every q between its ends, and moves at least one step. Among those, a dynamic programme
    over consecutive vertex pairs picks the one whose junctions cost least for GRBL's planner (feed ``v``
    mm/s, accelerations, junction deviation ``dev``). ``found`` is False when no choice keeps ``room``.
    ``t_in`` / ``t_out``: the unit direction in which the pen arrives at the first vertex / leaves the last one
    without stopping (a kept corner: the neighbouring piece's tangent there), (0, 0) where it stops; the
    junctions there are costed too, so the end chords turn towards the neighbour as far as ``room`` allows.
    Every divisor is non-zero (distinct vertices, a junction that is not straight on, v > 0), so the
    kernel skips Python's zero-division checks.
    """
    m = idx.shape[0]
    C = 9
    P = np.empty((m, C, 2))  # printed
    X = np.empty((m, C, 2))  # where GRBL goes: the printed value rounded to whole steps
    ok = np.zeros((m, C), np.bool_)
    room2 = room * room
    # next to an end the pen passes without stopping, candidates WIDE steps apart: the end chord can lean
    # towards the neighbour by up to ``room``, splitting the corner's turn over three junctions
    wide = max(int(0.8 * room * min(sx, sy)), 1)
    for k in range(m):
        qx, qy = q[idx[k], 0], q[idx[k], 1]
        nx, ny = _lround(qx * sx), _lround(qy * sy)
        stride = 1
        if (k == 1 and k < m - 1 and (t_in[0] != 0.0 or t_in[1] != 0.0)) or \
                (k == m - 2 and k > 0 and (t_out[0] != 0.0 or t_out[1] != 0.0)):
            stride = wide
        c = 0
        for di in range(-stride, stride + 1, stride):
            for dj in range(-stride, stride + 1, stride):
                px, py = np.round((nx + di) / sx, 3), np.round((ny + dj) / sy, 3)
                ex, ey = _lround(px * sx) / sx, _lround(py * sy) / sy
                P[k, c, 0], P[k, c, 1], X[k, c, 0], X[k, c, 1] = px, py, ex, ey
                ok[k, c] = (ex - qx) ** 2 + (ey - qy) ** 2 <= room2
                if (k == 0 or k == m - 1) and c != 4:
                    ok[k, c] = False  # the ends on the nearest step: a stroke that goes on from them meets them
                c += 1
    out = np.empty((m, 2))
    if m < 2:
        return out, False
    moved = np.empty((m, C))  # how far each candidate is from its point
    for k in range(m):
        for c in range(C):
            moved[k, c] = np.sqrt((X[k, c, 0] - q[idx[k], 0]) ** 2 + (X[k, c, 1] - q[idx[k], 1]) ** 2)
    far = np.empty(m - 1)  # how far q strays from each greedy chord
    for k in range(m - 1):
        far[k] = _stray(q, idx[k], idx[k + 1])
    sure = room * (1.0 - 1e-9)  # far + moved below it: covered beyond any rounding of _covers' own sums
    INF = 1e300
    cost = np.full((C, C), INF)  # cost[i, j]: vertex k-1 at candidate i, vertex k at j
    back = np.zeros((m, C, C), np.int8)
    new = np.empty((C, C))
    U = np.zeros((C, C, 2))  # unit direction of chord k-1 from candidate i to j
    W = np.zeros((C, C, 2))  # of chord k from j to n
    live = np.empty(C, np.int64)
    valid = np.empty(C, np.int64)
    best_t, bi_t = np.empty(C), np.empty(C, np.int64)
    wx, wy, jc = np.empty(C), np.empty(C), np.empty(C)  # the directions W[j, n] of the valid n, their junctions
    v2 = _sqrt_reaches(v)
    for k in range(0, m - 1):
        new[:, :] = INF
        for j in range(C):
            if not ok[k, j]:
                continue
            no = 0  # the candidates i of vertex k-1 before j: live[:no], in index order; i0 the first cheapest
            i0 = -1
            if k > 0:
                for i in range(C):
                    if cost[i, j] < INF:
                        live[no] = i
                        no += 1
                        if i0 < 0 or cost[i, j] < cost[i0, j]:
                            i0 = i
            nv = 0  # the candidates n that vertex k+1 can take after j: valid[:nv]
            for n in range(C):
                if not ok[k + 1, n] or (X[k, j, 0] == X[k + 1, n, 0] and X[k, j, 1] == X[k + 1, n, 1]):
                    continue
                # a chord whose ends moved at most e from the greedy chord's strays at most e further from q
                if far[k] + max(moved[k, j], moved[k + 1, n]) > sure and not _covers(
                        q, idx[k], idx[k + 1], X[k, j, 0], X[k, j, 1], X[k + 1, n, 0], X[k + 1, n, 1], room2):
                    continue
                dx, dy = X[k + 1, n, 0] - X[k, j, 0], X[k + 1, n, 1] - X[k, j, 1]
                d = np.sqrt(dx * dx + dy * dy)
                W[j, n, 0], W[j, n, 1] = dx / d, dy / d
                valid[nv] = n
                nv += 1
                if k == 0:  # the first chord: a junction only where the pen arrives moving
                    new[j, n] = 0.0
                    if t_in[0] != 0.0 or t_in[1] != 0.0:
                        new[j, n] = _junction_cost(t_in[0], t_in[1], W[j, n, 0], W[j, n, 1], v, v2, acc_x, acc_y,
                                                   dev)
            if k == 0 or no == 0:
                continue
            # Each n takes the first i (in index order) of least cost[i, j] + junction. A junction costs >= 0, so
            # an i whose cost alone is above every n's cost through i0 (the first cheapest) cannot win: its row
            # is skipped. The others are costed a row at a time (one i against every n: _junction_row, in vector
            # instructions), which costs less than choosing single pairs (bookkeeping, not arithmetic, was the
            # cost); the same choice to the bit.
            for t in range(nv):
                wx[t], wy[t] = W[j, valid[t], 0], W[j, valid[t], 1]
            _junction_row(U[i0, j, 0], U[i0, j, 1], wx, wy, nv, v, v2, acc_x, acc_y, dev, jc)
            c0, top = cost[i0, j], 0.0
            for t in range(nv):
                best_t[t], bi_t[t] = c0 + jc[t], i0
                top = max(top, best_t[t])
            for r in range(no):
                i = live[r]
                ci = cost[i, j]
                if i == i0 or ci > top:
                    continue
                _junction_row(U[i, j, 0], U[i, j, 1], wx, wy, nv, v, v2, acc_x, acc_y, dev, jc)
                for t in range(nv):
                    c = ci + jc[t]
                    if c < best_t[t] or (c == best_t[t] and i < bi_t[t]):
                        best_t[t], bi_t[t] = c, i
            for t in range(nv):
                new[j, valid[t]] = best_t[t]
                back[k + 1, j, valid[t]] = bi_t[t]
        cost[:, :] = new
        U[:, :, :] = W
    best, bj, bn = INF, 0, 0
    moving = t_out[0] != 0.0 or t_out[1] != 0.0  # the last chord's junction into the next piece
    for j in range(C):
        for n in range(C):
            c = cost[j, n]
            if moving and c < INF:
                c += _junction_cost(U[j, n, 0], U[j, n, 1], t_out[0], t_out[1], v, v2, acc_x, acc_y, dev)
            if c < best:
                best, bj, bn = c, j, n
    if best >= INF:
        return out, False
    ch = np.empty(m, np.int64)
    ch[m - 1], ch[m - 2] = bn, bj
    for k in range(m - 1, 1, -1):
        ch[k - 2] = back[k, ch[k - 1], ch[k]]
    for k in range(m):
        out[k, 0], out[k, 1] = P[k, ch[k], 0], P[k, ch[k], 1]
    return out, True
