"""The EiBotBoard's step arithmetic for one axis of LM, in exact integers.

From the EBB command reference (firmware 2.7+, docs/ebb.html "LM"): each axis has
an accumulator; at the start of a move the rate is lowered by Accel/2 (C division,
towards zero); then every 40 us tick (25 kHz) Rate += Accel, Rate is added to the
accumulator and, when the accumulator reaches 2^31, the motor takes one step and
2^31 is subtracted. The axis stops when it has taken |Steps| steps. With a rate that
stays positive the accumulator after t ticks is

    C_t = C_0 + t (Rate - trunc(Accel / 2)) + Accel t (t + 1) / 2

so the tick of the last step is found by bisection, exactly.

A rate that goes negative inside a move: the reference (2.7 and the 3.0 page) rolls it
over by + 2^31; that case is run tick by tick (``turn=False``). Firmware 2.9 / 3.0 changed
the ISR ("Get LT and LM commands to allow accelerations through zero (i.e. reverse direction
mid-move)", ebb.c's version history; plotink's ``ebb_calc.calculate_lm`` models it): the
rate is signed, the accumulator is cleared to 2^31 - 1 instead of 0 when the first tick's
rate is negative, and whenever Accumulator + Rate leaves [0, 2^31) the motor steps the way
the rate points and the accumulator is brought back by 2^31. So the motor's position after
t ticks is floor(C_t / 2^31) with C_t as above, both ways, and Steps counts every step
taken (out and back): ``turn=True``, exact in closed form too.
"""

from __future__ import annotations

TICK_HZ = 25000  # the board's motion interrupt
ACC = 1 << 31  # one step of accumulator
INT32 = (-(1 << 31), (1 << 31) - 1)


def trunc_half(a: int) -> int:
    """a / 2 as C divides integers (towards zero)."""
    return -((-a) // 2) if a < 0 else a // 2


def accumulated(c0: int, rate: int, accel: int, t: int) -> int:
    """The accumulator after t ticks (rates assumed positive throughout)."""
    return c0 + t * (rate - trunc_half(accel)) + accel * t * (t + 1) // 2


def axis_move(rate: int, steps: int, accel: int, c0: int | None = None, max_ticks: int = 1 << 34,
              turn: bool = True) -> tuple[int, int, int]:
    """Run one axis of an LM: (ticks until its last step, signed steps taken, final accumulator).

    ``turn``: a rate passing through zero turns the motor back (firmware 2.9+); False: it rolls
    over (2.7, 2.8). The two agree on every move whose rate keeps its sign.

    ``steps`` < 0 with ``rate`` > 0 means the negative direction: the board flips the
    signs of Rate, Steps and Accel, so Accel acts on the speed as for a positive move.
    ``c0`` is the accumulator before the move, None when the move clears it. Moving
    backwards the board counts its accumulator down from 2^31 - 1 (as plotink's
    ebb_calc models firmware 3); this returns it in that form.
    """
    if steps == 0 or (rate == 0 and accel == 0):
        return 0, 0, (0 if c0 is None else c0)
    if turn:
        return _signed(rate, steps, accel, c0, max_ticks)
    sign = 1
    if steps < 0:
        sign, steps = -1, -steps
        if rate < 0:  # both negative: not a form the reference gives
            raise ValueError("negative Rate with negative Steps")
    elif rate < 0:  # deprecated form: the sign of Rate gives the direction
        sign, rate, accel = -1, -rate, -accel
    t, c = _forward(rate, steps, accel, 0 if c0 is None else (c0 if sign > 0 else ACC - 1 - c0), max_ticks)
    return t, sign * steps, c if sign > 0 else ACC - 1 - c


def _signed(rate: int, steps: int, accel: int, c0: int | None, max_ticks: int) -> tuple[int, int, int]:
    """Firmware 2.9+: the position is floor(C_t / 2^31); the move ends when its steps out and back make Steps."""
    if steps < 0:
        if rate < 0:
            raise ValueError("negative Rate with negative Steps")
        steps, rate, accel = -steps, -rate, -accel  # the legacy form: the firmware flips all three
    r0 = rate - trunc_half(accel)
    r1 = r0 + accel
    if c0 is None:
        c0 = ACC - 1 if (r1 < 0 or (r1 == 0 and accel < 0)) else 0
    # the rate r0 + accel t keeps one sign up to tick ``turn`` (C_t is monotone on each side of it)
    turn = (-r0) // accel if accel and (r1 > 0) != (accel > 0) and r1 != 0 else None

    def at(t: int) -> int:
        return (c0 + t * r0 + accel * t * (t + 1) // 2) // ACC

    def taken(t: int) -> int:
        if turn is None or t <= turn:
            return abs(at(t))
        p = at(turn)
        return abs(p) + abs(at(t) - p)

    lo, hi = 0, 1
    while taken(hi) < steps:
        lo, hi = hi, hi * 2
        if hi > max_ticks:
            raise ValueError("move does not finish")
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if taken(mid) >= steps:
            hi = mid
        else:
            lo = mid
    pos = at(hi)
    return hi, pos, c0 + hi * r0 + accel * hi * (hi + 1) // 2 - pos * ACC


def _forward(rate: int, steps: int, accel: int, c0: int, max_ticks: int) -> tuple[int, int]:
    goal = steps * ACC
    r1 = rate - trunc_half(accel) + accel
    t_zero = None
    # the rate at tick t is r1 + accel (t - 1); find whether it stays positive until the goal
    if accel >= 0 and r1 > 0:
        positive = True
    elif r1 > 0 and accel < 0:
        t_zero = (r1 - 1) // (-accel) + 1  # ticks while the rate is still > 0
        positive = accumulated(c0, rate, accel, t_zero) >= goal
    else:
        positive = False
    if positive:
        lo, hi = 0, 1
        while accumulated(c0, rate, accel, hi) < goal:
            lo, hi = hi, hi * 2
            if t_zero is not None and hi >= t_zero:
                hi = t_zero  # past it the rate is negative: the accumulator falls again
                break
            if hi > max_ticks:
                raise ValueError("move does not finish")
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if accumulated(c0, rate, accel, mid) >= goal:
                hi = mid
            else:
                lo = mid
        return hi, accumulated(c0, rate, accel, hi) - goal
    # tick by tick, with the documented roll-over of a negative rate
    r, c, taken, t = rate - trunc_half(accel), c0, 0, 0
    while taken < steps:
        t += 1
        if t > max_ticks:
            raise ValueError("move does not finish")
        r += accel
        if r < 0:
            r += ACC
        c += r
        if c >= ACC:
            c -= ACC
            taken += 1
    return t, c
