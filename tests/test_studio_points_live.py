"""The studio's point edits (insert after, delete) and what its live machine view is built on, through the API.

Insert and delete re-plan only the edited stroke, answer as a patch, keep the curve a clamped B-spline
(its ends on its first and last control points), are undoable, and are checked by the server before any
planning. A send says "done" only once the machine it drove is at rest (the PLC simulator ready again, GRBL's
emulator Idle, the EBB emulator's queue empty); the timeline of one layer is what a one-layer send draws.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from test_studio_api import UPLOAD, edit, make_client, one_line, wait_state  # tests/ is on sys.path

from doodlecam.machine import load_machine
from doodlecam.model import Spline
from doodlecam.pipeline import Settings
from doodlecam.studio.app import StudioConfig, create_app
from doodlecam.studio.session import Session

ROOT = Path(__file__).resolve().parents[1]


def loaded(tmp_path: Path, picture: str, machine: str = "doodlebot") -> TestClient:
    if machine == "doodlebot":
        c = make_client(tmp_path)
    else:
        app = create_app(Session(Settings(machine=load_machine(machine))),
                         StudioConfig(token="secret-token", folders=(tmp_path,)))
        c = TestClient(app, headers={"x-doodlecam-token": "secret-token"}, base_url="http://127.0.0.1")
    p = next((ROOT / "samples").glob(f"*/{picture}"))
    assert c.post(f"/api/load?name={picture}", content=p.read_bytes(), headers=UPLOAD).status_code == 200
    return c


@pytest.fixture(scope="module")
def coins(tmp_path_factory):
    c = loaded(tmp_path_factory.mktemp("points"), "coins.png")
    yield c
    c.app.state.sender.close()


def test_insert_and_delete_a_point_replan_only_that_stroke_and_undo(coins):
    session = coins.app.state.session
    view0 = coins.get("/api/view").json()
    k = sorted(range(len(view0["strokes"])), key=lambda i: len(view0["strokes"][i]["control"]))[len(view0["strokes"]) // 2]
    ctrl = np.array(view0["strokes"][k]["control"])
    n, deg = len(ctrl), view0["strokes"][k]["degree"]
    j = n // 2
    before = session.job
    r = edit(coins, {"op": "insert", "stroke": k, "point": j, "reply": "patch"})
    assert r.status_code == 200, r.text
    p = r.json()
    assert [s["i"] for s in p["strokes"]] == [k]  # the answer carries the one re-planned stroke
    new = np.array(p["strokes"][0]["control"])
    assert len(new) == n + 1 and p["strokes"][0]["degree"] == deg
    assert np.allclose(new[:j + 1], ctrl[:j + 1], atol=1e-4) and np.allclose(new[j + 2:], ctrl[j + 1:], atol=1e-4)
    assert np.allclose(new[j + 1], (ctrl[j] + ctrl[j + 1]) / 2, atol=1e-4)  # halfway to the next point
    after = session.job
    for i, (a, b) in enumerate(zip(before.samples, after.samples)):
        assert (a is b) == (i != k), i  # only the edited stroke was planned again
    # still a clamped B-spline: the executed stroke starts and ends on its first and last control points
    pts = np.array(p["strokes"][0]["points"])
    step = 1 / load_machine("doodlebot").x.steps_per_mm
    assert np.linalg.norm(pts[0] - new[0]) <= step and np.linalg.norm(pts[-1] - new[-1]) <= step
    spline = Spline(deg, after.strokes[k].spline.control)
    assert np.allclose(spline(np.array([0.0, 1.0])), new[[0, -1]], atol=1e-4)
    # delete the point again: the old control polygon, re-planned as a patch too
    r = edit(coins, {"op": "delete_point", "stroke": k, "point": j + 1, "reply": "patch"})
    assert r.status_code == 200 and np.allclose(r.json()["strokes"][0]["control"], ctrl, atol=1e-4)
    for _ in range(2):
        assert coins.post("/api/undo", json={}).status_code == 200
    again = coins.get("/api/view").json()
    assert again["strokes"] == view0["strokes"] and session.job is before


def test_point_edits_are_checked_by_the_server_before_any_planning(coins):
    view = coins.get("/api/view").json()
    k = max(range(len(view["strokes"])), key=lambda i: len(view["strokes"][i]["control"]))
    ctrl = np.array(view["strokes"][k]["control"])
    n, deg = len(ctrl), view["strokes"][k]["degree"]
    far, nan, more = ctrl.copy(), ctrl.copy(), np.vstack([ctrl, ctrl[-1:]])
    far[1] = [5000.0, 100.0]
    nan[1] = [float("nan"), 1.0]
    cases = [({"op": "insert", "point": n - 1}, "last; insert after an earlier one"),
             ({"op": "insert", "point": n}, "does not exist"),
             ({"op": "delete_point", "point": -1}, "does not exist"),
             ({"op": "move", "control": more.tolist()}, f"move keeps the stroke's {n} control points"),
             ({"op": "move", "control": far.tolist()}, "control point (5000.0, 100.0) mm is far outside the 400 x 300 mm"),
             ({"op": "move", "control": json.loads(json.dumps(nan.tolist()).replace("NaN", "null"))}, "mm")]
    for body, words in cases:
        t0 = time.process_time()
        r = edit(coins, {"stroke": k, **body})
        assert r.status_code == 400 and words in one_line(r), (body, r.text)
        assert time.process_time() - t0 < 1.0  # refused before any planning
    assert coins.get("/api/view").json()["strokes"] == view["strokes"]
    # a stroke of degree + 1 points keeps them: its points cannot be deleted
    small = next((i for i, s in enumerate(view["strokes"]) if len(s["control"]) == deg + 1), None)
    if small is None:  # make one: split the longest near its end
        assert edit(coins, {"op": "split", "stroke": k, "point": n - deg - 1}).status_code == 200
        small = k + 1
    r = edit(coins, {"op": "delete_point", "stroke": small, "point": 0})
    assert r.status_code == 400 and f"at least {deg + 1} control points" in one_line(r)
    while coins.get("/api/state").json()["summary"]["can_undo"]:
        coins.post("/api/undo", json={})


def test_the_timeline_of_one_layer_is_what_a_one_layer_send_draws(tmp_path):
    c = loaded(tmp_path, "layers.svg")
    session = c.app.state.session
    layers = [l["name"] for l in c.get("/api/view").json()["layers"]]
    whole = c.get("/api/timeline").json()
    one = c.get("/api/timeline", params={"layers": json.dumps([layers[1]])}).json()
    job = session.only_layers(session.job, [layers[1]])
    assert one["duration"] == pytest.approx(job.duration, rel=1e-6) and one["duration"] < whole["duration"]
    # its pen-down positions are that layer's strokes as executed, in order
    down = np.array(one["xy"])[np.array(one["pen"]) == 1]
    executed = np.concatenate([sa.integrate() for sa in job.samples])
    assert np.allclose(down, executed, atol=1e-3)
    assert "layer" in one_line(c.get("/api/timeline", params={"layers": '["no such layer"]'}))
    assert "JSON list" in one_line(c.get("/api/timeline", params={"layers": "red"}))


def spy_on_done(sender, probe) -> list:
    """The machine's state (``probe()``) at the moment the send state is set to done."""
    seen, update = [], sender._update

    def spy(**kw):
        if kw.get("state") == "done":
            seen.append(probe())
        update(**kw)

    sender._update = spy
    return seen


