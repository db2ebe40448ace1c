"""Stream G-code to a GRBL controller over serial (``doodlecam send JOB --serial PORT``).

GRBL's rules (doc/markdown/interface.md, "Streaming protocol"), all kept here:

* character counting: GRBL's serial receive buffer is 128 bytes, so the
  sender keeps at most 127 bytes of lines that GRBL has not answered yet;
  each ``ok`` or ``error:N`` answers the oldest outstanding line;
* ``\n`` line endings only (GRBL ends a line on CR *and* on LF, so CR LF
  would be two lines and two answers, which breaks the count);
* ``$`` lines (settings writes, EEPROM) in send-and-wait mode, once idle;
* real-time commands bypass the buffer: ``?`` status (at most 5 Hz), ``!``
  feed hold, ``~`` resume, 0x18 soft reset;
* ``error:N`` stops the job (the code's meaning and the file line are
  reported); ``ALARM:N`` stops it and says how to recover ($X / $H);
* ``$C`` check mode parses the whole file without moving, as a dry run.

Controls while streaming (``controls()`` returns one of these or None):
``pause`` stops sending, lets GRBL finish what it has and lifts the pen
(the file's own pen-up command); ``resume`` puts the pen back down where it
was (``resume_prefix``) and goes on, so every file line is still sent once;
``hold`` / ``start`` are GRBL's feed hold ``!`` and cycle start ``~`` (an
immediate stop, the pen stays as it is); ``feed+``, ``feed-``, ``feed=``
the feed override bytes 0x91, 0x92, 0x90; ``stop`` is Ctrl-C's clean stop.

Pen changes: the G-code post writes ``M0 (change to pen 2 [red])`` between
layers, with the pen up. GRBL finishes every move before it, holds
(``Hold:0``) and answers the M0 line only after a cycle start. The streamer
then calls ``pen_change(pen, what)`` ("change to pen 2 (red), then press
Enter") and sends ``~`` when it returns. Without an answer (no callback, or
it raises Paused) GRBL is reset where it stands (Hold:0 keeps the position)
and the resume point is the M0 line, so sending the job again asks again.

The code tables are GRBL 1.1's (doc/csv/error_codes_en_US.csv and
alarm_codes_en_US.csv in the gnea/grbl repository).
"""

from __future__ import annotations

import json
import os
import re
import time
import zlib
from collections import deque
from pathlib import Path
from typing import Callable

from doodlecam.errors import InputError
from doodlecam.link.grbl.port import GrblLink, StreamResult
from doodlecam.link.grbl.protocol import (
    _AXIS,
    MAX_OUTSTANDING,
    GcodeLine,
    GrblError,
    GrblStatus,
    _is_offset,
    _is_pen,
    error_text,
    pen_up_line,
    prepare,
    resume_prefix,
)
from doodlecam.link.session import LinkError, Paused, clear_state, save_state

_PROGRAM_PAUSE = re.compile(r"(?<![A-Z\d.])M0*0(?![\d.])")
_PEN_IN_MESSAGE = re.compile(r"\bpen (\d+)\b", re.I)


def is_program_pause(line: GcodeLine) -> bool:
    """An M0 (program pause) line: GRBL holds there until a cycle start."""
    return bool(_PROGRAM_PAUSE.search(line.text.upper()))


def pen_change_message(line: GcodeLine) -> tuple[int | None, str]:
    """(pen number or None, what to fit) from an M0 line's comment, e.g.
    'M0 (change to pen 2 [red])' -> (2, 'pen 2 (red)'), 'M0 (fit pen 1)' (the first pen) -> (1, 'pen 1');
    brackets stand for the parentheses a G-code comment cannot hold."""
    m = re.search(r"\(([^)]*)\)", line.source) or re.search(r"M0*0\s+(.+)$", line.source, re.I)
    text = (m.group(1).strip() if m else "").replace("[", "(").replace("]", ")")
    text = re.sub(r"^(?:MSG,\s*)?(?:(?:change to|fit)\s+)?", "", text, flags=re.I) or "the next pen"
    pen = _PEN_IN_MESSAGE.search(text)
    return (int(pen.group(1)) if pen else None), text

