"""The built-in ``tsp`` tracer: a picture drawn as one continuous line ("TSP art").

Stipple points are placed as in the ``stipple`` tracer, but for a line: a
tour through points of density rho is about 0.7124 sqrt(rho) mm long per mm^2
(Beardwood, Halton and Hammersley), so its ink at the pen's width w grows
like sqrt(rho); the density is therefore the darkness squared, scaled so the
darkest tone has points ``spacing_mm`` apart. The tour through them is
doodlecam's own stroke order run on points (``order_strokes`` with a free
start and end: greedy, then 2-opt and Or-opt moves over neighbour lists and
double-bridge kicks). Crossings a 2-opt move would remove are then looked for
explicitly (shapely's STRtree over the tour's segments) and removed until
there are none: a crossing tour is never the shortest, and on paper it is a
visible knot.

``curve = "smooth"`` (the default) draws the tour as the uniform cubic
B-spline whose control points are the tour's points: it rounds every corner
(within a sixth of the turn's second difference, a fraction of the spacing),
so the pen keeps its speed through them: about a third less job time than
the straight tour, and the planner's work shrinks as much. Where the rounded
curve would touch itself, the straight tour is drawn there instead.
``"straight"`` draws the tour through the points exactly.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.trace.raster import IMAGE_EXTENSIONS

_BHH = 0.7124  # Beardwood-Halton-Hammersley: tour length ~ _BHH sqrt(n A) for n uniform points in area A
_HEX = 2 / np.sqrt(3)  # points per s^2 of a hexagonal packing at spacing s
_CELLS = 9.0  # grid cells per point region in the darkest tone
_SAMPLES = 3  # points of the smooth curve per tour edge (the fitter needs no more)
_ROUNDS = 1000  # crossing removal rounds at most: a random order of 300 points needs 124, a tour 0 or 1
_SMOOTH_ROUNDS = 20  # rounds making the rounded curve straight where it crosses itself


class TspTracer(Tracer):
    name = "tsp"
    summary = "The picture as one continuous line through stipple points (TSP art) (PNG, JPEG, ...)"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("points", int, 0, "number of points the line passes; 0 = from the tone: the darkest tone gets "
               "points spacing_mm apart"),
        Option("spacing_mm", float, 0.0, "spacing of the points in the darkest tone, mm; 0 = 2 pen widths "
               "(never below one pen width)"),
        Option("curve", str, "smooth", "'smooth': the tour rounded into a B-spline (the pen keeps its speed), "
               "'straight': straight lines through the points", choices=("smooth", "straight")),
        Option("iterations", int, 20, "Lloyd relaxation steps placing the points"),
        Option("gamma", float, 1.0, "tone curve: > 1 lightens mid-tones, < 1 darkens them"),
        Option("blur_mm", float, 0.0, "Gaussian blur of the picture first, mm as drawn (0 = none)"),
        Option("equalize", bool, False, "stretch the histogram first (CLAHE), for flat, grey photos"),
        Option("seed", int, 0, "random seed of the starting points (the result is deterministic for a seed)"),
    )

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """One polyline in the picture's px: x = column, y = row (down), pixel centres at integers."""
        from doodlecam.plugins.stipple import stipple_points, tone_grid

        opt = self.resolve_options(options)
        if opt["points"] < 0 or opt["spacing_mm"] < 0 or opt["blur_mm"] < 0:
            raise PluginError("tracer 'tsp': points, spacing_mm and blur_mm must be >= 0")
        if not 0 <= opt["iterations"] <= 500 or opt["gamma"] <= 0:
            raise PluginError("tracer 'tsp': iterations must be 0-500 and gamma > 0")
        pen = self.pen_mm or 0.5
        spacing = max(opt["spacing_mm"] or 2 * pen, pen)
        grid = tone_grid(path, self, spacing / np.sqrt(_CELLS * np.sqrt(3) / 2), opt["blur_mm"], opt["gamma"],
                         opt["equalize"])
        from dataclasses import replace

        grid = replace(grid, dark=grid.dark ** 2)  # the line's ink grows like sqrt(density)
        n = opt["points"] or int(round(float(grid.dark.sum()) * grid.cell ** 2 * _HEX / spacing ** 2))
        if n < 3:
            raise InputError(f"{path}: too little dark to draw a line through (the picture looks blank); "
                             "try --tracer-opt gamma=0.5 or points=N")
        pts = stipple_points(grid, n, opt["iterations"], opt["seed"])
        tour, fixed = tsp_tour(pts)
        if opt["curve"] == "smooth":
            line, straight = smooth_tour(tour)
        else:
            line, straight = tour, len(tour) - 1
        length = float(np.hypot(*np.diff(line, axis=0).T).sum())
        made = (f"one line through {n} points, {length / 1000:.2f} m long"
                + (f", {straight} of {len(tour) - 1} edges kept straight where the rounded curve met itself"
                   if opt["curve"] == "smooth" and straight else ""))
        return grid.drawing([line], path, {
            "tracer": self.name, "options": opt, "made": made, "points": n, "tour_mm": tour_length(tour),
            "line_mm": length, "crossings_removed": fixed, "straight_edges": straight, "spacing_mm": spacing,
            "polylines": 1, "vertices": len(line)})


