"""MOTDES-style motion design (Kirecci chapter 5) from a TOML file.

A design is a set of axes, each a list of *design points* (time and any of
position, velocity, acceleration, jerk) split into *segments*; every segment
has a motion law. Input comes either in the X–Y form (one table of points
for both axes, like the thesis's Table 5.1) or in the axis–time form (each
axis its own points and segments). See docs/motion.md for the file format.

Solving follows §3.5 (segmented polynomials): segments are solved in order
and, up to ``continuity`` (2 = acceleration, the thesis's recommendation), a
value a point leaves open is taken over from the end of the previous segment
("match"); a polynomial followed by a cam law ends with the law's start
values. Then every segment is checked against its tolerance envelope and for
meandering, every joint for continuity, and, given a machine, every point
against the workspace and the actuator limits through its kinematics plugin.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.errors import InputError
from doodlecam.motion import MotionError
from doodlecam.motion import laws as L
from doodlecam.motion.envelope import Finding, check_segment
from doodlecam.motion.polynomial import ORDER_NAMES, Condition, optimise_powers, solve

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

POLY_LAWS = ("polynomial", "cubic-spline")
DEFAULT_SAMPLES = 300  # rows of the MOTDES table (§5.2.2)
_MOTION_KEYS = {"name", "input", "continuity", "samples", "tolerance", "machine", "origin", "cycle_time", "description",
                "product_acceleration"}
_DRIVE_KEYS = {"motor_inertia", "load_inertia", "lead", "ratio", "max_torque", "friction_torque", "viscous", "load_torque"}
_SEGMENT_KEYS = {"law", "powers", "optimise", "max_power", "envelope", "b", "a1", "a2"}
_XY_POINT = {"t": None, "x": ("x", 0), "y": ("y", 0), "vx": ("x", 1), "vy": ("y", 1), "ax": ("x", 2), "ay": ("y", 2),
             "jx": ("x", 3), "jy": ("y", 3), "via": None}
_AXIS_POINT = {"t": None, "pos": 0, "vel": 1, "acc": 2, "jerk": 3, "via": None}


# ------------------------------------------------------------------ model


@dataclass(frozen=True)
class DesignPoint:
    index: int  # 1-based row in its table, for messages
    t: float  # s
    values: dict[int, float]  # order -> given value
    match: frozenset[int] = frozenset()  # orders taken over from the previous segment
    via: bool = False  # an interior point of a segment, not a segment end


@dataclass(frozen=True)
class SegmentSpec:
    law: str = "polynomial"
    powers: tuple[float, ...] | None = None
    optimise: str | None = None
    max_power: float = 40.0
    envelope: tuple[float, float] | None = None
    params: dict[str, float] = field(default_factory=dict)


UNITS = ("mm", "deg", "rad")
ROTATION_NAMES = ("theta", "θ", "Θ")  # an axis so named turns (the end effector's orientation, §6.1): degrees


@dataclass(frozen=True)
class AxisDesign:
    name: str
    points: tuple[DesignPoint, ...]
    segments: tuple[SegmentSpec, ...]
    unit: str = "mm"  # of position; derivatives per s, s², s³

    def units(self) -> tuple[str, str, str, str]:
        return (self.unit, f"{self.unit}/s", f"{self.unit}/s²", f"{self.unit}/s³")


@dataclass(frozen=True)
class Design:
    name: str
    axes: tuple[AxisDesign, ...]
    source: str = "<design>"
    input: str = "xy"
    continuity: int = 2
    samples: int = DEFAULT_SAMPLES
    tolerance: float = 0.0
    machine: str | None = None
    origin: tuple[float, float] = (0.0, 0.0)
    description: str = ""
    product_acceleration: float | None = None  # mm/s², the most the carried product tolerates (§4.5.3)
    drives: tuple["Drive", ...] = ()  # eq. 4.1 per axis

    def scaled(self, cycle_time: float) -> "Design":
        """The same design run in ``cycle_time`` s: times stretch, derivative
        conditions scale by 1/k^order (the thesis runs a unit-time design at
        any speed, §5.4)."""
        t0 = min(p.t for a in self.axes for p in a.points)
        t1 = max(p.t for a in self.axes for p in a.points)
        if not (cycle_time > 0 and np.isfinite(cycle_time)):
            raise MotionError(f"{self.source}: cycle time must be a positive, finite number of seconds, "
                              f"got {cycle_time:g}; give e.g. --cycle-time 10.6")
        k = cycle_time / (t1 - t0)
        axes = []
        for a in self.axes:
            pts = tuple(DesignPoint(p.index, t0 + (p.t - t0) * k, {o: v / k**o for o, v in p.values.items()},
                                    p.match, p.via) for p in a.points)
            axes.append(AxisDesign(a.name, pts, a.segments, a.unit))
        return Design(**{**self.__dict__, "axes": tuple(axes)})


# ---------------------------------------------------------------- parsing


def _err(src: str, msg: str) -> MotionError:
    return MotionError(f"{src}: {msg}")


def _unknown(src: str, where: str, keys, allowed) -> None:
    for key in keys:
        if key not in allowed:
            hint = difflib.get_close_matches(key, list(allowed), n=1)
            did = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise _err(src, f"unknown key '{key}' in {where}{did}; fix the design")


def _number(src: str, where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise _err(src, f"{where} must be a finite number, got {value!r}")
    return float(value)


def _parse_point(src: str, where: str, row: Any, columns: dict, index: int) -> tuple[float, dict, dict, bool]:
    """(t, {axis: {order: value}}, {axis: {orders matched}}, via) of one table row."""
    if not isinstance(row, dict):
        raise _err(src, f"{where} must be a table of values")
    _unknown(src, where, row, columns)
    if "t" not in row:
        raise _err(src, f"{where} has no time 't'; give the time (s) of every design point")
    t = _number(src, f"{where} t", row["t"])
    values: dict[str, dict[int, float]] = {}
    match: dict[str, set[int]] = {}
    for key, value in row.items():
        target = columns[key]
        if target is None:
            continue
        axis, order = target if isinstance(target, tuple) else ("", target)
        if isinstance(value, str):
            if value.strip().lower() != "match":
                raise _err(src, f"{where} {key} = {value!r}: give a number or \"match\"")
            match.setdefault(axis, set()).add(order)
        else:
            values.setdefault(axis, {})[order] = _number(src, f"{where} {key}", value)
    via = row.get("via", False)
    if not isinstance(via, bool):
        raise _err(src, f"{where} via must be true or false")
    return t, values, match, via


def _parse_segment(src: str, where: str, row: Any, axis: str | None = None) -> SegmentSpec:
    if isinstance(row, str):
        row = {"law": row}
    if not isinstance(row, dict):
        raise _err(src, f"{where} must be a table (law = \"...\") or a law name")
    # X–Y input: [segment.x] / [segment.y] override keys for one axis; an override
    # that names a law starts from that law alone (the shared row's powers or b do not carry over)
    allowed = set(_SEGMENT_KEYS) | ({"x", "y"} if axis is not None else set())
    _unknown(src, where, row, allowed)
    if axis is not None:
        for name in ("x", "y"):
            if name in row and not isinstance(row[name], dict):
                raise _err(src, f"{where}: [segment.{name}] must be a table of keys that override the row for axis {name}")
        override = row.get(axis, {})
        _unknown(src, f"{where} [segment.{axis}]", override, _SEGMENT_KEYS)
        base = {k: v for k, v in row.items() if k not in ("x", "y")}
        if "law" in override:
            base = {k: v for k, v in base.items() if k == "envelope"}
        row = {**base, **override}
    law = row.get("law", "polynomial")
    if not isinstance(law, str):
        raise _err(src, f"{where} law must be a name, got {law!r}")
    law = L.ALIASES.get(law, law)
    if law not in POLY_LAWS:
        law_obj = L.get_law(law, f"{src}: {where}")
        params = {k: row[k] for k in ("b", "a1", "a2") if k in row}
        params = L.check_params(law_obj, params, f"{src}: {where}")
        for key in ("powers", "optimise"):
            if key in row:
                raise _err(src, f"{where}: '{key}' applies to polynomial segments, not {law}")
    else:
        params = {}
        for key in ("b", "a1", "a2"):
            if key in row:
                raise _err(src, f"{where}: '{key}' is a parameter of a cam law, not of {law}")
    powers = row.get("powers")
    if powers is not None:
        if law != "polynomial" or not isinstance(powers, list) or not powers:
            raise _err(src, f"{where}: powers must be a list of numbers on a polynomial segment")
        powers = tuple(_number(src, f"{where} powers", p) for p in powers)
    optimise = row.get("optimise")
    if optimise is not None:
        if law != "polynomial" or optimise not in ("velocity", "acceleration", "jerk"):
            raise _err(src, f"{where}: optimise must be \"velocity\", \"acceleration\" or \"jerk\" on a polynomial segment")
        if powers is not None:
            raise _err(src, f"{where}: give either powers or optimise, not both")
    env = row.get("envelope")
    if env is not None:
        if not isinstance(env, list) or len(env) != 2:
            raise _err(src, f"{where}: envelope must be [low, high]")
        lo, hi = (_number(src, f"{where} envelope", v) for v in env)
        if lo > hi:
            raise _err(src, f"{where}: envelope [{lo:g}, {hi:g}] has low above high")
        env = (lo, hi)
    max_power = _number(src, f"{where} max_power", row.get("max_power", 40.0))
    return SegmentSpec(law=law, powers=powers, optimise=optimise, max_power=max_power, envelope=env, params=params)


def parse_design(data: dict[str, Any], source: str = "<design>") -> Design:
    """Validate a parsed TOML design and build a Design."""
    src = source
    _unknown(src, "the file", data, {"motion", "point", "segment", "axis", "drive"})
    head = data.get("motion", {})
    if not isinstance(head, dict):
        raise _err(src, "[motion] must be a table")
    _unknown(src, "[motion]", head, _MOTION_KEYS)
    kind = head.get("input", "time" if "axis" in data else "xy")
    if kind not in ("xy", "time"):
        raise _err(src, f"[motion] input = {kind!r}: use \"xy\" (one [[point]] table for X and Y) or \"time\" ([axis.NAME] tables)")
    continuity = head.get("continuity", 2)
    if isinstance(continuity, bool) or continuity not in (0, 1, 2, 3):
        raise _err(src, f"[motion] continuity = {continuity!r}: use 0 (position), 1 (velocity), 2 (acceleration) or 3 (jerk)")
    samples = head.get("samples", DEFAULT_SAMPLES)
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise _err(src, f"[motion] samples = {samples!r}: give a whole number >= 2 (the thesis exports 300)")
    tolerance = _number(src, "[motion] tolerance", head.get("tolerance", 0.0))
    if tolerance < 0:
        raise _err(src, "[motion] tolerance must be >= 0 (mm of slack around each envelope)")
    origin = head.get("origin", [0.0, 0.0])
    if not isinstance(origin, list) or len(origin) != 2:
        raise _err(src, "[motion] origin must be [x, y] in machine mm")
    origin = tuple(_number(src, "[motion] origin", v) for v in origin)
    machine = head.get("machine")
    if machine is not None and not isinstance(machine, str):
        raise _err(src, "[motion] machine must be a profile name or a .toml path")

    axes: list[AxisDesign] = []
    if kind == "xy":
        if "axis" in data:
            raise _err(src, "[axis.*] tables belong to input = \"time\"; use [[point]] rows with x, y for input = \"xy\"")
        rows = data.get("point")
        if not isinstance(rows, list) or len(rows) < 2:
            raise _err(src, "give at least two [[point]] rows (t, x, y and any of vx, vy, ax, ay, jx, jy)")
        parsed = [_parse_point(src, f"[[point]] {i}", r, _XY_POINT, i) for i, r in enumerate(rows, 1)]
        seg_rows = data.get("segment", [])
        for name in ("x", "y"):
            pts = tuple(DesignPoint(i, t, vals.get(name, {}), frozenset(m.get(name, ())), via)
                        for i, (t, vals, m, via) in enumerate(parsed, 1))
            specs = _segments(src, seg_rows, pts, "[[segment]]", name)
            axes.append(AxisDesign(name, pts, specs))
    else:
        if "point" in data or "segment" in data:
            raise _err(src, "[[point]] / [[segment]] rows belong to input = \"xy\"; put them under [axis.NAME] for input = \"time\"")
        table = data.get("axis")
        if not isinstance(table, dict) or not table:
            raise _err(src, "input = \"time\" needs [axis.NAME] tables, e.g. [[axis.x.point]] rows with t, pos, vel, acc, jerk")
        for name, ax in table.items():
            if not isinstance(ax, dict):
                raise _err(src, f"[axis.{name}] must be a table")
            _unknown(src, f"[axis.{name}]", ax, {"point", "segment", "unit"})
            unit = ax.get("unit", "deg" if name in ROTATION_NAMES else "mm")
            if unit not in UNITS:
                raise _err(src, f"[axis.{name}] unit = {unit!r}: use \"mm\" for a linear axis, \"deg\" or \"rad\" for a rotation")
            rows = ax.get("point")
            if not isinstance(rows, list) or len(rows) < 2:
                raise _err(src, f"axis {name}: give at least two [[axis.{name}.point]] rows (t, pos, vel, acc, jerk)")
            pts = []
            for i, r in enumerate(rows, 1):
                t, vals, m, via = _parse_point(src, f"[[axis.{name}.point]] {i}", r, _AXIS_POINT, i)
                pts.append(DesignPoint(i, t, vals.get("", {}), frozenset(m.get("", ())), via))
            pts = tuple(pts)
            axes.append(AxisDesign(name, pts, _segments(src, ax.get("segment", []), pts, f"[[axis.{name}.segment]]", None),
                                   unit))

    for a in axes:
        _check_points(src, a)
    d = Design(name=str(head.get("name", Path(source).stem)), axes=tuple(axes), source=src, input=kind,
               continuity=continuity, samples=samples, tolerance=tolerance, machine=machine,
               origin=origin, description=str(head.get("description", "")),
               product_acceleration=_positive(src, "[motion] product_acceleration", head.get("product_acceleration")),
               drives=_drives(src, data.get("drive", {}), {a.name: a for a in axes}))
    if "cycle_time" in head:
        d = d.scaled(_number(src, "[motion] cycle_time", head["cycle_time"]))
    return d


@dataclass(frozen=True)
class Drive:
    """One axis's drive for eq. 4.1, T_m − T_r = (J_m + J_p) Θ'' (SI units; Θ the motor angle)."""

    axis: str
    motor_inertia: float  # J_m, kg·m²
    load_inertia: float  # J_p, kg·m², the moving parts and the product seen at the motor
    max_torque: float  # N·m, what the motor delivers
    lead: float | None = None  # mm of a linear axis per motor revolution
    ratio: float = 1.0  # motor turns per turn of a rotation axis
    friction_torque: float = 0.0  # N·m, Coulomb, against the motion
    viscous: float = 0.0  # N·m·s/rad
    load_torque: float = 0.0  # N·m, constant (gravity, a process force)

    def motor_rad(self, unit: str) -> float:
        """Motor radians per unit of the axis position."""
        if unit == "mm":
            return 2 * np.pi / self.lead
        return self.ratio * (np.pi / 180 if unit == "deg" else 1.0)

    def torque(self, unit: str, vel: np.ndarray, acc: np.ndarray) -> np.ndarray:
        """T_m (N·m) the motor must deliver: (J_m + J_p) Θ'' + T_r(Θ')."""
        k = self.motor_rad(unit)
        w, dw = vel * k, acc * k
        return (self.motor_inertia + self.load_inertia) * dw + self.friction_torque * np.sign(w) + self.viscous * w + self.load_torque


