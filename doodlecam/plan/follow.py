"""Follow: how far the ramping machine strays from the curve between samples.

The PLC ramps each axis's velocity linearly over every period dT, so between
two sample instants the pen moves on a parabola (constant acceleration). The
samples keep the pen on the spline *at* the instants (doodlecam.plan.sample); in
between, the parabola cuts across whatever the spline does within one period.
A period covers l = v dT of arc; where the curve turns or wiggles within l,
the parabola cuts across, and targets that alternate +-e (invisible at the
instants) swing the pen e dT / 4 off the curve.

``path_deviation`` measures what is executed: the parabola of every period
against the spline (a Newton projection from where the sampler aimed), so the
distance is known between samples, not only at them. The pipeline reports the
worst value per job ("pen on the curve" in the summary). With ``[sampling]
path_tolerance`` set, the planner also bounds the pen's jerk across the path
(``jerk_limit``), the sampler keeps the pen moving along the curve at the
instants, and where a stroke is still measured beyond the tolerance its bound
is lowered there (``JerkBound.tightened``) and it is planned again
(doodlecam.pipeline).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from doodlecam.model import Spline, StrokeSamples

# Jerk across the path (mm/s^3) allowed per mm of path tolerance and per dT^-3 (a
# period's swing is ~ j dT^3 / 24 and swings add up); where a stroke still strays
# the bound is lowered there and the stroke re-planned. On camera.png (0.1 mm, 40 ms):
# 16 re-plans none and draws 86 s; 24 re-plans 4 strokes, 75 s; 32 re-plans 26, 70 s,
# at 10 % more planning time (benchmarks/bench_convert.py).
JERK_PER_TOL = 24.0
REACH = 2  # periods either side of one that strays whose jerk bound is lowered with it
SUB = 16  # points per period where the executed parabola is checked (8 read ~3 % low)
CANDIDATES = 8  # parameters tried per point before the Newton steps


def executed_points(samples: StrokeSamples, sub: int = SUB) -> np.ndarray:
    """(M, sub + 1, 2): where the ramping machine is at sub + 1 times in every period."""
    dt = samples.delta_time
    x = samples.integrate()
    v = np.vstack([np.zeros((1, 2)), samples.velocity])
    tau = np.linspace(0.0, dt, sub + 1)
    return (x[:-1, None, :] + v[:-1, None, :] * tau[None, :, None]
            + (v[1:] - v[:-1])[:, None, :] * (tau ** 2 / (2 * dt))[None, :, None])


def _aim_points(spline: Spline, samples: StrokeSamples, n: int = 4096) -> np.ndarray:
    """Curve parameters of the instants for samples without them (e.g. read from
    a file): the distance travelled maps to arc length, then each instant takes
    the nearest curve point within three periods' travel of that guess."""
    x = samples.integrate()
    grid = np.linspace(0.0, 1.0, n)
    pts = spline(grid)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    step = np.linalg.norm(np.diff(x, axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(step)]) * arc[-1] / max(step.sum(), 1e-300)
    reach = 3 * max(step.max(initial=0.0), arc[-1] / n)
    s = np.clip(travelled[:, None] + np.linspace(-reach, reach, 64)[None, :], 0.0, arc[-1])
    cand = np.interp(s, arc, grid)
    d = np.linalg.norm(spline(cand.ravel()).reshape(*cand.shape, 2) - x[:, None, :], axis=2)
    return np.maximum.accumulate(cand[np.arange(len(x)), d.argmin(axis=1)])


def distance_to_stretch(spline: Spline, x: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                        candidates: int = CANDIDATES, iterations: int = 4) -> np.ndarray:
    """Distance (mm) from each point x (n, 2) to the spline's stretch u in [lo, hi]
    (per point): the nearest of ``candidates`` evenly spread parameters, then
    Newton steps on (q(u) - x) . q'(u) = 0 kept within one spacing of it
    (compiled: plan.kernels.distance_to_stretch)."""
    from doodlecam.plan import kernels

    c = spline.derivative_controls
    out = np.empty(len(x))
    kernels.distance_to_stretch(c[0], c[1], c[min(2, spline.degree)], spline.degree, len(spline.control) - spline.degree,
                                np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(lo, dtype=float),
                                np.ascontiguousarray(hi, dtype=float), candidates, iterations, out)
    return out


@lru_cache(maxsize=64)
def _period_times(dt: float, sub: int) -> tuple[np.ndarray, np.ndarray]:
    """sub + 1 times across a period dT and tau^2 / 2 dT there (path_deviation; shared, not written to)."""
    tau = np.linspace(0.0, dt, sub + 1)
    return tau, tau ** 2 / (2 * dt)


