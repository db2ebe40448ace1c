"""The GRBL streamer against the GRBL emulator over real pseudo-terminals.

The emulator drops bytes that do not fit its 128-byte receive ring, as the
firmware does, and counts them: a streamer that overruns it fails here.
Everything is bounded in time (serial timeouts, subprocess timeouts).
"""

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import serial
from hypothesis import given, settings, strategies as st

from doodlecam.errors import InputError
from doodlecam.link.grbl.protocol import (ALARMS, ERRORS, MAX_OUTSTANDING, STATUS_PERIOD, GrblError, parse_status, pen_up_line, prepare, resume_prefix)
from doodlecam.link.grbl.port import GrblLink
from doodlecam.link.grbl.streamer import Streamer, send_gcode
from doodlecam.link.grbl.emulator import BANNER, GrblConfig, GrblEmulator
from doodlecam.link.session import LinkError

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONWARNINGS="ignore")


def synth_gcode(n_strokes=20, seg=40, seed=0, extra=None) -> str:
    """G-code shaped like the gcode post's: travel, pen down + dwell, G1 segments, pen up + dwell."""
    rng = np.random.default_rng(seed)
    out = ["; doodlecam G-code for machine 'testbot'", "G21 G90 G94", "G17", "M3 S0", "G4 P0.05"]
    for s in range(n_strokes):
        p = rng.uniform(20, 280, 2)
        out.append(f"G0 X{p[0]:.3f} Y{p[1]:.3f}")
        out += ["M3 S1000", "G4 P0.05"]
        for k in range(seg):
            p = np.clip(p + rng.normal(0, 2, 2), 0, 300)
            out.append(f"G1 X{p[0]:.3f} Y{p[1]:.3f}" + (f" F{rng.uniform(600, 6000):.1f}" if k % 5 == 0 else ""))
        out += ["M3 S0", "G4 P0.05"]
        if extra and s == 2:
            out += extra
    out += ["G0 X0 Y0", "M2"]
    return "\n".join(out) + "\n"


def sent_lines(text: str) -> list[str]:
    """What GRBL should receive for a file: its lines without spaces and comments, upper case."""
    return [ln.text.upper() for ln in prepare(text)]


@pytest.fixture
def emu_factory():
    emus = []

    def make(**kw):
        e = GrblEmulator(GrblConfig(**kw)).start()
        emus.append(e)
        return e

    yield make
    for e in emus:
        e.stop()


def bounded(fn, timeout=60.0):
    box = {}

    def target():
        try:
            box["value"] = fn()
        except BaseException as e:
            box["error"] = e

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout)
    if t.is_alive():
        raise AssertionError(f"did not finish within {timeout} s")
    if "error" in box:
        raise box["error"]
    return box["value"]


# ---------------------------------------------------------------- file and tables

def test_prepare_strips_comments_and_rejects_what_grbl_cannot_take():
    lines = prepare("; header\nG1 X1 Y2 (inline) F100 ; tail\n\n  \nM2\n", "t.gcode")
    assert [(ln.text, ln.lineno) for ln in lines] == [("G1X1Y2F100", 2), ("M2", 5)]
    with pytest.raises(InputError, match=r"t.gcode:2: .*real-time"):
        prepare("G0 X1\nG1 X2 ! \n", "t.gcode")
    with pytest.raises(InputError, match=r"t.gcode:1: 80 characters.*at most 79"):
        prepare("G1" + "X1" * 39 + "\n", "t.gcode")


@settings(max_examples=50, deadline=None)
@given(st.lists(st.text(alphabet="GXYF0123456789. ;()\t", max_size=60), max_size=20))
def test_prepared_lines_are_always_safe_to_count(raw_lines):
    try:
        lines = prepare("\n".join(raw_lines))
    except InputError:
        return
    for ln in lines:
        assert ln.text and len(ln.text) <= 79 and not set(ln.text) & set("?!~\x18 ;()\r\n")


