"""Constraint rows of the discretised time-optimal problem.

On the grid u_0 < ... < u_N the unknowns are b_k = u-dot^2 at the nodes; the
path acceleration a_k = (b_k+1 - b_k) / (2 h_k) is constant on interval k, so
b is linear in u there: b = b_k (1 - tau) + b_k+1 tau with tau = (u - u_k)/h_k.
Every limit becomes rows  tot b_k + beta (b_k+1 - b_k) <= gamma  per interval
(arrays of shape (K, R); unused rows have gamma = inf) plus node bounds ub.

``bernstein_rows`` (linear kinematics, theta = M q): on an interval inside one
knot span, actuator acceleration theta' a_k + theta'' b(tau) and velocity
squared theta'^2 b(tau) are polynomials in tau whose Bernstein coefficients
are linear in (b_k, b_k+1); bounding every coefficient bounds the polynomial
(convex hull property), so the limits hold at *every* u, not only at nodes.
``collocation_rows`` checks nodes only (TOPP-RA's collocation: the reference
optimum on a very fine grid). ``sampled_rows`` handles nonlinear kinematics
by sampling inside each interval; the planner verifies and refines those.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from math import comb

import numpy as np

from doodlecam.model import Spline


@dataclass(frozen=True)
class Rows:
    """Rows  tot b_k + beta (b_k+1 - b_k) <= gamma,  i.e. alpha = tot - beta.

    Stored as (tot, beta) because on fine grids alpha and beta are huge and
    nearly opposite (beta ~ 1/h): tot (the coefficient of b itself, e.g.
    theta'') is computed without that cancellation and the solvers stay exact.
    """

    tot: np.ndarray  # (K, R)
    beta: np.ndarray  # (K, R)
    gamma: np.ndarray  # (K, R), > 0; inf where unused
    ub: np.ndarray  # (K + 1,) upper bounds on b

    @property
    def alpha(self) -> np.ndarray:
        return self.tot - self.beta

    @cached_property
    def implied_ub(self) -> np.ndarray:
        """Finite upper bounds on every b_k implied by rows whose coefficients are
        both >= 0 (velocity rows): alpha b_k <= gamma and beta b_k+1 <= gamma.
        (Computed once: the LP/QP back-ends use it for bounds, scaling and row pruning.)"""
        alpha = self.alpha
        ok = np.isfinite(self.gamma) & (alpha >= 0) & (self.beta >= 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            left = np.where(ok & (alpha > 0), self.gamma / alpha, np.inf).min(axis=1)
            right = np.where(ok & (self.beta > 0), self.gamma / self.beta, np.inf).min(axis=1)
        ub = self.ub.copy()
        ub[:-1] = np.minimum(ub[:-1], left)
        ub[1:] = np.minimum(ub[1:], right)
        return ub

    def ratios(self, b: np.ndarray) -> np.ndarray:
        """(K, R) constraint usage (tot b_k + beta (b_k+1 - b_k)) / gamma."""
        lhs = self.tot * b[:-1, None] + self.beta * np.diff(b)[:, None]
        return np.where(np.isfinite(self.gamma), lhs / self.gamma, 0.0)


@lru_cache(maxsize=None)
def _b_matrix(n: int) -> np.ndarray:
    """T with bernstein = power @ T.T for degree-n polynomials on [0, 1]."""
    return np.array([[comb(i, j) / comb(n, j) if j <= i else 0.0 for j in range(n + 1)] for i in range(n + 1)])


@dataclass(frozen=True)
class Spans:
    """Every knot span's polynomial: Taylor coefficients ``T[s, j]`` = q^(j)(mid[s]) / j!
    (mm / u^j) at the span's midpoint, for s over the spans [bp[s], bp[s+1]]."""

    bp: np.ndarray  # (nseg + 1,) breakpoints
    mid: np.ndarray  # (nseg,)
    T: np.ndarray  # (nseg, degree + 1, 2)


@lru_cache(maxsize=None)
def _interior_taylor(p: int) -> np.ndarray:
    """C[r, j]: the j-th Taylor coefficient, at the middle of a knot span of unit
    width, of the r-th of the p + 1 uniform B-spline pieces over it."""
    from doodlecam.geometry.kernels import span_taylor

    nseg = 2 * p + 1  # span p is at least p spans from both ends
    C = np.empty((p + 1, p + 1))
    bp = np.linspace(0.0, 1.0, nseg + 1)
    for r in range(p + 1):
        e = np.zeros((nseg + p, 2))
        e[p + r, 0] = 1.0
        out = np.empty((nseg, p + 1, 2))
        span_taylor(_padded_derivatives(Spline(p, e)), p, nseg, (bp[:-1] + bp[1:]) / 2, np.empty((0, 0)), out)
        C[r] = out[p, :, 0] / float(nseg) ** np.arange(p + 1)
    return C