# ---------------------------------------------------------------- streaming

class Streamer:
    """Streams prepared lines over a GrblLink with character counting.

    ``before_write(k)`` is called just before line k is written to the port
    (lines [0, k) surely reached it: the resume record); ``progress(acked,
    total, status)`` as answers come.
    """

    def __init__(self, link: GrblLink, lines: list[GcodeLine], *, name: str = "G-code",
                 before_write: Callable[[int], None] | None = None,
                 progress: Callable[[int, int, GrblStatus | None], None] | None = None,
                 controls: Callable[[], str | None] | None = None,
                 pen_change: Callable[[int | None, str], None] | None = None):
        self.link, self.lines, self.name = link, lines, name
        self.pen_change = pen_change
        self.pen_changes = 0  # M0 pauses the operator answered
        self.controls = controls or (lambda: None)
        self.paused = False  # no new lines go out
        self.lifted = False  # the pause lifted the pen: resume lowers it again
        self.added: list[tuple[int, str]] = []  # (lines of the job sent before, text) of lines the sender added
        self.held = False
        self.before_write = before_write or (lambda k: None)
        self.progress = progress or (lambda a, n, s: None)
        self.inflight: deque[tuple[int, int]] = deque()  # (index, bytes)
        self.used = 0
        self.sent = 0
        self.acked = 0
        self.stopping = 0
        self.errors: list[tuple[GcodeLine, int]] = []
        self.halted = False
        self.max_outstanding = 0

    def where(self, i: int) -> str:
        ln = self.lines[i]
        return f"{self.name}:{ln.lineno} '{ln.source.strip() or ln.text}'" if ln.lineno else f"resume line '{ln.text}'"

    def _send_lines(self) -> None:
        link, lines = self.link, self.lines
        while self.sent < len(lines) and not self.stopping:
            ln = lines[self.sent]
            size = len(ln.text) + 1
            if ln.text.startswith("$"):
                # EEPROM writes stall GRBL's serial interrupt: send-and-wait, and only when idle.
                if self.inflight:
                    return
                link.wait_idle()
                i = self.sent
                self.before_write(i)
                kind, code = link.send_wait(ln.text)
                self.sent += 1
                self._answered(i, kind, code)
                continue
            if self.used + size > MAX_OUTSTANDING:
                return
            self.before_write(self.sent)
            link.write((ln.text + "\n").encode("ascii"))
            self.inflight.append((self.sent, size))
            self.used += size
            self.max_outstanding = max(self.max_outstanding, self.used)
            self.sent += 1

    def _answered(self, i: int, kind: str, code: int, check: bool = False) -> None:
        self.acked += 1
        if kind == "error":
            if check:
                self.errors.append((self.lines[i], code))
                return
            self._halt()
            raise GrblError(f"GRBL refused {self.where(i)}: error:{code} {error_text(code)}; the job was stopped there, "
                            "fix the line and send the job again")

    def _halt(self) -> None:
        """Stop motion at once, keeping the position: feed hold, then reset once held."""
        link = self.link
        try:
            link.realtime(b"!")
            end = time.monotonic() + link.timeout
            while time.monotonic() < end:
                st = link.fresh_status()
                if st.state in ("Idle", "Alarm") or (st.state == "Hold" and st.substate == 0):
                    break
            link.soft_reset()
        except LinkError:
            pass

    def run(self, check: bool = False) -> StreamResult:
        t0 = time.monotonic()
        start = self.sent
        self.acked = self.sent
        self.max_outstanding = 0
        with self.link.interrupts:
            return self._run(check, t0, start)

    def _run(self, check: bool, t0: float, start: int) -> StreamResult:
        while True:
            try:
                self._loop(check)
                break
            except KeyboardInterrupt:
                self.stopping += 1
                if self.stopping >= 2:
                    self._stop_now()
                self.link.log("finishing the lines GRBL already has, then lifting the pen (Ctrl-C again stops at once)")
        if self.stopping:
            try:
                self._finish_queued()
            except KeyboardInterrupt:
                self._stop_now()
            nxt = self.sent
            where = f"{self.name}:{self.lines[nxt].lineno}" if nxt < len(self.lines) else "the end"
            raise Paused(f"paused before {where} with the pen up; send the same job again to resume")
        return StreamResult(len(self.lines), start, self.errors, time.monotonic() - t0, self.max_outstanding)

    def _stop_now(self) -> None:
        """Second Ctrl-C: feed hold and reset. What GRBL had queued is lost, so no resume point is known."""
        self._halt()
        self.halted = True
        last = self.lines[max(self.sent - 1, 0)].lineno
        raise Paused(f"stopped at once (feed hold, reset) with lines up to {self.name}:{last} sent; check the drawing, "
                     "then send it again with --from-line N") from None

    def _control(self, check: bool) -> None:
        """Act on the user's control, if any (see the module docstring)."""
        c = self.controls()
        if c is None:
            return
        link = self.link
        if c == "stop":
            if self.held:  # already standing still: reset now (a reset in Hold:0 keeps the position)
                self._stop_now()
            raise KeyboardInterrupt
        if c == "pause" and not self.paused and not check:
            self.paused = True
            link.log("pausing: GRBL finishes the lines it has, then the pen is lifted ('resume' goes on)")
        elif c == "resume" and self.held:
            link.realtime(b"~")
            self.held = False
        elif c == "resume" and self.paused:
            if self.lifted:  # back to the state before the next line: position, pen down, dwell, feed
                for ln in resume_prefix(self.lines, self.sent):
                    self._extra(ln.text)
                link.wait_idle()
            self.paused = self.lifted = False
            link.log("resumed")
        elif c == "hold":
            link.realtime(b"!")
            self.held = True
        elif c in ("feed+", "feed-", "feed="):
            link.realtime({"feed+": b"\x91", "feed-": b"\x92", "feed=": b"\x90"}[c])

    def _extra(self, text: str) -> None:
        """A line the sender adds (not from the file), sent and answered alone."""
        self.added.append((self.sent, text))
        kind, code = self.link.send_wait(text)
        if kind != "ok":
            self._halt()
            raise GrblError(f"GRBL refused '{text}' (added to pause/resume the job): error:{code} {error_text(code)}")

    def _lift_when_drained(self) -> None:
        """Paused and nothing in flight: once GRBL is idle, lift the pen if it is down."""
        if self.lifted or self.sent >= len(self.lines):
            return
        self.link.wait_idle()
        up = pen_up_line(self.lines)
        last = next((ln.text for ln in reversed(self.lines[:self.sent]) if _is_pen(ln.text)), up)
        if last != up:
            self._extra(up)
            self.link.wait_idle()
        self.lifted = True
        self.link.log(f"paused before {self.where(self.sent)} with the pen up; 'resume' goes on")

    def _loop(self, check: bool) -> None:
        link = self.link
        while self.inflight if self.stopping else self.acked < len(self.lines):
            self._control(check)
            if not self.paused:
                self._send_lines()
            if not self.inflight:
                if self.sent >= len(self.lines) or self.stopping:
                    break
                if self.paused:
                    self._lift_when_drained()
                    link.next_event(0.05)  # status polled while paused
                continue
            ev = link.next_event(0.1)
            if ev is None:
                continue
            kind = ev[0]
            if kind in ("ok", "error"):
                if not self.inflight:
                    self._halt()
                    raise GrblError(f"GRBL on {link.port} answered a line that was never sent; is another program "
                                    "using the port? The job was stopped")
                i, size = self.inflight.popleft()
                self.used -= size
                self._answered(i, kind, ev[1] if kind == "error" else 0, check)
                self.progress(self.acked, len(self.lines), link.status)
            elif kind == "alarm":
                i = self.inflight[0][0] if self.inflight else self.sent - 1
                raise link.alarm_error(ev[1], f"near {self.where(i)}")
            elif kind == "banner":
                near = self.where(min(self.acked, len(self.lines) - 1))
                raise GrblError(f"GRBL reset itself during the job (near {near}); check its power and wiring, "
                                "home it, then send again with --from-line")
            elif kind == "status":
                self.progress(self.acked, len(self.lines), ev[1])
                st = ev[1]
                if (st.state == "Hold" and st.substate == 0 and not self.held and self.inflight
                        and is_program_pause(self.lines[self.inflight[0][0]])):
                    self._program_pause(self.inflight[0][0])
        if not check and not self.stopping:
            self.link.wait_idle()  # every line answered: wait for the motion to finish

    def _program_pause(self, i: int) -> None:
        """GRBL holds at the M0 of line i (pen up, every move before it done): ask the operator, then go on."""
        pen, what = pen_change_message(self.lines[i])
        try:
            if self.pen_change is None:
                raise Paused(f"the job waits for a pen change at {self.where(i)}")
            self.link.log(f"pen change at {self.where(i)}: change to {what}")
            self.pen_change(pen, what)
        except (Paused, KeyboardInterrupt) as e:
            # Nobody to answer: reset where it stands (Hold:0 keeps the position); what GRBL queued after
            # the M0 is lost, so the resume point is the M0 line itself, which asks again.
            self._halt()
            self.sent = i
            self.inflight.clear()
            raise Paused(f"{e or 'stopped'}; GRBL was reset before {self.where(i)} with the pen up: fit "
                         f"{what}, then send the same job again to resume there") from None
        self.link.fresh_status()  # the wait was silent: hear GRBL again before judging it
        self.link.realtime(b"~")
        self.pen_changes += 1
        self.link.log(f"{what} fitted, going on")

    def _finish_queued(self) -> None:
        """After Ctrl-C: let GRBL finish what it has, then lift the pen."""
        while self.inflight:
            self._loop(check=False)
        self.link.wait_idle()
        if self.sent < len(self.lines):
            kind, code = self.link.send_wait(pen_up_line(self.lines))
            if kind == "ok":
                self.link.wait_idle()


