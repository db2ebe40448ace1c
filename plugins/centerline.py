"""The built-in ``centerline`` tracer: line art drawn once, along the middle of each ink line.

Outline tracers (``edges``, ``contours``) draw both sides of an ink line, so a
sketch, a logo or a page of lettering is drawn twice. This tracer draws one
stroke per ink line instead:

threshold (Otsu unless given) -> specks removed -> skeleton (scikit-image's
``skeletonize``) -> the edge linker of ``edges`` (non-branching runs joined
straight through junctions; free-ended spurs shorter than the line width
dropped) -> each free end pulled back out of the line's round cap, where the
skeleton runs on past the centre line's end -> staircase smoothing ->
sharp corners put back where the arms' centre lines meet ->
Ramer-Douglas-Peucker -> short strokes dropped.

The ink line width is estimated from the distance transform along the
skeleton (the median of twice the distance to the paper) and reported in the
drawing's ``meta["line_width_px"]``; the layout turns it into millimetres.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.plugins.edges import CORNER, CORNER_HELP, check_corner
from doodlecam.trace.raster import IMAGE_EXTENSIONS, grid_scale, load_gray


class CenterlineTracer(Tracer):
    name = "centerline"
    summary = "centre lines of line art (sketches, logos, lettering) as single strokes (PNG, JPEG, ...)"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("threshold", float, 0.0, "grey level (0-1) below which a pixel is ink; 0 = automatic (Otsu)"),
        Option("spur", float, 0.0, "drop side branches with a free end shorter than this, in px; 0 = the line width"),
        Option("speck", float, 0.0, "drop ink blobs smaller than this many px, and fill holes in the ink under a "
               "quarter of it; 0 = a disc of the line width"),
        Option("simplify", float, 0.25, "line simplification tolerance in px (Ramer-Douglas-Peucker)"),
        Option("staircase", float, 1.5, "Gaussian smoothing along each stroke, in px (0 = off)"),
        Option("min_length", float, 0.0, "drop strokes shorter than this, in px; 0 = the line width"),
        Option("pixel_mm", float, 0.0, "trace a picture drawn coarser than this many mm per pixel scaled up to it, "
               "and one with lines wider than 12 px scaled down to it (0 = the pen width), so the same picture "
               "at 1x and 4x gives the same job; thin lines on finer pictures keep their resolution"),
        Option("corner", float, CORNER, CORNER_HELP),
    )

    @classmethod
    def layer_names(cls, options):
        return ()  # a picture's lines are one layer (--layer is refused before tracing)

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in pixels: x = column, y = row (down), a pixel's centre at its index."""
        opt = self.resolve_options(options)
        if not 0.0 <= opt["threshold"] <= 1.0:
            raise PluginError(f"tracer 'centerline': threshold must be within 0-1, got {opt['threshold']:g}")
        for key in ("spur", "speck", "simplify", "staircase", "min_length"):
            if opt[key] < 0:
                raise PluginError(f"tracer 'centerline': {key} must be >= 0, got {opt[key]:g}")
        return self.trace_gray(load_gray(path), path, opt, grid=grid_scale(self, opt["pixel_mm"]))

    def trace_gray(self, gray: np.ndarray, path: Path, opt: dict[str, Any], skel: np.ndarray | None = None,
                   grid: float | None = None) -> Drawing:
        """``trace`` of a picture already loaded (``skel``: its skeleton, when already made; ``grid``:
        pen-width grid px per picture px, when the drawn size is known)."""
        check_corner(self.name, opt.get("corner", CORNER))  # here: 'auto' calls this directly
        from doodlecam.trace.raster import in_picture_px

        ink, level = ink_mask(gray, opt["threshold"])
        work, ink, k = thin_enough(gray, ink, level, grid)
        if k != 1.0 and not opt["threshold"]:  # resampled: Otsu's level of the picture traced (of a
            ink, level = ink_mask(work)          # black-and-white one it is just above black)
        polylines, info = centerlines(ink, opt, skel if k == 1.0 else None)
        if not polylines:
            raise InputError(f"{path}: no ink lines found (threshold {level:.2f}); "
                             "try --tracer-opt threshold=... or a picture with dark lines on light paper")
        h, w = work.shape
        d = Drawing(
            polylines=tuple(p[:, ::-1] for p in polylines),  # (row, col) -> (x, y)
            units="px", y_down=True, source=str(path), extent=(float(w), float(h)),
            meta={"tracer": self.name, "options": opt, "threshold": level, **info,
                  "traced_corners_deg": float(opt.get("corner", CORNER)),
                  "line_width_px": info["line_width_px"] / k},
        )
        return in_picture_px(d, gray.shape)


