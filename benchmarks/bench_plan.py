"""Planner benchmark: doodlecam's solvers against toppra on the same paths.

Set up (toppra is a peer, never a doodlecam dependency):

    python3 -m venv /tmp/benchvenv
    /tmp/benchvenv/bin/pip install -e . toppra
    /tmp/benchvenv/bin/python benchmarks/bench_plan.py

Paths: the report's kind of 8-control-point curve, a circle, a 60-control-point
signature-like curve, a spiral where the velocity limit binds, a random walk
of 300 control points, a ~1 mm stroke and a near-cusp. Limits: 2000
mm/s^2 and 150 mm/s per axis. Reference optimum: doodlecam's exact solver on
the collocation grid at N = 200 000. "overshoot" is the worst relative excess
over any limit on a grid 20x finer than the one solved on (0 = within limits).
Times are medians of repeated runs in this process, in CPU time
(time.process_time); quote the ratios.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from doodlecam.model import Spline
from doodlecam.plan.planner import Limits, check_profile, interval_ratios, make_grid, plan_stroke, profile_times

VMAX, AMAX = 150.0, 2000.0


def paths() -> dict[str, Spline]:
    from doodlecam.geometry.fit import fit_polyline

    report = Spline(3, [[20, 20], [60, 90], [110, 30], [150, 110], [90, 150], [40, 120], [100, 60], [160, 40]])
    t = np.linspace(0, 2 * np.pi, 400)
    circle, _ = fit_polyline(np.c_[100 + 40 * np.cos(t), 100 + 40 * np.sin(t)], 3, 0.01)
    # a handwriting-like stroke: loops and waves, no cusps (a cusp makes the
    # collocation reference itself erratic, see the README)
    i = np.arange(60.0)
    signature = Spline(3, np.c_[20 + 4 * i + 9 * np.cos(0.9 * i), 100 + 30 * np.sin(0.45 * i) + 9 * np.sin(0.9 * i)])
    tt = np.linspace(0, 6 * np.pi, 1500)
    r = 20 + 12 * tt
    spiral, _ = fit_polyline(np.c_[150 + r * np.cos(tt), 150 + r * np.sin(tt)], 3, 0.01)
    rng = np.random.default_rng(14)
    walk = Spline(3, 100 + np.cumsum(rng.normal(0.0, 3.0, (300, 2)), axis=0))  # 300 control points
    tiny = Spline(3, [[50.0, 50.0], [50.3, 50.2], [50.6, 50.7], [51.0, 50.8]])  # a ~1 mm stroke
    # a near-cusp: the curve almost stops and turns back (|q'| ~ 1e-3 of its mean)
    cusp = Spline(3, [[0.0, 0.0], [40.0, 0.0], [60.0, 0.02], [40.0, 0.04], [0.0, 0.1]])
    return {"report-8": report, "circle": circle, "signature-60": signature, "spiral": spiral,
            "walk-300": walk, "tiny-1mm": tiny, "near-cusp": cusp}


def timed(fn, repeat):
    fn()  # warm (numba compile, imports)
    times = []
    for _ in range(repeat):
        t0 = time.process_time()  # CPU time: ratios survive a loaded machine better than wall time
        out = fn()
        times.append(time.process_time() - t0)
    return out, statistics.median(times)


def overshoot(spline, u, b, limits):
    wa, wv, wp = interval_ratios(spline, u, b, limits, 20)
    return max(float(max(wa.max(), wv.max(), wp.max())) - 1.0, 0.0)


def toppra_solve(spline: Spline, u: np.ndarray):
    import toppra.algorithm as algo
    import toppra.constraint as constraint
    from toppra.interpolator import AbstractGeometricPath

    class SplinePath(AbstractGeometricPath):
        def __call__(self, ss, order=0):
            return spline(np.atleast_1d(ss), order) if np.ndim(ss) else spline(np.atleast_1d(ss), order)[0]

        @property
        def dof(self):
            return 2

        @property
        def path_interval(self):
            return np.array([0.0, 1.0])

    path = SplinePath()
    vc = constraint.JointVelocityConstraint(np.array([[-VMAX, VMAX]] * 2))
    ac = constraint.JointAccelerationConstraint(np.array([[-AMAX, AMAX]] * 2),
                                                discretization_scheme=constraint.DiscretizationType.Interpolation)
    inst = algo.TOPPRA([vc, ac], path, gridpoints=u, parametrizer="ParametrizeSpline")
    _, sd, _ = inst.compute_parameterization(0, 0)  # (sdd, sd, v)
    return inst.problem_data.gridpoints, sd


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--sizes", type=int, nargs="*", default=[1000, 10000])
    ap.add_argument("--picture-only", action="store_true", help="only the all-strokes-of-camera timing")
    ap.add_argument("--phases", action="store_true", help="only where a plan's CPU time goes, per path and N")
    args = ap.parse_args()
    if args.picture_only:
        picture()
        return
    if args.phases:
        phases(args.sizes, args.repeat)
        return
    warnings.simplefilter("ignore")
    limits = Limits(np.array([VMAX, VMAX]), np.array([AMAX, AMAX]), np.eye(2))
    try:
        import toppra  # noqa: F401
        have_toppra = True
        import logging
        logging.getLogger("toppra").setLevel(logging.ERROR)
    except ImportError:
        have_toppra = False
        print("(toppra not installed: see the module docstring; doodlecam columns only)\n")
    print("| path | N | reference s | reach: time gap | reach: overshoot | reach: solve ms | "
          "toppra: time gap | toppra: overshoot | toppra: solve ms | speed-up | lp:clarabel gap | qp: time cost |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, s in paths().items():
        ref = plan_stroke(s, limits, n_points=200_000, mode="collocation", adaptive=False).duration
        for n in args.sizes:
            prof, t_reach = timed(lambda: plan_stroke(s, limits, n_points=n, adaptive=False), args.repeat)
            acc, vel = check_profile(s, prof, limits)
            over = max(acc, vel) - 1
            lp = plan_stroke(s, limits, solver="lp:clarabel", n_points=n, adaptive=False).duration if n <= 10000 else float("nan")
            qp = plan_stroke(s, limits, solver="qp", n_points=n, adaptive=False, smoothing=1.0).duration if n <= 2000 else float("nan")
            row = [name, n, f"{ref:.5f}", f"{100 * (prof.duration / ref - 1):+.4f} %", f"{max(over, 0):.1e}",
                   f"{1000 * t_reach:.2f}"]
            if have_toppra:
                (u, sd), t_top = timed(lambda: toppra_solve(s, make_grid(s, n_points=n)), args.repeat)
                u, b = np.asarray(u), np.asarray(sd) ** 2
                T = profile_times(u, b)[-1]
                row += [f"{100 * (T / ref - 1):+.4f} %", f"{overshoot(s, u, b, limits):.1e}", f"{1000 * t_top:.2f}",
                        f"{t_top / t_reach:.1f}x"]
            else:
                row += ["-", "-", "-", "-"]
            row += [f"{100 * (lp / prof.duration - 1):+.4f} %", f"{100 * (qp / prof.duration - 1):+.3f} %" if qp == qp else "-"]
            print("| " + " | ".join(map(str, row)) + " |")
    picture()


def phases(sizes, repeat) -> None:
    """CPU ms of each step of plan_stroke(adaptive=False), best of ``repeat`` x 20 calls."""
    from doodlecam.plan import constraints, planner, reach

    limits = Limits(np.array([VMAX, VMAX]), np.array([AMAX, AMAX]), np.eye(2))

    def best(fn):
        fn()
        times = []
        for _ in range(repeat):
            t0 = time.process_time()
            for _ in range(20):
                fn()
            times.append((time.process_time() - t0) / 20)
        return 1000 * min(times)

    print("| path | N | plan_stroke ms | input checks | span polynomials | grid | rows | passes | certificate |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, s in paths().items():
        for n in sizes:
            sp = constraints.spans(s)
            u = make_grid(s, n_points=n, span_polys=sp)
            rows = planner.build_rows(s, u, limits, "bernstein", sp)
            b = reach.solve(rows.tot, rows.beta, rows.gamma, rows.ub)
            cells = [best(lambda: plan_stroke(s, limits, n_points=n, adaptive=False)),
                     best(lambda: planner.check_inputs(s, limits)), best(lambda: constraints.spans(s)),
                     best(lambda: make_grid(s, n_points=n, span_polys=sp)),
                     best(lambda: planner.build_rows(s, u, limits, "bernstein", sp)),
                     best(lambda: reach.solve(rows.tot, rows.beta, rows.gamma, rows.ub)),
                     best(lambda: planner._certify(s, u, b, limits, 0.0, 0.0, rows))]
            print(f"| {name} | {n} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")


def picture() -> None:
    """All strokes of every sample picture: plan + sample wall time (best of 3 in a
    warm process), and how far the PLC's ramps stray from the curves between
    sample instants (the doodlebot profile's path tolerance, 0.1 mm, holds it)."""
    from doodlecam.trace.layout import fit_to_work_area
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, plan_job, trace

    m = load_machine("doodlebot")
    print("\n| picture | strokes | plan s | sample s | plan + sample s | worst acc ratio | between samples mm | re-planned |")
    print("|---|---|---|---|---|---|---|---|")
    for img in sorted((Path(__file__).resolve().parent.parent / "samples" / "images").glob("*.png")):
        d = fit_to_work_area(trace(img, Settings(machine=m)), m)
        plan_job(d, m)  # warm
        job = min((plan_job(d, m) for _ in range(3)), key=lambda j: j.meta["timings"]["plan"] + j.meta["timings"].get("sample", 0.0))
        t = job.meta["timings"]
        print(f"| {img.name} | {len(job.strokes)} | {t['plan']:.3f} | {t.get("sample", 0.0):.3f} | {t["plan"] + t.get("sample", 0.0):.3f} | "
              f"{job.meta['worst_acceleration_ratio']:.12f} | {job.meta['max_between_samples_mm']:.3f} | "
              f"{job.meta['strokes_replanned']} |")


if __name__ == "__main__":
    main()
