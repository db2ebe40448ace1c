"""CPU time of the G-code post alone (feeds = cap, the default) on a generated drawing.

    .venv/bin/python benchmarks/bench_gcode_post.py              # 5 000 paths of tests/generated_art's "mixed"
    .venv/bin/python benchmarks/bench_gcode_post.py --paths 20000

Plans the drawing once (as `doodlecam convert FILE --scale 1 --workers 1` does), then times GcodePost.write
on that job by process CPU time: the first call in the process (the compiled kernels loaded from numba's
cache, as a convert pays them) and a second one. Prints the G-code's MD5, so two versions can be checked
byte for byte. The convert's PLC and SVG writes are timed too (its post stage is the three: the first post
written also pays the job's cached properties, such as which strokes lift the pen), with their MD5s (the SVG
names its source, a temporary file: its MD5 changes from run to run).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    from generated_art import generated_svg

    from doodlecam.cli import main as cli
    from doodlecam.postprocessors import gcode, plc, svg

    captured = []
    write = gcode.GcodePost.write

    def timed(self, job, opts):  # the convert's own call, timed; then a second call on the same job
        t = time.process_time()
        data = write(self, job, opts)
        captured.append((time.process_time() - t, job, opts, data))
        return data

    gcode.GcodePost.write = timed
    others = {}
    for cls in (plc.PlcPost, svg.SvgPost):
        def timed_other(self, job, opts, _write=cls.write, _name=cls.name):
            t = time.process_time()
            data = _write(self, job, opts)
            others[_name] = (time.process_time() - t, data)
            return data
        cls.write = timed_other
    with tempfile.TemporaryDirectory() as tmp:
        svg = Path(tmp) / "drawing.svg"
        svg.write_text(generated_svg(a.paths, "mixed", seed=a.seed))
        with contextlib.redirect_stdout(io.StringIO()):
            rc = cli(["convert", str(svg), "-o", str(Path(tmp) / "out"), "--scale", "1", "--workers", "1", "--json"])
        if rc not in (0, None):
            raise SystemExit("convert failed")
    first, job, opts, data = captured[0]
    t = time.process_time()
    again = write(gcode.GcodePost(), job, opts)
    second = time.process_time() - t
    assert again == data
    print(f"| {a.paths} paths, {len(job.strokes)} strokes | first write {first:.2f} s CPU | second {second:.2f} s CPU "
          f"| {len(data) / 1e6:.1f} MB, md5 {hashlib.md5(data).hexdigest()} |")
    for name, (t, out) in others.items():
        print(f"| {name} write {t:.2f} s CPU | {len(out) / 1e6:.1f} MB, md5 {hashlib.md5(out).hexdigest()} |")
    print(f"| post stage (plc + gcode + svg, first writes) {first + sum(t for t, _ in others.values()):.2f} s CPU |")


if __name__ == "__main__":
    main()