def _positive(src: str, where: str, value: Any) -> float | None:
    if value is None:
        return None
    v = _number(src, where, value)
    if not v > 0:
        raise _err(src, f"{where} = {v:g} must be positive")
    return v


def _drives(src: str, table: Any, axes: dict) -> tuple[Drive, ...]:
    if not isinstance(table, dict):
        raise _err(src, "[drive.AXIS] must be tables, one per axis")
    out = []
    for name, row in table.items():
        where = f"[drive.{name}]"
        if name not in axes:
            raise _err(src, f"{where}: the design has no axis '{name}' (axes: {', '.join(axes)})")
        if not isinstance(row, dict):
            raise _err(src, f"{where} must be a table")
        _unknown(src, where, row, _DRIVE_KEYS)
        for key in ("motor_inertia", "load_inertia", "max_torque"):
            if key not in row:
                raise _err(src, f"{where} needs {key} (eq. 4.1: motor_inertia and load_inertia in kg·m², max_torque in N·m)")
        unit = axes[name].unit
        if unit == "mm" and "lead" not in row:
            raise _err(src, f"{where} needs lead, the mm axis {name} travels per motor revolution")
        if unit != "mm" and "lead" in row:
            raise _err(src, f"{where}: axis {name} turns ({unit}); give ratio (motor turns per axis turn), not lead")
        vals = {k: _number(src, f"{where} {k}", v) for k, v in row.items()}
        for key in ("lead", "ratio", "max_torque"):
            if key in vals and not vals[key] > 0:
                raise _err(src, f"{where} {key} = {vals[key]:g} must be positive")
        for key in ("motor_inertia", "load_inertia", "friction_torque", "viscous"):
            if vals.get(key, 0.0) < 0:
                raise _err(src, f"{where} {key} = {vals[key]:g} must be >= 0")
        out.append(Drive(axis=name, **vals))
    return tuple(out)


