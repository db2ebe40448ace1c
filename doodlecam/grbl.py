"""Stream G-code to a GRBL controller over serial (``doodlecam send JOB --serial PORT``).

GRBL's rules (doc/markdown/interface.md, "Streaming protocol"), all kept here:

* character counting: GRBL's serial receive buffer is 128 bytes, so the
  sender keeps at most 127 bytes of lines that GRBL has not answered yet;
  each ``ok`` or ``error:N`` answers the oldest outstanding line;
* ``\\n`` line endings only (GRBL ends a line on CR *and* on LF, so CR LF
  would be two lines and two answers, which breaks the count);
* ``$`` lines (settings writes, EEPROM) in send-and-wait mode, once idle;
* real-time commands bypass the buffer: ``?`` status (at most 5 Hz), ``!``
  feed hold, ``~`` resume, 0x18 soft reset;
* ``error:N`` stops the job (the code's meaning and the file line are
  reported); ``ALARM:N`` stops it and says how to recover ($X / $H);
* ``$C`` check mode parses the whole file without moving, as a dry run.

The code tables are GRBL 1.1's (doc/csv/error_codes_en_US.csv and
alarm_codes_en_US.csv in the gnea/grbl repository).
"""

from __future__ import annotations

import json
import os
import queue
import re
import threading
import time
import zlib
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .errors import InputError
from .udpsend import Interrupts, LinkError, Paused, clear_state, save_state

RX_BUFFER_SIZE = 128
MAX_OUTSTANDING = RX_BUFFER_SIZE - 1  # bytes of unanswered lines GRBL can hold
MAX_LINE = 79  # characters after GRBL drops spaces and comments (LINE_BUFFER_SIZE 80)
STATUS_PERIOD = 0.2  # s between '?' queries: GRBL asks for at most 5 Hz
REALTIME = "?!~\x18"

ERRORS: dict[int, str] = {
    1: "G-code words consist of a letter and a value; letter was not found",
    2: "numeric value format is not valid or missing an expected value",
    3: "GRBL '$' system command was not recognized or supported",
    4: "negative value received for an expected positive value",
    5: "homing cycle is not enabled via settings ($22)",
    6: "minimum step pulse time must be greater than 3 usec",
    7: "EEPROM read failed; affected values were restored to defaults",
    8: "GRBL '$' command cannot be used unless GRBL is idle",
    9: "G-code locked out during alarm or jog state",
    10: "soft limits cannot be enabled without homing also enabled",
    11: "max characters per line exceeded; line was not processed",
    12: "'$' setting value exceeds the maximum step rate supported",
    13: "safety door detected as opened and door state initiated",
    14: "build info or startup line exceeded EEPROM line length limit",
    15: "jog target exceeds machine travel; command ignored",
    16: "jog command with no '=' or contains prohibited G-code",
    17: "laser mode requires PWM output",
    20: "unsupported or invalid G-code command found in block",
    21: "more than one G-code command from the same modal group found in block",
    22: "feed rate has not yet been set or is undefined",
    23: "G-code command in block requires an integer value",
    24: "two G-code commands that both require XYZ axis words were detected in the block",
    25: "a G-code word was repeated in the block",
    26: "a G-code command requires XYZ axis words in the block, but none were detected",
    27: "N line number value is not within the valid range of 1 - 9,999,999",
    28: "a G-code command is missing some required P or L value words",
    29: "GRBL supports six work coordinate systems G54-G59; G59.1, G59.2 and G59.3 are not supported",
    30: "the G53 command requires either a G0 seek or G1 feed motion mode to be active",
    31: "there are unused axis words in the block and G80 motion mode cancel is active",
    32: "a G2 or G3 arc was commanded but there are no XYZ axis words in the selected plane",
    33: "the motion command has an invalid target",
    34: "a G2 or G3 arc traced with the radius definition had a mathematical error",
    35: "a G2 or G3 arc traced with the offset definition is missing the IJK offset word",
    36: "there are unused, leftover G-code words that aren't used by any command in the block",
    37: "the G43.1 dynamic tool length offset cannot apply to an axis other than its configured axis",
    38: "tool number greater than max supported value",
}

