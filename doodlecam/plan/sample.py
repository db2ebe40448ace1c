"""Sample: a planned stroke as velocity targets every dT for the PLC.

The PLC ramps each axis linearly from one velocity target to the next over a
period dT (report 2.1.0.5): the position it reaches is the trapezoidal sum of
the targets and its acceleration on each period is (v_j - v_j-1) / dT.
Sampling the planned velocity naively drifts off the curve (the report's
footnote to 2.4.6): a time-optimal plan switches acceleration between sample
instants, which whole-period ramps cannot follow in time.

They can follow it in *space*. The targets solve a small QP per stroke whose
reached positions x_j must lie within ``tolerance`` of the curve near the
planned point q(s_j), with a free tangential shift d_j (the pen may run a
little ahead or behind the plan, never off the path):

    minimise   sum_j d_j^2 + lam |v_j - v_plan(t_j)|^2
    subject to |x_j - q(s_j) - q'(s_j) d_j| <= tol  per axis (linearised; then
               re-linearised at s_j + d_j and checked exactly),
               x_j = x_j-1 + dT (v_j-1 + v_j) / 2, the end point reached exactly
               in whole machine steps, the last target zero (rest),
               |M (v_j - v_j-1)| <= A_max dT and |M v_j| <= V_max per actuator.

If the limits leave no such targets in ceil(T / dT) periods, periods are
added (the stroke runs slightly slower than planned) until they do.

Up to DENSE_INSTANTS instants (most strokes of a drawing) the QP is solved
exactly by quadprog's dual active-set method (kernels.sample_qp builds it), longer
strokes, pen-speed cones and nonlinear actuator rows by Clarabel.

``follow=True`` (a path tolerance is set) also penalises the targets'
component *across* the curve at every instant, with the shifts kept within a
trust region so the linearisation holds. With each instant on the curve and
the pen moving along it there, the period's parabola is the quadratic that
touches the curve at both ends, which hugs it; and the one motion the instants
cannot see, targets alternating +-e that keep every x_j in place but swing
the pen e dT / 4 off the curve between them, is damped (docs/sampling.md).
"""

from __future__ import annotations

import collections
import functools
import math
import threading

import numpy as np

from doodlecam.errors import PlanError
from doodlecam.model import Stroke, StrokeSamples

# Weight of velocity fidelity against timing fidelity (per dT^2).
VELOCITY_WEIGHT = 1e-3
# Largest distance per axis (in machine steps) from a sample instant's position to the curve;
# half a step is the target, 0.4 leaves room for whole-steps/s rounding in the post.
TRACKING_STEPS = 0.4
# follow=True: a target's velocity across the curve, e, is penalised as the swing
# e dT / 4 it causes mid-period, with this weight (per mm^2, against 1 per mm^2 of
# shift at the instants); shifts per solve stay within ~TRUST_MM of arc.
NORMAL_WEIGHT = 10.0
TRUST_MM = 0.5
# Up to this many instants the QP is solved densely (quadprog), past it by Clarabel: the dense
# method's cost grows as m^3 (~0.7 ms a solve at 20-24 instants, 2.9 ms at 35-40), Clarabel's
# about as m (0.8 ms, 1.3 ms): benchmarks/bench_sample.py measures both by instants.
DENSE_INSTANTS = 24
_NO_ROWS, _NONE = np.empty((0, 2)), np.empty(0)  # for the kernels' absent arguments
_ZERO = np.zeros(1)


class _Coo:
    """Sparse matrix assembled from index arrays (scipy's block helpers cost
    ~15 ms per stroke, ten times the solve itself)."""

    def __init__(self, ncols: int):
        self.r, self.c, self.v, self.n, self.ncols = [], [], [], 0, ncols

    def add(self, rows, cols, vals):
        rows = np.asarray(rows)
        self.r.append((rows + self.n).ravel())
        self.c.append(np.broadcast_to(cols, rows.shape).ravel())
        self.v.append(np.broadcast_to(np.asarray(vals, float), rows.shape).ravel())

    def close(self, nrows: int):
        self.n += nrows

    def csc(self):
        import scipy.sparse as sp

        return sp.csc_matrix((np.concatenate(self.v), (np.concatenate(self.r), np.concatenate(self.c))),
                             shape=(self.n, self.ncols))


