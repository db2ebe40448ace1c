"""The G-code post's chord search (feeds = cap) over many strokes per compiled call.

A generated drawing has 10^4-10^5 strokes and the search tries 3-4 chord levels on each: one Python call per
stroke and level (dense points, greedy chords, rounding, snapping, GRBL's dropped blocks, the serial check) cost
more than the work. These kernels take every stroke's arrays at once, concatenated with offsets (stroke s is
rows ``off[s]:off[s + 1]``), and compute exactly what the per-stroke NumPy code did, operation for operation,
so the G-code is byte-identical (tests/test_gcode_batch.py holds them to the per-stroke reference).
"""

import numba
import numpy as np

from doodlecam.geometry.chords import greedy_chords, one_step_apart, snap_chords
from doodlecam.geometry.kernels import _point, bspline_eval

# interior probes per segment when refining: 1/8 .. 7/8 of it, as np.linspace(0, 1, 9)[1:-1]; the middle first,
# where a segment's chord strays most, as a segment is split once one probe strays too far
_PROBE_ORDER = (4, 2, 6, 1, 3, 5, 7)


@numba.njit(cache=True, nogil=True)
def _grow(a, n):  # pragma: no cover - compiled
    """a (m, 2) with room for at least n rows (doubling), its rows kept."""
    if n <= a.shape[0]:
        return a
    b = np.empty((max(n, 2 * a.shape[0]), 2))
    b[:a.shape[0]] = a
    return b


@numba.njit(cache=True, nogil=True)
def _refine_one(c, k, u, tol, max_rounds):  # pragma: no cover - compiled
    """u split at the middle of every segment whose chord strays more than ``tol`` from the spline (control
    points c, degree k), round after round (postprocessors.gcode._refine): (u, the spline at u). A segment
    found within ``tol`` stays as it is, so only the halves of split ones are probed again; each point of u is
    evaluated once (a segment's ends are its neighbours' too)."""
    nseg = c.shape[0] - k
    N, left, right = np.empty(k + 1), np.empty(k + 1), np.empty(k + 1)
    done = np.zeros(u.shape[0] - 1, np.bool_)  # segment i is within tol
    p = np.empty((u.shape[0], 2))
    bspline_eval(c, k, nseg, u, p)  # as Spline.__call__
    for _ in range(max_rounds):
        n = u.shape[0]
        bad = np.zeros(n - 1, np.bool_)
        nbad = 0
        for i in range(n - 1):
            if done[i]:
                continue
            ax, ay = p[i, 0], p[i, 1]
            bx, by = p[i + 1, 0], p[i + 1, 1]
            dx, dy = bx - ax, by - ay
            dd = max(dx * dx + dy * dy, 1e-300)
            err = 0.0
            for r in _PROBE_ORDER:  # only whether one strays beyond tol counts: stop at the first that does
                x = u[i] + (u[i + 1] - u[i]) * (r * 0.125)
                qx, qy = _point(c, k, nseg, min(max(x, 0.0), 1.0), N, left, right)
                s = min(max(((qx - ax) * dx + (qy - ay) * dy) / dd, 0.0), 1.0)
                ex, ey = qx - (ax + s * dx), qy - (ay + s * dy)
                err = max(err, np.sqrt(ex * ex + ey * ey))
                if err > tol:
                    break
            if err > tol:
                bad[i] = True
                nbad += 1
            else:
                done[i] = True
        if nbad == 0:
            break
        v = np.empty(n + nbad)
        pv = np.empty((n + nbad, 2))
        dv = np.zeros(n + nbad - 1, np.bool_)
        m = 0
        for i in range(n):
            v[m], pv[m, 0], pv[m, 1] = u[i], p[i, 0], p[i, 1]
            if i < n - 1:
                dv[m] = done[i]
            m += 1
            if i < n - 1 and bad[i]:
                v[m] = 0.5 * (u[i] + u[i + 1])
                pv[m, 0], pv[m, 1] = _point(c, k, nseg, min(max(v[m], 0.0), 1.0), N, left, right)
                m += 1
        u, p, done = v, pv, dv
    return u, p


@numba.njit(cache=True, nogil=True)
def dense_points(ctrl, coff, degree, u0, uoff, tol, max_rounds):  # pragma: no cover - compiled
    """Every stroke's dense points: its spline (control points ctrl[coff[s]:coff[s+1]], ``degree[s]``) at the
    parameters u0[uoff[s]:uoff[s+1]] refined until each chord is within ``tol`` of it. (points, offsets)."""
    ns = coff.shape[0] - 1
    out = np.empty((max(uoff[-1], 1), 2))
    off = np.zeros(ns + 1, np.int64)
    for s in range(ns):
        c = ctrl[coff[s]:coff[s + 1]]
        k = degree[s]
        u, p = _refine_one(c, k, u0[uoff[s]:uoff[s + 1]].copy(), tol, max_rounds)
        n = u.shape[0]
        out = _grow(out, off[s] + n)
        out[off[s]:off[s] + n] = p
        off[s + 1] = off[s] + n
    return out[:off[ns]], off


