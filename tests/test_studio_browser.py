"""doodlecam studio in a real headless Chromium (Debian's ``chromium``, driven by Playwright).

One page goes through a user's session: load a picture, change a tracer
option, select and drag a control point, undo, export G-code, simulate, send
to the PLC simulator. What the page shows is checked against the server's
job, and the job against ``doodlecam convert`` and the Python B-spline.
Screenshots of the main views go to docs/ (DOODLECAM_SCREENSHOTS=1).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from doodlecam.cli import main as cli_main
from doodlecam.machine import load_machine
from doodlecam.model import Spline
from doodlecam.pipeline import Settings
from doodlecam.studio.app import StudioConfig, create_app
from doodlecam.studio.session import Session

ROOT = Path(__file__).resolve().parents[1]
CAMERA = ROOT / "samples" / "images" / "camera.png"
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run"]
SHOTS = ROOT / "docs" if os.environ.get("DOODLECAM_SCREENSHOTS") else None

playwright_api = pytest.importorskip("playwright.sync_api")
if not Path(CHROMIUM).exists():
    pytest.skip("Debian's chromium is not installed (.ci/run installs it: apt-get install chromium)",
                allow_module_level=True)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(folder: Path, machine: str = "doodlebot"):
    """The studio on 127.0.0.1:<free port> in a thread, shut down at the end."""
    import uvicorn

    session = Session(Settings(machine=load_machine(machine)))
    cfg = StudioConfig(token="browser-test-token", folders=(folder,))
    app = create_app(session, cfg)
    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    end = time.monotonic() + 30
    while not srv.started:
        assert time.monotonic() < end and thread.is_alive(), "the studio server did not start"
        time.sleep(0.05)
    yield {"url": f"http://127.0.0.1:{port}/?token={cfg.token}", "app": app, "folder": folder}
    srv.should_exit = True
    thread.join(10)


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with serve(tmp_path_factory.mktemp("studio")) as srv:
        yield srv


@pytest.fixture(scope="module")
def page(server):
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        pg = browser.new_page(viewport={"width": 1400, "height": 850}, accept_downloads=True)
        errors = []
        pg.on("pageerror", lambda e: errors.append(str(e)))
        pg.goto(server["url"])
        pg.wait_for_selector("body[data-ready='1']")
        yield pg
        browser.close()
        assert not errors, errors


@contextlib.contextmanager
def second_tab(page, url: str):
    """Another tab of ``page``'s browser on ``url``, ready; closed at the end, with no page errors."""
    pg = page.context.browser.new_page(viewport={"width": 1400, "height": 850})
    errors = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.goto(url)
    pg.wait_for_selector("body[data-ready='1']")
    yield pg
    pg.close()
    assert not errors, errors


def shot(page, name: str) -> None:
    if SHOTS is not None:
        page.screenshot(path=str(SHOTS / f"studio-{name}.png"))


def summary(server) -> dict:
    return server["app"].state.session.summary()


def ink_pixels(page) -> int:
    """Canvas pixels drawn in a speed colour (saturated), counted in the page."""
    return page.evaluate("""() => {
        const c = document.getElementById('paper'), d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let i = 0; i < d.length; i += 4) {
            const mx = Math.max(d[i], d[i + 1], d[i + 2]), mn = Math.min(d[i], d[i + 1], d[i + 2]);
            if (mx - mn > 80) n++;
        }
        return n;
    }""")


def test_1_load_a_picture_and_see_its_strokes(page, server):
    page.set_input_files("#file", str(CAMERA))
    page.wait_for_selector("body[data-strokes]", timeout=60_000)
    s = summary(server)
    assert page.text_content("#stat-strokes") == str(s["strokes"]) and s["strokes"] > 50
    assert page.text_content("#stat-time") == f"{s['job_time_s']:.2f} s"
    assert ink_pixels(page) > 5000
    assert page.evaluate("studioPerf.firstView") > 0
    shot(page, "job")


def test_2_a_tracer_option_changes_the_strokes(page, server):
    before = page.text_content("#stat-strokes")
    sigma = page.locator("#tracer-options input[name=sigma]")
    assert sigma.input_value() == "2"
    sigma.fill("4")
    sigma.dispatch_event("change")
    page.wait_for_function(f"document.getElementById('stat-strokes').textContent !== '{before}'", timeout=60_000)
    s = summary(server)
    assert s["tracer_options"]["sigma"] == 4.0  # the rest stay the tracer's defaults
    assert page.text_content("#stat-strokes") == str(s["strokes"]) != before


