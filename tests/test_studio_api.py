"""doodlecam studio's JSON API through FastAPI's TestClient (docs/studio.md).

What the machine would execute is checked from the job's own velocity samples
and posts, independently of the studio's code: ramps integrated as the PLC
does, accelerations against the limits, the G-code compared with ``doodlecam
convert``'s and with a fresh plan of the saved job.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from doodlecam.cli import main as cli_main
from doodlecam.machine import load_machine
from doodlecam.model import Spline
from doodlecam.pipeline import Settings
from doodlecam.studio.app import StudioConfig, create_app
from doodlecam.studio.session import Session

UPLOAD = {"content-type": "application/octet-stream"}  # how the page uploads a file (form and text bodies are refused)

ROOT = Path(__file__).resolve().parents[1]
PICTURE = ROOT / "samples" / "images" / "coins.png"


def make_client(tmp_path: Path, **cfg) -> TestClient:
    session = Session(Settings(machine=load_machine("doodlebot")), max_upload=cfg.pop("max_upload", 20 << 20))
    folder = tmp_path / "work"
    folder.mkdir(exist_ok=True)
    app = create_app(session, StudioConfig(token="secret-token", folders=(folder,), **cfg))
    return TestClient(app, headers={"x-doodlecam-token": "secret-token"}, base_url="http://127.0.0.1")


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    """A client with the coins traced and planned (shared: loading costs a few seconds)."""
    c = make_client(tmp_path_factory.mktemp("studio"))
    r = c.post("/api/load?name=coins.png", content=PICTURE.read_bytes(), headers=UPLOAD)
    assert r.status_code == 200, r.text
    return c


def one_line(r) -> str:
    msg = r.json()["error"]
    assert "\n" not in msg and "Traceback" not in msg and len(msg) < 300
    return msg


def test_load_traces_plans_and_matches_convert(loaded, tmp_path):
    s = loaded.get("/api/state").json()["summary"]
    assert s["strokes"] > 3 and s["job_time_s"] > 0
    view = loaded.get("/api/view").json()
    assert len(view["strokes"]) == s["strokes"] and len(view["travels"]) == s["strokes"] + 1
    m = view["machine"]
    for st in view["strokes"]:  # what the PLC executes stays on the paper
        p = np.array(st["points"])
        assert (p >= -1e-6).all() and (p[:, 0] <= m["width"] + 1e-6).all() and (p[:, 1] <= m["height"] + 1e-6).all()
    # the studio's G-code is byte for byte what `doodlecam convert` writes for the same file
    r = loaded.get("/api/export/gcode")
    assert r.status_code == 200 and 'filename="coins.gcode"' in r.headers["content-disposition"]
    assert cli_main([ "convert", str(PICTURE), "-o", str(tmp_path), "--post", "gcode"]) == 0
    assert r.content == (tmp_path / "coins.gcode").read_bytes()


def test_bad_uploads_say_one_line_and_write_nothing(tmp_path):
    c = make_client(tmp_path, max_upload=50_000)
    before = set(os.listdir(tmp_path / "work")), set(os.listdir("/tmp"))
    for name, data, words in [("notes.txt", b"hello", "no tracer reads"), ("empty.png", b"", "empty"),
                              ("broken.png", b"\x89PNG not really", "broken.png"),
                              ("camera.png", (ROOT / "samples/images/camera.png").read_bytes(), "limit"),
                              ("", b"x", "no file name"), ("..", b"x", "no file name")]:
        r = c.post(f"/api/load?name={name}", content=data, headers=UPLOAD)
        assert r.status_code == 400, (name, r.text)
        assert words in one_line(r) and "doodlecam-studio-" not in one_line(r)  # names the upload, not a temporary copy
    assert c.get("/api/state").json()["loaded"] is False
    assert (set(os.listdir(tmp_path / "work")), set(os.listdir("/tmp"))) == before
    assert "open a picture" in one_line(c.get("/api/view"))


def test_tracer_panel_options_and_retrace(tmp_path):
    c = make_client(tmp_path)
    tracers = {t["name"]: t for t in c.get("/api/tracers").json()}
    assert {"edges", "contours", "hatch", "vector", "stipple", "tsp", "flow"} <= set(tracers)
    sigma = next(o for o in tracers["edges"]["options"] if o["name"] == "sigma")
    assert sigma["type"] == "float" and sigma["default"] == 2.0 and sigma["help"]
    n0 = c.post("/api/load?name=coins.png", content=PICTURE.read_bytes(), headers=UPLOAD).json()["strokes"]
    r = c.post("/api/trace", json={"tracer": "edges", "options": {"sigma": 6.0, "min_length": 40}})
    assert r.status_code == 200 and r.json()["strokes"] != n0
    assert r.json()["tracer_options"] == {"sigma": 6.0, "min_length": 40}
    bad = c.post("/api/trace", json={"tracer": "edges", "options": {"sigma": "wide"}})
    assert bad.status_code == 400 and "sigma" in one_line(bad)
    assert "no option" in one_line(c.post("/api/trace", json={"tracer": "edges", "options": {"nope": 1}}))
    assert c.get("/api/state").json()["summary"]["strokes"] == r.json()["strokes"]  # a failed re-trace keeps the job


def executed(view_stroke) -> np.ndarray:
    return np.array(view_stroke["points"])


def test_move_control_point_replans_only_that_stroke(loaded, tmp_path):
    view = loaded.get("/api/view").json()
    k = max(range(len(view["strokes"])), key=lambda i: len(view["strokes"][i]["control"]))
    st = view["strokes"][k]
    control = np.array(st["control"])
    j = len(control) // 2
    control[j] += [4.0, -3.0]
    t0 = loaded.get("/api/state").json()["summary"]["job_time_s"]
    r = edit(loaded, {"op": "move", "stroke": k, "control": control.tolist()})
    assert r.status_code == 200, r.text
    assert r.json()["can_undo"] and r.json()["job_time_s"] != t0
    new = loaded.get("/api/view").json()
    assert np.allclose(new["strokes"][k]["control"], control, atol=1e-4)
    for i, (a, b) in enumerate(zip(view["strokes"], new["strokes"])):
        if i != k:
            assert a == b  # untouched strokes keep their plans
    # the machine's executed path, integrated independently: on the new curve, within its limits
    m = load_machine("doodlebot")
    f = loaded.get(f"/api/stroke/{k}").json()
    vx, vy = np.array(f["plots"]["vx"]), np.array(f["plots"]["vy"])
    dt = m.delta_time
    pos = executed(new["strokes"][k])
    steps = np.cumsum(0.5 * dt * np.c_[vx[1:] + vx[:-1], vy[1:] + vy[:-1]], axis=0)
    assert np.allclose(pos[1:], pos[0] + steps, atol=1e-3)
    spline = Spline(3, control)
    assert np.linalg.norm(pos[-1] - spline.end) < 1 / m.x.steps_per_mm  # ends on the moved curve's end
    dense = spline(np.linspace(0, 1, 20001))
    dist = np.min(np.linalg.norm(pos[:, None, :] - dense[None, ::4, :], axis=2), axis=1)
    assert dist.max() < m.path_tolerance + 0.05
    acc = np.abs(np.diff(np.c_[vx, vy], axis=0)) / dt
    assert (acc[:, 0] <= m.x.max_acceleration * (1 + 1e-6)).all() and (acc[:, 1] <= m.y.max_acceleration * (1 + 1e-6)).all()
    assert np.abs(vx).max() <= m.x.max_velocity * (1 + 1e-6) and np.abs(vy).max() <= m.y.max_velocity * (1 + 1e-6)
    assert f["max_between_samples_mm"] <= m.path_tolerance + 1e-3

    # the saved job, planned afresh without tracing, posts the same G-code as the edited session,
    # and the job's figures (kept up to date edit by edit) are those of the fresh plan
    saved = loaded.get("/api/job")
    assert saved.json()["format"] == "doodlecam-studio-job" and saved.json()["version"] == 1
    other = make_client(tmp_path)
    assert other.post("/api/job?name=coins.job.json", content=saved.content, headers=UPLOAD).status_code == 200
    assert other.get("/api/export/gcode").content == loaded.get("/api/export/gcode").content
    mine, fresh = (json.loads(c.get("/api/export/json").content)["meta"] for c in (loaded, other))
    for key in ("control_points", "worst_acceleration_ratio", "worst_velocity_ratio", "max_between_samples_mm",
                "max_fit_error_mm", "travel_time_by_law"):
        # the deviation between samples is a measurement of re-planned strokes whose jerk bound depends on
        # the strokes planned with them (issue 14's whole-bound lowering): equal to a micrometre
        tol = 1e-3 if key == "max_between_samples_mm" else 1e-12
        assert mine[key] == pytest.approx(fresh[key], rel=1e-9, abs=tol), key

    # undo restores the plan exactly; redo the edit
    assert loaded.post("/api/undo", json={}).json()["job_time_s"] == t0
    assert loaded.get("/api/view").json()["strokes"] == view["strokes"]
    assert loaded.post("/api/redo", json={}).json()["job_time_s"] == r.json()["job_time_s"]
    loaded.post("/api/undo", json={})
    assert "nothing to undo" in one_line(loaded.post("/api/undo", json={}))


def test_edit_with_a_patch_reply_equals_the_whole_view(loaded):
    """The page's re-plan after a drag asks for reply=patch: the changed stroke, travels, summary and
    figures in one answer, equal to what /api/view and /api/stroke answer afterwards."""
    view = loaded.get("/api/view").json()
    # a stroke near the middle with room to split (a traced line's pieces between corners can be short)
    k = min((i for i, s in enumerate(view["strokes"]) if len(s["control"]) >= 7),
            key=lambda i: abs(i - len(view["strokes"]) // 2))
    control = np.array(view["strokes"][k]["control"])
    control[len(control) // 2] += [0.5, 0.25]
    r = edit(loaded, {"op": "move", "stroke": k, "control": control.tolist(), "reply": "patch"})
    assert r.status_code == 200, r.text
    p = r.json()
    new = loaded.get("/api/view").json()
    assert [s["i"] for s in p["strokes"]] == [k] and p["strokes"][0] == new["strokes"][k]
    assert p["strokes"][0] != view["strokes"][k]
    travels = [list(t) for t in view["travels"]]
    for i, row in p["travels"]:  # only the travels into and out of the stroke, applied as the page does
        travels[i] = row
    assert [i for i, _ in p["travels"]] == [k, k + 1]
    assert travels == new["travels"] and p["summary"] == new["summary"]
    assert p["figures"] == loaded.get(f"/api/stroke/{k}").json()
    # an edit that changes the number of strokes answers the summary: the page fetches the whole view
    r = edit(loaded, {"op": "split", "stroke": k, "point": len(control) // 2, "reply": "patch"})
    assert r.status_code == 200 and "strokes" in r.json() and isinstance(r.json()["strokes"], int)
    for _ in range(2):
        loaded.post("/api/undo", json={})
    after = loaded.get("/api/view").json()
    assert after["summary"].pop("version") > view["summary"].pop("version")  # undone: the same job, a new version
    assert after == view


def test_structure_edits_and_their_errors(loaded):
    s0 = loaded.get("/api/state").json()["summary"]
    view = loaded.get("/api/view").json()
    k = max(range(len(view["strokes"])), key=lambda i: len(view["strokes"][i]["control"]))
    ctrl = view["strokes"][k]["control"]
    s = edit(loaded, {"op": "insert", "stroke": k, "point": 0}).json()
    assert s["control_points"] == s0["control_points"] + 1
    s = edit(loaded, {"op": "delete_point", "stroke": k, "point": 1}).json()
    assert s["control_points"] == s0["control_points"]
    s = edit(loaded, {"op": "reverse", "stroke": k}).json()
    assert loaded.get("/api/view").json()["strokes"][k]["control"][0] == ctrl[-1]
    s = edit(loaded, {"op": "split", "stroke": k, "point": len(ctrl) // 2}).json()
    assert s["strokes"] == s0["strokes"] + 1 and s["control_points"] == s0["control_points"] + 1
    s = edit(loaded, {"op": "reorder", "stroke": 0, "to": 2}).json()
    assert s["strokes"] == s0["strokes"] + 1
    s = edit(loaded, {"op": "delete", "stroke": 0}).json()
    assert s["strokes"] == s0["strokes"]
    for body, words in [({"op": "move", "stroke": k}, "control"), ({"op": "reverse", "stroke": 10_000}, "does not exist"),
                        ({"op": "fly", "stroke": 0}, "unknown edit"), ({"op": "move", "stroke": 0, "control": [[0, 0]]}, "at least"),
                        ({"op": "reverse", "stroke": 0, "colour": 1}, "unknown edit field"),
                        ({"op": "move", "stroke": 0, "control": [[0, 0], [1, 1], [2, "x"], [3, 3]]}, "mm")]:
        r = edit(loaded, body)
        assert r.status_code == 400 and words in one_line(r), (body, r.text)
    # a stroke dragged off the paper: the planner's one line, and the job stays as it was
    before = loaded.get("/api/view").json()
    far = np.array(before["strokes"][0]["control"])
    far[len(far) // 2] = [5000.0, 5000.0]
    r = edit(loaded, {"op": "move", "stroke": 0, "control": far.tolist()})
    assert r.status_code == 400 and "outside the 400 x 300 mm work area" in one_line(r)
    assert loaded.get("/api/view").json() == before
    while loaded.get("/api/state").json()["summary"]["can_undo"]:
        loaded.post("/api/undo", json={})
    same = lambda s: {k: v for k, v in s.items() if k != "version"}  # noqa: E731 (every change is a new version)
    assert same(loaded.get("/api/state").json()["summary"]) == same({**s0, "can_redo": True})


def test_paths_stay_inside_the_chosen_folders(loaded, tmp_path):
    folder = Path(loaded.app.state.config.folders[0])
    r = loaded.post("/api/export", json={"posts": ["gcode", "svg"], "folder": "out"})
    assert r.status_code == 200, r.text
    assert sorted(Path(p).name for p in r.json()["written"]) == ["coins.gcode", "coins.svg"]
    assert (folder / "out" / "coins.gcode").read_bytes() == loaded.get("/api/export/gcode").content
    outside = tmp_path / "outside"
    outside.mkdir()
    (folder / "link").symlink_to(outside)
    for where in ["../escape", str(outside), "link/x", "/etc"]:
        r = loaded.post("/api/export", json={"posts": ["gcode"], "folder": where})
        assert r.status_code == 400 and "outside the folders" in one_line(r), where
        r = loaded.post("/api/open", json={"path": where + "/coins.png"})
        assert r.status_code == 400 and "outside the folders" in one_line(r), where
    assert not list(outside.iterdir()) and not (tmp_path / "escape").exists()
    # a file opened from the folder is never overwritten by an export
    vector = folder / "badge.svg"
    vector.write_bytes((ROOT / "samples/vectors/badge.svg").read_bytes())
    assert loaded.post("/api/open", json={"path": "badge.svg"}).status_code == 200
    r = loaded.post("/api/export", json={"posts": ["svg"], "folder": "."})
    assert r.status_code == 400 and "opened from" in one_line(r)
    assert vector.read_bytes() == (ROOT / "samples/vectors/badge.svg").read_bytes()
    assert loaded.post("/api/load?name=coins.png", content=PICTURE.read_bytes(), headers=UPLOAD).status_code == 200
    r = loaded.get("/api/export/nope")
    assert r.status_code == 400 and "nope" in one_line(r)


def test_refit_turns_a_traced_stroke_into_few_handles_within_the_tolerance(loaded):
    from scipy.spatial import cKDTree

    from doodlecam.model import Spline

    view = loaded.get("/api/view").json()
    k = max(range(len(view["strokes"])), key=lambda i: len(view["strokes"][i]["control"]))
    before = view["strokes"][k]
    r = edit(loaded, {"op": "refit", "stroke": k, "tolerance": 0.3})
    assert r.status_code == 200, r.text
    after = loaded.get("/api/view").json()["strokes"][k]
    assert len(after["control"]) < len(before["control"]) / 2
    u = np.linspace(0, 1, 20000)
    old, new = (Spline(s["degree"], np.asarray(s["control"], float))(u) for s in (before, after))
    assert cKDTree(new).query(old)[0].max() <= 0.3 + 1e-6 and cKDTree(old).query(new)[0].max() <= 0.3 + 1e-6
    for bad in (0, -1, "x", 100, None):
        r = edit(loaded, {"op": "refit", "stroke": k, "tolerance": bad})
        assert r.status_code == 400 and "tolerance" in one_line(r)
    loaded.post("/api/undo", json={})
    assert loaded.get("/api/view").json()["strokes"][k] == before


def test_stale_edits_are_refused(loaded):
    """Tab A shows the job at some version; tab B opens another file or edits: A's edit is refused, not applied."""
    a = loaded.get("/api/state").json()["summary"]
    stroke0 = loaded.get("/api/view").json()["strokes"][0]["control"]
    r = loaded.post("/api/edit", json={"op": "reverse", "stroke": 0})
    assert r.status_code == 400 and "job and version" in one_line(r)
    assert edit(loaded, {"op": "reverse", "stroke": 0}).status_code == 200  # tab B edits
    for body in ({"op": "delete", "stroke": 0}, {"op": "move", "stroke": 0, "control": stroke0, "reply": "patch"}):
        r = loaded.post("/api/edit", json={**body, "job": a["job"], "version": a["version"]})  # tab A, one version behind
        assert r.status_code == 409 and r.json()["stale"] and one_line(r) == "the job changed in another tab; reload"
    r = loaded.post("/api/undo", json={"job": a["job"], "version": a["version"]})
    assert r.status_code == 409 and "another tab" in one_line(r)
    b = loaded.get("/api/state").json()["summary"]
    assert b["strokes"] == a["strokes"] and b["version"] == a["version"] + 1 and b["can_undo"]
    # another file opened in tab B: the old job's id is refused whatever its version
    assert loaded.post("/api/load?name=coins.png", content=PICTURE.read_bytes(), headers=UPLOAD).status_code == 200
    c = loaded.get("/api/state").json()["summary"]
    assert c["job"] != b["job"]
    r = loaded.post("/api/edit", json={"op": "delete", "stroke": 0, "job": b["job"], "version": c["version"]})
    assert r.status_code == 409
    assert loaded.get("/api/state").json()["summary"]["strokes"] == c["strokes"]