def _padded_derivatives(spline: Spline) -> np.ndarray:
    """D[j, :n - j] = the control points of q^(j) (Spline.derivative_controls)."""
    dc = spline.derivative_controls
    D = np.zeros((len(dc), len(dc[0]), 2))
    for j, c in enumerate(dc):
        D[j, : len(c)] = c
    return D


def spans(spline: Spline) -> Spans:
    """The span polynomials of ``spline``: computed once per plan, then the grid
    and the rows of every round use them (Horner instead of de Boor per point)."""
    from doodlecam.geometry.kernels import span_taylor

    p, bp = spline.degree, spline.breakpoints
    mid = (bp[:-1] + bp[1:]) / 2
    T = np.empty((len(mid), p + 1, 2))
    span_taylor(_padded_derivatives(spline), p, len(mid), mid, _interior_taylor(p), T)
    return Spans(bp, mid, T)


def bernstein_rows(spline: Spline, u: np.ndarray, M: np.ndarray, vmax: np.ndarray, amax: np.ndarray,
                   pen_speed: float | None = None, span_polys: Spans | None = None) -> Rows:
    """Certified rows for linear kinematics (the grid must contain every knot).

    Per interval (compiled: this is the planner's hot path): the Taylor
    coefficients of q', q'' at the left end (from its knot span's polynomial,
    ``span_polys`` = spans(spline) if not given) give, for every actuator,
    acceleration  a_k P(tau) + b(tau) Q(tau)  and velocity squared
    theta'(tau)^2 b(tau) in power form; their Bernstein coefficients are the
    rows. Sizes: 2 p acceleration rows and 2 p velocity rows per actuator,
    plus 2 p pen-speed rows.
    """
    from doodlecam.plan.kernels import bernstein_rows as kernel

    sp = span_polys if span_polys is not None else spans(spline)
    p = spline.degree
    K, na = len(u) - 1, M.shape[0]
    R = na * 4 * p + (2 * p if pen_speed is not None else 0)
    tot, beta, gamma = np.empty((K, R)), np.empty((K, R)), np.empty((K, R))
    kernel(sp.T, sp.bp, sp.mid, np.asarray(u, float), np.ascontiguousarray(M, float), np.asarray(vmax, float),
           np.asarray(amax, float), float(pen_speed) ** 2 if pen_speed is not None else 0.0,
           _b_matrix(p - 1), _b_matrix(2 * p - 1), tot, beta, gamma)
    return Rows(tot, beta, gamma, np.full(len(u), np.inf))


def collocation_rows(spline: Spline, u: np.ndarray, M: np.ndarray, vmax: np.ndarray, amax: np.ndarray,
                     pen_speed: float | None = None) -> Rows:
    """Limits at the nodes only (acceleration uses the interval to the right)."""
    h = np.diff(u)
    th1 = spline(u, 1) @ M.T
    th2 = spline(u, 2) @ M.T
    c1 = th1[:-1] / (2 * h)[:, None]
    tot = np.concatenate([th2[:-1], -th2[:-1]], axis=1)
    beta = np.concatenate([c1, -c1], axis=1)
    gamma = np.tile(np.concatenate([amax, amax]), (len(h), 1))
    ub = (vmax[None, :] ** 2 / np.maximum(th1 ** 2, 1e-300)).min(axis=1)
    if pen_speed is not None:
        ub = np.minimum(ub, pen_speed ** 2 / np.maximum((spline(u, 1) ** 2).sum(axis=1), 1e-300))
    return Rows(tot, beta, gamma, ub)


def sampled_rows(spline: Spline, u: np.ndarray, kinematics, vmax, amax, pen_speed=None, taus=(0.0, 0.5, 1.0)) -> Rows:
    """Rows at sample points inside every interval, for nonlinear kinematics."""
    h = np.diff(u)
    parts = []
    for tau in taus:
        uu = u[:-1] + tau * h if tau < 1 else np.nextafter(u[1:], -np.inf)  # the interval's side of a knot
        q, dq, ddq = spline(uu), spline(uu, 1), spline(uu, 2)
        _, t1, t2 = kinematics.derivatives(q, dq, ddq)
        # theta' a_k + theta'' (b_k + tau (b_k+1 - b_k)):  tot = theta''
        b_ = t2 * tau + t1 / (2 * h)[:, None]
        parts.append((np.concatenate([t2, -t2], 1), np.concatenate([b_, -b_], 1), np.tile(np.concatenate([amax, amax]), (len(h), 1))))
        sq = t1 ** 2
        parts.append((sq, sq * tau, np.tile(vmax ** 2, (len(h), 1))))
        if pen_speed is not None:
            s2 = (dq ** 2).sum(axis=1, keepdims=True)
            parts.append((s2, s2 * tau, np.full((len(h), 1), float(pen_speed) ** 2)))
    tot, beta, gamma = (np.concatenate([p[i] for p in parts], axis=1) for i in range(3))
    return Rows(tot, beta, gamma, np.full(len(u), np.inf))