def _segments(src: str, rows: Any, pts, where: str, axis: str | None) -> tuple[SegmentSpec, ...]:
    n = sum(1 for p in pts if not p.via) - 1
    if not isinstance(rows, list):
        raise _err(src, f"{where} must be an array of tables")
    if rows and len(rows) != n:
        raise _err(src, f"{len(rows)} {where} rows for {n} segments (between the {n + 1} points that are not via points); "
                        "give one per segment or none (all polynomial)")
    if not rows:
        return tuple(SegmentSpec() for _ in range(n))
    return tuple(_parse_segment(src, f"{where} {i}", r, axis) for i, r in enumerate(rows, 1))


def _check_points(src: str, a: AxisDesign) -> None:
    pts = a.points
    if pts[0].via or pts[-1].via:
        raise _err(src, f"axis {a.name}: the first and last points cannot be via points")
    for p, q in zip(pts, pts[1:]):
        if not q.t > p.t:
            raise _err(src, f"axis {a.name}: point {q.index} at t = {q.t:g} s does not come after point {p.index} "
                            f"(t = {p.t:g} s); a segment needs a positive duration, so times must increase")
    if pts[0].match:
        o = ORDER_NAMES[min(pts[0].match)]
        raise _err(src, f"axis {a.name}: point 1 asks to match {o}, but no segment precedes it; give a value")
    for p in pts:
        if p.via and p.match:
            raise _err(src, f"axis {a.name}: via point {p.index} cannot match; matching happens at segment ends")


