"""The PC side of the PLC link: send a .plc job over UDP (``doodlecam send JOB --udp``).

The PLC drives the exchange (docs/protocol.md): the sender says HELLO, sends
the job HEADER until the PLC takes it, then answers every REQUEST with the
requested commands, until the PLC reports the job DONE. It keeps no
retransmission state of its own: the PLC re-requests what it lacks, so
answering a duplicate or late REQUEST costs bandwidth, never correctness.

Resuming: the PLC's count of executed commands is the truth. The sender
stores the job id, the job's secret owner token and the last count it heard
in a small state file next to the job (written atomically, mode 0600), so a
restarted sender re-attaches to a job the PLC is still running, resumes one
the PLC holds (after Ctrl-C, an underrun, a killed sender or a power cycle),
and only falls back on its own record when the PLC no longer remembers the
job. Each run has its own random session nonce; every HEADER (and CANCEL)
carries the challenge the PLC announces in every message, and every DATA, STOP
and HELLO of the job the challenge its accepted HEADER carried, so the PLC can
tell this run's datagrams from a captured session played back; with a key
every datagram is HMAC-tagged. A PAUSE command (a pen change) makes the PLC hold the job with the
pen up; the sender asks the operator (``pen_change``) and resumes after it, and
so does any run that resumes right after a PAUSE, so a pen change is never
skipped. Silence is judged against the PLC's buffer: the sender waits
``timeout`` plus the planned time of the commands the PLC still holds.
"""

from __future__ import annotations

import secrets
import socket
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from doodlecam.link.plc import protocol as P
from doodlecam.link.plc.packetfile import PAUSE, read_plc_array
from doodlecam.link.plc.protocol import Fault, Msg, Nak, State
from doodlecam.link.session import (
    Interrupts,
    LinkError,
    Paused,
    clear_state,
    load_state,
    save_state,
)


@dataclass
class SendResult:
    job_id: int
    commands: int
    start_at: int  # first command this run sent (1 unless resumed)
    executed: int
    elapsed: float  # wall s
    resumed: bool = False
    already_done: bool = False
    underruns: int = 0
    stats: dict = field(default_factory=dict)




# ---------------------------------------------------------------- the sender

