"""The LP and the smoothing QP of the planner, through qpsolvers.

These carry the same rows as the reachability solver (doodlecam/plan/reach.py):
the LP "maximise sum b" as a cross-check of its exactness, and a QP that
trades a little time for smoothness (a penalty on changes of the path
acceleration a between grid intervals, a jerk proxy), warm-started from the
exact solution. Variables are scaled to O(1) for the solvers.
"""

from __future__ import annotations

import warnings

import numpy as np

from doodlecam.errors import PlanError
from doodlecam.plan.constraints import Rows

# Clarabel is the default back-end: on the report's curve at N = 1000 it solved
# the LP in 0.17 s and the QP in 0.28 s where OSQP took 35 s and 4.3 s
# (benchmarks/bench_plan.py); OSQP and HiGHS stay selectable.
BACKENDS = ("clarabel", "osqp", "highs")


def _sparse(rows: Rows, scale: float):
    """G x <= h for x = b / scale, every row normalised to unit largest entry
    (the raw rows span ~10 orders of magnitude, which first-order and
    interior-point solvers do not forgive)."""
    import scipy.sparse as sp

    K, R = rows.alpha.shape
    ub = rows.implied_ub
    # drop rows that cannot bind inside the box 0 <= b <= ub: they only hurt conditioning
    reach_max = np.maximum(rows.alpha, 0) * ub[:-1, None] + np.maximum(rows.beta, 0) * ub[1:, None]
    keep = np.isfinite(rows.gamma) & ~(reach_max <= rows.gamma * (1 - 1e-9))
    k = np.broadcast_to(np.arange(K)[:, None], (K, R))[keep]
    a, b = rows.alpha[keep] * scale, rows.beta[keep] * scale
    norm = np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-300)
    n = int(keep.sum())
    G = sp.csc_matrix((np.concatenate([a / norm, b / norm]),
                       (np.concatenate([np.arange(n)] * 2), np.concatenate([k, k + 1]))), shape=(n, K + 1))
    return G, rows.gamma[keep] / norm


def _options(backend: str) -> dict:
    if backend == "osqp":  # ADMM: tighter tolerances cost minutes; results are certified afterwards anyway
        return {"eps_abs": 1e-6, "eps_rel": 1e-6, "max_iter": 200000, "polish": True}
    return {}


def _bounds(rows: Rows, b0: float, bN: float, scale: float):
    lb = np.zeros(len(rows.ub))
    ub = np.minimum(rows.implied_ub, 1e12 * scale)
    lb[0] = ub[0] = b0
    lb[-1] = ub[-1] = bN
    return lb / scale, ub / scale


def _solve(P, q, rows, b0, bN, backend, scale, initvals=None) -> np.ndarray:
    from qpsolvers import Problem, solve_problem

    if backend not in BACKENDS:
        raise PlanError(f"unknown LP/QP back-end '{backend}'; choose one of {', '.join(BACKENDS)}")
    G, h = _sparse(rows, scale)
    lb, ub = _bounds(rows, b0, bN, scale)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sol = solve_problem(Problem(P, q, G, h, lb=lb, ub=ub), solver=backend, initvals=initvals, **_options(backend))
    x = sol.x
    # An interior-point "almost solved" point is fine: the planner certifies
    # (and if need be scales) every result against the rows afterwards.
    if x is None or not np.all(np.isfinite(x)):
        raise PlanError(f"the {backend} solver did not converge; try --solver reach")
    b = np.clip(x * scale, 0.0, rows.ub)
    b[0], b[-1] = b0, bN  # interior-point solvers leave ~1e-12 on fixed bounds
    return b


def _weights(u: np.ndarray) -> np.ndarray:
    w = np.zeros(len(u))
    w[:-1] += np.diff(u)
    w[1:] += np.diff(u)
    return w / w.sum()


def _scale(rows: Rows) -> float:
    finite = rows.implied_ub
    finite = finite[np.isfinite(finite)]
    if finite.size:
        return float(max(np.median(finite), 1e-12))
    # no velocity bound: a typical acceleration-limited b
    g = rows.gamma[np.isfinite(rows.gamma)]
    c = np.abs(rows.beta[np.isfinite(rows.gamma)])
    return float(max(np.median(g / np.maximum(c, 1e-300)), 1e-12))


def solve_lp(rows: Rows, u: np.ndarray, b0: float = 0.0, bN: float = 0.0, backend: str = "clarabel") -> np.ndarray:
    """max sum_k w_k b_k over the rows (w: interval lengths)."""
    import scipy.sparse as sp

    n = len(u)
    scale = _scale(rows)
    eps = 1e-9 if backend == "osqp" else 0.0  # OSQP wants a (tiny) quadratic term
    P = sp.eye(n, format="csc") * eps if eps else sp.csc_matrix((n, n))
    return _solve(P, -_weights(u), rows, b0, bN, backend, scale)


def solve_smooth(rows: Rows, u: np.ndarray, weight: float, warm: np.ndarray, b0: float = 0.0, bN: float = 0.0,
                 backend: str = "clarabel") -> np.ndarray:
    """max sum w b - weight * mean((a_k+1 - a_k) / a_typ)^2, warm-started at ``warm``."""
    import scipy.sparse as sp

    n = len(u)
    h = np.diff(u)
    scale = _scale(rows)
    # a_k = (b_k+1 - b_k) / (2 h_k);  D maps x = b / scale to a_k+1 - a_k
    A = sp.diags([-1 / (2 * h), 1 / (2 * h)], [0, 1], shape=(n - 1, n)).tocsr()
    D = (A[1:] - A[:-1]) * scale
    a = np.diff(warm) / (2 * h)
    a_typ = max(float(np.sqrt(np.mean(a ** 2))), 1e-12)
    P = (2 * weight / (a_typ ** 2 * max(n - 2, 1))) * (D.T @ D)
    P = sp.csc_matrix(P + sp.eye(n) * 1e-12)
    return _solve(P, -_weights(u), rows, b0, bN, backend, scale, initvals=warm / scale)
