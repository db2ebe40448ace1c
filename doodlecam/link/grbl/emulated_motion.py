"""GRBL 1.1's motion timing for the emulator: the look-ahead planner of planner.c and the stepper's profiles.

Written from reading the firmware (planner.c, stepper.c), not copied. What GRBL does and this keeps:

* a block's target is rounded to whole steps (``lround``); its direction, length and the junction with the
  previous block come from the rounded deltas, so a half step turns a short chord's junction;
* nominal speed F (times the feed override, at most the axis-limited rapid rate) or the rapid rate (times
  the rapid override); acceleration and rapid rate limited per axis along the block's direction;
* junction speed from the junction deviation ($11); entry speed at most both blocks' nominal speeds;
* the planner ring holds 15 blocks; after each new block a backward pass (the last block ends at rest)
  then a forward pass from the last optimally planned block (``block_buffer_planned``);
* the executing block runs a trapezoid from its current speed to the next block's entry speed, re-planned
  whenever the planner changes that exit (``st_update_plan_block_parameters``); a feed hold decelerates
  at each block's acceleration, and a resume or an override change re-plans everything from the head.

Stepper segments (10 ms) and the segment buffer's lead are not modelled: time is continuous. Units: mm, s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

SOME_LARGE_VALUE = 1.0e38
MINIMUM_FEED_RATE = 1.0 / 60.0  # mm/s (config.h: 1 mm/min)
BLOCKS = 15  # BLOCK_BUFFER_SIZE 16, one slot always empty


def lround(x: float) -> int:
    """C's lround: to the nearest integer, halves away from zero."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def _axis_limit(limits, unit) -> float:
    """limit_value_by_axis_maximum: the largest value along ``unit`` that keeps every axis within its limit."""
    return min((lim / abs(u) for lim, u in zip(limits, unit) if u), default=SOME_LARGE_VALUE)


@dataclass
class Block:
    start: tuple[float, float, float]  # mm, on whole steps
    end: tuple[float, float, float]
    unit: tuple[float, float, float]
    length: float  # mm
    acceleration: float  # mm/s²
    rapid_rate: float  # mm/s
    programmed_rate: float  # mm/s
    rapid: bool
    no_override: bool  # jog and probe moves ignore the feed override
    line: int
    max_junction_sqr: float = 0.0
    max_entry_sqr: float = 0.0
    entry_sqr: float = 0.0
    millimeters: float = 0.0  # still to go

    def position(self) -> list[float]:
        done = self.length - self.millimeters
        return [a + u * done for a, u in zip(self.start, self.unit)]


