"""Machine control against the GRBL emulator on a pseudo-terminal: bytes sent, replies, soft limits in
negative machine space, the interactive console, and ``doodlecam machine`` end to end."""

from __future__ import annotations

import time

import pytest
from test_grbl import bounded, emu_factory  # noqa: F401  (fixture)

from doodlecam.cli import main
from doodlecam.link.grbl.control import Controller, decode, run_console
from doodlecam.link.grbl.port import GrblLink
from doodlecam.link.grbl.protocol import GrblError
from doodlecam.link.grbl.streamer import send_gcode


def controller(emu) -> tuple[GrblLink, Controller]:
    link = GrblLink(emu.port, timeout=5.0).open()
    ctl = Controller(link)
    ctl.attach()
    return link, ctl


def test_soft_limits_live_in_negative_machine_space(emu_factory, tmp_path):
    emu = emu_factory(speed=50.0, soft_limits=True, travel=(400.0, 300.0))
    link, ctl = controller(emu)
    try:
        assert ctl.status().state == "Alarm"  # homing enabled: locked until $H, as GRBL 1.1 starts
        r = ctl.command("G0X10Y10")
        assert not r.ok and r.code == 9  # G-code locked out during alarm
        with pytest.raises(GrblError, match=r"error:9 .*GRBL is in alarm: home it .*machine --serial PORT home"):
            ctl.zero()
        st = ctl.home()
        assert emu.received[-1] == "$H" and st.state == "Idle" and st.mpos == (-1.0, -1.0, -1.0)  # $27 pull-off
        # A positive target is outside GRBL's travel (-400..0): ALARM:2, as the firmware does
        with pytest.raises(GrblError, match=r"ALARM:2 .*exceeds machine travel"):
            ctl.command("G0X10Y10")
        link.soft_reset()
        ctl.home()
        r = ctl.command("$J=G21G91X-500Y0F3000")
        assert not r.ok and r.code == 15 and "exceeds machine travel" in decode("error:15")  # jogs are refused, no alarm
        st = ctl.jog(-390.0, -290.0, 6000.0)
        assert emu.received[-1] == "$J=G21G91X-390.000Y-290.000F6000"
        assert st.mpos[:2] == (-391.0, -291.0)
        st = ctl.zero()
        assert emu.received[-1] == "G10L20P1X0.000Y0.000" and ctl.wco[:2] == (-391.0, -291.0)
    finally:
        link.close()
    # now a job in positive work coordinates runs inside the travel, and one that leaves it alarms
    ok = tmp_path / "ok.gcode"
    ok.write_text("G21 G90\nG0 X10 Y10\nG1 X380 Y280 F9000\nG0 X0 Y0\nM2\n")
    r = bounded(lambda: send_gcode(emu.port, ok, state_file=None))
    assert r["lines"] == 5 and emu.pos[:2] == [-391.0, -291.0]
    bad = tmp_path / "bad.gcode"
    bad.write_text("G21 G90\nG0 X10 Y10\nG0 X395 Y10\n")
    with pytest.raises(GrblError, match=r"ALARM:2 .*exceeds machine travel"):
        bounded(lambda: send_gcode(emu.port, bad, state_file=None))


def test_work_offset_option_makes_a_job_run_under_soft_limits(emu_factory, tmp_path):
    from test_gcode_dialects import write
    from test_posts import MACHINE, make_job

    from doodlecam.machine import parse_machine

    job = make_job(parse_machine(MACHINE, "test.toml"))
    text = write(job, work_offset="g10")
    assert "G10 L20 P1 X0 Y0" in text.splitlines()
    emu = emu_factory(speed=200.0, soft_limits=True, travel=(400.0, 300.0))
    link, ctl = controller(emu)
    try:
        ctl.home()
        ctl.jog(-390.0, -290.0, 9000.0)  # the pen over the profile's home corner
    finally:
        link.close()
    path = tmp_path / "job.gcode"
    path.write_text(text)
    r = bounded(lambda: send_gcode(emu.port, path, state_file=None), 120)
    assert r["lines"] == len([x for x in text.splitlines() if not x.startswith(";")])
    assert emu.g54[:2] == [-391.0, -291.0] and emu.state == "Idle"
    # without the offset the same job alarms at its first move
    path.write_text(write(job))
    link, ctl = controller(emu)
    try:
        ctl.command("G10L2P1X0Y0")  # forget the offset
    finally:
        link.close()
    with pytest.raises(GrblError, match="ALARM:2"):
        bounded(lambda: send_gcode(emu.port, path, state_file=None), 60)


