"""The UDP wire format between the PC and the DoodleBot PLC (docs/protocol.md).

The report (section 3.4) has the PLC announce READY, the PC answer with the
header, and the PLC request commands as its command buffer frees slots. This
module is that exchange made robust against loss, duplication, reordering,
corruption and delay:

* every datagram carries a magic, a version, its type, the job id, the
  sender's *origin* (the PC's session id or the PLC's boot id), a per-origin
  sequence number, and a CRC-32 trailer; a datagram that fails any check is
  dropped, never guessed at;
* commands travel in the packet file's own 16-byte records with their
  ``command_no``; the PLC stores command c only in buffer slot (c-1) mod
  BUFFER_SIZE and only while c is inside its window, and executes strictly in
  command_no order, so a duplicate, late or reordered DATA can neither repeat
  nor misorder a command;
* the PLC drives retransmission: it re-requests what has not arrived within
  its retransmission timeout; the PC only answers requests (stateless, so a
  duplicate or late REQUEST costs bandwidth, never correctness);
* version 2 added, for shared networks: every field range-checked in
  ``decode``; a random session nonce per PC run in ``origin`` and a job owner
  token in HEADER / CANCEL (the PLC binds a job to them); an HMAC-SHA256 tag
  with a pre-shared key and ``ReplayWindow`` over ``seq``; NAK reasons that
  name the busy job's owner and when a content finished;
* version 3 (this one) binds every session to a **challenge** the PLC draws
  at random (a fresh one at power-up and each time a HEADER or CANCEL uses
  it up) and carries in every datagram: a HEADER or CANCEL must carry the
  PLC's current challenge, every DATA / STOP / HELLO of the session the one
  its HEADER carried. A captured session (or HEADER) names a challenge that
  is used up, however many jobs or restarts later, so it starts and moves
  nothing (``Nak.STALE_CHALLENGE``). Versions 1 and 2 are recognised
  (``OldVersion``) and declined.

Pure encoding and decoding here; the PLC simulator is ``simulator``, the PC side
``sender``. Also the PLC command semantics both need: the planned position
and velocity after every command (``planned_states``).
"""

from __future__ import annotations

import hmac
import ipaddress
import math
import struct
import zlib
from hashlib import sha256
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from doodlecam.link.plc.packetfile import DRAW, MOVE, PAUSE, RECORD_DTYPE, PlcHeader

MAGIC = b"DP"
VERSION = 3
OLD_VERSIONS = (1, 2)  # recognised, and declined with a clear message
COMMON = struct.Struct("<2sBBIQIB3xQ")  # magic, version, type, job_id, origin, seq, flags, challenge
CRC = struct.Struct("<I")
TAG_SIZE = 32  # HMAC-SHA256 tag before the CRC when the AUTH flag is set
AUTH = 0x01  # COMMON flags: the datagram carries an HMAC-SHA256 tag
MAX_DATAGRAM = 1472  # one Ethernet frame (1500 - IP 20 - UDP 8): no IP fragmentation
MAX_PER_DATA = 64  # 64 x 16-byte records + 32 + 8 + 32 + 4 bytes of framing = 1100 bytes
MAX_RANGES = 16  # ranges per REQUEST
MAX_COMMAND = 0xFFFFFFFF  # command numbers are uint32, from 1
AGAIN = 0x01  # HEADER flags: run this content even though the PLC finished it before
MAX_DELTA_TIME = 1.0  # s; the report samples every 40 ms


class Msg(IntEnum):
    # PC -> PLC
    HELLO = 0x01
    HEADER = 0x02
    DATA = 0x03
    STOP = 0x04
    CANCEL = 0x05
    # PLC -> PC
    READY = 0x10
    REQUEST = 0x11
    STATUS = 0x12
    DONE = 0x13
    FAULT = 0x14
    NAK = 0x15


