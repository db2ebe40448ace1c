"""The built-in ``vector`` tracer: SVG and DXF drawings, and STL meshes.

* **SVG** (svgelements): paths, lines, polylines, polygons, rectangles,
  circles and ellipses, with every ``transform`` applied. Lengths are in mm:
  the root's ``width`` / ``height`` with units (mm, cm, in, pt, pc, px at 96
  per inch) against its ``viewBox`` give the size of one user unit; without
  them a user unit is a CSS px (0.2646 mm). The viewBox is the canvas the
  layout fits, so the drawing keeps its place on the page. Text is not
  drawn: convert it to paths first.
* **DXF** (ezdxf): lines, arcs, circles, (LW)polylines, splines and
  ellipses in model space; ``$INSUNITS`` gives the unit (mm when unset).
  Entities it cannot draw (text, hatches, dimensions, ...) are counted
  in the drawing's metadata; a file with none it can draw is an error.
* **STL / OBJ / PLY / OFF** (trimesh, the ``mesh`` extra): the outline of the mesh's section by
  a plane (``mesh = section``, ``plane = z=50%``: the plane at right angles
  to z half-way up; ``z=12.5`` is 12.5 mm; ``0,1,1=30%`` a tilted plane), or
  its silhouette seen along a direction (``mesh = silhouette``,
  ``direction = z``: seen from above), holes included. Meshes are in mm.

Curves become polylines within ``tolerance`` mm of the true curve (the spline
fit later smooths them), and pieces that meet end to end are joined into
one stroke.
"""

from __future__ import annotations

import io
import itertools
import re
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.collector import no_collections
from doodlecam.errors import InputError, PluginError
from doodlecam.extras import require
from doodlecam.model import Drawing
from doodlecam.plugins.svgrules import render_rules

MESH_EXTENSIONS = (".stl", ".obj", ".ply", ".off")
_UNIT_MM = {"mm": 1.0, "cm": 10.0, "in": 25.4, "pt": 25.4 / 72, "pc": 25.4 / 6, "px": 25.4 / 96, "": 25.4 / 96,
            "q": 0.25, "m": 1000.0}
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
_MAX_BYTES = 200 * 1024 * 1024  # larger vector files are refused before parsing


