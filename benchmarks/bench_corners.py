"""Traced corners on the sample photos: the job with them kept (``corner=30``, the default) and without (``corner=0``).

    .venv/bin/python benchmarks/bench_corners.py                       # camera coins x edges contours centerline
    .venv/bin/python benchmarks/bench_corners.py --photos chelsea --tracers edges

The whole convert on ``doodlebot`` (default layout). Prints a Markdown table: strokes (the
fitted pieces), pen lifts, corners kept, pen-down length, job time and CPU seconds of the
convert (with the G-code post, whose header gives GRBL's time: its own planner on the
G-code, docs), without and with the corners, and the changes.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IMAGES = ROOT / "samples" / "images"


def run(tracers: list[str], photos: list[str]) -> None:
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert

    m = load_machine("doodlebot")
    convert(IMAGES / "camera.png", Path(tempfile.mkdtemp()), Settings(machine=m, posts=("svg",)))  # warm-up
    print("| tracer | photo | strokes (pieces) | pen lifts | corners kept | pen-down length | job time | GRBL's time | CPU s |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in photos:
            for tracer in tracers:
                rows = []
                for corner in ("0", "30"):
                    t0 = time.process_time()
                    res = convert(IMAGES / f"{name}.png", Path(tmp), Settings(
                        machine=m, tracer=tracer, posts=("gcode",), tracer_options={"corner": corner}))
                    s = res.summary()
                    rows.append((s["strokes"], s["pen_lifts"], s["corners_kept"], s["pen_down_mm"], s["job_time_s"],
                                 res.grbl_estimate(), time.process_time() - t0))
                (n0, l0, _, d0, t0_, g0, c0), (n1, l1, k1, d1, t1, g1, c1) = rows
                print(f"| {tracer} | {name} | {n0} → {n1} | {l0} → {l1} | {k1} | {d0:.0f} → {d1:.0f} mm "
                      f"({100 * (d1 / d0 - 1):+.1f} %) | {t0_:.1f} → {t1:.1f} s ({100 * (t1 / t0_ - 1):+.0f} %) | "
                      f"{g0:.1f} → {g1:.1f} s ({100 * (g1 / g0 - 1):+.0f} %) | {c0:.1f} → {c1:.1f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracers", nargs="+", default=["edges", "contours", "centerline"])
    ap.add_argument("--photos", nargs="+", default=["camera", "coins"])
    a = ap.parse_args()
    run(a.tracers, a.photos)


if __name__ == "__main__":
    main()
