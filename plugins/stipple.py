"""The built-in ``stipple`` tracer: a picture's tones as dots (weighted Voronoi stippling).

Secord's method (2002): points are placed by Lloyd relaxation with the
picture's darkness as density, so each point ends at the centroid of its own
Voronoi region weighted by the ink the picture asks for there. Dense where
dark, sparse where light, evenly spread in between (blue noise, no clumps).

Everything is measured on the paper: the picture's darkness is resampled to a
grid in mm (``grid_mm``, a few cells per dot in the darkest tone), and the
number of dots follows from the ink one dot leaves at the pen's width, so the
dots' ink matches the picture's tone. The same picture at any resolution
gives the same dots. One Lloyd step on the grid: a KD-tree of the points
(scipy's cKDTree) answers, for every inked cell at once, which point is
nearest; ``np.bincount`` sums each region's weighted centroid. The first
steps run on a coarser grid (cheap, they move points far), the last on the
full one.

Dots are tiny circles (closed strokes the order may start anywhere) or pen
taps: the pipeline draws strokes, not points, so a tap is the shortest stroke
it keeps, a nudge one pen width long. The pipeline's order puts them in a
short-travel sequence (greedy, 2-opt, Or-opt). ``tone_grid`` and
``stipple_points`` are reusable: the ``tsp`` tracer draws one line through
such points.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.trace.raster import IMAGE_EXTENSIONS, load_gray

UNKNOWN_SIZE_MM = 200.0  # the picture's longer side as drawn, when the tracer is not told (direct calls, fit=ink)
_PEN_MM = 0.5  # pen width assumed when the tracer is not told
_HEX = 2 / np.sqrt(3)  # points per s^2 of a hexagonal packing at spacing s
_CELLS = 16.0  # grid cells per dot region in the darkest tone (the centroid's resolution)
_MAX_CELLS = 1_500_000  # grid cells at most (memory and time): the grid coarsens on huge drawings
_COARSE = 2  # the first steps run on a grid this many times coarser
_CIRCLE = 8  # vertices of a dot circle (the fitter rounds the octagon within its tolerance)


@dataclass(frozen=True)
class ToneGrid:
    """A picture's darkness (0 = paper, 1 = ink) on a grid of ``cell`` mm squares, and how it maps to the picture.

    Cell (r, c) covers [c, c + 1] x [r, r + 1] cells from the picture's top left corner; ``mm_per_px`` is the
    picture's pixel as drawn, so a point (x, y) mm is at pixel (x / mm_per_px - 0.5, y / mm_per_px - 0.5)."""

    dark: np.ndarray
    cell: float
    mm_per_px: float
    shape: tuple[int, int]  # the picture's (rows, cols)
    pen: float  # pen width, mm
    told: bool  # whether the pipeline told the drawn size (else UNKNOWN_SIZE_MM was assumed)

    @property
    def size(self) -> tuple[float, float]:
        """(width, height) of the picture as drawn, mm."""
        return self.shape[1] * self.mm_per_px, self.shape[0] * self.mm_per_px

    def to_px(self, xy: np.ndarray) -> np.ndarray:
        """Points in mm from the top left corner to the picture's px (pixel centres at integers)."""
        return np.asarray(xy, float) / self.mm_per_px - 0.5

    def sample(self, xy: np.ndarray) -> np.ndarray:
        """The darkness at points (n, 2) mm (bilinear, clamped at the border)."""
        from scipy import ndimage as ndi

        rc = np.asarray(xy, float)[:, ::-1] / self.cell - 0.5
        return ndi.map_coordinates(self.dark, rc.T, order=1, mode="nearest")

    def drawing(self, polylines, path: Path, meta: dict[str, Any]) -> Drawing:
        """A Drawing of polylines in mm from the top left corner, in the picture's px."""
        h, w = self.shape
        return Drawing(tuple(self.to_px(p) for p in polylines), units="px", y_down=True, source=str(path),
                       extent=(float(w), float(h)), meta=meta)


