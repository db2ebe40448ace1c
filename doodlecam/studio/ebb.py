"""EiBotBoard (AxiDraw) for the studio: the target (a real serial port, the board found by its USB id,
or the built-in EBB emulator on a pseudo-terminal) and where the pen stands after each command.

Everything that talks to the board is ``doodlecam.link.ebb``'s (the ``ebb`` transport's sender); the
send itself runs in ``studio.sending`` as the GRBL one does.
"""

from __future__ import annotations

import threading
from typing import Any

from doodlecam.errors import InputError
from doodlecam.studio.grbl import FAST, check_serial_port

EMULATOR = "ebb-simulator"
_PANEL = threading.Lock()  # one panel session on the board at a time (two tabs, two quick clicks)
PREFIX = "ebb:"  # ebb:/dev/ttyACM0, or ebb:auto (the first EiBotBoard on USB)


def is_ebb(target: str) -> bool:
    return target == EMULATOR or target.startswith(PREFIX)


def wants_ebb(machine) -> bool:
    """An AxiDraw-kinematics profile plots through the EBB post; the other links do not drive it."""
    return getattr(machine, "kinematics", "") == "axidraw"


class EbbTargets:
    """The built-in EBB emulator (one, living as long as the studio: it keeps its step position) and
    checked serial ports."""

    def __init__(self):
        self.emulator = None

    def port(self, target: str, speed: float | None = None) -> tuple[str | None, str]:
        """(port to open, None: find the board on USB; label for the page) of a target."""
        if target == EMULATOR:
            from doodlecam.link.ebb.emulator import EbbConfig, EbbEmulator

            want = float(speed) if speed else FAST
            if self.emulator is None:
                self.emulator = EbbEmulator(EbbConfig(speed=want)).start()
            else:
                self.emulator.cfg.speed = want
            return self.emulator.port, f"EBB emulator {self.emulator.port}"
        if not target.startswith(PREFIX):
            raise InputError(f"unknown EiBotBoard target '{target}'; use '{EMULATOR}' or 'ebb:PORT' "
                             "(e.g. ebb:/dev/ttyACM0, or ebb:auto to find the board on USB)")
        name = target[len(PREFIX):]
        if name in ("", "auto"):
            return None, "EiBotBoard on USB"
        return check_serial_port(name), f"EiBotBoard on {name}"

    def close(self) -> None:
        if self.emulator is not None:
            self.emulator.stop()
            self.emulator = None


def work_positions(steps: list[tuple[int, int]], steps_per_mm: float, height: float) -> list[tuple[float, float]]:
    """Work-area (x, y up) mm of motor step counts: motor 1 = x + y_page, motor 2 = x - y_page (the axidraw
    kinematics), y_page measured down from the home corner at (0, height)."""
    k = 2.0 * steps_per_mm
    return [(round((a + b) / k, 2), round(height - (a - b) / k, 2)) for a, b in steps]


def machine_action(port: str | None, label: str, action: str, args: dict[str, Any], machine) -> dict:
    """One of ``doodlecam machine ebb``'s controls on the board at ``port``: pen_up, pen_down, motors_off,
    jog (``x``, ``y``: mm on the paper, y up as the studio shows it; refused if it would leave the work
    area), home (the start corner, where the motors were switched on), status. Returns what was sent,
    the pen's position and a line for the page."""
    with _PANEL:
        return _machine_action(port, label, action, args, machine)


def _machine_action(port: str | None, label: str, action: str, args: dict[str, Any], machine) -> dict:
    from doodlecam.link.ebb import manual

    k = float(machine.kinematics_params.get("steps_per_mm", 80.0))
    if action != "jog":
        cmds = manual.commands(action)  # an unknown action: its one-line error
    else:
        x, y = args.get("x", 0.0), args.get("y", 0.0)
        manual.commands("jog", dx=x, dy=y, steps_per_mm=k)  # numbers, at least a step
        cmds = manual.commands("jog", dx=x, dy=-y, steps_per_mm=k)  # the board's page: y down from home
        here = work_positions([tuple(manual.run(port, [], wait=False)["steps"])], k, machine.height)[0]
        to = (here[0] + x, here[1] + y)
        if not (-1e-9 <= to[0] <= machine.width + 1e-9 and -1e-9 <= to[1] <= machine.height + 1e-9):
            raise InputError(f"jog to ({to[0]:.1f}, {to[1]:.1f}) mm would leave the {machine.width:g} x "
                             f"{machine.height:g} mm work area; jog less (the pen is at ({here[0]:.1f}, {here[1]:.1f}))")
    r = manual.run(port, cmds)
    pos = work_positions([tuple(r["steps"])], k, machine.height)[0]
    where = ("motors off: the carriage moves by hand, and positions count from where the motors are next "
             "switched on" if action == "motors_off" else f"pen at ({pos[0]:.1f}, {pos[1]:.1f}) mm")
    return {"action": action, "sent": " ".join(cmds), "state": "idle", "position_mm": list(pos),
            "line": f"{label}, firmware {r['firmware']}: {where} (motors at {r['steps'][0]}, {r['steps'][1]} steps)"}