class VectorTracer(Tracer):
    name = "vector"
    summary = "SVG and DXF drawings, and an STL mesh's section or silhouette (through trimesh)"
    extensions = (".svg", ".dxf") + MESH_EXTENSIONS
    options = (
        Option("tolerance", float, 0.02, "largest distance in mm between a curve and the polyline drawn for it"),
        Option("corner", float, 30.0, "keep corners exact where a path turns by more than this many degrees (polyline "
               "vertices, joins of segments): the stroke is split there and the pen stops on the corner without "
               "lifting (0 = round corners within the fit tolerance)"),
        Option("layers", str, "auto", "SVG/DXF: strokes' layers by 'layer' (Inkscape/DXF layers), 'colour' (SVG stroke "
               "colour), 'group' (SVG top-level groups), 'none', or 'auto' (layers, else colours)"),
        Option("mesh", str, "section", "meshes: 'section' (cut by a plane) or 'silhouette' (outline seen along a direction)"),
        Option("plane", str, "z=50%", "section plane: AXIS=POS with AXIS x, y, z or a normal 'a,b,c' and POS in mm or % of the extent"),
        Option("direction", str, "z", "silhouette view direction: x, y, z or 'a,b,c' (seen looking down it)"),
    )

    @classmethod
    def check_extension(cls, ext: str) -> None:
        if ext in MESH_EXTENSIONS:
            require("mesh", "a mesh (STL, OBJ, PLY, OFF)")

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in mm, y up (SVG: y down, as the file has it)."""
        opt = self.resolve_options(options)
        opt["layers"] = str(opt["layers"]).strip().lower()
        if opt["layers"] not in ("auto", "layer", "colour", "color", "group", "none"):
            raise PluginError(f"tracer 'vector': layers must be auto, layer, colour, group or none, got {opt['layers']!r}")
        if not opt["tolerance"] > 0:
            raise PluginError(f"tracer 'vector': tolerance must be > 0 mm, got {opt['tolerance']:g}")
        if not 0 <= opt["corner"] < 180:
            raise PluginError(f"tracer 'vector': corner must be 0 (off) to below 180 degrees, got {opt['corner']:g}")
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such file; check the path")
        size = path.stat().st_size
        if size == 0:
            raise InputError(f"{path}: the file is empty (0 bytes); give an SVG, DXF or STL file")
        if size > _MAX_BYTES:
            raise InputError(f"{path}: {size / 2**20:.0f} MB is too large for a plotter drawing; simplify it first")
        ext = path.suffix.lower()
        read = {".svg": _svg, ".dxf": _dxf, **{e: _mesh for e in MESH_EXTENSIONS}}.get(ext)
        if read is None:
            raise InputError(f"{path}: the vector tracer reads {', '.join(self.extensions)} files; "
                             "pick another tracer with --tracer")
        drawing = read(path, opt)
        if opt["corner"] > 0:  # the fitter cuts the strokes at these corners (pipeline.plan_job)
            drawing.meta["split_corners_deg"] = float(opt["corner"])
        return drawing


# ---------------------------------------------------------------- 2-D drawings

def _join(polylines: list[np.ndarray], tol: float) -> list[np.ndarray]:
    """Pieces meeting end to end become one stroke; a stroke ending at its start is closed exactly."""
    from doodlecam.geometry.order import merge_ends

    joined, _ = merge_ends(polylines, tol)
    out = []
    for p in joined:
        if len(p) >= 3 and np.hypot(*(p[0] - p[-1])) <= tol:
            p = np.vstack([p[:-1], p[:1]])
        out.append(p)
    return out


_CURVE_TURN = 0.25  # a curve's chords turn by at most this share of the corner angle at each point
# ... unless that takes more points: a cusp (a real corner, kept as one), or a hairpin so tight its
# turn is as good as one. A segment turns by at most ~2 pi, 48 chords at a quarter of 30 degrees,
# so 1024 leaves its speed 20x uneven; 4096 gave every cusp of a generated drawing 4 097 points
# (art20k: 4.7 -> 2.6 M points, its fit 5.0 -> 3.7 s CPU, 58 more corner pieces of 42 491)
_TURN_MAX_POINTS = 1024
_MAX_POINTS = 200_000  # points on one curve at most


def _curve_points(seg, tol: float, corner: float = 0.0) -> np.ndarray:
    """Points along one curved segment (an elliptical arc, or any segment svgelements can
    evaluate) whose chords stay within ``tol`` of it, end points included: as
    ``_bezier_points`` (which see), one segment at a time through svgelements' npoint."""
    from doodlecam.geometry.fit import turn_angles

    t = np.linspace(0.0, 1.0, 65)
    p = np.asarray(seg.npoint(t), float)
    d2 = float(np.abs(p[2:] - 2 * p[1:-1] + p[:-2]).max()) * 64**2
    n = max(1, int(np.ceil(1.2 * np.sqrt(d2 / (8 * tol)))))
    max_turn = np.radians(corner * _CURVE_TURN)
    sag_rounds = 0
    while True:
        n = min(n, _MAX_POINTS)
        t = np.linspace(0.0, 1.0, n + 1)
        p = np.asarray(seg.npoint(t), float)
        mid = np.asarray(seg.npoint((t[:-1] + t[1:]) / 2), float)
        sag = n == _MAX_POINTS or sag_rounds == 8 or np.hypot(*(mid - (p[:-1] + p[1:]) / 2).T).max() <= tol
        smooth = not corner or n >= _TURN_MAX_POINTS or turn_angles(p).max(initial=0.0) <= max_turn
        if sag and smooth:
            return p
        sag_rounds += not sag
        n *= 2


def _bezier_points(ctrl: np.ndarray, tol: float, corner: float = 0.0) -> list[np.ndarray | None]:
    """Points along each Bézier segment (control points ``ctrl``, (m, 3 or 4, 2)) whose chords
    stay within ``tol`` of it, end points included; all segments evaluated together.

    The chord over a parameter step dt sags by at most max|P''| dt² / 8; max|P''| is
    estimated from 64 samples, and the midpoints of the chords are then checked against
    the curve itself, doubling the count until every chord is within tolerance. With
    ``corner`` (degrees), also until the chords turn by at most a quarter of it at each
    point, so the fitter, which keeps every turn sharper than ``corner`` as a corner,
    finds only the path's own tangent breaks (a chord at a smooth join leans by half a
    turn, so a join is misjudged by at most an eighth of ``corner``). Each segment takes
    the steps ``_curve_points`` takes, in compiled passes (``plugins/bezier.py``) with
    svgelements' arithmetic, so the points are the same to the bit. A segment whose estimate
    is not finite is left as None for ``_curve_points`` (which raises on it as before).
    """
    from doodlecam.plugins.bezier import chord_counts, chord_points

    ctrl = np.ascontiguousarray(ctrl, float)
    max_turn = float(np.radians(corner * _CURVE_TURN)) if corner else -1.0
    n = chord_counts(ctrl, float(tol), max_turn, _MAX_POINTS, _TURN_MAX_POINTS)
    ok = n > 0
    points = np.empty((int((n[ok] + 1).sum()), 2))
    chord_points(ctrl, n, points)
    out: list[np.ndarray | None] = [None] * len(ctrl)
    for k, q in zip(np.flatnonzero(ok), np.split(points, np.cumsum(n[ok] + 1)[:-1])):
        out[k] = q
    return out


def _identity(pt) -> tuple[float, float]:
    """A point as svgelements' reify leaves it under the identity matrix (x 1 + y 0 + 0: -0.0 becomes 0.0)."""
    x, y = pt.x, pt.y
    return x * 1.0 + y * 0.0 + 1 * 0.0, x * 0.0 + y * 1.0 + 1 * 0.0


