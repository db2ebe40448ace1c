"""A planned job as the EiBotBoard's command stream (the ``.ebb`` file), one command per line.

Per stroke the planner's velocity samples (docs/formats.md: linear ramps over each
period dT) become one ``LM`` per period: on each motor a constant acceleration from
the period's start rate to its end rate, an exact whole number of steps. The motor
positions at the sample instants are the planned positions rounded to whole steps
(the running sum, as for the PLC), so nothing drifts and every stroke ends on its
last step exactly. Rounding moves a period's mean rate by (rounding now - rounding
before) / dT, at most 1 step / dT: the period's start and end rates are both shifted
by that, so its acceleration stays the plan's. A period in which a motor reverses is one
LM whose rate runs through zero: firmware 3.0 turns the motor back mid-move (board.axis_move,
turn_params); with ``firmware=2.7`` (older boards roll a negative rate over) it is split at the
reversal. So on 3.0 a stroke never has more commands than periods. Pen-up travel is a straight
trapezoid (accelerate, cruise, decelerate: three LMs) within the profile's pen-up
limits. Every LM clears the accumulators (Clear = 3), so each LM ends on the tick its
last step is due and the stream's time is known exactly (doodlecam.link.ebb.board).

Lines: ``; key: value`` header comments, board commands (EM, SC, SP, LM, SM), and the
host directive ``@PAUSE,<pen>`` (a pen change: the sender waits for the operator; it
is never sent to the board). docs/ebb.md describes the format.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from doodlecam.errors import OutputError
from doodlecam.link.ebb.board import ACC, TICK_HZ, accumulated, axis_move, trunc_half

FORMAT = 1
MAX_RATE = ACC - 1  # one step per tick
# A motor that turns back by at most this many steps inside a period is not split there (an LM
# turns each motor one way): it moves straight from its rounded start to its rounded end, at most
# this plus half a step from the plan mid-period (0.02 mm at 80 steps/mm).
TURN_STEPS = 1.0
CRUISE_MIN_S = 0.04  # a travel's constant-speed LM lasts at least this long (or is left out)
# Consecutive periods whose ramps one LM reproduces (every instant within half a step of the plan,
# on the board's arithmetic) are sent as one LM, up to this many (a stop waits for at most that).
MERGE_MAX = 8
BULGE_STEPS = 0.25  # ... and stray at most this far from the plan's ramps between the instants
TO_PEN = np.array([[0.5, 0.5], [0.5, -0.5]])  # motor steps -> pen steps on the page


@dataclass
class Counter:
    """What the writer has emitted: time (s) split by kind, and the motor position (steps)."""

    pos: np.ndarray = field(default_factory=lambda: np.zeros(2, dtype=np.int64))
    draw_s: float = 0.0
    travel_s: float = 0.0
    pen_s: float = 0.0
    lm: int = 0
    draw_lm: int = 0


def axis_params(n: int, vs: float, ve: float, ticks: int) -> tuple[int, int, int]:
    """(Rate, Steps, Accel) for one axis moving ``n`` steps in ``ticks`` ticks, from about ``vs`` to ``ve``
    steps/s (signed). Both rates are shifted equally so the mean is n / time; a rate that would turn
    negative is clamped at zero with the other end taking the difference."""
    if n == 0:
        return 0, 0, 0
    sign = 1 if n > 0 else -1
    m = abs(n)
    s, e = vs * sign, ve * sign
    mean = m * TICK_HZ / ticks
    shift = mean - 0.5 * (s + e)
    s, e = s + shift, e + shift
    if s < 0:
        s, e = 0.0, 2 * mean
    elif e < 0:
        s, e = 2 * mean, 0.0
    k = ACC / TICK_HZ  # accumulator units per tick, per step/s
    # keep the rate >= 1 at both ends: accel within [lo, hi] (rates ~ mean +- accel (T - 1) / 2)
    mu = m * ACC / ticks
    span = max(ticks - 1, 1) / 2
    a = int((e - s) * k / ticks)
    a = max(min(a, int((mu - 2) / span) - 1), -int((mu - 2) / span) + 1) if ticks > 1 else 0
    for _ in range(64):
        h = trunc_half(a)
        need = m * ACC - a * ticks * (ticks + 1) // 2
        rate = h + -(-need // ticks)
        r1, rt = rate - h + a, rate - h + a * ticks
        if r1 >= 1 and rt >= 1:
            break
        a += 1 if rt < 1 else -1
    else:  # pragma: no cover - the clamp above makes this unreachable
        raise OutputError("cannot express a move as an LM; report this job")
    if max(r1, rt) > MAX_RATE:
        raise OutputError(f"a move needs {max(r1, rt) / k:.0f} steps/s, above the EiBotBoard's 25000; lower the "
                          "profile's limits")
    return rate, sign * m, a


def turn_params(n: int, vs: float, ve: float, ticks: int, frac: float | None = None) -> tuple[int, int, int] | None:
    """(Rate, Steps, Accel) for one axis that turns back inside an LM (firmware 2.9+, board.axis_move
    turn=True): a constant acceleration from about ``vs`` through zero to about ``ve`` steps/s (opposite
    signs), ``n`` steps net, Steps counting the steps out and back. With ``frac`` None its last step falls
    on tick ``ticks`` (it sets the LM's length); else the other axis does, and the accumulator ends where
    the plan does, ``frac`` (planned - whole end position, steps) from the middle of its step, so the rates
    move by at most about 1 step over the LM, as an LM that keeps its direction. None where the whole ticks
    leave no such move (the period is then split at the turn)."""
    T = ticks
    a = int((ve - vs) * (ACC / TICK_HZ) / T)  # towards zero: never more than the plan's acceleration
    if a == 0 or T < 2:
        return None
    q1, q0 = a * T * (T + 1) // 2, a * (T - 1) * T // 2  # C_T, C_T-1 less c0 + t r0
    for c0 in (0, ACC - 1):  # cleared to 2^31 - 1 when the first tick's rate is negative
        if frac is not None:  # C_T in cell n, where the plan is: (n + 1/2 + frac) 2^31
            goal = int((n + 0.5 + min(max(frac, -0.45), 0.45)) * ACC)
            lo = hi = round((goal - c0 - q1) / T)
        elif ve > 0:  # the last step on tick T: C_T-1 < n 2^31 <= C_T
            lo, hi = -((c0 + q1 - n * ACC) // T), -((c0 + q0 - n * ACC) // (T - 1)) - 1
        else:  # C_T < (n + 1) 2^31 <= C_T-1
            lo, hi = -((c0 + q0 - (n + 1) * ACC) // (T - 1)), -((c0 + q1 - (n + 1) * ACC) // T) - 1
        if lo > hi:
            continue
        r0 = (lo + hi) // 2
        r1, rt = r0 + a, r0 + a * T
        if (c0 > 0) != (r1 < 0) or (r1 > 0) == (rt > 0) or max(abs(r1), abs(rt)) > MAX_RATE:
            continue
        at = [(c0 + t * r0 + a * t * (t + 1) // 2) // ACC for t in (-r0 // a, T)]
        steps = abs(at[0]) + abs(at[1] - at[0])
        rate = r0 + trunc_half(a)
        params = (-rate, -steps, -a) if c0 else (rate, steps, a)  # Steps' sign: the first direction
        if steps and params[0] >= 0:
            took, pos, _ = axis_move(*params)
            if pos == n and (took == T if frac is None else took <= T):
                return params
    return None


class _Split(Exception):
    """An LM cannot turn a motor back in this period as planned: split it there."""

    def __init__(self, period: int):
        self.period = period


def segment(ticks: int, n, vs, ve, turning=(False, False), frac=(0.0, 0.0)) -> tuple[str, int]:
    """One LM (or a timed wait when neither motor steps) and the ticks it really lasts; an axis in
    ``turning`` turns back inside it (turn_params; None raises _Split). ``frac``: planned - whole end
    position of each axis (steps), where a turning axis aims when the other one sets the LM's length."""
    if n[0] == 0 and n[1] == 0 and not any(turning):
        ms = max(1, round(ticks / 25))
        return f"SM,{ms},0,0", ms * 25
    p = []
    for i in range(2):
        q = None
        if turning[i]:
            # the other axis keeps its direction and moves: its last step ends the LM on its tick
            if not turning[1 - i] and n[1 - i] != 0:
                q = turn_params(int(n[i]), vs[i], ve[i], ticks, float(frac[i]))
            q = q or turn_params(int(n[i]), vs[i], ve[i], ticks)
            if q is None:
                raise _Split(-1)
        p.append(q or axis_params(int(n[i]), vs[i], ve[i], ticks))
    took = max(axis_move(*p[0])[0], axis_move(*p[1])[0])
    return "LM,{},{},{},{},{},{},3".format(*p[0], *p[1]), took


def _ramp_lines(pos0: np.ndarray, times: np.ndarray, vel: np.ndarray, end: np.ndarray | None, out: list[str],
                c: Counter, caps=None, merge: bool = True, turn: bool = False) -> int:
    """LMs for a motion whose motor velocities (steps/s, (N + 1, 2)) ramp linearly between
    instants ``times`` (s, N + 1); ``pos0`` integer start; ``end`` the exact integer end (or None).
    A motor that reverses inside a period turns back inside its LM (``turn``: firmware 2.9+), or the
    period is split there. Returns the ticks executed."""
    split: set[int] = set()
    while True:
        lines: list[str] = []
        try:
            total, c.pos = _ramp_try(pos0, times, vel, end, lines, caps, merge, turn, split)
        except _Split as e:
            split.add(e.period)
            continue
        out.extend(lines)
        c.lm += sum(line.startswith("LM") for line in lines)
        return total


def _ramp_try(pos0, times, vel, end, out, caps, merge, turn, split) -> tuple[int, np.ndarray]:
    # split points: where a motor's ramp crosses zero inside a period and it really turns there,
    # a whole step each way (a motor that turns within a step moves one way in whole steps)
    inc = 0.5 * np.diff(times)[:, None] * (vel[1:] + vel[:-1])
    at = pos0[None, :] + np.vstack([np.zeros((1, 2)), np.cumsum(inc, axis=0)])
    t_all, v_all, turns, period = [times[0]], [vel[0]], [(False, False)], [-1]
    for j in range(1, len(times)):
        t0, t1, v0, v1 = times[j - 1], times[j], vel[j - 1], vel[j]
        cuts, turning = [], [False, False]
        for i in range(2):
            if v0[i] * v1[i] < 0:
                f = float(v0[i] / (v0[i] - v1[i]))
                h = t1 - t0
                peak = at[j - 1, i] + v0[i] * f * h + (v1[i] - v0[i]) * f * f * h / 2
                # within TURN_STEPS of both ends the motor skips the turn: one way, in whole steps
                if min(abs(peak - at[j - 1, i]), abs(peak - at[j, i])) > TURN_STEPS and 1e-6 < f < 1 - 1e-6:
                    if turn and j not in split:
                        turning[i] = True
                    else:
                        cuts.append(f)
        for f in sorted(set(cuts)):
            t_all.append(t0 + f * (t1 - t0))
            v_all.append(v0 + f * (v1 - v0))
            turns.append((False, False))
            period.append(j)
        t_all.append(t1)
        v_all.append(v1)
        turns.append(tuple(turning))
        period.append(j)
    # integer ticks for every instant (shared by both motors); the velocities at a split's whole tick are
    # the period's ramp there, so every piece keeps the period's acceleration
    tick = np.round(np.asarray(t_all) * TICK_HZ).astype(np.int64)
    keep = np.concatenate([[True], np.diff(tick) > 0])
    keep[-1] = True
    tick = tick[keep]
    turns = [x for x, k in zip(turns, keep) if k]
    period = [x for x, k in zip(period, keep) if k]
    if len(tick) > 1 and tick[-1] <= tick[-2]:
        tick[-1] = tick[-2] + 1
    t = tick / TICK_HZ
    base = np.round(times * TICK_HZ) / TICK_HZ
    v = np.column_stack([np.interp(t, base, vel[:, i]) for i in range(2)])
    dt = np.diff(t)
    inc = 0.5 * dt[:, None] * (v[1:] + v[:-1])
    planned = pos0[None, :] + np.vstack([np.zeros((1, 2)), np.cumsum(inc, axis=0)])
    whole = np.round(planned).astype(np.int64)
    whole[0] = pos0
    if end is not None:
        if np.abs(planned[-1] - end).max() > 0.5 + 1e-6:
            raise OutputError("a stroke's samples do not end on its last point; re-plan the job")
        whole[-1] = end
    total = 0
    j = 0
    last = len(tick) - 1
    while j < last:
        # one LM over as many instants as keep every instant inside it within half a step of the plan
        b = j + 1
        while merge and b < last and b - j < MERGE_MAX and _holds(tick, whole, planned, v, j, b + 1, caps):
            b += 1
        try:
            line, took = segment(int(tick[b] - tick[j]), whole[b] - whole[j], v[j], v[b],
                                 turns[b] if b == j + 1 else (False, False), planned[b] - whole[b])
        except _Split:
            raise _Split(period[b]) from None
        if any(turns[b]) and b == j + 1 and caps is not None and not _within_caps(line, caps):
            raise _Split(period[b])
        out.append(line)
        total += took
        j = b
    return total, whole[-1].copy()


def _within_caps(line: str, caps) -> bool:
    """Whether an LM's rates on its first and last ticks keep the motors' and the pen's caps (steps/s);
    its rates are linear in between, so it keeps them throughout."""
    p = [int(x) for x in line.split(",")[1:7]]
    ends = np.zeros((2, 2))
    for i, (rate, steps, accel) in enumerate((p[0:3], p[3:6])):
        if steps:
            t = axis_move(rate, steps, accel)[0]
            sign = -1 if steps < 0 else 1  # the legacy form: the firmware flips Rate and Accel
            r0 = rate - trunc_half(accel)
            ends[:, i] = [sign * (r0 + accel) * TICK_HZ / ACC, sign * (r0 + accel * t) * TICK_HZ / ACC]
    for end in ends:
        if (np.abs(end) > caps[1]).any() or (caps[0] is not None and np.hypot(*(TO_PEN @ end)) > caps[0]):
            return False
    return True


def _holds(tick, whole, planned, v, a: int, b: int, caps=None) -> bool:
    """Whether one LM from instant a to instant b (the whole steps between them, the ramp's end rates)
    passes every instant in between within half a step of the planned position, on the board's
    arithmetic; turns each motor one way; and shifts its rates by at most 1 step over its length."""
    n = whole[b] - whole[a]
    T = int(tick[b] - tick[a])
    # between the instants the merged ramp must not bulge away from the planned one: a constant
    # acceleration differing by da over h strays by up to da h^2 / 8
    h = np.diff(tick[a:b + 1]) / TICK_HZ
    acc_plan = np.diff(v[a:b + 1], axis=0) / h[:, None]
    acc_lm = (v[b] - v[a]) / (T / TICK_HZ)
    if (np.abs(acc_plan - acc_lm) * (h ** 2)[:, None] / 8 > BULGE_STEPS).any():
        return False
    if caps is not None:  # the rates the shift gives at both ends keep the bounds one period has
        shift = n * TICK_HZ / T - 0.5 * (v[a] + v[b])
        for end in (v[a] + shift, v[b] + shift):
            if (np.abs(end) > caps[1]).any() or (caps[0] is not None and np.hypot(*(TO_PEN @ end)) > caps[0]):
                return False
    for i in range(2):
        if v[a, i] * v[b, i] < 0 or any(v[k, i] * v[a, i] < 0 or v[k, i] * v[b, i] < 0 for k in range(a + 1, b)):
            return False
        try:
            rate, steps, accel = axis_params(int(n[i]), v[a, i], v[b, i], T)
        except OutputError:  # faster than the board steps: not as one LM
            return False
        for k in range(a + 1, b):
            t = int(tick[k] - tick[a])
            done = 0 if steps == 0 else min(accumulated(0, rate, accel, t) // ACC, abs(steps))
            pos = whole[a, i] + (done if steps >= 0 else -done)
            if abs(pos - planned[k, i]) > 0.5:
                return False
    return True


class EbbWriter:
    """Builds the command lines of a job for an axidraw-kinematics machine."""

    def __init__(self, machine, kinematics, servo_up: int, servo_down: int, rate_up: int = 0, rate_down: int = 0,
                 turn: bool = True):
        self.m = machine
        self.turn = turn  # firmware 3.0: a motor turns back inside an LM
        self.kin = kinematics
        self.k = float(kinematics.steps_per_mm)
        self.M = np.asarray(kinematics.linear_map, float)[:2]  # the motors' rows (more may bound the pen)
        self.servo = (servo_up, servo_down, rate_up, rate_down)
        self.c = Counter()
        self.lines: list[str] = []
        # pen-up travel: path speed and acceleration from [travel] / [axes]; motors below 25000 steps/s
        m = machine
        self.travel_v = min(m.travel_speed or m.x.max_velocity, m.x.max_velocity, m.y.max_velocity)
        self.travel_a = min(m.x.max_acceleration, m.y.max_acceleration)
        self.motor_v = 24900.0 / self.k

    def motor(self, xy) -> np.ndarray:
        """Motor positions (whole steps from the home corner) of work-area points (mm)."""
        page = self.kin.page(np.atleast_2d(xy))
        th = np.column_stack([page[:, 0] + page[:, 1], page[:, 0] - page[:, 1]])
        return np.round(th * self.k).astype(np.int64)

    def pen(self, down: bool, delay_s: float) -> None:
        ms = max(1, int(math.ceil(delay_s * 1000 - 1e-9)))
        self.lines.append(f"SP,{0 if down else 1},{ms}")
        self.c.pen_s += ms / 1000

    def travel(self, target: np.ndarray) -> None:
        d = (target - self.c.pos).astype(float)
        if not d.any():
            return
        # pen travel in mm: x = (th1 + th2) / 2, y_page = (th1 - th2) / 2
        L = float(np.hypot((d[0] + d[1]) / 2, (d[0] - d[1]) / 2)) / self.k
        u = d / self.k / L  # motor mm per mm of path
        v = min(self.travel_v, self.motor_v / np.abs(u).max())
        a = self.travel_a
        ta = v / a
        if L < v * ta:  # triangle
            v = math.sqrt(L * a)
            ta = v / a
        tc = L / v - ta
        if 0 < tc < CRUISE_MIN_S:  # no cruise shorter than a period: whole steps would shift its short LM's rate
            ta, tc = L / v, 0.0  # (1 step over its length); reach v with a gentler acceleration instead
        Ta = int(math.ceil(ta * TICK_HZ - 1e-9)) or 1
        Tc = max(0, int(math.ceil(tc * TICK_HZ - 1e-9))) if tc > 1e-9 else 0
        vv = L / ((Ta + Tc) / TICK_HZ)  # the cruise speed the whole ticks give (<= v)
        times = np.array([0, Ta, Ta + Tc, 2 * Ta + Tc], float) / TICK_HZ
        speeds = np.array([0.0, vv, vv, 0.0])
        if Tc == 0:
            times, speeds = times[[0, 1, 3]], speeds[[0, 1, 3]]
        vel = speeds[:, None] * u[None, :] * self.k
        ticks = _ramp_lines(self.c.pos.copy(), times, vel, target, self.lines, self.c, merge=False)
        self.c.travel_s += ticks / TICK_HZ

    def stroke(self, samples, pen_cap: float | None = None) -> None:
        self.pen_cap = pen_cap
        k, M = self.k, self.M
        vel_xy = np.vstack([np.zeros((1, 2)), np.asarray(samples.velocity, float)])
        # motor rates in steps/s; the page's y is down, which linear_map already accounts for
        vel = vel_xy @ M.T * k
        start = self.motor(samples.start)[0]
        if (start != self.c.pos).any():
            raise OutputError("a stroke does not start where the machine is; re-plan the job")
        end = np.round(start + np.sum(0.5 * samples.delta_time * (vel[1:] + vel[:-1]), axis=0)).astype(np.int64)
        times = samples.delta_time * np.arange(len(vel))
        before = self.c.lm
        # merged periods may shift their rates as much as one period may: 1 step / delta_time
        allow = 1.0 / samples.delta_time
        cap = None if self.pen_cap is None else self.pen_cap * k + allow
        ticks = _ramp_lines(start, times, vel, end, self.lines, self.c, (cap, self.kin.vmax * k), turn=self.turn)
        self.c.draw_lm += self.c.lm - before
        self.c.draw_s += ticks / TICK_HZ


def job_lines(job, kinematics, options: dict) -> tuple[list[str], Counter]:
    """The command lines of a planned, sampled job (without the header)."""
    m = job.machine
    if len(job.samples) != len(job.strokes):
        raise OutputError("job has no velocity samples for its strokes; plan and sample it before writing EBB commands")
    if getattr(kinematics, "name", "") != "axidraw":
        raise OutputError(f"the ebb post needs a machine with axidraw kinematics; '{m.name}' uses "
                          f"'{m.kinematics}' (use -m axidraw-v3 or axidraw-se-a3)")
    w = EbbWriter(m, kinematics, options["servo_up"], options["servo_down"], options["servo_rate_up"],
                  options["servo_rate_down"], turn=options.get("firmware", "3.0") != "2.7")
    L = w.lines
    L.append("EM,1,1")  # both motors on, 16x microstepping; zeroes the step counters here, at home
    L.append(f"SC,4,{options['servo_up']}")
    L.append(f"SC,5,{options['servo_down']}")
    if options["servo_rate_up"]:
        L.append(f"SC,11,{options['servo_rate_up']}")
    if options["servo_rate_down"]:
        L.append(f"SC,12,{options['servo_rate_down']}")
    pens = job.pen_numbers
    changes = set(job.pen_pauses)  # each pen change, and the first pen when the machine has several
    number = getattr(m, "pen_number", None)
    w.c.pos = w.motor(m.home)[0]
    if w.c.pos.any():
        raise OutputError(f"'{m.name}' home {list(m.home)} is not the AxiDraw's home corner; set [work_area] home = "
                          f"[0, {m.height:g}]")
    pen0 = number(pens[0]) if (number and pens) else m.pen
    w.pen(False, pen0.up_delay)  # pen up before anything moves
    lifts = job.lifts
    for i, (stroke_samples, lift) in enumerate(zip(job.samples, lifts)):
        pen = number(pens[i]) if number else m.pen
        if i in changes:
            L.append(f"@PAUSE,{pens[i]}")
        if lift:
            w.travel(w.motor(stroke_samples.start)[0])
            w.pen(True, pen.down_delay)
        w.stroke(stroke_samples, pen.max_speed)
        if i + 1 == len(job.samples) or lifts[i + 1]:
            # the board starts the next move once SP's wait is over, the servo still rising: a pen
            # that clears the paper early (lift_clear) travels while it finishes the lift
            w.pen(False, min(pen.up_delay, options.get("lift_clear") or pen.up_delay))
    w.travel(w.motor(job.travels[-1].end if job.travels else m.home)[0])
    return L, w.c


def header(job, kinematics, c: Counter, options: dict, body: list[str]) -> list[str]:
    m = job.machine
    vmax, amax = kinematics.vmax, kinematics.amax
    total = c.draw_s + c.travel_s + c.pen_s
    crc = zlib.crc32("\n".join(body).encode("ascii"))
    return [
        f"; doodlecam EBB job, format {FORMAT} (docs/ebb.md): one command per line, '@PAUSE,<pen>' is a pen change",
        f"; machine: {m.name}",
        "; firmware: " + ("2.7.0 or newer (LM)" if options.get("firmware") == "2.7"
                          else "3.0.0 or newer (LM turning a motor back inside a move)"),
        f"; steps_per_mm: {kinematics.steps_per_mm:g}",
        f"; delta_time: {m.delta_time:g}",
        f"; motor_velocity: {vmax[0]:g} {vmax[1]:g}",
        f"; motor_acceleration: {amax[0]:g} {amax[1]:g}",
        f"; pen_speed: {m.pen.max_speed if m.pen.max_speed is not None else 0:g}",
        f"; travel: {min(m.travel_speed or m.x.max_velocity, m.x.max_velocity):g} {min(m.x.max_acceleration, m.y.max_acceleration):g}",
        f"; planned_time: {total:.3f}",
        f"; draw_time: {c.draw_s:.3f}",
        f"; travel_time: {c.travel_s:.3f}",
        f"; pen_time: {c.pen_s:.3f}",
        f"; draw_commands: {c.draw_lm}",
        f"; commands: {sum(not s.startswith('@') for s in body)}",
        f"; crc32: {crc:08x}",
    ]


def write_ebb(job, kinematics, options: dict) -> bytes:
    body, c = job_lines(job, kinematics, options)
    return ("\n".join(header(job, kinematics, c, options, body) + body) + "\n").encode("ascii")
