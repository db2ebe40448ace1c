"""Layout: a traced drawing placed in the machine's work area, in millimetres.

Pictures keep their framing (the whole canvas is fitted, not just the inked
part, unless ``fit = "ink"``); the aspect ratio is always kept; the drawing is
centred inside the margin, optionally rotated by a quarter turn when that
makes it larger (``rotate = "auto"``), or set to a target size (``width`` /
``height`` in mm) or a fixed ``scale`` (mm per drawing unit: 1 draws an SVG
in mm at its true size). Image rows (y down) become machine y (up), and
strokes shorter than the pen width are dropped: they would only leave a dot.

Image tracers put a pixel's centre at its integer index, so a W x H picture's
canvas is [-0.5, W - 0.5] x [-0.5, H - 0.5] (``units == "px"``); other
drawings may name their canvas in ``meta["canvas"] = (x0, y0, x1, y1)``.

Options come from the profile's ``[layout]`` / ``[order]`` tables, overridden
by the CLI; both are checked here so that a bad value fails before any work.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from doodlecam.errors import InputError
from doodlecam.model import Drawing
from doodlecam.options import layout_options

def _canvas(drawing: Drawing, pts: np.ndarray, fit: str) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) in drawing units: the frame to fit."""
    x, y = pts[:, 0], pts[:, 1]  # a column at a time: reductions along axis 0 of (n, 2) are ~20x slower
    ink = (x.min(), y.min(), x.max(), y.max())
    if fit == "ink":
        return ink
    frame = drawing.meta.get("canvas")
    if frame is None and drawing.extent is not None:
        w, h = drawing.extent
        off = 0.5 if drawing.units == "px" else 0.0  # pixel centres at integer indices
        frame = (-off, -off, w - off, h - off)
    if frame is None:
        return ink
    return (min(frame[0], ink[0]), min(frame[1], ink[1]), max(frame[2], ink[2]), max(frame[3], ink[3]))


def _area(machine, opt: dict[str, Any], src: str) -> tuple[float, float]:
    """(width, height) mm the drawing fits into: the work area, or the page centred on it,
    less the margin. Raises InputError when the page or the margin leaves no room."""
    margin = machine.margin if opt["margin"] is None else opt["margin"]
    pw, ph = machine.width, machine.height
    if opt["page"] is not None:
        pw, ph = opt["page"]
        if opt["orientation"] is not None and (pw > ph) != (opt["orientation"] == "landscape"):
            pw, ph = ph, pw
        if pw > machine.width * (1 + 1e-9) or ph > machine.height * (1 + 1e-9):
            turn = " (try the other orientation)" if ph <= machine.width and pw <= machine.height else ""
            raise InputError(f"{src}: a {pw:g} x {ph:g} mm page does not fit the {machine.width:g} x {machine.height:g} mm "
                             f"work area of machine '{machine.name}'; choose a smaller page{turn}")
    aw, ah = pw - 2 * margin, ph - 2 * margin
    if aw <= 0 or ah <= 0:
        raise InputError(f"{src}: margin {margin:g} mm leaves no room on the {pw:g} x {ph:g} mm "
                         f"{'page' if opt['page'] else 'work area'}; use a smaller margin")
    return aw, ah


def _scale(w: float, h: float, aw: float, ah: float, opt: dict[str, Any]) -> tuple[int, float]:
    """(quarter turns, mm per drawing unit) of a w x h frame in an aw x ah mm area."""

    def fill(turns: int) -> float:  # the scale that fills the area
        cw, ch = (w, h) if turns % 2 == 0 else (h, w)
        return min(aw / cw, ah / ch)

    # auto: the quarter turn only when it makes the drawing larger (squarish pictures stay upright)
    turns = (1 if fill(1) > fill(0) * (1 + 1e-9) else 0) if opt["rotate"] == "auto" else int(opt["rotate"]) // 90
    cw, ch = (w, h) if turns % 2 == 0 else (h, w)
    if opt["scale"] is not None:
        return turns, float(opt["scale"])
    if opt["width"] is not None or opt["height"] is not None:
        return turns, float(min(opt["width"] / cw if opt["width"] is not None else np.inf,
                                opt["height"] / ch if opt["height"] is not None else np.inf))
    return turns, fill(turns)


def picture_scale(width_px: float, height_px: float, machine, options: dict[str, Any] | None = None,
                  src: str = "picture") -> float | None:
    """mm per pixel a width x height px picture will be drawn at (laid out by its
    canvas), known before tracing; None when the layout fits the ink instead."""
    opt = layout_options({**getattr(machine, "layout", {}), **(options or {})})
    if opt["fit"] == "ink" or width_px <= 0 or height_px <= 0:
        return None
    return _scale(width_px, height_px, *_area(machine, opt, src), opt)[1]


