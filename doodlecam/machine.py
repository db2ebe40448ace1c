"""Machine profiles: TOML files that describe a plotter.

A profile is validated completely when it is loaded, so later stages can rely
on every limit being present, numeric and positive. Errors name the file and
the key and say how to fix it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from doodlecam.errors import MachineError, did_you_mean
from doodlecam.options import (LAYOUT_DEFAULTS, ORDER_DEFAULTS, SOLVERS, TRAVEL_ALIASES, TRAVEL_LAWS, layout_options,
                               order_options, travel_law_name)
from doodlecam.plausible import findings

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib


@dataclass(frozen=True)
class Axis:
    name: str
    steps_per_mm: float
    max_velocity: float  # mm/s
    max_acceleration: float  # mm/s^2


@dataclass(frozen=True)
class Pen:
    width: float = 0.5  # mm; strokes shorter than this are dropped
    up_delay: float = 0.1  # s to lift and settle
    down_delay: float = 0.1  # s to lower and settle
    max_speed: float | None = None  # mm/s pen-speed cap while drawing
    # [[pen]] entries: a machine with several pens (or one pen changed by hand)
    name: str = ""
    colour: str = ""  # CSS colour, for the preview and the pen-change message
    max_accel: float | None = None  # mm/s^2 cap on each paper axis' acceleration (a brush is drawn gently)
    layers: tuple[str, ...] = ()  # the drawing's layers this pen draws (else matched by name or colour, then in order)

    def describe(self, number: int) -> str:
        """'pen 2 (red)', "pen 2 'fineliner' (red)": how the operator is told which pen to fit."""
        what = f" {self.name!r}" if self.name and self.name.lower() != self.colour.lower() else ""
        return f"pen {number}{what}" + (f" ({self.colour})" if self.colour else "")


@dataclass(frozen=True)
class Machine:
    name: str
    width: float  # mm, work area x in [0, width]
    height: float  # mm, work area y in [0, height]
    axes: tuple[Axis, Axis]
    margin: float = 10.0
    home: tuple[float, float] = (0.0, 0.0)
    pen: Pen = Pen()  # the first pen: the one a single-pen job draws with
    pens: tuple[Pen, ...] = ()  # every [[pen]] of the profile (empty: one [pen] table)
    travel_speed: float | None = None  # mm/s per axis for pen-up moves
    travel_law: str = "trapezoid"  # pen-up move profile, see doodlecam.plan.travel
    delta_time: float = 0.04  # s, velocity sample period
    path_tolerance: float = 0.1  # mm the pen may stray between samples (0: not enforced; docs/sampling.md)
    degree: int = 3
    tolerance: float = 0.1  # mm, spline fit tolerance
    kinematics: str = "cartesian"
    kinematics_params: dict[str, Any] = field(default_factory=dict)
    solver: str = "reach"
    smoothing: float = 1.0  # weight of the smoothing QP (solver qp[:backend]) against time
    description: str = ""
    source: str = ""
    plugin_options: dict[str, dict[str, Any]] = field(default_factory=dict)  # "post.gcode" -> {...}
    layout: dict[str, Any] = field(default_factory=dict)  # [layout], checked by doodlecam.trace.layout
    order: dict[str, Any] = field(default_factory=dict)  # [order], checked by doodlecam.trace.layout
    warnings: tuple[str, ...] = ()  # implausible but possible values (doodlecam.plausible), shown with each job

    @property
    def x(self) -> Axis:
        return self.axes[0]

    @property
    def y(self) -> Axis:
        return self.axes[1]

    @property
    def move_speed(self) -> tuple[float, float]:
        """Per-axis speed (mm/s) for pen-up moves."""
        if self.travel_speed is None:
            return (self.x.max_velocity, self.y.max_velocity)
        return (min(self.travel_speed, self.x.max_velocity), min(self.travel_speed, self.y.max_velocity))

    def pen_assignment(self, layers, colours: dict[str, str] | None = None) -> dict[str, int]:
        """Layer name -> pen number (1-based), for the layers in the order given (:meth:`assign_pens`)."""
        return {name: k for name, (k, _) in self.assign_pens(layers, colours).items()}

    def assign_pens(self, layers, colours: dict[str, str] | None = None) -> dict[str, tuple[int, str]]:
        """Layer name -> (pen number (1-based), why that pen), for the layers in the order given.

        A pen takes the layers it lists (``layers = [...]``); then a layer goes to
        the pen of its name or colour; the rest take the unused pens in order
        (again from the first once all are used: shared). Without [[pen]] entries
        the operator fits one pen per layer: the number is the layer's place.
        """
        layers = list(dict.fromkeys(layers))
        if not self.pens:
            return {name: (k, "one pen per layer (the profile has no [[pen]] list)") for k, name in enumerate(layers, 1)}
        colours = {k: _colour_key(v) for k, v in (colours or {}).items()}
        out: dict[str, tuple[int, str]] = {}
        for name in layers:
            key = name.lower()
            for k, p in enumerate(self.pens, 1):
                if name in p.layers:
                    out[name] = (k, "the pen lists this layer")
                    break
            else:
                for k, p in enumerate(self.pens, 1):
                    if key and key in (p.name.lower(), p.colour.lower()):
                        out[name] = (k, "the pen's name" if key == p.name.lower() else "the pen's colour")
                        break
                    if p.colour and colours.get(name) == _colour_key(p.colour):
                        out[name] = (k, "the pen's colour")
                        break
        used = {k for k, _ in out.values()}
        free = [k for k in range(1, len(self.pens) + 1) if k not in used]
        for i, name in enumerate(n for n in layers if n not in out):
            if free:
                k = free[i % len(free)]
                out[name] = (k, "no pen of its own: a spare pen" if i < len(free) else
                             "no pen of its own: shares a spare pen")
            else:  # every pen has a layer: share the pen nearest in colour (else take turns)
                near = _nearest_colour(colours.get(name), [p.colour for p in self.pens])
                k = near + 1 if near is not None else 1 + i % len(self.pens)
                out[name] = (k, "no pen of its own: shares the pen nearest in colour" if near is not None
                             else "no pen of its own: shares a pen (every pen has a layer)")
        return {name: out[name] for name in layers}

    def pen_number(self, number: int) -> Pen:
        """The Pen of a pen number from :meth:`pen_assignment` (the [pen] table when there are no [[pen]]s)."""
        return self.pens[number - 1] if self.pens else self.pen

    def describe_pen(self, number: int | None, otherwise: str) -> str:
        """Pen ``number`` as the operator is told it (:meth:`Pen.describe`), or ``otherwise`` when the
        profile has no such pen (a job written for another machine)."""
        if number and (not self.pens or number <= len(self.pens)):
            return self.pen_number(number).describe(number)
        return otherwise


def _nearest_colour(colour: str | None, choices: list[str]) -> int | None:
    """Index of the colour in ``choices`` nearest to ``colour`` (sRGB distance), None when unknown."""
    from svgelements import Color

    def rgb(text):
        try:
            c = Color(str(text)) if text else None
        except (ValueError, TypeError):
            return None
        return None if c is None or c.value is None else (c.red, c.green, c.blue)

    want, have = rgb(colour), [rgb(c) for c in choices]
    known = [(sum((a - b) ** 2 for a, b in zip(want, h)), k) for k, h in enumerate(have) if h] if want else []
    return min(known)[1] if known else None


def _colour_key(text: str) -> str:
    """A colour in one spelling ('red', '#F00', 'rgb(255,0,0)' -> '#ff0000'), for matching pens to layers."""
    from svgelements import Color

    try:
        return Color(str(text)).hex.lower()
    except (ValueError, TypeError):
        return str(text).lower()


# ---------------------------------------------------------------- loading

_SCHEMA: dict[str, dict[str, tuple[type, bool]]] = {
    # table -> key -> (type, required). Numbers accept int or float.
    "machine": {"name": (str, True), "description": (str, False), "kinematics": (str, False), "solver": (str, False),
                "smoothing": (float, False)},
    "work_area": {"width": (float, True), "height": (float, True), "margin": (float, False), "home": (list, False)},
    "axes.x": {"steps_per_mm": (float, True), "max_velocity": (float, True), "max_acceleration": (float, True)},
    "axes.y": {"steps_per_mm": (float, True), "max_velocity": (float, True), "max_acceleration": (float, True)},
    "pen": {"width": (float, False), "up_delay": (float, False), "down_delay": (float, False), "max_speed": (float, False),
            "max_accel": (float, False)},
    "travel": {"speed": (float, False), "law": (str, False)},
    "sampling": {"delta_time": (float, False), "path_tolerance": (float, False)},
    "fit": {"degree": (int, False), "tolerance": (float, False)},
    # layout and order: see doodlecam/trace/layout.py and docs/tracing.md (values are checked there)
    "layout": {k: (object, False) for k in LAYOUT_DEFAULTS},
    "order": {k: (object, False) for k in ORDER_DEFAULTS},
}
_PENS_KEYS = {"name": (str, False), "colour": (str, False), "color": (str, False), "width": (float, False),
              "up_delay": (float, False), "down_delay": (float, False), "max_speed": (float, False),
              "max_accel": (float, False), "layers": (list, False)}
_FREE_TABLES = ("kinematics", "trace", "post", "transport")  # plugin-defined contents
_NON_NEGATIVE = {"work_area.margin", "pen.up_delay", "pen.down_delay", "sampling.path_tolerance"}


MACHINES_ENV = "DOODLECAM_MACHINES"


def user_machine_dir() -> Path:
    """The user's profile folder, e.g. ~/.config/doodlecam/machines on Linux
    (platformdirs: $XDG_CONFIG_HOME is honoured), where ``machines new`` writes."""
    from platformdirs import user_config_dir

    return Path(user_config_dir("doodlecam", appauthor=False)) / "machines"


def builtin_machine_dir() -> Path:
    """The profiles shipped inside the package (package data)."""
    return Path(__file__).resolve().parent / "machines"


def machine_dirs() -> list[tuple[Path, str]]:
    """(folder, where-label) in search order: $DOODLECAM_MACHINES, the user folder,
    ./machines, the built-ins. The first profile of a name wins."""
    dirs = [(Path(p), f"${MACHINES_ENV}") for p in os.environ.get(MACHINES_ENV, "").split(os.pathsep) if p]
    dirs += [(user_machine_dir(), "user"), (Path.cwd() / "machines", "./machines"), (builtin_machine_dir(), "built-in")]
    return dirs


@dataclass(frozen=True)
class ProfileEntry:
    name: str
    path: Path
    origin: str  # "built-in", "user", "./machines" or "$DOODLECAM_MACHINES"
    shadows: tuple[Path, ...] = ()  # profiles of the same name further down the search path


def find_machines() -> dict[str, ProfileEntry]:
    """Every profile on the search path by name (file stem), with where it comes from."""
    found: dict[str, ProfileEntry] = {}
    for d, origin in machine_dirs():
        if not d.is_dir():
            continue
        for p in sorted(d.glob("*.toml")):
            if p.stem in found:
                e = found[p.stem]
                found[p.stem] = replace(e, shadows=e.shadows + (p,))
            else:
                found[p.stem] = ProfileEntry(p.stem, p, origin)
    return found


def available_machines() -> dict[str, Path]:
    """Profile name (file stem) -> path, for every profile on the search path."""
    return {name: e.path for name, e in find_machines().items()}


def resolve_machine(spec: str) -> Path:
    """A profile path from a path or a name on the search path."""
    p = Path(spec)
    if p.suffix == ".toml" or os.sep in spec or "/" in spec:
        if not p.is_file():
            raise MachineError(f"{spec}: no such machine profile; give the path of a .toml file or a name from 'doodlecam machines'")
        return p
    known = available_machines()
    if spec in known:
        return known[spec]
    raise MachineError(f"unknown machine '{spec}'{did_you_mean(spec, known)}; known: {', '.join(sorted(known)) or 'none'}; "
                       "or give a .toml path, or make one: doodlecam machines new NAME")


def _check(path: str, table: str, key: str, value: Any, typ: type) -> Any:
    where = f"{path}: [{table}] {key}"
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise MachineError(f"{where} must be a number, got {value!r}; fix the profile")
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            raise MachineError(f"{where} must be finite, got {value!r}; fix the profile")
        if f"{table}.{key}" in _NON_NEGATIVE:
            if value < 0:
                raise MachineError(f"{where} must be >= 0, got {value:g}; fix the profile")
        elif value <= 0:
            raise MachineError(f"{where} must be positive, got {value:g}; fix the profile")
    elif typ is int:
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise MachineError(f"{where} must be a positive whole number, got {value!r}; fix the profile")
    elif not isinstance(value, typ):
        raise MachineError(f"{where} must be a {typ.__name__}, got {value!r}; fix the profile")
    return value


def _table(data: dict, dotted: str) -> Any:
    node: Any = data
    for part in dotted.split("."):
        if not isinstance(node, dict):
            return None
        node = node.get(part)
    return node


def _travel_law(path: str, law: str | None) -> str:
    try:
        return travel_law_name(law)
    except ValueError:
        names = list(TRAVEL_LAWS) + list(TRAVEL_ALIASES)
        raise MachineError(f"{path}: [travel] law {law!r} is unknown{did_you_mean(str(law), names)}; use one of {', '.join(names)}") from None


def parse_machine(data: dict[str, Any], path: str = "<profile>") -> Machine:
    """Validate a profile's parsed TOML and build a Machine."""
    allowed_top = {t.split(".")[0] for t in _SCHEMA} | set(_FREE_TABLES)
    for key in data:
        if key not in allowed_top:
            raise MachineError(f"{path}: unknown table [{key}]{did_you_mean(key, allowed_top, '[]')}; remove or rename it")
    axes = data.get("axes", {})
    if isinstance(axes, dict):
        for key in axes:
            if key not in ("x", "y"):
                raise MachineError(f"{path}: unknown axis [axes.{key}]; a plotter profile has [axes.x] and [axes.y]")
    pen_list = data.get("pen") if isinstance(data.get("pen"), list) else None
    if pen_list is not None:
        data = {k: v for k, v in data.items() if k != "pen"}
    vals: dict[str, dict[str, Any]] = {}
    for table, keys in _SCHEMA.items():
        t = _table(data, table)
        if t is None:
            t = {}
            if any(req for _, req in keys.values()):
                raise MachineError(f"{path}: missing table [{table}]; add it with keys {', '.join(k for k, (_, r) in keys.items() if r)}")
        if not isinstance(t, dict):
            raise MachineError(f"{path}: [{table}] must be a table; fix the profile")
        for key in t:
            if key not in keys:
                raise MachineError(f"{path}: unknown key '{key}' in [{table}]{did_you_mean(key, keys)}; fix the profile")
        vals[table] = {}
        for key, (typ, required) in keys.items():
            if key not in t:
                if required:
                    raise MachineError(f"{path}: missing key '{key}' in [{table}]; add it (see 'doodlecam machines new')")
                continue
            vals[table][key] = _check(path, table, key, t[key], typ)

    wa = vals["work_area"]
    home = wa.get("home", [0.0, 0.0])
    if len(home) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in home):
        raise MachineError(f"{path}: [work_area] home must be two numbers [x, y] in mm; fix the profile")
    margin = wa.get("margin", 10.0)
    if 2 * margin >= min(wa["width"], wa["height"]):
        raise MachineError(f"{path}: [work_area] margin {margin:g} mm leaves no room to draw; make it smaller than half the work area")
    axes_t = tuple(Axis(n, **vals[f"axes.{n}"]) for n in ("x", "y"))
    pen_v = vals["pen"]
    pen = Pen(
        width=pen_v.get("width", 0.5),
        up_delay=pen_v.get("up_delay", 0.1),
        down_delay=pen_v.get("down_delay", 0.1),
        max_speed=pen_v.get("max_speed"),
        max_accel=pen_v.get("max_accel"),
    )
    pens = _parse_pens(path, pen_list) if pen_list is not None else ()
    if pens:
        pen = pens[0]
    fit = vals["fit"]
    degree = fit.get("degree", 3)
    tolerance = fit.get("tolerance", 0.1)
    if degree > 5:
        raise MachineError(f"{path}: [fit] degree {degree} is too high; use 2 to 5 (3 is the report's URBS)")
    if degree < 2:
        raise MachineError(f"{path}: [fit] degree {degree} gives no continuous velocity; use 2 to 5 (3 is the report's URBS)")
    plugin_options: dict[str, dict[str, Any]] = {}
    for group in ("trace", "post", "transport"):
        for name, opts in (data.get(group) or {}).items():
            if not isinstance(opts, dict):
                raise MachineError(f"{path}: [{group}.{name}] must be a table of options; fix the profile")
            plugin_options[f"{group}.{name}"] = dict(opts)
    m = vals["machine"]
    solver = m.get("solver", "reach")
    if solver not in SOLVERS:
        raise MachineError(f"{path}: [machine] solver {solver!r} is unknown{did_you_mean(solver, SOLVERS)}; "
                           f"use one of {', '.join(SOLVERS)}")
    machine = Machine(
        name=m["name"],
        description=m.get("description", ""),
        kinematics=m.get("kinematics", "cartesian"),
        kinematics_params=dict(data.get("kinematics") or {}),
        solver=solver,
        smoothing=m.get("smoothing", 1.0),
        width=wa["width"],
        height=wa["height"],
        margin=margin,
        home=(float(home[0]), float(home[1])),
        axes=axes_t,  # type: ignore[arg-type]
        pen=pen,
        pens=pens,
        travel_speed=vals["travel"].get("speed"),
        travel_law=_travel_law(path, vals["travel"].get("law")),
        delta_time=vals["sampling"].get("delta_time", 0.04),
        # the pen stays as close to the curve between samples as the fit is to the picture
        path_tolerance=vals["sampling"].get("path_tolerance", tolerance),
        degree=degree,
        tolerance=tolerance,
        source=path,
        plugin_options=plugin_options,
        layout=layout_options(vals["layout"], f"{path}: [layout]", MachineError),
        order=order_options(vals["order"], f"{path}: [order]", MachineError),
    )
    found = findings(machine)
    if found and found[0].error:
        raise MachineError(found[0].message)
    return replace(machine, warnings=tuple(f.message for f in found))


