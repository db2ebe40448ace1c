"""The EiBotBoard link on real pseudo-terminals: jobs streamed to the EBB emulator (every command once and in
order, flow control, pause/resume/stop at stroke ends, a lost board, pen changes), the emulator's answers to
malformed and out-of-range commands, plotink driving the emulator, and bad input refused in one line before
anything moves."""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from doodlecam.errors import InputError
from doodlecam.link.ebb.emulator import EbbConfig, EbbEmulator
from doodlecam.link.ebb.jobfile import EbbJob, read_ebb
from doodlecam.link.ebb.sender import EbbSender, line_effects, send_ebb
from doodlecam.link.session import LinkError, Paused

ROOT = Path(__file__).resolve().parent.parent
ENV = dict(os.environ, PYTHONWARNINGS="ignore")
QUERIES = ("V", "QM", "QS")


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    from doodlecam import pipeline
    from doodlecam.machine import load_machine

    out = tmp_path_factory.mktemp("ebbjobs")
    m = load_machine("axidraw-v3")
    for name in ("badge.svg", "layers.svg"):
        pipeline.convert(ROOT / "samples" / "vectors" / name, out, pipeline.Settings(machine=m, posts=("ebb",)))
    return out


def _commands(emu):
    return [s for s in emu.received if s.split(",")[0] not in QUERIES]


def _emulator(**kw):
    return EbbEmulator(EbbConfig(**{"speed": 400.0, **kw})).start()


def test_stream_every_command_once_in_order_and_ends_home(jobs, tmp_path):
    path = jobs / "badge.ebb"
    job = read_ebb(path.read_bytes())
    with _emulator() as emu:
        r = send_ebb(emu.port, path, state_file=tmp_path / "s.json")
        assert _commands(emu) == list(job.lines)
        assert emu.errors == [] and emu.idle
        # the board's step counters after every motion command are the job's (exact LM arithmetic)
        pos, _ = line_effects(job.lines)
        motion = [i for i, s in enumerate(job.lines) if not s.startswith("SC")]
        assert [e["pos"] for e in emu.executed] == [pos[i] for i in motion]
        assert tuple(emu.pos) == (0, 0) and emu.pen_up == 1
        # executed time: the header's planned time
        assert emu.executed[-1]["t"] == pytest.approx(job.planned_time, abs=0.01)
    assert r["commands"] == len(job.lines) and not r["resumed"]
    assert not (tmp_path / "s.json").exists()  # a finished job leaves no resume record


def test_flow_control_never_overruns_the_fifo(jobs):
    path = jobs / "badge.ebb"
    with _emulator(speed=20.0, fifo=3) as emu:
        send_ebb(emu.port, path, state_file=None)
        assert len(emu.fifo) == 0 and emu.errors == []


def test_stop_at_stroke_end_then_resume_from_there(jobs, tmp_path):
    path = jobs / "badge.ebb"
    job = read_ebb(path.read_bytes())
    state = tmp_path / "s.json"
    n = {"calls": 0}

    def controls():
        n["calls"] += 1
        return "stop" if n["calls"] == 300 else None

    with _emulator() as emu:
        with pytest.raises(Paused) as ei:
            send_ebb(emu.port, path, state_file=state, controls=controls)
        first = _commands(emu)
        assert "\n" not in str(ei.value)
        assert first == list(job.lines[:len(first)])
        assert first[-1].startswith("SP,1") and emu.idle and emu.pen_up == 1  # at a stroke's end, pen up
        # the same board, sent again: set-up, pen up, then on from the next command
        r = send_ebb(emu.port, path, state_file=state)
        assert r["resumed"] and r["start_at"] == len(first) + 1
        rest = _commands(emu)[len(first):]
        preamble = [s for s in job.lines if s.startswith("SC")] + ["SP,1,200"]
        assert rest[:len(preamble)] == preamble
        assert rest[len(preamble):] == list(job.lines[len(first):])  # no HM: the board is where the job expects
        assert tuple(emu.pos) == (0, 0)


