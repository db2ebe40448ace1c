"""Plain data passed between the stages. Units: millimetres and seconds.

Every stage takes one of these and returns the next; nothing reaches back.
Arrays are float64 NumPy arrays and are not mutated after construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import Any

import numpy as np


def _frozen(a, shape_tail=None) -> np.ndarray:
    arr = np.array(a, dtype=float)  # a private copy
    if shape_tail is not None and (arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail):
        raise ValueError(f"expected shape (n, {', '.join(map(str, shape_tail))}), got {arr.shape}")
    arr.setflags(write=False)
    return arr


def _handed(new, fields: dict):
    """``new`` (an instance made with object.__new__) given ``fields`` as they are, the arrays among
    them made read-only in place: the constructors that take arrays their caller has just made
    and hands over (never keeps or writes again), without __post_init__'s copies (a planned job
    of 10^4 strokes made ~3 x 10^5 of them). The arrays must be what _frozen would make: float64,
    C-contiguous, of the right shape."""
    for k, v in fields.items():
        if type(v) is np.ndarray:
            v.setflags(write=False)  # (half the time of setting v.flags.writeable)
        object.__setattr__(new, k, v)
    return new


def polyline_length(p: np.ndarray) -> float:
    """Length of an (n, 2) polyline."""
    if len(p) < 2:
        return 0.0
    return float(np.hypot(*np.diff(p, axis=0).T).sum())


SAME_POINT = 1e-6  # mm: a travel shorter than this joins two strokes pen down (Job.lifts)

_GAUSS8 = np.polynomial.legendre.leggauss(8)  # nodes, weights (computing them costs 0.6 ms)

@dataclass(frozen=True)
class Drawing:
    """Pen-down polylines, each an (n, 2) array, in ``units`` ("px" or "mm").

    Image tracers return pixel coordinates with ``y_down=True`` (row axis
    points down); the layout stage turns any drawing into machine millimetres
    with y up.
    """

    polylines: tuple[np.ndarray, ...]
    units: str = "mm"
    y_down: bool = False
    source: str = ""
    extent: tuple[float, float] | None = None  # source canvas (width, height) in units
    meta: dict[str, Any] = field(default_factory=dict)
    # the layer (pen) of each polyline, e.g. an Inkscape or DXF layer; empty: all on one layer
    layers: tuple[str, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "polylines", tuple(_frozen(p, (2,)) for p in self.polylines))
        object.__setattr__(self, "layers", tuple(str(n) for n in self.layers))
        if self.layers and len(self.layers) != len(self.polylines):
            raise ValueError(f"Drawing: {len(self.layers)} layer names for {len(self.polylines)} polylines")

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of all points; zeros when empty."""
        if not self.polylines:
            return (0.0, 0.0, 0.0, 0.0)
        pts = np.concatenate(self.polylines)
        return (*pts.min(axis=0), *pts.max(axis=0))

    @property
    def length(self) -> float:
        return sum(polyline_length(p) for p in self.polylines)


@lru_cache(maxsize=None)
def _eval():
    """geometry.kernels.bspline_eval, imported on first use (numba's import is slow)."""
    from doodlecam.geometry.kernels import bspline_eval

    return bspline_eval


@dataclass(frozen=True)
class _KnotTable:
    """What every clamped uniform spline with the same number of control points and degree
    shares (not to be written to; writeable, as the compiled kernels they are passed to
    were compiled for): knots, breakpoints, the knot steps each derivative's controls are
    divided by ((m, 1) each), and the Gauss points and half-widths of Spline.length."""

    knots: np.ndarray
    breakpoints: np.ndarray
    steps: tuple[np.ndarray, ...]
    gauss_u: np.ndarray
    gauss_half: np.ndarray
    gauss_shape: tuple[int, int]


