"""The sample stage on a generated drawing: the dense QP path against Clarabel for every QP.

    .venv/bin/python benchmarks/bench_sample.py                 # 20 000 paths (tests/generated_art.py, "mixed")
    .venv/bin/python benchmarks/bench_sample.py --svg some.svg

Converts the drawing once (doodlebot, --workers 1) recording every sample_stroke call, then
replays the calls twice in this process: with sample.DENSE_INSTANTS = 0 (every QP through
Clarabel, as before the dense path) and as shipped. CPU time (process_time) of the replays
only; also the periods per stroke (they must never be more) and the largest velocity change.
Prints a Markdown table.
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


if __name__ == "__main__":
    main()
