"""G-code post-processor (GRBL flavour) for pen plotters.

Each stroke becomes short G1 segments along its spline. Segment ends sit at
the planned sample instants, split further until every chord stays within
``chord_tolerance`` of the spline. Each segment's feed is its chord length
over the planned time between its ends, so a controller that follows F
reproduces the time-optimal profile (GRBL's own planner smooths the joins).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from doodlecam.api import Option, PostProcessor
from doodlecam.errors import OutputError, PluginError

MAX_LINE = 80  # GRBL's line buffer


def _num(v: float, decimals: int = 3) -> str:
    s = f"{v:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "", "-") else s


def _t_of_u(profile, u: np.ndarray) -> np.ndarray:
    """Planned time (s) at which the profile reaches each u (exact: b is linear in u)."""
    k = np.clip(np.searchsorted(profile.u, u, side="right") - 1, 0, len(profile.u) - 2)
    du = u - profile.u[k]
    span = profile.u[k + 1] - profile.u[k]
    b0 = np.maximum(profile.b[k], 0.0)
    b = np.maximum(b0 + (profile.b[k + 1] - b0) * du / span, 0.0)
    denom = np.sqrt(b0) + np.sqrt(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = np.where(denom > 0, 2.0 * du / denom, 0.0)
    return profile.t[k] + dt


def _refine(spline, u: np.ndarray, tol: float, max_rounds: int = 30) -> np.ndarray:
    """Split segments at their middle until every chord is within ``tol`` of the spline."""
    f = np.linspace(0.0, 1.0, 9)[1:-1]  # interior probes per segment
    for _ in range(max_rounds):
        p = spline(u)
        a, d = p[:-1], p[1:] - p[:-1]
        uu = u[:-1, None] + (u[1:] - u[:-1])[:, None] * f
        q = spline(uu.ravel()).reshape(len(uu), len(f), 2)
        dd = np.maximum((d * d).sum(1), 1e-300)[:, None]
        s = np.clip(((q - a[:, None]) * d[:, None]).sum(2) / dd, 0.0, 1.0)
        err = np.linalg.norm(q - (a[:, None] + s[..., None] * d[:, None]), axis=2).max(1)
        bad = err > tol
        if not bad.any():
            break
        u = np.sort(np.concatenate([u, 0.5 * (u[:-1] + u[1:])[bad]]))
    return u


class GcodePost(PostProcessor):
    name = "gcode"
    summary = "GRBL-style G-code: G0 travels, G1 strokes whose feeds follow the planned profile"
    extension = ".gcode"
    options = (
        Option("pen_up", str, "M3 S0", "command that lifts the pen (servo on spindle PWM by default)"),
        Option("pen_down", str, "M3 S1000", "command that lowers the pen"),
        Option("chord_tolerance", float, 0.05, "largest distance (mm) between a G1 segment and the spline"),
        Option("min_feed", float, 10.0, "smallest feed (mm/min) written, so no segment has F0"),
        Option("program_end", str, "M2", "last line of the program (M2 or M30)"),
    )

    def _check(self, options: dict[str, Any]) -> None:
        for key in ("pen_up", "pen_down", "program_end"):
            v = options[key]
            if not v.strip() or "\n" in v or "\r" in v or len(v) > MAX_LINE or not v.isascii():
                raise PluginError(f"postprocessor 'gcode': option '{key}' must be one ASCII line of at most {MAX_LINE} characters, got {v!r}")
        for key in ("chord_tolerance", "min_feed"):
            if not options[key] > 0:
                raise PluginError(f"postprocessor 'gcode': option '{key}' must be positive, got {options[key]!r}")

    def _stroke_points(self, stroke, dt: float, tol: float, min_feed: float):
        """Rounded G1 points (n, 2) and the feed (mm/min) of each of the n-1 segments."""
        prof = stroke.profile
        if prof is None:
            raise OutputError("job is not planned (a stroke has no feed profile); plan it before writing G-code")
        t = np.append(np.arange(0.0, prof.duration, dt), prof.duration)
        u = np.unique(np.append(prof.state_at(t)[0], [0.0, 1.0]))
        # Leave room for rounding the coordinates to 3 decimals (<= 0.0007 mm).
        u = _refine(stroke.spline, u, max(tol - 1e-3, 0.5 * tol))
        p = np.round(stroke.spline(u), 3)
        keep = np.ones(len(p), bool)
        keep[1:] = np.any(p[1:] != p[:-1], axis=1)  # drop moves that round to zero length
        if not keep[-1]:  # always end exactly at u = 1
            j = np.flatnonzero(keep)[-1]
            if j > 0:
                keep[j], keep[-1] = False, True
        p, tu = p[keep], _t_of_u(prof, u[keep])
        chord, dtu = np.linalg.norm(np.diff(p, axis=0), axis=1), np.diff(tu)
        with np.errstate(divide="ignore", invalid="ignore"):
            feed = np.where(dtu > 0, 60.0 * chord / dtu, np.inf)
        feed = np.maximum(feed, min_feed)
        if np.isinf(feed).any():  # a zero-time segment (degenerate profile): use the fastest finite feed
            finite = feed[np.isfinite(feed)]
            feed[np.isinf(feed)] = finite.max() if len(finite) else min_feed
        return p, feed

    def write(self, job, options: dict[str, Any]) -> bytes:
        self._check(options)
        m = job.machine
        tol, min_feed = float(options["chord_tolerance"]), float(options["min_feed"])
        dts = [s.delta_time for s in job.samples] if len(job.samples) == len(job.strokes) else []
        paths = [self._stroke_points(s, dts[i] if dts else m.delta_time, tol, min_feed)
                 for i, s in enumerate(job.strokes)]
        home = job.travels[-1].end if job.travels else np.asarray(m.home, float)

        pts = [p for p, _ in paths] + [np.asarray([home])]
        lo, hi = np.concatenate(pts).min(0), np.concatenate(pts).max(0)
        name = "".join(c if c.isascii() and c.isprintable() else "?" for c in m.name)
        head = [
            f"; doodlecam G-code for machine '{name}'",
            f"; planned time {job.duration:.1f} s, {len(job.strokes)} strokes",
            f"; pen-down {job.pen_down_length:.1f} mm, travel {job.travel_length:.1f} mm",
            f"; bounds X {_num(lo[0])}..{_num(hi[0])} Y {_num(lo[1])}..{_num(hi[1])} mm",
        ]
        lines = [h[:MAX_LINE] for h in head]
        lines += ["G21 G90 G94", "G17"]  # mm, absolute, feed per minute, XY plane

        def pen(cmd: str, delay: float) -> None:
            lines.append(cmd)
            if delay > 0:  # GRBL's G4 P is in seconds
                lines.append(f"G4 P{_num(delay)}")

        pen(options["pen_up"], m.pen.up_delay)
        for p, feed in paths:
            lines.append(f"G0 X{_num(p[0, 0])} Y{_num(p[0, 1])}")
            pen(options["pen_down"], m.pen.down_delay)
            last_f = ""
            for (x, y), f in zip(p[1:].tolist(), feed.tolist()):
                fs = _num(max(f, 0.1), 1)  # never print F0
                lines.append(f"G1 X{_num(x)} Y{_num(y)}" + (f" F{fs}" if fs != last_f else ""))
                last_f = fs
            pen(options["pen_up"], m.pen.up_delay)
        lines.append(f"G0 X{_num(home[0])} Y{_num(home[1])}")
        lines.append(options["program_end"])
        return ("\n".join(lines) + "\n").encode("ascii")
