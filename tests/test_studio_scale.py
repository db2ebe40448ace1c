"""doodlecam studio on large drawings (docs/studio.md, "Large drawings"): a drawing is shown as traced
while it is planned in the background, open pages follow through /api/events, the page's view comes as
flat arrays, and an edit re-plans only its own strokes."""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from doodlecam.machine import load_machine
from doodlecam.pipeline import Settings
from doodlecam.studio import session as studio_session
from doodlecam.studio.app import StudioConfig, create_app
from doodlecam.studio.session import Session, thin_paths

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from generated_art import generated_svg  # noqa: E402

UPLOAD = {"content-type": "application/octet-stream"}


def client() -> tuple[TestClient, Session]:
    session = Session(Settings(machine=load_machine("doodlebot")))
    app = create_app(session, StudioConfig(token="t"))
    return TestClient(app, headers={"x-doodlecam-token": "t"}, base_url="http://127.0.0.1"), session


def events(c: TestClient, until, timeout: float = 120.0, opened=None) -> list[tuple[str, dict]]:
    """(name, data) of /api/events until ``until(name, data)`` holds for one of them; ``opened()`` is
    called once the first event is in (e.g. to let a held plan go on only when the stream can see it)."""
    out, name, end = [], None, time.monotonic() + timeout
    with c.stream("GET", "/api/events") as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            assert time.monotonic() < end, out
            if line.startswith("event: "):
                name = line[7:]
            elif line.startswith("data: "):
                out.append((name, json.loads(line[6:])))
                if opened is not None and len(out) == 1:
                    opened()
                if until(*out[-1]):
                    return out
    raise AssertionError(out)


def decode(view: dict) -> tuple[list[dict], list[list[float]]]:
    """The flat view's strokes and travels as the object view has them (what the page's fetchView does)."""
    g, strokes = view["geometry"], []
    for i, _ in enumerate(g["degree"]):
        a, b = g["offsets"][i], g["offsets"][i + 1]
        ca, cb = g["control_offsets"][i], g["control_offsets"][i + 1]
        strokes.append({"i": i, "degree": g["degree"][i], "length": g["length"][i],
                        "control": np.reshape(g["control"][2 * ca:2 * cb], (-1, 2)).tolist(),
                        "points": np.reshape(g["xy"][2 * a:2 * b], (-1, 2)).tolist(), "speed": g["speed"][a:b],
                        "time": g["time"][i], "layer": g["layer_names"][g["layer"][i]]})
    return strokes, np.reshape(view["travels"], (-1, 5)).tolist()


@pytest.fixture
def held(monkeypatch):
    """Background plans wait for ``held.set()`` (so a test sees the studio while it plans); every drawing
    of 20 paths or more is planned in the background."""
    gate = threading.Event()
    plan = Session._plan

    def waiting(self, drawing, progress=None):
        if progress is not None:
            assert gate.wait(120)
        return plan(self, drawing, progress)

    monkeypatch.setattr(Session, "_plan", waiting)
    monkeypatch.setattr(studio_session, "BACKGROUND_MIN", 20)
    yield gate
    gate.set()


def test_a_drawing_is_shown_as_traced_then_planned_in_the_background(held):
    c, session = client()
    r = c.post("/api/load?name=art.svg", content=generated_svg(60, "lines").encode(), headers=UPLOAD)
    assert r.status_code == 200, r.text
    s = r.json()
    assert s["planning"] == {"stage": "ordering", "done": 0, "total": 60} and s["strokes"] == 60
    assert c.get("/api/state").json()["loaded"] is True
    view = c.get("/api/view?flat=1").json()
    assert "geometry" not in view and view["summary"]["version"] == s["version"]
    pre = view["preview"]
    assert len(pre["offsets"]) == 61 and len(pre["xy"]) == 2 * pre["offsets"][-1] == 2 * 120  # lines: two ends each
    # nothing that needs the plan is done on the preview; each says so in one line
    for r in (c.post("/api/edit", json={"op": "reverse", "stroke": 0, "job": s["job"], "version": s["version"]}),
              c.get("/api/view"), c.get("/api/export/gcode"), c.get("/api/timeline")):
        assert r.status_code == 400 and "still being planned" in r.json()["error"], r.text
    # the plan goes on once the stream is open; the events say how far it got, then that it is done
    seen = events(c, lambda name, d: name == "job" and d["planning"] is None, opened=held.set)
    jobs = [d for name, d in seen if name == "job"]
    assert jobs[0]["planning"] is not None and jobs[-1]["version"] > s["version"] and jobs[-1]["job"] != s["job"]
    done = [d["planning"]["done"] for d in jobs[:-1] if d["planning"]["stage"] == "planning"]
    assert done == sorted(done)
    # the planned job: the flat view is the object view, number for number
    flat, full = c.get("/api/view?flat=1").json(), c.get("/api/view").json()
    strokes, travels = decode(flat)
    assert strokes == full["strokes"] and travels == full["travels"] and len(strokes) == session.summary()["strokes"]
    assert flat["summary"] == full["summary"] and flat["summary"]["planning"] is None