def _clarabel(P, q, A, b, n_eq, n_soc=0, n_tail=0):
    """min 1/2 z'Pz + q'z s.t. the first ``n_eq`` rows of A z = b, the last
    3 ``n_soc`` rows before the last ``n_tail`` ones b - A z in second-order
    cones of dimension 3, the rest <= b (P upper triangular, CSC). Clarabel directly: qpsolvers' checks and
    re-stacking cost more than the solve."""
    import clarabel

    # the solver copies the settings and cones at set-up, so one of each serves every solve
    cones = _cones(n_eq, A.shape[0] - n_eq - 3 * n_soc - n_tail, n_soc, n_tail)
    res = clarabel.DefaultSolver(P, q, A, b, cones, _settings()).solve()
    return np.asarray(res.x) if res.status == clarabel.SolverStatus.Solved else None


@functools.lru_cache(maxsize=1)
def _settings():
    import clarabel

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    # refinement buys residuals of 3e-10 instead of 1e-8 (mm, mm/s) at a quarter of the
    # time; the limit rows keep a 1e-6 relative margin and positions are checked after
    settings.iterative_refinement_enable = False
    return settings


@functools.lru_cache(maxsize=256)
def _cones(n_eq: int, n_ineq: int, n_soc: int, n_tail: int) -> list:
    import clarabel

    cones = [clarabel.ZeroConeT(n_eq), clarabel.NonnegativeConeT(n_ineq)] + [clarabel.SecondOrderConeT(3)] * n_soc
    return cones + [clarabel.NonnegativeConeT(n_tail)] if n_tail else cones


@functools.lru_cache(maxsize=256)
def _objective(m: int):
    """CSC pattern (upper triangle) of the objective for m instants: diagonal,
    plus each target's (vx_j, vy_j) coupling for the penalty across the curve.
    Returns the matrix (zeros) and where in its data the diagonal of vx, the
    diagonal of vy and the couplings go."""
    import scipy.sparse as sp

    n = m - 1
    N = 2 * n + 3 * m
    # column c < n (vx_c): row c; column n + j (vy_j): rows j, n + j; the rest: diagonal
    counts = np.ones(N, np.int64)
    counts[n : 2 * n] = 2
    indptr = np.concatenate([[0], np.cumsum(counts)])
    indices = np.arange(N, dtype=np.int64).repeat(counts)
    jn = np.arange(n)
    indices[indptr[n + jn]] = jn
    P = sp.csc_matrix((np.zeros(len(indices)), indices, indptr), shape=(N, N))
    return P, indptr[jn], indptr[n + jn] + 1, indptr[n + jn]


_TAG = 1e9
_WORK = threading.local()  # per thread: working copies of the cached matrices, filled in place


def _working(key, template):
    """This thread's copy of a cached (immutable) matrix: Clarabel copies its data
    at set-up, so one copy per pattern can be refilled for every solve instead of
    building a scipy matrix each time (a quarter of a millisecond)."""
    cache = getattr(_WORK, "cache", None)
    if cache is None:
        cache = _WORK.cache = collections.OrderedDict()
    if key in cache:
        cache.move_to_end(key)
    else:
        cache[key] = template.copy()
        if len(cache) > 64:
            cache.popitem(last=False)
    return cache[key]