def _plain(p):
    return p.x, p.y


class _Curves:
    """Curved segments met while reading shapes, numbered in order, and the points found for them."""

    def __init__(self):
        self.segs: list = []
        self.ctrl: dict[int, list] = {3: [], 4: []}  # control points of quadratic / cubic Béziers
        self.where: dict[int, list[int]] = {3: [], 4: []}  # ... and their numbers
        self.points: list = []

    def add(self, seg, point) -> int:
        import svgelements as se

        k = len(self.segs)
        self.segs.append(seg)
        if isinstance(seg, se.CubicBezier):
            c = [point(seg.start), point(seg.control1), point(seg.control2), point(seg.end)]
        elif isinstance(seg, se.QuadraticBezier):
            c = [point(seg.start), point(seg.control), point(seg.end)]
        else:
            return k  # an arc: svgelements evaluates it
        self.ctrl[len(c)].append(c)
        self.where[len(c)].append(k)
        return k

    def evaluate(self, tol: float, corner: float) -> None:
        self.points = [None] * len(self.segs)
        for size in (3, 4):
            if self.ctrl[size]:
                for k, q in zip(self.where[size], _bezier_points(np.array(self.ctrl[size], float), tol, corner)):
                    self.points[k] = q
        for k, seg in enumerate(self.segs):
            if self.points[k] is None:  # arcs, and curves whose estimate is not finite
                self.points[k] = _curve_points(seg, tol, corner)


def _shape_plan(shape, curves: _Curves) -> list[list]:
    """``shape``'s subpaths as lists of points (x, y), curve k (its points after the first)
    or ~k (its first point); curves are registered in ``curves``.

    The parse (reify=True) leaves shapes with the identity transform: paths of lines and
    Béziers, polylines and polygons are read as they are, their points as svgelements'
    reify would leave them (``_identity``), without the cost of a Path copy and reify.
    Other shapes (arcs, rectangles, circles, ...) go through a reified Path."""
    import svgelements as se

    if shape.transform.is_identity() and isinstance(shape, (se.Polyline, se.Polygon)):
        if shape.is_degenerate():
            return []
        pts = [_identity(p) for p in shape.points]  # svgelements: a Move, Lines, and a Close for a polygon
        if isinstance(shape, se.Polygon):
            pts.append(pts[0])
        return [pts] if len(pts) > 1 else []
    segs, point = shape.segments(transformed=False), _identity
    fast = (se.Move, se.Line, se.Close, se.QuadraticBezier, se.CubicBezier)
    if not (isinstance(shape, se.Path) and shape.transform.is_identity() and all(isinstance(s, fast) for s in segs)):
        path = se.Path(shape)
        path.reify()
        segs, point = path.segments(transformed=False), _plain
    polys: list[list] = []
    pts: list = []
    for seg in segs:  # svgelements' subpaths: from a Move, or after a Close, to the next
        if isinstance(seg, se.Move):
            if len(pts) > 1:
                polys.append(pts)
            pts = [point(seg.end)]
            continue
        if seg.start is not None and seg.end is not None:
            if isinstance(seg, (se.Line, se.Close)):
                if not pts:
                    pts = [point(seg.start)]
                pts.append(point(seg.end))
            else:
                k = curves.add(seg, point)
                if not pts:
                    pts = [~k]
                pts.append(k)
        if isinstance(seg, se.Close):
            if len(pts) > 1:
                polys.append(pts)
            pts = []
    if len(pts) > 1:
        polys.append(pts)
    return polys


def _paths_polylines(shapes, tol: float, corner: float = 0.0) -> list[list[np.ndarray]]:
    """Each svgelements shape as polylines, one per subpath, in its units, without zero-length
    steps (subpaths left with less than a line, or not finite, are dropped): the Béziers of
    all shapes evaluated together (``_bezier_points``), subpaths of straight lines turned into
    arrays all at once."""
    curves = _Curves()
    plans = [_shape_plan(shape, curves) for shape in shapes]
    curves.evaluate(tol, corner)
    # every subpath's points as a run of one array (the straight ones' from one list of (x, y), the
    # others' piece by piece), so that the checks are a few passes over it, not a few per subpath
    rows: list = []
    pieces: list[np.ndarray] = []
    size = 0
    runs = []  # per shape, per subpath: (in pieces, first point, end)
    for polys in plans:
        spans = []
        for pts in polys:
            if all(type(q) is tuple for q in pts):
                spans.append((False, len(rows), len(rows) + len(pts)))
                rows += pts
                continue
            first = size
            for points, group in itertools.groupby(pts, key=lambda q: type(q) is tuple):
                add = [np.array(list(group), float)] if points else \
                    [curves.points[k][1:] if k >= 0 else curves.points[~k][:1] for k in group]
                pieces += add
                size += sum(len(q) for q in add)
            spans.append((True, first, size))
        runs.append(spans)
    flat = np.concatenate([np.array(rows, float).reshape(-1, 2), *pieces])
    x, y = flat[:, 0], flat[:, 1]
    # zero-length steps and points that are not finite, counted up to each point
    zero = np.r_[0, np.cumsum((x[1:] == x[:-1]) & (y[1:] == y[:-1]))]
    bad = np.r_[0, np.cumsum(~(np.isfinite(x) & np.isfinite(y)))]
    out = []
    for spans in runs:
        mine = []
        for in_pieces, a, b in spans:
            a, b = (a + len(rows), b + len(rows)) if in_pieces else (a, b)
            q = flat[a:b] if zero[b - 1] == zero[a] and bad[b] == bad[a] else _polyline(flat[a:b])
            if q is not None:
                mine.append(q)
        out.append(mine)
    return out