def test_costly_or_broken_jobs_are_refused_at_once_while_the_view_answers(loaded):
    """A 6 KB job of degree 500 once held the session for minutes: every saved job is checked before any work."""
    import json
    import threading

    saved = json.loads(loaded.get("/api/job").content)
    line = [[10.0 + i, 20.0 + (i % 2)] for i in range(501)]
    bad = {"degree 500": [{"degree": 500, "control": line}], "degree 2.5": [{"degree": 2.5, "control": line[:4]}],
           "NaN": [{"degree": 3, "control": [[0, 0], [1, "NaN"], [2, 0], [3, 0]]}],
           "infinite": [{"degree": 3, "control": [[0, 0], [1, 1e999], [2, 0], [3, 0]]}],
           "far outside": [{"degree": 3, "control": [[0, 0], [1e6, 0], [2, 0], [3, 0]]}],
           "huge": [{"degree": 3, "control": [[1.0, 1.0]] * 200_001}],
           "not pairs": [{"degree": 3, "control": [[0, 0, 0]] * 4}]}
    answers = []
    view = threading.Thread(target=lambda: answers.extend(loaded.get("/api/state").status_code for _ in range(20)))
    view.start()
    for what, strokes in bad.items():
        data = json.dumps({**saved, "strokes": strokes}).encode()
        r = loaded.post("/api/job?name=bad.job.json", content=data, headers=UPLOAD)
        assert r.status_code == 400 and "malformed" in one_line(r) and "\n" not in r.json()["error"], (what, r.text)
    view.join(60)
    assert answers == [200] * 20
    assert loaded.get("/api/state").json()["summary"]["strokes"] == len(saved["strokes"])