def test_unlock_status_settings_and_refusals(emu_factory):
    emu = emu_factory(speed=50.0, homing=True)
    link, ctl = controller(emu)
    try:
        assert ctl.status().state == "Alarm"
        st = ctl.unlock()
        assert emu.received[-1] == "$X" and st.state == "Idle"
        lines = ctl.settings()
        assert "$110=9000.000 (X-axis maximum rate, mm/min)" in lines and "$1=25 (step idle delay, ms)" in lines
        assert "$22=1 (homing cycle enable, bool)" in lines
        assert emu.received[-1] == "$$"
    finally:
        link.close()
    emu2 = emu_factory(speed=50.0)  # homing disabled: $H is refused with error:5
    link, ctl = controller(emu2)
    try:
        with pytest.raises(GrblError, match=r"error:5 homing cycle is not enabled"):
            ctl.home()
    finally:
        link.close()


def test_console_keys_jog_override_and_dollar_commands(emu_factory):
    emu = emu_factory(speed=50.0)
    link, ctl = controller(emu)
    keys = list("]") + ["\x1b", "[", "C"] + ["\x1b", "[", "A"] + list("++-") + list("$$\r") + list("$Q\r")
    script = iter(keys)
    out: list[str] = []
    state = {"wait": 0}

    def getch():
        k = next(script, None)
        if k is None:  # all typed: let the jogs and replies land, then quit
            state["wait"] += 1
            return "q" if state["wait"] > 40 else None
        return k

    try:
        bounded(lambda: run_console(ctl, getch, out.append, step=1.0, feed=3000.0), 30)
        st = ctl.status()
    finally:
        link.close()
    sent = [x for x in emu.received if x.startswith("$J=")]
    assert sent == ["$J=G21G91X10.000Y0.000F3000", "$J=G21G91X0.000Y10.000F3000"]  # ] made the step 10 mm
    assert st.mpos[:2] == (10.0, 10.0)
    assert emu.overrides == 110 and "feed 110%" in "\n".join(out)  # +10 +10 -10
    assert "$110=9000.000 (X-axis maximum rate, mm/min)" in out
    assert "error:2 (numeric value format is not valid or missing an expected value)" in out  # $Q, as GRBL 1.1h
    assert any(x.startswith("Idle") and "MPos 10.000,10.000" in x for x in out)


def test_cli_machine_commands_end_to_end(emu_factory, capsys):
    emu = emu_factory(speed=50.0, soft_limits=True)
    assert main(["machine", "--serial", emu.port, "home"]) == 0
    assert "MPos -1.000,-1.000,-1.000" in capsys.readouterr().out
    assert main(["machine", "--serial", emu.port, "jog", "--", "-10", "-20"]) == 0
    assert main(["machine", "--serial", emu.port, "zero"]) == 0
    out = capsys.readouterr().out
    assert "WPos 0.000,0.000" in out.splitlines()[-1]
    assert main(["machine", "--serial", emu.port, "status"]) == 0
    assert capsys.readouterr().out.startswith("Idle")
    assert main(["machine", "--serial", emu.port, "jog", "--", "10", "500"]) != 0  # beyond $131: error:15
    err = capsys.readouterr().err
    assert "error:15" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert main(["machine", "--serial", "/dev/nonexistent-tty", "status"]) != 0
    err = capsys.readouterr().err
    assert "no such device" in err and len(err.strip().splitlines()) == 1
    time.sleep(0.05)


# ------------------------------------------------------------ controls during send

