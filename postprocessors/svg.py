"""SVG preview post-processor: what the pen will draw, and where it travels.

One SVG user unit is one machine millimetre. Machine y points up and SVG y
points down, so every point is written as (x, height - y): the preview looks
upright without a transform (which would confuse editors' layer coordinates).
Pen-down strokes and pen-up travels are separate Inkscape layers. A cubic
stroke is written exactly, one SVG cubic Bezier per polynomial piece of the
spline; other degrees as a polyline ``step`` mm apart.
"""

from __future__ import annotations

from typing import Any
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from doodlecam.api import Option, PostProcessor
from doodlecam.errors import PluginError
from doodlecam.geometry.spline_batch import eval_many, offsets

PAD = 2.0  # mm around the work area, so its outline is not clipped


def _path_d(p: np.ndarray) -> str:
    xy = [f"{x:.3f} {y:.3f}" for x, y in np.round(p, 3).tolist()]
    return "M" + xy[0] + "L" + " ".join(xy[1:] or xy[:1])


def _segments_d(a: np.ndarray, b: np.ndarray) -> list[str]:
    """_path_d of every segment a[k]-b[k] (rows, already flipped): one format call for all of them."""
    if not len(a):
        return []
    xy = np.round(np.stack([a, b], axis=1), 3).reshape(len(a), 4).tolist()
    return ("\n".join(["M%.3f %.3fL%.3f %.3f"] * len(xy)) % tuple(v for r in xy for v in r)).split("\n")


def _cubic_ds(splines, flip) -> list[str]:
    """SvgPost._stroke_d of cubic splines, all at once: their end points and derivatives at the breakpoints in
    one compiled call, the Bezier points in array operations over all of them (the same per element as one
    stroke's), one format call for every number (a stroke at a time cost ~40 us of Python each)."""
    if not splines:
        return []
    bps = [s.breakpoints for s in splines]
    n = np.fromiter((len(b) for b in bps), np.int64, len(bps))
    u = np.concatenate(bps)
    at = (u, offsets(n))
    q, d1 = eval_many(splines, at), eval_many(splines, at, 1)
    last = np.cumsum(n) - 1  # each spline's last breakpoint
    a = np.ones(len(u), bool)
    a[last] = False
    a = np.flatnonzero(a)  # the start of every polynomial piece
    h = (u[a + 1] - u[a])[:, None]
    ctrl = np.stack([q[a] + d1[a] * h / 3, q[a + 1] - d1[a + 1] * h / 3, q[a + 1]], axis=1).reshape(-1, 2)
    head = np.round(q[last - n + 1] * flip[0] + flip[1], 3)
    ctrl = np.round(ctrl * flip[0] + flip[1], 3)
    # each spline's head, then its pieces' 3 points each
    rows = np.empty((len(head) + len(ctrl), 2))
    starts = np.concatenate([[0], np.cumsum(1 + 3 * (n - 1))[:-1]])
    rows[starts] = head
    body = np.ones(len(rows), bool)
    body[starts] = False
    rows[body] = ctrl
    fmts: dict[int, str] = {}
    for k in set((n - 1).tolist()):
        fmts[k] = "M%.3f %.3fC" + " ".join(["%.3f %.3f"] * (3 * k))
    return ("\n".join([fmts[k] for k in (n - 1).tolist()]) % tuple(rows.reshape(-1).tolist())).split("\n")


