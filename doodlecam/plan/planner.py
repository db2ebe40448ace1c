"""Plan: a time-optimal feed profile along each stroke (Verscheure et al. 2009).

Unknowns on the grid u_0 < ... < u_N are b_k = u-dot^2 >= 0, with the path
acceleration a_k = (b_k+1 - b_k) / (2 h_k) constant on each interval, so b is
linear in u between nodes and the time is sum 2 h_k / (sqrt b_k + sqrt b_k+1).
Every limit is a linear row in (b_k, b_k+1) (doodlecam/plan/constraints.py):
Bernstein bounds make them hold everywhere on the curve for linear kinematics;
nonlinear kinematics (the five-bar arm) is sampled inside each interval,
verified on a 20x finer grid and refined where that check fails.

Solvers (``solver=``): "reach" — the exact O(N) two-pass reachability solver
(default); "lp[:backend]" — max sum b through qpsolvers (Clarabel by default,
OSQP or HiGHS), a cross-check; "qp[:backend]" — the smoothing QP (penalised
changes of a, a jerk proxy) warm-started from the reach solution.

The grid contains every knot and is refined where constraints bind but the
Bernstein bound is loose (``adaptive``), instead of everywhere.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from doodlecam.errors import PlanError, did_you_mean
from doodlecam.extras import require
from doodlecam.options import SOLVERS
from doodlecam.model import Profile, Spline
from doodlecam.plan import constraints, convex, reach

CHECK_REFINE = 20  # the verification grid is this many times finer
SPACING, TURN_STEP = 0.5, 0.05  # grid steps: mm along the curve, rad of turning (make_grid)
MAX_POINTS = 200_000  # grid nodes at most
MAX_ROUNDS = 6  # solves on refined grids at most
# jerk_max: the rows take sqrt(b) from a profile b_hat the solution stays below. The
# first solve takes the plan without the bound; the next min(that, 2 x the last),
# which the last solution satisfies, so each is at least as fast (camera.png, same
# bound: drawing 83 s -> 70 s). Re-solving with b_hat = the last b alone gains nothing:
# the last solution is then the greatest feasible one.
JERK_GROW = (1.0, 2.0)
_JERK_GROW = np.array(JERK_GROW)


@dataclass(frozen=True)
class Limits:
    """Actuator limits and how to get actuator derivatives along a path."""

    vmax: np.ndarray  # (n_act,) actuator velocity limits, units/s
    amax: np.ndarray  # (n_act,) actuator acceleration limits, units/s^2
    M: np.ndarray | None  # (n_act, 2) when theta = M @ xy, else None
    pen_speed: float | None = None  # mm/s cap on |q-dot|
    kinematics: Any = None  # api.Kinematics, used when M is None

    @classmethod
    def from_machine(cls, machine, kinematics) -> "Limits":
        vmax, amax = kinematics.actuator_limits()
        M = None if kinematics.linear_map is None else np.asarray(kinematics.linear_map, dtype=float)
        return cls(np.asarray(vmax, float), np.asarray(amax, float), M, machine.pen.max_speed, kinematics)

    @functools.cached_property  # checked once per Limits, not once per stroke planned with them
    def problem(self) -> str:
        """Why these limits cannot be planned with (one line), or "" when they can."""
        for name, x in (("velocity", self.vmax), ("acceleration", self.amax)):
            x = np.atleast_1d(np.asarray(x, float))
            if x.size == 0 or not _finite(x) or (x <= 0).any():
                return f"every actuator {name} limit must be a positive finite number, got {x.tolist()}; fix the machine profile"
        if self.M is not None:
            M = np.asarray(self.M, float)
            if M.ndim != 2 or M.shape != (len(np.atleast_1d(self.vmax)), 2) or not _finite(M) or not M.any(axis=1).all():
                return "the kinematics' linear map must be a finite (actuators x 2) matrix with a non-zero row per actuator; fix the kinematics"
            if len(np.atleast_1d(self.amax)) != M.shape[0]:
                return "the kinematics give different numbers of velocity and acceleration limits; fix the kinematics"
        elif self.kinematics is None:
            return "nonlinear limits need the kinematics (Limits.kinematics); build them with Limits.from_machine"
        if self.pen_speed is not None and not (math.isfinite(self.pen_speed) and self.pen_speed > 0):
            return f"the pen-speed cap must be a positive finite number, got {self.pen_speed!r}; fix [pen] max_speed"
        return ""

    @functools.cached_property
    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, vmax, amax) as contiguous float arrays, once per Limits (linear kinematics)."""
        return np.ascontiguousarray(self.M, float), np.asarray(self.vmax, float), np.asarray(self.amax, float)

    @functools.cached_property
    def cubic_rows(self) -> tuple:
        """(M, vmax, amax, pen speed squared, rows per interval, Bernstein matrices of degrees 2 and 5,
        taus of the rounds' check, pen speed): kernels.curve_rounds' arguments from these limits,
        once per Limits instead of once per stroke (linear kinematics, cubics)."""
        M, vmax, amax = self.arrays
        p, pen = 3, self.pen_speed
        R = M.shape[0] * 4 * p + (2 * p if pen is not None else 0)  # as constraints.bernstein_rows
        return (M, vmax, amax, float(pen) ** 2 if pen is not None else 0.0, R, constraints._b_matrix(p - 1),
                constraints._b_matrix(2 * p - 1), _taus(8), float(pen or 0.0))

    @functools.cached_property
    def easiest(self) -> tuple[float, float]:
        """(speed mm/s, acceleration mm/s^2) in the most favourable direction (linear kinematics),
        generously: actuator units per mm there halved (a direction may share the motion
        between actuators); the pen-speed cap kept (stroke._least_time)."""
        gain = float(np.min(np.abs(np.asarray(self.M, float)).max(axis=0))) / 2
        v, a = float(np.max(self.vmax)) / gain, float(np.max(self.amax)) / gain
        if self.pen_speed is not None:
            v = min(v, float(self.pen_speed))
        return v, a

    def derivatives(self, spline: Spline, u: np.ndarray):
        """theta'(u), theta''(u), each (len(u), n_act), and |q'(u)|."""
        d1, d2 = spline(u, 1), spline(u, 2)
        if self.M is not None:
            return linear_map(d1, self.M), linear_map(d2, self.M), np.hypot(d1[:, 0], d1[:, 1])
        _, t1, t2 = self.kinematics.derivatives(spline(u), d1, d2)
        return t1, t2, np.linalg.norm(d1, axis=1)