def load_design(path: str | Path) -> Design:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such design file; check the path") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read the design ({e}); check the file") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: not valid TOML ({e}); fix the syntax") from None
    return parse_design(data, str(path))


# ---------------------------------------------------------------- solving


@dataclass(frozen=True)
class LawSegment:
    """A cam-law segment: position p0 + law(t − t0) for a rise h over T."""

    t0: float
    duration: float
    p0: float
    h: float
    law: str
    params: dict[str, float]

    @property
    def t1(self) -> float:
        return self.t0 + self.duration

    def evaluate(self, t) -> np.ndarray:
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), self.t0, self.t1)
        f = L.evaluate(self.law, t - self.t0, self.h, self.duration, **self.params)
        f[0] += self.p0
        return f

    def describe(self) -> str:
        return L.get_law(self.law).title


@dataclass(frozen=True)
class SplineSegment:
    """A cubic spline through position via points (§2.10), end slopes or curvatures given."""

    t0: float
    t1: float
    spline: Any  # scipy.interpolate.CubicSpline

    @property
    def duration(self) -> float:
        return self.t1 - self.t0

    def evaluate(self, t) -> np.ndarray:
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), self.t0, self.t1)
        return np.stack([self.spline(t, k) for k in range(4)])

    def describe(self) -> str:
        return f"cubic spline, {len(self.spline.x) - 1} pieces"


@dataclass(frozen=True)
class SolvedSegment:
    axis: str
    number: int  # 1-based
    spec: SegmentSpec
    impl: Any  # PolySegment | LawSegment | SplineSegment
    first_point: int
    last_point: int

    @property
    def t0(self) -> float:
        return self.impl.t0

    @property
    def t1(self) -> float:
        return self.impl.t1

    @property
    def where(self) -> str:
        return f"axis {self.axis} segment {self.number} (points {self.first_point}-{self.last_point}, {self.spec.law})"

    def evaluate(self, t) -> np.ndarray:
        return self.impl.evaluate(t)


@dataclass(frozen=True)
class AxisTrajectory:
    name: str
    segments: tuple[SolvedSegment, ...]
    points: tuple[DesignPoint, ...]
    unit: str = "mm"

    def units(self) -> tuple[str, str, str, str]:
        return (self.unit, f"{self.unit}/s", f"{self.unit}/s²", f"{self.unit}/s³")

    @property
    def t0(self) -> float:
        return self.segments[0].t0

    @property
    def t1(self) -> float:
        return self.segments[-1].t1

    def evaluate(self, t) -> np.ndarray:
        """(4, n): pos, vel, acc, jerk at times t; held at the ends outside [t0, t1]."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        ends = np.array([s.t1 for s in self.segments[:-1]])
        k = np.searchsorted(ends, t, side="right")
        out = np.empty((4, len(t)))
        for i, seg in enumerate(self.segments):
            m = k == i
            if m.any():
                out[:, m] = seg.evaluate(t[m])
        out[1:, (t < self.t0) | (t > self.t1)] = 0.0  # at rest outside the design
        return out


@dataclass(frozen=True)
class Trajectory:
    design: Design
    axes: tuple[AxisTrajectory, ...]

    @property
    def t0(self) -> float:
        return min(a.t0 for a in self.axes)

    @property
    def t1(self) -> float:
        return max(a.t1 for a in self.axes)

    def axis(self, name: str) -> AxisTrajectory:
        for a in self.axes:
            if a.name == name:
                return a
        raise KeyError(name)

    def sample(self, n: int | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """n evenly spaced times over the whole design (both ends included)
        and each axis's (4, n) pos/vel/acc/jerk: the MOTDES table."""
        n = n or self.design.samples
        t = np.linspace(self.t0, self.t1, n)
        return t, {a.name: a.evaluate(t) for a in self.axes}


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))