def _select_longest(page) -> int:
    k = page.evaluate("""() => { const v = studio.view.strokes;
        return v.reduce((b, s) => s.control.length > v[b].control.length ? s.i : b, 0); }""")
    p = page.evaluate(f"studio.view.strokes[{k}].points[Math.floor(studio.view.strokes[{k}].points.length / 3)]")
    x, y = page.evaluate(f"studioScreen({p[0]}, {p[1]})")
    box = page.locator("#paper").bounding_box()
    page.mouse.move(box["x"] + x, box["y"] + y)  # hover: a tooltip with the stroke's figures
    assert page.get_attribute("#paper", "title").startswith(f"stroke {k + 1}: ")
    page.mouse.click(box["x"] + x, box["y"] + y)
    page.wait_for_function(f"document.getElementById('sel-index').textContent.startsWith('{k + 1} of')")
    page.wait_for_selector("#stroke-figures tr")
    return k


def test_3_drag_a_control_point_moves_the_curve_and_updates_the_time(page, server):
    k = _select_longest(page)
    assert page.evaluate("studio.selected") == k
    shot(page, "stroke")
    control = np.array(page.evaluate(f"studio.view.strokes[{k}].control"))
    j = len(control) // 2
    x, y = page.evaluate(f"studioScreen({control[j][0]}, {control[j][1]})")
    box = page.locator("#paper").bounding_box()
    t_before = page.get_attribute("body", "data-job-time")
    page.mouse.move(box["x"] + x, box["y"] + y)
    page.mouse.down()
    for step in range(1, 11):
        page.mouse.move(box["x"] + x + 3 * step, box["y"] + y + 2 * step)
    # mid-drag: the curve is evaluated in the page; it agrees with the Python B-spline
    dragged = np.array(page.evaluate("studio.drag.control"))
    assert np.linalg.norm(dragged[j] - control[j]) > 1.0 and np.allclose(np.delete(dragged, j, 0), np.delete(control, j, 0))
    curve = np.array(page.evaluate("Array.from(studio.curve)")).reshape(-1, 2)
    assert np.allclose(curve, Spline(3, dragged)(np.linspace(0, 1, len(curve))), atol=1e-9)
    page.mouse.up()
    page.wait_for_function(f"document.body.dataset.jobTime !== '{t_before}'", timeout=30_000)
    after = np.array(page.evaluate(f"studio.view.strokes[{k}].control"))
    assert np.allclose(after, dragged, atol=1e-3)  # the server planned the dragged curve
    s = summary(server)
    assert page.text_content("#stat-time") == f"{s['job_time_s']:.2f} s" and s["can_undo"]
    assert max(page.evaluate("studioPerf.moves")) < 1000  # it redrew on every move (the benchmark times it)
    assert page.evaluate("studio.selected") == k  # the selection stays (control points shown)
    shot(page, "edit")


def test_4_undo_restores_the_plan(page, server):
    edited = summary(server)["job_time_s"]
    page.click("#undo")
    page.wait_for_function(f"document.body.dataset.jobTime !== '{edited}'")
    s = summary(server)
    assert not s["can_undo"] and s["can_redo"]
    assert page.text_content("#stat-time") == f"{s['job_time_s']:.2f} s"


def test_4b_right_click_offers_insert_after_and_ctrl_z_undoes(page, server):
    k = page.evaluate("studio.selected")
    assert k >= 0
    n = len(page.evaluate(f"studio.view.strokes[{k}].control"))
    c = page.evaluate(f"studio.view.strokes[{k}].control[3]")
    x, y = page.evaluate(f"studioScreen({c[0]}, {c[1]})")
    box = page.locator("#paper").bounding_box()
    page.mouse.click(box["x"] + x, box["y"] + y, button="right")  # the point's menu: insert after / delete
    page.click("#point-menu [data-point-op=insert]")
    page.wait_for_function(f"studio.view.strokes[{k}].control.length === {n + 1}")
    assert summary(server)["can_undo"]
    page.keyboard.press("Control+z")
    page.wait_for_function(f"studio.view.strokes[{k}].control.length === {n}")
    assert not summary(server)["can_undo"]