@lru_cache(maxsize=4096)
def _knot_table(n_control: int, degree: int) -> _KnotTable:
    t = Spline.uniform_knots(n_control, degree)
    bp = np.unique(t)
    steps, tt, k = [], t, degree
    for _ in range(degree):
        steps.append((tt[k + 1 : -1] - tt[1 : -k - 1])[:, None])
        tt, k = tt[1:-1], k - 1
    x, _ = _GAUSS8
    lo, hi = bp[:-1, None], bp[1:, None]
    u = (lo + hi) / 2 + (hi - lo) / 2 * x
    return _KnotTable(t, bp, tuple(steps), u.ravel(), (hi - lo) / 2, u.shape)


@dataclass(frozen=True)
class Spline:
    """A clamped uniform B-spline q(u), u in [0, 1], in millimetres.

    The knot vector is implied (the report's URBS): ``degree + 1`` knots at 0
    and at 1, and the interior knots evenly spaced, so the control points
    alone define the curve.
    """

    degree: int
    control: np.ndarray  # (n, 2), n >= degree + 1

    def __post_init__(self):
        object.__setattr__(self, "control", _frozen(self.control, (2,)))
        if len(self.control) < self.degree + 1:
            raise ValueError("a B-spline needs at least degree + 1 control points")

    @staticmethod
    def uniform_knots(n_control: int, degree: int) -> np.ndarray:
        inner = np.linspace(0.0, 1.0, n_control - degree + 1)
        return np.concatenate([np.zeros(degree), inner, np.ones(degree)])

    @cached_property
    def knots(self) -> np.ndarray:
        return _knot_table(len(self.control), self.degree).knots

    @cached_property
    def breakpoints(self) -> np.ndarray:
        """Distinct knots: the curve is one polynomial between neighbours."""
        return _knot_table(len(self.control), self.degree).breakpoints

    @cached_property
    def derivative_controls(self) -> list[np.ndarray]:
        """Control points of q, q', ..., q^(degree): each a clamped uniform spline
        over the same knot spans, one degree lower than the last."""
        return self._levels()

    def _levels(self, top: int | None = None) -> list[np.ndarray]:
        """derivative_controls up to q^(top) (all by default)."""
        c, k = np.ascontiguousarray(self.control), self.degree
        out = [c]
        for den in _knot_table(len(self.control), self.degree).steps[:top]:
            c = k * (c[1:] - c[:-1]) / den
            k -= 1
            out.append(c)
        return out

    def controls_of(self, der: int) -> np.ndarray:
        """The control points of q^(der) (derivative_controls[der]), without caching them once
        ``forget_derivatives`` was called."""
        if der == 0:
            return self.control
        if self.__dict__.get("_forgotten"):
            return self._levels(der)[der]
        return self.derivative_controls[der]

    def forget_derivatives(self) -> None:
        """Drop the cached derivative controls and make them on demand from here, unkept: a
        planned job of 10^5 strokes is written from the curves (and their first derivative at a
        few points), and the cached controls hold ~1 KB a stroke."""
        self.__dict__.pop("derivative_controls", None)
        self.__dict__["_forgotten"] = True

    @cached_property
    def straight(self) -> bool:
        """A segment run at constant speed in u (q'' = 0, as a fitted line is): q(u) = start + u (end - start)."""
        d = self.derivative_controls
        if self.degree < 2:
            return len(self.control) == 2
        scale = float(np.abs(d[1][0]).max())
        return scale > 1e-9 and float(np.abs(d[2]).max()) <= 1e-9 * scale

    def __call__(self, u, der: int = 0) -> np.ndarray:
        """q^(der)(u) for u in [0, 1]; shape (len(u), 2). Units mm / u^der."""
        u = np.asarray(u, dtype=float)
        if der > self.degree:
            return np.zeros(u.shape + (2,))
        out = np.empty((u.size, 2))
        nseg = len(self.control) - self.degree
        _eval()(self.controls_of(der), self.degree - der, nseg, u.reshape(-1), out)  # clipped to [0, 1] there
        return out.reshape(u.shape + (2,))

    @cached_property
    def length(self) -> float:
        """Arc length in mm (Gauss-Legendre per knot span; exact to ~1e-9 rel)."""
        g = _knot_table(len(self.control), self.degree)
        speed = np.linalg.norm(self(g.gauss_u, 1), axis=1).reshape(g.gauss_shape)
        return float((g.gauss_half * speed * _GAUSS8[1]).sum())

    @property
    def start(self) -> np.ndarray:
        return self.control[0]

    @property
    def end(self) -> np.ndarray:
        return self.control[-1]

    def reversed(self) -> "Spline":
        return Spline(self.degree, self.control[::-1])


