"""A single-file drop-in post: a plain-text report of the planned job.

No package, no install: pass the folder holding this file with
``--plugin-dir samples/plugins`` (or list it in $DOODLECAM_PLUGIN_PATH), then
``doodlecam convert in.png --plugin-dir samples/plugins --post stats``.
"""

from __future__ import annotations

from doodlecam.api import Option, PostProcessor


class StatsPost(PostProcessor):
    name = "stats"
    summary = "Plain-text report: per-stroke length, planned time and peak speed (drop-in example)"
    extension = ".stats.txt"
    options = (Option("top", int, 5, "how many of the slowest strokes to list"),)

    def write(self, job, options):
        import numpy as np

        rows = []
        for i, st in enumerate(job.strokes):
            p = st.profile
            speed = np.linalg.norm(st.spline(p.u, 1), axis=1) * np.sqrt(np.maximum(p.b, 0.0))
            rows.append((i, st.spline.length, p.duration, float(speed.max())))
        lines = [f"job {job.source} on {job.machine.name}",
                 f"strokes {len(job.strokes)}",
                 f"pen-down {job.pen_down_length:.1f} mm, travel {job.travel_length:.1f} mm",
                 f"planned time {job.duration:.2f} s",
                 f"slowest strokes (mean speed), top {options['top']}:"]
        for i, length, t, vmax in sorted(rows, key=lambda r: r[1] / max(r[2], 1e-9))[: options["top"]]:
            lines.append(f"  stroke {i}: {length:.1f} mm in {t:.2f} s, peak {vmax:.1f} mm/s")
        return ("\n".join(lines) + "\n").encode()
