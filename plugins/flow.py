"""The built-in ``flow`` tracer: long lines that follow the picture's structure, spaced by its tone.

The picture's darkness on a grid in mm gives a structure tensor (Gaussian
derivatives at ``sigma_mm``, their products smoothed at ``smooth_mm``); lines
run along its minor eigenvector, along edges and isophotes, so they wrap
around shapes the way an engraver's lines do. Where the picture is flat the
tensor has no direction of its own, so a faint one at ``angle`` is added:
there the lines are parallel.

Lines are placed by Jobard and Lefer's evenly spaced streamlines
(``doodlecam.plugins.streamlines``) with a separation that follows the tone:
parallel lines of width w spaced s apart ink w / s of the paper, so the
separation wanted at darkness d is ``spacing_mm`` / d, and tones lighter than
``spacing_mm`` / ``max_spacing_mm`` get no lines. A line ends where it would
come nearer another than ``gap`` times the separation wanted there (0.7:
Jobard and Lefer's 0.5 lets converging lines bunch to twice the ink, which
blotches the tone), and never nearer than the pen's width (checked between
samples too, not only at them).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.trace.raster import IMAGE_EXTENSIONS

_BIAS = 0.02  # the flat-area direction's weight, of the tensor's mean trace
_MAX_STEPS = 100_000  # steps per half line at most


class FlowTracer(Tracer):
    name = "flow"
    summary = "Flow lines: long strokes along the picture's structure, spaced by its tone (PNG, JPEG, ...)"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("spacing_mm", float, 0.0, "line separation in the darkest tone, mm; 0 = 2 pen widths"),
        Option("gap", float, 0.7, "a line ends where it comes nearer another than this share of the separation "
               "(Jobard and Lefer's d_test, 0.3-0.95): higher = more even tone, shorter lines; never nearer than "
               "the pen's width whatever the settings"),
        Option("max_spacing_mm", float, 0.0, "separation in the lightest tone still drawn, mm; lighter tones get "
               "no lines; 0 = 8 x spacing_mm"),
        Option("sigma_mm", float, 1.0, "scale of the picture's gradient, mm as drawn"),
        Option("smooth_mm", float, 4.0, "smoothing of the structure tensor, mm: larger = calmer, longer lines"),
        Option("angle", float, 45.0, "direction of the lines where the picture is flat, degrees counter-clockwise"),
        Option("min_length_mm", float, 0.0, "drop lines shorter than this, mm; 0 = 2 x spacing_mm"),
        Option("step_mm", float, 0.0, "integration step along a line, mm; 0 = half the pen width"),
        Option("gamma", float, 1.0, "tone curve: > 1 lightens mid-tones (fewer lines), < 1 darkens them"),
        Option("equalize", bool, False, "stretch the histogram first (CLAHE), for flat, grey photos"),
    )

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in the picture's px: x = column, y = row (down), pixel centres at integers."""
        from scipy import ndimage as ndi

        from doodlecam.plugins.stipple import tone_grid
        from doodlecam.plugins.streamlines import evenly_spaced

        opt = self.resolve_options(options)
        for key in ("spacing_mm", "max_spacing_mm", "min_length_mm", "step_mm"):
            if opt[key] < 0:
                raise PluginError(f"tracer 'flow': {key} must be >= 0, got {opt[key]:g}")
        if opt["sigma_mm"] <= 0 or opt["smooth_mm"] < 0 or opt["gamma"] <= 0:
            raise PluginError("tracer 'flow': sigma_mm and gamma must be > 0 and smooth_mm >= 0")
        if not 0.3 <= opt["gap"] <= 0.95:
            raise PluginError(f"tracer 'flow': gap must be 0.3-0.95, got {opt['gap']:g}")
        pen = self.pen_mm or 0.5
        spacing = opt["spacing_mm"] or 2 * pen
        widest = opt["max_spacing_mm"] or 8 * spacing
        if widest <= spacing:
            raise PluginError(f"tracer 'flow': max_spacing_mm ({widest:g}) must be more than spacing_mm ({spacing:g})")
        step = opt["step_mm"] or pen / 2
        grid = tone_grid(path, self, min(spacing / 4, opt["sigma_mm"] / 2), 0.0, opt["gamma"], opt["equalize"])
        g = grid.cell
        dark = grid.dark
        # structure tensor of the darkness (x = columns, y = rows down)
        ix = ndi.gaussian_filter(dark, opt["sigma_mm"] / g, order=(0, 1), mode="nearest")
        iy = ndi.gaussian_filter(dark, opt["sigma_mm"] / g, order=(1, 0), mode="nearest")
        j11, j12, j22 = ix * ix, ix * iy, iy * iy
        if opt["smooth_mm"] > 0:
            j11, j12, j22 = (ndi.gaussian_filter(j, opt["smooth_mm"] / g, mode="nearest") for j in (j11, j12, j22))
        a = np.radians(opt["angle"])
        nx, ny = np.sin(a), np.cos(a)  # the normal of lines at `angle` on paper (y up), in grid axes (y down)
        bias = _BIAS * float((j11 + j22).mean()) + 1e-12
        fa = j11 - j22 + bias * (nx * nx - ny * ny)
        fb = 2 * j12 + bias * 2 * nx * ny
        with np.errstate(divide="ignore"):
            sep = np.where(dark * widest > spacing, spacing / dark, np.inf)
        if not np.isfinite(sep).any():
            raise InputError(f"{path}: nothing dark enough for flow lines (the picture looks blank); "
                             "try --tracer-opt gamma=0.5 or a larger max_spacing_mm")
        w_mm, h_mm = grid.size
        # fallback seeds: a lattice at the darkest separation, darkest first (then by position: deterministic)
        ys, xs = np.mgrid[spacing / 2:h_mm:spacing, spacing / 2:w_mm:spacing]
        seeds = np.column_stack([xs.ravel(), ys.ravel()])
        tone = grid.sample(seeds)
        order = np.argsort(-tone, kind="stable")
        seeds = seeds[order][tone[order] * widest > spacing]
        min_len = opt["min_length_mm"] or 2 * spacing
        xy, off = evenly_spaced(np.ascontiguousarray(fa), np.ascontiguousarray(fb), np.ascontiguousarray(sep), g,
                                w_mm, h_mm, opt["gap"], step, pen, min_len, _MAX_STEPS, np.ascontiguousarray(seeds))
        lines = [xy[a:b] for a, b in zip(off[:-1], off[1:]) if b - a >= 2]
        if not lines:
            raise InputError(f"{path}: no flow line is longer than {min_len:g} mm; "
                             "try --tracer-opt min_length_mm=1 or a darker gamma")
        lengths = np.array([np.hypot(*np.diff(p, axis=0).T).sum() for p in lines])
        made = (f"{len(lines)} flow lines, {lengths.sum() / 1000:.2f} m in all, {np.median(lengths):.0f} mm median, "
                f"{spacing:.2f}-{widest:.2f} mm apart")
        return grid.drawing(lines, path, {
            "tracer": self.name, "options": opt, "made": made, "lines": len(lines), "line_mm": float(lengths.sum()),
            "spacing_mm": spacing, "max_spacing_mm": widest, "min_gap_mm": max(opt["gap"] * spacing, pen),
            "grid_mm": g, "polylines": len(lines), "vertices": int(len(xy))})
