"""The PLC packet file: the report's header + command list, as bytes.

The DoodleBot PLC (report sections 2.1.0.5 and 3.4.2.2, table 3.4.2) takes a
header (delta_time, no_commands, max_accel_x/y, move_speed_x/y) and then a
numbered command list. Each command is

* type 0, DRAW: x, y are axis *velocity targets* in steps/s. The PLC ramps
  each axis linearly from its current velocity to the target over one
  delta_time. DRAW commands are executed pen-down.
* type 1, MOVE: x, y are an absolute *position* in steps from the machine
  origin, reached with the PLC's own move profile (move_speed, max_accel),
  from rest to rest. MOVE commands are executed pen-up.
* type 2, PAUSE (format version 2): a pen change. The PLC lifts the pen,
  stops and holds the job until the operator has fitted pen number x and
  resumes it; y is 0. It comes between strokes, with the machine at rest.

The report's machine has no separate pen command, so the pen follows the
command type: the PLC lowers the pen (and waits its down delay) before a DRAW
that follows a MOVE, and lifts it before a MOVE that follows a DRAW. A DRAW
after a DRAW keeps the pen down, so two strokes that meet (the pieces of a
split outline) are written as one run of DRAWs without a MOVE between.

The byte layout is documented in docs/formats.md; this module is the one
reader and writer (the UDP transport and ``doodlecam inspect`` use it too).
"""

from __future__ import annotations

import io
import math
import zlib
from dataclasses import dataclass

import numba
import numpy as np

from doodlecam.errors import InputError, OutputError

MAGIC = b"\x89DCPLC\r\n"  # high bit + CRLF catch 7-bit and text-mode mangling, as PNG does
VERSION = 2  # written; version 1 files (no PAUSE, 56-byte header) are still read
DRAW, MOVE, PAUSE = 0, 1, 2

HEADER_V1_DTYPE = np.dtype([
    ("magic", "S8"),
    ("version", "<u2"),
    ("record_size", "<u2"),
    ("no_commands", "<u4"),
    ("delta_time", "<f8"),
    ("steps_per_mm_x", "<f8"),
    ("steps_per_mm_y", "<f8"),
    ("max_accel_x", "<i4"),
    ("max_accel_y", "<i4"),
    ("move_speed_x", "<i4"),
    ("move_speed_y", "<i4"),
])
# Version 2 adds the most any DRAW ramp of the file accelerates each axis: for a Cartesian
# machine at most max_accel; for a five-bar the pen's, which the crank limits allow to exceed
# the MOVE limits. A PLC can refuse a job its drives cannot follow before it starts.
HEADER_DTYPE = np.dtype(HEADER_V1_DTYPE.descr + [("draw_accel_x", "<i4"), ("draw_accel_y", "<i4")])
HEADER_SIZES = {1: HEADER_V1_DTYPE.itemsize, 2: HEADER_DTYPE.itemsize}
RECORD_DTYPE = np.dtype([
    ("command_no", "<u4"),
    ("type", "<u2"),
    ("reserved", "<u2"),  # written as 0, ignored by version-1 readers
    ("x", "<i4"),
    ("y", "<i4"),
])
TRAILER_SIZE = 4  # CRC-32 (zlib) of every byte before it, little-endian uint32
assert HEADER_V1_DTYPE.itemsize == 56 and HEADER_DTYPE.itemsize == 64 and RECORD_DTYPE.itemsize == 16

_I32 = np.iinfo(np.int32)


@dataclass(frozen=True)
class PlcHeader:
    """The report's header plus steps/mm, so a reader can convert back to mm."""

    delta_time: float  # s, period of the DRAW velocity samples
    no_commands: int
    max_accel_x: int  # steps/s^2
    max_accel_y: int  # steps/s^2
    move_speed_x: int  # steps/s, for MOVE commands
    move_speed_y: int  # steps/s
    steps_per_mm_x: float
    steps_per_mm_y: float
    # version 2: the largest DRAW ramp acceleration in the file, steps/s^2 (write_plc
    # computes them from the commands; 0 in a version 1 file, which does not say)
    draw_accel_x: int = 0
    draw_accel_y: int = 0
    version: int = VERSION  # of the file read; write_plc always writes VERSION