ALARMS: dict[int, str] = {
    1: "hard limit triggered; machine position is likely lost due to the sudden halt",
    2: "soft limit: a G-code motion target exceeds machine travel; machine position retained",
    3: "reset while in motion; machine position is likely lost",
    4: "probe fail: the probe is not in the expected initial state before starting the probe cycle",
    5: "probe fail: the probe did not contact the workpiece within the programmed travel",
    6: "homing fail: the active homing cycle was reset",
    7: "homing fail: the safety door was opened during the homing cycle",
    8: "homing fail: pull-off travel failed to clear the limit switch",
    9: "homing fail: could not find the limit switch within the search distance",
    10: "homing fail: on dual-axis machines, could not find the second limit switch",
}

_ALARM_TODO = {
    1: "check what hit the limit, then home with $H (or unlock with $X and re-zero)",
    2: "the job leaves the machine's travel ($130/$131): fix the job or the settings, then unlock with $X",
    3: "home with $H (or unlock with $X and re-zero) before running again",
}


def error_text(code: int) -> str:
    return ERRORS.get(code, "unknown error code (see your firmware's documentation)")


def alarm_text(code: int) -> str:
    return ALARMS.get(code, "unknown alarm code (see your firmware's documentation)")


def alarm_advice(code: int) -> str:
    return _ALARM_TODO.get(code, "fix the cause, then home with $H or unlock with $X")


class GrblError(LinkError):
    """GRBL refused a line, raised an alarm, or reset itself."""


# ---------------------------------------------------------------- the file

@dataclass(frozen=True)
class GcodeLine:
    text: str  # what is sent: spaces and comments removed, as GRBL would
    lineno: int  # 1-based line in the file; 0 for lines the sender adds
    source: str = ""


_COMMENT = re.compile(r"\([^)]*\)|;.*$")


def prepare(text: str, name: str = "G-code") -> list[GcodeLine]:
    """The lines to stream, checked; raise InputError naming the file line that GRBL cannot take."""
    out = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        s = "".join(_COMMENT.sub("", raw).split())
        if not s:
            continue
        if "(" in s or ")" in s:
            raise InputError(f"{name}:{lineno}: unbalanced comment parentheses; close the comment on the same line")
        bad = [c for c in s if c in REALTIME or not (32 < ord(c) < 127)]
        if bad:
            raise InputError(f"{name}:{lineno}: contains {bad[0]!r}, which GRBL treats as a real-time command or "
                             "cannot read; remove it")
        if len(s) > MAX_LINE:
            raise InputError(f"{name}:{lineno}: {len(s)} characters without spaces and comments; GRBL takes at most "
                             f"{MAX_LINE}, split the line")
        out.append(GcodeLine(s, lineno, raw))
    return out


_AXIS = re.compile(r"([XYZF])([-+]?(?:\d+\.?\d*|\.\d+))")
_SPINDLE = re.compile(r"M0*[345](?!\d)|S[-+.\d]")


def _is_pen(text: str) -> bool:
    return bool(_SPINDLE.search(text.upper())) and not re.search(r"G0*[0-3](?!\d)", text.upper())


def _is_g0(text: str) -> bool:
    return bool(re.match(r"G0*0(?!\d)", text.upper()))


def pen_up_line(lines: list[GcodeLine]) -> str:
    """The file's own pen-up command: the pen line right before a G0 travel (skipping dwells)."""
    last_pen = None
    for ln in lines:
        t = ln.text.upper()
        if _is_g0(t) and last_pen is not None:
            return last_pen
        if _is_pen(t):
            last_pen = ln.text
        elif not t.startswith("G4"):
            last_pen = None
    return "M5"


