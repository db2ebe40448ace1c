"""How long GRBL 1.1 really takes for a G-code program: a model of its planner.

GRBL does not follow the feeds it is given exactly: its planner
(grbl/planner.c) limits every block and every junction, and only looks a few
blocks ahead. This module reproduces that model, so a user knows the job time
the firmware will take, not only the time doodlecam planned:

* a block's nominal speed is its F (G1) or the rapid rate (G0), capped so no
  axis exceeds its max rate ($110..$112): ``min_i(rate_i / |u_i|)`` for the
  block's unit vector u; its acceleration is ``min_i(accel_i / |u_i|)``
  ($120..$122), the same ``limit_value_by_axis_maximum`` GRBL uses;
* the junction between two blocks allows
  ``v² = a_j · δ · sin(θ/2) / (1 − sin(θ/2))`` with δ the junction deviation
  ($11), ``cos θ = −u_prev · u`` and ``a_j`` the acceleration limit along
  ``u − u_prev``; a straight junction is unlimited, a reversal stops; the entry
  speed is also at most both blocks' nominal speeds;
* look-ahead is bounded: GRBL's 16-entry block ring holds 15 blocks, the
  executing one included, and the last of them must be able to stop; a sender
  that keeps the buffer full (as ``doodlecam send`` does) sees exactly this
  window: block i may leave at most at the speed from which blocks
  i+1..i+14 can still brake to rest;
* M-codes (spindle/servo changes, outside laser mode), G10 (an EEPROM
  write) and G4 dwells synchronise: the planner empties and the machine
  stops; a dwell adds its time (GRBL's G4 P is in seconds);
* each time motion stops (the stepper segment buffer runs empty, i.e. at
  every synchronisation after a move and at the program end) ``st_go_idle``
  waits the ``$1`` stepper idle delay (25 ms by default) before GRBL goes on;
  ``$1=255`` keeps the motors on and skips it.

Each block then runs a trapezoid (or triangle) between its entry and exit
speeds. Stepper segment quantisation (~ms) is ignored. Units: mm, s, mm/s.
Everything is vectorised with NumPy: the backward pass runs over all windows
at once (14 steps), the forward pass is a min-plus prefix scan.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from doodlecam.errors import InputError

SOME_LARGE_VALUE = 1.0e38


@dataclass(frozen=True)
class GrblSettings:
    """GRBL 1.1 settings that shape motion time (mm/s, mm/s², mm)."""

    max_rate: tuple[float, float, float] = (83.333, 83.333, 8.333)  # $110..$112 / 60
    acceleration: tuple[float, float, float] = (500.0, 500.0, 100.0)  # $120..$122 (mm/s²)
    junction_deviation: float = 0.01  # $11
    blocks: int = 16  # BLOCK_BUFFER_SIZE; the ring holds blocks - 1
    idle_delay_ms: int = 25  # $1; 255 keeps the motors enabled (no delay)
    arc_tolerance: float = 0.002  # $12 (mm): how finely GRBL cuts G2/G3 into line blocks
    steps_per_mm: tuple[float, float, float] = (250.0, 250.0, 250.0)  # $100..$102

    @classmethod
    def from_machine(cls, machine, junction_deviation: float = 0.01, idle_delay_ms: int = 25) -> "GrblSettings":
        """Settings matching a doodlecam machine profile (Z like X: a pen lift is short)."""
        x, y = machine.axes
        return cls((x.max_velocity, y.max_velocity, x.max_velocity),
                   (x.max_acceleration, y.max_acceleration, x.max_acceleration), junction_deviation,
                   idle_delay_ms=int(idle_delay_ms), steps_per_mm=(x.steps_per_mm, y.steps_per_mm, x.steps_per_mm))

    @property
    def idle_delay(self) -> float:
        """Seconds GRBL waits each time motion stops ($1)."""
        return 0.0 if self.idle_delay_ms >= 255 else self.idle_delay_ms / 1000.0

    def dollars(self) -> dict[str, float]:
        """These settings as GRBL ``$`` settings (units as GRBL takes them: mm/min for $110..$112)."""
        out: dict[str, float] = {}
        for k, v in enumerate(self.steps_per_mm):
            out[f"${100 + k}"] = round(v, 3)
        for k, v in enumerate(self.max_rate):
            out[f"${110 + k}"] = round(60.0 * v, 3)
        for k, v in enumerate(self.acceleration):
            out[f"${120 + k}"] = round(v, 3)
        out["$11"] = self.junction_deviation
        out["$1"] = self.idle_delay_ms
        return out


def grbl_settings_for(machine, junction_deviation: float = 0.01, idle_delay_ms: int = 25) -> dict[str, float]:
    """The ``$`` settings a GRBL 1.1 controller needs for a doodlecam machine profile.

    Keys ``$1``, ``$11``, ``$100..$102`` (steps/mm), ``$110..$112`` (mm/min),
    ``$120..$122`` (mm/s², as GRBL shows them), ``$130/$131`` (travel, mm).
    """
    out = GrblSettings.from_machine(machine, junction_deviation, idle_delay_ms).dollars()
    out["$130"], out["$131"] = float(machine.width), float(machine.height)
    return dict(sorted(out.items(), key=lambda kv: int(kv[0][1:])))


@dataclass
class Estimate:
    """The estimated time (s) and its parts."""

    motion: float = 0.0
    dwell: float = 0.0
    idle: float = 0.0  # $1 stepper idle delays
    stops: int = 0  # times motion stopped
    blocks: int = 0
    block_times: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def total(self) -> float:
        return self.motion + self.dwell + self.idle


def _axis_limit(values: np.ndarray, unit: np.ndarray) -> np.ndarray:
    """GRBL's limit_value_by_axis_maximum for each row of unit (n, 3)."""
    with np.errstate(divide="ignore"):
        r = np.where(unit != 0, values / np.abs(unit), SOME_LARGE_VALUE)
    out = r[:, 0].copy()
    for k in range(1, r.shape[1]):  # column by column: r.min(axis=1) over 2-3 columns is ~3x slower
        np.minimum(out, r[:, k], out=out)
    return out


