"""Iterative learning control with a windowed FIR filter (Kirecci §7.2.3).

A repetitive machine runs the same command every cycle. After cycle n the
next command is (eq. 7.5 and 7.12)

    u_{n+1,i} = ( Σ_k {u_{n,k} + λ (r_k − y_{n,k})} C_{k−i} ) / Σ C

with r the reference (the designed trajectory), y the recorded response,
λ in (0, 1) the learning gain and C the non-recursive low-pass filter of
eq. 7.6–7.11:

    C_k = sin(ω_c k) / (k π),  C_0 = ω_c / π,  k = −m..m,

ω_c being the cut-off in radians per sample (ω_c = cut-off [rad/s] × ΔT).
The half-length m is the first at which Σ C_k reaches one (eq. 7.9) and the
remainder R = Σ C_k − 1 (eq. 7.10) is compensated by dividing by Σ C_k =
1 + R. (The scan prints eq. 7.11 as "/ R" and eq. 7.8 as "C_0 = ω_c"; the
forms above are the ones under which a constant passes the filter
unchanged, which eq. 7.9 is there to ensure.)

Without the filter the plain update piles up what the servo cannot follow
(noise, the high frequencies its loop lags on); the command roughens and the
actuator saturates after some cycles, as the thesis observed (7–10 cycles).
The filter removes that before it accumulates.
"""

from __future__ import annotations

import numpy as np

from doodlecam.motion import MotionError


def fir_coefficients(omega_c: float) -> np.ndarray:
    """The 2m + 1 coefficients C_{-m}..C_m for a cut-off ω_c (rad/sample,
    0 < ω_c < π), normalised to sum to one (remainder compensated)."""
    if not 0 < omega_c < np.pi:
        raise MotionError(f"filter cut-off {omega_c:g} rad/sample must lie between 0 and π; "
                          "lower the cut-off or sample faster")
    kmax = int(np.ceil(2 * np.pi / omega_c)) + 2  # the partial sums pass 1 before k = π/ω_c
    k = np.arange(1, kmax + 1)
    ck = np.sin(omega_c * k) / (k * np.pi)
    c0 = omega_c / np.pi
    partial = c0 + 2 * np.cumsum(ck)
    reach = np.flatnonzero(partial >= 1.0)
    m = 0 if c0 >= 1.0 else int(reach[0]) + 1  # eq. 7.9: continue until the sum is >= 1
    c = np.concatenate([ck[:m][::-1], [c0], ck[:m]])
    return c / c.sum()  # eq. 7.10-7.11: divide by 1 + R


def is_closed(u: np.ndarray) -> bool:
    """True when the data is one closed cycle (last sample repeats the first)."""
    scale = max(1.0, float(np.abs(u).max()))
    return bool(abs(u[-1] - u[0]) <= 1e-6 * scale)


def fir_filter(u, coeffs: np.ndarray, periodic: bool | None = None) -> np.ndarray:
    """Eq. 7.6 along the first axis: u_i = Σ_k u_{i+k} C_k.

    A closed cycle (``periodic``, detected by default) is filtered as one
    period of a repeating signal; otherwise the ends are held, so the filter
    does not pull the start and end positions towards zero.
    """
    u = np.asarray(u, dtype=float)
    m = (len(coeffs) - 1) // 2
    if m == 0:
        return u.copy()
    if periodic is None:
        periodic = is_closed(u)
    if periodic:
        core = u[:-1]
        padded = np.pad(core, (m, m), mode="wrap")
        out = np.convolve(padded, coeffs[::-1], mode="valid")
        return np.append(out, out[0])
    padded = np.pad(u, (m, m), mode="edge")
    return np.convolve(padded, coeffs[::-1], mode="valid")


FILTER_MODES = ("correction", "command")


def learn_step(command, reference, response, gain: float = 0.3, coeffs: np.ndarray | None = None,
               periodic: bool | None = None, mode: str = "correction") -> np.ndarray:
    """The next command after one cycle; plain eq. 7.5 when ``coeffs`` is None.

    ``mode = "command"`` is eq. 7.12 as printed: u_{n+1} = F(u_n + λ(r − y_n)).
    ``mode = "correction"`` (default) filters only what learning added to
    the reference: u_{n+1} = r + F(u_n − r + λ(r − y_n)). F is linear, so
    the two differ only by F(r) − r, the filter's own distortion of the
    designed trajectory; leaving r out of the filter stops that distortion
    from becoming a permanent tracking error (the plain form settles at an
    error of about (1 − F)/λ times the reference's content near the cut-off).
    """
    if not 0 < gain < 1:
        raise MotionError(f"learning gain {gain:g} must lie between 0 and 1 (the thesis uses 0.3)")
    u, r, y = (np.asarray(a, dtype=float) for a in (command, reference, response))
    if not (u.shape == r.shape == y.shape):
        raise MotionError(f"command, reference and response differ in length ({len(u)}, {len(r)}, {len(y)}); "
                          "record one full cycle at the reference's sample times")
    nxt = u + gain * (r - y)
    if coeffs is None:
        return nxt
    if mode not in FILTER_MODES:
        raise MotionError(f"filter mode '{mode}' is not one of {', '.join(FILTER_MODES)}")
    if periodic is None:
        periodic = is_closed(r)
    if mode == "command":
        return fir_filter(nxt, coeffs, periodic)
    return r + fir_filter(nxt - r, coeffs, periodic)