@dataclass(frozen=True)
class Profile:
    """A feed profile along one spline on the grid u_0 < ... < u_N.

    ``b[k]`` is u-dot squared at u_k (1/s^2), ``a[k]`` is the constant u-ddot on
    [u_k, u_k+1] (1/s^2), ``t[k]`` the time (s) at which u_k is reached. Between
    grid points b is linear in u, so u(t) is a quadratic on each interval.
    """

    u: np.ndarray
    b: np.ndarray
    a: np.ndarray
    t: np.ndarray
    solver: str = ""

    def __post_init__(self):
        for name in ("u", "b", "a", "t"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))

    @classmethod
    def handed(cls, u: np.ndarray, b: np.ndarray, a: np.ndarray, t: np.ndarray, solver: str = "") -> "Profile":
        """Profile(u, b, a, t, solver) of fresh float64 C-contiguous arrays the caller hands over
        (made read-only in place, not copied; the planner's own results)."""
        return _handed(object.__new__(cls), {"u": u, "b": b, "a": a, "t": t, "solver": solver})

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def state_at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, u-dot, u-ddot) at times ``t`` (s), exact for this profile."""
        # np.clip's values bit for bit (signed zeros and NaN too), without its Python wrapper
        t = np.minimum(self.t[-1], np.maximum(0.0, np.asarray(t, dtype=float)))
        k = np.minimum(len(self.a) - 1, np.maximum(0, np.searchsorted(self.t, t, side="right") - 1))
        tau = t - self.t[k]
        v0 = np.sqrt(np.maximum(self.b[k], 0.0))
        a = self.a[k]
        ud = np.maximum(v0 + a * tau, 0.0)
        u = np.minimum(self.u[k] + v0 * tau + 0.5 * a * tau * tau, self.u[k + 1])
        # a: a fresh array already where t is one (fancy indexing copies)
        return u, ud, a if isinstance(a, np.ndarray) and a.shape == u.shape else np.broadcast_to(a, u.shape).copy()


@dataclass(frozen=True)
class Stroke:
    """One spline drawn pen-down in one motion, from rest to rest."""

    spline: Spline
    profile: Profile | None = None
    source_index: int = -1  # index of the polyline it was fitted to
    fit_error: float = 0.0  # largest deviation from that polyline, mm
    layer: str = ""  # the drawing's layer (pen) it belongs to

    @property
    def duration(self) -> float:
        return self.profile.duration if self.profile is not None else 0.0

    def with_profile(self, profile: Profile | None) -> "Stroke":
        """This stroke planned with ``profile``: dataclasses.replace(self, profile=profile), without
        its walk over the fields (the planner makes one per stroke, 10^4-10^5 per job)."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        new.__dict__["profile"] = profile
        return new


@dataclass(frozen=True)
class Travel:
    """A pen-up move between two points (mm), rest to rest."""

    start: np.ndarray
    end: np.ndarray
    duration: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "start", _frozen(self.start))
        object.__setattr__(self, "end", _frozen(self.end))

    @classmethod
    def handed(cls, start: np.ndarray, end: np.ndarray, duration: float = 0.0) -> "Travel":
        """Travel(start, end, duration) of fresh float64 (2,) arrays the caller hands over (made read-only
        in place, not copied; plan.travel.make_travels' rows of the array it made)."""
        return _handed(object.__new__(cls), {"start": start, "end": end, "duration": duration})

    @cached_property  # the studio's summaries ask every travel of a 10^4-stroke job after each edit
    def length(self) -> float:
        return float(np.hypot(*(self.end - self.start)))


