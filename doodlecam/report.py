"""``index.html`` for a batch: one card per file with its SVG preview and figures.

The previews are linked (``<img src="sub/a.svg">``), not copied, so the page
stays small; open it from the output folder.
"""

from __future__ import annotations

from html import escape
from typing import Any
from urllib.parse import quote

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