class State(IntEnum):
    """The Governor's states (report section 3.4.3)."""

    POWER_ON = 0
    A_INIT = 1
    B_READY = 2
    C_BUFFER = 3
    D_OPERATING = 4


class Fault(IntEnum):
    NONE = 0
    BOUNDARY = 1  # a command would cross the work-area boundary: stopped before it, job aborted
    LIMIT_SWITCH = 2  # a limit switch tripped: immediate stop, position lost, re-initialise
    UNDERRUN = 3  # the next command was not there in time: stopped, job held for resume
    STOPPED = 4  # the PC asked to stop (pause): job held for resume
    CANCELLED = 5  # the PC cancelled the job
    BAD_COMMAND = 6  # a command the PLC cannot execute (unknown type)
    POWER_LOST = 7  # the PLC restarted during the job: held, resumes at its next command
    PEN_CHANGE = 8  # a PAUSE command ran: pen up, job held until the operator has fitted the pen and resumes


class Nak(IntEnum):
    BUSY = 1  # another job is running; detail = its job id
    FINISHED = 2  # this job id already ran to the end or was cancelled/aborted; detail = Fault
    START_MISMATCH = 3  # resume point differs from the held job's; detail = the PLC's next command
    BAD_HEADER = 4  # header values the PLC cannot use
    NOT_READY = 5  # PLC is not in B_ready (not initialised); detail = State
    ALREADY_DONE = 6  # this content (job_crc) ran to its end; detail = that job id, when = its end (Unix s)
    AUTH_REQUIRED = 7  # the PLC has a key and the datagram had no valid tag
    STALE_CHALLENGE = 8  # a HEADER / CANCEL without the PLC's current challenge (the NAK carries it): nothing done



_NAK_REASONS = frozenset(n.value for n in Nak)

FAULT_TEXT = {
    Fault.NONE: "no fault",
    Fault.BOUNDARY: "a command would cross the work-area boundary; the PLC stopped before it and aborted the job",
    Fault.LIMIT_SWITCH: "a limit switch tripped; the PLC stopped at once and must be re-initialised (press a Y limit switch)",
    Fault.UNDERRUN: "the PLC ran out of commands while drawing and stopped",
    Fault.STOPPED: "stopped on request",
    Fault.CANCELLED: "job cancelled",
    Fault.BAD_COMMAND: "a command has an unknown type",
    Fault.POWER_LOST: "the PLC restarted during the job",
    Fault.PEN_CHANGE: "waiting for a pen change",
}

# flags in the status block
HELD = 0x01  # the PLC holds a suspended job (job_id / job_crc / executed say which and where)

_STATUS = struct.Struct("<BBBBIIIIiiII")  # state fault pen flags buffer_size executed buffered fault_cmd x y last_done job_crc
_HEADER = struct.Struct("<IIIIdddiiiiddiiQ")
_CANCEL = struct.Struct("<Q")  # the job's owner token
_DATA = struct.Struct("<IHxx")
_STOP = struct.Struct("<B3x")
_NREQ = struct.Struct("<Hxx")
_RANGE = struct.Struct("<II")
_NAK = struct.Struct("<HHIII")  # reason, owner_port, detail, owner_ip (IPv4), when (Unix s)


class ProtocolError(ValueError):
    """A datagram that is not a valid message (dropped by the receiver)."""


class OldVersion(ProtocolError):
    """A well-formed datagram of an earlier protocol version (declined, not interpreted)."""

    def __init__(self, version: int):
        super().__init__(f"protocol version {version}, this side speaks {VERSION}")
        self.version = version


class AuthError(ProtocolError):
    """A datagram without a valid HMAC tag where a key is set (or with a tag where none is)."""