def _fixed_law(spec: SegmentSpec, t0: float, t1: float, p0: float, p1: float) -> LawSegment:
    return LawSegment(t0=t0, duration=t1 - t0, p0=p0, h=p1 - p0, law=spec.law, params=dict(spec.params))


def solve_axis(design: Design, axis: AxisDesign) -> AxisTrajectory:
    src = design.source
    pts = axis.points
    ends = [i for i, p in enumerate(pts) if not p.via]
    spans = list(zip(ends, ends[1:]))
    cont = design.continuity
    solved: list[SolvedSegment] = []
    carry: np.ndarray | None = None  # pos/vel/acc/jerk at the end of the previous segment

    def law_positions(s: int, carried: float | None) -> tuple[float, float]:
        spec = axis.segments[s]
        i0, i1 = spans[s]
        P0, P1 = pts[i0], pts[i1]
        where = f"{src}: axis {axis.name} segment {s + 1} (points {P0.index}-{P1.index}, {spec.law})"
        if i1 - i0 > 1:
            raise MotionError(f"{where}: a cam law runs between its two end points only; remove the via point or use law = \"polynomial\"")
        p0 = P0.values.get(0, carried)
        if p0 is None:
            raise MotionError(f"{where}: point {P0.index} gives no position; a cam law needs the position at both ends")
        p1 = P1.values.get(0)
        if p1 is None:
            if spec.law != "dwell":
                raise MotionError(f"{where}: point {P1.index} gives no position; a cam law needs the position at both ends")
            p1 = p0
        return p0, p1

    for s, ((i0, i1), spec) in enumerate(zip(spans, axis.segments)):
        P0, P1 = pts[i0], pts[i1]
        t0, t1 = P0.t, P1.t
        where = f"{src}: axis {axis.name} segment {s + 1} (points {P0.index}-{P1.index}, {spec.law})"
        if spec.law in POLY_LAWS:
            conds: list[Condition] = []
            for o in range(4):  # start: given, else taken over from the previous segment
                if o in P0.values:
                    conds.append(Condition(t0, o, P0.values[o], f"point {P0.index}"))
                elif carry is not None and (o <= cont or o in P0.match):
                    conds.append(Condition(t0, o, float(carry[o]), f"point {P0.index} (matched)"))
            for P in pts[i0 + 1:i1]:
                conds += [Condition(P.t, o, v, f"via point {P.index}") for o, v in sorted(P.values.items())]
            nxt = axis.segments[s + 1] if s + 1 < len(axis.segments) else None
            law_start = None
            if nxt is not None and nxt.law not in POLY_LAWS:
                q0, q1 = law_positions(s + 1, None)
                law_start = _fixed_law(nxt, t1, pts[spans[s + 1][1]].t, q0, q1).evaluate([t1])[:, 0]
            for o in range(4):  # end: given, else the next cam law's start value
                if o in P1.values:
                    conds.append(Condition(t1, o, P1.values[o], f"point {P1.index}"))
                elif law_start is not None and (o <= cont or o in P1.match):
                    conds.append(Condition(t1, o, float(law_start[o]), f"point {P1.index} (next law)"))
            if spec.law == "cubic-spline":
                impl = _spline(where, conds, t0, t1)
            elif spec.optimise:
                impl = optimise_powers(conds, t0, t1 - t0, spec.optimise, continuity=cont, max_power=spec.max_power,
                                       envelope=_envelope(spec, conds, t0, t1), where=where)
            else:
                _check_powers(where, spec.powers, cont)
                impl = solve(conds, t0, t1 - t0, powers=spec.powers, where=where)
        else:
            p0, p1 = law_positions(s, None if carry is None else float(carry[0]))
            if spec.law == "dwell" and not _close(p0, p1):
                raise MotionError(f"{where}: a dwell holds its position, but point {P1.index} moves it from {p0:g} to {p1:g}; "
                                  "use a rise law")
            impl = _fixed_law(spec, t0, t1, p0, p1)
            f0, f1 = impl.evaluate([t0, t1]).T
            for P, f in ((P0, f0), (P1, f1)):
                for o, v in P.values.items():
                    if not _close(v, float(f[o])):
                        raise MotionError(f"{where}: point {P.index} asks {ORDER_NAMES[o]} = {v:g}, but {spec.law} gives "
                                          f"{float(f[o]):.6g} there; drop the condition or use law = \"polynomial\"")
        solved.append(SolvedSegment(axis.name, s + 1, spec, impl, P0.index, P1.index))
        carry = impl.evaluate([t1])[:, 0]
    return AxisTrajectory(axis.name, tuple(solved), pts, axis.unit)


