"""The fit stage on generated drawings of many short paths: today's batched fit against the fitter
of an older revision, in one run, on the very same polylines (CPU time, process_time).

    .venv/bin/python benchmarks/bench_fit.py                          # 5 000 paths, against 03f0fac
    .venv/bin/python benchmarks/bench_fit.py --sizes 5000 20000 --against 03f0fac

The drawings are tests/generated_art.py's "mixed" kind read by the vector tracer (its corners
cut as the pipeline cuts them), at the doodlebot's degree and tolerance; today's fit takes them
pipeline.FIT_BATCH at a time (doodlecam.geometry.fit.fit_many), the old one a stroke at a time
(fit_pieces). Also checks that both give the same control points and errors to the bit.
Prints a Markdown table.
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

    import numpy as np
    from bench_trace import _fit_at
    from generated_art import generated_svg

    from doodlecam.geometry.fit import fit_many
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import FIT_BATCH
    from doodlecam.plugins.vector import VectorTracer

    old = _fit_at(args.against)
    m = load_machine("doodlebot")
    print(f"| paths | pieces | control points | fit s CPU | fit s CPU at {args.against} | less CPU | same bits |")
    print("|---|---|---|---|---|---|---|")
    for n in args.sizes:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "art.svg"
            path.write_text(generated_svg(n, "mixed", seed=1))
            d = VectorTracer().trace(path, {})
        polys, corner = list(d.polylines), float(d.meta.get("split_corners_deg", 0.0))
        bend = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])  # imports and numba's start, outside the timings
        fit_many([bend], m.degree, m.tolerance)
        old.fit_pieces(bend, m.degree, m.tolerance)
        t = time.process_time()
        new = [f for k in range(0, len(polys), FIT_BATCH)
               for f in fit_many(polys[k:k + FIT_BATCH], m.degree, m.tolerance, corner=corner)]
        t_new = time.process_time() - t
        t = time.process_time()
        was = [old.fit_pieces(p, m.degree, m.tolerance, corner=corner) for p in polys]
        t_old = time.process_time() - t
        same = all(len(a) == len(b) and all(s.control.tobytes() == r.control.tobytes() and e == f
                                            for (s, e), (r, f) in zip(a, b)) for a, b in zip(new, was))
        pieces = sum(map(len, new))
        ctrl = sum(len(s.control) for f in new for s, _ in f)
        print(f"| {n} | {pieces} | {ctrl} | {t_new:.2f} | {t_old:.2f} | {t_old / t_new:.2f}x | {same} |", flush=True)


if __name__ == "__main__":
    main()