def linear_map(xy: np.ndarray, M: np.ndarray) -> np.ndarray:
    """xy (n, 2) @ M.T, written out: numpy hands a product this narrow to threaded BLAS,
    whose threads cost more CPU spinning than the sum (the 20x check grid: 40 % of planning)."""
    return xy[:, :1] * M[:, 0] + xy[:, 1:] * M[:, 1]


_GAUSS = np.polynomial.legendre.leggauss(6)


def _span_measures(spline: Spline, span_polys: constraints.Spans | None = None):
    """Arc length (mm) and total turning (rad) of every knot span."""
    from doodlecam.plan.kernels import span_measures

    sp = span_polys if span_polys is not None else constraints.spans(spline)
    x, w = _GAUSS
    length, turning = np.empty(len(sp.mid)), np.empty(len(sp.mid))
    span_measures(sp.T, (sp.bp[1:] - sp.bp[:-1]) / 2, x, w, length, turning)
    return length, turning


def make_grid(spline: Spline, spacing: float = SPACING, turn_step: float = TURN_STEP, n_points: int | None = None,
              min_per_span: int = 2, max_points: int = MAX_POINTS,
              span_polys: constraints.Spans | None = None) -> np.ndarray:
    """Grid in u: every knot; each span split so steps are ~``spacing`` mm and
    turn ~``turn_step`` rad at most (dense where the curve is tight), or into
    ``n_points`` nodes in total distributed by the same weights.
    ``span_polys``: constraints.spans(spline), if already computed."""
    bp = spline.breakpoints
    length, turning = _span_measures(spline, span_polys)
    weight = length / spacing + turning / turn_step
    if n_points is not None:
        n = np.maximum(np.floor(weight / weight.sum() * (n_points - 1)).astype(int), 1)
        short = (n_points - 1) - n.sum()  # hand out the remainder by largest weight per step
        if short > 0:
            order = np.argsort(-(weight / n))
            n[order[: min(short, len(n))]] += 1
            n[0] += max(short - len(n), 0)
    else:
        n = np.maximum(np.ceil(weight).astype(int), min_per_span)  # np.clip's values for integers
        total = int(n.sum())
        if total > max_points:
            n = np.maximum((n * max_points / total).astype(int), 1)
    from doodlecam.plan.kernels import grid_fill

    n = n.astype(np.int64, copy=False)
    u = np.empty(int(n.sum()) + 1)
    grid_fill(bp, n, u)
    return u


