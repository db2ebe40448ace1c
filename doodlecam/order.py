"""Order: which stroke next, and in which direction, to keep pen-up travel short.

Greedy nearest neighbour from the home position over both ends of every
remaining stroke (a stroke may be drawn backwards). Vectorised per step; the
tracing issue adds a spatial index and 2-opt improvement on top of this.
"""

from __future__ import annotations

import numpy as np


def order_polylines(polylines, home=(0.0, 0.0), allow_reverse: bool = True):
    """(order, reversed_flags): indices into ``polylines`` and whether to flip each."""
    n = len(polylines)
    starts = np.array([p[0] for p in polylines], dtype=float).reshape(n, 2)
    ends = np.array([p[-1] for p in polylines], dtype=float).reshape(n, 2)
    left = np.ones(n, bool)
    pos = np.asarray(home, dtype=float)
    order, flips = [], []
    for _ in range(n):
        ds = np.where(left, np.hypot(*(starts - pos).T), np.inf)
        de = np.where(left, np.hypot(*(ends - pos).T), np.inf) if allow_reverse else np.full(n, np.inf)
        i_s, i_e = int(np.argmin(ds)), int(np.argmin(de))
        if de[i_e] < ds[i_s]:
            i, flip = i_e, True
        else:
            i, flip = i_s, False
        order.append(i)
        flips.append(flip)
        left[i] = False
        pos = starts[i] if flip else ends[i]
    return order, flips
