"""Is a valid profile a plausible plotter? Bounds on its numbers, with the unit slip that
most likely put a value outside them.

A profile can be well-formed and still describe no machine: ``delta_time = 40``
(milliseconds written for seconds) makes a 40 s sample period and a job that never
ends; ``max_velocity = 6000`` (GRBL's mm/min) asks for 6 m/s and a 480 kHz step rate.
``machine.parse_machine`` raises the first error found here (so ``machines check``,
``convert``, ``batch`` and the studio refuse such a profile alike) and keeps the
warnings on the Machine, where ``machines check`` and each job's summary show them.

Bounds are wide: they only catch values no pen plotter has.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from doodlecam.machine import Machine

# (lowest, highest) a plotter has; outside them a value is refused (errors) or questioned (warnings)
DELTA_TIME = (0.001, 1.0)  # s: the report samples every 40-150 ms; controllers take 1 ms at best
PEN_DELAY_MAX = 5.0  # s: a servo lifts in 0.1-0.3 s, a Z axis in well under a second
SPEED_MAX = 2000.0  # mm/s: the fastest pen plotters draw at a few hundred mm/s
SPEED_LOW = 1.0  # mm/s: slower than this, m/s were probably written for mm/s (a warning)
ACCEL_MAX = 100_000.0  # mm/s^2: 10 g
ACCEL_LOW = 10.0  # mm/s^2 (a warning)
# steps/s the controller can send per motor
STEP_RATES = {"EiBotBoard": 25_000.0, "GRBL": 30_000.0, "other": 200_000.0}


@dataclass(frozen=True)
class Finding:
    error: bool  # True: the profile is refused; False: a warning
    message: str


def _speed(where: str, value: float) -> Finding | None:
    if value > SPEED_MAX:
        hint = (f"; {value:g} looks like mm/min (GRBL's unit): write {value / 60:g} (mm/s)"
                if value / 60 <= SPEED_MAX else "")
        return Finding(True, f"{where} = {value:g} mm/s is faster than any pen plotter (at most {SPEED_MAX:g} mm/s)"
                             f"{hint}; speeds are in mm/s")
    if value < SPEED_LOW:
        return Finding(False, f"{where} = {value:g} mm/s is very slow; if you meant {value:g} m/s, write "
                              f"{value * 1000:g} (speeds are in mm/s)")
    return None


def _accel(where: str, value: float) -> Finding | None:
    if value > ACCEL_MAX:
        return Finding(True, f"{where} = {value:g} mm/s^2 is over {ACCEL_MAX / 1000:g} m/s^2 (10 g), more than a "
                             "plotter's motors give; accelerations are in mm/s^2 (GRBL's $120 uses the same unit)")
    if value < ACCEL_LOW:
        return Finding(False, f"{where} = {value:g} mm/s^2 is very gentle; if you meant {value:g} m/s^2, write "
                              f"{value * 1000:g} (accelerations are in mm/s^2)")
    return None


def _seconds(where: str, value: float, low: float, high: float, typical: str) -> Finding | None:
    if low <= value <= high:
        return None
    if value > high:
        hint = (f"; {value:g} looks like milliseconds: write {value / 1000:g}" if low <= value / 1000 <= high
                else "")
        return Finding(True, f"{where} = {value:g} s is longer than {high:g} s{hint} (times are in seconds, "
                             f"typically {typical})")
    return Finding(True, f"{where} = {value:g} s is shorter than {low * 1000:g} ms, faster than a controller "
                         f"executes; times are in seconds, typically {typical}")


def controller(machine: "Machine") -> str:
    """Which controller the profile drives, as far as it says: the AxiDraw's EiBotBoard, GRBL (a
    [post.gcode] table for the grbl dialect, the G-code post's default) or another (a PLC)."""
    if machine.kinematics == "axidraw":
        return "EiBotBoard"
    gcode = machine.plugin_options.get("post.gcode")
    if gcode is not None and str(gcode.get("dialect", "grbl")).lower() == "grbl":
        return "GRBL"
    return "other"


def findings(machine: "Machine") -> list[Finding]:
    """Every implausible value of a (well-formed) profile, errors first."""
    m, src = machine, machine.source or machine.name
    out: list[Finding | None] = []
    hx, hy = m.home
    eps = 1e-9 * max(m.width, m.height)
    if not (-eps <= hx <= m.width + eps and -eps <= hy <= m.height + eps):
        out.append(Finding(True, f"{src}: work_area.home = [{hx:g}, {hy:g}] is outside the {m.width:g} x {m.height:g} mm "
                                 f"work area; give the corner the pen starts from, within [0..{m.width:g}, 0..{m.height:g}] "
                                 "(e.g. [0, 0])"))
    out.append(_seconds(f"{src}: sampling.delta_time", m.delta_time, *DELTA_TIME, "0.04 (40 ms)"))
    pens = m.pens or (m.pen,)
    for k, p in enumerate(pens, 1):
        table = f"pen[{k}]" if m.pens else "pen"  # the dotted keys of doodlecam.schema
        for key in ("up_delay", "down_delay"):
            out.append(_seconds(f"{src}: {table}.{key}", getattr(p, key), 0.0, PEN_DELAY_MAX, "0.1-0.3"))
        if p.max_speed is not None:
            out.append(_speed(f"{src}: {table}.max_speed", p.max_speed))
        if p.max_accel is not None:
            out.append(_accel(f"{src}: {table}.max_accel", p.max_accel))
    if m.travel_speed is not None:
        out.append(_speed(f"{src}: travel.speed", m.travel_speed))
    ctl = controller(m)
    for ax in m.axes:
        table = f"{src}: axes.{ax.name}"
        fast = _speed(f"{table}.max_velocity", ax.max_velocity)
        out += [fast, _accel(f"{table}.max_acceleration", ax.max_acceleration)]
        rate = ax.max_velocity * ax.steps_per_mm
        if rate > STEP_RATES[ctl] and not (fast and fast.error):
            top = STEP_RATES[ctl] / ax.steps_per_mm
            who = {"EiBotBoard": "the EiBotBoard steps", "GRBL": "GRBL 1.1 on an Arduino steps",
                   "other": "stepper drivers take"}[ctl]
            out.append(Finding(ctl == "EiBotBoard",
                               f"{table}.max_velocity = {ax.max_velocity:g} mm/s at {ax.steps_per_mm:g} steps/mm is "
                               f"{rate / 1000:.0f} kHz of steps; {who} at most about {STEP_RATES[ctl] / 1000:g} kHz: "
                               f"lower max_velocity to {top:.0f} mm/s or steps_per_mm"))
        reach = ax.max_velocity ** 2 / (2 * ax.max_acceleration)
        span = m.width if ax.name == "x" else m.height
        if reach > span and not (fast and fast.error):
            out.append(Finding(False, f"{table}: reaching max_velocity = {ax.max_velocity:g} mm/s at "
                                      f"{ax.max_acceleration:g} mm/s^2 takes {reach:.0f} mm, more than the "
                                      f"{span:g} mm of travel: check both units (mm/s, mm/s^2)"))
    found = [f for f in out if f is not None]
    return sorted(found, key=lambda f: not f.error)
