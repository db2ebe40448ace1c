"""Photo styles: CPU time of stipple, tsp and flow, the tsp tour against LKH-3, and job times.

    .venv/bin/python benchmarks/bench_styles.py                 # everything
    .venv/bin/python benchmarks/bench_styles.py --no-jobs       # timings and the tour only

* stipple and tsp with 20 000 points on a 1000 x 1000 portrait (camera.png
  upscaled, drawn 200 mm wide on doodlebot): CPU seconds of the tracer; for
  tsp also the planning of its single stroke (order, fit, plan, sample).
* the tsp tour against LKH-3 on ``--lkh-points`` of the same kind of points:
  with ``--lkh PATH`` through benchmarks/lkh/build.sh's ``lkh_solve`` (LKH-3.0.8
  as elkai's source distribution ships it, with LKH's own settings for big
  instances above 5 000 points), else through ``elkai`` if importable (its API
  sets only RUNS: LKH's default of one trial per point takes hours at 20 000).
  Neither is a doodlecam dependency. LKH's closed tour less its longest edge
  is compared with doodlecam's open one.
* job times of each style on camera.png drawn ``--width`` mm wide, on the
  doodlebot and the AxiDraw V3 profiles (the whole convert: trace, order,
  fit, plan, sample).

CPU time is the process's (both cores count), so a busy machine changes it less than the wall clock.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CAMERA = ROOT / "samples" / "images" / "camera.png"


def _portrait(folder: Path) -> Path:
    from PIL import Image

    path = folder / "portrait1000.png"
    Image.open(CAMERA).convert("L").resize((1000, 1000), Image.BICUBIC).save(path)
    return path


def _tracer(name: str, mm_per_px: float, pen: float):
    from doodlecam import registry

    t = registry.get("tracer", name)()
    t.mm_per_px, t.pen_mm = mm_per_px, pen
    return t


def _cpu(fn, *args):
    c0 = time.process_time()
    out = fn(*args)
    return out, time.process_time() - c0


def bench_points(portrait: Path, points: int) -> None:
    from doodlecam.geometry.order import order_strokes
    from doodlecam.machine import load_machine
    from doodlecam.model import Drawing
    from doodlecam.pipeline import plan_job

    order_strokes([np.zeros((1, 2)), np.ones((1, 2))], home=None)  # numba's kernels loaded before any clock
    m = load_machine("doodlebot")
    mm = 200.0 / 1000
    d, t = _cpu(_tracer("stipple", mm, m.pen.width).trace, portrait, {"points": points})
    print(f"| stipple | {points} points | trace {t:.1f} s CPU | {d.meta['made']} |")
    d, t = _cpu(_tracer("tsp", mm, m.pen.width).trace, portrait, {"points": points})
    line = (d.polylines[0] + 0.5) * mm
    job, tp = _cpu(plan_job, Drawing((line + 20.0,), units="mm"), m)
    print(f"| tsp | {points} points | trace {t:.1f} s + plan {tp:.1f} s CPU | {d.meta['made']}; tour "
          f"{d.meta['tour_mm'] / 1000:.2f} m; job {job.duration:.0f} s, {len(job.strokes)} pieces, "
          f"{job.pen_lifts} pen-down, {job.meta['control_points']} control points, acceleration <= "
          f"{job.meta['worst_acceleration_ratio']:.4f} of the limit |")
    d, t = _cpu(_tracer("flow", mm, m.pen.width).trace, portrait, {})
    print(f"| flow | defaults | trace {t:.1f} s CPU | {d.meta['made']} |")


# LKH-3's own advice for big instances (its DOC): POPMUSIC candidates and a short ascent; trials
# capped, since the default (one per point) takes hours at 20 000 points
LKH_BIG = "MAX_TRIALS = 1000\nCANDIDATE_SET_TYPE = POPMUSIC\nINITIAL_PERIOD = 100\n"


def _lkh_order(pts: np.ndarray, lkh: Path | None) -> tuple[np.ndarray, float, str]:
    """An LKH-3 tour of pts (closed, node order), its CPU seconds and the settings used: through
    ``lkh`` (benchmarks/lkh/build.sh's lkh_solve) with LKH's parameters, else elkai's API."""
    if lkh is None:
        import elkai

        c0 = time.process_time()
        # TSPLIB's EUC_2D rounds distances to integers: coordinates in 1/100 mm
        order = elkai.Coordinates2D({i: (float(x * 100), float(y * 100)) for i, (x, y) in enumerate(pts)}).solve_tsp(runs=1)
        return np.asarray(order[:-1]), time.process_time() - c0, "elkai, runs=1"
    import resource
    import subprocess

    params = "PROBLEM_FILE = :stdin:\nRUNS = 1\nTRACE_LEVEL = 0\n" + (LKH_BIG if len(pts) > 5000 else "")
    with tempfile.TemporaryDirectory() as tmp:
        par, tsp = Path(tmp) / "p.par", Path(tmp) / "p.tsp"
        par.write_text(params)
        # EUC_2D rounds distances to integers: coordinates in micrometres
        tsp.write_text(f"TYPE : TSP\nDIMENSION : {len(pts)}\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n"
                       + "".join(f"{i + 1} {x * 1000:.3f} {y * 1000:.3f}\n" for i, (x, y) in enumerate(pts)) + "EOF\n")
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
        out = subprocess.run([str(lkh), str(par), str(tsp)], capture_output=True, text=True, check=True).stdout
        cpu = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - before
    order = np.array([int(w) for w in out.split()]) - 1
    assert sorted(order) == list(range(len(pts))), "LKH's tour is not a permutation of the points"
    return order, cpu, "LKH-3 " + ", ".join(line for line in params.splitlines()[1:] if "TRACE" not in line)


def bench_lkh(portrait: Path, points: int, lkh: Path | None) -> None:
    if lkh is None:
        try:
            import elkai  # noqa: F401
        except ImportError:
            print("(no LKH-3: give --lkh (benchmarks/lkh/build.sh) or 'pip install elkai' in the benchmark environment)")
            return
    from doodlecam.plugins.stipple import tone_grid, stipple_points
    from doodlecam.plugins.tsp import tour_length, tsp_tour
    from dataclasses import replace

    t = _tracer("tsp", 200.0 / 1000, 0.5)
    grid = tone_grid(portrait, t, 0.3)
    pts = stipple_points(replace(grid, dark=grid.dark ** 2), points, 20)
    (tour, _), ours = _cpu(tsp_tour, pts)
    order, lkh_t, how = _lkh_order(pts, lkh)
    closed = pts[order]
    edges = np.hypot(*np.diff(np.vstack([closed, closed[:1]]), axis=0).T)
    best = float(edges.sum() - edges.max())  # the closed tour less its longest edge: an open one
    print(f"| tour, {points} points | doodlecam {tour_length(tour):.0f} mm in {ours:.2f} s CPU | {how}: "
          f"{best:.0f} mm in {lkh_t:.1f} s CPU | doodlecam / LKH = {tour_length(tour) / best:.4f} |")


def bench_jobs(width: float) -> None:
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert

    with tempfile.TemporaryDirectory() as tmp:
        for machine in ("doodlebot", "axidraw-v3"):
            m = load_machine(machine)
            for style in ("stipple", "tsp", "flow"):
                r, t = _cpu(convert, CAMERA, Path(tmp), Settings(machine=m, tracer=style, posts=("svg",),
                                                                 layout={"width": width}))
                s = r.summary()
                print(f"| {style} | {machine} | {s['tracer_made']} | {s['strokes']} strokes, {s['pen_lifts']} pen "
                      f"lifts | job {s['job_time_s']:.0f} s | convert {t:.1f} s CPU |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--points", type=int, default=20_000)
    ap.add_argument("--lkh-points", type=int, default=2000)
    ap.add_argument("--width", type=float, default=100.0, help="camera.png drawn this wide (mm) for the job times")
    ap.add_argument("--no-jobs", action="store_true")
    ap.add_argument("--lkh", type=Path, help="lkh_solve from benchmarks/lkh/build.sh (else elkai, if importable)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        portrait = _portrait(Path(tmp))
        bench_points(portrait, a.points)
        bench_lkh(portrait, a.lkh_points, a.lkh)
    if not a.no_jobs:
        bench_jobs(a.width)


if __name__ == "__main__":
    main()
