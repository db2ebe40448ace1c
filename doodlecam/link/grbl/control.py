"""Machine control for a GRBL 1.1 controller: home, unlock, jog, set work zero, status, settings,
and an interactive console (``doodlecam machine --serial PORT ...``).

Every command is GRBL's own (doc/markdown/commands.md, jogging.md in the
gnea/grbl repository): ``$H`` homing, ``$X`` unlock, ``$J=G21G91X..Y..F..``
jogging (cancelled by the real-time byte 0x85), ``G10 L20 P1 X0 Y0`` work zero
at the current position (stored in G54), ``$$`` settings, ``?`` status,
``!``/``~`` feed hold and cycle start, 0x90..0x94 feed override.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from doodlecam.link.grbl.port import GrblLink
from doodlecam.link.grbl.protocol import HOME, UNLOCK, GrblError, GrblStatus, alarm_advice, alarm_text, error_text
from doodlecam.link.session import LinkError

# Real-time bytes (GRBL 1.1 config.h CMD_*).
JOG_CANCEL = b"\x85"
FEED_100, FEED_PLUS_10, FEED_MINUS_10, FEED_PLUS_1, FEED_MINUS_1 = (bytes([c]) for c in range(0x90, 0x95))
HOLD, RESUME, RESET = b"!", b"~", b"\x18"

# GRBL 1.1 settings (doc/csv/setting_codes_en_US.csv): number -> (name, unit).
SETTINGS: dict[int, tuple[str, str]] = {
    0: ("step pulse time", "µs"), 1: ("step idle delay", "ms"), 2: ("step pulse invert", "mask"),
    3: ("step direction invert", "mask"), 4: ("invert step enable pin", "bool"), 5: ("invert limit pins", "bool"),
    6: ("invert probe pin", "bool"), 10: ("status report options", "mask"), 11: ("junction deviation", "mm"),
    12: ("arc tolerance", "mm"), 13: ("report in inches", "bool"), 20: ("soft limits enable", "bool"),
    21: ("hard limits enable", "bool"), 22: ("homing cycle enable", "bool"), 23: ("homing direction invert", "mask"),
    24: ("homing locate feed rate", "mm/min"), 25: ("homing search seek rate", "mm/min"),
    26: ("homing switch debounce delay", "ms"), 27: ("homing switch pull-off distance", "mm"),
    30: ("maximum spindle speed", "RPM"), 31: ("minimum spindle speed", "RPM"), 32: ("laser-mode enable", "bool"),
    100: ("X-axis travel resolution", "step/mm"), 101: ("Y-axis travel resolution", "step/mm"),
    102: ("Z-axis travel resolution", "step/mm"), 110: ("X-axis maximum rate", "mm/min"),
    111: ("Y-axis maximum rate", "mm/min"), 112: ("Z-axis maximum rate", "mm/min"),
    120: ("X-axis acceleration", "mm/sec^2"), 121: ("Y-axis acceleration", "mm/sec^2"),
    122: ("Z-axis acceleration", "mm/sec^2"), 130: ("X-axis maximum travel", "mm"),
    131: ("Y-axis maximum travel", "mm"), 132: ("Z-axis maximum travel", "mm"),
}

HOMING_TIMEOUT = 120.0  # s: GRBL answers $H only when the whole cycle is over


def decode(line: str) -> str:
    """A GRBL reply with its meaning: ``$110=9000 (X-axis maximum rate, mm/min)``, ``error:15 (jog target ...)``."""
    if line.startswith("$") and "=" in line:
        key = line[1:].split("=", 1)[0]
        if key.isdigit() and int(key) in SETTINGS:
            name, unit = SETTINGS[int(key)]
            return f"{line} ({name}, {unit})"
    for prefix, text in (("error:", error_text), ("ALARM:", alarm_text)):
        if line.startswith(prefix) and line[len(prefix):].isdigit():
            return f"{line} ({text(int(line[len(prefix):]))})"
    return line


def status_line(st: GrblStatus, wco: tuple[float, ...] | None = None) -> str:
    """One line for a person: state, machine and work position, feed, override."""
    state = st.state + (f":{st.substate}" if st.substate is not None else "")
    parts = [f"{state:<7}"]
    if st.mpos:
        parts.append("MPos " + ",".join(f"{v:.3f}" for v in st.mpos[:3]))
    wpos = st.wpos or (tuple(m - w for m, w in zip(st.mpos, wco)) if st.mpos and wco else None)
    if wpos:
        parts.append("WPos " + ",".join(f"{v:.3f}" for v in wpos[:3]))
    if st.feed is not None:
        parts.append(f"F {st.feed:.0f}")
    ov = _field(st.raw, "Ov")
    if ov:
        parts.append(f"feed {ov.split(',')[0]}%")
    return " | ".join(parts)


def _field(raw: str, key: str) -> str | None:
    for f in raw.strip("<>").split("|")[1:]:
        k, _, v = f.partition(":")
        if k == key:
            return v
    return None


@dataclass
class Reply:
    ok: bool
    lines: list[str]  # everything GRBL printed before its ok / error (settings, messages)
    code: int = 0  # error code when not ok


class Controller:
    """Machine control over a GrblLink that is open (``attach`` first)."""

    def __init__(self, link: GrblLink):
        self.link = link
        self.wco: tuple[float, ...] | None = None

    # ------------------------------------------------------------ basics

    def attach(self, reset_if_silent: bool = False) -> GrblStatus:
        """Wait for GRBL's first status report; unlike ``send`` it takes any state (alarm too).
        A GRBL blocked after a limit alarm answers nothing but a reset: ``reset_if_silent`` sends one."""
        try:
            return self._seen(self.link.first_status())
        except LinkError:
            if not reset_if_silent:
                raise LinkError(f"no answer from GRBL on {self.link.port}; after a limit alarm GRBL answers nothing "
                                f"until reset: run 'doodlecam machine --serial {self.link.port} reset' (else check the "
                                "port, the baud rate and that the controller runs GRBL)") from None
        return self.reset()

    def reset(self) -> GrblStatus:
        """Soft reset (Ctrl-X): frees a GRBL blocked after a limit alarm; motion stops, the position is kept
        unless it was moving (then GRBL stays in alarm until homed or unlocked)."""
        if not self.link.try_reset():
            raise LinkError(f"GRBL on {self.link.port} did not restart after a soft reset; check the port and the "
                            "baud rate, or power-cycle it")
        return self.status()

    def _seen(self, st: GrblStatus) -> GrblStatus:
        wco = _field(st.raw, "WCO")
        if wco:
            try:
                self.wco = tuple(float(v) for v in wco.split(","))
            except ValueError:
                pass
        return st

    def status(self) -> GrblStatus:
        return self._seen(self.link.fresh_status())

    def command(self, text: str, timeout: float | None = None, on_line: Callable[[str], None] | None = None) -> Reply:
        """Send one line and collect what GRBL prints until its ``ok`` or ``error:N``."""
        link = self.link
        if text == "$H":  # GRBL answers nothing, not even status, until the homing cycle is over
            link.log(f"homing (GRBL is silent until the cycle ends, up to {timeout or link.timeout:g} s) ...")
            polling, link.polling = link.polling, False
            try:
                return self._command(text, timeout, on_line)
            finally:
                link.polling = polling
        return self._command(text, timeout, on_line)

    def _command(self, text: str, timeout: float | None, on_line: Callable[[str], None] | None) -> Reply:
        link = self.link
        link.write((text + "\n").encode("ascii"))
        lines: list[str] = []
        end = time.monotonic() + (timeout if timeout is not None else link.timeout)
        while time.monotonic() < end:
            ev = link.next_event(0.1)
            if ev is None:
                continue
            kind = ev[0]
            if kind == "ok":
                return Reply(True, lines)
            if kind == "error":
                return Reply(False, lines, ev[1])
            if kind == "status":
                self._seen(ev[1])
                continue
            if kind == "alarm":  # a limit alarm: GRBL is reset as soon as it listens again
                raise link.alarm_error(ev[1], f"after '{text}'")
            text_line = ev[1] if kind == "info" else (f"[MSG:{ev[1]}]" if kind == "msg" else str(ev[1]))
            lines.append(text_line)
            if on_line:
                on_line(text_line)
        raise LinkError(f"GRBL on {link.port} did not answer '{text}' within {timeout or link.timeout:g} s; "
                        "check the cable and that the controller runs GRBL")

    def _must(self, text: str, what: str, timeout: float | None = None) -> Reply:
        r = self.command(text, timeout)
        if not r.ok:
            hint = ""
            if r.code in (8, 9) and self.status().state == "Alarm":
                hint = f"; GRBL is in alarm: home it ($H: '{HOME}') or unlock it ($X: '{UNLOCK}') first"
            raise GrblError(f"GRBL refused {what} ('{text}'): error:{r.code} {error_text(r.code)}{hint}")
        return r

    # ------------------------------------------------------------ commands

    def home(self) -> GrblStatus:
        """``$H``: run the homing cycle (needs $22=1); clears an alarm."""
        self._must("$H", "homing", HOMING_TIMEOUT)
        return self.status()

    def unlock(self) -> GrblStatus:
        """``$X``: leave the alarm state without homing (the position may be wrong)."""
        self._must("$X", "unlock")
        return self.status()

    def jog(self, x: float, y: float, feed: float, absolute: bool = False, wait: bool = True) -> GrblStatus | None:
        """``$J=``: jog by (x, y) mm (or to work (x, y) when ``absolute``) at ``feed`` mm/min."""
        if not feed > 0:
            raise GrblError(f"jog feed must be positive, got {feed:g} mm/min")
        mode = "G90" if absolute else "G91"
        self._must(f"$J=G21{mode}X{x:.3f}Y{y:.3f}F{feed:.0f}", "the jog")
        return self.link.wait_idle() if wait else None

    def jog_cancel(self) -> None:
        self.link.realtime(JOG_CANCEL)

    def zero(self, x: float = 0.0, y: float = 0.0) -> GrblStatus:
        """``G10 L20 P1``: the current position becomes work (x, y) in G54, which GRBL stores."""
        self._must(f"G10L20P1X{x:.3f}Y{y:.3f}", "setting work zero")
        return self.status()

    def settings(self) -> list[str]:
        """``$$``: every setting, decoded."""
        return [decode(s) for s in self._must("$$", "listing the settings").lines]


# ------------------------------------------------------------ console

KEYS_HELP = ("arrows jog (step [ ] /10 x10) | h home | u unlock | z zero here | ! hold | ~ resume | "
             "+ - = feed override | c cancel jog | $... Enter: command | x reset | q quit")
ARROWS = {"\x1b[A": (0, 1), "\x1b[B": (0, -1), "\x1b[C": (1, 0), "\x1b[D": (-1, 0)}


def read_key(getch: Callable[[], str | None]) -> str | None:
    """One key from a character source: an arrow's escape sequence as one string."""
    c = getch()
    if c != "\x1b":
        return c
    seq = c
    for _ in range(2):
        n = getch()
        if n is None:
            break
        seq += n
    return seq