def test_5_export_gcode_equals_convert(page, server, tmp_path):
    page.select_option("#post", "gcode")
    with page.expect_download() as dl:
        page.click("#download")
    data = Path(dl.value.path()).read_bytes()
    assert dl.value.suggested_filename == "camera.gcode"
    assert cli_main(["convert", str(CAMERA), "-o", str(tmp_path), "--post", "gcode", "--tracer", "edges",
                     "--tracer-opt", "sigma=4"]) == 0
    assert data == (tmp_path / "camera.gcode").read_bytes()
    # redo the last edit (4b's inserted point): the G-code of the edited job equals a fresh plan of
    # the saved job (no re-tracing)
    page.click("#redo")
    page.wait_for_function("document.getElementById('undo').disabled === false")
    with page.expect_download() as dl:
        page.click("#download")
    edited = Path(dl.value.path()).read_bytes()
    with page.expect_download() as job:
        page.click("#save")
    fresh = Session(Settings(machine=load_machine("doodlebot")))
    fresh.open_job(Path(job.value.path()).read_bytes())
    assert edited != data and edited == fresh.export("gcode")[1]


def test_6_simulate(page, server):
    page.select_option("#sim-speed", "10")
    page.click("#play")
    page.wait_for_function("studioPerf.frames.length > 30", timeout=30_000)
    page.click("#play")  # pause
    t = page.evaluate("studio.sim.t")
    assert 0 < t < page.evaluate("studio.timeline.duration")
    assert "left" in page.text_content("#sim-time")
    shot(page, "simulate")
    page.locator("#scrub").fill("500")
    page.locator("#scrub").dispatch_event("input")
    assert abs(page.evaluate("studio.sim.t / studio.timeline.duration") - 0.5) < 1e-3


def test_7_send_to_the_plc_simulator(page, server):
    page.select_option("#target", "simulator")
    page.click("#send")
    page.wait_for_selector("#send-status[data-state=done]", timeout=60_000)
    assert page.evaluate("document.getElementById('send-progress').value") == 100
    assert page.text_content("#send-status").startswith(f"done: {summary_commands(server)} commands in ")
    shot(page, "send")


def test_7b_send_to_the_grbl_emulator_pause_resume_stop(page, server):
    """The edited job to the built-in GRBL emulator over a real pseudo-terminal: the machine panel,
    pause (pen lifted) and resume, completion with every line acknowledged once; a stop leaves the pen up."""
    from grbl_received import check_received  # tests/ is on sys.path

    from doodlecam.link.grbl.protocol import prepare

    sender = server["app"].state.sender
    lines = prepare(server["app"].state.session.export("gcode")[1].decode())  # the edited job
    page.select_option("#target", "grbl-simulator")
    assert page.is_visible("#machine-panel") and not page.is_visible("#ebb-panel")
    page.click("[data-machine=status]")
    page.wait_for_selector("#machine-status[data-state=Idle]")
    emu = sender._grbl.emulator
    n0 = len(emu.received)
    page.select_option("#send-speed", "10")
    page.click("#send")
    page.wait_for_function("() => /^sending: line \\d+ \\(\\d+ of \\d+ answered\\), [\\d.]+ %, [\\d.]+ s left at \\(/"
                           ".test(document.getElementById('send-status').textContent)", timeout=30_000)
    page.click("#pause")
    page.wait_for_selector("#send-status[data-state=paused]", timeout=30_000)
    assert emu.state == "Idle" and emu.modal["s"] == 0  # at rest, pen up (M3 S0)
    assert page.is_visible("#resume") and not page.is_visible("#pause")
    shot(page, "send-grbl")
    page.click("#resume")
    page.wait_for_selector("#send-status[data-state=done]", timeout=120_000)
    assert page.evaluate("document.getElementById('send-progress').value") == 100
    assert page.text_content("#send-status").startswith(f"done: {len(lines)} lines in ")
    check_received(emu.received[n0:], lines)  # every line of the edited job acknowledged exactly once
    # a second send, stopped: GRBL finishes its queued lines and the pen ends up
    page.click("#send")
    page.wait_for_function("() => /^sending: line/.test(document.getElementById('send-status').textContent)")
    page.click("#stop")
    page.wait_for_selector("#send-status[data-state=stopped]", timeout=30_000)
    assert "with the pen up" in page.text_content("#send-status")
    assert emu.state == "Idle" and emu.modal["s"] == 0
    assert page.text_content("#send").strip() == "Resume"
    page.select_option("#target", "simulator")
    assert not page.is_visible("#machine-panel")


