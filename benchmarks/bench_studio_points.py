"""The studio's control-point edits: server CPU time of an insert and of a delete (each re-plans one stroke).

    .venv/bin/python benchmarks/bench_studio_points.py            # camera.png, 20 strokes

Through the API (FastAPI's TestClient, no browser): for the strokes nearest in control points to 20, 50,
100 and 200, an insert after the middle point and the delete that takes it back, each with reply=patch as the
page sends them; the thread CPU time comes from the answer's Server-Timing header (the edit, its checks and
the re-plan of that one stroke, and the patch). Prints a Markdown table of medians.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def cpu_ms(r) -> float:
    parts = dict(p.strip().split(";dur=") for p in r.headers["server-timing"].split(","))
    return float(parts["cpu"])


def main() -> None:
    from fastapi.testclient import TestClient

    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings
    from doodlecam.studio.app import StudioConfig, create_app
    from doodlecam.studio.session import Session

    ap = argparse.ArgumentParser()
    ap.add_argument("picture", nargs="?", default=str(ROOT / "samples" / "images" / "camera.png"))
    ap.add_argument("--per-size", type=int, default=5, help="strokes per size class")
    args = ap.parse_args()
    pic = Path(args.picture)
    c = TestClient(create_app(Session(Settings(machine=load_machine("doodlebot"))), StudioConfig(token="t")),
                   headers={"x-doodlecam-token": "t"}, base_url="http://127.0.0.1")
    r = c.post(f"/api/load?name={pic.name}", content=pic.read_bytes(), headers={"content-type": "application/octet-stream"})
    r.raise_for_status()
    view = c.get("/api/view").json()
    sizes = [len(s["control"]) for s in view["strokes"]]
    print(f"{pic.name}: {len(sizes)} strokes\n")
    print("| control points (target) | strokes | insert: server CPU ms (median) | delete: server CPU ms (median) |")
    print("|---|---|---|---|")
    for target in (20, 50, 100, 200):
        ks = sorted(range(len(sizes)), key=lambda i: abs(sizes[i] - target))[:args.per_size]
        ins, dele = [], []
        for k in ks:
            j = sizes[k] // 2
            for op, point, out in (("insert", j, ins), ("delete_point", j + 1, dele)):
                s = c.get("/api/state").json()["summary"]
                r = c.post("/api/edit", json={"op": op, "stroke": k, "point": point, "reply": "patch",
                                              "job": s["job"], "version": s["version"]})
                r.raise_for_status()
                out.append(cpu_ms(r))
        got = ", ".join(str(sizes[k]) for k in ks)
        print(f"| {target} ({got}) | {len(ks)} | {statistics.median(ins):.0f} | {statistics.median(dele):.0f} |")


if __name__ == "__main__":
    main()
