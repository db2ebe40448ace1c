"""GRBL for the studio: the serial target (a real port or the built-in emulator), the job's time left
from GRBL's planner model, and the machine-control panel (``doodlecam machine``'s commands).

Everything that talks to GRBL is ``doodlecam.link.grbl``'s: ``GrblLink`` and
``Controller`` for the panel, the serial transport for a send (``sending``).
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.errors import InputError

EMULATOR = "grbl-simulator"
SERIAL_PREFIX = "serial:"
# An unattended emulator runs this many times faster than real time when the page asks for "as fast as possible".
FAST = 100.0


class GrblTargets:
    """The built-in GRBL emulator (one, living as long as the studio) and checked serial ports."""

    def __init__(self):
        self.emulator = None

    def port(self, target: str, speed: float | None = None, keep_speed: bool = False) -> tuple[str, str]:
        """(port to open, label for the page) of a target: 'grbl-simulator' (at ``speed`` x real time,
        None: FAST; ``keep_speed``: as it is) or 'serial:/dev/ttyUSB0'."""
        if not isinstance(target, str):
            raise InputError(f"the GRBL target must be '{EMULATOR}' or 'serial:PORT'")
        if target == EMULATOR:
            from doodlecam.link.grbl.emulator import GrblConfig, GrblEmulator

            want = float(speed) if speed else FAST
            if self.emulator is None:
                self.emulator = GrblEmulator(GrblConfig(speed=want)).start()
            elif not keep_speed:
                self.emulator.cfg.speed = want  # one machine: its position and work offset stay across sends
            return self.emulator.port, f"GRBL emulator {self.emulator.port}"
        if not target.startswith(SERIAL_PREFIX):
            raise InputError(f"unknown GRBL target '{target}'; use '{EMULATOR}' or 'serial:PORT' (e.g. serial:/dev/ttyUSB0)")
        return check_serial_port(target[len(SERIAL_PREFIX):]), f"GRBL on {target[len(SERIAL_PREFIX):]}"

    def close(self) -> None:
        if self.emulator is not None:
            self.emulator.stop()
            self.emulator = None


def check_serial_port(name: str) -> str:
    """A request may name a serial device, never a file: /dev/... character devices (or COMn on Windows)."""
    if re.fullmatch(r"COM\d{1,3}", name or ""):
        return name
    p = Path(name or "")
    try:
        ok = p.is_absolute() and str(p).startswith("/dev/") and stat.S_ISCHR(os.stat(p).st_mode)
    except OSError:
        ok = False
    if not ok:
        raise InputError(f"'{name}' is not a serial port; give a device such as /dev/ttyUSB0 or /dev/ttyACM0 "
                         "(ls /dev/ttyUSB* /dev/ttyACM*)")
    return str(p)


def work_position(st) -> tuple[float, float] | None:
    """Work (x, y) in mm of a GRBL status report: WPos, else MPos - WCO (GRBL reports one of them)."""
    if st is None:
        return None
    if st.wpos:
        return (round(st.wpos[0], 3), round(st.wpos[1], 3))
    if not st.mpos:
        return None
    wco = (0.0, 0.0)
    m = re.search(r"\|WCO:([-\d.]+),([-\d.]+)", st.raw)
    if m:
        wco = (float(m.group(1)), float(m.group(2)))
    return (round(st.mpos[0] - wco[0], 3), round(st.mpos[1] - wco[1], 3))


def pen_commands(gcode: str) -> tuple[str, str]:
    """(pen up, pen down) lines of a job's G-code: the commands its gcode post wrote (no second source)."""
    from doodlecam.link.grbl.protocol import _is_pen, pen_up_line, prepare

    lines = prepare(gcode, "job.gcode")
    up = pen_up_line(lines)
    down = next((ln.text for ln in lines if _is_pen(ln.text) and ln.text != up), None)
    if down is None:
        raise InputError("the job's G-code has no pen-down command; draw at least one stroke")
    return up, down


MACHINE_ACTIONS = ("status", "home", "unlock", "jog", "zero", "pen_up", "pen_down", "settings")


def machine_action(port: str, action: str, args: dict[str, Any], pens: tuple[str, str] | None, settings_for: dict,
                   baud: int = 115200, timeout: float = 5.0) -> dict:
    """One ``doodlecam machine`` command on GRBL at ``port``; the status after it (and the settings check).

    ``settings_for``: the ``$`` settings the machine profile needs
    (``timing.grbl_settings_for``), compared with GRBL's own for ``settings``.
    """
    from doodlecam.link.grbl.control import Controller, status_line
    from doodlecam.link.grbl.port import GrblLink
    from doodlecam.link.grbl.protocol import GrblError, error_text

    if action not in MACHINE_ACTIONS:
        raise InputError(f"unknown machine action '{action}'; use one of {', '.join(MACHINE_ACTIONS)}")
    out: dict[str, Any] = {"action": action}
    with GrblLink(port, baud, timeout=timeout) as link:
        ctl = Controller(link)
        st = ctl.attach()
        if action == "home":
            st = ctl.home()
        elif action == "unlock":
            st = ctl.unlock()
        elif action == "jog":
            x, y, feed = (_number(args, k, d) for k, d in (("x", None), ("y", None), ("feed", 3000.0)))
            st = ctl.jog(x, y, feed, absolute=bool(args.get("absolute")))
        elif action == "zero":
            st = ctl.zero(_number(args, "x", 0.0), _number(args, "y", 0.0))
        elif action in ("pen_up", "pen_down"):
            if pens is None:
                raise InputError("load a job first: the pen commands are the ones its G-code uses (the gcode post's "
                                 "pen_up / pen_down)")
            line = pens[0] if action == "pen_up" else pens[1]
            r = ctl.command(line)
            if not r.ok:
                raise GrblError(f"GRBL refused '{line}': error:{r.code} {error_text(r.code)}")
            st = link.wait_idle()
            out["sent"] = line
        elif action == "settings":
            have = {}
            for s in ctl.settings():
                m = re.match(r"\$(\d+)=([-+\d.]+)", s)
                if m:
                    have[f"${m.group(1)}"] = float(m.group(2))
            out["settings"] = [{"key": k, "want": v, "have": have.get(k),
                                "ok": k in have and abs(have[k] - v) <= 1e-3 * max(1.0, abs(v))}
                               for k, v in settings_for.items()]
            st = ctl.status()
        out.update(state=st.state, position_mm=work_position(st), line=status_line(st, ctl.wco))
    return out


def _number(args: dict, key: str, default: float | None) -> float:
    v = args.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise InputError(f"{key} must be a number (mm, feed mm/min), got {v!r}")
    return float(v)
