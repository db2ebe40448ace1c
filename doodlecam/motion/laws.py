"""The thesis's standard cam motions (Kirecci §2.7), dwell-rise-dwell.

Each law is written for the normalised rise: x = θ/β = t/T in [0, 1] and
f(x) in [0, 1]. For a rise h over a duration T (the thesis's ω/β = 1/T):

    position = h f(x),  velocity = h f'(x)/T,
    acceleration = h f''(x)/T²,  jerk = h f'''(x)/T³.

So with h = 1, T = 1 the printed figures of the thesis come out directly
(cycloidal peak acceleration 2π = 6.28, initial jerk 4π² = 39.47; modified
trapezoid peak acceleration 8π/(2+π) = 4.88).

Where the scanned equations carry typos they are corrected here and the
tests check the corrected forms by continuity: eq. 2.47 and 2.66 lose a
(1 − θ/β) and a β; eq. 2.58–2.69 drop h; the cross-over jerk of the triple
harmonic (printed 2π(−A1 + 3A2 − 3A3)) is 2π(−A1 + 2A2 − 3A3) by eq. 2.82.
Jerk arrays hold the finite part; where a law's acceleration jumps (see
``Law.continuity``) the true jerk there is an impulse.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from doodlecam.motion import MotionError

PI = np.pi


def _constant_velocity(x):
    z = np.zeros_like(x)
    return np.stack([x, np.ones_like(x), z, z])


def _simple_harmonic(x):  # eq. 2.36-2.38
    s, c = np.sin(PI * x), np.cos(PI * x)
    return np.stack([(1 - c) / 2, PI / 2 * s, PI**2 / 2 * c, -(PI**3) / 2 * s])


def _double_harmonic(x):  # eq. 2.39-2.41
    s1, c1, s2, c2 = np.sin(PI * x), np.cos(PI * x), np.sin(2 * PI * x), np.cos(2 * PI * x)
    return np.stack([
        0.5 * ((1 - c1) - 0.25 * (1 - c2)),
        PI / 2 * (s1 - 0.5 * s2),
        PI**2 / 2 * (c1 - c2),
        PI**3 / 2 * (-s1 + 2 * s2),
    ])


def _bang_bang(x):  # eq. 2.42-2.44
    first = x < 0.5
    r = 1 - x
    return np.stack([
        np.where(first, 2 * x * x, 1 - 2 * r * r),
        np.where(first, 4 * x, 4 * r),
        np.where(first, 4.0, -4.0),
        np.zeros_like(x),
    ])


def _cubic_1(x):  # eq. 2.45-2.47 (constant pulse #1)
    first = x < 0.5
    r = 1 - x
    return np.stack([
        np.where(first, 4 * x**3, 1 - 4 * r**3),
        np.where(first, 12 * x * x, 12 * r * r),
        np.where(first, 24 * x, -24 * r),
        np.full_like(x, 24.0),
    ])


def _cubic_2(x):  # eq. 2.48-2.50
    return np.stack([x * x * (3 - 2 * x), 6 * x * (1 - x), 6 * (1 - 2 * x), np.full_like(x, -12.0)])


def _cycloidal(x):  # eq. 2.51-2.53
    w = 2 * PI * x
    return np.stack([x - np.sin(w) / (2 * PI), 1 - np.cos(w), 2 * PI * np.sin(w), 4 * PI**2 * np.cos(w)])


MOD_TRAP_A = 8 * PI / (2 + PI)  # eq. 2.54


def _modified_trapezoid(x):  # eq. 2.55-2.69, five pieces
    A = MOD_TRAP_A
    k = 4 * PI
    out = np.empty((4,) + x.shape)
    pieces = [
        (x < 0.125, lambda x: (
            A / k * (x - np.sin(k * x) / k), A / k * (1 - np.cos(k * x)),
            A * np.sin(k * x), A * k * np.cos(k * x))),
        ((x >= 0.125) & (x < 0.375), lambda x: (
            A / 2 * x * x + A / 4 * (1 / PI - 0.5) * x + A / 64 * (0.5 - 4 / PI**2),
            A * x + A / 4 * (1 / PI - 0.5), np.full_like(x, A), np.zeros_like(x))),
        ((x >= 0.375) & (x < 0.625), lambda x: (
            -A / (16 * PI**2) * np.cos(k * (x - 0.375)) + A / 4 * (1 + 1 / PI) * x - A / 16,
            A / k * np.sin(k * (x - 0.375)) + A / 4 * (1 + 1 / PI),
            A * np.cos(k * (x - 0.375)), -A * k * np.sin(k * (x - 0.375)))),
        ((x >= 0.625) & (x < 0.875), lambda x: (
            -A / 2 * x * x + A / 8 * (7 + 2 / PI) * x - 33 * A / 128 + A / (16 * PI**2),
            -A * x + A / 8 * (7 + 2 / PI), np.full_like(x, -A), np.zeros_like(x))),
        (x >= 0.875, lambda x: (
            A / (16 * PI**2) * np.cos(k * (x - 0.875)) + A / k * x + A / 8,
            -A / k * np.sin(k * (x - 0.875)) + A / k,
            -A * np.cos(k * (x - 0.875)), A * k * np.sin(k * (x - 0.875)))),
    ]
    for mask, fn in pieces:
        if mask.any():
            out[:, mask] = np.stack(fn(x[mask]))
    return out


def modified_sine_peak(b: float) -> float:
    """Peak acceleration coefficient A of the modified sine law (eq. 2.70)."""
    return PI**2 / (2 * PI * b + 2 - 8 * b)


def _modified_sine(x, b: float = 0.125):  # eq. 2.70-2.79
    A = modified_sine_peak(b)
    out = np.empty((4,) + x.shape)
    w1 = PI / (2 * b)
    w2 = PI / (1 - 2 * b)
    pieces = [
        (x < b, lambda x: (
            2 * A * b / PI * (x - 2 * b / PI * np.sin(w1 * x)), 2 * A * b / PI * (1 - np.cos(w1 * x)),
            A * np.sin(w1 * x), A * w1 * np.cos(w1 * x))),
        ((x >= b) & (x < 1 - b), lambda x: (
            -A * ((1 - 2 * b) / PI) ** 2 * np.cos(w2 * (x - b)) + 2 * A * b * x / PI + A / PI**2 * (1 - 4 * b),
            A * (1 - 2 * b) / PI * np.sin(w2 * (x - b)) + 2 * A * b / PI,
            A * np.cos(w2 * (x - b)), -A * w2 * np.sin(w2 * (x - b)))),
        (x >= 1 - b, lambda x: (
            A * (2 * b / PI) ** 2 * np.cos(w1 * (x - 1 + b)) + 2 * A * b * x / PI + 2 * A / PI**2 * (1 - 4 * b),
            -2 * A * b / PI * np.sin(w1 * (x - 1 + b)) + 2 * A * b / PI,
            -A * np.cos(w1 * (x - 1 + b)), A * w1 * np.sin(w1 * (x - 1 + b)))),
    ]
    for mask, fn in pieces:
        if mask.any():
            out[:, mask] = np.stack(fn(x[mask]))
    return out


# Fig. 5.1(e): MOTDES's triple-harmonic menu opens with these harmonics.
TRIPLE_A1 = 6.203105
TRIPLE_A2 = 0.0


def triple_a3(a1: float, a2: float) -> float:
    """The derived third harmonic: A1 + A2/2 + A3/3 = 2π (eq. 2.83)."""
    return 3 * (2 * PI - a1 - a2 / 2)


def _triple_harmonic(x, a1: float = TRIPLE_A1, a2: float = TRIPLE_A2):  # eq. 2.80-2.83
    a3 = triple_a3(a1, a2)
    w = 2 * PI * x
    s1, s2, s3 = np.sin(w), np.sin(2 * w), np.sin(3 * w)
    c1, c2, c3 = np.cos(w), np.cos(2 * w), np.cos(3 * w)
    return np.stack([
        x - (a1 * s1 + a2 / 4 * s2 + a3 / 9 * s3) / (4 * PI**2),
        1 - (a1 * c1 + a2 / 2 * c2 + a3 / 3 * c3) / (2 * PI),
        a1 * s1 + a2 * s2 + a3 * s3,
        2 * PI * (a1 * c1 + 2 * a2 * c2 + 3 * a3 * c3),
    ])


def _dwell(x):
    z = np.zeros_like(x)
    return np.stack([z, z, z, z])


@dataclass(frozen=True)
class Law:
    """One motion law. ``continuity``: highest derivative continuous over the
    whole dwell-rise-dwell motion (0 position, 1 velocity, 2 acceleration)."""

    name: str
    title: str
    equations: str
    fn: Callable[..., np.ndarray]
    continuity: int
    params: tuple[tuple[str, float], ...] = ()
    symmetric: bool = True  # acceleration odd about x = 1/2
    high_speed: bool = False  # §2.7.2 rather than §2.7.1


LAWS: dict[str, Law] = {law.name: law for law in (
    Law("constant-velocity", "constant velocity (linear)", "2.33-2.35", _constant_velocity, 0, symmetric=False),
    Law("simple-harmonic", "simple harmonic", "2.36-2.38", _simple_harmonic, 1),
    Law("double-harmonic", "double harmonic", "2.39-2.41", _double_harmonic, 1, symmetric=False),
    Law("bang-bang", "constant acceleration (bang-bang)", "2.42-2.44", _bang_bang, 1),
    Law("cubic-1", "cubic / constant pulse #1", "2.45-2.47", _cubic_1, 1),
    Law("cubic-2", "cubic / constant pulse #2", "2.48-2.50", _cubic_2, 1),
    Law("cycloidal", "cycloidal", "2.51-2.53", _cycloidal, 2, high_speed=True),
    Law("modified-trapezoid", "modified trapezoidal", "2.54-2.69", _modified_trapezoid, 2, high_speed=True),
    Law("modified-sine", "modified sine", "2.70-2.79", _modified_sine, 2, (("b", 0.125),), high_speed=True),
    Law("triple-harmonic", "triple harmonic", "2.80-2.83", _triple_harmonic, 2,
        (("a1", TRIPLE_A1), ("a2", TRIPLE_A2)), symmetric=False, high_speed=True),
    Law("dwell", "dwell", "-", _dwell, 3),
)}
ALIASES = {"constant-acceleration": "bang-bang", "linear": "constant-velocity", "cubic1": "cubic-1", "cubic2": "cubic-2"}


def get_law(name: str, where: str = "") -> Law:
    key = ALIASES.get(name, name)
    if key not in LAWS:
        import difflib

        hint = difflib.get_close_matches(name, list(LAWS) + ["polynomial", "cubic-spline"], n=1)
        did = f" (did you mean '{hint[0]}'?)" if hint else ""
        pre = f"{where}: " if where else ""
        raise MotionError(f"{pre}unknown motion law '{name}'{did}; choose one of {', '.join(LAWS)}, polynomial, cubic-spline")
    return LAWS[key]


def check_params(law: Law, params: dict, where: str = "") -> dict[str, float]:
    """Law parameters with defaults, validated (b in (0, 1/2) for modified sine)."""
    pre = f"{where}: " if where else ""
    known = dict(law.params)
    out = dict(known)
    for key, value in params.items():
        if key not in known:
            names = ", ".join(known) or "none"
            raise MotionError(f"{pre}{law.name} has no parameter '{key}' (parameters: {names})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise MotionError(f"{pre}{law.name} parameter '{key}' must be a number, got {value!r}")
        out[key] = float(value)
    if law.name == "modified-sine" and not 0 < out["b"] < 0.5:
        raise MotionError(f"{pre}modified-sine b = {out['b']:g} must lie between 0 and 0.5 (0.125 is the usual value)")
    return out


def normalised(name: str, x, **params) -> np.ndarray:
    """(4, n) array: f, f', f'', f''' of the law at x in [0, 1] (clipped)."""
    law = get_law(name)
    p = check_params(law, params)
    x = np.clip(np.atleast_1d(np.asarray(x, dtype=float)), 0.0, 1.0)
    return law.fn(x, **p)


def evaluate(name: str, t, h: float = 1.0, duration: float = 1.0, **params) -> np.ndarray:
    """(4, n) array: position, velocity, acceleration and jerk of a rise ``h``
    (mm) over ``duration`` (s) at times ``t`` (s from the start of the rise)."""
    if not duration > 0:
        raise MotionError(f"{name}: duration must be positive, got {duration:g} s")
    f = normalised(name, np.asarray(t, dtype=float) / duration, **params)
    scale = h / duration ** np.arange(4.0)
    return f * scale[:, None]


@lru_cache(maxsize=64)
def _peaks(name: str, items: tuple) -> tuple[float, float, float]:
    x = np.linspace(0.0, 1.0, 200_001)
    f = normalised(name, x, **dict(items))
    return tuple(float(np.abs(f[k]).max()) for k in (1, 2, 3))  # type: ignore[return-value]


def coefficients(name: str, **params) -> dict[str, float]:
    """Peak |velocity|, |acceleration|, |jerk| for h = 1, T = 1 (Cv, Ca, Cj),
    and the jerk at the start (the thesis's 'initial jerk')."""
    cv, ca, cj = _peaks(ALIASES.get(name, name), tuple(sorted(params.items())))
    j0 = float(normalised(name, [0.0], **params)[3, 0])
    return {"velocity": cv, "acceleration": ca, "jerk": cj, "initial_jerk": j0}
