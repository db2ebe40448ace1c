"""Link throughput: the UDP protocol through impaired networks, GRBL streaming vs send-and-wait.

Everything runs on 127.0.0.1 with the project's own simulators (no extra
packages): the PLC simulator in simulated time (so the link, not the
machine, is measured) and the GRBL emulator with motion sped up 400x (so
flow control, not motion, is measured).

    .venv/bin/python benchmarks/bench_link.py            # full table (~1 min)
    .venv/bin/python benchmarks/bench_link.py --quick    # smaller jobs

Prints two markdown tables: wall time and commands (lines) per second.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))


def udp_rows(n_strokes: int, repeats: int):
    from test_udp import assert_drawn_as_planned, synth_job

    from doodlecam.plcsim import Impairments, PlcConfig, PlcSimulator
    from doodlecam.udpsend import UdpSender

    data = synth_job(n_strokes=n_strokes, samples=98, seed=1)
    n = n_strokes * 99 + 1
    cases = [("clean", Impairments()),
             ("5 % loss", Impairments(loss=0.05, seed=1)),
             ("20 % loss + 10 % dup + 10 % reorder + 1 % corrupt", Impairments(loss=0.2, dup=0.1, reorder=0.1, corrupt=0.01, seed=1)),
             ("as above + 1-3 ms delay", Impairments(loss=0.2, dup=0.1, reorder=0.1, corrupt=0.01, delay=0.001, jitter=0.002, seed=1))]
    for name, imp in cases:
        times, sent = [], []
        for r in range(repeats):
            imp.seed = r + 1 if imp.active else None
            sim = PlcSimulator(PlcConfig(rto=0.02, impair=imp)).start()
            try:
                t0 = time.perf_counter()
                res = UdpSender(*sim.address, data, timeout=5.0, rto=0.03).run()
                times.append(time.perf_counter() - t0)
                assert_drawn_as_planned(sim, data, res.job_id)
                sent.append(res.stats["commands_sent"] / n)
            finally:
                sim.stop()
        t = float(np.median(times))
        yield name, n, t, n / t, float(np.mean(sent))


def grbl_rows(n_strokes: int):
    from test_grbl import synth_gcode

    from doodlecam.grbl import GrblLink, Streamer, prepare
    from doodlecam.grblsim import GrblConfig, GrblEmulator

    text = synth_gcode(n_strokes=n_strokes, seg=60, seed=1)
    lines = prepare(text)
    for mode in ("character counting (127 bytes)", "send-and-wait (one line at a time)"):
        emu = GrblEmulator(GrblConfig(speed=400.0)).start()
        try:
            with GrblLink(emu.port) as link:
                link.connect()
                t0 = time.perf_counter()
                if mode.startswith("character"):
                    Streamer(link, lines).run()
                else:
                    for ln in lines:
                        kind, code = link.send_wait(ln.text)
                        assert kind == "ok", code
                    link.wait_idle()
                t = time.perf_counter() - t0
            assert emu.overruns == 0 and len(emu.received) == len(lines)
            yield mode, len(lines), t, len(lines) / t
        finally:
            emu.stop()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller jobs, one repeat")
    args = ap.parse_args()
    strokes, reps, gstrokes = (30, 1, 20) if args.quick else (101, 3, 80)
    print("UDP link, PLC simulator in simulated time (median of", reps, "runs):\n")
    print("| network | commands | wall s | commands/s | commands sent per command |")
    print("|---|---|---|---|---|")
    for name, n, t, rate, sent in udp_rows(strokes, reps):
        print(f"| {name} | {n} | {t:.2f} | {rate:,.0f} | {sent:.2f} |")
    print("\nGRBL over a pseudo-terminal, emulator motion 400x real time:\n")
    print("| streaming | lines | wall s | lines/s |")
    print("|---|---|---|---|")
    for mode, n, t, rate in grbl_rows(gstrokes):
        print(f"| {mode} | {n} | {t:.2f} | {rate:,.0f} |")


if __name__ == "__main__":
    main()