class ReplayWindow:
    """Anti-replay window over a session's ``seq`` (as IPsec's, RFC 4303 section 3.4.3).

    Accepts each sequence number at most once: anything above the highest seen,
    or within ``size`` below it and not seen yet (so reordering costs nothing);
    older or repeated numbers are refused.
    """

    def __init__(self, size: int = 64):
        self.size, self.top, self.bits = size, 0, 0

    def accept(self, seq: int) -> bool:
        if seq > self.top:
            shift = seq - self.top
            self.bits = ((self.bits << shift) | 1) & ((1 << self.size) - 1) if shift < self.size else 1
            self.top = seq
            return True
        back = self.top - seq
        if seq == 0 or back >= self.size or self.bits >> back & 1:
            return False
        self.bits |= 1 << back
        return True


@dataclass(frozen=True)
class JobHeader:
    """The report's header (table 3.4.2) plus what a robust resume needs.

    Rates in steps/s (squared), positions in steps. ``start_at`` is the first
    command to execute (1 for a fresh job); ``resume_*`` are the *planned*
    position and velocity after command ``start_at - 1`` (zero when 1).
    """

    job_crc: int
    no_commands: int
    start_at: int
    delta_time: float
    steps_per_mm_x: float
    steps_per_mm_y: float
    max_accel_x: int
    max_accel_y: int
    move_speed_x: int
    move_speed_y: int
    resume_x: float = 0.0
    resume_y: float = 0.0
    resume_vx: int = 0
    resume_vy: int = 0
    flags: int = 0
    token: int = 0  # the job's owner token: random, chosen by the PC that starts the job (docs/protocol.md 1.5)

    @classmethod
    def from_plc(cls, h: PlcHeader, job_crc: int, start_at: int = 1, resume=((0.0, 0.0), (0, 0)), *,
                 token: int = 0, flags: int = 0) -> "JobHeader":
        (rx, ry), (rvx, rvy) = resume
        return cls(job_crc, h.no_commands, start_at, h.delta_time, h.steps_per_mm_x, h.steps_per_mm_y,
                   h.max_accel_x, h.max_accel_y, h.move_speed_x, h.move_speed_y,
                   float(rx), float(ry), int(rvx), int(rvy), flags, token)

    def problem(self) -> str | None:
        """Why a PLC cannot run this header (field ranges of docs/protocol.md 1.3), or None."""
        floats = (self.delta_time, self.steps_per_mm_x, self.steps_per_mm_y, self.resume_x, self.resume_y)
        if not all(math.isfinite(v) for v in floats):
            return "a value is not finite"
        if not 1 <= self.start_at <= self.no_commands:
            return "start_at outside 1..no_commands"
        if not 0.0 < self.delta_time <= MAX_DELTA_TIME:
            return f"delta_time outside (0, {MAX_DELTA_TIME:g}] s"
        if min(self.steps_per_mm_x, self.steps_per_mm_y, self.max_accel_x, self.max_accel_y,
               self.move_speed_x, self.move_speed_y) <= 0:
            return "a scale, acceleration or speed is not positive"
        if self.flags & ~AGAIN:
            return f"unknown flags 0x{self.flags:x}"
        return None

    def pack(self) -> bytes:
        return _HEADER.pack(self.job_crc, self.no_commands, self.start_at, self.flags, self.delta_time,
                            self.steps_per_mm_x, self.steps_per_mm_y, self.max_accel_x, self.max_accel_y,
                            self.move_speed_x, self.move_speed_y, self.resume_x, self.resume_y,
                            self.resume_vx, self.resume_vy, self.token)

    @classmethod
    def unpack(cls, body: bytes) -> "JobHeader":
        (crc, n, start, flags, dt, sx, sy, ax, ay, vx, vy, rx, ry, rvx, rvy, token) = _HEADER.unpack(body)
        return cls(crc, n, start, dt, sx, sy, ax, ay, vx, vy, rx, ry, rvx, rvy, flags, token)