def parse_target(text: str, default_port: int | None = None) -> tuple[str, int]:
    """'HOST:PORT' -> (host, port); raise LinkError with the expected form."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, str(default_port) if default_port else ""
    try:
        p = int(port)
        if not 0 < p < 65536:
            raise ValueError
    except ValueError:
        raise LinkError(f"'{text}' is not HOST:PORT (e.g. 192.168.1.20:5005)") from None
    return host.strip("[]") or "127.0.0.1", p


class UdpSender:
    """Sends one packet file to a PLC. ``run()`` returns a SendResult or raises a DoodleError."""

    def __init__(self, host: str, port: int, plc_bytes: bytes, name: str = "job.plc", *,
                 state_file: Path | None = None, timeout: float = 5.0, rto: float = 0.1,
                 restart: bool = False, again: bool = False, key: bytes | None = None,
                 progress: Callable[[int, int, P.Status | None], None] | None = None,
                 log: Callable[[str], None] | None = None,
                 pen_change: Callable[[int, str], None] | None = None):
        if timeout <= 0 or rto <= 0:
            raise ValueError("timeout and rto must be positive")
        self.key = key or None
        self.again = again
        self.host, self.port, self.name = host, port, name
        self.plc_header, self.records = read_plc_array(plc_bytes, name)
        self.n = len(self.records)
        self.crc = P.job_crc(plc_bytes)
        self.state_file = state_file
        self.timeout, self.rto = timeout, rto
        self.stall_timeout = max(30.0, 6 * timeout)  # no command takes this long: a MOVE across 400 mm takes ~3 s
        self.restart = restart
        self.progress = progress or (lambda executed, total, status: None)
        self.log = log or (lambda msg: None)
        self.pen_change = pen_change  # (pen number, what to fit): returns once the operator has fitted it
        self._pen_fitted = 0  # the resume point whose pen change the operator answered
        self.pen_changes = 0
        # This run's session nonce: the PLC takes DATA / STOP only from this address with this nonce.
        self.session = secrets.randbits(64) | 1
        self.challenge = 0  # the PLC's current challenge, from its latest message: the next HEADER / CANCEL carries it
        self.bound = 0  # the challenge of the HEADER the PLC took: this run's DATA / STOP / HELLO carry it
        self.seq = 0
        self.job_id: int | None = None
        self.token = 0  # the job's owner token (random, in the record): proves the job is ours after a restart
        self.executed = 0
        self.start_at = 1
        self.boot: int | None = None
        self.last_seq = 0
        self.last_heard = 0.0
        self.last_status: P.Status | None = None
        self.underruns = 0
        self.stats = {"datagrams_sent": 0, "datagrams_received": 0, "invalid_received": 0,
                      "unauthenticated_received": 0, "stale_received": 0, "commands_sent": 0}
        self._left = planned_time_left(self.records, self.plc_header)
        self._saved_at = 0.0
        self._saved_executed = -1
        self.sock: socket.socket | None = None
        self._serving = False  # the job is under way: an unreachable port is a pause, not a wrong address
        self.interrupts = Interrupts()

    # ------------------------------------------------------------ plumbing

    @property
    def where(self) -> str:
        return f"{self.host}:{self.port}"

    def _open(self) -> None:
        try:
            infos = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_DGRAM)
        except socket.gaierror as e:
            raise LinkError(f"cannot resolve PLC host '{self.host}' ({e.strerror}); check the name or use its IP address") from None
        family, _, _, _, addr = infos[0]
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self.sock.connect(addr)  # also filters datagrams from other hosts and reports ICMP errors
        except OSError as e:
            self.sock.close()
            raise LinkError(f"cannot reach the PLC at {self.where} ({e.strerror}); check the address and the network") from None

    def _send(self, datagram: bytes) -> None:
        try:
            self.sock.send(datagram)
        except ConnectionRefusedError:
            if self._serving:  # mid-job, a PLC rebooting: silence, judged by the patience of _serve
                return
            raise self._refused() from None
        except OSError as e:
            raise LinkError(f"cannot send to the PLC at {self.where} ({e.strerror}); check the network") from None
        self.stats["datagrams_sent"] += 1

    def _refused(self) -> LinkError:
        return LinkError(f"nothing answers at {self.where} (connection refused); is the PLC on, and the port right? "
                         f"(to try without hardware: doodlecam sim plc --port {self.port})")

    def _next_seq(self) -> int:
        self.seq += 1
        return self.seq

    def _recv(self, wait: float) -> P.Message | None:
        """The next valid, new PLC message within ``wait`` s, else None."""
        self.interrupts.check()
        self.sock.settimeout(max(min(wait, 0.2), 1e-4))
        try:
            data = self.sock.recv(65536)
        except (socket.timeout, BlockingIOError):
            return None
        except ConnectionRefusedError:
            if self._serving:
                return None
            raise self._refused() from None
        except OSError as e:
            raise LinkError(f"lost the link to the PLC at {self.where} ({e.strerror})") from None
        self.stats["datagrams_received"] += 1
        try:
            m = P.decode(data, self.key)
        except P.OldVersion as e:
            raise LinkError(f"the PLC at {self.where} speaks protocol version {e.version}, this doodlecam speaks "
                            f"{P.VERSION}; update the PLC's program (docs/protocol.md)") from None
        except P.AuthError:
            self.stats["unauthenticated_received"] += 1
            return None
        except P.ProtocolError:
            self.stats["invalid_received"] += 1
            return None
        if m.type < 0x10:
            self.stats["invalid_received"] += 1
            return None
        if self.boot is not None and m.origin != self.boot:
            # A new boot id: the PLC restarted and lost its buffer and position.
            if self.job_id is not None and self.executed > 0:
                self._save(force=True)
                raise LinkError(f"the PLC at {self.where} restarted during the job (after command {self.executed} of "
                                f"{self.n}); it keeps its place: once it is homed, send the job again to resume")
            self.last_seq = 0
        self.boot = m.origin
        if m.seq <= self.last_seq:  # a duplicate, or overtaken by a newer message: stale news
            self.stats["stale_received"] += 1
            return None
        self.last_seq = m.seq
        self.challenge = m.challenge
        self.last_heard = time.monotonic()
        self.last_status = m.status
        return m

    def _save(self, force: bool = False) -> None:
        now = time.monotonic()
        if force or (self.executed != self._saved_executed and now - self._saved_at > 0.5):
            save_state(self.state_file, {"job_crc": self.crc, "job_id": self.job_id, "token": self.token,
                                         "executed": self.executed, "total": self.n, "plc": self.where,
                                         "updated": time.time()})
            self._saved_at, self._saved_executed = now, self.executed

    # ------------------------------------------------------------ phases

    def _hello(self) -> P.Message:
        """Say HELLO until the PLC answers; wait out its initialisation."""
        deadline = time.monotonic() + self.timeout
        next_hello = 0.0
        m = None
        while time.monotonic() < deadline:
            if time.monotonic() >= next_hello:
                self._send(P.hello(self.session, self._next_seq(), self.job_id or 0, self.key, self.bound))
                next_hello = time.monotonic() + min(0.25, self.timeout / 4)
            got = self._recv(min(next_hello, deadline) - time.monotonic())
            if got is None:
                continue
            m = got
            if m.type == Msg.NAK and m.reason == Nak.BUSY and m.detail != self.job_id:
                raise self._busy(m)
            if m.type == Msg.NAK and m.reason == Nak.AUTH_REQUIRED:
                raise LinkError(f"the PLC at {self.where} requires a key: give the same one with --transport-opt "
                                "key=... or the machine profile's [transport.udp] key")
            if m.status.state not in (State.POWER_ON, State.A_INIT):
                return m
        if m is not None:
            raise LinkError(f"the PLC at {self.where} is not initialised (state {State(m.status.state).name}); "
                            "press a Y limit switch so it homes, then send the job again")
        if self.stats["unauthenticated_received"]:
            raise LinkError(f"the PLC at {self.where} answers, but not with this key: set the same key on both sides "
                            "(--transport-opt key=... / the PLC's key), or none on both")
        raise LinkError(f"no answer from the PLC at {self.where} within {self.timeout:g} s; check that it is on, "
                        f"connected and at that address (to try without hardware: doodlecam sim plc --port {self.port}); "
                        "if the PLC requires a key, give it with --transport-opt key=...")

    def _busy(self, m: P.Message) -> LinkError:
        who = f"{m.owner[0]}:{m.owner[1]}" if m.owner else "another computer"
        return LinkError(f"busy: job {m.detail} from {who} is running on the PLC at {self.where}; wait for it to "
                         "finish (only the computer that started a job can stop or cancel it)")

    def _decide(self, m: P.Message, saved: dict | None) -> int | None:
        """The first command to send, or None when the PLC already finished this job."""
        s = m.status
        mine = self.job_id
        jid = m.detail if m.type == Msg.NAK else m.job_id  # NAK BUSY: the running job is in detail
        if s.state in (State.C_BUFFER, State.D_OPERATING):
            if jid == mine:
                self.executed = s.executed
                self.log(f"the PLC is running this job (at command {s.executed + 1}); re-attaching")
                return s.executed + 1  # the header (with our token) re-binds the job to this run
            raise LinkError(f"busy: job {jid} is running on the PLC at {self.where}; wait for it to finish")
        if s.held and not self.restart and s.job_crc == self.crc and mine is None:
            raise LinkError(f"the PLC at {self.where} holds this job (job {m.job_id}), but this computer has no record "
                            f"of starting it, so it cannot resume it; add --restart to start over (that abandons it)")
        if s.held and not self.restart and s.job_crc == self.crc and mine == m.job_id:
            self.job_id = m.job_id
            self.log(f"the PLC holds this job before command {s.executed + 1} ({P.FAULT_TEXT[Fault(s.fault)]}); resuming")
            return s.executed + 1
        if s.held and m.job_id != mine:
            self.log(f"the PLC holds an unfinished job (id {m.job_id}); sending this one discards it")
        if mine is not None and m.job_id == mine and not s.held:
            if s.last_done_job == mine:
                return None
            if s.fault in (Fault.CANCELLED, Fault.BOUNDARY, Fault.LIMIT_SWITCH, Fault.BAD_COMMAND):
                raise LinkError(f"this job ended on the PLC: {P.FAULT_TEXT[Fault(s.fault)]} (command {s.fault_command}); "
                                "send it again with --restart to start over")
        if mine is not None and saved and not self.restart:
            k = int(saved.get("executed", 0))
            if k >= self.n:
                return None
            if k > 0:
                self.log(f"the PLC does not remember job {mine} (was it restarted?); resuming from this computer's "
                         f"record after command {k}: commands executed after that record was saved run again")
            return k + 1
        self.job_id = secrets.randbits(32) or 1  # a fresh job id: a job id is used for one run only
        self.token = secrets.randbits(64) | 1
        return 1

    def _start(self, start_at: int) -> None:
        """Send HEADER until the PLC takes the job (answers about it in C_buffer / D_operating)."""
        for _ in range(3):  # a START_MISMATCH correction at most twice
            self.start_at = start_at
            self.executed = max(start_at - 1, 0)
            self._save(force=True)  # the job id is on disk before the PLC can start it
            self._ask_for_pen(start_at)
            resume = P.resume_state(self.records, self.plc_header.delta_time, start_at)
            hdr = P.JobHeader.from_plc(self.plc_header, self.crc, start_at, resume, token=self.token,
                                       flags=P.AGAIN if self.again else 0)
            deadline = time.monotonic() + self.timeout
            next_send = 0.0
            sent_with = 0
            while True:
                now = time.monotonic()
                if now >= deadline:
                    raise LinkError(f"the PLC at {self.where} did not take the job header within {self.timeout:g} s; "
                                    "check that it is idle (B_ready) and the link is up")
                if now >= next_send:
                    sent_with = self.challenge  # the PLC's latest: if it takes this header, the session has it
                    self._send(P.header(self.session, self._next_seq(), self.job_id, hdr, self.key, sent_with))
                    next_send = now + self.rto
                m = self._recv(min(next_send, deadline) - time.monotonic())
                if m is None:
                    continue
                s = m.status
                if m.type == Msg.NAK:
                    if m.reason == Nak.START_MISMATCH and m.job_id == self.job_id and m.detail >= 1:
                        self.log(f"the PLC holds this job before command {m.detail}; resuming there")
                        start_at = m.detail
                        break
                    if m.reason == Nak.FINISHED and m.job_id == self.job_id:
                        if s.last_done_job == self.job_id:
                            self.executed = self.n
                            return
                        raise LinkError(f"the PLC will not run job {self.job_id} again ({P.FAULT_TEXT[Fault(m.detail)]}); "
                                        "send it with --restart to start over")
                    if m.reason == Nak.BUSY:
                        raise self._busy(m)
                    if m.reason == Nak.ALREADY_DONE:
                        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(m.when))
                        raise LinkError(f"the PLC at {self.where} already finished {self.name} on {when} (job "
                                        f"{m.detail}); to draw it again, add --again")
                    if m.reason == Nak.BAD_HEADER:
                        raise LinkError(f"the PLC at {self.where} rejected the header of {self.name}; re-export the job")
                    if m.reason == Nak.STALE_CHALLENGE:
                        next_send = 0.0  # at once, with the challenge this NAK carries
                    continue  # NOT_READY: keep trying until the deadline
                if m.job_id == self.job_id and (s.state in (State.C_BUFFER, State.D_OPERATING) or m.type == Msg.DONE):
                    self.bound = sent_with
                    self._on_message(m)
                    return
        raise LinkError(f"the PLC at {self.where} keeps changing its resume point; cancel the job with --cancel")

    def _ask_for_pen(self, start_at: int) -> None:
        """Resuming right after a PAUSE: the operator fits the pen first (once per pause)."""
        if start_at < 2 or self.records["type"][start_at - 2] != PAUSE or self._pen_fitted == start_at:
            return
        pen = int(self.records["x"][start_at - 2])
        if self.pen_change is None:
            raise Paused(f"the job waits for a pen change before command {start_at} of {self.n}, pen up: fit pen "
                         f"{pen}, then send the same job again to resume")
        self.pen_change(pen, f"pen {pen}")
        self._pen_fitted = start_at
        self.pen_changes += 1
        self.last_heard = time.monotonic()  # the operator's time is not the PLC's silence

    def _send_range(self, first: int, count: int) -> None:
        lo, hi = max(first, 1), min(first + count - 1, self.n)
        for a in range(lo, hi + 1, P.MAX_PER_DATA):
            b = min(a + P.MAX_PER_DATA - 1, hi)
            self._send(P.data(self.session, self._next_seq(), self.job_id, self.records[a - 1:b], self.key, self.bound))
            self.stats["commands_sent"] += b - a + 1

    def _on_message(self, m: P.Message) -> str | None:
        """React to a message about our job; 'done' / 'held' when the job leaves the PLC's hands."""
        if m.job_id != self.job_id:
            return None
        s = m.status
        if s.executed > self.executed:
            self.executed = s.executed
        if m.type == Msg.REQUEST:
            for first, count in m.ranges:
                self._send_range(first, count)
        if m.type == Msg.DONE or s.last_done_job == self.job_id:
            self.executed = self.n
            return "done"
        if s.state == State.B_READY:
            if s.held:
                return "held"
            if m.type == Msg.FAULT or s.fault != Fault.NONE:
                self._save(force=True)
                where = f" at ({s.x / self.plc_header.steps_per_mm_x:.1f}, {s.y / self.plc_header.steps_per_mm_y:.1f}) mm"
                if s.fault == Fault.CANCELLED:  # not a fault of the machine: say how far the job got
                    ran = max(self.executed, s.fault_command - 1)
                    raise LinkError(f"the job was cancelled on the PLC after command {ran} of {self.n}{where} "
                                    "('doodlecam send --cancel' from this computer); send it with --restart to draw "
                                    "it from the beginning")
                raise LinkError(f"PLC fault at command {s.fault_command} of {self.n}{where}: {P.FAULT_TEXT[Fault(s.fault)]}")
        return None

    def _serve(self, stopping: bool = False) -> str:
        """Answer requests until the job is done (or held, when stopping)."""
        last_progress = next_hello = 0.0
        moved_at, mark = time.monotonic(), None
        self._serving = True
        while True:
            m = self._recv(0.1)
            now = time.monotonic()
            st = self.last_status
            if st is not None and (self.executed, st.buffered) != mark:
                moved_at, mark = now, (self.executed, st.buffered)
            elif now - moved_at > self.stall_timeout:
                self._save(force=True)
                raise LinkError(f"the PLC at {self.where} answers but has made no progress for {self.stall_timeout:g} s "
                                f"(after command {self.executed} of {self.n}); check the machine, then send again")
            if m is None:
                silent = now - self.last_heard
                if silent > self._patience():
                    self._save(force=True)
                    raise LinkError(f"the PLC at {self.where} stopped answering for {silent:.1f} s after command "
                                    f"{self.executed} of {self.n}; check it, then send the job again to resume")
                if silent > 2 * self.rto and now >= next_hello:  # ask: a restarted PLC answers with its new boot id
                    self._send(P.hello(self.session, self._next_seq(), self.job_id, self.key, self.bound))
                    next_hello = now + max(self.rto, 0.25)
                continue
            outcome = self._on_message(m)
            if now - last_progress > 0.1 or outcome:
                self.progress(self.executed, self.n, m.status)
                last_progress = now
            if outcome == "done":
                return "done"
            if outcome == "held":
                s = m.status
                if stopping or s.fault == Fault.STOPPED:
                    return "held"
                if s.fault == Fault.PEN_CHANGE:  # a PAUSE ran: the operator changes the pen, then it goes on
                    self._start(s.executed + 1)
                    moved_at, mark = time.monotonic(), None
                    self._save()
                    continue
                # The PLC ran dry (this computer or the network was too slow): resume where it stopped.
                self.underruns += 1
                self.log(f"the PLC ran out of commands before command {s.executed + 1} and stopped; resuming")
                self._start(s.executed + 1)
            self._save()

    def _patience(self) -> float:
        """Seconds of silence to accept: ``timeout``, or longer while the PLC still has commands buffered."""
        st = self.last_status
        if st is None:
            return self.timeout
        lo, hi = (min(max(int(v), 0), self.n) for v in (st.executed, st.buffered))
        return self.timeout + max(float(self._left[lo] - self._left[max(hi, lo)]), 0.0)

    def _pause(self) -> None:
        """Ctrl-C: stop at the end of the stroke (again: stop now), wait for the PLC to confirm."""
        mode = 0
        self.log("stopping at the end of the current stroke (Ctrl-C again stops at once)")
        self.last_heard = time.monotonic()
        while True:
            try:
                self._send(P.stop(self.session, self._next_seq(), self.job_id, now=bool(mode), key=self.key,
                                  challenge=self.bound))
                end = time.monotonic() + self.rto * 3
                while time.monotonic() < end:
                    m = self._recv(end - time.monotonic())
                    if m is None:
                        continue
                    outcome = self._on_message(m)
                    if outcome == "done":  # it finished before the stop took effect
                        return
                    if outcome is None and m.status.state == State.B_READY and not (
                            m.status.held and m.job_id == self.job_id):
                        self._save(force=True)  # the PLC has not taken the job (yet): nothing to stop
                        raise Paused(f"stopped before the PLC started the job (after command {self.executed} of "
                                     f"{self.n}); send the same job again to resume")
                    if outcome == "held":
                        self._save(force=True)
                        raise Paused(f"paused before command {self.executed + 1} of {self.n}, pen up; send the same job "
                                     "again to resume, or add --cancel to abandon it")
                if time.monotonic() - self.last_heard > self.timeout:  # the stroke may be long: wait while it talks
                    self._save(force=True)
                    raise LinkError(f"the PLC at {self.where} stopped answering before confirming the stop; check the machine "
                                    f"(last executed command {self.executed} of {self.n})")
            except KeyboardInterrupt:
                if mode == 1:
                    self._save(force=True)
                    raise Paused(f"gave up waiting for the PLC to stop after command {self.executed}; check the machine")
                mode = 1
                self.log("stopping now")

    # ------------------------------------------------------------ entry points

    def run(self) -> SendResult:
        t0 = time.monotonic()
        saved = None if self.restart else load_state(self.state_file, self.crc)
        if saved:
            self.job_id, self.token = saved["job_id"], int(saved.get("token") or 0)
        self._open()
        try:
            with self.interrupts:
                return self._run(t0, saved)
        finally:
            self.sock.close()

    def _run(self, t0: float, saved: dict | None) -> SendResult:
        first = self._hello()
        start_at = self._decide(first, saved)
        already = start_at is None
        initial = start_at or self.executed + 1  # pen changes restart the job later on: report this run's start
        if not already:
            try:
                if start_at:
                    self._start(start_at)
                else:
                    self.start_at = self.executed + 1
                self.progress(self.executed, self.n, self.last_status)
                if self.executed < self.n:
                    self._serve()
            except KeyboardInterrupt:
                self._pause()
        clear_state(self.state_file)
        self.executed = self.n
        self.progress(self.n, self.n, self.last_status)
        return SendResult(self.job_id or 0, self.n, initial, self.n, time.monotonic() - t0,
                          resumed=initial > 1, already_done=already, underruns=self.underruns,
                          stats=dict(self.stats))

    def cancel(self) -> int | None:
        """Cancel the job the PLC runs or holds; return its id (None if it had none)."""
        saved = load_state(self.state_file, self.crc)
        if saved:
            self.job_id = saved["job_id"]
        self._open()
        try:
            m = self._hello()
            s = m.status
            busy = s.state in (State.C_BUFFER, State.D_OPERATING) or s.held
            if not busy:
                clear_state(self.state_file)
                return None
            victim = m.detail if m.type == Msg.NAK else m.job_id
            saved = load_state(self.state_file, self.crc)
            if not saved or saved["job_id"] != victim:
                who = f" from {m.owner[0]}:{m.owner[1]}" if m.owner else ""
                raise LinkError(f"the PLC at {self.where} has job {victim}{who}, which {self.name} did not start here; "
                                "only the computer that started a job can cancel it")
            self.job_id, self.token = victim, int(saved.get("token") or 0)
            deadline = time.monotonic() + self.timeout
            while time.monotonic() < deadline:
                self._send(P.cancel(self.session, self._next_seq(), victim, self.token, self.key, self.challenge))
                end = time.monotonic() + self.rto * 3
                while time.monotonic() < end:
                    r = self._recv(end - time.monotonic())
                    if r is None:
                        continue
                    rs = r.status
                    if r.type == Msg.NAK and r.reason == Nak.BUSY:
                        raise self._busy(r)
                    if rs.state == State.B_READY and not (rs.held and r.job_id == victim):
                        clear_state(self.state_file)
                        return victim
            raise LinkError(f"the PLC at {self.where} did not confirm the cancel within {self.timeout:g} s; check the machine")
        finally:
            self.sock.close()


def planned_time_left(records: np.ndarray, plc_header) -> np.ndarray:
    """left[k] = planned seconds still to run after k commands executed (pen delays excluded)."""
    d = P.command_durations(records, plc_header)
    return np.concatenate([[d.sum()], d.sum() - np.cumsum(d)])
