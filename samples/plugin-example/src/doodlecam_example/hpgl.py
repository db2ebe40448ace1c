"""HP-GL post-processor: a third-party doodlecam plugin, the example to copy.

HP-GL is what vintage pen plotters (HP 7475A, Roland DXY, ...) speak:
``IN`` initialise, ``SP1`` pick pen 1, ``VS`` pen speed (cm/s), ``PU x,y``
move pen-up, ``PD x,y,...`` draw, in plotter units of 0.025 mm (40 per mm).
The plotter has its own fixed acceleration, so the planned profile is carried
only as the stroke's average speed in ``VS``.
"""

from __future__ import annotations

from typing import Any

from doodlecam.api import Option, PostProcessor
from doodlecam.errors import PluginError

UNITS_PER_MM = 40.0


class HpglPost(PostProcessor):
    name = "hpgl"
    summary = "HP-GL for vintage pen plotters (example third-party plugin package)"
    extension = ".hpgl"
    api_version = 1  # the doodlecam plugin API this plugin was written for
    options = (
        Option("pen", int, 1, "pen number selected with SP"),
        Option("step", float, 0.25, "largest distance (mm) between PD points along a stroke"),
        Option("speed", bool, True, "set VS per stroke from its planned average speed"),
    )

    def write(self, job, options: dict[str, Any]) -> bytes:
        import numpy as np  # heavy imports inside methods keep 'doodlecam plugins' fast

        if not options["step"] > 0 or not 1 <= options["pen"] <= 8:
            raise PluginError(f"postprocessor 'hpgl': 'step' must be positive and 'pen' 1..8, got {options['step']}, {options['pen']}")
        out = ["IN;", f"SP{options['pen']};"]
        for st in job.strokes:
            n = max(int(np.ceil(st.spline.length / options["step"])), 1)
            p = np.rint(st.spline(np.linspace(0.0, 1.0, n + 1)) * UNITS_PER_MM).astype(int)
            if options["speed"] and st.duration > 0:
                vs = min(max(st.spline.length / st.duration / 10.0, 0.1), 128.0)  # cm/s
                out.append(f"VS{vs:.1f};")
            out.append(f"PU{p[0, 0]},{p[0, 1]};")
            out.append("PD" + ",".join(f"{x},{y}" for x, y in p[1:].tolist()) + ";")
        home = job.travels[-1].end if job.travels else (0.0, 0.0)
        out += [f"PU{round(home[0] * UNITS_PER_MM)},{round(home[1] * UNITS_PER_MM)};", "SP0;"]
        return ("\n".join(out) + "\n").encode("ascii")