def path_deviation(spline: Spline, samples: StrokeSamples, sub: int = SUB) -> np.ndarray:
    """Per period, the largest distance (mm) of the executed parabola from the spline.

    Each executed point is projected onto the stretch of the spline the
    sampler aimed at in that period, widened by half on each side
    (``distance_to_stretch``). So the distance is to the curve being drawn
    then, not to another part of it that passes nearby.
    """
    su = samples.sample_u
    if su is None:
        su = _aim_points(spline, samples)
    if not spline.straight:  # the points, their distances and the peaks in one compiled pass
        from doodlecam.plan import kernels

        tau, c2dt = _period_times(float(samples.delta_time), sub)
        c = spline.derivative_controls
        out = np.empty(len(samples.velocity))
        kernels.executed_deviation(c[0], c[1], c[min(2, spline.degree)], spline.degree,
                                   len(spline.control) - spline.degree, samples.start, samples.velocity,
                                   0.5 * samples.delta_time, tau, c2dt, np.asarray(su, float), CANDIDATES, 4, out)
        return out
    pts = executed_points(samples, sub)
    m = len(pts)
    x = pts.reshape(-1, 2)
    # the period's u-step widened by half of it on each side
    span = np.maximum(np.diff(su), 1e-9)
    lo = np.repeat(np.maximum(su[:-1] - span / 2, 0.0), sub + 1)
    hi = np.repeat(np.minimum(su[1:] + span / 2, 1.0), sub + 1)
    # a straight stroke, q(u) = a + u d: the nearest point of the stretch in closed form
    a, d = spline.start, spline.end - spline.start
    u = np.clip((x - a) @ d / float(d @ d), lo, hi)
    dist = np.hypot(*(x - a - u[:, None] * d).T).reshape(m, sub + 1)
    # the peak usually falls between the points: a parabola through the largest
    # and its neighbours in time recovers it (a kink where the curve turns tightly still reads a little low)
    k = np.clip(dist.argmax(axis=1), 1, sub - 1)
    r = np.arange(m)
    fm, f0, fp = dist[r, k - 1], dist[r, k], dist[r, k + 1]
    curv = 2 * f0 - fm - fp
    peak = f0 + np.where(curv > 1e-15, (fp - fm) ** 2 / (8 * np.maximum(curv, 1e-15)), 0.0)
    return np.maximum(dist.max(axis=1), np.minimum(peak, f0 + np.abs(fp - fm)))


def ramp_ratios(samples: StrokeSamples, kinematics, vmax, amax, sub: int = 8) -> tuple[float, float]:
    """Worst (acceleration, velocity) / limit of the actuators along the executed
    ramps, at ``sub`` + 1 times in every period. For nonlinear kinematics (the
    five-bar arm) the samples are pen motion, whose constant-acceleration periods
    the cranks follow with varying acceleration; a linear map keeps the limits
    the sampler's rows impose."""
    dt = samples.delta_time
    pos = executed_points(samples, sub)
    v = np.vstack([np.zeros((1, 2)), samples.velocity])
    acc = ((v[1:] - v[:-1]) / dt)[:, None, :]
    vel = v[:-1, None, :] + acc * np.linspace(0.0, dt, sub + 1)[None, :, None]
    _, t1, t2 = kinematics.derivatives(pos.reshape(-1, 2), vel.reshape(-1, 2),
                                       np.broadcast_to(acc, pos.shape).reshape(-1, 2))
    return float((np.abs(t2) / amax).max(initial=0.0)), float((np.abs(t1) / vmax).max(initial=0.0))


@dataclass(frozen=True)
class JerkBound:
    """The planner's jerk bound along one stroke (mm/s^3 at curve parameter u):
    ``base``, times the factor of every stretch in ``scaled`` ((u_lo, u_hi,
    factor) each) that u lies in."""

    base: float
    scaled: tuple[tuple[float, float, float], ...] = ()

    def __call__(self, u: np.ndarray) -> np.ndarray:
        scale = np.ones_like(u, dtype=float)
        for lo, hi, f in self.scaled:
            scale[(u >= lo) & (u <= hi)] *= f
        return self.base * scale

    def tightened(self, samples: StrokeSamples, deviation: np.ndarray, tolerance: float,
                  reach: int = REACH) -> "JerkBound":
        """Lowered where the executed path strayed beyond ``tolerance``, in
        proportion (a period's swing grows with the jerk), with a margin: each
        such period widened by ``reach`` periods on both sides (the swing builds
        up over the periods before it)."""
        su = samples.sample_u
        bad = np.flatnonzero(deviation > tolerance)
        merged: list[list[float]] = []
        for k in bad:  # sorted, so are the stretches
            lo, hi = float(su[max(k - reach, 0)]), float(su[min(k + 1 + reach, len(su) - 1)])
            f = float(np.clip(0.8 * tolerance / deviation[k], 0.25, 0.7))
            if merged and lo <= merged[-1][1]:
                merged[-1][1], merged[-1][2] = max(hi, merged[-1][1]), min(f, merged[-1][2])
            else:
                merged.append([lo, hi, f])
        return JerkBound(self.base, self.scaled + tuple(tuple(s) for s in merged))


def jerk_limit(tolerance: float, dt: float) -> float:
    """The planner's bound on the pen's jerk across the path (mm/s^3) for a path
    tolerance (mm) between samples every ``dt`` (s)."""
    return JERK_PER_TOL * tolerance / dt ** 3