@numba.njit(cache=True, nogil=True)
def _drop_unmoved(p, sx, sy):  # pragma: no cover - compiled
    """p without the points that round to the same motor steps as the last kept one; the last point is kept in
    place of the one before (postprocessors.gcode._one_step_apart)."""
    n = p.shape[0]
    st = np.empty((n, 2), np.int64)
    for r in range(n):
        st[r, 0], st[r, 1] = np.int64(np.rint(p[r, 0] * sx)), np.int64(np.rint(p[r, 1] * sy))
    keep = one_step_apart(st) if n else np.ones(0, np.bool_)
    if n > 1 and not keep[-1]:
        j = n - 1
        while not keep[j]:
            j -= 1
        if j > 0:
            keep[j] = False
            keep[-1] = True
    return p[keep]


@numba.njit(cache=True, nogil=True)
def cap_candidates(q, qoff, which, level, rooms, r0, sx, sy, v, acc_x, acc_y, dev, snap, t_in,
                   t_out):  # pragma: no cover - compiled
    """Candidate c: stroke which[c]'s longest chords within rooms[level[c]] of its dense points, their vertices
    on GRBL's steps (snap_chords, within r0; rounded to 3 decimals where that fails or ``snap`` is False),
    without the blocks GRBL drops (feed v[c] mm/s). t_in[s] / t_out[s]: the direction the pen arrives / leaves
    stroke s in without stopping, (0, 0) where it stops (snap_chords). (points, offsets) as
    postprocessors.gcode's search made them one stroke at a time."""
    nc = which.shape[0]
    out = np.empty((max(4 * nc, 1), 2))
    off = np.zeros(nc + 1, np.int64)
    for c in range(nc):
        s = which[c]
        qs = q[qoff[s]:qoff[s + 1]]
        idx = greedy_chords(qs, rooms[level[c]])
        near = np.empty((idx.shape[0], 2))
        dot = True
        for r in range(idx.shape[0]):
            near[r, 0], near[r, 1] = np.round(qs[idx[r], 0], 3), np.round(qs[idx[r], 1], 3)
            dot = dot and np.rint(near[r, 0] * sx) == np.rint(near[0, 0] * sx) and \
                np.rint(near[r, 1] * sy) == np.rint(near[0, 1] * sy)
        p = near
        if not dot and snap:
            snapped, found = snap_chords(qs, idx, r0, sx, sy, v[c], acc_x, acc_y, dev, t_in[s], t_out[s])
            if found:
                p = snapped
        p = _drop_unmoved(p, sx, sy)
        out = _grow(out, off[c] + p.shape[0])
        out[off[c]:off[c] + p.shape[0]] = p
        off[c + 1] = off[c] + p.shape[0]
    return out[:off[nc]], off


@numba.njit(cache=True, nogil=True, inline="always")
def _num_len(x):  # pragma: no cover - compiled
    """len(postprocessors.gcode._num(x)) for x printed to 3 decimals (x == k / 1000 exactly); -1 otherwise."""
    k = np.rint(x * 1000.0)
    if k / 1000.0 != x or abs(k) > 1e15:
        return -1
    if k == 0:
        return 1  # "0", also for -0
    a = np.int64(abs(k))
    n = 1 if k < 0 else 0
    ip, fp = a // 1000, a % 1000
    n += 1
    while ip >= 10:
        ip //= 10
        n += 1
    if fp:
        d = 3
        while fp % 10 == 0:
            fp //= 10
            d -= 1
        n += 1 + d
    return n


@numba.njit(cache=True, nogil=True)
def serial_keeps_up(pts, poff, bt, boff, baud, window):  # pragma: no cover - compiled
    """Per candidate (points pts[poff[c]:poff[c+1]], its blocks' times bt[boff[c]:boff[c] + n - 1]): 1 if a
    sender at ``baud`` keeps GRBL's ``window`` planned blocks fed through it, 0 if not, -1 if a coordinate is
    not printed to 3 decimals (the caller formats it). As postprocessors.gcode._serial_keeps_up."""
    nc = poff.shape[0] - 1
    res = np.ones(nc, np.int8)
    for c in range(nc):
        nb = poff[c + 1] - poff[c] - 1
        if baud <= 0 or nb < window:
            continue
        slack = np.empty(nb + 1)
        slack[0] = 0.0
        acc = 0.0
        for r in range(nb):
            lx, ly = _num_len(pts[poff[c] + r + 1, 0]), _num_len(pts[poff[c] + r + 1, 1])
            if lx < 0 or ly < 0:
                res[c] = -1
                break
            acc = acc + (bt[boff[c] + r] - (5 + lx + ly) * 10.0 / baud)  # "G1X" x "Y" y "\n"
            slack[r + 1] = acc
        if res[c] < 0:
            continue
        worst = np.inf
        for r in range(nb + 1 - window):
            worst = min(worst, slack[r + window] - slack[r])
        res[c] = 1 if worst >= 0.0 else 0
    return res
