"""The studio's GRBL send and machine panel, against the built-in GRBL emulator on a real pseudo-terminal.

What GRBL received and did is read from the emulator (every line it got, its
parser's pen state, its position and state), not from the studio's own
record: each line of the job's G-code reaches GRBL exactly once, in order;
a pause lifts the pen; a feed hold stands still with the pen as it was; a stop
ends with the pen up, and sending again resumes after the last line.
"""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from grbl_received import check_received  # tests/ is on sys.path
from test_studio_api import UPLOAD

STEP = 0.5 / 80 + 1e-3  # GRBL stands on whole steps (80/mm): half a step off a target, then 3 decimals

from doodlecam.link.grbl.protocol import pen_up_line, prepare
from doodlecam.link.grbl.streamer import end_positions
from doodlecam.machine import load_machine
from doodlecam.pipeline import Settings
from doodlecam.studio.app import StudioConfig, create_app
from doodlecam.studio.session import Session


ROOT = Path(__file__).resolve().parents[1]
PICTURE = ROOT / "samples" / "images" / "coins.png"


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    session = Session(Settings(machine=load_machine("doodlebot")))
    folder = tmp_path_factory.mktemp("grbl")
    app = create_app(session, StudioConfig(token="tok", folders=(folder,)))
    c = TestClient(app, headers={"x-doodlecam-token": "tok"}, base_url="http://127.0.0.1")
    assert c.post("/api/load?name=coins.png", content=PICTURE.read_bytes(), headers=UPLOAD).status_code == 200
    yield c
    app.state.sender.close()


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


def longest_stroke(lines) -> tuple[int, int]:
    """(first, last) index of the longest run of G1 lines: the middle of a stroke, pen down."""
    best, start = (0, 0), None
    for i, ln in enumerate(lines + [None]):
        if ln is not None and ln.text.startswith("G1"):
            start = i if start is None else start
        elif start is not None:
            best = max(best, (start, i - 1), key=lambda r: r[1] - r[0])
            start = None
    return best


def pen_down(emu) -> bool:
    """The emulator's parser state: the doodlebot's servo pen is down at M3 S1000, up at M3 S0."""
    return emu.modal["spindle"] == 3 and emu.modal["s"] > 0


def test_grbl_send_pause_hold_stop_resume_every_line_once(studio):
    sender = studio.app.state.sender
    gcode = studio.get("/api/export/gcode").content.decode()
    lines = prepare(gcode)
    assert pen_up_line(lines) == "M3S0"
    first, last = longest_stroke(lines)
    assert last - first > 150
    r = studio.post("/api/send", json={"target": "grbl-simulator", "speed": 4})
    assert r.status_code == 200 and r.json()["transport"] == "grbl", r.text
    emu = sender._grbl.emulator
    n0 = len(emu.received)
    assert "a send is running" in one_line(studio.post("/api/send", json={"target": "grbl-simulator"}))
    assert "GRBL" in one_line(studio.post("/api/machine", json={"action": "status"}))  # the port is the send's

    # pause in the middle of the longest stroke: GRBL finishes the lines it has, then the pen is lifted
    s = wait(sender, lambda s: s["executed"] >= first + 20)
    assert s["state"] == "sending" and s["time_left_s"] > 0 and s["line"] == lines[s["executed"]].lineno
    control(studio, "pause")
    s = wait(sender, lambda s: s["state"] == "paused", 30)
    k = s["executed"]
    assert first + 20 <= k < last - 20, (first, k, last)  # mid-stroke
    got = emu.received[n0:]
    assert got[-1] == "M3S0" and got[-2] == lines[k - 1].text  # the pen lifted right after the last line run
    assert emu.state == "Idle" and not pen_down(emu)
    x, y = end_positions(lines)[k - 1]
    assert emu.pos[:2] == pytest.approx([x, y], abs=STEP) and s["position_mm"] == pytest.approx([x, y], abs=STEP)
    time.sleep(0.3)
    assert len(emu.received) == n0 + len(got)  # nothing goes out while paused
    assert "cannot hold while paused" in one_line(studio.post("/api/send/control", json={"action": "hold"}))

    # resume: the pen goes down where it was lifted, the stroke goes on
    control(studio, "resume")
    wait(sender, lambda s: s["executed"] >= k + 10)
    resumed = emu.received[n0 + len(got):]
    assert resumed[0] == "G21G90G94G17" and resumed[2:4] == ["M3S1000", "G4P0.15"]
    m = re.fullmatch(r"G0X([-\d.]+)Y([-\d.]+)", resumed[1])  # back to where the pen was lifted (it stands there)
    assert m and (float(m.group(1)), float(m.group(2))) == pytest.approx((x, y), abs=STEP)
    assert resumed[resumed.index(lines[k].text) - 1].startswith("F")  # then the feed, then the next line of the file
    # feed hold mid-stroke: GRBL stands still on the path with the pen down
    control(studio, "hold")
    time.sleep(0.4)
    p1 = list(emu.pos)
    time.sleep(0.3)
    assert emu.state == "Hold" and emu.pos == p1 and pen_down(emu)
    # stop from a hold: resume, GRBL finishes its lines, the pen is lifted; the job is kept to resume
    control(studio, "stop")
    s = wait(sender, lambda s: s["state"] not in ("stopping", "held", "sending"), 30)
    assert s["state"] == "stopped" and "pen up" in s["message"] and "job.gcode:" in s["message"], s
    assert emu.state == "Idle" and not pen_down(emu)
    assert 0 < s["executed"] < s["total"]

    # send again: resumes after the last line that ran, to the end
    r = studio.post("/api/send", json={"target": "grbl-simulator", "speed": 50})
    assert r.status_code == 200, r.text
    s = wait(sender, lambda s: s["state"] not in ("sending",), 60)
    assert s["state"] == "done" and "resumed at line" in s["message"] and s["percent"] == 100.0, s
    assert s["executed"] == s["total"] == len(lines)

    # what GRBL received: every line of the file exactly once, in order, plus only pause/resume lines
    extra = check_received(emu.received[n0:], lines)
    assert len(extra) <= 12  # one pen-up per pause and stop, one resume prefix each
    assert emu.state == "Idle" and not pen_down(emu)


