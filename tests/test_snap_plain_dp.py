"""chords.snap_chords prunes its dynamic programme (it costs a junction only where the predecessor can still win)
and costs the junctions in vector batches. Here a plain dynamic programme written out in Python, every
predecessor of every pair costed one junction at a time with the scalar _junction_cost, must choose exactly the
same step positions, ties included: a pruning that skipped a pair that could win, or broke a tie another way,
fails here even where the total cost stays the same."""

from __future__ import annotations

import numpy as np
import pytest

from doodlecam.geometry.chords import _covers, _junction_cost, _lround, _sqrt_reaches, _stray, greedy_chords, \
    snap_chords

SX, SY = 80.0, 80.0  # steps/mm (the doodlebot's)
INF = 1e300


def _candidates(q, idx, room, t_in, t_out):
    """The kernel's 3 x 3 step positions per vertex: printed (m, 9, 2), as GRBL goes (m, 9, 2), allowed (m, 9)."""
    m = len(idx)
    P, X, ok = np.empty((m, 9, 2)), np.empty((m, 9, 2)), np.zeros((m, 9), bool)
    wide = max(int(0.8 * room * min(SX, SY)), 1)
    for k in range(m):
        qx, qy = q[idx[k]]
        nx, ny = _lround(qx * SX), _lround(qy * SY)
        stride = wide if ((k == 1 and k < m - 1 and any(t_in)) or (k == m - 2 and k > 0 and any(t_out))) else 1
        c = 0
        for di in (-stride, 0, stride):
            for dj in (-stride, 0, stride):
                px, py = np.round((nx + di) / SX, 3), np.round((ny + dj) / SY, 3)
                ex, ey = _lround(px * SX) / SX, _lround(py * SY) / SY
                P[k, c], X[k, c] = (px, py), (ex, ey)
                ok[k, c] = (ex - qx) * (ex - qx) + (ey - qy) * (ey - qy) <= room * room and \
                    (c == 4 or 0 < k < m - 1)
                c += 1
    return P, X, ok


def plain_snap(q, idx, room, v, acc, dev, t_in, t_out):
    """snap_chords without pruning: cost[k][i, j] is the least junction cost of the chords up to vertex k at
    candidate j, vertex k-1 at i; each (j, n) takes the first i in index order of least cost + junction."""
    m = len(idx)
    P, X, ok = _candidates(q, idx, room, t_in, t_out)
    moved = np.sqrt((X[:, :, 0] - q[idx][:, None, 0]) ** 2 + (X[:, :, 1] - q[idx][:, None, 1]) ** 2)
    far = [_stray(q, idx[k], idx[k + 1]) for k in range(m - 1)]
    sure, v2 = room * (1.0 - 1e-9), _sqrt_reaches(v)

    def J(u, w):
        return _junction_cost(u[0], u[1], w[0], w[1], v, v2, acc, acc, dev)

    def chord(k, j, n):  # the unit direction of chord k from candidate j to n, None where not allowed
        a, b = X[k, j], X[k + 1, n]
        if not ok[k, j] or not ok[k + 1, n] or (a == b).all():
            return None
        if far[k] + max(moved[k, j], moved[k + 1, n]) > sure and not _covers(
                q, idx[k], idx[k + 1], a[0], a[1], b[0], b[1], room * room):
            return None
        dx, dy = b[0] - a[0], b[1] - a[1]
        d = np.sqrt(dx * dx + dy * dy)
        return (dx / d, dy / d)

    U = {(j, n): chord(0, j, n) for j in range(9) for n in range(9)}
    cost = np.full((9, 9), INF)
    for (j, n), u in U.items():
        if u is not None:
            cost[j, n] = J(t_in, u) if any(t_in) else 0.0
    back = []
    for k in range(1, m - 1):
        W = {(j, n): chord(k, j, n) for j in range(9) for n in range(9)}
        new, pick = np.full((9, 9), INF), np.zeros((9, 9), int)
        for (j, n), w in W.items():
            if w is None:
                continue
            for i in range(9):
                if cost[i, j] < INF:
                    c = cost[i, j] + J(U[i, j], w)
                    if c < new[j, n]:
                        new[j, n], pick[j, n] = c, i
        cost, U = new, W
        back.append(pick)
    best, bj, bn = INF, 0, 0
    for j in range(9):
        for n in range(9):
            c = cost[j, n]
            if any(t_out) and c < INF:
                c += J(U[j, n], t_out)
            if c < best:
                best, bj, bn = c, j, n
    if best >= INF:
        return None
    ch = [bj, bn]
    for pick in reversed(back):
        ch.insert(0, pick[ch[0], ch[1]])
    return P[np.arange(m), ch]


def _curve(rng, n=400):
    t = np.linspace(0.0, 1.0, n)
    x0, y0, ang = rng.uniform(20, 80), rng.uniform(20, 80), rng.uniform(0, 2 * np.pi)
    bend = rng.uniform(1.0, 3.0)
    a, b = 4 * t, bend * np.sin(rng.uniform(1.0, 4.0) * t) + 0.002 * rng.standard_normal(n)  # a traced wobble
    return np.ascontiguousarray(np.c_[x0 + a * np.cos(ang) - b * np.sin(ang), y0 + a * np.sin(ang) + b * np.cos(ang)])


CASES = [(s, 150.0, (0.0, 0.0), (0.0, 0.0)) for s in range(20)] + [(s, 40.0, (0.0, 0.0), (0.0, 0.0)) for s in range(20, 30)] \
    + [(s, 3.0, (0.0, 0.0), (0.0, 0.0)) for s in range(30, 40)] \
    + [(40, 150.0, (0.6, 0.8), (0.0, 0.0)), (41, 150.0, (0.0, 0.0), (-0.28, 0.96)), (42, 40.0, (0.8, -0.6), (0.0, 1.0))]


@pytest.mark.parametrize("seed, v, t_in, t_out", CASES)
def test_snapping_chooses_what_the_plain_dynamic_programme_chooses(seed, v, t_in, t_out):
    """The same points to the bit on short curves, at a feed so low that GRBL slows at few junctions (most cost 0:
    ties everywhere) and where the pen arrives or leaves moving."""
    rng = np.random.default_rng(seed)
    q = _curve(rng)
    room, acc, dev = rng.uniform(0.02, 0.06), 2000.0, 0.01
    idx = greedy_chords(q, rng.uniform(0.003, 0.012))[:24]
    t_in, t_out = np.array(t_in), np.array(t_out)
    pts, found = snap_chords(q, idx, room, SX, SY, v, acc, acc, dev, t_in, t_out)
    want = plain_snap(q, idx, room, v, acc, dev, t_in, t_out)
    assert found == (want is not None)
    assert len(idx) > 4
    if found:
        assert np.array_equal(pts, want)
