"""A GRBL 1.1h emulator on a pseudo-terminal (``doodlecam sim grbl``), checked line by line against GRBL's own
firmware code (``tests/test_grbl_emulator_firmware.py`` runs both on the same lines).

What it shares with the firmware:

* the banner ``Grbl 1.1h ['$' for help]`` at start and after a soft reset;
* a 128-byte receive ring (127 usable) that *drops* bytes that do not fit, as the serial ISR does (every
  drop counted in ``overruns``), fed at the serial line's rate (115200 baud: 11 520 bytes per simulated s);
* lines parsed only as fast as the 15-block planner frees room, so a sender that ignores flow control
  overflows the ring for real;
* the G-code interpreter (``emulated_gcode``: gcode.c's words, modal groups and checks in its order, G0-G3
  incl. R arcs, G4, G10 L2/L20, G17-G19, G20/G21, G28/G30 (.1), G38.2-G38.5, G40, G43.1/G49, G53-G59,
  G61, G80, G90/G91 (.1), G92 (.1), G93/G94, M0-M2, M30, M3-M5, M8/M9, F S T N), so every line gets the
  firmware's ``ok`` or ``error:N``; the 34 ``$`` settings with GRBL's checks and number formats
  (``emulated_settings``), ``$$ $# $G $I $N $C $X $H $J= $RST=``;
* GRBL's motion timing (``emulated_motion``: step-rounded targets, junction deviation, 15-block look-ahead,
  trapezoids, feed and rapid overrides, feed hold deceleration) and the ``$1`` stepper idle delay each time
  motion stops (``st_go_idle``), run at ``speed`` times real time, or on a simulated clock (``simulate``);
* synchronisation as the firmware: spindle (pen) and coolant changes, dwells, work offset changes and EEPROM
  writes wait until the planner is empty; ``M0`` holds until a cycle start ``~``;
* status reports as report.c writes them (``$10``: MPos or WPos, ``Bf:``; ``WCO:`` and ``Ov:`` on their
  refresh counters, ``A:`` for the spindle, ``FS:`` the current speed);
* real-time commands ``?``, ``!`` (a hold decelerates; ``~`` resumes once it is complete), ``~``, 0x18
  (soft reset; ALARM:3 if moving), 0x85 (jog cancel), feed 0x90-0x94 and rapid 0x95-0x97 overrides;
* soft limits as GRBL 1.1 checks them (machine travel ``-$130 <= x <= 0``; ALARM:2, or error:15 for a
  jog); with homing ($22=1) the machine starts in alarm until ``$H`` or ``$X``; after ALARM:1/2 resets
  within 500 ms are discarded and nothing is answered until a later reset; nothing answered while homing;
* a probe that never touches (as the firmware simulator's): G38.2 runs to its target then ALARM:5;
* injectable errors and alarms at the N-th received line, and a port that vanishes after the N-th line.

Not modelled: laser mode ($32=1) motion, parking, safety door, sleep, spindle overrides, the 500 ms pause
after a non-critical alarm.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

from doodlecam.link.grbl import emulated_settings
from doodlecam.link.grbl.emulated_gcode import GcodeError, Interpreter, Move
from doodlecam.link.grbl.emulated_motion import Planner, BLOCKS

RX_BUFFER_SIZE = 128  # the ring holds RX_BUFFER_SIZE - 1 bytes
LINE_BUFFER_SIZE = 80  # at most 79 characters per line
PLANNER_BLOCKS = BLOCKS  # usable blocks of the 16-block planner ring
BANNER = "Grbl 1.1h ['$' for help]"
CRITICAL_DELAY_S = 0.5  # report_alarm_message's delay_ms(500): a reset sent sooner is discarded

BUSY = ("Run", "Hold", "Jog", "Home")  # report.c refreshes WCO and Ov less often in these states
INCH_PER_MM = 0.0393701


@dataclass
class GrblConfig:
    speed: float = 1.0  # simulated seconds per wall second
    error_at: dict[int, int] = field(default_factory=dict)  # n-th received line -> error code
    alarm_at: dict[int, int] = field(default_factory=dict)  # n-th received line -> alarm code
    vanish_at: int | None = None  # close the port after receiving this many lines
    rapid: float = 9000.0  # mm/min, G0 ($110..$112)
    travel: tuple[float, float] = (400.0, 300.0)  # mm ($130/$131); soft limits when soft_limits
    soft_limits: bool = False  # $20
    report_mask: int = 1  # $10: 1 = MPos (else WPos), +2 = Bf (buffer state)
    homing: bool | None = None  # $22; None = on when soft_limits (GRBL refuses $20=1 without it)
    idle_delay_ms: int = 25  # $1
    homing_time: float = 2.0  # simulated s a homing cycle takes
    baud: int = 115200  # the serial line: bytes reach the ring at baud / 10 per simulated second (0: at once)
    acceleration: float = 2000.0  # mm/s² ($120..$122)
    steps_per_mm: float = 80.0  # $100..$102


@dataclass
class Simulation:
    """What ``GrblEmulator.simulate`` saw: every line GRBL sent with its simulated time, and the job time."""

    replies: list[tuple[float, str]]
    job_s: float  # first byte to the last step or answer, as the firmware simulator's job_s

    @property
    def lines(self) -> list[str]:
        return [r for _, r in self.replies]


def _fmt(values, inches: bool, decimals_mm: int = 3) -> str:
    if inches:
        return ",".join(emulated_settings.grbl_float(v * INCH_PER_MM, decimals_mm + 1) for v in values)
    return ",".join(emulated_settings.grbl_float(v, decimals_mm) for v in values)


class GrblEmulator:
    """Run with ``start()``; connect a serial client to ``port``; ``stop()`` when done. Or ``simulate(bytes)``."""

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
        self.settings = dict(emulated_settings.DEFAULTS)  # GRBL's own defaults, then the test machine's EEPROM
        self.settings.update({1: int(self.cfg.idle_delay_ms), 10: int(self.cfg.report_mask), 20: int(self.cfg.soft_limits),
                              22: int(homing), 130: float(self.cfg.travel[0]), 131: float(self.cfg.travel[1])})
        for i in range(3):
            self.settings.update({100 + i: float(self.cfg.steps_per_mm), 110 + i: float(self.cfg.rapid),
                                  120 + i: float(self.cfg.acceleration)})
        self.startup_lines = ["", ""]  # $N0, $N1
        self.build_info = ""  # $I=
        self.gc = Interpreter()
        self.motion = Planner(self.settings)
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
        self._rx_in = self._rx_out = 0  # bytes into / out of the ring: its head and tail (for Bf:)
        self._wire = bytearray()  # bytes on their way down the serial line
        self._budget = 0.0
        self._out = bytearray()
        self._clock = 0.0  # simulated seconds
        self._moved_at = 0.0  # simulated time of the last motion
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.vanished = False
        self.machine_pos = [0.0, 0.0, 0.0]
        self._init_machine(power_up=True)

    # ------------------------------------------------------------ lifecycle

    def start(self) -> "GrblEmulator":
        self._greet()
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
        """main.c's loop on power-up and after every reset: the system, parser and planner re-initialised."""
        if power_up:
            # homing enabled: GRBL starts locked in alarm until $H or $X (HOMING_INIT_LOCK)
            self.state = "Alarm" if self.settings.get(22) else "Idle"
        pos = list(self.pos) if not power_up else [0.0, 0.0, 0.0]
        self.machine_pos = pos
        self.motion.feed_override = self.motion.rapid_override = 100
        self.motion.reset(pos)
        self.gc.arc_tolerance = float(self.settings[12])
        self.gc.reset(pos)
        self.spindle, self.spindle_s, self.coolant = 5, 0.0, 0
        self.idle_left = 0.0  # simulated s of the $1 delay still to wait (st_go_idle: nothing runs meanwhile)
        self.dwell_left: float | None = None
        self.homing_left = 0.0
        self.jog_cancel = False
        self.probe_pos, self.probe_stage = [0.0, 0.0, 0.0], None
        self.line = bytearray()
        self.line_flags = set()
        self.pending: deque | None = None  # the actions of the line being executed
        self.pending_line = 0
        self.critical = False  # alarm that needs a reset
        self.critical_since: float | None = None  # when a critical alarm was printed (resets count 500 ms after)
        self.critical_said = False  # "[MSG:Reset to continue]" printed
        self.status_owed = False  # a status request that arrived while homing
        self.hold: str | None = None  # None, "decel" (Hold:1) or "done" (Hold:0)
        self.m0_hold = False  # holding at an M0 line until a cycle start
        self.report_wco = self.report_ovr = 0  # report.c's refresh counters
        self._rx.clear()
        self._rx_out = self._rx_in
        self._last = time.monotonic()

    def _greet(self) -> None:
        """The banner, then the alarm lock message or the startup lines."""
        self._reply(f"\r\n{BANNER}")
        if self.state == "Alarm":
            self._reply("[MSG:'$H'|'$X' to unlock]")
            return
        for text in self.startup_lines:
            if text:
                code = self._run_now(text)
                self._reply(f">{text}:" + ("ok" if code == 0 else f"error:{code}"))

    # ------------------------------------------------------------ observable state

    @property
    def pos(self) -> list[float]:
        """Machine position (mm) now."""
        return self.motion.position or list(self.machine_pos)

    @property
    def modal(self) -> dict:
        """The parser's modes, as older tests and tools read them."""
        m = self.gc.modal
        return {"motion": m["motion"], "abs": m["distance"] == 0, "inch": bool(m["units"]), "spindle": m["spindle"],
                "feed": self.gc.feed_rate, "s": self.gc.spindle_speed}

    @property
    def wco(self) -> list[float]:
        return self.gc.wco

    @property
    def g54(self) -> list[float]:
        return self.gc.coords[0]

    @property
    def g92(self) -> list[float]:
        return self.gc.coord_offset

    @property
    def overrides(self) -> int:
        return self.motion.feed_override

    @property
    def planner(self) -> list:
        return self.motion.blocks

    @property
    def check(self) -> bool:
        return self.state == "Check"

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
                    self._wire += os.read(self.master, 4096)
                except BlockingIOError:
                    pass
                except OSError:  # no client has the port open right now
                    time.sleep(0.01)
            now = time.monotonic()
            dt = (now - self._last) * self.cfg.speed
            self._last = now
            self._deliver(dt)
            if self.critical_since is not None and not self.critical_said and \
                    time.monotonic() - self.critical_since >= CRITICAL_DELAY_S:
                self.critical_said = True
                self._reply("[MSG:Reset to continue]")
            self._protocol()
            self._advance(dt)
            self._protocol()
            self._flush_out()
        if self.vanished:
            self._flush_out()
            os.close(self.master)  # the client sees the port disappear
            self.master = -1

    def _deliver(self, dt: float, only_with_room: bool = False) -> None:
        """Bytes down the serial line at its rate; with ``only_with_room`` none while the ring is full."""
        if not self._wire:
            self._budget = 0.0
            return
        self._budget = self._budget + dt * self.cfg.baud / 10.0 if self.cfg.baud else float(len(self._wire))
        n = min(int(self._budget), len(self._wire))
        if only_with_room:
            n = min(n, RX_BUFFER_SIZE - 1 - len(self._rx))
        if n <= 0:
            if only_with_room:
                self._budget = min(self._budget, 1.0)
            return
        self._budget -= n
        data = bytes(self._wire[:n])
        del self._wire[:n]
        for b in data:  # GRBL reads each byte as it comes: a '?' after a line is served after that line
            self._on_byte(b)
            if b in (0x0A, 0x0D):
                self._protocol()

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
            self._feed_hold()
        elif b == ord("~"):
            self._cycle_start()
        elif b == 0x85:  # jog cancel: decelerate, then drop the jog motion
            if self.state == "Jog" and not self.jog_cancel:
                self.jog_cancel = True
                self.hold = "decel"
                self.motion.hold()
        elif 0x90 <= b <= 0x97:
            self._override(b)
        elif b >= 0x80:
            pass  # spindle and coolant overrides: accepted, ignored
        elif len(self._rx) >= RX_BUFFER_SIZE - 1:
            self.overruns += 1  # the firmware drops the byte
            self.log(f"OVERRUN: dropped byte {b:#04x} (receive buffer full)")
        else:
            self._rx.append(b)
            self._rx_in += 1
            self.max_rx = max(self.max_rx, len(self._rx))

    def _feed_hold(self) -> None:
        if self.state in ("Alarm", "Check", "Home") or self.jog_cancel:
            return
        if self.state == "Jog":  # a hold cancels a jog
            self.jog_cancel, self.hold = True, "decel"
            self.motion.hold()
        elif self.state == "Run":
            if self.hold is None:
                self.hold = "decel"
                self.motion.hold()
            self.state = "Hold"
        elif self.state == "Idle":
            self.state, self.hold = "Hold", "done"

    def _cycle_start(self) -> None:
        if self.state == "Idle" and self.motion.blocks:
            self.state = "Run"
        elif self.state == "Hold" and self.hold == "done":  # ignored while still decelerating
            self.hold = None
            self.motion.resume()
            self.state = "Run" if self.motion.blocks else "Idle"

    def _override(self, b: int) -> None:
        feed, rapid = self.motion.feed_override, self.motion.rapid_override
        if b <= 0x94:  # 100 %, +10, -10, +1, -1 (GRBL keeps 10..200 %)
            step = {0x90: None, 0x91: 10, 0x92: -10, 0x93: 1, 0x94: -1}[b]
            feed = 100 if step is None else min(200, max(10, feed + step))
        else:
            rapid = {0x95: 100, 0x96: 50, 0x97: 25}[b]
        if (feed, rapid) != (self.motion.feed_override, self.motion.rapid_override):
            self.motion.feed_override, self.motion.rapid_override = feed, rapid
            self.report_ovr = 0
            self.motion.replan()

    def _soft_reset(self) -> None:
        moving = self.state in ("Run", "Jog", "Home") or self.hold == "decel"
        homing = self.state == "Home"
        self.resets += 1
        alarm = self.state == "Alarm" or moving
        if moving:  # position is likely lost: GRBL stops the steppers where they are
            self.machine_pos = list(self.pos)
            self.motion.blocks.clear()
        self._init_machine()
        if moving:
            self._reply("ALARM:6" if homing else "ALARM:3")
        self.state = "Alarm" if alarm else "Idle"
        self._greet()

    # ------------------------------------------------------------ time

    def _advance(self, dt: float) -> None:
        """Let ``dt`` simulated seconds pass: motion, the $1 delay, dwells, homing; the parser goes on at
        each event that may unblock it (a block done, motion stopped, a dwell over)."""
        for _ in range(100000):
            if dt <= 0:
                return
            if self.idle_left > 0:  # st_go_idle's delay_ms: everything waits
                used = min(dt, self.idle_left)
                self.idle_left -= used
                dt -= used
                self._clock += used
                if self.idle_left <= 0:
                    self.idle_left = 0.0
                    self._after_stop()
                    self._protocol()
                continue
            if self.state == "Home":
                used = min(dt, self.homing_left)
                self.homing_left -= used
                dt -= used
                self._clock += used
                if self.homing_left <= 0:
                    self._homed()
                    self._protocol()
                continue
            runs = self.state in ("Run", "Jog") or (self.state == "Hold" and self.hold == "decel")
            if runs and self.motion.blocks:
                left, done = self.motion.advance(dt)
                self._clock += dt - left
                if left < dt:
                    self._moved_at = self._clock
                dt = left
                if done is not None:
                    self.machine_pos = list(done.end)
                    self.executed.append(done.line)
                if not self.motion.blocks or (self.hold == "decel" and self.motion.speed <= 0.0):
                    self._stopped_moving()
                self._protocol()
                continue
            if runs and self.hold == "decel":  # a hold with nothing left to run
                self._stopped_moving()
                continue
            if self.dwell_left is not None and self.dwell_left > 0:
                used = min(dt, self.dwell_left)
                self.dwell_left -= used
                dt -= used
                self._clock += used
                if self.dwell_left <= 0:
                    self.dwell_left = 0.0
                    self._protocol()
                continue
            self._clock += dt
            return

    def _stopped_moving(self) -> None:
        """The segment buffer ran dry: st_go_idle waits $1 ms (255: motors stay on, no wait), then cycle stop."""
        delay = int(self.settings[1])
        self.idle_left = delay / 1000.0 if delay != 255 else 0.0
        if self.idle_left <= 0:
            self._after_stop()

    def _after_stop(self) -> None:
        """EXEC_CYCLE_STOP: a hold is complete (and a cancelled jog flushed), or the cycle is over."""
        if self.hold == "decel":
            self.machine_pos = list(self.pos)
            if self.jog_cancel:
                self.motion.reset(self.machine_pos)
                self.gc.position = list(self.machine_pos)
                self.jog_cancel, self.hold, self.state = False, None, "Idle"
            else:
                self.hold = "done"
                self.motion.holding = False
                self.motion.speed = 0.0
                self.motion.replan()
                self.motion.holding = True
        elif self.state in ("Run", "Jog") and not self.motion.blocks:
            self.state = "Idle"

    def _homed(self) -> None:
        # homes towards +X +Y +Z (the default $23) and pulls off by $27: machine travel is negative
        pull = float(self.settings[27])
        self.machine_pos = [-pull, -pull, -pull]
        self.motion.reset(self.machine_pos)
        self.gc.position = list(self.machine_pos)
        self.state = "Idle"

    def simulate(self, data: bytes | str, step: float = 0.001, limit_s: float = 7200.0) -> Simulation:
        """Run ``data`` on a simulated clock, without the port or a thread, as the firmware simulator does:
        bytes arrive at the serial rate whenever the ring has room (a sender that counts characters).
        Ends when everything is sent, answered and still; call on a fresh, unstarted emulator."""
        if isinstance(data, str):
            data = data.encode()
        self._wire += data
        replies: list[tuple[float, str]] = []
        first, answered = None, 0.0
        while self._clock < limit_s:
            if first is None and self._wire:
                first = self._clock
            self._deliver(step, only_with_room=True)
            self._protocol()
            self._advance(step)
            self._protocol()
            if self._out:
                for text in self._out.decode(errors="replace").split("\r\n")[:-1]:
                    replies.append((self._clock, text))
                    if text.startswith(("ok", "error")):
                        answered = self._clock
                self._out.clear()
            if not self._wire and not self._rx and self.pending is None and not self.motion.blocks and \
                    self.idle_left <= 0 and self.state in ("Idle", "Alarm", "Check"):
                break
        start = first or 0.0
        return Simulation(replies, max(answered, self._moved_at) - start)

    def _status(self) -> str:
        """report_realtime_status."""
        st = self.state
        if st == "Hold":
            st = f"Hold:{0 if self.hold == 'done' else 1}"
        mask = int(self.settings[10])
        inches = bool(self.settings[13])
        pos = self.pos
        wco = self.gc.wco
        if not mask & 1:
            pos = [p - w for p, w in zip(pos, wco)]
        parts = [st, ("MPos:" if mask & 1 else "WPos:") + _fmt(pos, inches)]
        if mask & 2:
            head, tail = self._rx_in % RX_BUFFER_SIZE, self._rx_out % RX_BUFFER_SIZE
            rx_free = RX_BUFFER_SIZE - (head - tail) if head >= tail else tail - head - 1
            parts.append(f"Bf:{self.motion.free()},{rx_free}")
        rate = self.motion.speed * 60.0 if self.state in BUSY else 0.0
        rate_s = emulated_settings.grbl_float(rate * INCH_PER_MM, 1) if inches else emulated_settings.grbl_float(rate, 0)
        parts.append(f"FS:{rate_s},{emulated_settings.grbl_float(self.spindle_s, 0)}")
        busy = self.state in BUSY
        if self.report_wco > 0:
            self.report_wco -= 1
        else:
            self.report_wco = 29 if busy else 9
            if self.report_ovr == 0:
                self.report_ovr = 1
            parts.append("WCO:" + _fmt(wco, inches))
        if self.report_ovr > 0:
            self.report_ovr -= 1
        else:
            self.report_ovr = 19 if busy else 9
            parts.append(f"Ov:{self.motion.feed_override},{self.motion.rapid_override},100")
            acc = ("S" if self.spindle == 3 else "C" if self.spindle == 4 else "") if self.spindle_s > 0 else ""
            acc += "F" if self.coolant else ""
            if acc:
                parts.append("A:" + acc)
        return "<" + "|".join(parts) + ">"

    # ------------------------------------------------------------ protocol

    def _protocol(self) -> None:
        """GRBL's main loop: finish a pending line, then pull characters from the ring."""
        while True:
            if self.critical:
                self._rx.clear()  # nothing is accepted until a reset
                self._rx_out = self._rx_in
                return
            if self.idle_left > 0 or self.state == "Home":
                return  # the main loop is stuck in st_go_idle's delay or in the homing cycle
            if self.pending is not None and not self._try_pending():
                return
            if not self._rx:
                return
            c = self._rx.pop(0)
            self._rx_out += 1
            if c in (0x0A, 0x0D):  # '\n' or '\r' ends a line (so CR LF ends two)
                raw = bytes(self.line)
                flags = self.line_flags
                self.line, self.line_flags = bytearray(), set()
                self._line(raw.decode("ascii", "replace"), flags)
                if self.vanished:
                    return
            elif self.line_flags:  # in a comment or past the line's end: only ')' matters
                if c == ord(")"):
                    self.line_flags.discard("comment(")
            elif c <= 0x20 or c == ord("/"):
                pass  # whitespace, control characters and block delete are thrown away
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
            self._dollar(line, n)
            return
        if self.state in ("Alarm", "Jog"):
            self._reply("error:9")
            return
        self._execute(line, n)

    def _execute(self, line: str, n: int) -> None:
        try:
            actions = self.gc.execute(line, check=self.check)
        except GcodeError as e:
            self._reply(f"error:{e.code}")
            return
        self.pending, self.pending_line = deque(actions), n
        self._try_pending()

    def _run_now(self, line: str) -> int:
        """A startup line: executed at once (the machine is idle after a reset); its status code."""
        try:
            actions = self.gc.execute(line, check=self.check)
        except GcodeError as e:
            return e.code
        self.pending, self.pending_line = deque(actions), 0
        self._try_pending(answer=False)
        return 0

    def _alarm(self, code: int) -> None:
        self.planner.clear()
        self.machine_pos = list(self.pos) if self.motion.blocks else self.machine_pos
        self.motion.reset(self.machine_pos)
        self.hold = None
        self.pending = None
        self.state = "Alarm"
        self._reply(f"ALARM:{code}")
        if code in (1, 2):  # hard and soft limits: critical, only a reset (sent after the 500 ms) frees it
            self.critical = True
            self.critical_since = time.monotonic()

    def _stopped(self) -> bool:
        """protocol_buffer_synchronize is over: nothing planned, nothing running."""
        return not self.motion.blocks and self.idle_left <= 0 and self.state not in ("Run", "Jog", "Hold", "Home")

    def _try_pending(self, answer: bool = True) -> bool:
        """Run the pending line's actions as far as GRBL could now; True when done (answered)."""
        check = self.check
        while self.pending:
            act = self.pending[0]
            kind = act[0]
            if kind in ("sync", "wco", "eeprom"):
                if not check and not self._stopped():
                    return False
                if kind == "wco" and not check:
                    self.report_wco = 0
            elif kind == "spindle":
                if not check:
                    self.spindle, self.spindle_s = act[1], (act[2] if act[1] != 5 else 0.0)
                    self.report_ovr = 0
            elif kind == "coolant":
                if not check:
                    self.coolant = act[1]
                    self.report_ovr = 0
            elif kind == "dwell":
                if not check:
                    if not self._stopped():
                        return False
                    if self.dwell_left is None:
                        self.dwell_left = float(act[1])
                    if self.dwell_left > 0:
                        return False
                    self.dwell_left = None
            elif kind == "line":
                mv: Move = act[1]
                if self._outside(mv.target):
                    self.pending = None
                    self._alarm(2)  # soft limit: critical
                    return True
                if not check:
                    if self.motion.free() <= 0:
                        return False  # planner full: GRBL waits before answering, the ring fills up
                    if self.motion.add(mv.target, mv.feed, mv.rapid, mv.inverse_time, mv.no_override,
                                       self.pending_line):
                        if self.state == "Idle":
                            self.state = "Run"
            elif kind == "jog":
                mv = act[1]
                if self._outside(mv.target):
                    self.pending = None
                    self._reply("error:15")
                    return True
                if self.motion.free() <= 0:
                    return False
                self.motion.add(mv.target, mv.feed, no_override=True, line=self.pending_line)
                self.gc.position = list(mv.target)
                if self.state == "Idle" and self.motion.blocks:
                    self.state = "Jog"
            elif kind == "homing":
                if self.state == "Home":
                    return False
                self.pending.popleft()
                self.pending = None
                self._reply("ok")
                if self.status_owed:  # the request that came while homing
                    self.status_owed = False
                    self._reply(self._status())
                return True
            elif kind == "probe":
                if not check and not self._probe(act):
                    return False
                if self.pending is None:
                    return True
            elif kind == "pause":  # M0: wait for the planner, hold, answer after the cycle start
                if not check:
                    if not self.m0_hold:
                        if not self._stopped():
                            return False
                        self.state, self.hold, self.m0_hold = "Hold", "done", True
                        self.pauses += 1
                        return False
                    if self.state == "Hold":
                        return False
                    self.m0_hold = False
            elif kind == "end":  # M2/M30
                if not check:
                    if not self._stopped():
                        return False
                    self.spindle, self.spindle_s, self.coolant = 5, 0.0, 0
                    self.report_ovr = self.report_wco = 0
                self.motion.feed_override = self.motion.rapid_override = 100  # RESTORE_OVERRIDES_AFTER_PROGRAM_END
                self._reply("[MSG:Pgm End]")
            self.pending.popleft()
        self.pending = None
        if answer:
            self._reply("ok")
        return True

    def _probe(self, act) -> bool:
        """mc_probe_cycle with a probe that never touches; True when over."""
        _, mv, away, quiet = act
        if self.probe_stage is None:
            if away:  # the probe must start touched to probe away: it is not
                self._alarm_quiet(4)
                return True
            self.motion.add(mv.target, mv.feed, no_override=True, line=self.pending_line)
            self.state, self.probe_stage = "Run", "moving"
            return False
        if not self._stopped():
            return False
        self.probe_stage = None
        if quiet:
            self.probe_pos = list(self.pos)
        else:
            self._alarm_quiet(5)
        self._reply(f"[PRB:{_fmt(self.probe_pos, bool(self.settings[13]))}:0]")
        return True

    def _alarm_quiet(self, code: int) -> None:
        """A probe alarm: the state and message, the line still answered."""
        self.state = "Alarm"
        self._reply(f"ALARM:{code}")

    def _outside(self, end) -> bool:
        """GRBL 1.1's soft limit check (no HOMING_FORCE_SET_ORIGIN): machine travel is -$13x..0."""
        return bool(self.settings[20]) and not all(-float(self.settings[130 + i]) <= end[i] <= 0.0 for i in range(3))

    # ------------------------------------------------------------ $ commands

    def _dollar(self, line: str, n: int) -> None:  # noqa: C901 (system_execute_line)
        c = line[1:2]
        if line == "$":
            self._reply("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
        elif c == "J":
            if self.state not in ("Idle", "Jog"):
                return self._reply("error:8")
            if line[2:3] != "=":
                return self._reply("error:3")
            return self._execute(line, n)
        elif c in ("$", "G", "C", "X"):
            if len(line) > 2:
                return self._reply("error:3")
            if c == "$":
                if self.state in ("Run", "Hold"):
                    return self._reply("error:8")
                for text in emulated_settings.report_lines(self.settings):
                    self._reply(text)
            elif c == "G":
                f = self.gc.feed_rate * (INCH_PER_MM if self.settings[13] else 1.0)
                rate = emulated_settings.grbl_float(f, 1 if self.settings[13] else 0)
                self._reply(f"[GC:{self.gc.modes()} F{rate} S{emulated_settings.grbl_float(self.gc.spindle_speed, 0)}]")
            elif c == "C":
                if self.state == "Check":
                    self._reply("[MSG:Disabled]")
                    self._reply("ok")
                    self._soft_reset()  # leaving check mode resets the parser
                    return
                if self.state != "Idle":
                    return self._reply("error:8")
                self.state = "Check"
                self._reply("[MSG:Enabled]")
            elif self.state == "Alarm":
                self.state = "Idle"
                self._reply("[MSG:Caution: Unlocked]")
        else:
            if self.state not in ("Idle", "Alarm"):
                return self._reply("error:8")
            code = self._dollar_idle(line)
            if code is None:
                return  # answered (or answers later)
            if code:
                return self._reply(f"error:{code}")
        self._reply("ok")

    def _dollar_idle(self, line: str) -> int | None:
        """The $ commands GRBL runs only idle or in alarm; a status code, None when it answers itself."""
        c = line[1]
        if c == "#":
            if len(line) > 2:
                return 3
            inches = bool(self.settings[13])
            for k, name in enumerate(("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30")):
                self._reply(f"[{name}:{_fmt(self.gc.coords[k], inches)}]")
            self._reply(f"[G92:{_fmt(self.gc.coord_offset, inches)}]")
            self._reply(f"[TLO:{_fmt([self.gc.tool_length_offset], inches)}]")
            self._reply(f"[PRB:{_fmt(self.probe_pos, inches)}:0]")
            return 0
        if c == "H":
            if not self.settings[22]:
                return 5
            if len(line) > 2:
                return 3
            self.state, self.homing_left = "Home", float(self.cfg.homing_time)
            self.pending, self.pending_line = deque([("homing",)]), 0  # answered when the cycle is over
            return None
        if c == "I":
            if len(line) == 2:
                self._reply(f"[VER:1.1h.20190830:{self.build_info}]")
                self._reply(f"[OPT:V,{BLOCKS},{RX_BUFFER_SIZE}]")
                return 0
            if line[2] != "=":
                return 3
            self.build_info = line[3:]
            return 0
        if line.startswith("$RST="):
            what = line[5:]
            if what not in ("$", "#", "*"):
                return 3
            if what in ("$", "*"):
                self.settings.clear()
                self.settings.update(emulated_settings.DEFAULTS)
            if what in ("#", "*"):
                self.gc.coords[:] = [[0.0, 0.0, 0.0] for _ in range(8)]
            if what == "*":
                self.startup_lines, self.build_info = ["", ""], ""
            self._reply("[MSG:Restoring defaults]")
            self._reply("ok")
            self._soft_reset()
            return None
        if c == "N":
            if len(line) == 2:
                for k, text in enumerate(self.startup_lines):
                    self._reply(f"$N{k}={text}")
                return 0
            if self.state != "Idle":
                return 8
        try:
            key, i = _read_number(line, 2 if c == "N" else 1)
        except GcodeError as e:
            return e.code
        if line[i:i + 1] != "=":
            return 3
        if c == "N":  # a startup line: checked by the parser (on a copy: nothing runs now)
            import copy

            try:
                copy.deepcopy(self.gc).execute(line[i + 1:])
            except GcodeError as e:
                return e.code
            k = int(key)
            if k >= len(self.startup_lines):
                return 3
            self.startup_lines[k] = line[i + 1:]
            return 0
        try:
            value, j = _read_number(line, i + 1)
        except GcodeError as e:
            return e.code
        if j != len(line) or key > 255:
            return 3
        code = emulated_settings.store(self.settings, key, value)
        if code == 0:
            self.gc.arc_tolerance = float(self.settings[12])
            if int(key) == 13:
                self.report_wco = 0
        return code


def _read_number(line: str, i: int) -> tuple[float, int]:
    from doodlecam.link.grbl.emulated_gcode import read_float

    return read_float(line, i)
