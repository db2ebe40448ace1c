"""The plugin API: what a tracer, kinematics, post-processor or transport is.

Third-party plugins subclass one of these, declare ``name``, a one-line
``summary`` and their ``options``, and are registered through an entry point
(see pyproject.toml) or dropped as a ``.py`` file into a ``--plugin-dir``.
Keep module-level imports light: heavy libraries belong inside methods, so
that listing plugins stays fast.

API_VERSION changes only when a change would break an existing plugin.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from doodlecam.errors import PlanError, PluginError, did_you_mean

API_VERSION = 1


_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


@dataclass(frozen=True)
class Option:
    """One plugin option: declared once, settable from the CLI and profiles."""

    name: str
    type: type
    default: Any
    help: str
    choices: tuple[Any, ...] | None = None  # allowed values, when the option is an enumeration

    def coerce(self, value: Any, plugin: str) -> Any:
        """``value`` (a CLI string or a TOML value) as this option's type."""
        if value is None and self.default is None:  # an option that may stay unset, passed on unset
            return None
        value = self._coerce(value, plugin)
        if self.choices is not None and value not in self.choices:
            raise PluginError(f"{plugin}: option '{self.name}' must be one of {', '.join(map(str, self.choices))}, got {value!r}")
        return value

    def _coerce(self, value: Any, plugin: str) -> Any:
        try:
            if self.type is bool:
                if isinstance(value, bool):
                    return value
                text = str(value).strip().lower()
                if text in _TRUE | _FALSE:
                    return text in _TRUE
                raise ValueError
            if self.type is float and isinstance(value, bool):
                raise ValueError
            return self.type(value)
        except (TypeError, ValueError):
            raise PluginError(
                f"{plugin}: option '{self.name}' must be a {self.type.__name__}, got {value!r}"
            ) from None


class Plugin:
    """Common base. Subclasses set the class attributes below."""

    kind: ClassVar[str] = ""
    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    options: ClassVar[tuple[Option, ...]] = ()
    api_version: ClassVar[int] = API_VERSION

    @classmethod
    def resolve_options(cls, *layers: dict[str, Any]) -> dict[str, Any]:
        """Defaults overlaid by each layer in turn (profile, then CLI)."""
        known = {o.name: o for o in cls.options}
        out = {o.name: o.default for o in cls.options}
        for layer in layers:
            for key, value in layer.items():
                if key not in known:
                    raise PluginError(f"{cls.kind} '{cls.name}' has no option '{key}'{did_you_mean(key, known)} "
                                      f"(options: {', '.join(known) or 'none'})")
                out[key] = known[key].coerce(value, f"{cls.kind} '{cls.name}'")
        return out


class Tracer(Plugin):
    """Turns an input file into a Drawing (polylines in px or mm)."""

    kind = "tracer"
    extensions: ClassVar[tuple[str, ...]] = ()  # lower-case, with the dot
    # Set by the pipeline before ``trace`` when it can tell (pictures laid out by
    # their canvas): how many mm one picture pixel will be drawn, and the pen
    # width in mm. None when unknown (direct calls, fit = "ink"). Optional to use.
    mm_per_px: float | None = None
    pen_mm: float | None = None

    def trace(self, path: Path, options: dict[str, Any]):  # -> doodlecam.model.Drawing
        raise NotImplementedError

    @classmethod
    def check_options(cls, options: dict[str, Any], pen_mm: float | None = None) -> None:
        """Raise a PluginError for resolved ``options`` that cannot work (``pen_mm``: the pen's
        width when known). Called before anything is traced; optional to override."""

    @classmethod
    def check_extension(cls, ext: str) -> None:
        """Raise a DoodleError when files with this extension (lower-case, with the dot) cannot be
        read here, e.g. an optional library is missing (doodlecam.extras.require). Called before
        anything is traced; optional to override."""

    @classmethod
    def layer_names(cls, options: dict[str, Any]) -> tuple[str, ...] | None:
        """The layers this tracer's drawings can have with these resolved options, when that is
        known before tracing: ``()`` for one unnamed layer (a photo's edges); ``None``, the
        default, when it depends on the file (an SVG's layers). ``--layer`` is checked against it
        before the work."""
        return None