@functools.lru_cache(maxsize=256)
def _pattern(m: int, dt: float, M: tuple | None, trust: bool, pen: bool = False):
    """The constraint matrix for m instants, built once per (m, dT, kinematics):
    only the tangent coefficients of the tracking rows change between solves
    (assembling the rest every time cost as much as the solve). Returns the CSC
    matrix with zeros there, the number of equality rows, and where in the CSC
    data the tangent coefficients go (positions, and the sign, instant and axis
    of each).

    Unknowns: [vx (n), vy (n), xx (m), xy (m), d (m)], n = m - 1: targets v_1..v_n
    (v_0 = v_m = 0), positions x_1..x_m from the start, shifts d in mm along the
    tangent. Rows: ramps and end point (equalities); tracking boxes at instants
    1..m-1; monotone shifted parameter; per actuator |M dv| <= A dT and |M v| <= V;
    with ``trust``, |d| <= a trust radius; with ``pen``, last, one second-order
    cone (cap, v_j) per target: |v_j| <= the pen-speed cap.
    """
    n = m - 1
    nv, nx = 2 * n, 2 * m
    N = nv + nx + m
    V = lambda a, j: a * n + j  # noqa: E731  column of v_{j+1} on axis a
    X = lambda a, j: nv + a * m + j  # noqa: E731  column of x_{j+1}
    D = lambda j: nv + nx + j  # noqa: E731
    j, jn, k = np.arange(m), np.arange(n), np.arange(m - 1)
    A = _Coo(N)
    # ramp: x_j - x_j-1 - dT/2 (v_j-1 + v_j) = 0 at instants 1..m; then the end exactly
    for a in range(2):
        A.add(j, X(a, j), 1.0)
        A.add(j[1:], X(a, j[1:] - 1), -1.0)
        A.add(jn, V(a, jn), -dt / 2)
        A.add(jn + 1, V(a, jn), -dt / 2)
        A.close(m)
    A.add(np.arange(2), [X(0, m - 1), X(1, m - 1)], 1.0)
    A.close(2)
    n_eq = A.n
    # tracking box: sign (x - tang d) <= sign p + tol; the tangent entries hold
    # -(_TAG + their index) so they can be found after the CSC sort
    tags = []
    for sign in (1.0, -1.0):
        for a in range(2):
            A.add(k, X(a, k), sign)
            A.add(k, D(k), -(_TAG + len(tags) * (m - 1) + k))
            tags.append((sign, a))
            A.close(m - 1)
    # the shifted parameter stays monotone: u_j + d_j / L <= u_j+1 + d_j+1 / L
    A.add(k, D(k), 1.0)
    A.add(k, D(k + 1), -1.0)
    A.close(m - 1)
    if M is not None:
        Mk = np.asarray(M, float).reshape(-1, 2)
        na = Mk.shape[0]
        for sign in (1.0, -1.0):  # blocks of m acceleration rows, then n velocity rows
            for a in range(2):
                c = sign * Mk[:, a]
                off = (np.arange(na) * (m + n))[:, None]
                A.add(off + jn, np.broadcast_to(V(a, jn), (na, n)), np.repeat(c[:, None], n, 1))
                A.add(off + jn + 1, np.broadcast_to(V(a, jn), (na, n)), np.repeat(-c[:, None], n, 1))
                A.add(off + m + jn, np.broadcast_to(V(a, jn), (na, n)), np.repeat(c[:, None], n, 1))
            A.close(na * (m + n))
    if trust:
        for sign in (1.0, -1.0):
            A.add(j, D(j), sign)
            A.close(m)
    if pen:  # s = (cap, v_x, v_y) = b - A z: rows (0; -1 at vx_j; -1 at vy_j)
        A.add(3 * jn + 1, V(0, jn), -1.0)
        A.add(3 * jn + 2, V(1, jn), -1.0)
        A.close(3 * n)
    csc = A.csc()
    tagged = np.flatnonzero(csc.data <= -_TAG)
    idx = (-csc.data[tagged] - _TAG).astype(np.int64)  # 0 .. 4 (m-1) - 1
    block, inst = np.divmod(idx, max(m - 1, 1))
    signs = np.array([t[0] for t in tags])[block]
    axes = np.array([t[1] for t in tags])[block]
    csc.data[tagged] = 0.0
    return csc, n_eq, tagged, signs, inst, axes


def _crank_rows(J: np.ndarray, dt: float, vcap: np.ndarray, acap: np.ndarray):
    """Rows (CSC over the QP's unknowns) and bounds keeping nonlinear actuators
    within ``vcap``, ``acap`` at the instants, linearised: J (m, n_act, 2) is
    d theta / d xy at the points aimed at, instants 1..m. Velocity J_j v_j;
    a period's mean acceleration (J_j v_j - J_j-1 v_j-1) / dT (v_0 = v_m = 0,
    exact for theta' at the instants). How far the acceleration strays from
    that mean inside a period is left to the caller's margin (pipeline)."""
    m, na, _ = J.shape
    n = m - 1
    N = 2 * n + 3 * m
    A = _Coo(N)
    jn = np.arange(n)
    for sign in (1.0, -1.0):
        for i in range(na):
            for a in range(2):  # mean accelerations of periods 1..m: +J_p v_p, -J_p-1 v_p-1
                A.add(jn, a * n + jn, sign * J[:n, i, a])
                A.add(jn + 1, a * n + jn, -sign * J[:n, i, a])
            A.close(m)
            for a in range(2):
                A.add(jn, a * n + jn, sign * J[:n, i, a])
            A.close(n)
    rhs = np.concatenate([np.concatenate([np.full(m, acap[i] * dt), np.full(n, vcap[i])])
                          for _ in (1.0, -1.0) for i in range(na)])
    return A.csc(), rhs


