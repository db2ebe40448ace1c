"""The compiled part of the ``flow`` tracer: Jobard and Lefer's evenly spaced streamlines.

Jobard & Lefer, "Creating evenly-spaced streamlines of arbitrary density"
(1997), with a separation that varies over the picture: a streamline is
integrated (midpoint rule, step ``h``) both ways from its seed until it comes
closer to another line than ``d_test`` times the separation wanted there,
leaves the picture or a tone too light for lines, or turns too sharply (a
singularity of the field); then seeds are tried at one separation on either
side of every new line, in the order the lines were made, and each seed far
enough from every line starts the next. When no seed is left the fallback
seeds (the caller's, darkest first) reach the regions the lines did not.

The field is an orientation, not a direction (a structure tensor's
eigenvector has no sign): it is held as the doubled angle (a, b) = (J11 -
J22, 2 J12), interpolated bilinearly, and each step keeps the sign of the
previous one. Nearness is answered by a uniform grid of buckets (a linked
list per cell) holding every sample of every line, inserted as the line
grows, so a line also stops where it would run into itself. Sequential by
nature (each line depends on all before it), so compiled with numba and
imported only when the tracer runs.
"""

import numba
import numpy as np

_TURN_COS = np.cos(np.radians(30.0))  # a step turning more than this ends the line (a singularity)


@numba.njit(cache=True, nogil=True)
def _bilinear(g, x, y, cell):  # pragma: no cover - compiled
    """g (rows, cols) of cell-sized squares at mm (x, y), clamped at the border."""
    rows, cols = g.shape
    u = min(max(x / cell - 0.5, 0.0), cols - 1.0)
    v = min(max(y / cell - 0.5, 0.0), rows - 1.0)
    c0 = min(int(u), cols - 2) if cols > 1 else 0
    r0 = min(int(v), rows - 2) if rows > 1 else 0
    fu, fv = u - c0, v - r0
    c1, r1 = min(c0 + 1, cols - 1), min(r0 + 1, rows - 1)
    return ((1 - fv) * ((1 - fu) * g[r0, c0] + fu * g[r0, c1])
            + fv * ((1 - fu) * g[r1, c0] + fu * g[r1, c1]))


@numba.njit(cache=True, nogil=True)
def _direction(fa, fb, x, y, cell, px, py):  # pragma: no cover - compiled
    """The unit line direction at (x, y) with the sign of (px, py); (px, py) itself where the field vanishes."""
    a = _bilinear(fa, x, y, cell)
    b = _bilinear(fb, x, y, cell)
    if a * a + b * b < 1e-24:
        return px, py
    phi = 0.5 * np.arctan2(b, a)  # the gradient's orientation; lines run across it
    dx, dy = -np.sin(phi), np.cos(phi)
    if dx * px + dy * py < 0:
        return -dx, -dy
    return dx, dy


@numba.njit(cache=True, nogil=True)
def _near(x, y, r, line, arc, skip_arc, X, Y, L, A, alive, head, nxt, hc, hx, hy):  # pragma: no cover - compiled
    """Whether a sample of a living line lies within r of (x, y); samples of ``line`` itself count only
    farther than ``skip_arc`` along it (its own neighbours are not a crowd)."""
    cx0 = max(int((x - r) / hc), 0)
    cx1 = min(int((x + r) / hc), hx - 1)
    cy0 = max(int((y - r) / hc), 0)
    cy1 = min(int((y + r) / hc), hy - 1)
    r2 = r * r
    for cy in range(cy0, cy1 + 1):
        for cx in range(cx0, cx1 + 1):
            k = head[cy * hx + cx]
            while k >= 0:
                if alive[L[k]]:
                    dx, dy = X[k] - x, Y[k] - y
                    if dx * dx + dy * dy < r2 and (L[k] != line or abs(A[k] - arc) > skip_arc):
                        return True
                k = nxt[k]
    return False