def resume_prefix(lines: list[GcodeLine], k: int) -> list[GcodeLine]:
    """Lines that put a freshly reset GRBL in the state the job had before line index ``k``.

    Units, distance and feed modes, the last position (reached pen up), the
    last pen command and its dwell, and the feed rate. Raise InputError when
    the job cannot be resumed there (relative coordinates).
    """
    units, absolute, feed, pen, dwell, pos = "G21", True, None, None, None, {}
    for ln in lines[:k]:
        t = ln.text.upper()
        for g in re.findall(r"G0*(\d+(?:\.\d+)?)", t):
            if g in ("20", "21"):
                units = "G" + g
            elif g == "90":
                absolute = True
            elif g == "91":
                absolute = False
        if _is_pen(t):
            pen, dwell = ln.text, None
        elif t.startswith("G4") and pen is not None:
            dwell = ln.text
        for letter, val in _AXIS.findall(t):
            if letter == "F":
                feed = val
            elif not t.startswith("G4") and not t.startswith("$"):
                pos[letter] = val
    if not absolute:
        raise InputError("the job uses relative coordinates (G91) at the resume point; it can only restart from the beginning")
    out = [f"{units}G90G94G17"]
    if pos:
        out.append("G0" + "".join(f"{a}{pos[a]}" for a in "XYZ" if a in pos))
    if pen:
        out.append(pen)
        if dwell:
            out.append(dwell)
    if feed:
        out.append(f"F{feed}")
    return [GcodeLine(t, 0, t) for t in out]


def line_durations(lines: list[GcodeLine]) -> list[float]:
    """Rough time (s) of each line: G1 length / F, G0 at the fastest feed seen, G4 dwells."""
    durs, pos, feed, mode, fastest = [], {"X": 0.0, "Y": 0.0, "Z": 0.0}, None, 0, 0.0
    for ln in lines:
        t = ln.text.upper()
        for m in re.finditer(r"F([-+]?[\d.]+)", t):
            fastest = max(fastest, float(m.group(1)))
    fastest = fastest or 3000.0
    for ln in lines:
        t = ln.text.upper()
        d = 0.0
        if t.startswith("G4"):
            m = re.search(r"P([\d.]+)", t)
            d = float(m.group(1)) if m else 0.0
        elif not t.startswith("$"):
            g = re.match(r"G0*([01])(?!\d)", t)
            if g:
                mode = int(g.group(1))
            new = dict(pos)
            for letter, val in _AXIS.findall(t):
                if letter == "F":
                    feed = float(val)
                else:
                    new[letter] = float(val)
            dist = sum((new[a] - pos[a]) ** 2 for a in "XYZ") ** 0.5
            rate = (feed or fastest) if mode == 1 else fastest
            d = 60.0 * dist / rate if rate > 0 else 0.0
            pos = new
        durs.append(d)
    return durs


# ---------------------------------------------------------------- status

@dataclass(frozen=True)
class GrblStatus:
    state: str  # Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep
    substate: int | None
    mpos: tuple[float, ...] | None
    wpos: tuple[float, ...] | None
    buffer: tuple[int, int] | None  # Bf: planner blocks free, RX bytes free
    feed: float | None
    raw: str
    at: float  # time.monotonic() when received


def parse_status(line: str, at: float = 0.0) -> GrblStatus | None:
    if not (line.startswith("<") and line.endswith(">")):
        return None
    fields = line[1:-1].split("|")
    state, _, sub = fields[0].partition(":")
    data = {}
    for f in fields[1:]:
        k, _, v = f.partition(":")
        data[k] = v

    def nums(key):
        try:
            return tuple(float(x) for x in data[key].split(",")) if key in data else None
        except ValueError:
            return None

    bf = nums("Bf")
    fs = nums("FS") or nums("F")
    return GrblStatus(state, int(sub) if sub.isdigit() else None, nums("MPos"), nums("WPos"),
                      (int(bf[0]), int(bf[1])) if bf and len(bf) == 2 else None, fs[0] if fs else None, line, at)


