"""Polynomials through boundary conditions (Kirecci eq. 3.1–3.6, §3.6).

A segment from t0 to t0 + T is written in the scaled time τ = (t − t0)/T in
[0, 1], so that the matrix of eq. 3.1 (A = T·C) is built from numbers near
one whatever the units. Every condition fixes one derivative (0 position,
1 velocity, 2 acceleration, 3 jerk) at one time; as in the thesis the number
of coefficients equals the number of conditions.

* ``solve`` with integer powers 0..n-1: the ordinary power-form polynomial.
  It is solved in the Chebyshev basis on [-1, 1] (the same polynomial, a far
  better conditioned system than monomials) and falls back to least squares
  when the system is still ill-conditioned; rank-deficient systems are
  reported as inconsistent or under-determined conditions.
* ``solve`` with ``powers``: the arbitrary-power polynomial d = Σ C_i τ^{p_i}
  of eq. 3.9/3.11.
* ``optimise_powers``: chooses the free powers (scipy differential evolution,
  then Nelder–Mead) to minimise the peak velocity, acceleration or jerk while
  meeting every condition exactly, keeping the powers that carry the start
  conditions fixed and the others above m + 0.5 (eq. 3.10).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from doodlecam.motion import MotionError

ORDER_NAMES = ("pos", "vel", "acc", "jerk")
OBJECTIVES = {"velocity": 1, "acceleration": 2, "jerk": 3}


@dataclass(frozen=True)
class Condition:
    """One boundary condition: derivative ``order`` equals ``value`` at ``t``."""

    t: float  # s
    order: int  # 0 pos (mm), 1 vel (mm/s), 2 acc (mm/s^2), 3 jerk (mm/s^3)
    value: float
    label: str = ""  # where it came from, for messages ("point 3")

    @property
    def name(self) -> str:
        what = f"{ORDER_NAMES[self.order]} = {self.value:g} at t = {self.t:g} s"
        return f"{self.label} {what}" if self.label else what


def _falling(p: np.ndarray, k: int) -> np.ndarray:
    out = np.ones_like(p)
    for j in range(k):
        out = out * (p - j)
    return out


def power_basis(tau, powers, k: int) -> np.ndarray:
    """d^k/dτ^k of τ^p for each power p: shape (len(tau), len(powers))."""
    tau = np.asarray(tau, dtype=float)[:, None]
    p = np.asarray(powers, dtype=float)[None, :]
    fac = _falling(p, k)
    with np.errstate(divide="ignore", invalid="ignore"):
        val = fac * np.power(tau, p - k)
    return np.where(fac == 0, 0.0, val)


def cheb_basis(tau, n: int, k: int) -> np.ndarray:
    """d^k/dτ^k of the Chebyshev polynomials T_0..T_{n-1}(2τ − 1)."""
    from numpy.polynomial import chebyshev as C

    u = 2 * np.asarray(tau, dtype=float) - 1
    if k >= n:
        return np.zeros((len(u), n))
    D = C.chebder(np.eye(n), m=k, axis=0) * 2.0**k  # (n - k, n)
    return C.chebvander(u, n - k - 1) @ D


@dataclass(frozen=True)
class PolySegment:
    """A solved polynomial segment on [t0, t0 + duration].

    ``powers`` is None for an ordinary polynomial (Chebyshev coefficients in
    ``coef``), else the real powers of τ (monomial coefficients in ``coef``).
    """

    t0: float
    duration: float
    coef: np.ndarray
    powers: np.ndarray | None = None
    conditions: tuple[Condition, ...] = field(default=(), repr=False)

    @property
    def t1(self) -> float:
        return self.t0 + self.duration

    @property
    def degree(self) -> float:
        return float(np.max(self.powers)) if self.powers is not None else len(self.coef) - 1

    def basis(self, tau, k: int) -> np.ndarray:
        if self.powers is None:
            return cheb_basis(tau, len(self.coef), k)
        return power_basis(tau, self.powers, k)

    def evaluate(self, t) -> np.ndarray:
        """(4, n): position, velocity, acceleration, jerk at times t (s), clipped to the segment."""
        tau = np.clip((np.atleast_1d(np.asarray(t, dtype=float)) - self.t0) / self.duration, 0.0, 1.0)
        out = np.empty((4, len(tau)))
        with np.errstate(all="ignore"):
            for k in range(4):
                # a real power below k gives an infinite derivative at τ = 0 (e.g. jerk of τ^2.5)
                terms = np.where(self.coef == 0, 0.0, self.basis(tau, k) * self.coef)
                out[k] = terms.sum(axis=1) / self.duration**k
                if self.powers is not None:
                    out[k] = self._start_limit(tau, k, out[k])
        return out

    def _start_limit(self, tau: np.ndarray, k: int, row: np.ndarray) -> np.ndarray:
        """Where two infinite terms meet at τ = 0 (inf − inf = nan) the term of
        the lowest power dominates as τ → 0+: the derivative is ±inf by its sign."""
        bad = np.isnan(row) & (tau == 0)
        if not bad.any():
            return row
        p = np.asarray(self.powers, float)
        live = (self.coef != 0) & (p < k) & (_falling(p, k) != 0)
        j = int(np.flatnonzero(live)[np.argmin(p[live])])
        row = row.copy()
        row[bad] = np.sign(self.coef[j] * _falling(p[j:j + 1], k)[0]) * np.inf
        return row

    def power_form(self) -> tuple[np.ndarray, np.ndarray]:
        """(powers, C): d(t) = Σ C_i (t − t0)^{p_i}, the thesis's coefficients (eq. 3.3)."""
        if self.powers is not None:
            return self.powers.copy(), self.coef / self.duration**self.powers
        from numpy.polynomial import chebyshev as C
        from numpy.polynomial import polynomial as P

        mono = C.cheb2poly(self.coef)  # monomials in u = 2τ − 1; substitute u below
        out = np.zeros(len(mono))
        term = np.array([1.0])
        lin = np.array([-1.0, 2.0])
        for c in mono:
            out[: len(term)] += c * term
            term = P.polymul(term, lin)
        p = np.arange(len(out), dtype=float)
        return p, out / self.duration**p

    def describe(self) -> str:
        if self.powers is None:
            return f"polynomial degree {len(self.coef) - 1}"
        return "polynomial powers (" + ", ".join(f"{p:g}" for p in self.powers) + ")"


