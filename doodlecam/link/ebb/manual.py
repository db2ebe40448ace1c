"""Manual controls of an EiBotBoard: pen up/down, motors off, jog, home to the start corner, status.

One source for ``doodlecam machine --serial PORT ebb ...`` and the studio's EiBotBoard panel: the
commands of each action (EBB command reference: SP, EM, XM, HM, QS) and one short session that checks
the board (``V``, firmware for LM), sends them, waits until it has executed them (``QM``) and reads the
step position (``QS``).
"""

from __future__ import annotations

import math

from doodlecam.errors import InputError
from doodlecam.link.ebb.sender import HOME_RATE  # the sender's resume move: the same HM rate

ACTIONS = ("status", "pen_up", "pen_down", "motors_off", "jog", "home")
PEN_MS = 200  # SP's wait: longer than any AxiDraw pen move (0.13 s with the profiles' servo settings)
JOG_SPEED = 50.0  # mm/s of the pen: XM starts and stops at once, so gently


def commands(action: str, dx: float = 0.0, dy: float = 0.0, speed: float = JOG_SPEED,
             steps_per_mm: float = 80.0) -> list[str]:
    """The board commands of ``action``; ``jog`` moves the pen up by (dx, dy) mm on the page (x right,
    y away from home) with XM, whose axis A is x and B is y (motor 1 = A + B, motor 2 = A - B)."""
    if action not in ACTIONS:
        raise InputError(f"unknown EiBotBoard action '{action}'; use one of {', '.join(ACTIONS)}")
    if action in ("pen_up", "pen_down"):
        return [f"SP,{1 if action == 'pen_up' else 0},{PEN_MS}"]
    if action == "motors_off":
        return ["EM,0,0"]
    if action == "home":
        return [f"SP,1,{PEN_MS}", f"HM,{HOME_RATE}"]
    if action == "jog":
        for name, v in (("x", dx), ("y", dy), ("speed", speed)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"jog {name} must be a number (mm, speed mm/s), got {v!r}")
        if speed <= 0:
            raise InputError(f"jog speed must be positive (mm/s), got {speed:g}")
        a, b = round(dx * steps_per_mm), round(dy * steps_per_mm)
        if a == 0 and b == 0:
            raise InputError("jog distance is below one motor step; give a larger x or y")
        ms = max(1, round(1000 * math.hypot(dx, dy) / speed))
        return [f"SP,1,{PEN_MS}", f"XM,{ms},{a},{b}"]
    return []


def run(port: str | None, cmds: list[str], wait: bool = True, timeout: float = 5.0) -> dict:
    """Open the board at ``port`` (None: find it by its USB id), check it, send ``cmds`` one by one, wait
    until it has executed them, and return {firmware, port, steps: [motor 1, motor 2], sent}."""
    from doodlecam.link.ebb.jobfile import EbbJob
    from doodlecam.link.ebb.sender import EbbSender, _Refused, find_port
    from doodlecam.link.session import LinkError

    s = EbbSender(find_port() if port is None else port, EbbJob({}, ()), "manual", timeout=timeout)
    s._open()
    try:
        s.handshake()
        for c in cmds:
            try:
                s._ask(c, s.timeout)
            except _Refused as e:
                raise LinkError(f"the EiBotBoard refused {c}: {e}") from None
        if wait and cmds:
            s.wait_idle(600)
        first = s._ask("QS", s.timeout).split("\n")[0]
        try:
            steps = [int(v) for v in first.split(",")[:2]]
        except ValueError:
            steps = []
        if len(steps) != 2:
            raise InputError(f"{s.port_name} answered {first!r} to QS (step position); is it an EiBotBoard?")
        return {"firmware": s.version, "port": s.port_name, "steps": steps, "sent": list(cmds)}
    finally:
        s.ser.close()
