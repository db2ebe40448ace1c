"""Memory over a long batch: 1 000 pictures, ``--jobs 2``, worker memory sampled as it runs.

    .venv/bin/python benchmarks/bench_batch_memory.py                     # 1000 pictures, default recycling
    .venv/bin/python benchmarks/bench_batch_memory.py --recycle-after 0   # no recycling: does a worker grow?
    .venv/bin/python benchmarks/bench_batch_memory.py --count 200         # a quick look

The pictures are 96-128 px resizes and crops of ``samples/images`` (names and sizes
are deterministic), drawn 50 mm wide, so that 1 000 of them take minutes on two
cores, not an hour: what matters for memory growth is how many files a worker goes
through, not how big they are.

Runs the real CLI (``python -m doodlecam batch``) in a subprocess and every
``--interval`` seconds reads the resident memory (RSS) of its worker processes
(psutil if installed, else /proc) and the number of files done (the manifest).
Prints the workers' RSS at 10 %, 50 % and 100 % of the files done, the slope of the
mean worker RSS against files done from 10 % on (MB per 100 files; about 0 means no
growth), each worker's figures from report.json (RSS after its first and last file,
growth per 100 files, peak), the coordinator's RSS and the wall time. A worker's first
``--warmup`` seconds (imports, JIT; RSS climbs from 10 to 200 MB) are left out of the
samples, so that a freshly recycled worker does not pass for a drop in memory.
Before measuring, a 5-picture batch fills numba's on-disk cache, as any earlier run
would have (``--cold`` skips it: then the first workers also compile, ~20 s, +80 MB).

Measured on a 2-core VM (README): RSS per worker about 210 MB at 10 %, 211 MB at 50 %,
215 MB at 100 % without recycling (``--recycle-after 0``, 500 files per worker), a slope
of +0.6 MB per 100 files; three blank crops of camera.png fail with "no edges found".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def make_pictures(dst: Path, count: int) -> None:
    """``count`` small PNGs cut from the samples: alternately the whole picture resized
    and a crop, 96-128 px, offsets and sizes a fixed function of the index."""
    from PIL import Image

    samples = [Image.open(p) for p in sorted((ROOT / "samples" / "images").glob("*.png"))]
    dst.mkdir(parents=True)
    for i in range(count):
        img = samples[i % len(samples)]
        k = i // len(samples)
        size = 96 + (k * 7) % 33
        w, h = img.size
        if k % 2 == 0:
            pic = img.resize((size, max(8, round(size * h / w))))
        else:
            x, y = (k * 37) % (w - size), (k * 53) % (h - size)
            pic = img.crop((x, y, x + size, y + size))
        pic.save(dst / f"{Path(img.filename).stem}_{i:04d}.png")


def _children(pid: int) -> dict[int, float]:
    """RSS in MB of the pool workers under ``pid`` (not the resource tracker)."""
    try:
        import psutil

        kids = [c.pid for c in psutil.Process(pid).children()]
    except ImportError:
        kids = []
        for d in Path("/proc").iterdir():
            try:
                if d.name.isdigit() and int((d / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    kids.append(int(d.name))
            except (OSError, IndexError, ValueError):
                continue
    except Exception:  # psutil.Error: the batch just ended
        return {}
    out = {}
    for kid in kids:
        try:
            if b"--multiprocessing-fork" in Path(f"/proc/{kid}/cmdline").read_bytes():
                out[kid] = _rss(kid)
        except OSError:
            continue
    return out


def _rss(pid: int) -> float:
    """RSS of one process in MB (OSError once it has ended)."""
    try:
        import psutil
    except ImportError:
        psutil = None
    if psutil is not None:
        try:
            return psutil.Process(pid).memory_info().rss / 2**20
        except psutil.Error as e:
            raise OSError(str(e)) from None
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise OSError(f"no VmRSS for {pid}")


def _done(out: Path) -> int:
    try:
        return len(json.loads((out / ".doodlecam-manifest.json").read_text())["files"])
    except (OSError, ValueError, KeyError):
        return 0


def _slope(points: list[tuple[float, float]]) -> float:
    """Least-squares slope of y against x."""
    n = len(points)
    if n < 2:
        return float("nan")
    mx = sum(x for x, _ in points) / n
    my = sum(y for _, y in points) / n
    sxx = sum((x - mx) ** 2 for x, _ in points)
    return sum((x - mx) * (y - my) for x, y in points) / sxx if sxx else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=1000, help="pictures (default 1000)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--recycle-after", type=int, default=None, help="passed to batch (default: batch's default)")
    ap.add_argument("--width", type=float, default=50.0, help="drawing width, mm")
    ap.add_argument("--interval", type=float, default=0.5, help="seconds between samples")
    ap.add_argument("--cold", action="store_true",
                    help="skip the 5-picture batch that first fills numba's disk cache (as any earlier run would)")
    ap.add_argument("--warmup", type=float, default=5.0,
                    help="seconds after a worker appears before its RSS counts (imports, JIT)")
    ap.add_argument("--samples", type=Path, help="also write every sample here (JSON: seconds, files done, "
                                                 "worker pid -> RSS MB, coordinator RSS MB)")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        src, out = Path(tmp) / "in", Path(tmp) / "out"
        make_pictures(src, args.count)
        if not args.cold:  # numba compiles on first use (~20 s, +80 MB per worker) unless its disk cache is warm
            subprocess.run([sys.executable, "-m", "doodlecam", "batch", str(src), str(Path(tmp) / "warm"), "--jobs", "1",
                            "--width", str(args.width), "--no-progress", "--include", "*_000[0-4].png"],
                           check=True, stdout=subprocess.DEVNULL)
        cmd = [sys.executable, "-m", "doodlecam", "batch", str(src), str(out), "--jobs", str(args.jobs),
               "--width", str(args.width), "--no-progress"]
        if args.recycle_after is not None:
            cmd += ["--recycle-after", str(args.recycle_after)]
        print(f"{args.count} pictures 96-128 px: doodlecam batch IN OUT {' '.join(cmd[6:])}\n")
        samples = []  # (seconds, files done, {worker pid: RSS MB}, coordinator RSS MB)
        with open(Path(tmp) / "stderr", "w+") as err:
            t0 = time.perf_counter()
            proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
            while proc.poll() is None:
                try:
                    samples.append((time.perf_counter() - t0, _done(out), _children(proc.pid), _rss(proc.pid)))
                except OSError:  # the coordinator just ended
                    pass
                time.sleep(args.interval)
            wall = time.perf_counter() - t0
            if proc.returncode not in (0, 1):  # 1: some files failed; they are listed below
                err.seek(0)
                sys.exit(f"batch failed ({proc.returncode}): {err.read()[-2000:]}")
        report = json.loads((out / "report.json").read_text())
    if args.samples:
        args.samples.write_text(json.dumps(samples))

    n = args.count
    born: dict[str, float] = {}
    steady = []  # (files done, [RSS of each worker past its start-up], coordinator RSS)
    for t, done, workers, coord in samples:
        for pid in workers:
            born.setdefault(pid, t)
        rss = [v for pid, v in workers.items() if t - born[pid] >= args.warmup]
        if rss:
            steady.append((done, rss, coord))
    print("| files done | worker RSS mean MB | worker RSS max MB | workers | coordinator RSS MB |")
    print("|---|---|---|---|---|")
    for frac in (0.10, 0.50, 1.00):
        done, rss, coord = next((s for s in steady if s[0] >= frac * n), steady[-1])  # 100 %: the last sample
        print(f"| {done} ({100 * done / n:.0f} %) | {sum(rss) / len(rss):.1f} | {max(rss):.1f} | {len(rss)} | {coord:.1f} |")
    points = [(done, sum(rss) / len(rss)) for done, rss, _ in steady if done >= 0.10 * n]
    print(f"\nslope of the mean worker RSS against files done, from 10 % on: {100 * _slope(points):+.2f} MB per 100 files "
          f"({len(points)} samples)")
    print(f"wall {wall:.1f} s, {n / wall:.2f} files/s, counts {report['counts']}")
    for f in report["files"]:
        if f["status"] == "failed":
            print(f"  failed: {f['input']}: {f['error']}")
    print(f"peak worker RSS {report['peak_worker_rss_mb']} MB; {len(report['workers'])} worker processes "
          "(report.json):\n")
    print("| worker pid | files | RSS after first file MB | RSS after last file MB | growth MB per 100 files | peak RSS MB |")
    print("|---|---|---|---|---|---|")
    for w in report["workers"]:
        growth = 100 * (w["rss_mb_last"] - w["rss_mb_first"]) / (w["files"] - 1) if w["files"] > 1 else float("nan")
        print(f"| {w['pid']} | {w['files']} | {w['rss_mb_first']} | {w['rss_mb_last']} | {growth:+.2f} | {w['peak_rss_mb']} |")


if __name__ == "__main__":
    main()