def test_8_motion_page_curves_follow_a_changed_segment_law(page, server):
    shutil.copy(ROOT / "samples" / "motion" / "fuse.toml", server["folder"] / "fuse.toml")
    page.click(".tabs button[data-tab=motion]")
    page.wait_for_function("document.body.dataset.motionVersion >= 1", timeout=30_000)
    assert page.locator("#motion-sample").input_value() == "fuse.toml"
    before = page.evaluate("studioMotion.result")
    # the curves pass through the design table's positions at its times
    points = page.evaluate("studioMotion.doc.point")
    t = np.array(before["t"])
    for p in points:
        if isinstance(p.get("x"), (int, float)):
            assert np.interp(p["t"], t, before["axes"]["x"][0]) == pytest.approx(p["x"], abs=0.5)
    law = page.locator("#motion-tables table[data-kind=segment] tr[data-row='0'] select[name=law]")
    assert law.input_value() == "polynomial"
    law.select_option("cycloidal")
    page.wait_for_function("document.body.dataset.motionVersion >= 2", timeout=30_000)
    after = page.evaluate("studioMotion.result")
    assert after["segments"][0]["law"] == "cycloidal"
    assert not np.allclose(np.array(after["axes"]["x"][2], dtype=float), np.array(before["axes"]["x"][2], dtype=float),
                           equal_nan=True)
    flags = page.locator("#motion-tables td.checks").all_text_contents()
    assert flags == segment_flags(after) and len(flags) == len(after["segments"]) // 2  # X-Y input: one row, two axes
    page.click("#m-play")  # the end effector along the trajectory, in real time (0.666 s)
    page.wait_for_function("document.getElementById('m-time').textContent.startsWith('0.666 /')", timeout=30_000)
    assert page.evaluate("studioMotion.frames") > 10
    shot(page, "motion")


def test_8b_motion_page_animates_a_theta_axis(page, server):
    """A design with X, Y and a Θ axis (samples/motion/turn.toml): the tool is drawn at (x, y) turned by Θ."""
    shutil.copy(ROOT / "samples" / "motion" / "turn.toml", server["folder"] / "turn.toml")
    page.evaluate("window.studioMotion && (studioMotion.opened = false)")  # list the folder again (it shows the first design)
    version = page.evaluate("Number(document.body.dataset.motionVersion || 0)")
    page.click(".tabs button[data-tab=paper]")
    page.click(".tabs button[data-tab=motion]")
    page.wait_for_function(f"Number(document.body.dataset.motionVersion) > {version}", timeout=30_000)
    page.select_option("#motion-sample", "turn.toml")
    page.wait_for_function("studioMotion.name === 'turn.toml'", timeout=30_000)
    r = page.evaluate("studioMotion.result")
    assert r["units"] == {"x": "mm", "y": "mm", "theta": "deg"}
    page.click("#m-play")
    samples = []
    for _ in range(40):  # the effector as the page draws it, against the solved curves
        e = page.evaluate("studioMotion.effector")
        if e and "theta" in e:
            samples.append(e)
        if page.text_content("#m-time").startswith("1.000 /"):
            break
        time.sleep(0.03)
    page.wait_for_function("document.getElementById('m-time').textContent.startsWith('1.000 /')", timeout=30_000)
    e = page.evaluate("studioMotion.effector")
    assert (e["x"], e["y"], e["theta"]) == pytest.approx((80.0, 0.0, 90.0), abs=1e-6)
    t = np.array(r["t"])
    moving = [s for s in samples if 0.25 < s["t"] < 0.75]
    assert moving, samples
    for s in samples:
        for axis in ("x", "y", "theta"):
            assert s[axis] == pytest.approx(float(np.interp(s["t"], t, r["axes"][axis][0])), abs=1e-6)
    # the tool at 90 degrees stands upright: red above and below its centre, not beside it, and the
    # white tick of its leading end above (Θ counter-clockwise from +X)
    cx, cy = e["screen"]
    colour = page.evaluate("""([x, y]) => { const c = document.getElementById('m-anim'), d = window.devicePixelRatio || 1;
        const at = (u, v) => c.getContext('2d').getImageData(Math.round(u * d), Math.round(v * d), 1, 1).data;
        return [[x, y - 10], [x, y + 10], [x + 10, y], [x - 10, y], [x, y - 17], [x, y + 17]].map(([u, v]) => {
            const p = at(u, v); return p[3] < 128 ? "none" : p[0] > 180 && p[1] < 80 ? "red" : p[1] > 200 ? "white" : "other"; });
    }""", [cx, cy])
    assert colour[:4] == ["red", "red", "none", "none"] and colour[4:] == ["white", "red"], colour
    shot(page, "motion-theta")


