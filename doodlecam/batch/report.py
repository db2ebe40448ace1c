"""A batch's reports: the summary table, report.json, and index.html (one card per file with
its SVG preview and figures; previews are linked, not copied, so the page stays small).
"""

from __future__ import annotations

import dataclasses
import json
from html import escape
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from doodlecam import __version__
from doodlecam.batch.manifest import write_atomic
from doodlecam.batch.options import BatchOptions

if TYPE_CHECKING:
    from doodlecam.batch.runner import BatchResult

REPORT_NAME = "report.json"
INDEX_NAME = "index.html"


_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
h1{font-size:1.3em} .counts span{margin-right:1.2em}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(260px,1fr));gap:1em}
.card{border:1px solid #ccc;border-radius:6px;padding:.6em;background:#fafafa}
.card img{width:100%;height:200px;object-fit:contain;background:#fff;border:1px solid #eee}
.card h2{font-size:.95em;margin:.2em 0 .4em;word-break:break-all}
.failed{border-color:#c33;background:#fff4f4} .unsupported{border-color:#bbb;background:#f4f4f4;color:#666}
.err{color:#a00;font-size:.85em;word-break:break-word} .warn{color:#a60;font-size:.85em}
table{font-size:.85em;border-collapse:collapse} td{padding:0 .5em 0 0} td.n{text-align:right}
"""


def _figures(s: dict[str, Any]) -> str:
    rows = [("strokes", f"{s['strokes']}"), ("pen-down", f"{s['pen_down_mm']:.1f} mm"),
            ("travel", f"{s['travel_mm']:.1f} mm"), ("planned time", f"{s['job_time_s']:.1f} s"),
            ("drawing time", f"{s['draw_time_s']:.1f} s")]
    return "<table>" + "".join(f"<tr><td>{k}</td><td class=n>{escape(v)}</td></tr>" for k, v in rows) + "</table>"


def index_html(report: dict[str, Any]) -> str:
    c = report["counts"]
    cards = []
    for f in report["files"]:
        status = f["status"]
        cls = status if status in ("failed", "unsupported") else "ok"
        parts = [f"<div class='card {cls}'><h2>{escape(f['input'])}</h2>"]
        svg = next((o for o in f.get("outputs", []) if o.endswith(".svg")), None)
        if svg:
            parts.append(f"<a href='{quote(svg)}'><img loading=lazy src='{quote(svg)}' alt='preview of {escape(f['input'])}'></a>")
        parts.append(f"<div>{escape(status)}</div>")
        if f.get("summary"):
            parts.append(_figures(f["summary"]))
        if f.get("outputs"):
            parts.append("<div>" + " ".join(f"<a href='{quote(o)}'>{escape(o.rsplit('.', 1)[-1])}</a>"
                                             for o in f["outputs"]) + "</div>")
        if f.get("error"):
            parts.append(f"<div class=err>{escape(f['error'])}</div>")
        for w in f.get("warnings", []):
            parts.append(f"<div class=warn>warning: {escape(w)}</div>")
        parts.append("</div>")
        cards.append("".join(parts))
    counts = "".join(f"<span>{escape(k)}: <b>{v}</b></span>" for k, v in c.items())
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>doodlecam batch: {escape(report['input_dir'])}</title>"
            f"<style>{_CSS}</style></head><body><h1>doodlecam batch: {escape(report['input_dir'])}</h1>"
            f"<p class=counts>{counts}<span>time: {report['elapsed_s']:.1f} s</span>"
            + ("<span><b>interrupted</b>: re-run to resume</span>" if report.get("interrupted") else "")
            + f"</p><div class=grid>{''.join(cards)}</div></body></html>\n")


# ---------------------------------------------------------------- reports


def write_reports(result: BatchResult, in_dir: Path, out_dir: Path, options: BatchOptions, key: str) -> None:
    report = {
        "doodlecam": __version__,
        "input_dir": str(in_dir),
        "output_dir": str(out_dir),
        "options": dataclasses.asdict(options),
        "options_hash": key,
        "elapsed_s": result.elapsed_s,
        "interrupted": result.interrupted,
        "counts": {s: result.count(s) for s in ("converted", "skipped", "failed", "unsupported")},
        "peak_worker_rss_mb": result.peak_rss_mb,
        "workers": result.workers,
        "files": result.files,
    }
    write_atomic(out_dir / REPORT_NAME, json.dumps(report, indent=1, ensure_ascii=False).encode("utf-8"))
    write_atomic(out_dir / INDEX_NAME, index_html(report).encode("utf-8"))


def summary_table(result: BatchResult, limit: int = 40) -> str:
    """The end-of-batch table: one row per file (failures always; others up to ``limit``)."""
    rows = [f for f in result.files if f["status"] in ("converted", "skipped")]
    bad = [f for f in result.files if f["status"] in ("failed", "unsupported")]
    lines = []
    hdr = f"{'file':<32} {'status':<11} {'strokes':>7} {'pen-down mm':>11} {'travel mm':>10} {'time s':>8}  notes"
    lines.append(hdr)
    lines.append("-" * len(hdr))
    shown = rows if len(rows) <= limit else rows[:limit]
    for f in shown + bad:
        s = f.get("summary") or {}
        name = f["input"] if len(f["input"]) <= 32 else "..." + f["input"][-29:]
        notes = f.get("error") or "; ".join(f.get("warnings", []))
        if s:
            lines.append(f"{name:<32} {f['status']:<11} {s['strokes']:>7} {s['pen_down_mm']:>11.1f} "
                         f"{s['travel_mm']:>10.1f} {s['job_time_s']:>8.1f}  {notes}")
        else:
            lines.append(f"{name:<32} {f['status']:<11} {'':>7} {'':>11} {'':>10} {'':>8}  {notes}")
    if len(rows) > len(shown):
        lines.append(f"... {len(rows) - len(shown)} more converted files (see report.json / index.html)")
    lines.append("-" * len(hdr))
    lines.append(f"{result.count('converted')} converted, {result.count('skipped')} up to date, "
                 f"{result.failed} failed, {result.count('unsupported')} unsupported in {result.elapsed_s:.1f} s"
                 + ("  (interrupted: re-run to resume)" if result.interrupted else ""))
    if result.workers:
        lines.append(f"{len(result.workers)} worker processes, peak memory {result.peak_rss_mb or 0:.0f} MB "
                     f"(per worker: report.json 'workers')")
    return "\n".join(lines)
