"""How much memory this process holds: the figure a batch report and convert's summary give."""

from __future__ import annotations

import sys


def memory_mb() -> tuple[float | None, float | None]:
    """(current, peak) resident memory of this process in MB. /proc's VmHWM is this
    process's own peak; ru_maxrss (the fallback) also counts the parent's memory at fork."""
    try:
        with open("/proc/self/status") as f:
            kb = {k: int(v.split()[0]) for k, _, v in (line.partition(":") for line in f) if k in ("VmRSS", "VmHWM")}
        return round(kb["VmRSS"] / 1024, 1), round(kb["VmHWM"] / 1024, 1)
    except (OSError, KeyError, ValueError, IndexError):
        pass
    try:
        import resource

        kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return None, round(kb / (1024 * 1024 if sys.platform == "darwin" else 1024), 1)
    except Exception:  # pragma: no cover - not on POSIX
        return None, None
