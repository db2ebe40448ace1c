"""Cartesian XY kinematics: each actuator drives one axis directly.

The example to copy for a kinematics plugin. The planner works in actuator
space; for an XY plotter that is the pen position itself (mm), so the map is
the identity and the limits are the profile's per-axis limits. Steps per mm
are applied only at the machine edge (the posts).
"""

import numpy as np

from doodlecam.api import Kinematics
from doodlecam.errors import PlanError


class Cartesian(Kinematics):
    name = "cartesian"
    summary = "XY plotter: one actuator per axis (identity kinematics, per-axis limits)"

    linear_map = np.eye(2)

    def actuator_limits(self):
        m = self.machine
        return (np.array([m.x.max_velocity, m.y.max_velocity]),
                np.array([m.x.max_acceleration, m.y.max_acceleration]))

    def check_reachable(self, points) -> None:
        m = self.machine
        p = np.asarray(points, dtype=float)
        bad = np.flatnonzero((p[:, 0] < -1e-9) | (p[:, 0] > m.width + 1e-9) | (p[:, 1] < -1e-9) | (p[:, 1] > m.height + 1e-9))
        if bad.size:
            x, y = p[bad[0]]
            raise PlanError(f"point ({x:.2f}, {y:.2f}) mm is outside the {m.width:g} x {m.height:g} mm work area of '{m.name}'")