def _dedupe(conditions, where: str) -> list[Condition]:
    seen: dict[tuple[float, int], Condition] = {}
    for c in conditions:
        key = (round(c.t, 12), c.order)
        if key in seen:
            old = seen[key]
            if abs(old.value - c.value) > 1e-9 * max(1.0, abs(old.value), abs(c.value)):
                raise MotionError(f"{where}: inconsistent conditions {old.name} and {c.name}; keep one")
            continue
        seen[key] = c
    return list(seen.values())


def solve(conditions, t0: float, duration: float, powers=None, where: str = "segment") -> PolySegment:
    """The polynomial (integer powers 0..n-1, or the given real ``powers``)
    that meets every condition. Raises MotionError naming ``where`` and the
    condition when the conditions are inconsistent or under-determined."""
    if not (duration > 0 and np.isfinite(duration)):
        raise MotionError(f"{where}: duration is {duration:g} s; a segment needs a positive duration")
    conds = _dedupe(conditions, where)
    n = len(conds)
    if n == 0:
        raise MotionError(f"{where}: no boundary conditions; give at least a position at each end")
    for c in conds:
        if c.order not in (0, 1, 2, 3):
            raise MotionError(f"{where}: condition order {c.order} is not pos, vel, acc or jerk")
        if not np.isfinite(c.value):
            raise MotionError(f"{where}: {c.name} is not a finite number")
        if c.t < t0 - 1e-9 * max(1, abs(t0)) or c.t > t0 + duration * (1 + 1e-9) + 1e-12:
            raise MotionError(f"{where}: {c.name} lies outside the segment [{t0:g}, {t0 + duration:g}] s")
    if not any(c.order == 0 for c in conds):
        raise MotionError(f"{where}: no position condition, so nothing fixes where the curve is; give a position")
    if powers is not None:
        powers = np.asarray(powers, dtype=float)
        if powers.shape != (n,):
            raise MotionError(f"{where}: {len(powers)} powers for {n} conditions; give one power per condition")
        if np.any(powers < 0) or not np.all(np.isfinite(powers)):
            raise MotionError(f"{where}: powers must be finite and >= 0, got {list(powers)}")
        if len(np.unique(powers)) < n:
            raise MotionError(f"{where}: powers {list(powers)} repeat a value; each term needs its own power")
    # clipped like evaluate() clips: (t1 - t0) / T may round to 1 + 5e-13
    tau = np.clip(np.array([(c.t - t0) / duration for c in conds]), 0.0, 1.0)
    order = np.array([c.order for c in conds])
    A = np.empty((n, n))
    for k in range(4):
        rows = order == k
        if rows.any():
            A[rows] = cheb_basis(tau[rows], n, k) if powers is None else power_basis(tau[rows], powers, k)
    if not np.all(np.isfinite(A)):
        i, j = np.argwhere(~np.isfinite(A))[0]
        raise MotionError(f"{where}: power {powers[j]:g} is too low for {conds[i].name} "
                          f"(a {ORDER_NAMES[conds[i].order]} condition at the start needs powers above {conds[i].order})")
    b = np.array([c.value * duration**c.order for c in conds])  # d^k/dτ^k = T^k d^k/dt^k
    coef = _solve_system(A, b, conds, where)
    return PolySegment(t0=float(t0), duration=float(duration), coef=coef,
                       powers=None if powers is None else powers, conditions=tuple(conds))