def test_export_never_replaces_a_foreign_file_without_asking(loaded):
    folder = Path(loaded.app.state.config.folders[0])
    r = loaded.post("/api/export", json={"posts": ["gcode"]})
    assert r.status_code == 400 and "choose the folder" in one_line(r)  # no silent default folder
    (folder / "mine").mkdir()
    foreign = folder / "mine" / "coins.gcode"
    foreign.write_text("the user's own file\n")
    r = loaded.post("/api/export", json={"posts": ["gcode", "svg"], "folder": "mine"})
    assert r.status_code == 409 and r.json()["confirm"] is True and "not written by the studio" in one_line(r)
    assert foreign.read_text() == "the user's own file\n" and not (folder / "mine" / "coins.svg").exists()
    r = loaded.post("/api/export", json={"posts": ["gcode", "svg"], "folder": "mine", "overwrite": True})
    assert r.status_code == 200 and foreign.read_bytes() == loaded.get("/api/export/gcode").content
    # what the studio wrote itself it may write again without asking
    assert loaded.post("/api/export", json={"posts": ["gcode"], "folder": "mine"}).status_code == 200


def test_saved_job_errors(loaded):
    for data, words in [(b"{not json", "not a JSON"), (b"[1]", "not a doodlecam studio job"),
                        (json.dumps({"format": "doodlecam-studio-job", "version": 99}).encode(), "version 99"),
                        (json.dumps({"format": "doodlecam-studio-job", "version": 1, "machine": "fivebar",
                                     "strokes": []}).encode(), "--machine fivebar"),
                        (json.dumps({"format": "doodlecam-studio-job", "version": 1, "machine": "doodlebot",
                                     "strokes": [{"degree": 3, "control": [[0, 0]]}]}).encode(), "malformed")]:
        r = loaded.post("/api/job?name=bad.json", content=data, headers=UPLOAD)
        assert r.status_code == 400 and words in one_line(r), (data, r.text)
    assert loaded.get("/api/state").json()["loaded"]


