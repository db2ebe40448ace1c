"""Generated drawings at scale: whole `doodlecam convert` against `vpype read linemerge linesort write`.

vpype is NOT a doodlecam dependency. Install it in its own environment, once:

    python3 -m venv /tmp/vpype-venv && /tmp/vpype-venv/bin/pip install vpype

then run (both tools in subprocesses on the very same files, CPU time of each
process and its children, in the same run):

    .venv/bin/python benchmarks/bench_scale.py                  # 2 000 and 20 000 paths
    .venv/bin/python benchmarks/bench_scale.py --sizes 100000   # the big one (minutes)
    .venv/bin/python benchmarks/bench_scale.py --no-vpype

The drawings are tests/generated_art.py's "mixed" kind (short lines, short cubics,
tiny polygons, long curves, 4:3:2:1; 20 000 paths is 2 MB of SVG, ~375 m of
line). doodlecam writes PLC, G-code and SVG (the default posts) at --scale 1;
vpype merges, sorts and writes an SVG. Also prints the planner's throughput
(plan + sample + certificates, one process) for short lines, short curves and
long curves. Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
DEFAULT_VPYPE = Path("/tmp/vpype-venv/bin/vpype")


def _run(cmd) -> tuple[float, float, int, str]:
    """(CPU s, wall s, peak RSS MB, stdout) of this one process and its children: os.wait4's own
    rusage (RUSAGE_CHILDREN's ru_maxrss is the largest of every child so far, vpype's included)."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t = time.perf_counter()
        p = subprocess.Popen(cmd, stdout=out, stderr=err, text=True)
        _, status, use = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t
        out.seek(0)
        err.seek(0)
        if p.returncode != 0:
            raise SystemExit(f"{cmd[0]} failed: {err.read().strip()[-400:]}")
        return use.ru_utime + use.ru_stime, wall, use.ru_maxrss // 1024, out.read()


def throughput() -> None:
    import numpy as np

    from doodlecam.geometry.fit import fit_pieces
    from doodlecam.machine import load_machine
    from doodlecam.model import Drawing
    from doodlecam.pipeline import plan_job

    m = load_machine("doodlebot")
    rng = np.random.default_rng(0)

    def line():
        a, n = rng.uniform(0, 2 * np.pi), rng.uniform(2, 30)
        return 100 + np.array([[0, 0], [n * np.cos(a), n * np.sin(a)]])

    def curve():
        t = np.linspace(0, 1, 30)[:, None]
        p = np.cumsum(rng.normal(0, 4, (4, 2)), 0)
        return 100 + ((1 - t) ** 3 * p[0] + 3 * (1 - t) ** 2 * t * p[1] + 3 * (1 - t) * t ** 2 * p[2] + t ** 3 * p[3])

    def long():
        t = np.linspace(0, 1, 400)[:, None]
        return np.clip(140 + np.c_[100 * np.cos(3 * t) + 8 * np.sin(40 * t), 70 * np.sin(2 * t)], 5, [275, 175])

    plan_job(Drawing(polylines=(curve(),), units="mm"), m)  # load the kernels
    print("\n| strokes | count | fit + plan + sample, CPU s | strokes/s |\n|---|---|---|---|")
    for name, make, n in (("short lines (2-30 mm)", line, 2000), ("short cubics", curve, 1000), ("long curves (~700 mm)", long, 20)):
        d = Drawing(polylines=tuple(make() for _ in range(n)), units="mm")
        t = time.process_time()
        job = plan_job(d, m, order={"merge": 0.0})
        cpu = time.process_time() - t
        print(f"| {name} | {len(job.strokes)} | {cpu:.2f} | {len(job.strokes) / cpu:.0f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[2000, 20000])
    ap.add_argument("--vpype", type=Path, default=DEFAULT_VPYPE)
    ap.add_argument("--no-vpype", action="store_true")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--no-throughput", action="store_true")
    args = ap.parse_args()
    from generated_art import generated_svg

    use_vpype = not args.no_vpype and args.vpype.exists()
    dc = [str(Path(sys.executable).with_name("doodlecam"))]
    tmp = Path(tempfile.mkdtemp(prefix="bench-scale-"))
    try:
        small = tmp / "warm.svg"
        small.write_text(generated_svg(20, "mixed"))
        _run(dc + ["convert", str(small), "-o", str(tmp / "warm"), "--scale", "1"])  # compiled kernels cached
        print("| paths | SVG MB | doodlecam workers | doodlecam CPU s | wall s | peak MB (largest process) | strokes | pen lifts "
              "| vpype CPU s | vpype peak MB | doodlecam / vpype (CPU) |\n|---|---|---|---|---|---|---|---|---|---|---|")
        for n in args.sizes:
            svg = tmp / f"art{n}.svg"
            svg.write_text(generated_svg(n, "mixed", seed=1))
            mb = svg.stat().st_size / 1e6
            vp = vp_rss = None
            if use_vpype:
                vp, _, vp_rss, _ = _run([str(args.vpype), "read", str(svg), "linemerge", "linesort", "write",
                                         str(tmp / f"vp{n}.svg")])
            for w in args.workers:
                cpu, wall, rss, out = _run(dc + ["convert", str(svg), "-o", str(tmp / f"out{n}-{w}"), "--scale", "1",
                                                 "--json", "--workers", str(w)])
                s = json.loads(out)
                ratio = f"{cpu / vp:.2f}" if vp else "-"
                print(f"| {n} | {mb:.1f} | {w} | {cpu:.1f} | {wall:.1f} | {rss} | {s['strokes']} | {s['pen_lifts']} | "
                      f"{f'{vp:.1f}' if vp else '-'} | {vp_rss or '-'} | {ratio} |", flush=True)
        if not args.no_throughput:
            throughput()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