@dataclass(frozen=True, slots=True)
class PlcCommand:
    """One command: DRAW (type 0) velocity in steps/s, MOVE (type 1) position in steps."""

    command_no: int  # 1..no_commands
    type: int  # DRAW = 0 (pen down), MOVE = 1 (pen up), PAUSE = 2 (pen change: x = the pen number)
    x: int
    y: int

    @property
    def is_draw(self) -> bool:
        return self.type == DRAW


# ---------------------------------------------------------------- from a job

def _ceil_rate(value: float) -> int:
    # Round what the file asks of the drives up: the header never understates it.
    return max(0, min(int(_I32.max), int(math.ceil(value * (1 - 1e-12)))))


def draw_accelerations(arr: np.ndarray, delta_time: float) -> tuple[float, float]:
    """The largest |change of DRAW target| / delta_time per axis (steps/s^2): the PLC's
    ramps. A run of DRAWs starts from rest (after a MOVE, a PAUSE or the file's start)."""
    if not len(arr):
        return 0.0, 0.0
    draw = (arr["type"] == DRAW)[:, None]
    v = np.where(draw, np.column_stack([arr["x"], arr["y"]]).astype(np.float64), 0.0)
    dv = np.abs(np.diff(np.vstack([np.zeros((1, 2)), v]), axis=0))[draw[:, 0]]
    return tuple(float(a) / delta_time for a in dv.max(axis=0, initial=0.0))  # type: ignore[return-value]


def _floor_rate(value: float) -> int:
    # Round limits down: the PLC must never be told it may exceed the profile.
    return max(1, min(int(_I32.max), int(math.floor(value * (1 + 1e-12)))))


def whole_step_targets(velocity, steps_per_mm) -> np.ndarray:
    """DRAW targets (steps/s, whole numbers as floats) of velocity targets (M, 2) in mm/s.

    Rounds the running sum, not each sample: the ramp model's position is
    dT * (sum of targets), so this keeps the drawn position within a fraction
    of a step of the plan instead of a random walk of rounding errors, while
    every target stays within 1 step/s of the exact value and every change
    between two within 2 (plan.sample.whole_step_limits plans for that).
    """
    v = np.ascontiguousarray(velocity, dtype=float).reshape(-1, 2)
    # the compiled run's arithmetic is NumPy's here (products, a running sum, np.round, differences), in one
    # call instead of seven: the planner's checks ask it for every stroke
    return _whole_step_runs(v, np.ascontiguousarray(steps_per_mm, dtype=float), np.array([0, len(v)], np.int64))


@numba.njit(cache=True, nogil=True)
def _whole_step_runs(velocity, steps_per_mm, off):  # pragma: no cover - compiled
    """whole_step_targets of every stroke's velocity rows off[s]:off[s + 1] (concatenated), in one call: the
    same products, running sums, roundings and differences, so the same numbers."""
    out = np.empty_like(velocity)
    for s in range(off.shape[0] - 1):
        for a in range(2):
            last = 0.0
            acc = 0.0
            for r in range(off[s], off[s + 1]):
                x = velocity[r, a] * steps_per_mm[a]
                acc = x if r == off[s] else acc + x
                cum = np.rint(acc)
                out[r, a] = cum - last
                last = cum
    return out