def test_code_tables_cover_grbl_1_1():
    assert set(range(1, 18)) | set(range(20, 39)) <= set(ERRORS)
    assert set(range(1, 11)) <= set(ALARMS)
    assert "feed rate" in ERRORS[22] and "hard limit" in ALARMS[1]


def test_status_report_parsing():
    st_ = parse_status("<Hold:0|MPos:1.000,-2.500,0.000|Bf:15,127|FS:500,8000>")
    assert (st_.state, st_.substate, st_.mpos, st_.buffer, st_.feed) == ("Hold", 0, (1.0, -2.5, 0.0), (15, 127), 500.0)
    assert parse_status("ok") is None


def test_resume_prefix_restores_modes_position_pen_and_feed():
    lines = prepare(synth_gcode(n_strokes=2, seg=10))
    k = next(i for i, ln in enumerate(lines) if ln.text.startswith("G1X")) + 7  # inside the first stroke
    pre = [ln.text for ln in resume_prefix(lines, k)]
    last = [ln.text for ln in lines[:k] if ln.text.startswith("G1X")][-1]
    x, y = re.findall(r"X([-\d.]+)Y([-\d.]+)", last)[0]
    assert pre[0] == "G21G90G94G17" and pre[1] == f"G0X{x}Y{y}" and pre[2] == "M3S1000" and pre[3] == "G4P0.05"
    assert pre[4].startswith("F")
    assert pen_up_line(lines) == "M3S0"


# ---------------------------------------------------------------- emulator fidelity

def test_emulator_drops_bytes_of_a_sender_without_flow_control(emu_factory):
    """The oracle works: blasting lines without counting overruns the 128-byte ring."""
    emu = emu_factory(speed=1.0)
    text = synth_gcode(n_strokes=3, seg=40)
    with serial.Serial(emu.port, 115200, timeout=0.2) as s:
        s.write(text.encode())
        time.sleep(0.5)
    assert emu.overruns > 0 and emu.max_rx == 127


def test_emulator_answers_crlf_twice_and_handles_realtime_commands(emu_factory):
    emu = emu_factory(speed=1.0)
    with serial.Serial(emu.port, 115200, timeout=0.5) as s:
        time.sleep(0.1)
        s.reset_input_buffer()  # the start-up banner, if it came after the open
        s.write(b"G21\r\n")
        assert [s.readline(), s.readline()] == [b"ok\r\n", b"ok\r\n"]  # CR and LF each end a line
        s.write(b"G1 X50 F600\n")  # 5 s of motion
        assert s.readline() == b"ok\r\n"
        s.write(b"?")
        assert s.readline().startswith(b"<Run|")
        s.write(b"!")
        time.sleep(0.2)
        s.write(b"?")
        assert s.readline().startswith(b"<Hold:0|")
        s.write(b"~")
        s.write(b"?")
        assert s.readline().startswith(b"<Run|")
        s.write(b"\x18")  # reset while moving: alarm 3, then the banner
        assert s.readline() == b"ALARM:3\r\n"
        assert s.readline() == b"\r\n" and s.readline().decode().strip() == BANNER
        assert b"to unlock" in s.readline()
        s.write(b"G1 X1\n")
        assert s.readline() == b"error:9\r\n"  # G-code locked while in alarm


# ---------------------------------------------------------------- streaming

def test_large_job_completes_without_ever_overrunning(emu_factory, tmp_path):
    text = synth_gcode(n_strokes=80, seg=60, seed=1)  # ~5300 lines
    job = tmp_path / "big.gcode"
    job.write_text(text)
    emu = emu_factory(speed=400.0, report_mask=3)
    progress = []
    r = bounded(lambda: send_gcode(emu.port, job, state_file=tmp_path / "s.json",
                                   progress=lambda a, n, s: progress.append(a)), 120)
    assert emu.overruns == 0
    assert emu.received == sent_lines(text)  # every line once, in order
    assert r["max_outstanding_bytes"] == MAX_OUTSTANDING  # the buffer was used fully, never beyond
    assert emu.max_rx > 64
    assert progress[-1] == r["lines"] and progress == sorted(progress)
    assert not (tmp_path / "s.json").exists()
    assert emu.state == "Idle" and emu.pos[:2] == [0.0, 0.0]  # it waited for the motion to end