def _polyline(poly: np.ndarray) -> np.ndarray | None:
    """A subpath's points without zero-length steps; None when less than a line is left or it is not finite."""
    d = np.diff(poly, axis=0)
    step = (d[:, 0] != 0) | (d[:, 1] != 0)  # a column at a time: 10x faster than np.any(axis=1)
    if not step.all():
        if step.sum() < 1:
            return None
        poly = poly[np.r_[True, step]]
    return poly if np.isfinite(poly).all() else None


def _mm_per_px(svg) -> float:
    """Millimetres per unit of svgelements' output (CSS px at 96 per inch).

    svgelements converts mm and cm with 0.0393701 in/mm (1.3e-6 off); where the root's
    width or height is in mm or cm, the exact factor is taken from that length instead."""
    for key, size in (("width", svg.width), ("height", svg.height)):
        m = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(mm|cm)\s*", str(svg.values.get(key, "")))
        if m and size:
            return float(m.group(1)) * _UNIT_MM[m.group(2)] / float(size)
    return _UNIT_MM["px"]


_NOT_DRAWN_SVG = {"text": "text", "image": "raster image", "linearGradient": "gradient",
                  "radialGradient": "gradient", "pattern": "pattern fill", "mask": "mask"}
_NOT_DRAWN_HINT = {"text": "convert text to paths"}


def _svg_scan(path: Path) -> dict[str, int]:
    """Read the file once with the standard library's XML parser (internal entities are
    expanded, external ones never fetched): the root must be <svg>; counts elements that a
    pen cannot draw, for the warning line."""
    import xml.etree.ElementTree as ET

    counts: dict[str, int] = {}
    try:
        for i, (_, el) in enumerate(ET.iterparse(str(path), events=("start",))):
            tag = str(el.tag).rpartition("}")[2]
            if i == 0 and tag != "svg":
                raise InputError(f"{path}: the root element is <{tag}>, not <svg>; give an SVG file")
            what = _NOT_DRAWN_SVG.get(tag)
            if what:
                counts[what] = counts.get(what, 0) + 1
    except ET.ParseError as e:
        msg = " ".join(str(e).split())[:100]
        raise InputError(f"{path}: not a readable SVG file ({msg}); re-export it") from None
    return counts


_NUMERIC = {"d", "points", "x", "y", "width", "height", "cx", "cy", "r", "rx", "ry", "x1", "y1", "x2", "y2",
            "transform", "viewBox"}
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_NOT_A_NUMBER = re.compile(r"nan|inf", re.I)


def _excerpt(text: str) -> str:
    """A short, printable excerpt of file text for a message (never raw bytes)."""
    return repr(text[:40] + ("..." if len(text) > 40 else ""))


def _printable(text: str, n: int = 100) -> str:
    """A parser's message for one line: whitespace runs as one space, control bytes escaped, at most n chars."""
    text = " ".join(str(text).split())
    return "".join(c if c.isprintable() else f"\\x{ord(c):02x}" for c in text)[:n]


def _svg_check_numbers(path: Path) -> None:
    """Refuse, with the element and its line, what a renderer would refuse or svgelements would quietly drop or
    change: non-finite numbers (NaN, inf, 1e999) in geometry, negative sizes, a viewBox of zero size."""
    import math
    import xml.parsers.expat

    parser = xml.parsers.expat.ParserCreate(namespace_separator=" ")
    found: list[str] = []

    def start(name, attrs):
        if found:
            return
        tag = name.rpartition(" ")[2]
        attrs = {k.rpartition(" ")[2]: v for k, v in attrs.items()}
        line = parser.CurrentLineNumber

        def what():  # made only for a message: most elements need none
            return f"line {line}: <{tag}" + (f" id={attrs['id']!r}" if "id" in attrs else "") + ">"

        for key in _NUMERIC & attrs.keys():
            v = attrs[key]
            big = "e" in v or "E" in v or len(v) > 300  # only an exponent or 300 digits overflow a float
            if _NOT_A_NUMBER.search(v) or big and not all(math.isfinite(float(t)) for t in _NUMBER.findall(v)):
                found.append(f"{what()} has a number that is not finite in {key}={_excerpt(v)}; fix it in the file")
                return
        for key in ("width", "height", "r", "rx", "ry"):
            m = _NUMBER.match(attrs.get(key, "").strip())
            if m and float(m.group()) < 0:
                found.append(f"{what()} has a negative {key} ({_excerpt(attrs[key])}), which SVG does not allow; "
                             "fix it in the file")
                return
        if tag == "svg" and "viewBox" in attrs:
            box = [float(t) for t in _NUMBER.findall(attrs["viewBox"])]
            if len(box) != 4 or box[2] <= 0 or box[3] <= 0:
                found.append(f"{what()} has a viewBox of no size ({_excerpt(attrs['viewBox'])}); give it a width and "
                             "height above 0")

    parser.StartElementHandler = start
    try:
        with open(path, "rb") as f:
            parser.ParseFile(f)
    except xml.parsers.expat.ExpatError:
        return  # malformed files are refused by the scan, with its message
    if found:
        raise InputError(f"{path}: {found[0]}")