def test_grbl_targets_and_controls_are_checked(studio):
    for target, words in [("serial:/etc/passwd", "not a serial port"), ("serial:", "not a serial port"),
                          ("serial:../../x", "not a serial port")]:
        assert words in one_line(studio.post("/api/send", json={"target": target}))
        assert words in one_line(studio.post("/api/machine", json={"target": target, "action": "status"}))
    assert "no send is running" in one_line(studio.post("/api/send/control", json={"action": "pause"}))
    assert "speed" in one_line(studio.post("/api/send", json={"target": "grbl-simulator", "speed": -1}))
    # sending and machine control need the token even on the loopback interface
    bare = TestClient(studio.app, base_url="http://127.0.0.1")
    assert bare.post("/api/send", json={"target": "grbl-simulator"}).status_code == 403
    assert bare.post("/api/machine", json={"action": "home"}).status_code == 403
    assert bare.post("/api/send/control", json={"action": "stop"}).status_code == 403


def test_machine_panel_on_the_emulator(studio):
    def act(action, **kw):
        r = studio.post("/api/machine", json={"target": "grbl-simulator", "action": action, **kw})
        assert r.status_code == 200, r.text
        return r.json()

    emu_before = act("status")
    assert emu_before["state"] == "Idle"
    emu = studio.app.state.sender._grbl.emulator
    x0, y0 = emu.pos[:2]
    s = act("jog", x=5, y=-2)
    assert s["position_mm"] == pytest.approx([x0 + 5, y0 - 2], abs=STEP) and emu.pos[:2] == pytest.approx([x0 + 5, y0 - 2], abs=STEP)
    s = act("zero")
    assert s["position_mm"] == pytest.approx([0, 0], abs=STEP) and emu.wco[:2] == pytest.approx([x0 + 5, y0 - 2])
    assert act("pen_down")["sent"] == "M3S1000" and pen_down(emu)
    assert act("pen_up")["sent"] == "M3S0" and not pen_down(emu)
    rows = {r["key"]: r for r in act("settings")["settings"]}
    # the emulator's rates and accelerations are the doodlebot's; it has GRBL's Z axis settings too
    assert rows["$110"]["ok"] and rows["$120"]["ok"] and rows["$100"]["ok"] and "$112" in rows
    assert "unlock" in act("unlock")["action"]
    assert "homing cycle is not enabled" in one_line(studio.post("/api/machine", json={"action": "home"}))
    assert "unknown machine action" in one_line(studio.post("/api/machine", json={"action": "dance"}))
    assert "x must be a number" in one_line(studio.post("/api/machine", json={"action": "jog", "x": "far", "y": 1}))
    act("zero", x=0, y=0)
    act("jog", x=0, y=0, absolute=True)


