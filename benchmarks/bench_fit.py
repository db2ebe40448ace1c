"""The fit stage on generated drawings of many short paths: today's batched fit against the fitter
of an older revision, in one run, on the very same polylines (CPU time, process_time).

    .venv/bin/python benchmarks/bench_fit.py                          # 5 000 paths, against 03f0fac
    .venv/bin/python benchmarks/bench_fit.py --sizes 5000 20000 --against 7c84917

The drawings are tests/generated_art.py's "mixed" kind read by the vector tracer (its corners
cut as the pipeline cuts them), at the doodlebot's degree and tolerance; today's fit takes them
pipeline.FIT_BATCH at a time (doodlecam.geometry.fit.fit_many), the old one so too if it has
fit_many, else a stroke at a time (fit_pieces). Also counts the polylines whose control points or
errors differ in any bit, and both fits' control points. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5000])
    ap.add_argument("--against", default="03f0fac", help="git revision of the fitter to compare with")
    args = ap.parse_args()

    from bench_trace import _fit_at
    from generated_art import generated_svg

    from doodlecam.geometry import fit as today
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import FIT_BATCH
    from doodlecam.plugins.vector import VectorTracer

    old = _fit_at(args.against)
    m = load_machine("doodlebot")
    print(f"| paths | pieces | control points | at {args.against} | fit s CPU | at {args.against} | less CPU "
          "| polylines changed |")
    print("|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "art.svg"
            path.write_text(generated_svg(n, "mixed", seed=1))
            d = VectorTracer().trace(path, {})
        polys, corner = list(d.polylines), float(d.meta.get("split_corners_deg", 0.0))
        def batched(fitter):
            if not hasattr(fitter, "fit_many"):  # a fitter from before fit_many: a stroke at a time
                return [fitter.fit_pieces(p, m.degree, m.tolerance, corner=corner) for p in polys]
            return [f for k in range(0, len(polys), FIT_BATCH)
                    for f in fitter.fit_many(polys[k:k + FIT_BATCH], m.degree, m.tolerance, corner=corner)]

        def timed(fitter):  # the better of two runs: the first pays numba's start and one-time costs
            times = []
            for _ in range(2):
                t = time.process_time()
                fits = batched(fitter)
                times.append(time.process_time() - t)
            return fits, min(times)

        new, t_new = timed(today)
        was, t_old = timed(old)
        changed = sum(not (len(a) == len(b) and all(s.control.tobytes() == r.control.tobytes() and e == f
                                                    for (s, e), (r, f) in zip(a, b))) for a, b in zip(new, was))
        pieces = sum(map(len, new))
        ctrl, ctrl_old = (sum(len(s.control) for f in fits for s, _ in f) for fits in (new, was))
        print(f"| {n} | {pieces} | {ctrl} | {ctrl_old} | {t_new:.2f} | {t_old:.2f} | {t_old / t_new:.2f}x | {changed} |",
              flush=True)


if __name__ == "__main__":
    main()