def test_status_queries_never_exceed_5_hz(emu_factory, tmp_path, monkeypatch):
    sent = []
    real = GrblLink.realtime

    def spy(self, char):
        if char == b"?":
            sent.append(time.monotonic())
        real(self, char)

    monkeypatch.setattr(GrblLink, "realtime", spy)
    job = tmp_path / "j.gcode"
    job.write_text(synth_gcode(n_strokes=4, seg=20))
    emu = emu_factory(speed=20.0)
    bounded(lambda: send_gcode(emu.port, job, state_file=None))
    assert len(sent) >= 5 and np.diff(sent).min() >= STATUS_PERIOD
    assert len(emu.status_queries) == len(sent)


def test_dollar_lines_are_sent_only_when_idle_and_alone(emu_factory, tmp_path):
    # The emulator answers error:8 to a '$' setting while anything moves: the job passes only with send-and-wait.
    text = synth_gcode(n_strokes=5, seg=20, extra=["$110=8000", "$111=8000"])
    job = tmp_path / "d.gcode"
    job.write_text(text)
    emu = emu_factory(speed=50.0)
    bounded(lambda: send_gcode(emu.port, job, state_file=None))
    assert emu.settings[110] == 8000.0 and emu.overruns == 0


def test_error_stops_the_job_and_names_the_line_and_meaning(emu_factory, tmp_path):
    text = synth_gcode(n_strokes=10, seg=30)
    job = tmp_path / "e.gcode"
    job.write_text(text)
    emu = emu_factory(speed=50.0, error_at={100: 20})  # GRBL refuses the 100th line it receives
    with pytest.raises(GrblError) as ei:
        bounded(lambda: send_gcode(emu.port, job, state_file=tmp_path / "s.json"))
    msg = str(ei.value)
    bad = prepare(text)[99]
    assert f"e.gcode:{bad.lineno}" in msg and "error:20" in msg and "unsupported or invalid G-code" in msg
    assert "\n" not in msg
    assert len(emu.received) <= 100 + MAX_OUTSTANDING // 3  # nothing beyond what was in flight
    assert emu.resets >= 2  # stopped at once: feed hold, then reset
    assert not (tmp_path / "s.json").exists()


def test_alarm_stops_the_job_and_explains_recovery(emu_factory, tmp_path):
    job = tmp_path / "a.gcode"
    job.write_text(synth_gcode(n_strokes=10, seg=30))
    emu = emu_factory(speed=50.0, alarm_at={150: 1})
    with pytest.raises(GrblError, match=r"ALARM:1 .*hard limit.*\$H.*\$X"):
        bounded(lambda: send_gcode(emu.port, job, state_file=None))
    n = len(emu.received)
    time.sleep(0.3)
    assert len(emu.received) == n and n <= 150 + MAX_OUTSTANDING // 3  # nothing more was sent


def test_soft_limit_alarm_from_the_emulator(emu_factory, tmp_path):
    job = tmp_path / "s.gcode"
    job.write_text("G21 G90\nG0 X-10 Y-10\nG0 X-900 Y-10\nG0 X0 Y0\n")  # GRBL's travel is negative
    emu = emu_factory(speed=50.0, soft_limits=True, travel=(400.0, 300.0))
    with pytest.raises(GrblError, match=r"alarm state.*\$H"):  # soft limits need homing: locked at power-up
        bounded(lambda: send_gcode(emu.port, job, state_file=None))
    from doodlecam.link.grbl.control import Controller
    from doodlecam.link.grbl.port import GrblLink

    with GrblLink(emu.port) as link:
        Controller(link).attach()
        Controller(link).home()
    with pytest.raises(GrblError, match=r"ALARM:2 .*exceeds machine travel"):
        bounded(lambda: send_gcode(emu.port, job, state_file=None))
    assert emu.received[-1] == "G0X-900Y-10"  # refused at the line that leaves the travel


