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

``between=True`` also penalises the pen's offset from the curve (normal to it)
at 1/3 and 2/3 of every period, with the shifts kept within a trust region so
the linearisation holds. That damps the one motion the instants cannot see:
targets alternating +-e keep every x_j in place but swing the pen e dT / 4 off
the curve between them (docs/sampling.md).
"""

from __future__ import annotations

import functools

import numpy as np

from .errors import PlanError
from .model import Stroke, StrokeSamples

# Weight of velocity fidelity against timing fidelity (per dT^2).
VELOCITY_WEIGHT = 1e-3
# Largest distance per axis (in machine steps) from a sample instant's position to the curve;
# half a step is the target, 0.4 leaves room for whole-steps/s rounding in the post.
TRACKING_STEPS = 0.4
# between=True: the pen's offset from the curve (normal to it) at these fractions
# of every period is penalised with this weight (per mm^2, against 1 per mm^2 of
# shift at the instants); shifts per solve stay within ~TRUST_MM of arc.
BETWEEN_WEIGHT = 10.0
BETWEEN_FRACTIONS = (1 / 3, 2 / 3)
TRUST_MM = 0.2


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


def _clarabel(P_diag, q, A, b, n_eq):
    """min 1/2 z'diag(P)z + q'z s.t. the first ``n_eq`` rows of A z = b, the rest <= b.
    Clarabel directly: qpsolvers' checks and re-stacking cost more than the solve."""
    import clarabel
    import scipy.sparse as sp

    n = len(q)
    P = sp.csc_matrix((P_diag, np.arange(n), np.arange(n + 1)), shape=(n, n))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    cones = [clarabel.ZeroConeT(n_eq), clarabel.NonnegativeConeT(A.shape[0] - n_eq)]
    res = clarabel.DefaultSolver(P, q, A, b, cones, settings).solve()
    return np.asarray(res.x) if res.status == clarabel.SolverStatus.Solved else None


_TAG = 1e9


