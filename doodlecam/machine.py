"""Machine profiles: TOML files that describe a plotter.

A profile is validated completely when it is loaded (its schema: doodlecam/schema.py;
plausible values: doodlecam/plausible.py), so later stages can rely on every limit
being present, numeric and positive. Errors name the file and the key and say how to
fix it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from doodlecam.errors import MachineError, did_you_mean
from doodlecam.options import layout_options, order_options
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


def parse_machine(data: dict[str, Any], path: str = "<profile>") -> Machine:
    """Validate a profile's parsed TOML (doodlecam.schema, then doodlecam.plausible) and build a Machine."""
    from doodlecam.schema import validate

    p = validate(data, path)
    w = p.work_area
    if isinstance(p.pen, list):
        pens = tuple(Pen(width=e.width, up_delay=e.up_delay, down_delay=e.down_delay, max_speed=e.max_speed,
                         max_accel=e.max_accel, name=e.name, colour=e.colour or e.color, layers=tuple(e.layers))
                     for e in p.pen)
        pen = pens[0]
    else:
        pens, pen = (), Pen(width=p.pen.width, up_delay=p.pen.up_delay, down_delay=p.pen.down_delay,
                            max_speed=p.pen.max_speed, max_accel=p.pen.max_accel)
    plugin_options = {f"{group}.{name}": dict(opts) for group in ("trace", "post", "transport")
                      for name, opts in getattr(p, group).items()}
    where = f"{path}: "  # [layout] and [order] values: the checks the CLI's --layout / --order options use
    machine = Machine(
        name=p.machine.name,
        description=p.machine.description,
        kinematics=p.machine.kinematics,
        kinematics_params=dict(p.kinematics),
        solver=p.machine.solver,
        smoothing=p.machine.smoothing,
        width=w.width,
        height=w.height,
        margin=w.margin,
        home=(float(w.home[0]), float(w.home[1])),
        axes=tuple(Axis(n, **getattr(p.axes, n).model_dump()) for n in ("x", "y")),  # type: ignore[arg-type]
        pen=pen,
        pens=pens,
        travel_speed=p.travel.speed,
        travel_law=p.travel.law,
        delta_time=p.sampling.delta_time,
        # the pen stays as close to the curve between samples as the fit is to the picture
        path_tolerance=p.fit.tolerance if p.sampling.path_tolerance is None else p.sampling.path_tolerance,
        degree=p.fit.degree,
        tolerance=p.fit.tolerance,
        source=path,
        plugin_options=plugin_options,
        layout=layout_options(p.layout.model_dump(exclude_unset=True), where + "layout", MachineError, sep="."),
        order=order_options(p.order.model_dump(exclude_unset=True), where + "order", MachineError, sep="."),
    )
    found = findings(machine)
    if found and found[0].error:
        raise MachineError(found[0].message)
    return replace(machine, warnings=tuple(f.message for f in found))


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
