"""The built-in ``edges`` tracer: a picture's Canny edges as pen strokes.

This is the method of the DoodleBot report, and the example to copy for a
tracer plugin of your own: subclass ``doodlecam.api.Tracer``, set ``name``,
``summary``, ``extensions`` and ``options``, implement ``trace`` and register
the class under the ``doodlecam.tracers`` entry-point group (or drop the file
into a ``--plugin-dir``). Keep module-level imports light; import heavy
libraries inside methods so that listing plugins stays fast.

Pipeline: grey levels -> optional equalisation / median filter -> Canny ->
one-pixel-thin skeleton -> "edge objects" (non-branching pixel chains, linked
by walking the pixel graph, so each edge is drawn once, not once per side as
contour tracing of the edge map would) -> chains paired straight through
junctions -> Ramer-Douglas-Peucker simplification -> short chains dropped.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.trace.raster import IMAGE_EXTENSIONS, denoise_amount, in_picture_px, load_working, noise_level

# A high threshold never drops below the gradient of a step of this size
# (fraction of black-to-white), so a blank, noisy sheet gives no edges.
_MIN_STEP = 0.02
_TANGENT_PX = 5  # how far along a chain its direction at a junction is measured
_BIG = 4_000_000  # pixels; larger pictures are filtered in float32
CORNER = 30.0  # degrees: traced corners kept exact (doodlecam.geometry.corners), here and in contours, centerline
CORNER_HELP = ("keep corners exact where a traced line turns by more than this many degrees over a few pen "
               "widths: the stroke is split there and the pen stops on the corner without lifting (0 = off)")


def check_corner(tracer: str, corner: float) -> None:
    if not 0 <= corner < 180:
        raise PluginError(f"tracer '{tracer}': corner must be 0 (off) to below 180 degrees, got {corner:g}")


class EdgesTracer(Tracer):
    name = "edges"
    summary = "Canny edges of a picture as single-line strokes (PNG, JPEG, BMP, TIFF, GIF)"
    extensions = IMAGE_EXTENSIONS
    options = (
        Option("sigma", float, 2.0, "Canny Gaussian blur in px; larger = fewer, smoother edges"),
        Option("low", float, 0.7, "hysteresis low threshold, as a quantile (0-1) of gradient strength"),
        Option("high", float, 0.9, "hysteresis high threshold, as a quantile (0-1) of gradient strength"),
        Option("equalize", bool, False, "adaptive histogram equalisation (CLAHE) first, for dull or backlit photos"),
        Option("smooth", float, 0.0, "median-filter radius in px applied first; removes texture/speckle, keeps edges"),
        Option("simplify", float, 0.25, "line simplification tolerance in px (Ramer-Douglas-Peucker)"),
        Option("staircase", float, 0.8, "Gaussian smoothing along each chain, in px, before simplifying: "
               "removes the pixel staircase, so fewer control points and a faster, smoother job (0 = off)"),
        Option("join", float, 2.0, "join strokes whose free ends are at most this far apart, in px (0 = never)"),
        Option("min_length", float, 4.0, "drop strokes shorter than this, in px"),
        Option("denoise", bool, True, "estimate the picture's noise and raise smooth and sigma to match "
               "(up to smooth=3 sigma=3 for heavy noise; clean pictures are untouched); false = off"),
        Option("pixel_mm", float, 0.0, "trace the picture scaled (down, or up if coarser) to this many mm per pixel "
               "as drawn (0 = the pen width), so px options mean the same drawn size at any resolution"),
        Option("corner", float, CORNER, CORNER_HELP),
    )

    @classmethod
    def layer_names(cls, options):
        return ()  # a picture's lines are one layer (--layer is refused before tracing)

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in pixels: x = column, y = row (down), a pixel's centre at its index."""
        opt = self.resolve_options(options)
        # on the pen-width grid whatever the input: sigma, join, min_length ... are the same drawn size
        gray, shape = load_working(path, self, opt["pixel_mm"], upscale=True)
        return in_picture_px(self.trace_gray(gray, path, opt), shape)

    def trace_gray(self, gray: np.ndarray, path: Path, opt: dict[str, Any]) -> Drawing:
        """``trace`` of a picture already loaded, with resolved options."""
        check_corner(self.name, opt.get("corner", CORNER))  # here: 'auto' calls this directly
        noise = noise_level(gray)
        if opt["denoise"] and (a := denoise_amount(noise)) > 0:
            # the settings that rescued a noisy photo by hand, reached at heavy noise
            opt = {**opt, "smooth": max(opt["smooth"], round(3 * a)), "sigma": max(opt["sigma"], 2.0 + a)}
        edges, low, high = self.edge_map(gray, opt)
        chains, n_objects, n_junctions = link_edges(edges, opt["min_length"])
        polylines = _finish(chains, opt["simplify"], opt["min_length"], opt["join"], opt["staircase"])
        if not polylines:
            raise InputError(
                f"{path}: no edges found (the picture looks blank at sigma={opt['sigma']:g}); "
                "try a lower --tracer-opt sigma=... or a picture with more contrast"
            )
        h, w = gray.shape
        return Drawing(
            polylines=tuple(p[:, ::-1] for p in polylines),  # (row, col) -> (x, y)
            units="px", y_down=True, source=str(path), extent=(float(w), float(h)),
            meta={"tracer": self.name, "options": opt, "edge_pixels": int(edges.sum()),
                  "edge_objects": n_objects, "junctions": n_junctions, "polylines": len(polylines),
                  "vertices": int(sum(len(p) for p in polylines)),
                  "length_px": float(_lengths(polylines).sum()),
                  "low_threshold": low, "high_threshold": high, "noise": noise,
                  "traced_corners_deg": float(opt.get("corner", CORNER)), "corner_blur_px": float(opt["sigma"])},
        )

    @staticmethod
    def edge_map(gray: np.ndarray, opt: dict[str, Any]) -> tuple[np.ndarray, float, float]:
        """One-pixel-thin Canny edges of ``gray`` and the absolute thresholds used."""
        from scipy import ndimage as ndi
        from skimage import exposure, feature, morphology

        if not (0.0 <= opt["low"] <= opt["high"] <= 1.0):
            raise PluginError(f"tracer 'edges': need 0 <= low <= high <= 1, got low={opt['low']:g}, high={opt['high']:g}")
        if opt["sigma"] < 0 or opt["smooth"] < 0:
            raise PluginError("tracer 'edges': sigma and smooth must be >= 0")
        if opt["equalize"]:
            gray = exposure.equalize_adapthist(gray)
        if opt["smooth"] > 0:
            gray = ndi.median_filter(gray, footprint=morphology.disk(max(1, round(opt["smooth"]))))
        # Thresholds are quantiles of the very gradient magnitude Canny computes
        # (Gaussian, then unnormalised Sobel), so they adapt to the contrast.
        if gray.size > _BIG:  # half the memory and time; float32 is ample for 8-bit tones
            gray = gray.astype(np.float32)
        blurred = ndi.gaussian_filter(gray, opt["sigma"], mode="nearest")
        low, high = np.quantile(_gradient_sample(blurred), [opt["low"], opt["high"]])
        floor = _MIN_STEP * 8.0 / (np.sqrt(2 * np.pi) * max(opt["sigma"], 0.5))  # Sobel peak of that step
        high = max(high, floor)
        low = min(max(low, 0.4 * floor), high)
        # Canny on the picture we already blurred (sigma 0 = no second blur): the same edges, once.
        edges = feature.canny(blurred, sigma=0.0, low_threshold=low, high_threshold=high, mode="nearest")
        return thin(edges), float(low), float(high)


