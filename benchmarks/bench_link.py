"""Link throughput: the UDP protocol through impaired networks, GRBL streaming vs send-and-wait.

Everything runs on 127.0.0.1 with the project's own simulators (no extra
packages): the PLC simulator as a separate process in simulated time (so the
link, not the machine, is measured; every run is checked against the plan)
and the GRBL emulator with motion sped up 400x (so flow control, not motion,
is measured).

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
    """The sender in this process, the PLC simulator as its own process (as a real PLC would be)."""
    import signal
    import subprocess

    from test_udp import synth_job

    from doodlecam.link.plc import protocol as P
    from doodlecam.link.plc.packetfile import read_plc_array
    from doodlecam.link.plc.sender import UdpSender

    data = synth_job(n_strokes=n_strokes, samples=98, seed=1)
    header, arr = read_plc_array(data)
    planned, _ = P.planned_states(arr, header.delta_time)
    n = len(arr)
    bad = ["--loss", "0.2", "--dup", "0.1", "--reorder", "0.1", "--corrupt", "0.01"]
    key = "bench key, shared by both sides"
    cases = [("clean", [], None), ("5 % loss", ["--loss", "0.05"], None),
             ("20 % loss + 10 % dup + 10 % reorder + 1 % corrupt", bad, None),
             ("as above + 1-3 ms delay", bad + ["--delay", "0.001", "--jitter", "0.002"], None),
             ("20 % loss + ..., HMAC-SHA256 key", bad + ["--key", key], key)]
    with tempfile.TemporaryDirectory() as tmp:
        for name, flags, k in cases:
            times, sent, cpu = [], [], []
            for r in range(repeats):
                rec = Path(tmp) / f"trace{r}.csv"
                sim = subprocess.Popen([sys.executable, "-m", "doodlecam", "sim", "plc", "--port", "0", "--rto", "0.02",
                                        "--quiet", "--seed", str(r + 1), "--record", str(rec), *flags],
                                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                try:
                    port = int(sim.stdout.readline().split(" on ")[1].split()[0].rsplit(":", 1)[1])
                    t0, c0 = time.perf_counter(), time.process_time()
                    res = UdpSender("127.0.0.1", port, data, timeout=5.0, rto=0.03,
                                    key=k.encode() if k else None).run()
                    times.append(time.perf_counter() - t0)
                    cpu.append(time.process_time() - c0)
                    sent.append(res.stats["commands_sent"] / n)
                finally:
                    sim.send_signal(signal.SIGINT)
                    sim.communicate(timeout=30)
                rows = np.loadtxt(rec, delimiter=",", skiprows=1)
                rows = rows[rows[:, 1] >= 0]
                assert np.array_equal(rows[:, 0], np.arange(1, n + 1)), "a command was lost, repeated or reordered"
                assert np.abs(rows[:, 3:5] - planned).max() < 1e-3, "the trajectory left the plan"
            t = float(np.median(times))
            yield name, n, t, n / t, float(np.mean(sent)), float(np.median(cpu))


def grbl_rows(n_strokes: int):
    from test_grbl import synth_gcode

    from doodlecam.link.grbl.port import GrblLink
    from doodlecam.link.grbl.streamer import Streamer
    from doodlecam.link.grbl.protocol import prepare
    from doodlecam.link.grbl.emulator import GrblConfig, GrblEmulator

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
    print("UDP link, PLC simulator (own process) in simulated time, median of", reps, "runs:\n")
    print("| network | commands | wall s | commands/s | commands sent per command | sender CPU s |")
    print("|---|---|---|---|---|---|")
    for name, n, t, rate, sent, cpu in udp_rows(strokes, reps):
        print(f"| {name} | {n} | {t:.2f} | {rate:,.0f} | {sent:.2f} | {cpu:.2f} |")
    print("\nGRBL over a pseudo-terminal, emulator motion 400x real time:\n")
    print("| streaming | lines | wall s | lines/s |")
    print("|---|---|---|---|")
    for mode, n, t, rate in grbl_rows(gstrokes):
        print(f"| {mode} | {n} | {t:.2f} | {rate:,.0f} |")


if __name__ == "__main__":
    main()