@dataclass(frozen=True)
class Status:
    """The PLC's state, carried by every PLC -> PC message."""

    state: int = State.POWER_ON
    fault: int = Fault.NONE
    pen: int = 0  # 1 = down
    flags: int = 0
    buffer_size: int = 0
    executed: int = 0  # commands of job_id executed (counterCommand.counter)
    buffered: int = 0  # highest command_no received with nothing missing below (counterBuffer.counter)
    fault_command: int = 0  # command_no the fault happened at (0 if none)
    x: int = 0  # actual position, steps
    y: int = 0
    last_done_job: int = 0  # the last job id that ran to its end
    job_crc: int = 0  # CRC-32 of the current or held job's packet file

    @property
    def held(self) -> bool:
        return bool(self.flags & HELD)

    def pack(self) -> bytes:
        return _STATUS.pack(self.state, self.fault, self.pen, self.flags, self.buffer_size, self.executed,
                            self.buffered, self.fault_command, self.x, self.y, self.last_done_job, self.job_crc)

    @classmethod
    def unpack(cls, body: bytes) -> "Status":
        return cls(*_STATUS.unpack(body))


@dataclass(frozen=True)
class Message:
    """A decoded datagram. Which payload fields are set depends on ``type``."""

    type: Msg
    job_id: int
    origin: int
    seq: int
    header: JobHeader | None = None
    status: Status | None = None
    first: int = 0  # DATA: command_no of the first record
    records: np.ndarray | None = None  # DATA: RECORD_DTYPE array
    ranges: tuple[tuple[int, int], ...] = ()  # REQUEST: (first command_no, count)
    mode: int = 0  # STOP: 0 = at the end of the current stroke, 1 = now
    token: int = 0  # CANCEL: the owner token of the job to cancel
    reason: int = 0  # NAK
    detail: int = 0  # NAK
    owner: tuple[str, int] | None = None  # NAK BUSY: the address of the sender whose job runs
    when: int = 0  # NAK ALREADY_DONE: Unix s the content finished
    authenticated: bool = False  # carried a valid HMAC tag
    # PC -> PLC: the PLC challenge the datagram answers (HEADER / CANCEL: the current one; DATA / STOP / HELLO:
    # its session's); PLC -> PC: the PLC's current challenge, the one the next HEADER or CANCEL must carry
    challenge: int = 0


# ---------------------------------------------------------------- encoding

def _tag(key: bytes, msg) -> bytes:
    return hmac.new(key, msg, sha256).digest()


def frame(kind: int, job_id: int, origin: int, seq: int, body: bytes = b"", key: bytes | None = None,
          challenge: int = 0) -> bytes:
    """One datagram: common header, body, HMAC-SHA256 tag (when ``key``), CRC-32."""
    head = COMMON.pack(MAGIC, VERSION, kind, job_id & 0xFFFFFFFF, origin & 0xFFFFFFFFFFFFFFFF, seq & 0xFFFFFFFF,
                       AUTH if key else 0, challenge & 0xFFFFFFFFFFFFFFFF)
    msg = head + body
    if key:
        msg += _tag(key, msg)
    return msg + CRC.pack(zlib.crc32(msg))


# PC -> PLC. ``challenge``: HEADER and CANCEL the PLC's current one, DATA / STOP / HELLO their session's.

def hello(origin: int, seq: int, job_id: int = 0, key: bytes | None = None, challenge: int = 0) -> bytes:
    return frame(Msg.HELLO, job_id, origin, seq, key=key, challenge=challenge)


def header(origin: int, seq: int, job_id: int, h: JobHeader, key: bytes | None = None, challenge: int = 0) -> bytes:
    return frame(Msg.HEADER, job_id, origin, seq, h.pack(), key, challenge)


def data(origin: int, seq: int, job_id: int, records: np.ndarray, key: bytes | None = None,
         challenge: int = 0) -> bytes:
    """DATA with consecutive records (RECORD_DTYPE, at most MAX_PER_DATA)."""
    if not 0 < len(records) <= MAX_PER_DATA:
        raise ValueError(f"DATA carries 1..{MAX_PER_DATA} records, got {len(records)}")
    return frame(Msg.DATA, job_id, origin, seq,
                 _DATA.pack(int(records["command_no"][0]), len(records)) + records.astype(RECORD_DTYPE, copy=False).tobytes(),
                 key, challenge)


