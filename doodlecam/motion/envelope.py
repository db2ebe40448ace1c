"""Tolerance envelope and meandering (Kirecci §3.5, §4.7).

The *maximum tolerance envelope* is the rectangle between successive design
points, via points included: in the position–time plane the position should
stay between the positions of the two points either side (Fig. 3.6, §4.2). A designer may give a
narrower or wider envelope. *Meandering* is the curve turning back for no
reason: the velocity changes sign more often than the boundary conditions
ask for (Fig. 3.7: the slider starts backwards although nothing asks it to).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Finding:
    """One check that failed: what, where (time, s) and by how much."""

    kind: str  # "envelope", "meander", "discontinuity", "limit", "smoothness"
    where: str  # "axis x segment 2"
    t: float
    message: str

    def __str__(self) -> str:
        return f"{self.where}: {self.message}"


def _sign_changes(signs: np.ndarray) -> int:
    s = signs[signs != 0]
    return int(np.count_nonzero(s[1:] != s[:-1])) if len(s) > 1 else 0


Knot = tuple[float, "float | None", "float | None"]  # (t s, position or None, given velocity or None)


def knot_envelopes(knots: Sequence[Knot]) -> list[tuple[float, float, float, float]]:
    """(t0, t1, low, high) of the maximum tolerance envelope between each pair
    of successive design points that give a position (Fig. 3.6).

    Where the positions turn at an interior point whose velocity is not given
    as zero (a peak or a trough the curve passes with a free slope), the
    conditions ask the curve to turn there but not exactly at the point: a
    smooth curve turns just beyond it. The bound on that side of the two
    rectangles next to the point is lifted; the meander check still counts
    the turn, so the curve may turn there once and only once.
    """
    pts = [(t, p, v) for t, p, v in knots if p is not None]
    boxes = [[a[0], b[0], min(a[1], b[1]), max(a[1], b[1])] for a, b in zip(pts, pts[1:])]
    for k in range(1, len(pts) - 1):
        before, after = np.sign(pts[k][1] - pts[k - 1][1]), np.sign(pts[k + 1][1] - pts[k][1])
        free = pts[k][2] is None or pts[k][2] != 0
        if before != 0 and after == -before and free:
            side = 3 if before > 0 else 2  # a peak lifts the high bounds, a trough the low ones
            for box in (boxes[k - 1], boxes[k]):
                box[side] = np.inf if side == 3 else -np.inf
    return [tuple(b) for b in boxes]


def _asked_turns(knots: Sequence[Knot], v0: float, v1: float, vtol: float, slack: float) -> int:
    """How often the conditions ask the velocity to change sign: the given
    end velocities, the direction from each design point to the next and
    the velocities given at via points, in time order."""
    sign = lambda v: np.sign(v) if abs(v) > vtol else 0.0  # noqa: E731
    asked = [sign(v0)]
    pts = [(t, p, v) for t, p, v in knots if p is not None or v is not None]
    last = None
    for i, (t, p, v) in enumerate(pts):
        if 0 < i < len(pts) - 1 and v is not None:
            asked.append(sign(v))
        if p is not None:
            if last is not None and abs(p - last) > slack:
                asked.append(np.sign(p - last))
            last = p
    asked.append(sign(v1))
    return _sign_changes(np.array(asked, dtype=float))


def check_segment(t: np.ndarray, f: np.ndarray, where: str, envelope: tuple[float, float] | None = None,
                  tolerance: float = 0.0, knots: Sequence[Knot] | None = None) -> list[Finding]:
    """Envelope and meandering findings for one segment sampled at times ``t``
    (first and last are the segment's ends) with ``f`` = (pos, vel, acc, jerk).

    ``knots`` are the segment's design points, ends and via points, as
    (t, position or None, given velocity or None): the envelope is then the
    rectangle between each pair of successive points (``knot_envelopes``)
    and the asked turns follow them. ``envelope`` (a designer's [low, high])
    overrides the rectangles; with neither, the end positions bound it.
    ``tolerance`` (mm) widens every envelope (rounding noise is ignored).
    """
    pos, vel = f[0], f[1]
    p0, p1 = float(pos[0]), float(pos[-1])
    if knots is None or len([k for k in knots if k[1] is not None]) < 2:
        knots = [(float(t[0]), p0, None), (float(t[-1]), p1, None)]
    boxes = knot_envelopes(knots)
    if envelope is not None:
        boxes = [(float(t[0]), float(t[-1]), *envelope)]
    starts = np.array([b[0] for b in boxes])
    k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(boxes) - 1)
    lo = np.array([b[2] for b in boxes])[k]
    hi = np.array([b[3] for b in boxes])[k]
    finite = np.abs(np.concatenate([[p0, p1], [b[2] for b in boxes], [b[3] for b in boxes]]))
    scale = max(1.0, float(finite[np.isfinite(finite)].max()))
    slack = tolerance + 1e-9 * scale
    found = []
    out = np.maximum(pos - (hi + slack), 0) + np.maximum((lo - slack) - pos, 0)
    i = int(np.argmax(out))
    if out[i] > 0:
        b = boxes[k[i]]
        span = f" between t = {b[0]:.4g} and {b[1]:.4g} s" if len(boxes) > 1 else ""
        found.append(Finding("envelope", where, float(t[i]),
                             f"position leaves its envelope [{b[2]:g}, {b[3]:g}]{span} by {out[i] + slack:.4g} at "
                             f"t = {t[i]:.4g} s (reaches {pos[i]:.6g}); change the conditions, the law or use arbitrary powers"))
    duration = float(t[-1] - t[0])
    vtol = 1e-6 * max(float(np.abs(vel).max()), abs(p1 - p0) / duration, 1e-12)
    v0, v1 = float(vel[0]), float(vel[-1])
    inner = vel[1:-1]
    seen = np.where(np.abs(inner) > vtol, np.sign(inner), 0.0)
    # a reversal that travels back no further than the tolerance is not meandering
    cuts = np.flatnonzero(np.diff(seen) != 0) + 1
    bounds = np.concatenate([[0], cuts, [len(seen)]])
    runs = []
    for a, b in zip(bounds[:-1], bounds[1:]):
        travel = abs(pos[b] - pos[a])  # interior run a..b-1 travels from pos[a] to pos[b]
        if travel <= slack:
            seen[a:b] = 0.0
        else:
            runs.append((a, b, travel))
    extra = _sign_changes(seen) - _asked_turns(knots, v0, v1, vtol, slack)
    if extra > 0:
        # the runs against the direction asked between the design points around them: where and how far
        pts = [(kt, kp) for kt, kp, _ in knots if kp is not None]
        ktimes = np.array([kt for kt, _ in pts])
        trend = np.sign(np.diff([kp for _, kp in pts]))
        ti = t[1:-1]

        def asked_at(a: int, b: int) -> float:
            j = int(np.clip(np.searchsorted(ktimes, ti[(a + b - 1) // 2], side="right") - 1, 0, len(trend) - 1))
            return float(trend[j])

        back = [(a, b, tr) for a, b, tr in runs if asked_at(a, b) != 0 and seen[a] != asked_at(a, b)] or runs
        a0 = back[0][0] if back else 0
        tm = float(t[1:-1][a0]) if len(t) > 2 else float(t[0])
        far = max(tr for _, _, tr in back) if back else 0.0
        found.append(Finding("meander", where, tm,
                             f"meanders: turns back by up to {far:.4g} from t = {tm:.4g} s (the velocity changes sign "
                             f"{extra} more time(s) than the conditions ask for); change the conditions or use arbitrary powers"))
    return found