def _colour(shape) -> str:
    for c in (shape.stroke, shape.fill):
        if c is not None and getattr(c, "value", None) is not None:
            return c.hexrgb
    return "#000000"


def _clip_region(node, tol: float):
    """The region (shapely) that ``node``'s clip-path lets through, in final coordinates.

    The clip path's shapes come reified in the coordinates where <clipPath> was defined;
    clipPathUnits="userSpaceOnUse" puts them in the user space of the element that uses
    them, so they are mapped from the one to the other."""
    clip = getattr(node, "clip_path", None)
    if clip is None:  # most shapes: no clip, and no shapely to import
        return None
    import svgelements as se
    from shapely.affinity import affine_transform
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    # svgelements' a * b applies a, then b: undo the clip's own placement, then the user's
    m = ~se.Matrix(clip.values.get("transform", "")) * se.Matrix(node.values.get("transform", ""))
    rings = []
    for shape in clip:
        if isinstance(shape, se.Shape):
            rings += [Polygon(q).buffer(0) for q in _paths_polylines([shape], tol)[0] if len(q) >= 3]
    region = unary_union(rings) if rings else Polygon()
    # svgelements' Matrix(a, b, c, d, e, f) maps (x, y) to (a x + c y + e, b x + d y + f)
    return affine_transform(region, [m.a, m.c, m.b, m.d, m.e, m.f])


def _clipped(polys: list[np.ndarray], region) -> list[np.ndarray]:
    from shapely.geometry import LineString

    out = []
    for q in polys:
        inside = LineString(q).intersection(region)
        for g in getattr(inside, "geoms", [inside]):
            if g.geom_type == "LineString" and not g.is_empty and g.length > 0:
                out.append(np.asarray(g.coords, float))
    return out


_INKSCAPE = "{http://www.inkscape.org/namespaces/inkscape}"


_SHAPES_AT_ONCE = 4096  # shapes whose curves are evaluated together (bounds the memory of their points)


def _svg_shapes(svg, tol: float, corner: float = 0.0):
    """(polylines, layer name, colour) of every visible shape, clip paths applied."""
    import svgelements as se

    found = []  # (polylines, inkscape layer, top group, colour, index of the shape)
    pending = []  # shapes waiting for their points: (shape, clip regions, layer, top group, colour)
    seen = [0]  # shapes handed to pending so far

    def flush():
        polys = _paths_polylines([shape for shape, *_ in pending], tol, corner)
        first = seen[0] - len(pending)
        for i, ((_, regions, layer, group, colour), qs) in enumerate(zip(pending, polys)):
            for r in regions:
                qs = _clipped(qs, r)
            if qs:
                found.append((qs, layer, group, colour, first + i))
        pending.clear()

    def walk(node, layer, group, regions):
        for child in node:
            if isinstance(child, se.ClipPath):
                continue
            region = _clip_region(child, tol)
            here = regions + [region] if region is not None else regions
            if isinstance(child, (se.Group, se.Use)):
                lay = layer
                if layer is None and child.values.get(_INKSCAPE + "groupmode") == "layer":
                    lay = child.values.get(_INKSCAPE + "label") or child.values.get("id") or "layer"
                walk(child, lay, group if group is not None else seen[0], here)  # named below
            elif isinstance(child, se.Shape) and not isinstance(child, se.Text):
                if child.values.get("visibility") in ("hidden", "collapse"):
                    continue
                if all(c is None or getattr(c, "value", None) is None for c in (child.stroke, child.fill)):
                    continue  # no stroke and no fill: it renders nothing (a fill-only shape is drawn as its outline)
                pending.append((child, here, layer, group, _colour(child)))
                seen[0] += 1
                if len(pending) >= _SHAPES_AT_ONCE:
                    flush()

    walk(svg, None, None, [])
    flush()
    # a top-level group is "group N", N - 1 the number of shapes drawn before it
    drawn = np.searchsorted([i for *_, i in found], [g if g is not None else 0 for _, _, g, _, _ in found])
    return [(qs, layer, None if g is None else f"group {n + 1}", colour)
            for (qs, layer, g, colour, _), n in zip(found, drawn)]


