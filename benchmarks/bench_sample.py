"""The sample stage on a generated drawing: the dense QP path against Clarabel for every QP.

    .venv/bin/python benchmarks/bench_sample.py                 # 20 000 paths (tests/generated_art.py, "mixed")
    .venv/bin/python benchmarks/bench_sample.py --svg some.svg

Converts the drawing once (doodlebot, --workers 1) recording every sample_stroke call, then
replays the calls twice in this process: with sample.DENSE_INSTANTS = 0 (every QP through
Clarabel, as before the dense path) and as shipped. CPU time (process_time) of the replays
only; also the periods per stroke (they must never be more) and the largest velocity change.
Prints a Markdown table, then one of the QPs of the shipped replay by instants: CPU per solve
with quadprog and with Clarabel, on up to 60 of each size (where DENSE_INSTANTS comes from).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))


def record(svg: Path, out: Path) -> list:
    from doodlecam.cli import main
    from doodlecam.plan import sample

    calls, real = [], sample.sample_stroke

    def rec(*a, **kw):
        calls.append((a, kw))
        return real(*a, **kw)

    sample.sample_stroke = rec  # plan/stroke.py looks it up at every stroke
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            rc = main(["convert", str(svg), "-o", str(out), "--scale", "1", "--workers", "1"])
    finally:
        sample.sample_stroke = real
    if rc:
        sys.exit(f"the convert failed (exit {rc})")
    for a, _ in calls:  # sampled as in the convert: the curves' derivatives at hand (it drops them after)
        a[0].spline.__dict__.pop("_forgotten", None)
        a[0].spline.derivative_controls
    return calls


def replay(calls, dense: int):
    from doodlecam.plan import sample

    keep, sample.DENSE_INSTANTS = sample.DENSE_INSTANTS, dense
    try:
        sample.sample_stroke(*calls[0][0], **calls[0][1])  # compiled kernels loaded outside the timing
        t = time.process_time()
        out = [sample.sample_stroke(*a, **kw) for a, kw in calls]
        return time.process_time() - t, out
    finally:
        sample.DENSE_INSTANTS = keep


def by_instants(calls, per_size: int = 60):
    """CPU ms per solve of the shipped replay's QPs, dense (quadprog) and Clarabel, by instants."""
    import numpy as np

    from doodlecam.plan import sample

    seen, real = {}, sample._qp

    def keep(*a):
        got = real(*a)
        if a[10] is None and a[6].pen_speed is None:  # no nonlinear rows, no pen-speed cones: either method
            seen.setdefault(len(a[0]), []).append(tuple(x.copy() if isinstance(x, np.ndarray) else x for x in a))
        return got

    sample._qp = keep
    try:
        for a, kw in calls:
            sample.sample_stroke(*a, **kw)
    finally:
        sample._qp = real
    keep_dense, rows = sample.DENSE_INSTANTS, []
    try:
        for lo, hi in ((2, 5), (5, 10), (10, 15), (15, 20), (20, 25), (25, 30), (30, 35), (35, 41), (41, 60)):
            probs = [p for m in range(lo, hi) for p in seen.get(m, [])]
            if not probs:
                continue
            probs = probs[:: max(1, len(probs) // per_size)][:per_size]
            ms = []
            for dense in (10**6, 0):
                sample.DENSE_INSTANTS = dense
                t = time.process_time()
                for p in probs:
                    real(*p)
                ms.append((time.process_time() - t) / len(probs) * 1e3)
            rows.append((f"{lo}-{hi - 1}", sum(len(seen.get(m, [])) for m in range(lo, hi)), *ms))
    finally:
        sample.DENSE_INSTANTS = keep_dense
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=20000)
    ap.add_argument("--svg", type=Path, help="an SVG to convert instead of a generated drawing")
    args = ap.parse_args()

    import numpy as np
    from generated_art import generated_svg

    from doodlecam.plan import sample

    with tempfile.TemporaryDirectory() as tmp:
        svg = args.svg
        if svg is None:
            svg = Path(tmp) / "art.svg"
            svg.write_text(generated_svg(args.paths, "mixed", seed=1))
        calls = record(svg, Path(tmp) / "out")
    t_old, old = replay(calls, 0)
    t_new, new = replay(calls, sample.DENSE_INSTANTS)
    po, pn = np.array([len(s.velocity) for s in old]), np.array([len(s.velocity) for s in new])
    dv = max((float(np.abs(a.velocity - b.velocity).max())
              for a, b in zip(old, new) if len(a.velocity) == len(b.velocity)), default=0.0)
    print("| sample_stroke calls | samples, Clarabel / dense | strokes with more / fewer periods "
          f"| largest velocity change mm/s | CPU s, Clarabel | CPU s, dense up to {sample.DENSE_INSTANTS} instants "
          "| less CPU |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {len(calls)} | {po.sum()} / {pn.sum()} | {(pn > po).sum()} / {(pn < po).sum()} | {dv:.3g} "
          f"| {t_old:.2f} | {t_new:.2f} | {t_old / t_new:.2f}x |")
    print()
    print("| instants | solves (shipped replay) | CPU ms a solve, quadprog | CPU ms a solve, Clarabel |")
    print("|---|---|---|---|")
    for size, count, dense, clar in by_instants(calls):
        print(f"| {size} | {count} | {dense:.3f} | {clar:.3f} |")


if __name__ == "__main__":
    main()
