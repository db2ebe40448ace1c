"""Generated line art of known centre geometry, for the centre-line tracer's tests and benchmark.

Each picture is the set of pixels within half the line width of its centre
polylines (a round pen), dark on white, so the true centre line and its
length are known exactly.
"""

from __future__ import annotations

import numpy as np

# A stroke font: each letter a few polylines on a 4 x 6 grid (y down).
_FONT = {
    "H": [[(0, 0), (0, 6)], [(4, 0), (4, 6)], [(0, 3), (4, 3)]],
    "E": [[(4, 0), (0, 0), (0, 6), (4, 6)], [(0, 3), (3, 3)]],
    "L": [[(0, 0), (0, 6), (4, 6)]],
    "T": [[(0, 0), (4, 0)], [(2, 0), (2, 6)]],
    "V": [[(0, 0), (2, 6), (4, 0)]],
    "Z": [[(0, 0), (4, 0), (0, 6), (4, 6)]],
    "N": [[(0, 6), (0, 0), (4, 6), (4, 0)]],
}


def _dense(poly: np.ndarray, step: float = 0.05) -> np.ndarray:
    seg = np.diff(poly, axis=0)
    n = np.maximum(np.ceil(np.hypot(*seg.T) / step).astype(int), 1)
    pts = [poly[i] + seg[i] * (np.arange(k) / k)[:, None] for i, k in enumerate(n)]
    return np.vstack(pts + [poly[-1:]])


def polyline_length(polys: list[np.ndarray]) -> float:
    return float(sum(np.hypot(*np.diff(p, axis=0).T).sum() for p in polys))


def render(polys: list[np.ndarray], shape: tuple[int, int], width: float) -> np.ndarray:
    """8-bit grey picture (rows, cols): ink (0) within width / 2 of the polylines (x, y = col, row)."""
    from scipy import ndimage as ndi

    h, w = shape
    d = np.full((h, w), np.inf)
    rr, cc = np.mgrid[0:h, 0:w]
    pts = np.vstack([_dense(np.asarray(p, float)) for p in polys])
    # nearest centre point to every pixel, through a KD-tree (exact to the 0.05 px sampling)
    from scipy.spatial import cKDTree

    d = cKDTree(pts).query(np.column_stack([cc.ravel(), rr.ravel()]))[0].reshape(h, w)
    del ndi
    return np.where(d <= width / 2, 0, 255).astype(np.uint8)


def distance_to(polys: list[np.ndarray], points: np.ndarray) -> np.ndarray:
    """Distance of each (x, y) point to the nearest centre polyline (sampled every 0.05 px)."""
    from scipy.spatial import cKDTree

    return cKDTree(np.vstack([_dense(np.asarray(p, float)) for p in polys])).query(points)[0]


def circles() -> tuple[list[np.ndarray], tuple[int, int]]:
    t = np.linspace(0, 2 * np.pi, 721)
    polys = [np.column_stack([cx + r * np.cos(t), cy + r * np.sin(t)])
             for cx, cy, r in ((80, 80, 50), (200, 90, 35), (140, 190, 60))]
    return polys, (270, 280)


def grid() -> tuple[list[np.ndarray], tuple[int, int]]:
    polys = [np.array([[20.0, y], [220.0, y]]) for y in range(20, 221, 40)]
    polys += [np.array([[x, 20.0], [x, 220.0]]) for x in range(20, 221, 40)]
    return polys, (240, 240)


def text(word: str = "HELTVN", size: float = 9.0) -> tuple[list[np.ndarray], tuple[int, int]]:
    polys = []
    for k, ch in enumerate(word):
        for stroke in _FONT[ch]:
            polys.append(np.array(stroke, float) * size + (20 + k * 6 * size, 20))
    return polys, (int(40 + 6 * size), int(40 + len(word) * 6 * size))


def scribble(seed: int = 3) -> tuple[list[np.ndarray], tuple[int, int]]:
    """One long open curve crossing itself at wide angles (a Lissajous figure, seeded phase)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.8 * np.pi, 3001)
    ph = rng.uniform(0.3, 1.2)
    return [np.column_stack([150 + 115 * np.sin(3 * t + ph), 150 + 115 * np.sin(2 * t)])], (300, 300)


def big_drawing(seed: int = 1, shape: tuple[int, int] = (2200, 3000)) -> np.ndarray:
    """A large made-up line drawing (8-bit grey, rows x cols), drawn with skimage.draw: straight
    lines, circles and ellipses, Bézier curves and words of the stroke font, in 3, 5 and 9 px wide
    lines. At 3000 x 2200 it gives ~700 strokes, ~90 of which the path tolerance re-plans."""
    from scipy import ndimage as ndi
    from skimage import draw

    rng = np.random.default_rng(seed)
    h, w = shape
    widths = (3, 5, 9)
    masks = [np.zeros(shape, bool) for _ in widths]

    def ink(rr, cc):
        masks[rng.integers(len(widths))][rr, cc] = True

    for _ in range(60):
        r0, r1 = rng.integers(40, h - 40, 2)
        c0, c1 = rng.integers(40, w - 40, 2)
        ink(*draw.line(r0, c0, r1, c1))
    for _ in range(25):
        rad = int(rng.integers(20, 400))
        r, c = int(rng.integers(rad + 5, h - rad - 5)), int(rng.integers(rad + 5, w - rad - 5))
        if rng.random() < 0.5:
            ink(*draw.circle_perimeter(r, c, rad, shape=shape))
        else:
            ink(*draw.ellipse_perimeter(r, c, rad, int(rad * rng.uniform(0.2, 1)), orientation=rng.uniform(0, np.pi),
                                        shape=shape))
    for _ in range(30):
        p = rng.integers(40, min(h, w) - 40, 6)
        ink(*draw.bezier_curve(p[0], p[1] + 500, p[2], p[3] + 900, p[4], p[5], float(rng.uniform(0.5, 5)), shape=shape))
    letters = list(_FONT)
    for k in range(8):  # words: letters of the stroke font, 6-16 px per grid unit
        size, r0, c0 = rng.uniform(6, 16), 100 + k * (h - 200) / 8, rng.uniform(80, w / 2)
        m = masks[rng.integers(len(widths))]
        for j in range(int(rng.integers(4, 9))):
            for stroke in _FONT[letters[rng.integers(len(letters))]]:
                pts = [(r0 + y * size, c0 + (x + 6 * j) * size) for x, y in stroke]
                for (ra, ca), (rb, cb) in zip(pts, pts[1:]):
                    rr, cc = draw.line(int(ra), int(ca), int(rb), int(cb))
                    m[rr, cc] = True
    drawn = np.zeros(shape, bool)
    for width, m in zip(widths, masks):
        drawn |= ndi.binary_dilation(m, np.ones((width, width), bool))
    return np.where(drawn, 0, 255).astype(np.uint8)
