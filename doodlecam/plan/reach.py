"""The exact O(N) reachability solver for the discretised time-optimal problem.

Constraints on interval k are rows  tot_r b_k + beta_r (b_k+1 - b_k) <= gamma_r,
with node bounds 0 <= b_k <= ub_k and given b_0, b_N. The backward pass
computes the controllable set [lo_k, hi_k] of every node (the b_k from which
the end can still be reached), eliminating b_k+1 from each 2-variable
system exactly; the forward pass then takes, at every node, the largest
b_k+1 that is reachable and controllable (TOPP-RA's two passes, Pham & Pham
2018).

The elimination: b_k is feasible where (least upper bound on b_k+1) -
(greatest lower bound) >= 0, a concave piecewise-linear function of b_k, so
Newton steps on its active pieces find both ends of that interval in a few
passes over the bounds; where they do not (an infeasible interval, a tie),
Fourier-Motzkin over every pair of an upper and a lower bound decides, as it
did for every interval before (tests/test_plan_kernels.py checks the two
agree). The passes are sequential, so they are compiled (doodlecam/plan/kernels.py).
"""

from __future__ import annotations

import numpy as np


def solve(tot: np.ndarray, beta: np.ndarray, gamma: np.ndarray, ub: np.ndarray, b0: float = 0.0, bN: float = 0.0):
    """The greatest feasible b (length K + 1) or raise ValueError(message)."""
    from doodlecam.plan.kernels import reach_passes

    K = tot.shape[0]
    b = np.empty(K + 1)
    lo = np.empty(K + 1)
    hi = np.empty(K + 1)
    status = reach_passes(np.ascontiguousarray(tot, float), np.ascontiguousarray(beta, float),
                          np.ascontiguousarray(gamma, float), np.ascontiguousarray(ub, float),
                          float(b0), float(bN), b, lo, hi)
    if status != 0:
        raise ValueError(message(status))
    return b


def message(status: int) -> str:
    """What a reach_passes status other than 0 means."""
    if status == -1:
        return "the requested start speed is too high to stop in time"
    return f"no feasible speed at grid interval {status - 1}"