class Kinematics(Plugin):
    """Maps pen positions (mm) to actuator coordinates for the planner.

    ``actuator_limits`` gives (velocity, acceleration) limits in actuator
    units per second (squared). ``derivatives`` gives, along a path q(u),
    the actuator coordinates theta(u) and their path derivatives theta'(u),
    theta''(u) by the chain rule. If the actuators are a linear map of the pen
    position (theta = M @ xy), set ``linear_map = M``: the planner then
    certifies limits between grid points exactly with Bernstein bounds;
    otherwise it verifies them on a finer grid and refines where needed.
    """

    kind = "machine"
    linear_map = None  # (n_act, 2) array when theta = M @ xy
    actuator_names: ClassVar[tuple[str, ...]] = ("x", "y")
    actuator_units: ClassVar[str] = "mm"

    # The [kinematics] table's schema: a doodlecam.schema.Table (a pydantic model). Set, the table is
    # checked on load, each mistake one line naming the file and key (kinematics.a0), and
    # ``self.params`` is the model; None: ``self.params`` is the table's dict, unchecked.
    Params: ClassVar[type | None] = None

    def __init__(self, machine, params: dict[str, Any]):
        self.machine = machine
        if self.Params is not None:
            from doodlecam.schema import validate

            where = getattr(machine, "source", "") or getattr(machine, "name", "") or "<profile>"
            params = validate(dict(params or {}), where, self.Params, prefix=("kinematics",))
        self.params = params

    def actuator_limits(self):
        """(vmax, amax): arrays of shape (n_act,), actuator units/s and /s^2."""
        raise NotImplementedError

    def inverse(self, xy):
        """Actuator coordinates (n, n_act) of pen positions xy (n, 2) in mm."""
        return np.asarray(xy, float) @ np.asarray(self.linear_map, float).T

    def forward(self, theta):
        """Pen positions (n, 2) in mm of actuator coordinates (n, n_act)."""
        return np.asarray(theta, float) @ np.linalg.pinv(np.asarray(self.linear_map, float)).T

    def derivatives(self, q, dq, ddq):
        """(theta, theta', theta'') along a path with pen q, q', q'' (each (n, 2))."""
        M = np.asarray(self.linear_map, float).T
        return q @ M, dq @ M, ddq @ M

    def check_reachable(self, points) -> None:
        """Raise a DoodleError naming the first point the machine cannot reach (a machine that
        reaches its whole rectangular work area: ``check_in_work_area(self.machine, points)``)."""


def check_in_work_area(machine, points) -> None:
    """Raise a PlanError naming the first of ``points`` ((n, 2) mm) outside the machine's work
    area, 0..width x 0..height mm: ``check_reachable`` for machines that reach all of it."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    eps = 1e-9  # points on the edge, up to rounding, are inside
    bad = np.flatnonzero((p[:, 0] < -eps) | (p[:, 0] > machine.width + eps) |
                         (p[:, 1] < -eps) | (p[:, 1] > machine.height + eps))
    if bad.size:
        x, y = p[bad[0]]
        raise PlanError(f"point ({x:.2f}, {y:.2f}) mm is outside the {machine.width:g} x {machine.height:g} mm "
                        f"work area of '{machine.name}'")


class PostProcessor(Plugin):
    """Writes a planned Job as a file's bytes.

    ``write(job, options)`` receives the planned :class:`doodlecam.model.Job`
    (read-only) and the resolved options (a dict: every declared option, with
    the profile's ``[post.NAME]`` table and ``--post-opt NAME.KEY=VALUE``
    applied, already coerced to each option's type). It returns ``bytes``,
    written atomically to ``OUT/STEM{extension}``. See docs/plugins.md.
    """

    kind = "postprocessor"
    extension: ClassVar[str] = ""  # e.g. ".gcode"

    def write(self, job, options: dict[str, Any]) -> bytes:
        raise NotImplementedError


class Transport(Plugin):
    """Streams a job to a machine (UDP, serial, ...)."""

    kind = "transport"