def edit(c: TestClient, body: dict):
    """An edit as the page makes it: on the job and version the page shows."""
    s = c.get("/api/state").json()["summary"]
    return c.post("/api/edit", json={**body, "job": s["job"], "version": s["version"]})


def studio_routes(app) -> list[tuple[str, str]]:
    """Every (method, path) of the app's /api routes, read from the app itself: a new route cannot skip the checks."""
    out = []
    for r in app.routes:
        if getattr(r, "path", "").startswith("/api/"):
            path = r.path.replace("{i}", "0").replace("{post}", "gcode")
            out += [(m, path) for m in sorted(getattr(r, "methods", ()) or ()) if m != "HEAD"]
    return out


def test_every_api_route_needs_the_token(tmp_path):
    c = make_client(tmp_path)
    routes = studio_routes(c.app)
    assert len(routes) >= 20 and ("GET", "/api/state") in routes and ("POST", "/api/export") in routes
    bare = TestClient(c.app, base_url="http://127.0.0.1")
    for method, path in routes:
        for token in ({}, {"x-doodlecam-token": "wrong"}):
            r = bare.request(method, path, json={}, headers=token)
            assert r.status_code == 403 and "token" in one_line(r), (method, path, r.text)
    assert bare.get("/api/state?token=wrong").status_code == 403
    assert bare.get("/api/state?token=secret-token").status_code == 200  # downloads and the event stream
    assert bare.post("/api/send/stop?token=secret-token", json={}).status_code == 403  # a POST carries it in a header
    assert bare.get("/").status_code == 200  # the page itself carries no data