@dataclass(frozen=True)
class StrokeSamples:
    """Velocity targets (mm/s) at t = dT, 2 dT, ..., M dT after the stroke starts.

    The machine ramps its velocity linearly from one target to the next over
    each period dT (the report's PLC, section 2.1.0.5), starting from rest at
    ``start``. The last target is zero: every stroke ends at rest.
    """

    start: np.ndarray
    velocity: np.ndarray  # (M, 2)
    delta_time: float
    time_scale: float = 1.0  # plan time per executed time (< 1 when slowed to whole periods)
    sample_u: np.ndarray | None = None  # curve parameter each instant t = 0, dT, ... tracks

    def __post_init__(self):
        object.__setattr__(self, "start", _frozen(self.start))
        object.__setattr__(self, "velocity", _frozen(self.velocity, (2,)))

    @classmethod
    def handed(cls, start: np.ndarray, velocity: np.ndarray, delta_time: float, time_scale: float = 1.0,
               sample_u: np.ndarray | None = None) -> "StrokeSamples":
        """StrokeSamples(...) of fresh float64 C-contiguous arrays the caller hands over: start (2,) and
        velocity (M, 2) made read-only in place, not copied (the sampler's own results); sample_u kept
        as given, as the constructor keeps it."""
        return _handed(object.__new__(cls), {"start": start, "velocity": velocity, "delta_time": delta_time,
                                             "time_scale": time_scale, "sample_u": sample_u})

    def integrate(self) -> np.ndarray:
        """Positions (M + 1, 2) the ramping machine reaches at t = 0, dT, ..."""
        v = np.vstack([np.zeros((1, 2)), self.velocity])
        steps = 0.5 * self.delta_time * (v[1:] + v[:-1])
        return self.start + np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])


