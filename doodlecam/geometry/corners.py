"""Corners of traced polylines: where a line traced from a picture turns sharply.

A vector file says where its corners are (a vertex turning by more than an angle,
``fit.split_corners``). A line traced from pixels does not: its vertices sit on a
pixel staircase, smoothed and simplified, so neighbouring segments turn by tens of
degrees where the drawn shape is straight, and the tracer (Canny's blur, a
threshold of a blurred picture, a skeleton) rounds a true corner over a pixel or
two, so no single vertex turns by the corner's angle.

The turn is measured over a support instead, as in the k-cosine corner detector of
Rosenfeld and Johnston (IEEE Trans. Computers C-22, 1973), with the support an arc
length in mm (a few pixels of the grid traced, at least a few pen widths) rather
than a number of points, so the same shape gives the same corners at any
resolution: the angle at a vertex between the chords to the points an arc length
L behind and ahead of it. A corner is where that angle exceeds the threshold and
is the largest within L on either side (non-maximum suppression, as in Teh and Chin,
IEEE PAMI 11(8), 1989). A smooth curve turns too, in proportion to the support
(a circle of radius r by 2L/r), while a corner's turn is concentrated: it hardly
grows when the support is doubled, and the pixel staircase's wobble, a few pixels
long, shrinks. So a candidate is kept only when the angle over 2L is within a
factor ``_SPREAD`` of the angle over L (a corner between straight arms: 1; any
circle or ellipse arc short against its radius of curvature: about 2; staircase
noise: about 1/2), the two-scale test of curvature scale space corner detection
(Mokhtarian and Suomela, IEEE PAMI 20(12), 1998) put in terms of turning angles.

Each corner found is put back where its arms meet when they are straight: lines
fitted to the arms (least squares, from L to 2L away from the corner, outside the
rounding) are intersected, and the rounded stretch between is replaced by that point
when it lies within L of the traced vertex; else the line is cut at the traced vertex.
"""

from __future__ import annotations

import numpy as np

# Most the turn may grow or shrink from support L to 2L at a corner (a circle's doubles, the
# staircase's wobble halves). A picture coarser than the grid rounds its corners over its own
# pixels, so their turn still grows: at 1.4 a third of the corners of tests/test_traced_corners.py
# at 1 mm per pixel were missed, at 1.6 none.
_SPREAD = 1.6
# A corner's arms are fitted from one to two supports away from it: within one support the
# tracer's rounding bends them (a thresholded blur pulls a sharp tip back by several times
# the blur; with arms from a third of the support the star tips of tests/test_traced_corners.py
# came out 0.85 mm off, with these 0.22 mm), and out to two the concentration test holds them
# straight.
_INNER, _OUTER = 1.0, 2.0
# An arm is straight when its points are within this share of the support of its line (RMS):
# traced polygon sides measured up to 0.009 (contours), 0.025 (edges) and 0.039 (a pixel
# staircase smoothed as edges smooths it); a photo's outlines a median of 0.04 (contours) and
# 0.025 (edges), a tenth over 0.07. A corner between bent arms is cut where it was traced.
_STRAIGHT = 0.05


def _arc(p: np.ndarray) -> np.ndarray:
    return np.r_[0.0, np.cumsum(np.hypot(*np.diff(p, axis=0).T))]


def _at(p: np.ndarray, s: np.ndarray, t) -> np.ndarray:
    """Points of the polyline ``p`` (arc lengths ``s``) at arc lengths ``t``."""
    return np.column_stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])])


