"""The options of one conversion, shared by ``convert`` and ``batch``.

Kept free of heavy imports: the batch coordinator builds them without loading
the pipeline. ``pipeline.Settings`` adds the loaded machine profile;
``batch.BatchOptions`` adds the profile's name (picklable, hashable for the
manifest).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

from doodlecam.errors import DoodleError, InputError


@dataclass(frozen=True, kw_only=True)
class ConvertOptions:
    tracer: str | None = None
    tracer_options: dict[str, Any] = field(default_factory=dict)
    posts: tuple[str, ...] = ("plc", "gcode", "svg")
    post_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    solver: str | None = None
    smoothing: float | None = None
    path_tolerance: float | None = None  # overrides the profile's [sampling] path_tolerance (mm; 0 = off)
    plugin_dirs: tuple[str, ...] = ()
    layout: dict[str, Any] = field(default_factory=dict)  # overrides the profile's [layout] (doodlecam.trace.layout)
    order: dict[str, Any] = field(default_factory=dict)  # overrides the profile's [order]
    allow_deviation: bool = False  # write the job even when a measured figure is over its bound
    layer: str | None = None  # convert only this layer of the drawing

    def __post_init__(self):
        # Settings(posts="gcode") is one post, not the posts 'g', 'c', 'o', ...
        if isinstance(self.posts, str):
            object.__setattr__(self, "posts", (self.posts,))
        if isinstance(self.plugin_dirs, str):
            object.__setattr__(self, "plugin_dirs", (self.plugin_dirs,))
        object.__setattr__(self, "posts", tuple(self.posts))
        object.__setattr__(self, "plugin_dirs", tuple(self.plugin_dirs))


# the planner's back-ends (doodlecam.plan.planner), named here so a profile is checked on load
SOLVERS = ("reach", "lp", "lp:osqp", "lp:highs", "lp:clarabel", "qp", "qp:osqp", "qp:highs", "qp:clarabel")


# ---------------------------------------------------------------- layout, order and travel
# Checked here, below every stage, so that a machine profile is validated on load
# without importing the stages that use these options.

ROTATIONS = ("0", "90", "180", "270", "auto")
FITS = ("canvas", "ink")

LAYOUT_DEFAULTS: dict[str, Any] = {
    "margin": None,  # mm; None = the work area's margin
    "rotate": "0",  # quarter turns counter-clockwise, or "auto" for the larger of 0 and 90
    "width": None,  # mm; target size (aspect kept: the drawing fits both when both are given)
    "height": None,
    "scale": None,  # mm per drawing unit (px or mm); excludes width/height
    "fit": "canvas",  # "canvas": the whole picture frame; "ink": only what is drawn
    "min_length": None,  # mm; shorter strokes are dropped; None = the pen width
    "page": None,  # (width, height) mm of the paper, centred on the work area; the drawing fits inside it
    "orientation": None,  # "landscape" / "portrait" turns the page; None: as named (ISO and US sizes: portrait)
}
ORDER_DEFAULTS: dict[str, Any] = {
    "reverse": True,  # strokes may be drawn backwards (false for pens that draw differently each way)
    "merge": 0.05,  # mm; strokes whose ends meet within this are drawn as one
    "budget": None,  # s: an optional clock cap on improving the order (0 = greedy only); None = no clock,
    # so the same input gives the same order on any machine under any load
    "moves": 200.0,  # improving moves (2-opt / Or-opt / kicks' repairs) per stroke at most: the deterministic cap
    "layers": "pen",  # "pen": layers grouped by pen, so each pen is fitted once; "file": the drawing's order
}
LAYER_ORDERS = ("pen", "file")


_LENGTH = re.compile(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z]*)\s*")


def parse_length(value, where: str, error=InputError) -> float:
    """A length in mm from a number (mm) or text with a unit: mm, cm, in, pt, pc, px (96 per inch), ...

    Units are papersize's table with CSS's meaning of pt (1/72 in, TeX's "bp") and px (96 per
    inch); no unit means mm."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    m = _LENGTH.fullmatch(str(value))
    if not m:
        raise error(f"{where} must be a length such as 20, 20mm, 2cm or 1.5in, got {value!r}")
    number, unit = float(m.group(1)), m.group(2).lower() or "mm"
    if unit == "px":
        number, unit = number * 0.75, "bp"
    elif unit == "pt":
        unit = "bp"  # papersize's pt is TeX's 1/72.27 in
    import papersize

    if unit not in papersize.UNITS or not unit:
        raise error(f"{where}: unknown unit '{m.group(2)}' in {value!r}; use mm, cm, in, pt or px")
    return float(papersize.convert_length(number, unit, "mm"))


