"""The curved strokes' plans of a generated drawing: plan_checked's two compiled calls against
plan_stroke + check_profile (the same plans and ratios, checked here), and path_deviation.

    .venv/bin/python benchmarks/bench_plan_curves.py                 # 20 000 paths (tests/generated_art.py, "mixed")
    .venv/bin/python benchmarks/bench_plan_curves.py --svg some.svg

Converts the drawing up to the plan (doodlebot, --workers 1) to get its strokes, plans them all
once (plan_strokes, for the samples path_deviation measures), then times, for every curved stroke
that needed no re-plan, its first plan with the jerk bound and the check (both ways) and the
path deviation of its samples. CPU time (process_time), the best of three passes.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))


class _Planned(Exception):
    pass


def plan_inputs(svg: Path):
    """(context, strokes, pens) that `doodlecam convert` hands to plan_strokes."""
    from doodlecam.cli import main
    from doodlecam.plan import stroke

    got, real = [], stroke.plan_strokes

    def grab(ctx, strokes, pens, workers=1, progress=None):
        got.append((ctx, strokes, pens))
        raise _Planned

    stroke.plan_strokes = grab  # the pipeline looks it up at every convert
    try:
        with tempfile.TemporaryDirectory() as out, contextlib.redirect_stdout(io.StringIO()), \
                contextlib.suppress(_Planned):
            main(["convert", str(svg), "-o", out, "--scale", "1", "--workers", "1"])
    finally:
        stroke.plan_strokes = real
    return got[0]


def best_of(passes: int, f) -> float:
    times = []
    for _ in range(passes):
        t0 = time.process_time()
        f()
        times.append(time.process_time() - t0)
    return min(times)


def main(argv=None) -> int:
    from doodlecam.errors import PlanError
    from doodlecam.plan import planner
    from doodlecam.plan.follow import path_deviation
    from doodlecam.plan.stroke import plan_strokes

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--svg", type=Path)
    ap.add_argument("--paths", type=int, default=20_000)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        svg = args.svg
        if svg is None:
            from generated_art import generated_svg

            svg = Path(tmp) / "art.svg"
            svg.write_text(generated_svg(args.paths, "mixed", seed=1))
        ctx, strokes, pens = plan_inputs(svg)
    outcomes = plan_strokes(ctx, strokes, pens)
    curves = [(s.spline, ctx.pens[p], o.samples) for s, p, o in zip(strokes, pens, outcomes)
              if o.replans == 0 and not s.spline.straight and o.stroke.profile.solver == "reach"
              and s.spline.degree == 3 and len(o.stroke.profile.u) > 4]

    def separate():
        out = []
        for spline, (lim, plan_lim), _ in curves:
            try:
                prof = planner.plan_stroke(spline, plan_lim, jerk_max=ctx.jerk, jerk_period=ctx.delta_time)
                out.append((prof, planner.check_profile(spline, prof, lim)))
            except PlanError as e:
                out.append(str(e))
        return out

    def fused():
        out = []
        for spline, (lim, plan_lim), _ in curves:
            try:
                out.append(planner.plan_checked(spline, plan_lim, lim, jerk_max=ctx.jerk, jerk_period=ctx.delta_time))
            except PlanError as e:
                out.append(str(e))
        return out

    def deviation():
        for spline, _, smp in curves:
            path_deviation(spline, smp)

    for a, b in zip(separate(), fused()):  # the same plans, ratios and errors
        assert (a == b) if isinstance(a, str) else (
            all(np.array_equal(getattr(a[0], k), getattr(b[0], k)) for k in "uabt") and a[1] == b[1])
    t_sep, t_fused, t_dev = best_of(3, separate), best_of(3, fused), best_of(3, deviation)
    n = len(curves)
    print(f"{n} curved strokes of {svg.name if args.svg else f'{args.paths} generated paths'} (same plans both ways)\n")
    print("| part | s CPU | us per stroke |")
    print("|---|---|---|")
    for name, t in (("plan_stroke + check_profile", t_sep), ("plan_checked", t_fused), ("path_deviation", t_dev)):
        print(f"| {name} | {t:.2f} | {t / n * 1e6:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