def _gradient_sample(b: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude of ``b`` (as Canny computes it): everywhere on
    pictures up to _BIG pixels, else at about a million evenly spread pixels,
    whose quantiles are as good and cost no whole-picture filter passes."""
    from scipy import ndimage as ndi

    if b.size <= _BIG or min(b.shape) < 3:
        return np.hypot(ndi.sobel(b, 0), ndi.sobel(b, 1)).ravel()
    k = int(np.ceil(np.sqrt(b.size / 1e6)))
    r = np.arange(1, b.shape[0] - 1, k)[:, None]
    c = np.arange(1, b.shape[1] - 1, k)[None, :]
    g0 = (b[r + 1, c - 1] + 2 * b[r + 1, c] + b[r + 1, c + 1]) - (b[r - 1, c - 1] + 2 * b[r - 1, c] + b[r - 1, c + 1])
    g1 = (b[r - 1, c + 1] + 2 * b[r, c + 1] + b[r + 1, c + 1]) - (b[r - 1, c - 1] + 2 * b[r, c - 1] + b[r + 1, c - 1])
    return np.hypot(g0, g1).ravel()


@functools.lru_cache(maxsize=None)
def _guo_hall_tables() -> tuple[np.ndarray, np.ndarray]:
    """Which pixels the two sub-iterations of Guo and Hall's thinning (Comm. ACM 32(3), 1989,
    algorithm A1; the one ``skimage.morphology.thin`` runs) delete, by the 8-bit code of the
    3x3 neighbourhood: bit k-1 is neighbour x_k, x_1 east, then counter-clockwise."""
    x = ((np.arange(256)[:, None] >> np.arange(8)) & 1).astype(bool)  # x[:, k - 1] = x_k

    def X(k):  # x_k, k = 1..9 with x_9 = x_1
        return x[:, (k - 1) % 8]

    one_component = sum((~X(2 * i - 1) & (X(2 * i) | X(2 * i + 1))).astype(int) for i in range(1, 5)) == 1  # G1
    n1 = sum((X(2 * k - 1) | X(2 * k)).astype(int) for k in range(1, 5))
    n2 = sum((X(2 * k) | X(2 * k + 1)).astype(int) for k in range(1, 5))
    end_safe = (np.minimum(n1, n2) >= 2) & (np.minimum(n1, n2) <= 3)  # G2
    first = ~((X(2) | X(3) | ~X(8)) & X(1))  # G3
    second = ~((X(6) | X(7) | ~X(4)) & X(5))  # G3'
    return one_component & end_safe & first, one_component & end_safe & second


def thin(edges: np.ndarray) -> np.ndarray:
    """``skimage.morphology.thin`` (which, unlike skeletonize, keeps line ends), on edge pixels only.

    The same thinning, applied to the 3x3 neighbourhood codes of the set pixels rather than
    to the whole picture: Canny edges are a few per cent of a photo, so each pass costs that
    much instead of a full correlation (7x faster on a 3000 x 2200 photo).
    """
    skel = np.pad(edges.astype(bool), 1)
    rr, cc = np.nonzero(skel)
    ring = ((-1, -1, 8), (-1, 0, 4), (-1, 1, 2), (0, -1, 16), (0, 1, 1), (1, -1, 32), (1, 0, 64), (1, 1, 128))
    while len(rr):
        removed = 0
        for table in _guo_hall_tables():
            code = np.zeros(len(rr), np.intp)
            for dr, dc, wgt in ring:
                code += skel[rr + dr, cc + dc] * wgt
            gone = table[code]
            skel[rr[gone], cc[gone]] = False
            rr, cc = rr[~gone], cc[~gone]
            removed += int(gone.sum())
        if not removed:
            break
    return skel[1:-1, 1:-1]


def link_edges(edges: np.ndarray, min_length: float = 0.0, prune: bool = False) -> tuple[list[np.ndarray], int, int]:
    """Chains of (row, col) points covering a thin edge map, each edge pixel once.

    Returns (chains, number of edge objects, number of junction clusters).
    Edge objects are the non-branching runs between junctions; a chain
    shorter than ``min_length`` with a free end (a spur or a speck) is
    dropped, and the rest are joined straight through junctions, so fewer
    pen lifts are needed. With ``prune`` the dropping repeats until nothing
    changes: a short chain left with a free end once its branches are gone (a
    forked spur) goes too. Closed chains repeat their first point.
    """
    from scipy.sparse import csgraph

    h, w = edges.shape
    rr, cc = np.nonzero(edges)
    n = len(rr)
    if n == 0:
        return [], 0, 0
    rc = np.column_stack([rr, cc]).astype(float)
    ids = np.full((h + 2, w + 2), -1, dtype=np.int64)  # padded: neighbours never wrap
    ids[rr + 1, cc + 1] = np.arange(n)

    def at(dr, dc):
        return ids[rr + 1 + dr, cc + 1 + dc]

    src, dst = [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        nb = at(dr, dc)
        ok = nb >= 0
        if dr and dc:  # a diagonal beside an orthogonal two-step path would close a triangle
            ok &= (at(0, dc) < 0) & (at(dr, 0) < 0)
        src.append(np.flatnonzero(ok))
        dst.append(nb[ok])
    src, dst = np.concatenate(src), np.concatenate(dst)
    junction = np.diff(_graph(src, dst, n).indptr) >= 3

    # Without the junctions every component is a simple path or a cycle.
    keep = ~junction[src] & ~junction[dst]
    runs = _graph(src[keep], dst[keep], n)
    deg = np.diff(runs.indptr)
    _, label = csgraph.connected_components(runs, directed=False)
    # One DFS lists each component contiguously, in walking order, when every
    # component hangs by one start (an end if it has one) off a path of
    # virtual nodes n, n+1, ... (a path: scipy rescans a wide node's edges).
    nodes = np.flatnonzero(~junction)
    by = np.lexsort((deg[nodes], label[nodes]))
    starts = nodes[by][np.r_[True, np.diff(label[nodes][by]) != 0]]
    virtual = n + np.arange(len(starts))
    rooted = _graph(np.r_[src[keep], virtual, virtual[:-1]], np.r_[dst[keep], starts, virtual[1:]], n + len(starts))
    order = csgraph.depth_first_order(rooted, n, directed=False, return_predecessors=False)
    order = order[order < n]
    first = np.r_[0, np.flatnonzero(np.diff(label[order])) + 1]
    last = np.r_[first[1:], len(order)] - 1
    a, b = order[first], order[last]
    cycle = (last - first >= 2) & (deg[a] == 2)

    # Junction pixels that touch are one junction, drawn at its most central pixel.
    jj = junction[src] & junction[dst]
    _, jlabel = csgraph.connected_components(_graph(src[jj], dst[jj], n), directed=False)
    jnodes = np.flatnonzero(junction)
    jl = jlabel[jnodes]
    centre = np.zeros((n, 2))
    if len(jnodes):
        mean = np.stack([np.bincount(jl, rc[jnodes, k], minlength=n) for k in (0, 1)], 1)
        mean = mean[jl] / np.bincount(jl, minlength=n)[jl][:, None]
        best = np.lexsort((np.hypot(*(rc[jnodes] - mean).T), jl))
        best = best[np.r_[True, np.diff(jl[best]) != 0]]
        centre[jl[best]] = rc[jnodes[best]]

    # The junction(s) each run end touches; only a one-pixel run can touch two.
    s2, d2 = np.r_[src, dst], np.r_[dst, src]
    m = ~junction[s2] & junction[d2]
    s2, d2 = s2[m], d2[m]
    by = np.argsort(s2, kind="stable")
    s2, d2 = s2[by], d2[by]
    one = np.r_[True, s2[1:] != s2[:-1]] if len(s2) else np.zeros(0, bool)
    j1, j2 = np.full(n, -1), np.full(n, -1)
    j1[s2[one]], j2[s2[~one]] = d2[one], d2[~one]
    ja, jb = j1[a], np.where(a == b, j2[a], j1[b])
    ca, cb = np.where(ja >= 0, jlabel[ja], -1), np.where(jb >= 0, jlabel[jb], -1)

    # All chains in one array: [junction] + run pixels + [junction, or the
    # first pixel again for a cycle]; tails are listed first so that np.insert
    # puts a tail before the next run's head at the same index.
    head, tail = ca >= 0, (cb >= 0) | cycle
    extra = np.vstack([np.where(cycle[:, None], rc[a], centre[cb])[tail], centre[ca[head]]])
    pts = np.insert(rc[order], np.r_[last[tail] + 1, first[head]], extra, axis=0)
    stop = np.cumsum(last - first + 1 + head + tail)
    start = stop - (last - first + 1 + head + tail)
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(pts, axis=0).T))]
    length = cum[stop - 1] - cum[start]

    # Drop spurs and specks before joining, so they cannot hijack a junction.
    alive = (length >= min_length) | ((ca >= 0) & (cb >= 0) & (ca != cb))
    while prune:  # a spur's own branches gone, the spur has a free end: drop it too, to a fixed point
        ends = np.r_[ca[alive], cb[alive]]
        count = np.bincount(ends[ends >= 0], minlength=n)
        tied = (ca >= 0) & (cb >= 0) & (ca != cb) & (count[np.maximum(ca, 0)] > 1) & (count[np.maximum(cb, 0)] > 1)
        now = alive & ((length >= min_length) | tied)
        if np.array_equal(now, alive):
            break
        alive = now
    chains = _join(pts, start[alive], stop[alive], ca[alive], cb[alive])
    return chains, len(first), len(np.unique(jl))


def _graph(src, dst, n):
    from scipy import sparse

    m = sparse.coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(n, n))
    return (m + m.T).tocsr()


def _join(pts, start, stop, ca, cb) -> list[np.ndarray]:
    """Join chains ``pts[start:stop]`` through shared junctions, straightest first.

    Chain ends are numbered 2 * chain + side (side 0 = start); ``ca``/``cb``
    give the junction at each end (-1 = free).
    """
    nch = len(start)
    cl = np.stack([ca, cb], 1).ravel()
    e = np.flatnonzero(cl >= 0)
    ch, side = e // 2, e % 2
    # Heading of each end: from the junction into the chain, a few points in.
    k = np.minimum(_TANGENT_PX, stop[ch] - start[ch] - 1)
    tip = np.where(side == 0, start[ch], stop[ch] - 1)
    u = pts[np.where(side == 0, tip + k, tip - k)] - pts[tip]
    u /= np.maximum(np.hypot(*u.T), 1e-12)[:, None]
    # Every pair of ends at the same junction, scored 1 when one chain
    # continues the other straight on.
    by = np.argsort(cl[e], kind="stable")
    e, u, c = e[by], u[by], cl[e][by]
    gfirst = np.r_[0, np.flatnonzero(np.diff(c)) + 1] if len(c) else np.zeros(0, int)
    gsize = np.diff(np.r_[gfirst, len(c)])
    grp = np.repeat(np.arange(len(gfirst)), gsize)
    later = (gsize[grp] - (np.arange(len(e)) - gfirst[grp]) - 1) if len(e) else np.zeros(0, int)
    i = np.repeat(np.arange(len(e)), later)
    j = i + 1 + np.arange(len(i)) - np.repeat(np.cumsum(later) - later, later)
    best = np.argsort(np.einsum("ij,ij->i", u[i], u[j]), kind="stable")  # most opposed = straightest

    # Greedy, straightest first. Closing a loop is deferred: it never saves a
    # pen lift, while joining the same end to another chain does.
    group = list(range(nch))

    def find(x):
        while group[x] != x:
            group[x] = x = group[group[x]]
        return x

    partner = [-1] * (2 * nch)
    loops = []
    for x, y in zip(e[i[best]].tolist(), e[j[best]].tolist()):
        if partner[x] >= 0 or partner[y] >= 0:
            continue
        gx, gy = find(x >> 1), find(y >> 1)
        if gx == gy:
            loops.append((x, y))
            continue
        partner[x], partner[y], group[gx] = y, x, gy
    for x, y in loops:
        if partner[x] < 0 and partner[y] < 0:
            partner[x], partner[y] = y, x

    out, seen = [], [False] * nch
    for c0 in range(nch):
        if seen[c0]:
            continue
        x = 2 * c0  # walk back to a free end (or once round a loop) ...
        while partner[x] >= 0 and partner[x] >> 1 != c0:
            x = partner[x] ^ 1
        pieces = []
        while not seen[x >> 1]:  # ... then forward, entering each chain at end x
            c = x >> 1
            seen[c] = True
            p = pts[start[c]:stop[c]] if x % 2 == 0 else pts[start[c]:stop[c]][::-1]
            pieces.append(p if not pieces else p[1:])  # the shared junction point once
            if partner[x ^ 1] < 0:
                break
            x = partner[x ^ 1]
        out.append(pieces[0] if len(pieces) == 1 else np.concatenate(pieces))
    return out


def _lengths(polylines: list[np.ndarray]) -> np.ndarray:
    """Length of every polyline, in one pass over all points."""
    if not polylines:
        return np.zeros(0)
    counts = np.array([len(p) for p in polylines])
    stop = np.cumsum(counts)
    seg = np.r_[0.0, np.hypot(*np.diff(np.concatenate(polylines), axis=0).T)]
    seg[stop[:-1]] = 0.0  # not between one polyline and the next
    cum = np.cumsum(seg)
    return cum[stop - 1] - cum[stop - counts]


def _finish(chains: list[np.ndarray], tolerance: float, min_length: float, join: float = 0.0,
            staircase: float = 0.0) -> list[np.ndarray]:
    """Join chains meeting end to end, smooth, simplify, keep those at least ``min_length`` px long."""
    if join > 0 and len(chains) > 1:
        from doodlecam.geometry.order import merge_ends

        chains = merge_ends(chains, join)[0]
    if staircase > 0:
        chains = [unstair(c, staircase) for c in chains]
    out = simplify(chains, tolerance) if tolerance > 0 else chains
    keep = _lengths(out) >= max(min_length, 1e-9)
    return [p for p, k in zip(out, keep) if k and len(p) >= 2]


def unstair(chain: np.ndarray, sigma: float) -> np.ndarray:
    """A pixel chain smoothed along its length (Gaussian, ``sigma`` px).

    Edge pixels step in whole pixels, so a chain is a staircase; a spline
    fitted to it within 0.1 mm follows every step, which costs control points
    and makes the pen accelerate and brake at each one. Smoothing moves points
    by well under a pixel on straight runs. Open chains keep their end points
    (junctions stay joined); closed chains wrap around.
    """
    from scipy.ndimage import gaussian_filter1d

    if len(chain) < 4:
        return chain
    closed = np.array_equal(chain[0], chain[-1])
    if closed:
        ring = gaussian_filter1d(chain[:-1], sigma, axis=0, mode="wrap")
        out = np.vstack([ring, ring[:1]])
    else:
        out = gaussian_filter1d(chain, sigma, axis=0, mode="nearest")
        out[0], out[-1] = chain[0], chain[-1]
    # never move a point more than half a pixel: corners stay where the edge is
    d = out - chain
    r = np.hypot(*d.T)
    far = r > 0.5
    out[far] = chain[far] + d[far] * (0.5 / r[far])[:, None]
    return out


def simplify(chains: list[np.ndarray], tolerance: float) -> list[np.ndarray]:
    """Ramer-Douglas-Peucker on all chains at once, one split level per round.

    Every point stays within ``tolerance`` of the simplified chain; chain ends
    (junctions, and the repeated point of closed chains) are always kept.
    Vectorised across chains, so thousands of short chains cost a few passes
    over one array instead of a Python loop per split.
    """
    if not chains:
        return []
    p = np.concatenate(chains)
    stop = np.cumsum([len(c) for c in chains])
    keep = np.zeros(len(p), dtype=bool)
    keep[stop - 1] = keep[np.r_[0, stop[:-1]]] = True
    idx = np.arange(len(p))
    while True:
        kept = np.flatnonzero(keep)
        seg = np.searchsorted(kept, idx, side="right") - 1  # segment kept[seg] -> kept[seg + 1]
        seg = np.minimum(seg, len(kept) - 2)
        a, b = p[kept[seg]], p[kept[seg + 1]]
        ab, ap = b - a, p - a
        t = np.clip(np.einsum("ij,ij->i", ap, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0.0, 1.0)
        dist = np.hypot(*(ap - t[:, None] * ab).T)
        dist[keep] = 0.0
        worst = np.maximum.reduceat(dist, kept[:-1])  # per segment
        far = worst > tolerance
        if not far.any():
            break
        hit = (dist == worst[seg]) & far[seg] & ~keep
        first = np.unique(seg[hit], return_index=True)[1]  # one point per segment per round
        keep[idx[hit][first]] = True
    return [p[k] for k in np.split(np.flatnonzero(keep), np.searchsorted(np.flatnonzero(keep), stop[:-1]))]