# ---------------------------------------------------------------- the link

@dataclass
class StreamResult:
    lines: int
    start: int  # index of the first line of the job this run sent
    errors: list  # check mode: (GcodeLine, code)
    elapsed: float
    max_outstanding: int


class GrblLink:
    """A GRBL controller on a serial port (or a pyserial URL such as ``loop://``)."""

    def __init__(self, port: str, baud: int = 115200, *, timeout: float = 5.0, connect_timeout: float = 3.0,
                 log: Callable[[str], None] | None = None):
        self.port, self.baud = port, baud
        self.timeout, self.connect_timeout = timeout, connect_timeout
        self.log = log or (lambda msg: None)
        self.q: queue.Queue = queue.Queue()
        self.status: GrblStatus | None = None
        self.messages: list[str] = []
        self.ser = None
        self._reader: threading.Thread | None = None
        self._closing = threading.Event()
        self._last_query = 0.0
        self._last_rx = time.monotonic()
        self.polling = True
        self.max_outstanding = 0
        self.alarm_banner = False
        self.interrupts = Interrupts()  # Ctrl-C surfaces in next_event, never halfway through a write

    # ------------------------------------------------------------ port

    def open(self) -> "GrblLink":
        import serial

        try:
            self.ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0.05, write_timeout=self.timeout)
        except (serial.SerialException, OSError, ValueError) as e:
            if "://" not in self.port and not os.path.exists(self.port):
                why = "no such device"
            else:
                why = str(getattr(e, "strerror", None) or e).split(":")[-1].strip() or type(e).__name__
            raise LinkError(f"serial port {self.port}: {why}; check the cable and the port name "
                            "(ls /dev/ttyUSB* /dev/ttyACM*), or try 'doodlecam sim grbl'") from None
        self._last_rx = time.monotonic()
        self._reader = threading.Thread(target=self._read_loop, name="grbl-reader", daemon=True)
        self._reader.start()
        return self

    def close(self) -> None:
        self._closing.set()
        if self._reader is not None:
            self._reader.join(1.0)
        if self.ser is not None:
            try:
                self.ser.close()
            except Exception:
                pass

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def _gone(self, why: str) -> LinkError:
        return LinkError(f"serial port {self.port} disappeared ({why}); reconnect it, then send the job again to resume")

    def _read_loop(self) -> None:
        buf = b""
        while not self._closing.is_set():
            try:
                chunk = self.ser.read(self.ser.in_waiting or 1)
            except Exception as e:  # pyserial raises SerialException, OSError or TypeError on a vanished port
                if not self._closing.is_set():
                    self.q.put(("gone", str(e) or type(e).__name__))
                return
            if not chunk:
                continue
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for raw in lines:
                line = raw.strip(b"\r").decode("ascii", "replace").strip()
                if line:
                    self._dispatch(line)

    def _dispatch(self, line: str) -> None:
        now = time.monotonic()
        if line == "ok":
            self.q.put(("ok",))
        elif line.startswith("error:"):
            self.q.put(("error", _code(line)))
        elif line.startswith("ALARM:"):
            self.q.put(("alarm", _code(line)))
        elif line.startswith("<"):
            st = parse_status(line, now)
            if st is not None:
                self.status = st
                self.q.put(("status", st))
        elif line.startswith("Grbl "):
            self.q.put(("banner", line))
        elif line.startswith("[MSG:"):
            self.q.put(("msg", line[5:-1] if line.endswith("]") else line[5:]))
        else:
            self.q.put(("info", line))

    def write(self, data: bytes) -> None:
        import serial

        try:
            self.ser.write(data)
        except (serial.SerialException, OSError) as e:
            raise self._gone(str(e) or type(e).__name__) from None

    def realtime(self, char: bytes) -> None:
        self.write(char)

    # ------------------------------------------------------------ events

    def _poll(self) -> None:
        now = time.monotonic()
        if self.polling and now - self._last_query >= STATUS_PERIOD:
            self._last_query = now
            self.realtime(b"?")

    def next_event(self, wait: float) -> tuple | None:
        """The next event from GRBL within ``wait`` s (status polled meanwhile), else None."""
        end = time.monotonic() + wait
        while True:
            self.interrupts.check()
            self._poll()
            now = time.monotonic()
            left = end - now
            if left <= 0:
                self._check_alive()
                return None
            step = min(left, max(self._last_query + STATUS_PERIOD - now, 0.001)) if self.polling else left
            try:
                ev = self.q.get(timeout=step)
            except queue.Empty:
                self._check_alive()
                continue
            self._last_rx = time.monotonic()
            if ev[0] == "gone":
                raise self._gone(ev[1])
            if ev[0] == "msg":
                self.messages.append(ev[1])
                if "to unlock" in ev[1]:
                    self.alarm_banner = True
            return ev

    def _check_alive(self) -> None:
        if self.polling and time.monotonic() - self._last_rx > self.timeout:
            raise LinkError(f"GRBL on {self.port} stopped answering for {self.timeout:g} s; check the cable and its power")

    def fresh_status(self, wait: float | None = None) -> GrblStatus:
        """A status report requested after this call."""
        t0 = time.monotonic()
        end = t0 + (wait if wait is not None else self.timeout)
        while time.monotonic() < end:
            ev = self.next_event(end - time.monotonic())
            if ev is None:
                break
            if ev[0] == "status" and ev[1].at > t0:
                return ev[1]
            self._unexpected(ev, during="waiting for a status report")
        raise LinkError(f"GRBL on {self.port} sends no status reports; check the port and baud rate")

    def _unexpected(self, ev: tuple, during: str) -> None:
        if ev[0] == "alarm":
            raise self._alarm_error(ev[1], during)
        if ev[0] == "banner":
            raise GrblError(f"GRBL on {self.port} reset itself while {during}; check its power and wiring, then send again")

    def _alarm_error(self, code: int, where: str) -> GrblError:
        if code in (1, 2, 10):  # critical: GRBL takes nothing until a soft reset
            try:
                self.realtime(b"\x18")
            except LinkError:
                pass
        return GrblError(f"GRBL ALARM:{code} {where}: {alarm_text(code)}; {alarm_advice(code)}")

    def wait_idle(self) -> GrblStatus:
        """Wait until GRBL reports Idle (motion done), failing on alarms or silence."""
        while True:
            st = self.fresh_status()
            if st.state in ("Idle", "Check"):
                return st
            if st.state == "Alarm":
                raise GrblError(f"GRBL on {self.port} is in alarm state; {alarm_advice(0)}")
            if st.state in ("Door", "Sleep"):
                raise GrblError(f"GRBL on {self.port} is in {st.state} state; close the door / reset it, then send again")

    def send_wait(self, text: str) -> tuple[str, int]:
        """Send one line and wait for its answer: ('ok', 0) or ('error', code)."""
        self.write((text + "\n").encode("ascii"))
        while True:
            ev = self.next_event(self.timeout)
            if ev is None:
                continue
            if ev[0] == "ok":
                return "ok", 0
            if ev[0] == "error":
                return "error", ev[1]
            self._unexpected(ev, during=f"waiting for the answer to '{text}'")

    def wait_banner(self, wait: float) -> bool:
        end = time.monotonic() + wait
        while time.monotonic() < end:
            ev = self.next_event(end - time.monotonic())
            if ev is not None and ev[0] == "banner":
                return True
        return False

    def soft_reset(self) -> None:
        self.alarm_banner = False
        self.realtime(b"\x18")
        if not self.wait_banner(self.connect_timeout):
            raise LinkError(f"GRBL on {self.port} did not restart after a soft reset; power-cycle it")

    # ------------------------------------------------------------ session

    def connect(self) -> GrblStatus:
        """Make sure GRBL answers, wait for a previous job to finish, start from a clean reset."""
        end = time.monotonic() + self.connect_timeout
        st = None
        while time.monotonic() < end and st is None:
            try:
                ev = self.next_event(end - time.monotonic())
            except LinkError as e:
                if "stopped answering" in str(e):
                    break
                raise
            if ev and ev[0] == "status":
                st = ev[1]
        if st is None:
            raise LinkError(f"no answer from GRBL on {self.port} within {self.connect_timeout:g} s; check the port, the "
                            "baud rate (--baud) and that the controller runs GRBL")
        if st.state in ("Run", "Jog", "Home"):
            self.log("GRBL is still moving (a previous job?); waiting for it to finish")
            st = self.wait_idle()
        if st.state == "Hold":
            raise GrblError(f"GRBL on {self.port} is in feed hold; resume (~) or reset it, then send again")
        if st.state == "Check":
            self.send_wait("$C")
            self.wait_banner(self.connect_timeout)
            st = self.fresh_status()
        if st.state == "Alarm":
            raise GrblError(f"GRBL on {self.port} is in alarm state; home it with $H or unlock it with $X "
                            "(e.g. in a serial terminal), then send again")
        if st.state != "Idle":
            raise GrblError(f"GRBL on {self.port} is in {st.state} state; make it idle, then send again")
        # A soft reset while idle keeps the position and clears any half-received line.
        self.soft_reset()
        st = self.fresh_status()
        if st.state == "Alarm" or self.alarm_banner:
            raise GrblError(f"GRBL on {self.port} starts in alarm state (homing enabled?); home it with $H or "
                            "unlock it with $X, then send again")
        return st


