"""One stroke planned, sampled and re-planned until its certificates hold; many strokes at once.

Every stroke of a job is independent once ordered and fitted, so ``plan_strokes``
hands them to worker processes in fixed chunks when asked: each stroke's result
depends only on the stroke, never on the worker or the load, so the files are
byte-identical with any number of workers.
"""

from __future__ import annotations

import os
import signal
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from doodlecam.errors import PlanError
from doodlecam.model import Stroke

REPLANS = 10  # at most this many re-plans with a lower jerk bound of a stroke still off the curve between samples
LOCAL_REPLANS = 3  # ... the first ones lower the jerk bound where it strays, the rest also everywhere
GLOBAL_JERK_STEP = 0.7
# ... then the stroke is slowed as a whole: the swing between instants shrinks with the
# speed squared, so SLOW_STEP per re-plan ends within the tolerance (0.7^12: 1.4 % of the speed)
SLOW_REPLANS = 12
SLOW_STEP = 0.7
ABSURD = 200.0  # a first plan this many times slower than the least possible time is a degenerate one
RAMP_REPLANS = 6  # ... and of one whose ramps pass a (nonlinear) actuator's limit
RAMP_GAIN = 1.25  # the share of a limit drops by this times the excess measured on the ramps
PARALLEL_MIN = 400  # strokes: fewer are planned in this process (a worker costs ~0.3 s to start)
CHUNK = 64  # strokes per task handed to a worker


@dataclass(frozen=True)
class Context:
    """What every stroke of a job is planned with."""

    delta_time: float
    solver: str
    smoothing: float
    path_tolerance: float
    jerk: Any  # follow.JerkBound or None (no path tolerance)
    steps: tuple[float, float]
    kinematics: Any
    pens: dict  # pen key -> (limits, limits lowered for whole steps)

    @property
    def nonlinear(self) -> bool:
        return self.kinematics.linear_map is None


@dataclass(frozen=True)
class Outcome:
    stroke: Stroke  # planned
    ratios: tuple[float, float]  # worst (acceleration, velocity) / limit of the plan, on the fine check grid
    samples: Any  # StrokeSamples
    deviation: np.ndarray  # per period: the executed path's distance from the curve (mm)
    replans: int
    slowed_for_ramps: bool
    ramp: float  # worst actuator ratio along the sampled ramps (nonlinear kinematics)
    slowed: float  # speed share after slowing the stroke as a whole (1: not slowed)
    worst_deviation: float = 0.0  # deviation.max(initial=0.0), mm (found while checking it)

    @classmethod
    def of(cls, stroke, ratios, samples, deviation, replans, slowed_for_ramps, ramp, slowed,
           worst_deviation) -> "Outcome":
        """Outcome(...) with every field, without the frozen dataclass's __init__ (an
        object.__setattr__ per field, 5x the time: a job of 10^4-10^5 strokes makes one each)."""
        new = object.__new__(cls)
        new.__dict__.update(stroke=stroke, ratios=ratios, samples=samples, deviation=deviation, replans=replans,
                            slowed_for_ramps=slowed_for_ramps, ramp=ramp, slowed=slowed,
                            worst_deviation=worst_deviation)
        return new


