"""Many splines evaluated in one compiled call (the posts write 10^4-10^5 strokes: one Spline.__call__ each
cost more than the evaluation). Exactly Spline.__call__'s arithmetic (kernels.bspline_eval), so the values are the
same to the bit."""

import numba
import numpy as np

from doodlecam.geometry.kernels import bspline_eval


@numba.njit(cache=True, nogil=True)
def points_at(ctrl, coff, degree, u, uoff):  # pragma: no cover - compiled
    """Spline s (control points ctrl[coff[s]:coff[s+1]], ``degree[s]``, clamped uniform) at u[uoff[s]:uoff[s+1]]
    clipped to [0, 1]: (len(u), 2). A derivative's controls (Spline.derivative_controls[d], degree - d) give it."""
    out = np.empty((u.shape[0], 2))
    for s in range(coff.shape[0] - 1):
        c = ctrl[coff[s]:coff[s + 1]]
        bspline_eval(c, degree[s], c.shape[0] - degree[s], u[uoff[s]:uoff[s + 1]], out[uoff[s]:uoff[s + 1]])
    return out


def offsets(lengths) -> np.ndarray:
    """Row offsets of arrays of these lengths concatenated: array s is rows off[s]:off[s + 1]."""
    return np.concatenate([[0], np.cumsum(np.asarray(lengths, np.int64))]).astype(np.int64)


def eval_many(splines, us, der: int = 0) -> np.ndarray:
    """[spline(u, der) for spline, u in zip(splines, us)] concatenated (all of degree >= der)."""
    ctrl = [s.controls_of(der) for s in splines]
    if not ctrl:
        return np.zeros((0, 2))
    return points_at(np.ascontiguousarray(np.concatenate(ctrl), dtype=float), offsets([len(c) for c in ctrl]),
                     np.array([s.degree - der for s in splines], np.int64),
                     np.concatenate([np.asarray(u, float).reshape(-1) for u in us]), offsets([np.size(u) for u in us]))