def _parse_pens(path: str, entries: list) -> tuple[Pen, ...]:
    """[[pen]] entries: the same keys as [pen] plus name, colour, max_accel and layers."""
    if not entries:
        raise MachineError(f"{path}: [[pen]] is empty; give at least one pen, or use a single [pen] table")
    pens, seen = [], set()
    for k, e in enumerate(entries, 1):
        where = f"[[pen]] number {k}"
        if not isinstance(e, dict):
            raise MachineError(f"{path}: {where} must be a table; fix the profile")
        for key in e:
            if key not in _PENS_KEYS:
                raise MachineError(f"{path}: unknown key '{key}' in {where}{did_you_mean(key, _PENS_KEYS)}; fix the profile")
        try:
            v = {key: _check(path, "pen", key, e[key], typ) for key, (typ, _) in _PENS_KEYS.items() if key in e}
        except MachineError as err:
            raise MachineError(str(err).replace("[pen]", where, 1)) from None
        layers = v.get("layers", [])
        if not all(isinstance(n, str) for n in layers):
            raise MachineError(f"{path}: {where} layers must be a list of layer names (strings); fix the profile")
        name = v.get("name", "")
        if name and name.lower() in seen:
            raise MachineError(f"{path}: two [[pen]] entries are named {name!r}; give each pen its own name")
        seen.add(name.lower())
        pens.append(Pen(width=v.get("width", 0.5), up_delay=v.get("up_delay", 0.1), down_delay=v.get("down_delay", 0.1),
                        max_speed=v.get("max_speed"), name=name, colour=v.get("colour", v.get("color", "")),
                        max_accel=v.get("max_accel"), layers=tuple(layers)))
    return tuple(pens)


def load_machine(spec: str | os.PathLike) -> Machine:
    """Load and validate a profile given by path or by name."""
    path = resolve_machine(str(spec))
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise MachineError(f"{path}: cannot read machine profile ({e.strerror or e}); check the file") from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")) or b"\x00" in raw[:200]:
        raise MachineError(f"{path}: is saved as UTF-16 (Windows \"Unicode\"); save it as UTF-8")
    try:  # utf-8-sig: a byte-order mark (Notepad writes one) is no part of the TOML
        data = tomllib.loads(raw.decode("utf-8-sig"))
    except UnicodeDecodeError as e:
        raise MachineError(f"{path}: is not UTF-8 text (byte {e.start} cannot be read); save it as UTF-8") from None
    except tomllib.TOMLDecodeError as e:
        raise MachineError(f"{path}: not valid TOML ({e}); fix the syntax") from None
    return parse_machine(data, str(path))