def ink_mask(gray: np.ndarray, threshold: float = 0.0) -> tuple[np.ndarray, float]:
    """(ink pixels, grey level used): dark ink on light paper; ``threshold`` 0 = Otsu's."""
    from skimage.filters import threshold_otsu

    level = threshold if threshold > 0 else (float(threshold_otsu(gray)) if np.ptp(gray) > 0.05 else 0.5)
    return gray < level, level


def skeleton_length(skel: np.ndarray) -> float:
    """Length in px of a one-pixel-thin skeleton: its 4-neighbour links count 1,
    its diagonal links (where no 4-neighbour path joins the pair) sqrt(2)."""
    a = skel
    orth = np.count_nonzero(a[:, 1:] & a[:, :-1]) + np.count_nonzero(a[1:] & a[:-1])
    d1 = a[1:, 1:] & a[:-1, :-1] & ~a[1:, :-1] & ~a[:-1, 1:]
    d2 = a[1:, :-1] & a[:-1, 1:] & ~a[1:, 1:] & ~a[:-1, :-1]
    return float(orth + np.sqrt(2.0) * (np.count_nonzero(d1) + np.count_nonzero(d2)))


# Ink wider than _FULL_WIDTH px is traced on the picture scaled down to lines
# _WORK_WIDTH px wide: a skeleton costs per ink pixel and per pixel of width.
_FULL_WIDTH, _WORK_WIDTH = 12.0, 6.0
# An upscaled picture is blurred as a much finer picture of the same scene is on its way down
# to the grid: working_picture's anti-aliasing Gaussian (scikit-image's resize, sigma =
# (source px per grid px - 1) / 2 source px) tends to half a grid px. (0.3 px of the picture,
# the spread of a pixel's square, left a picture drawn 0.55 mm/px almost unblurred: a sampled
# Gaussian that narrow hardly spreads, and the thresholded 1x camera had twice the pinholes and
# thin dark lines of its 4x upscale.)
_UP_BLUR = 0.5  # grid px


def rough_width(ink: np.ndarray) -> float:
    """A quick line width in px: twice the ink area over its boundary pixels (a line has two sides)."""
    inner = ink.copy()
    inner[1:] &= ink[:-1]
    inner[:-1] &= ink[1:]
    inner[:, 1:] &= ink[:, :-1]
    inner[:, :-1] &= ink[:, 1:]
    boundary = np.count_nonzero(ink) - np.count_nonzero(inner)
    return 2.0 * np.count_nonzero(ink) / boundary if boundary else 0.0


