"""CSV post-processor: the MOTDES-style motion table of the planned job.

Kirecci's MOTDES exports position, velocity, acceleration and jerk tables of a
designed motion at a fixed time step; this post does the same for the whole
planned job, on the job clock: pen-up travels (the machine's travel law),
pen-down/-up settle delays (the pen at rest) and strokes (the planned
time-optimal profile, evaluated exactly: v = q'·u̇, a = q''·u̇² + q'·ü,
j = q'''·u̇³ + 3·q''·u̇·ü, since ü is constant on each planning interval).

Columns: ``t`` (s), ``x, y`` (mm), ``vx, vy`` (mm/s), ``ax, ay`` (mm/s²),
``jerk`` (|j|, mm/s³), ``jx, jy`` (mm/s³) and ``pen`` (1 = down). Times are
planned times: strokes use the continuous profile, not the whole-period
samples, so the last ``t`` can be a little below the summary's job time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from doodlecam.api import Option, PostProcessor
from doodlecam.errors import OutputError, PluginError

COLUMNS = ("t", "x", "y", "vx", "vy", "ax", "ay", "jerk", "jx", "jy", "pen")


def stroke_state(stroke, t: np.ndarray) -> np.ndarray:
    """(4, n, 2): position, velocity, acceleration, jerk of a stroke at plan times t (s)."""
    u, ud, udd = stroke.profile.state_at(t)
    sp = stroke.spline
    d1, d2, d3 = sp(u, 1), sp(u, 2), sp(u, 3)
    ud, udd = ud[:, None], udd[:, None]
    return np.stack([sp(u), d1 * ud, d2 * ud ** 2 + d1 * udd, d3 * ud ** 3 + 3 * d2 * ud * udd])


class CsvPost(PostProcessor):
    name = "csv"
    summary = "MOTDES-style motion table: t, x, y, vx, vy, ax, ay, jerk (+ jx, jy, pen) at a fixed time step"
    extension = ".csv"
    options = (
        Option("step", float, 0.01, "time step (s) between rows"),
        Option("travels", bool, True, "include pen-up travels and pen delays (else pen-down strokes only)"),
        Option("decimals", int, 6, "decimals written per value"),
        Option("comments", bool, True, "start with '# ' lines naming the job, units and columns"),
    )

    def write(self, job, options: dict[str, Any]) -> bytes:
        from doodlecam.plan.travel import travel_state

        step, dec = float(options["step"]), int(options["decimals"])
        if not step > 0 or not 0 <= dec <= 12:
            raise PluginError(f"postprocessor 'csv': 'step' must be positive and 'decimals' 0..12, got {step!r}, {dec!r}")
        m = job.machine
        # The job as a timeline of (duration, state function, pen) pieces.
        pieces = []

        def rest(point, duration, pen):
            if duration > 0:
                p = np.asarray(point, float)
                pieces.append((duration, lambda t, p=p: np.stack([np.broadcast_to(p, (len(t), 2)), *np.zeros((3, len(t), 2))]), pen))

        lifts = job.lifts + (True,)  # no pen delays (nor a zero travel) where the pen stays down
        for i, tr in enumerate(job.travels):
            if options["travels"] and lifts[i]:
                pieces.append((tr.duration, lambda t, tr=tr: travel_state(tr, m, t), 0))
            if i < len(job.strokes):
                st = job.strokes[i]
                if st.profile is None:
                    raise OutputError("job is not planned (a stroke has no feed profile); plan it before writing the table")
                if options["travels"] and lifts[i]:
                    rest(st.spline.start, m.pen.down_delay, 1)
                pieces.append((st.profile.duration, lambda t, st=st: stroke_state(st, t), 1))
                if options["travels"] and lifts[i + 1]:
                    rest(st.spline.end, m.pen.up_delay, 0)
        total = sum(p[0] for p in pieces)
        n = int(np.floor(total / step + 1e-9)) + 1
        grid = np.append(np.arange(n) * step, [] if abs((n - 1) * step - total) < 1e-9 else [total])
        rows = []
        t0 = 0.0
        for k, (dur, fn, pen) in enumerate(pieces):
            last = k == len(pieces) - 1
            sel = (grid >= t0 - 1e-12) & ((grid <= t0 + dur + 1e-12) if last else (grid < t0 + dur))
            tt = grid[sel]
            if len(tt):
                s = np.asarray(fn(np.clip(tt - t0, 0.0, dur)), float)
                j = s[3]
                rows.append(np.column_stack([tt, s[0], s[1], s[2], np.linalg.norm(j, axis=1), j, np.full(len(tt), pen)]))
            t0 += dur
        table = np.round(np.vstack(rows), dec) + 0.0 if rows else np.zeros((0, len(COLUMNS)))  # + 0.0: no "-0"
        out = []
        if options["comments"]:
            out += [f"# doodlecam motion table: {job.source or 'job'} on {m.name}",
                    f"# step {step:g} s, {len(table)} rows, planned time {total:.3f} s",
                    "# units: t s; x, y mm; vx, vy mm/s; ax, ay mm/s^2; jerk, jx, jy mm/s^3; pen 1 = down"]
        out.append(",".join(COLUMNS))
        fmt = ",".join([f"%.{dec}f"] * (len(COLUMNS) - 1) + ["%d"])
        body = "\n".join(fmt % tuple(r) for r in table.tolist()) if len(table) else ""
        text = "\n".join(out) + "\n" + (body + "\n" if body else "")
        return text.encode("ascii")