def test_foreign_hosts_and_origins_are_refused(tmp_path):
    """DNS rebinding (a foreign Host) and cross-site pages (a foreign Origin, Sec-Fetch-Site) get nothing,
    even with the token; the studio's own names are served."""
    c = make_client(tmp_path)
    for method, path in studio_routes(c.app) + [("GET", "/"), ("GET", "/static/app.js")]:
        r = c.request(method, path.replace("/api/", "/api/"), json={}, headers={"host": "evil.example"})
        assert r.status_code == 403 and "own address" in one_line(r), (method, path, r.text)
    for host in ("127.0.0.1:8765", "localhost:8765", "[::1]:8765", "LOCALHOST"):
        assert c.get("/api/state", headers={"host": host}).status_code == 200, host
    assert c.get("/api/state", headers={"host": "127.0.0.1.evil.example"}).status_code == 403
    for origin in ("http://evil.example", "null", "http://127.0.0.1:9999", "https://127.0.0.1"):
        r = c.post("/api/export", json={"posts": ["gcode"], "folder": "."}, headers={"origin": origin})
        assert r.status_code == 403 and "cross-origin" in one_line(r), origin
    assert c.get("/api/state", headers={"origin": "http://127.0.0.1"}).status_code == 200  # same origin
    r = c.get("/api/state", headers={"sec-fetch-site": "cross-site"})
    assert r.status_code == 403 and "cross-site" in one_line(r)
    assert c.get("/api/state", headers={"sec-fetch-site": "same-origin"}).status_code == 200
    extra = make_client(tmp_path, hosts=("studio.lan",))  # --host: the bound name is served too
    assert extra.get("/api/state", headers={"host": "studio.lan:8765"}).status_code == 200


