"""The built-in ``vector`` tracer: SVG and DXF drawings, and STL meshes, through trimesh.

* **SVG** (trimesh.path): paths, lines, polylines, polygons, rectangles,
  circles and ellipses, with every ``transform`` applied. Lengths are in mm:
  the root's ``width`` / ``height`` with units (mm, cm, in, pt, pc, px at 96
  per inch) against its ``viewBox`` give the size of one user unit; without
  them a user unit is a CSS px (0.2646 mm). The viewBox is the canvas the
  layout fits, so the drawing keeps its place on the page. Text is not
  drawn: convert it to paths first.
* **DXF** (trimesh.path): lines, arcs, circles, (LW)polylines, splines and
  ellipses in model space; ``$INSUNITS`` gives the unit (mm when unset).
  Entities trimesh cannot read (text, hatches, dimensions, ...) are counted
  in the drawing's metadata; a file with none it can read is an error.
* **STL / OBJ / PLY / OFF** (trimesh): the outline of the mesh's section by
  a plane (``mesh = section``, ``plane = z=50%``: the plane at right angles
  to z half-way up; ``z=12.5`` is 12.5 mm; ``0,1,1=30%`` a tilted plane), or
  its silhouette seen along a direction (``mesh = silhouette``,
  ``direction = z``: seen from above), holes included. Meshes are in mm.

Curves become polylines within ``tolerance`` mm of the true curve (the spline
fit later smooths them), and pieces that meet end to end are joined into
one stroke.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.api import Option, Tracer
from doodlecam.errors import InputError, PluginError
from doodlecam.model import Drawing

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
        Option("mesh", str, "section", "meshes: 'section' (cut by a plane) or 'silhouette' (outline seen along a direction)"),
        Option("plane", str, "z=50%", "section plane: AXIS=POS with AXIS x, y, z or a normal 'a,b,c' and POS in mm or % of the extent"),
        Option("direction", str, "z", "silhouette view direction: x, y, z or 'a,b,c' (seen looking down it)"),
    )

    def trace(self, path: Path, options: dict[str, Any]) -> Drawing:
        """Polylines in mm, y up (SVG: y down, as the file has it)."""
        opt = self.resolve_options(options)
        if not opt["tolerance"] > 0:
            raise PluginError(f"tracer 'vector': tolerance must be > 0 mm, got {opt['tolerance']:g}")
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such file; check the path")
        size = path.stat().st_size
        if size == 0:
            raise InputError(f"{path}: the file is empty (0 bytes); give an SVG, DXF or STL file")
        if size > _MAX_BYTES:
            raise InputError(f"{path}: {size / 2**20:.0f} MB is too large for a plotter drawing; simplify it first")
        ext = path.suffix.lower()
        if ext == ".svg":
            return _svg(path, opt)
        if ext == ".dxf":
            return _dxf(path, opt)
        if ext in MESH_EXTENSIONS:
            return _mesh(path, opt)
        raise InputError(f"{path}: the vector tracer reads {', '.join(self.extensions)} files; "
                         "pick another tracer with --tracer")


# ---------------------------------------------------------------- 2-D drawings

def _load_path(path: Path, what: str, data: bytes | None = None):
    import io
    import logging

    import trimesh

    logging.getLogger("trimesh").setLevel(logging.ERROR)  # we report what was skipped ourselves
    try:
        if data is None:
            loaded = trimesh.load_path(str(path))
        else:
            loaded = trimesh.load_path(io.BytesIO(data), file_type=path.suffix.lower().lstrip("."))
    except Exception as e:  # parsers raise anything: XML, struct, KeyError, ...
        msg = " ".join(str(e).split())[:100] or type(e).__name__
        raise InputError(f"{path}: not a readable {what} file ({msg}); re-export it") from None
    return loaded


def _entity_polylines(p, tol_units: float) -> list[np.ndarray]:
    """Every entity of a trimesh Path2D as a polyline in file units."""
    from doodlecam.plugins.edges import simplify

    if p is None or not len(getattr(p, "entities", ())):
        return []
    scale = max(float(p.scale), 1e-9)
    out = []
    for e in p.entities:
        if type(e).__name__ == "Text":  # trimesh keeps DXF text as a label, not as strokes
            continue
        try:
            d = np.asarray(e.discrete(p.vertices, scale=scale), float)
        except Exception:  # a degenerate arc or curve: skip it, the rest still draws
            continue
        if d.ndim == 2 and len(d) >= 2 and np.isfinite(d).all():
            out.append(d[:, :2])
    # Curves come in at trimesh's fixed resolution: keep only what the tolerance needs.
    return simplify(out, tol_units / 2) if out else []


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


def _svg_units(path: Path) -> tuple[float, tuple[float, float, float, float] | None, bytes]:
    """(mm per user unit, viewBox (x0, y0, x1, y1) in user units, the SVG with defaults filled in)."""
    from lxml import etree

    try:
        root = etree.parse(str(path), etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False)).getroot()
    except Exception as e:
        msg = " ".join(str(e).split())[:100] or type(e).__name__
        raise InputError(f"{path}: not a readable SVG file ({msg}); re-export it") from None
    if not str(root.tag).endswith("svg"):
        raise InputError(f"{path}: the root element is <{etree.QName(root).localname}>, not <svg>; give an SVG file")

    def length(text):
        if text is None:
            return None
        m = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z%]*)\s*", text)
        if not m or m.group(2).lower() not in _UNIT_MM:
            return None  # percentages and unknown units: fall back to the viewBox
        return float(m.group(1)) * _UNIT_MM[m.group(2).lower()]

    # SVG's defaults that trimesh's reader expects written out (a circle's cx, cy are 0, ...).
    for el in root.iter():
        tag = etree.QName(el).localname if isinstance(el.tag, str) else ""
        for attr in {"circle": ("cx", "cy"), "ellipse": ("cx", "cy"), "rect": ("x", "y"),
                     "line": ("x1", "y1", "x2", "y2")}.get(tag, ()):
            if el.get(attr) is None:
                el.set(attr, "0")
        if tag == "rect" and (el.get("rx") or el.get("ry")):
            _round_rect(el)
    data = etree.tostring(root)
    w_mm, h_mm = length(root.get("width")), length(root.get("height"))
    box = None
    vb = root.get("viewBox")
    if vb:
        try:
            x0, y0, bw, bh = (float(v) for v in re.split(r"[\s,]+", vb.strip()))
            if bw > 0 and bh > 0:
                box = (x0, y0, x0 + bw, y0 + bh)
        except ValueError:
            box = None
    if box is None:
        per = _UNIT_MM["px"]
        if w_mm and h_mm:
            box = (0.0, 0.0, w_mm / per, h_mm / per)
        return per, box, data
    bw, bh = box[2] - box[0], box[3] - box[1]
    if w_mm and h_mm:
        return min(w_mm / bw, h_mm / bh), box, data  # preserveAspectRatio's default "meet"
    if w_mm:
        return w_mm / bw, box, data
    if h_mm:
        return h_mm / bh, box, data
    return _UNIT_MM["px"], box, data


def _round_rect(el) -> None:
    """A rectangle with rounded corners as the equivalent path (trimesh draws square corners)."""
    def num(name, default=0.0):
        m = re.match(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)", el.get(name) or "")
        return float(m.group(1)) if m else default

    x, y, w, h = num("x"), num("y"), num("width"), num("height")
    rx = num("rx", -1.0)
    ry = num("ry", -1.0)
    rx, ry = (ry if rx < 0 else rx), (rx if ry < 0 else ry)
    rx, ry = min(max(rx, 0.0), w / 2), min(max(ry, 0.0), h / 2)
    if w <= 0 or h <= 0:
        return
    el.tag = el.tag.replace("rect", "path")
    for name in ("x", "y", "width", "height", "rx", "ry"):
        el.attrib.pop(name, None)
    arc = f"A {rx:g} {ry:g} 0 0 1"
    el.set("d", f"M {x + rx:g} {y:g} H {x + w - rx:g} {arc} {x + w:g} {y + ry:g} V {y + h - ry:g} "
                f"{arc} {x + w - rx:g} {y + h:g} H {x + rx:g} {arc} {x:g} {y + h - ry:g} V {y + ry:g} "
                f"{arc} {x + rx:g} {y:g} Z")


def _svg(path: Path, opt) -> Drawing:
    mm, box, data = _svg_units(path)
    p = _load_path(path, "SVG", data)
    polys = _entity_polylines(p, opt["tolerance"] / mm)
    if not polys:
        raise InputError(f"{path}: no shapes to draw (no paths, lines, rectangles, circles, ...; text must be "
                         "converted to paths first)")
    polys = [q * mm for q in polys]
    polys = _join(polys, 1e-6 * max(1.0, _span(polys)))
    meta = {"tracer": "vector", "format": "svg", "mm_per_user_unit": mm, "polylines": len(polys)}
    if box is not None:
        meta["canvas"] = tuple(v * mm for v in box)
    return Drawing(tuple(polys), units="mm", y_down=True, source=str(path), meta=meta)


def _dxf_entity_types(path: Path) -> tuple[dict[str, int], int | None]:
    """(entity types in the ENTITIES section counted, the $INSUNITS code) of an ASCII DXF."""
    counts: dict[str, int] = {}
    units = None
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return counts, units
    inside = False
    pairs = list(zip(lines[0::2], lines[1::2]))
    for k, (code, value) in enumerate(pairs):
        code, value = code.strip(), value.strip()
        if code == "9" and value == "$INSUNITS" and k + 1 < len(pairs):
            try:
                units = int(pairs[k + 1][1].strip())
            except ValueError:
                units = None
        if code == "2" and value == "ENTITIES":
            inside = True
        elif inside and code == "0":
            if value == "ENDSEC":
                break
            counts[value] = counts.get(value, 0) + 1
    return counts, units


_DXF_UNITS = {1: "inches", 2: "feet", 3: "miles", 4: "millimeters", 5: "centimeters", 6: "meters", 7: "kilometers",
              8: "microinches", 9: "mils", 10: "yards", 13: "microns", 14: "decimeters"}
_DXF_DRAWN = {"LINE", "ARC", "CIRCLE", "LWPOLYLINE", "POLYLINE", "VERTEX", "SEQEND", "SPLINE", "ELLIPSE", "BSPLINE"}


def _dxf(path: Path, opt) -> Drawing:
    import trimesh

    types, code = _dxf_entity_types(path)
    skipped = {k: v for k, v in types.items() if k not in _DXF_DRAWN}
    p = _load_path(path, "DXF")
    # $INSUNITS only: trimesh also reads $LUNITS, which is a number format, not a unit.
    unit = _DXF_UNITS.get(code or 0)
    mm = trimesh.units.unit_conversion(unit, "millimeters") if unit else 1.0
    polys = _entity_polylines(p, opt["tolerance"] / mm)
    if not polys:
        found = ", ".join(sorted(skipped)) or "nothing"
        raise InputError(f"{path}: no lines, arcs, circles, polylines or splines to draw (found {found}); "
                         "explode blocks and convert text to polylines in your CAD program")
    polys = [q * mm for q in polys]
    polys = _join(polys, 1e-6 * max(1.0, _span(polys)))
    return Drawing(tuple(polys), units="mm", y_down=False, source=str(path),
                   meta={"tracer": "vector", "format": "dxf", "units": unit or "millimeters (assumed)",
                         "skipped_entities": skipped, "polylines": len(polys)})


def _span(polys: list[np.ndarray]) -> float:
    pts = np.concatenate(polys)
    return float(np.ptp(pts, axis=0).max())


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
                polylines=len(polys))
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
    return polys, {"plane": plane, "level_mm": level, "closed_outlines": closed, "open_outlines": len(polys) - closed}


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
