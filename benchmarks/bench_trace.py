"""Tracing: edge fidelity, speed and memory of every tracer, and spline size per mm.

    .venv/bin/python benchmarks/bench_trace.py            # all tables
    .venv/bin/python benchmarks/bench_trace.py --quick    # skip the 4000 x 3000 photo and the fits
    .venv/bin/python benchmarks/bench_trace.py --fits     # only the spline sizes (table 4)
    .venv/bin/python benchmarks/bench_trace.py --lifts    # only the pen lifts (table 6)
    .venv/bin/python benchmarks/bench_trace.py --fits --against REV   # ... and doodlecam/geometry/fit.py at git REV, same run

Tables (Markdown):

1. `edges` on every sample picture: the issue's fidelity targets, in image
   space: the share of Canny's edge pixels within 1 px of a stroke, and the
   share of stroke length within 1 px of an edge pixel (both >= 98 %).
2. Hatching `camera` at several settings, best of 3 (target < 0.5 s).
3. A 4000 x 3000 px photograph (chelsea scaled up, with sensor-like noise,
   saved as JPEG) traced by every tracer, each in a fresh process: the trace's
   wall time, the process's CPU time (imports included; the fairer figure on a
   busy machine) and its peak resident memory, VmHWM (targets < 5 s, < 1 GB).
5. Line art (`--lineart` for this table only): generated pictures of known
   centre lines (tests/lineart.py) traced by `centerline`, `edges` and
   `contours`: drawn length against the true centre-line length (target:
   within 3 % for centerline), the farthest drawn point from the centre line
   in line widths (target <= 0.5), strokes, and which tracer `auto` picks;
   then sharp corners: a V of 20-60 degrees and bold lettering (12 line
   widths tall) by centerline: drawn length, how far the stroke stays from
   the V's apex, the farthest drawn point.
6. Pen lifts (`--lifts` for this table only): every photo traced by
   `contours` and planned on `doodlebot`: strokes, pen lifts (Job.lifts: the
   pen stays down between the pieces of a split outline; before, every
   stroke was a lift), traced outlines (closed rings: a region's boundary or
   a hole's) and connected dark regions at the traced threshold
   (skimage.measure.label, 8-neighbours, on the blurred picture) plus the
   light holes in them (4-neighbours, not touching the frame): all of them,
   and those of at least min_area px. Then `hatch` with join=false
   (each line its own pen-down, the old default) and join=true (the
   default): job time, pen lifts, ink and the CPU time of tracing + planning.
4. Spline size: every sample traced, laid out on the `doodlebot` profile and
   fitted at its default tolerance: control points per mm of stroke against
   polyline vertices per mm.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
IMAGES = sorted((ROOT / "samples" / "images").glob("*.png"))
VECTORS = sorted((ROOT / "samples" / "vectors").glob("*.*"))


def densify(p: np.ndarray, step: float) -> np.ndarray:
    a, b = p[:-1], p[1:]
    k = np.maximum(1, np.ceil(np.hypot(*(b - a).T) / step)).astype(int)
    seg = np.repeat(np.arange(len(a)), k)
    t = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)) / np.repeat(k, k)
    return np.vstack([a[seg] + t[:, None] * (b - a)[seg], p[-1:]])


def fidelity() -> None:
    from scipy.spatial import cKDTree
    from skimage import feature

    from doodlecam.plugins.edges import EdgesTracer
    from doodlecam.trace.raster import load_gray

    tr = EdgesTracer()
    opt = tr.resolve_options({})
    print("| picture | strokes | Canny edge px | edge px within 1 px of a stroke | stroke length within 1 px of an edge px | trace s |")
    print("|---|---|---|---|---|---|")
    for img in IMAGES:
        t = time.perf_counter()
        d = tr.trace(img, {})
        dt = time.perf_counter() - t
        gray = load_gray(img)
        _, low, high = tr.edge_map(gray, opt)
        canny = feature.canny(gray, opt["sigma"], low, high, mode="nearest")  # Canny's own map, unthinned
        px = np.argwhere(canny)[:, ::-1].astype(float)
        dense = [densify(p, 0.1) for p in d.polylines]
        pts = np.vstack(dense)
        cover = (cKDTree(pts).query(px)[0] <= 1.0).mean()
        w = np.concatenate([np.r_[np.hypot(*np.diff(q, axis=0).T), 0.0] for q in dense])
        on = cKDTree(px).query(pts)[0] <= 1.0
        print(f"| {img.name} | {len(d.polylines)} | {len(px)} | {100 * cover:.2f} % | {100 * (w * on).sum() / w.sum():.2f} % | {dt:.3f} |")


def hatch_speed() -> None:
    from doodlecam.plugins.hatch import HatchTracer

    tr = HatchTracer()
    cam = ROOT / "samples" / "images" / "camera.png"
    tr.trace(cam, {})  # imports outside the timing
    settings = [{}, {"cross": False}, {"join": False}, {"spacing": 1, "levels": 8},
                {"spacing": 0.5, "levels": 8, "blur": 0}, {"spacing": 0.5, "levels": 8, "blur": 0, "join": False},
                {"equalize": True, "blur": 3}]
    print("| hatch settings (camera.png) | strokes | pen-down px | best of 3, s |")
    print("|---|---|---|---|")
    for s in settings:
        best = np.inf
        for _ in range(3):
            t = time.perf_counter()
            d = tr.trace(cam, s)
            best = min(best, time.perf_counter() - t)
        label = ", ".join(f"{k}={v}" for k, v in s.items()) or "defaults"
        print(f"| {label} | {len(d.polylines)} | {d.length:.0f} | {best:.3f} |")


_CHILD = """
import sys, time, json, resource
from doodlecam import registry
cls = registry.get("tracer", sys.argv[1])
opts = json.loads(sys.argv[3])
t = time.perf_counter()
d = cls().trace(sys.argv[2], opts)
dt = time.perf_counter() - t
ru = resource.getrusage(resource.RUSAGE_SELF)
# VmHWM: this process's peak resident memory (ru_maxrss would include the parent's at fork)
hwm = [int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM")][0] / 1024
print(json.dumps({"s": dt, "cpu": ru.ru_utime + ru.ru_stime, "strokes": len(d.polylines), "peak_mb": hwm}))
"""


def big_photo() -> None:
    import json

    from PIL import Image

    with tempfile.TemporaryDirectory() as tmp:
        photo = Path(tmp) / "photo_4000x3000.jpg"
        im = Image.open(ROOT / "samples" / "images" / "chelsea.png").convert("RGB").resize((4000, 3000), Image.BICUBIC)
        noisy = np.asarray(im).astype(np.float32) + np.random.default_rng(0).normal(0, 6, (3000, 4000, 3)).astype(np.float32)
        Image.fromarray(np.clip(noisy, 0, 255).astype(np.uint8)).save(photo, quality=90)
        del im, noisy
        print("| tracer on a 4000 x 3000 px JPEG | strokes | trace s | process CPU s | process wall s | peak memory MB |")
        print("|---|---|---|---|---|---|")
        for name, opts in (("auto", {}), ("edges", {}), ("centerline", {}), ("contours", {}),
                           ("contours", {"fill": True}), ("hatch", {}), ("hatch", {"join": False})):
            t = time.perf_counter()
            out = subprocess.run([sys.executable, "-c", _CHILD, name, str(photo), json.dumps(opts)],
                                 capture_output=True, text=True, check=True).stdout
            wall = time.perf_counter() - t
            r = json.loads(out.strip().splitlines()[-1])
            label = name + (" " + ", ".join(f"{k}={v}" for k, v in opts.items()) if opts else "")
            print(f"| {label} | {r['strokes']} | {r['s']:.2f} | {r['cpu']:.2f} | {wall:.2f} | {r['peak_mb']:.0f} |", flush=True)


def line_art() -> None:
    from PIL import Image

    sys.path.insert(0, str(ROOT / "tests"))
    import lineart

    from doodlecam.plugins.centerline import AutoTracer, CenterlineTracer
    from doodlecam.plugins.contours import ContoursTracer
    from doodlecam.plugins.edges import EdgesTracer

    print("| line art | width px | true length px | tracer | strokes | drawn / true | farthest / width | auto picks |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for shape in ("circles", "grid", "text", "scribble"):
            for width in (3, 5, 7):
                polys, size = lineart.text(size=2.5 * width) if shape == "text" else getattr(lineart, shape)()
                path = Path(tmp) / f"{shape}_{width}.png"
                Image.fromarray(lineart.render(polys, size, width)).save(path)
                true = lineart.polyline_length(polys)
                picked = AutoTracer().trace(path, {}).meta["tracer"]
                for tracer in (CenterlineTracer(), EdgesTracer(), ContoursTracer()):
                    d = tracer.trace(path, {})
                    drawn = lineart.polyline_length([np.asarray(p) for p in d.polylines])
                    pts = np.vstack([lineart._dense(np.asarray(p), 0.2) for p in d.polylines])
                    far = lineart.distance_to(polys, pts).max() / width
                    print(f"| {shape} | {width} | {true:.0f} | {tracer.name} | {len(d.polylines)} | {drawn / true:.3f} "
                          f"| {far:.2f} | {picked} |", flush=True)
        # Sharp corners: a V of a round pen (its arms' centre lines meet at the apex) and bold
        # lettering (12 line widths tall) by centerline.
        print()
        print("| sharp corner (centerline) | width px | strokes | drawn / true | apex missed by, widths | farthest / width |")
        print("|---|---|---|---|---|---|")
        for angle in (20, 30, 40, 60):
            for width in (5, 7, 9):
                a, apex = np.radians(angle), np.array([150.0, 40.0])
                polys = [np.array([apex + 120 * np.array([np.sin(a / 2), np.cos(a / 2)]), apex,
                                   apex + 120 * np.array([-np.sin(a / 2), np.cos(a / 2)])])]
                path = Path(tmp) / f"v{angle}_{width}.png"
                Image.fromarray(lineart.render(polys, (200, 300), width)).save(path)
                d = CenterlineTracer().trace(path, {})
                pts = np.vstack([lineart._dense(np.asarray(p), 0.2) for p in d.polylines])
                drawn = lineart.polyline_length([np.asarray(p) for p in d.polylines]) / lineart.polyline_length(polys)
                miss = np.hypot(*(pts - apex).T).min() / width
                print(f"| V {angle}° | {width} | {len(d.polylines)} | {drawn:.3f} | {miss:.2f} | "
                      f"{lineart.distance_to(polys, pts).max() / width:.2f} |", flush=True)
        for word in ("ZN", "VZNV", "HELTVN"):
            for width in (5, 7, 9):
                polys, size = lineart.text(word, size=2.0 * width)
                path = Path(tmp) / f"bold_{word}_{width}.png"
                Image.fromarray(lineart.render(polys, size, width)).save(path)
                d = CenterlineTracer().trace(path, {})
                pts = np.vstack([lineart._dense(np.asarray(p), 0.2) for p in d.polylines])
                drawn = lineart.polyline_length([np.asarray(p) for p in d.polylines]) / lineart.polyline_length(polys)
                print(f"| bold {word} | {width} | {len(d.polylines)} | {drawn:.3f} | | "
                      f"{lineart.distance_to(polys, pts).max() / width:.2f} |", flush=True)


def _fit_at(rev: str):
    """doodlecam.geometry.fit as it was at git revision ``rev`` (loaded beside today's, for an A/B in one run)."""
    import importlib
    import importlib.util

    for where in ("doodlecam/geometry/fit.py", "doodlecam/fit.py"):  # the fitter's home before and after the layout change
        run = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{where}"], capture_output=True, text=True)
        if run.returncode == 0:
            src = run.stdout
            break
    else:
        raise SystemExit(f"no fitter at git revision {rev}")
    path = Path(tempfile.mkdtemp()) / "fit_at_rev.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("doodlecam._fit_at_rev", path)
    mod = importlib.util.module_from_spec(spec)
    mod.__package__ = "doodlecam"
    # a fitter from before the layout change imports its basis from doodlecam.kernels
    sys.modules.setdefault("doodlecam.kernels", importlib.import_module("doodlecam.geometry.kernels"))
    spec.loader.exec_module(mod)
    return mod


def spline_size(against: str | None = None) -> None:
    from doodlecam import registry
    from doodlecam.geometry.fit import fit_pieces
    from doodlecam.trace.layout import fit_to_work_area
    from doodlecam.machine import load_machine

    fitters = [fit_pieces] + ([_fit_at(against).fit_pieces] if against else [])
    m = load_machine("doodlebot")
    for f in fitters:
        f(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]))  # imports and numba's start, outside the timings
    cols = "control points / mm | fit s |" + (f" control points / mm at {against} | fit s at {against} |" if against else "")
    print(f"| input | tracer | strokes | pen-down mm | polyline vertices / mm | {cols}  (tolerance {m.tolerance} mm, degree {m.degree})")
    print("|---|---|---|---|---|---|---|" + ("---|---|" if against else ""))
    jobs = [(img, "edges") for img in IMAGES] + [(IMAGES[0], "contours"), (IMAGES[0], "hatch")] + [(v, "vector") for v in VECTORS]
    for path, tracer in jobs:
        d = fit_to_work_area(registry.get("tracer", tracer)().trace(path, {}), m)
        cells = []
        for f in fitters:
            t = time.perf_counter()
            ctrl = sum(len(s.control) for p in d.polylines for s, _ in f(p, m.degree, m.tolerance))
            cells.append(f"{ctrl / d.length:.3f} | {time.perf_counter() - t:.3f}")
        verts = sum(len(p) for p in d.polylines)
        print(f"| {path.name} | {tracer} | {len(d.polylines)} | {d.length:.0f} | {verts / d.length:.3f} | {' | '.join(cells)} |",
              flush=True)


