"""The options of one conversion, shared by ``convert`` and ``batch``.

Kept free of heavy imports: the batch coordinator builds them without loading
the pipeline. ``pipeline.Settings`` adds the loaded machine profile;
``batch.BatchOptions`` adds the profile's name (picklable, hashable for the
manifest).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


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
    layout: dict[str, Any] = field(default_factory=dict)  # overrides the profile's [layout] (doodlecam.layout)
    order: dict[str, Any] = field(default_factory=dict)  # overrides the profile's [order]