def test_a_new_load_supersedes_a_background_plan(held):
    c, session = client()
    c.post("/api/load?name=big.svg", content=generated_svg(40, "lines").encode(), headers=UPLOAD)
    r = c.post("/api/load?name=small.svg", content=generated_svg(30, "curves").encode(), headers=UPLOAD)
    held.set()
    events(c, lambda name, d: name == "job" and d["planning"] is None)
    time.sleep(0.5)  # the first plan, released too, stops at its first progress report
    assert session.name == "small.svg" and session.job.source == "small.svg" and session.job_id != r.json()["job"]
    assert len({st.source_index for st in session.job.strokes}) == 30


def test_a_failed_background_plan_is_one_line_and_keeps_the_preview(monkeypatch):
    from doodlecam.errors import InputError

    def fail(self, drawing, progress=None):
        raise InputError("stroke 3 leaves the work area; draw it smaller")

    monkeypatch.setattr(Session, "_plan", fail)
    c, session = client()
    c.post("/api/load?name=art.svg", content=generated_svg(1000, "lines").encode(), headers=UPLOAD)
    seen = events(c, lambda name, d: name == "job" and d["planning"] and "error" in d["planning"])
    assert seen[-1][1]["planning"] == {"error": "stroke 3 leaves the work area; draw it smaller"}
    assert c.get("/api/view?flat=1").json()["preview"]["offsets"][-1] == 2000
    assert c.get("/api/view").json()["error"] == "planning failed: stroke 3 leaves the work area; draw it smaller"


def test_an_edit_replans_its_stroke_only_and_other_tabs_hear_of_it(monkeypatch):
    c, session = client()
    s = c.post("/api/load?name=art.svg", content=generated_svg(300, "curves").encode(), headers=UPLOAD).json()
    assert s["planning"] is None  # under BACKGROUND_MIN: planned before the answer
    planned = []
    plan = studio_session.plan_job

    def counting(drawing, *a, fitted=None, **kw):
        planned.append(len(fitted))
        return plan(drawing, *a, fitted=fitted, **kw)

    monkeypatch.setattr(studio_session, "plan_job", counting)
    job = session.job
    k = len(job.strokes) // 2
    control = np.array(job.strokes[k].spline.control)
    control[1] += 0.4  # an interior point: the stroke's ends and so its travels stay
    r = c.post("/api/edit", json={"op": "move", "stroke": k, "control": control.tolist(), "reply": "patch",
                                  "job": s["job"], "version": s["version"]})
    assert r.status_code == 200, r.text
    new = session.job
    assert planned == [1]
    assert all(a is b for n, (a, b) in enumerate(zip(job.strokes, new.strokes)) if n != k) and new.strokes[k] is not job.strokes[k]
    assert all(a is b for a, b in zip(job.travels, new.travels))
    # the summary is the new job's own figures, and the patch carries only stroke k and its two travels
    p = r.json()
    assert p["summary"]["job_time_s"] == round(new.duration, 3) and p["summary"]["travel_mm"] == round(new.travel_length, 3)
    assert [st["i"] for st in p["strokes"]] == [k] and [i for i, _ in p["travels"]] == [k, k + 1]
    # reversing moves its ends: its two travels are made again, the others kept
    job, s = new, p["summary"]
    r = c.post("/api/edit", json={"op": "reverse", "stroke": k, "job": s["job"], "version": s["version"]})
    new = session.job
    assert [n for n, (a, b) in enumerate(zip(job.travels, new.travels)) if a is not b] == [k, k + 1]
    assert r.json()["travel_mm"] == round(new.travel_length, 3) and r.json()["job_time_s"] == round(new.duration, 3)
    # another tab's stream: the job's new version
    seen = events(c, lambda name, d: name == "job")
    assert seen[0][1] == {"job": s["job"], "version": r.json()["version"], "planning": None}


