"""Pen-up travel and ordering time: doodlecam's order against vpype's linesort, same strokes, same run.

vpype is NOT a doodlecam dependency. Install it in its own environment, once:

    python3 -m venv /tmp/vpype-venv && /tmp/vpype-venv/bin/pip install vpype

then run (vpype is called in a subprocess of that environment, on the very
strokes doodlecam orders, timed inside that process on the same machine):

    .venv/bin/python benchmarks/bench_order.py                      # looks for /tmp/vpype-venv
    .venv/bin/python benchmarks/bench_order.py --vpype-python PATH  # another vpype interpreter
    .venv/bin/python benchmarks/bench_order.py --no-vpype           # doodlecam only
    .venv/bin/python benchmarks/bench_order.py --scale 20000 100000 # generated drawings, CPU s

Stroke sets: the `edges` strokes of every sample picture and the `hatch`
strokes of camera (pixel units, as traced), and 5 000 random strokes.
Travel is counted as vpype counts it (between consecutive strokes, no legs
to a home position) and doodlecam orders with a free start (home=None) to
match; "home" columns give doodlecam's pipeline mode from (0, 0) and back.
Prints a Markdown table; times are the best of --repeat runs. Then one
fresh process orders the camera edges twice: the first call pays numba's
one-time start in that process (shared with every later compiled stage, such
as the planner), which a trivial cached function shows on its own.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_VPYPE = Path("/tmp/vpype-venv/bin/python")


def vpype_worker(npz: str, repeat: int) -> None:
    """Runs inside the vpype environment: linesort greedy and --two-opt on the strokes."""
    import inspect

    import vpype as vp
    from vpype_cli.operations import linesort

    sort = inspect.getclosurevars(linesort.callback).nonlocals["f"]  # the layer function itself
    z = np.load(npz)
    lines = [z[k][:, 0] + 1j * z[k][:, 1] for k in sorted(z.files, key=lambda s: int(s.split("_")[1]))]
    out = {}
    for name, two_opt in (("greedy", False), ("two_opt", True)):
        best, travel = np.inf, None
        for _ in range(repeat if not two_opt else 1):  # two-opt is slow: once
            lc = vp.LineCollection(lines)
            t = time.perf_counter()
            res = sort(lc, no_flip=False, two_opt=two_opt, passes=250)
            best = min(best, time.perf_counter() - t)
            travel = float(res.pen_up_length()[0])
        out[name] = {"seconds": best, "travel": travel}
    print(json.dumps(out))


def fresh_worker(npz: str) -> None:
    """Runs in a new process: what the first ordering costs there, and why."""
    t = time.perf_counter()
    import numba

    @numba.njit(cache=True)
    def one(x):  # a trivial compiled function: its first call is numba's start alone
        return x + 1

    t_import = time.perf_counter() - t
    t = time.perf_counter()
    one(1)
    t_trivial = time.perf_counter() - t
    from doodlecam.geometry.order import order_strokes

    z = np.load(npz)
    polys = [z[k] for k in sorted(z.files, key=lambda s: int(s.split("_")[1]))]
    times = []
    for _ in range(2):
        t = time.perf_counter()
        order_strokes(polys, (0.0, 0.0))
        times.append(time.perf_counter() - t)
    print(json.dumps({"import_numba": t_import, "trivial_first": t_trivial, "first": times[0], "second": times[1]}))


def fresh_process(polys: list[np.ndarray]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        npz = os.path.join(tmp, "strokes.npz")
        np.savez(npz, **{f"s_{i}": p for i, p in enumerate(polys)})
        import sys

        res = subprocess.run([sys.executable, __file__, "--fresh-worker", npz], capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def stroke_sets() -> dict[str, list[np.ndarray]]:
    from doodlecam.plugins.edges import EdgesTracer
    from doodlecam.plugins.hatch import HatchTracer

    sets = {}
    for img in sorted((ROOT / "samples" / "images").glob("*.png")):
        sets[f"edges {img.name}"] = list(EdgesTracer().trace(img, {}).polylines)
    sets["hatch camera.png"] = list(HatchTracer().trace(ROOT / "samples" / "images" / "camera.png", {}).polylines)
    rng = np.random.default_rng(0)
    sets["random 5000"] = [np.cumsum(rng.normal(size=(rng.integers(2, 8), 2)) * 3, axis=0) + rng.uniform(0, 400, 2)
                           for _ in range(5000)]
    return sets


def scale(sizes: list[int]) -> None:
    """Order generated drawings of many paths as a conversion does; CPU time (process_time)."""
    import sys

    sys.path.insert(0, str(ROOT / "tests"))
    from generated_art import generated_svg

    from doodlecam.geometry.order import _compile_once, order_strokes
    from doodlecam.plugins.vector import VectorTracer

    _compile_once()  # numba's compile or cache load, outside the timings
    print("| paths | strokes | greedy travel mm | travel mm | moves | kicks | rounds | order s CPU |")
    print("|---|---|---|---|---|---|---|---|")
    for n in sizes:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "art.svg"
            path.write_text(generated_svg(n, "mixed", seed=1))
            polys = list(VectorTracer().trace(path, {}).polylines)
        t = time.process_time()
        o = order_strokes(polys, (0.0, 0.0), budget=None)
        dt = time.process_time() - t
        m = o.meta
        print(f"| {n} | {len(polys)} | {m['greedy_travel']:.1f} | {o.travel:.1f} | {m['moves']} | {m['kicks']} | "
              f"{m['rounds']} | {dt:.2f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vpype-python", type=Path, default=DEFAULT_VPYPE)
    ap.add_argument("--no-vpype", action="store_true")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--budget", type=float, default=1.0, help="doodlecam's improvement budget, s (the default)")
    ap.add_argument("--scale", type=int, nargs="+", metavar="N",
                    help="only order generated drawings of N paths (tests/generated_art.py, 'mixed', read by the vector "
                         "tracer) from home with no clock (budget=None), as a conversion does: CPU s, travel, moves")
    ap.add_argument("--vpype-worker", help=argparse.SUPPRESS)
    ap.add_argument("--fresh-worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.vpype_worker:
        vpype_worker(args.vpype_worker, args.repeat)
        return
    if args.fresh_worker:
        fresh_worker(args.fresh_worker)
        return
    if args.scale:
        scale(args.scale)
        return
    from doodlecam.geometry.order import order_strokes, travel_length

    use_vpype = not args.no_vpype and args.vpype_python.exists()
    if not args.no_vpype and not use_vpype:
        print(f"(no vpype at {args.vpype_python}: see the docstring to install it; doodlecam only)\n")
    order_strokes([np.zeros((2, 2))], None)  # import scipy.spatial outside the timings
    cols = ["strokes", "stored", "ours greedy", "ours", "ours s", "ours home", "ours home s"]
    if use_vpype:
        cols += ["vpype greedy", "vpype greedy s", "vpype 2-opt", "vpype 2-opt s", "travel ours/2-opt", "time ours/greedy"]
    print("| strokes | " + " | ".join(cols) + " |")
    print("|---" * (len(cols) + 1) + "|")
    sets = stroke_sets()
    for name, polys in sets.items():
        best = None
        for _ in range(args.repeat):
            t = time.perf_counter()
            o = order_strokes(polys, None, budget=args.budget)
            dt = time.perf_counter() - t
            if best is None or dt < best[1]:
                best = (o, dt)
        o, dt = best
        assert abs(travel_length(o.polylines) - o.travel) < 1e-6 * max(1.0, o.travel)
        t = time.perf_counter()
        oh = order_strokes(polys, (0.0, 0.0), budget=args.budget)
        dth = time.perf_counter() - t
        row = [len(polys), travel_length(polys), o.meta["greedy_travel"], o.travel, dt, oh.travel, dth]
        if use_vpype:
            with tempfile.TemporaryDirectory() as tmp:
                npz = os.path.join(tmp, "strokes.npz")
                np.savez(npz, **{f"s_{i}": p for i, p in enumerate(polys)})
                res = subprocess.run([str(args.vpype_python), __file__, "--vpype-worker", npz, "--repeat", str(args.repeat)],
                                     capture_output=True, text=True, check=True)
                v = json.loads(res.stdout.strip().splitlines()[-1])
            row += [v["greedy"]["travel"], v["greedy"]["seconds"], v["two_opt"]["travel"], v["two_opt"]["seconds"],
                    o.travel / v["two_opt"]["travel"], dt / v["greedy"]["seconds"]]
        cells = [f"{x:.0f}" if isinstance(x, (int, np.integer)) else (f"{x:.3f}" if x < 100 else f"{x:.0f}") for x in row]
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    f = fresh_process(sets["edges camera.png"])
    print(f"\nfresh process, camera edges from home: first ordering {f['first']:.3f} s, second {f['second']:.4f} s; "
          f"numba's one-time start (first call of a trivial cached function) {f['trivial_first']:.3f} s")


if __name__ == "__main__":
    main()
