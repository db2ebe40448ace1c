"""GRBL job time: doodlecam's G-code against constant-feed G-code of the same strokes (vpype-gcode).

For each sample picture (doodlebot profile: 80 steps/mm, 150 mm/s, 2000 mm/s²,
GRBL $11 = 0.010, $1 = 25 ms) three programs with the same pen commands,
dwells, stroke order and chord tolerance (0.05 mm):

* ``cap``  — doodlecam's default G-code (``feeds = cap``: chords chosen for GRBL's planner, their
  vertices on its step positions, F = pen cap);
* ``plan`` — doodlecam's ``feeds = plan`` (the PLC plan's feeds, the old default);
* ``vpype`` — the ``plan`` polylines (the spline within the chord tolerance) written by
  vpype-gcode at F9000, the machine's maximum feed.

All are timed with doodlecam's model of GRBL 1.1's planner
(``doodlecam.link.grbl.timing``). vpype and vpype-gcode live only in a separate
environment, never in doodlecam's::

    python3 -m venv /tmp/vpype-env && /tmp/vpype-env/bin/pip install vpype vpype-gcode
    .venv/bin/python benchmarks/bench_grbl_time.py --vpype /tmp/vpype-env/bin/vpype

With ``--firmware GRBL_LOCK`` (GRBL 1.1h's own code in the load-independent simulator of
``../shared/grbl-fw``: ``build.sh OUTDIR`` makes ``OUTDIR/grbl_lock``) the ``cap`` and ``vpype``
programs also run on the firmware with the doodlebot EEPROM (``--eeprom``), and the table gives
its job times (``job_s``) and their ratio: the independent reference for the model; a second table
splits the firmware's time into drawing, travel and standing still (its step trace)::

    /work/shared/grbl-fw/build.sh /tmp/fw
    .venv/bin/python benchmarks/bench_grbl_time.py --vpype /tmp/vpype-env/bin/vpype --firmware /tmp/fw/grbl_lock

The ``bound`` column is the model's time for ``cap`` if GRBL never slowed at a junction, over
``vpype``'s: no choice of chords does better with these pen commands, dwells, travels and stroke
ends, which take the same time in both programs.

Prints a markdown table; exits non-zero if ``cap`` is not at most 0.9x ``vpype`` everywhere.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ("camera", "chelsea", "coins", "horse", "text")

PROFILE = """
[gwrite.doodle]
unit = "mm"
document_start = "G21 G90 G94\\nG17\\nM3 S0\\nG4 P0.15\\n"
segment_first = "G0 X{x:.3f} Y{y:.3f}\\nM3 S1000\\nG4 P0.15\\n"
segment = "G1 X{x:.3f} Y{y:.3f} F9000\\n"
line_end = "M3 S0\\nG4 P0.15\\n"
document_end = "G0 X0 Y0\\nM2\\n"
"""


def polylines(gcode: str) -> list[np.ndarray]:
    """The pen-down polylines of a G-code text (start point included)."""
    out, pos, cur = [], None, None
    for line in gcode.splitlines():
        w = line.split()
        if not w or w[0].startswith(";"):
            continue
        if w[0] in ("G0", "G1") and len(w) >= 3:
            pos = (float(w[1][1:]), float(w[2][1:]))
            if cur is not None and w[0] == "G1":
                cur.append(pos)
        elif line == "M3 S1000":
            cur = [pos]
        elif line == "M3 S0" and cur is not None:
            out.append(np.array(cur))
            cur = None
    return out


def svg(lines: list[np.ndarray], w: float, h: float) -> str:
    """Polylines in mm, y not flipped (so vpype writes the same coordinates back)."""
    paths = "".join('<polyline fill="none" stroke="black" points="' + " ".join(f"{x:.3f},{y:.3f}" for x, y in p)
                    + '"/>\n' for p in lines)
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}mm" height="{h}mm" viewBox="0 0 {w} {h}">\n'
            f"{paths}</svg>\n")


def firmware_time(grbl_lock: Path, eeprom: Path, gcode: str, run: Path) -> tuple[float, dict[str, float]]:
    """GRBL 1.1h's own job time (s) for the program, from the simulator's summary line, and where it goes
    (from its step trace, 16 MHz ticks): ``draw`` from the first to the last step of each pen-down stretch,
    ``travel`` the same pen up, ``still`` the rest (dwells, $1 delays, synchronisations)."""
    import shutil

    run.mkdir(parents=True, exist_ok=True)
    shutil.copy(eeprom, run / "EEPROM.DAT")
    p = subprocess.run([str(grbl_lock.resolve()), "-s", "trace.txt"], input=gcode.encode(), cwd=run,
                       capture_output=True, check=True)
    last = p.stderr.decode().strip().splitlines()[-1]
    words = dict(w.split("=", 1) for w in last.split() if "=" in w)
    if int(words.get("error", 0)) or int(words.get("alarm", 0)):
        raise SystemExit(f"the firmware answered errors or alarms: {last}")
    parts = {"draw": 0.0, "travel": 0.0}
    pen, first, last_step = 0, None, None
    for line in (run / "trace.txt").read_text().splitlines():
        kind, tick, *rest = line.split()
        if kind == "P" or kind == "E":  # a pen command (spindle PWM, enable) or the end: close the stretch
            if first is not None:
                parts["draw" if pen else "travel"] += (last_step - first) / 16e6
            first = None
            pen = int(rest[1]) if kind == "P" else pen
        elif kind == "S":
            first = int(tick) if first is None else first
            last_step = int(tick)
    job = float(words["job_s"])
    parts["still"] = job - parts["draw"] - parts["travel"]
    return job, parts


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vpype", required=True, help="the vpype executable of the benchmark environment")
    ap.add_argument("--samples", nargs="*", default=SAMPLES)
    ap.add_argument("--firmware", type=Path, help="grbl_lock built from ../shared/grbl-fw (build.sh OUTDIR)")
    ap.add_argument("--eeprom", type=Path, default=ROOT.parent / "shared" / "grbl-fw" / "eeprom-doodlebot" / "EEPROM.DAT")
    args = ap.parse_args()

    from doodlecam.link.grbl.timing import GrblSettings, estimate_gcode
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, plan_job, trace
    from doodlecam.postprocessors.gcode import GcodePost
    from doodlecam.trace.layout import fit_to_work_area

    machine = load_machine("doodlebot")
    grbl = GrblSettings.from_machine(machine)
    rows, parts, worst = [], [], 0.0
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "vpype.toml"
        cfg.write_text(PROFILE)
        for name in args.samples:
            settings = Settings(machine=machine, posts=("gcode",))
            drawing = fit_to_work_area(trace(ROOT / "samples" / "images" / f"{name}.png", settings), machine,
                                       settings.layout)
            job = plan_job(drawing, machine)
            text, cpu = {}, {}
            for f in ("cap", "plan"):
                t0 = time.process_time()
                text[f] = GcodePost().write(job, GcodePost.resolve_options({"feeds": f})).decode()
                cpu[f] = time.process_time() - t0
            lines = polylines(text["plan"])
            src, out = Path(tmp) / f"{name}.svg", Path(tmp) / f"{name}.vpype.gcode"
            src.write_text(svg(lines, machine.width, machine.height))
            subprocess.run([args.vpype, "-c", str(cfg), "read", str(src), "gwrite", "-p", "doodle", str(out)],
                           check=True, capture_output=True)
            text["vpype"] = out.read_text()
            back = polylines(text["vpype"])  # vpype must have kept the strokes as given
            assert len(back) == len(lines) and all(np.allclose(a, b, atol=2e-3) for a, b in zip(back, lines))
            t = {k: estimate_gcode(v, grbl, start=tuple(machine.home)).total for k, v in text.items()}
            # the best any chords could do with these pen commands, travels and stroke ends: GRBL never
            # slowing at a junction (the rest of the job, dwells, $1 delays and travels, is the same in both)
            free = estimate_gcode(text["cap"], replace(grbl, junction_deviation=1e9), start=tuple(machine.home)).total
            n = {k: sum(1 for x in v.splitlines() if x.startswith("G1")) for k, v in text.items()}
            ratio = t["cap"] / t["vpype"]
            worst = max(worst, ratio)
            fw = ""
            if args.firmware:
                runs = {k: firmware_time(args.firmware, args.eeprom, text[k], Path(tmp) / f"fw-{name}-{k}")
                        for k in ("cap", "vpype")}
                f = {k: v[0] for k, v in runs.items()}
                parts += [f"| {name} | {k} | " + " | ".join(f"{v[1][c]:.2f}" for c in ("draw", "travel", "still")) + " |"
                          for k, v in runs.items()]
                fw = f" {f['cap']:.2f} | {f['vpype']:.2f} | {f['cap'] / f['vpype']:.3f} | {t['cap'] / f['cap']:.3f} |"
            rows.append(f"| {name} | {len(job.strokes)} | {t['plan']:.1f} ({n['plan']}) | {t['vpype']:.1f} ({n['vpype']}) "
                        f"| {t['cap']:.1f} ({n['cap']}) | {ratio:.3f} | {free / t['vpype']:.3f} "
                        f"| {cpu['cap']:.2f} / {cpu['plan']:.2f} |" + fw)
    print("GRBL 1.1 job time by doodlecam's planner model, s (G1 lines); doodlebot, $11=0.010, $1=25 ms, "
          "chord tolerance 0.05 mm\n")
    head = ("| picture | strokes | feeds=plan | vpype-gcode F9000 | feeds=cap (default) | cap / vpype "
            "| bound: no junction slow-down / vpype | post CPU s cap / plan |")
    if args.firmware:
        head += " firmware: cap s | firmware: vpype s | firmware: cap / vpype | estimate / firmware (cap) |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    print("\n".join(rows))
    if parts:
        print("\nWhere the firmware's time goes, s (its step trace)\n")
        print("| picture | program | drawing | travel | standing: dwells, $1 delays, syncs |\n|---|---|---|---|---|")
        print("\n".join(parts))
    return 0 if worst <= 0.9 else 1


if __name__ == "__main__":
    sys.exit(main())