def test_check_mode_lists_every_error_and_moves_nothing(emu_factory, tmp_path):
    text = synth_gcode(n_strokes=4, seg=20).replace("M3 S1000", "M7 S1000", 2)
    job = tmp_path / "c.gcode"
    job.write_text(text)
    emu = emu_factory(speed=1.0)  # real time: a real run would take minutes, check mode is instant
    r = bounded(lambda: send_gcode(emu.port, job, check=True, state_file=tmp_path / "s.json"), 30)
    lines = prepare(text)
    expect = [ln.lineno for ln in lines if ln.text.startswith("M7")]
    assert [e[0] for e in r["errors"]] == expect and all(e[2] == 20 for e in r["errors"])
    assert emu.pos == [0.0, 0.0, 0.0] and not emu.check and emu.state == "Idle"
    assert "$C" in emu.received and emu.received.count("$C") == 2
    assert not (tmp_path / "s.json").exists()


def test_port_that_disappears_mid_job_is_a_one_line_error(emu_factory, tmp_path):
    job = tmp_path / "v.gcode"
    job.write_text(synth_gcode(n_strokes=10, seg=30))
    emu = emu_factory(speed=50.0, vanish_at=200)
    t0 = time.monotonic()
    with pytest.raises(LinkError, match="disappeared") as ei:
        bounded(lambda: send_gcode(emu.port, job, state_file=tmp_path / "s.json"))
    assert "\n" not in str(ei.value) and time.monotonic() - t0 < 20
    saved = json.loads((tmp_path / "s.json").read_text())  # the resume record survives
    assert saved["next"] >= 199


def test_missing_port_is_a_one_line_error_quickly(tmp_path):
    job = tmp_path / "m.gcode"
    job.write_text("G0 X1\n")
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--serial", "/dev/ttyDOODLE_NONE"],
                       capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=30)
    assert r.returncode != 0 and time.monotonic() - t0 < 15
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "/dev/ttyDOODLE_NONE" in lines[0] and "no such device" in lines[0]


def test_silent_port_is_a_one_line_error_within_the_connect_timeout(tmp_path):
    master, slave = os.openpty()  # a serial port with nothing behind it
    try:
        import tty

        tty.setraw(slave)
        job = tmp_path / "m.gcode"
        job.write_text("G0 X1\n")
        r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--serial", os.ttyname(slave),
                            "--transport-opt", "connect_timeout=0.8"], capture_output=True, text=True, env=ENV,
                           cwd=ROOT, timeout=30)
    finally:
        os.close(master)
        os.close(slave)
    lines = r.stderr.strip().splitlines()
    assert r.returncode != 0 and len(lines) == 1 and "no answer from GRBL" in lines[0]


# ---------------------------------------------------------------- interrupted runs, through the CLI

def _wait_idle(emu, timeout=30):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if emu.state == "Idle" and not emu._rx and emu.pending is None and not emu.planner:
            return
        time.sleep(0.01)
    raise AssertionError("the emulator did not finish its queued lines")


def _assert_resumed_exactly(emu, text, n1, stdout, paused):
    """GRBL got the job's lines [0, m), (the pause's pen-up line), the resume prefix, then lines [start, end)."""
    lines = prepare(text)
    expected = sent_lines(text)
    lineno = int(re.search(r"resumed at line (\d+)", stdout).group(1))
    start = next(i for i, ln in enumerate(lines) if ln.lineno == lineno)
    first = emu.received[:n1]
    if paused:
        assert first[-1] == "M3S0"  # the pause lifted the pen after the queued lines ran
        first = first[:-1]
    m = len(first)
    assert first == expected[:m]
    prefix = [ln.text.upper() for ln in resume_prefix(lines, start)]
    assert emu.received[n1:] == prefix + expected[start:]
    # Nothing skipped, nothing repeated -- except a line that does not move, whose fate a kill can hide.
    assert start == m or (start == m - 1 and not paused and not re.search(r"[XY]", expected[start]))


