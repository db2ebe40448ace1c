"""A GRBL 1.1 protocol emulator on a pseudo-terminal (``doodlecam sim grbl``).

Enough of GRBL's serial behaviour to try ``doodlecam send --serial`` without
hardware and to test the streamer over real serial I/O:

* the banner ``Grbl 1.1h ['$' for help]`` at start and after a soft reset;
* a 128-byte receive ring (127 usable) that *drops* bytes that do not fit,
  as the firmware's serial ISR does; every drop is counted (``overruns``);
* lines parsed only as fast as the 16-block planner frees room (a motion line
  is answered ``ok`` when it is planned), so a sender that ignores flow
  control overflows the ring for real;
* ``ok`` / ``error:N`` (unsupported words, missing feed, overlong lines,
  ``$`` while not idle, G-code while in alarm ...), ``ALARM:N``;
* real-time commands ``?`` (status report), ``!`` (feed hold), ``~``
  (resume), 0x18 (soft reset; alarm 3 if moving), picked off before the ring;
* ``$C`` check mode, ``$X`` unlock, ``$H`` homing, ``$$`` / ``$x=val``;
* simulated motion time (G0 at the rapid rate, G1 at F times the feed
  override, G4 dwells), sped up by ``speed``, and the ``$1`` stepper idle
  delay each time motion stops (GRBL's ``st_go_idle``);
* a pen change (``M3``/``M5``/``S``) and ``G10`` synchronise: they wait until
  the planner is empty, as the firmware does outside laser mode;
* ``M0`` program pause: once the planner is empty GRBL holds (``Hold:0``) and
  answers the line only after a cycle start ``~`` (gcode.c: a feed hold);
* soft limits as GRBL 1.1 checks them (without ``HOMING_FORCE_SET_ORIGIN``):
  machine travel is ``-$130 <= x <= 0``, ``-$131 <= y <= 0``; a G-code target
  outside raises ``ALARM:2``, a jog target outside is refused with
  ``error:15``; soft limits need homing ($22=1), so the machine starts in
  alarm until ``$H`` (which leaves it at ``-$27`` on each axis) or ``$X``;
* work offsets: ``G10 L2/L20 P1`` (G54), ``G92``; ``WCO`` in status reports;
* jogging ``$J=...`` (state Jog, cancelled by 0x85), feed overrides 0x90..0x94
  (``Ov:`` in status reports);
* injectable errors and alarms at the N-th received line, and a port that
  vanishes after the N-th line.
"""

from __future__ import annotations

import os
import re
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

RX_BUFFER_SIZE = 128  # the ring holds RX_BUFFER_SIZE - 1 bytes
LINE_BUFFER_SIZE = 80  # at most 79 characters per line
PLANNER_BLOCKS = 15  # usable blocks of the 16-block planner ring
BANNER = "Grbl 1.1h ['$' for help]"
CRITICAL_DELAY_S = 0.5  # report_alarm_message's delay_ms(500): a reset sent sooner is discarded

_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass
class GrblConfig:
    speed: float = 1.0  # simulated seconds per wall second
    error_at: dict[int, int] = field(default_factory=dict)  # n-th received line -> error code
    alarm_at: dict[int, int] = field(default_factory=dict)  # n-th received line -> alarm code
    vanish_at: int | None = None  # close the port after receiving this many lines
    rapid: float = 9000.0  # mm/min, G0 ($110/$111)
    travel: tuple[float, float] = (400.0, 300.0)  # mm ($130/$131); soft limits when soft_limits
    soft_limits: bool = False  # $20
    report_mask: int = 1  # $10: 1 = MPos, +2 = Bf (buffer state)
    hold_time: float = 0.05  # simulated s of deceleration before Hold:0
    homing: bool | None = None  # $22; None = on when soft_limits (GRBL refuses $20=1 without it)
    idle_delay_ms: int = 25  # $1
    homing_time: float = 2.0  # simulated s a homing cycle takes


@dataclass
class _Block:
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    duration: float  # simulated s
    line: int
    dwell: bool = False
    rapid: bool = False  # G0: the feed override does not apply