def stop(origin: int, seq: int, job_id: int, now: bool = False, key: bytes | None = None, challenge: int = 0) -> bytes:
    return frame(Msg.STOP, job_id, origin, seq, _STOP.pack(1 if now else 0), key, challenge)


def cancel(origin: int, seq: int, job_id: int, token: int, key: bytes | None = None, challenge: int = 0) -> bytes:
    return frame(Msg.CANCEL, job_id, origin, seq, _CANCEL.pack(token), key, challenge)


def _ipv4(addr: str) -> int:
    try:
        return int(ipaddress.IPv4Address(addr))
    except ValueError:
        return 0  # not IPv4: the owner is named by port only


def plc_message(kind: Msg, origin: int, seq: int, job_id: int, status: Status, *,
                ranges=(), reason: int = 0, detail: int = 0, owner: tuple[str, int] | None = None, when: int = 0,
                key: bytes | None = None, challenge: int = 0) -> bytes:
    """READY, STATUS, DONE, FAULT (status only), REQUEST (+ ranges) or NAK (+ reason)."""
    body = status.pack()
    if kind == Msg.REQUEST:
        ranges = list(ranges)[:MAX_RANGES]
        body += _NREQ.pack(len(ranges)) + b"".join(_RANGE.pack(int(f), int(c)) for f, c in ranges)
    elif kind == Msg.NAK:
        ip, port = (_ipv4(owner[0]), owner[1]) if owner else (0, 0)
        body += _NAK.pack(reason, port, detail & 0xFFFFFFFF, ip, max(0, min(int(when), 0xFFFFFFFF)))
    return frame(kind, job_id, origin, seq, body, key, challenge)


# ---------------------------------------------------------------- decoding

_FIXED = {Msg.HELLO: 0, Msg.HEADER: _HEADER.size, Msg.STOP: _STOP.size, Msg.CANCEL: _CANCEL.size,
          Msg.READY: _STATUS.size, Msg.STATUS: _STATUS.size, Msg.DONE: _STATUS.size, Msg.FAULT: _STATUS.size,
          Msg.NAK: _STATUS.size + _NAK.size}


def _status(body: bytes) -> Status:
    s = Status.unpack(body[:_STATUS.size])
    if s.state > State.D_OPERATING or s.fault > max(Fault) or s.pen > 1 or s.flags & ~HELD:
        raise ProtocolError("status field out of range")
    return s


