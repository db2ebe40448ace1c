"""doodlecam studio on a generated drawing of 5 000 paths (10 641 strokes): first view and re-plan.

    .venv/bin/python benchmarks/bench_studio_scale.py            # 5 000 "mixed" paths (tests/generated_art.py)
    .venv/bin/python benchmarks/bench_studio_scale.py --paths 2000 --kind lines

1. Without a browser (this process is the server): the thread CPU time of the upload request (trace + layout;
   planning starts in the background) and of the first /api/view?flat=1 (the traced paths, thinned), and its
   bytes; then the process CPU time until the job is planned, and the planned view's CPU time and bytes,
   against the view of one object per stroke (/api/view).
2. In headless Chromium (the studio in a thread of this process): the file chosen until its paths are drawn
   (wall), the server's thread CPU for the load and the view (their Server-Timing headers), the bytes, the
   page's decoding and drawing; the same for the planned job once the event stream says it is planned.
3. Re-planning one stroke after a drag, 10 times (after the background checks): the server's thread CPU
   (Server-Timing), the answer's bytes, the page's wall time from mouse release to the redrawn plan.

Wall times depend on the machine's load (2 shared cores here); the CPU times do not. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))


def wait_planned(session, timeout: float = 900.0) -> None:
    end = time.monotonic() + timeout
    while session.planning is not None:
        if "error" in session.planning or time.monotonic() > end:
            raise SystemExit(f"planning did not finish: {session.planning}")
        time.sleep(0.2)


def wait_checked(session, timeout: float = 300.0) -> None:
    """Until the background checks of every stroke and the job's largest figures by them are done (an edit before
    then checks the rest itself)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and not (session._worst_of is not None and session._worst_of[0] is session.job):
        time.sleep(0.2)


def warm_up(svg: Path) -> None:
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings
    from doodlecam.studio.session import Session

    session = Session(Settings(machine=load_machine("doodlebot")))
    session.load(svg.name, svg.read_bytes(), background=False)
    session.view(flat=True)


def in_process(svg: Path) -> dict:
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings
    from doodlecam.studio.session import Session

    out = {}
    session = Session(Settings(machine=load_machine("doodlebot")))
    p0, c0 = time.process_time(), time.thread_time()
    s = session.load(svg.name, svg.read_bytes())
    c1 = time.thread_time()
    body = json.dumps(session.view(flat=True), separators=(",", ":"))
    c2 = time.thread_time()
    out["paths traced"] = s["strokes"]
    out["load request, server CPU s (trace + layout)"] = c1 - c0
    out["first view (traced paths), server CPU s"] = c2 - c1
    out["first view: load + view, server CPU s"] = c2 - c0
    out["first view, bytes"] = len(body)
    wait_planned(session)
    out["planned: strokes"] = len(session.job.strokes)
    out["load until planned, process CPU s (background planning)"] = time.process_time() - p0
    c0 = time.thread_time()
    body = json.dumps(session.view(flat=True), separators=(",", ":"))
    out["planned view (flat), server CPU s"] = time.thread_time() - c0
    out["planned view (flat), bytes"] = len(body)
    c0 = time.thread_time()
    body = json.dumps(session.view(), separators=(",", ":"))
    out["planned view (an object per stroke), server CPU s"] = time.thread_time() - c0
    out["planned view (an object per stroke), bytes"] = len(body)
    return out