class SvgPost(PostProcessor):
    name = "svg"
    summary = "SVG preview: pen-down strokes and pen-up travels as layers, in machine mm"
    extension = ".svg"
    options = (
        Option("step", float, 0.2, "largest distance (mm) between preview points along a stroke"),
        Option("pen_width", float, 0.0, "stroke width (mm); 0 uses the machine's pen width"),
        Option("travel_color", str, "#e0201b", "colour of the dashed pen-up travel lines"),
        Option("show_travels", bool, True, "draw the pen-up travels layer's paths"),
    )

    def _stroke_points(self, spline, step: float) -> np.ndarray:
        # Dense enough in length, and at least 8 points per polynomial piece
        # so tight curls survive even when the stroke is short.
        n = max(int(np.ceil(spline.length / step)), 8 * (len(spline.breakpoints) - 1), 2)
        return spline(np.linspace(0.0, 1.0, n + 1))

    def _stroke_d(self, spline, step: float, flip) -> str:
        if spline.degree != 3:
            return _path_d(self._stroke_points(spline, step) * flip[0] + flip[1])
        # a cubic piece on [u0, u1] is the Bezier with end points q and inner points
        # q(u0) + q'(u0) h / 3, q(u1) - q'(u1) h / 3: exact, and far fewer numbers than a polyline
        bp = spline.breakpoints
        q, d1 = spline(bp), spline(bp, 1)
        h = np.diff(bp)[:, None]
        ctrl = np.stack([q[:-1] + d1[:-1] * h / 3, q[1:] - d1[1:] * h / 3, q[1:]], axis=1).reshape(-1, 2)
        head = np.round(q[0] * flip[0] + flip[1], 3)
        xy = " ".join(f"{x:.3f} {y:.3f}" for x, y in np.round(ctrl * flip[0] + flip[1], 3).tolist())
        return f"M{head[0]:.3f} {head[1]:.3f}C{xy}"

    def _strokes_d(self, splines, step: float, flip) -> list[str]:
        """[_stroke_d(s, step, flip) for s in splines], the cubic ones in one batch (_cubic_ds)."""
        cubic = [k for k, s in enumerate(splines) if s.degree == 3]
        out = [None if s.degree == 3 else self._stroke_d(s, step, flip) for s in splines]
        for k, d in zip(cubic, _cubic_ds([splines[k] for k in cubic], flip)):
            out[k] = d
        return out

    def _pen_layers(self, job, strokes: list[str], width: float) -> list[str]:
        """The pen-down strokes: one Inkscape layer per pen layer of the job, in its colour."""
        names = job.layers or ("",)
        colours = job.meta.get("layer_colours", {})
        m = job.machine
        # With [[pen]]s in the profile each layer is drawn in its pen's colour and width: what will come out.
        pens = job.layer_pens if getattr(m, "pens", ()) else {}
        out = []
        for k, name in enumerate(names):
            ident = "pen-down" if len(names) == 1 else f"pen-down-{k + 1}"
            pen = m.pen_number(pens[name]) if pens else None
            label = "pen down" + (f": {name}" if name else "") + (f" ({pen.describe(pens[name])})" if pen else "")
            colour = (pen.colour if pen is not None and pen.colour else colours.get(name, "#000"))
            w = pen.width if pen is not None and width == m.pen.width else width
            out += [f'<g id="{ident}" inkscape:groupmode="layer" inkscape:label={quoteattr(label)} fill="none" '
                    f'stroke={quoteattr(colour)} stroke-width="{w:g}" stroke-linecap="round" '
                    'stroke-linejoin="round">',
                    *(f'<path d="{d}"/>' for d, s in zip(strokes, job.strokes) if s.layer == name),
                    "</g>"]
        return out

    def write(self, job, options: dict[str, Any]) -> bytes:
        step = float(options["step"])
        if not step > 0 or options["pen_width"] < 0:
            raise PluginError(f"postprocessor 'svg': options 'step' must be positive and 'pen_width' >= 0, got {step!r}, {options['pen_width']!r}")
        m = job.machine
        W, H = m.width, m.height
        flip = np.array([1.0, -1.0]), np.array([0.0, H])
        width = options["pen_width"] or m.pen.width
        thin = max(0.2, width / 3)

        strokes = self._strokes_d([s.spline for s in job.strokes], step, flip)
        shown = [t for t, lift in zip(job.travels, job.lifts + (True,)) if lift] if options["show_travels"] else []
        travels = _segments_d(np.array([t.start for t in shown], float).reshape(-1, 2) * flip[0] + flip[1],
                              np.array([t.end for t in shown], float).reshape(-1, 2) * flip[0] + flip[1])

        vb = f"{-PAD:g} {-PAD:g} {W + 2 * PAD:g} {H + 2 * PAD:g}"
        out = [
            '<?xml version="1.0" encoding="UTF-8"?>',
            '<svg xmlns="http://www.w3.org/2000/svg" '
            'xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" '
            f'width="{W + 2 * PAD:g}mm" height="{H + 2 * PAD:g}mm" viewBox="{vb}">',
            f"<title>{escape(job.source or 'doodlecam job')} on {escape(m.name)}</title>",
            f"<desc>{len(job.strokes)} strokes, pen-down {job.pen_down_length:.1f} mm, "
            f"travel {job.travel_length:.1f} mm, planned time {job.duration:.1f} s</desc>",
            # Work area and drawable area (inside the margin), not a layer: not plotted.
            f'<rect id="work-area" x="0" y="0" width="{W:g}" height="{H:g}" fill="none" stroke="#888" stroke-width="0.3"/>',
            f'<rect id="margin" x="{m.margin:g}" y="{m.margin:g}" width="{W - 2 * m.margin:g}" height="{H - 2 * m.margin:g}" '
            'fill="none" stroke="#ccc" stroke-width="0.2" stroke-dasharray="2 2"/>',
            *self._pen_layers(job, strokes, width),
            f'<g id="pen-up" inkscape:groupmode="layer" inkscape:label="pen up" fill="none" stroke={quoteattr(options["travel_color"])} '
            f'stroke-width="{thin:g}" stroke-dasharray="{3 * thin:g} {2 * thin:g}">',
            *(f'<path d="{d}"/>' for d in travels),
            "</g>",
            "</svg>",
        ]
        return ("\n".join(out) + "\n").encode("utf-8")