def commands_array(job) -> tuple[PlcHeader, np.ndarray]:
    """Like :func:`commands_from_job`, as a RECORD_DTYPE array (fast path: every stroke's commands placed by
    array operations, the DRAW targets of all strokes from one compiled call)."""
    m = job.machine
    spm = np.array([m.x.steps_per_mm, m.y.steps_per_mm])
    if len(job.samples) != len(job.strokes):
        raise OutputError("job has no velocity samples for its strokes; plan and sample it before writing PLC commands")
    dts = {s.delta_time for s in job.samples}
    if len(dts) > 1:
        raise OutputError(f"job strokes were sampled with different periods {sorted(dts)}; the PLC header has one delta_time, re-sample the job")
    dt = dts.pop() if dts else m.delta_time
    home = job.travels[-1].end if job.travels else np.asarray(m.home, dtype=float)

    changes = set(job.pen_pauses)  # each pen change, and the first pen when the machine has several
    pens = job.pen_numbers if changes else ()
    ns = len(job.samples)
    vel = [np.asarray(s.velocity, float).reshape(-1, 2) for s in job.samples]
    counts = np.array([len(v) for v in vel], np.int64)
    off = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    draws = _whole_step_runs(np.concatenate(vel) if ns else np.zeros((0, 2)), spm, off)
    # per stroke: a PAUSE where a pen change comes before it (at rest, the pen lifts, the operator fits pen
    # pens[k]), a MOVE to its start unless it goes on from the last one's end (the pen stays down), its DRAWs
    pause = np.zeros(ns, np.int64)
    pause[sorted(k for k in changes if k < ns and pens[k])] = 1
    lift = np.array(job.lifts[:ns], bool).astype(np.int64)
    size = pause + lift + counts
    first = np.concatenate([[0], np.cumsum(size)]).astype(np.int64)  # each stroke's first row
    n = int(first[-1]) + 1
    out = np.zeros(n, RECORD_DTYPE)
    xy = np.empty((n, 2))
    types = np.full(n, DRAW, dtype=np.uint16)
    k = np.flatnonzero(pause)
    types[first[k]] = PAUSE
    xy[first[k]] = np.column_stack([[pens[i] for i in k.tolist()], np.zeros(len(k))]) if len(k) else np.zeros((0, 2))
    k = np.flatnonzero(lift)
    rows = first[k] + pause[k]
    types[rows] = MOVE
    xy[rows] = np.round(np.array([job.samples[i].start for i in k.tolist()], float).reshape(-1, 2) * spm)
    # the DRAWs: row r of stroke s goes to first[s] + pause[s] + lift[s] + (r - off[s])
    xy[np.repeat(first[:-1] + pause + lift - off[:-1], counts) + np.arange(int(off[-1]))] = draws
    i = n - 1
    types[i], xy[i] = MOVE, np.round(np.asarray(home) * spm)
    if np.abs(xy).max(initial=0) > _I32.max:
        raise OutputError("a PLC command exceeds the int32 range; check steps_per_mm and the work area in the machine profile")
    out["command_no"] = np.arange(1, n + 1)
    out["type"] = types
    out["x"], out["y"] = xy[:, 0], xy[:, 1]
    vx, vy = (v * k for v, k in zip(m.move_speed, spm))
    ax, ay = draw_accelerations(out, float(dt))
    header = PlcHeader(
        delta_time=float(dt), no_commands=n,
        max_accel_x=_floor_rate(m.x.max_acceleration * spm[0]),
        max_accel_y=_floor_rate(m.y.max_acceleration * spm[1]),
        move_speed_x=_floor_rate(vx), move_speed_y=_floor_rate(vy),
        steps_per_mm_x=float(spm[0]), steps_per_mm_y=float(spm[1]),
        draw_accel_x=_ceil_rate(ax), draw_accel_y=_ceil_rate(ay),
    )
    return header, out


def commands_from_job(job) -> tuple[PlcHeader, list[PlcCommand]]:
    """Header and commands for a planned, sampled Job.

    Per stroke: a PAUSE first where the operator fits a pen (job.pen_pauses), a MOVE
    to its start (rounded to steps), then one DRAW per velocity sample
    (steps/s); finally a MOVE home. Numbered 1..N. A stroke that starts where
    the one before ended (``job.lifts``) gets no MOVE: its DRAWs follow the
    last ones, so the pen stays down between them.
    """
    header, arr = commands_array(job)
    return header, to_commands(arr)


# ---------------------------------------------------------------- array <-> objects