def in_browser(svg: Path) -> dict:
    from playwright.sync_api import sync_playwright

    from bench_studio import ARGS, drag_and_wait, start_server

    out = {}
    srv, session, url = start_server(preload=False)
    timing = """(part) => { const e = performance.getEntriesByType('resource').filter((x) => x.name.includes(part)).pop();
        return e ? [Object.fromEntries((e.serverTiming || []).map((x) => [x.name, x.duration])), e.encodedBodySize] : null; }"""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 850})
        page.goto(url)
        page.wait_for_selector("body[data-ready='1']")
        t0 = time.perf_counter()
        page.set_input_files("#file", str(svg))
        page.wait_for_selector("body[data-preview='1'][data-strokes]", timeout=120_000)
        out["browser: file chosen until its paths are drawn, wall s"] = time.perf_counter() - t0
        load, view = page.evaluate(timing, "/api/load"), page.evaluate(timing, "/api/view")
        out["browser: load + first view, server thread CPU s"] = (load[0]["cpu"] + view[0]["cpu"]) / 1e3
        out["browser: load + first view, server wall s"] = (load[0]["load"] + view[0]["view"]) / 1e3
        out["browser: load + first view, server waiting for a core s"] = (load[0]["runqueue"] + view[0]["runqueue"]) / 1e3
        out["browser: first view, bytes"] = view[1]
        perf = page.evaluate("studioPerf.view")
        out["browser: first view, page request (upload excluded) ms"] = perf["request"]
        out["browser: first view, page draw ms"] = page.evaluate("studioRedraw()")
        page.wait_for_function("document.body.dataset.preview === '' && studio.view.strokes.length > 0",
                               timeout=900_000, polling=500)
        out["browser: file chosen until the planned job is drawn, wall s"] = time.perf_counter() - t0
        view = page.evaluate(timing, "/api/view")
        out["browser: planned view, server thread CPU s"] = view[0]["cpu"] / 1e3
        out["browser: planned view, bytes"] = view[1]
        out["browser: planned view, page decode ms"] = page.evaluate("studioPerf.view")["decode"]
        out["browser: planned view, page draw ms"] = statistics.median(page.evaluate("studioRedraw()") for _ in range(5))

        wait_checked(session)
        # re-plan: drag the middle control point of a stroke of 6 or more control points, release, 10 times
        k = page.evaluate("studio.view.strokes.findIndex((s) => s.control.length >= 6 && s.length > 20)")
        out["re-plan: stroke control points"] = page.evaluate(f"studio.view.strokes[{k}].control.length")
        box = page.locator("#paper").bounding_box()
        pt = page.evaluate(f"studio.view.strokes[{k}].points[Math.floor(studio.view.strokes[{k}].points.length / 2)]")
        x, y = page.evaluate(f"studioScreen({pt[0]}, {pt[1]})")
        page.mouse.click(box["x"] + x, box["y"] + y)
        page.wait_for_function("studio.selected >= 0")
        k = page.evaluate("studio.selected")
        for r in range(10):
            drag_and_wait(page, box, k, f"Math.floor(studio.view.strokes[{k}].control.length / 2)", r, timeout=60_000)
        parts = page.evaluate("studioPerf.replanParts")
        assert len(parts) == 10, parts
        out["re-plan: server thread CPU ms (median of 10)"] = statistics.median(p["cpu"] for p in parts)
        out["re-plan: server thread CPU ms (max of 10)"] = max(p["cpu"] for p in parts)
        out["re-plan: answer bytes (median)"] = statistics.median(p["bytes"] for p in parts)
        out["re-plan: release to redrawn, wall ms (median)"] = statistics.median(page.evaluate("studioPerf.replan"))
        out["re-plan: page redraw ms (median)"] = statistics.median(p["page"] for p in parts)
        browser.close()
    srv.should_exit = True
    return out


def main() -> None:
    from generated_art import generated_svg

    ap = argparse.ArgumentParser()
    ap.add_argument("--paths", type=int, default=5000)
    ap.add_argument("--kind", default="mixed")
    ap.add_argument("--no-browser", action="store_true")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        svg = Path(tmp) / f"generated-{a.paths}.svg"
        svg.write_text(generated_svg(a.paths, a.kind))
        warm = Path(tmp) / "warm-up.svg"  # imports, numba's caches: not part of the figures
        warm.write_text(generated_svg(50, a.kind))
        warm_up(warm)
        rows = in_process(svg)
        if not a.no_browser:
            rows.update(in_browser(svg))
    print(f"| measure ({a.paths} generated '{a.kind}' paths) | value |")
    print("|---|---|")
    for key, v in rows.items():
        print(f"| {key} | {v:.3f} |" if isinstance(v, float) else f"| {key} | {v} |")


if __name__ == "__main__":
    main()
