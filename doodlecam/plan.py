"""Plan: a time-optimal feed profile along each stroke (Verscheure et al.).

Unknowns on the grid u_0 < ... < u_N are b_k = u-dot^2 (>= 0) and the
constant u-ddot a_k = (b_k+1 - b_k) / (2 h_k) on each interval, so b is linear
in u between grid points. For actuator coordinates theta = M q (a linear map
from the kinematics plugin) the actuator acceleration on an interval is

    theta''(u) = M (q'(u) a_k + q''(u) (b_k + 2 a_k (u - u_k)))

a polynomial of degree p - 1 in u whose Bernstein coefficients are linear in
(b_k, b_k+1). Bounding the coefficients bounds the polynomial (convex hull
property), so the limits hold *everywhere* on the curve, not only at grid
points. Velocity: |theta_i'(u)| is bounded by its largest Bernstein
coefficient and b(u) by max(b_k, b_k+1), giving upper bounds on each b_k.
The grid contains every knot, so each interval is inside one polynomial piece.

The feasible set contains b = 0 and is convex, and maximising sum(b) gives the
time-optimal profile (the set has a greatest element in all but degenerate
cases, where the result is still feasible). Time: sum 2 h / (sqrt b_k + sqrt b_k+1).
Because the constraints are homogeneous in b (rest-to-rest), a solver's
tolerance-level violation is removed exactly by scaling b down.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np

from .errors import PlanError
from .model import Profile, Spline


@dataclass(frozen=True)
class Limits:
    """Limits in actuator space: theta = M @ xy (M = identity for an XY plotter)."""

    vmax: np.ndarray  # (n_act,) actuator velocity limits, units/s
    amax: np.ndarray  # (n_act,) actuator acceleration limits, units/s^2
    M: np.ndarray  # (n_act, 2)
    pen_speed: float | None = None  # mm/s cap on |q-dot|

    @classmethod
    def from_machine(cls, machine, kinematics) -> "Limits":
        M = np.asarray(kinematics.linear_map, dtype=float)
        return cls(np.asarray(kinematics.velocity_limits(), float), np.asarray(kinematics.acceleration_limits(), float),
                   M, machine.pen.max_speed)


def make_grid(spline: Spline, spacing: float = 0.5, min_per_span: int = 2, max_points: int = 20000) -> np.ndarray:
    """Grid in u: every knot, each span split so steps are about ``spacing`` mm."""
    bp = spline.breakpoints
    x, w = np.polynomial.legendre.leggauss(6)
    lo, hi = bp[:-1, None], bp[1:, None]
    speed = np.linalg.norm(spline(((lo + hi) / 2 + (hi - lo) / 2 * x).ravel(), 1), axis=1).reshape(-1, len(x))
    span_len = ((hi - lo)[:, 0] / 2) * (speed * w).sum(axis=1)
    n = np.clip(np.ceil(span_len / spacing).astype(int), min_per_span, None)
    if n.sum() > max_points:
        n = np.maximum((n * max_points / n.sum()).astype(int), 1)
    starts = np.repeat(bp[:-1], n)
    widths = np.repeat(np.diff(bp) / n, n)
    frac = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    return np.append(starts + widths * frac, 1.0)


def _bernstein_from_power(c: np.ndarray) -> np.ndarray:
    """Power-basis coefficients (..., n+1) on tau in [0,1] to Bernstein coefficients."""
    n = c.shape[-1] - 1
    T = np.array([[comb(i, j) / comb(n, j) if j <= i else 0.0 for j in range(n + 1)] for i in range(n + 1)])
    return c @ T.T


def interval_bounds(spline: Spline, u: np.ndarray, M: np.ndarray):
    """Bernstein coefficients per interval k and actuator i.

    Returns (P, Q, V): actuator acceleration on interval k is a_k P(tau) + b_k Q(tau)
    with Bernstein coefficients P[k, i, :], Q[k, i, :]; V[k, i, :] are the
    Bernstein coefficients of theta_i'(u) and S[k, :] of |q'(u)| bounds.
    """
    p = spline.degree
    h = np.diff(u)
    ul = u[:-1]
    # Taylor coefficients at the left end (right limit: scipy evaluates a knot
    # with the span to its right) in tau = (u - u_k)/h.
    d = [spline(ul, j) for j in range(1, p + 1)]  # q', q'', ..., q^(p); each (K, 2)
    fact = np.cumprod([1.0] + list(range(1, p + 1)))
    hp = h[:, None] ** np.arange(p)[None, :]  # (K, p)
    # q'(tau) = sum_j q^(j+1) h^j tau^j / j!, j = 0..p-1  -> (K, 2, p)
    dq = np.stack([d[j] * (hp[:, j] / fact[j])[:, None] for j in range(p)], axis=2)
    # q''(tau) = sum_j q^(j+2) h^j tau^j / j!, j = 0..p-2, padded to p terms
    ddq = np.zeros_like(dq)
    for j in range(p - 1):
        ddq[:, :, j] = d[j + 1] * (hp[:, j] / fact[j])[:, None]
    # P(tau) = q'(tau) + 2 h tau q''(tau)   (tau * ddq shifts powers by one)
    P = dq.copy()
    P[:, :, 1:] += 2 * h[:, None, None] * ddq[:, :, :-1]
    Pb = _bernstein_from_power(np.einsum("ij,kjn->kin", M, P))
    Qb = _bernstein_from_power(np.einsum("ij,kjn->kin", M, ddq))
    Vb = _bernstein_from_power(np.einsum("ij,kjn->kin", M, dq))
    Sb = np.linalg.norm(_bernstein_from_power(dq), axis=1)  # |q'| <= max over these
    return Pb, Qb, Vb, Sb


def _constraints(spline: Spline, u: np.ndarray, limits: Limits):
    """Sparse G, h for G b <= h (acceleration) and upper bounds ub on b."""
    import scipy.sparse as sp

    Pb, Qb, Vb, Sb = interval_bounds(spline, u, limits.M)
    K, n_act, nb = Pb.shape
    h = np.diff(u)
    # a_k P + b_k Q with a_k = (b_k+1 - b_k)/(2h): coefficient of b_k and b_k+1
    c1 = Pb / (2 * h)[:, None, None]
    c0 = Qb - c1
    amax = np.broadcast_to(limits.amax[None, :, None], Pb.shape)
    rows = np.arange(K * n_act * nb).reshape(K, n_act, nb)
    kk = np.broadcast_to(np.arange(K)[:, None, None], Pb.shape)
    r = np.concatenate([rows.ravel(), rows.ravel()])
    c = np.concatenate([kk.ravel(), kk.ravel() + 1])
    G_up = sp.csr_matrix((np.concatenate([c0.ravel(), c1.ravel()]), (r, c)), shape=(rows.size, K + 1))
    G = sp.vstack([G_up, -G_up]).tocsc()
    hvec = np.concatenate([amax.ravel(), amax.ravel()])
    # velocity: (max Bernstein |theta_i'|)^2 * b <= vmax_i^2 at both interval ends
    vb = np.abs(Vb).max(axis=2)  # (K, n_act)
    cap = (limits.vmax[None, :] ** 2 / np.maximum(vb, 1e-150) ** 2).min(axis=1)
    if limits.pen_speed is not None:
        cap = np.minimum(cap, limits.pen_speed**2 / np.maximum(Sb.max(axis=1), 1e-150) ** 2)
    ub = np.full(K + 1, np.inf)
    ub[:-1] = cap
    ub[1:] = np.minimum(ub[1:], cap)
    return G, hvec, ub


def profile_times(u: np.ndarray, b: np.ndarray) -> np.ndarray:
    sb = np.sqrt(np.maximum(b, 0.0))
    dt = 2 * np.diff(u) / (sb[:-1] + sb[1:])
    return np.concatenate([[0.0], np.cumsum(dt)])


def plan_stroke(spline: Spline, limits: Limits, solver: str = "highs", spacing: float = 0.5) -> Profile:
    """Time-optimal rest-to-rest profile along ``spline`` (LP through qpsolvers)."""
    import scipy.sparse as sp
    from qpsolvers import solve_qp

    u = make_grid(spline, spacing)
    G, hvec, ub = _constraints(spline, u, limits)
    n = len(u)
    lb = np.zeros(n)
    ub = ub.copy()
    ub[0] = ub[-1] = 0.0  # start and end at rest
    ub = np.minimum(ub, 1e12)  # finite bounds for every solver
    # maximise sum(b) weighted by interval length (so fine grids do not skew it)
    w = np.zeros(n)
    w[:-1] += np.diff(u)
    w[1:] += np.diff(u)
    scale = max(float(np.median(ub[1:-1])) if n > 2 else 1.0, 1e-12)
    P = sp.csc_matrix((n, n))
    kw = {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200000, "polish": True} if solver == "osqp" else {}
    # solve for x = b / scale so the numbers the solver sees are O(1)
    b = solve_qp(P, -w / w.sum(), G, hvec / scale, lb=lb, ub=ub / scale, solver=solver, **kw)
    if b is None:
        raise PlanError(f"the {solver} solver found no feasible profile; try --solver highs")
    b = np.clip(b * scale, 0.0, ub)
    b[0] = b[-1] = 0.0
    b = certify(b, G, hvec, ub)
    a = np.diff(b) / (2 * np.diff(u))
    t = profile_times(u, b)
    if not np.all(np.isfinite(t)):
        raise PlanError("the planned profile stops mid-stroke (a limit forces zero speed); check the machine's limits")
    return Profile(u=u, b=b, a=a, t=t, solver=solver)


def certify(b: np.ndarray, G, hvec: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """Scale b down so every constraint holds exactly (they are homogeneous)."""
    lhs = G @ b
    ratio = max(float(np.max(lhs / hvec)), float(np.max(np.where(ub > 0, b / np.where(ub > 0, ub, 1), 0))), 0.0)
    if ratio > 1.0:
        b = b / (ratio * (1 + 1e-12))
    return b


def check_profile(spline: Spline, profile: Profile, limits: Limits, refine: int = 20):
    """Worst ratios (actuator accel / limit, actuator speed / limit) on a grid
    ``refine`` times finer than the one solved on, evaluated directly from the
    spline and the profile (not from the Bernstein bounds)."""
    u, b, a = profile.u, profile.b, profile.a
    tau = np.linspace(0.0, 1.0, refine + 1)[:-1]
    k = np.repeat(np.arange(len(a)), refine)
    uu = u[k] + np.tile(tau, len(a)) * np.diff(u)[k]
    uu = np.append(uu, u[-1])
    k = np.append(k, len(a) - 1)
    bb = b[k] + 2 * a[k] * (uu - u[k])
    th1 = spline(uu, 1) @ limits.M.T
    th2 = spline(uu, 2) @ limits.M.T
    acc = th1 * a[k][:, None] + th2 * bb[:, None]
    vel = th1 * np.sqrt(np.maximum(bb, 0.0))[:, None]
    return float((np.abs(acc) / limits.amax).max()), float((np.abs(vel) / limits.vmax).max())