def tone_grid(path: Path, tracer: Tracer, cell: float, blur_mm: float = 0.0, gamma: float = 1.0,
              equalize: bool = False) -> ToneGrid:
    """The picture's darkness on a grid of ``cell`` mm (area-averaged or interpolated from its pixels).

    The drawn size is the pipeline's (``Tracer.mm_per_px``) or, when unknown, a longer side of
    ``UNKNOWN_SIZE_MM``; ``blur_mm`` is a Gaussian blur as drawn."""
    from skimage.transform import resize

    from doodlecam.plugins.hatch import darkness

    gray = load_gray(path)
    h, w = gray.shape
    told = bool(tracer.mm_per_px)
    mm = tracer.mm_per_px if told else UNKNOWN_SIZE_MM / max(h, w)
    pen = tracer.pen_mm or _PEN_MM
    rows, cols = max(2, round(h * mm / cell)), max(2, round(w * mm / cell))
    if rows * cols > _MAX_CELLS:
        k = np.sqrt(rows * cols / _MAX_CELLS)
        rows, cols, cell = max(2, round(rows / k)), max(2, round(cols / k)), cell * k
    dark = darkness(gray, 0.0, gamma, equalize)
    grid = resize(dark, (rows, cols), order=1, anti_aliasing=rows < h).astype(np.float64)
    cell = w * mm / cols  # exact (rows and cols are rounded)
    if blur_mm > 0:
        from scipy import ndimage as ndi

        grid = ndi.gaussian_filter(grid, blur_mm / cell, mode="nearest")
    return ToneGrid(np.clip(grid, 0.0, 1.0), cell, mm, (h, w), pen, told)


def stipple_points(grid: ToneGrid, n: int, iterations: int = 30, seed: int = 0) -> np.ndarray:
    """``n`` points (mm from the picture's top left) spread with density proportional to ``grid.dark``.

    Weighted Lloyd relaxation on the grid's cells (Secord 2002): each step moves every point to the
    darkness-weighted centroid of the cells nearest to it. Deterministic for a given seed."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    levels = [_cells(grid.dark, grid.cell, 1)]
    if iterations > 3 and min(grid.dark.shape) >= 4 * _COARSE:
        levels.insert(0, _cells(grid.dark, grid.cell, _COARSE))
    # start: cells drawn with probability by darkness, a random spot in each (a good start halves the steps)
    cells, wt, size = levels[0]
    pts = cells[rng.choice(len(wt), size=n, p=wt / wt.sum())] + (rng.random((n, 2)) - 0.5) * size
    steps = [iterations - iterations // 3, iterations // 3] if len(levels) == 2 else [iterations]
    for (cells, wt, size), count in zip(levels, steps):
        wx, wy = wt * cells[:, 0], wt * cells[:, 1]
        for _ in range(count):
            at = cells + (rng.random(cells.shape) - 0.5) * size  # a random spot in each cell: no grid lock
            wx, wy = wt * at[:, 0], wt * at[:, 1]
            owner = cKDTree(pts).query(at, workers=-1)[1]
            mass = np.bincount(owner, wt, n)
            has = mass > 0
            pts[has, 0] = np.bincount(owner, wx, n)[has] / mass[has]
            pts[has, 1] = np.bincount(owner, wy, n)[has] / mass[has]
            if not has.all():  # a point left without ink (rare: squeezed out) restarts on a random dark cell
                k = int((~has).sum())
                pts[~has] = cells[rng.choice(len(wt), size=k, p=wt / wt.sum())] + (rng.random((k, 2)) - 0.5) * size
    return pts


def _cells(dark: np.ndarray, cell: float, k: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(centres (m, 2) mm, darkness (m,), size mm) of the inked cells of ``dark`` merged k x k
    (a block's centre is its ink's centroid, so the coarse grid weighs the same picture)."""
    h, w = dark.shape
    r0, c0 = np.arange(0, h, k), np.arange(0, w, k)
    yy, xx = np.mgrid[0:h, 0:w]
    sums = [np.add.reduceat(np.add.reduceat(a, r0, axis=0), c0, axis=1)
            for a in (dark, dark * (xx + 0.5), dark * (yy + 0.5))]
    m, sx, sy = sums
    inked = m > 0
    centres = np.column_stack([sx[inked] / m[inked], sy[inked] / m[inked]]) * cell
    return centres, m[inked], cell * k