def test_grbl_pause_at_a_stroke_boundary_and_restart(studio):
    """A pause asked for as a stroke ends: the pen is up at rest, lifted by the sender only if the
    lines GRBL still had lowered it again (no redundant pen command); restart starts at line 1."""
    sender = studio.app.state.sender
    lines = prepare(studio.get("/api/export/gcode").content.decode())
    first, last = longest_stroke(lines)
    assert lines[last + 1].text == "M3S0"  # the stroke's own pen-up line
    assert studio.post("/api/send", json={"target": "grbl-simulator", "speed": 4}).status_code == 200
    emu = sender._grbl.emulator
    n0 = len(emu.received)
    wait(sender, lambda s: s["executed"] >= last + 2)  # GRBL answered the pen-up line: the stroke has run
    control(studio, "pause")
    s = wait(sender, lambda s: s["state"] == "paused", 30)
    k = s["executed"]
    got = emu.received[n0:]
    file_pens = [ln.text for ln in lines[:k] if ln.text in ("M3S0", "M3S1000")]
    if file_pens[-1] == "M3S1000":  # GRBL's queue reached into the next stroke: the sender lifted the pen
        assert got[-1] == "M3S0" and len(got) == k + 1
    else:  # stopped in the travel, the pen already up: nothing added
        assert got[-1] == lines[k - 1].text and len(got) == k
    assert emu.state == "Idle" and not pen_down(emu)
    # stop while paused: stays up, and the record says where to resume
    control(studio, "stop")
    s = wait(sender, lambda s: s["state"] not in ("paused", "stopping"), 30)
    assert s["state"] == "stopped" and f"job.gcode:{lines[k].lineno}" in s["message"], s
    assert not pen_down(emu)
    # restart: from the first line of the file, not from the resume point
    n1 = len(emu.received)
    assert studio.post("/api/send", json={"target": "grbl-simulator", "speed": 4, "restart": True}).status_code == 200
    wait(sender, lambda s: s["executed"] >= 5)
    control(studio, "stop")
    s = wait(sender, lambda s: s["state"] not in ("sending", "stopping"), 30)
    assert s["state"] == "stopped" and emu.received[n1:n1 + 3] == [ln.text for ln in lines[:3]]
    assert not pen_down(emu) and emu.state == "Idle"


def test_closing_the_studio_during_a_grbl_send_stops_with_the_pen_up(tmp_path):
    """Ctrl-C of the studio (its shutdown) during a GRBL send: stopped as Stop does, pen up, not cut off
    mid-stroke with the pen down; the page being closed does not stop it (the send belongs to the server)."""
    session = Session(Settings(machine=load_machine("doodlebot")))
    app = create_app(session, StudioConfig(token="tok", folders=(tmp_path,)))
    c = TestClient(app, headers={"x-doodlecam-token": "tok"}, base_url="http://127.0.0.1")
    assert c.post("/api/load?name=coins.png", content=PICTURE.read_bytes(), headers=UPLOAD).status_code == 200
    sender = app.state.sender
    assert c.post("/api/send", json={"target": "grbl-simulator", "speed": 4}).status_code == 200
    with c.stream("GET", "/api/send/events") as ev:  # a page follows, then goes away
        assert '"state": "sending"' in next(ev.iter_lines())
    emu = sender._grbl.emulator
    s = wait(sender, lambda s: s["executed"] >= 300)
    assert s["state"] == "sending"
    emu_stop, seen = emu.stop, {}
    emu.stop = lambda: (seen.update(state=emu.state, down=pen_down(emu), thread=sender.busy), emu_stop())
    sender.close()
    assert seen == {"state": "Idle", "down": False, "thread": False}
    s = sender.snapshot()[1]
    assert s["state"] == "stopped" and "pen up" in s["message"], s


def test_grbl_hold_during_a_travel_keeps_the_pen_up(studio):
    """A feed hold at a stroke boundary (during the pen-up travel to the next stroke): GRBL stands still
    on the travel with the pen up. GRBL runs a pen command only with its planner empty, so the pen's
    state while a travel runs is the last pen command received before that travel."""
    sender = studio.app.state.sender
    assert studio.post("/api/send", json={"target": "grbl-simulator", "speed": 1, "restart": True}).status_code == 200
    emu = sender._grbl.emulator
    end = time.monotonic() + 40
    while time.monotonic() < end:  # a travel of 30 mm or more running, less than a third done
        head = emu.planner[0] if emu.planner else None
        if head is not None and head.rapid and math.dist(head.start, head.end) > 30 and head.millimeters > 0.7 * head.length:
            break
        time.sleep(0.001)
    else:
        raise AssertionError("no travel seen")
    control(studio, "hold")
    wait(sender, lambda s: s["machine_state"].startswith("Hold") or emu.state == "Hold", 10)
    time.sleep(0.3)
    p1 = list(emu.pos)
    time.sleep(0.3)
    assert emu.state == "Hold" and emu.pos == p1
    travel = emu.planner[0]
    assert travel.rapid and 0 < math.dist(travel.start[:2], p1[:2]) < math.dist(travel.start[:2], travel.end[:2])
    before = emu.received[:travel.line - 1]
    pens = [t for t in before if t in ("M3S0", "M3S1000")]
    assert pens and pens[-1] == "M3S0"  # the pen is up while the travel stands held
    control(studio, "resume")
    wait(sender, lambda s: s["executed"] >= 20)
    control(studio, "stop")
    s = wait(sender, lambda s: s["state"] not in ("sending", "stopping"), 30)
    assert s["state"] == "stopped" and emu.state == "Idle" and not pen_down(emu)
