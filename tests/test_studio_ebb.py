"""The studio's send to an AxiDraw's EiBotBoard, against the EBB emulator on a real pseudo-terminal.

What the board received and did is read from the emulator (every command it got, its step counters,
its pen and its motion queue), not from the studio's own record: each command of the job's ``.ebb``
stream reaches the board exactly once and in order (plus the resume preamble the link documents);
pause and stop take effect at a stroke's end with the pen up; a pen change waits with the board at
rest; sending again resumes where the job stopped.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from test_studio_api import UPLOAD  # tests/ is on sys.path

from doodlecam.link.ebb.emulator import EbbConfig, EbbEmulator
from doodlecam.link.ebb.jobfile import read_ebb
from doodlecam.link.ebb.sender import line_effects
from doodlecam.machine import load_machine
from doodlecam.pipeline import Settings
from doodlecam.studio.app import StudioConfig, create_app
from doodlecam.studio.session import Session

ROOT = Path(__file__).resolve().parents[1]
QUERIES = ("V", "QM", "QS")
K = 80.0  # the axidraw-v3's steps per mm on each motor


def client(tmp_path: Path, machine: str = "axidraw-v3", picture: str = "badge.svg") -> TestClient:
    session = Session(Settings(machine=load_machine(machine)))
    app = create_app(session, StudioConfig(token="tok", folders=(tmp_path,)))
    c = TestClient(app, headers={"x-doodlecam-token": "tok"}, base_url="http://127.0.0.1")
    data = (ROOT / "samples" / "vectors" / picture).read_bytes()
    assert c.post(f"/api/load?name={picture}", content=data, headers=UPLOAD).status_code == 200
    return c


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    c = client(tmp_path_factory.mktemp("ebb"))
    yield c
    c.app.state.sender.close()


def received(sender) -> int:
    """Lines the studio's EBB emulator has received so far (0 before it exists)."""
    emu = sender._ebb.emulator
    return len(emu.received) if emu is not None else 0


def commands(emu) -> list[str]:
    return [s for s in emu.received if s.split(",")[0] not in QUERIES]


def one_line(r) -> str:
    assert r.status_code == 400, r.text
    msg = r.json()["error"]
    assert "\n" not in msg and "Traceback" not in msg
    return msg


