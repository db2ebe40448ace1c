"""doodlecam studio's targets, measured with the real browser (headless Debian chromium via Playwright).

    .venv/bin/python benchmarks/bench_studio.py            # camera.png, 3 repeats

1. First view: the page opened on a studio started with camera.png (`doodlecam studio camera.png`),
   until its strokes are drawn; and the upload of camera.png from the page (trace + plan + draw).
2. Dragging a control point of the stroke with the number of control points nearest 100:
   script time per mousemove event (the page's handler: B-spline evaluation + redraw), in the page.
3. Re-planning the dragged stroke and updating the figures: mouse release until the page
   shows the new plan (wall, median of 10), this process's CPU time meanwhile (server and Playwright's
   client), and its parts: the request (the edit answers with what changed: one request), the server's
   wall and thread CPU time for it and its time runnable but waiting for a core (its Server-Timing
   header, from Linux schedstat), the page's redraw; and the CPU time of
   the same request through the API without a browser.
4. Simulation playback of the whole job: frame intervals and script time per frame.

Wall times depend on the load of the machine (2 shared cores here); the server's CPU time does not.
Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import socket
import statistics
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CAMERA = ROOT / "samples" / "images" / "camera.png"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
        "--disable-sync", "--no-first-run"]


def start_server(preload: bool):
    import uvicorn

    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings
    from doodlecam.studio.app import StudioConfig, create_app
    from doodlecam.studio.session import Session

    session = Session(Settings(machine=load_machine("doodlebot")))
    if preload:
        session.load(CAMERA.name, CAMERA.read_bytes())
    cfg = StudioConfig(token="bench")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    srv = uvicorn.Server(uvicorn.Config(create_app(session, cfg), host="127.0.0.1", port=port, log_level="warning"))
    threading.Thread(target=srv.run, daemon=True).start()
    while not srv.started:
        time.sleep(0.02)
    return srv, session, f"http://127.0.0.1:{port}/?token=bench"


def run_once(p) -> dict:
    out = {}
    browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
    try:
        # 1a. page opened on a studio that traced camera.png at start
        srv, session, url = start_server(preload=True)
        page = browser.new_page(viewport={"width": 1400, "height": 850})
        t0 = time.perf_counter()
        page.goto(url)
        page.wait_for_selector("body[data-strokes]")
        out["open_preloaded_s"] = time.perf_counter() - t0
        page.close()
        srv.should_exit = True

        # 1b. camera.png uploaded from the page: trace, plan, draw
        srv, session, url = start_server(preload=False)
        page = browser.new_page(viewport={"width": 1400, "height": 850})
        page.goto(url)
        page.wait_for_selector("body[data-ready='1']")
        c0 = time.process_time()
        t0 = time.perf_counter()
        page.set_input_files("#file", str(CAMERA))
        page.wait_for_selector("body[data-strokes]", timeout=120_000)
        out["upload_first_view_s"] = time.perf_counter() - t0
        out["upload_server_cpu_s"] = time.process_time() - c0  # this process runs the server (and the driver)

        # 2. drag a control point of the stroke with about 100 control points
        k, n = page.evaluate("""() => { const v = studio.view.strokes; let b = 0;
            for (const s of v) if (Math.abs(s.control.length - 100) < Math.abs(v[b].control.length - 100)) b = s.i;
            return [b, v[b].control.length]; }""")
        out["drag_stroke_control_points"] = n
        pt = page.evaluate(f"studio.view.strokes[{k}].points[Math.floor(studio.view.strokes[{k}].points.length / 3)]")
        box = page.locator("#paper").bounding_box()
        x, y = page.evaluate(f"studioScreen({pt[0]}, {pt[1]})")
        page.mouse.click(box["x"] + x, box["y"] + y)
        page.wait_for_function(f"studio.selected === {k}")
        c = page.evaluate(f"studio.view.strokes[{k}].control[{n // 2}]")
        x, y = page.evaluate(f"studioScreen({c[0]}, {c[1]})")
        page.evaluate("studioPerf.moves.length = 0")
        page.mouse.move(box["x"] + x, box["y"] + y)
        page.mouse.down()
        for i in range(1, 61):
            page.mouse.move(box["x"] + x + i * 0.5, box["y"] + y + i * 0.3)
        moves = page.evaluate("studioPerf.moves")
        out["drag_move_script_ms_median"] = statistics.median(moves)
        out["drag_move_script_ms_max"] = max(moves)
        # 3. release: re-plan on the server, figures updated in the page
        before = page.get_attribute("body", "data-job-time")
        c0 = time.process_time()
        page.mouse.up()
        page.wait_for_function(f"studioPerf.replan.length > 0 && document.body.dataset.jobTime !== '{before}'")
        out["replan_cpu_s"] = time.process_time() - c0
        # nine more drags and releases of the same point: medians of the re-plan and its parts
        for r in range(9):
            drag_and_wait(page, box, k, str(n // 2), r)
        out["replan_page_ms"] = statistics.median(page.evaluate("studioPerf.replan"))
        parts = page.evaluate("studioPerf.replanParts")
        for key, name in (("request", "replan_request_ms"), ("lock", "replan_server_lock_wait_ms"),
                          ("edit", "replan_server_wall_ms"), ("cpu", "replan_server_thread_cpu_ms"),
                          ("runqueue", "replan_server_waiting_for_a_core_ms"),
                          ("page", "replan_page_redraw_ms"), ("bytes", "replan_answer_bytes")):
            out[name] = statistics.median(p[key] for p in parts)

        # 4. simulation of the whole job at 10x (the studio's speeds are 1, 2, 5, 10 and 50x)
        page.select_option("#sim-speed", "10")
        page.click("#play")
        page.wait_for_function("studioPerf.frames.length > 240", timeout=60_000)
        page.click("#play")
        frames = page.evaluate("studioPerf.frames")
        at = np.array([f["at"] for f in frames])
        out["sim_frame_interval_ms_median"] = float(np.median(np.diff(at)))
        out["sim_fps"] = 1000.0 / out["sim_frame_interval_ms_median"]
        out["sim_script_ms_median"] = statistics.median(f["script"] for f in frames)
        out["sim_script_ms_max"] = max(f["script"] for f in frames)
        srv.should_exit = True
    finally:
        browser.close()
    out["replan_api_cpu_ms"] = replan_api_cpu(session) * 1000
    return out


def drag_and_wait(page, box, k: int, index: str, r: int, timeout: float = 30_000) -> None:
    """Drag control point ``index`` (a JS expression) of stroke k a few pixels (left or right by r),
    release, and wait until the page has the re-planned stroke."""
    n_before = page.evaluate("studioPerf.replan.length")
    c = page.evaluate(f"studio.view.strokes[{k}].control[{index}]")
    x, y = page.evaluate(f"studioScreen({c[0]}, {c[1]})")
    page.mouse.move(box["x"] + x, box["y"] + y)
    page.mouse.down()
    for i in range(1, 6):
        page.mouse.move(box["x"] + x + i * 0.4 * (-1) ** r, box["y"] + y + i * 0.2)
    page.mouse.up()
    page.wait_for_function(f"studioPerf.replan.length > {n_before}", timeout=timeout)


def replan_api_cpu(session, n: int = 10) -> float:
    """CPU s per re-plan as the page asks for it (edit, view, figures), through the HTTP API
    in this process without a browser: the server's share of target 3."""
    from fastapi.testclient import TestClient

    from doodlecam.studio.app import StudioConfig, create_app

    c = TestClient(create_app(session, StudioConfig(token="bench")), headers={"x-doodlecam-token": "bench"},
                   base_url="http://127.0.0.1")  # the studio answers only to its own host
    view = c.get("/api/view").json()
    k = min(range(len(view["strokes"])), key=lambda i: abs(len(view["strokes"][i]["control"]) - 100))
    control = np.array(view["strokes"][k]["control"])
    c0 = time.process_time()
    for _ in range(n):
        control[len(control) // 2] += 0.3
        s = view["summary"]  # an edit names the job and version it was made on (stale ones are refused)
        r = c.post("/api/edit", json={"op": "move", "stroke": k, "control": control.tolist(), "reply": "patch",
                                      "job": s["job"], "version": s["version"]})
        r.raise_for_status()
        view["summary"] = r.json()["summary"]
    return (time.process_time() - c0) / n


def main() -> None:
    from playwright.sync_api import sync_playwright

    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    runs = []
    with sync_playwright() as p:
        run_once(p)  # warm-up: numba caches, browser profile
        for _ in range(a.repeat):
            runs.append(run_once(p))
    print(f"| measure (camera.png, median of {a.repeat}) | value |")
    print("|---|---|")
    for key in runs[0]:
        v = statistics.median(r[key] for r in runs)
        print(f"| {key} | {v:.3f} |" if isinstance(v, float) else f"| {key} | {v} |")


if __name__ == "__main__":
    main()
