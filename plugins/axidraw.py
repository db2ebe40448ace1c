"""AxiDraw (EiBotBoard) mixed-axis kinematics: two motors, each moving x + y or x - y.

The AxiDraw's belt (an H-bot) is driven by two steppers. In the machine's page
coordinates (origin at the home corner, x to the right, y away from home, down
the page) motor 1 turns by x + y and motor 2 by x - y (AxiDraw driver and
plotink: ``motor_dist1 = xDist + yDist``, ``motor_dist2 = xDist - yDist``),
2032 steps per inch of belt at 16x microstepping (``native_res_factor`` 1016 x 2)
= 80 steps/mm on each motor axis.

doodlecam's work area has y up (the SVG post flips it), with the home corner at
(0, height). So y_page = height - y and the actuators are the linear map

    theta1 = x - y,  theta2 = x + y   (mm of belt, plus constants)

The planner keeps each motor's velocity and acceleration limits on this map and
certifies them between grid points exactly (Bernstein bounds), as for a
Cartesian machine. The EBB post executes one constant-acceleration ``LM`` per
velocity-sample period in whole motor steps; the shift that puts each period on
whole steps changes a motor's rate by at most 1 step / delta_time, so the limits
given to the planner are the profile's less that (docs/ebb.md).

``pen_acceleration`` (optional): the AxiDraw driver's acceleration limit is on the
pen's path, not on a motor. With it the map gains eight rows, the pen's acceleration
along 0, 22.5, ..., 157.5 degrees, each within pen_acceleration x cos 11.25 deg, so the
pen accelerates at most pen_acceleration in every direction (a regular 16-gon in the
circle, at most 1.9 % short of it; per-motor limits alone are a diamond, 29 % short on
the diagonals; an octagon was 7.6 % short, which cost 1.4 % of the time on curvy drawings).
"""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import Field

from doodlecam.api import Kinematics, check_in_work_area
from doodlecam.errors import MachineError
from doodlecam.schema import Num, Table

MOTORS = np.array([[1.0, -1.0], [1.0, 1.0]])  # work area (x, y up) -> (x + y_page, x - y_page)
# pen acceleration <= A in every direction: its components along PEN_DIRECTIONS directions
# k 180 / PEN_DIRECTIONS degrees within A cos(90 / PEN_DIRECTIONS deg) (a regular polygon inside the circle of radius A)
PEN_DIRECTIONS = 8
_ANG = np.arange(PEN_DIRECTIONS) * np.pi / PEN_DIRECTIONS
POLYGON = np.column_stack([np.cos(_ANG), np.sin(_ANG)])
EBB_MAX_STEP_RATE = 25000.0  # steps/s: one step per 40 us tick at most


Positive = Annotated[Num, Field(gt=0)]


class AxiDrawParams(Table):
    """The [kinematics] table of an AxiDraw profile (checked on load: doodlecam.schema)."""

    steps_per_mm: Positive = Field(description="steps per mm of belt on each motor, e.g. 80 (16x microstepping)")
    max_velocity: tuple[Positive, Positive] = Field(description="[motor1, motor2] in mm/s of belt, e.g. [312, 312]")
    max_acceleration: tuple[Positive, Positive] = Field(description="[motor1, motor2] in mm/s^2, e.g. [1077, 1077]")
    pen_acceleration: Positive | None = Field(None, description="the pen's acceleration in every direction in "
                                                                "mm/s^2, e.g. 762")


class AxiDraw(Kinematics):
    name = "axidraw"
    summary = "AxiDraw / EiBotBoard H-bot: motor 1 moves x + y, motor 2 x - y (per-motor limits)"

    actuator_names = ("motor1", "motor2")
    actuator_units = "mm"
    linear_map = MOTORS

    Params = AxiDrawParams

    def __init__(self, machine, params: dict[str, Any]):
        super().__init__(machine, params)  # checks the table against AxiDrawParams
        p = self.params
        where = f"{getattr(machine, 'source', '') or getattr(machine, 'name', '') or '<profile>'}: kinematics"
        self.steps_per_mm = p.steps_per_mm
        self.vmax, self.amax = np.array(p.max_velocity), np.array(p.max_acceleration)
        self.pen_accel = p.pen_acceleration
        if self.pen_accel is not None:  # the maker's limit is on the pen's path: rows for it after the motors'
            self.linear_map = np.vstack([MOTORS, POLYGON])
            self.actuator_names = ("motor1", "motor2") + tuple(f"pen {a:g} deg" for a in np.degrees(_ANG))
        top = EBB_MAX_STEP_RATE / self.steps_per_mm
        if (self.vmax > top).any():
            raise MachineError(f"{where}.max_velocity = {self.vmax.max():g} mm/s is above the EiBotBoard's 25000 steps/s "
                               f"({top:g} mm/s at {self.steps_per_mm:g} steps/mm); lower it")
        spm = getattr(machine, "axes", None)
        if spm and any(abs(a.steps_per_mm - self.steps_per_mm) > 1e-9 for a in machine.axes):
            raise MachineError(f"{where}.steps_per_mm = {self.steps_per_mm:g} differs from axes.x.steps_per_mm or axes.y.steps_per_mm; "
                               "the EBB post rounds x and y on the motors' grid, so give them the same value")

    def margin(self) -> float:
        """mm/s of belt that whole-step LMs may add to a motor's rate: 1 step per sample period."""
        return 1.0 / (self.steps_per_mm * float(getattr(self.machine, "delta_time", 0.04)))

    def actuator_limits(self):
        v = self.vmax - self.margin()
        if (v <= 0).any():
            raise MachineError("the axidraw motors' max_velocity is below one step per sample period; raise it")
        if self.pen_accel is None:
            return v, self.amax.copy()
        # the pen rows bound acceleration only (the pen-speed cap and the motors bound speed)
        a_pen = self.pen_accel * np.cos(np.pi / (2 * PEN_DIRECTIONS))
        return (np.concatenate([v, np.full(PEN_DIRECTIONS, 10 * self.vmax.max())]),
                np.concatenate([self.amax, np.full(PEN_DIRECTIONS, a_pen)]))

    def page(self, xy) -> np.ndarray:
        """Work-area points (mm, y up) as the AxiDraw's page coordinates (mm from home, y down)."""
        p = np.asarray(xy, float)
        return np.column_stack([p[:, 0], self.machine.height - p[:, 1]])

    def check_reachable(self, points) -> None:
        check_in_work_area(self.machine, points)  # the H-bot reaches its whole travel
