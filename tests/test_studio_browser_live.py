"""doodlecam studio in headless Chromium: point edits, simulation speeds, the live machine view, the STL panel.

* a control point is selected by a click, then inserted after or deleted with the stroke panel's buttons, the
  keys (I, Delete) or the right-click menu; each re-plans that stroke only, and undo takes it back;
* the simulation plays at 1x to 50x and pauses, its clock showing the machine time the pen is drawn at;
* during a send to the PLC simulator or the GRBL emulator the part the machine has executed is drawn in ink
  over the faded toolpath, where the link reports the machine; everything in ink once it is done;
* an STL opened in the studio gets the section-plane / silhouette panel, whose settings are the tracer
  options `convert` takes (the command line it shows gives the same G-code).
Screenshots go to docs/ with DOODLECAM_SCREENSHOTS=1.
"""

from __future__ import annotations

import shlex
import time
from pathlib import Path

import numpy as np
import pytest
from test_studio_browser import ROOT, _select_longest, page, second_tab, serve, shot  # noqa: F401 (page: a fixture)

from doodlecam.cli import main as cli_main



@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with serve(tmp_path_factory.mktemp("studio-live")) as srv:
        yield srv
        srv["app"].state.sender.close()


def open_file(page, path: Path) -> None:
    page.set_input_files("#file", str(path))
    page.wait_for_function(f"document.getElementById('machine').textContent.endsWith('{path.name}')", timeout=60_000)


def at(page, x: float, y: float) -> tuple[float, float]:
    """Page coordinates of a point in mm on the paper."""
    sx, sy = page.evaluate(f"studioScreen({x}, {y})")
    box = page.locator("#paper").bounding_box()
    return box["x"] + sx, box["y"] + sy


def controls(page, k: int) -> int:
    return len(page.evaluate(f"studio.view.strokes[{k}].control"))


def test_1_select_a_point_then_insert_and_delete_it(page, server):
    open_file(page, ROOT / "samples" / "images" / "horse.png")
    session = server["app"].state.session
    k = _select_longest(page)
    page.fill("#refit-tolerance", "0.3")  # a traced stroke's hundreds of points become a few handles first
    version = page.evaluate("studio.view.summary.version")
    page.click("#stroke-tools button[data-op=refit]")
    page.wait_for_function(f"studio.view.summary.version !== {version}", timeout=30_000)
    n = controls(page, k)
    assert page.is_disabled("#insert-point") and page.is_disabled("#delete-point")
    j = n // 2
    c = page.evaluate(f"studio.view.strokes[{k}].control[{j}]")
    page.mouse.move(*at(page, *c))
    for _ in range(4):
        page.mouse.wheel(0, -300)  # zoom in around it (the screenshot shows the handles)
    page.mouse.click(*at(page, *c))  # a click without a drag selects the point
    assert page.evaluate("studio.point") == j
    assert page.text_content("#point-hint").startswith(f"point {j + 1} of {n} selected: I inserts")
    before = session.job
    page.click("#insert-point")
    page.wait_for_function(f"studio.view.strokes[{k}].control.length === {n + 1}", timeout=30_000)
    after = session.job
    assert [i for i, (a, b) in enumerate(zip(before.samples, after.samples)) if a is not b] == [k]  # that stroke only
    assert session.last_changed == (k,)  # answered as a patch (no whole view)
    new = np.array(page.evaluate(f"studio.view.strokes[{k}].control"))
    old = np.array(before.strokes[k].spline.control)
    assert np.allclose(new[j + 1], (old[j] + old[j + 1]) / 2, atol=1e-3)
    assert page.evaluate("studio.point") == j + 1  # the new point is selected
    shot(page, "points")
    page.keyboard.press("Delete")  # deletes the selected (new) point
    page.wait_for_function(f"studio.view.strokes[{k}].control.length === {n}", timeout=30_000)
    assert np.allclose(page.evaluate(f"studio.view.strokes[{k}].control"), old, atol=1e-3)
    page.keyboard.press("i")
    page.wait_for_function(f"studio.view.strokes[{k}].control.length === {n + 1}", timeout=30_000)
    # the right-click menu: select the point and offer both actions (no confirm dialog)
    c = page.evaluate(f"studio.view.strokes[{k}].control[{j - 1}]")
    page.mouse.click(*at(page, *c), button="right")
    page.wait_for_selector("#point-menu:not([hidden])")
    assert page.evaluate("studio.point") == j - 1
    page.click("#point-menu [data-point-op=delete_point]")
    page.wait_for_function(f"studio.view.strokes[{k}].control.length === {n}", timeout=30_000)
    assert page.is_hidden("#point-menu")
    # the last point has no point after it: insert is not offered
    for _ in range(4):
        page.mouse.wheel(0, 300)  # zoom out again
    last = page.evaluate(f"studio.view.strokes[{k}].control[{n - 1}]")
    page.mouse.click(*at(page, *last))
    assert page.evaluate("studio.point") == n - 1 and page.is_disabled("#insert-point")
    for m in (n + 1, n, n + 1, n):  # four edits, four undos: each one a step
        page.keyboard.press("Control+z")
        page.wait_for_function(f"studio.view.strokes[{k}].control.length === {m}", timeout=30_000)
    assert np.allclose(np.array(session.job.strokes[k].spline.control), old)
    page.keyboard.press("Escape")
    assert page.evaluate("studio.point") == -1