def test_edits_in_place_carry_the_totals_and_figures_of_a_fresh_job():
    """An edit that replaces strokes in place (move, reverse, insert, delete_point) costs what its strokes cost:
    the job's totals are the old ones plus the differences (Job.replacing) and its largest figures are kept
    unless the edited stroke held one. Every figure must equal what a pass over the whole new job gives."""
    from doodlecam.model import Job
    from doodlecam.plan.travel import travel_time_by_law

    _, session = client()
    session.load("art.svg", generated_svg(200, "curves").encode(), background=False)
    s = session.summary()  # the summary knows the totals: the edits carry them over
    job = session.job
    by_fit = max(range(len(job.strokes)), key=lambda i: job.strokes[i].fit_error)
    second = max(st.fit_error for i, st in enumerate(job.strokes) if i != by_fit)
    assert job.strokes[by_fit].fit_error > second > 0
    k = len(job.strokes) // 3
    for op, i, kw in [("move", by_fit, {"point": 1}), ("reverse", k, {}), ("insert", k, {"point": 1}),
                      ("delete_point", k, {"point": 2}), ("move", k, {"point": 0})]:
        old = session.job
        if op == "move":
            c = np.array(old.strokes[i].spline.control)
            c[kw.pop("point")] += 0.3
            kw["control"] = c.tolist()
        s = session.edit(op, i, **kw)
        new = session.job
        assert all(a is b for n, (a, b) in enumerate(zip(old.strokes, new.strokes)) if n != i)
        fresh = Job(new.machine, new.strokes, new.travels, new.samples, new.source, dict(new.meta))
        for name in ("pen_down_length", "travel_length", "draw_time", "travel_time", "pen_delays", "duration"):
            assert getattr(new, name) == pytest.approx(getattr(fresh, name), rel=1e-12, abs=1e-12), (op, name)
        assert new.lifts == fresh.lifts and new.layers == fresh.layers
        assert s["job_time_s"] == round(new.duration, 3) and s["pen_down_mm"] == round(new.pen_down_length, 3)
        checks = [session.checks(st, sa) for st, sa in zip(new.strokes, new.samples)]
        assert new.meta["worst_acceleration_ratio"] == max(c[0] for c in checks)
        assert new.meta["worst_velocity_ratio"] == max(c[1] for c in checks)
        assert new.meta["max_between_samples_mm"] == max(c[3] for c in checks)
        assert new.meta["max_fit_error_mm"] == max(st.fit_error for st in new.strokes)
        assert new.meta["control_points"] == sum(len(st.spline.control) for st in new.strokes)
        law = travel_time_by_law(new.travels, new.machine)
        assert new.meta["travel_time_by_law"] == pytest.approx(law, rel=1e-12)
        if op == "move" and i == by_fit:  # the stroke of the largest fit error, edited: the next largest
            assert new.meta["max_fit_error_mm"] == second


def test_after_the_background_checks_an_edit_checks_only_its_own_strokes():
    _, session = client()
    session.load("art.svg", generated_svg(150, "curves").encode(), background=False)
    job = session.job
    end = time.monotonic() + 60
    while not (session._worst_of is not None and session._worst_of[0] is job) and time.monotonic() < end:
        time.sleep(0.05)  # the background checks, then the job's largest figures by them
    k = len(job.strokes) // 2
    asked = []

    class Checks(dict):  # every look-up of a stroke's checks
        def get(self, key, default=None):
            asked.append(key)
            return super().get(key, default)

    session._checks = Checks(session._checks)
    control = np.array(job.strokes[k].spline.control)
    control[1] += 0.2
    session.edit("move", k, control=control.tolist())
    assert asked and set(asked) <= {id(job.strokes[k]), id(session.job.strokes[k])}


def test_thin_paths_keep_ends_corners_and_shape():
    t = np.linspace(0, 2 * np.pi, 2000)
    paths = [np.c_[0.3 * np.cos(t), 0.3 * np.sin(t)] + 5,  # a tight circle, densely flattened
             np.c_[np.linspace(0, 40, 500), np.zeros(500)],  # a straight line of many points
             np.c_[np.linspace(0, 10, 9), [0, 3, 0, 3, 0, 3, 0, 3, 0]],  # a zig-zag: every corner stays
             np.c_[np.linspace(0, 60, 3000), 4 * np.sin(np.linspace(0, 9, 3000)) + np.sin(np.linspace(0, 40, 3000))],
             np.array([[1.0, 1.0], [1.0, 1.0]])]  # a dot
    offsets, xy = thin_paths(paths)
    assert len(offsets) == len(paths) + 1 and offsets[-1] == len(xy) < sum(map(len, paths)) / 4
    for k, p in enumerate(paths):
        q = xy[offsets[k]:offsets[k + 1]]
        assert np.array_equal(q[0], p[0]) and np.array_equal(q[-1], p[-1])
        assert all((p == row).all(axis=1).any() for row in q)  # only the path's own points
        a, b = q[:-1], q[1:]
        ab = b - a
        L = np.maximum((ab ** 2).sum(1), 1e-30)
        u = np.clip(((p[:, None] - a[None]) * ab[None]).sum(2) / L[None], 0, 1)
        far = np.hypot(*(a[None] + u[..., None] * ab[None] - p[:, None]).transpose(2, 0, 1)).min(1)
        assert far.max() < 0.05, (k, far.max())
    assert offsets[2] - offsets[1] <= 42 and offsets[3] - offsets[2] == 9  # the line: a point a mm; the zig-zag: all
