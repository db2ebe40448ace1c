"""The studio's sends stop at each pen change and wait for the page's Continue (PLC and GRBL).

A three-layer drawing (samples/vectors/layers.svg) is sent to the built-in PLC simulator over UDP
and to the GRBL emulator over a pseudo-terminal: the send waits (state 'waiting', the machine
holding the job with the pen up) until Continue; Stop there ends it, resumable; every command runs once.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from doodlecam.link.plc.protocol import Fault

from test_studio_api import UPLOAD, make_client, one_line, wait_state  # tests/ is on sys.path
from test_studio_grbl import control as answer


ROOT = Path(__file__).resolve().parents[1]
LAYERS = ROOT / "samples" / "vectors" / "layers.svg"


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    c = make_client(tmp_path_factory.mktemp("pens"))
    assert c.post("/api/load?name=layers.svg", content=LAYERS.read_bytes(), headers=UPLOAD).status_code == 200
    yield c
    c.app.state.sender.close()


def wait(c, until) -> dict:
    return wait_state(c, until, timeout=90.0)


def test_plc_send_waits_for_each_pen_change(studio):
    sender = studio.app.state.sender
    assert studio.post("/api/send", json={"target": "simulator"}).status_code == 200
    messages = []
    for _ in range(2):  # 3 layers, 2 pen changes
        s = wait(studio, lambda s: s["state"] in ("waiting", "done", "failed"))
        assert s["state"] == "waiting" and s["controls"] == ["continue", "stop"], s
        sim = sender._sim
        assert sim.held is not None and sim.held.reason == Fault.PEN_CHANGE and not sim.pen  # holding, pen up
        messages.append(s["message"])
        answer(studio, "continue")
        wait(studio, lambda s: s["state"] != "waiting" or s["message"] != messages[-1])
    s = wait(studio, lambda s: s["state"] in ("done", "failed"))
    assert s["state"] == "done", s
    assert messages == ["change to pen 2, then press Continue", "change to pen 3, then press Continue"]
    ex = sim.executed()
    np.testing.assert_array_equal(np.sort(ex), np.arange(1, len(ex) + 1))  # every command once


def test_plc_stop_at_a_pen_change_resumes_and_asks_again(studio):
    sender = studio.app.state.sender
    assert studio.post("/api/send", json={"target": "simulator", "again": True}).status_code == 200
    wait(studio, lambda s: s["state"] == "waiting")
    answer(studio, "stop")
    s = wait(studio, lambda s: s["state"] in ("stopped", "failed", "done"))
    assert s["state"] == "stopped" and "pen change" in s["message"], s
    assert sender._sim.held is not None and sender._sim.held.reason == Fault.PEN_CHANGE
    assert studio.post("/api/send", json={"target": "simulator"}).status_code == 200  # resume: asks again first
    s = wait(studio, lambda s: s["state"] in ("waiting", "done", "failed"))
    assert s["state"] == "waiting" and "pen 2" in s["message"]
    answer(studio, "continue")
    wait(studio, lambda s: s["state"] == "waiting" and "pen 3" in s["message"])
    answer(studio, "continue")
    assert wait(studio, lambda s: s["state"] in ("done", "failed"))["state"] == "done"


def test_grbl_send_waits_at_each_m0(studio):
    from doodlecam.link.grbl.protocol import prepare

    sender = studio.app.state.sender
    r = studio.post("/api/send", json={"target": "grbl-simulator", "speed": 50, "restart": True})
    assert r.status_code == 200, r.text
    emu = sender._grbl.emulator
    before = len(emu.received)
    for k in (2, 3):
        s = wait(studio, lambda s: s["state"] in ("waiting", "done", "failed", "stopped"))
        assert s["state"] == "waiting" and f"pen {k}" in s["message"] and "continue" in s["controls"], s
        assert emu.state == "Hold" and emu.m0_hold and emu.modal["s"] == 0  # GRBL holds at the M0, pen up (M3 S0)
        answer(studio, "continue")
        wait(studio, lambda s: s["state"] != "waiting")
    s = wait(studio, lambda s: s["state"] in ("done", "failed", "stopped"))
    assert s["state"] == "done", s
    gcode = (sender.record_dir("grbl-simulator") / "studio.gcode").read_text()
    assert emu.received[before:] == [ln.text.upper() for ln in prepare(gcode)]  # every line once, in order
    assert emu.pauses >= 2


def test_simulation_takes_the_planned_time(studio):
    summary = studio.get("/api/state").json()["summary"]
    tl = studio.get("/api/timeline").json()
    assert abs(tl["duration"] - summary["job_time_s"]) < 1e-3 * summary["job_time_s"]


def test_layers_in_the_view_and_plotting_one_layer(studio):
    """The layers panel's data (each layer's pen, colour, strokes) and 'plot one layer': only its strokes are
    exported and sent, with no pen change, read back from the PLC and G-code files."""
    from doodlecam.link.plc.packetfile import read_plc_array

    view = studio.get("/api/view").json()
    layers = view["layers"]
    assert len(layers) == 3 and sum(l["strokes"] for l in layers) == len(view["strokes"])
    assert [l["name"] for l in layers] == list(dict.fromkeys(s["layer"] for s in view["strokes"]))
    assert all(l["pen_name"] and l["colour"] for l in layers)
    session = studio.app.state.session
    one = layers[1]
    gcode = session.export("gcode", [one["name"]])[1].decode()
    _, records = read_plc_array(session.export("plc", [one["name"]])[1])
    assert "M0" not in gcode and not np.any(records["type"] == 2)  # one pen: no pen change inside
    _, every = read_plc_array(session.export("plc")[1])
    assert 0 < np.sum(records["type"] == 0) < np.sum(every["type"] == 0)  # that layer's drawing, not the others'
    assert "no layer 'nope'" in one_line(studio.post("/api/send", json={"target": "simulator", "layers": ["nope"]}))
    r = studio.post("/api/send", json={"target": "simulator", "layers": [one["name"]], "again": True})
    assert r.status_code == 200 and r.json()["total"] == len(records)
    s = wait(studio, lambda s: s["state"] not in ("sending", "stopping"))
    assert s["state"] == "done" and s["executed"] == len(records), s