def _qp(p, tang, v_plan, end, dt, tol, bounds, L, nrm=None, trust=None, crank=None, shifted=None):
    """One linearised QP. p: (m, 3) curve points relative to the start and
    their u, tang: (m, 2) tangents per mm of shift, end: (2,) float, bounds: _Bounds.
    Returns (v, x, d) or None.

    ``shifted`` (m,): how far (mm of arc) p already lies from the anchor points; the cost is
    the total shift (shifted + d)^2, so re-linearised solves converge to one answer.

    ``nrm`` (m, 2): unit normals of the curve at the instants; the targets'
    components along them are penalised with NORMAL_WEIGHT.
    ``trust``: (m,) bounds on |d|, so the linearisation holds.
    ``crank``: (rows, bounds) of _crank_rows, appended last.
    """
    m = len(p)
    n = m - 1
    nv, nx = 2 * n, 2 * m
    pen = bounds.pen_speed is not None
    lam = VELOCITY_WEIGHT * dt * dt
    if crank is None and not pen and m <= DENSE_INSTANTS:
        got = _dense_qp(p, tang, v_plan, end, dt, tol, bounds, L, nrm, trust, shifted, lam)
        if got is not False:
            return got
    M = bounds.key
    key = (m, float(dt), M, trust is not None, pen)
    base, n_eq, tagged, signs, inst, axes = _pattern(*key)
    A = _working(key, base)
    P, dx, dy, cross = _objective(m)
    P = _working(m, P)
    limited = M is not None
    n_rows = 2 * m + 2 + 5 * (m - 1) + (2 * len(bounds.amax) * (m + n) if limited else 0) \
        + (2 * m if trust is not None else 0) + (3 * n if pen else 0)
    q, b = np.empty(nv + nx + m), np.empty(n_rows)
    # in one compiled pass (kernels.qp_fill): A's tangent entries, the objective (its
    # diagonal; with nrm, the swing e dT / 4 per unit of velocity across, weighted
    # NORMAL_WEIGHT), q and b: the tracking boxes, the monotone shifts, the actuator rows a
    # hair inside the limits (solver tolerance, ~1e-8, never shows as overshoot), the trust
    # region and the pen-speed cones (the velocity is linear on a period, so |v| <= cap at
    # both ends holds throughout)
    from doodlecam.plan.kernels import qp_fill

    qp_fill(tang, tagged, signs, inst, axes, A.data, P.indices, P.data, dx, dy, cross,
            nrm if nrm is not None else _NO_ROWS, NORMAL_WEIGHT * (dt / 4) ** 2, lam, v_plan,
            shifted if shifted is not None else np.zeros(m), p, tol, L, end, bounds.amax, bounds.vmax,
            float(dt), trust if trust is not None else _NONE, float(bounds.pen_speed) if pen else -1.0, q, b)
    n_tail = 0
    if crank is not None:
        import scipy.sparse as sp

        A, b, n_tail = sp.vstack([A, crank[0]], format="csc"), np.concatenate([b, crank[1]]), len(crank[1])
    z = _clarabel(P, q, A, b, n_eq, n if pen else 0, n_tail)
    if z is None:
        return None
    return z[:nv].reshape(2, n).T, z[nv : nv + nx].reshape(2, m).T, z[nv + nx : nv + nx + m]