def _layer_names(found, by: str) -> list[str]:
    if by == "auto":
        if any(layer is not None for _, layer, _, _ in found):
            by = "layer"
        elif len({c for *_, c in found}) > 1:
            by = "colour"
        else:
            by = "none"
    if by == "layer":
        return [layer or "0" for _, layer, _, _ in found]
    if by in ("colour", "color"):
        return [c for *_, c in found]
    if by == "group":
        return [g or "0" for _, _, g, _ in found]
    return ["0"] * len(found)


def _svg(path: Path, opt) -> Drawing:
    import svgelements as se

    not_drawn = _svg_scan(path)
    _svg_check_numbers(path)
    # no cyclic collections while the parse allocates millions of objects: each young collection walked
    # them again (art20k: ~170 collections, 0.15 s of CPU) and found a few hundred; the document's own
    # cycles (~40 000 objects there) are garbage only once its shapes are read
    with no_collections():
        try:
            rendered = render_rules(path)
            svg = se.SVG.parse(io.BytesIO(rendered) if rendered is not None else str(path), reify=True, ppi=96.0)
        except Exception as e:  # the parser raises anything on a malformed file
            msg = _printable(e) or type(e).__name__
            raise InputError(f"{path}: not a readable SVG file ({msg}); re-export it") from None
        mm = _mm_per_px(svg)
        vb = se.Matrix(getattr(svg, "viewbox_transform", "") or "")
        mm_per_unit = float(np.sqrt(abs(vb.a * vb.d - vb.b * vb.c))) * mm
        canvas = (0.0, 0.0, float(svg.width) * mm, float(svg.height) * mm) if svg.width and svg.height else None
        found = _svg_shapes(svg, opt["tolerance"] / mm, opt["corner"])
        del svg  # the document (~3 kB a path) is not needed any more
    if not found:
        raise InputError(f"{path}: no shapes to draw (no paths, lines, rectangles, circles, ...; text must be "
                         "converted to paths first)")
    shapes_of: dict[str, list[int]] = {}
    for i, name in enumerate(_layer_names(found, opt["layers"])):
        shapes_of.setdefault(name, []).append(i)
    polys, layers, colours = [], [], {}
    for name, shapes in shapes_of.items():  # join pieces within a layer, in the file's order of layers
        mine = []
        for i in shapes:
            qs = found[i][0]
            mine += [q * mm for q in qs]
            qs.clear()  # a shape's points in its units go as their copies in mm come (one copy of the drawing)
        joined = _join(mine, 1e-6 * max(1.0, _span(mine)))
        polys += joined
        layers += [name] * len(joined)
        colours[name] = found[shapes[0]][3]
    meta = {"tracer": "vector", "format": "svg", "mm_per_user_unit": mm_per_unit, "polylines": len(polys),
            "layer_colours": colours, "not_drawn": not_drawn}
    if canvas is not None:
        meta["canvas"] = canvas
    if not_drawn:
        hints = [_NOT_DRAWN_HINT[k] for k in not_drawn if k in _NOT_DRAWN_HINT]
        meta["warnings"] = ["not drawn: " + ", ".join(f"{n} {k}{'s' if n > 1 else ''}" for k, n in not_drawn.items())
                            + (f" ({'; '.join(hints)})" if hints else "")]
    return Drawing(tuple(polys), units="mm", y_down=True, source=str(path), meta=meta, layers=tuple(layers))


_DXF_UNITS = {1: "inches", 2: "feet", 3: "miles", 4: "millimeters", 5: "centimeters", 6: "meters", 7: "kilometers",
              8: "microinches", 9: "mils", 10: "yards", 13: "microns", 14: "decimeters"}
_DXF_DRAWN = {"LINE", "ARC", "CIRCLE", "ELLIPSE", "LWPOLYLINE", "POLYLINE", "SPLINE"}
_DXF_QUIET = {"ATTDEF", "SEQEND", "VERTEX"}  # parts of other entities, or block definitions' fields


def _dxf_entities(entities, skipped: dict[str, int], layer: str | None = None, depth: int = 0):
    """(entity, layer) for every entity, blocks (INSERT) expanded into their transformed
    contents; a block's entities on layer "0" take the INSERT's layer (DXF's rule). An
    entity that fails to expand is counted in ``skipped``, the rest still draws."""
    for e in entities:
        own = e.dxf.get("layer", "0")
        here = layer if (own == "0" and layer is not None) else own
        if e.dxftype() == "INSERT" and depth < 16:
            try:
                parts = list(e.virtual_entities())
            except Exception:
                skipped["INSERT"] = skipped.get("INSERT", 0) + 1
                continue
            yield from _dxf_entities(parts, skipped, here, depth + 1)
        else:
            yield e, here


