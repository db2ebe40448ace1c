"""Travel: pen-up moves between strokes, as the PLC executes them.

A move command goes to an absolute position; each axis runs its own
rest-to-rest trapezoidal profile (the stepper module's absolute move) at the
move speed and the axis's acceleration limit, so the move lasts as long as the
slower axis needs.
"""

from __future__ import annotations

import numpy as np

from .model import Travel


def axis_move_time(distance, vmax: float, amax: float):
    """Rest-to-rest time (s) for |distance| mm: triangle or trapezoid profile."""
    d = np.abs(np.asarray(distance, dtype=float))
    d_ramp = vmax * vmax / amax  # distance to reach vmax and stop again
    return np.where(d < d_ramp, 2 * np.sqrt(d / amax), d / vmax + vmax / amax)


def make_travel(start, end, machine) -> Travel:
    d = np.asarray(end, float) - np.asarray(start, float)
    vx, vy = machine.move_speed
    t = max(float(axis_move_time(d[0], vx, machine.x.max_acceleration)),
            float(axis_move_time(d[1], vy, machine.y.max_acceleration)))
    return Travel(start=start, end=end, duration=t)
