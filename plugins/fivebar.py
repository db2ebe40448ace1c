"""Kirecci's five-bar planar arm: two cranks on the frame drive a pen at the
joint of two coupler links (thesis "Motion design for high-speed machines",
section 6.5, eq. 6.1-6.10).

Geometry (arm frame, mm)::

                 P (pen)
            a2  / \\  a3
               B   C
           a1 /     \\ a4
             A ----- D
                a0

A is the first crank's pivot at the arm origin, D = (a0, 0) the second's.
Crank a1 turns about A to angle theta1, crank a4 about D to angle theta4
(both from +x, counter-clockwise); couplers a2 = BP and a3 = CP meet at the pen.

Inverse kinematics (eq. 6.1-6.10), one half at a time::

    b = |AP|, theta_b = atan2(y, x), cos beta1 = (b^2 + a1^2 - a2^2) / (2 a1 b)
    theta1 = theta_b + beta1                                   (6.5)
    c = |DP|, theta_c = atan2(y, x - a0), cos beta2 = (c^2 + a4^2 - a3^2) / (2 a4 c)
    theta4 = theta_c - beta2                                   (6.10)

beta = arccos(...) lies in [0, pi], so these signs fix one of the four
assembly modes of the thesis's Fig. 6.6: the "elbows out" mode of Fig. 6.7 (B
to the left of A->P, C to the right of D->P), which the thesis picks for its
better transmission angles. The mode can only change where a crank and its
coupler become collinear (the thesis's condition angle(ABP), angle(PCD) <=
180 deg, i.e. the edge of the workspace, where theta' blows up) or where the
two couplers do (B, P, C collinear: the forward solution branches). Both
show up as a transmission angle near 0 or 180 deg, so the feasibility check
keeps every transmission angle within [mu_min, 180 - mu_min]:

* at B: angle ABP between crank a1 and coupler a2 (torque of crank 1 reaches the pen),
* at C: angle DCP between crank a4 and coupler a3,
* at P: angle BPC between the couplers (signed: negative means the other
  assembly mode).

The pen must also stay above the line through A and D, where this mode's
links do not cross each other or the frame.

Path derivatives (chain rule, for the planner). For one half with crank
vector r = B - A (|r| = a1) and coupler vector d = P - B (|d| = a2), the loop
constraint |P - A - r(theta)|^2 = a2^2 differentiated once and twice along
the path q(u) gives, with s = cross(r, d) (zero exactly when A, B, P are
collinear) and r_perp = (-r_y, r_x)::

    theta'  = d . q' / s                                  (the Jacobian row d / s)
    theta'' = (|q' - theta' r_perp|^2 + d . q'' + theta'^2 d . r) / s

which equals J q'' + (dJ/du) q'. The second half is the same with D, C, a4, a3.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
from pydantic import BeforeValidator, Field

from doodlecam.api import Kinematics
from doodlecam.errors import MachineError, PlanError
from doodlecam.schema import Num, Table

DEFAULT_MIN_TRANSMISSION_DEG = 20.0


def _both(v):
    """One number for both cranks' limit."""
    return [v, v] if isinstance(v, (int, float)) and not isinstance(v, bool) else v


Positive = Annotated[Num, Field(gt=0)]
CrankPair = Annotated[tuple[Positive, Positive], BeforeValidator(_both)]


class FiveBarParams(Table):
    """The [kinematics] table of a five-bar profile (checked on load: doodlecam.schema)."""

    a0: Positive = Field(description="the distance A-D between the crank pivots in mm, e.g. 620")
    a1: Positive = Field(description="the length of crank A-B in mm, e.g. 200")
    a2: Positive = Field(description="the length of coupler B-P in mm, e.g. 544")
    a3: Positive = Field(description="the length of coupler C-P in mm, e.g. 544")
    a4: Positive = Field(description="the length of crank D-C in mm, e.g. 200")
    origin: tuple[Num, Num] = Field(description="pivot A in work-area mm, two numbers [x, y], e.g. [-170, -358]")
    max_velocity: CrankPair = Field(description="[crank 1, crank 4] in rad/s, e.g. [1.5, 1.5] (one number: both)")
    max_acceleration: CrankPair = Field(description="[crank 1, crank 4] in rad/s^2, e.g. [15, 15] (one number: both)")
    min_transmission_angle: Num = Field(DEFAULT_MIN_TRANSMISSION_DEG, gt=0, lt=60,
                                        description="degrees between 0 and 60 (0 would admit the singular poses; "
                                                    "20-40 is usual)")


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return (u * v).sum(axis=-1)