def tour_length(tour: np.ndarray) -> float:
    return float(np.hypot(*np.diff(tour, axis=0).T).sum())


def tsp_tour(pts: np.ndarray) -> tuple[np.ndarray, int]:
    """(the points in tour order, an open path, crossings removed): doodlecam's stroke order on
    points (greedy, 2-opt, Or-opt, kicks), then every remaining crossing undone by a 2-opt move."""
    from doodlecam.geometry.order import order_strokes

    # budget None: the same points give the same tour on any machine; the moves cap bounds the work
    o = order_strokes([p[None] for p in pts], home=None, budget=None)
    tour = np.concatenate(o.polylines)
    return uncross(tour)


def crossings(line: np.ndarray) -> np.ndarray:
    """(k, 2) index pairs i < j of segments (line[i], line[i + 1]) that cross properly."""
    import shapely

    segs = shapely.linestrings(np.stack([line[:-1], line[1:]], axis=1))
    a, b = shapely.STRtree(segs).query(segs, predicate="crosses")
    keep = a < b
    return np.column_stack([a[keep], b[keep]])


def uncross(tour: np.ndarray) -> tuple[np.ndarray, int]:
    """The open tour with every proper self-crossing removed by 2-opt moves, and how many were.

    Segments i and j > i cross: reversing tour[i + 1 .. j] replaces them by two shorter ones
    (triangle inequality), so the length drops at every move and the loop ends. Each round
    undoes crossings whose reversed spans do not overlap, then looks again."""
    tour = tour.copy()
    fixed = 0
    for _ in range(_ROUNDS):
        pairs = crossings(tour)
        if not len(pairs):
            return tour, fixed
        pairs = pairs[np.argsort(pairs[:, 1] - pairs[:, 0], kind="stable")]  # short reversals first
        taken = np.zeros(len(tour), bool)
        for i, j in pairs.tolist():
            if taken[i:j + 2].any():
                continue
            tour[i + 1:j + 1] = tour[i + 1:j + 1][::-1].copy()
            taken[i:j + 2] = True
            fixed += 1
    raise PluginError(f"tracer 'tsp': the tour still crosses itself after {_ROUNDS} rounds; report this picture")


def smooth_tour(tour: np.ndarray) -> tuple[np.ndarray, int]:
    """(the tour rounded into its uniform cubic B-spline, sampled, from its first point to its last;
    the number of edges drawn straight where the rounded curve would cross itself)."""
    straight = np.zeros(len(tour) - 1, bool)  # tour edges drawn straight
    for _ in range(_SMOOTH_ROUNDS):
        line, edge_of = _rounded(tour, straight)
        pairs = crossings(line)
        if not len(pairs):
            return line, int(straight.sum())
        hit = edge_of[pairs.ravel()]
        for d in (-2, -1, 0, 1, 2):  # the neighbouring edges too: their curve runs near the crossing
            straight[np.clip(hit + d, 0, len(straight) - 1)] = True
    return tour, len(tour) - 1


def _rounded(tour: np.ndarray, straight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples of the clamped uniform cubic B-spline on ``tour``'s points, except along the
    ``straight`` edges, drawn as the tour; and the tour edge each sample segment belongs to."""
    P = np.vstack([tour[:1], tour[:1], tour, tour[-1:], tour[-1:]])  # tripled ends: the curve starts and ends on them
    t = (np.arange(_SAMPLES) / _SAMPLES)[:, None]
    basis = np.hstack([(1 - t) ** 3, 3 * t ** 3 - 6 * t ** 2 + 4, -3 * t ** 3 + 3 * t ** 2 + 3 * t + 1, t ** 3]) / 6
    spans = np.stack([P[i:len(P) - 3 + i] for i in range(4)], axis=1)  # span m runs near tour edge m - 1
    curve = np.einsum("kj,mjd->mkd", basis, spans)  # (spans, _SAMPLES, 2)
    m = len(curve)
    edge = np.clip(np.arange(m) - 1, 0, len(straight) - 1)
    keep = ~straight[edge]
    # a kept span gives its samples; a straight edge its start point once (its end starts what follows)
    first = ~keep & np.r_[True, (edge[1:] != edge[:-1]) | keep[:-1]]
    use = np.zeros((m, _SAMPLES), bool)
    use[keep] = True
    use[first, 0] = True
    pts = np.where(keep[:, None, None], curve, tour[edge][:, None, :])
    line = np.vstack([pts[use], tour[-1:]])
    owner = np.r_[np.broadcast_to(edge[:, None], use.shape)[use], len(straight) - 1]
    same = np.r_[True, np.any(np.abs(np.diff(line, axis=0)) > 1e-12, axis=1)]  # the clamped ends repeat points
    return line[same], owner[same][:-1] if same.sum() > 1 else owner[same]
