"""Travel: pen-up moves between strokes.

A move goes to an absolute position; each axis runs its own rest-to-rest
profile at the move speed and the axis's acceleration limit, so the move
lasts as long as the slower axis needs. The profile's shape is the machine's
travel law (``[travel] law`` in the profile):

* ``trapezoid`` (alias ``bang-bang``, the default): constant acceleration at
  the limit, cruise, constant deceleration — time-optimal, but the
  acceleration jumps (infinite jerk), which shakes an open-loop stepper.
* ``modified-sine`` (alias ``smooth``), ``modified-trapezoid``, ``cycloidal``:
  Kirecci's high-speed cam laws (§2.7.2) with the same *peak* acceleration:
  acceleration is continuous, so the move starts and stops without a jolt,
  at the price of some time. For a long move the law's first half ramps up to
  the move speed, the axis cruises, and the second half ramps down.

The PLC executes MOVE commands with its own trapezoid (docs/formats.md), so
for the PLC the law changes the planned time estimate, and what a post that
writes the motion itself (G-code segments, a velocity stream) could emit
through ``axis_move_state``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from doodlecam.model import Travel
from doodlecam.options import TRAVEL_LAWS, travel_law_name

_CAM_LAW = {"trapezoid": "bang-bang"}  # the motion-law name behind each travel law


@lru_cache(maxsize=None)
def law_coefficients(law: str) -> tuple[float, float]:
    """(Cv, Ca): peak velocity and acceleration of the law for a unit rise in unit time."""
    law = travel_law_name(law)
    if law == "trapezoid":
        return 2.0, 4.0
    if law == "cycloidal":
        return 2.0, 2 * np.pi
    if law == "modified-trapezoid":
        return 2.0, 8 * np.pi / (2 + np.pi)  # eq. 2.54
    a = np.pi**2 / (2 * np.pi * 0.125 + 2 - 8 * 0.125)  # eq. 2.70, b = 1/8
    return a / np.pi, a  # modified sine: peak velocity at mid-rise is A/π


def _ramp(vmax: float, amax: float, law: str) -> tuple[float, float]:
    """(τ, H): ramp time to vmax at peak acceleration amax, and the rise of the
    whole law that reaches vmax at its middle (the distance of ramp up + down)."""
    cv, ca = law_coefficients(law)
    tau = ca * vmax / (2 * cv * amax)
    return tau, 2 * vmax * tau / cv


def axis_move_time(distance, vmax: float, amax: float, law: str = "trapezoid"):
    """Rest-to-rest time (s) for |distance| mm with peak speed vmax and peak acceleration amax."""
    d = np.abs(np.asarray(distance, dtype=float))
    cv, ca = law_coefficients(law)
    tau, h = _ramp(vmax, amax, law)
    return np.where(d < h, np.sqrt(ca * d / amax), 2 * tau + (d - h) / vmax)


def axis_move_state(distance: float, vmax: float, amax: float, law: str, t) -> np.ndarray:
    """(4, n): position (from the start), velocity, acceleration, jerk of one
    axis's move at times t (s); at rest at ``distance`` after it ends."""
    from doodlecam.motion import laws

    law = travel_law_name(law)
    cam = _CAM_LAW.get(law, law)
    t = np.atleast_1d(np.asarray(t, dtype=float))
    sign, d = np.sign(distance), abs(float(distance))
    if d == 0:
        return np.zeros((4, len(t)))
    tau, h = _ramp(vmax, amax, law)
    if d < h:
        out = laws.evaluate(cam, t, d, float(axis_move_time(d, vmax, amax, law)))
    else:
        tc = (d - h) / vmax  # cruise
        out = np.zeros((4, len(t)))
        up, cruise, down = t < tau, (t >= tau) & (t <= tau + tc), t > tau + tc
        out[:, up] = laws.evaluate(cam, t[up], h, 2 * tau)
        out[0, cruise] = h / 2 + vmax * (t[cruise] - tau)
        out[1, cruise] = vmax
        out[:, down] = laws.evaluate(cam, t[down] - tc, h, 2 * tau)
        out[0, down] += vmax * tc
    return out * sign


def machine_law(machine) -> str:
    return travel_law_name(getattr(machine, "travel_law", "trapezoid"))


def travel_times(starts, ends, machine, law: str | None = None) -> np.ndarray:
    """Durations (s) of the pen-up moves from each start to each end ((n, 2) mm), all at once:
    each axis on its own profile with the machine's travel law (or ``law``), the slower one sets it."""
    law = travel_law_name(law) if law else machine_law(machine)
    d = np.asarray(ends, float).reshape(-1, 2) - np.asarray(starts, float).reshape(-1, 2)
    vx, vy = machine.move_speed
    return np.maximum(axis_move_time(d[:, 0], vx, machine.x.max_acceleration, law),
                      axis_move_time(d[:, 1], vy, machine.y.max_acceleration, law))


def make_travel(start, end, machine, law: str | None = None) -> Travel:
    """The pen-up move from start to end (mm) with the machine's travel law (or ``law``)."""
    return Travel(start=start, end=end, duration=float(travel_times(start, end, machine, law)[0]))


def make_travels(points, machine) -> tuple[Travel, ...]:
    """The moves points[0] -> points[1], points[2] -> points[3], ... ((2n, 2) mm) with the machine's law."""
    p = np.array(points, float).reshape(-1, 2)  # a copy of its own: its rows are handed to the travels
    t = travel_times(p[0::2], p[1::2], machine).tolist()
    return tuple(Travel.handed(p[2 * i], p[2 * i + 1], t[i]) for i in range(len(t)))


def travel_state(travel: Travel, machine, t, law: str | None = None) -> np.ndarray:
    """(4, n, 2): pen position (mm), velocity, acceleration, jerk of a travel
    at times t (s) from its start, each axis on its own profile."""
    law = travel_law_name(law) if law else machine_law(machine)
    d = travel.end - travel.start
    vx, vy = machine.move_speed
    fx = axis_move_state(d[0], vx, machine.x.max_acceleration, law, t)
    fy = axis_move_state(d[1], vy, machine.y.max_acceleration, law, t)
    out = np.stack([fx, fy], axis=-1)
    out[0] += travel.start
    return out


def travel_time_by_law(travels, machine) -> dict[str, float]:
    """Total pen-up time (s) of these moves under every travel law: the
    job-time cost of smoothness is the difference to ``trapezoid``."""
    starts = np.array([tr.start for tr in travels], float).reshape(-1, 2)
    ends = np.array([tr.end for tr in travels], float).reshape(-1, 2)
    # summed in order, one move after another (as the job's own time is)
    return {law: sum(travel_times(starts, ends, machine, law).tolist()) for law in TRAVEL_LAWS}