def _solve_system(A: np.ndarray, b: np.ndarray, conds, where: str) -> np.ndarray:
    n = len(b)
    col = np.abs(A).max(axis=0)
    if np.any(col == 0):
        raise MotionError(f"{where}: the conditions ({', '.join(c.name for c in conds)}) leave a term free "
                          "(under-determined); add a position or move a condition")
    As = A / col
    u, s, vt = np.linalg.svd(As)
    tol = s[0] * n * 1e-13
    rank = int((s > tol).sum())
    scale = max(1.0, float(np.abs(b).max()))
    if rank == n and s[0] / s[-1] < 1e10:
        x = np.linalg.solve(As, b)
        x += np.linalg.solve(As, b - As @ x)  # one step of iterative refinement
    else:
        # ill-conditioned or singular: truncated-SVD least squares, then judge the residual
        inv = np.where(s > tol, 1.0 / np.where(s > tol, s, 1.0), 0.0)
        x = vt.T @ (inv * (u.T @ b))
    resid = np.abs(As @ x - b)
    if resid.max() > 1e-9 * scale:
        bad = conds[int(np.argmax(resid))]
        if rank < n:
            raise MotionError(f"{where}: inconsistent conditions: {bad.name} cannot be met together with the others; "
                              "remove or change it")
        raise MotionError(f"{where}: the conditions are too ill-conditioned to meet {bad.name}; "
                          "split the segment or use fewer conditions")
    if rank < n:
        raise MotionError(f"{where}: under-determined: {n} conditions but only {rank} independent "
                          f"({', '.join(c.name for c in conds)}); give conditions at different times or orders")
    return x / col


# ------------------------------------------------------------- optimisation


