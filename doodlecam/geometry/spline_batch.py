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


def controls_many(splines, der: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """[s.controls_of(der) for s in splines] concatenated, and their row offsets. The derivative controls of
    splines of one shape (number of control points, degree) are made in one NumPy step, with the same
    divisions as Spline.derivative_controls (a written job has forgotten them: one small call per spline
    cost ~6 us, more than the evaluation)."""
    from doodlecam.model import _knot_table

    rows = np.fromiter((len(s.control) for s in splines), np.int64, len(splines))
    off = offsets(rows - der)
    if der == 0:
        return np.ascontiguousarray(np.concatenate([s.control for s in splines]), dtype=float), off
    out = np.empty((int(off[-1]), 2))
    groups: dict[tuple[int, int], list[int]] = {}
    for i, s in enumerate(splines):
        groups.setdefault((len(s.control), s.degree), []).append(i)
    for (n, k), idx in groups.items():
        c = np.stack([splines[i].control for i in idx]).astype(float, copy=False)
        for den in _knot_table(n, k).steps[:der]:
            c = k * (c[:, 1:] - c[:, :-1]) / den
            k -= 1
        out[(off[idx][:, None] + np.arange(n - der)).reshape(-1)] = c.reshape(-1, 2)
    return out, off


def eval_many(splines, us, der: int = 0) -> np.ndarray:
    """[spline(u, der) for spline, u in zip(splines, us)] concatenated (all of degree >= der). ``us``: a list
    of parameter arrays, or (u, offsets): all of them concatenated, spline s's at u[offsets[s]:offsets[s + 1]]."""
    if not len(splines):
        return np.zeros((0, 2))
    ctrl, coff = controls_many(splines, der)
    if isinstance(us, tuple):
        u, uoff = np.asarray(us[0], float).reshape(-1), np.asarray(us[1], np.int64)
    else:
        u = np.concatenate([np.asarray(x, float).reshape(-1) for x in us])
        uoff = offsets([np.size(x) for x in us])
    degree = np.fromiter((s.degree for s in splines), np.int64, len(splines)) - der
    return points_at(ctrl, coff, degree, u, uoff)