@dataclass(frozen=True)
class Job:
    """The planned job: ordered strokes, the travels around them, samples.

    ``travels[i]`` leads to ``strokes[i]``; the last travel returns home, so
    ``len(travels) == len(strokes) + 1``. Times in seconds, lengths in mm.
    """

    machine: Any  # doodlecam.machine.Machine
    strokes: tuple[Stroke, ...]
    travels: tuple[Travel, ...]
    samples: tuple[StrokeSamples, ...] = ()
    source: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    @cached_property  # strokes, travels and samples never change: the studio asks often
    def pen_down_length(self) -> float:
        return sum(s.spline.length for s in self.strokes)

    @cached_property  # strokes, travels and samples never change: the studio asks often
    def layers(self) -> tuple[str, ...]:
        """The layers in the order they are plotted (one pen each)."""
        return tuple(dict.fromkeys(s.layer for s in self.strokes))

    @property
    def layer_pens(self) -> dict[str, int]:
        """Layer -> pen number (1-based), in plotting order: as planned (``meta["layer_pens"]``, chosen
        in the drawing's order of layers), else the machine's assignment of layers to its [[pen]]s,
        else one pen per layer."""
        planned = self.meta.get("layer_pens") or {}
        if all(n in planned for n in self.layers):
            return {n: int(planned[n]) for n in self.layers}
        assign = getattr(self.machine, "pen_assignment", None)
        return (assign(self.layers, self.meta.get("layer_colours")) if assign
                else {n: k for k, n in enumerate(self.layers, 1)})

    @property
    def pen_numbers(self) -> tuple[int, ...]:
        """The pen (1-based number) of every stroke."""
        table = self.layer_pens
        return tuple(table[s.layer] for s in self.strokes)

    @property
    def pen_changes(self) -> tuple[int, ...]:
        """Indices i of the strokes before which the pen is changed: where the pen number
        changes, at a layer boundary (the job pauses there, pen up, for the operator)."""
        p = self.pen_numbers
        return tuple(i for i in range(1, len(p)) if p[i] != p[i - 1])

    @property
    def pen_pauses(self) -> tuple[int, ...]:
        """Indices i of the strokes before which the job pauses, pen up, for the operator to fit
        a pen: every pen change, and before the first stroke when the machine has more than one
        [[pen]] (nobody knows which one is in the holder). Posts and links pause here."""
        first = (0,) if self.strokes and len(getattr(self.machine, "pens", ())) > 1 else ()
        return first + self.pen_changes

    @cached_property  # strokes, travels and samples never change: the studio asks often
    def lifts(self) -> tuple[bool, ...]:
        """lifts[i]: the pen travels pen-up to strokes[i] and is lowered there.

        False where strokes[i] starts exactly where strokes[i - 1] ended (its
        travel is shorter than ``SAME_POINT`` mm, as between the pieces of a
        split outline) on the same layer: the pen stays down, no up/down delays,
        no travel move. The first stroke and every pen change always lift. Every
        post and link that emits pen up/down follows this one predicate.
        """
        return tuple(map(self._lift, range(len(self.strokes))))

    def _lift(self, i: int) -> bool:
        """lifts[i], for one stroke."""
        return i == 0 or self.strokes[i].layer != self.strokes[i - 1].layer or self.travels[i].length >= SAME_POINT

    @property
    def pen_lifts(self) -> int:
        """How many times the pen is lowered (and lifted again) in the job."""
        return sum(self.lifts)

    @cached_property  # strokes, travels and samples never change: the studio asks often
    def travel_length(self) -> float:
        return sum(t.length for t in self.travels)

    @cached_property  # strokes, travels and samples never change: the studio asks often
    def draw_time(self) -> float:
        """Pen-down time as executed: whole sample periods once sampled."""
        if self.samples:
            return sum(len(s.velocity) * s.delta_time for s in self.samples)
        return sum(s.duration for s in self.strokes)

    @cached_property  # strokes, travels and samples never change: the studio asks often
    def travel_time(self) -> float:
        """Pen-up time: every travel's (s)."""
        return sum(t.duration for t in self.travels)

    @cached_property  # strokes, travels and samples never change: the studio asks often
    def pen_delays(self) -> float:
        """The pen's down and up delays of every lift, each with its pen's (s)."""
        pens = [self._pen(k) for k in self.pen_numbers] if self.strokes else []  # each lift with its pen's delays
        return sum(p.down_delay + p.up_delay for p, lift in zip(pens, self.lifts) if lift)

    def _pen(self, k: int):
        """Pen number k's settings ([[pen]]; the machine's one [pen] without pen_number)."""
        number = getattr(self.machine, "pen_number", None)
        return number(k) if number else self.machine.pen

    @property
    def duration(self) -> float:
        """Planned job time: strokes, travels and pen up/down delays (one pair per lift)."""
        return self.draw_time + self.travel_time + self.pen_delays

    def replacing(self, strokes: dict[int, tuple[Stroke, StrokeSamples]], travels: dict[int, Travel],
                  meta: dict[str, Any]) -> "Job":
        """This job with the strokes (and their samples) and the travels at these positions replaced, on the
        same layers, and ``meta``. The totals it already knows (lengths, times, lifts) are carried over by
        the differences, so an edit of one stroke of 10^5 (the studio) costs what that stroke costs; they
        may differ from a fresh sum over every stroke in the last bits."""
        if any(st.layer != self.strokes[i].layer for i, (st, _) in strokes.items()):
            raise ValueError("Job.replacing keeps each stroke's layer")
        st, sa, tr = list(self.strokes), list(self.samples), list(self.travels)
        for i, (s, m) in strokes.items():
            st[i] = s
            if sa:
                sa[i] = m
        for i, t in travels.items():
            tr[i] = t
        new = Job(self.machine, tuple(st), tuple(tr), tuple(sa), self.source, meta)
        known, d = self.__dict__, new.__dict__

        def carried(name: str, where, delta) -> None:  # the old total plus the differences at ``where``
            if name in known:
                d[name] = known[name] + sum(delta(i) for i in sorted(where))

        carried("pen_down_length", strokes, lambda i: new.strokes[i].spline.length - self.strokes[i].spline.length)
        if sa:
            carried("draw_time", strokes, lambda i: len(new.samples[i].velocity) * new.samples[i].delta_time
                    - len(self.samples[i].velocity) * self.samples[i].delta_time)
        else:
            carried("draw_time", strokes, lambda i: new.strokes[i].duration - self.strokes[i].duration)
        carried("travel_length", travels, lambda i: new.travels[i].length - self.travels[i].length)
        carried("travel_time", travels, lambda i: new.travels[i].duration - self.travels[i].duration)
        if "layers" in known:
            d["layers"] = known["layers"]
        if "lifts" in known:  # a lift depends on the travel into its stroke (the layers are kept)
            moved = [i for i in travels if i < len(st)]
            lifts = list(known["lifts"])
            for i in moved:
                lifts[i] = new._lift(i)
            d["lifts"] = tuple(lifts)
            if "pen_delays" in known:
                pens = self.layer_pens

                def delay(i: int) -> float:
                    p = self._pen(pens[st[i].layer])
                    return (p.down_delay + p.up_delay) * (d["lifts"][i] - known["lifts"][i])

                carried("pen_delays", moved, delay)
        return new