def thin_enough(gray: np.ndarray, ink: np.ndarray, level: float,
                grid: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """(picture, ink, scale factor): scaled down when its ink lines are wider than
    _FULL_WIDTH px, so the skeleton of a high-resolution scan or of a photo's
    dark areas costs a fraction; thin lines keep the full resolution.

    With ``grid`` (pen-width grid px per picture px) a coarser picture is scaled
    up to that grid (bicubic: no line fades) and wide lines are scaled down to
    it, never below _WORK_WIDTH px: the same picture at 1x and 4x is then traced
    on the same grid, so spurs, specks and breaks are the same drawn size."""
    from doodlecam.trace.raster import working_picture

    if grid and grid > 1:
        from scipy import ndimage as ndi

        work, k = working_picture(gray, grid, 1.0, upscale=True)
        work = ndi.gaussian_filter(work, _UP_BLUR, mode="nearest")
        return work, work < level, k
    width = rough_width(ink)
    if width <= _FULL_WIDTH:
        return gray, ink, 1.0
    work, k = working_picture(gray, max(grid or 0.0, _WORK_WIDTH / width), 1.0)
    return work, work < level, k


def line_width(ink: np.ndarray, skel: np.ndarray) -> float:
    """The ink line width in px: ink area over centre-line length (exact for a
    long line at any angle, where distance-transform values step by whole pixels)."""
    length = skeleton_length(skel)
    return float(np.count_nonzero(ink) / length) if length > 0 else 0.0


def centerlines(ink: np.ndarray, opt: dict[str, Any], skel: np.ndarray | None = None
                ) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Centre-line polylines, (row, col) in px, of the ink mask, and what was measured on the way."""
    from scipy import ndimage as ndi
    from skimage import morphology

    from doodlecam.plugins.edges import _lengths, link_edges, simplify, unstair

    dist = ndi.distance_transform_edt(ink)
    skel = morphology.skeletonize(ink) if skel is None else skel.copy()
    width = max(line_width(ink, skel), 1.0)
    speck = opt["speck"] or np.pi * width * width / 4
    if speck > 1:  # specks of dust or noise: no line to draw
        ink = morphology.remove_small_objects(ink, max_size=int(speck))
        # Pinholes of paper in the ink (a photo's dark areas thresholded, upscaled pixels'
        # corners) would each be a loop of the skeleton: two junctions that break a line into
        # three strokes and a ring of short ones, and they come and go with the resolution.
        # Holes under a quarter of a speck (a disc of half the line width) are filled; a bold
        # letter's counter is wider than that.
        filled = morphology.remove_small_holes(ink, max_size=int(speck / 4))
        if np.count_nonzero(filled) != np.count_nonzero(ink):
            ink = filled
            skel = morphology.skeletonize(ink)
            dist = ndi.distance_transform_edt(ink)
            width = max(line_width(ink, skel), 1.0)  # the loops' length no longer thins the estimate
        else:
            skel &= ink
    spur = opt["spur"] or width
    # pruned to a fixed point: a spur that forks (noise on a photo's dark area) goes as a whole
    chains, n_objects, n_junctions = link_edges(skel, spur, prune=True)
    radius = (width + 1) / 2
    chains = [_out_of_caps(c, dist, radius) for c in chains]
    if len(chains) > 1:
        # Ends within a line width of each other are one line's: the arms of a
        # sharp corner meet the skeleton's corner branch a little apart.
        from doodlecam.geometry.order import merge_ends

        chains = merge_ends(chains, 1.5 * width)[0]
    if opt["staircase"] > 0:
        chains = [unstair(c, opt["staircase"]) for c in chains]
    chains = [_sharp_corners(c, dist, width) for c in chains]
    chains = simplify(chains, opt["simplify"]) if opt["simplify"] > 0 else chains
    min_len = opt["min_length"] or width
    keep = _lengths(chains) >= max(min_len, 1e-9) if chains else np.zeros(0, bool)
    out = [c for c, k in zip(chains, keep) if k and len(c) >= 2]
    info = {"line_width_px": width, "skeleton_pixels": int(skel.sum()), "edge_objects": n_objects,
            "junctions": n_junctions, "polylines": len(out), "dropped_short": int(len(chains) - len(out)),
            "vertices": int(sum(len(p) for p in out)), "length_px": float(_lengths(out).sum()) if out else 0.0}
    return out, info


def _sharp_corners(chain: np.ndarray, dist: np.ndarray, width: float) -> np.ndarray:
    """The chain with each sharp corner put back where its arms' centre lines meet.

    At a corner sharper than about 90 degrees the skeleton of a thick line
    leaves its arms a line width or so before the corner and cuts across it
    (its corner branch is a spur, dropped), so the drawn corner falls short by
    up to a line width. Where the chain turns by more than ``_CORNER_TURN``
    within two line widths, straight lines fitted to both arms (from 1.5 to 4
    line widths away) are intersected; when that point lies deep in the ink
    (as a round pen's corner has it: its centre is half a width from the
    paper) and within 1.5 line widths of the chain, the chain runs to it
    instead of cutting across. (row, col) in px.
    """
    if len(chain) < 5 or np.array_equal(chain[0], chain[-1]):
        return chain
    s = np.r_[0.0, np.cumsum(np.hypot(*np.diff(chain, axis=0).T))]
    a = 2.0 * width
    before = np.interp(s - a, s, np.arange(len(s))).round().astype(int)
    after = np.interp(s + a, s, np.arange(len(s))).round().astype(int)
    d0, d1 = chain - chain[before], chain[after] - chain
    n0, n1 = np.hypot(*d0.T), np.hypot(*d1.T)
    ok = (s >= width) & (s <= s[-1] - width) & (n0 > 0) & (n1 > 0)
    cos = np.where(ok, (d0 * d1).sum(axis=1) / np.maximum(n0 * n1, 1e-12), 1.0)
    sharp = cos < np.cos(np.radians(_CORNER_TURN))
    if not sharp.any():
        return chain
    out, last = [], 0
    for run in np.split(np.flatnonzero(sharp), np.flatnonzero(np.diff(np.flatnonzero(sharp)) > 1) + 1):
        i = run[np.argmin(cos[run])]
        arms = []
        for lo, hi in ((s[i] - 4 * width, s[i] - 1.5 * width), (s[i] + 1.5 * width, s[i] + 4 * width)):
            pts = chain[(s >= lo) & (s <= hi)]
            if len(pts) < 3:
                break
            c = pts.mean(axis=0)
            _, sv, vt = np.linalg.svd(pts - c, full_matrices=False)
            if sv[1] / np.sqrt(len(pts)) > 0.1 * width:  # not straight: a curve, not a corner
                break
            arms.append((c, vt[0]))
        if len(arms) < 2:
            continue
        (c0, u0), (c1, u1) = arms
        m = np.array([u0, -u1]).T
        if abs(np.linalg.det(m)) < 1e-6:
            continue
        t = np.linalg.solve(m, c1 - c0)
        q = c0 + t[0] * u0
        r, cidx = np.rint(q).astype(int)
        if not (0 <= r < dist.shape[0] and 0 <= cidx < dist.shape[1]):
            continue
        if dist[r, cidx] < width / 2 - 1.5 or np.hypot(*(q - chain[i])) > 1.5 * width:
            continue
        cut = (s > s[i] - 1.5 * width) & (s < s[i] + 1.5 * width)
        first, end = int(np.argmax(cut)), len(cut) - int(np.argmax(cut[::-1]))
        if first < last:
            continue
        out += [chain[last:first], q[None]]
        last = end
    if not out:
        return chain
    return np.vstack(out + [chain[last:]])


_CORNER_TURN = 90.0  # degrees the chain turns within two line widths: a corner under 90 degrees


def _out_of_caps(chain: np.ndarray, dist: np.ndarray, radius: float) -> np.ndarray:
    """The chain with each free end pulled back to where the line has its full width.

    A round-capped ink line's skeleton runs on into the cap, up to a pixel
    from its tip: a pen of that width drawing only to the centre line's end
    leaves the same cap, so the extra length would be drawn twice. Points are
    dropped from an open end while their distance to the paper is below the
    line's half width, never more than that half width along the chain.
    Closed chains have no ends.
    """
    if len(chain) < 3 or np.array_equal(chain[0], chain[-1]):
        return chain
    d = dist[chain[:, 0].astype(int), chain[:, 1].astype(int)]
    step = np.r_[0.0, np.cumsum(np.hypot(*np.diff(chain, axis=0).T))]
    total = step[-1]
    short = d < radius - 1.25
    lo = 0
    while lo < len(chain) - 2 and short[lo] and step[lo] < radius:
        lo += 1
    hi = len(chain) - 1
    while hi > lo + 1 and short[hi] and total - step[hi] < radius:
        hi -= 1
    return chain[lo:hi + 1]


# Line-art test (``--tracer auto``): a picture is line art when it is paper and
# ink with few tones between, the ink is thin lines rather than filled areas,
# and the lines are narrow against the picture.
_MAX_INK = 0.35  # share of the picture that is ink
_MIN_CONTRAST = 0.3  # paper minus ink grey level
_MAX_MID = 0.08  # share of the picture in mid tones (anti-aliased line edges stay well below)
_MAX_FILLED = 0.15  # share of the ink farther than 1.5 line half-widths from the paper
_MAX_WIDTH = 0.1  # line width as a share of the picture's shorter side


def line_art(gray: np.ndarray) -> tuple[bool, str, np.ndarray | None]:
    """(is it line art?, the reason in words, the ink's skeleton when it was made)."""
    from scipy import ndimage as ndi
    from skimage import morphology

    ink, level = ink_mask(gray)
    share = float(np.count_nonzero(ink)) / gray.size
    if share == 0.0 or share > _MAX_INK:
        return False, f"a picture: {share:.0%} of it is dark (line art has under {_MAX_INK:.0%})", None
    ink_tone, paper = float(gray[ink].mean()), float(gray[~ink].mean())
    if paper - ink_tone < _MIN_CONTRAST:
        return False, f"a picture: ink and paper differ by only {paper - ink_tone:.2f} in grey level", None
    lo, hi = ink_tone + 0.3 * (paper - ink_tone), paper - 0.3 * (paper - ink_tone)
    mid = float(np.count_nonzero((gray > lo) & (gray < hi))) / gray.size
    if mid > _MAX_MID:
        return False, f"a picture: {mid:.0%} of it is mid tones (line art has under {_MAX_MID:.0%})", None
    gray, ink, k = thin_enough(gray, ink, level)
    skel = morphology.skeletonize(ink)
    width = line_width(ink, skel)
    if width <= 0:
        return False, "a picture: no ink lines", None
    if width > _MAX_WIDTH * min(gray.shape):
        return False, f"a picture: its dark shapes are {width / k:.0f} px wide, not lines", None
    dist = ndi.distance_transform_edt(ink)
    filled = float(np.count_nonzero(dist > 1.5 * (width / 2 + 1))) / np.count_nonzero(ink)
    if filled > _MAX_FILLED:
        return False, f"a picture: {filled:.0%} of its ink is filled areas, not lines", None
    return True, (f"line art: paper and ink lines {width / k:.1f} px wide, {mid:.1%} mid tones; "
                  "drawn once along their centre"), skel if k == 1.0 else None


class AutoTracer(Tracer):
    name = "auto"
    summary = "the default for pictures: centerline for line art (thin dark lines on paper), else edges"
    extensions = IMAGE_EXTENSIONS

    @classmethod
    def layer_names(cls, options):
        return ()  # a picture's lines are one layer (--layer is refused before tracing)

    @classmethod
    def _options(cls) -> tuple[Option, ...]:
        from doodlecam.plugins.edges import EdgesTracer

        seen, out = set(), []
        for o in (*EdgesTracer.options, *CenterlineTracer.options):
            if o.name not in seen:
                seen.add(o.name)
                out.append(Option(o.name, o.type, None, f"passed to the chosen tracer; {o.help}"))
        return tuple(out)

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        from dataclasses import replace

        from doodlecam.plugins.edges import EdgesTracer

        # None = not given (the chosen tracer's default), also when the pipeline resolved them already
        given = {k: v for k, v in self.resolve_options({k: v for k, v in options.items() if v is not None}).items()
                 if v is not None}
        gray = load_gray(path)
        art, reason, skel = line_art(gray)
        chosen = CenterlineTracer if art else EdgesTracer
        extra = set(given) - {o.name for o in chosen.options}
        if extra:
            raise PluginError(f"tracer 'auto' chose '{chosen.name}' ({reason}), which has no option "
                              f"'{sorted(extra)[0]}'; pick the tracer with --tracer")
        # the profile's [trace.edges] / [trace.centerline] table applies to the chosen tracer too
        profile = getattr(self, "profile_options", {}).get(f"trace.{chosen.name}", {})
        opt = chosen.resolve_options(profile, given)
        if art:  # line art keeps its full resolution: thin lines would fade to grey
            d = CenterlineTracer().trace_gray(gray, path, opt, skel, grid_scale(self, opt["pixel_mm"]))
        else:
            from doodlecam.trace.raster import in_picture_px, working_picture

            pixel = opt["pixel_mm"] if opt["pixel_mm"] > 0 else (self.pen_mm or 0.0)
            work = working_picture(gray, self.mm_per_px, pixel, upscale=True)[0]  # as edges itself does
            d = in_picture_px(EdgesTracer().trace_gray(work, path, opt), gray.shape)
        return replace(d, meta={**d.meta, "tracer_reason": f"auto: {reason}"})


AutoTracer.options = AutoTracer._options()
