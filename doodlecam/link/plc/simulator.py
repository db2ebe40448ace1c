"""A DoodleBot PLC simulator on a real UDP socket (``doodlecam sim plc``).

It runs the report's programs (section 3.4) against the wire format of
``protocol`` (version 3, docs/protocol.md):

* Governor: POWER_ON -> A_Init (home) -> B_ready (READY every
  ``ready_interval``) -> C_buffer (request commands until the buffer is full
  or the job is all received) -> D_operating (execute, keep requesting as
  slots free) -> B_ready.
* Communications: the bounded ``commandBuffer`` of BUFFER_SIZE slots
  (command c lives in slot (c-1) mod BUFFER_SIZE, only while c is within
  BUFFER_SIZE of the last executed command), requests with a retransmission
  timeout, idempotent handling of duplicates and late datagrams.
* motorControl: DRAW ramps the velocity linearly to its target over
  delta_time; MOVE is a rest-to-rest trapezoid per axis at move_speed /
  max_accel; the pen follows the command type with its delays. PAUSE (a pen
  change) lifts the pen and holds the job until its sender resumes it.
* checkLimitSwitch: commands — and the re-entry move of a resumed job — that
  would leave the work area stop the machine before they run (soft
  boundaries); limit switches just outside it stop it at once if anything
  gets there anyway.
* A hostile network: every datagram is range-checked by ``protocol.decode``
  and counted when dropped; a running job is bound to the address, nonce and
  challenge of the PC run that drives it and owned by its IP and token; a
  HEADER or CANCEL must carry the PLC's current challenge, which it then uses
  up, so a captured session never starts or moves anything again; a key
  requires an HMAC tag on every datagram, with a replay window per session.
* Non-volatile memory (``nvram``): the ended jobs with their content CRC, the
  current job and its command counter survive a restart (a new simulator on
  the same ``state_file``), so a finished job never runs again and a resume
  never repeats a command.

Time is simulated (as fast as the network allows; for tests) or real time,
optionally sped up. Every executed command is recorded (command_no, end time,
position, velocity, pen) so tests compare what was drawn with the plan.
Network impairments (loss, duplication, reordering, corruption, delay) apply
to datagrams in both directions.
"""

from __future__ import annotations

import math
import random
import secrets
import select
import socket
import threading
import time
from collections import Counter, OrderedDict
from dataclasses import astuple, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from doodlecam.link.plc import protocol as P
from doodlecam.link.plc.network import Impairments, LossyNetwork
from doodlecam.link.plc.nvram import NvRam
from doodlecam.link.plc.packetfile import DRAW, MOVE, PAUSE, RECORD_DTYPE
from doodlecam.link.plc.protocol import Fault, Msg, Nak, State

TRACE_DTYPE = np.dtype([("command_no", "<u4"), ("type", "<i2"), ("t", "<f8"), ("x", "<f8"), ("y", "<f8"),
                        ("vx", "<f8"), ("vy", "<f8"), ("pen", "<u1")])
# trace rows that are not a command: the machine's own motions
STOP_ROW, REENTRY_ROW = -1, -2




@dataclass
class PlcConfig:
    """Simulator settings. Lengths in steps, times in s (wall s for the link)."""

    host: str = "127.0.0.1"
    port: int = 0  # 0 = any free port
    buffer_size: int = 256  # BUFFER_SIZE
    width: float = 32000.0  # boundaries: x in [0, width], y in [0, height] (steps from home corner)
    height: float = 24000.0
    switch_margin: float = 160.0  # limit switches sit this far outside the boundaries
    home: tuple[float, float] = (0.0, 0.0)
    pen_up_delay: float = 0.15
    pen_down_delay: float = 0.15
    speed: float = math.inf  # simulated seconds per wall second; inf = simulated time (no waiting)
    rto: float = 0.05  # re-request what has not arrived within this (wall s)
    ready_interval: float = 0.5
    status_interval: float = 0.25
    starve_timeout: float = 2.0  # wall s without the next command before the PLC gives up waiting
    request_batch: int = 16  # request once this many slots are free (or the buffer runs low)
    soft_limits: bool = True  # check commands against the boundaries before running them
    init_time: float = 0.0  # wall s spent in A_Init
    impair: Impairments = field(default_factory=Impairments)
    key: bytes | None = None  # pre-shared key: every datagram must carry an HMAC-SHA256 tag
    state_file: Path | None = None  # non-volatile memory (ended jobs, current job, progress); None = volatile

    @classmethod
    def from_machine(cls, machine, **overrides) -> "PlcConfig":
        """Boundaries, home and pen delays from a machine profile."""
        sx, sy = machine.x.steps_per_mm, machine.y.steps_per_mm
        base = dict(width=machine.width * sx, height=machine.height * sy,
                    home=(machine.home[0] * sx, machine.home[1] * sy), switch_margin=2.0 * sx,
                    pen_up_delay=machine.pen.up_delay, pen_down_delay=machine.pen.down_delay)
        base.update(overrides)
        return cls(**base)