def parse_page(value, where: str, error=InputError) -> tuple[float, float]:
    """(width, height) mm of a paper size: a name (a4, a3, letter, ...) or WxH with units
    ("210x297mm", "5x4in", "20cmx10cm"; a unit on the second length only applies to both)."""
    if isinstance(value, (tuple, list)) and len(value) == 2:
        return parse_length(value[0], where, error), parse_length(value[1], where, error)
    import papersize

    text = str(value).strip().lower()
    if text in papersize.SIZES:
        text = papersize.SIZES[text]
    parts = [t.strip() for t in re.split(r"\s*x\s*", text)]
    if len(parts) != 2 or not all(parts):
        names = ", ".join(n for n in ("a5", "a4", "a3", "a2", "letter", "legal", "tabloid"))
        raise error(f"{where}: unknown page {value!r}; use a name ({names}, ...) or WxH with units, e.g. 210x297mm")
    first, second = parts
    unit = _LENGTH.fullmatch(second)
    if unit and _LENGTH.fullmatch(first) and not _LENGTH.fullmatch(first).group(2):
        first += unit.group(2)  # "5x4in": both in inches
    w, h = parse_length(first, where, error), parse_length(second, where, error)
    if not (w > 0 and h > 0 and math.isfinite(w) and math.isfinite(h)):
        raise error(f"{where}: the page must have a positive size, got {value!r}")
    return w, h


def _number(value, where: str, error, minimum: float = 0.0, strict: bool = True, length: bool = False) -> float:
    if length and isinstance(value, str) and _LENGTH.fullmatch(value) and _LENGTH.fullmatch(value).group(2):
        value = parse_length(value, where, error)
    try:
        if isinstance(value, bool):
            raise ValueError
        v = float(value)
    except (TypeError, ValueError):
        raise error(f"{where} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < minimum or (strict and v == minimum):
        raise error(f"{where} must be {'>' if strict else '>='} {minimum:g}, got {value!r}")
    return v


def layout_options(raw: dict[str, Any] | None, where: str = "layout", error: type[DoodleError] = InputError,
                   sep: str = " ") -> dict[str, Any]:
    """Checked layout options: the defaults overlaid by ``raw`` (CLI strings or TOML values); a
    message names an option as ``where + sep + key`` (a profile's keys: "file: layout.rotate")."""
    out = dict(LAYOUT_DEFAULTS)
    for key, value in (raw or {}).items():
        if key not in LAYOUT_DEFAULTS:
            raise error(f"{where}: unknown layout option '{key}'; use one of {', '.join(LAYOUT_DEFAULTS)}")
        if value is None:
            continue
        w = f"{where}{sep}{key}"
        if key == "rotate":
            v = str(value).strip().lower().removesuffix(".0")
            if v not in ROTATIONS:
                raise error(f"{w} must be one of {', '.join(ROTATIONS)}, got {value!r}")
            out[key] = v
        elif key == "fit":
            v = str(value).strip().lower()
            if v not in FITS:
                raise error(f"{w} must be one of {', '.join(FITS)}, got {value!r}")
            out[key] = v
        elif key in ("margin", "min_length"):
            out[key] = _number(value, w, error, strict=False, length=True)
        elif key == "page":
            out[key] = parse_page(value, w, error)
        elif key == "orientation":
            v = str(value).strip().lower()
            if v not in ("landscape", "portrait"):
                raise error(f"{w} must be landscape or portrait, got {value!r}")
            out[key] = v
        else:
            out[key] = _number(value, w, error, length=key in ("width", "height"))
    if out["scale"] is not None and (out["width"] is not None or out["height"] is not None):
        raise error(f"{where}: give a scale or a target width/height, not both")
    return out


def order_options(raw: dict[str, Any] | None, where: str = "order", error: type[DoodleError] = InputError,
                  sep: str = " ") -> dict[str, Any]:
    """Checked ordering options: the defaults overlaid by ``raw`` (``sep``: as in :func:`layout_options`)."""
    out = dict(ORDER_DEFAULTS)
    for key, value in (raw or {}).items():
        if key not in ORDER_DEFAULTS:
            raise error(f"{where}: unknown order option '{key}'; use one of {', '.join(ORDER_DEFAULTS)}")
        if value is None:
            continue
        if key == "reverse":
            if isinstance(value, str) and value.strip().lower() in ("1", "true", "yes", "on", "0", "false", "no", "off"):
                value = value.strip().lower() in ("1", "true", "yes", "on")
            if not isinstance(value, bool):
                raise error(f"{where}{sep}reverse must be true or false, got {value!r}")
            out[key] = value
        elif key == "layers":
            if str(value).strip().lower() not in LAYER_ORDERS:
                raise error(f"{where}{sep}layers must be 'pen' (each pen fitted once) or 'file' (the drawing's order), "
                            f"got {value!r}")
            out[key] = str(value).strip().lower()
        else:
            out[key] = _number(value, f"{where}{sep}{key}", error, strict=False)
    return out


TRAVEL_LAWS = ("trapezoid", "modified-sine", "modified-trapezoid", "cycloidal")
TRAVEL_ALIASES = {"bang-bang": "trapezoid", "smooth": "modified-sine"}


def travel_law_name(law: str | None) -> str:
    """The canonical travel-law name, or ValueError for an unknown one."""
    key = TRAVEL_ALIASES.get(law or "trapezoid", law or "trapezoid")
    if key not in TRAVEL_LAWS:
        raise ValueError(law)
    return key