def segment_flags(result) -> list[str]:
    """Per segment number, the findings of both axes as the page writes them ("envelope, meander" or "ok")."""
    numbers = sorted({s["number"] for s in result["segments"]})
    kinds = [sorted({k for s in result["segments"] if s["number"] == n for k in s["findings"]}) for n in numbers]
    return [", ".join(k) or "ok" for k in kinds]


def test_9_drop_a_file_on_the_paper(page, server):
    import base64

    page.click(".tabs button[data-tab=paper]")
    strokes = page.text_content("#stat-strokes")
    # a file no tracer reads: convert's one line in the page, the job kept
    page.set_input_files("#file", files=[{"name": "notes.txt", "mimeType": "text/plain", "buffer": b"hello"}])
    page.wait_for_selector("#error:not([hidden])")
    assert page.text_content("#error").startswith("notes.txt: no tracer reads '.txt' files")
    assert page.text_content("#stat-strokes") == strokes
    data = base64.b64encode((ROOT / "samples" / "images" / "horse.png").read_bytes()).decode()
    page.evaluate("""(b64) => {
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        const dt = new DataTransfer();
        dt.items.add(new File([bytes], "horse.png", { type: "image/png" }));
        document.getElementById("paper-wrap").dispatchEvent(new DragEvent("drop", { dataTransfer: dt, bubbles: true }));
    }""", data)
    page.wait_for_function("document.getElementById('machine').textContent.endsWith('horse.png')", timeout=60_000)
    assert page.text_content("#stat-strokes") == str(summary(server)["strokes"])
    page.check("#show-order")
    assert ink_pixels(page) > 1000


def summary_commands(server) -> int:
    """Commands in the job's PLC file, read back with the packet-file reader."""
    from doodlecam.link.plc.packetfile import read_plc_array

    return len(read_plc_array(server["app"].state.session.export("plc")[1])[1])


def test_10_a_job_of_several_pens_waits_for_continue(page, server):
    """samples/vectors/layers.svg (3 layers, 2 pen changes) to the PLC simulator: the page shows which
    pen to fit and a Continue button at each change, while the simulator holds the job, pen up."""
    from doodlecam.link.plc.protocol import Fault

    page.click(".tabs button[data-tab=paper]")
    page.set_input_files("#file", str(ROOT / "samples" / "vectors" / "layers.svg"))
    page.wait_for_function("document.getElementById('machine').textContent.endsWith('layers.svg')", timeout=60_000)
    sender = server["app"].state.sender
    page.select_option("#target", "simulator")
    page.select_option("#send-speed", "")
    page.click("#send")
    for pen in (2, 3):
        page.wait_for_selector("#send-status[data-state=waiting]", timeout=60_000)
        assert f"change to pen {pen}, then press Continue" in page.text_content("#send-status")
        # a dialog the operator cannot miss, over the page, saying which pen
        page.wait_for_selector("#pen-modal[open]")
        assert page.is_visible("#pen-modal-continue") and f"pen {pen}" in page.text_content("#pen-modal-text")
        held = sender._sim.held
        assert held is not None and held.reason == Fault.PEN_CHANGE and not sender._sim.pen
        if pen == 2:
            shot(page, "pen-change")
        page.click("#pen-modal-continue")
        page.wait_for_function(f"!/pen {pen},/.test(document.getElementById('send-status').textContent)")
    # (a late answer to Continue must not put an older state over the 'done' event: showSend's version check)
    page.wait_for_selector("#send-status[data-state=done]", timeout=60_000)
    assert page.text_content("#send-status").startswith(f"done: {summary_commands(server)} commands in ")
    assert not page.is_visible("#continue") and not page.is_visible("#pen-modal")