def on_terminal(args: list[str], steps, timeout: float = 30.0):
    """Run ``doodlecam ARGS`` with its keyboard on a pseudo-terminal; ``steps`` are (wait-until, keys)."""
    import os
    import subprocess
    import sys

    from test_grbl import ENV, ROOT

    master, slave = os.openpty()
    p = subprocess.Popen([sys.executable, "-m", "doodlecam", *args], stdin=slave, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    try:
        end = time.monotonic() + timeout
        for until, keys in steps:
            while not until() and time.monotonic() < end:
                time.sleep(0.01)
            os.write(master, keys)
        out, err = p.communicate(timeout=timeout)
    finally:
        p.kill()
        os.close(master)
        os.close(slave)
    return p.returncode, out, err


def _scripted(emu, plan):
    """controls(): each (condition(emu), command) fires once, in order, when its condition holds."""
    steps = list(plan)
    fired: list[tuple[str, int, dict]] = []

    def controls():
        if steps and steps[0][0](emu):
            cmd = steps.pop(0)[1]
            fired.append((cmd, len(emu.received), {"state": emu.state, "s": emu.modal["s"], "pos": list(emu.pos)}))
            return cmd
        return None

    return controls, fired, steps


def lasting(cond, seconds: float):
    """A condition on the emulator that holds for ``seconds``; what it saw first (time, lines, position)."""
    seen: dict = {}

    def check(e) -> bool:
        if not cond(e):
            return False
        seen.setdefault("t", time.monotonic())
        seen.setdefault("n", len(e.received))
        seen.setdefault("pos", list(e.pos))
        return time.monotonic() - seen["t"] > seconds

    return check, seen


def test_pause_lifts_the_pen_and_resume_sends_every_line_once(emu_factory, tmp_path):
    from test_grbl import sent_lines, synth_gcode

    text = synth_gcode(n_strokes=6, seg=40, seed=5)
    job = tmp_path / "p.gcode"
    job.write_text(text)
    emu = emu_factory(speed=40.0)
    # after the pause: idle, pen up, nothing new for a while
    paused_and_still, seen = lasting(lambda e: e.state == "Idle" and e.modal["s"] == 0 and not e.planner, 0.5)

    controls, fired, left = _scripted(emu, [
        (lambda e: len(e.received) > 60 and e.modal["s"] == 1000, "pause"),  # mid-stroke, pen down
        (paused_and_still, "resume"),
    ])
    r = bounded(lambda: send_gcode(emu.port, job, state_file=None, controls=controls), 120)
    assert not left and [f[0] for f in fired] == ["pause", "resume"]
    expected = sent_lines(text)
    got = emu.received
    assert fired[1][1] == seen["n"]  # nothing was sent while paused
    # the file's lines, each once and in order, with the sender's lift before the pause point and
    # the resume prefix (position, pen down, dwell, feed) after it
    k = next(i for i in range(len(expected)) if got[i] != expected[i])
    assert got[k] == "M3S0"  # the pen was lifted (the file's own pen-up command)
    rest = got[k + 1:]
    prefix = [x for x in rest[:6] if x.startswith(("G21G90", "G0X", "M3S1000", "G4P", "F"))]
    assert "M3S1000" in prefix  # the pen went down again where it was lifted
    assert rest[len(prefix):] == expected[k:] and r["lines"] == len(expected)
    assert fired[1][2]["s"] == 0  # the pen was up during the pause


def test_hold_resume_and_feed_override_during_send(emu_factory, tmp_path):
    from test_grbl import sent_lines, synth_gcode

    text = synth_gcode(n_strokes=4, seg=40, seed=6)
    job = tmp_path / "h.gcode"
    job.write_text(text)
    emu = emu_factory(speed=40.0)
    held_long_enough, held = lasting(lambda e: e.state == "Hold", 0.4)

    controls, fired, left = _scripted(emu, [
        (lambda e: len(e.received) > 40 and e.state == "Run", "feed+"),
        (lambda e: True, "feed+"),
        (lambda e: True, "feed-"),
        (lambda e: e.overrides == 110, "hold"),
        (held_long_enough, "resume"),
    ])
    bounded(lambda: send_gcode(emu.port, job, state_file=None, controls=controls), 120)
    assert not left
    assert emu.received == sent_lines(text)  # a hold adds nothing and loses nothing
    assert emu.overrides == 100  # it was 110 (the hold's trigger); M2 restores it, as GRBL 1.1h does
    assert fired[-1][2]["state"] == "Hold" and fired[-1][2]["pos"] == pytest.approx(held["pos"], abs=1e-6)


def test_send_keys_from_a_terminal(emu_factory, tmp_path):
    """`doodlecam send` on a terminal: + raises the feed override, s stops cleanly with the pen up."""
    from test_grbl import synth_gcode

    job = tmp_path / "k.gcode"
    job.write_text(synth_gcode(n_strokes=12, seg=40, seed=3))
    emu = emu_factory(speed=10.0)
    rc, out, err = on_terminal(["send", str(job), "--serial", emu.port, "--no-progress"],
                               [(lambda: len(emu.received) >= 60, b"+"), (lambda: emu.overrides == 110, b"s")])
    assert emu.overrides == 110
    assert rc == 130 and "paused before" in err and "keys: p pause" in err and "Traceback" not in err
    assert emu.received[-1] == "M3S0" and emu.state == "Idle"


def test_offset_lines_are_not_positions_and_g92_cannot_resume():
    from doodlecam.errors import InputError
    from doodlecam.link.grbl.protocol import line_durations, prepare, resume_prefix
    from doodlecam.link.grbl.streamer import end_positions

    lines = prepare("G21 G90 G94\nG10 L20 P1 X5 Y7\nG0 X10 Y10\nM3 S1000\nG1 X20 Y10 F600\nM3 S0\n")
    assert end_positions(lines)[1] == (None, None)  # G10 sets an offset, the pen does not move
    assert line_durations(lines)[1] == 0.0
    pre = [x.text for x in resume_prefix(lines, 5)]
    assert pre[1] == "G0X20Y10" and "G10L20P1X5Y7" not in pre  # G54 is stored in GRBL: not repeated
    g92 = prepare("G21 G90\nG92 X0 Y0\nG0 X10 Y10\nG1 X20 Y10 F600\n")
    with pytest.raises(InputError, match="G92"):
        resume_prefix(g92, 3)


def test_emulator_pen_change_waits_for_the_planner_and_the_idle_delay():
    """M3 S (outside laser mode) is answered only once motion has stopped and $1 (25 ms) has passed; with
    $1=255 (motors always on) at once. On the emulator's simulated clock (GRBL's planner: 10 mm at 10 mm/s
    with 2000 mm/s² ramps take 1.005 s)."""
    from doodlecam.link.grbl.emulator import GrblConfig, GrblEmulator

    def answers(text: str, **kw) -> list[float]:
        emu = GrblEmulator(GrblConfig(**kw))
        try:
            return [t for t, line in emu.simulate(text).replies if line == "ok"]
        finally:
            emu.stop()

    moved = 1.0 + 10.0 / 2000.0
    first, pen = answers("G1X10F600\nM3S1000\n")
    assert first < 0.01 and pen == pytest.approx(moved + 0.025, abs=0.003)
    first, pen = answers("G1X10F600\nM3S1000\n", idle_delay_ms=255)
    assert pen == pytest.approx(moved, abs=0.003)


def test_cli_console_on_a_terminal(emu_factory):
    """`doodlecam machine console` with its keyboard on a pseudo-terminal: arrows jog, $$ decodes, q quits."""
    emu = emu_factory(speed=50.0)
    settle = {}

    def a_moment_after_dollars() -> bool:  # the $$ replies printed
        if "$$" in emu.received:
            settle.setdefault("t", time.monotonic())
            return time.monotonic() - settle["t"] > 0.3
        return False

    rc, out, err = on_terminal(["machine", "--serial", emu.port, "console", "--step", "5"], [
        (lambda: bool(emu.status_queries), b"\x1b[C"),  # the console is up and polling: right arrow
        (lambda: any(x.startswith("$J=") for x in emu.received), b"$$\r"),
        (a_moment_after_dollars, b"q"),
    ], timeout=20)
    assert rc == 0, err
    assert "$J=G21G91X5.000Y0.000F3000" in emu.received and emu.pos[0] == pytest.approx(5.0)
    assert "$110=9000.000 (X-axis maximum rate, mm/min)" in out and "arrows jog" in out


def test_a_soft_limit_alarm_during_send_leaves_grbl_reset_not_locked(emu_factory, tmp_path, capsys):
    """GRBL 1.1h after ALARM:2 (protocol.c): 500 ms of delay, "[MSG:Reset to continue]", every reset sent
    before it discarded, then silence (no status either) until a new reset. The emulator does the same;
    send waits for the message, resets, and says so; `machine status` then answers at once."""
    emu = emu_factory(speed=50.0, soft_limits=True, travel=(400.0, 300.0))
    assert main(["machine", "--serial", emu.port, "home"]) == 0
    bad = tmp_path / "bad.gcode"
    bad.write_text("G21 G90\nG0 X10 Y10\nG0 X395 Y10\n")
    resets = emu.resets
    with pytest.raises(GrblError, match=r"ALARM:2 .*GRBL was reset and stays locked: .*unlock") as e:
        bounded(lambda: send_gcode(emu.port, bad, state_file=None))
    assert len(str(e.value).splitlines()) == 1 and emu.critical_since is None  # the block is lifted
    assert emu.resets == resets + 2  # the one at the start of the send, the one after the alarm
    capsys.readouterr()
    assert main(["machine", "--serial", emu.port, "status"]) == 0
    assert "Alarm" in capsys.readouterr().out  # reset after moving: locked until homed, as the firmware


def test_the_emulator_is_as_deaf_as_the_firmware_after_a_limit_alarm(emu_factory, capsys):
    """A reset within the 500 ms is lost and every command then meets silence; `machine reset` (and the
    console) free it, where every other command says to run it."""
    emu = emu_factory(speed=50.0, soft_limits=True, travel=(400.0, 300.0))
    link, ctl = controller(emu)
    try:
        ctl.home()
        link.write(b"G0X10Y10\n")
        t0 = time.monotonic()
        while not any(ev and ev[0] == "alarm" for ev in [link.next_event(0.05)]):
            assert time.monotonic() - t0 < 5
        link.realtime(b"\x18")  # too early: GRBL clears it before it waits for a reset
        asked = len(emu.status_queries)
        seen = [link.next_event(0.05) for _ in range(20)]  # 1 s, asking for status every 0.1 s meanwhile
        assert ("msg", "Reset to continue") in seen and not [ev for ev in seen if ev and ev[0] == "status"]
        assert emu.critical_since is not None and len(emu.status_queries) == asked  # not one status report
    finally:
        link.close()
    assert main(["machine", "--serial", emu.port, "--timeout", "1", "status"]) != 0
    assert "run 'doodlecam machine --serial" in capsys.readouterr().err
    assert main(["machine", "--serial", emu.port, "reset"]) == 0
    assert emu.critical_since is None and "Alarm" in capsys.readouterr().out
    assert main(["machine", "--serial", emu.port, "status"]) == 0


def test_homing_longer_than_the_answer_timeout(emu_factory, capsys):
    """GRBL sends nothing during a homing cycle (limits_go_home serves no status request): `machine home`
    waits for its ok up to the homing limit, saying it homes, instead of giving up after the answer timeout."""
    emu = emu_factory(speed=1.0, soft_limits=True, travel=(400.0, 300.0), homing_time=2.5)
    t0 = time.monotonic()
    assert main(["machine", "--serial", emu.port, "--timeout", "1", "home"]) == 0
    out = capsys.readouterr()
    assert time.monotonic() - t0 >= 2.5 and "homing" in out.err and "Idle" in out.out