def decode(datagram: bytes, key: bytes | None = None) -> Message:
    """Check and parse one datagram; raise ProtocolError for anything invalid.

    With ``key`` every datagram must carry a valid HMAC-SHA256 tag (AuthError
    otherwise); without, a tagged datagram is refused too (AuthError: the
    sides disagree about the key). Every field is range-checked here except
    the header's values, which the PLC refuses with NAK BAD_HEADER
    (``JobHeader.problem``).
    """
    n = len(datagram)
    if n < 3 + CRC.size:
        raise ProtocolError(f"short datagram ({n} bytes)")
    (crc,) = CRC.unpack_from(datagram, n - CRC.size)
    if zlib.crc32(memoryview(datagram)[:n - CRC.size]) != crc:
        raise ProtocolError("CRC mismatch")
    if datagram[:2] != MAGIC:
        raise ProtocolError("bad magic")
    if datagram[2] != VERSION:  # before the length: an older version's common header is shorter
        raise OldVersion(datagram[2]) if datagram[2] in OLD_VERSIONS else ProtocolError(f"unknown version {datagram[2]}")
    if n < COMMON.size + CRC.size:
        raise ProtocolError(f"short datagram ({n} bytes)")
    magic, version, kind, job_id, origin, seq, flags, challenge = COMMON.unpack_from(datagram)
    if flags & ~AUTH:
        raise ProtocolError(f"unknown flags 0x{flags:x}")
    end = n - CRC.size
    if flags & AUTH:
        end -= TAG_SIZE
        if end < COMMON.size:
            raise ProtocolError("short authenticated datagram")
        if not key:
            raise AuthError("authenticated datagram, but no key is set")
        if not hmac.compare_digest(_tag(key, memoryview(datagram)[:end]), bytes(datagram[end:end + TAG_SIZE])):
            raise AuthError("HMAC tag mismatch")
    elif key:
        raise AuthError("datagram without HMAC tag")
    try:
        kind = Msg(kind)
    except ValueError:
        raise ProtocolError(f"unknown message type {kind}") from None
    body = bytes(datagram[COMMON.size:end])
    base = dict(type=kind, job_id=job_id, origin=origin, seq=seq, authenticated=bool(flags & AUTH), challenge=challenge)
    if kind in _FIXED:
        if len(body) != _FIXED[kind]:
            raise ProtocolError(f"{kind.name} body is {len(body)} bytes, expected {_FIXED[kind]}")
        if kind == Msg.HEADER:
            return Message(**base, header=JobHeader.unpack(body))
        if kind == Msg.STOP:
            mode = _STOP.unpack(body)[0]
            if mode > 1:
                raise ProtocolError(f"STOP mode {mode} is not 0 or 1")
            return Message(**base, mode=mode)
        if kind == Msg.CANCEL:
            return Message(**base, token=_CANCEL.unpack(body)[0])
        if kind == Msg.HELLO:
            return Message(**base)
        status = _status(body)
        if kind == Msg.NAK:
            reason, port, detail, ip, when = _NAK.unpack_from(body, _STATUS.size)
            if reason not in _NAK_REASONS:
                raise ProtocolError(f"unknown NAK reason {reason}")
            owner = (str(ipaddress.IPv4Address(ip)), port) if reason == Nak.BUSY else None
            return Message(**base, status=status, reason=reason, detail=detail, owner=owner, when=when)
        return Message(**base, status=status)
    if kind == Msg.DATA:
        if len(body) < _DATA.size:
            raise ProtocolError("short DATA")
        first, count = _DATA.unpack_from(body)
        if not 0 < count <= MAX_PER_DATA or len(body) != _DATA.size + count * RECORD_DTYPE.itemsize:
            raise ProtocolError(f"DATA length does not match its count {count}")
        if first < 1 or first + count - 1 > MAX_COMMAND:
            raise ProtocolError(f"DATA command numbers {first}+{count} outside 1..{MAX_COMMAND}")
        recs = np.frombuffer(body, RECORD_DTYPE, count=count, offset=_DATA.size)
        # The records must be exactly first, first+1, ...: a sender bug must not reorder commands.
        if not np.array_equal(recs["command_no"], np.arange(first, first + count, dtype=np.int64)):
            raise ProtocolError("DATA records are not numbered consecutively from 'first'")
        if np.any(recs["type"] > PAUSE):
            raise ProtocolError("DATA record type is not DRAW (0), MOVE (1) or PAUSE (2)")
        return Message(**base, first=first, records=recs)
    # REQUEST
    if len(body) < _STATUS.size + _NREQ.size:
        raise ProtocolError("short REQUEST")
    status = _status(body)
    (count,) = _NREQ.unpack_from(body, _STATUS.size)
    off = _STATUS.size + _NREQ.size
    if count > MAX_RANGES or len(body) != off + count * _RANGE.size:
        raise ProtocolError("REQUEST length does not match its range count")
    ranges = tuple(_RANGE.unpack_from(body, off + i * _RANGE.size) for i in range(count))
    if any(f < 1 or c < 1 or f + c - 1 > MAX_COMMAND for f, c in ranges):
        raise ProtocolError("REQUEST range outside 1..2^32-1")
    return Message(**base, status=status, ranges=ranges)