# ---------------------------------------------------------------- a whole send

class ResumeRecord:
    """The per-line resume record of a serial run, cheap enough to write before every line.

    Created whole by a temp file + rename (``save_state``); then each update
    is one fixed-size ``pwrite`` at offset 0. A killed process cannot stop a
    write() system call halfway, so the file always holds one complete
    record (JSON padded with spaces).
    """

    SIZE = 512

    def __init__(self, path: Path | None):
        self.path = Path(path) if path is not None else None
        self.fd: int | None = None

    def write(self, state: dict) -> None:
        if self.path is None:
            return
        data = json.dumps(state).ljust(self.SIZE).encode()
        if len(data) > self.SIZE or self.fd is None:
            save_state(self.path, state)
            self.close()
            if len(data) <= self.SIZE:
                self.fd = os.open(self.path, os.O_WRONLY)
                os.pwrite(self.fd, data, 0)  # pad to the fixed size once
            return
        os.pwrite(self.fd, data, 0)

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def clear(self) -> None:
        self.close()
        clear_state(self.path)


def end_positions(lines: list[GcodeLine]) -> list[tuple[float | None, float | None]]:
    """(x, y) reached after each line (absolute coordinates; None before an axis is first given)."""
    out, x, y = [], None, None
    for ln in lines:
        t = ln.text.upper()
        if not (t.startswith("G4") or t.startswith("$") or _is_offset(t)):
            for letter, val in _AXIS.findall(t):
                if letter == "X":
                    x = float(val)
                elif letter == "Y":
                    y = float(val)
        out.append((x, y))
    return out