@functools.lru_cache(maxsize=256)
def _pattern(m: int, dt: float, M: tuple | None):
    """The constraint matrix for m instants, built once per (m, dT, kinematics):
    only the tangent coefficients of the tracking rows change between solves
    (assembling the rest every time cost as much as the solve). Returns the CSC
    matrix with zeros there, the number of equality rows, and where in the CSC
    data the tangent coefficients go (positions, and the sign, instant and axis
    of each).

    Unknowns: [vx (n), vy (n), xx (m), xy (m), d (m)], n = m - 1: targets v_1..v_n
    (v_0 = v_m = 0), positions x_1..x_m from the start, shifts d in mm along the
    tangent. Rows: ramps and end point (equalities); tracking boxes at instants
    1..m-1; monotone shifted parameter; per actuator |M dv| <= A dT and |M v| <= V.
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
    csc = A.csc()
    tagged = np.flatnonzero(csc.data <= -_TAG)
    idx = (-csc.data[tagged] - _TAG).astype(np.int64)  # 0 .. 4 (m-1) - 1
    block, inst = np.divmod(idx, max(m - 1, 1))
    signs = np.array([t[0] for t in tags])[block]
    axes = np.array([t[1] for t in tags])[block]
    csc.data[tagged] = 0.0
    return csc, n_eq, tagged, signs, inst, axes


def _qp(p, tang, v_plan, end, dt, tol, limits, L, between=None, trust=None):
    """One linearised QP. p: (m, 3) curve points relative to the start and
    their u, tang: (m, 2) tangents per mm of shift, end: (2,). Returns (v, x, d) or None.

    ``between`` = (ref, nrm), each (m, F, 2): curve points (relative to the start)
    and unit normals at BETWEEN_FRACTIONS of every period; the pen's offsets from
    them along the normals become unknowns e, penalised with BETWEEN_WEIGHT.
    ``trust``: (m,) bounds on |d|, so the linearisation holds.
    """
    import scipy.sparse as sp

    m = len(p)
    n = m - 1
    nv, nx = 2 * n, 2 * m
    M = None if limits.M is None else tuple(np.asarray(limits.M, float).ravel())
    base, n_eq, tagged, signs, inst, axes = _pattern(m, float(dt), M)
    data = base.data.copy()
    data[tagged] = -signs * tang[inst, axes]
    A = sp.csc_matrix((data, base.indices, base.indptr), shape=base.shape)
    lam = VELOCITY_WEIGHT * dt * dt
    P = np.concatenate([np.full(nv, lam), np.zeros(nx), np.ones(m)]) + 1e-12
    q = np.concatenate([-lam * v_plan[:n, 0], -lam * v_plan[:n, 1], np.zeros(nx + m)])
    rhs = [np.zeros(2 * m), end]
    for sign in (1.0, -1.0):
        for a in range(2):
            rhs.append(sign * p[:-1, a] + tol)
    rhs.append(L * np.diff(p[:, 2]))
    if M is not None:
        # a hair inside the limits so solver tolerance (~1e-8) never shows as overshoot
        for _sign in (1.0, -1.0):
            for i in range(len(limits.amax)):
                rhs += [np.full(m, limits.amax[i] * dt * (1 - 1e-6)), np.full(n, limits.vmax[i] * (1 - 1e-6))]
    rhs = np.concatenate(rhs)
    if between is not None:
        A, rhs, n_eq, P, q = _with_between(A, rhs, n_eq, P, q, m, dt, between, trust)
    z = _clarabel(P, q, A, rhs, n_eq)
    if z is None:
        return None
    v = np.column_stack([z[:n], z[n:nv]])
    x = np.column_stack([z[nv : nv + m], z[nv + m : nv + 2 * m]])
    return v, x, z[nv + nx : nv + nx + m]


def _with_between(A, rhs, n_eq, P, q, m, dt, between, trust):
    """The QP of ``_qp`` plus the between-instant offsets: equality rows
    e = n . (x_j + dT (al v_j + be v_j+1) - ref) (x_0 = v_0 = v_m = 0) after the
    other equalities, and |d| <= trust after the inequalities."""
    import scipy.sparse as sp

    ref, nrm = between
    n, F = m - 1, ref.shape[1]
    nv, nx = 2 * n, 2 * m
    N = A.shape[1]
    V = lambda a, j: a * n + j  # noqa: E731  (columns as in _pattern)
    X = lambda a, j: nv + a * m + j  # noqa: E731
    j, jn = np.arange(m), np.arange(n)
    extra = _Coo(N + m * F)
    for f, frac in enumerate(BETWEEN_FRACTIONS):
        al, be = frac - frac * frac / 2, frac * frac / 2  # the ramp's position at frac of a period
        extra.add(j, N + j * F + f, 1.0)
        for a in range(2):
            extra.add(j[1:], X(a, j[1:] - 1), -nrm[1:, f, a])
            extra.add(j[1:], V(a, j[1:] - 1), -dt * al * nrm[1:, f, a])
            extra.add(jn, V(a, jn), -dt * be * nrm[:-1, f, a])
        extra.close(m)
    e_rhs = np.concatenate([-(nrm[:, f] * ref[:, f]).sum(axis=1) for f in range(F)])
    box = _Coo(N + m * F)
    for sign in (1.0, -1.0):
        box.add(j, nv + nx + j, sign)
        box.close(m)
    zeros = sp.csc_matrix((A.shape[0], m * F))
    Ab = sp.hstack([A, zeros], format="csr")
    full = sp.vstack([Ab[:n_eq], extra.csc(), Ab[n_eq:], box.csc()], format="csc")
    rhs = np.concatenate([rhs[:n_eq], e_rhs, rhs[n_eq:], trust, trust])
    P = np.concatenate([P, np.full(m * F, BETWEEN_WEIGHT)])
    q = np.concatenate([q, np.zeros(m * F)])
    return full, rhs, n_eq + m * F, P, q


def _between_refs(spline, u, start):
    """Curve points (relative to ``start``) and unit normals at BETWEEN_FRACTIONS
    of every period, by parameter between the instants' u (u_0 = 0): (m, F, 2) each."""
    m = len(u)
    u0 = np.concatenate([[0.0], u[:-1]])
    uf = (u0[:, None] + np.asarray(BETWEEN_FRACTIONS)[None, :] * (u - u0)[:, None]).ravel()
    d1 = spline(uf, 1)
    nrm = np.column_stack([-d1[:, 1], d1[:, 0]]) / np.maximum(np.linalg.norm(d1, axis=1), 1e-300)[:, None]
    return (spline(uf) - start).reshape(m, -1, 2), nrm.reshape(m, -1, 2)