class _Job:
    def __init__(self, job_id: int, h: P.JobHeader, size: int):
        self.id = job_id
        self.h = h
        self.n = h.no_commands
        self.executed = h.start_at - 1  # counterCommand.counter
        self.buffered = self.executed  # counterBuffer.counter
        self.slot_no = np.zeros(size, np.int64)  # commandBuffer[].command_no
        self.slot_rec = np.zeros(size, RECORD_DTYPE)
        self.req_no = np.zeros(size, np.int64)  # what was last requested for each slot, and when
        self.req_t = np.zeros(size)
        self.reentry = h.start_at > 1
        self.stop_mode: int | None = None
        self.starving_since: float | None = None
        self.filling_since: float | None = None
        self.started = False


@dataclass
class _Held:
    id: int
    h: P.JobHeader
    next: int  # first command not executed
    reason: Fault
    owner: str = ""  # IP of the PC that started the job (with h.token: who may resume it)


_INT32 = (-2**31, 2**31 - 1)


def _challenge() -> int:
    """A session challenge: 64 random bits from the OS's CSPRNG, never 0 (0 = none)."""
    return secrets.randbits(64) or 1




class PlcSimulator:
    """The simulated PLC. ``start()`` runs it in a thread; ``run()`` in the caller's."""

    def __init__(self, config: PlcConfig | None = None, log: Callable[[str], None] | None = None):
        self.cfg = cfg = config or PlcConfig()
        if cfg.buffer_size < 1 or cfg.rto <= 0 or not cfg.speed > 0:
            raise ValueError("buffer_size >= 1, rto > 0 and speed > 0 are required")
        self.log = log or (lambda msg: None)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.sock.bind((cfg.host, cfg.port))
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        self.boot_id = random.getrandbits(63) | 1
        self.seq = 0
        self.state = State.POWER_ON
        self.peer: tuple | None = None  # where periodic messages go: the bound session's address
        # ((IP, port), nonce, challenge) of the PC run that drives the job: its HEADER's address, origin and challenge
        self.session: tuple[tuple, int, int] | None = None
        self.challenge = _challenge()  # what the next HEADER or CANCEL must carry; used up by it
        self.owner: str = ""  # IP of the PC that started the running job (with its token)
        self.window = P.ReplayWindow()  # the bound session's seq numbers: each accepted once
        self.job: _Job | None = None
        self.held: _Held | None = None
        # job ids never to run again -> (how it ended, its content CRC, Unix s); kept in non-volatile memory
        self.finished: OrderedDict[int, tuple[Fault, int, float]] = OrderedDict()
        self.last_done = 0
        self.last_job = 0  # the last job that ended (done, aborted or cancelled)
        self.fault = Fault.NONE
        self.fault_cmd = 0
        self.nv = NvRam(cfg.state_file)
        self._restore()
        # motorControl state: steps, steps/s, simulated s
        self.pos = np.array(cfg.home, float)
        self.vel = np.zeros(2)
        self.pen = False
        self.t = 0.0
        self.trace: list[tuple] = []
        self.executed_log: list[tuple[int, int]] = []  # (job_id, command_no) in execution order
        self.events: list[tuple[float, str]] = []
        self.stats: Counter = Counter()
        self._inbound = LossyNetwork(cfg.impair)
        self._outbound = LossyNetwork(Impairments(**{**vars(cfg.impair), "seed": None if cfg.impair.seed is None
                                                 else cfg.impair.seed + 1}))
        self._wall0 = time.monotonic()
        self._timer = 0.0
        self._next_ready = 0.0
        self._next_status = 0.0
        self._next_auth_nak = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------ lifecycle

    def start(self) -> "PlcSimulator":
        self._thread = threading.Thread(target=self.run, name="plcsim", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Switch off (a power cycle, when a new simulator starts on the same ``state_file``)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self.sock.close()
        self.nv.close()

    # ------------------------------------------------------------ non-volatile memory

    def _restore(self) -> None:
        """Power-up: the ended jobs, and the job that was running or held, from non-volatile memory."""
        rec = self.nv.record
        try:
            for jid, why, crc, when in rec.get("finished", []):
                self.finished[int(jid)] = (Fault(why), int(crc), float(when))
            self.last_done, self.last_job = int(rec.get("last_done", 0)), int(rec.get("last_job", 0))
            j = rec.get("job")
            if j:
                h = P.JobHeader(*j["header"])
                nv_id, nv_exec = self.nv.executed
                nxt = nv_exec + 1 if nv_id == j["id"] else int(j["next"])
                why = Fault(j["held"]) if j.get("held") else Fault.POWER_LOST
                self.held = _Held(int(j["id"]), h, nxt, why, j["owner"])
                self.peer = (j["owner"], int(j["port"]))  # tell the PC that the PLC is back
                self.fault, self.fault_cmd = why, nxt
        except (KeyError, TypeError, ValueError):
            self.finished.clear()
            self.held = None

    def _nv_save(self) -> None:
        rec: dict = {"finished": [[k, int(f), c, w] for k, (f, c, w) in self.finished.items()],
                     "last_done": self.last_done, "last_job": self.last_job}
        if self.job is not None:
            j = self.job
            rec["job"] = {"id": j.id, "header": list(astuple(j.h)), "next": j.executed + 1, "held": 0,
                          "owner": self.owner, "port": self.peer[1] if self.peer else 0}
        elif self.held is not None:
            hd = self.held
            rec["job"] = {"id": hd.id, "header": list(astuple(hd.h)), "next": hd.next, "held": int(hd.reason),
                          "owner": hd.owner, "port": self.peer[1] if self.peer else 0}
        self.nv.record = rec
        self.nv.save()

    def _finished_content(self, crc: int) -> tuple[int, float] | None:
        """(job id, Unix s) of the latest job with this content that ran to its end."""
        for jid, (why, c, when) in reversed(self.finished.items()):
            if c == crc and why == Fault.NONE:
                return jid, when
        return None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def run(self) -> None:
        self._enter(State.A_INIT, time.monotonic())
        while not self._stop.is_set():
            now = time.monotonic()
            for data, addr in self._inbound.due(now):
                self._handle(data, addr, now)
            for data, addr in self._outbound.due(now):
                try:
                    self.sock.sendto(data, addr)
                except OSError:
                    self.stats["send_errors"] += 1
            self._tick(now)
            wake = min(self._next_wakeup(now), self._inbound.next_time(), self._outbound.next_time())
            timeout = min(max(wake - time.monotonic(), 0.0), 0.05)
            try:
                readable, _, _ = select.select([self.sock], [], [], timeout)
            except (OSError, ValueError):
                break
            if readable:
                self._drain(time.monotonic())

    def _drain(self, now: float) -> None:
        for _ in range(512):
            try:
                data, addr = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # e.g. ICMP port unreachable from a PC that went away
                self.stats["recv_errors"] += 1
                continue
            self._inbound.schedule(now, data, addr)
            for d, a in self._inbound.due(now):
                self._handle(d, a, now)

    # ------------------------------------------------------------ clock

    def sim_now(self, now: float) -> float:
        """Simulated time the wall clock has reached (real-time mode)."""
        return (now - self._wall0) * self.cfg.speed

    @property
    def realtime(self) -> bool:
        return math.isfinite(self.cfg.speed)

    def _next_wakeup(self, now: float) -> float:
        t = math.inf
        if self.state in (State.A_INIT,):
            t = self._timer
        elif self.state == State.B_READY:
            t = self._next_ready
        elif self.state in (State.C_BUFFER, State.D_OPERATING):
            t = min(self._next_status, now + self.cfg.rto / 2)
            if self.realtime and self.state == State.D_OPERATING:
                t = min(t, self._wall0 + self.t / self.cfg.speed)
        return t

    # ------------------------------------------------------------ sending

    def _status(self) -> P.Status:
        job, held = self.job, self.held
        executed = job.executed if job else (held.next - 1 if held else 0)
        buffered = job.buffered if job else executed
        crc = job.h.job_crc if job else (held.h.job_crc if held else 0)
        x, y = (int(np.clip(np.round(v), *_INT32)) for v in self.pos)
        return P.Status(int(self.state), int(self.fault), int(self.pen), P.HELD if held and not job else 0,
                        self.cfg.buffer_size, executed, buffered, self.fault_cmd, x, y, self.last_done, crc)

    def _send(self, kind: Msg, now: float, to: tuple | None = None, **kw) -> None:
        """To ``to``, else to the bound session's address (the report's PC_IP)."""
        dest = to or self.peer
        if dest is None:
            return
        job_id = kw.pop("job_id", None)
        if job_id is None:
            job_id = self.job.id if self.job else (self.held.id if self.held else self.last_job)
        self.seq += 1
        data = P.plc_message(kind, self.boot_id, self.seq, job_id, self._status(), key=self.cfg.key,
                             challenge=self.challenge, **kw)
        self.stats[f"sent_{kind.name}"] += 1
        self._outbound.schedule(now, data, dest)

    def _busy(self, m: P.Message, addr, now: float) -> None:
        """NAK BUSY to a PC that is not the job's: names the job and who drives it; changes nothing."""
        jid = self.job.id if self.job else self.held.id
        owner = self.peer if self.job else (self.held.owner, self.peer[1] if self.peer else 0)
        self.stats["refused_busy"] += 1
        self._send(Msg.NAK, now, to=addr, job_id=m.job_id, reason=Nak.BUSY, detail=jid, owner=owner)

    # ------------------------------------------------------------ Governor

    def _enter(self, state: State, now: float) -> None:
        if state != self.state:
            self.events.append((self.t, f"state {state.name}"))
            self.log(f"state {state.name}")
        self.state = state
        if state == State.A_INIT:
            self._timer = now + self.cfg.init_time
        elif state == State.B_READY:
            self._next_ready = now  # announce at once
        elif state in (State.C_BUFFER, State.D_OPERATING):
            self._next_status = now

    def _tick(self, now: float) -> None:
        if self.state == State.POWER_ON:  # the sim presses the Y limit switch itself
            self._enter(State.A_INIT, now)
        elif self.state == State.A_INIT and now >= self._timer:
            self.pos[:] = self.cfg.home  # boundaries checked, centred on home
            self.vel[:] = 0
            self.pen = False
            self._enter(State.B_READY, now)
        elif self.state == State.B_READY and now >= self._next_ready:
            self._send(Msg.READY, now)
            self._next_ready = now + self.cfg.ready_interval
        elif self.state in (State.C_BUFFER, State.D_OPERATING):
            self._operate(now)
            if self.state in (State.C_BUFFER, State.D_OPERATING):
                self._maybe_request(now)
                if now >= self._next_status:
                    self._send(Msg.STATUS, now)
                    self._next_status = now + self.cfg.status_interval

    # ------------------------------------------------------------ receiving

    def _handle(self, data: bytes, addr, now: float) -> None:
        """One datagram from ``addr``: checked, then acted on only if it is allowed (docs/protocol.md 1.5)."""
        try:
            m = P.decode(data, self.cfg.key)
        except P.OldVersion as e:
            self.stats["dropped_old_version"] += 1
            if self.stats["dropped_old_version"] == 1:
                self.log(f"ignoring {addr[0]}:{addr[1]}: {e}")
            return
        except P.AuthError:
            self.stats["dropped_unauthenticated"] += 1
            if data[3:4] == bytes([Msg.HELLO]) and now >= self._next_auth_nak:
                # Say why, unauthenticated and with an empty status (nothing to learn); at most 10 per s.
                self._next_auth_nak = now + 0.1
                self.seq += 1
                self._outbound.schedule(now, P.plc_message(Msg.NAK, self.boot_id, self.seq, 0, P.Status(),
                                                           reason=Nak.AUTH_REQUIRED), addr)
            return
        except P.ProtocolError:
            self.stats["dropped_invalid"] += 1
            return
        if m.type >= 0x10:
            self.stats["dropped_invalid"] += 1
            return
        try:
            self._dispatch(m, addr, now)
        except Exception as e:  # noqa: BLE001 - one datagram must never stop the machine; tests assert none
            self.stats["handler_errors"] += 1
            self.log(f"internal error on {m.type.name} from {addr[0]}:{addr[1]}: {e!r}")

    def _dispatch(self, m: P.Message, addr, now: float) -> None:
        mine = self.session is not None and (tuple(addr[:2]), m.origin, m.challenge) == self.session
        if mine and not self.window.accept(m.seq):
            self.stats["dropped_replayed"] += 1  # a duplicate or a replay of the bound session
            return
        self.stats[f"recv_{m.type.name}"] += 1
        if m.type == Msg.HELLO:
            if mine or (self.job is None and self.held is None):
                self.peer = addr  # the session's PC or, idle, whoever asks
                self._send(Msg.STATUS if self.job else Msg.READY, now)
            elif self.job is not None:
                self._busy(m, addr, now)
            else:
                self._send(Msg.READY, now, to=addr)  # a held job: the PC sees it, the owner keeps the PLC
        elif m.type == Msg.HEADER:
            self._on_header(m, addr, mine, now)
        elif m.type == Msg.CANCEL:
            self._on_cancel(m, addr, now)
        elif not mine:
            self.stats["dropped_foreign"] += 1  # DATA / STOP from another address or session: not ours
        elif m.type == Msg.DATA:
            self._on_data(m, now)
        elif m.type == Msg.STOP:
            if self.job and m.job_id == self.job.id:
                self.job.stop_mode = max(self.job.stop_mode or 0, m.mode)
                self.log(f"stop requested ({'now' if m.mode else 'at the end of the stroke'})")
                self._operate(now)
            self._send(Msg.STATUS if self.job else Msg.READY, now)

    def _on_cancel(self, m: P.Message, addr, now: float) -> None:
        """CANCEL carries the job's owner token: only the PC that started the job can end it."""
        job, held = self.job, self.held
        ours = (job and m.job_id == job.id and (addr[0], m.token) == (self.owner, job.h.token)) or (
            held and m.job_id == held.id and (addr[0], m.token) == (held.owner, held.h.token))
        if ours and m.challenge != self.challenge:
            self._stale(m, addr, now)  # a CANCEL captured earlier (or sent before the challenge changed)
            return
        if ours:
            self.challenge = _challenge()  # used up
        if job and m.job_id == job.id and (addr[0], m.token) == (self.owner, job.h.token):
            self._halt(now)
            self._forget(job.id, Fault.CANCELLED)
            self.job = None
            self.fault, self.fault_cmd = Fault.CANCELLED, job.executed + 1  # the first command that did not run
            self._enter(State.B_READY, now)
        elif held and m.job_id == held.id and (addr[0], m.token) == (held.owner, held.h.token):
            self._forget(held.id, Fault.CANCELLED)
            self.held = None
            self.fault, self.fault_cmd = Fault.CANCELLED, held.next
        elif job or held:
            self._busy(m, addr, now)
            return
        else:
            self._send(Msg.READY, now, to=addr, job_id=m.job_id)
            return
        self.session = None
        self.log(f"job {m.job_id} cancelled")
        self._nv_save()
        self._send(Msg.READY, now, to=addr, job_id=m.job_id)

    def _forget(self, job_id: int, why: Fault) -> None:
        crc = (self.job.h.job_crc if self.job and self.job.id == job_id
               else self.held.h.job_crc if self.held and self.held.id == job_id else 0)
        self.finished[job_id] = (why, crc, time.time())
        self.last_job = job_id
        while len(self.finished) > 64:
            self.finished.popitem(last=False)

    def _bind(self, m: P.Message, addr) -> None:
        """The sending PC run becomes the session: its address, nonce and the challenge its HEADER carried,
        which is used up (a fresh one for the next HEADER); a fresh replay window."""
        self.session, self.peer = (tuple(addr[:2]), m.origin, m.challenge), addr
        self.challenge = _challenge()
        self.window = P.ReplayWindow()
        self.window.accept(m.seq)

    def _stale(self, m: P.Message, addr, now: float) -> None:
        """A HEADER or CANCEL without the current challenge: nothing changes; the NAK carries the current one."""
        self.stats["stale_challenges"] += 1
        self._send(Msg.NAK, now, to=addr, job_id=m.job_id, reason=Nak.STALE_CHALLENGE)

    def _on_header(self, m: P.Message, addr, mine: bool, now: float) -> None:
        h, job, held = m.header, self.job, self.held
        if job is not None:
            if m.job_id == job.id and (addr[0], h.token) == (self.owner, job.h.token):
                if not mine:
                    if m.challenge != self.challenge:  # a captured header played back: the session stays
                        self._stale(m, addr, now)
                        return
                    self._bind(m, addr)  # the job's PC restarted its sender: the new run drives the job
                    self.log(f"job {job.id}: sender re-attached from {addr[0]}:{addr[1]}")
                self._send(Msg.STATUS, now)  # a duplicate of the header we run: idempotent
            else:
                self._busy(m, addr, now)
            return
        if m.job_id in self.finished:
            self._send(Msg.NAK, now, to=addr, job_id=m.job_id, reason=Nak.FINISHED,
                       detail=int(self.finished[m.job_id][0]))
            return
        if self.state != State.B_READY:
            self._send(Msg.NAK, now, to=addr, job_id=m.job_id, reason=Nak.NOT_READY, detail=int(self.state))
            return
        problem = "job id 0" if m.job_id == 0 else h.problem()
        if problem:
            self.stats["bad_headers"] += 1
            self._send(Msg.NAK, now, to=addr, job_id=m.job_id, reason=Nak.BAD_HEADER)
            return
        if m.challenge != self.challenge:  # a HEADER captured from an earlier session: starts nothing
            self._stale(m, addr, now)
            return
        resuming = held is not None and m.job_id == held.id
        if resuming:
            if (addr[0], h.token) != (held.owner, held.h.token):
                self._busy(m, addr, now)
                return
            if h.start_at != held.next or h.job_crc != held.h.job_crc or h.no_commands != held.h.no_commands:
                self._send(Msg.NAK, now, to=addr, job_id=m.job_id, reason=Nak.START_MISMATCH, detail=held.next)
                return
        else:
            done = self._finished_content(h.job_crc)
            if done and not h.flags & P.AGAIN:
                self._send(Msg.NAK, now, to=addr, job_id=m.job_id, reason=Nak.ALREADY_DONE, detail=done[0],
                           when=int(done[1]))
                return
            if held is not None:  # a new job replaces the held one, which is abandoned
                self._forget(held.id, Fault.CANCELLED)
        self.held = None
        self._bind(m, addr)
        self.owner = addr[0]
        self.job = _Job(m.job_id, h, self.cfg.buffer_size)
        self.fault, self.fault_cmd = Fault.NONE, 0
        self.nv.progress(m.job_id, h.start_at - 1)
        self._nv_save()
        what = f"resuming at command {h.start_at}" if h.start_at > 1 else "starting"
        self.log(f"job {m.job_id} from {addr[0]}:{addr[1]}: {h.no_commands} commands, {what}")
        self._enter(State.C_BUFFER, now)
        self._maybe_request(now, force=True)

    def _on_data(self, m: P.Message, now: float) -> None:
        job = self.job
        if job is None or m.job_id != job.id:
            self.stats["dropped_other_job"] += 1
            return
        B = self.cfg.buffer_size
        cs = m.records["command_no"].astype(np.int64)
        hi = min(job.n, job.executed + B)
        slots = (cs - 1) % B
        new = (cs > job.executed) & (cs <= hi) & (job.slot_no[slots] != cs)
        self.stats["dup_or_late_commands"] += int(len(cs) - new.sum())
        job.slot_no[slots[new]] = cs[new]
        job.slot_rec[slots[new]] = m.records[new]
        self._advance_buffered(job)
        self._operate(now)
        if self.state in (State.C_BUFFER, State.D_OPERATING):
            self._maybe_request(now)

    def _advance_buffered(self, job: _Job) -> None:
        B = self.cfg.buffer_size
        hi = min(job.n, job.executed + B)
        if job.buffered >= hi:
            return
        cands = np.arange(job.buffered + 1, hi + 1)
        present = job.slot_no[(cands - 1) % B] == cands
        gap = np.flatnonzero(~present)
        job.buffered = int(cands[gap[0]] - 1) if len(gap) else hi

    def _maybe_request(self, now: float, force: bool = False) -> None:
        job, B = self.job, self.cfg.buffer_size
        hi = min(job.n, job.executed + B)
        if job.buffered >= hi:
            return
        cands = np.arange(job.buffered + 1, hi + 1)
        slots = (cands - 1) % B
        missing = job.slot_no[slots] != cands
        asked = job.req_no[slots] == cands
        timed_out = asked & (job.req_t[slots] <= now - self.cfg.rto)
        fresh = missing & ~asked
        due = missing & (~asked | timed_out)
        if not due.any():
            return
        level = job.buffered - job.executed
        # Batch fresh requests (one REQUEST per request_batch freed slots) unless the buffer runs low.
        if not (force or (missing & timed_out).any() or fresh.sum() >= min(self.cfg.request_batch, job.n - job.buffered)
                or level < B // 2):
            return
        want = cands[due]
        breaks = np.flatnonzero(np.diff(want) != 1) + 1
        starts = np.concatenate([[0], breaks])[:P.MAX_RANGES]
        ends = np.concatenate([breaks, [len(want)]])[:P.MAX_RANGES]
        ranges = [(int(want[s]), int(e - s)) for s, e in zip(starts, ends)]
        asked_now = want[:ends[-1]]
        job.req_no[(asked_now - 1) % B] = asked_now
        job.req_t[(asked_now - 1) % B] = now
        self.stats["requested_commands"] += len(asked_now)
        self.stats["rerequested_commands"] += int((missing & timed_out).sum())
        self._send(Msg.REQUEST, now, ranges=ranges)

    # ------------------------------------------------------------ motorControl

    def _operate(self, now: float) -> None:
        job = self.job
        while job is not None and job is self.job:
            if self.state == State.C_BUFFER:
                full = job.buffered >= min(job.n, job.executed + self.cfg.buffer_size)
                if job.filling_since is None:
                    job.filling_since = now
                # The report's rule: operate once full or all received; also when filling stalls,
                # so a PC that goes away mid-fill leaves a held job, not a PLC stuck in C_buffer.
                if full or now - job.filling_since >= self.cfg.starve_timeout:
                    self._enter(State.D_OPERATING, now)
                    if self.realtime and self.t < self.sim_now(now):
                        self.t = self.sim_now(now)  # start now, not in the past
                else:
                    return
            c = job.executed + 1
            if c > job.n:
                self._finish(now)
                return
            moving = bool(np.any(self.vel != 0))
            if job.stop_mode == 1 or (job.stop_mode == 0 and not moving and self._next_is_move_or_rest(job, c)):
                self._suspend(Fault.STOPPED, now)
                return
            if self.realtime and self.t > self.sim_now(now):
                return  # the previous command is still running
            slot = (c - 1) % self.cfg.buffer_size
            if job.slot_no[slot] != c:
                if job.starving_since is None:
                    job.starving_since = now
                if (self.realtime and moving) or now - job.starving_since >= self.cfg.starve_timeout:
                    self.stats["underruns"] += 1
                    self._suspend(Fault.UNDERRUN, now)
                return
            job.starving_since = None
            if self.realtime and not moving and self.t < self.sim_now(now):
                self.t = self.sim_now(now)  # at rest the clock ran on while waiting
            rec = job.slot_rec[slot]
            kind = int(rec["type"])
            if not self._execute(job, c, kind, float(rec["x"]), float(rec["y"]), now):
                return
            job.executed = c
            self.nv.progress(job.id, c)  # retentive, as the command counter of a real PLC
            self.executed_log.append((job.id, c))
            if kind == PAUSE:  # a pen change: hold the job, pen up, until the operator resumes it
                self.log(f"pen change: fit pen {int(rec['x'])}, then resume the job")
                self._suspend(Fault.PEN_CHANGE, now)
                return

    def _next_is_move_or_rest(self, job: _Job, c: int) -> bool:
        """A stop at the end of a stroke may happen here: pen up already, or a MOVE comes next."""
        if not self.pen:
            return True
        slot = (c - 1) % self.cfg.buffer_size
        return job.slot_no[slot] == c and int(job.slot_rec[slot]["type"]) == MOVE

    def _record(self, c: int, kind: int) -> None:
        self.trace.append((c, kind, self.t, self.pos[0], self.pos[1], self.vel[0], self.vel[1], int(self.pen)))

    def _pen_to(self, down: bool) -> None:
        if self.pen != down:
            self.pen = down
            self.t += self.cfg.pen_down_delay if down else self.cfg.pen_up_delay

    def _inside(self, lo, hi, margin: float = 0.0) -> bool:
        return (lo[0] >= -margin and lo[1] >= -margin and hi[0] <= self.cfg.width + margin
                and hi[1] <= self.cfg.height + margin)

    def _move_time(self, h: P.JobHeader, d: np.ndarray) -> float:
        vmax = np.array([h.move_speed_x, h.move_speed_y], float)
        acc = np.array([h.max_accel_x, h.max_accel_y], float)
        d = np.abs(d)
        t = np.where(d >= vmax * vmax / acc, d / vmax + vmax / acc, 2.0 * np.sqrt(d / acc))
        return float(t.max())

    def _execute(self, job: _Job, c: int, kind: int, x: float, y: float, now: float) -> bool:
        h = job.h
        if kind not in (DRAW, MOVE, PAUSE) or (kind == PAUSE and (np.any(self.vel != 0) or x < 1)):
            self._abort(Fault.BAD_COMMAND, c, now)  # unknown, or a pen change while moving
            return False
        if kind == PAUSE:
            self._pen_to(False)
            self._record(c, kind)
            return True
        if job.reentry:
            job.reentry = False
            if kind == DRAW:  # resume mid-stroke: see docs/protocol.md, "Resuming"
                target = np.array([h.resume_x, h.resume_y]) + 0.5 * h.delta_time * np.array([h.resume_vx, h.resume_vy])
                if not (np.all(np.isfinite(target)) and self._inside(target, target)):
                    self._abort(Fault.BOUNDARY, c, now)  # the re-entry move is a MOVE like any other
                    return False
                self._pen_to(False)
                self.t += self._move_time(h, target - self.pos)
                self.pos[:], self.vel[:] = target, 0.0
                self._record(0, REENTRY_ROW)
        if kind == MOVE:
            target = np.array([x, y])
            if self.cfg.soft_limits and not self._inside(target, target):
                self._abort(Fault.BOUNDARY, c, now)
                return False
            self._pen_to(False)
            if np.any(self.vel != 0):
                self.stats["moves_from_motion"] += 1  # a stroke that did not end at rest
            self.t += self._move_time(h, target - self.pos)
            if not self._inside(target, target, self.cfg.switch_margin):
                self.pos[:] = np.clip(target, -self.cfg.switch_margin,
                                      [self.cfg.width + self.cfg.switch_margin, self.cfg.height + self.cfg.switch_margin])
                self._trip(c, now)
                return False
            self.pos[:], self.vel[:] = target, 0.0
        else:
            dt = h.delta_time
            v0, v1 = self.vel.copy(), np.array([x, y])
            end = self.pos + 0.5 * dt * (v0 + v1)
            # The ramp's position is monotone per axis unless the velocity changes sign inside the period.
            ext = end.copy()
            flip = v0 * v1 < 0
            tau = np.where(flip, v0 * dt / np.where(flip, v0 - v1, 1.0), 0.0)
            ext[flip] = (self.pos + 0.5 * v0 * tau)[flip]
            lo, hi = np.minimum.reduce([self.pos, end, ext]), np.maximum.reduce([self.pos, end, ext])
            if self.cfg.soft_limits and not self._inside(lo, hi):
                self.vel[:] = 0.0  # immediate stop, before the command runs
                self._abort(Fault.BOUNDARY, c, now)
                return False
            # If the next command never comes (a sender that stalls or withholds DATA) the PLC brakes from
            # (end, v1). Run a ramp only when that stop still fits inside the work area: then, by induction
            # from rest, every stop the PLC may have to make stays inside, however the job starves.
            if self.cfg.soft_limits and not self._inside(*np.sort([end, self._stop_point(end, v1, h)], axis=0)):
                self._halt(now)  # from where it is now, which the previous command checked the same way
                self._abort(Fault.BOUNDARY, c, now)
                return False
            self._pen_to(True)
            self.t += dt
            if not self._inside(lo, hi, self.cfg.switch_margin):
                m = self.cfg.switch_margin
                self.pos[:] = np.clip(end, -m, [self.cfg.width + m, self.cfg.height + m])
                self._trip(c, now)
                return False
            self.pos[:], self.vel[:] = end, v1
        self._record(c, kind)
        return True

    @staticmethod
    def _stop_point(pos: np.ndarray, vel: np.ndarray, h: P.JobHeader) -> np.ndarray:
        """Where the PLC comes to rest braking at max_accel per axis from ``pos`` at ``vel`` (steps)."""
        acc = np.array([h.max_accel_x, h.max_accel_y], float)
        return pos + vel * np.abs(vel) / (2 * acc)

    def _halt(self, now: float) -> None:
        """Decelerate to rest at max_accel (per axis) and lift the pen."""
        h = (self.job or self.held).h if (self.job or self.held) else None
        if np.any(self.vel != 0) and h is not None:
            acc = np.array([h.max_accel_x, h.max_accel_y], float)
            self.pos[:] = self._stop_point(self.pos, self.vel, h)
            self.t += float((np.abs(self.vel) / acc).max())
            self.vel[:] = 0.0
            self._record(0, STOP_ROW)
        self._pen_to(False)

    def _suspend(self, why: Fault, now: float) -> None:
        job = self.job
        self._halt(now)
        self.held = _Held(job.id, job.h, job.executed + 1, why, self.owner)
        self.job = None
        self._nv_save()
        self.fault, self.fault_cmd = why, job.executed + 1
        self.events.append((self.t, f"job {job.id} held at command {job.executed + 1}: {why.name}"))
        self.log(f"job {job.id} held before command {job.executed + 1} ({P.FAULT_TEXT[why]})")
        self._enter(State.B_READY, now)
        self._send(Msg.READY, now)

    def _abort(self, why: Fault, c: int, now: float) -> None:
        job = self.job
        self.vel[:] = 0.0  # immediate stop
        self.pen = False
        self.fault, self.fault_cmd = why, c
        self._forget(job.id, why)
        self.events.append((self.t, f"job {job.id} aborted at command {c}: {why.name}"))
        self.log(f"FAULT at command {c}: {P.FAULT_TEXT[why]}")
        self._send(Msg.FAULT, now)
        self.job = None
        self.session = None
        self._nv_save()
        self._enter(State.B_READY, now)

    def _trip(self, c: int, now: float) -> None:
        self.vel[:] = 0.0
        self._record(c, STOP_ROW)  # where the switch stopped it
        self._abort(Fault.LIMIT_SWITCH, c, now)
        self._enter(State.POWER_ON, now)  # position lost: re-initialise

    def _finish(self, now: float) -> None:
        job = self.job
        self._pen_to(False)
        self.last_done = job.id
        self._forget(job.id, Fault.NONE)
        self.events.append((self.t, f"job {job.id} done"))
        self.log(f"job {job.id} done: {job.n} commands, {self.t:.2f} s simulated")
        self._send(Msg.DONE, now)
        self.job = None
        self.session = None
        self._nv_save()
        self.fault, self.fault_cmd = Fault.NONE, 0
        self._enter(State.B_READY, now)

    # ------------------------------------------------------------ results

    def trajectory(self) -> np.ndarray:
        """Every executed command (and the machine's own stop / re-entry motions) as TRACE_DTYPE rows."""
        return np.array(self.trace, dtype=TRACE_DTYPE)

    def executed(self, job_id: int | None = None) -> np.ndarray:
        """command_no of every executed command, in execution order (of one job, or all)."""
        rows = self.executed_log if job_id is None else [r for r in self.executed_log if r[0] == job_id]
        return np.array([c for _, c in rows], dtype=np.int64)

    def write_trace_csv(self, path) -> None:
        """The trajectory as CSV (steps, steps/s, s), written atomically."""
        from pathlib import Path

        from doodlecam.atomic import write_bytes

        tr = self.trajectory()
        rows = ["command_no,type,t,x,y,vx,vy,pen\n"]
        rows += [f"{r['command_no']},{r['type']},{r['t']:.6f},{r['x']:.4f},{r['y']:.4f},"
                 f"{r['vx']:.3f},{r['vy']:.3f},{r['pen']}\n" for r in tr]
        write_bytes(Path(path), "".join(rows).encode())
