"""GRBL 1.1h's 34 ``$`` settings for the emulator: their defaults, how ``$x=val`` stores them and how ``$$``
prints them (settings.c, report.c, print.c of the firmware; written from reading them, not copied)."""

from __future__ import annotations

import math

# defaults.h, DEFAULTS_GENERIC (what $RST=$ restores); units as GRBL shows them
DEFAULTS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000.0, 31: 0.0, 32: 0,
    100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}
# printed as whole numbers (an 8-bit integer or a flag); every other setting is a float
INTEGER = frozenset({0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 32})
FLAGS = frozenset({4, 5, 6, 13, 20, 21, 22, 32})  # stored as one bit: any non-zero value is 1
DECIMALS = {30: 0, 31: 0}  # N_DECIMAL_RPMVALUE; other floats N_DECIMAL_SETTINGVALUE = 3


def grbl_float(value: float, decimals: int) -> str:
    """A number as print.c's printFloat writes it: sign, then scaled, +0.5 and truncated (no banker's rounding)."""
    sign = "-" if value < 0 else ""
    digits = str(int(abs(value) * 10 ** decimals + 0.5))
    if decimals:
        digits = digits.rjust(decimals + 1, "0")
        digits = digits[:-decimals] + "." + digits[-decimals:]
    return sign + digits


def store(settings: dict[int, float], key: float, value: float) -> int:
    """Store ``$key=value`` as settings_store_global_setting does; the status code (0 = ok)."""
    if value < 0.0:
        return 4
    if key > 255:
        return 3
    key = int(key)  # the parameter is read as a float and truncated to a byte
    if key not in DEFAULTS:
        return 3
    if key in INTEGER:
        byte = int(math.trunc(value)) & 0xFF  # trunc(value) into a uint8_t
        if key == 0 and byte < 3:
            return 6  # step pulse shorter than 3 us
        if key == 20 and byte and not settings[22]:
            return 10  # soft limits need homing
        settings[key] = (1 if byte else 0) if key in FLAGS else byte
        if key == 22 and not byte:
            settings[20] = 0  # homing off forces soft limits off
    else:
        settings[key] = float(value)
    return 0


def report_lines(settings: dict[int, float]) -> list[str]:
    """``$$``: every setting in GRBL's order and number format."""
    out = []
    for key in DEFAULTS:
        v = settings[key]
        out.append(f"${key}={int(v) & 0xFF}" if key in INTEGER else f"${key}={grbl_float(v, DECIMALS.get(key, 3))}")
    return out
