"""The built-in ``hatch`` tracer: a picture's tones as layers of hatching.

Darker grey levels get more layers of parallel lines: layer ``i`` of
``levels`` covers the pixels darker than ``(i + 1) / (levels + 1)``, at its
own angle (cross-hatching) or interleaved with the others at one angle. Each
layer is found by scanning a rotated grid of lines over the picture: every
line is sampled at once (NumPy, in blocks of lines so memory stays bounded),
runs of dark samples become segments. With ``join``, consecutive segments on
neighbouring lines are linked by smooth U-turns when the link stays on dark
paper, so a region is drawn in a few long meanders, not hundreds of dashes
(off by default: the spline fit takes long over such meanders).

``hatch_mask`` is the reusable part: the ``contours`` tracer fills its dark
regions with it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.trace.raster import IMAGE_EXTENSIONS, in_picture_px, load_working

_STEP = 0.5  # px between samples along a scan line (run ends are found to within half of it) ...
_BIG = 4_000_000  # ... or 1 px on pictures above this many pixels, where half a pixel is invisible
_BLOCK = 1 << 21  # samples per block: bounds memory on huge pictures
_UTURN = 6  # points on each U-turn between linked lines
_PEN_FACTOR = 4.0  # default line spacing in pen widths: each layer inks a quarter of its area
_SPACING_PX = 4.0  # ... or in px, when the tracer is not told the drawn size (direct calls)
_CROSS = (0.0, 90.0, 45.0, 135.0)  # layer angles relative to `angle` for the first four layers


class HatchTracer(Tracer):
    name = "hatch"
    summary = "Tone by hatching: more layers of lines where the picture is darker (PNG, JPEG, ...)"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("spacing_mm", float, 0.0, f"distance between the lines of one layer as drawn, in mm; 0 = {_PEN_FACTOR:g} "
               "pen widths (never below one pen width)"),
        Option("spacing", float, 0.0, "the same in px of the picture, instead of spacing_mm; 0 = use spacing_mm "
               f"({_SPACING_PX:g} px when the drawn size is unknown)"),
        Option("levels", int, 4, "number of tone layers: the darkest pixels get them all (1-8)"),
        Option("angle", float, 45.0, "angle of the first layer's lines, degrees counter-clockwise from the x axis"),
        Option("cross", bool, True, "give each layer its own angle (cross-hatching); off: parallel, interleaved lines"),
        Option("blur", float, 1.0, "Gaussian blur of the picture in px first (0 = none); softens noise and dither"),
        Option("gamma", float, 1.0, "tone curve: > 1 lightens mid-tones (fewer lines), < 1 darkens them"),
        Option("equalize", bool, False, "stretch the histogram first (CLAHE), for flat, grey photos"),
        Option("join", bool, False, "link neighbouring lines by U-turns where they stay in the dark: fewer pen "
               "lifts, but long curvy strokes that are slow to fit and plan"),
        Option("min_length", float, 2.0, "drop hatch strokes shorter than this, in px"),
        Option("pixel_mm", float, 0.0, "trace finer pictures scaled down to this many mm per pixel as drawn "
               "(0 = the pen width), so px options mean the same drawn size at any resolution"),
    )

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in pixels: x = column, y = row (down), pixel centres at integers."""
        opt = self.resolve_options(options)
        if opt["spacing"] != 0 and opt["spacing"] < 0.5:
            raise PluginError(f"tracer 'hatch': spacing must be >= 0.5 px (or 0: spacing_mm), got {opt['spacing']:g}")
        if opt["spacing_mm"] < 0:
            raise PluginError(f"tracer 'hatch': spacing_mm must be >= 0, got {opt['spacing_mm']:g}")
        if not 1 <= opt["levels"] <= 8:
            raise PluginError(f"tracer 'hatch': levels must be 1 to 8, got {opt['levels']}")
        if opt["blur"] < 0 or opt["gamma"] <= 0 or opt["min_length"] < 0:
            raise PluginError("tracer 'hatch': blur and min_length must be >= 0 and gamma > 0")
        gray, shape = load_working(path, self, opt["pixel_mm"])
        opt["spacing"] = spacing = _spacing_px(self, opt, gray.shape[1] / shape[1])
        dark = darkness(gray, opt["blur"], opt["gamma"], opt["equalize"])
        polylines: list[np.ndarray] = []
        n = opt["levels"]
        for i in range(n):
            mask = dark > (i + 1) / (n + 1)
            if not mask.any():
                break  # the next layers are darker still: empty too
            if opt["cross"]:
                angle = opt["angle"] + _CROSS[i % 4] + (i // 4) * 22.5
                offset = 0.0 if i < 4 else 0.5
            else:
                angle, offset = opt["angle"], _interleave(i)
            polylines += hatch_mask(mask, spacing, angle, offset=offset, join=opt["join"],
                                    min_length=opt["min_length"])
        if not polylines:
            raise InputError(f"{path}: nothing dark enough to hatch (the picture looks blank); "
                             "try --tracer-opt gamma=0.5 or more levels")
        h, w = gray.shape
        return in_picture_px(Drawing(tuple(polylines), units="px", y_down=True, source=str(path),
                                     extent=(float(w), float(h)),
                                     meta={"tracer": self.name, "options": opt, "polylines": len(polylines),
                                           "vertices": int(sum(len(p) for p in polylines))}), shape)


def _spacing_px(self: HatchTracer, opt: dict[str, Any], k: float) -> float:
    """Line spacing in px of the working picture (``k`` of the picture's px per px):
    spacing_mm (default: pen widths) when the drawn size is known, never below the pen width."""
    mm = self.mm_per_px / k if self.mm_per_px else None  # mm per working px
    if opt["spacing"] > 0:
        px = opt["spacing"] * k
    elif mm is None:
        return _SPACING_PX
    else:
        px = (opt["spacing_mm"] or _PEN_FACTOR * (self.pen_mm or 0.5)) / mm
    if mm is not None and self.pen_mm:  # lines closer than the pen only ink the paper solid
        px = max(px, self.pen_mm / mm)
    return max(px, 0.5)


def _interleave(i: int) -> float:
    """Offsets 0, 1/2, 1/4, 3/4, 1/8, ... of the spacing: each new layer halves the gaps."""
    if i == 0:
        return 0.0
    k = int(np.floor(np.log2(i)))
    return (2 * (i - 2 ** k) + 1) / 2 ** (k + 1)


def darkness(gray: np.ndarray, blur: float = 0.0, gamma: float = 1.0, equalize: bool = False) -> np.ndarray:
    """1 - grey level after the optional equalisation, blur and tone curve (float32)."""
    g = gray
    if equalize:
        from skimage import exposure

        g = exposure.equalize_adapthist(g)
    g = g.astype(np.float32, copy=False)
    if blur > 0:
        from scipy import ndimage as ndi

        g = ndi.gaussian_filter(g, blur, mode="nearest")
    if gamma != 1.0:
        g = np.power(np.clip(g, 0, 1), 1.0 / gamma)
    return 1.0 - g


def hatch_mask(mask: np.ndarray, spacing: float, angle: float, offset: float = 0.0, join: bool = False,
               min_length: float = 0.0) -> list[np.ndarray]:
    """Parallel lines ``spacing`` px apart at ``angle`` degrees, clipped to ``mask``.

    ``mask`` is (rows, cols), True where to draw; returns (x, y) polylines in
    pixels (y down, pixel centres at integers). ``offset`` shifts the lines
    by that fraction of the spacing. With ``join``, a line's end is linked
    to the next line's start by a U-turn when the link is short and stays in
    (or next to) the mask, giving meanders.
    """
    h, w = mask.shape
    a = np.deg2rad(angle)
    u = np.array([np.cos(a), -np.sin(a)])  # along the lines; image y points down
    nrm = np.array([-u[1], u[0]])  # across them
    c = np.array([(w - 1) / 2, (h - 1) / 2])
    r = 0.5 * np.hypot(w, h) + 1
    t = np.arange(np.ceil((-r / spacing) - offset), np.floor(r / spacing - offset) + 1) * spacing + offset * spacing
    # Each line is sampled only across the picture: the s range where it is inside
    # [-0.5, w - 0.5] x [-0.5, h - 0.5] (slab clipping), on a common grid of step `step`.
    # Lines closer than 1.5 px, or a huge picture: one sample per pixel is plenty.
    step = _STEP if h * w <= _BIG and spacing >= 1.5 else 1.0
    lo_s, hi_s = np.full(len(t), -r), np.full(len(t), r)
    for k, size in ((0, w), (1, h)):
        base = c[k] + t * nrm[k]
        if abs(u[k]) < 1e-12:
            out = (base < -0.5) | (base > size - 0.5)
            hi_s[out] = -np.inf
            continue
        e0, e1 = (-0.5 - base) / u[k], (size - 0.5 - base) / u[k]
        lo_s, hi_s = np.maximum(lo_s, np.minimum(e0, e1)), np.minimum(hi_s, np.maximum(e0, e1))
    j0 = np.ceil(lo_s / step)
    count = np.where(hi_s >= lo_s, np.floor(hi_s / step) - j0 + 1, 0).clip(0).astype(np.int64)
    j0 = np.where(count > 0, j0, 0).astype(np.int64)
    starts, ends, line_of = [], [], []
    first = 0
    while first < len(t):  # blocks of whole lines, about _BLOCK samples each
        last = int(np.searchsorted(np.cumsum(count[first:] + 1), _BLOCK)) + first + 1
        last = min(max(last, first + 1), len(t))
        cnt = count[first:last] + 1  # one sentinel (never dark) after each line
        tot = int(cnt.sum())
        lk = np.repeat(np.arange(first, last), cnt)
        pos = np.arange(tot) - np.repeat(np.cumsum(cnt) - cnt, cnt)  # sample number within the line
        sv = (j0[lk] + pos) * step
        # float32 and a per-line base point: fewer, lighter passes over the samples
        bx = (c[0] + t[first:last] * nrm[0]).astype(np.float32)
        by = (c[1] + t[first:last] * nrm[1]).astype(np.float32)
        sv32 = sv.astype(np.float32)
        li = lk - first
        x = np.rint(bx[li] + sv32 * np.float32(u[0])).astype(np.int32)
        y = np.rint(by[li] + sv32 * np.float32(u[1])).astype(np.int32)
        del sv32
        real = pos < cnt[li] - 1
        np.clip(x, 0, w - 1, out=x)
        np.clip(y, 0, h - 1, out=y)
        on = mask[y, x] & real
        del x, y
        d = np.diff(on.view(np.int8), prepend=np.int8(0))
        st = np.flatnonzero(d == 1)  # first dark sample of each run
        en = np.flatnonzero(d == -1) - 1  # its last (a sentinel ends every run)
        starts.append(sv[st] - step / 2)
        ends.append(sv[en] + step / 2)
        line_of.append(lk[st])
        first = last
    s0, s1, line = np.concatenate(starts), np.concatenate(ends), np.concatenate(line_of)
    if not len(line):
        return []
    s0, s1 = np.maximum(s0, lo_s[line]), np.minimum(s1, hi_s[line])  # not past the canvas
    back = line % 2 == 1  # boustrophedon: every other line runs backwards
    a_s, b_s = np.where(back, s1, s0), np.where(back, s0, s1)
    tl = t[line]
    p0 = c + tl[:, None] * nrm + a_s[:, None] * u
    p1 = c + tl[:, None] * nrm + b_s[:, None] * u
    keep = np.abs(s1 - s0) >= min_length if min_length > 0 else np.ones(len(line), bool)
    if not join:
        return list(np.stack([p0[keep], p1[keep]], axis=1))
    nxt = _links(mask, line, a_s, b_s, p0, p1, keep, spacing)
    return _chains(p0, p1, nxt, keep, (-0.5, -0.5), (w - 0.5, h - 0.5))


def _links(mask, line, a_s, b_s, p0, p1, keep, spacing) -> np.ndarray:
    """next[i]: the run on the following line that run i's end links to, or -1."""
    n = len(line)
    nxt = np.full(n, -1)
    idx = np.flatnonzero(keep)
    if len(idx) < 2:
        return nxt
    # Runs of the next line, keyed by (line, position along the line), searched for each end.
    big = 4.0 * (np.abs(a_s).max() + np.abs(b_s).max() + 1)
    key = line[idx] * big + a_s[idx]
    order = np.argsort(key, kind="stable")
    skey, sidx = key[order], idx[order]
    q = (line[idx] + 1) * big + b_s[idx]
    hi = np.searchsorted(skey, q)
    best, best_d = np.full(len(idx), -1), np.full(len(idx), np.inf)
    for cand in (hi - 1, hi):
        ok = (cand >= 0) & (cand < len(sidx))
        j = np.where(ok, sidx[np.clip(cand, 0, len(sidx) - 1)], 0)
        ok &= line[j] == line[idx] + 1
        d = np.where(ok, np.hypot(*(p0[j] - p1[idx]).T), np.inf)
        better = d < best_d
        best, best_d = np.where(better, j, best), np.where(better, d, best_d)
    # A link longer than a few spacings would cross paper or draw a visible stripe.
    ok = best_d <= 2.5 * spacing
    src, dst, dist = idx[ok], best[ok], best_d[ok]
    if not len(src):
        return nxt
    # Each start takes the closest end that wants it.
    by = np.lexsort((dist, dst))
    first = np.r_[True, dst[by][1:] != dst[by][:-1]]
    src, dst = src[by][first], dst[by][first]
    # The link must stay on (or a pixel next to) the dark region: each sample
    # point or one of its four neighbours is dark (no dilation of a huge mask).
    h, w = mask.shape
    f = np.linspace(0, 1, 7)[1:-1]
    pts = p1[src][:, None, :] + f[None, :, None] * (p0[dst] - p1[src])[:, None, :]
    xi, yi = np.rint(pts[..., 0]).astype(int), np.rint(pts[..., 1]).astype(int)
    near = np.zeros(xi.shape, bool)
    for dx, dy in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
        near |= mask[np.clip(yi + dy, 0, h - 1), np.clip(xi + dx, 0, w - 1)]
    inside = near.all(axis=1)
    nxt[src[inside]] = dst[inside]
    return nxt


def _chains(p0, p1, nxt, keep, lo=(-np.inf, -np.inf), hi=(np.inf, np.inf)) -> list[np.ndarray]:
    """Follow the links: each chain is a zig-zag polyline through its runs' ends.

    Pointer jumping finds every run's chain head and rank in log(length)
    vectorised steps, so thousands of chains cost no Python loop.
    """
    idx = np.flatnonzero(keep)
    if not len(idx):
        return []
    n = len(nxt)
    prv = np.full(n, -1)
    linked = nxt >= 0
    prv[nxt[linked]] = np.flatnonzero(linked)
    root = np.where(prv >= 0, prv, np.arange(n))
    rank = (prv >= 0).astype(np.int64)
    while True:
        up = root[root]
        if np.array_equal(up, root):
            break
        rank = rank + np.where(root != up, rank[root], 0)
        root = up
    order = idx[np.lexsort((rank[idx], root[idx]))]
    # A U-turn bulges 3/8 of the gap beyond the line ends; where that would
    # leave the canvas [lo, hi], both lines stop short by the difference.
    src = np.flatnonzero(keep & (nxt >= 0))
    if len(src):
        dst = nxt[src]
        u = p1[src] - p0[src]
        u /= np.maximum(np.hypot(*u.T), 1e-12)[:, None]
        bulge = 0.375 * np.hypot(*(p0[dst] - p1[src]).T)
        room = np.full(len(src), np.inf)
        for q in (p1[src], p0[dst]):
            for k in (0, 1):
                with np.errstate(divide="ignore", invalid="ignore"):
                    r = np.where(u[:, k] > 1e-12, (hi[k] - q[:, k]) / u[:, k],
                                 np.where(u[:, k] < -1e-12, (lo[k] - q[:, k]) / u[:, k], np.inf))
                room = np.minimum(room, r)
        short = np.minimum(np.hypot(*(p1[src] - p0[src]).T), np.hypot(*(p1[dst] - p0[dst]).T))
        back = np.clip(bulge - room, 0.0, 0.45 * short)[:, None] * u
        p1, p0 = p1.copy(), p0.copy()
        p1[src] -= back
        p0[dst] -= back
    # Each run, then (if linked) a U-turn to the next one: a cubic Bezier leaving
    # along the run and arriving along the next, so a zig-zag has no corner
    # the spline fit would have to split at (the pen would stop and lift there).
    a, b = p0[order], p1[order]
    has = nxt[order] >= 0
    nb = np.where(has, nxt[order], order)
    c = p0[nb]
    d = b - a
    d /= np.maximum(np.hypot(*d.T), 1e-12)[:, None]
    reach = 0.5 * np.hypot(*(c - b).T)[:, None]
    f = np.linspace(0, 1, _UTURN + 2)[1:-1, None, None]
    c1, c2 = b + reach * d, c + reach * d
    curve = ((1 - f) ** 3 * b + 3 * (1 - f) ** 2 * f * c1 + 3 * (1 - f) * f ** 2 * c2 + f ** 3 * c).transpose(1, 0, 2)
    block = np.concatenate([a[:, None], b[:, None], curve], axis=1)  # (runs, 2 + _UTURN, 2)
    use = np.ones(block.shape[:2], bool)
    use[~has, 2:] = False
    pts = block[use]
    np.clip(pts, lo, hi, out=pts)  # numerical safety: nothing leaves the canvas
    cut = np.flatnonzero(np.diff(root[order])) + 1
    return np.split(pts, np.cumsum(use.sum(axis=1))[cut - 1])
