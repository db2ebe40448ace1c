"""Compiled B-spline kernels (numba): knots, basis functions, evaluation, span polynomials.

The data model (``Spline``), the fitter and the planner's follower all evaluate splines
through these; they import nothing from doodlecam, so everything can import them.
"""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def knot(j, p, nseg):  # pragma: no cover - compiled
    """Knot j of the clamped uniform knot vector: p + 1 zeros, even steps, p + 1 ones."""
    return min(max(j - p, 0), nseg) / nseg


@numba.njit(cache=True, nogil=True, inline="always")
def span_at(x, nseg):  # pragma: no cover - compiled
    """The knot span s of x in [0, 1] ([s, s + 1] / nseg), right-continuous at knots."""
    s = min(max(int(x * nseg), 0), nseg - 1)
    step = 1.0 / nseg  # knot j is j * step, as numpy.linspace makes Spline.knots
    if s + 1 < nseg and x >= (s + 1) * step:  # x * nseg rounded across a knot:
        s += 1  # right-continuous at knots, as scipy (it matters for the top derivative)
    elif s > 0 and x < s * step:
        s -= 1
    return s


@numba.njit(cache=True, nogil=True, inline="always")
def cubic_inner(x, nseg, s):  # pragma: no cover - compiled
    """The four cubic basis functions at x in the inner span s (evenly spaced knots all round)."""
    t = x * nseg - s
    t2 = t * t
    t3 = t2 * t
    return ((1.0 - t) ** 3 / 6.0, (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0, (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
            t3 / 6.0)


@numba.njit(cache=True, nogil=True, inline="always")
def basis_at(x, p, nseg, N, left, right):  # pragma: no cover - compiled
    """The p + 1 basis functions that do not vanish at x, into N; returns the
    index of the first (= the knot span). Cox-de Boor as in the NURBS book's
    A2.2, or the closed form of a cubic where the knots are evenly spaced."""
    s = span_at(x, nseg)
    if p == 3 and p <= s < nseg - p:
        N[0], N[1], N[2], N[3] = cubic_inner(x, nseg, s)
        return s
    k = s + p
    N[0] = 1.0
    for j in range(1, p + 1):
        left[j] = x - knot(k + 1 - j, p, nseg)
        right[j] = knot(k + j, p, nseg) - x
        saved = 0.0
        for r in range(j):
            t = N[r] / (right[r + 1] + left[j - r])
            N[r] = saved + right[r + 1] * t
            saved = left[j - r] * t
        N[j] = saved
    return s


@numba.njit(cache=True, nogil=True, inline="always")
def _point(c, k, nseg, u, N, left, right):  # pragma: no cover - compiled
    """The spline (control points c, degree k, nseg spans) at u in [0, 1]: (x, y)."""
    f = basis_at(u, k, nseg, N, left, right)
    sx = 0.0
    sy = 0.0
    for r in range(k + 1):
        sx += N[r] * c[f + r, 0]
        sy += N[r] * c[f + r, 1]
    return sx, sy


@numba.njit(cache=True, nogil=True)
def bspline_eval(c, k, nseg, x, out):  # pragma: no cover - compiled
    """out[j] = the clamped uniform B-spline of degree k with nseg knot spans and
    control points c (n, 2) at x[j] clipped to [0, 1] (a derivative of such a
    spline is one too, of degree k - 1 over the same spans). scipy's BSpline
    costs ~50 us per call before any work, and the planner, sampler and
    deviation check call it thousands of times per picture."""
    N = np.empty(k + 1)
    left = np.empty(k + 1)
    right = np.empty(k + 1)
    for j in range(x.shape[0]):
        out[j, 0], out[j, 1] = _point(c, k, nseg, min(max(x[j], 0.0), 1.0), N, left, right)


@numba.njit(cache=True, nogil=True)
def span_taylor(D, p, nseg, mid, C, out):  # pragma: no cover - compiled
    """out[s, j] = q^(j)(mid[s]) / j!, the Taylor coefficients of knot span s at
    its midpoint mid[s] (j = 0..p), for every span s < nseg. D[j]: the control
    points of q^(j) (its first n - j rows; a clamped uniform spline of degree
    p - j, nseg spans). At the midpoint no knot is near, so each span gets its
    own polynomial even where a derivative jumps at its ends. Spans at least p
    from both ends take C[r, j] (the same for all of them: the uniform pieces'
    coefficients on a unit-width span) times nseg^j; the others de Boor. With
    C of shape (0, 0), all by de Boor."""
    N = np.empty(p + 1)
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    uniform = C.shape[0] == p + 1
    for s in range(nseg):
        if uniform and p <= s < nseg - p:
            f = 1.0
            for j in range(p + 1):
                x = 0.0
                y = 0.0
                for r in range(p + 1):
                    x += C[r, j] * D[0, s + r, 0]
                    y += C[r, j] * D[0, s + r, 1]
                out[s, j, 0] = x * f
                out[s, j, 1] = y * f
                f *= nseg
            continue
        f = 1.0
        for j in range(p + 1):
            if j > 0:
                f *= j
            x, y = _point(D[j], p - j, nseg, mid[s], N, left, right)
            out[s, j, 0] = x / f
            out[s, j, 1] = y / f