def to_steps(mm: np.ndarray, steps_per_mm: np.ndarray) -> np.ndarray:
    """Whole steps as GRBL's lround: to the nearest, halves away from zero."""
    x = np.asarray(mm, float) * steps_per_mm
    return np.sign(x) * np.floor(np.abs(x) + 0.5)


def _segment_time(points: np.ndarray, feeds: np.ndarray, s: GrblSettings, rest: np.ndarray | None = None) -> np.ndarray:
    """Times (s) of the blocks points[k] -> points[k+1]: _segment_time_numpy (the model, and its
    documentation) compiled (doodlecam.link.grbl.planner_kernel, the same numbers to the bit)."""
    points = np.asarray(points, float)
    rate, acc = np.asarray(s.max_rate, float), np.asarray(s.acceleration, float)
    if points.ndim != 2 or len(points) < 2 or points.shape[1] != len(rate) or len(acc) != len(rate):
        return _segment_time_numpy(points, feeds, s, rest)  # the edge cases (and their errors) as they were
    from doodlecam.link.grbl.planner_kernel import block_times

    if rest is None:
        rest = np.zeros(len(points) - 1, bool)
        rest[:1] = True
    spm = np.asarray(s.steps_per_mm, float)[:points.shape[1]]
    return block_times(np.ascontiguousarray(points), np.ascontiguousarray(feeds, dtype=float),
                       np.ascontiguousarray(rest, dtype=bool), np.ascontiguousarray(spm), rate, acc,
                       float(s.junction_deviation), max(int(s.blocks) - 1, 1))


