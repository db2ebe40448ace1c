"""Cartesian XY kinematics: each actuator drives one axis directly.

The example to copy for a kinematics plugin. The planner works in actuator
space; for an XY plotter that is the pen position itself (mm), so the map is
the identity and the limits are the profile's per-axis limits. Steps per mm
are applied only at the machine edge (the posts).
"""

import numpy as np

from doodlecam.api import Kinematics, check_in_work_area


class Cartesian(Kinematics):
    name = "cartesian"
    summary = "XY plotter: one actuator per axis (identity kinematics, per-axis limits)"

    linear_map = np.eye(2)

    def actuator_limits(self):
        m = self.machine
        return (np.array([m.x.max_velocity, m.y.max_velocity]),
                np.array([m.x.max_acceleration, m.y.max_acceleration]))

    def check_reachable(self, points) -> None:
        check_in_work_area(self.machine, points)  # every point of the work area is reachable