def _dense_qp(p, tang, v_plan, end, dt, tol, bounds, L, nrm, trust, shifted, lam):
    """_qp's problem solved exactly by quadprog (Goldfarb and Idnani's dual active-set method) on
    the dense arrays of kernels.sample_qp: (v, x, d), None where it is infeasible, or False where
    quadprog gives up (use Clarabel). An active-set answer is the QP's optimum to rounding, so the
    rows hold without an interior point's residuals; for a few dozen instants it costs a fraction
    of Clarabel's set-up (benchmarks/bench_sample.py)."""
    solve_qp, sample_qp = _dense_solvers()
    m = len(p)
    n = m - 1
    H, a, C, b, T = _dense_arrays(m, len(bounds.amax), trust is not None)
    sample_qp(tang, p, v_plan, shifted if shifted is not None else np.zeros(m), nrm if nrm is not None else _NO_ROWS,
              NORMAL_WEIGHT * (dt / 4) ** 2, lam, tol, L, end, bounds.M if bounds.M is not None else _NO_ROWS,
              bounds.amax, bounds.vmax, float(dt), trust if trust is not None else _NONE, H, a, C, b, T)
    try:  # quadprog: min 1/2 z'Hz - a'z subject to C' z >= b, the first meq rows equalities
        z = solve_qp(H, a, C.T, b, 2)[0]
    except ValueError as e:  # "constraints are inconsistent, no solution" is its verdict of infeasible
        return None if "inconsistent" in str(e) else False
    v = z[:2 * n].reshape(2, n).T
    return v, T @ v, z[2 * n:]


@functools.lru_cache(maxsize=1)
def _dense_solvers():
    """(quadprog.solve_qp, kernels.sample_qp), imported on first use (numba's import is slow), then
    looked up once instead of at each of ~10^4 solves."""
    import quadprog

    from doodlecam.plan.kernels import sample_qp

    return quadprog.solve_qp, sample_qp


def _dense_arrays(m: int, na: int, trusted: bool):
    """This thread's arrays for kernels.sample_qp of m instants, na actuators, with or without the
    trust rows: quadprog copies what it is handed, and x = T v is taken before the next fill."""
    cache = getattr(_WORK, "dense", None)
    if cache is None:
        cache = _WORK.dense = {}
    key = (m, na, trusted)
    got = cache.get(key)
    if got is None:
        n = m - 1
        nz, nc = 2 * n + m, 2 + 5 * (m - 1) + 2 * na * (m + n) + (2 * m if trusted else 0)
        got = cache[key] = (np.empty((nz, nz)), np.empty(nz), np.empty((nc, nz)), np.empty(nc), np.empty((m, n)))
    return got


def whole_step_limits(limits, steps_per_mm, dt: float):
    """``limits`` lowered by what writing the targets in whole steps/s can add.

    The PLC post rounds the running sum of the targets (steps/s) to integers
    and writes the differences (link/plc/packetfile.commands_array): with
    S_j = k (v_1 + ... + v_j) and e_j = round(S_j) - S_j in [-1/2, 1/2], e_0 = 0,
    the written target is k v_j + e_j - e_j-1 (off by at most 1 step/s) and a
    period's change k (v_j - v_j-1) + e_j - 2 e_j-1 + e_j-2 (by at most 2). The
    header's max_accel is the limit rounded down, up to 1 step/s^2 lower, so
    a period's change may use A k dT - dT of it. Hence, per actuator i of
    theta = M xy: acceleration lower by sum_a |M_ia| (2 + dT) / (k_a dT), velocity
    by sum_a |M_ia| / k_a, and the pen-speed cap by |(1/k_x, 1/k_y)|. Planned
    and sampled within these, the written file keeps the profile's limits and
    its own header (tests/test_executed.py reads it back). Nonlinear kinematics:
    only the pen cap (the cranks are checked along the executed ramps).
    """
    from dataclasses import replace

    k = np.asarray(steps_per_mm, float)
    pen = limits.pen_speed
    if pen is not None:
        pen = float(pen) - float(np.hypot(*(1.0 / k)))
    if limits.M is None:
        return replace(limits, pen_speed=pen)
    absM = np.abs(np.asarray(limits.M, float))
    return replace(limits, vmax=limits.vmax - absM @ (1.0 / k), amax=limits.amax - absM @ ((2.0 + dt) / (k * dt)),
                   pen_speed=pen)


class _Bounds:
    """What every solve reads of the lowered limits, as the kernels take it (made once per job)."""

    __slots__ = ("pen_speed", "M", "key", "amax", "vmax", "too_low")

    def __init__(self, limits):
        self.pen_speed = limits.pen_speed
        limited = limits.M is not None
        self.too_low = (limited and ((limits.vmax <= 0).any() or (limits.amax <= 0).any())) or \
            (limits.pen_speed is not None and limits.pen_speed <= 0)
        self.M = np.asarray(limits.M, float) if limited else None
        self.key = tuple(self.M.ravel()) if limited else None  # _pattern's cache key
        self.amax = np.asarray(limits.amax, float) if limited else _NONE
        self.vmax = np.asarray(limits.vmax, float) if limited else _NONE


