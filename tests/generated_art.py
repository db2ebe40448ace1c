"""Generated drawings as vsketch, p5.js or an Inkscape extension write them: many short paths.

Shared by tests/test_scale.py and benchmarks/bench_scale.py. Deterministic for a seed.
"""

from __future__ import annotations

import numpy as np

KINDS = ("lines", "curves", "shapes", "long", "grid", "mixed")


def generated_svg(n: int, kind: str = "mixed", seed: int = 1, width: float = 280.0, height: float = 196.0) -> str:
    """An SVG (mm) of ``n`` paths: short straight lines, short cubic curves, tiny closed
    polygons, long wandering curves, a grid of touching segments (connected paths cut
    into pieces, as generators write them), or a mix of the first four (4:3:2:1)."""
    rng = np.random.default_rng(seed)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:g}mm" height="{height:g}mm" '
           f'viewBox="0 0 {width:g} {height:g}">']
    if kind == "grid":
        cols = max(int(np.sqrt(n / 2)), 1)
        step = min((width - 10) / cols, (height - 10) / cols)
        k = 0
        for r in range(cols + 1):
            for c in range(cols):
                if k >= n:
                    break
                x, y = 5 + c * step, 5 + r * step  # horizontal pieces, then vertical ones: ends meet
                out.append(f'<path d="M{x:.3f},{y:.3f} L{x + step:.3f},{y:.3f}" fill="none" stroke="black"/>')
                k += 1
                if k < n:
                    out.append(f'<path d="M{y:.3f},{x:.3f} L{y:.3f},{x + step:.3f}" fill="none" stroke="black"/>')
                    k += 1
        out.append("</svg>")
        return "\n".join(out)
    for i in range(n):
        pick = {"lines": 0, "curves": 4, "shapes": 7, "long": 9}.get(kind, i % 10)
        x, y = rng.uniform(5, width - 5), rng.uniform(5, height - 5)
        if pick < 4:
            a, length = rng.uniform(0, 2 * np.pi), rng.uniform(2, 30)
            x2, y2 = np.clip([x + length * np.cos(a), y + length * np.sin(a)], 2, [width - 2, height - 2])
            out.append(f'<path d="M{x:.3f},{y:.3f} L{x2:.3f},{y2:.3f}" fill="none" stroke="black"/>')
        elif pick < 7:
            p = np.clip(np.cumsum(rng.normal(0, 4, (4, 2)), axis=0) + (x, y), 2, [width - 2, height - 2])
            out.append('<path d="M{:.3f},{:.3f} C{:.3f},{:.3f} {:.3f},{:.3f} {:.3f},{:.3f}" fill="none" '
                       'stroke="black"/>'.format(*p.ravel()))
        elif pick < 9:
            m, r = int(rng.integers(3, 7)), rng.uniform(0.8, 4)
            t = np.linspace(0, 2 * np.pi, m, endpoint=False) + rng.uniform(0, 6)
            pts = " ".join(f"{x + r * np.cos(u):.3f},{y + r * np.sin(u):.3f}" for u in t)
            out.append(f'<polygon points="{pts}" fill="none" stroke="black"/>')
        else:
            p = np.clip(np.cumsum(rng.normal(0, 6, (13, 2)), axis=0) + (x, y), 2, [width - 2, height - 2])
            d = f"M{p[0, 0]:.3f},{p[0, 1]:.3f} " + " ".join(
                f"Q{a:.3f},{b:.3f} {c:.3f},{e:.3f}" for (a, b), (c, e) in zip(p[1::2], p[2::2]))
            out.append(f'<path d="{d}" fill="none" stroke="black"/>')
    out.append("</svg>")
    return "\n".join(out)