@pytest.mark.parametrize("target", ["simulator", "grbl-simulator"])
def test_done_only_when_the_machine_is_idle(tmp_path, target):
    from doodlecam.link.plc.protocol import State

    c = loaded(tmp_path, "badge.svg")
    sender = c.app.state.sender
    try:
        if target == "simulator":
            seen = spy_on_done(sender, lambda: (sender._sim.state == State.B_READY, bool(sender._sim.pen),
                                                bool(np.any(sender._sim.vel))))
            idle = (True, False, False)
        else:
            seen = spy_on_done(sender, lambda: sender._grbl.emulator.state)
            idle = "Idle"
        r = c.post("/api/send", json={"target": target, "speed": 10})
        assert r.status_code == 200, r.text
        first = r.json()
        assert first["layers"] is None and first["time_total_s"] > 0 and first["time_left_s"] <= first["time_total_s"]
        s = wait_state(c, lambda s: s["state"] not in ("sending", "stopping"), 120)
        assert s["state"] == "done", s
        assert seen == [idle]
    finally:
        sender.close()


def test_done_only_when_the_eibotboard_is_idle(tmp_path):
    c = loaded(tmp_path, "badge.svg", "axidraw-v3")
    sender = c.app.state.sender
    try:
        seen = spy_on_done(sender, lambda: (sender._ebb.emulator.idle, sender._ebb.emulator.pen_up))
        layers = [l["name"] for l in c.get("/api/view").json()["layers"]]
        r = c.post("/api/send", json={"target": "ebb-simulator", "speed": 10, "layers": layers[:1]})
        assert r.status_code == 200 and r.json()["layers"] == layers[:1], r.text
        s = wait_state(c, lambda s: s["state"] not in ("sending", "stopping", "pausing"), 120)
        assert s["state"] == "done", s
        assert seen == [(True, 1)]  # at rest, pen up
    finally:
        sender.close()
