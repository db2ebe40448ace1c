"""Vector import fidelity: pen-down length of SVG files against their exact geometry,
doodlecam's reader and vpype's reader on the same files, in the same run.

vpype is NOT a doodlecam dependency. Install it in its own environment, once:

    python3 -m venv /tmp/vpype-venv && /tmp/vpype-venv/bin/pip install vpype

then run (vpype reads the very same files in a subprocess of that environment):

    .venv/bin/python benchmarks/bench_vector.py                      # looks for /tmp/vpype-venv
    .venv/bin/python benchmarks/bench_vector.py --vpype-python PATH  # another vpype interpreter
    .venv/bin/python benchmarks/bench_vector.py --no-vpype           # doodlecam only

The corpus is tests/svg_corpus.py: one file per feature (ellipse, <use> of <defs>, clip
path, hidden elements, arcs, Béziers) and a design-tool file with all of them. The exact
length of each comes from the geometry (ellipse perimeters from the complete elliptic
integral, Béziers sampled 200 000 times). The error is the drawn length's relative
difference from it; the target is within 0.1 % on every file.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
DEFAULT_VPYPE = Path("/tmp/vpype-venv/bin/python")

VPYPE_SCRIPT = r"""
import json, sys, time
import vpype
out = {}
for path in sys.argv[1:]:
    t = time.process_time()
    lines, _w, _h = vpype.read_svg(path, quantization=0.02 * 96 / 25.4)  # all layers in one (read_multilayer_svg drops <use>)
    cpu = time.process_time() - t
    out[path] = {"length_mm": lines.length() * 25.4 / 96, "cpu_s": cpu}
print(json.dumps(out))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vpype-python", type=Path, default=DEFAULT_VPYPE)
    ap.add_argument("--no-vpype", action="store_true")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many conversions for the layer timing")
    args = ap.parse_args()

    from svg_corpus import write_corpus

    from doodlecam.model import polyline_length
    from doodlecam.plugins.vector import VectorTracer

    folder = Path(tempfile.mkdtemp(prefix="svg-corpus-"))
    files = write_corpus(folder)
    ours = {}
    for path in files:
        t = time.process_time()
        d = VectorTracer().trace(path, {})
        ours[path] = {"length_mm": sum(polyline_length(p) for p in d.polylines), "cpu_s": time.process_time() - t}
    theirs = {}
    if not args.no_vpype:
        if not args.vpype_python.exists():
            sys.exit(f"no vpype interpreter at {args.vpype_python}; install it (see the docstring) or pass --no-vpype")
        run = subprocess.run([str(args.vpype_python), "-c", VPYPE_SCRIPT, *map(str, files)], capture_output=True,
                             text=True, check=True)
        theirs = {Path(k): v for k, v in json.loads(run.stdout).items()}

    print("| file | exact mm | doodlecam mm | doodlecam error | vpype mm | vpype error |")
    print("|---|---|---|---|---|---|")
    for path, exact in files.items():
        o = ours[path]["length_mm"]
        row = f"| {path.stem} | {exact:.2f} | {o:.2f} | {100 * (o / exact - 1):+.3f} % |"
        if path in theirs:
            v = theirs[path]["length_mm"]
            row += f" {v:.2f} | {100 * (v / exact - 1):+.3f} % |"
        else:
            row += " - | - |"
        print(row)
    worst = max(abs(ours[p]["length_mm"] / e - 1) for p, e in files.items())
    print(f"\ndoodlecam: worst error {100 * worst:.3f} % (target 0.1 %)")
    layers_vs_one(args.repeat)


def layers_vs_one(repeat: int) -> None:
    """The multi-layer sample against the same strokes read as one layer: conversion CPU time
    (best of ``repeat``) and the planned job (the pen changes add the operator's pauses only)."""
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert

    svg = ROOT / "samples" / "vectors" / "layers.svg"
    machine = load_machine("doodlebot")
    rows = {}
    for label, opts in (("3 layers", {}), ("one layer", {"layers": "none"})):
        best, job = float("inf"), None
        for _ in range(repeat):
            out = Path(tempfile.mkdtemp(prefix="layers-"))
            t = time.process_time()
            job = convert(svg, out, Settings(machine=machine, tracer_options=opts, posts=("plc", "gcode"))).job
            best = min(best, time.process_time() - t)
        rows[label] = (best, job)
    print("\n| samples/vectors/layers.svg | convert CPU s | pen changes | draw s | travel mm | job s |")
    print("|---|---|---|---|---|---|")
    for label, (cpu, job) in rows.items():
        print(f"| {label} | {cpu:.3f} | {len(job.pen_changes)} | {job.draw_time:.1f} | {job.travel_length:.0f} | "
              f"{job.duration:.1f} |")
    (c3, j3), (c1, j1) = rows["3 layers"], rows["one layer"]
    print(f"\nlayers / one layer: convert CPU {c3 / c1:.2f}x, job time {j3.duration / j1.duration:.3f}x "
          f"(+{len(j3.pen_changes)} operator pauses)")


if __name__ == "__main__":
    main()