def _perp(u: np.ndarray) -> np.ndarray:
    """u rotated by +90 degrees."""
    return np.stack([-u[..., 1], u[..., 0]], axis=-1)


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Signed angle (rad, in (-pi, pi]) from vector u to vector v."""
    return np.arctan2(_cross(u, v), _dot(u, v))


class FiveBar(Kinematics):
    name = "fivebar"
    summary = "Kirecci's five-bar arm: two cranks drive the pen (closed-form inverse, thesis 6.5)"

    actuator_names = ("theta1", "theta4")
    actuator_units = "rad"
    linear_map = None  # nonlinear: the planner uses derivatives()

    Params = FiveBarParams

    def __init__(self, machine, params: dict[str, Any]):
        super().__init__(machine, params)  # checks the table against FiveBarParams
        p = self.params
        where = f"{getattr(machine, 'source', '') or getattr(machine, 'name', '') or '<profile>'}: kinematics"
        self.a0, self.a1, self.a2, self.a3, self.a4 = p.a0, p.a1, p.a2, p.a3, p.a4
        self.origin, self.vmax, self.amax = (np.array(v, float) for v in (p.origin, p.max_velocity, p.max_acceleration))
        mu = p.min_transmission_angle
        self.min_transmission = math.radians(mu)
        if self.a0 >= self.a1 + self.a2 + self.a3 + self.a4:
            raise MachineError(f"{where}.a0 = {self.a0:g} mm is not shorter than a1 + a2 + a3 + a4 = "
                               f"{self.a1 + self.a2 + self.a3 + self.a4:g} mm, so the arm cannot close; shorten a0 or lengthen the links")
        if not self._workspace_grid().any():
            raise MachineError(f"{where}: links a0..a4 = {self.a0:g}, {self.a1:g}, {self.a2:g}, {self.a3:g}, {self.a4:g} mm leave no "
                               f"point with transmission angles >= {mu:g} deg; change the lengths or lower min_transmission_angle")

    # ------------------------------------------------------------ geometry

    def _local(self, xy) -> np.ndarray:
        """Work-area mm -> arm frame (A at the origin, D at (a0, 0))."""
        return np.atleast_2d(np.asarray(xy, dtype=float)) - self.origin

    def _cos_betas(self, p: np.ndarray):
        """(b, cos beta1, c, cos beta2) of arm-frame points p (eq. 6.1, 6.4, 6.6, 6.9)."""
        b = np.hypot(p[:, 0], p[:, 1])
        c = np.hypot(p[:, 0] - self.a0, p[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            cb1 = (b * b + self.a1**2 - self.a2**2) / (2 * self.a1 * b)
            cb2 = (c * c + self.a4**2 - self.a3**2) / (2 * self.a4 * c)
        return b, np.nan_to_num(cb1, nan=np.inf), c, np.nan_to_num(cb2, nan=np.inf)

    def _joints(self, theta: np.ndarray):
        """Crank vectors r1 = B - A, r4 = C - D and the joints B, C (arm frame)."""
        r1 = self.a1 * np.column_stack([np.cos(theta[:, 0]), np.sin(theta[:, 0])])
        r4 = self.a4 * np.column_stack([np.cos(theta[:, 1]), np.sin(theta[:, 1])])
        return r1, r4, r1, r4 + np.array([self.a0, 0.0])

    def inverse(self, xy) -> np.ndarray:
        """Crank angles (n, 2) = (theta1, theta4) in rad of pen positions (n, 2) mm.

        NaN where a point is out of reach (|cos beta| > 1).
        """
        p = self._local(xy)
        _, cb1, _, cb2 = self._cos_betas(p)
        with np.errstate(invalid="ignore"):
            beta1, beta2 = np.arccos(cb1), np.arccos(cb2)  # NaN outside [-1, 1]
        theta1 = np.arctan2(p[:, 1], p[:, 0]) + beta1  # eq. 6.2, 6.5
        theta4 = np.arctan2(p[:, 1], p[:, 0] - self.a0) - beta2  # eq. 6.7, 6.10
        return np.column_stack([theta1, theta4])

    def _arm(self, p: np.ndarray):
        """Crank vectors r1 = B - A, r4 = C - D and the joints B, C of arm-frame
        pen positions p, without trigonometry: B is AP turned by +beta1 and
        scaled to a1, C is DP turned by -beta2 and scaled to a4 (eq. 6.5, 6.10)."""
        b, cb1, c, cb2 = self._cos_betas(p)
        with np.errstate(invalid="ignore", divide="ignore"):
            sb1, sb2 = np.sqrt(1.0 - cb1 * cb1), np.sqrt(1.0 - cb2 * cb2)  # NaN out of reach
            e1 = p / b[:, None]
            e4 = (p - [self.a0, 0.0]) / c[:, None]
        r1 = self.a1 * (cb1[:, None] * e1 + sb1[:, None] * _perp(e1))
        r4 = self.a4 * (cb2[:, None] * e4 - sb2[:, None] * _perp(e4))
        return r1, r4, r1, r4 + np.array([self.a0, 0.0])

    def forward(self, theta) -> np.ndarray:
        """Pen positions (n, 2) mm of crank angles (n, 2) rad, in the same mode.

        The pen is where the circles of radius a2 about B and a3 about C meet,
        on the left of B->C (the branch of the elbows-out mode). NaN where the
        circles do not meet.
        """
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        _, _, B, C = self._joints(theta)
        bc = C - B
        d = np.hypot(bc[:, 0], bc[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            along = (self.a2**2 - self.a3**2 + d * d) / (2 * d)
            h = np.sqrt(self.a2**2 - along**2)  # NaN: the couplers cannot meet
            e = bc / d[:, None]
        p = B + along[:, None] * e + h[:, None] * _perp(e)
        return p + self.origin

    def jacobian(self, xy) -> np.ndarray:
        """d theta / d xy (n, 2, 2) in rad/mm; rows d / cross(r, d) per half."""
        p = self._local(xy)
        r1, r4, B, C = self._arm(p)
        d1, d4 = p - B, p - C
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.stack([d1 / _cross(r1, d1)[:, None], d4 / _cross(r4, d4)[:, None]], axis=1)

    def derivatives(self, q, dq, ddq):
        """(theta, theta', theta'') (each (n, 2), rad per u^k) along a pen path
        with positions q (mm) and path derivatives q', q'' (mm/u, mm/u^2).

        theta' = J q', theta'' = J q'' + (dJ/du) q' (closed form, see the module doc).
        The parameter u can be anything, time included.
        """
        q, dq, ddq = (np.atleast_2d(np.asarray(a, dtype=float)) for a in (q, dq, ddq))
        theta = self.inverse(q)
        p = self._local(q)
        r1, r4, B, C = self._arm(p)
        d1_out, d2_out = [], []
        for r, joint in ((r1, B), (r4, C)):
            d = p - joint
            with np.errstate(divide="ignore", invalid="ignore"):
                s = _cross(r, d)
                t1 = _dot(d, dq) / s
                dd = dq - t1[:, None] * _perp(r)  # d(d)/du
                t2 = (_dot(dd, dd) + _dot(d, ddq) + t1 * t1 * _dot(d, r)) / s
            d1_out.append(t1)
            d2_out.append(t2)
        return theta, np.column_stack(d1_out), np.column_stack(d2_out)

    def actuator_limits(self):
        return self.vmax.copy(), self.amax.copy()

    # ------------------------------------------------------------ feasibility

    def transmission_angles(self, xy) -> np.ndarray:
        """Angles (n, 3) in rad at B (crank a1 / coupler a2), C (crank a4 /
        coupler a3) and P (between the couplers, signed: < 0 in the other
        assembly mode). NaN where out of reach."""
        p = self._local(xy)
        r1, r4, B, C = self._arm(p)
        at_b = np.abs(_angle(-r1, p - B))  # angle ABP
        at_c = np.abs(_angle(-r4, p - C))  # angle DCP
        at_p = _angle(B - p, C - p)  # angle BPC, > 0 when P is left of B->C
        return np.column_stack([at_b, at_c, at_p])

    def _problems(self, xy) -> np.ndarray:
        """Per point, the code of the first failed check (0 = fine)."""
        p = self._local(xy)
        _, cb1, _, cb2 = self._cos_betas(p)
        mu = self.transmission_angles(xy)
        lo, hi = self.min_transmission, math.pi - self.min_transmission
        slack = 1e-12
        checks = [
            p[:, 1] <= 0.0,  # 1: at or below the base line A-D
            cb1 > 1.0,  # 2: too far from A (or too close, if a1 > a2)
            cb1 < -1.0,  # 3: too close to A
            cb2 > 1.0,  # 4
            cb2 < -1.0,  # 5
            (mu[:, 0] < lo - slack) | (mu[:, 0] > hi + slack),  # 6: crank 1 near collinear
            (mu[:, 1] < lo - slack) | (mu[:, 1] > hi + slack),  # 7: crank 4 near collinear
            (mu[:, 2] < lo - slack) | (mu[:, 2] > hi + slack),  # 8: couplers near collinear / other mode
        ]
        code = np.zeros(len(p), dtype=int)
        for k in range(len(checks) - 1, -1, -1):  # the lowest failing code wins
            code = np.where(checks[k], k + 1, code)
        return code

    def _workspace_grid(self, n: int = 161) -> np.ndarray:
        """Feasible arm-frame points on a grid over the reach (for validating params)."""
        reach = max(self.a1 + self.a2, self.a3 + self.a4)
        xs = np.linspace(-reach, self.a0 + reach, n)
        ys = np.linspace(0.0, reach, n // 2)[1:]
        g = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
        return self._problems(g + self.origin) == 0

    def feasible(self, points) -> np.ndarray:
        """Boolean mask: which pen positions (mm) pass every check."""
        p = np.atleast_2d(np.asarray(points, dtype=float))
        return self._problems(p) == 0

    def check_reachable(self, points) -> None:
        """Raise PlanError naming the first point the arm cannot reach safely."""
        p = np.atleast_2d(np.asarray(points, dtype=float))
        if p.size == 0:
            return
        code = self._problems(p)
        bad = np.flatnonzero(code)
        if not bad.size:
            return
        i = int(bad[0])
        x, y = p[i]
        local = self._local(p[i])
        b, _, c, _ = self._cos_betas(local)
        mu = np.degrees(self.transmission_angles(p[i])[0])
        mn = math.degrees(self.min_transmission)
        reasons = {
            1: "is not above the line through the crank pivots, where this arm works",
            2: f"is out of reach of crank a1 and coupler a2 (|AP| = {b[0]:.1f} mm, needs {abs(self.a2 - self.a1):.1f} to {self.a1 + self.a2:.1f})",
            3: f"is too close to pivot A (|AP| = {b[0]:.1f} mm, needs at least {self.a2 - self.a1:.1f})",
            4: f"is out of reach of crank a4 and coupler a3 (|DP| = {c[0]:.1f} mm, needs {abs(self.a3 - self.a4):.1f} to {self.a3 + self.a4:.1f})",
            5: f"is too close to pivot D (|DP| = {c[0]:.1f} mm, needs at least {self.a3 - self.a4:.1f})",
            6: f"puts crank a1 and coupler a2 near collinear (transmission angle {mu[0]:.1f} deg, limit {mn:g} to {180 - mn:g})",
            7: f"puts crank a4 and coupler a3 near collinear (transmission angle {mu[1]:.1f} deg, limit {mn:g} to {180 - mn:g})",
            8: f"puts the couplers near collinear (angle BPC {mu[2]:.1f} deg, limit {mn:g} to {180 - mn:g})",
        }
        name = getattr(self.machine, "name", "") or "fivebar"
        raise PlanError(f"point ({x:.2f}, {y:.2f}) mm {reasons[int(code[i])]} on five-bar '{name}'; "
                        f"keep the drawing inside the arm's workspace (smaller work area, or move [kinematics] origin)")
