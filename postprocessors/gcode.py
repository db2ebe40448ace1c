"""G-code post-processor for pen plotters: GRBL, Marlin and LinuxCNC dialects.

Each stroke becomes G1 segments along its spline, every chord within
``chord_tolerance`` of it, in one of two modes (``feeds``):

* ``cap`` (default): the longest chords within the tolerance (or within
  2^(-k/4) of it), their vertices on the motor-step positions that make
  GRBL's step-rounded chords turn smoothly, all at the pen-speed cap; the
  firmware's planner sets the speeds. Per stroke the polyline that
  ``doodlecam.link.grbl.timing`` (GRBL 1.1's planner) runs fastest is
  written, among those a serial line at ``baud`` can feed.
* ``plan``: segment ends at the planned sample instants, split further until
  every chord is within the tolerance; each feed is the chord over the
  planned time between its ends, so a controller that follows F reproduces
  the time-optimal profile and its true acceleration limits on curves.

No segment is shorter than one motor step (GRBL drops those) and no F is
above the pen-speed cap. The GRBL header states the model's job time and the
``$`` settings it assumes.

Dialects (``dialect``; every line stays within the firmware's line limit):

* ``grbl`` — GRBL 1.1 (79 characters: its 80-byte line buffer holds a NUL).
  Pen by servo on the spindle PWM (``M3 S0`` / ``M3 S1000``) or by Z.
  Every M3 with a new S empties GRBL's planner outside laser mode, so the
  settle dwell ``G4 P<s>`` costs nothing extra.
* ``marlin`` — Marlin 2 (95 characters: MAX_CMD_SIZE 96). Pen by servo
  ``M280 P0 S<angle>`` or by Z; ``G4 P`` is in milliseconds; no G94/G17.
* ``linuxcnc`` — LinuxCNC (255 characters). Pen by Z by default; ``G64 P``
  sets the path-blending tolerance to the chord tolerance.

A built-in post is written exactly like a third-party one; see docs/plugins.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from doodlecam.api import Option, PostProcessor
from doodlecam.errors import OutputError, PluginError
from doodlecam.geometry.chord_batch import cap_candidates, dense_points, serial_keeps_up
from doodlecam.geometry.chords import chord_ok, one_step_apart
from doodlecam.geometry.spline_batch import controls_many, eval_many, offsets

CAP_LEVELS = 24  # chord tolerances for feeds = cap: tol, tol/2^(1/4), ... (down to MIN_LEVEL_STEPS)
CHORD_LEVEL = 2 ** -0.25
MIN_LEVEL_STEPS = 0.15  # the finest level's tolerance, in motor steps
START_LEVEL_STEPS = 0.3  # the level the search starts from, in motor steps
CAP_CHUNK = 4000  # feeds = cap: curved strokes searched together (memory, not the chords: each search is its own)
G1_CHUNK = 2000  # strokes whose G1 lines are formatted together (memory: a line's string lives until its stroke's is joined)
_ENDS = np.array([0.0, 1.0])  # a straight stroke's chord: its ends
MAX_LINE = 79  # GRBL's line buffer is 80 bytes including the terminating NUL


@dataclass(frozen=True)
class Dialect:
    name: str
    max_line: int  # characters per line, without the newline
    pen: str  # default pen mechanism: "servo" or "z"
    servo_up: str
    servo_down: str
    dwell_ms: bool  # G4 P in milliseconds (Marlin) rather than seconds
    preamble: tuple[str, ...]
    program_end: str
    firmware: str


DIALECTS = {
    "grbl": Dialect("grbl", MAX_LINE, "servo", "M3 S0", "M3 S1000", False, ("G21 G90 G94", "G17"), "M2", "GRBL 1.1"),
    "marlin": Dialect("marlin", 95, "servo", "M280 P0 S90", "M280 P0 S0", True, ("G21", "G90"), "M84", "Marlin 2"),
    "linuxcnc": Dialect("linuxcnc", 255, "z", "M3 S0", "M3 S1000", False, ("G21 G90 G94", "G17"), "M2", "LinuxCNC 2.9"),
}


def _num(v: float, decimals: int = 3) -> str:
    s = f"{v:.{decimals}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "", "-") else s


_TRAILING_ZEROS = re.compile(r"0+(?=\n)")
_BARE_POINT = re.compile(r"\.(?=\n)")
_MINUS_ZERO = re.compile(r"^-0$", re.M)


def _nums(values: np.ndarray) -> list[str]:
    """[_num(v) for v in values] (3 decimals), in one format call and three substitutions over all of them
    rather than a format and two strips each: "%.3f" always prints a point, so stripping the zeros before each
    line end and then a bare point is what rstrip("0").rstrip(".") does to each."""
    if not len(values):
        return []
    text = ("%.3f\n" * len(values)) % tuple(values.tolist())
    text = _MINUS_ZERO.sub("0", _BARE_POINT.sub("", _TRAILING_ZEROS.sub("", text)))
    return text.split("\n")[:-1]


def _t_of_u(profile, u: np.ndarray) -> np.ndarray:
    """Planned time (s) at which the profile reaches each u (exact: b is linear in u)."""
    k = np.clip(np.searchsorted(profile.u, u, side="right") - 1, 0, len(profile.u) - 2)
    du = u - profile.u[k]
    span = profile.u[k + 1] - profile.u[k]
    b0 = np.maximum(profile.b[k], 0.0)
    b = np.maximum(b0 + (profile.b[k + 1] - b0) * du / span, 0.0)
    denom = np.sqrt(b0) + np.sqrt(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = np.where(denom > 0, 2.0 * du / denom, 0.0)
    return profile.t[k] + dt


def _refine(spline, u: np.ndarray, tol: float, max_rounds: int = 30) -> np.ndarray:
    """Split segments at their middle until every chord is within ``tol`` of the spline."""
    f = np.linspace(0.0, 1.0, 9)[1:-1]  # interior probes per segment
    for _ in range(max_rounds):
        p = spline(u)
        a, d = p[:-1], p[1:] - p[:-1]
        uu = u[:-1, None] + (u[1:] - u[:-1])[:, None] * f
        q = spline(uu.ravel()).reshape(len(uu), len(f), 2)
        dd = np.maximum((d * d).sum(1), 1e-300)[:, None]
        s = np.clip(((q - a[:, None]) * d[:, None]).sum(2) / dd, 0.0, 1.0)
        err = np.linalg.norm(q - (a[:, None] + s[..., None] * d[:, None]), axis=2).max(1)
        bad = err > tol
        if not bad.any():
            break
        u = np.sort(np.concatenate([u, 0.5 * (u[:-1] + u[1:])[bad]]))
    return u


def _furthest(ok, lo: int, n: int, step: int) -> int:
    """The largest j < n with ok(j), searching up from lo (ok) by doubling steps, then bisecting."""
    while lo + step < n and ok(lo + step):
        lo += step
        step *= 2
    hi = min(lo + step, n)  # ok(lo), not ok(hi) (or hi = n)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo


def _chord_ok(q: np.ndarray, i: int, j: int, tol2: float) -> bool:
    return chord_ok(q, i, j, tol2)


MAX_ARC_RADIUS = 2000.0  # mm: flatter pieces are chords
MAX_ARC_SWEEP = 1.9 * np.pi


def _arc_fit(q: np.ndarray, i: int, j: int, tol: float):
    """The circle through q[i], q[mid], q[j] if every q[i..j] lies within ``tol`` of it, in one turning
    direction: (centre, clockwise), else None."""
    if j - i < 2:
        return None
    a = q[i]
    b, c = q[(i + j) // 2] - a, q[j] - a
    d = 2.0 * (b[0] * c[1] - b[1] * c[0])
    if abs(d) < 1e-12:
        return None
    bb, cc = b @ b, c @ c
    centre = a + np.array([c[1] * bb - b[1] * cc, b[0] * cc - c[0] * bb]) / d
    r = float(np.hypot(*(a - centre)))
    if r > MAX_ARC_RADIUS:
        return None
    rel = q[i:j + 1] - centre
    if np.abs(np.hypot(rel[:, 0], rel[:, 1]) - r).max() > tol:
        return None
    inc = np.diff(np.unwrap(np.arctan2(rel[:, 1], rel[:, 0])))
    if not ((inc > 0).all() or (inc < 0).all()) or abs(inc.sum()) > MAX_ARC_SWEEP:
        return None
    return centre, bool(inc[0] < 0)


def _greedy_arcs(q: np.ndarray, tol: float) -> tuple[np.ndarray, dict[int, tuple]]:
    """Vertices through q like geometry.chords.greedy_chords, but a piece that a circular arc within ``tol``
    covers at least twice as far as the longest chord becomes that arc: (indices, {segment k: (centre, clockwise)})."""
    n, tol2 = len(q), tol * tol
    out, arcs = [0], {}
    i = 0
    while i < n - 1:
        jc = _furthest(lambda j: _chord_ok(q, i, j, tol2), i + 1, n, 1)
        ja = _furthest(lambda j: _arc_fit(q, i, j, tol) is not None, i + 2, n, 1) if i + 2 < n and \
            _arc_fit(q, i, i + 2, tol) is not None else i
        if ja - i >= 2 * (jc - i) and ja > jc:
            if np.hypot(*(q[-1] - q[ja])) < 0.5 and _arc_fit(q, i, n - 1, tol) is not None:
                ja = n - 1  # no sliver of a segment after the arc
            arcs[len(out) - 1] = _arc_fit(q, i, ja, tol)
            i = ja
        else:
            i = jc
        out.append(i)
    return np.asarray(out), arcs


def _one_step_apart(p: np.ndarray, steps_per_mm: np.ndarray) -> np.ndarray:
    """Keep-mask of points (n, 2) that move at least one motor step from the previous kept one.

    GRBL drops a block whose target rounds to the same steps (so no F word of it
    means anything); the last point is always kept, in place of the one before.
    """
    st = np.round(p * steps_per_mm).astype(np.int64)
    keep = one_step_apart(st) if len(p) else np.ones(0, bool)  # compares with the last point kept
    if len(p) > 1 and not keep[-1]:
        j = np.flatnonzero(keep)[-1]
        if j > 0:
            keep[j] = False
            keep[-1] = True
        # else: the whole stroke is within one step of its start: no move at all (the pen makes a dot)
    return keep


def pause_lines(d: Dialect, message: str) -> list[str]:
    """A program pause (M0) that tells the operator ``message``: in a comment on GRBL's line (the
    streamer shows it: doodlecam.link.grbl.streamer.pen_change_message), as M0's text on Marlin
    (its display), as a (MSG, ...) line before M0 on LinuxCNC. Parentheses become brackets:
    a G-code comment cannot hold them."""
    text = "".join(c if c.isascii() and c.isprintable() else "?" for c in message)
    text = text.replace("(", "[").replace(")", "]").replace(";", ",")
    if d.name == "marlin":
        return [f"M0 {text}"[:d.max_line]]
    if d.name == "linuxcnc":
        return [f"(MSG, {text})"[:d.max_line - 1].rstrip(")") + ")", "M0"]
    return [f"M0 ({text[:d.max_line - 6]})"]


def _pen_cap(machine, number: int, max_feed: float) -> float:
    """The feed cap (mm/min) for pen ``number`` of the machine (its own max_speed when [[pen]] gives one)."""
    from dataclasses import replace

    pen = machine.pen_number(number)
    cap = pen_feed_cap(replace(machine, pen=pen), max_feed)
    return min(cap, 60.0 * pen.max_speed) if machine.pens and pen.max_speed else cap


def pen_feed_cap(machine, max_feed: float = 0.0) -> float:
    """The fastest pen-down feed (mm/min): ``max_feed`` if given, else the pen-speed cap, else the slower axis."""
    v = min(machine.x.max_velocity, machine.y.max_velocity)
    if machine.pen.max_speed:
        v = min(v, machine.pen.max_speed)
    return float(max_feed) if max_feed > 0 else 60.0 * v


def _expand_arcs(p: np.ndarray, arcs: dict, arc_tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """The blocks GRBL plans for a polyline with arcs: their end points (start first) and the bytes of the line
    each block comes from (all on an arc's first block)."""
    from doodlecam.link.grbl.timing import arc_points

    pts, nbytes = [p[:1]], []
    for k in range(len(p) - 1):
        x, y = p[k + 1]
        if k in arcs:
            (i, j), cw = arcs[k]
            seg = arc_points(p[k], p[k + 1], p[k] + (i, j), cw, arc_tolerance)
            nbytes += [len(f"G2X{_num(x)}Y{_num(y)}I{_num(i)}J{_num(j)}") + 1] + [0] * (len(seg) - 1)
        else:
            seg = p[k + 1:k + 2]
            nbytes.append(len(f"G1X{_num(x)}Y{_num(y)}") + 1)
        pts.append(seg)
    return np.vstack(pts), np.asarray(nbytes, float)


def _serial_keeps_up(p: np.ndarray, block_times: np.ndarray, baud: int, window: int = 15,
                     nbytes: np.ndarray | None = None) -> bool:
    """Can a character-counting sender at ``baud`` keep GRBL's planner full through these blocks?

    Every ``window`` consecutive blocks (the planned look-ahead) must take at
    least as long as their lines take on the wire (10 bits per byte, spaces
    stripped as the streamer sends them); otherwise the planner runs dry and
    GRBL brakes to a stop at its last block.
    """
    if baud <= 0 or len(block_times) < window:
        return True
    if nbytes is None:
        nbytes = np.array([len(f"G1X{_num(x)}Y{_num(y)}") + 1 for x, y in p[1:].tolist()], float)
    slack = np.concatenate([[0.0], np.cumsum(block_times - nbytes * 10.0 / baud)])
    return bool((slack[window:] - slack[:-window]).min() >= 0.0)


SNAP = True  # feeds = cap: vertices on GRBL's steps (tests turn it off to compare with rounded vertices)


def _with_feeds(points, feeds) -> list[tuple]:
    """[(p, np.full(len(p) - 1, feeds[i]), {})]: every path's segment feeds as views of one array (one np.full
    per path cost more than the rest of the writing of a straight stroke)."""
    n = np.fromiter((len(p) - 1 for p in points), np.int64, len(points))
    f = np.repeat(np.asarray(feeds, float), n)
    at = offsets(n).tolist()
    return [(p, f[at[i]:at[i + 1]], {}) for i, p in enumerate(points)]


def _linspaces(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.linspace(0.0, 1.0, n[s]) for every s (each n[s] >= 2) concatenated, and their offsets, in a few array
    operations: numpy's own arithmetic (k * (1.0 / (n - 1)) + 0.0, the last 1.0), so the values are the same."""
    off = offsets(n)
    k = np.arange(off[-1], dtype=float) - np.repeat(off[:-1], n)
    u = k * np.repeat(1.0 / (n - 1), n) + 0.0
    u[off[1:] - 1] = 1.0
    return u, off


def _pass_through(strokes, which, lifts) -> tuple[np.ndarray, np.ndarray]:
    """For strokes[which[s]]: the unit direction in which the pen arrives at its start / leaves its end without
    stopping (the neighbouring stroke's tangent at the point they share, where Job.lifts says the pen stays
    down), (0, 0) where it stops. The tangents are evaluated in one call (eval_many: Spline.__call__'s bits)."""
    t = np.zeros((2, len(which), 2))  # t_in, t_out
    if lifts is None or not len(which):
        return t[0], t[1]
    # for each (side, s): the neighbour k, where on it (its end arriving, its start leaving), in array operations
    i = np.asarray(which, np.int64)
    k = np.stack([i - 1, i + 1])  # (side, s)
    inside = (k >= 0) & (k < len(strokes))
    kc = np.clip(k, 0, len(strokes) - 1)
    lifted = np.asarray(lifts, bool)[np.maximum(i, kc)]  # the pen lifts between the two
    curve = np.fromiter((st.spline.degree >= 1 for st in strokes), bool, len(strokes))[kc]
    side, s = np.nonzero(inside & ~lifted & curve)  # side-major: the order of the rows does not matter
    if len(side):
        d = eval_many([strokes[j].spline for j in kc[side, s].tolist()], (np.where(side == 0, 1.0, 0.0),
                      np.arange(len(side) + 1)), 1)
        n = np.hypot(d[:, 0], d[:, 1])
        good = n > 0
        t[side[good], s[good]] = d[good] / n[good, None]
    return t[0], t[1]


class _CapWalk:
    """One stroke's walk over the chord levels (GcodePost._cap_levels): told each asked level's time on GRBL
    (inf when a serial line cannot feed it), it says the next level to try, or None when done. From the start
    level it goes finer while that pays; if the first finer level does not, coarser while that pays or until a
    serial line can feed it."""

    def __init__(self, start: int, levels: int):
        self.k, self.levels, self.start = start, levels, start
        self.best = None  # the time of level k, once known
        self.phase = "start"

    def send(self, t: float) -> int | None:
        if self.phase == "start":
            self.best = t
        elif self.phase == "finer":
            if t < self.best:
                self.best, self.k = t, self.k + 1
            else:
                return self._coarser()
        else:  # coarser
            if self.best < np.inf and not t < self.best:
                return None
            self.best, self.k = t, self.k - 1
            return self.k - 1 if self.k > 0 else None
        if self.best < np.inf and self.k + 1 < self.levels:
            self.phase = "finer"
            return self.k + 1
        return self._coarser()

    def _coarser(self) -> int | None:
        if self.k != self.start or self.k == 0:
            return None
        self.phase = "coarser"
        return self.k - 1


def _g1_text(paths, num) -> dict[int, tuple]:
    """The G1 lines of every path (points, feeds mm/min, arcs) without arcs, formatted G1_CHUNK paths at a
    time: {path: (its lines joined by newlines, F words)}. A line moves to a point after the first; an F word
    is printed on a path's first line and where the printed feed changes. The F words (NaN where none) go to
    the GRBL estimate with the points (timing.estimate_program's "G1*" runs), so no Python tuple is made per
    vertex. One string per path, not per line: 10^5 strokes have millions of lines. ``num``: _num, cached."""
    which = [n for n, (_, f, arc) in enumerate(paths) if not arc and len(f)]
    out: dict[int, tuple] = {}
    for c0 in range(0, len(which), G1_CHUNK):
        out.update(_g1_chunk(paths, which[c0:c0 + G1_CHUNK], num))
    return out


def _g1_chunk(paths, which, num) -> dict[int, tuple]:
    pts = np.concatenate([paths[n][0][1:] for n in which])
    f = np.maximum(np.concatenate([paths[n][1] for n in which]), 0.1)  # never print F0
    off = np.concatenate([[0], np.cumsum([len(paths[n][1]) for n in which])])
    # each distinct coordinate formatted once (they lie on the motor steps: they repeat)
    vals, at = np.unique(pts.reshape(-1), return_inverse=True)
    coord = np.array(_nums(vals), object)
    clen = np.fromiter(map(len, coord), np.int64, len(coord))[at.reshape(-1)].reshape(-1, 2)
    # each distinct feed printed once; lines with the same printed feed share an id
    uniq, inv = np.unique(f, return_inverse=True)
    inv = inv.reshape(-1)
    printed = [num(u, 1) for u in uniq.tolist()]
    ids = {}
    sid = np.array([ids.setdefault(t, len(ids)) for t in printed], np.int64)[inv]
    word = np.ones(len(f), bool)
    word[1:] = sid[1:] != sid[:-1]
    word[off[:-1]] = True
    fw = np.full(len(f), np.nan)
    ks = np.flatnonzero(word)
    fw[ks] = np.array([float(t) for t in printed])[inv[ks]]
    # every line "G1 X<x> Y<y>[ F<f>]" in one format call, then each path's lines cut out of it by their lengths
    first = 2 * np.arange(len(f)) + np.cumsum(word) - word  # the line's first argument
    args = np.empty(2 * len(f) + len(ks), object)
    args[first], args[first + 1] = coord[at[0::2]], coord[at[1::2]]
    ftext = np.array(printed, object)[inv[ks]]
    args[first[ks] + 2] = ftext
    text = "\n".join(np.where(word, "G1 X%s Y%s F%s", "G1 X%s Y%s").tolist()) % tuple(args.tolist())
    size = 7 + clen.sum(axis=1)  # "G1 X" x " Y" y "\n"
    size[ks] += 2 + np.fromiter(map(len, ftext), np.int64, len(ks))  # " F" f
    at_char = np.concatenate([[0], np.cumsum(size)]).tolist()
    return {n: (text[at_char[a]:at_char[b] - 1], fw[a:b]) for n, a, b in zip(which, off[:-1].tolist(), off[1:].tolist())}


class GcodePost(PostProcessor):
    name = "gcode"
    summary = "G-code (GRBL, Marlin, LinuxCNC): G0 travels, G1 strokes at the pen-speed cap or the planned feeds"
    extension = ".gcode"
    options = (
        Option("dialect", str, "grbl", "firmware: sets line limit, pen commands, dwell units, preamble", tuple(DIALECTS)),
        Option("pen", str, "", "pen mechanism: servo (M3 S / M280) or z; empty = the dialect's (grbl, marlin: servo; linuxcnc: z)",
               ("", "servo", "z")),
        Option("pen_up", str, "", "command that lifts the pen; empty = the dialect's (grbl servo: M3 S0; z: G0 Z<z_up>)"),
        Option("pen_down", str, "", "command that lowers the pen; empty = the dialect's (grbl servo: M3 S1000; z: G1 Z<z_down>)"),
        Option("z_up", float, 2.0, "pen-up height (mm) when pen = z"),
        Option("z_down", float, 0.0, "pen-down height (mm) when pen = z"),
        Option("z_feed", float, 1000.0, "feed (mm/min) that lowers the pen when pen = z"),
        Option("chord_tolerance", float, 0.05, "largest distance (mm) between a G1 segment and the spline"),
        Option("min_feed", float, 10.0, "smallest feed (mm/min) written, so no segment has F0"),
        Option("program_end", str, "", "last line of the program; empty = the dialect's (grbl, linuxcnc: M2; marlin: M84)"),
        Option("estimate", bool, True, "grbl: put GRBL 1.1's own job time (planner model, doodlecam.link.grbl.timing) in the header"),
        Option("feeds", str, "cap", "cap: the longest chords within chord_tolerance at one feed, the pen-speed cap, and the "
               "firmware's planner sets the speeds (fastest on GRBL); plan: feeds follow the time-optimal plan, which keeps "
               "the true acceleration limits on curves (for controllers that follow F literally)", ("cap", "plan")),
        Option("max_feed", float, 0.0, "highest feed (mm/min) written; 0 = the pen-speed cap (pen.max_speed, else the "
               "slower axis' max_velocity) x 60"),
        Option("junction_deviation", float, 0.01, "grbl: the $11 (mm) the estimate assumes"),
        Option("idle_delay", int, 25, "grbl: the $1 stepper idle delay (ms) the estimate assumes; 255 = motors always on"),
        Option("arcs", bool, False, "feeds = cap: write a piece as one G2/G3 arc where a circle within "
               "chord_tolerance covers at least twice as far as the longest chord and GRBL's model (which cuts arcs "
               "into $12 = 0.002 mm chords) runs the stroke faster"),
        Option("baud", int, 115200, "feeds = cap: the serial rate (baud) the chords must not outrun (GRBL's 15 planned "
               "blocks must take longer than sending their lines); 0 = no limit"),
        Option("work_offset", str, "none", "grbl: none; g10: G10 L20 P1 makes the pen's position at the start the "
               "profile's home (stored, for machines with soft limits in negative space); g92: the same with G92 "
               "(forgotten at a reset: such a job cannot resume)", ("none", "g10", "g92")),
    )

    def _resolve(self, options: dict[str, Any]) -> tuple[Dialect, dict[str, Any]]:
        """The dialect and the options with its defaults filled in, all checked."""
        d = DIALECTS.get(options.get("dialect", "grbl"))
        if d is None:
            raise PluginError(f"postprocessor 'gcode': option 'dialect' must be one of {', '.join(DIALECTS)}, got {options['dialect']!r}")
        o = dict(options)
        o.setdefault("pen", "")
        pen = o["pen"] or d.pen
        if pen not in ("servo", "z"):
            raise PluginError(f"postprocessor 'gcode': option 'pen' must be servo or z, got {pen!r}")
        for key in ("z_up", "z_down", "z_feed"):
            o.setdefault(key, dict((x.name, x.default) for x in self.options)[key])
        if pen == "z":
            up, down = f"G0 Z{_num(o['z_up'])}", f"G1 Z{_num(o['z_down'])} F{_num(o['z_feed'], 1)}"
        else:
            up, down = d.servo_up, d.servo_down
        o["pen_up"] = o.get("pen_up") or up
        o["pen_down"] = o.get("pen_down") or down
        o["program_end"] = o.get("program_end") or d.program_end
        o["pen"] = pen
        for key in ("pen_up", "pen_down", "program_end"):
            v = o[key]
            if not v.strip() or "\n" in v or "\r" in v or len(v) > d.max_line or not v.isascii():
                raise PluginError(f"postprocessor 'gcode': option '{key}' must be one ASCII line of at most {d.max_line} characters, got {v!r}")
        defaults = {x.name: x.default for x in self.options}
        for key in ("feeds", "max_feed", "junction_deviation", "idle_delay", "work_offset", "baud", "arcs"):
            o.setdefault(key, defaults[key])
        if o["feeds"] not in ("cap", "plan"):
            raise PluginError(f"postprocessor 'gcode': option 'feeds' must be cap or plan, got {o['feeds']!r}")
        if o["work_offset"] not in ("none", "g10", "g92"):
            raise PluginError(f"postprocessor 'gcode': option 'work_offset' must be none, g10 or g92, got {o['work_offset']!r}")
        if o["work_offset"] == "g10" and d.name == "marlin":
            raise PluginError("postprocessor 'gcode': Marlin's G10 is a retract, not a work offset; use work_offset=g92")
        if not (0 <= o["idle_delay"] <= 255):
            raise PluginError(f"postprocessor 'gcode': option 'idle_delay' must be 0..255 ms ($1), got {o['idle_delay']!r}")
        for key in ("max_feed", "junction_deviation", "baud"):
            if not o[key] >= 0:
                raise PluginError(f"postprocessor 'gcode': option '{key}' must not be negative, got {o[key]!r}")
        for key in ("chord_tolerance", "min_feed", "z_feed"):
            if not o[key] > 0:
                raise PluginError(f"postprocessor 'gcode': option '{key}' must be positive, got {o[key]!r}")
        if pen == "z" and not o["z_up"] > o["z_down"]:
            raise PluginError(f"postprocessor 'gcode': option 'z_up' ({o['z_up']}) must be above 'z_down' ({o['z_down']})")
        return d, o

    def _plan_points(self, stroke, dt: float, tol: float, min_feed: float):
        """feeds = plan: G1 points at the planned sample instants, refined to the tolerance, and the
        feed (mm/min) of each segment: its chord over the planned time between its ends."""
        prof = stroke.profile
        t = np.append(np.arange(0.0, prof.duration, dt), prof.duration)
        u = np.unique(np.append(prof.state_at(t)[0], [0.0, 1.0]))
        # Leave room for rounding the coordinates to 3 decimals (<= 0.0007 mm).
        u = _refine(stroke.spline, u, max(tol - 1e-3, 0.5 * tol))
        return u

    @staticmethod
    def _dense(strokes, tol: float):
        """Dense points of every stroke whose own chords stray at most ``fine`` from its spline: a chord within
        e - fine - 0.0007 of them (rounding to 3 decimals) is within e of the spline. (points, offsets, fine):
        stroke s is points[offsets[s]:offsets[s + 1]] (doodlecam.geometry.chord_batch.dense_points, as _refine
        does it)."""
        fine = 0.02 * tol
        if not len(strokes):
            return np.zeros((0, 2)), np.zeros(1, np.int64), fine
        splines = [st.spline for st in strokes]
        # _refine adds points where the curve bends
        length = np.fromiter((s.length for s in splines), float, len(splines))
        u0, uoff = _linspaces(np.maximum(np.ceil(length / 0.5).astype(np.int64) + 1, 9))
        ctrl, coff = controls_many(splines)
        q, off = dense_points(ctrl, coff, np.fromiter((s.degree for s in splines), np.int64, len(splines)),
                              u0, uoff, fine, 30)
        return q, off, fine

    def _arc_candidate(self, stroke, tol: float, spm: np.ndarray):
        """feeds = cap, arcs: vertices (rounded) and {segment: (I, J, clockwise)}, or None."""
        q, _, fine = self._dense([stroke], tol)
        # GRBL cuts an arc into chords $12 = 0.002 mm inside it; centre and ends are rounded to 0.001
        idx, arcs = _greedy_arcs(q, tol - fine - 0.004)
        if not arcs:
            return None
        p = np.round(q[idx], 3)
        if not _one_step_apart(p, spm).all():
            return None
        return p, {k: (np.round(c - p[k], 3), cw) for k, (c, cw) in arcs.items()}

    @staticmethod
    def _cap_levels(tol: float, spm: np.ndarray):
        """feeds = cap: the chord levels (mm), the snapping room r0 (mm) and the level the search starts from.

        Longer chords turn more at each junction, and GRBL's junction speed falls
        as the turn grows, while shorter ones starve its 15-block look-ahead and
        suffer more from its rounding to whole steps: which is faster depends on
        the curve, so the caller times each with GRBL's model. Level k takes the
        longest chords within (tol - fine) / 2^(k/4) of the curve, then places
        each vertex on one of the step positions around it, within the whole
        tolerance (the vertices leave the curve, the chords stay within the
        tolerance of it), so that GRBL's rounded chords turn smoothly
        (``doodlecam.geometry.chords.snap_chords``). The search starts near a
        third of a step (where traced curves run fastest) and walks to finer or
        coarser levels while they pay (_CapWalk).
        """
        r0 = tol - 0.02 * tol - 7.1e-4  # unsnapped vertices are rounded to 3 decimals
        rooms = r0 * CHORD_LEVEL ** np.arange(CAP_LEVELS)
        rooms = rooms[(rooms >= MIN_LEVEL_STEPS / spm.max()) | (np.arange(CAP_LEVELS) == 0)]
        return rooms, r0, int(np.argmin(np.abs(np.log(rooms * spm.max() / START_LEVEL_STEPS))))

    def _stroke_points(self, stroke, dt: float, tol: float, min_feed: float, mode: str, cap: float, machine,
                       grbl, baud: int, arcs: bool = False):
        """Rounded end points (n, 2), the feed (mm/min) of each of the n-1 segments, and the arcs among them
        ({segment: ((I, J), clockwise)})."""
        prof = stroke.profile
        if prof is None:
            raise OutputError("job is not planned (a stroke has no feed profile); plan it before writing G-code")
        spm = np.array([machine.x.steps_per_mm, machine.y.steps_per_mm])
        if mode == "cap":
            feed = max(cap, min_feed)
            (best, feeds, _), = self._cap_paths([stroke], [feed], tol, machine, grbl, baud)
            if arcs and not stroke.spline.straight:
                from doodlecam.link.grbl.timing import _segment_time

                # a stroke runs from rest to rest (the pen commands empty GRBL's planner)
                best_t = _segment_time(np.c_[best, np.zeros(len(best))], np.full(len(best) - 1, feed / 60.0), grbl).sum()
                cand = self._arc_candidate(stroke, tol, spm)
                if cand is not None:
                    p, arc = cand
                    pts, nbytes = _expand_arcs(p, arc, grbl.arc_tolerance)
                    bt = _segment_time(np.c_[pts, np.zeros(len(pts))], np.full(len(pts) - 1, feed / 60.0), grbl)
                    if bt.sum() < best_t and _serial_keeps_up(pts, bt, baud, nbytes=nbytes):
                        return p, np.full(len(p) - 1, feed), arc
            return best, feeds, {}
        u = self._plan_points(stroke, dt, tol, min_feed)
        p = np.round(stroke.spline(u), 3)
        keep = _one_step_apart(p, spm)  # also drops moves that round to zero length
        p, tu = p[keep], _t_of_u(prof, u[keep])
        chord, dtu = np.linalg.norm(np.diff(p, axis=0), axis=1), np.diff(tu)
        with np.errstate(divide="ignore", invalid="ignore"):
            feed = np.where(dtu > 0, 60.0 * chord / dtu, np.inf)
        # never above the pen-speed cap (a very short last segment has a tiny planned time)
        return p, np.clip(feed, min_feed, max(cap, min_feed)), {}

    def _cap_paths(self, strokes, feeds, tol: float, machine, grbl, baud: int, lifts=None):
        """feeds = cap without arcs for every stroke, as _stroke_points chooses them: each round, every stroke
        still searching gets its next level's chords from one compiled call over all of them
        (doodlecam.geometry.chord_batch), and all of them are timed with GRBL's model in one call (one call per
        stroke and level cost more than the work on drawings of 10^4 strokes). ``lifts`` (Job.lifts): where the
        pen goes on from one stroke into the next (a kept corner), the end chords are snapped to turn towards
        the neighbour's tangent (_pass_through)."""
        spm = np.array([machine.x.steps_per_mm, machine.y.steps_per_mm])
        out: list = [None] * len(strokes)
        curved, straight = [], []
        for i, st in enumerate(strokes):
            if st.profile is None:
                raise OutputError("job is not planned (a stroke has no feed profile); plan it before writing G-code")
            (straight if st.spline.straight else curved).append(i)
        # a straight stroke is one chord: its ends, both kept unless they round to the same steps
        # (_one_step_apart of two points), all evaluated in one call
        ends = np.round(eval_many([strokes[i].spline for i in straight],
                                  (np.tile(_ENDS, len(straight)), np.arange(0, 2 * len(straight) + 1, 2))), 3).reshape(-1, 2, 2)
        steps = np.round(ends * spm).astype(np.int64)
        moved = (steps[:, 0] != steps[:, 1]).any(axis=1).tolist()
        for i, p, m in zip(straight, ends, moved):
            out[i] = p if m else p[:1]
        if not curved:
            return _with_feeds(out, feeds)
        rooms, r0, start = self._cap_levels(tol, spm)
        acc = np.asarray(grbl.acceleration, float)
        t_in, t_out = _pass_through(strokes, curved, lifts)
        # CAP_CHUNK strokes at a time: each stroke's search is its own, so the chunks change no chord, and
        # the dense points and candidates of 10^5 strokes are never all held at once
        for c0 in range(0, len(curved), CAP_CHUNK):
            part = curved[c0:c0 + CAP_CHUNK]
            best = self._cap_search([strokes[i] for i in part], [feeds[i] for i in part], tol, spm, grbl, baud,
                                    rooms, r0, start, acc, t_in[c0:c0 + CAP_CHUNK], t_out[c0:c0 + CAP_CHUNK])
            for s, p in enumerate(best):
                out[part[s]] = p
        return _with_feeds(out, feeds)

    def _cap_search(self, strokes, feeds, tol, spm, grbl, baud, rooms, r0, start, acc, t_in, t_out):
        """The chosen chords (points) of each of these curved strokes (_cap_paths)."""
        from doodlecam.link.grbl.timing import _segment_time

        q, qoff, _ = self._dense(strokes, tol)
        v = np.array([f / 60.0 for f in feeds])
        walks = {s: _CapWalk(start, len(rooms)) for s in range(len(strokes))}  # by position in strokes
        best: dict[int, tuple] = {}  # position -> (points, key) of its best level so far
        asked = {s: start for s in walks}
        while asked:
            which = np.fromiter(asked, np.int64, len(asked))
            pts, off = cap_candidates(q, qoff, which, np.fromiter(asked.values(), np.int64, len(asked)), rooms, r0,
                                      float(spm[0]), float(spm[1]), v[which], float(acc[0]), float(acc[1]),
                                      float(grbl.junction_deviation), SNAP, t_in, t_out)
            n = np.diff(off)
            # one program of all candidates, each from rest to rest (the pen commands empty GRBL's
            # planner): the block joining two candidates starts from rest and its time is dropped;
            # a candidate of one point (the stroke within one step) has no block
            moving = n > 1
            first = np.zeros(len(n), np.int64)
            bt = np.zeros(0)
            if moving.any():
                mpts = pts[np.repeat(moving, n)]
                nm = n[moving]
                first[moving] = np.concatenate([[0], np.cumsum(nm)[:-1]])  # each candidate's first point
                fm = first[moving]
                rest = np.zeros(len(mpts) - 1, bool)
                rest[fm] = True  # its first block
                rest[fm[1:] - 1] = True  # the joining block
                feed = np.repeat(v[which[moving]], nm)[:-1]
                bt = _segment_time(np.c_[mpts, np.zeros(len(mpts))], feed, grbl, rest)
            usable = serial_keeps_up(pts, off, bt, first, int(baud), 15)
            asked = {}
            no_time = np.zeros(0)
            # Python ints and bools for the loop (indexing arrays by numpy scalars costs more than the work)
            offl, firstl, nl, movingl, usablel = off.tolist(), first.tolist(), n.tolist(), moving.tolist(), usable.tolist()
            for c, s in enumerate(which.tolist()):
                p = pts[offl[c]:offl[c + 1]]
                times = bt[firstl[c]:firstl[c] + nl[c] - 1] if movingl[c] else no_time
                t = float(times.sum())
                ok = usablel[c] > 0 if usablel[c] >= 0 else _serial_keeps_up(p, times, baud)
                # the fastest candidate a serial line can feed; if none can, the one of fewest lines
                key = (0, t) if ok else (1, len(p))
                if s not in best or key < best[s][1]:
                    best[s] = (p.copy(), key)  # not a view: this round's arrays go
                k = walks[s].send(t if ok else np.inf)
                if k is not None:
                    asked[s] = k
        return [best[s][0] for s in range(len(strokes))]

    def write(self, job, options: dict[str, Any]) -> bytes:
        d, options = self._resolve(options)
        m = job.machine
        tol, min_feed = float(options["chord_tolerance"]), float(options["min_feed"])
        if tol < 2e-3:
            raise PluginError(f"postprocessor 'gcode': option 'chord_tolerance' must be at least 0.002 mm (coordinates "
                              f"are written to 0.001 mm), got {tol!r}")
        cap = pen_feed_cap(m, float(options["max_feed"]))
        dts = [s.delta_time for s in job.samples] if len(job.samples) == len(job.strokes) else []
        from doodlecam.link.grbl.timing import GrblSettings

        grbl = GrblSettings.from_machine(m, float(options["junction_deviation"]), int(options["idle_delay"]))
        # Each stroke is drawn with its layer's pen: its delays, and its speed cap on the feed.
        pen_no = job.pen_numbers
        changes = set(job.pen_changes)
        pauses = set(job.pen_pauses)  # the changes, and the first pen when the machine has several
        caps = {k: _pen_cap(m, k, float(options["max_feed"])) for k in set(pen_no)}
        if options["feeds"] == "cap" and not options["arcs"]:  # the default: every stroke's chords at once
            paths = self._cap_paths(job.strokes, [max(caps[k], min_feed) for k in pen_no], tol, m, grbl,
                                    int(options["baud"]), job.lifts)
        else:
            paths = [self._stroke_points(s, dts[i] if dts else m.delta_time, tol, min_feed, options["feeds"],
                                         caps[pen_no[i]], m, grbl, int(options["baud"]), bool(options["arcs"]))
                     for i, s in enumerate(job.strokes)]
        home = job.travels[-1].end if job.travels else np.asarray(m.home, float)

        from functools import lru_cache

        from doodlecam.link.grbl.timing import parse_gcode

        # a drawing's coordinates lie on the motor steps and its pen lines repeat: each is formatted or
        # parsed once (10^5 calls cost more than the rest of the writing)
        num, parse = lru_cache(maxsize=None)(_num), lru_cache(maxsize=None)(parse_gcode)
        body: list[str] = []
        # The same moves for the GRBL estimate, built here rather than parsed back
        # from the text (the coordinates are already rounded as printed).
        estimate = d.name == "grbl" and options.get("estimate", False)
        program: list[tuple] = []

        def line(text: str) -> None:  # a user- or dialect-defined line: parse it for the estimate
            body.append(text)
            if estimate:
                program.extend(parse(text))

        def pen_lines(cmd: str, delay: float) -> tuple[list[str], list[tuple]]:
            """A pen command and its dwell: the lines, and their moves for the estimate."""
            lines = [cmd] + ([f"G4 P{int(round(delay * 1000.0))}" if d.dwell_ms else f"G4 P{_num(delay)}"]
                             if delay > 0 else [])
            return lines, [item for text in lines for item in parse(text)] if estimate else []

        def put(lines_moves: tuple[list[str], list[tuple]]) -> None:  # pen_lines' lines and moves, emitted
            body.extend(lines_moves[0])
            program.extend(lines_moves[1])

        g1 = _g1_text(paths, num)
        # every path's first and last point as printed, formatted together (the loop below asks each)
        ends = np.array([(p[0], p[-1]) if len(p) else np.zeros((2, 2)) for p, _, _ in paths]).reshape(-1, 4)
        x0, y0, x1, y1 = (_nums(ends[:, k]) for k in range(4))
        tools = {k: m.pen_number(k) for k in set(pen_no)}
        # each pen's lowering and lifting lines (and their moves), made once, not per stroke
        downs = {k: pen_lines(options["pen_down"], t.down_delay) for k, t in tools.items()}
        ups = {k: pen_lines(options["pen_up"], t.up_delay) for k, t in tools.items()}
        put(pen_lines(options["pen_up"], m.pen.up_delay))
        lifts = job.lifts + (True,)  # a stroke that starts where the last ended keeps the pen down
        for n, (p, feed, arc) in enumerate(paths):
            tool = tools[pen_no[n]]
            if n in pauses:  # pen up already: the operator fits the next pen, then resumes
                for text in pause_lines(d, f"{'change to' if n else 'fit'} {tool.describe(pen_no[n])}"):
                    line(text)
            if lifts[n]:
                body.append(f"G0 X{x0[n]} Y{y0[n]}")
                program.append(("G0", p[0, 0], p[0, 1], None, None))
                put(downs[pen_no[n]])
            elif n and len(p) and len(paths[n - 1][0]) and (x0[n], y0[n]) != (x1[n - 1], y1[n - 1]):
                # pen down from the last stroke's end, which the two strokes' vertices may place on different
                # steps (each within the tolerance of the point they share)
                fs = _num(max(feed[0] if len(feed) else caps[pen_no[n]], 0.1), 1)
                body.append(f"G1 X{x0[n]} Y{y0[n]} F{fs}")
                program.append(("G1", p[0, 0], p[0, 1], None, float(fs)))
            if arc:
                last_f = ""
                for k, ((x, y), f) in enumerate(zip(p[1:].tolist(), feed.tolist())):
                    fs = num(max(f, 0.1), 1)  # never print F0
                    fword = f" F{fs}" if fs != last_f else ""
                    if k in arc:
                        (i, j), cw = arc[k]
                        body.append(f"G{2 if cw else 3} X{num(x)} Y{num(y)} I{_num(i)} J{_num(j)}" + fword)
                        program.append((f"G{2 if cw else 3}", x, y, None, float(i), float(j), float(fs) if fword else None))
                    else:
                        body.append(f"G1 X{num(x)} Y{num(y)}" + fword)
                        program.append(("G1", x, y, None, float(fs) if fword else None))
                    last_f = fs
            elif n in g1:
                text, fw = g1.pop(n)
                body.append(text)
                program.append(("G1*", p[1:], fw))
            if lifts[n + 1]:
                put(ups[pen_no[n]])
        body.append(f"G0 X{_num(home[0])} Y{_num(home[1])}")
        program.append(("G0", float(np.round(home[0], 3)), float(np.round(home[1], 3)), None, None))
        line(options["program_end"])

        pts = [p for p, _, _ in paths] + [np.asarray([home])]
        lo, hi = np.concatenate(pts).min(0), np.concatenate(pts).max(0)
        name = "".join(c if c.isascii() and c.isprintable() else "?" for c in m.name)
        head = [
            f"; doodlecam G-code for machine '{name}'",
            f"; planned time {job.duration:.1f} s, {len(job.strokes)} strokes",
            f"; pen-down {job.pen_down_length:.1f} mm, travel {job.travel_length:.1f} mm",
            *([f"; {len(changes)} pen change{'s' if len(changes) != 1 else ''}: the program pauses (M0) for each"]
              if changes else []),
            *([f"; the program pauses (M0) first to fit {m.pen_number(pen_no[0]).describe(pen_no[0])}"]
              if 0 in pauses else []),
            f"; bounds X {_num(lo[0])}..{_num(hi[0])} Y {_num(lo[1])}..{_num(hi[1])} mm",
        ]
        if d.name != "grbl" or options["pen"] != "servo":
            head.append(f"; dialect {d.name} ({d.firmware}), pen by {options['pen']}")
        if estimate:
            from doodlecam.link.grbl.timing import estimate_program

            gs = grbl
            est = estimate_program(program, gs, start=tuple(m.home)).total
            head.append(f"; GRBL 1.1 estimate {est:.1f} s (planner model, see doodlecam.link.grbl.timing)")
            words = [f"{k}={_num(v, 3)}" for k, v in gs.dollars().items() if k not in ("$102", "$112", "$122")]
            head.append("; assumes " + " ".join(words[:4]))  # split: GRBL lines are at most 79 characters
            head.append("; assumes " + " ".join(words[4:]))
        head.append(f"; feeds {options['feeds']}: " + ("longest chords at F" + _num(cap, 1) if options["feeds"] == "cap"
                                                        else "the planned profile's"))
        preamble = list(d.preamble)
        if options["work_offset"] != "none":
            # The pen stands on the profile's home point: make that its work coordinates, so a
            # GRBL with soft limits (machine travel in negative space) runs the positive job.
            preamble.append(("G10 L20 P1" if options["work_offset"] == "g10" else "G92")
                            + f" X{_num(m.home[0])} Y{_num(m.home[1])}")
        if d.name == "linuxcnc":
            preamble.append(f"G64 P{_num(tol)}")  # blend corners within the chord tolerance
        lines = [h[:d.max_line] for h in head] + preamble + body
        return ("\n".join(lines) + "\n").encode("ascii")