def sample_stroke(stroke: Stroke, dt: float, limits, steps_per_mm=(80.0, 80.0), tracking_steps: float = TRACKING_STEPS,
                  max_extra: float = 1.0, between: bool = False) -> StrokeSamples:
    """Velocity targets (mm/s) for one planned stroke at t = dT, 2 dT, ...

    The stroke starts and ends on whole machine steps (``steps_per_mm``), so a
    post that writes whole steps lands exactly on every stroke's end.
    ``between``: also pull the pen onto the curve between the instants (see the
    module doc; several times slower).
    """
    prof, spline = stroke.profile, stroke.spline
    k = np.asarray(steps_per_mm, float)
    start = np.round(spline.start * k) / k
    end = np.round(spline.end * k) / k - start
    tol = tracking_steps / k.max()
    L = max(spline.length, 1e-9)
    m0 = max(int(np.ceil(prof.duration / dt - 1e-9)), 2)  # up, then down to rest
    m = m0
    while m <= m0 * (1 + max_extra) + 4:
        c = prof.duration / (m * dt)  # time scale <= 1: a uniformly slower plan is within limits
        t = dt * np.arange(1, m + 1)
        u, ud, _ = prof.state_at(c * t)
        u[-1] = 1.0
        v_plan = spline(u, 1) * (c * ud)[:, None]
        v_plan[-1] = 0.0
        ok = False
        for _ in range(5 if between else 3):  # linearise, solve, re-linearise at the shifted points
            p = spline(u) - start
            d1 = spline(u, 1)
            tang = d1 / L  # d is in mm of arc (roughly): q(u + d/L) ~ q + q' d / L
            mid = trust = None
            if between:
                mid = _between_refs(spline, u, start)
                trust = TRUST_MM * L / np.maximum(np.linalg.norm(d1, axis=1), 1e-12)  # ~TRUST_MM of arc
            # the box is 3/4 of the tolerance: the rest absorbs the linearisation error
            res = _qp(np.column_stack([p, u]), tang, v_plan, end, dt, 0.75 * tol, limits, L, mid, trust)
            if res is None:
                break
            v, x, d = res
            u_new = np.clip(u + d / L, 0.0, 1.0)
            u_new[-1] = 1.0
            err = np.abs(x - (spline(u_new) - start))[:-1]  # per axis: steps are per axis
            if err.size == 0 or err.max() <= tol:
                ok = True
                u = u_new
                break
            u = np.maximum.accumulate(u_new)
        if ok:
            vel = np.vstack([v, np.zeros((1, 2))])
            return StrokeSamples(start=start, velocity=vel, delta_time=dt, time_scale=c, sample_u=np.append(0.0, u))
        m += max(1, m0 // 20)
    raise PlanError("cannot follow the stroke within the limits with velocity samples every "
                    f"{dt * 1000:g} ms; use a shorter [sampling] delta_time")


def reference_positions(stroke: Stroke, samples: StrokeSamples) -> np.ndarray:
    """The curve points the sampler aimed at for t = 0, dT, ..., M dT (mm)."""
    if samples.sample_u is not None:
        return stroke.spline(samples.sample_u)
    t = samples.delta_time * np.arange(len(samples.velocity) + 1)
    u, _, _ = stroke.profile.state_at(samples.time_scale * t)
    pos = stroke.spline(u)
    pos[-1] = stroke.spline.end
    return pos