def test_pause_waits_pen_up_at_a_stroke_end_and_resumes(jobs):
    path = jobs / "badge.ebb"
    job = read_ebb(path.read_bytes())
    seen = {"calls": 0, "paused_at": None}
    emu = _emulator()

    def controls():
        # "resume" is answered on every poll once the board rests after a pen up, not once: the sender also polls
        # between sending that pen up and waiting in the pause, where a resume means nothing. A bounded wait: a
        # pause that never comes to rest ends the test as a stop (a failure), never as a hang.
        seen["calls"] += 1
        if seen["calls"] == 200:
            seen["asked"] = time.monotonic()
            return "pause"
        if seen["calls"] > 200 and emu.idle and _commands(emu)[-1].startswith("SP,1"):
            if seen["paused_at"] is None:
                seen["paused_at"] = (len(_commands(emu)), emu.pen_up)
            return "resume"
        if seen["calls"] > 200 and time.monotonic() - seen["asked"] > 300:
            return "stop"
        return None

    logged = []
    try:
        send_ebb(emu.port, path, state_file=None, controls=controls, log=logged.append)
        assert _commands(emu) == list(job.lines)
        assert seen["paused_at"] is not None and seen["paused_at"][1] == 1
        assert any(m.startswith("paused, pen up") for m in logged) and "resumed" in logged
    finally:
        emu.stop()


def test_lost_board_resumes_at_the_cut_stroke(jobs, tmp_path):
    path = jobs / "badge.ebb"
    job = read_ebb(path.read_bytes())
    state = tmp_path / "s.json"
    with _emulator(vanish_at=400) as emu:
        with pytest.raises(LinkError) as ei:
            send_ebb(emu.port, path, state_file=state, timeout=1.0)
        assert "\n" not in str(ei.value) and "lost the board" in str(ei.value)
        time.sleep(0.1)
        where = tuple(emu.pos)
        got = _commands(emu)
    # the board comes back (a new port), where it stopped: the job goes on from the start of the cut stroke
    with _emulator() as emu2:
        emu2.pos = list(where)
        r = send_ebb(emu2.port, path, state_file=state)
        assert r["resumed"]
        start = r["start_at"] - 1
        assert start <= len(got) and job.lines[start - 1].startswith(("SP,1", "@PAUSE"))
        pos, _ = line_effects(job.lines)
        sent = _commands(emu2)
        if where != pos[start - 1]:
            assert f"HM,4000,{pos[start - 1][0]},{pos[start - 1][1]}" in sent
        assert sent[-(len(job.lines) - start):] == list(job.lines[start:])
        assert tuple(emu2.pos) == (0, 0)


def test_pen_changes_ask_the_operator_with_the_board_at_rest_pen_up(jobs):
    path = jobs / "layers.ebb"
    job = read_ebb(path.read_bytes())
    assert job.pauses(), "layers.svg plots several pens"
    asked = []
    with _emulator() as emu:
        def pen_change(pen, what):
            asked.append((pen, emu.idle, emu.pen_up))

        r = send_ebb(emu.port, path, state_file=None, pen_change=pen_change)
        assert [p for p, _, _ in asked] == [p for _, p in job.pauses()]
        assert all(idle and up == 1 for _, idle, up in asked)
        assert _commands(emu) == [s for s in job.lines if not s.startswith("@")]  # never sent to the board
    assert r["pen_changes"] == len(asked)


def test_pen_change_without_an_operator_stops_resumable(jobs, tmp_path):
    path = jobs / "layers.ebb"
    job = read_ebb(path.read_bytes())
    state = tmp_path / "s.json"
    with _emulator() as emu:
        with pytest.raises(Paused) as ei:
            send_ebb(emu.port, path, state_file=state)
        assert "pen change to pen" in str(ei.value)
        first = job.pauses()[0][0]
        assert _commands(emu) == [s for s in job.lines[:first]]


