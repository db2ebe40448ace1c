"""SVG rendering rules svgelements does not apply, applied to the file before it is parsed.

* Symbols (SVG 2, 5.6.3): a ``<use>`` of a ``<symbol>`` renders the symbol's content in
  the use's viewport (x, y, width, height) through the symbol's viewBox and
  preserveAspectRatio; a symbol is never rendered by itself. svgelements draws a
  symbol's content where it stands and at its own size.
* Percentages (SVG 2, 8.9 "Units"): a percentage length is of the nearest viewport's
  width for x, cx, x1, x2, width and rx, of its height for y, cy, y1, y2, height and ry,
  and of its normalised diagonal sqrt((w² + h²) / 2) for anything else (a circle's r).
  svgelements takes r="10%" of the width for rx and of the height for ry: an ellipse.

The viewport of a shape is the viewBox of its nearest ``<svg>`` or ``<symbol>``
ancestor, else that element's width and height (the root's in px at 96 per inch).
"""

from __future__ import annotations

import re
from pathlib import Path

SVG_NS, XLINK = "http://www.w3.org/2000/svg", "{http://www.w3.org/1999/xlink}href"
_PX_PER = {"": 1.0, "px": 1.0, "in": 96.0, "cm": 96.0 / 2.54, "mm": 96.0 / 25.4, "q": 96.0 / 101.6, "pt": 96.0 / 72,
           "pc": 16.0}
_LENGTH = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z]*|%)\s*")
_ALONG_X = {"x", "cx", "x1", "x2", "width", "rx"}
_ALONG_Y = {"y", "cy", "y1", "y2", "height", "ry"}
_DIAGONAL = {"r"}
_VIEWPORTS = {"svg", "symbol"}


def _tag(el) -> str:
    return str(el.tag).rpartition("}")[2]


def _number(text: str | None, default: float) -> float:
    """A plain SVG length in user units; ``default`` when absent or given in units or percent."""
    try:
        return float(text) if text is not None else default
    except ValueError:
        return default


def _length(text: str | None, percent_of: float | None) -> float | None:
    """A length in user units (px for the root's size), a percentage of ``percent_of``; None when unknown."""
    m = _LENGTH.fullmatch(text or "")
    if not m:
        return None
    value, unit = float(m.group(1)), m.group(2).lower()
    if unit == "%":
        return None if percent_of is None else value / 100 * percent_of
    return value * _PX_PER[unit] if unit in _PX_PER else None


def _viewbox(el) -> tuple[float, float] | None:
    box = [_number(v, 0.0) for v in (el.get("viewBox") or "").replace(",", " ").split()]
    return (box[2], box[3]) if len(box) == 4 and box[2] > 0 and box[3] > 0 else None


def _resolve_percentages(el, viewport: tuple[float, float] | None) -> bool:
    """Percentage lengths under ``el`` in user units of their viewports (in place); True if any changed."""
    changed = False
    for child in el:
        if not isinstance(child.tag, str):  # comments, processing instructions
            continue
        if viewport is not None:
            w, h = viewport
            for key, value in list(child.attrib.items()):
                if "%" not in value or key not in _ALONG_X | _ALONG_Y | _DIAGONAL:
                    continue
                of = w if key in _ALONG_X else h if key in _ALONG_Y else ((w * w + h * h) / 2) ** 0.5
                v = _length(value, of)
                if v is not None:
                    child.set(key, f"{v:.12g}")
                    changed = True
        inner = viewport
        if _tag(child) in _VIEWPORTS:  # a new viewport: its viewBox, else its size, else the parent's
            size = (_length(child.get("width"), None), _length(child.get("height"), None))
            inner = _viewbox(child) or (size if None not in size else viewport)
        changed |= _resolve_percentages(child, inner)
    return changed


def _symbol_transform(use, symbol) -> str:
    """The transform that maps a symbol's viewBox into its <use>'s viewport (x, y, width, height) as SVG's
    viewBox and preserveAspectRatio rules say (default xMidYMid meet; 'none' stretches; 'slice' covers)."""
    x, y = _number(use.get("x"), 0.0), _number(use.get("y"), 0.0)
    box = [_number(v, 0.0) for v in (symbol.get("viewBox") or "").replace(",", " ").split()]
    if len(box) != 4 or box[2] <= 0 or box[3] <= 0:
        return f"translate({x:g},{y:g})"
    bx, by, bw, bh = box
    w, h = _number(use.get("width"), bw), _number(use.get("height"), bh)
    sx, sy = w / bw, h / bh
    par = (symbol.get("preserveAspectRatio") or "xMidYMid meet").split()
    align = par[0] if par else "xMidYMid"
    if align != "none":
        sx = sy = (max if len(par) > 1 and par[1] == "slice" else min)(sx, sy)
        fx = {"xMin": 0.0, "xMid": 0.5, "xMax": 1.0}.get(align[:4], 0.5)
        fy = {"YMin": 0.0, "YMid": 0.5, "YMax": 1.0}.get(align[4:], 0.5)
        x, y = x + (w - bw * sx) * fx, y + (h - bh * sy) * fy
    return f"translate({x - bx * sx:g},{y - by * sy:g}) scale({sx:g},{sy:g})"


def _render_symbols(root) -> bool:
    """Each <use> of a <symbol> becomes a group of the symbol's content with the use's placement, and the
    symbols themselves are removed (in place); True if the file had a symbol."""
    import copy
    import xml.etree.ElementTree as ET

    symbols = {el.get("id"): el for el in root.iter() if _tag(el) == "symbol"}
    if not symbols:
        return False
    parents = {child: parent for parent in root.iter() for child in parent}
    for el in list(root.iter()):
        if _tag(el) != "use":
            continue
        ref = (el.get(XLINK) or el.get("href") or "").lstrip("#")
        sym = symbols.get(ref)
        if sym is None:
            continue
        attrs = {k: v for k, v in el.attrib.items() if k not in (XLINK, "href", "x", "y", "width", "height")}
        place = _symbol_transform(el, sym)
        attrs["transform"] = f"{attrs.get('transform', '')} {place}".strip()
        group = ET.Element(f"{{{SVG_NS}}}g", attrs)
        for child in sym:
            group.append(copy.deepcopy(child))
        parent = parents[el]
        parent[list(parent).index(el)] = group
    for sym in symbols.values():  # never rendered where it stands
        parents[sym].remove(sym)
    return True


def render_rules(path: Path) -> bytes | None:
    """The SVG file with the rules above applied, for svgelements to parse; None when none applies."""
    import xml.etree.ElementTree as ET

    ET.register_namespace("", SVG_NS)
    ET.register_namespace("xlink", XLINK[1:].split("}")[0])
    root = ET.parse(str(path)).getroot()
    size = (_length(root.get("width"), None), _length(root.get("height"), None))
    viewport = _viewbox(root) or (size if None not in size else None)
    changed = _resolve_percentages(root, viewport)
    changed |= _render_symbols(root)  # after: a symbol's percentages are of its own viewBox
    return ET.tostring(root) if changed else None