def test_ctrl_c_finishes_queued_lines_lifts_the_pen_and_resumes(emu_factory, tmp_path):
    text = synth_gcode(n_strokes=12, seg=40, seed=3)
    job = tmp_path / "p.gcode"
    job.write_text(text)
    emu = emu_factory(speed=20.0)
    cmd = [sys.executable, "-m", "doodlecam", "send", str(job), "--serial", emu.port, "--no-progress"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    try:
        end = time.monotonic() + 30
        while len(emu.received) < 150 and time.monotonic() < end:
            time.sleep(0.01)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 130 and "paused before" in err and "Traceback" not in err
    assert emu.received[-1] == "M3S0" and emu.state == "Idle"  # queued lines done, then the pen lifted
    n1 = len(emu.received)
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60)
    assert r.returncode == 0, r.stderr
    _assert_resumed_exactly(emu, text, n1, r.stdout, paused=True)
    assert emu.overruns == 0


def test_killed_streamer_resumes_without_repeating_a_line(emu_factory, tmp_path):
    text = synth_gcode(n_strokes=12, seg=40, seed=5)
    job = tmp_path / "k.gcode"
    job.write_text(text)
    emu = emu_factory(speed=20.0)
    cmd = [sys.executable, "-m", "doodlecam", "send", str(job), "--serial", emu.port, "--no-progress"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, cwd=ROOT)
    try:
        end = time.monotonic() + 30
        while len(emu.received) < 200 and time.monotonic() < end:
            time.sleep(0.005)
    finally:
        p.kill()
        p.communicate(timeout=10)
    saved = json.loads((tmp_path / "k.gcode.send.json").read_text())
    assert saved["next"] >= 150 and saved["pending"]
    _wait_idle(emu)  # GRBL runs every line it had received
    n1 = len(emu.received)
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=90)
    assert r.returncode == 0, r.stderr
    _assert_resumed_exactly(emu, text, n1, r.stdout, paused=False)
    assert emu.overruns == 0


@pytest.mark.parametrize("reached", [True, False])
def test_a_line_in_doubt_is_settled_by_where_the_machine_stands(emu_factory, tmp_path, reached):
    """Killed while writing line k: it is skipped if the machine reached its end, sent if not."""
    text = synth_gcode(n_strokes=3, seg=20, seed=6)
    job = tmp_path / "d.gcode"
    job.write_text(text)
    lines = prepare(text)
    k = next(i for i, ln in enumerate(lines) if ln.text.startswith("G1X")) + 5
    emu = emu_factory(speed=50.0)
    with GrblLink(emu.port) as link:  # a first run that got lines [0, k) or [0, k] out
        link.connect()
        Streamer(link, lines[:k + 1 if reached else k]).run()
    state = tmp_path / "d.gcode.send.json"
    import zlib

    state.write_text(json.dumps({"job_crc": zlib.crc32(text.encode()), "next": k, "pending": True}))
    n1 = len(emu.received)
    r = bounded(lambda: send_gcode(emu.port, job, state_file=state))
    start = k + 1 if reached else k
    assert r["start_line"] == lines[start].lineno
    assert emu.received[n1:] == [ln.text.upper() for ln in resume_prefix(lines, start)] + sent_lines(text)[start:]


def test_cli_sim_grbl_and_send_end_to_end(tmp_path):
    job = tmp_path / "e2e.gcode"
    job.write_text(synth_gcode(n_strokes=3, seg=20))
    link = tmp_path / "ttyGRBL"
    sim = subprocess.Popen([sys.executable, "-m", "doodlecam", "sim", "grbl", "--speed", "50", "--link", str(link)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    try:
        first = sim.stdout.readline()
        assert first.startswith("GRBL emulator on /dev/") and link.is_symlink()
        r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--serial", str(link), "--no-progress"],
                           capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60)
        assert r.returncode == 0, r.stderr
        assert "lines done" in r.stdout
        r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(job), "--serial", str(link), "--check"],
                           capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=60)
        assert r.returncode == 0 and "check mode passed" in r.stdout
    finally:
        sim.send_signal(signal.SIGINT)
        _, err = sim.communicate(timeout=10)
    assert "0 bytes dropped" in err