def _dxf_colours(doc, layers) -> dict[str, str]:
    """Each layer's colour (its ACI number) as #rrggbb; ACI 7, white on a black CAD screen, is black on paper."""
    from ezdxf import colors

    out = {}
    for name in layers:
        aci = abs(int(doc.layers.get(name).dxf.color)) if doc.layers.has_entry(name) else 7
        r, g, b = (0, 0, 0) if aci in (0, 7, 256) else colors.aci2rgb(aci)
        out[name] = f"#{r:02x}{g:02x}{b:02x}"
    return out


def _dxf(path: Path, opt) -> Drawing:
    import logging

    from ezdxf import recover, units
    from ezdxf import path as dxfpath

    logging.getLogger("ezdxf").setLevel(logging.ERROR)  # we report what was skipped ourselves
    try:
        doc, _auditor = recover.readfile(str(path))
    except Exception as e:  # the loader raises anything on a malformed entity
        msg = _printable(e) or type(e).__name__
        raise InputError(f"{path}: not a readable DXF file ({msg}); re-export it") from None
    with open(path, "rb") as f:  # a DXF ends with "0 / EOF": without it entities may be missing, unseen
        f.seek(max(0, path.stat().st_size - 64))
        if b"EOF" not in f.read():
            raise InputError(f"{path}: the DXF file is cut short (it does not end with EOF), so drawing may be missing; "
                             "re-export or copy it again")
    code = int(doc.header.get("$INSUNITS", 0) or 0)
    unit = _DXF_UNITS.get(code)
    mm = units.conversion_factor(code, units.MM) if code else 1.0
    tol = opt["tolerance"] / mm
    # ezdxf draws curves as Béziers of up to 180 degrees' turn (arcs: 90): enough points on each that its
    # chords turn by at most a quarter of the corner angle (as _curve_points), so only real corners are kept
    segments = max(4, int(np.ceil(180.0 / (opt["corner"] * _CURVE_TURN)))) if opt["corner"] > 0 else 4
    skipped: dict[str, int] = {}
    by_layer: dict[str, list[np.ndarray]] = {}
    for e, layer in _dxf_entities(doc.modelspace(), skipped):
        kind = e.dxftype()
        if kind not in _DXF_DRAWN:
            if kind not in _DXF_QUIET:
                skipped[kind] = skipped.get(kind, 0) + 1
            continue
        try:
            pts = np.array([(v.x, v.y) for v in dxfpath.make_path(e).flattening(distance=tol, segments=segments)], float)
        except Exception:  # a degenerate or 3-D-only entity (mesh polyline, ...): counted, the rest draws
            skipped[kind] = skipped.get(kind, 0) + 1
            continue
        if not np.isfinite(pts).all():
            raise InputError(f"{path}: {kind} (handle {e.dxf.get('handle', '?')}) on layer {layer!r} has coordinates "
                             "that are not finite (NaN or infinite); fix it in the CAD program")
        if len(pts) >= 2:
            by_layer.setdefault(layer, []).append(pts * mm)
    if not by_layer:
        found = ", ".join(sorted(skipped)) or "nothing"
        raise InputError(f"{path}: no lines, arcs, circles, ellipses, polylines or splines to draw (found {found}); "
                         "convert text to polylines in your CAD program")
    span = _span([q for qs in by_layer.values() for q in qs])
    polys, layers = [], []
    for name, mine in by_layer.items():
        joined = _join(mine, 1e-6 * max(1.0, span))
        polys += joined
        layers += [name] * len(joined)
    if opt["layers"] == "none":
        layers = ["0"] * len(polys)
    meta = {"tracer": "vector", "format": "dxf", "units": unit or "millimeters (assumed)",
            "skipped_entities": skipped, "polylines": len(polys), "layer_colours": _dxf_colours(doc, by_layer)}
    if skipped:
        meta["warnings"] = ["not drawn: " + ", ".join(f"{n} {k}" for k, n in sorted(skipped.items()))]
    return Drawing(tuple(polys), units="mm", y_down=False, source=str(path), meta=meta, layers=tuple(layers))


def _span(polys: list[np.ndarray]) -> float:
    """The larger side of the polylines' bounding box (a thousand at a time: one array of millions
    of points would be fresh pages; a column at a time: 20x faster than axis=0)."""
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for i in range(0, len(polys), 1000):
        pts = np.concatenate(polys[i:i + 1000])
        lo = np.minimum(lo, (pts[:, 0].min(), pts[:, 1].min()))
        hi = np.maximum(hi, (pts[:, 0].max(), pts[:, 1].max()))
    return float((hi - lo).max())


# ---------------------------------------------------------------- meshes

def _vector3(text: str, what: str) -> np.ndarray:
    text = text.strip().lower()
    if text in _AXES:
        return np.array(_AXES[text])
    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) == 0:
        raise PluginError(f"tracer 'vector': {what} must be x, y, z or three numbers 'a,b,c', got {text!r}")
    return v / np.linalg.norm(v)


