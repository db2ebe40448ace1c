"""The options of one conversion, shared by ``convert`` and ``batch``.

Kept free of heavy imports: the batch coordinator builds them without loading
the pipeline. ``pipeline.Settings`` adds the loaded machine profile;
``batch.BatchOptions`` adds the profile's name (picklable, hashable for the
manifest).
"""

from __future__ import annotations

import math
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
}
ORDER_DEFAULTS: dict[str, Any] = {
    "reverse": True,  # strokes may be drawn backwards (false for pens that draw differently each way)
    "merge": 0.05,  # mm; strokes whose ends meet within this are drawn as one
    "budget": None,  # s: an optional clock cap on improving the order (0 = greedy only); None = no clock,
    # so the same input gives the same order on any machine under any load
    "moves": 200.0,  # improving moves (2-opt / Or-opt / kicks' repairs) per stroke at most: the deterministic cap
}


def _number(value, where: str, error, minimum: float = 0.0, strict: bool = True) -> float:
    try:
        if isinstance(value, bool):
            raise ValueError
        v = float(value)
    except (TypeError, ValueError):
        raise error(f"{where} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < minimum or (strict and v == minimum):
        raise error(f"{where} must be {'>' if strict else '>='} {minimum:g}, got {value!r}")
    return v


def layout_options(raw: dict[str, Any] | None, where: str = "layout", error: type[DoodleError] = InputError
                   ) -> dict[str, Any]:
    """Checked layout options: the defaults overlaid by ``raw`` (CLI strings or TOML values)."""
    out = dict(LAYOUT_DEFAULTS)
    for key, value in (raw or {}).items():
        if key not in LAYOUT_DEFAULTS:
            raise error(f"{where}: unknown layout option '{key}'; use one of {', '.join(LAYOUT_DEFAULTS)}")
        if value is None:
            continue
        w = f"{where} {key}"
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
            out[key] = _number(value, w, error, strict=False)
        else:
            out[key] = _number(value, w, error)
    if out["scale"] is not None and (out["width"] is not None or out["height"] is not None):
        raise error(f"{where}: give a scale or a target width/height, not both")
    return out


def order_options(raw: dict[str, Any] | None, where: str = "order", error: type[DoodleError] = InputError
                  ) -> dict[str, Any]:
    """Checked ordering options: the defaults overlaid by ``raw``."""
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
                raise error(f"{where} reverse must be true or false, got {value!r}")
            out[key] = value
        else:
            out[key] = _number(value, f"{where} {key}", error, strict=False)
    return out


TRAVEL_LAWS = ("trapezoid", "modified-sine", "modified-trapezoid", "cycloidal")
TRAVEL_ALIASES = {"bang-bang": "trapezoid", "smooth": "modified-sine"}


def travel_law_name(law: str | None) -> str:
    """The canonical travel-law name, or ValueError for an unknown one."""
    key = TRAVEL_ALIASES.get(law or "trapezoid", law or "trapezoid")
    if key not in TRAVEL_LAWS:
        raise ValueError(law)
    return key