def settle_doubt(lines: list[GcodeLine], k: int, status: GrblStatus | None, name: str) -> int:
    """A sender killed while writing line k: did that line reach GRBL? Tell by where the machine stopped.

    GRBL runs every complete line it received, so an idle machine stands at
    the end of the last one. A line that does not move is sent again
    (repeating a pen command or a dwell is harmless).
    """
    pos = end_positions(lines)
    before = pos[k - 1] if k > 0 else (None, None)
    after = pos[k]
    if after == before or status is None:
        return k
    here = status.wpos or status.mpos
    if here is None:
        raise GrblError(f"GRBL reports no position, so it is unknown whether {name}:{lines[k].lineno} ran before the "
                        "last run stopped; check the drawing and send again with --from-line N")

    def at(p) -> bool:  # GRBL stands on whole steps: half a step off the line's target (0.00625 mm at 80/mm)
        return all(v is None or abs(v - h) <= 1e-2 for v, h in zip(p, here[:2]))

    if at(after):
        return k + 1
    if at(before):
        return k
    raise GrblError(f"the machine stands at X{here[0]:.3f} Y{here[1]:.3f}, not where the last run left off "
                    f"({name}:{lines[k].lineno}); check the drawing and send again with --from-line N")


def send_gcode(port: str, path: Path, *, baud: int = 115200, check: bool = False, restart: bool = False,
               from_line: int | None = None, timeout: float = 5.0, connect_timeout: float = 3.0,
               state_file: Path | None = None, progress=None, log=None, controls=None, pen_change=None) -> dict:
    """Stream a G-code file (resuming a paused run unless ``restart``); return a summary dict."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror}); check the path") from None
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not an ASCII G-code file; GRBL reads ASCII only") from None
    lines = prepare(text, str(path))
    if not lines:
        raise InputError(f"{path}: no G-code lines to send")
    crc = zlib.crc32(raw)
    log = log or (lambda msg: None)

    start, pending = 0, False
    if from_line is not None:
        start = next((i for i, ln in enumerate(lines) if ln.lineno >= from_line), len(lines))
    elif not (restart or check) and state_file is not None:
        try:
            st = json.loads(Path(state_file).read_text())
            if st.get("job_crc") == crc and 0 < int(st.get("next", 0)) < len(lines):
                start, pending = int(st["next"]), bool(st.get("pending"))
        except (OSError, ValueError, TypeError, AttributeError):
            pass

    t0 = time.monotonic()
    with GrblLink(port, baud, timeout=timeout, connect_timeout=connect_timeout, log=log) as link:
        status = link.connect()
        if pending:
            start = settle_doubt(lines, start, status, str(path))
        if start and from_line is None and not check:
            log(f"resuming {path.name} at line {lines[start].lineno} (send with --restart to start over)")
        prefix = resume_prefix(lines, start) if start and not check else []
        stream = prefix + lines[start:]

        rec = ResumeRecord(None if check else state_file)

        def record(k: int, pending: bool) -> None:
            if k >= len(prefix):
                rec.write({"job_crc": crc, "next": start + k - len(prefix), "pending": pending, "lines": len(lines),
                           "port": port})

        def prog(acked, total, st):
            if progress:
                progress(min(start + max(acked - len(prefix), 0), len(lines)), len(lines), st)

        if check:
            kind, code = link.send_wait("$C")
            if kind != "ok":
                raise GrblError(f"GRBL on {port} refused check mode ($C): error:{code} {error_text(code)}")
        # Written before each line goes out: lines [0, k) reached GRBL, line k may have (see settle_doubt).
        s = Streamer(link, stream, name=str(path), before_write=lambda k: record(k, True), progress=prog,
                     controls=controls, pen_change=pen_change)
        try:
            result = s.run(check=check)
        except Paused:
            if s.halted:  # reset at once: what GRBL had queued is lost, no resume point is known
                rec.clear()
            else:  # a clean pause: everything sent has run
                record(s.sent, False)
            raise
        except GrblError:
            # After an error or an alarm GRBL was reset: what it had queued is lost.
            rec.clear()
            raise
        finally:
            rec.close()
            if check:
                try:
                    link.send_wait("$C")  # leave check mode; GRBL resets itself
                    link.wait_banner(link.connect_timeout)
                except LinkError:
                    pass
    if not check:
        clear_state(state_file)
    return {"lines": len(lines), "start_line": lines[start].lineno if start < len(lines) else None,
            "resumed": start > 0, "errors": [(ln.lineno, ln.source.strip(), code, error_text(code))
                                             for ln, code in result.errors],
            "elapsed_s": time.monotonic() - t0, "max_outstanding_bytes": result.max_outstanding,
            "pen_changes": s.pen_changes}
