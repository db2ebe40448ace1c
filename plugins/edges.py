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

from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing
from doodlecam.raster import IMAGE_EXTENSIONS, load_gray

# A high threshold never drops below the gradient of a step of this size
# (fraction of black-to-white), so a blank, noisy sheet gives no edges.
_MIN_STEP = 0.02
_TANGENT_PX = 5  # how far along a chain its direction at a junction is measured


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
        Option("simplify", float, 0.8, "line simplification tolerance in px (Ramer-Douglas-Peucker)"),
        Option("min_length", float, 4.0, "drop strokes shorter than this, in px"),
    )

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in pixels: x = column, y = row (down), a pixel's centre at its index."""
        opt = self.resolve_options(options)
        gray = load_gray(path)
        edges, low, high = self.edge_map(gray, opt)
        chains, n_objects, n_junctions = link_edges(edges, opt["min_length"])
        polylines = _finish(chains, opt["simplify"], opt["min_length"])
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
                  "length_px": sum(_length(p) for p in polylines),
                  "low_threshold": low, "high_threshold": high},
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
        blurred = ndi.gaussian_filter(gray, opt["sigma"], mode="nearest")
        magnitude = np.hypot(ndi.sobel(blurred, 0), ndi.sobel(blurred, 1))
        low, high = np.quantile(magnitude, [opt["low"], opt["high"]])
        floor = _MIN_STEP * 8.0 / (np.sqrt(2 * np.pi) * max(opt["sigma"], 0.5))  # Sobel peak of that step
        high = max(high, floor)
        low = min(max(low, 0.4 * floor), high)
        edges = feature.canny(gray, sigma=opt["sigma"], low_threshold=low, high_threshold=high, mode="nearest")
        return morphology.thin(edges), float(low), float(high)  # thin(), unlike skeletonize(), keeps line ends