class Planner:
    """The planner ring (``blocks[0]`` executes) and the executing block's speed."""

    def __init__(self, settings: dict):
        self.settings = settings  # the emulator's $ settings, read live
        self.blocks: list[Block] = []
        self.feed_override = 100
        self.rapid_override = 100
        self.reset([0.0, 0.0, 0.0])

    def reset(self, position) -> None:
        """plan_reset + plan_sync_position: an empty ring, the planner at ``position`` (mm)."""
        self.blocks.clear()
        self.planned = 0
        self.speed = 0.0
        self.holding = False
        spm = self._steps_per_mm()
        self.steps = [lround(p * s) for p, s in zip(position, spm)]
        self.prev_unit = (0.0, 0.0, 0.0)
        self.prev_nominal = 0.0

    def _steps_per_mm(self):
        return [float(self.settings[100 + i]) for i in range(3)]

    def free(self) -> int:
        return BLOCKS - len(self.blocks)

    def nominal(self, b: Block) -> float:
        """plan_compute_profile_nominal_speed (mm/s)."""
        if b.rapid:
            v = b.programmed_rate * 0.01 * self.rapid_override
        else:
            v = b.programmed_rate if b.no_override else b.programmed_rate * 0.01 * self.feed_override
            v = min(v, b.rapid_rate)
        return max(v, MINIMUM_FEED_RATE)

    def add(self, target, rate: float, rapid: bool = False, inverse_time: bool = False, no_override: bool = False,
            line: int = 0) -> bool:
        """plan_buffer_line: a block to ``target`` (machine mm) at ``rate`` (mm/min, or 1/min in inverse time);
        False for a block of no whole step, which GRBL drops."""
        spm = self._steps_per_mm()
        target_steps = [lround(t * s) for t, s in zip(target, spm)]
        delta = [(t - p) / s for t, p, s in zip(target_steps, self.steps, spm)]
        if target_steps == self.steps:
            return False
        length = math.sqrt(sum(d * d for d in delta))
        unit = tuple(d / length for d in delta)
        accel = _axis_limit([float(self.settings[120 + i]) for i in range(3)], unit)
        rapid_rate = _axis_limit([float(self.settings[110 + i]) / 60.0 for i in range(3)], unit)
        programmed = rapid_rate if rapid else (rate * length if inverse_time else rate) / 60.0
        start = tuple(p / s for p, s in zip(self.steps, spm))
        end = tuple(t / s for t, s in zip(target_steps, spm))
        b = Block(start, end, unit, length, accel, rapid_rate, programmed, rapid, no_override, line,
                  millimeters=length)
        if not self.blocks:
            b.max_junction_sqr = 0.0  # from rest
        else:
            cos_theta = -sum(p * u for p, u in zip(self.prev_unit, unit))
            if cos_theta > 0.999999:  # a reversal: stop
                b.max_junction_sqr = 0.0
            elif cos_theta < -0.999999:  # straight on
                b.max_junction_sqr = SOME_LARGE_VALUE
            else:
                ju = [u - p for u, p in zip(unit, self.prev_unit)]
                jn = math.sqrt(sum(x * x for x in ju))
                ja = _axis_limit([float(self.settings[120 + i]) for i in range(3)], [x / jn for x in ju])
                sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
                b.max_junction_sqr = max(0.0, ja * float(self.settings[11]) * sin_half / (1.0 - sin_half))
        nominal = self.nominal(b)
        b.max_entry_sqr = min(min(nominal, self.prev_nominal) ** 2, b.max_junction_sqr)
        self.prev_nominal, self.prev_unit, self.steps = nominal, unit, target_steps
        self.blocks.append(b)
        self._recalculate()
        return True

    def _recalculate(self) -> None:
        """planner_recalculate: backward pass down to the planned block, forward pass from it."""
        blocks, last = self.blocks, len(self.blocks) - 1
        if last <= self.planned:
            return
        self._sync_head()
        cur = blocks[last]
        cur.entry_sqr = min(cur.max_entry_sqr, 2 * cur.acceleration * cur.millimeters)
        for i in range(last - 1, self.planned, -1):
            nxt, cur = cur, blocks[i]
            if cur.entry_sqr != cur.max_entry_sqr:
                cur.entry_sqr = min(cur.max_entry_sqr, nxt.entry_sqr + 2 * cur.acceleration * cur.millimeters)
        nxt = blocks[self.planned]
        for i in range(self.planned + 1, last + 1):
            cur, nxt = nxt, blocks[i]
            if cur.entry_sqr < nxt.entry_sqr:
                reach = cur.entry_sqr + 2 * cur.acceleration * cur.millimeters
                if reach < nxt.entry_sqr:
                    nxt.entry_sqr = reach
                    self.planned = i
            if nxt.entry_sqr == nxt.max_entry_sqr:
                self.planned = i

    def _sync_head(self) -> None:
        """The executing block enters at its current speed over what is left of it (st_update_plan_block_parameters)."""
        if self.blocks:
            self.blocks[0].entry_sqr = self.speed * self.speed

    def replan(self) -> None:
        """plan_update_velocity_profile_parameters + plan_cycle_reinitialize (override change, resume)."""
        prev = SOME_LARGE_VALUE
        for b in self.blocks:
            nominal = self.nominal(b)
            b.max_entry_sqr = min(min(nominal, prev) ** 2, b.max_junction_sqr)
            prev = nominal
        if self.blocks:
            self.prev_nominal = prev
        self.planned = 0
        self._recalculate()

    def hold(self) -> None:
        self.holding = True

    def resume(self) -> None:
        self.holding = False
        self.replan()

    # ------------------------------------------------------------ execution

    def _phases(self, b: Block) -> list[tuple[float, float, float]]:
        """What is left of the executing block as (length, speed at start, speed at end), constant
        acceleration in each: the profile stepper.c builds from the current speed."""
        v, rem, a = self.speed, b.millimeters, b.acceleration
        if self.holding:  # forced deceleration to rest, into the next blocks if need be
            stop = v * v / (2 * a)
            if stop >= rem:
                return [(rem, v, math.sqrt(max(v * v - 2 * a * rem, 0.0)))]
            return [(stop, v, 0.0)]
        exit_sqr = self.blocks[1].entry_sqr if len(self.blocks) > 1 else 0.0
        ve = math.sqrt(exit_sqr)
        vn = self.nominal(b)
        if v > vn:  # an override reduced the speed: decelerate to it, then as usual
            down = (v * v - vn * vn) / (2 * a)
            if down >= rem:
                return [(rem, v, math.sqrt(max(v * v - 2 * a * rem, 0.0)))]
            tail = max(rem - down - (vn * vn - exit_sqr) / (2 * a), 0.0)
            return [(down, v, vn), (tail, vn, vn), (rem - down - tail, vn, ve)]
        inter = 0.5 * (rem + (v * v - exit_sqr) / (2 * a))  # where accelerating meets decelerating, from the end
        if inter <= 0.0:  # accelerating all along (to the exit speed)
            return [(rem, v, ve)]
        if inter >= rem:  # decelerating all along
            return [(rem, v, ve)]
        decel = (vn * vn - exit_sqr) / (2 * a)
        if decel < inter:  # trapezoid
            accel = (vn * vn - v * v) / (2 * a)
            return [(accel, v, vn), (rem - accel - decel, vn, vn), (decel, vn, ve)]
        peak = math.sqrt(2 * a * inter + exit_sqr)
        return [(rem - inter, v, peak), (inter, peak, ve)]

    def advance(self, dt: float) -> tuple[float, Block | None]:
        """Run for up to ``dt`` s; returns (time left over, the block that finished or None). Stops early
        when a block ends (the planner has room) or when a hold reaches rest."""
        if not self.blocks or dt <= 0:
            return dt, None
        if self.holding and self.speed <= 0.0:
            return dt, None
        b = self.blocks[0]
        for length, v0, v1 in self._phases(b):
            if length <= 0.0:
                continue
            t = length / v0 if v0 == v1 else 2.0 * length / (v0 + v1)
            if dt < t:
                acc = (v1 * v1 - v0 * v0) / (2 * length)
                b.millimeters -= min(v0 * dt + 0.5 * acc * dt * dt, length)
                self.speed = max(v0 + acc * dt, 0.0)
                return 0.0, None
            dt -= t
            b.millimeters -= length
            self.speed = v1
            if self.holding and v1 <= 0.0 and b.millimeters > 1e-9:
                return dt, None  # at rest inside the block: the hold is complete
        done = self.blocks.pop(0)
        self.planned = max(self.planned - 1, 0)
        if self.blocks:  # the next block starts at the speed this one ended with
            self.blocks[0].entry_sqr = self.speed * self.speed
        else:
            self.speed = 0.0
        return dt, done

    @property
    def position(self) -> list[float] | None:
        """Where the executing block has got to (mm), None with an empty ring."""
        return self.blocks[0].position() if self.blocks else None
