"""Tolerance envelope and meandering (Kirecci §3.5, §4.7).

The *maximum tolerance envelope* of a segment is the rectangle between its
two design points: in the position–time plane the position should stay
between the start and end positions (Fig. 3.6). A designer may give a
narrower or wider envelope. *Meandering* is the curve turning back for no
reason: the velocity changes sign more often than the boundary conditions
ask for (Fig. 3.7: the slider starts backwards although nothing asks it to).
"""

from __future__ import annotations

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


def envelope_excursion(pos: np.ndarray, lo: float, hi: float) -> tuple[float, int]:
    """(largest distance outside [lo, hi], index where it happens)."""
    out = np.maximum(pos - hi, 0) + np.maximum(lo - pos, 0)
    i = int(np.argmax(out))
    return float(out[i]), i


def check_segment(t: np.ndarray, f: np.ndarray, where: str, envelope: tuple[float, float] | None = None,
                  tolerance: float = 0.0) -> list[Finding]:
    """Envelope and meandering findings for one segment sampled at times ``t``
    (first and last are the segment's ends) with ``f`` = (pos, vel, acc, jerk).

    ``envelope`` defaults to the maximum tolerance envelope [min, max] of the
    end positions; ``tolerance`` (mm) widens it (rounding noise is ignored).
    """
    pos, vel = f[0], f[1]
    p0, p1 = float(pos[0]), float(pos[-1])
    lo, hi = envelope if envelope is not None else (min(p0, p1), max(p0, p1))
    scale = max(1.0, abs(p0), abs(p1), abs(lo), abs(hi))
    slack = tolerance + 1e-9 * scale
    found = []
    dist, i = envelope_excursion(pos, lo - slack, hi + slack)
    if dist > 0:
        found.append(Finding("envelope", where, float(t[i]),
                             f"position leaves its envelope [{lo:g}, {hi:g}] by {dist + slack:.4g} at t = {t[i]:.4g} s "
                             f"(reaches {pos[i]:.6g}); change the conditions, the law or use arbitrary powers"))
    duration = float(t[-1] - t[0])
    vtol = 1e-6 * max(float(np.abs(vel).max()), abs(p1 - p0) / duration, 1e-12)
    v0, v1 = float(vel[0]), float(vel[-1])
    trend = np.sign(p1 - p0) if abs(p1 - p0) > slack else 0.0
    asked = np.array([np.sign(v0) if abs(v0) > vtol else 0.0, trend, np.sign(v1) if abs(v1) > vtol else 0.0])
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
    extra = _sign_changes(seen) - _sign_changes(asked)
    if extra > 0:
        # the runs against the direction the conditions ask for: where and how far
        want = asked[asked != 0]
        first_want = want[0] if len(want) else 0.0
        back = [(a, tr) for a, b, tr in runs if seen[a] != first_want] or [(a, tr) for a, b, tr in runs]
        a0 = back[0][0] if back else 0
        tm = float(t[1:-1][a0]) if len(t) > 2 else float(t[0])
        far = max(tr for _, tr in back) if back else 0.0
        found.append(Finding("meander", where, tm,
                             f"meanders: turns back by up to {far:.4g} from t = {tm:.4g} s (the velocity changes sign "
                             f"{extra} more time(s) than the conditions ask for); change the conditions or use arbitrary powers"))
    return found