def test_11_refit_makes_a_traced_stroke_a_few_handles(page, server):
    """Refit within a tolerance the user sets: the selected stroke keeps its shape with far fewer control points."""
    k = _select_longest(page)
    n0 = len(page.evaluate(f"studio.view.strokes[{k}].control"))
    page.fill("#refit-tolerance", "0.3")
    version = page.evaluate("studio.view.summary.version")
    page.click("#stroke-tools button[data-op=refit]")
    page.wait_for_function(f"studio.view.summary.version !== {version}", timeout=30_000)
    n1 = len(page.evaluate(f"studio.view.strokes[{k}].control"))
    assert n1 < 0.75 * n0, (n0, n1)  # (the API test checks the curve stays within the tolerance)
    shot(page, "refit")
    page.keyboard.press("Control+z")
    page.wait_for_function(f"studio.view.strokes[{k}].control.length === {n0}", timeout=30_000)


def test_12_the_machine_position_is_shown_on_the_drawing_during_a_send(page, server):
    """During a send the page draws the pen where the PLC's status reports put it, and clears it at the end."""
    page.select_option("#target", "simulator")
    page.select_option("#send-speed", "10")
    page.click("#send")
    page.wait_for_function("document.body.dataset.machinePos", timeout=60_000)
    x, y = map(float, page.get_attribute("body", "data-machine-pos").split(","))
    m = server["app"].state.session.machine
    assert 0 <= x <= m.width and 0 <= y <= m.height
    sx, sy = page.evaluate(f"studioScreen({x}, {y})")
    pixel = page.evaluate(f"Array.from(document.getElementById('paper').getContext('2d')"
                          f".getImageData({sx} * devicePixelRatio, {sy} * devicePixelRatio - 10 * devicePixelRatio, 1, 1).data)")
    assert pixel[0] > 150 and pixel[1] < 100 and pixel[2] < 100, pixel  # the red marker's cross above the centre
    shot(page, "send-position")
    page.click("#stop")
    page.wait_for_selector("#send-status[data-state=stopped]", timeout=60_000)
    assert page.get_attribute("body", "data-machine-pos") == ""
    page.wait_for_selector("#start-over", state="visible")
    assert page.is_visible("#abandon")


