"""Sample: a planned stroke as velocity targets every dT for the PLC.

The PLC ramps each axis linearly from one velocity target to the next over a
period dT (report 2.1.0.5), so the position it reaches is the trapezoidal sum
of the targets, and its acceleration on each period is (v_j - v_j-1)/dT.
Sampling the planned velocity naively makes that sum drift off the curve (the
report's footnote to 2.4.6). Instead the targets solve a small QP per stroke:

    minimise   sum_j |x_j - q(t_j)|^2 + lam |v_j - v_plan(t_j)|^2
    subject to the end point reached exactly, the last target zero (rest),
               |M (v_j - v_j-1)| <= A_max dT  and  |M v_j| <= V_max  per actuator,

so the executed stream itself respects the machine's limits.
"""

from __future__ import annotations

import warnings

import numpy as np

from .errors import PlanError
from .model import Stroke, StrokeSamples

# Weight of velocity fidelity against position fidelity, per dT^2.
VELOCITY_WEIGHT = 1e-3
# Largest distance (mm) between reached and planned positions at sample instants.
TRACKING_TOLERANCE = 0.1


def _solve(stroke: Stroke, dt: float, m: int, limits):
    """Targets for the plan slowed uniformly to last exactly m periods, and
    the largest position error at the sample instants (mm)."""
    import scipy.sparse as sp
    from qpsolvers import solve_qp

    prof, spline = stroke.profile, stroke.spline
    c = prof.duration / (m * dt)  # time scale <= 1: slower is always within limits
    t = dt * np.arange(1, m + 1)
    u, ud, _ = prof.state_at(c * t)
    target = spline(u) - spline.start  # positions to reach at each instant
    target[-1] = spline.end - spline.start
    v_plan = spline(u, 1) * (c * ud)[:, None]
    v_plan[-1] = 0.0
    # Unknowns per axis: targets v_1..v_n (n = m - 1; v_0 = v_m = 0) and the
    # positions reached x_1..x_m, tied by the ramp: x_j = x_j-1 + dT (v_j-1 + v_j)/2.
    # Keeping x as variables makes every matrix banded, so the QP is O(m).
    n = m - 1
    lam = VELOCITY_WEIGHT * dt * dt
    I2 = sp.eye(2)
    wv = np.full(n, lam)
    wx = np.ones(m)
    wx[-1] = 0.0  # the end point is an equality below
    P = sp.csc_matrix(sp.kron(I2, sp.diags(np.concatenate([wv, wx]))))
    q = -np.concatenate([np.concatenate([lam * v_plan[:n, i], target[:, i] * wx]) for i in range(2)])
    S = sp.diags([1.0, 1.0], [0, -1], shape=(m, n))  # v_j-1 + v_j for j = 1..m
    X = sp.diags([1.0, -1.0], [0, -1], shape=(m, m))  # x_j - x_j-1
    ramp = sp.hstack([-dt / 2 * S, X])
    end = sp.csr_matrix(([1.0], ([0], [n + m - 1])), shape=(1, n + m))
    Aeq = sp.csc_matrix(sp.kron(I2, sp.vstack([ramp, end])))
    beq = np.concatenate([np.append(np.zeros(m), target[-1, i]) for i in range(2)])
    # differences v_j - v_j-1 for j = 1..m, mapped to actuators. (Nonlinear
    # kinematics: the pen's targets cannot be bounded per actuator linearly;
    # the plan itself is certified, the samples only track it.)
    G = h = None
    if limits.M is not None:
        D = sp.hstack([sp.diags([1.0, -1.0], [0, -1], shape=(m, n)), sp.csr_matrix((m, m))])
        V = sp.hstack([sp.eye(n), sp.csr_matrix((n, m))])
        Mact = sp.csr_matrix(limits.M)
        Gd, Gv = sp.kron(Mact, D), sp.kron(Mact, V)
        # a hair inside the limits so solver tolerance (~1e-8) never shows as overshoot
        da = np.repeat(limits.amax * dt * (1 - 1e-6), m)
        dv = np.repeat(limits.vmax * (1 - 1e-6), n)
        G = sp.csc_matrix(sp.vstack([Gd, -Gd, Gv, -Gv]))
        h = np.concatenate([da, da, dv, dv])
    with warnings.catch_warnings():  # "infeasible" is an expected answer here
        warnings.simplefilter("ignore")
        v = solve_qp(P, q, G, h, Aeq, beq, solver="clarabel")
    if v is None:
        return None, np.inf
    x = np.column_stack([v[n : n + m], v[2 * n + m :]])
    return np.column_stack([v[:n], v[n + m : 2 * n + m]]), float(np.abs(x - target).max())


def sample_stroke(stroke: Stroke, dt: float, limits, tolerance: float = TRACKING_TOLERANCE) -> StrokeSamples:
    """Velocity targets (mm/s) for one planned stroke at t = dT, 2 dT, ...

    A time-optimal plan switches acceleration between sample instants, which
    a ramp of whole periods cannot follow within the same limits; where the
    reached positions would stray more than ``tolerance`` (mm) from the curve,
    the stroke is slowed uniformly by whole periods until they do not.
    """
    m0 = max(int(np.ceil(stroke.profile.duration / dt - 1e-9)), 2)  # up, then down to rest
    best = (None, np.inf, m0)
    m = m0
    while m <= 2 * m0 + 4:
        v, err = _solve(stroke, dt, m, limits)
        if v is not None and err < best[1]:
            best = (v, err, m)
        if err <= tolerance:
            break
        m += max(1, m0 // 10)
    v, err, m = best
    if v is None:
        raise PlanError("cannot sample a stroke within the acceleration limits at this dT; use a shorter [sampling] delta_time")
    vel = np.vstack([v, np.zeros((1, 2))])
    return StrokeSamples(start=stroke.spline.start, velocity=vel, delta_time=dt, time_scale=stroke.profile.duration / (m * dt))


def reference_positions(stroke: Stroke, samples: StrokeSamples) -> np.ndarray:
    """Where the (uniformly slowed) plan puts the pen at t = 0, dT, ..., M dT (mm)."""
    t = samples.delta_time * np.arange(len(samples.velocity) + 1)
    u, _, _ = stroke.profile.state_at(samples.time_scale * t)
    pos = stroke.spline(u)
    pos[-1] = stroke.spline.end
    return pos