def _turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (degrees, 0..180) between the directions a and b, row by row."""
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return np.degrees(np.abs(np.arctan2(cross, (a * b).sum(axis=1))))


def _laps(p: np.ndarray, s: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """The polyline and its arc lengths, a closed one as three laps (arc length 0 at the
    middle lap's start), so chords and arms run across its seam."""
    if not closed:
        return p, s
    total = s[-1]
    return np.vstack([p[:-1], p[:-1], p]), np.concatenate([s[:-1] - total, s[:-1], s + total])


def find_corners(p: np.ndarray, support: float, angle: float, smooth: float | None = None) -> np.ndarray:
    """Indices of the vertices of the polyline ``p`` (mm) that are corners turning by more than
    ``angle`` degrees, measured over the arc length ``support`` (mm) on either side, in order.
    A closed polyline (first point = last) is a loop; its last index is never returned. An open
    one has no corner within ``support`` of its ends (the pen stops there anyway). ``smooth``:
    the Gaussian smoothing (mm) of the line before its turns are measured, a pixel (None = a
    third of the support)."""
    p = np.asarray(p, dtype=float)
    if len(p) < 3 or support <= 0 or angle <= 0:
        return np.zeros(0, int)
    closed = bool(np.array_equal(p[0], p[-1]))
    s = _arc(p)
    total = s[-1]
    if closed and total < 4 * support:  # a dot or a tiny loop: its turn is all curve
        return np.zeros(0, int)
    q, sq = _laps(p, s, closed)
    idx = np.arange(len(p) - 1) if closed else np.flatnonzero((s >= support) & (s <= total - support))
    if len(idx) == 0:
        return np.zeros(0, int)
    # The turns are measured on the line smoothed by about a pixel, as curvature scale space
    # detectors measure curvature on the Gaussian-smoothed curve: a raw pixel staircase wobbles
    # by half a pixel, a few pixels long.
    from scipy.ndimage import gaussian_filter1d

    step = support / 8
    grid = np.arange(sq[0], sq[-1] + step / 2, step)
    sigma = (support / 3 if smooth is None else smooth) / step
    q, sq = gaussian_filter1d(_at(q, sq, grid), sigma, axis=0, mode="nearest") if sigma > 0 else _at(q, sq, grid), grid
    si = s[idx]
    here = _at(q, sq, si)

    def turn(L: float) -> np.ndarray:
        return _turn(here - _at(q, sq, si - L), _at(q, sq, si + L) - here)

    t1 = turn(support)
    cand = np.flatnonzero(t1 > angle)
    if len(cand) == 0:
        return np.zeros(0, int)
    t2 = turn(2 * support)
    cand = cand[(t2[cand] <= _SPREAD * t1[cand]) & (_SPREAD * t2[cand] >= t1[cand])]
    keep: list[int] = []
    for k in cand[np.argsort(-t1[cand], kind="stable")]:  # the largest turn within the support wins
        d = np.abs(si[keep] - si[k]) if keep else np.zeros(0)
        if closed:
            d = np.minimum(d, total - d)
        if not (d <= support).any():
            keep.append(int(k))
    return np.sort(idx[keep]) if keep else np.zeros(0, int)


def _line(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(centroid, unit direction, RMS distance of the points) of the least-squares line through ``pts``."""
    c = pts.mean(axis=0)
    _, sv, vt = np.linalg.svd(pts - c, full_matrices=False)
    return c, vt[0], float(sv[1] / np.sqrt(len(pts)))


def _meet(q: np.ndarray, sq: np.ndarray, at: float, here: np.ndarray, support: float) -> np.ndarray | None:
    """Where the arms of the corner at arc length ``at`` meet: least-squares lines through each
    arm from _INNER to _OUTER x ``support`` away, intersected; None when an arm is not straight,
    they are nearly parallel or they meet farther than ``support`` from the traced corner ``here``."""
    arms = [_line(_at(q, sq, np.linspace(a, b, 17))) for a, b in
            ((at - _OUTER * support, at - _INNER * support), (at + _INNER * support, at + _OUTER * support))]
    (c0, u0, e0), (c1, u1, e1) = arms
    if max(e0, e1) > _STRAIGHT * support:  # a bend, not a straight arm: nothing to extend
        return None
    m = np.column_stack([u0, -u1])
    if abs(np.linalg.det(m)) < 0.1:  # under about 6 degrees apart: no place to meet
        return None
    x = c0 + np.linalg.solve(m, c1 - c0)[0] * u0
    return x if np.hypot(*(x - here)) <= support else None


def split_traced(p: np.ndarray, support: float, angle: float, smooth: float | None = None,
                 arms: float | None = None) -> list[np.ndarray]:
    """The traced polyline ``p`` (mm) cut at its corners (``find_corners``), each corner put where
    its arms meet (the rounded stretch within _INNER x ``support`` of it replaced by that point);
    the pieces share the corner points, in order. A closed polyline starts and ends on its
    first corner, so the pen stops nowhere else. ``smooth`` as for ``find_corners``; ``arms``: the
    support the arms are fitted over and the rounding replaced within (None = ``support``; more
    where the picture's own pixels, coarser than the grid traced, round a corner further)."""
    p = np.asarray(p, dtype=float)
    corners = find_corners(p, support, angle, smooth)
    if len(corners) == 0:
        return [p]
    closed = bool(np.array_equal(p[0], p[-1]))
    if closed:
        ring = np.roll(p[:-1], -corners[0], axis=0)
        corners = corners - corners[0]
        p = np.vstack([ring, ring[:1]])
    s = _arc(p)
    q, sq = _laps(p, s, closed)
    arms = support if arms is None else max(arms, support)
    r = _INNER * arms
    ends = []  # (arc length, point, stretch cut on either side)
    for i in corners:
        x = _meet(q, sq, s[i], p[i], arms)
        ends.append((s[i], p[i], 0.0) if x is None else (s[i], x, r))
    if closed:  # round to the first corner again
        bounds = ends + [(s[-1], ends[0][1], ends[0][2])]
    else:
        bounds = [(0.0, p[0], 0.0)] + ends + [(s[-1], p[-1], 0.0)]
    out = []
    for (a, xa, ra), (b, xb, rb) in zip(bounds[:-1], bounds[1:]):
        inner = p[(s > a + ra) & (s < b - rb)]
        piece = np.vstack([xa[None], inner, xb[None]])
        if np.any(piece != piece[0]):  # a piece of no length (two corners put on one point) goes
            out.append(piece)
    return out or [p]