def test_emulator_answers_as_the_reference_says():
    with _emulator() as emu:
        with serial.Serial(emu.port, timeout=2) as s:
            def ask(cmd):
                s.write((cmd + "\r").encode())
                out = s.readline().decode()
                if "Err" in out:
                    out += s.readline().decode()
                return out

            assert ask("V").startswith("EBBv13_and_above EB Firmware Version 3.0.2")
            assert ask("LM,1,2") == "!4 Err: Missing parameter(s)\r\nOK\r\n"
            assert ask("LM,1,2,3,4,5,6,3,9") == "!7 Err: Extra parameter\r\nOK\r\n"
            assert ask("LM,1,2x,3,4,5,6") == "!5 Err: Need comma next, found: 'x'\r\nOK\r\n"
            assert ask("LM,9999999999,1,0,0,0,0") == "!6 Err: Invalid parameter value\r\nOK\r\n"
            assert ask("LM,1000,1,0,0,0,0,4") == "!6 Err: Invalid parameter value\r\nOK\r\n"
            assert ask("SC,4,70000") == "!6 Err: Invalid parameter value\r\nOK\r\n"
            assert ask("ZZ") == "!8 Err: Unknown command 'ZZ:5A5A'\r\nOK\r\n"
            assert ask("SM,10,300,0") == "!0 Err: <axis1> step rate too high\r\nOK\r\n"
            assert ask("SM,100,10,-20") == "OK\r\n"
            time.sleep(0.05)
            assert ask("QS") == "10,-20\n" and s.readline() == b"\rOK\r\n"
        assert emu.pos == [10, -20] and len(emu.errors) == 8


@pytest.mark.parametrize("error_end", ["ok-line", "inline", "bare"])
def test_refused_command_is_reported_in_one_line(tmp_path, error_end):
    lines = ("EM,1,1", "SP,1,10", "LM,85899346,10,0,17180814,2,0,3", "SC,4,70000", "LM,85899346,10,0,0,0,0,3")
    with _emulator(error_end=error_end) as emu:
        sender = EbbSender(emu.port, EbbJob({}, lines), "bad.ebb", state_file=tmp_path / "s.json")
        with pytest.raises(LinkError) as ei:
            sender.run()
        msg = str(ei.value)
        assert "\n" not in msg and "refused command 4" in msg and "!6 Err: Invalid parameter value" in msg
        assert _commands(emu) == list(lines[:4])  # nothing after the refused command


def test_plotink_drives_the_emulator():
    """Evil Mad Scientist's plotink talks to the emulator; the steps it moves and the time it takes
    are what plotink's own LM arithmetic (ebb_calc.calculate_lm) says."""
    from plotink import ebb_calc, ebb_motion, ebb_serial

    rnd = random.Random(3)
    with _emulator(speed=1000.0) as emu:
        port = ebb_serial.testPort(emu.port)
        assert port is not None, "plotink's testPort does not see an EiBotBoard"
        try:
            assert ebb_serial.min_version(port, "2.7.0") is True
            want, ticks = [0, 0], 0
            for _ in range(30):
                mv = []
                for _axis in range(2):
                    steps = rnd.randint(1, 400) * rnd.choice([1, -1])
                    rate = rnd.randint(2 ** 20, 2 ** 30)
                    accel = rnd.randint(0, 2000)
                    mv += [rate, steps, accel]
                ebb_motion.doLowLevelMove(port, *mv, clear=3, verbose=False)
                t1, p1, _ = ebb_calc.calculate_lm(mv[1], mv[0], mv[2])
                t2, p2, _ = ebb_calc.calculate_lm(mv[4], mv[3], mv[5])
                want = [want[0] + p1, want[1] + p2]
                ticks += max(t1, t2)
            deadline = time.monotonic() + 10
            while not emu.idle and time.monotonic() < deadline:
                time.sleep(0.01)
            steps = ebb_motion.query_steps(port, verbose=False)
            assert [int(v) for v in steps] == want
            assert emu.executed[-1]["t"] == pytest.approx(ticks / 25000, abs=1e-9)
        finally:
            ebb_serial.closePort(port)


# ---------------------------------------------------------------- bad input: one line, before anything moves