def plan_one(ctx: Context, n: int, total: int, stroke: Stroke, pen) -> Outcome:
    """Plan and sample stroke n of total (drawn with ``pen``) within every bound: the
    limits on the plan's fine grid, the actuators along the sampled ramps
    (nonlinear kinematics) and the path tolerance between sample instants."""
    from doodlecam.plan.follow import path_deviation, ramp_ratios
    from doodlecam.plan.planner import plan_checked
    from doodlecam.plan.sample import sample_stroke, written_samples

    limits, plan_limits = ctx.pens[pen]
    share = [1.0, 1.0]  # (velocity, acceleration) shares of the actuator limits (nonlinear)
    slow = 1.0
    ramp = 0.0

    def plan(jerk_max, grid=None):
        sv, sa = share[0] * slow, share[1] * slow * slow
        lim = plan_limits
        if (sv, sa) != (1.0, 1.0):
            pen_speed = None if lim.pen_speed is None else lim.pen_speed * slow
            lim = replace(lim, vmax=lim.vmax * sv, amax=lim.amax * sa, pen_speed=pen_speed)
        try:  # the plan and its check on the fine grid within the limits themselves
            prof, ratios = plan_checked(stroke.spline, lim, limits, solver=ctx.solver, smoothing=ctx.smoothing,
                                        jerk_max=jerk_max, grid=grid, jerk_period=ctx.delta_time)
        except PlanError as e:
            raise PlanError(f"stroke {n} of {total}: {e}") from None
        return stroke.with_profile(prof), ratios

    def sample(s):
        return sample_stroke(s, ctx.delta_time, limits, ctx.steps, follow=ctx.jerk is not None,
                             crank_share=tuple(share) if ctx.nonlinear else None)

    def sample_within_ramps(s, ratios, jerk_max):
        """Samples of s; for nonlinear kinematics re-planned with lower shares until the
        actuators keep their limits along the sampled ramps."""
        nonlocal ramp
        smp = sample(s)
        for attempt in range(RAMP_REPLANS + 1 if ctx.nonlinear else 0):
            ra, rv = ramp_ratios(written_samples(smp, ctx.steps), ctx.kinematics, limits.vmax, limits.amax)
            ramp = max(ra, rv)
            if ra <= 1.0 and rv <= 1.0:
                break
            if attempt == RAMP_REPLANS:
                raise PlanError(f"stroke {n} of {total}: velocity samples every {ctx.delta_time * 1000:g} ms "
                                "cannot keep the actuators within their limits; use a shorter [sampling] delta_time")
            # the variation inside a period is bounded by the kinematics' second derivatives
            # times the motion, which only slows: share - RAMP_GAIN e + (1 + e - share) < 1
            step = lambda e: 0.0 if e <= 0 else max(RAMP_GAIN * e, 1e-3)  # noqa: E731
            share[0], share[1] = max(share[0] - step(rv - 1.0), 0.1), max(share[1] - step(ra - 1.0), 0.1)
            s, ratios = plan(jerk_max, s.profile.u)
            smp = sample(s)
        return s, ratios, smp, path_deviation(s.spline, written_samples(smp, ctx.steps))  # what the machine draws

    least = _least_time(stroke.spline, plan_limits)

    def planned_within(jerk_max, grid=None):
        """The plan within jerk_max (None: no jerk bound), or None where the jerk rows pin it down:
        they take sqrt(b) from a profile the plan stays below, and where the curve turns very tightly
        over a dense grid that can hold b near 0 (seen: 6 mm planned to take 1.5e5 s, or stopped mid-stroke)."""
        if jerk_max is None:
            return plan(None, grid)
        try:
            out = plan(jerk_max, grid)
        except PlanError:
            return None
        return None if out[0].profile.duration > ABSURD * least + 1.0 else out

    bound = ctx.jerk
    planned = planned_within(bound)
    if planned is None:
        # plan without the bound and let the slowing below keep the path tolerance (bounded:
        # 1 / SLOW_STEP^SLOW_REPLANS times the plan at most)
        bound = None
        planned = plan(None)
    s, ratios = planned
    s, ratios, smp, dev = sample_within_ramps(s, ratios, bound)
    replans = 0
    worst = float(dev.max(initial=0.0))
    for attempt in range(REPLANS + SLOW_REPLANS if ctx.jerk is not None else 0):
        if worst <= ctx.path_tolerance:
            break
        if bound is not None and attempt < REPLANS:  # lower the jerk bound where it strays
            bound = bound.tightened(smp, dev, ctx.path_tolerance)
            if attempt >= LOCAL_REPLANS:
                # the sampler solves for the whole stroke, so a long one can stray somewhere
                # new after each local change; lowering the whole bound geometrically ends it
                bound = replace(bound, base=bound.base * GLOBAL_JERK_STEP)
        else:  # the bound alone did not end it: slow the whole stroke, which does
            slow *= SLOW_STEP
        again = planned_within(bound, s.profile.u)
        if again is None:
            bound = None  # the lower bound pinned the plan down: slow the stroke instead
            again = plan(None, s.profile.u)
        s, ratios = again
        s, ratios, smp, dev = sample_within_ramps(s, ratios, bound)
        worst = float(dev.max(initial=0.0))
        replans += 1
    return Outcome.of(s, ratios, smp, dev, replans, min(share) < 1.0, ramp, slow, worst)


def _least_time(spline, limits) -> float:
    """A lower bound on any plan's time: the length at the largest speed any actuator
    allows, plus accelerating to it and stopping (the path at its easiest everywhere)."""
    if limits.M is None:
        return np.inf  # nonlinear kinematics: no such bound here (the guard is off)
    v, a = limits.easiest
    length = spline.length
    return length / v + 2 * np.sqrt(length / a)


_CTX: Context | None = None


def _start_worker(ctx: Context) -> None:
    global _CTX
    _CTX = ctx
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the coordinator's to handle, once


def _work(task):
    total, items = task
    return [plan_one(_CTX, n, total, s, pen) for n, s, pen in items]


def default_workers() -> int:
    try:
        return max(1, min(2, len(os.sched_getaffinity(0))))
    except AttributeError:  # not Linux
        return max(1, min(2, os.cpu_count() or 1))


def plan_strokes(ctx: Context, strokes: list[Stroke], pens: list, workers: int = 1, progress=None) -> list[Outcome]:
    """plan_one for every stroke, in order; with ``workers`` > 1 (and enough strokes) in
    that many processes, each taking CHUNK strokes at a time. ``progress(k)``: called
    as strokes finish."""
    from doodlecam.model import prime_splines
    from doodlecam.plan.lines import eligible_all, plan_lines

    total = len(strokes)
    # straight strokes in closed form, all at once; the rest (and any of those the closed forms
    # do not cover) one by one
    lines = eligible_all(ctx, strokes)
    done = {i: Outcome.of(*o[:4], 0, False, 0.0, 1.0, o[4])
            for i, o in zip(lines, plan_lines(ctx, [strokes[i] for i in lines], [pens[i] for i in lines]))
            if o is not None}
    if progress and done:
        progress(len(done))
    items = [(n, s, pen) for n, (s, pen) in enumerate(zip(strokes, pens), 1) if n - 1 not in done]
    prime_splines([s.spline for _, s, _ in items], lengths=True)  # _least_time's and the sampler's lengths
    rest = _plan_each(ctx, items, total, workers, progress)
    return [done[i] if i in done else next(rest) for i in range(total)]


def _plan_each(ctx: Context, items: list, total: int, workers: int, progress):
    """plan_one for every (n, stroke, pen) of items, as an iterator in their order."""
    if workers <= 1 or len(items) < PARALLEL_MIN:
        out = []
        for n, s, pen in items:
            out.append(plan_one(ctx, n, total, s, pen))
            if progress:
                progress(1)
        return iter(out)
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    tasks = [(total, items[i:i + CHUNK]) for i in range(0, len(items), CHUNK)]
    # fork: the workers inherit the loaded kernels and the context instead of unpickling them
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"),
                               initializer=_start_worker, initargs=(ctx,))
    out: list[Outcome] = []
    try:
        for part in pool.map(_work, tasks):
            out += part
            if progress:
                progress(len(part))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    return iter(out)