def to_array(commands) -> np.ndarray:
    """PlcCommand list (or a RECORD_DTYPE array, returned as is) -> RECORD_DTYPE array."""
    if isinstance(commands, np.ndarray):
        return commands.astype(RECORD_DTYPE, copy=False)
    rows = ((c.command_no, c.type, 0, c.x, c.y) for c in commands)
    return np.fromiter(rows, dtype=RECORD_DTYPE, count=len(commands))


def to_commands(arr: np.ndarray) -> list[PlcCommand]:
    cols = (arr["command_no"].tolist(), arr["type"].tolist(), arr["x"].tolist(), arr["y"].tolist())
    return [PlcCommand(*row) for row in zip(*cols)]


# ---------------------------------------------------------------- bytes

def write_plc(header: PlcHeader, commands) -> bytes:
    """The packet file's bytes for a header and its commands (list or array)."""
    arr = to_array(commands)
    if header.no_commands != len(arr):
        raise ValueError(f"header says {header.no_commands} commands but {len(arr)} were given")
    h = np.zeros(1, HEADER_DTYPE)
    h["magic"], h["version"], h["record_size"] = MAGIC, VERSION, RECORD_DTYPE.itemsize
    for name in PlcHeader.__dataclass_fields__:
        if name != "version":
            h[name] = getattr(header, name)
    ax, ay = draw_accelerations(arr, header.delta_time)
    h["draw_accel_x"], h["draw_accel_y"] = _ceil_rate(ax), _ceil_rate(ay)
    body = h.tobytes() + arr.tobytes()
    return body + np.array([zlib.crc32(body)], "<u4").tobytes()


def read_plc(data: bytes, name: str = "PLC data") -> tuple[PlcHeader, list[PlcCommand]]:
    """Parse and check a packet file; raise InputError naming ``name`` if it is not valid."""
    header, arr = read_plc_array(data, name)
    return header, to_commands(arr)


