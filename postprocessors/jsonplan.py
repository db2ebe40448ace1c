"""JSON post-processor: the whole plan, for other tools and notebooks.

One UTF-8 JSON object, ``"format": "doodlecam-plan"``, ``"version": 1``:
the machine profile, every stroke (its clamped uniform B-spline: degree and
control points, knots implied; its planned profile on the grid: ``u``,
``b = u̇²`` (1/s²), ``a = ü`` (1/s², per interval), ``t`` (s); ``pen_lift``,
false where it goes on pen down from the last stroke's end), the pen-up
travels, the fixed-ΔT velocity samples and the job's figures. Units: mm, s.
Floats are written with ``repr`` precision by default, so the plan reloads
exactly; ``decimals`` rounds them for a smaller file.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import numpy as np

from doodlecam.api import API_VERSION, Option, PostProcessor
from doodlecam.errors import PluginError

FORMAT, VERSION = "doodlecam-plan", 1


def _plain(x: Any, dec: int | None) -> Any:
    """JSON-able copy: arrays to (rounded) lists, dataclasses to dicts, others to str."""
    if isinstance(x, np.ndarray):
        x = np.round(x, dec) if dec is not None else x
        return x.tolist()
    if isinstance(x, (np.floating, float)):
        return round(float(x), dec) if dec is not None else float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {f.name: _plain(getattr(x, f.name), dec) for f in dataclasses.fields(x)}
    if isinstance(x, dict):
        return {str(k): _plain(v, dec) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v, dec) for v in x]
    if x is None or isinstance(x, (bool, int, str)):
        return x
    return str(x)


class JsonPost(PostProcessor):
    name = "json"
    summary = "The whole plan as JSON: machine, splines, feed profiles, travels, velocity samples"
    extension = ".json"
    options = (
        Option("samples", bool, True, "include the fixed-ΔT velocity samples"),
        Option("decimals", int, -1, "round floats to this many decimals (-1: exact, repr precision)"),
        Option("indent", int, 0, "pretty-print with this indent (0: compact)"),
    )

    def write(self, job, options: dict[str, Any]) -> bytes:
        dec = int(options["decimals"])
        if not -1 <= dec <= 15 or options["indent"] < 0:
            raise PluginError(f"postprocessor 'json': 'decimals' must be -1..15 and 'indent' >= 0, got {dec}, {options['indent']}")
        d = None if dec < 0 else dec
        strokes = []
        pens = job.pen_numbers
        for s, pen, lift in zip(job.strokes, pens, job.lifts):
            item = {"degree": s.spline.degree, "control": _plain(s.spline.control, d),
                    "length_mm": _plain(s.spline.length, d), "fit_error_mm": _plain(s.fit_error, d),
                    "source_index": s.source_index, "layer": s.layer, "pen": pen, "pen_lift": lift, "profile": None}
            if s.profile is not None:
                p = s.profile
                item["profile"] = {"solver": p.solver, "duration_s": _plain(p.duration, d),
                                   **{k: _plain(getattr(p, k), d) for k in ("u", "b", "a", "t")}}
            strokes.append(item)
        doc = {
            "format": FORMAT, "version": VERSION, "plugin_api": API_VERSION,
            "source": job.source,
            "machine": _plain(job.machine, d),
            "figures": {"strokes": len(job.strokes), "pen_lifts": job.pen_lifts, "pen_down_mm": _plain(job.pen_down_length, d),
                        "travel_mm": _plain(job.travel_length, d), "draw_time_s": _plain(job.draw_time, d),
                        "job_time_s": _plain(job.duration, d), "pen_changes": list(job.pen_changes),
                        "pen_pauses": list(job.pen_pauses)},
            "strokes": strokes,
            "travels": [{"start": _plain(t.start, d), "end": _plain(t.end, d), "duration_s": _plain(t.duration, d)}
                        for t in job.travels],
            "meta": _plain(job.meta, d),
        }
        if options["samples"]:
            doc["samples"] = [{"start": _plain(s.start, d), "delta_time_s": s.delta_time, "time_scale": _plain(s.time_scale, d),
                               "velocity": _plain(s.velocity, d)} for s in job.samples]
        indent = int(options["indent"]) or None
        text = json.dumps(doc, indent=indent, separators=None if indent else (",", ":"), allow_nan=False, ensure_ascii=False)
        return (text + "\n").encode("utf-8")