_LOWERED: list = [None]  # the last (limits, (k, dT), lowered limits, _Bounds)


def _lowered(limits, k: np.ndarray, dt: float):
    """whole_step_limits(limits, k, dt) and its _Bounds, remembered for the last limits: a job
    samples all its strokes with one Limits (per pen), which are never changed in place (they
    cache their own checks too). Swapping one tuple keeps threads safe."""
    key = (float(k[0]), float(k[1]), float(dt))
    last = _LOWERED[0]
    if last is not None and last[0] is limits and last[1] == key:
        return last[2], last[3]
    low = whole_step_limits(limits, k, dt)
    bounds = _Bounds(low)
    _LOWERED[0] = (limits, key, low, bounds)
    return low, bounds


def sample_stroke(stroke: Stroke, dt: float, limits, steps_per_mm=(80.0, 80.0), tracking_steps: float = TRACKING_STEPS,
                  max_extra: float = 1.0, follow: bool = False, crank_share: tuple[float, float] | None = None) -> StrokeSamples:
    """Velocity targets (mm/s) for one planned stroke at t = dT, 2 dT, ...

    The stroke starts and ends on whole machine steps (``steps_per_mm``), so a
    post that writes whole steps lands exactly on every stroke's end; the
    targets keep ``limits`` lowered by ``whole_step_limits``, so they still keep
    ``limits`` once written in whole steps/s (plan the stroke within the
    lowered limits too, or the sampler may need extra periods).
    ``follow``: also keep the pen moving along the curve at the instants, so it
    stays near the curve between them (see the module doc; up to 5 linearised
    solves instead of 3).
    ``crank_share`` (velocity, acceleration), nonlinear kinematics: keep the
    actuators' velocity at the instants and mean acceleration per period
    within these shares of their limits (_crank_rows; the pipeline lowers the
    shares by what a period's variation adds, measured on the executed ramps).
    """
    prof, spline = stroke.profile, stroke.spline
    k = np.asarray(steps_per_mm, float)
    if prof is None:
        raise PlanError("the stroke has no profile; plan it (plan_stroke) before sampling")
    if not 0.0 < dt < math.inf:  # (NaN fails too) plain comparisons: numpy's checks cost 5 us a stroke
        raise PlanError(f"delta_time must be a positive number of seconds, got {dt!r}; fix [sampling] delta_time")
    kl = k.tolist()
    if k.shape != (2,) or not all(0.0 < x < math.inf for x in kl):
        raise PlanError(f"steps_per_mm must be two positive numbers, got {kl}; fix the machine profile")
    limits, bounds = _lowered(limits, k, dt)
    if bounds.too_low:
        raise PlanError("the limits are below one machine step per sample period; raise them or steps_per_mm")
    # both ends in whole steps in one pass (the same roundings and divisions, elementwise)
    ends = np.round(spline.control[[0, -1]] * k) / k
    start = ends[0]
    end = ends[1] - start
    tol = tracking_steps / max(kl)  # (k.max()'s value: two positive numbers)
    if crank_share is None and spline.degree >= 2 and spline.straight:  # (straight_samples: None for the rest)
        fast = straight_samples(stroke, dt, limits, k, tol)
        if fast is not None:
            return fast
    L = max(spline.length, 1e-9)
    from doodlecam.plan.kernels import relinearise, sample_aim

    dc, deg, nseg = spline.derivative_controls, spline.degree, len(spline.control) - spline.degree

    def attempt(m: int) -> StrokeSamples | None:
        c = prof.duration / (m * dt)  # time scale <= 1: a uniformly slower plan is within limits
        # the plan's points at t = c dT, 2 c dT, ... (the last the end) and velocities there (the last
        # zero), linearised there: the points aimed at (from the start, with their u), the tangents (d
        # is in mm of arc, roughly: q(u + d/L) ~ q + q' d / L); following, the unit normals and the
        # trust region, ~TRUST_MM of arc (compiled, with the bits of Profile.state_at and Spline)
        u, v_plan, pu, tang = np.empty(m), np.empty((m, 2)), np.empty((m, 3)), np.empty((m, 2))
        nrm, trust = (np.empty((m, 2)), np.empty(m)) if follow else (_NO_ROWS, _NONE)
        sample_aim(prof.t, prof.u, prof.b, prof.a, c, dt, dc[0], dc[1], deg, nseg, start, L, u, v_plan, pu,
                   tang, nrm, trust, TRUST_MM)
        if not follow:
            nrm, trust = None, None
        ok = False
        anchor = u  # where the shifts are costed from: the planned points, then the first solve's
        for it in range(5 if follow else 3):  # linearise, solve, re-linearise at the shifted points
            crank = None
            if crank_share is not None and limits.M is None:
                J = _jacobians(limits.kinematics, spline(u))
                # whole steps/s add up to 1 (velocity) and 2 (a period's change) steps/s per axis
                absJ = np.abs(J).max(axis=0)
                crank = _crank_rows(J, dt, limits.vmax * crank_share[0] * (1 - 1e-6) - absJ @ (1.0 / k),
                                    limits.amax * crank_share[1] * (1 - 1e-6) - absJ @ (2.0 / (k * dt)))
            # the box is 3/4 of the tolerance: the rest absorbs the linearisation error
            res = _qp(pu, tang, v_plan, end, dt, 0.75 * tol, bounds, L, nrm, trust, crank, (u - anchor) * L)
            if res is None and it == 0 and trust is not None:
                # the ramps may need to run further behind (or ahead of) the plan than the trust region
                # lets one solve shift: the first solve then sets the timing without it, and the
                # re-linearised solves that follow keep it (docs/sampling.md)
                res = _qp(pu, tang, v_plan, end, dt, 0.75 * tol, bounds, L, nrm, None, crank, (u - anchor) * L)
            if res is None:
                break
            v, x, d = res
            # checked at u + d / L (per axis: steps are per axis), where the frame is remade; linearised
            # there next, unless made monotone (then there)
            u_new, u_mono = np.empty(m), np.empty(m)
            if relinearise(dc[0], dc[1], deg, nseg, u, d, L, x, start, tol, pu, tang,
                           nrm if follow else _NO_ROWS, trust if follow else _NONE, TRUST_MM, u_new, u_mono):
                ok = True
                u = u_new
                break
            u = u_mono
            if it == 0:
                # the first solve sets the samples' timing (whole-period ramps cannot keep the
                # plan's); costing later shifts from there, not from the last solve, lets the
                # re-linearised solves converge instead of drifting (docs/sampling.md)
                anchor = u
        if not ok:
            return None
        vel = np.zeros((m, 2))
        vel[:-1] = v
        # (start is every attempt's: a copy of it)
        return StrokeSamples.handed(start.copy(), vel, dt, c, np.concatenate((_ZERO, u)))

    m0 = max(math.ceil(prof.duration / dt - 1e-9), 2)  # up, then down to rest
    m, bad = m0, m0 - 1
    while m <= m0 * (1 + max_extra) + 4:
        got = attempt(m)
        if got is not None:
            # periods were added in steps of 5 %: bisect back towards the last failure, to 1 % (more
            # periods = a uniformly slower plan, so feasibility is monotone in practice; a failed
            # probe only keeps the longer samples)
            while m - bad > max(1, m0 // 100):
                mid = (m + bad) // 2
                probe = attempt(mid)
                if probe is None:
                    bad = mid
                else:
                    m, got = mid, probe
            return got
        bad, m = m, m + max(1, m0 // 20)
    raise PlanError("cannot follow the stroke within the limits with velocity samples every "
                    f"{dt * 1000:g} ms; use a shorter [sampling] delta_time")


def straight_samples(stroke: Stroke, dt: float, limits, k: np.ndarray, tol: float) -> StrokeSamples | None:
    """The fewest-period samples of a straight stroke in closed form, or None where the QP is needed.

    Along a straight line every target points one way, e = (end - start) / D, so
    the QP reduces to speeds s_j >= 0 with |s_j - s_j-1| <= A dT, s_j <= V (A, V:
    the tightest actuator and pen limits along e) and dT sum s_j = D. For m
    periods the pointwise greatest feasible speeds min(V, A dT j, A dT (m - j))
    go furthest; the least m that reaches D, its speeds scaled down to land on
    D exactly, is the optimum (scaling down keeps every limit). Generated
    drawings are mostly such lines: this is ~50x cheaper than the QP. ``limits``
    are already lowered for whole steps; None (use the QP) for nonlinear
    kinematics, a curve, a stroke under one step long, or an instant too far
    off its aim.

    The whole-step ends tilt the drawn segment off the line by up to half a
    step per axis at each end. Each instant aims at the point as far along the
    line as it is along the segment, so its offset is the blend of the ends'
    (at most half a step per axis); it must be within ``tol`` or within half a
    step less what writing the targets in whole steps/s may move it (dT / 2
    steps), else the QP bends the pen onto the line.
    """
    from doodlecam.plan.planner import is_straight

    spline = stroke.spline
    if limits.M is None or not is_straight(spline, limits):
        return None
    start = np.round(spline.start * k) / k
    end = np.round(spline.end * k) / k - start
    D = float(np.hypot(*end))
    if D * k.max() < 1.0:
        return None
    e = end / D
    from doodlecam.plan.planner import linear_map

    along = np.abs(linear_map(e[None, :], np.asarray(limits.M, float))[0])  # written out, as plan.lines
    use = along > 0
    vcap = float(np.min(limits.vmax[use] / along[use])) * (1 - 1e-6)
    if limits.pen_speed is not None:
        vcap = min(vcap, float(limits.pen_speed) * (1 - 1e-6))
    dv = float(np.min(limits.amax[use] / along[use])) * dt * (1 - 1e-6)  # the largest change per period
    # never faster than the plan (a slowed plan stays slow); m periods of ramps are one of the
    # continuous motions, so the plan's time is also about the least m for a plan at full speed
    m = max(int(np.ceil(stroke.profile.duration / dt - 1e-9)), 2)
    while True:
        j = np.arange(1, m)
        speed = np.minimum(np.minimum(dv * j, dv * (m - j)), vcap)
        reach = dt * float(np.cumsum(speed)[-1])  # summed in order, as plan.lines' compiled loop sums it
        if reach >= D:
            break
        m += 1
    speed *= D / reach
    v = np.concatenate([[0.0], speed, [0.0]])
    f = np.minimum(np.append(0.0, np.cumsum(0.5 * dt * (v[1:] + v[:-1]))) / D, 1.0)  # instants 0 .. m dT
    a0, d = spline.start, spline.end - spline.start
    pos = start + f[:, None] * end
    u = f  # the straight spline is a0 + u d
    if (np.abs(pos - (a0 + u[:, None] * d))[1:-1] > straight_bound(tol, k, dt)).any():
        return None
    vel = np.vstack([speed[:, None] * e, np.zeros((1, 2))])
    return StrokeSamples.handed(start, vel, dt, stroke.profile.duration / (m * dt), u)  # all made here


def straight_bound(tol: float, k: np.ndarray, dt: float) -> np.ndarray:
    """Per axis (mm), how far a straight stroke's instant may be from its aim (straight_samples)."""
    return np.maximum(tol, (0.5 - 0.5 * dt - 1e-9) / np.asarray(k, float))


def _jacobians(kinematics, xy: np.ndarray) -> np.ndarray:
    """d theta / d xy (len(xy), n_act, 2) from the kinematics' derivatives."""
    zero = np.zeros_like(xy)
    cols = [kinematics.derivatives(xy, np.broadcast_to(e, xy.shape), zero)[1] for e in ((1.0, 0.0), (0.0, 1.0))]
    return np.stack(cols, axis=2)


def written_samples(samples: StrokeSamples, steps_per_mm) -> StrokeSamples:
    """The samples as the PLC post writes them (whole steps/s) and the machine
    executes them, in mm/s: what the executed-path checks should read."""
    from doodlecam.plan.kernels import written_velocity

    k = np.asarray(steps_per_mm, float)
    vel = np.empty(samples.velocity.shape)  # link.plc.packetfile.whole_step_targets(velocity, k) / k, compiled
    written_velocity(samples.velocity, k, vel)
    # the same fields, the start shared (read-only already), the new targets handed over
    return StrokeSamples.handed(samples.start, vel, samples.delta_time, samples.time_scale, samples.sample_u)


def reference_positions(stroke: Stroke, samples: StrokeSamples) -> np.ndarray:
    """The curve points the sampler aimed at for t = 0, dT, ..., M dT (mm)."""
    if samples.sample_u is not None:
        return stroke.spline(samples.sample_u)
    t = samples.delta_time * np.arange(len(samples.velocity) + 1)
    u, _, _ = stroke.profile.state_at(samples.time_scale * t)
    pos = stroke.spline(u)
    pos[-1] = stroke.spline.end
    return pos
