"""A simulated servo axis, to show what learning control does (Kirecci §7.2.3).

Plant: a motor-and-load axis, x'' = a − c x', whose acceleration a is
limited to ±``accel_limit`` (actuator saturation). Controller: a digital
PID-like position loop running every ``tick`` = 416 µs (the thesis's servo
card, §7.2.3.1),

    a_cmd = Kp e + Kd ė + Ki ∫e,  e = u − x_measured,

with Kp = ω², Kd = 2ζω for a closed-loop natural frequency ω, the
measurement quantised to the encoder resolution (plus optional noise) and the
command applied one tick late (the computation delay of a digital servo).
Between ticks the demanded acceleration is held and the plant is integrated
exactly, so the loop is stable at any command sample time (the loop it
replaces took 4 Euler steps per 35 ms sample, which diverged). The command
is the trajectory u sampled at the design's times and interpolated linearly
between them, as a servo card does.

The default axis is under-damped (ζ = 0.1, 6 Hz): the thesis found learning
works best on an under-damped system, and on one plain learning (eq. 7.5)
first improves the tracking and then pumps the resonance, where the
response lags the command by more than a quarter period and every cycle
adds to the error instead of removing it, until the actuator saturates:
on Example 1 at λ = 0.3 within 7–10 cycles, as on the rig. The FIR filter
(eq. 7.12) with a cut-off below the resonance stops that.

``learning_cycles`` runs the thesis's experiment: the same reference for N
cycles, learning after each with or without the filter, and records the
tracking error and the actuator effort of every cycle. A closed reference
runs back to back, as the machine runs it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from doodlecam.motion import MotionError
from doodlecam.motion.ilc import fir_coefficients, is_closed, learn_step


TICK = 416e-6  # s, the servo card's sample time on the thesis's rig (§7.2.3.1)


@dataclass
class ServoState:
    """What the axis carries from one cycle into the next when cycles run back to back."""

    x: float
    v: float = 0.0
    integ: float = 0.0
    e_prev: float = 0.0
    d_term: float = 0.0
    pending: list = field(default_factory=list)
    k: int = 0  # ticks run so far (indexes the measurement noise)


@dataclass(frozen=True)
class ServoAxis:
    accel_limit: float  # mm/s^2, the most the actuator can give
    bandwidth: float = 6.0  # Hz, closed-loop natural frequency
    damping: float = 0.1  # under-damped, as the thesis tuned its rig for learning
    integral: float = 0.05  # Ki = integral * ω^3 (a little integral action)
    friction: float = 5.0  # 1/s, viscous
    derivative_filter: float = 8.0  # the D term rolls off at this many times ω
    tick: float = TICK  # s, controller period; the plant is integrated exactly in between
    delay: int = 1  # ticks between measuring and applying
    resolution: float = 0.001  # mm per encoder count
    noise: float = 0.0  # mm rms measurement noise
    seed: int = 0

    def ticks_per_sample(self, dt: float) -> int:
        return max(1, int(np.ceil(dt / self.tick - 1e-9)))

    def run(self, t, command, state: ServoState | None = None) -> "ServoRun":
        """Run one cycle of ``command`` (mm) at sample times ``t`` (s): from rest at
        command[0], or from ``state`` (the end of the previous cycle, back to back).

        The controller runs every ``tick`` s (at least once per sample); between
        ticks the demanded acceleration a is held and the plant x'' = a − c x'
        is integrated exactly, so the simulation is stable and exact for the
        linear part at any command sample time (saturation, encoder
        quantisation and the one-tick delay act at the ticks, as on a card).
        """
        t = np.asarray(t, dtype=float)
        u = np.asarray(command, dtype=float)
        if len(t) != len(u) or len(t) < 2 or not np.all(np.diff(t) > 0):
            raise MotionError("servo: times must increase and match the command samples")
        ticks = self.ticks_per_sample(float(t[1] - t[0]))
        dt = float(t[1] - t[0]) / ticks
        n = (len(t) - 1) * ticks
        ui = np.interp(np.linspace(t[0], t[-1], n + 1)[:-1], t, u).tolist()
        w = 2 * np.pi * self.bandwidth
        kp, kd, ki = w * w, 2 * self.damping * w, self.integral * w**3
        st = state if state is not None else ServoState(float(u[0]), pending=[0.0] * self.delay)
        rng = np.random.default_rng([self.seed, st.k])
        noise = (rng.normal(0.0, self.noise, n) if self.noise > 0 else np.zeros(n)).tolist()
        q = self.resolution
        lim, c = self.accel_limit, self.friction
        tf = 1.0 / (self.derivative_filter * w)  # a real D term is filtered (a lead network)
        # exact zero-order-hold step of x'' = a - c x' over dt
        if c > 0:
            ed = float(np.exp(-c * dt))
            fv, fx = (1 - ed) / c, (dt - (1 - ed) / c) / c
        else:
            ed, fv, fx = 1.0, dt, 0.5 * dt * dt
        x, v, integ, e_prev, d_term, pending = st.x, st.v, st.integ, st.e_prev, st.d_term, list(st.pending)
        xs = [0.0] * n
        peak, over = 0.0, 0
        for i in range(n):  # the loop is inherently sequential (saturation, delay)
            xs[i] = x
            meas = round((x + noise[i]) / q) * q if q > 0 else x + noise[i]
            e = ui[i] - meas
            integ += e * dt
            d_term = (tf * d_term + kd * (e - e_prev)) / (tf + dt)
            a_cmd = kp * e + d_term + ki * integ
            e_prev = e
            if abs(a_cmd) > peak:
                peak = abs(a_cmd)
            if abs(a_cmd) > lim:
                over += 1
            pending.append(a_cmd)
            a = min(max(pending.pop(0), -lim), lim)
            x, v = x + v * fv + a * fx, v * ed + a * fv
        y = np.append(np.asarray(xs)[::ticks], x)
        end = ServoState(x, v, integ, e_prev, d_term, pending, st.k + n)
        return ServoRun(t=t, command=u, response=y, effort=peak / lim, saturated=over / n, state=end)


@dataclass(frozen=True)
class ServoRun:
    t: np.ndarray
    command: np.ndarray
    response: np.ndarray
    effort: float  # peak |a_cmd| / accel_limit (> 1: the actuator saturated)
    saturated: float  # fraction of ticks spent saturated
    state: ServoState | None = None  # at the end of the cycle


@dataclass(frozen=True)
class CycleStats:
    cycle: int
    rms_error: float  # mm, of r − y
    max_error: float  # mm
    effort: float  # peak demand / limit
    saturated: float  # fraction of ticks saturated


def learning_cycles(axis: ServoAxis, t, reference, cycles: int = 15, gain: float = 0.3,
                    cutoff: float | None = None, mode: str = "correction",
                    periodic: bool | None = None) -> list[CycleStats]:
    """Run ``cycles`` learning cycles; ``cutoff`` (rad/s) switches the FIR filter on
    (``mode`` as in ``ilc.learn_step``).

    A closed reference (``periodic``, detected when the last sample repeats
    the first) runs as the machine runs it: cycles back to back, each
    starting where the last one ended, after one unrecorded lap of the
    reference (the machine is already running when learning starts). An
    open one starts every cycle from rest at r(0).
    """
    t = np.asarray(t, dtype=float)
    r = np.asarray(reference, dtype=float)
    if periodic is None:
        periodic = is_closed(r)
    coeffs = fir_coefficients(cutoff * float(t[1] - t[0])) if cutoff else None
    u = r.copy()
    # a lap simulates up to its last sample, which is the next lap's first: its end state starts the next
    state = axis.run(t, r).state if periodic else None
    stats = []
    for n in range(1, cycles + 1):
        run = axis.run(t, u, state)
        if periodic:
            state = run.state
        err = r - run.response
        stats.append(CycleStats(n, float(np.sqrt(np.mean(err**2))), float(np.abs(err).max()), run.effort, run.saturated))
        u = learn_step(u, r, run.response, gain, coeffs, periodic=periodic, mode=mode)
    return stats
