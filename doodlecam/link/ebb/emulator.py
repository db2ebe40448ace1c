"""An EiBotBoard on a pseudo-terminal, written from the EBB command reference (firmware 3.0, legacy syntax).

It parses every command doodlecam sends (V, QM, QS, QP, QG, CS, SC, SP, EM, ES, LM, SM, XM, HM, R),
answers as the reference says (``OK\\r\\n``; ``!N Err: ...`` for malformed commands and
parameters out of range), queues motion commands in a FIFO of ``fifo`` commands behind the
one executing (a command that finds the FIFO full is answered only once it fits, and the
board reads nothing else meanwhile), and executes LM with the board's integer accumulators on
its 25 kHz clock (doodlecam.link.ebb.board; a rate through zero turns the motor back from version
2.9 on, as firmware 3.0 does, and rolls over before), SM/XM/HM as straight moves. ``executed`` records the
step counters after every motion command, for the tests. Time runs ``speed`` times real time.
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

from doodlecam.link.ebb.board import TICK_HZ, axis_move

I32 = (-(1 << 31), (1 << 31) - 1)
_NUM = re.compile(r"-?\d+")


class _Err(Exception):
    def __init__(self, code: int, text: str):
        super().__init__(f"!{code} Err: {text}")


@dataclass
class EbbConfig:
    version: str = "3.0.2"
    speed: float = 1.0  # simulated seconds per real second
    fifo: int = 1  # motion commands queued behind the executing one (the board boots with 1)
    vanish_at: int | None = None  # close the port after receiving this many commands
    answer: str = "ebb"  # "ebb", or "grbl" (answers as a GRBL would) / "silent" (answers nothing)
    # how a legacy-mode error ends: "ok-line" (an OK line after it), "inline" (the reference's
    # 'OK\r\n' line ending), "bare" (firmware 3.0's source: '\r\n')
    error_end: str = "ok-line"


@dataclass
class _Motion:
    index: int  # received-command number (1-based)
    line: str
    seconds: float
    steps: tuple[int, int] = (0, 0)
    pen: int | None = None  # SP: 1 up, 0 down
    clear: int = 0
    lm: tuple | None = None
    absolute: tuple[int, int] | None = None  # HM target
    enable: tuple[int, int] | None = None
    extra: dict = field(default_factory=dict)


class EbbEmulator:
    def __init__(self, config: EbbConfig | None = None, log: Callable[[str], None] | None = None):
        self.cfg = config or EbbConfig()
        self.log = log or (lambda m: None)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.port = os.ttyname(self.slave)
        # observable by tests
        self.received: list[str] = []
        self.errors: list[tuple[str, str]] = []  # (command, error) answered
        self.executed: list[dict] = []  # {"index", "line", "pos", "t"} after each motion command
        self.pen_log: list[tuple[float, int]] = []  # (simulated time, 1 up / 0 down)
        self.vanished = False
        # board state
        self.pos = [0, 0]
        self.accum = [0, 0]
        self.pen_up = 1
        self.enabled = (0, 0)
        self.servo = {4: 12000, 5: 16000}
        self.fifo: deque[_Motion] = deque()
        self.current: _Motion | None = None
        self.left = 0.0  # simulated s of the current command still to run
        self.sim_t = 0.0
        self._rx = b""
        self._out = b""
        self._waiting: tuple[str, _Motion] | None = None  # a motion command that did not fit the FIFO yet
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._last = time.monotonic()

    # ------------------------------------------------------------ lifecycle

    def start(self) -> "EbbEmulator":
        if self._thread is not None:  # already running (``with EbbEmulator(...).start()``)
            return self
        self._thread = threading.Thread(target=self._run, name="ebbsim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        for fd in (self.master, self.slave):
            try:
                if fd >= 0:
                    os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    @property
    def idle(self) -> bool:
        return self.current is None and not self.fifo and self._waiting is None

    # ------------------------------------------------------------ I/O loop

    def _run(self) -> None:
        while not self._stop.is_set() and not self.vanished:
            try:
                r, _, _ = select.select([self.master], [], [], 0.002)
            except (OSError, ValueError):
                return
            if r:
                try:
                    self._rx += os.read(self.master, 4096)
                except (BlockingIOError, OSError):
                    time.sleep(0.005)
            self._advance()
            self._parse_input()
            self._flush()
        if self.vanished:
            self._flush()
            try:
                os.close(self.master)
            except OSError:
                pass
            self.master = -1

    def _flush(self) -> None:
        while self._out:
            try:
                n = os.write(self.master, self._out)
            except BlockingIOError:
                return
            except OSError:
                self._out = b""
                return
            self._out = self._out[n:]

    def _say(self, text: str) -> None:
        self._out = self._out + text.encode("ascii")

    def _parse_input(self) -> None:
        while self._waiting is None and not self.vanished:
            m = re.search(rb"[\r\n]", self._rx)
            if not m:
                return
            raw, self._rx = self._rx[:m.start()], self._rx[m.end():]
            if not raw.strip():
                continue
            line = raw.decode("ascii", "replace").strip()
            self.received.append(line)
            self._command(line)
            if self.cfg.vanish_at is not None and len(self.received) >= self.cfg.vanish_at:
                self.log(f"vanishing after command {len(self.received)}")
                self.vanished = True

    # ------------------------------------------------------------ motion

    def _advance(self) -> None:
        now = time.monotonic()
        dt = (now - self._last) * self.cfg.speed
        self._last = now
        while dt > 0 or (self.current is None and (self.fifo or self._waiting)):
            if self.current is None:
                if not self.fifo and self._waiting is not None:
                    self._admit()
                if not self.fifo:
                    break
                self._begin(self.fifo.popleft())
                if self._waiting is not None:
                    self._admit()
                continue
            step = min(dt, self.left)
            self.left -= step
            self.sim_t += step
            dt -= step
            if self.left <= 1e-12:
                self._finish(self.current)
                self.current = None
            else:
                break

    def _admit(self) -> None:
        """The command that waited for room enters the FIFO and is answered now."""
        if self._waiting is not None and len(self.fifo) < self.cfg.fifo:
            _, mo = self._waiting
            self._waiting = None
            self.fifo.append(mo)
            self._say("OK\r\n")

    def _begin(self, mo: _Motion) -> None:
        self.current = mo
        if mo.enable is not None:
            self.enabled = mo.enable
            self.pos = [0, 0]  # the step counters are zeroed whenever EM runs
        if mo.pen is not None:
            self.pen_up = mo.pen
            self.pen_log.append((self.sim_t, mo.pen))
        if mo.lm is not None:
            r1, s1, a1, r2, s2, a2, clear = mo.lm
            # 2.9 / 3.0 turn a motor back where its rate passes through zero; 2.7 / 2.8 roll the rate over
            turn = tuple(int(v) for v in re.findall(r"\d+", self.cfg.version)[:3]) >= (2, 9, 0)
            t1, d1, c1 = axis_move(r1, s1, a1, None if clear & 1 else self.accum[0], turn=turn)
            t2, d2, c2 = axis_move(r2, s2, a2, None if clear & 2 else self.accum[1], turn=turn)
            self.accum = [c1, c2]
            mo.steps = (d1, d2)
            mo.seconds = max(t1, t2) / TICK_HZ
            mo.extra["ticks"] = (t1, t2)
        if mo.absolute is not None:
            rate = mo.extra["rate"]
            d = (mo.absolute[0] - self.pos[0], mo.absolute[1] - self.pos[1])
            mo.steps = d
            mo.seconds = max(abs(d[0]), abs(d[1])) / rate
        self.left = mo.seconds

    def _finish(self, mo: _Motion) -> None:
        self.pos = [self.pos[0] + mo.steps[0], self.pos[1] + mo.steps[1]]
        if mo.steps != (0, 0) and self.enabled == (0, 0):
            self.enabled = (1, 1)  # motion commands enable both motors
        self.executed.append({"index": mo.index, "line": mo.line, "pos": tuple(self.pos), "t": self.sim_t,
                              "seconds": mo.seconds, **mo.extra})

    # ------------------------------------------------------------ commands

    def _command(self, line: str) -> None:
        mode = self.cfg.answer
        if mode == "silent":
            return
        if mode == "grbl":
            self._say("error:1\r\n")
            return
        parts = line.split(",")
        name = parts[0].upper()
        try:
            args = self._ints(parts[1:])
            reply = self._dispatch(name, args, line)
        except _Err as e:
            self.errors.append((line, str(e)))
            self.log(f"refused {line!r}: {e}")
            self._say(f"{e}" + {"ok-line": "\r\nOK\r\n", "inline": "OK\r\n", "bare": "\r\n"}[self.cfg.error_end])
            return
        if reply is not None:
            self._say(reply)

    @staticmethod
    def _ints(args: list[str]) -> list[int]:
        out = []
        for a in args:
            m = _NUM.match(a)
            if a == "":
                raise _Err(4, "Missing parameter(s)")
            if not m:
                raise _Err(6, "Invalid parameter value")
            if m.end() != len(a):
                raise _Err(5, f"Need comma next, found: '{a[m.end()]}'")
            v = int(a[:m.end()])
            if not I32[0] <= v <= I32[1]:
                raise _Err(6, "Invalid parameter value")
            out.append(v)
        return out

    @staticmethod
    def _count(args: list[int], lo: int, hi: int) -> None:
        if len(args) < lo:
            raise _Err(4, "Missing parameter(s)")
        if len(args) > hi:
            raise _Err(7, "Extra parameter")

    def _queue(self, mo: _Motion) -> str | None:
        if len(self.fifo) < self.cfg.fifo:
            self.fifo.append(mo)
            return "OK\r\n"
        self._waiting = ("", mo)  # the board stops reading until it fits
        return None

    def _dispatch(self, name: str, a: list[int], line: str) -> str | None:
        n = len(self.received)
        if name == "V":
            self._count(a, 0, 0)
            return f"EBBv13_and_above EB Firmware Version {self.cfg.version}\r\n"
        if name == "QM":
            self._count(a, 0, 1)
            busy = int(self.current is not None)
            m1 = int(busy and self.current.steps[0] != 0) if self.current else 0
            m2 = int(busy and self.current.steps[1] != 0) if self.current else 0
            return f"QM,{busy},{m1},{m2},{int(bool(self.fifo))}\n\r"
        if name == "QS":
            self._count(a, 0, 0)
            return f"{self.pos[0]},{self.pos[1]}\n\rOK\r\n"
        if name == "QP":
            self._count(a, 0, 0)
            return f"{self.pen_up}\n\rOK\r\n"
        if name == "QG":
            self._count(a, 0, 0)
            status = (self.pen_up == 0) << 4 | (self.current is not None) << 3 | bool(self.fifo)
            return f"{status:02X}\r\n"
        if name == "CS":
            self._count(a, 0, 0)
            self.pos, self.accum = [0, 0], [0, 0]
            return "OK\r\n"
        if name == "R":
            self._count(a, 0, 0)
            self.fifo.clear()
            self.current, self.pos, self.accum = None, [0, 0], [0, 0]
            return "OK\r\n"
        if name == "ES":
            self._count(a, 0, 1)
            interrupted = int(self.current is not None or bool(self.fifo))
            if self.current is not None and self.current.lm is not None:
                self.current.steps = (0, 0)  # stopped where it was: the emulator drops the rest of the move
            self.fifo.clear()
            self.current = None
            return f"{interrupted}\n\rOK\r\n"
        if name == "SC":
            self._count(a, 2, 2)
            if not 0 <= a[0] <= 255 or not 0 <= a[1] <= 65535:
                raise _Err(6, "Invalid parameter value")
            self.servo[a[0]] = a[1]
            return "OK\r\n"
        if name == "SP":
            self._count(a, 1, 3)
            if a[0] not in (0, 1, 2, 3) or (len(a) > 1 and not 1 <= a[1] <= 65535) or (len(a) > 2 and not 0 <= a[2] <= 7):
                raise _Err(6, "Invalid parameter value")
            if a[0] >= 2:  # immediate lift
                self.pen_up = 1
                self.pen_log.append((self.sim_t, 1))
                return "OK\r\n"
            return self._queue(_Motion(n, line, (a[1] if len(a) > 1 else 0) / 1000, pen=a[0]))
        if name == "EM":
            self._count(a, 1, 2)
            if not 0 <= a[0] <= 5 or (len(a) > 1 and not 0 <= a[1] <= 5):
                raise _Err(6, "Invalid parameter value")
            return self._queue(_Motion(n, line, 0.0, enable=(a[0], a[1] if len(a) > 1 else self.enabled[1])))
        if name == "LM":
            self._count(a, 6, 7)
            clear = a[6] if len(a) > 6 else 0
            if not 0 <= clear <= 3:
                raise _Err(6, "Invalid parameter value")
            r1, s1, a1, r2, s2, a2 = a[:6]
            if (s1 < 0 and r1 < 0) or (s2 < 0 and r2 < 0):  # a direction given twice (plotink's calculate_lm: invalid)
                raise _Err(6, "Invalid parameter value")
            return self._queue(_Motion(n, line, 0.0, lm=(r1, s1, a1, r2, s2, a2, clear)))
        if name in ("SM", "XM"):
            self._count(a, 2 if name == "SM" else 3, 4)
            dur = a[0]
            if dur < 1:
                raise _Err(6, "Invalid parameter value")
            s1 = a[1]
            s2 = a[2] if len(a) > 2 else 0
            if name == "XM":
                s1, s2 = a[1] + a[2], a[1] - a[2]
            if (s1 or s2) and max(abs(s1), abs(s2)) / (dur / 1000) > TICK_HZ:
                axis = "axis1" if abs(s1) >= abs(s2) else "axis2"
                raise _Err(0, f"<{axis}> step rate too high")
            if not (s1 or s2):
                dur = min(dur, 100000)
            return self._queue(_Motion(n, line, dur / 1000, steps=(s1, s2)))
        if name == "HM":
            self._count(a, 1, 3)
            if not 2 <= a[0] <= 25000 or len(a) == 2:
                raise _Err(6 if len(a) != 2 else 4, "Invalid parameter value" if len(a) != 2 else "Missing parameter(s)")
            target = (a[1], a[2]) if len(a) == 3 else (0, 0)
            return self._queue(_Motion(n, line, 0.0, absolute=target, extra={"rate": a[0]}))
        hexes = "".join(f"{ord(ch):02X}" for ch in name[:2])
        raise _Err(8, f"Unknown command '{name[:2]}:{hexes}'")
