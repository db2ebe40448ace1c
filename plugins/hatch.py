"""The built-in ``hatch`` tracer: a picture's tones as layers of hatching.

Darker grey levels get more layers of parallel lines: layer ``i`` of
``levels`` covers the pixels darker than ``(i + 1) / (levels + 1)``, at its
own angle (cross-hatching) or interleaved with the others at one angle. Each
layer is found by scanning a rotated grid of lines over the picture: every
line is sampled at once (NumPy, in blocks of lines so memory stays bounded),
runs of dark samples become segments. With ``join`` (the default), the pen
goes on from a segment's end to the next line's segment along a short
straight move that stays on dark paper (it runs along the region's edge or
through ink), and zig-zags end to end likewise, so a region is drawn in a
few pen-downs, not hundreds of dashes. The fitter cuts the zig-zags at their
corners into straight pieces (exact at once) that the pen draws without
lifting (``Job.lifts``): on the sample photos the job is 32-36 % shorter.
``turns`` links by smooth U-turns instead (slow to fit and plan, less gain).

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
_REACH = 3.0  # spacings: the longest link through ink between two zig-zags (straight joins)
_CORNER = 20.0  # degrees: joined hatching is fitted as straight pieces between turns sharper than this
_CROSS = (0.0, 90.0, 45.0, 135.0)  # layer angles relative to `angle` for the first four layers


class HatchTracer(Tracer):
    name = "hatch"
    summary = "Tone by hatching: more layers of lines where the picture is darker (PNG, JPEG, ...)"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("spacing_mm", float, None, f"distance between the lines of one layer as drawn, in mm, at least the pen "
               f"width; unset = {_PEN_FACTOR:g} pen widths"),
        Option("spacing", float, 0.0, "the same in px of the picture, instead of spacing_mm; 0 = use spacing_mm "
               f"({_SPACING_PX:g} px when the drawn size is unknown)"),
        Option("levels", int, 4, "number of tone layers: the darkest pixels get them all (1-8)"),
        Option("angle", float, 45.0, "angle of the first layer's lines, degrees counter-clockwise from the x axis"),
        Option("cross", bool, True, "give each layer its own angle (cross-hatching); off: parallel, interleaved lines"),
        Option("blur", float, 1.0, "Gaussian blur of the picture in px first (0 = none); softens noise and dither"),
        Option("gamma", float, 1.0, "tone curve: > 1 lightens mid-tones (fewer lines), < 1 darkens them"),
        Option("equalize", bool, False, "stretch the histogram first (CLAHE), for flat, grey photos"),
        Option("join", bool, True, "go on pen down from one line to the next along short moves that stay in the "
               "dark region (the region's edge or through ink), instead of lifting the pen: about a third less job time"),
        Option("turns", bool, False, "with join: link lines by smooth U-turns instead of straight moves (slow to "
               "fit and plan, a smaller gain)"),
        Option("layers", str, "one", "'tone': each tone level's lines on a layer of its own, 'tone 1' (darkest) to "
               "'tone N' (lightest), plotted one after another, to draw each with its own pen; 'one': a single layer"),
        Option("min_length", float, 2.0, "drop hatch strokes shorter than this, in px"),
        Option("pixel_mm", float, 0.0, "trace the picture scaled (down, or up if coarser) to this many mm per pixel "
               "as drawn (0 = the pen width), so px options mean the same drawn size at any resolution"),
    )

    @classmethod
    def check_options(cls, opt: dict[str, Any], pen_mm: float | None = None) -> None:
        if opt["spacing"] != 0 and opt["spacing"] < 0.5:
            raise PluginError(f"tracer 'hatch': spacing must be >= 0.5 px (or 0: spacing_mm), got {opt['spacing']:g}")
        mm = opt["spacing_mm"]
        if mm is not None and (mm <= 0 or (pen_mm and mm < pen_mm)):  # closer than the pen: solid ink
            pen = f" ({pen_mm:g} mm)" if pen_mm else ""
            raise PluginError(f"tracer 'hatch': spacing_mm must be at least the pen's width{pen}, got {mm:g} "
                              f"(closer lines ink the paper solid); leave it out for {_PEN_FACTOR:g} pen widths")
        if not 1 <= opt["levels"] <= 8:
            raise PluginError(f"tracer 'hatch': levels must be 1 to 8, got {opt['levels']}")
        if opt["blur"] < 0 or opt["gamma"] <= 0 or opt["min_length"] < 0:
            raise PluginError("tracer 'hatch': blur and min_length must be >= 0 and gamma > 0")
        if opt["layers"] not in ("one", "tone"):
            raise PluginError(f"tracer 'hatch': layers must be 'one' or 'tone', got {opt['layers']!r}")

    @classmethod
    def layer_names(cls, opt: dict[str, Any]) -> tuple[str, ...]:
        return tuple(f"tone {k}" for k in range(1, opt["levels"] + 1)) if opt["layers"] == "tone" else ()

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in pixels: x = column, y = row (down), pixel centres at integers."""
        opt = self.resolve_options(options)
        self.check_options(opt, self.pen_mm)
        gray, shape = load_working(path, self, opt["pixel_mm"], upscale=True)
        opt["spacing"] = spacing = _spacing_px(self, opt, gray.shape[1] / shape[1])
        dark = darkness(gray, opt["blur"], opt["gamma"], opt["equalize"])
        polylines: list[np.ndarray] = []
        layers: list[str] = []  # the tone of each polyline: level i of n is tone n - i (1 = darkest)
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
            polylines += hatch_mask(mask, spacing, angle, offset=offset, join=opt["join"], turns=opt["turns"],
                                    min_length=opt["min_length"])
            layers += [f"tone {n - i}"] * (len(polylines) - len(layers))
        if not polylines:
            raise InputError(f"{path}: nothing dark enough to hatch (the picture looks blank); "
                             "try --tracer-opt gamma=0.5 or more levels")
        h, w = gray.shape
        return in_picture_px(Drawing(tuple(polylines), units="px", y_down=True, source=str(path),
                                     extent=(float(w), float(h)), layers=tuple(layers) if opt["layers"] == "tone" else (),
                                     meta={"tracer": self.name, "options": opt, "polylines": len(polylines),
                                           "vertices": int(sum(len(p) for p in polylines)),
                                           # the fitter cuts the zig-zags at their corners: straight pieces
                                           **({"split_corners_deg": _CORNER} if opt["join"] and not opt["turns"] else {})}), shape)


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
               min_length: float = 0.0, turns: bool = False) -> list[np.ndarray]:
    """Parallel lines ``spacing`` px apart at ``angle`` degrees, clipped to ``mask``.

    ``mask`` is (rows, cols), True where to draw; returns (x, y) polylines in
    pixels (y down, pixel centres at integers). ``offset`` shifts the lines
    by that fraction of the spacing. With ``join``, a line's end is linked
    to the next line's start when the link is short and stays in (or next
    to) the mask: by a straight connecting line (a zig-zag, to be fitted as
    straight pieces the pen draws without lifting), or with ``turns`` by a
    smooth U-turn (a meander).
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
    chains = _chains(p0, p1, nxt, keep, (-0.5, -0.5), (w - 0.5, h - 0.5), turns)
    return chains if turns else _bridge(chains, mask, _REACH * spacing)


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
    ok = best_d <= 4.0 * spacing
    src, dst, dist = idx[ok], best[ok], best_d[ok]
    if not len(src):
        return nxt
    # Each start takes the closest end that wants it.
    by = np.lexsort((dist, dst))
    first = np.r_[True, dst[by][1:] != dst[by][:-1]]
    src, dst = src[by][first], dst[by][first]
    inside = _in_ink(mask, p1[src], p0[dst], 7)
    nxt[src[inside]] = dst[inside]
    return nxt


def _in_ink(mask: np.ndarray, a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Whether each segment a -> b (px) stays on (or a pixel next to) the dark
    region: each of its n - 2 inner sample points or one of their four
    neighbours is dark (no dilation of a huge mask)."""
    h, w = mask.shape
    f = np.linspace(0, 1, n)[1:-1]
    pts = a[:, None, :] + f[None, :, None] * (b - a)[:, None, :]
    xi, yi = np.rint(pts[..., 0]).astype(int), np.rint(pts[..., 1]).astype(int)
    near = np.zeros(xi.shape, bool)
    for dx, dy in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
        near |= mask[np.clip(yi + dy, 0, h - 1), np.clip(xi + dx, 0, w - 1)]
    return near.all(axis=1)