class GrblEmulator:
    """Run with ``start()``; connect a serial client to ``port``; ``stop()`` when done."""

    def __init__(self, config: GrblConfig | None = None, log: Callable[[str], None] | None = None):
        self.cfg = config or GrblConfig()
        if not self.cfg.speed > 0:
            raise ValueError("speed must be positive")
        self.log = log or (lambda msg: None)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no CR/LF translation: bytes as a UART sees them
        os.set_blocking(self.master, False)
        self.port = os.ttyname(self.slave)
        homing = self.cfg.soft_limits if self.cfg.homing is None else self.cfg.homing
        self.settings = {0: 10, 1: self.cfg.idle_delay_ms, 10: self.cfg.report_mask, 11: 0.010,
                         20: int(self.cfg.soft_limits), 21: 0, 22: int(homing), 27: 1.0,
                         100: 80.0, 101: 80.0, 110: self.cfg.rapid, 111: self.cfg.rapid, 120: 2000.0, 121: 2000.0,
                         130: self.cfg.travel[0], 131: self.cfg.travel[1]}
        # observable by tests
        self.received: list[str] = []  # every complete line, as received
        self.executed: list[int] = []  # received-line numbers whose motion completed
        self.overruns = 0
        self.pauses = 0  # M0 program pauses held
        self.max_rx = 0
        self.status_queries: list[float] = []  # wall times of '?'
        self.resets = 0
        self.crlf_lines = 0
        # machine state
        self._rx = bytearray()
        self._out = bytearray()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.vanished = False
        self._init_machine(power_up=True)

    # ------------------------------------------------------------ lifecycle

    def start(self) -> "GrblEmulator":
        self._reply(f"\r\n{BANNER}")
        if self.state == "Alarm":
            self._reply("[MSG:'$H'|'$X' to unlock]")
        self._thread = threading.Thread(target=self._run, name="grblsim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def _init_machine(self, power_up: bool = False) -> None:
        if power_up:
            # homing enabled: GRBL starts locked in alarm until $H or $X (HOMING_INIT_LOCK)
            self.state = "Alarm" if self.settings.get(22) else "Idle"
            self.pos = [0.0, 0.0, 0.0]
            self.g54 = [0.0, 0.0, 0.0]  # stored work offset (EEPROM)
            self.overrides = 100  # feed override, %
        self.g92 = [0.0, 0.0, 0.0]  # G92 is forgotten on reset (GRBL 1.1 does not store it)
        self.idle_left = 0.0  # simulated s of the $1 delay still to wait
        self.jogging = False
        self.planner: deque[_Block] = deque()
        self.block_t = 0.0  # simulated s into the head block
        self.line = bytearray()
        self.line_flags = set()
        self.pending: tuple | None = None  # a parsed line waiting for planner room / sync
        self.critical = False  # alarm that needs a reset
        self.critical_since: float | None = None  # when a critical alarm was printed (resets count 500 ms after)
        self.critical_said = False  # "[MSG:Reset to continue]" printed
        self.status_owed = False  # a status request that arrived while homing
        self.hold = None  # None, or simulated s left until Hold:0
        self.m0_hold = False  # holding at an M0 line until a cycle start
        self.check = False
        self.modal = {"motion": 0, "abs": True, "feed": None, "spindle": 5, "s": 0.0, "inch": False}
        self._rx.clear()
        self._last = time.monotonic()

    # ------------------------------------------------------------ I/O

    def _reply(self, text: str) -> None:
        self._out += (text + "\r\n").encode()

    def _flush_out(self) -> None:
        while self._out:
            try:
                n = os.write(self.master, self._out)
            except BlockingIOError:
                return
            except OSError:
                self._out.clear()
                return
            del self._out[:n]

    def _run(self) -> None:
        while not self._stop.is_set() and not self.vanished:
            try:
                r, w, _ = select.select([self.master], [self.master] if self._out else [], [], 0.002)
            except (OSError, ValueError):
                return
            if r:
                try:
                    data = os.read(self.master, 4096)
                except BlockingIOError:
                    data = b""
                except OSError:  # no client has the port open right now
                    data = b""
                    time.sleep(0.01)
                for b in data:
                    self._on_byte(b)
            if self.critical_since is not None and not self.critical_said and \
                    time.monotonic() - self.critical_since >= CRITICAL_DELAY_S:
                self.critical_said = True
                self._reply("[MSG:Reset to continue]")
            self._advance()
            self._protocol()
            self._flush_out()
        if self.vanished:
            self._flush_out()
            os.close(self.master)  # the client sees the port disappear
            self.master = -1

    def _on_byte(self, b: int) -> None:
        # Real-time commands are picked off by the serial ISR before the ring; they only set flags that
        # the main loop serves. Two places of the firmware's main loop serve none of them but a reset:
        # the homing cycle (limits_go_home polls only reset, door and cycle stop) and the block after a
        # critical alarm (protocol.c: ALARM:N, delay_ms(500) in report_alarm_message, then
        # "[MSG:Reset to continue]", the reset flag cleared, and a loop that waits for a new one).
        if self.critical_since is not None:
            if b == 0x18 and time.monotonic() - self.critical_since >= CRITICAL_DELAY_S:
                self._soft_reset()
            return  # a reset within the 500 ms is cleared before the loop looks for one
        if self.state == "Home" and b == ord("?"):
            self.status_owed = True  # the flag stays set: the report comes when the cycle is over
            return
        if b == 0x18:
            self._soft_reset()
        elif b == ord("?"):
            self.status_queries.append(time.monotonic())
            self._reply(self._status())
        elif b == ord("!"):
            if self.state in ("Run",) and self.hold is None:
                self.hold = self.cfg.hold_time
                self.state = "Hold"
        elif b == ord("~"):
            if self.state == "Hold":
                self.hold = None
                self.state = "Run" if self.planner else "Idle"
        elif b == 0x85:  # jog cancel: drop the jog motion, keep the position
            if self.jogging:
                self.planner.clear()
                self.block_t = 0.0
                self.jogging = False
                self.state = "Idle"
        elif 0x90 <= b <= 0x94:  # feed override: 100 %, +10, -10, +1, -1 (GRBL keeps 10..200 %)
            step = {0x90: None, 0x91: 10, 0x92: -10, 0x93: 1, 0x94: -1}[b]
            self.overrides = 100 if step is None else min(200, max(10, self.overrides + step))
        elif b >= 0x80:
            pass  # other overrides: accepted, ignored
        elif len(self._rx) >= RX_BUFFER_SIZE - 1:
            self.overruns += 1  # the firmware drops the byte
            self.log(f"OVERRUN: dropped byte {b:#04x} (receive buffer full)")
        else:
            self._rx.append(b)
            self.max_rx = max(self.max_rx, len(self._rx))

    def _soft_reset(self) -> None:
        moving = self.state == "Run" or (self.state == "Hold" and self.hold is not None and self.hold > 0)
        self.resets += 1
        alarm = self.state == "Alarm" or moving
        self._init_machine()
        if moving:
            self._reply("ALARM:3")
        self.state = "Alarm" if alarm else "Idle"
        self._reply(f"\r\n{BANNER}")
        if alarm:
            self._reply("[MSG:'$H'|'$X' to unlock]")

    # ------------------------------------------------------------ motion

    def _advance(self) -> None:
        now = time.monotonic()
        dt = (now - self._last) * self.cfg.speed
        self._last = now
        if self.hold is not None:
            if self.hold > 0:
                self.hold = max(0.0, self.hold - dt)
            return
        while self.planner and dt > 0 and self.state in ("Run", "Idle", "Jog", "Home"):
            if self.state == "Idle":
                self.state = "Run"
            blk = self.planner[0]
            rate = 1.0 if blk.dwell or blk.rapid else self.overrides / 100.0
            left = (blk.duration - self.block_t) / rate
            if dt < left:
                self.block_t += dt * rate
                f = self.block_t / blk.duration if blk.duration > 0 else 1.0
                self.pos = [a + (b - a) * f for a, b in zip(blk.start, blk.end)]
                return
            dt -= left
            self.pos = list(blk.end)
            self.planner.popleft()
            self.block_t = 0.0
            self.executed.append(blk.line)
            if not self.planner and not blk.dwell and int(self.settings.get(1, 25)) < 255:
                self.idle_left = int(self.settings.get(1, 25)) / 1000.0  # st_go_idle: delay_ms($1)
        if self.idle_left > 0:
            self.idle_left = max(0.0, self.idle_left - dt)
            if self.idle_left > 0:
                return
        if not self.planner and self.state in ("Run", "Jog"):
            self.state = "Idle"
            self.jogging = False

    def _status(self) -> str:
        st = self.state
        if st == "Hold":
            st = f"Hold:{0 if not self.hold else 1}"
        if self.check:
            st = "Check"
        x, y, z = self.pos
        parts = [st, f"MPos:{x:.3f},{y:.3f},{z:.3f}"]
        if int(self.settings.get(10, 1)) & 2:
            parts.append(f"Bf:{PLANNER_BLOCKS - len(self.planner)},{RX_BUFFER_SIZE - 1 - len(self._rx)}")
        feed = self.modal["feed"] or 0.0
        parts.append(f"FS:{feed if self.state == 'Run' else 0:.0f},{self.modal['s']:.0f}")
        wco = self.wco
        if any(wco):  # GRBL sends WCO every 10-30 reports; every report is as valid
            parts.append("WCO:" + ",".join(f"{v:.3f}" for v in wco))
        parts.append(f"Ov:{self.overrides},100,100")
        return "<" + "|".join(parts) + ">"

    # ------------------------------------------------------------ protocol

    def _protocol(self) -> None:
        """GRBL's main loop: finish a pending line, then pull characters from the ring."""
        while True:
            if self.critical:
                self._rx.clear()  # nothing is accepted until a reset
                return
            if self.pending is not None and not self._try_pending():
                return
            if not self._rx:
                return
            c = self._rx.pop(0)
            if c in (0x0A, 0x0D):  # '\n' or '\r' ends a line (so CR LF ends two)
                raw = bytes(self.line)
                flags = self.line_flags
                self.line, self.line_flags = bytearray(), set()
                self._line(raw.decode("ascii", "replace"), flags)
                if self.vanished:
                    return
            elif "comment(" in self.line_flags:
                if c == ord(")"):
                    self.line_flags.discard("comment(")
            elif "comment;" in self.line_flags:
                pass
            elif c <= 0x20:
                pass  # whitespace and control characters are thrown away
            elif c == ord("("):
                self.line_flags.add("comment(")
            elif c == ord(";"):
                self.line_flags.add("comment;")
            elif len(self.line) >= LINE_BUFFER_SIZE - 1:
                self.line_flags.add("overflow")
            else:
                self.line.append(c - 32 if ord("a") <= c <= ord("z") else c)

    def _line(self, line: str, flags: set) -> None:
        self.received.append(line)
        n = len(self.received)
        if self.cfg.vanish_at is not None and n >= self.cfg.vanish_at:
            self.vanished = True
            return
        if not line and not flags:
            self.crlf_lines += 1
            self._reply("ok")  # an empty line is valid and answered
            return
        if n in self.cfg.error_at:
            self._reply(f"error:{self.cfg.error_at[n]}")
            return
        if n in self.cfg.alarm_at:
            self._alarm(self.cfg.alarm_at[n])
            return
        if "overflow" in flags:
            self._reply("error:11")
            return
        if not line:
            self._reply("ok")
            return
        if line.startswith("$"):
            self._dollar(line)
            return
        if self.state == "Alarm":
            self._reply("error:9")
            return
        try:
            action = self._parse(line, n)
        except _GcodeError as e:
            self._reply(f"error:{e.code}")
            return
        self.pending = action
        self._try_pending()

    def _alarm(self, code: int) -> None:
        self.planner.clear()
        self.block_t = 0.0
        self.hold = None
        self.pending = None
        self.state = "Alarm"
        self._reply(f"ALARM:{code}")
        if code in (1, 2):  # hard and soft limits: critical, only a reset (sent after the 500 ms) frees it
            self.critical = True
            self.critical_since = time.monotonic()

    def _dollar(self, line: str) -> None:
        busy = bool(self.planner) or self.state in ("Run", "Hold")
        if line == "$":
            self._reply("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
        elif line == "$$":
            for k, v in sorted(self.settings.items()):
                self._reply(f"${k}={v:g}" if isinstance(v, float) else f"${k}={v}")
        elif line == "$C":
            if busy:
                self._reply("error:8")
                return
            self.check = not self.check
            self._reply("[MSG:Enabled]" if self.check else "[MSG:Disabled]")
            if not self.check:
                self._reply("ok")
                self._soft_reset()  # leaving check mode resets the parser
                return
        elif line == "$X":
            if self.state == "Alarm":
                self.state = "Idle"
                self._reply("[MSG:Caution: Unlocked]")
        elif line == "$H":
            if not self.settings.get(22):
                self._reply("error:5")
                return
            if busy:
                self._reply("error:8")
                return
            # homes towards +X +Y +Z (the default $23) and pulls off by $27: machine travel is negative
            pull = float(self.settings.get(27, 1.0))
            self.planner.append(_Block(tuple(self.pos), (-pull, -pull, -pull), self.cfg.homing_time, len(self.received),
                                       rapid=True))
            self.state = "Home"
            self.pending = ("homing",)
            return
        elif line == "$#":
            for name, v in (("G54", self.g54), ("G92", self.g92)):
                self._reply(f"[{name}:" + ",".join(f"{x:.3f}" for x in v) + "]")
            self._reply("[TLO:0.000]")
        elif line.startswith("$J="):
            if self.state not in ("Idle", "Jog") or self.check:
                self._reply("error:8")
                return
            try:
                blk = self._jog(line[3:])
            except _GcodeError as e:
                self._reply(f"error:{e.code}")
                return
            if blk is not None:
                self.planner.append(blk)
                self.state, self.jogging = "Jog", True
        elif line == "$G":
            m = self.modal
            self._reply(f"[GC:G{m['motion']} G54 G17 {'G20' if m['inch'] else 'G21'} {'G90' if m['abs'] else 'G91'} "
                        f"G94 M{m['spindle']} M9 T0 F{m['feed'] or 0:g} S{m['s']:g}]")
        elif line == "$I":
            self._reply("[VER:1.1h.20190825:doodlecam emulator]")
            self._reply("[OPT:V,15,128]")
        elif re.fullmatch(r"\$\d+=[-+]?[\d.]+", line):
            if busy:
                self._reply("error:8")
                return
            key, val = line[1:].split("=")
            self.settings[int(key)] = float(val)
        else:
            self._reply("error:3")
            return
        self._reply("ok")

    @staticmethod
    def _arc_length(start, end, offset: dict, clockwise: bool) -> float:
        """Length (mm) of an XY arc given by its centre offset (I, J), checked as gcode.c does."""
        import math

        if not offset:
            raise _GcodeError(35)  # no radius or offset words
        cx, cy = start[0] + offset.get("I", 0.0), start[1] + offset.get("J", 0.0)
        r0, r1 = start[0] - cx, start[1] - cy
        t0, t1 = end[0] - cx, end[1] - cy
        radius, delta_r = math.hypot(r0, r1), abs(math.hypot(t0, t1) - math.hypot(r0, r1))
        if delta_r > 0.005 and (delta_r > 0.5 or delta_r > 0.001 * radius):
            raise _GcodeError(33)  # the target is not on the circle
        theta = math.atan2(r0 * t1 - r1 * t0, r0 * t0 + r1 * t1)
        if clockwise and theta >= -5e-7:
            theta -= 2 * math.pi
        elif not clockwise and theta <= 5e-7:
            theta += 2 * math.pi
        return math.hypot(abs(theta) * radius, end[2] - start[2])

    def _outside(self, end) -> bool:
        """GRBL 1.1's soft limit check (no HOMING_FORCE_SET_ORIGIN): machine travel is -$13x..0."""
        return bool(self.settings.get(20)) and not all(-float(self.settings[130 + i]) <= end[i] <= 0.0
                                                        for i in range(2))

    def _jog(self, text: str) -> "_Block | None":
        """A $J= jog line: G90/G91, G20/G21, G53, X Y Z and a required F."""
        words = _WORD.findall(text)
        if not words or "".join(a + b for a, b in words) != text:
            raise _GcodeError(16)
        absolute, inch, machine, target, feed = True, self.modal["inch"], False, {}, None
        for letter, val in words:
            v = float(val)
            if letter == "G" and v in (90, 91):
                absolute = v == 90
            elif letter == "G" and v in (20, 21):
                inch = v == 20
            elif letter == "G" and v == 53:
                machine = True
            elif letter in "XYZ":
                target[letter] = v
            elif letter == "F":
                feed = v
            else:
                raise _GcodeError(16)
        if feed is None or feed <= 0:
            raise _GcodeError(22)
        k = 25.4 if inch else 1.0
        start = self._end_pos()
        end = list(start)
        for i, a in enumerate("XYZ"):
            if a in target:
                v = target[a] * k
                end[i] = v if machine else (v + self.wco[i] if absolute else start[i] + v)
        if self._outside(end):
            raise _GcodeError(15)
        length = sum((a - b) ** 2 for a, b in zip(end, start)) ** 0.5
        return _Block(tuple(start), tuple(end), 60.0 * length / (feed * k), len(self.received)) if length else None

    def _parse(self, line: str, n: int):
        words = _WORD.findall(line)
        if "".join(a + b for a, b in words) != line:
            raise _GcodeError(1 if not line[:1].isalpha() else 2)
        m = dict(self.modal)
        target = {}
        motion = None
        dwell = None
        sync = False
        seen = set()
        nonmodal = None  # G10 or G92
        offset: dict[str, float] = {}  # I, J of an arc
        in_machine = False  # G53
        lval = None
        for letter, val in words:
            v = float(val)
            if letter == "G":
                if v in (0, 1, 2, 3):
                    if motion is not None:
                        raise _GcodeError(21)
                    motion = int(v)
                elif v == 4:
                    dwell = -1.0
                elif v in (10, 92, 53):
                    if v != 53 and nonmodal is not None:
                        raise _GcodeError(21)
                    if v == 53:
                        in_machine = True
                    else:
                        nonmodal = int(v)
                elif v == 90:
                    m["abs"] = True
                elif v == 91:
                    m["abs"] = False
                elif v == 21:
                    m["inch"] = False
                elif v == 20:
                    m["inch"] = True
                elif v in (17, 94, 54):
                    pass
                else:
                    raise _GcodeError(20)
            elif letter == "M":
                if v in (3, 4, 5):
                    m["spindle"] = int(v)
                    sync = True
                elif v in (2, 30):
                    sync = True
                    m["end"] = True
                elif v == 0:
                    sync = True
                    m["pause"] = True
                else:
                    raise _GcodeError(20)
            elif letter in "XYZIJ":
                if letter in seen:
                    raise _GcodeError(25)
                seen.add(letter)
                (offset if letter in "IJ" else target)[letter] = v * (25.4 if m["inch"] else 1.0)
            elif letter == "F":
                m["feed"] = v * (25.4 if m["inch"] else 1.0)
            elif letter == "S":
                m["s"] = v
                sync = True
            elif letter == "P":
                if nonmodal == 10:
                    if v not in (0, 1):
                        raise _GcodeError(29)  # only G54 is modelled
                    continue
                if dwell is None:
                    raise _GcodeError(36)
                dwell = v
            elif letter == "L":
                if nonmodal != 10:
                    raise _GcodeError(36)
                lval = v
            elif letter == "N":
                pass
            else:
                raise _GcodeError(20)
        if dwell == -1.0:
            raise _GcodeError(28)
        if motion is not None:
            m["motion"] = motion
        block = None
        if nonmodal is not None:  # an offset: the axis words set it, nothing moves
            if nonmodal == 10 and lval not in (2, 20):
                raise _GcodeError(28)
            if not target:
                raise _GcodeError(26)
            here = self._end_pos()
            for i, k in enumerate("XYZ"):
                if k in target:
                    if nonmodal == 92:
                        self.g92[i] = here[i] - self.g54[i] - target[k]
                    elif lval == 2:
                        self.g54[i] = target[k]
                    else:  # L20: the current position gets these work coordinates
                        self.g54[i] = here[i] - self.g92[i] - target[k]
            target = {}
            sync = sync or nonmodal == 10  # GRBL writes G54 to EEPROM only with the planner empty
        if target:
            if motion is None:
                motion = m["motion"]
            end = list(self._end_pos())
            wco = self.wco
            for i, k in enumerate("XYZ"):
                if k in target:
                    if in_machine:
                        end[i] = target[k]
                    else:
                        end[i] = target[k] + wco[i] if m["abs"] else end[i] + target[k]
            if motion in (1, 2, 3) and not m["feed"]:
                raise _GcodeError(22)
            if self._outside(end):  # (an arc's bulge is not checked against the travel here)
                return ("alarm", 2)
            rate = m["feed"] if motion else float(self.settings[110])
            start = self._end_pos()
            length = sum((a - b) ** 2 for a, b in zip(end, start)) ** 0.5
            if motion in (2, 3):
                length = self._arc_length(start, end, offset, motion == 2)
            block = _Block(tuple(start), tuple(end), 60.0 * length / rate, n, rapid=motion == 0)
        elif motion == 1 and not m["feed"]:
            raise _GcodeError(22)
        elif offset:
            raise _GcodeError(36)  # I/J without an arc
        end_prog = m.pop("end", False)
        pause = m.pop("pause", False)
        if end_prog:
            m.update(motion=1 if m["motion"] else 0, abs=True, spindle=5)
        self.modal = m
        if n in self.cfg.alarm_at:
            return ("alarm", self.cfg.alarm_at[n])
        if pause:
            return ("pause", n)
        return ("exec", block, sync or dwell is not None or end_prog, dwell, end_prog, n)

    @property
    def wco(self) -> list[float]:
        """Work coordinate offset: machine = work + WCO (G54 + G92)."""
        return [a + b for a, b in zip(self.g54, self.g92)]

    def _end_pos(self) -> tuple[float, float, float]:
        return self.planner[-1].end if self.planner else tuple(self.pos)

    def _try_pending(self) -> bool:
        """Execute the pending line if GRBL could now; True when done (ok sent)."""
        kind, *rest = self.pending
        if kind == "wait_empty":  # a dwell runs; G4 answers when it is over
            if self.planner:
                return False
            self.pending = None
            self._reply("ok")
            return True
        if kind == "alarm":
            self.pending = None
            self._alarm(rest[0])
            return True
        if kind == "pause":  # M0: wait for the planner, hold, answer after the cycle start
            if self.check:
                self.pending = None
                self._reply("ok")
                return True
            if not self.m0_hold:
                if self.planner or self.idle_left > 0 or self.hold is not None:
                    return False  # protocol_buffer_synchronize()
                self.state, self.hold, self.m0_hold = "Hold", 0.0, True
                self.pauses += 1
                return False
            if self.state == "Hold":
                return False
            self.m0_hold = False
            self.pending = None
            self._reply("ok")
            return True
        if kind == "homing":  # $H answers when the cycle is over
            if self.planner:
                return False
            self.pending = None
            self.state = "Idle"
            self._reply("ok")
            if self.status_owed:
                self.status_owed = False
                self._reply(self._status())
            return True
        block, sync, dwell, end_prog, n = rest
        if self.check:
            self.pending = None
            self._reply("ok")
            return True
        if sync and (self.planner or self.hold is not None or self.idle_left > 0):
            return False  # protocol_buffer_synchronize(): wait for motion to finish
        if block is not None and len(self.planner) >= PLANNER_BLOCKS:
            return False  # planner full: GRBL waits before answering, the ring fills up
        if dwell is not None and dwell > 0:
            self.planner.append(_Block(tuple(self.pos), tuple(self.pos), dwell, n, dwell=True))
            self.state = "Run"
            self.pending = ("wait_empty",)
            return False
        if block is not None:
            self.planner.append(block)
            if self.state == "Idle":
                self.state = "Run"
        if end_prog:
            self._reply("[MSG:Pgm End]")
        self.pending = None
        self._reply("ok")
        return True


class _GcodeError(Exception):
    def __init__(self, code: int):
        self.code = code