@numba.njit(cache=True, nogil=True)
def evenly_spaced(fa, fb, sep, cell, width, height, d_test, h, pen, min_len, max_steps, seeds):  # pragma: no cover - compiled
    """Streamlines of the orientation field (fa, fb) spaced ``sep`` (mm, a grid like fa; inf where no
    line may run) apart, never nearer than d_test * sep nor than ``pen``.

    Returns (xy (m, 2) mm, offsets (lines + 1,)): line i is xy[offsets[i]:offsets[i + 1]]."""
    big = 0.0
    small = np.inf
    for v in sep.ravel():
        if np.isfinite(v):
            big = max(big, v)
            small = min(small, v)
    if big == 0.0:
        return np.zeros((0, 2)), np.zeros(1, np.int64)
    hc = max(small * d_test, pen)  # bucket size: the nearest a line may come in the darkest tone
    hx, hy = int(width / hc) + 1, int(height / hc) + 1
    head = np.full(hx * hy, -1, np.int64)
    cap = 1 << 16
    X, Y, A = np.empty(cap), np.empty(cap), np.empty(cap)
    L, nxt = np.empty(cap, np.int64), np.empty(cap, np.int64)
    alive = np.zeros(1 << 12, np.bool_)
    n = 0
    nlines = 0
    # lines made: their sample ranges (a line's samples are contiguous in X, Y, in drawing order after `_order`)
    start = np.empty(1 << 12, np.int64)
    stop = np.empty(1 << 12, np.int64)
    qx, qy = np.empty(1 << 14), np.empty(1 << 14)  # seeds waiting
    qh, qt = 0, 0
    fallback = 0
    half = h * h / 4.0
    while True:
        # the next seed: the queue's, else the next fallback one
        if qh < qt:
            sx, sy = qx[qh], qy[qh]
            qh += 1
        elif fallback < seeds.shape[0]:
            sx, sy = seeds[fallback, 0], seeds[fallback, 1]
            fallback += 1
        else:
            break
        if not (0.0 <= sx <= width and 0.0 <= sy <= height):
            continue
        s0 = _bilinear(sep, sx, sy, cell)
        if not np.isfinite(s0):
            continue
        # a seed one separation from every line, and never nearer than the steps below may come
        r0 = max(s0, np.sqrt(max(d_test * s0, pen) ** 2 + half))
        if _near(sx, sy, r0, -1, 0.0, 0.0, X, Y, L, A, alive, head, nxt, hc, hx, hy):
            continue
        line = nlines
        if line == alive.shape[0]:
            a2 = np.zeros(2 * line, np.bool_)
            a2[:line] = alive
            alive = a2
            s2, e2 = np.empty(2 * line, np.int64), np.empty(2 * line, np.int64)
            s2[:line], e2[:line] = start[:line], stop[:line]
            start, stop = s2, e2
        alive[line] = True
        nlines += 1
        first = n
        length = 0.0
        # forward (+1) then backward (-1) from the seed; the seed is the forward half's first sample
        for way in (1.0, -1.0):
            x, y = sx, sy
            px, py = _direction(fa, fb, x, y, cell, 1.0, 0.0)
            px, py = way * px, way * py
            arc = 0.0
            if way > 0:  # the seed itself
                if n == cap:
                    cap *= 2
                    X, Y, A, L, nxt = _grow(X, Y, A, L, nxt, n, cap)
                X[n], Y[n], A[n], L[n] = x, y, 0.0, line
                b = min(int(y / hc), hy - 1) * hx + min(int(x / hc), hx - 1)
                nxt[n] = head[b]
                head[b] = n
                n += 1
            for _ in range(max_steps):
                kx, ky = _direction(fa, fb, x, y, cell, px, py)
                mx, my = x + 0.5 * h * kx, y + 0.5 * h * ky
                dx, dy = _direction(fa, fb, mx, my, cell, kx, ky)
                nx, ny = x + h * dx, y + h * dy
                if dx * px + dy * py < _TURN_COS:
                    break
                if not (0.0 <= nx <= width and 0.0 <= ny <= height):
                    break
                s = _bilinear(sep, nx, ny, cell)
                if not np.isfinite(s):
                    break
                # samples this far apart keep the segments between them at least max(d_test * s, pen) apart
                r = np.sqrt(max(d_test * s, pen) ** 2 + half)
                arc += way * h
                if _near(nx, ny, r, line, arc, 3.0 * r, X, Y, L, A, alive, head, nxt, hc, hx, hy):
                    break
                if n == cap:
                    cap *= 2
                    X, Y, A, L, nxt = _grow(X, Y, A, L, nxt, n, cap)
                X[n], Y[n], A[n], L[n] = nx, ny, arc, line
                b = min(int(ny / hc), hy - 1) * hx + min(int(nx / hc), hx - 1)
                nxt[n] = head[b]
                head[b] = n
                n += 1
                length += h
                x, y, px, py = nx, ny, dx, dy
        start[line], stop[line] = first, n
        if length < min_len:
            alive[line] = False  # too short to draw: its samples stay, unseen
            continue
        # seeds one separation to either side of the line, every half separation along it
        every = max(1, int(0.5 * s0 / h))
        for k in range(first, n, every):
            tx, ty = _direction(fa, fb, X[k], Y[k], cell, 1.0, 0.0)  # the line's direction there (either sign)
            s = _bilinear(sep, X[k], Y[k], cell)
            if not np.isfinite(s):
                continue
            for side in (1.0, -1.0):
                if qt == qx.shape[0]:
                    qx2, qy2 = np.empty(2 * qt), np.empty(2 * qt)
                    qx2[:qt], qy2[:qt] = qx[:qt], qy[:qt]
                    qx, qy = qx2, qy2
                qx[qt] = X[k] - side * ty * s
                qy[qt] = Y[k] + side * tx * s
                qt += 1
    return _collect(X, Y, A, alive, start, stop, nlines)


@numba.njit(cache=True, nogil=True)
def _grow(X, Y, A, L, nxt, n, cap):  # pragma: no cover - compiled
    X2, Y2, A2, L2, N2 = np.empty(cap), np.empty(cap), np.empty(cap), np.empty(cap, np.int64), np.empty(cap, np.int64)
    X2[:n], Y2[:n], A2[:n], L2[:n], N2[:n] = X[:n], Y[:n], A[:n], L[:n], nxt[:n]
    return X2, Y2, A2, L2, N2


@numba.njit(cache=True, nogil=True)
def _collect(X, Y, A, alive, start, stop, nlines):  # pragma: no cover - compiled
    """The living lines' samples in order along each line (the backward half reversed before the forward)."""
    total = 0
    count = 0
    for i in range(nlines):
        if alive[i]:
            total += stop[i] - start[i]
            count += 1
    xy = np.empty((total, 2))
    off = np.zeros(count + 1, np.int64)
    j = 0
    m = 0
    for i in range(nlines):
        if not alive[i]:
            continue
        idx = np.arange(start[i], stop[i])
        order = idx[np.argsort(A[start[i]:stop[i]])]
        for k in order:
            xy[m, 0], xy[m, 1] = X[k], Y[k]
            m += 1
        j += 1
        off[j] = m
    return xy, off
