"""A batch's reports: the summary table, report.json, and index.html (one card per file with
its SVG preview and figures; previews are linked, not copied, so the page stays small).
"""

from __future__ import annotations

import dataclasses
import json
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


def index_html(report: dict[str, Any]) -> str:
    """The page: doodlecam/templates/batch_index.html (package data), autoescaped by jinja2."""
    from jinja2 import Environment, PackageLoader, select_autoescape

    env = Environment(loader=PackageLoader("doodlecam", "templates"), autoescape=select_autoescape(["html"]),
                      keep_trailing_newline=True)
    env.filters["urlquote"] = quote  # links to outputs whose names hold spaces, '#', '?' ...
    env.tests["svgfile"] = lambda name: str(name).endswith(".svg")
    return env.get_template("batch_index.html").render(report=report)


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