class StippleTracer(Tracer):
    name = "stipple"
    summary = "Tone as dots: weighted Voronoi stippling, dense where dark (PNG, JPEG, ...)"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("points", int, 0, "number of dots; 0 = as many as make the dots' ink match the picture's tone "
               "at the pen's width"),
        Option("dot", str, "circle", "how a dot is drawn: 'circle' (a tiny circle) or 'tap' (pen down, a nudge "
               "one pen width long, pen up)", choices=("circle", "tap")),
        Option("dot_mm", float, 0.0, "diameter of a dot circle along the pen's centre, mm; 0 = the pen width "
               "(the dot's ink is then two pen widths across)"),
        Option("spacing_mm", float, 0.0, "closest spacing of dots, in the darkest tone, mm; 0 = the dot's ink "
               "diameter (dots just touch in black)"),
        Option("iterations", int, 30, "Lloyd relaxation steps (more: more even spacing, slower)"),
        Option("gamma", float, 1.0, "tone curve: > 1 lightens mid-tones (fewer dots), < 1 darkens them"),
        Option("blur_mm", float, 0.0, "Gaussian blur of the picture first, mm as drawn (0 = none)"),
        Option("equalize", bool, False, "stretch the histogram first (CLAHE), for flat, grey photos"),
        Option("seed", int, 0, "random seed of the starting points (the result is deterministic for a seed)"),
    )

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Dots in the picture's px: x = column, y = row (down), pixel centres at integers."""
        opt = self.resolve_options(options)
        if opt["points"] < 0 or opt["dot_mm"] < 0 or opt["spacing_mm"] < 0 or opt["blur_mm"] < 0:
            raise PluginError("tracer 'stipple': points, dot_mm, spacing_mm and blur_mm must be >= 0")
        if not 0 <= opt["iterations"] <= 500 or opt["gamma"] <= 0:
            raise PluginError("tracer 'stipple': iterations must be 0-500 and gamma > 0")
        pen = self.pen_mm or _PEN_MM
        dot = opt["dot_mm"] or pen
        if opt["dot"] == "circle":
            ink = np.pi / 4 * (dot + pen) ** 2 if dot <= pen else np.pi * dot * pen  # a disc, or a ring
            across = dot + pen
        else:
            ink = pen * pen + np.pi / 4 * pen * pen  # a stadium one pen width long
            across = pen
        spacing = max(opt["spacing_mm"] or across, pen)
        grid = tone_grid(path, self, spacing / np.sqrt(_CELLS * np.sqrt(3) / 2), opt["blur_mm"], opt["gamma"],
                         opt["equalize"])
        cell_area = grid.cell ** 2
        total = float(grid.dark.sum()) * cell_area  # mm^2 of ink the picture asks for
        # darkness d asks for d / ink dots per mm^2, at most the hexagonal packing at `spacing`
        dense = min(1.0 / ink, _HEX / spacing ** 2)
        n = opt["points"] or int(round(total * dense))
        if n < 1 or total <= 0:
            raise InputError(f"{path}: nothing dark enough to stipple (the picture looks blank); "
                             "try --tracer-opt gamma=0.5 or points=N")
        pts = stipple_points(grid, n, opt["iterations"], opt["seed"])
        polylines = dots(pts, opt["dot"], dot, pen)
        spacing_at = _spacings(pts)
        made = (f"{n} dots ({'circles ' + format(dot, '.2f') + ' mm' if opt['dot'] == 'circle' else 'taps'}), "
                f"{np.percentile(spacing_at, 5):.2f}-{np.percentile(spacing_at, 95):.2f} mm apart")
        return grid.drawing(polylines, path, {
            "tracer": self.name, "options": opt, "made": made, "points": n, "dot_ink_mm2": ink,
            "spacing_mm": spacing, "grid_mm": grid.cell, "polylines": len(polylines),
            "vertices": int(sum(len(p) for p in polylines))})


def dots(pts: np.ndarray, kind: str, dot: float, pen: float) -> list[np.ndarray]:
    """A stroke per point (mm): a closed circle of diameter ``dot`` or a tap nudge one pen width long."""
    if kind == "circle":
        a = np.linspace(0, 2 * np.pi, _CIRCLE + 1)
        a[-1] = 0.0  # closed exactly: the order may start a loop anywhere
        ring = 0.5 * dot * np.column_stack([np.cos(a), np.sin(a)])
        return list(pts[:, None, :] + ring[None])
    # 1 % over the pen width: the layout drops strokes shorter than it
    nudge = np.array([[-0.505 * pen, 0.0], [0.505 * pen, 0.0]])
    return list(pts[:, None, :] + nudge[None])


def _spacings(pts: np.ndarray) -> np.ndarray:
    """Distance from each point to its nearest neighbour."""
    from scipy.spatial import cKDTree

    if len(pts) < 2:
        return np.zeros(1)
    return cKDTree(pts).query(pts, k=2)[0][:, 1]
