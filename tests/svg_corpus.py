"""SVG files with the features design tools write, and the exact pen-down length of each (mm).

Shared by tests/test_vector_corpus.py and benchmarks/bench_vector.py (which measures vpype's
reader on the same files)."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ellipe

HEAD = ('<svg xmlns="http://www.w3.org/2000/svg" xmlns:xlink="http://www.w3.org/1999/xlink" '
        'xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" width="200mm" height="100mm" viewBox="0 0 200 100">')


def ellipse_perimeter(a: float, b: float) -> float:
    a, b = max(a, b), min(a, b)
    return 4 * a * ellipe(1 - (b / a) ** 2)


def _cubic_length(*pts, n=200_001) -> float:
    p0, p1, p2, p3 = map(np.asarray, pts)
    t = np.linspace(0, 1, n)[:, None]
    q = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t ** 2 * p2 + t ** 3 * p3
    return float(np.hypot(*np.diff(q, axis=0).T).sum())


LEAF = _cubic_length((0, 0), (10, -10), (20, -10), (30, 0)) + _cubic_length((30, 0), (20, 10), (10, 10), (0, 0))

CORPUS: dict[str, tuple[str, float]] = {
    "ellipse": ('<ellipse cx="100" cy="50" rx="30" ry="10" transform="rotate(30 100 50)"/>', ellipse_perimeter(30, 10)),
    "use": ('<defs><circle id="dot" cx="0" cy="0" r="5"/></defs><use xlink:href="#dot" x="20" y="30"/>'
            '<use href="#dot" transform="translate(60 40) scale(2)"/>', 2 * math.pi * 5 + 2 * math.pi * 10),
    "clip-path": ('<defs><clipPath id="c"><rect x="0" y="0" width="10" height="10"/></clipPath></defs>'
                  '<g transform="translate(50 0)"><line x1="-20" y1="5" x2="30" y2="5" clip-path="url(#c)"/></g>'
                  '<g clip-path="url(#c)" transform="translate(100 0)"><circle cx="0" cy="0" r="5"/></g>',
                  10 + 2 * math.pi * 5 / 4),
    "hidden": ('<g inkscape:groupmode="layer" inkscape:label="shown"><line x1="0" y1="0" x2="10" y2="0"/></g>'
               '<g inkscape:groupmode="layer" inkscape:label="off" style="display:none"><line x1="0" y1="9" x2="90" y2="9"/></g>'
               '<line x1="0" y1="20" x2="50" y2="20" display="none"/>'
               '<g visibility="hidden"><line x1="0" y1="30" x2="50" y2="30"/></g>'
               '<line x1="0" y1="40" x2="50" y2="40" style="visibility:hidden"/>', 10.0),
    "arcs": ('<path d="M 40 50 A 20 20 0 0 1 80 50 A 20 20 0 0 1 40 50 Z"/><path d="M 150 50 a 30 15 0 0 0 30 -15"/>',
             2 * math.pi * 20 + ellipse_perimeter(30, 15) / 4),
    "beziers": ('<path d="M 10 80 C 40 10, 65 10, 95 80 S 150 150, 180 80"/>',
                _cubic_length((10, 80), (40, 10), (65, 10), (95, 80)) + _cubic_length((95, 80), (125, 150), (150, 150), (180, 80))),
    "design-tool": ('<defs><clipPath id="c"><rect x="0" y="0" width="100" height="100"/></clipPath>'
                    '<path id="leaf" d="M 0 0 C 10 -10 20 -10 30 0 C 20 10 10 10 0 0 Z"/></defs>'
                    '<g inkscape:groupmode="layer" inkscape:label="Black" clip-path="url(#c)">'
                    '<rect x="5" y="5" width="90" height="90" rx="10"/>'
                    '<line x1="-50" y1="50" x2="150" y2="50" stroke="black"/></g>'
                    '<g inkscape:groupmode="layer" inkscape:label="Red">'
                    '<ellipse cx="150" cy="50" rx="40" ry="20" stroke="red"/>'
                    '<use xlink:href="#leaf" x="135" y="50"/></g>'
                    '<g inkscape:groupmode="layer" inkscape:label="Draft" style="display:none"><circle cx="50" cy="50" r="45"/></g>'
                    '<text x="10" y="10">not drawn</text>',
                    2 * (70 + 70) + 2 * math.pi * 10 + 100 + ellipse_perimeter(40, 20) + LEAF),
}


def write_corpus(folder) -> dict:
    """Write every file into ``folder``: {path: exact length in mm}."""
    from pathlib import Path

    out = {}
    for name, (body, exact) in CORPUS.items():
        path = Path(folder) / f"{name}.svg"
        path.write_text(HEAD + body + "</svg>")
        out[path] = exact
    return out