def run_console(ctl: Controller, getch: Callable[[], str | None], out: Callable[[str], None], *,
                step: float = 1.0, feed: float = 3000.0, idle: Callable[[], None] | None = None) -> None:
    """The interactive console: keys from ``getch`` (None: no key yet), lines to ``out``.

    Shows the status line when it changes; arrow keys jog by ``step`` mm at
    ``feed`` mm/min; ``$`` starts a command line sent on Enter, its replies decoded.
    """
    link = ctl.link
    out(KEYS_HELP)
    last = ""
    typing: str | None = None
    while True:
        ev = link.next_event(0.02)
        if ev is not None:
            if ev[0] == "status":
                line = status_line(ctl._seen(ev[1]), ctl.wco) + f" | step {step:g} mm"
                if line != last:
                    out(line)
                    last = line
            elif ev[0] == "alarm":
                out(decode(f"ALARM:{ev[1]}") + f"; {alarm_advice(ev[1])}")
            elif ev[0] in ("msg", "banner", "info"):
                out(str(ev[1]))
        key = read_key(getch)
        if key is None:
            if idle:
                idle()
            continue
        if typing is not None:
            if key in ("\r", "\n"):
                cmd, typing = typing.strip(), None
                if cmd:
                    out(f"> {cmd}")
                    r = ctl.command(cmd, on_line=lambda s: out(decode(s)))
                    out("ok" if r.ok else decode(f"error:{r.code}"))
            elif key in ("\x7f", "\b"):
                typing = typing[:-1]
            elif key == "\x1b":
                typing = None
            elif key.isprintable():
                typing += key
            continue
        if key in ARROWS:
            dx, dy = ARROWS[key]
            r = ctl.command(f"$J=G21G91X{dx * step:.3f}Y{dy * step:.3f}F{feed:.0f}")
            if not r.ok:
                out(decode(f"error:{r.code}"))
        elif key == "[":
            step = max(step / 10.0, 0.01)
        elif key == "]":
            step = min(step * 10.0, 100.0)
        elif key == "h":
            out("homing ...")
            r = ctl.command("$H", HOMING_TIMEOUT)
            out("homed" if r.ok else decode(f"error:{r.code}"))
        elif key == "u":
            r = ctl.command("$X", on_line=lambda s: out(decode(s)))
            out("ok" if r.ok else decode(f"error:{r.code}"))
        elif key == "z":
            r = ctl.command("G10L20P1X0Y0")
            out("work zero set here" if r.ok else decode(f"error:{r.code}"))
        elif key in ("!", "~"):
            link.realtime(key.encode())
        elif key in ("+", "-", "="):
            link.realtime({"+": FEED_PLUS_10, "-": FEED_MINUS_10, "=": FEED_100}[key])
        elif key == "c":
            link.realtime(JOG_CANCEL)
        elif key == "x":
            link.realtime(RESET)
        elif key == "$":
            typing = "$"
        elif key == "q":
            return