def prime_splines(splines, lengths: bool = False) -> None:
    """Fill the cached derivative controls and ``straight`` (and with ``lengths`` the
    length) of many splines at once, the same values each would compute: splines of
    one shape (number of control points, degree) in one numpy pass, not ~10 small
    calls each (a generated drawing's 10^4 strokes come in a few dozen shapes)."""
    groups: dict[tuple[int, int], list[Spline]] = {}
    for s in splines:
        if "derivative_controls" not in s.__dict__ or (lengths and "length" not in s.__dict__):
            groups.setdefault((len(s.control), s.degree), []).append(s)
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite strokes: planning says what is wrong
        for (n, degree), group in groups.items():
            _prime_group(_knot_table(n, degree), n, degree, group, lengths)


def _prime_group(g: _KnotTable, n: int, degree: int, group: list, lengths: bool) -> None:
    """prime_splines for splines of one shape: each level of derivative controls of the whole
    group in one step (the same divisions as Spline.derivative_controls)."""
    levels = [np.stack([s.control for s in group])]
    k = degree
    for den in g.steps:
        levels.append(k * (levels[-1][:, 1:] - levels[-1][:, :-1]) / den)
        k -= 1
    if degree >= 2:
        scale = np.abs(levels[1][:, 0]).max(axis=1)
        flat = (scale > 1e-9) & (np.abs(levels[2]).reshape(len(group), -1).max(axis=1) <= 1e-9 * scale)
    else:
        flat = np.full(len(group), n == 2)
    # each spline's rows of the levels (the views c[i] of each level) and flag, walked together
    rows = zip(*levels[1:]) if degree >= 1 else iter(lambda: (), None)
    for s, straight, der in zip(group, flat.tolist(), rows):
        d = s.__dict__
        if "derivative_controls" not in d:
            d["derivative_controls"] = [s.control, *der]
            d["straight"] = straight
            d["breakpoints"] = g.breakpoints  # (the planner's: shared by the shape)
    if lengths and degree >= 1:
        ev, u = _eval(), g.gauss_u
        speed = np.empty((len(group), len(u), 2))
        for i in range(len(group)):
            ev(levels[1][i], degree - 1, n - degree, u, speed[i])
        speed = np.linalg.norm(speed.reshape(-1, 2), axis=1).reshape(len(group), *g.gauss_shape)
        total = (g.gauss_half * speed * _GAUSS8[1]).reshape(len(group), -1).sum(axis=1)
        for s, length in zip(group, total.tolist()):
            s.__dict__.setdefault("length", length)
