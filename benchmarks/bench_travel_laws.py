"""The job-time cost of smooth pen-up travel: every travel law on every sample.

    .venv/bin/python benchmarks/bench_travel_laws.py             # all sample pictures
    .venv/bin/python benchmarks/bench_travel_laws.py --machine my.toml a.png

Converts each picture once (the strokes do not depend on the travel law),
then times its pen-up moves under each law of doodlecam.plan.travel: the
time-optimal trapezoid and the smooth laws with the same peak acceleration.
Prints a Markdown table: travel time per law and the whole job's time, with
the extra seconds and per cent smoothness costs. A second table gives single
moves of a few lengths.
"""

from __future__ import annotations

import argparse
import tempfile
import warnings
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--machine", default="doodlebot")
    ap.add_argument("images", nargs="*", type=Path)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert
    from doodlecam.plan.travel import TRAVEL_LAWS, axis_move_time, travel_time_by_law

    machine = replace(load_machine(args.machine), travel_law="trapezoid")
    images = args.images or sorted((ROOT / "samples" / "images").glob("*.png"))
    smooth = [law for law in TRAVEL_LAWS if law != "trapezoid"]
    print(f"machine {machine.name}: move speed {machine.move_speed[0]:g} mm/s, "
          f"acceleration {machine.x.max_acceleration:g} mm/s² (x)\n")
    print("| picture | moves | travel mm | trapezoid travel s | job s | "
          + " | ".join(f"{law} travel s | job s (+%)" for law in smooth) + " |")
    print("|" + "---|" * (5 + 2 * len(smooth)))
    with tempfile.TemporaryDirectory() as out:
        for img in images:
            job = convert(img, out, Settings(machine=machine, posts=())).job
            times = travel_time_by_law(job.travels, machine)
            base = job.duration
            cells = [img.name, str(len(job.travels)), f"{job.travel_length:.0f}", f"{times['trapezoid']:.2f}", f"{base:.2f}"]
            for law in smooth:
                extra = times[law] - times["trapezoid"]
                cells += [f"{times[law]:.2f}", f"{base + extra:.2f} (+{100 * extra / base:.1f} %)"]
            print("| " + " | ".join(cells) + " |")
    print("\n| move mm | " + " | ".join(f"{law} s" for law in TRAVEL_LAWS) + " |")
    print("|" + "---|" * (1 + len(TRAVEL_LAWS)))
    v, a = machine.move_speed[0], machine.x.max_acceleration
    for d in (1, 5, 20, 100, 300):
        base = float(axis_move_time(d, v, a))
        row = [f"{float(axis_move_time(d, v, a, law)):.4f}" + ("" if law == "trapezoid" else
               f" (+{100 * (float(axis_move_time(d, v, a, law)) / base - 1):.0f} %)") for law in TRAVEL_LAWS]
        print(f"| {d} | " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