def _bridge(chains: list[np.ndarray], mask: np.ndarray, reach: float) -> list[np.ndarray]:
    """Join zig-zags end to end through ink: from each chain's end, on to the
    nearest unused chain end (either way round) within ``reach`` px whose
    straight link stays in the dark region; the pen draws the link instead of
    lifting. Greedy, in the chains' (scan) order; deterministic."""
    n = len(chains)
    if n < 2:
        return chains
    from scipy.spatial import cKDTree

    ends = np.array([c[i] for c in chains for i in (0, -1)])  # 2k: start of chain k, 2k + 1: its end
    k = min(8, 2 * n)
    dist, cand = cKDTree(ends).query(ends, k=k, distance_upper_bound=reach)
    dist, cand = dist.reshape(2 * n, k), cand.reshape(2 * n, k)
    ok = np.isfinite(dist) & (cand // 2 != np.arange(2 * n)[:, None] // 2)
    src = np.repeat(np.arange(2 * n), k)[ok.ravel()]
    dst = cand.ravel()[ok.ravel()]
    ok[ok] = _in_ink(mask, ends[src], ends[dst], max(3, int(np.ceil(reach)) + 2))
    used = np.zeros(n, bool)
    out: list[np.ndarray] = []
    for first in range(n):
        if used[first]:
            continue
        used[first] = True
        parts, tip = [chains[first]], 2 * first + 1
        while True:
            nxt = next((int(c) for c, good in zip(cand[tip], ok[tip]) if good and not used[c // 2]), -1)
            if nxt < 0:
                break
            used[nxt // 2] = True
            c = chains[nxt // 2]
            parts.append(c if nxt % 2 == 0 else c[::-1])  # entered at its start, or at its end
            tip = nxt ^ 1
        out.append(np.vstack(parts))
    return out


def _chains(p0, p1, nxt, keep, lo=(-np.inf, -np.inf), hi=(np.inf, np.inf), turns: bool = True) -> list[np.ndarray]:
    """Follow the links: each chain is a polyline through its runs' ends, linked
    by U-turns (``turns``) or straight (a zig-zag).

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
    if len(src) and turns:
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
    use[~has if turns else slice(None), 2:] = False
    pts = block[use]
    np.clip(pts, lo, hi, out=pts)  # numerical safety: nothing leaves the canvas
    cut = np.flatnonzero(np.diff(root[order])) + 1
    return np.split(pts, np.cumsum(use.sum(axis=1))[cut - 1])