def _segment_time_numpy(points: np.ndarray, feeds: np.ndarray, s: GrblSettings, rest: np.ndarray | None = None) -> np.ndarray:
    """Times (s) of the blocks points[k] -> points[k+1].

    ``feeds[k]`` is the block's requested speed (mm/s; inf for rapids).
    ``rest[k]``: block k starts from rest (a synchronisation before it); by
    default only the first. Runs between synchronisations are independent, so
    many are timed in one call: a rest start is an entry speed of 0, which both
    passes carry exactly (one call per run cost more than the model itself).
    Zero-length blocks (GRBL drops them) get time 0.
    """
    # GRBL plans from targets rounded to whole steps (planner.c: lround(target * steps_per_mm), and the
    # block's direction and length from the rounded deltas): on chords of a fraction of a millimetre a
    # half step turns a junction by a degree or two, and GRBL slows there
    spm = np.asarray(s.steps_per_mm, float)[:points.shape[1]]
    points = to_steps(points, spm) / spm
    d = np.diff(points, axis=0)
    L = np.linalg.norm(d, axis=1)
    if rest is None:
        rest = np.zeros(len(L), bool)
        rest[:1] = True
    keep = L > 0  # GRBL drops zero-length blocks
    out = np.zeros(len(L))
    d, L, feeds = d[keep], L[keep], feeds[keep]
    n = len(L)
    if n == 0:
        return out
    # a kept block starts from rest when it is the first of its run (a dropped
    # block's rest start passes on to the next kept one)
    run = np.cumsum(rest)[keep]
    starts = np.r_[True, run[1:] != run[:-1]]
    u = d / L[:, None]
    rate, acc = np.asarray(s.max_rate, float), np.asarray(s.acceleration, float)
    a = _axis_limit(acc, u)
    nominal = np.minimum(feeds, _axis_limit(rate, u))
    n2 = nominal ** 2

    # Junction limits: block k's entry, from u[k-1] and u[k]; the first block starts at rest.
    cos = -(u[:-1] * u[1:]).sum(1)
    ju = u[1:] - u[:-1]
    jn = np.linalg.norm(ju, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ja = _axis_limit(acc, ju / np.where(jn > 0, jn, 1.0)[:, None])
        sin_d2 = np.sqrt(np.clip(0.5 * (1.0 - cos), 0.0, 1.0))
        vj2 = np.maximum(0.0, ja * s.junction_deviation * sin_d2 / (1.0 - sin_d2))
    vj2 = np.where(cos > 0.999999, 0.0, np.where(cos < -0.999999, SOME_LARGE_VALUE, vj2))
    me = np.empty(n)  # max entry speed²
    me[0] = 0.0
    me[1:] = np.minimum(vj2, np.minimum(n2[1:], n2[:-1]))
    me[starts] = 0.0

    # Backward pass over every window at once: block i's exit may be at most the
    # entry of block i+1 from which blocks up to i+W-1 can still stop.
    W = max(int(s.blocks) - 1, 1)
    pad = W
    me_p = np.concatenate([me, np.zeros(pad + 1)])  # past the program end: rest
    two_aL = np.concatenate([2.0 * a * L, np.zeros(pad + 1)])
    cur = np.zeros(n)  # exit² of block i + W - 1
    for k in range(W - 1, 0, -1):  # rows i + k of every i: a slice, not a gather
        cur = np.minimum(me_p[k:k + n], cur + two_aL[k:k + n])
    limit = cur  # exit² bound of block i (= entry² bound of block i+1)

    # Forward pass: exit_i² = min(limit_i, exit_{i-1}² + 2 a_i L_i), from rest. A min-plus scan;
    # a rest start has limit 0 on the block before it, so the scan restarts there.
    C = np.cumsum(2.0 * a * L)
    exit2 = C + np.minimum(0.0, np.minimum.accumulate(limit - C))
    exit2 = np.maximum(exit2, 0.0)
    entry2 = np.concatenate([[0.0], exit2[:-1]])
    entry2[starts] = 0.0

    vi, vf, vn = np.sqrt(entry2), np.sqrt(exit2), nominal
    d1 = (n2 - entry2) / (2 * a)
    d2 = (n2 - exit2) / (2 * a)
    cruise = L - d1 - d2
    with np.errstate(invalid="ignore", divide="ignore"):
        trap = (vn - vi) / a + (vn - vf) / a + np.where(cruise > 0, cruise / vn, 0.0)
        vp = np.sqrt(np.maximum((2 * a * L + entry2 + exit2) / 2, np.maximum(entry2, exit2)))
        tri = (vp - vi) / a + (vp - vf) / a
    out[keep] = np.where(cruise >= 0, trap, tri)
    return out


ARC_ANGULAR_TRAVEL_EPSILON = 5e-7


def arc_points(start, target, center, clockwise: bool, arc_tolerance: float = 0.002) -> np.ndarray:
    """The line blocks GRBL 1.1 cuts an XY arc into (motion_control.c ``mc_arc``): their end points, target last.

    ``segments = floor(|θ| r / 2 / sqrt(tol (2r - tol)))`` equal angles, then
    a last line to the exact target; a full circle when start and target meet.
    """
    start, target, center = (np.asarray(v, float) for v in (start, target, center))
    r0, r1 = start[:2] - center[:2]
    t0, t1 = target[:2] - center[:2]
    radius = float(np.hypot(r0, r1))
    theta = np.arctan2(r0 * t1 - r1 * t0, r0 * t0 + r1 * t1)
    if clockwise:
        if theta >= -ARC_ANGULAR_TRAVEL_EPSILON:
            theta -= 2 * np.pi
    elif theta <= ARC_ANGULAR_TRAVEL_EPSILON:
        theta += 2 * np.pi
    seg = int(np.floor(abs(0.5 * theta * radius) / np.sqrt(arc_tolerance * (2 * radius - arc_tolerance)))) \
        if radius > arc_tolerance else 0
    k = np.arange(1, seg)
    ang = np.arctan2(r1, r0) + theta * k / max(seg, 1)
    pts = np.zeros((len(k), len(start)))
    pts[:, 0], pts[:, 1] = center[0] + radius * np.cos(ang), center[1] + radius * np.sin(ang)
    if len(start) > 2:
        pts[:, 2:] = start[2:] + (target[2:] - start[2:]) * (k / max(seg, 1))[:, None]
    return np.vstack([pts, target[None, :]])


RUN_CHUNK = 100_000  # blocks timed per call of _segment_time (it holds ~40 arrays of its blocks)


def _run_times(points, feeds, s: GrblSettings, rest) -> np.ndarray:
    """_segment_time of the blocks points[k] -> points[k+1], RUN_CHUNK blocks or so at a time, each part
    starting at a synchronisation: runs are independent (a rest start carries entry speed 0 through
    both passes, as the program's end does), so the parts give the same times as one call, in bounded memory."""
    n = len(feeds)
    cuts = [0]
    starts = np.flatnonzero(rest)
    while n - cuts[-1] > RUN_CHUNK:
        later = starts[starts > cuts[-1]]
        if not len(later):
            break
        within = later[later <= cuts[-1] + RUN_CHUNK]
        cuts.append(int(within[-1] if len(within) else later[0]))  # else one run longer than a part: whole
    cuts.append(n)
    return np.concatenate([_segment_time(points[a:b + 1], feeds[a:b], s, rest[a:b])
                           for a, b in zip(cuts[:-1], cuts[1:])])


def estimate_program(program, settings: GrblSettings = GrblSettings(), start=(0.0, 0.0, 0.0)) -> Estimate:
    """Estimate a program given as a list of moves.

    Items: ``("G0", x, y[, z], None)`` rapids, ``("G1", x, y[, z], F)`` with F in
    mm/min (None keeps the modal feed), ``("G4", seconds)`` dwells and
    ``("M", text)`` commands (both synchronise: the machine stops), and arcs
    ``("G2"|"G3", x, y, z, i, j, F)`` (clockwise / counter-clockwise, centre at
    the start plus (i, j)), cut into lines as GRBL does (``arc_points``).
    Coordinates are absolute mm; x, y or z None keeps that axis.
    ``("G1*", xy, F)``: a run of G1 moves to the rows of xy (n, 2), z kept, block k with the
    F word F[k] (mm/min; NaN: none, the modal feed), as n G1 items would be (a writer's strokes
    without one Python tuple per vertex).
    """
    pos = np.zeros(3)
    pos[:len(start)] = np.asarray(start, float)
    est = Estimate()
    # all runs in one call: block k goes from pts[k] to pts[k+1]; a synchronisation
    # (dwell, M command) makes the next block start from rest. Single moves go to plain
    # float lists (an array per point cost ~200 bytes: 10^6 blocks of a generated drawing),
    # runs as arrays, each with the number of single moves before it: both are put in
    # program order once, at the end
    xs, ys, zs = [], [], []
    feeds, rest = [], []
    runs: list[tuple] = []  # (single moves before it, points (n, 2), F words, first feed, z, rest)
    here = [float(pos[0]), float(pos[1]), float(pos[2])]
    feed = None
    feed_run = None  # after a run: its index (the modal feed is its last F word, found when needed)
    sync = True

    def add(x, y, z, v):
        nonlocal sync
        xs.append(x)
        ys.append(y)
        zs.append(z)
        feeds.append(v)
        rest.append(sync)
        sync = False
        here[:] = x, y, z

    def modal(what="G1"):
        """The modal feed (mm/min); after a run, its last F word."""
        nonlocal feed, feed_run
        if feed_run is not None:
            _, _, fw, f0, _, _ = runs[feed_run]
            words = np.flatnonzero(fw == fw)
            feed, feed_run = (float(fw[words[-1]]) if len(words) else f0), None
        if feed is None:
            raise InputError(f"{what} without a feed rate: GRBL refuses it (error:22); add F")
        return feed

    for item in program:
        kind = item[0]
        if kind == "G1*":
            xy, fw = item[1], item[2]
            if not len(xy):
                continue
            f0 = fw[0] if fw[0] == fw[0] else modal()  # a NaN: no F word, the modal feed
            runs.append((len(xs), xy, fw, float(f0), here[2], sync))
            sync = False
            feed_run = len(runs) - 1
            here[:] = float(xy[-1, 0]), float(xy[-1, 1]), here[2]
        elif kind in ("G0", "G1"):
            coords, f = item[1:-1], item[-1]
            target = list(here)
            for k, c in enumerate(coords[:3]):
                if c is not None:
                    target[k] = float(c)
            if kind == "G1":
                if f is not None:
                    feed, feed_run = f, None
                v = modal() / 60.0
            else:
                v = np.inf
            add(target[0], target[1], target[2], v)
        elif kind in ("G2", "G3"):
            x, y, z, i, j, f = item[1:]
            if f is not None:
                feed, feed_run = f, None
            feed = modal("G2/G3")
            at = np.array(here)
            target = at.copy()
            for k, c in enumerate((x, y, z)):
                if c is not None:
                    target[k] = c
            centre = at.copy()
            centre[:2] += (i or 0.0, j or 0.0)
            for q in arc_points(at, target, centre, kind == "G2", settings.arc_tolerance):
                add(float(q[0]), float(q[1]), float(q[2]), feed / 60.0)
        elif kind == "G4":
            sync = True
            est.dwell += float(item[1])
        elif kind == "M":
            sync = True
        else:
            raise ValueError(f"unknown program item {item!r}")
    nr = np.array([len(r[1]) for r in runs], np.int64)
    n = len(xs) + int(nr.sum())
    pts, fv, rs = np.empty((n + 1, 3)), np.empty(n), np.empty(n, bool)
    pts[0] = pos
    if runs:
        # block r of the runs' concatenation comes after the single moves before its run
        into = np.repeat(np.array([r[0] for r in runs], np.int64), nr) + np.arange(int(nr.sum()))
        first = np.concatenate([[0], np.cumsum(nr)[:-1]])  # each run's first block among the runs' blocks
        pts[1 + into, :2] = np.concatenate([r[1] for r in runs])
        pts[1 + into, 2] = np.repeat([r[4] for r in runs], nr)
        # each block's feed: its F word, else the last one before it in its run, else the feed before the run
        f = np.concatenate([r[2] for r in runs]).astype(float)
        f[first] = [r[3] for r in runs]
        f = f[np.maximum.accumulate(np.where(f == f, np.arange(len(f)), 0))]
        fv[into] = f / 60.0
        starts = np.zeros(len(f), bool)
        starts[first] = [r[5] for r in runs]
        rs[into] = starts
        single = np.ones(n, bool)
        single[into] = False
    else:
        single = slice(None)
    pts[1:][single] = np.column_stack([xs, ys, zs]).reshape(-1, 3)
    fv[single] = feeds
    rs[single] = rest
    bt = _run_times(pts, fv, settings, rs) if len(fv) else np.zeros(0)
    if len(bt):  # every run with motion ends in a stop: st_go_idle waits $1
        run = np.cumsum(rs)
        est.stops = len(np.unique(run[bt > 0]))
        est.idle = est.stops * settings.idle_delay
    bt = bt[bt > 0]  # the blocks GRBL keeps (zero-length ones take no time)
    est.block_times, est.blocks, est.motion = bt, len(bt), float(bt.sum())
    return est


_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


def parse_gcode(text: str) -> list[tuple]:
    """The moves of a G-code text (the subset doodlecam writes, plus modal G0/G1), for estimate_program."""
    program: list[tuple] = []
    motion = None
    for no, raw in enumerate(text.splitlines(), 1):
        line = re.sub(r"\(.*?\)", "", raw.split(";")[0]).upper().strip()
        if not line:
            continue
        words = _WORD.findall(line)
        g = [float(v) for k, v in words if k == "G"]
        vals = {k: float(v) for k, v in words if k in "XYZFPIJ"}
        if any(k == "M" for k, _ in words) or 10.0 in g:  # G10 writes EEPROM: GRBL synchronises first
            program.append(("M", line))
        if 10.0 in g or 92.0 in g:
            continue  # offsets move nothing
        if 4.0 in g:
            program.append(("G4", vals.get("P", 0.0)))
            continue
        for m in (0.0, 1.0, 2.0, 3.0):
            if m in g:
                motion = f"G{int(m)}"
        if any(k in vals for k in "XYZ"):
            if motion is None:
                raise InputError(f"line {no}: a move before any G0/G1; cannot estimate")
            if motion in ("G2", "G3"):
                program.append((motion, vals.get("X"), vals.get("Y"), vals.get("Z"), vals.get("I"), vals.get("J"),
                                vals.get("F")))
            else:
                program.append((motion, vals.get("X"), vals.get("Y"), vals.get("Z"), vals.get("F")))
        elif "F" in vals and motion == "G1":
            program.append(("G1", None, None, None, vals["F"]))  # a feed-only line sets the modal feed
    return program


def estimate_gcode(text: str, settings: GrblSettings = GrblSettings(), start=(0.0, 0.0, 0.0)) -> Estimate:
    """Estimate GRBL 1.1's time for a G-code text."""
    return estimate_program(parse_gcode(text), settings, start)


_HEADER_ESTIMATE = re.compile(r"^;\s*GRBL 1\.1 estimate ([0-9.]+) s", re.M)


def header_estimate(text: str) -> float | None:
    """The GRBL estimate (s) the G-code post wrote in a file's header, if it did."""
    said = _HEADER_ESTIMATE.search(text[:4000])
    return float(said.group(1)) if said else None


def time_left(text: str, lines, machine=None) -> np.ndarray:
    """Seconds left before each prepared line (index k: lines [0, k) done), GRBL's planner model in total.

    The total is this module's model of the whole program (accelerations, junctions, look-ahead, pen
    synchronisations, step-rounded targets): the figure the G-code post wrote in the header, else the
    model run here with ``machine``'s settings. Each line gets that total's share of its nominal time
    (``protocol.line_durations``), so the count down is GRBL's at the start and reaches 0 with the last line.
    """
    from doodlecam.link.grbl.protocol import line_durations

    d = np.asarray(line_durations(lines), float)
    said = header_estimate(text)
    if said is not None:
        total = said
    elif machine is not None:
        total = estimate_gcode(text, GrblSettings.from_machine(machine), start=tuple(machine.home)).total
    else:
        total = float(d.sum())
    if d.sum() > 0:
        d *= total / d.sum()
    return np.concatenate([[d.sum()], d.sum() - np.cumsum(d)]).clip(min=0.0)