def test_simple_cross_site_bodies_are_refused(loaded, tmp_path):
    """A web page can POST text/plain, a form or multipart without a preflight: such bodies never reach the job
    or the disk, even with the token (a leaked token in a page's script cannot write files either)."""
    before = loaded.get("/api/state").json()["summary"]
    for kind in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x", None):
        headers = {"content-type": kind} if kind else {}
        for path, data in (("/api/load?name=x.svg", b"<svg/>"), ("/api/export", b'{"posts":["gcode"],"folder":"."}'),
                           ("/api/edit", b'{"op":"delete","stroke":0}')):
            r = loaded.post(path, content=data, headers=headers)
            assert r.status_code in (400, 403) and ("JSON" in one_line(r) or "file upload" in one_line(r)), (kind, path)
    r = loaded.post("/api/export", content=b'{"posts":["gcode"],"folder":"."}', headers=UPLOAD)  # JSON routes want JSON
    assert r.status_code == 400 and "JSON" in one_line(r)
    assert loaded.get("/api/state").json()["summary"] == before
    assert not list(tmp_path.rglob("*.gcode"))


def test_server_survives_a_failing_request(loaded, monkeypatch):
    def boom():
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(loaded.app.state.session, "timeline", boom)
    r = loaded.get("/api/timeline")
    assert r.status_code == 500 and one_line(r) == "internal error: RuntimeError: disk on fire"
    assert loaded.get("/api/state").status_code == 200