_BLOCK = 1 << 15  # points transformed at a time (fit_to_work_area): four buffers of 256 kB


def fit_to_work_area(drawing: Drawing, machine, options: dict[str, Any] | None = None) -> Drawing:
    """The drawing in machine millimetres, inside the work area's margin.

    ``options`` override the profile's ``[layout]`` table (keys as
    ``LAYOUT_DEFAULTS``). Raises InputError when there is nothing to draw or
    the requested size does not fit.
    """
    opt = layout_options({**getattr(machine, "layout", {}), **(options or {})})
    src = drawing.source or "drawing"
    if not drawing.polylines:
        raise InputError(f"{src}: nothing to draw; try other tracer options or another picture")
    pts = np.concatenate(drawing.polylines)
    if not np.isfinite(pts.ravel()).all():
        raise InputError(f"{src}: the drawing has non-finite coordinates; check the file")
    x0, y0, x1, y1 = _canvas(drawing, pts, opt["fit"])
    if drawing.y_down:  # to y up: flip about the canvas
        y0, y1 = -y1, -y0
    flip_y = -1.0 if drawing.y_down else 1.0
    aw, ah = _area(machine, opt, src)
    w, h = max(x1 - x0, 1e-9), max(y1 - y0, 1e-9)
    turns, scale = _scale(w, h, aw, ah, opt)
    cw, ch = (w, h) if turns % 2 == 0 else (h, w)
    if cw * scale > aw * (1 + 1e-9) or ch * scale > ah * (1 + 1e-9):
        raise InputError(
            f"{src}: at {cw * scale:.1f} x {ch * scale:.1f} mm the drawing does not fit the "
            f"{aw:g} x {ah:g} mm inside the margin of machine '{machine.name}'; choose a smaller size or scale")
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    ox, oy = machine.width / 2, machine.height / 2  # the page (or the work area) is centred
    cos, sin = [(1, 0), (0, 1), (-1, 0), (0, -1)][turns]
    min_len = machine.pen.width if opt["min_length"] is None else opt["min_length"]
    # All points at once: thousands of hatch strokes cost one pass, not a loop. In place, a block of
    # points at a time through four small buffers: arrays of millions of points are fresh pages at every
    # allocation (a 2.6 M-point drawing's temporaries were ~130 MB of page faults), the buffers stay in cache.
    q = pts  # the concatenation is this function's own copy
    buf = np.empty((4, min(_BLOCK, len(q))))
    for i in range(0, len(q), _BLOCK):
        j = min(i + _BLOCK, len(q))
        x, y, a, b = buf[:, :j - i]
        np.subtract(q[i:j, 0], cx, out=x)
        np.multiply(flip_y, q[i:j, 1], out=y)
        y -= cy
        np.multiply(cos, x, out=a)
        np.multiply(sin, y, out=b)
        a -= b
        a *= scale
        np.add(ox, a, out=q[i:j, 0])  # ox + scale (cos x - sin y)
        np.multiply(sin, x, out=a)
        np.multiply(cos, y, out=b)
        a += b
        a *= scale
        np.add(oy, a, out=q[i:j, 1])  # oy + scale (sin x + cos y)
    counts = np.array([len(p) for p in drawing.polylines])
    stop = np.cumsum(counts)
    cum = np.zeros(len(q))
    for i in range(1, len(q), _BLOCK):  # each point's step from the one before
        j = min(i + _BLOCK, len(q))
        dx, dy = buf[:2, :j - i]
        np.subtract(q[i:j, 0], q[i - 1:j - 1, 0], out=dx)
        np.subtract(q[i:j, 1], q[i - 1:j - 1, 1], out=dy)
        np.hypot(dx, dy, out=cum[i:j])
    cum[stop[:-1]] = 0.0  # no segment between one polyline's end and the next one's start
    np.cumsum(cum, out=cum)
    lengths = cum[stop - 1] - cum[stop - counts]
    keep = (counts >= 2) & (lengths >= max(min_len, 1e-9))
    out = [piece for piece, k in zip(np.split(q, stop[:-1]), keep) if k]
    if not out:
        raise InputError(f"{src}: every stroke is shorter than {min_len:g} mm (the pen width) at this size; "
                         "draw it larger or use a finer pen")
    meta = dict(drawing.meta, scale_mm_per_unit=scale, rotation_deg=90 * turns,
                size_mm=(cw * scale, ch * scale), dropped_short=len(drawing.polylines) - len(out),
                min_length_mm=min_len)
    meta.pop("canvas", None)
    layers = tuple(n for n, k in zip(drawing.layers, keep) if k)
    return Drawing(tuple(out), units="mm", y_down=False, source=drawing.source,
                   extent=(machine.width, machine.height), meta=meta, layers=layers)
