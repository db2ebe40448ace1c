"""The studio asks for the first pen before a job starts when the profile has more than one
[[pen]] (issue 28): the PLC file begins with a PAUSE, and the send waits for Continue before
the first stroke, naming pen 1; then it asks at the one pen change."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from doodlecam.machine import load_machine
from doodlecam.pipeline import Settings
from doodlecam.studio.app import StudioConfig, create_app
from doodlecam.studio.session import Session

from test_pen_changes import PROFILE  # two [[pen]]s (tests/ is on sys.path)
from test_studio_api import UPLOAD, wait_state
from test_studio_grbl import control as answer

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ROOT / "samples" / "vectors" / "layers.svg"
def test_the_studio_asks_for_the_first_pen_then_at_each_change(tmp_path):
    profile = tmp_path / "two-pens.toml"
    profile.write_text(PROFILE)
    session = Session(Settings(machine=load_machine(str(profile))))
    folder = tmp_path / "work"
    folder.mkdir()
    app = create_app(session, StudioConfig(token="t0ken-for-tests", folders=(folder,)))
    c = TestClient(app, headers={"x-doodlecam-token": "t0ken-for-tests"}, base_url="http://127.0.0.1")
    try:
        assert c.post("/api/load?name=layers.svg", content=LAYERS.read_bytes(), headers=UPLOAD).status_code == 200
        job = session._require()
        assert job.pen_pauses[0] == 0  # a pause before the first stroke
        assert c.post("/api/send", json={"target": "simulator"}).status_code == 200
        s = wait_state(c, lambda s: s["state"] in ("waiting", "done", "failed"), timeout=90)
        assert s["state"] == "waiting" and "pen 1" in s["message"], s
        sim = app.state.sender._sim
        assert not sim.executed().size or sim.executed().max() <= 1  # nothing drawn before the pen is fitted
        answer(c, "continue")
        messages = [s["message"]]
        while True:
            s = wait_state(c, lambda s: s["state"] in ("done", "failed")
                           or (s["state"] == "waiting" and s["message"] != messages[-1]), timeout=90)
            if s["state"] != "waiting":
                break
            messages.append(s["message"])
            answer(c, "continue")
        assert s["state"] == "done", s
        assert len(messages) == 1 + len(job.pen_changes) and "pen 2" in messages[-1], messages
    finally:
        app.state.sender.close()
