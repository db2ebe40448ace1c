"""Batch throughput: --jobs 1 vs --jobs N on copies of the sample pictures, and a no-change re-run.

    .venv/bin/python benchmarks/bench_batch.py                 # 20 copies (4 of each sample), jobs 1 and 2
    .venv/bin/python benchmarks/bench_batch.py --copies 20     # 100 pictures (the issue's target)
    .venv/bin/python benchmarks/bench_batch.py --jobs 1 2 4

Runs the real CLI (``python -m doodlecam batch``) in a subprocess, so worker
start-up is included. Prints a Markdown table: files, wall time, files/s, speed-up
over one job, the no-change re-run time and the peak RSS of a worker (report.json).
Times are wall-clock on whatever machine runs it; compare ratios, not seconds.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def run(args: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "doodlecam", "batch", *args, "--no-progress"], check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--copies", type=int, default=4, help="copies of each sample picture")
    ap.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--machine", default="doodlebot")
    args = ap.parse_args()
    images = sorted((ROOT / "samples" / "images").glob("*.png"))
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "in"
        src.mkdir()
        for k in range(args.copies):
            for img in images:
                shutil.copy(img, src / f"{img.stem}_{k:03d}.png")
        n = len(images) * args.copies
        print(f"{n} pictures ({', '.join(i.name for i in images)}), machine {args.machine}, posts plc+gcode+svg\n")
        print("| jobs | files | wall s | files/s | speed-up | no-change re-run s | peak worker RSS MB |")
        print("|---|---|---|---|---|---|---|")
        base = None
        for jobs in args.jobs:
            out = Path(tmp) / f"out{jobs}"
            wall = run([str(src), str(out), "--jobs", str(jobs), "-m", args.machine])
            first = json.loads((out / "report.json").read_text())
            rerun = run([str(src), str(out), "--jobs", str(jobs), "-m", args.machine])
            rep = json.loads((out / "report.json").read_text())
            assert rep["counts"]["skipped"] == n, rep["counts"]
            base = base or wall
            print(f"| {jobs} | {n} | {wall:.1f} | {n / wall:.2f} | {base / wall:.2f}x | {rerun:.2f} | "
                  f"{first.get('peak_worker_rss_mb') or '-'} |")


if __name__ == "__main__":
    main()