def _check_powers(where: str, powers, continuity: int) -> None:
    """Eq. 3.10: a power that is not a whole number must exceed m + 0.5, m being
    the derivative up to which segments join continuously; below it the
    derivative steps at the segment's start (Fig. 3.11). Refused, not lifted:
    the designer chose the powers, and a silently changed curve is worse."""
    if powers is None:
        return
    q = continuity + 0.5
    for p in powers:
        if p != round(p) and not p > q:
            raise MotionError(f"{where}: power {p:g} breaks eq. 3.10 (a power that is not a whole number must exceed "
                              f"m + 0.5 = {q:g} for continuity up to {ORDER_NAMES[continuity]}); raise it above {q:g}, "
                              "make it a whole number or lower [motion] continuity")


def _envelope(spec: SegmentSpec, conds, t0: float, t1: float) -> tuple[float, float]:
    """The optimiser's penalty box: the designer's envelope, else the span of
    the segment's positions (via points included; the rectangles between
    successive points are checked afterwards)."""
    if spec.envelope is not None:
        return spec.envelope
    pos = [c.value for c in conds if c.order == 0]
    ends = [c for c in conds if c.order == 0 and c.t in (t0, t1)]
    if len(ends) < 2:
        return (-np.inf, np.inf)
    return (min(pos), max(pos))


def _spline(where: str, conds, t0: float, t1: float) -> SplineSegment:
    from scipy.interpolate import CubicSpline

    pos = sorted((c.t, c.value) for c in conds if c.order == 0)
    times = [p[0] for p in pos]
    if len(pos) < 2 or not _close(times[0], t0) or not _close(times[-1], t1):
        raise MotionError(f"{where}: a cubic spline needs the position at both ends (and at each via point)")
    if any(c.order == 3 for c in conds):
        raise MotionError(f"{where}: a cubic spline cannot meet a jerk condition; use law = \"polynomial\"")
    vias_extra = [c for c in conds if c.order > 0 and not (_close(c.t, t0) or _close(c.t, t1))]
    if vias_extra:
        raise MotionError(f"{where}: a cubic spline takes only positions at via points ({vias_extra[0].name}); "
                          "use law = \"polynomial\"")

    def bc(t):
        given = {c.order: c.value for c in conds if _close(c.t, t) and c.order in (1, 2)}
        if 1 in given:
            return (1, given[1])
        return (2, given.get(2, 0.0))  # natural end when nothing is given

    return SplineSegment(t0, t1, CubicSpline(times, [p[1] for p in pos], bc_type=(bc(t0), bc(t1))))


def solve_design(design: Design) -> Trajectory:
    return Trajectory(design, tuple(solve_axis(design, a) for a in design.axes))


# ----------------------------------------------------------------- checks


@dataclass
class Report:
    """What ``check`` found; ``findings`` empty means every check passed."""

    findings: list[Finding] = field(default_factory=list)
    peaks: dict[str, dict[str, float]] = field(default_factory=dict)  # axis -> {"velocity": ...}
    actuators: list[dict[str, Any]] = field(default_factory=list)  # one per actuator
    fastest_cycle: float | None = None  # s, shortest run of this design within the actuator limits
    machine: str | None = None
    product: dict[str, Any] | None = None  # the carried product's acceleration: limit, peak, where
    drives: list[dict[str, Any]] = field(default_factory=list)  # eq. 4.1 per axis: peak torque, where

    @property
    def ok(self) -> bool:
        return not self.findings


def check(traj: Trajectory, machine=None, kinematics=None, per_segment: int = 2001) -> Report:
    """Envelope, meandering and continuity checks; with a machine also the
    workspace (raises MotionError) and actuator limits (findings)."""
    d = traj.design
    rep = Report(machine=getattr(machine, "name", None))
    for a in traj.axes:
        for seg in a.segments:
            t = np.linspace(seg.t0, seg.t1, per_segment)
            f = seg.evaluate(t)
            rep.findings += check_segment(t, f, seg.where, seg.spec.envelope, d.tolerance, _knots(a, seg, f))
            law = L.LAWS.get(seg.spec.law)
            # a dwell and a constant velocity are smooth inside; their joins are judged below
            if law is not None and law.continuity < min(d.continuity, 2) and law.name not in ("dwell", "constant-velocity"):
                rep.findings.append(Finding("smoothness", seg.where, seg.t0,
                                            f"{law.title} has a discontinuous {ORDER_NAMES[law.continuity + 1]} "
                                            f"(infinite jerk: a low-speed law, §2.7.1); use a §2.7.2 law or a polynomial"))
        for left, right in zip(a.segments, a.segments[1:]):
            fl = left.evaluate([left.t1])[:, 0]
            fr = right.evaluate([right.t0])[:, 0]
            for o in range(min(d.continuity, 3) + 1):
                if not np.isfinite(fl[o]) or not np.isfinite(fr[o]) or abs(fl[o] - fr[o]) > 1e-6 * max(1.0, abs(fl[o]), abs(fr[o])):
                    rep.findings.append(Finding("discontinuity", f"axis {a.name} point {left.last_point}", left.t1,
                                                f"{ORDER_NAMES[o]} jumps from {fl[o]:.6g} to {fr[o]:.6g} between segments "
                                                f"{left.number} and {right.number}; give the value at the point or change a law"))
        tt = np.concatenate([np.linspace(s.t0, s.t1, per_segment) for s in a.segments])
        f = a.evaluate(tt)
        fin = np.where(np.isfinite(f), np.abs(f), np.nan)
        rep.peaks[a.name] = {n: float(np.nanmax(fin[k])) if np.isfinite(fin[k]).any() else 0.0
                             for k, n in enumerate(("position", "velocity", "acceleration", "jerk"))}
        rep.peaks[a.name]["jerk_infinite"] = bool(np.isinf(f[3]).any())
    _check_dynamics(traj, rep, per_segment)
    if machine is not None:
        _check_machine(traj, machine, kinematics, rep, per_segment)
    return rep


