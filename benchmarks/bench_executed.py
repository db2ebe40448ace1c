"""What the machine executes, on every sample picture: the written .plc file read
with tests/test_executed.py's own reader (docs/formats.md) and ramped as the PLC
does, against the profile's limits and the file's header.

    .venv/bin/python benchmarks/bench_executed.py                      # all three cases
    .venv/bin/python benchmarks/bench_executed.py doodlebot-cap100     # one case

Cases: ``doodlebot-cap100`` (Cartesian, [pen] max_speed = 100 mm/s),
``fivebar`` (cranks through the inverse kinematics), ``doodlebot-deg2``
([fit] degree = 2). Ratios are executed / limit (1 = at the limit);
instant_steps is the worst distance (steps, per axis) from the curve point
aimed at; between_mm the worst distance from the curve between instants.
"""

from __future__ import annotations

import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from doodlecam.machine import load_machine  # noqa: E402
from doodlecam.pipeline import Settings, convert  # noqa: E402
from test_executed import IMAGES, executed_ratios  # noqa: E402

KEYS = ("acc", "vel", "header_acc", "draw_header_acc", "pen", "crank_acc", "crank_vel", "instant_steps", "between_mm")


def machine_for(case: str):
    m = load_machine(case.split("-")[0])
    if "cap100" in case:
        m = replace(m, pen=replace(m.pen, max_speed=100.0))
    if "deg2" in case:
        m = replace(m, degree=2)
    return m


def main() -> None:
    cases = sys.argv[1:] or ["doodlebot-cap100", "fivebar", "doodlebot-deg2"]
    print("| case | picture | " + " | ".join(KEYS) + " | drawing s | convert CPU s |")
    print("|---" * (len(KEYS) + 4) + "|")
    for case in cases:
        m = machine_for(case)
        for img in sorted(IMAGES.glob("*.png")):
            with tempfile.TemporaryDirectory() as d:
                t0 = time.process_time()
                res = convert(img, d, Settings(machine=m, posts=("plc",)))
                cpu = time.process_time() - t0
                r = executed_ratios((Path(d) / f"{img.stem}.plc").read_bytes(), res.job, m.path_tolerance)
            print(f"| {case} | {img.name} | " + " | ".join(f"{r[k]:.6f}" for k in KEYS)
                  + f" | {res.job.draw_time:.1f} | {cpu:.1f} |", flush=True)


if __name__ == "__main__":
    main()
