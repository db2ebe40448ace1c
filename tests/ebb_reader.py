"""An .ebb reader for the tests, written from the EBB command reference (docs/ebb.html, LM, SM, SP, EM)
and, for a rate that passes through zero, firmware 3.0's motion ISR (ebb.c, "2.9.0: Get LT and LM
commands to allow accelerations through zero (i.e. reverse direction mid-move)").

It shares no code with doodlecam.link.ebb: each LM is run tick by tick as the firmware's 25 kHz
interrupt does (vectorised over the ticks of one command):

  at the start, for each axis: if Steps < 0 (and Rate >= 0) Rate, Steps and Accel change sign, so the
  sign of Rate is the direction; Rate -= Accel / 2 (towards 0); if Clear says so the accumulator is
  zeroed, or set to 2^31 - 1 when the first tick's rate (Rate + Accel) is negative;
  every tick: Rate += Accel; Accumulator += Rate; when it reaches 2^31 the motor steps forward and
  2^31 is taken off, when it falls below 0 the motor steps back and 2^31 is added; the axis stops
  after |Steps| steps (out and back); the command ends when both have.

It yields, per command, the ticks it lasts, the rate of each axis on every tick (steps/s) and
the motor positions after every tick.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TICK = 40e-6
TWO31 = 2 ** 31


@dataclass
class Run:
    """One executed motion command."""

    line: str
    index: int  # line number among the commands (0-based)
    t0: float  # s, when it started
    pos: np.ndarray  # (ticks + 1, 2) motor positions, steps, from its start to its end
    rate: np.ndarray  # (ticks, 2) steps/s on each tick (signed; 0 once an axis is done)
    accel: tuple[float, float]  # steps/s^2 of each moving axis
    pen_down: bool


def _axis(rate: int, steps: int, accel: int, acc, clear: bool):
    """Per-tick signed rate (steps/s), signed position after each tick, ticks used, final accumulator."""
    if steps == 0:
        return None
    if steps < 0:
        assert rate >= 0, "negative Rate with negative Steps is refused by the board"
        steps, rate, accel = -steps, -rate, -accel
    r = rate - int(accel / 2)  # C division
    if clear:
        acc = TWO31 - 1 if (r + accel < 0 or (r + accel == 0 and accel < 0)) else 0
    n = 16
    while True:
        ticks = np.arange(1, n + 1, dtype=object if abs(accel) * n * n + abs(r) * n > 2 ** 60 else np.int64)
        rates = r + accel * ticks
        c = acc + np.cumsum(rates)
        pos = c // TWO31  # the accumulator stays in [0, 2^31): each crossing is one step that way
        taken = np.cumsum(np.abs(np.diff(np.concatenate([[0], pos]))))
        if (taken >= steps).any():
            done = int(np.argmax(taken >= steps)) + 1
            assert (np.abs(rates[:done]) < TWO31).all(), f"more than a step per tick in LM axis {rate},{steps},{accel}"
            return (rates[:done].astype(float) * (1 / TICK) / TWO31, pos[:done].astype(np.int64), done,
                    int(c[done - 1] - pos[done - 1] * TWO31))
        n *= 2
        if n > 1 << 26:
            raise AssertionError("LM does not finish")


def execute(lines):
    """Run the command lines; yield a Run per motion command (LM, SM, SP's delay)."""
    pos = np.zeros(2, dtype=np.int64)
    acc = [0, 0]
    t = 0.0
    pen_down = False
    for i, line in enumerate(lines):
        if line.startswith(";") or line.startswith("@"):
            continue
        p = line.split(",")
        name, a = p[0], [int(v) for v in p[1:]]
        if name == "EM":
            pos[:] = 0
        elif name == "SP":
            pen_down = a[0] == 0
            t += (a[1] if len(a) > 1 else 0) / 1000
        elif name == "SM":
            ticks = a[0] * 25
            d = np.array([a[1], a[2] if len(a) > 2 else 0])
            if d.any():
                raise AssertionError("this reader runs SM only as a wait")
            yield Run(line, i, t, np.repeat(pos[None], ticks + 1, axis=0), np.zeros((ticks, 2)), (0.0, 0.0), pen_down)
            t += a[0] / 1000
        elif name == "LM":
            clear = a[6] if len(a) > 6 else 0
            axes = [_axis(a[3 * k], a[3 * k + 1], a[3 * k + 2], acc[k], bool(clear & (1 << k))) for k in range(2)]
            ticks = max(x[2] for x in axes if x is not None)
            rate = np.zeros((ticks, 2))
            steps = np.zeros((ticks + 1, 2), dtype=np.int64)
            accel = [0.0, 0.0]
            for k, x in enumerate(axes):
                if x is None:
                    continue
                r, count, done, acc[k] = x
                rate[:done, k] = r
                steps[1:done + 1, k] = count
                steps[done + 1:, k] = count[-1]
                accel[k] = (-1 if a[3 * k + 1] < 0 else 1) * a[3 * k + 2] / TICK / TICK / TWO31  # signed, as run
            yield Run(line, i, t, pos[None] + steps, rate, tuple(accel), pen_down)
            pos = pos + steps[-1]
            t += ticks * TICK