def _grid(traj: Trajectory, per_segment: int) -> np.ndarray:
    """Sample times over the whole design, dense in every segment of every axis."""
    ends = sorted({traj.t0, traj.t1, *(s.t1 for a in traj.axes for s in a.segments)})
    return np.unique(np.concatenate([np.linspace(a, b, per_segment) for a, b in zip(ends, ends[1:])]))


def _segment_at(a: AxisTrajectory, t: float) -> str:
    seg = next((s for s in a.segments if s.t0 <= t <= s.t1), a.segments[-1])
    return seg.where


def _check_dynamics(traj: Trajectory, rep: Report, per_segment: int) -> None:
    """§4.5.2–4.5.3: the carried product's acceleration limit on the end
    effector (the vector sum over the linear axes) and eq. 4.1's motor
    torque per axis that has a [drive]; the worst time and segment named."""
    d = traj.design
    if d.product_acceleration is None and not d.drives:
        return
    t = _grid(traj, per_segment)
    f = {a.name: a.evaluate(t) for a in traj.axes}
    if d.product_acceleration is not None:
        linear = [a for a in traj.axes if a.unit == "mm"]
        acc = np.sqrt(sum(f[a.name][2] ** 2 for a in linear))
        i = int(np.nanargmax(acc))
        worst = max(linear, key=lambda a: abs(f[a.name][2][i]))
        lim = d.product_acceleration
        rep.product = {"limit": lim, "peak": float(acc[i]), "t": float(t[i]), "where": _segment_at(worst, float(t[i])),
                       "axes": [a.name for a in linear]}
        if acc[i] > lim * (1 + 1e-9):
            rep.findings.append(Finding("product", rep.product["where"], float(t[i]),
                                        f"the product is accelerated at {acc[i]:.4g} mm/s², {acc[i] / lim:.3g}x the "
                                        f"{lim:g} it tolerates (§4.5.3), at t = {t[i]:.4g} s; lengthen this segment or "
                                        "change its conditions"))
    for dr in d.drives:
        a = traj.axis(dr.axis)
        torque = dr.torque(a.unit, f[a.name][1], f[a.name][2])
        i = int(np.nanargmax(np.abs(torque)))
        where = _segment_at(a, float(t[i]))
        rep.drives.append({"axis": a.name, "peak_torque": float(abs(torque[i])), "max_torque": dr.max_torque,
                           "ratio": float(abs(torque[i]) / dr.max_torque), "t": float(t[i]), "where": where})
        if abs(torque[i]) > dr.max_torque * (1 + 1e-9):
            rep.findings.append(Finding("torque", where, float(t[i]),
                                        f"the motor of axis {a.name} must deliver {abs(torque[i]):.4g} N·m (eq. 4.1), "
                                        f"{abs(torque[i]) / dr.max_torque:.3g}x its {dr.max_torque:g} N·m, at t = "
                                        f"{t[i]:.4g} s; lengthen this segment, change it or use a stronger drive"))


def _knots(a: AxisTrajectory, seg: SolvedSegment, f: np.ndarray) -> list:
    """The segment's design points as envelope knots (t, position, given velocity);
    an end that gives no position (matched or carried) takes the curve's."""
    pts = a.points[seg.first_point - 1:seg.last_point]
    knots = []
    for i, p in enumerate(pts):
        pos = p.values.get(0)
        if pos is None and i in (0, len(pts) - 1):
            pos = float(f[0, 0] if i == 0 else f[0, -1])
        knots.append((p.t, pos, p.values.get(1)))
    return knots


def _limits(kin) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(kin, "actuator_limits"):
        try:
            v, a = kin.actuator_limits()
            return np.asarray(v, float), np.asarray(a, float)
        except NotImplementedError:
            pass
    return np.asarray(kin.velocity_limits(), float), np.asarray(kin.acceleration_limits(), float)


def _actuator_derivatives(kin, q, dq, ddq):
    try:
        return kin.derivatives(q, dq, ddq)
    except (AttributeError, NotImplementedError):
        M = np.asarray(kin.linear_map, float).T
        return q @ M, dq @ M, ddq @ M