def _cli(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "doodlecam", *args], capture_output=True, text=True, env=ENV,
                          cwd=ROOT, timeout=timeout)


def test_damaged_ebb_line_is_refused_before_the_port_opens(jobs, tmp_path):
    text = (jobs / "badge.ebb").read_text().splitlines()
    k = next(i for i, s in enumerate(text) if s.startswith("LM"))
    text[k] = text[k].replace(",", ";", 1)
    bad = tmp_path / "bad.ebb"
    bad.write_text("\n".join(text) + "\n")
    with pytest.raises(InputError) as ei:
        read_ebb(bad.read_bytes(), str(bad))
    assert f"line {k + 1}" in str(ei.value)
    text[k] = "LM,1,2,3,4,5,6,3"  # well-formed but not the file's command: the checksum says so
    bad.write_text("\n".join(text) + "\n")
    with _emulator() as emu:
        r = _cli("send", str(bad), "--serial", emu.port)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "crc32" in r.stderr
        assert emu.received == []


def test_a_grbl_is_not_taken_for_an_ebb(jobs):
    from doodlecam.link.grbl.emulator import GrblEmulator

    with GrblEmulator() as grbl:  # doodlecam's GRBL 1.1 emulator: it greets, then answers V with an error
        r = _cli("send", str(jobs / "badge.ebb"), "--serial", grbl.port)
        lines = r.stderr.strip().splitlines()
        assert r.returncode != 0 and len(lines) == 1 and "not an EiBotBoard" in lines[0] and "error:" in lines[0]
        assert grbl.executed == []


@pytest.mark.parametrize("answer,expect", [("grbl", "answered 'error:1'"), ("silent", "did not answer")])
def test_a_board_that_is_not_an_ebb_is_refused(jobs, answer, expect):
    with _emulator(answer=answer) as emu:
        r = _cli("send", str(jobs / "badge.ebb"), "--serial", emu.port)
        lines = r.stderr.strip().splitlines()
        assert r.returncode != 0 and len(lines) == 1 and expect in lines[0] and "not an EiBotBoard" in lines[0]
        assert emu.received == ["V"] and emu.executed == []


def test_firmware_too_old_for_lm_is_refused(jobs):
    with _emulator(version="2.5.3") as emu:
        r = _cli("send", str(jobs / "badge.ebb"), "--serial", emu.port)
        lines = r.stderr.strip().splitlines()
        assert r.returncode != 0 and len(lines) == 1 and "2.5.3 is too old" in lines[0]
        assert emu.received == ["V"] and emu.executed == []


def test_lms_turning_a_motor_back_need_firmware_3(tmp_path):
    """A job whose LMs turn a motor back mid-move (post ebb's default, firmware 3.0) runs on the 3.0 emulator
    step for step as line_effects predicts, in its planned time; a 2.8.1 board refuses it in one line before
    anything moves, and the firmware=2.7 conversion of the same drawing runs there."""
    from test_ebb import _circles

    from doodlecam import pipeline
    from doodlecam.machine import load_machine

    src = _circles(tmp_path / "circles.svg", n=12)
    m = load_machine("axidraw-v3")
    paths = {}
    for fw in ("3.0", "2.7"):
        r = pipeline.convert(src, tmp_path / fw, pipeline.Settings(machine=m, posts=("ebb",),
                                                                   post_options={"ebb": {"firmware": fw}}))
        paths[fw] = r.outputs[0]
    job = read_ebb(paths["3.0"].read_bytes())
    assert sum(_turns(s) for s in job.lines if s.startswith("LM")) > 10
    with _emulator() as emu:
        send_ebb(emu.port, paths["3.0"], state_file=None)
        pos, _ = line_effects(job.lines)
        motion = [i for i, s in enumerate(job.lines) if not s.startswith("SC")]
        assert emu.errors == [] and [e["pos"] for e in emu.executed] == [pos[i] for i in motion]
        assert emu.executed[-1]["t"] == pytest.approx(job.planned_time, abs=0.01)
    with _emulator(version="2.8.1") as emu:
        r = _cli("send", str(paths["3.0"]), "--serial", emu.port)
        lines = r.stderr.strip().splitlines()
        assert r.returncode != 0 and len(lines) == 1 and "needs 3.0.0 or newer" in lines[0] and "ebb.firmware=2.7" in lines[0]
        assert emu.received == ["V"] and emu.executed == []
    with _emulator(version="2.8.1") as emu:
        send_ebb(emu.port, paths["2.7"], state_file=None)
        old = read_ebb(paths["2.7"].read_bytes())
        assert emu.errors == [] and tuple(emu.pos) == (0, 0)
        assert emu.executed[-1]["t"] == pytest.approx(old.planned_time, abs=0.01)