def link_edges(edges: np.ndarray, min_length: float = 0.0) -> tuple[list[np.ndarray], int, int]:
    """Chains of (row, col) points covering a thin edge map, each edge pixel once.

    Returns (chains, number of edge objects, number of junction clusters).
    Edge objects are the non-branching runs between junctions; a chain
    shorter than ``min_length`` with a free end (a spur or a speck) is
    dropped, and the rest are joined straight through junctions, so fewer
    pen lifts are needed. Closed chains repeat their first point.
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
    adj = _graph(src, dst, n)
    junction = np.diff(adj.indptr) >= 3

    # Without the junctions every component is a simple path or a cycle.
    keep = ~junction[src] & ~junction[dst]
    runs = _graph(src[keep], dst[keep], n)
    deg = np.diff(runs.indptr)
    _, label = csgraph.connected_components(runs, directed=False)
    # One DFS from a virtual root tied to one start per component (an end if
    # it has one) lists each component contiguously, in walking order.
    nodes = np.flatnonzero(~junction)
    first = np.lexsort((deg[nodes], label[nodes]))
    starts = nodes[first][np.r_[True, np.diff(label[nodes][first]) != 0]]
    rooted = _graph(np.r_[src[keep], np.full(len(starts), n)], np.r_[dst[keep], starts], n + 1)
    order = csgraph.depth_first_order(rooted, n, directed=False, return_predecessors=False)[1:]
    cuts = np.flatnonzero(np.diff(label[order])) + 1

    # Junction pixels that touch are one junction, drawn at its most central pixel.
    jj = junction[src] & junction[dst]
    _, jlabel = csgraph.connected_components(_graph(src[jj], dst[jj], n), directed=False)
    jnodes = np.flatnonzero(junction)
    jl = jlabel[jnodes]
    centre = np.zeros((n, 2))
    if len(jnodes):
        counts = np.bincount(jl, minlength=n)[jl][:, None]
        mean = np.stack([np.bincount(jl, rc[jnodes, k], minlength=n) for k in (0, 1)], 1)[jl] / counts
        best = np.lexsort((np.hypot(*(rc[jnodes] - mean).T), jl))
        best = best[np.r_[True, np.diff(jl[best]) != 0]]
        centre[jl[best]] = rc[jnodes[best]]

    chains, ends = [], []
    indptr, indices = adj.indptr, adj.indices
    for run in np.split(order, cuts):
        pts = rc[run]
        a, b = run[0], run[-1]
        if len(run) > 2 and deg[a] == 2:  # a cycle: no ends, no junctions
            chains.append(np.vstack([pts, pts[:1]]))
            ends.append((-1, -1))
            continue
        ja = [j for j in indices[indptr[a]:indptr[a + 1]] if junction[j]]
        jb = ja[1:] if a == b else [j for j in indices[indptr[b]:indptr[b + 1]] if junction[j]]
        ca = jlabel[ja[0]] if ja else -1
        cb = jlabel[jb[0]] if jb else -1
        pts = np.vstack([centre[[ca]] if ja else pts[:0], pts, centre[[cb]] if jb else pts[:0]])
        chains.append(pts)
        ends.append((ca, cb))
    n_objects = len(chains)

    # Drop spurs and specks before joining, so they cannot hijack a junction.
    lengths = [_length(p) for p in chains]
    alive = [L >= min_length or (e[0] >= 0 and e[1] >= 0 and e[0] != e[1]) for L, e in zip(lengths, ends)]
    chains = [c for c, k in zip(chains, alive) if k]
    ends = [e for e, k in zip(ends, alive) if k]
    return _join(chains, ends), n_objects, len(np.unique(jl))


def _graph(src, dst, n):
    from scipy import sparse

    m = sparse.coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(n, n))
    return (m + m.T).tocsr()


def _length(p: np.ndarray) -> float:
    return float(np.hypot(*np.diff(p, axis=0).T).sum()) if len(p) > 1 else 0.0


def _join(chains: list[np.ndarray], ends: list[tuple[int, int]]) -> list[np.ndarray]:
    """Join chains through shared junctions, straightest continuations first."""
    at: dict[int, list[tuple[int, int]]] = {}
    for i, e in enumerate(ends):
        for side in (0, 1):
            if e[side] >= 0:
                at.setdefault(e[side], []).append((i, side))

    def heading(i, side):  # unit vector pointing from the junction into the chain
        p = chains[i] if side == 0 else chains[i][::-1]
        d = p[min(_TANGENT_PX, len(p) - 1)] - p[0]
        return d / (np.hypot(*d) or 1.0)

    pairs = []  # (straightness, end, end); 1 = the two chains continue each other straight
    for inc in at.values():
        if len(inc) >= 2:
            u = np.array([heading(*e) for e in inc])
            i, j = np.triu_indices(len(inc), 1)
            pairs += zip(-np.einsum("kd,kd->k", u[i], u[j]), (inc[k] for k in i), (inc[k] for k in j))
    # Greedy, straightest first. Closing a loop is deferred: it never saves a
    # pen lift, while joining the same end to another chain does.
    group = list(range(len(chains)))

    def find(i):
        while group[i] != i:
            group[i] = i = group[group[i]]
        return i

    link: dict[tuple[int, int], tuple[int, int]] = {}
    loops = []
    for _, a, b in sorted(pairs, key=lambda p: -p[0]):
        if a in link or b in link:
            continue
        if find(a[0]) == find(b[0]):
            loops.append((a, b))
            continue
        link[a], link[b] = b, a
        group[find(a[0])] = find(b[0])
    for a, b in loops:
        if a not in link and b not in link:
            link[a], link[b] = b, a

    out, seen = [], set()
    for i in range(len(chains)):
        if i in seen:
            continue
        c, side = i, 0  # walk back to a free end (or once round a loop)
        while (c, side) in link:
            c2, s2 = link[(c, side)]
            if c2 == i:
                break
            c, side = c2, 1 - s2
        pieces = []
        while c not in seen:  # walk forward, entering chain c at end `side`
            seen.add(c)
            p = chains[c] if side == 0 else chains[c][::-1]
            pieces.append(p if not pieces else p[1:])  # the shared junction point once
            if (c, 1 - side) not in link:
                break
            c, side = link[(c, 1 - side)]
        out.append(np.vstack(pieces))
    return out


def _finish(chains: list[np.ndarray], tolerance: float, min_length: float) -> list[np.ndarray]:
    """Simplify each chain and keep those at least ``min_length`` px long."""
    out = simplify(chains, tolerance) if tolerance > 0 else chains
    return [p for p in out if len(p) >= 2 and _length(p) >= max(min_length, 1e-9)]


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
