"""Per-stage wall time and job figures for every sample picture.

    .venv/bin/python benchmarks/bench_convert.py            # all samples
    .venv/bin/python benchmarks/bench_convert.py --repeat 3 # best of 3
    .venv/bin/python benchmarks/bench_convert.py --path-tolerance 0.1   # docs/sampling.md

Prints a Markdown table (the README's benchmark table comes from here).
Times are wall-clock on whatever machine runs it; compare ratios, not seconds.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--path-tolerance", type=float, default=None, metavar="MM",
                    help="keep the pen within MM of the curve between samples too (docs/sampling.md)")
    ap.add_argument("--machine", default="doodlebot")
    ap.add_argument("--tracer-opt", action="append", default=[], metavar="KEY=VALUE",
                    help="a tracer option, as on convert (repeatable)")
    ap.add_argument("images", nargs="*", type=Path)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert

    images = args.images or sorted((ROOT / "samples" / "images").glob("*.png"))
    tracer_options = dict(o.split("=", 1) for o in args.tracer_opt)
    settings = Settings(machine=load_machine(args.machine), path_tolerance=args.path_tolerance,
                        tracer_options=tracer_options)
    stages = ["trace", "order", "fit", "plan", "post"]  # "plan": planning, sampling and their checks, stroke by stroke
    print("| picture | strokes | ctrl pts | pen-down mm | travel mm | job s | optimal draw s | "
          + " | ".join(f"{s} s" for s in stages) + " | total s | worst acc ratio | between samples mm |")
    print("|" + "---|" * (11 + len(stages)))
    with tempfile.TemporaryDirectory() as out:
        for img in images:
            best = None
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                res = convert(img, out, settings)
                total = time.perf_counter() - t0
                if best is None or total < best[1]:
                    best = (res, total)
            res, total = best
            s = res.summary()
            print(f"| {img.name} | {s['strokes']} | {s['control_points']} | {s['pen_down_mm']:.0f} | {s['travel_mm']:.0f} | "
                  f"{s['job_time_s']:.1f} | {s['optimal_draw_time_s']:.1f} | "
                  + " | ".join(f"{s['timings_s'].get(k, 0):.2f}" for k in stages)
                  + f" | {total:.2f} | {s['worst_acceleration_ratio']:.9f} | {s['max_between_samples_mm']:.3f} |")


if __name__ == "__main__":
    main()