def _turns(line: str) -> bool:
    """Whether an LM's rate passes through zero on an axis (firmware 3.0 turns that motor back)."""
    from doodlecam.link.ebb.board import axis_move, trunc_half

    p = [int(v) for v in line.split(",")[1:7]]
    for rate, steps, accel in (p[0:3], p[3:6]):
        if steps:
            r0, t = rate - trunc_half(accel), axis_move(rate, steps, accel)[0]
            if (r0 + accel > 0) != (r0 + accel * t > 0):
                return True
    return False


def test_cli_send_inspect_and_machine_controls(jobs, tmp_path):
    job = tmp_path / "badge.ebb"
    job.write_bytes((jobs / "badge.ebb").read_bytes())
    r = _cli("inspect", str(job), "--limit", "3")
    assert r.returncode == 0 and "planned_time" in r.stdout and "axidraw-v3" in r.stdout and "EM,1,1" in r.stdout
    with _emulator() as emu:
        r = _cli("send", str(job), "--serial", emu.port, "--no-progress")
        assert r.returncode == 0, r.stderr
        assert "sent" in r.stdout and _commands(emu) == list(read_ebb(job.read_bytes()).lines)
        r = _cli("machine", "--serial", emu.port, "ebb", "jog", "10", "5")
        assert r.returncode == 0, r.stderr
        assert tuple(emu.pos) == (1200, 400)  # motor 1 = x + y, motor 2 = x - y, 80 steps/mm
        r = _cli("machine", "--serial", emu.port, "ebb", "home")
        assert r.returncode == 0 and tuple(emu.pos) == (0, 0)
        r = _cli("machine", "--serial", emu.port, "ebb", "pen", "down")
        assert r.returncode == 0 and emu.pen_up == 0


def test_ctrl_c_stops_at_the_stroke_end_and_sending_again_resumes(jobs, tmp_path):
    import signal

    job = tmp_path / "badge.ebb"
    job.write_bytes((jobs / "badge.ebb").read_bytes())
    lines = list(read_ebb(job.read_bytes()).lines)
    with _emulator(speed=4.0) as emu:
        p = subprocess.Popen([sys.executable, "-m", "doodlecam", "send", str(job), "--serial", emu.port, "--no-progress"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
        deadline = time.monotonic() + 60
        while len(_commands(emu)) < 40 and time.monotonic() < deadline:  # drawing its first strokes
            time.sleep(0.05)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=120)
        assert p.returncode == 130, err
        said = err.strip().splitlines()  # what it does, then one line saying where it stopped
        assert "stopping at the end of the stroke" in said[0] and "stopped at command" in said[-1] and "pen up" in said[-1]
        first = _commands(emu)
        assert first == lines[:len(first)] and first[-1].startswith("SP,1") and emu.idle and emu.pen_up == 1
        assert Path(str(job) + ".send.json").exists()
        emu.cfg.speed = 400.0
        r = _cli("send", str(job), "--serial", emu.port, "--no-progress")
        assert r.returncode == 0, r.stderr
        assert f"resumed at command {len(first) + 1}" in r.stdout
        rest = _commands(emu)[len(first):]
        assert rest[-(len(lines) - len(first)):] == lines[len(first):]
        assert tuple(emu.pos) == (0, 0) and not Path(str(job) + ".send.json").exists()
