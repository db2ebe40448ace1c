"""A simulated servo axis, to show what learning control does (Kirecci §7.2.3).

Plant: a motor-and-load axis, x'' = a − c x', whose acceleration a is
limited to ±``accel_limit`` (actuator saturation). Controller: a digital
PID-like position loop running ``ticks`` times per command sample,

    a_cmd = Kp e + Kd ė + Ki ∫e,  e = u − x_measured,

with Kp = ω², Kd = 2ζω for a closed-loop natural frequency ω, the
measurement quantised to the encoder resolution (plus optional noise) and the
command applied one tick late (the computation delay of a digital servo).
The command is the trajectory u sampled at the design's times and
interpolated linearly between them, as a servo card does.

``learning_cycles`` runs the thesis's experiment: the same reference for N
cycles, each starting from rest at r(0), learning after each cycle with or
without the FIR filter, and records the tracking error and the actuator
effort of every cycle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from doodlecam.motion import MotionError
from doodlecam.motion.ilc import fir_coefficients, learn_step


@dataclass(frozen=True)
class ServoAxis:
    accel_limit: float  # mm/s^2, the most the actuator can give
    bandwidth: float = 25.0  # Hz, closed-loop natural frequency
    damping: float = 0.7
    integral: float = 0.05  # Ki = integral * ω^3 (a little integral action)
    friction: float = 5.0  # 1/s, viscous
    derivative_filter: float = 8.0  # the D term rolls off at this many times ω
    ticks: int = 4  # servo ticks per command sample (the thesis's card: 416 µs)
    delay: int = 1  # ticks between measuring and applying
    resolution: float = 0.001  # mm per encoder count
    noise: float = 0.0  # mm rms measurement noise
    seed: int = 0

    def run(self, t, command) -> "ServoRun":
        """Run one cycle of ``command`` (mm) at sample times ``t`` (s), from rest at command[0]."""
        t = np.asarray(t, dtype=float)
        u = np.asarray(command, dtype=float)
        if len(t) != len(u) or len(t) < 2 or not np.all(np.diff(t) > 0):
            raise MotionError("servo: times must increase and match the command samples")
        dt = float(t[1] - t[0]) / self.ticks
        n = (len(t) - 1) * self.ticks + 1
        tt = np.linspace(t[0], t[-1], n)
        ui = np.interp(tt, t, u)
        w = 2 * np.pi * self.bandwidth
        kp, kd, ki = w * w, 2 * self.damping * w, self.integral * w**3
        rng = np.random.default_rng(self.seed)
        noise = rng.normal(0.0, self.noise, n) if self.noise > 0 else np.zeros(n)
        q = self.resolution
        x, v, integ = float(u[0]), 0.0, 0.0
        e_prev = 0.0
        d_term = 0.0
        tf = 1.0 / (self.derivative_filter * w)  # a real D term is filtered (a lead network)
        pending = [0.0] * self.delay
        xs = np.empty(n)
        effort = np.empty(n)
        lim = self.accel_limit
        c = self.friction
        for i in range(n):  # the loop is inherently sequential (saturation, delay)
            xs[i] = x
            meas = np.round((x + noise[i]) / q) * q if q > 0 else x + noise[i]
            e = ui[i] - meas
            integ += e * dt
            d_term = (tf * d_term + kd * (e - e_prev)) / (tf + dt)
            a_cmd = kp * e + d_term + ki * integ
            e_prev = e
            effort[i] = a_cmd
            pending.append(a_cmd)
            a = min(max(pending.pop(0), -lim), lim)
            acc = a - c * v
            x += v * dt + 0.5 * acc * dt * dt
            v += acc * dt
        y = xs[:: self.ticks]
        return ServoRun(t=t, command=u, response=y, effort=float(np.abs(effort).max() / lim),
                        saturated=float(np.mean(np.abs(effort) > lim)))


@dataclass(frozen=True)
class ServoRun:
    t: np.ndarray
    command: np.ndarray
    response: np.ndarray
    effort: float  # peak |a_cmd| / accel_limit (> 1: the actuator saturated)
    saturated: float  # fraction of ticks spent saturated


@dataclass(frozen=True)
class CycleStats:
    cycle: int
    rms_error: float  # mm, of r − y
    max_error: float  # mm
    effort: float  # peak demand / limit
    saturated: float  # fraction of ticks saturated


def learning_cycles(axis: ServoAxis, t, reference, cycles: int = 15, gain: float = 0.3,
                    cutoff: float | None = None, mode: str = "correction") -> list[CycleStats]:
    """Run ``cycles`` learning cycles; ``cutoff`` (rad/s) switches the FIR filter on
    (``mode`` as in ``ilc.learn_step``)."""
    t = np.asarray(t, dtype=float)
    r = np.asarray(reference, dtype=float)
    coeffs = fir_coefficients(cutoff * float(t[1] - t[0])) if cutoff else None
    u = r.copy()
    stats = []
    for n in range(1, cycles + 1):
        run = axis.run(t, u)
        err = r - run.response
        stats.append(CycleStats(n, float(np.sqrt(np.mean(err**2))), float(np.abs(err).max()), run.effort, run.saturated))
        u = learn_step(u, r, run.response, gain, coeffs, mode=mode)
    return stats
