"""Reading generated drawings (the vector tracer, then the layout into the work area): today's
against an older revision's, in one run, on the very same file (CPU time, process_time).

    .venv/bin/python benchmarks/bench_read.py                              # 5 000 and 20 000 paths, against b3ba41c
    .venv/bin/python benchmarks/bench_read.py --sizes 100000 --against b3ba41c

The drawings are tests/generated_art.py's "mixed" kind. Imports and numba's start are outside
the timings (a convert pays them in planning anyway). Also checks that both give the same
polylines and the same laid-out strokes to the bit. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))


def _module_at(rev: str, where: str):
    """The module at ``where`` as it was at git revision ``rev``, loaded beside today's."""
    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{where}"], capture_output=True, text=True, check=True)
    path = Path(tempfile.mkdtemp()) / Path(where).name
    path.write_text(src.stdout)
    spec = importlib.util.spec_from_file_location(f"_at_{rev}_{path.stem}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _same(a, b) -> bool:
    return (len(a.polylines) == len(b.polylines) and a.layers == b.layers
            and all(p.tobytes() == q.tobytes() for p, q in zip(a.polylines, b.polylines)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[5000, 20000])
    ap.add_argument("--against", default="b3ba41c", help="git revision of the reader to compare with")
    args = ap.parse_args()

    from generated_art import generated_svg

    from doodlecam.machine import load_machine
    from doodlecam.plugins import vector
    from doodlecam.trace import layout

    readers = {"today": (vector, layout),
               args.against: (_module_at(args.against, "plugins/vector.py"),
                              _module_at(args.against, "doodlecam/trace/layout.py"))}
    m = load_machine("doodlebot")
    print(f"| paths | points | read s CPU | layout s CPU | read s CPU at {args.against} | layout s CPU at "
          f"{args.against} | less CPU (both) | same bits |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        warm = Path(tmp) / "warm.svg"
        warm.write_text(generated_svg(20, "mixed", seed=2))
        for vec, lay in readers.values():  # imports and numba's start, outside the timings
            lay.fit_to_work_area(vec.VectorTracer().trace(warm, {}), m, {"scale": 1})
        for n in args.sizes:
            path = Path(tmp) / f"art{n}.svg"
            path.write_text(generated_svg(n, "mixed", seed=1))
            times, out = {}, {}
            for name, (vec, lay) in readers.items():
                t0 = time.process_time()
                d = vec.VectorTracer().trace(path, {})
                t1 = time.process_time()
                placed = lay.fit_to_work_area(d, m, {"scale": 1})
                times[name] = (t1 - t0, time.process_time() - t1)
                out[name] = (d, placed)
                del d, placed
            (r, f), (r0, f0) = times.values()
            (d, p), (d0, p0) = out.values()
            print(f"| {n} | {sum(map(len, d.polylines))} | {r:.2f} | {f:.2f} | {r0:.2f} | {f0:.2f} | "
                  f"{(r0 + f0) / (r + f):.2f}x | {_same(d, d0) and _same(p, p0)} |", flush=True)
            del out, d, p, d0, p0


if __name__ == "__main__":
    main()
