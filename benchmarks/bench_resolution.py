"""The same photo at 1x and 4x through the image tracers: strokes and job time.

    .venv/bin/python benchmarks/bench_resolution.py                       # edges contours hatch centerline
    .venv/bin/python benchmarks/bench_resolution.py --tracers hatch --photos coins

Each sample photo (samples/images) is converted as it is and upscaled 4x with
Pillow (bicubic), both laid out at the same drawn size on ``doodlebot``; the
whole convert (trace, order, fit, plan). Prints a Markdown table: strokes and
job time at 1x and 4x and the 4x figure's difference from the 1x one.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IMAGES = ROOT / "samples" / "images"


def run(tracers: list[str], photos: list[str]) -> None:
    from PIL import Image

    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert

    m = load_machine("doodlebot")
    print("| tracer | photo | strokes 1x / 4x | job time 1x / 4x (s) | strokes, time 4x vs 1x | CPU s 1x / 4x |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for tracer in tracers:
            for name in photos:
                src = Image.open(IMAGES / f"{name}.png")
                rows = []
                for k in (1, 4):
                    path = Path(tmp) / f"{name}{k}.png"
                    src.resize((src.width * k, src.height * k), Image.BICUBIC).save(path)
                    t0 = time.process_time()
                    s = convert(path, Path(tmp) / "o", Settings(machine=m, tracer=tracer, posts=("svg",))).summary()
                    rows.append((s["strokes"], s["job_time_s"], time.process_time() - t0))
                (n1, t1, c1), (n4, t4, c4) = rows
                print(f"| {tracer} | {name} | {n1} / {n4} | {t1:.0f} / {t4:.0f} | {100 * (n4 / n1 - 1):+.0f} %, "
                      f"{100 * (t4 / t1 - 1):+.0f} % | {c1:.1f} / {c4:.1f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracers", nargs="+", default=["edges", "contours", "hatch", "centerline"])
    ap.add_argument("--photos", nargs="+", default=["camera", "chelsea", "coins"])
    a = ap.parse_args()
    run(a.tracers, a.photos)


if __name__ == "__main__":
    main()