def wait(sender, until, timeout: float = 60.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        s = sender.snapshot()[1]
        if until(s):
            return s
        time.sleep(0.005)
    raise AssertionError(f"send state never reached: {sender.snapshot()[1]}")


def control(c: TestClient, action: str) -> dict:
    r = c.post("/api/send/control", json={"action": action})
    assert r.status_code == 200, r.text
    return r.json()


def work_mm(emu, height: float = 218.0) -> tuple[float, float]:
    """The emulator's step counters as work-area mm, from the AxiDraw's belts (motor 1 = x + y_page,
    motor 2 = x - y_page, y_page down from the home corner)."""
    a, b = emu.pos
    return (a + b) / (2 * K), height - (a - b) / (2 * K)


def test_axidraw_studio_offers_its_board_and_streams_every_command_with_progress(studio):
    assert studio.get("/api/state").json()["targets"] == ["ebb-simulator", "ebb-serial"]
    sender = studio.app.state.sender
    lines = list(read_ebb(studio.get("/api/export/ebb").content).lines)
    n0 = received(sender)
    r = studio.post("/api/send", json={"target": "ebb-simulator", "speed": 20})
    assert r.status_code == 200 and r.json()["transport"] == "ebb" and r.json()["total"] == len(lines), r.text
    emu = sender._ebb.emulator
    assert "a send is running" in one_line(studio.post("/api/send", json={"target": "ebb-simulator"}))
    seen = []
    s = wait(sender, lambda s: seen.append(s) or s["state"] != "sending")
    assert s["state"] == "done" and s["percent"] == 100.0 and "firmware 3.0.2" in s["message"], s
    # live progress: commands answered grow, the time left falls, the pen's place follows the board
    mid = [x for x in seen if 0 < x["executed"] < x["total"]]
    assert len(mid) >= 5
    assert all(a["executed"] <= b["executed"] and a["time_left_s"] >= b["time_left_s"] for a, b in zip(mid, mid[1:]))
    steps, _ = line_effects(lines)
    for x in mid[::max(1, len(mid) // 5)]:
        a, b = steps[x["executed"] - 1]
        assert x["position_mm"] == pytest.approx([(a + b) / (2 * K), 218.0 - (a - b) / (2 * K)], abs=0.01)
    got = [c for c in emu.received[n0:] if c.split(",")[0] not in QUERIES]
    assert got == lines and emu.errors == [] and emu.idle
    assert tuple(emu.pos) == (0, 0) and emu.pen_up == 1


def test_pause_and_stop_at_a_stroke_end_pen_up_then_resume(studio):
    sender = studio.app.state.sender
    lines = list(read_ebb(studio.get("/api/export/ebb").content).lines)
    n0 = received(sender)
    assert studio.post("/api/send", json={"target": "ebb-simulator", "speed": 4}).status_code == 200
    emu = sender._ebb.emulator
    wait(sender, lambda s: s["executed"] >= 60)
    assert "cannot hold while sending" in one_line(studio.post("/api/send/control", json={"action": "hold"}))
    assert control(studio, "pause")["state"] == "pausing"
    s = wait(sender, lambda s: s["state"] == "paused", 30)
    k = s["executed"]
    got = [c for c in emu.received[n0:] if c.split(",")[0] not in QUERIES]
    assert got == lines[:k] and got[-1].startswith("SP,1")  # the stroke ran to its end, the pen lifted
    assert emu.idle and emu.pen_up == 1 and s["controls"] == ["resume", "stop"]
    assert s["position_mm"] == pytest.approx(work_mm(emu), abs=0.01)
    time.sleep(0.3)
    assert [c for c in emu.received[n0:] if c.split(",")[0] not in QUERIES] == got  # nothing goes out while paused
    control(studio, "resume")
    wait(sender, lambda s: s["executed"] >= k + 40)
    # stop: at the end of the stroke it is drawing, pen up; the job is kept to resume
    control(studio, "stop")
    s = wait(sender, lambda s: s["state"] not in ("sending", "stopping"), 30)
    assert s["state"] == "stopped" and "pen up" in s["message"] and "send the job again" in s["message"], s
    j = s["executed"]
    got = [c for c in emu.received[n0:] if c.split(",")[0] not in QUERIES]
    assert got == lines[:j] and got[-1].startswith("SP,1") and emu.idle and emu.pen_up == 1
    # send again: the servo set-up and a pen up, then on from the command after the stop, to the end
    r = studio.post("/api/send", json={"target": "ebb-simulator", "speed": 50})
    assert r.status_code == 200, r.text
    s = wait(sender, lambda s: s["state"] != "sending")
    assert s["state"] == "done" and f"resumed at command {j + 1}" in s["message"], s
    rest = [c for c in emu.received[n0:] if c.split(",")[0] not in QUERIES][j:]
    preamble = [c for c in lines if c.startswith("SC")] + ["SP,1,200"]
    assert rest == preamble + lines[j:]  # every command once: none lost, none repeated
    assert tuple(emu.pos) == (0, 0) and emu.pen_up == 1 and emu.errors == []


def test_stop_while_paused_and_start_over(studio):
    sender = studio.app.state.sender
    lines = list(read_ebb(studio.get("/api/export/ebb").content).lines)
    assert studio.post("/api/send", json={"target": "ebb-simulator", "speed": 4}).status_code == 200
    wait(sender, lambda s: s["executed"] >= 30)
    control(studio, "pause")
    wait(sender, lambda s: s["state"] == "paused", 30)
    control(studio, "stop")
    s = wait(sender, lambda s: s["state"] not in ("paused", "stopping"), 30)
    assert s["state"] == "stopped", s
    # Start over: from the first command, not from the resume point
    emu = sender._ebb.emulator
    n1 = len(emu.received)
    assert studio.post("/api/send", json={"target": "ebb-simulator", "speed": 50, "restart": True}).status_code == 200
    s = wait(sender, lambda s: s["state"] != "sending")
    assert s["state"] == "done" and "resumed" not in s["message"]
    assert [c for c in emu.received[n1:] if c.split(",")[0] not in QUERIES] == lines
    # abandon forgets a stopped job's record
    r = studio.post("/api/send/abandon", json={"target": "ebb-simulator"})
    assert r.status_code == 200 and "abandoned" in r.json()["message"]


def test_pen_change_waits_for_the_operator_at_rest_pen_up(tmp_path):
    c = client(tmp_path, picture="layers.svg")
    sender = c.app.state.sender
    try:
        job = read_ebb(c.get("/api/export/ebb").content)
        pauses = job.pauses()
        assert len(pauses) >= 2, "layers.svg plots several pens"
        assert c.post("/api/send", json={"target": "ebb-simulator", "speed": 50}).status_code == 200
        emu = sender._ebb.emulator
        # the first change: the board at rest with the pen up, Continue goes on
        s = wait(sender, lambda s: s["state"] == "waiting")
        assert "then press Continue" in s["message"] and s["controls"] == ["continue", "stop"]
        assert emu.idle and emu.pen_up == 1 and commands(emu) == [x for x in job.lines[:pauses[0][0]]]
        control(c, "continue")
        # the second: Stop ends there, resumable; sending again asks for that pen again
        s = wait(sender, lambda s: s["state"] == "waiting" and len(commands(emu)) > pauses[0][0])
        n = len(commands(emu))
        control(c, "stop")
        s = wait(sender, lambda s: s["state"] not in ("waiting", "stopping"))
        assert s["state"] == "stopped" and "pen up" in s["message"] and emu.pen_up == 1, s
        assert c.post("/api/send", json={"target": "ebb-simulator", "speed": 50}).status_code == 200
        s = wait(sender, lambda s: s["state"] == "waiting")
        assert len([x for x in commands(emu)[n:] if not x.startswith(("SC", "SP,1,200"))]) == 0  # asked before moving
        while True:
            control(c, "continue")
            s = wait(sender, lambda s: s["state"] != "sending")
            if s["state"] != "waiting":
                break
        assert s["state"] == "done", s
        sent = commands(emu)
        assert sent[:n] == [x for x in job.lines if not x.startswith("@")][:n]
        assert tuple(emu.pos) == (0, 0) and emu.pen_up == 1
    finally:
        sender.close()


def test_a_board_on_a_serial_port(tmp_path):
    """'ebb:PORT' drives the board on that port (here the emulator's pseudo-terminal, a real tty)."""
    c = client(tmp_path)
    sender = c.app.state.sender
    lines = list(read_ebb(c.get("/api/export/ebb").content).lines)
    with EbbEmulator(EbbConfig(speed=100.0)) as emu:
        r = c.post("/api/send", json={"target": f"ebb:{emu.port}"})
        assert r.status_code == 200 and "EiBotBoard on" in r.json()["target"], r.text
        s = wait(sender, lambda s: s["state"] != "sending")
        assert s["state"] == "done" and commands(emu) == lines, s
    with EbbEmulator(EbbConfig(version="2.5.3")) as old:  # too old for LM: refused before anything moves
        assert c.post("/api/send", json={"target": f"ebb:{old.port}"}).status_code == 200
        s = wait(sender, lambda s: s["state"] != "sending")
        assert s["state"] == "failed" and "2.5.3 is too old" in s["message"] and old.received == ["V"]
    sender.close()


def test_targets_are_checked(studio, tmp_path):
    for target in ("ebb:/etc/passwd", "ebb:../../x"):
        assert "not a serial port" in one_line(studio.post("/api/send", json={"target": target}))
    assert "no send is running" in one_line(studio.post("/api/send/control", json={"action": "pause"}))
    assert "speed" in one_line(studio.post("/api/send", json={"target": "ebb-simulator", "speed": -1}))
    bare = TestClient(studio.app, base_url="http://127.0.0.1")
    assert bare.post("/api/send", json={"target": "ebb-simulator"}).status_code == 403
    # a machine that is not an AxiDraw is offered its PLC and GRBL, and refused an EiBotBoard in one line
    other = client(tmp_path, machine="doodlebot")
    assert "ebb-simulator" not in other.get("/api/state").json()["targets"]
    assert "axidraw kinematics" in one_line(other.post("/api/send", json={"target": "ebb-simulator"}))


def commands_since(emu, n: int) -> list[str]:
    return [s for s in emu.received[n:] if s.split(",")[0] not in QUERIES]


def test_machine_panel_drives_the_board(tmp_path):
    """The studio's EiBotBoard panel (``doodlecam machine ebb``'s controls): what the emulator received and did."""
    c = client(tmp_path)
    sender = c.app.state.sender
    m = load_machine("axidraw-v3")

    def act(action, **kw):
        r = c.post("/api/machine", json={"target": "ebb-simulator", "action": action, **kw})
        assert r.status_code == 200, r.text
        return r.json()

    try:
        r = act("pen_down")
        emu = sender._ebb.emulator
        assert r["sent"] == "SP,0,200" and emu.pen_up == 0 and r["position_mm"] == [0.0, m.height]
        # 10 mm right and 5 mm down the paper (y up on the page, away from home on the board): the pen is
        # raised first; motor 1 = x + y_page, motor 2 = x - y_page at 80 steps/mm
        r = act("jog", x=10, y=-5)
        assert emu.pen_up == 1 and tuple(emu.pos) == (1200, 400)
        assert r["position_mm"] == [10.0, m.height - 5] and "pen at (10.0, 213.0) mm" in r["line"]
        before = len(emu.received)
        assert "would leave" in one_line(c.post("/api/machine", json={"target": "ebb-simulator", "action": "jog",
                                                                      "x": -20, "y": 0}))
        assert commands_since(emu, before) == [] and tuple(emu.pos) == (1200, 400)
        assert "must be a number" in one_line(c.post("/api/machine", json={"target": "ebb-simulator", "action": "jog",
                                                                            "x": "far", "y": 0}))
        r = act("home")
        assert tuple(emu.pos) == (0, 0) and emu.pen_up == 1 and r["sent"].startswith("SP,1,200 HM,")
        r = act("status")
        assert r["sent"] == "" and r["position_mm"] == [0.0, m.height]
        before = len(emu.received)
        r = act("motors_off")
        assert commands_since(emu, before) == ["EM,0,0"] and "motors off" in r["line"]
        assert "unknown EiBotBoard action" in one_line(c.post("/api/machine", json={"target": "ebb-simulator",
                                                                                     "action": "dance"}))
        # while a send drives the board, the panel waits for it
        assert c.post("/api/send", json={"target": "ebb-simulator", "speed": 1}).status_code == 200
        assert "send to the EiBotBoard is running" in one_line(c.post("/api/machine", json={
            "target": "ebb-simulator", "action": "pen_up"}))
        control(c, "stop")
        wait(sender, lambda s: s["state"] not in ("sending", "stopping"))
    finally:
        sender.close()