def _basis(normal: np.ndarray) -> np.ndarray:
    """Two unit vectors spanning the plane at right angles to ``normal`` (x, y kept for axis views)."""
    if abs(normal[2]) > 0.999999:
        return np.array([[1.0, 0, 0], [0, 1.0, 0]]) * np.array([1.0, np.sign(normal[2])])[:, None]
    if abs(normal[1]) > 0.999999:
        return np.array([[1.0, 0, 0], [0, 0, 1.0]])
    if abs(normal[0]) > 0.999999:
        return np.array([[0, 1.0, 0], [0, 0, 1.0]])
    e1 = np.cross([0.0, 0.0, 1.0], normal)
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(normal, e1)])


def _mesh(path: Path, opt) -> Drawing:
    VectorTracer.check_extension(path.suffix.lower())  # for callers that skipped the checks
    import logging

    import trimesh

    logging.getLogger("trimesh").setLevel(logging.ERROR)
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as e:
        msg = " ".join(str(e).split())[:100] or type(e).__name__
        raise InputError(f"{path}: not a readable mesh ({msg}); re-export it as STL") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or not np.isfinite(mesh.vertices).all():
        raise InputError(f"{path}: the mesh has no triangles; export the solid again")
    mode = opt["mesh"].strip().lower()
    if mode == "section":
        polys, meta = _section(mesh, opt["plane"], path)
    elif mode == "silhouette":
        polys, meta = _silhouette(mesh, opt["direction"], path)
    else:
        raise PluginError(f"tracer 'vector': mesh must be 'section' or 'silhouette', got {opt['mesh']!r}")
    from doodlecam.plugins.edges import simplify

    polys = simplify(polys, opt["tolerance"] / 2)
    meta.update(tracer="vector", format="mesh", watertight=bool(mesh.is_watertight), faces=len(mesh.faces),
                polylines=len(polys), bounds_mm=np.round(mesh.bounds, 6).tolist())  # the studio's STL panel shows them
    return Drawing(tuple(polys), units="mm", y_down=False, source=str(path), meta=meta)


def _section(mesh, plane: str, path: Path):
    import trimesh

    axis, sep, where = plane.partition("=")
    normal = _vector3(axis, "the plane's axis")
    heights = mesh.vertices @ normal
    lo, hi = float(heights.min()), float(heights.max())
    where = where.strip() or "50%"
    try:
        level = lo + (hi - lo) * float(where[:-1]) / 100 if where.endswith("%") else float(where)
    except ValueError:
        raise PluginError(f"tracer 'vector': plane must look like z=50% or z=12.5, got {plane!r}") from None
    if not lo < level < hi:
        raise InputError(f"{path}: the plane {plane} misses the mesh, which spans {lo:.3g} to {hi:.3g} mm "
                         f"along it; choose a position in between (or a percentage)")
    segments = trimesh.intersections.mesh_plane(mesh, normal, normal * level)
    if not len(segments):
        raise InputError(f"{path}: the plane {plane} cuts no triangle of the mesh; choose another position")
    b = _basis(normal)
    seg2 = segments @ b.T  # (n, 2, 2) in the plane
    size = max(hi - lo, float(np.ptp(mesh.vertices, axis=0).max()), 1e-9)
    polys = _join([s for s in seg2], 1e-7 * size)
    closed = sum(1 for p in polys if len(p) >= 3 and np.array_equal(p[0], p[-1]))
    return polys, {"plane": plane, "level_mm": level, "span_mm": [lo, hi], "closed_outlines": closed,
                   "open_outlines": len(polys) - closed}


def _silhouette(mesh, direction: str, path: Path):
    from trimesh.path.polygons import projected

    normal = _vector3(direction, "direction")
    try:
        shape = projected(mesh, normal=normal, ignore_sign=True)
    except Exception as e:
        msg = " ".join(str(e).split())[:100] or type(e).__name__
        raise InputError(f"{path}: cannot project the mesh ({msg}); check that it is a valid solid") from None
    if shape is None or shape.is_empty or shape.area <= 0:
        raise InputError(f"{path}: the mesh has no silhouette seen along {direction} (it is flat that way); "
                         "choose another direction")
    # trimesh projects onto its own plane frame; redo it in ours so axis views keep x / y.
    polygons = list(getattr(shape, "geoms", [shape]))
    b = _basis(normal)
    to_ours = _frame_change(mesh, normal, b)
    polys = []
    for pg in polygons:
        for ring in [pg.exterior, *pg.interiors]:
            c = np.asarray(ring.coords, float)
            if len(c) >= 4:
                polys.append(to_ours(c))
    return polys, {"direction": direction, "regions": len(polygons)}


def _frame_change(mesh, normal, b):
    """Map trimesh's projected 2-D coordinates to ours (the basis ``b``)."""
    from trimesh.geometry import plane_transform

    to_2d = plane_transform(origin=np.zeros(3), normal=normal)
    inv = np.linalg.inv(to_2d)

    def f(c2: np.ndarray) -> np.ndarray:
        p3 = np.column_stack([c2, np.zeros(len(c2)), np.ones(len(c2))]) @ inv.T
        return p3[:, :3] @ b.T

    return f
