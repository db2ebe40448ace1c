"""The built-in ``contours`` tracer: a two-colour rendering of a picture.

The picture is split into dark and light at a threshold (Otsu's, or a grey
level you give); the outlines of the dark regions, holes included, become
closed strokes. The outlines are the sub-pixel iso-lines of the (lightly
blurred) grey levels at the threshold, so they are smooth rather than pixel
staircases, and a region touching the picture's edge is closed along it.
With ``fill`` the dark regions are also hatched, so dark stays dark on paper.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.plugins.edges import CORNER, CORNER_HELP, check_corner
from doodlecam.trace.raster import IMAGE_EXTENSIONS, in_picture_px, load_working


class ContoursTracer(Tracer):
    name = "contours"
    summary = "Outlines of the dark regions (with holes), optionally hatched: a two-colour rendering"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("threshold", str, "otsu", "grey level (0-1) that splits dark from light, or 'otsu' to choose it"),
        Option("invert", bool, False, "outline the light regions instead (light drawing on dark paper)"),
        Option("blur", float, 1.0, "Gaussian blur in px before thresholding; smooths outlines and noise"),
        Option("min_area", float, 16.0, "drop outlines enclosing less than this many px^2 (specks, dust)"),
        Option("simplify", float, 0.3, "line simplification tolerance in px (Ramer-Douglas-Peucker)"),
        Option("fill", bool, False, "hatch the dark regions too, so they stay dark on paper"),
        Option("fill_spacing", float, 3.0, "distance between fill lines in px"),
        Option("fill_angle", float, 45.0, "angle of the fill lines in degrees"),
        Option("fill_cross", bool, False, "cross-hatch the fill (a second layer at right angles)"),
        Option("pixel_mm", float, 0.0, "trace the picture scaled (down, or up if coarser) to this many mm per pixel "
               "as drawn (0 = the pen width), so px options mean the same drawn size at any resolution"),
        Option("corner", float, CORNER, CORNER_HELP),
    )

    @classmethod
    def layer_names(cls, options):
        return ()  # a picture's lines are one layer (--layer is refused before tracing)

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in pixels: x = column, y = row (down), pixel centres at integers."""
        from skimage import measure

        from doodlecam.plugins.edges import simplify
        from doodlecam.plugins.hatch import hatch_mask

        opt = self.resolve_options(options)
        check_corner(self.name, opt["corner"])
        if opt["blur"] < 0 or opt["min_area"] < 0 or opt["simplify"] < 0 or opt["fill_spacing"] < 0.5:
            raise PluginError("tracer 'contours': blur, min_area and simplify must be >= 0 and fill_spacing >= 0.5")
        gray, shape = load_working(path, self, opt["pixel_mm"], upscale=True)
        # The size options are px of the pen-width grid the picture is traced on
        # (scaled up or down to it): a picture drawn within 5 % of that grid (not
        # resampled) gets them scaled to its own px, so the specks dropped mean the
        # same drawn size at any resolution. The blur stays in working px.
        k = _grid_px(self, opt["pixel_mm"], shape, gray.shape)
        blur, min_area, simp = opt["blur"], opt["min_area"] / (k * k), opt["simplify"] / k
        gray = gray.astype(np.float32)
        if opt["invert"]:
            gray = 1.0 - gray
        if blur > 0:
            from scipy import ndimage as ndi

            gray = ndi.gaussian_filter(gray, blur, mode="nearest")
        level = self.level(gray, opt["threshold"], path)
        # A light frame closes regions that touch the picture's edge, along the
        # edge itself: each frame value mirrors its neighbour about the level,
        # so the iso-line crosses exactly half-way, at the canvas border.
        padded = np.pad(gray, 1, mode="edge")
        frame = np.ones(padded.shape, bool)
        frame[1:-1, 1:-1] = False
        v = padded[frame]
        padded[frame] = np.where(v < level, 2 * level - v, np.maximum(v, level + 1e-6))
        rings = [c[:, ::-1] - 1.0 for c in measure.find_contours(padded, level)]  # (row, col) -> (x, y)
        rings = [np.vstack([c, c[:1]]) if not np.array_equal(c[0], c[-1]) else c for c in rings]
        area = _areas(rings)
        rings = [c for c, a in zip(rings, area) if abs(a) >= max(min_area, 1e-9)]
        if simp > 0:
            rings = simplify(rings, simp)
        polylines = [c for c in rings if len(c) >= 3]
        n_outlines = len(polylines)
        if opt["fill"]:
            from skimage import morphology

            # the same specks the outlines drop are not filled either
            dark = morphology.remove_small_objects(gray < level, max_size=max(int(min_area), 1))
            polylines += hatch_mask(dark, opt["fill_spacing"] / k, opt["fill_angle"], min_length=1.0)
            if opt["fill_cross"]:
                polylines += hatch_mask(dark, opt["fill_spacing"] / k, opt["fill_angle"] + 90, min_length=1.0)
        if not polylines:
            raise InputError(f"{path}: no dark regions at threshold {level:.3f} (the picture looks blank); "
                             "try --tracer-opt threshold=0.7 or invert=true")
        h, w = gray.shape
        return in_picture_px(Drawing(
            tuple(polylines), units="px", y_down=True, source=str(path), extent=(float(w), float(h)),
            meta={"tracer": self.name, "options": opt, "threshold": level, "outlines": n_outlines,
                  "blur_px": blur, "min_area_px": min_area,  # as used, in the picture's working px
                  "polylines": len(polylines), "vertices": int(sum(len(p) for p in polylines)),
                  "traced_corners_deg": float(opt["corner"]), "corner_blur_px": float(blur)}), shape)

    @staticmethod
    def level(gray: np.ndarray, threshold: str, path) -> float:
        """The grey level splitting dark from light: Otsu's or the one given."""
        text = str(threshold).strip().lower()
        if text == "otsu":
            lo, hi = float(gray.min()), float(gray.max())
            if hi - lo < 0.02:  # one flat tone: nothing to split
                raise InputError(f"{path}: the picture is one flat tone, nothing to outline; "
                                 "give a picture with contrast or --tracer-opt threshold=LEVEL")
            from skimage.filters import threshold_otsu

            return float(threshold_otsu(gray))
        try:
            level = float(text)
        except ValueError:
            raise PluginError(f"tracer 'contours': threshold must be 'otsu' or a grey level 0-1, got {threshold!r}") from None
        if not 0.0 < level < 1.0:
            raise PluginError(f"tracer 'contours': threshold must be between 0 and 1, got {level:g}")
        return level


def _grid_px(tracer: Tracer, pixel_mm: float, shape: tuple[int, int], working: tuple[int, int]) -> float:
    """Pen-width grid px per working px when the picture was not resampled and its
    drawn size is known; else 1 (a resampled picture is on the grid already)."""
    from doodlecam.trace.raster import grid_scale

    k = grid_scale(tracer, pixel_mm)
    return k if k and tuple(working) == tuple(shape) else 1.0


def _areas(rings: list[np.ndarray]) -> np.ndarray:
    """Signed shoelace area of every closed ring, in one pass over all points."""
    if not rings:
        return np.zeros(0)
    counts = np.array([len(c) for c in rings])
    pts = np.concatenate(rings)
    cross = pts[:-1, 0] * pts[1:, 1] - pts[1:, 0] * pts[:-1, 1]
    cross = np.r_[cross, 0.0]
    cross[np.cumsum(counts) - 1] = 0.0  # no term from one ring's last point to the next ring's first
    return 0.5 * np.add.reduceat(cross, np.r_[0, np.cumsum(counts)[:-1]])
