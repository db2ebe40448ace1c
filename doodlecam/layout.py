"""Layout: a traced drawing scaled into the machine's work area.

Pictures keep their framing (the source canvas is fitted, not just the inked
part), aspect ratio is kept, the result is centred inside the margin, image
rows (y down) become machine y (up), and strokes shorter than the pen width
are dropped: they would only leave a dot.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .model import Drawing, polyline_length


def fit_to_work_area(drawing: Drawing, machine) -> Drawing:
    """The drawing in machine millimetres, inside the work area's margin."""
    if not drawing.polylines:
        raise InputError(f"{drawing.source}: nothing to draw; try other tracer options or another picture")
    xmin, ymin, xmax, ymax = drawing.bounds
    if drawing.extent is not None:  # fit the whole canvas, keep the composition
        xmin, ymin = min(xmin, 0.0), min(ymin, 0.0)
        xmax, ymax = max(xmax, drawing.extent[0]), max(ymax, drawing.extent[1])
    w, h = max(xmax - xmin, 1e-9), max(ymax - ymin, 1e-9)
    aw, ah = machine.width - 2 * machine.margin, machine.height - 2 * machine.margin
    scale = min(aw / w, ah / h)
    ox = machine.margin + (aw - w * scale) / 2
    oy = machine.margin + (ah - h * scale) / 2
    out = []
    for p in drawing.polylines:
        x = (p[:, 0] - xmin) * scale + ox
        y = ((ymax - p[:, 1]) if drawing.y_down else (p[:, 1] - ymin)) * scale + oy
        q = np.column_stack([x, y])
        if polyline_length(q) >= machine.pen.width:
            out.append(q)
    if not out:
        raise InputError(f"{drawing.source}: every stroke is shorter than the pen width ({machine.pen.width:g} mm); use a larger picture or a finer pen")
    meta = dict(drawing.meta, scale_mm_per_unit=scale, dropped_short=len(drawing.polylines) - len(out))
    return Drawing(tuple(out), units="mm", y_down=False, source=drawing.source,
                   extent=(machine.width, machine.height), meta=meta)