def wait_state(c: TestClient, until, timeout: float = 60.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        s = c.get("/api/send").json()
        if until(s):
            return s
        time.sleep(0.05)
    raise AssertionError(f"send state never reached: {s}")


def test_send_to_simulator_completes_even_when_the_page_goes(loaded):
    sender = loaded.app.state.sender
    r = loaded.post("/api/send", json={"target": "simulator", "speed": 20})
    assert r.status_code == 200 and r.json()["state"] == "sending"
    # a page follows the events, then is closed mid-send: the send goes on
    with loaded.stream("GET", "/api/send/events") as ev:
        first = json.loads(next(ev.iter_lines()).removeprefix("data: "))
        assert first["state"] == "sending" and first["total"] > 0
    assert loaded.get("/api/send").json()["state"] == "sending"
    s = wait_state(loaded, lambda s: s["state"] != "sending")
    assert s["state"] == "done" and s["executed"] == s["total"] and s["percent"] == 100.0, s
    # the simulated PLC executed every command and ended with the pen up
    assert not sender._sim.pen


def test_stop_ends_at_a_stroke_boundary_with_the_pen_up_and_resumes(loaded):
    sender = loaded.app.state.sender
    # the job was drawn to its end by the test before: the PLC refuses it unless asked to draw it again
    assert loaded.post("/api/send", json={"target": "simulator", "speed": 20}).status_code == 200
    s = wait_state(loaded, lambda s: s["state"] != "sending")
    assert s["state"] == "failed" and "again" in s["message"], s
    assert loaded.post("/api/send", json={"target": "simulator", "speed": 20, "again": True}).status_code == 200
    assert "a send is running" in one_line(loaded.post("/api/send", json={"target": "simulator"}))
    wait_state(loaded, lambda s: s["executed"] > 5)
    assert loaded.post("/api/send/stop", json={}).status_code == 200
    s = wait_state(loaded, lambda s: s["state"] != "sending")
    assert s["state"] == "stopped" and "pen up" in s["message"], s
    assert 0 < s["executed"] < s["total"]
    # the PLC holds the job at rest with the pen lifted (the simulator's own state)
    assert not sender._sim.pen and not np.any(sender._sim.vel)
    held = s["executed"]
    records = sender._sender.records
    # sending the same job again resumes after the last executed command
    assert loaded.post("/api/send", json={"target": "simulator", "speed": 20}).status_code == 200
    s = wait_state(loaded, lambda s: s["state"] != "sending")
    assert s["state"] == "done" and f"resumed at command {held + 1}" in s["message"], s["message"]
    ran = [c for job, c in sender._sim.executed_log if job == sender._sender.job_id]
    assert sorted(ran) == list(range(1, len(records) + 1))  # every command once, none repeated
    assert "no send is running" in one_line(loaded.post("/api/send/stop", json={}))
    assert "HOST:PORT" in one_line(loaded.post("/api/send", json={"target": "plc-without-port:x"}))


def test_one_send_at_a_time_and_a_resume_belongs_to_its_target(tmp_path):
    """Two Sends at once (a double-click, two tabs): exactly one starts. A job stopped on one PLC, then sent to
    another, starts there at command 1 (its lines were never drawn there), and the first PLC still resumes it."""
    import threading

    from doodlecam.link.plc.simulator import PlcConfig, PlcSimulator

    c = make_client(tmp_path)
    assert c.post("/api/load?name=coins.png", content=PICTURE.read_bytes(), headers=UPLOAD).status_code == 200
    sender = c.app.state.sender
    for _ in range(3):
        clients = [TestClient(c.app, base_url="http://127.0.0.1", headers={"x-doodlecam-token": "secret-token"})
                   for _ in range(2)]
        go, codes = threading.Barrier(2), []

        def send(client):
            go.wait()
            codes.append(client.post("/api/send", json={"target": "simulator", "speed": 20, "again": True}).status_code)

        threads = [threading.Thread(target=send, args=(cl,)) for cl in clients]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert sorted(codes) == [200, 400], codes
        wait_state(c, lambda s: s["executed"] > 5)
        assert c.post("/api/send/stop", json={}).status_code == 200
        s = wait_state(c, lambda s: s["state"] not in ("sending", "stopping"))
        assert s["state"] == "stopped", s
    from doodlecam.link.plc.keys import profile_key

    machine = c.app.state.session.machine  # a real PLC, paired with the machine's key (the studio sends with it)
    other = PlcSimulator(PlcConfig.from_machine(machine, speed=math.inf, key=profile_key(machine)[0])).start()
    try:
        host, port = other.address
        assert c.post("/api/send", json={"target": f"{host}:{port}"}).status_code == 200
        s = wait_state(c, lambda s: s["state"] not in ("sending", "stopping"))
        assert s["state"] == "done" and "resumed" not in s["message"], s
        job = sender._sender.job_id
        assert sorted(k for j, k in other.executed_log if j == job) == list(range(1, s["total"] + 1))
    finally:
        other.stop()
    # back on the first PLC the stopped job resumes where it stopped, or is abandoned with the page's button
    s = wait_state(c, lambda s: True)
    r = c.post("/api/send/abandon", json={"target": "simulator"})
    assert r.status_code == 200 and "abandoned" in r.json()["message"], r.text
    assert c.post("/api/send", json={"target": "simulator", "speed": 20}).status_code == 200
    s = wait_state(c, lambda s: s["state"] not in ("sending", "stopping"))
    assert s["state"] == "done" and "resumed" not in s["message"], s


def test_motion_design_routes(tmp_path):
    import shutil

    from doodlecam.motion.design import load_design, solve_design
    from doodlecam.motion.export import read_table

    c = make_client(tmp_path)
    folder = Path(c.app.state.config.folders[0])
    shutil.copy(ROOT / "samples/motion/slider.toml", folder / "slider.toml")
    (folder / "notes.toml").write_text("[other]\nx = 1\n")
    assert c.get("/api/motion/designs").json() == ["slider.toml"]
    r = c.post("/api/motion/open", json={"path": "slider.toml"})
    assert r.status_code == 200, r.text
    doc, res = r.json()["doc"], r.json()["result"]
    assert set(res["axes"]) == {"table32", "fixed"}
    # the thesis's Fig. 3.7: acc = -75 at the second point meanders, acc = 0 does not
    assert {f["kind"] for f in res["findings"] if "table32" in f["where"]} >= {"meander"}
    assert not [f for f in res["findings"] if "fixed" in f["where"]]
    # positions at the design points are the table's
    t = np.array(res["t"])
    for p in doc["axis"]["fixed"]["point"]:
        assert np.interp(p["t"], t, res["axes"]["fixed"][0]) == pytest.approx(p["pos"], abs=2e-3)
    doc["axis"]["table32"]["point"][1]["acc"] = 0.0  # the cure, edited as in the page
    fixed = c.post("/api/motion/solve", json={"doc": doc, "name": "slider.toml"}).json()
    assert not [f for f in fixed["findings"] if f["kind"] == "meander"]
    assert np.allclose(fixed["axes"]["table32"][0], fixed["axes"]["fixed"][0])
    csv = c.post("/api/motion/table", json={"doc": doc, "name": "slider.toml"})
    assert csv.status_code == 200 and 'filename="slider.csv"' in csv.headers["content-disposition"]
    (tmp_path / "t.csv").write_bytes(csv.content)
    header, rows = read_table(tmp_path / "t.csv")
    assert header[:2] == ["t", "table32_pos"] and len(rows) == load_design(folder / "slider.toml").samples
    tt, axes = solve_design(load_design(folder / "slider.toml")).sample()
    assert np.allclose(rows[:, header.index("fixed_pos")], axes["fixed"][0], atol=1e-6)
    for body, words in [({"doc": {"motion": {"input": "sideways"}}}, "input"), ({"doc": [1]}, "JSON object")]:
        r = c.post("/api/motion/solve", json=body)
        assert r.status_code == 400 and words in one_line(r), r.text
    assert "outside the folders" in one_line(c.post("/api/motion/open", json={"path": "../../etc/x.toml"}))


def test_motion_design_with_a_theta_axis(tmp_path):
    """samples/motion/turn.toml: X, Y in mm and Θ in degrees; the page gets each axis's unit and
    Θ's curve from the design (dwell, cycloidal quarter turn, dwell)."""
    import shutil

    c = make_client(tmp_path)
    folder = Path(c.app.state.config.folders[0])
    shutil.copy(ROOT / "samples/motion/turn.toml", folder / "turn.toml")
    r = c.post("/api/motion/open", json={"path": "turn.toml"})
    assert r.status_code == 200, r.text
    res = r.json()["result"]
    assert res["units"] == {"x": "mm", "y": "mm", "theta": "deg"}
    t, th = np.array(res["t"]), np.array(res["axes"]["theta"][0], dtype=float)
    assert np.allclose(th[t <= 0.2], 0.0, atol=1e-9) and np.allclose(th[t >= 0.8], 90.0, atol=1e-9)
    mid = (t > 0.2) & (t < 0.8)  # the cycloidal law: 90 (tau - sin(2 pi tau) / (2 pi)), tau = (t - 0.2) / 0.6
    tau = (t[mid] - 0.2) / 0.6
    assert np.allclose(th[mid], 90 * (tau - np.sin(2 * np.pi * tau) / (2 * np.pi)), atol=1e-6)
    assert [s["law"] for s in res["segments"] if s["axis"] == "theta"] == ["dwell", "cycloidal", "dwell"]


def test_the_studio_command(tmp_path):
    """`doodlecam studio` itself: bad input is one line before any server; a real server answers, then stops."""
    import signal
    import subprocess
    import sys

    import httpx2 as httpx

    def run(*args):
        return subprocess.run([sys.executable, "-m", "doodlecam", "studio", "--no-browser", *args], capture_output=True,
                              text=True, timeout=120, cwd=tmp_path)

    (tmp_path / "notes.txt").write_text("hello")
    for args, words in [(["missing.png"], "no such file"), (["notes.txt"], "no tracer reads"),
                        (["--folder", "nowhere"], "no such folder"), (["--host", "203.0.113.1"], "cannot listen")]:
        r = run(*args)
        assert r.returncode != 0 and words in r.stderr, (args, r.stderr)
        assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
    p = subprocess.Popen([sys.executable, "-m", "doodlecam", "studio", "--no-browser", "--port", "0"], cwd=tmp_path,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        assert line.startswith("doodlecam studio: http://127.0.0.1:"), line + p.stderr.read()
        url = line.split()[-1]
        token = url.split("token=")[1]
        base = url.split("/?")[0]
        assert httpx.get(base + "/api/state", timeout=10).status_code == 403  # the token, even on loopback
        assert httpx.get(base + "/api/state", headers={"x-doodlecam-token": token}, timeout=10).json()["loaded"] is False
        assert httpx.post(base + "/api/send", json={}, timeout=10).status_code == 403
        assert "access token " + token in p.stdout.readline()
        busy = run("--port", base.rsplit(":", 1)[1])
        assert busy.returncode != 0 and "cannot listen" in busy.stderr
    finally:
        p.send_signal(signal.SIGINT)
        p.wait(20)
    # beyond the loopback interface every request needs the printed token
    p = subprocess.Popen([sys.executable, "-m", "doodlecam", "studio", "--no-browser", "--port", "0", "--host", "0.0.0.0"],
                         cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = p.stdout.readline().split()[-1]
        assert "every request" in p.stdout.readline()
        base, token = url.split("/?token=")
        assert httpx.get(base + "/api/state", timeout=10).status_code == 403
        assert httpx.get(base + "/api/state", headers={"x-doodlecam-token": token}, timeout=10).status_code == 200
        p.send_signal(signal.SIGTERM)  # a service manager's stop
        p.wait(10)
    finally:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
            p.wait(20)


def test_fivebar_edits_replan(tmp_path):
    """Issue 20's known limit: on the five-bar arm an edited stroke of horse.png was refused by the
    sampler even for a 0.05 mm move (11 of 42 such edits on the studio's first version, whose sampler
    lacked #14's converging ramp re-plans); every one plans now, within the cranks' limits."""
    session = Session(Settings(machine=load_machine("fivebar")))
    folder = tmp_path / "work"
    folder.mkdir()
    c = TestClient(create_app(session, StudioConfig(token="t", folders=(folder,))), headers={"x-doodlecam-token": "t"},
                   base_url="http://127.0.0.1")
    assert c.post("/api/load?name=horse.png", content=(ROOT / "samples/images/horse.png").read_bytes(), headers=UPLOAD).status_code == 200
    view = c.get("/api/view").json()
    m = load_machine("fivebar")
    for k, st in enumerate(view["strokes"]):
        c0 = np.array(st["control"])
        for j in (0, len(c0) // 2):  # an end and the middle (both refused before), two directions
            for d in ([0.05, 0.0], [0.0, -0.05]):
                control = c0.copy()
                control[j] += d
                r = edit(c, {"op": "move", "stroke": k, "control": control.tolist(), "reply": "patch"})
                assert r.status_code == 200, (k, j, d, r.text)
                f = r.json()["figures"]
                assert f["worst_acceleration_ratio"] <= 1 + 1e-6 and f["worst_velocity_ratio"] <= 1 + 1e-6
                assert f["max_between_samples_mm"] <= m.path_tolerance + 1e-3
                assert c.post("/api/undo", json={}).status_code == 200