@lru_cache(maxsize=16)
def _taus_and_ends(taus: tuple) -> tuple[np.ndarray, np.ndarray]:
    """The taus as an array and where they are >= 1 (jerk_coefficients; shared, not written to)."""
    t = np.asarray(taus, float)
    return t, t >= 1


def jerk_coefficients(spline: Spline, u: np.ndarray, taus=(0.0, 0.5, 1.0)):
    """(taus (T,), u there (T, K), c1 (T, K), c2 (T, K)) on the K intervals of the grid u,
    the pen's jerk across the path being sqrt(b) (c1 a + c2 b) there (see with_jerk):
    c1 = 3 kappa |q'|^2, c2 = 3 kappa q'.q'' + |q'|^3 dkappa/ds, with
    kappa = q' x q'' / |q'|^3 and dkappa/ds = (q' x q''' |q'|^2 - 3 q' x q'' q'.q'') / |q'|^6."""
    from doodlecam.plan.kernels import jerk_finish, jerk_terms

    h = u[1:] - u[:-1]
    taus, ends = _taus_and_ends(tuple(taus))
    uu = (u[:-1, None] + taus[None, :] * h[:, None]).T  # (len(taus), K): all at once
    if ends.any():
        uu[ends] = np.nextafter(u[1:], -np.inf)  # the interval's own side of a knot (degree 2)
    sp, c12, c13, dot12 = (np.empty(uu.shape) for _ in range(4))
    d = spline.derivative_controls
    k = spline.degree
    jerk_terms(d[1], d[min(2, k)], d[min(3, k)], k, len(spline.control) - k, uu, sp, c12, c13, dot12)
    c1, c2 = np.empty(uu.shape), np.empty(uu.shape)
    jerk_finish(sp, sp ** 3, sp ** 6, c12, c13, dot12, c1, c2)  # numpy's powers (as ever: the same plans)
    return taus, uu, c1, c2


def jerk_bound(coefficients, jerk_max) -> np.ndarray:
    """The jerk bound (mm/s^3; a number, or a function of u such as follow.JerkBound) at the
    points of ``coefficients`` (T, K): once per grid, for every set of rows on it."""
    uu = coefficients[1]
    return jerk_max(uu) if callable(jerk_max) else np.full(uu.shape, float(jerk_max))


def with_jerk(rows: Rows, coefficients, u: np.ndarray, b_hat: np.ndarray, jm: np.ndarray) -> Rows:
    """``rows`` and rows bounding the pen's jerk across the path, |3 v kappa a_t + v^3 dkappa/ds| <= jm
    (mm/s^3, jerk_bound) at the points of ``coefficients`` (jerk_coefficients on the grid u) inside
    every interval, all on the grid u (the jerk rows last: per interval and tau, + then -).

    With v = |q'| sqrt(b) and a_t = |q'| a + (q'.q''/|q'|) b it is sqrt(b) (c1 a + c2 b),
    c1 = 3 kappa |q'|^2, c2 = 3 kappa q'.q'' + |q'|^3 dkappa/ds. sqrt(b) is taken from
    ``b_hat`` (nodes), a profile the new one stays below (b <= b_hat is a node bound), so
    the linear rows |c1 a + c2 b| <= jm / sqrt(b_hat) are conservative. This jerk is what
    the PLC's constant-acceleration periods cannot follow (docs/sampling.md).
    """
    from doodlecam.plan.kernels import with_jerk_rows

    taus, _, c1, c2 = coefficients
    K, R = rows.tot.shape[0], rows.tot.shape[1] + 2 * len(taus)
    tot, beta, gamma = np.empty((K, R)), np.empty((K, R)), np.empty((K, R))
    with_jerk_rows(rows.tot, rows.beta, rows.gamma, c1, c2, taus, u, b_hat, jm, tot, beta, gamma)
    return Rows(tot, beta, gamma, np.minimum(rows.ub, b_hat))


def worst_ratios(rows: Rows, b: np.ndarray, first: int = 0) -> np.ndarray:
    """Per interval, the largest of rows.ratios(b) over the rows from ``first`` on (compiled)."""
    from doodlecam.plan.kernels import row_ratios

    out = np.empty(rows.tot.shape[0])
    row_ratios(rows.tot, rows.beta, rows.gamma, np.asarray(b, float), first, out)
    return out