def _check_machine(traj: Trajectory, machine, kin, rep: Report, per_segment: int) -> None:
    from doodlecam.errors import DoodleError

    d = traj.design
    names = [a.name for a in traj.axes]
    if "x" not in names or "y" not in names:
        raise MotionError(f"{d.source}: the machine check needs axes named x and y (the pen position); this design has "
                          f"{', '.join(names)}")
    if kin is None:
        from doodlecam.registry import kinematics_for

        kin = kinematics_for(machine)
    t = _grid(traj, per_segment)
    fx, fy = traj.axis("x").evaluate(t), traj.axis("y").evaluate(t)
    ox, oy = d.origin
    q = np.column_stack([fx[0] + ox, fy[0] + oy])
    try:
        kin.check_reachable(q)
    except DoodleError as e:
        lo, hi = 0, len(q)  # bisect for the first point it refuses, to name the time
        while hi - lo > 1:
            mid = (lo + hi) // 2
            try:
                kin.check_reachable(q[:mid])
                lo = mid
            except DoodleError:
                hi = mid
        raise MotionError(f"{d.source}: at t = {t[lo]:.4g} s the design leaves the workspace of '{machine.name}' ({e}); "
                          "move it with [motion] origin or change the points") from None
    dq = np.column_stack([fx[1], fy[1]])
    ddq = np.column_stack([fx[2], fy[2]])
    _, th1, th2 = _actuator_derivatives(kin, q, dq, ddq)
    vmax, amax = _limits(kin)
    act_names = list(getattr(kin, "actuator_names", ()) or [f"actuator {i + 1}" for i in range(th1.shape[1])])
    worst = 0.0
    for i in range(th1.shape[1]):
        v, a = np.abs(th1[:, i]), np.abs(th2[:, i])
        iv, ia = int(np.nanargmax(v)), int(np.nanargmax(a))
        rv, ra = float(v[iv] / vmax[i]), float(a[ia] / amax[i])
        rep.actuators.append({"name": act_names[i] if i < len(act_names) else f"actuator {i + 1}",
                              "peak_velocity": float(v[iv]), "velocity_limit": float(vmax[i]), "velocity_ratio": rv,
                              "peak_acceleration": float(a[ia]), "acceleration_limit": float(amax[i]),
                              "acceleration_ratio": ra})
        worst = max(worst, rv, np.sqrt(ra))
        for kind, r, idx, lim in (("velocity", rv, iv, vmax[i]), ("acceleration", ra, ia, amax[i])):
            if r > 1 + 1e-9:
                rep.findings.append(Finding("limit", f"actuator {act_names[i] if i < len(act_names) else i + 1}", float(t[idx]),
                                            f"{kind} {r:.3g}x its limit {lim:g} at t = {t[idx]:.4g} s; slow the design "
                                            f"(--cycle-time) or change it"))
    # velocities scale with 1/k and accelerations with 1/k^2 when the design is stretched k times
    rep.fastest_cycle = (traj.t1 - traj.t0) * worst if worst > 0 else None


# ------------------------------------------------------- per-segment times

LIMIT_KINDS = ("limit", "product", "torque")


def _retimed(design: Design, seg: int, duration: float) -> Design:
    """The design with segment ``seg`` (0-based, shared by every axis) lasting
    ``duration`` s: its via points stretch with it, later points shift; the
    values at the points stay (they are physical: a weld speed is a weld speed)."""
    axes = []
    for a in design.axes:
        ends = [i for i, p in enumerate(a.points) if not p.via]
        i0, i1 = ends[seg], ends[seg + 1]
        t0, t1 = a.points[i0].t, a.points[i1].t
        k = duration / (t1 - t0)
        pts = []
        for i, p in enumerate(a.points):
            if i <= i0:
                t = p.t
            elif i <= i1:
                t = t0 + (p.t - t0) * k
            else:
                t = p.t + duration - (t1 - t0)
            pts.append(DesignPoint(p.index, t, p.values, p.match, p.via))
        axes.append(AxisDesign(a.name, tuple(pts), a.segments, a.unit))
    return Design(**{**design.__dict__, "axes": tuple(axes)})


def _within_limits(design: Design, machine, kinematics, per_segment: int) -> bool:
    try:
        rep = check(solve_design(design), machine, kinematics, per_segment)
    except MotionError:
        return False
    return not any(f.kind in LIMIT_KINDS for f in rep.findings)


def segment_times(design: Design, machine=None, kinematics=None, per_segment: int = 401,
                  span: float = 20.0, steps: int = 32, tol: float = 1e-3) -> tuple[list[dict[str, Any]], Design]:
    """Shortest duration of every segment that keeps every limit (§4.5: the
    actuators through the machine, the product's acceleration, eq. 4.1's
    torque), segment after segment, each with the ones before already
    shortened; dwells keep their (process) time.

    For each segment the durations from T/``span`` to T·``span`` are scanned
    on a geometric grid and the first that keeps the limits is refined by
    bisection against the one below it to ``tol`` (relative). Returns one
    row per segment and the re-timed design.
    """
    d = design
    ends = [[p.t for p in a.points if not p.via] for a in d.axes]
    if any(len(e) != len(ends[0]) or not np.allclose(e, ends[0]) for e in ends):
        raise MotionError(f"{d.source}: per-segment times need axes whose segments share their design-point times "
                          "(input = \"xy\", or the same times on every axis)")
    if machine is None and d.product_acceleration is None and not d.drives:
        raise MotionError(f"{d.source}: per-segment times need limits: a machine (-m), [motion] product_acceleration "
                          "or [drive.AXIS] tables")
    if kinematics is None and machine is not None:
        from doodlecam.registry import kinematics_for

        kinematics = kinematics_for(machine)
    rows = []
    for s in range(len(ends[0]) - 1):
        T = ends[0][s + 1] - ends[0][s]
        laws = {a.segments[s].law for a in d.axes}
        row: dict[str, Any] = {"segment": s + 1, "points": [d.axes[0].points[i].index for i, p in enumerate(d.axes[0].points)
                                                             if not p.via][s:s + 2],
                               "laws": sorted(laws), "design_s": T, "shortest_s": None}
        if laws == {"dwell"}:
            row["shortest_s"], row["note"] = T, "dwell: process time kept"
            rows.append(row)
            continue
        ok = lambda dur: _within_limits(_retimed(d, s, dur), machine, kinematics, per_segment)  # noqa: E731
        grid = T * np.geomspace(1 / span, span, steps)
        first = next((i for i, g in enumerate(grid) if ok(g)), None)
        if first is None:
            row["note"] = f"no duration from {grid[0]:.4g} to {grid[-1]:.4g} s keeps the limits (its points' own values exceed them)"
            rows.append(row)
            continue
        hi = float(grid[first])
        if first > 0:
            lo = float(grid[first - 1])
            while hi - lo > tol * hi:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if ok(mid) else (mid, hi)
        row["shortest_s"] = hi
        d = _retimed(d, s, hi)
        rows.append(row)
    return rows, d