def job_crc(plc_bytes: bytes) -> int:
    """A packet file's identity: its stored CRC-32 trailer."""
    return CRC.unpack_from(plc_bytes, len(plc_bytes) - CRC.size)[0]


# ---------------------------------------------------------------- command semantics

def planned_states(records: np.ndarray, delta_time: float, home=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Planned position (steps) and velocity (steps/s) after every command, shape (n, 2) each.

    The packet file's semantics (docs/formats.md): a MOVE ends at rest at its
    target; a DRAW ramps linearly from the previous velocity (0 after a MOVE)
    to its target over ``delta_time``. The machine starts at ``home`` at rest.
    """
    n = len(records)
    xy = np.column_stack([records["x"], records["y"]]).astype(float)
    is_move = records["type"] == MOVE
    still = (records["type"] != DRAW)[:, None]  # MOVE and PAUSE end at rest; a PAUSE does not move
    vel = np.where(still, 0.0, xy)
    prev_v = np.vstack([np.zeros((1, 2)), vel[:-1]])
    incr = np.where(still, 0.0, 0.5 * delta_time * (prev_v + vel))
    csum = np.cumsum(incr, axis=0)
    # Position = target of the last MOVE at or before i (home if none) + DRAW increments since it.
    idx = np.where(is_move, np.arange(n), -1)
    last = np.maximum.accumulate(idx) if n else idx
    base = np.where(last[:, None] >= 0, xy[np.maximum(last, 0)], np.asarray(home, float))
    base_sum = np.where(last[:, None] >= 0, csum[np.maximum(last, 0)], 0.0)
    return base + csum - base_sum, vel


def resume_state(records: np.ndarray, delta_time: float, start_at: int, home=(0.0, 0.0)):
    """((x, y), (vx, vy)): the planned state after command ``start_at - 1``."""
    if start_at <= 1:
        return (float(home[0]), float(home[1])), (0, 0)
    k = start_at - 2
    # Only the run since the last MOVE matters: integrate that slice, not the whole job.
    is_move = records["type"][:k + 1] == MOVE
    lo = int(np.flatnonzero(is_move)[-1]) if is_move.any() else 0
    pos, vel = planned_states(records[lo:k + 1], delta_time, home)
    return (float(pos[-1, 0]), float(pos[-1, 1])), (int(vel[-1, 0]), int(vel[-1, 1]))


def command_durations(records: np.ndarray, header: PlcHeader, home=(0.0, 0.0)) -> np.ndarray:
    """Planned execution time (s) of every command (pen delays excluded).

    DRAW: one ``delta_time``; MOVE: the slower axis' trapezoid (or triangle)
    profile at move_speed / max_accel from the previous planned position;
    PAUSE: 0 (the operator's time is not planned).
    """
    pos, _ = planned_states(records, header.delta_time, home)
    prev = np.vstack([np.asarray(home, float)[None], pos[:-1]])
    d = np.abs(pos - prev)
    vmax = np.array([header.move_speed_x, header.move_speed_y], float)
    acc = np.array([header.max_accel_x, header.max_accel_y], float)
    t = np.where(d >= vmax * vmax / acc, d / vmax + vmax / acc, 2.0 * np.sqrt(d / acc))
    return np.where(records["type"] == MOVE, t.max(axis=1), np.where(records["type"] == PAUSE, 0.0, header.delta_time))


__all__ = [
    "MAGIC", "VERSION", "OLD_VERSIONS", "MAX_PER_DATA", "MAX_RANGES", "MAX_COMMAND", "AGAIN", "AUTH", "Msg", "State",
    "Fault", "Nak", "FAULT_TEXT", "HELD", "JobHeader", "Status", "Message", "ProtocolError", "OldVersion", "AuthError",
    "ReplayWindow", "frame", "hello", "header", "data", "stop", "cancel",
    "plc_message", "decode", "job_crc", "planned_states", "resume_state", "command_durations", "DRAW", "MOVE", "PAUSE",
]
