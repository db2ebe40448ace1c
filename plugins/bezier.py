"""Compiled passes of the vector tracer (numba): how many chords each Bézier segment needs,
and their points.

The search doubles a segment's chord count until the chords are close and smooth enough
(``vector._bezier_points`` says how); in NumPy every round of every segment costs a dozen
array operations, here one loop per segment, stopping at the first chord that fails. Every
point is computed with svgelements' npoint's operations in its order (numba, without
fastmath, fuses no multiply-add), so the points, and the decisions taken on them, are
svgelements' to the bit (tests/test_vector_batch.py). Imported only when a drawing has
Béziers (numba's import costs ~0.3 s).
"""

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def _at(c, k, t):  # pragma: no cover - compiled
    """Segment k of ``c`` at t, with svgelements' npoint's operations in its order."""
    n = 1 - t
    if c.shape[1] == 4:
        a0, a1, a2, a3 = n * n * n, n * n * t, t * t * n, t * t * t
        return (a0 * c[k, 0, 0] + 3 * (a1 * c[k, 1, 0] + a2 * c[k, 2, 0]) + a3 * c[k, 3, 0],
                a0 * c[k, 0, 1] + 3 * (a1 * c[k, 1, 1] + a2 * c[k, 2, 1]) + a3 * c[k, 3, 1])
    a0, a1, a2 = n * n, 2 * (n * t), t * t
    return a0 * c[k, 0, 0] + a1 * c[k, 1, 0] + a2 * c[k, 2, 0], a0 * c[k, 0, 1] + a1 * c[k, 1, 1] + a2 * c[k, 2, 1]


@numba.njit(cache=True, nogil=True)
def chord_counts(c, tol, max_turn, max_points, turn_max_points):  # pragma: no cover - compiled
    """Chords of each segment of ``c`` ((m, 3 or 4, 2) control points); -1 where the first
    estimate is not finite (the caller lets svgelements raise on it). ``max_turn`` < 0: no
    turn limit."""
    m = c.shape[0]
    out = np.empty(m, np.int64)
    for k in range(m):
        # max|P''| from 64 steps: second differences of 65 points
        d2 = 0.0
        x0, y0 = _at(c, k, 0.0)
        x1, y1 = _at(c, k, 1.0 / 64)
        for i in range(2, 65):
            x2, y2 = _at(c, k, 1.0 if i == 64 else i * (1.0 / 64))
            for v in (abs(x2 - 2 * x1 + x0), abs(y2 - 2 * y1 + y0)):
                if d2 == d2 and not v <= d2:  # a NaN stays, as in a NumPy max
                    d2 = v
            x0, y0, x1, y1 = x1, y1, x2, y2
        nf = np.ceil(1.2 * np.sqrt(d2 * 64**2 / (8 * tol)))  # a float: math.ceil would be an int
        if not math.isfinite(nf):
            out[k] = -1
            continue
        n = int(max(1.0, min(nf, 2.0**40)))
        rounds = 0
        while True:
            n = min(n, max_points)
            step = 1.0 / n
            sag = n == max_points or rounds == 8  # then the chords' sag is not checked
            smooth = max_turn < 0 or n >= turn_max_points
            sag_ok = True
            turn_ok = True
            t0 = 0.0
            px, py = _at(c, k, t0)
            ex = ey = 0.0
            for j in range(n):
                t1 = 1.0 if j + 1 == n else (j + 1) * step
                qx, qy = _at(c, k, t1)
                if not sag:
                    mx, my = _at(c, k, (t0 + t1) / 2)
                    if not math.hypot(mx - (px + qx) / 2, my - (py + qy) / 2) <= tol:
                        sag_ok = False
                        break
                if not smooth and turn_ok:
                    dx, dy = qx - px, qy - py
                    # the dot product summed from +0.0 as NumPy's sum does: at a chord of length 0
                    # (a cusp sampled on both sides), atan2(0, +0.0) is 0 where atan2(0, -0.0) is pi
                    if j > 0 and not abs(math.atan2(ex * dy - ey * dx, 0.0 + ex * dx + ey * dy)) <= max_turn:
                        turn_ok = False
                        if sag:
                            break
                    ex, ey = dx, dy
                t0, px, py = t1, qx, qy
            if sag_ok and turn_ok:
                out[k] = n
                break
            rounds += not sag_ok
            n *= 2
    return out


@numba.njit(cache=True, nogil=True)
def chord_points(c, counts, out):  # pragma: no cover - compiled
    """The points of each segment of ``c`` at ``counts[k]`` equal steps (np.linspace's), one
    after the other into ``out``; segments counted 0 or less are skipped."""
    at = 0
    for k in range(c.shape[0]):
        n = counts[k]
        if n <= 0:
            continue
        step = 1.0 / n
        for j in range(n + 1):
            out[at + j, 0], out[at + j, 1] = _at(c, k, 1.0 if j == n else j * step)
        at += n + 1
