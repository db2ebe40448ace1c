"""An .ebb reader for the tests, written from the EBB command reference alone (docs/ebb.html, LM, SM, SP, EM).

It shares no code with doodlecam.link.ebb: each LM is run tick by tick as the reference
describes its 25 kHz interrupt (vectorised over the ticks of one command):

  at the start, for each axis: if Clear says so the accumulator is zeroed; Rate -= Accel / 2 (towards 0);
  if Steps < 0 (and Rate > 0) the axis turns backwards and Rate, Steps, Accel change sign, so the
  rate's magnitude follows |Rate| and Accel;
  every tick: Rate += Accel; Accumulator += Rate; when it reaches 2^31 the motor steps once and
  2^31 is taken off; the axis stops after |Steps| steps; the command ends when both have.

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


def _axis(rate: int, steps: int, accel: int, acc: int):
    """Per-tick rate (steps/s, unsigned), step count after each tick, ticks used, final accumulator."""
    if steps == 0:
        return None
    sign = 1
    if steps < 0:
        sign, steps = -1, -steps
    half = int(accel / 2)  # C division
    r = rate - half
    # long enough: twice the mean-rate estimate, at least one tick per step
    n = 16
    while True:
        ticks = np.arange(1, n + 1, dtype=object if abs(accel) * n * n > 2 ** 60 else np.int64)
        rates = r + accel * ticks
        c = acc + np.cumsum(rates)
        count = np.minimum(c // TWO31, steps)
        if (count >= steps).any() or (rates < 0).any():
            if not (count >= steps).any() or (rates[:int(np.argmax(count >= steps)) + 1] < 0).any():
                raise AssertionError(f"a rate turns negative (rolls over) in LM axis {rate},{steps},{accel}")
            done = int(np.argmax(count >= steps)) + 1
            return (rates[:done].astype(float) * (1 / TICK) / TWO31, count[:done].astype(np.int64), done,
                    int(c[done - 1] - steps * TWO31), sign)
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
            axes = []
            for k in range(2):
                if clear & (1 << k):
                    acc[k] = 0
                axes.append(_axis(a[3 * k], a[3 * k + 1], a[3 * k + 2], acc[k]))
            ticks = max(x[2] for x in axes if x is not None)
            rate = np.zeros((ticks, 2))
            steps = np.zeros((ticks + 1, 2), dtype=np.int64)
            accel = [0.0, 0.0]
            for k, x in enumerate(axes):
                if x is None:
                    continue
                r, count, done, acc[k], sign = x
                rate[:done, k] = sign * r
                steps[1:done + 1, k] = sign * count
                steps[done + 1:, k] = sign * count[-1]
                accel[k] = a[3 * k + 2] / TICK / TICK / TWO31
            yield Run(line, i, t, pos[None] + steps, rate, tuple(accel), pen_down)
            pos = pos + steps[-1]
            t += ticks * TICK