def read_plc_array(data: bytes, name: str = "PLC data") -> tuple[PlcHeader, np.ndarray]:
    """Like :func:`read_plc`, with the commands as a read-only RECORD_DTYPE array."""
    def fail(why: str, todo: str = "re-export it with 'doodlecam convert --post plc'") -> InputError:
        return InputError(f"{name}: {why}; {todo}")

    data = bytes(data)
    if data[:len(MAGIC)] != MAGIC[:len(data)]:  # a short prefix of MAGIC is truncated, below
        raise fail("not a doodlecam PLC file (bad magic)", "give a .plc file written by doodlecam")
    if len(data) < HEADER_V1_DTYPE.itemsize + TRAILER_SIZE:
        raise fail(f"truncated PLC file ({len(data)} bytes, shorter than the {HEADER_V1_DTYPE.itemsize + TRAILER_SIZE}-byte header and checksum)")
    version = int(np.frombuffer(data, "<u2", count=1, offset=8)[0])
    if version not in HEADER_SIZES:
        raise fail(f"PLC file format version {version} is not supported (this doodlecam reads versions "
                   f"{', '.join(map(str, HEADER_SIZES))})", "use the doodlecam version that wrote it or re-export it")
    hsize = HEADER_SIZES[version]
    if len(data) < hsize + TRAILER_SIZE:
        raise fail(f"truncated PLC file ({len(data)} bytes, shorter than the {hsize + TRAILER_SIZE}-byte header and checksum)")
    h = np.frombuffer(data, HEADER_DTYPE if version == 2 else HEADER_V1_DTYPE, count=1)[0]
    if int(h["record_size"]) != RECORD_DTYPE.itemsize:
        raise fail(f"PLC file has {int(h['record_size'])}-byte command records, version {version} uses {RECORD_DTYPE.itemsize}")
    n = int(h["no_commands"])
    expected = hsize + n * RECORD_DTYPE.itemsize + TRAILER_SIZE
    if len(data) != expected:
        what = "truncated" if len(data) < expected else "has trailing bytes"
        raise fail(f"PLC file {what}: header says {n} commands ({expected} bytes) but it has {len(data)} bytes")
    stored = int(np.frombuffer(data, "<u4", count=1, offset=expected - TRAILER_SIZE)[0])
    actual = zlib.crc32(data[:expected - TRAILER_SIZE])
    if stored != actual:
        raise fail(f"PLC file is corrupt (CRC-32 {actual:08x} does not match the stored {stored:08x})")
    arr = np.frombuffer(data, RECORD_DTYPE, count=n, offset=hsize)
    # A valid checksum only proves the bytes are intact; check they make sense.
    dt, sx, sy = float(h["delta_time"]), float(h["steps_per_mm_x"]), float(h["steps_per_mm_y"])
    if not all(math.isfinite(v) and v > 0 for v in (dt, sx, sy)):
        raise fail(f"PLC header has a non-positive delta_time or steps_per_mm ({dt:g}, {sx:g}, {sy:g})")
    if n and not np.array_equal(arr["command_no"], np.arange(1, n + 1)):
        k = int(np.argmax(arr["command_no"] != np.arange(1, n + 1)))
        raise fail(f"PLC command {k + 1} is numbered {int(arr['command_no'][k])}; commands must run 1..{n}")
    top = PAUSE if version >= 2 else MOVE
    bad = np.flatnonzero(arr["type"] > top)
    if len(bad):
        known = "0 = DRAW, 1 = MOVE, 2 = PAUSE" if version >= 2 else "0 = DRAW, 1 = MOVE; PAUSE needs version 2"
        raise fail(f"PLC command {bad[0] + 1} has unknown type {int(arr['type'][bad[0]])} ({known})")
    pauses = np.flatnonzero(arr["type"] == PAUSE)
    if len(pauses):
        if np.any(arr["x"][pauses] < 1) or np.any(arr["y"][pauses] != 0):
            k = int(pauses[np.argmax((arr["x"][pauses] < 1) | (arr["y"][pauses] != 0))])
            raise fail(f"PLC command {k + 1} is a PAUSE for pen {int(arr['x'][k])}, {int(arr['y'][k])}; "
                       "a PAUSE names a pen number >= 1 and 0")
        before = pauses[pauses > 0] - 1
        moving = before[(arr["type"][before] == DRAW) & ((arr["x"][before] != 0) | (arr["y"][before] != 0))]
        if len(moving):
            raise fail(f"PLC command {int(moving[0]) + 2} is a PAUSE while the machine moves; a pen change comes "
                       "between strokes, at rest")
    extra = {}
    if version >= 2:
        extra = {"draw_accel_x": int(h["draw_accel_x"]), "draw_accel_y": int(h["draw_accel_y"])}
        ax, ay = draw_accelerations(arr, dt)
        if _ceil_rate(ax) > extra["draw_accel_x"] or _ceil_rate(ay) > extra["draw_accel_y"]:
            raise fail(f"PLC file's DRAW ramps accelerate up to ({ax:.0f}, {ay:.0f}) steps/s^2, above its header's "
                       f"draw_accel ({extra['draw_accel_x']}, {extra['draw_accel_y']})")
    header = PlcHeader(
        delta_time=dt, no_commands=n,
        max_accel_x=int(h["max_accel_x"]), max_accel_y=int(h["max_accel_y"]),
        move_speed_x=int(h["move_speed_x"]), move_speed_y=int(h["move_speed_y"]),
        steps_per_mm_x=sx, steps_per_mm_y=sy, version=version, **extra,
    )
    return header, arr


# ---------------------------------------------------------------- text

def to_csv(header: PlcHeader, commands) -> str:
    """A CSV dump: '#' comment lines with the header, then command_no,type,x,y.

    Units: DRAW x, y in steps/s, MOVE x, y in steps (see the module docstring).
    """
    arr = to_array(commands)
    buf = io.StringIO()
    buf.write(f"# doodlecam PLC commands, format version {header.version}\n")
    for key, value in vars(header).items():
        buf.write(f"# {key}={value}\n")
    buf.write("command_no,type,x,y\n")
    table = np.column_stack([arr["command_no"], arr["type"], arr["x"], arr["y"]]).astype(np.int64)
    np.savetxt(buf, table, fmt="%d", delimiter=",")
    return buf.getvalue()