def _code(line: str) -> int:
    try:
        return int(line.split(":", 1)[1])
    except ValueError:
        return -1


# ---------------------------------------------------------------- streaming

class Streamer:
    """Streams prepared lines over a GrblLink with character counting.

    ``before_write(k)`` is called just before line k is written to the port
    (lines [0, k) surely reached it: the resume record); ``progress(acked,
    total, status)`` as answers come.
    """

    def __init__(self, link: GrblLink, lines: list[GcodeLine], *, name: str = "G-code",
                 before_write: Callable[[int], None] | None = None,
                 progress: Callable[[int, int, GrblStatus | None], None] | None = None):
        self.link, self.lines, self.name = link, lines, name
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

    def _loop(self, check: bool) -> None:
        link = self.link
        while self.inflight if self.stopping else self.acked < len(self.lines):
            self._send_lines()
            if not self.inflight:
                if self.sent >= len(self.lines) or self.stopping:
                    break
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
                raise link._alarm_error(ev[1], f"near {self.where(i)}")
            elif kind == "banner":
                near = self.where(min(self.acked, len(self.lines) - 1))
                raise GrblError(f"GRBL reset itself during the job (near {near}); check its power and wiring, "
                                "home it, then send again with --from-line")
            elif kind == "status":
                self.progress(self.acked, len(self.lines), ev[1])
        if not check and not self.stopping:
            self.link.wait_idle()  # every line answered: wait for the motion to finish

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
        if not (t.startswith("G4") or t.startswith("$")):
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

    def at(p) -> bool:
        return all(v is None or abs(v - h) <= 2e-3 for v, h in zip(p, here[:2]))

    if at(after):
        return k + 1
    if at(before):
        return k
    raise GrblError(f"the machine stands at X{here[0]:.3f} Y{here[1]:.3f}, not where the last run left off "
                    f"({name}:{lines[k].lineno}); check the drawing and send again with --from-line N")


def send_gcode(port: str, path: Path, *, baud: int = 115200, check: bool = False, restart: bool = False,
               from_line: int | None = None, timeout: float = 5.0, connect_timeout: float = 3.0,
               state_file: Path | None = None, progress=None, log=None) -> dict:
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
        s = Streamer(link, stream, name=str(path), before_write=lambda k: record(k, True), progress=prog)
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
            "elapsed_s": time.monotonic() - t0, "max_outstanding_bytes": result.max_outstanding}