def test_2_the_simulation_plays_at_1x_to_50x_and_pauses_with_an_honest_clock(page, server):
    speeds = page.evaluate("Array.from(document.querySelectorAll('#sim-speed option')).map((o) => o.value)")
    assert speeds == ["1", "2", "5", "10", "50"]
    timeline = server["app"].state.session.timeline()
    t, xy = np.array(timeline["t"]), np.array(timeline["xy"])
    for speed in (1, 50):
        page.select_option("#sim-speed", str(speed))
        page.locator("#scrub").fill("0")  # from the start, and not as far as the end
        page.locator("#scrub").dispatch_event("input")
        start = page.evaluate("studioPerf.frames.length")
        page.click("#play")
        time.sleep(min(1.5, 0.35 * timeline["duration"] / speed))
        page.click("#play")  # pause
        frames = page.evaluate(f"studioPerf.frames.slice({start})")
        playing = [f for f, g in zip(frames[1:], frames) if f["t"] > g["t"]]  # frames that moved the clock on
        assert len(playing) > 10, len(playing)
        a, b = playing[0], playing[-1]
        rate = (b["t"] - a["t"]) / ((b["at"] - a["at"]) / 1000)
        assert rate == pytest.approx(speed, rel=0.02)  # machine seconds per second on the screen
        for f in playing[:: max(1, len(playing) // 20)]:  # the pen is drawn where the machine is at the clock's time
            assert f["x"] == pytest.approx(np.interp(f["t"], t, xy[:, 0]), abs=1e-6)
            assert f["y"] == pytest.approx(np.interp(f["t"], t, xy[:, 1]), abs=1e-6)
        paused = page.evaluate("studio.sim.t")
        time.sleep(0.3)
        assert page.evaluate("studio.sim.t") == paused
        text = page.text_content("#sim-time")
        assert text.startswith(f"{paused:.1f} / {timeline['duration']:.1f} s") and text.endswith("paused")
    page.select_option("#sim-speed", "10")
    page.locator("#scrub").fill("0")
    page.locator("#scrub").dispatch_event("input")
    page.click("#play")
    time.sleep(0.3)
    assert page.text_content("#sim-time").endswith("at 10×")
    shot(page, "sim-speeds")
    page.click("#play")


INK = """([points, times]) => {
    // each pen-down point of the job as the page draws it now: ink (dark), faded (light), and the machine's time
    const c = document.getElementById('paper'), g = c.getContext('2d'), d = devicePixelRatio;
    const px = points.map(([x, y]) => { const [u, v] = studioScreen(x, y);
        return Array.from(g.getImageData(Math.round(u * d), Math.round(v * d), 1, 1).data); });
    return { t: studioLive.t, px, pos: document.body.dataset.machinePos };
}"""


def live_check(page, server, target: str, speed: str) -> None:
    """A send of the loaded job: mid-send the executed part is ink, what remains is faded, and the machine's
    reported position is on the toolpath at the time the page says; everything is ink once it is done."""
    tl = server["app"].state.session.timeline()
    t, xy, pen = np.array(tl["t"]), np.array(tl["xy"]), np.array(tl["pen"])
    D = tl["duration"]
    down = np.flatnonzero((pen[:-1] == 1) & (pen[1:] == 1))  # starts of pen-down segments
    mid = (xy[down] + xy[down + 1]) / 2
    tmid = (t[down] + t[down + 1]) / 2
    page.select_option("#target", target)
    page.select_option("#send-speed", speed)
    page.click("#send")
    page.wait_for_function(f"studioLive.state === 'sending' && studioLive.timeline && studioLive.t > {0.3 * D}",
                           timeout=60_000)
    snap = page.evaluate(INK, [mid.tolist(), tmid.tolist()])
    assert 0 < snap["t"] < D, snap["t"]
    px = np.array(snap["px"])[:, :3]
    # judged away from the boundary (the pen moves on while the page is read) and from crossings
    drawn = px[tmid < snap["t"] - 0.5]
    remains = px[tmid > snap["t"] + 3.0]
    assert len(drawn) > 20 and len(remains) > 20
    assert np.mean(drawn.max(axis=1) < 160) > 0.95  # ink (anti-aliased: 17 on the line, lighter beside it)
    assert np.mean(remains.min(axis=1) > 165) > 0.9  # faded (a crossing with an inked stroke is the rest)
    if snap["pos"]:  # the reported position lies on the toolpath at the matched time (within the match tolerance)
        x, y = map(float, snap["pos"].split(","))
        k = int(np.clip(np.searchsorted(t, snap["t"]) - 1, 0, len(t) - 2))
        a, b = xy[k], xy[k + 1]
        u = np.clip(np.dot([x, y] - a, b - a) / max(np.dot(b - a, b - a), 1e-12), 0, 1)
        assert np.hypot(*(a + u * (b - a) - [x, y])) < 1.0 + 1e-6, (x, y, snap["t"], a, b)
    shot(page, f"live-{target}")
    page.wait_for_selector("#send-status[data-state=done]", timeout=120_000)
    page.wait_for_function(f"studioLive.t === {D}")
    px = np.array(page.evaluate(INK, [mid.tolist(), tmid.tolist()])["px"])[:, :3]
    assert np.mean(px.max(axis=1) < 160) > 0.97
    assert page.is_visible("#live-legend") and "(done, idle)" in page.text_content("#live-time")


def test_3_live_view_of_a_send_to_the_plc_simulator(page, server):
    open_file(page, ROOT / "samples" / "vectors" / "badge.svg")
    live_check(page, server, "simulator", "10")


def test_3b_the_live_view_of_a_stopped_send_goes_on_from_where_it_stopped(page, server):
    """Stop mid-job (the PLC holds it, pen up), then Resume: the ink stays where the machine stopped and goes
    on from there, never back (the resumed send's first positions match the stop's place on the toolpath)."""
    D = server["app"].state.session.timeline()["duration"]
    page.evaluate("""() => { window.liveLog = [];
        new MutationObserver(() => liveLog.push([studioLive.state, Number(document.body.dataset.liveT)]))
            .observe(document.body, { attributes: true, attributeFilter: ['data-live-t'] }); }""")
    page.select_option("#target", "simulator")
    page.select_option("#send-speed", "10")
    page.click("#send")  # "Send again": the PLC finished this job once
    page.wait_for_function(f"studioLive.state === 'sending' && studioLive.t > {0.3 * D}", timeout=60_000)
    page.click("#stop")
    page.wait_for_selector("#send-status[data-state=stopped]", timeout=60_000)
    stopped = page.evaluate("studioLive.t")
    assert 0.3 * D < stopped < D and page.is_visible("#live-legend")  # what was drawn stays shown
    page.evaluate("liveLog.length = 0")
    page.click("#send")  # Resume
    page.wait_for_selector("#send-status[data-state=done]", timeout=60_000)
    assert "resumed at command" in page.text_content("#send-status")
    log = [t for state, t in page.evaluate("liveLog") if t > 0]
    assert log and log[-1] == pytest.approx(D, abs=1e-3)
    assert log[0] >= stopped - 1.0, (stopped, log[:5])  # picked up where it stopped, not from the start
    assert all(b >= a for a, b in zip(log, log[1:]))


def test_4_live_view_of_a_send_to_the_grbl_emulator(page, server):
    if not page.text_content("#machine").endswith("badge.svg"):  # (run on its own)
        open_file(page, ROOT / "samples" / "vectors" / "badge.svg")
    page.evaluate("delete document.body.dataset.finishing")
    live_check(page, server, "grbl-simulator", "10")
    # every line was answered while GRBL still ran the last ones: the page said so, and "done" came later
    finishing = page.evaluate("Number(document.body.dataset.finishing)")
    done = server["app"].state.sender.snapshot()[1]
    assert done["state"] == "done" and 0 < finishing < done["version"]


def test_5_an_stl_gets_its_section_panel_and_the_same_job_as_the_cli(page, server, tmp_path):
    gear = ROOT / "samples" / "vectors" / "gear.stl"
    open_file(page, gear)
    session = server["app"].state.session
    page.wait_for_selector("#stl-panel:not([hidden])")  # (the tracer panel is built after the view)
    assert page.is_hidden("#tracer-options input[name=layers]")
    assert page.is_hidden("#tracer-options input[name=plane]")  # written by the panel
    assert "spans 0.00 to 6.00 mm along it; cut at 3.00 mm" in page.text_content("#stl-extent")
    page.evaluate("""() => { const r = document.getElementById('stl-range'); r.value = 25;
        r.dispatchEvent(new Event('input')); r.dispatchEvent(new Event('change')); }""")
    page.wait_for_function("document.getElementById('stl-extent').textContent.includes('cut at 1.50 mm')", timeout=60_000)
    assert session.tracer_options["plane"] == "z=25%" and session.tracer_options["mesh"] == "section"
    cli = page.text_content("#stl-cli")
    assert cli == "doodlecam convert gear.stl --tracer vector --tracer-opt mesh=section --tracer-opt plane=z=25%"
    shot(page, "stl")
    args = shlex.split(cli)[1:]
    args[1] = str(gear)
    assert cli_main(args + ["-o", str(tmp_path), "--post", "gcode"]) == 0
    assert session.export("gcode")[1] == (tmp_path / "gear.gcode").read_bytes()
    # the same height in mm; then the silhouette seen along x
    page.select_option("#stl-unit", "mm")
    assert page.input_value("#stl-pos") == "1.5"
    page.check("#stl-panel input[value=silhouette]")
    page.wait_for_function("document.getElementById('stl-cli').textContent.endsWith('mesh=silhouette --tracer-opt direction=z')")
    page.select_option("#stl-dir", "x")
    page.wait_for_function(f"studio.view.summary.tracer_options.direction === 'x'", timeout=60_000)
    assert session.tracer_options["mesh"] == "silhouette" and page.is_hidden("#stl-section")
    # an SVG shows its own options, not the mesh's
    open_file(page, ROOT / "samples" / "vectors" / "badge.svg")
    page.wait_for_selector("#stl-panel", state="hidden")
    assert page.is_hidden("#stl-panel") and page.is_visible("#tracer-options input[name=layers]")
    assert page.is_hidden("#tracer-options input[name=plane]")


def test_6_live_view_of_a_send_to_the_eibotboard_emulator(page, tmp_path):
    # a second studio, in a second tab of the same browser
    with serve(tmp_path, "axidraw-v3") as srv, second_tab(page, srv["url"]) as pg:
        open_file(pg, ROOT / "samples" / "vectors" / "badge.svg")
        live_check(pg, srv, "ebb-simulator", "10")
        srv["app"].state.sender.close()