def test_13_the_layers_panel_shows_hides_colours_by_pen_and_plots_one_layer(page, server):
    page.set_input_files("#file", str(ROOT / "samples" / "vectors" / "layers.svg"))
    page.wait_for_function("document.getElementById('machine').textContent.endsWith('layers.svg')", timeout=60_000)
    layers = page.evaluate("studio.view.layers")
    assert page.locator("#layers tr").count() == len(layers) + 1 == 4
    assert all(l["pen_name"] in page.text_content("#layers") for l in layers)
    # hide the first layer: none of its strokes is drawn (a pixel on one of them turns white)
    k = next(i for i, s in enumerate(page.evaluate("studio.view.strokes")) if s["layer"] == layers[0]["name"])
    p = page.evaluate(f"studio.view.strokes[{k}].points")[len(page.evaluate(f"studio.view.strokes[{k}].points")) // 2]
    x, y = page.evaluate(f"studioScreen({p[0]}, {p[1]})")
    ink = f"Array.from(document.getElementById('paper').getContext('2d').getImageData({x} * devicePixelRatio, {y} * devicePixelRatio, 1, 1).data)"
    assert min(page.evaluate(ink)[:3]) < 200
    page.click("#layers input[data-layer='0']")
    assert page.evaluate(f"studio.hidden.has({layers[0]['name']!r})") and min(page.evaluate(ink)[:3]) > 240
    page.click("#layers input[data-layer='0']")
    page.check("#colour-by-pen")
    shot(page, "layers")
    page.uncheck("#colour-by-pen")
    # plot one layer: only its commands reach the PLC, with no pen change
    page.select_option("#send-layers", "1")
    page.select_option("#target", "simulator")
    page.select_option("#send-speed", "")
    page.click("#send")
    page.wait_for_selector("#send-status[data-state=done]", timeout=60_000)
    from doodlecam.link.plc.packetfile import read_plc_array

    session = server["app"].state.session
    n = len(read_plc_array(session.export("plc", [layers[1]["name"]])[1])[1])
    assert page.text_content("#send-status").startswith(f"done: {n} commands in ") and n < summary_commands(server)


def test_14_an_axidraw_sends_to_its_eibotboard_with_pause_and_resume(page, tmp_path):
    """With the axidraw-v3 profile the page offers the EiBotBoard (emulator, serial port) instead of the PLC
    and GRBL; a send to the EBB emulator shows its progress, pauses at a stroke end with the pen up, resumes,
    and the board receives every command of the job once, in order."""
    from doodlecam.link.ebb.jobfile import read_ebb

    # a second studio, in a second tab of the same browser
    with serve(tmp_path, "axidraw-v3") as srv, second_tab(page, srv["url"]) as pg:
        offered = pg.evaluate("Array.from(document.querySelectorAll('#target option')).filter((o) => !o.hidden)"
                              ".map((o) => o.value)")
        assert offered == ["ebb-simulator", "ebb-serial"] and pg.input_value("#target") == "ebb-simulator"
        pg.select_option("#target", "ebb-serial")
        assert pg.is_visible("#target-ebb") and not pg.is_visible("#send-speed-label")
        pg.select_option("#target", "ebb-simulator")
        pg.set_input_files("#file", str(ROOT / "samples" / "vectors" / "badge.svg"))
        pg.wait_for_function("document.getElementById('machine').textContent.endsWith('badge.svg')", timeout=60_000)
        sender = srv["app"].state.sender
        lines = list(read_ebb(srv["app"].state.session.export("ebb")[1]).lines)
        pg.select_option("#send-speed", "10")
        pg.click("#send")
        pg.wait_for_function("() => /^sending: command \\d+ of \\d+ answered, [\\d.]+ %, [\\d.]+ s left at \\(/"
                             ".test(document.getElementById('send-status').textContent)", timeout=30_000)
        pg.click("#pause")
        pg.wait_for_selector("#send-status[data-state=paused]", timeout=30_000)
        emu = sender._ebb.emulator
        assert emu.idle and emu.pen_up == 1  # at rest at a stroke's end, pen up
        assert pg.is_visible("#resume") and not pg.is_visible("#pause") and not pg.is_visible("#hold")
        shot(pg, "send-ebb")
        pg.click("#resume")
        pg.wait_for_selector("#send-status[data-state=done]", timeout=120_000)
        assert pg.text_content("#send-status").startswith(f"done: {len(lines)} commands in ")
        assert [c for c in emu.received if c.split(",")[0] not in ("V", "QM", "QS")] == lines
        # the EiBotBoard panel: `doodlecam machine ebb`'s controls on the same board, back at home after the job
        assert pg.is_visible("#ebb-panel") and not pg.is_visible("#machine-panel")
        n0 = len(emu.received)
        pg.click("[data-ebb=pen_down]")
        pg.wait_for_selector("#ebb-status[data-action=pen_down]", timeout=30_000)
        assert emu.pen_up == 0 and pg.text_content("#ebb-status").startswith("sent SP,0,200: ")
        pg.fill("#ebb-jog-step", "10")
        pg.click("[data-ebb-jog='1,0']")  # 10 mm right: both motors forward, the pen raised first
        pg.wait_for_selector("#ebb-status[data-action=jog]", timeout=30_000)
        assert tuple(emu.pos) == (800, 800) and emu.pen_up == 1
        pg.click("[data-ebb-jog='0,-1']")  # 10 mm down the paper (away from home): motor 1 on, motor 2 back
        pg.wait_for_selector("#ebb-status[data-position='10,208']", timeout=30_000)
        assert tuple(emu.pos) == (1600, 0)
        pg.click("[data-ebb-jog='-1,0']")
        pg.wait_for_selector("#ebb-status[data-position='0,208']", timeout=30_000)
        pg.click("[data-ebb-jog='-1,0']")  # past the left edge of the work area: refused, nothing moves
        pg.wait_for_function("() => /would leave/.test(document.getElementById('error').textContent)", timeout=30_000)
        assert tuple(emu.pos) == (800, -800)
        pg.click("[data-ebb=home]")
        pg.wait_for_selector("#ebb-status[data-action=home]", timeout=30_000)
        assert tuple(emu.pos) == (0, 0) and emu.pen_up == 1
        assert [c.split(",")[0] for c in emu.received[n0:] if c.split(",")[0] not in ("V", "QM", "QS")] == \
            ["SP", "SP", "XM", "SP", "XM", "SP", "XM", "SP", "HM"]
        shot(pg, "ebb-panel")
        sender.close()


def test_15_other_tabs_follow_a_large_load_and_an_edit_through_the_event_stream(page, tmp_path, monkeypatch):
    """Two tabs of one studio: tab A uploads a drawing of 1 200 paths, which the studio shows as traced at once
    and plans in the background; tab B, which sends no request of its own (no polling), follows through
    /api/events: it shows the traced paths, then the planned job, then A's edit of a stroke."""
    import sys

    sys.path.insert(0, str(ROOT / "tests"))
    from generated_art import generated_svg

    from doodlecam.studio.session import Session

    svg = tmp_path / "lines.svg"
    svg.write_text(generated_svg(1200, "lines"))
    # the background plan waits until both tabs show the traced paths (1 200 lines plan in well under
    # a second: the preview could be gone before a tab looked)
    gate, plan = threading.Event(), Session._plan
    monkeypatch.setattr(Session, "_plan", lambda self, d, progress=None:
                        (progress is None or gate.wait(120)) and plan(self, d, progress))
    with serve(tmp_path) as srv:
        session = srv["app"].state.session
        browser = page.context.browser
        a, b = (browser.new_page(viewport={"width": 1400, "height": 850}) for _ in range(2))
        errors, asked = [], []
        for pg in (a, b):
            pg.on("pageerror", lambda e: errors.append(str(e)))
            pg.goto(srv["url"])
            pg.wait_for_selector("body[data-ready='1']")
        b.on("request", lambda r: asked.append(r.url.split("?")[0].split("/", 3)[-1]))
        a.set_input_files("#file", str(svg))
        for pg in (a, b):  # the traced paths, while the job is planned
            pg.wait_for_selector("body[data-preview='1']", timeout=60_000)
            assert pg.evaluate("studio.view.preview.offsets.length") == 1201
            assert pg.evaluate("studio.view.strokes.length") == 0
        # B's tracer panel follows too: the vector tracer's options, not the edges' it showed with no file
        b.wait_for_function("!document.querySelector('#tracer-options [name=sigma]')")
        shot(b, "planning")
        assert session.job is None  # still planned in the background
        gate.set()
        for pg in (a, b):  # then the planned job
            pg.wait_for_function("document.body.dataset.preview === '' && studio.view.strokes.length > 0",
                                 timeout=300_000)
            s = summary(srv)
            assert pg.text_content("#stat-strokes") == str(s["strokes"]) and pg.is_hidden("#planning")
            assert pg.evaluate("[studio.view.summary.job, studio.view.summary.version]") == [s["job"], s["version"]]
        k = _select_longest(a)
        before = b.evaluate(f"studio.view.strokes[{k}].control")
        version = summary(srv)["version"]
        a.click("#stroke-tools [data-op=reverse]")
        a.wait_for_function(f"studio.view.summary.version > {version}", timeout=60_000)  # A's edit is done
        b.wait_for_function(f"studio.view.summary.version === {summary(srv)['version']}", timeout=60_000)
        assert b.evaluate(f"studio.view.strokes[{k}].control") == before[::-1]
        assert b.text_content("#stat-time") == f"{summary(srv)['job_time_s']:.2f} s"
        # tab B asked only for what the events told it of (a view per change, its tracer panel per new job id:
        # the preview's and the planned job's), and nothing while nothing changes: no polling
        assert asked.count("api/view") == 3 and asked.count("api/state") == 2 and set(asked) == {"api/view", "api/state"}, asked
        time.sleep(3)
        assert len(asked) == 5, asked
        a.close()
        b.close()
    assert not errors, errors