def build_rows(spline: Spline, u: np.ndarray, limits: Limits, mode: str = "bernstein",
               span_polys: constraints.Spans | None = None) -> constraints.Rows:
    if mode == "collocation":
        if limits.M is None:
            raise PlanError("collocation mode needs linear kinematics")
        return constraints.collocation_rows(spline, u, limits.M, limits.vmax, limits.amax, limits.pen_speed)
    if limits.M is not None:
        return constraints.bernstein_rows(spline, u, limits.M, limits.vmax, limits.amax, limits.pen_speed, span_polys)
    return constraints.sampled_rows(spline, u, limits.kinematics, limits.vmax, limits.amax, limits.pen_speed)


def profile_times(u: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Time (s) at every node of the profile b (inf after a node where it stops)."""
    from doodlecam.plan.kernels import times

    t = np.empty(len(u))
    times(np.asarray(u, float), np.asarray(b, float), t)
    return t


def interval_ratios(spline: Spline, u: np.ndarray, b: np.ndarray, limits: Limits, refine: int = CHECK_REFINE):
    """Per interval, the worst (acceleration, velocity, pen speed) / limit on
    ``refine`` points inside it, straight from the spline (no bounds)."""
    from doodlecam.plan.kernels import interval_worst, spline_interval_worst

    tau = _taus(refine)
    if limits.M is not None and spline.degree >= 2:
        c = spline.derivative_controls
        return spline_interval_worst(c[1], c[2], spline.degree, len(spline.control) - spline.degree,
                                     np.asarray(u, float), tau, np.asarray(b, float),
                                     np.ascontiguousarray(limits.M, float), np.asarray(limits.amax, float),
                                     np.asarray(limits.vmax, float), float(limits.pen_speed or 0.0))
    h = np.diff(u)
    uu = u[:-1, None] + tau[None, :] * h[:, None]
    # the right end as the interval's own limit: at a knot q'' (degree 2) or q' (degree 1) jumps
    uu[:, -1] = np.nextafter(u[1:], -np.inf)
    t1, t2, sp = limits.derivatives(spline, uu.ravel())
    return interval_worst(np.asarray(b, float), h, t1, t2, sp, limits.amax, limits.vmax,
                          float(limits.pen_speed or 0.0), refine)


@functools.lru_cache(maxsize=8)
def _taus(refine: int) -> np.ndarray:
    tau = np.linspace(0.0, 1.0, refine + 1)
    tau.flags.writeable = False
    return tau


def check_profile(spline: Spline, profile: Profile, limits: Limits, refine: int = CHECK_REFINE):
    """Worst (acceleration / limit, velocity / limit) on a grid ``refine`` times
    finer than the one solved on, evaluated directly from the spline."""
    wa, wv, wp = interval_ratios(spline, profile.u, profile.b, limits, refine)
    return float(wa.max()), float(max(wv.max(), wp.max()))


_NO_GRID = np.empty(0)  # (shared, never written to)
_NO_STRETCH = np.empty((0, 3))
_JERK_TAUS = np.array([0.0, 0.5, 1.0])  # constraints.jerk_coefficients' taus


def plan_checked(spline: Spline, limits: Limits, check_limits: Limits, solver: str = "reach", smoothing: float = 0.0,
                 jerk_max=None, grid: np.ndarray | None = None, jerk_period: float | None = None):
    """(plan_stroke(spline, limits, ...), check_profile(spline, that profile, check_limits)): the
    profile and its worst (acceleration, velocity) ratios within ``check_limits``. A curved cubic
    on linear kinematics with the reach solver (a generated drawing's 10^4 curves) takes two
    compiled calls (kernels.curve_rounds, curve_finish) instead of ~40 numpy and compiled ones,
    the same operations in the same order, so the same bits (tests/test_plan_batch.py)."""
    if (solver == "reach" and isinstance(spline, Spline) and spline.degree == 3 and limits.M is not None
            and check_limits.M is not None and not limits.problem and not spline.straight):
        jerk = _jerk_form(jerk_max)
        if jerk is not None:
            out = _fused(spline, limits, check_limits, jerk, grid)
            if out is not None:
                return out
    prof = plan_stroke(spline, limits, solver=solver, smoothing=smoothing, jerk_max=jerk_max, grid=grid,
                       jerk_period=jerk_period)
    return prof, check_profile(spline, prof, check_limits)


def _jerk_form(jerk_max):
    """jerk_max as curve_finish takes it: (base, (n, 3) stretches (lo, hi, factor)), () for no
    bound, or None for a bound it cannot take (a function of u other than follow.JerkBound)."""
    from doodlecam.plan.follow import JerkBound

    if type(jerk_max) is JerkBound:
        stretches = np.array(jerk_max.scaled, float).reshape(-1, 3) if jerk_max.scaled else _NO_STRETCH
        return float(jerk_max.base), stretches
    if not jerk_max:
        return ()
    if isinstance(jerk_max, (int, float)) and not isinstance(jerk_max, bool):
        return float(jerk_max), _NO_STRETCH
    return None


def _fused(spline: Spline, limits: Limits, check_limits: Limits, jerk, grid):
    """plan_checked's compiled calls: (profile, ratios), or None where the rounds meet a
    standing-still span (plan_stroke's Python rounds handle it)."""
    from doodlecam.plan.kernels import curve_finish, curve_rounds

    if grid is not None and _bad_grid(grid):
        return None  # plan_stroke says what is wrong, after the stroke's own problems
    c = spline.derivative_controls
    p = 3
    M, vmax, amax, pen2, R, B1, B2, tau8, pen = limits.cubic_rows
    bad, status, u, b, tot, beta, gamma, uu, sp, c12, c13, dot12 = curve_rounds(
        c[0], c[1], c[2], c[3], constraints._interior_taylor(p), spline.breakpoints, _GAUSS[0], _GAUSS[1], SPACING,
        TURN_STEP, MAX_POINTS, _NO_GRID if grid is None else np.array(grid, float), M, vmax, amax, pen2, R, B1, B2,
        tau8, pen, 0.0, 0.0, MAX_ROUNDS, _JERK_TAUS if jerk else _NO_GRID)
    if bad:
        raise PlanError(_INPUT_PROBLEMS[bad])
    if status == -2:
        return None
    if status != 0:
        raise PlanError(reach.message(status))
    base, stretches = jerk if jerk else (0.0, _NO_STRETCH)
    sp3, sp6 = (sp ** 3, sp ** 6) if jerk else (sp, sp)  # numpy's powers, as jerk_coefficients takes them
    cM, cv, ca = check_limits.arrays
    bad, status, b, a, t, acc, vel = curve_finish(
        u, b, tot, beta, gamma, uu, sp, sp3, sp6, c12, c13, dot12, _JERK_TAUS, base, stretches, _JERK_GROW, 0.0, 0.0,
        2.0, c[1], c[2], len(spline.control) - p, _taus(CHECK_REFINE), cM, ca, cv, float(check_limits.pen_speed or 0.0))
    if bad == 1:
        raise PlanError(reach.message(status))
    if bad == 2:
        raise PlanError("the start/end speeds cannot be met within the limits; lower them")
    if bad == 3:
        raise PlanError(_STOPS)
    return Profile.handed(u, b, a, t, "reach"), (float(acc), float(vel))  # the kernels' fresh arrays


_INPUT_PROBLEMS = {1: "the stroke has non-finite control points (NaN or infinity); fix the drawing",
                   2: "the stroke has zero length (all control points equal); drop it or draw a dot"}
_STOPS = "the planned profile stops mid-stroke (a limit forces zero speed); check the machine's limits"


def _bad_grid(grid) -> bool:
    g = np.asarray(grid, float)
    return g.ndim != 1 or len(g) < 2 or not _finite(g) or g[0] != 0.0 or g[-1] != 1.0 or bool((np.diff(g) <= 0).any())


def _solve(rows, u, solver: str, b0: float, bN: float) -> np.ndarray:
    if solver == "reach":
        try:
            return reach.solve(rows.tot, rows.beta, rows.gamma, rows.ub, b0, bN)
        except ValueError as e:
            raise PlanError(str(e)) from None
    kind, _, backend = solver.partition(":")
    return convex.solve_lp(rows, u, b0, bN, backend or "clarabel")


def _split(u: np.ndarray, which: np.ndarray) -> np.ndarray:
    mid = (u[:-1] + u[1:])[which] / 2
    return np.sort(np.concatenate([u, mid]))


def _finite(x) -> bool:
    return bool(np.all(np.isfinite(np.asarray(x, float))))


def check_inputs(spline: Spline, limits: Limits, v_start: float = 0.0, v_end: float = 0.0) -> None:
    """Raise a one-line PlanError unless the stroke and the limits can be planned:
    finite control points of a stroke with length, degree >= 1, positive finite
    limits (and pen cap), non-negative finite end speeds."""
    if not isinstance(spline, Spline):
        raise PlanError(f"expected a Spline to plan, got {type(spline).__name__}")
    if spline.degree < 1:
        raise PlanError(f"a degree-{spline.degree} spline has no velocity; fit the stroke with degree 1 or more")
    c = np.asarray(spline.control, float)
    lo, hi = c.min(axis=0).tolist(), c.max(axis=0).tolist()  # (NaN propagates into both)
    if not all(map(math.isfinite, lo + hi)):
        raise PlanError(_INPUT_PROBLEMS[1])
    tiny = 1e-9 * max(1.0, *map(abs, lo + hi))
    if max(h - l for l, h in zip(lo, hi)) <= tiny:
        raise PlanError(_INPUT_PROBLEMS[2])
    if spline.degree == 1 and (np.linalg.norm(np.diff(c, axis=0), axis=1) <= tiny).any():
        raise PlanError("the degree-1 stroke repeats a control point (a span without length); remove repeated points")
    if limits.problem:
        raise PlanError(limits.problem)
    for name, v in (("start", v_start), ("end", v_end)):
        if not (math.isfinite(v) and v >= 0):
            raise PlanError(f"the {name} speed must be a non-negative finite number of mm/s, got {v!r}")


def knot_caps(spline: Spline, u: np.ndarray, jerk_max=None, period: float | None = None) -> np.ndarray:
    """Upper bounds on b = u-dot^2 at the grid nodes u (inf where free).

    Where q' changes direction at a knot (degree 1: a corner) the pen must stop
    there: its velocity would jump. Where the curvature jumps at a knot (degree
    2) the pen's acceleration across the path jumps by v^2 |dkappa|; with
    ``jerk_max`` (mm/s^3) and the sample ``period`` (s), that jump counts as a
    jerk spread over one period, v^2 |dkappa| / period <= jerk_max, so the
    PLC's constant-acceleration periods can follow it as they follow the
    jerk-bounded rest of the curve (docs/sampling.md)."""
    cap = np.full(len(u), np.inf)
    bp = spline.breakpoints[1:-1]
    if spline.degree > 2 or len(bp) == 0:
        return cap
    at = np.flatnonzero(np.isin(u, bp))
    if len(at) == 0:
        return cap
    uk = u[at]
    left, right = np.nextafter(uk, -np.inf), uk
    d1l, d1r = spline(left, 1), spline(right, 1)
    if spline.degree == 1:
        cross = d1l[:, 0] * d1r[:, 1] - d1l[:, 1] * d1r[:, 0]
        corner = (np.abs(cross) > 1e-9 * np.linalg.norm(d1l, axis=1) * np.linalg.norm(d1r, axis=1)) | ((d1l * d1r).sum(axis=1) < 0)
        cap[at[corner]] = 0.0
        return cap
    if not jerk_max or not period:
        return cap

    def kappa(d1, d2):
        return (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.maximum(np.linalg.norm(d1, axis=1), 1e-300) ** 3

    jump = np.abs(kappa(d1l, spline(left, 2)) - kappa(d1r, spline(right, 2)))
    jm = jerk_max(uk) if callable(jerk_max) else np.full(len(uk), float(jerk_max))
    sp2 = np.maximum((d1r ** 2).sum(axis=1), 1e-300)
    with np.errstate(divide="ignore"):
        cap[at] = np.where(jump > 0, jm * period / (jump * sp2), np.inf)
    return cap


def _standing_still(rows: constraints.Rows, u: np.ndarray, b: np.ndarray, base: str, b0: float, bN: float):
    """No limit bounds b where q' = 0 on whole intervals (a span of equal control
    points: the pen stands still), so the solver leaves b = inf there and the
    profile's a and b are not finite. Any finite b keeps those rows: cap it at
    1e4 x the fastest b elsewhere and solve again (the time spent standing still,
    2 h / sqrt(b), is then 1 % of what the same stretch of u takes at that speed)."""
    fin = b[np.isfinite(b)]
    cap = np.where(np.isfinite(b), np.inf, 1e4 * max(float(fin.max(initial=0.0)), 1.0))
    rows = _capped(rows, cap)
    return rows, _solve(rows, u, base, b0, bN)


def _capped(rows: constraints.Rows, cap: np.ndarray) -> constraints.Rows:
    if np.isinf(cap).all():
        return rows
    return constraints.Rows(rows.tot, rows.beta, rows.gamma, np.minimum(rows.ub, cap))


def check_solver(solver: str) -> None:
    if solver not in SOLVERS:
        raise PlanError(f"unknown solver '{solver}'{did_you_mean(solver, SOLVERS)}; choose one of {', '.join(SOLVERS)}")
    if solver != "reach":  # the LP and the QP go through qpsolvers; the default needs none of it
        require("solvers", f"the {solver.partition(':')[0]} solver", "or use the default, --solver reach")


def plan_stroke(spline: Spline, limits: Limits, solver: str = "reach", spacing: float = SPACING,
                n_points: int | None = None, adaptive: bool = True, smoothing: float = 0.0,
                v_start: float = 0.0, v_end: float = 0.0, mode: str = "bernstein",
                max_rounds: int = MAX_ROUNDS, jerk_max=None, grid: np.ndarray | None = None,
                jerk_period: float | None = None) -> Profile:
    """Time-optimal profile along ``spline``; v_start / v_end are pen speeds (mm/s).

    ``jerk_max`` (mm/s^3, a number or a function of u such as
    follow.JerkBound): also bound the pen's jerk across the path
    (constraints.with_jerk), which slows it where the curve's turning changes
    fast; two more solves on the final grid (``JERK_GROW``).
    ``grid``: plan on these u instead of making (and refining) a grid, e.g. the
    grid of an earlier plan of the same stroke.
    ``jerk_period`` (s, the sample period): with ``jerk_max``, a curvature jump
    at a knot (degree 2) is bounded as that jerk over one period (knot_caps).
    Degree 1: the pen stops at every corner.

    Raises PlanError (one line) on inputs that cannot be planned (check_inputs).
    """
    check_solver(solver)
    check_inputs(spline, limits, v_start, v_end)
    if not (math.isfinite(spacing) and spacing > 0):
        raise PlanError(f"the grid spacing must be a positive number of mm, got {spacing!r}")
    if n_points is not None and n_points < 2:
        raise PlanError(f"a grid needs at least 2 points, got n_points = {n_points}")
    if grid is not None and _bad_grid(grid):
        raise PlanError("a planning grid must rise strictly from 0 to 1; pass the u of an earlier plan")
    d1 = spline.derivative_controls[1]
    (x0, y0), (x1, y1) = d1[0].tolist(), d1[-1].tolist()
    # |q'(0)|, |q'(1)|: a clamped spline's end controls (x^2 + y^2 as numpy sums a pair)
    b0 = (v_start / max(math.sqrt(x0 * x0 + y0 * y0), 1e-300)) ** 2
    bN = (v_end / max(math.sqrt(x1 * x1 + y1 * y1), 1e-300)) ** 2
    period = jerk_period if jerk_max else None
    if solver == "reach" and mode == "bernstein" and grid is None and n_points is None and is_straight(spline, limits):
        return _trapezoid(spline, limits, b0, bN)
    sp = constraints.spans(spline)  # the span polynomials, shared by the grid and every round's rows
    if grid is not None:
        u, adaptive = np.asarray(grid, float), False
    else:
        u = make_grid(spline, spacing, n_points=n_points, span_polys=sp)
    base = solver if solver.startswith(("reach", "lp")) else "reach"
    nonlinear = limits.M is None and mode != "collocation"
    done = None
    if base == "reach" and mode == "bernstein" and limits.M is not None and spline.degree >= 3 and max_rounds >= 1:
        done = _compiled_rounds(spline, u, limits, sp, b0, bN, max_rounds, adaptive)  # no knot caps at degree 3
    if done is not None:
        u, b, rows = done
    else:
        u, b, rows = _rounds(spline, u, limits, sp, b0, bN, max_rounds, adaptive, mode, base, jerk_max, period)
    if jerk_max:
        base_rows = rows
        coefficients = constraints.jerk_coefficients(spline, u)
        jm = constraints.jerk_bound(coefficients, jerk_max)
        if base == "reach":
            rows, b = _jerk_solves(base_rows, coefficients, u, jm, b, b0, bN)
        else:
            rows, b = _jerk_python(base_rows, coefficients, u, jm, b, b0, bN, base)
    if solver.startswith("qp"):
        backend = solver.partition(":")[2] or "clarabel"
        b = convex.solve_smooth(rows, u, smoothing if smoothing > 0 else 1.0, b, b0, bN, backend)
    b = _certify(spline, u, b, limits, b0, bN, rows if not nonlinear else None)
    a = (b[1:] - b[:-1]) / (2 * (u[1:] - u[:-1]))  # np.diff's subtraction, without its wrapper
    t = profile_times(u, b)
    if not np.isfinite(t).all():
        raise PlanError(_STOPS)
    return Profile(u=u, b=b, a=a, t=t, solver=solver)


def _compiled_rounds(spline: Spline, u, limits: Limits, sp: constraints.Spans, b0, bN, max_rounds: int, adaptive: bool):
    """_rounds in one compiled call (kernels.plan_rounds) where the rows have no knot caps, the
    same (u, b, rows); None where b is not finite (_rounds handles a standing-still span)."""
    from doodlecam.plan.kernels import plan_rounds

    p, pen = spline.degree, limits.pen_speed
    M = np.ascontiguousarray(limits.M, float)
    R = M.shape[0] * 4 * p + (2 * p if pen is not None else 0)  # as constraints.bernstein_rows
    c = spline.derivative_controls
    status, u, b, tot, beta, gamma = plan_rounds(
        sp.T, sp.bp, sp.mid, np.asarray(u, float), M, np.asarray(limits.vmax, float), np.asarray(limits.amax, float),
        float(pen) ** 2 if pen is not None else 0.0, R, constraints._b_matrix(p - 1), constraints._b_matrix(2 * p - 1),
        c[1], c[2], p, len(spline.control) - p, _taus(8), float(pen or 0.0), float(b0), float(bN), max_rounds,
        bool(adaptive))
    if status == -2:
        return None
    if status != 0:
        raise PlanError(reach.message(status))
    return u, b, constraints.Rows(tot, beta, gamma, np.full(len(u), np.inf))


def _rounds(spline, u, limits, sp, b0, bN, max_rounds, adaptive, mode, base, jerk_max, period):
    """Solve on the grid u and, while it pays (``adaptive``), refine it where a row binds but
    its bound is loose (linear kinematics) or the check finds a limit passed (nonlinear):
    (u, b, rows) of the last solve."""
    nonlinear = limits.M is None and mode != "collocation"
    best_t = np.inf
    for round_ in range(max_rounds):
        rows = _capped(build_rows(spline, u, limits, mode, sp), knot_caps(spline, u, jerk_max, period))
        b = _solve(rows, u, base, b0, bN)
        if not np.isfinite(b).all():
            rows, b = _standing_still(rows, u, b, base, b0, bN)
        if mode == "collocation" or not (adaptive or nonlinear):
            break
        wa, wv, wp = interval_ratios(spline, u, b, limits, refine=8 if not nonlinear else CHECK_REFINE)
        worst = np.maximum(np.maximum(wa, wv), wp)
        if nonlinear:
            split = worst > 1 + 1e-9  # sampled rows missed a peak: refine there
        else:
            used = constraints.worst_ratios(rows, b)
            t = profile_times(u, b)[-1]
            if not np.isfinite(t) or t > best_t * (1 - 1e-4):
                break  # refinement no longer pays
            best_t = t
            split = (used > 1 - 1e-6) & (worst < 1 - 2e-3)  # binding, but the bound is loose
        if not split.any() or len(u) + split.sum() > 200_000 or round_ == max_rounds - 1:
            break  # (u and b stay in step: split only when another solve follows)
        u = _split(u, split)
    return u, b, rows


def _jerk_python(base_rows, coefficients, u, jm, b, b0, bN, base):
    """The solves with the jerk rows (``JERK_GROW``): (rows, b) of the last."""
    b_free = b
    for grow in JERK_GROW:
        # b <= b_hat keeps sqrt(b) below the sqrt(b_hat) the rows were made with
        b_hat = np.minimum(b_free, grow * b) * (1 + 1e-12)
        rows = constraints.with_jerk(base_rows, coefficients, u, b_hat, jm)
        first = base_rows.tot.shape[1]  # the jerk rows
        if grow == JERK_GROW[0] and constraints.worst_ratios(rows, b_free, first).max(initial=0.0) <= 1.0:
            break  # the plan already keeps the bound (a straight stroke, say): it is the answer
        b = _solve(rows, u, base, b0, bN)
    return rows, b


def _jerk_solves(base_rows, coefficients, u, jm, b, b0, bN):
    """_jerk_python for the reach solver in one compiled call (kernels.jerk_solves), the same (rows, b)."""
    from doodlecam.plan.kernels import jerk_solves

    taus, _, c1, c2 = coefficients
    status, b, tot, beta, gamma, ub = jerk_solves(
        base_rows.tot, base_rows.beta, base_rows.gamma, np.asarray(base_rows.ub, float), c1, c2, taus,
        np.asarray(u, float), jm, np.asarray(b, float), _JERK_GROW, float(b0), float(bN))
    if status != 0:
        raise PlanError(reach.message(status))
    return constraints.Rows(tot, beta, gamma, ub), b


def is_straight(spline: Spline, limits: Limits) -> bool:
    """A straight stroke at constant speed in u (q'' = 0: a fitted segment) on
    linear kinematics, whose optimum is a trapezoid."""
    return limits.M is not None and spline.degree >= 2 and spline.straight


def _trapezoid(spline: Spline, limits: Limits, b0: float, bN: float) -> Profile:
    """The exact time-optimal profile of a straight stroke: with q' constant and
    q'' = 0 every limit is a bound on |a| or on b alone, so the fastest profile
    accelerates at the largest allowed a, cruises at the largest allowed b and
    brakes (hatching has thousands of these; the general solver costs ~1.5 ms each)."""
    q1 = spline.derivative_controls[1][0]  # q', mm per u, the same everywhere
    d = linear_map(q1[None, :], np.asarray(limits.M, float))[0]  # actuator units per u (written out, as plan.lines)
    with np.errstate(divide="ignore"):
        a = float(np.min(limits.amax / np.abs(d)))
        cap = float(np.min(limits.vmax ** 2 / d ** 2))
    if limits.pen_speed:
        cap = min(cap, float(limits.pen_speed) ** 2 / float(q1 @ q1))
    if max(b0, bN) > cap * (1 + 1e-9):
        raise PlanError("the start/end speeds cannot be met within the limits; lower them")
    if b0 > (bN + 2 * a) * (1 + 1e-9):
        raise PlanError("the requested start speed is too high to stop in time")
    if bN > (b0 + 2 * a) * (1 + 1e-9):
        raise PlanError("the requested end speed cannot be reached within the stroke; lower it")
    u1, u2 = (cap - b0) / (2 * a), 1.0 - (cap - bN) / (2 * a)
    if u1 < u2:
        u = np.array([0.0, u1, u2, 1.0])
    else:  # no time to cruise: accelerate until braking must start
        u = np.unique(np.clip([0.0, (bN - b0 + 2 * a) / (4 * a), 1.0], 0.0, 1.0))
    # a hair inside the limits, as the general solver's certify leaves it; the ends as asked
    b = np.minimum(np.minimum(b0 + 2 * a * u, bN + 2 * a * (1 - u)), cap) * (1 - 1e-12)
    b[0], b[-1] = b0, bN
    return Profile.handed(u, b, np.diff(b) / (2 * np.diff(u)), profile_times(u, b), "reach")  # all made here


def _certify(spline, u, b, limits, b0, bN, rows) -> np.ndarray:
    """Remove solver-tolerance violations exactly: the rows are homogeneous in b
    (rest to rest), so scaling b down by the worst ratio restores them. For
    sampled (nonlinear) rows the 20x finer check itself is the certificate."""
    if rows is not None:
        from doodlecam.plan.kernels import max_ratio

        r = float(max_ratio(rows.tot, rows.beta, rows.gamma, b))
        fin = np.isfinite(rows.ub) & (rows.ub > 0)
        if fin.any():
            r = max(r, float((b[fin] / rows.ub[fin]).max()))
        acc_r, vel_r = r, np.sqrt(max(r, 0.0))
    else:
        wa, wv, wp = interval_ratios(spline, u, b, limits)
        acc_r, vel_r = float(wa.max()), float(max(wv.max(), wp.max()))
    c = min(1.0 / max(acc_r, 1e-300), 1.0 / max(vel_r ** 2, 1e-300))  # all-zero rows (b = 0): no scaling
    if c < 1.0:
        if (b0 > 0 or bN > 0) and c < 1 - 1e-6:
            raise PlanError("the start/end speeds cannot be met within the limits; lower them")
        b = b * c * (1 - 1e-12)
    return b