def _batch_basis(tau: np.ndarray, P: np.ndarray, k: int) -> np.ndarray:
    """power_basis for S sets of powers P (S, n) at once: (S, len(tau), n)."""
    fac = _falling(P, k)[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        val = fac * np.power(tau[None, :, None], P[:, None, :] - k)
    return np.where(fac == 0, 0.0, val)


def _batch_apply(tau: np.ndarray, P: np.ndarray, k: int, coef: np.ndarray) -> np.ndarray:
    """Σ_j coef_j d^k/dτ^k τ^{p_j} for each of S members: (S, len(tau))."""
    B = _batch_basis(tau, P, k)
    return np.where(coef[:, None, :] == 0, 0.0, B * coef[:, None, :]).sum(axis=2)


def _start_orders(conds, t0: float, duration: float) -> list[int]:
    return sorted({c.order for c in conds if abs(c.t - t0) <= 1e-12 * max(1.0, duration)})


def optimise_powers(conditions, t0: float, duration: float, objective: str = "velocity", continuity: int = 2,
                    max_power: float = 40.0, envelope: tuple[float, float] | None = None,
                    where: str = "segment", seed: int = 0, maxiter: int = 120) -> PolySegment:
    """Arbitrary-power polynomial meeting ``conditions`` with the smallest
    peak |velocity|, |acceleration| or |jerk| (``objective``).

    The powers 0..j that carry the start conditions stay fixed (§3.6.2); the
    remaining powers range over (max(j, continuity) + 0.5, max_power], the
    lower bound being eq. 3.10. With ``envelope`` = (lo, hi) a position
    leaving [lo, hi] is penalised, so the optimiser also removes meandering
    (§3.5) when the conditions allow it. Never worse than the plain
    polynomial when that one is admissible: it is a starting candidate.
    """
    from scipy.optimize import differential_evolution, minimize

    if objective not in OBJECTIVES:
        raise MotionError(f"{where}: optimise = '{objective}' is not one of {', '.join(OBJECTIVES)}")
    conds = _dedupe(conditions, where)
    n = len(conds)
    start = _start_orders(conds, t0, duration)
    if 0 not in start:
        raise MotionError(f"{where}: arbitrary powers need the position at the start of the segment; give it")
    fixed = np.arange(max(start) + 1, dtype=float)
    free = n - len(fixed)
    plain = solve(conds, t0, duration, where=where)  # raises for bad conditions
    if free <= 0:
        return plain
    lo = max(float(max(start)), float(continuity)) + 0.5
    hi = float(max_power)
    if hi <= lo + 0.01 * free:
        raise MotionError(f"{where}: max_power {hi:g} leaves no room above {lo:g} for {free} free powers; raise it")
    k = OBJECTIVES[objective]
    grid = np.linspace(0.0, 1.0, 257)
    lo_env, hi_env = envelope if envelope is not None else (-np.inf, np.inf)
    span = max(1e-12, float(np.ptp([c.value for c in conds if c.order == 0])) or 1.0)
    c_tau = np.clip(np.array([(c.t - t0) / duration for c in conds]), 0.0, 1.0)
    c_ord = np.array([c.order for c in conds])
    b = np.array([c.value * duration**c.order for c in conds])

    def costs(Q: np.ndarray) -> np.ndarray:
        """Peak of the objective derivative (dimensionless) plus the envelope
        penalty, for a population Q (free, S) of free powers at once."""
        Q = np.sort(np.asarray(Q, dtype=float).reshape(free, -1), axis=0).T  # (S, free)
        S = len(Q)
        P = np.concatenate([np.broadcast_to(fixed, (S, len(fixed))), Q], axis=1)
        bad = (Q[:, 0] < lo) | (Q[:, -1] > hi) | np.any(np.diff(Q, axis=1) < 0.01, axis=1)
        A = np.empty((S, n, n))
        for d in range(4):
            rows = c_ord == d
            if rows.any():
                A[:, rows, :] = _batch_basis(c_tau[rows], P, d)
        bad |= ~np.isfinite(A).all(axis=(1, 2))
        A[bad] = np.eye(n)
        try:
            coef = np.linalg.solve(A, np.broadcast_to(b, (S, n))[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a singular member: solve one by one
            coef = np.zeros((S, n))
            for i in range(S):
                try:
                    coef[i] = np.linalg.solve(A[i], b)
                except np.linalg.LinAlgError:
                    bad[i] = True
        # cancelling giants are too ill-conditioned to trust
        bad |= ~np.isfinite(coef).all(axis=1) | (np.abs(coef).max(axis=1) > 1e8 * (1 + np.abs(b).max()))
        with np.errstate(all="ignore"):
            val = np.abs(_batch_apply(grid, P, k, coef)).max(axis=1) / span
            if envelope is not None:
                pos = _batch_apply(grid, P, 0, coef)
                val += 1e3 * (np.maximum(pos - hi_env, 0).max(axis=1) + np.maximum(lo_env - pos, 0).max(axis=1)) / span
        val[bad | ~np.isfinite(val)] = 1e9
        return val

    def cost_of(seg: PolySegment) -> float:
        f = seg.evaluate(t0 + grid * duration)
        c = float(np.abs(f[k]).max()) * duration**k / span
        if envelope is not None:
            c += 1e3 * float(np.maximum(f[0] - hi_env, 0).max() + np.maximum(lo_env - f[0], 0).max()) / span
        return c if np.isfinite(c) else 1e9

    res = differential_evolution(costs, [(lo, hi)] * free, seed=seed, maxiter=maxiter, popsize=15,
                                 tol=1e-8, polish=False, vectorized=True, updating="deferred")
    best = minimize(lambda q: float(costs(q)[0]), res.x, method="Nelder-Mead", bounds=[(lo, hi)] * free,
                    options={"xatol": 1e-4, "fatol": 1e-9, "maxiter": 300})
    q = np.sort(best.x if best.fun <= res.fun else res.x)
    try:
        seg = solve(conds, t0, duration, powers=np.concatenate([fixed, q]), where=where)
    except MotionError:
        return plain
    return seg if cost_of(seg) < cost_of(plain) else plain