def pen_lifts() -> None:
    from scipy import ndimage as ndi
    from skimage import measure, morphology

    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, plan_job, trace
    from doodlecam.plugins.contours import ContoursTracer
    from doodlecam.trace.layout import fit_to_work_area
    from doodlecam.trace.raster import load_working

    m = load_machine("doodlebot")
    photos = [p for p in IMAGES if p.stem != "text"]
    print("| contours | strokes | pen lifts before | pen lifts now | outlines | dark regions + holes (all) | "
          "dark regions + holes >= min_area |")
    print("|---|---|---|---|---|---|---|")
    for img in photos:
        d = trace(img, Settings(machine=m, tracer="contours"))
        job = plan_job(fit_to_work_area(d, m), m)
        opt = d.meta["options"]
        gray, _ = load_working(img, ContoursTracer(), opt["pixel_mm"])
        dark = ndi.gaussian_filter(gray.astype(np.float32), d.meta["blur_px"], mode="nearest") < d.meta["threshold"]
        regions = measure.label(dark, connectivity=2).max()
        holes = measure.label(np.pad(~dark, 1, constant_values=True), connectivity=1).max() - 1
        big = morphology.remove_small_objects(dark, max_size=int(d.meta["min_area_px"]))
        big_holes = morphology.remove_small_objects(np.pad(~big, 1, constant_values=True), max_size=int(d.meta["min_area_px"]))
        print(f"| {img.name} | {len(job.strokes)} | {len(job.strokes)} | {job.pen_lifts} | {d.meta['outlines']} | "
              f"{regions} + {holes} | {measure.label(big, connectivity=2).max()} + "
              f"{measure.label(big_holes, connectivity=1).max() - 1} |", flush=True)
    print()
    print("| hatch | join | strokes | pen lifts | ink m | job min | shorter | trace + plan CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for img in photos:
        base = None
        for join in (False, True):
            t = time.process_time()
            d = trace(img, Settings(machine=m, tracer="hatch", tracer_options={"join": join}))
            job = plan_job(fit_to_work_area(d, m), m)
            cpu = time.process_time() - t
            base = base or job.duration
            print(f"| {img.name} | {str(join).lower()} | {len(job.strokes)} | {job.pen_lifts} | "
                  f"{job.pen_down_length / 1000:.1f} | {job.duration / 60:.2f} | {100 * (1 - job.duration / base):.1f} % | "
                  f"{cpu:.1f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip the big photo and the spline fits")
    ap.add_argument("--fits", action="store_true", help="only the spline sizes and fit times")
    ap.add_argument("--lineart", action="store_true", help="only the line-art table")
    ap.add_argument("--lifts", action="store_true", help="only the pen-lift table")
    ap.add_argument("--against", metavar="REV", help="with --fits: also time doodlecam/geometry/fit.py as at git revision REV")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if args.fits:
        spline_size(args.against)
        return
    if args.lineart:
        line_art()
        return
    if args.lifts:
        pen_lifts()
        return
    fidelity()
    print()
    hatch_speed()
    print()
    line_art()
    if not args.quick:
        print()
        big_photo()
        print()
        spline_size()


if __name__ == "__main__":
    main()
