"""A calibration pattern: rulers to measure steps/mm, rows of rising speed and acceleration.

``doodlecam calibrate`` draws it (README, "Your machine"). All in mm, y up:

* two rulers along the bottom and left edges, ticks every 10 mm (longer every
  50 mm), drawn gently: measure them to correct steps/mm;
* one row per factor f (bottom row first, identified by 1, 2, 3 ... short
  ticks at its left): a straight line that reaches full speed, and a sine
  whose wavelength shrinks from 40 mm to 5 mm, so the pen turns harder and
  harder along it. Each row is planned with the profile's speeds scaled by f
  and its accelerations by f as well, so rows above f = 1 pass the profile on
  purpose: the last row the machine draws cleanly (no lost steps, no ringing,
  the sine's peaks sharp and in place) gives the limits to keep.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterable

import numpy as np

from doodlecam.errors import MachineError, PlanError
from doodlecam.machine import Axis, Machine
from doodlecam.model import Drawing, Job
from doodlecam.plan.travel import make_travels, travel_time_by_law

FACTORS = (0.5, 0.75, 1.0, 1.25, 1.5)
RULER_GAP = 15.0  # mm between the rulers and the rows


@dataclass(frozen=True)
class Row:
    """One row of the pattern: its factor and the limits it was planned with."""

    number: int  # 1 = bottom; the count of ticks at its left
    factor: float
    velocity: float  # mm/s, x axis (the y axis is scaled alike)
    acceleration: float  # mm/s^2, x axis
    duration: float  # s, planned pen-down time of the row


def scaled(machine: Machine, f: float) -> Machine:
    """The profile with every speed and acceleration limit times ``f``."""
    axes = tuple(Axis(a.name, a.steps_per_mm, a.max_velocity * f, a.max_acceleration * f) for a in machine.axes)
    pen = replace(machine.pen, max_speed=None if machine.pen.max_speed is None else machine.pen.max_speed * f)
    travel = None if machine.travel_speed is None else machine.travel_speed * f
    # actuator limits of other kinematics (the five-bar's crank rad/s, rad/s^2) scale alike
    kin = {k: ([x * f for x in v] if isinstance(v, list) else v * f) if k in ("max_velocity", "max_acceleration") else v
           for k, v in machine.kinematics_params.items()}
    return replace(machine, axes=axes, pen=pen, travel_speed=travel, kinematics_params=kin)


def rulers(machine: Machine) -> list[np.ndarray]:
    """Polylines (mm) of the two rulers, each a whole number of centimetres long."""
    x0 = y0 = machine.margin
    lx = 10.0 * np.floor(min(200.0, machine.width - 2 * machine.margin) / 10.0)
    ly = 10.0 * np.floor(min(200.0, machine.height - 2 * machine.margin) / 10.0)
    out = [np.array([[x0, y0], [x0 + lx, y0]]), np.array([[x0, y0], [x0, y0 + ly]])]
    for k in range(1, int(lx // 10) + 1):
        h = 6.0 if k % 5 == 0 else 3.0
        out.append(np.array([[x0 + 10 * k, y0], [x0 + 10 * k, y0 + h]]))
    for k in range(1, int(ly // 10) + 1):
        h = 6.0 if k % 5 == 0 else 3.0
        out.append(np.array([[x0, y0 + 10 * k], [x0 + h, y0 + 10 * k]]))
    return out


def row_polylines(machine: Machine, number: int, count: int) -> list[np.ndarray]:
    """Row ``number`` (1-based) of ``count``: identifying ticks, a straight line, a chirped sine."""
    left = machine.margin + RULER_GAP
    right = machine.width - machine.margin
    bottom = machine.margin + RULER_GAP
    h = (machine.height - machine.margin - bottom) / count
    if right - left < 60.0 or h < 8.0:
        raise MachineError(f"{machine.source}: the work area is too small for {count} calibration rows; "
                           "use fewer --factors")
    y = bottom + (number - 1) * h
    out = [np.array([[left + 2.0 * k, y], [left + 2.0 * k, y + min(4.0, 0.8 * h)]]) for k in range(number)]
    start = left + 2.0 * number + 4.0
    out.append(np.array([[start, y], [right, y]]))
    amp = min(10.0, 0.3 * h)
    x = np.linspace(start, right, max(200, int((right - start) * 8)))
    # wavelength from 40 mm down to 5 mm: the phase integrates 1/wavelength along x
    s = (x - start) / (right - start)
    wavelength = 40.0 * (5.0 / 40.0) ** s
    phase = 2 * np.pi * np.concatenate([[0.0], np.cumsum(np.diff(x) * 0.5 * (1 / wavelength[1:] + 1 / wavelength[:-1]))])
    out.append(np.column_stack([x, y + 0.5 * h + amp * np.sin(phase)]))
    return out


def _join(jobs: list[Job], machine: Machine) -> Job:
    """One job of several planned ones, drawn one after the other from home to home."""
    strokes = tuple(s for j in jobs for s in j.strokes)
    samples = tuple(s for j in jobs for s in j.samples)
    points = [np.asarray(machine.home, float)]
    for s in strokes:
        points += [s.spline.start, s.spline.end]
    points.append(np.asarray(machine.home, float))
    travels = make_travels(points, machine)
    meta = dict(jobs[0].meta)
    for key in ("worst_acceleration_ratio", "worst_velocity_ratio", "max_fit_error_mm", "max_between_samples_mm"):
        meta[key] = max(j.meta[key] for j in jobs)
    for key in ("control_points", "strokes_replanned", "strokes_slowed_for_ramps"):
        meta[key] = sum(j.meta[key] for j in jobs)
    meta["travel_time_by_law"] = travel_time_by_law(travels, machine)
    meta["timings"] = {k: sum(j.meta["timings"].get(k, 0.0) for j in jobs) for k in jobs[0].meta["timings"]}
    return Job(machine=machine, strokes=strokes, travels=travels, samples=samples, source="calibration pattern",
               meta=meta)


def calibration_job(machine: Machine, factors: Iterable[float] = FACTORS, solver: str | None = None,
                    plugin_dirs: Iterable[str] = ()) -> tuple[Job, list[Row]]:
    """The planned pattern and what each row is. The job's machine carries the largest
    factor's limits, so every post accepts the rows that pass the profile."""
    from doodlecam.pipeline import plan_job

    factors = [float(f) for f in factors]
    if not factors or any(not (0.05 <= f <= 4.0) for f in factors):
        raise MachineError(f"calibration factors must lie between 0.05 and 4 (of the profile's limits), got {factors}")
    solver = solver or machine.solver
    dirs = tuple(plugin_dirs)
    gentle = scaled(machine, min(min(factors), 0.5))
    jobs = [plan_job(Drawing(tuple(rulers(machine)), units="mm", source="rulers"), gentle, solver, dirs)]
    rows = []
    for n, f in enumerate(factors, 1):
        m = scaled(machine, f)
        try:
            job = plan_job(Drawing(tuple(row_polylines(machine, n, len(factors))), units="mm", source=f"row {n}"),
                           m, solver, dirs)
        except PlanError as e:
            raise PlanError(f"calibration row {n} (x{f:g}): {e}; or leave that factor out of --factors") from None
        jobs.append(job)
        rows.append(Row(n, f, m.x.max_velocity, m.x.max_acceleration, sum(s.duration for s in job.strokes)))
    return _join(jobs, scaled(machine, max(factors))), rows
