"""What a GRBL emulator received, checked against a G-code file (tests of the studio's GRBL send)."""

from __future__ import annotations

import re

# lines the streamer adds to pause and resume (pen commands, the resume prefix): nothing else may reach GRBL
ADDED = re.compile(r"M3S0|M3S1000|G21G90G94G17|G0X[-\d.]+Y[-\d.]+|G4P[\d.]+|F[\d.]+")


def check_received(received: list[str], lines) -> list[str]:
    """Assert every line of the file reached GRBL exactly once, in order, and anything else is a
    pause/resume line; return those added lines."""
    j, extra = 0, []
    for text in received:
        if j < len(lines) and text == lines[j].text:
            j += 1
        else:
            extra.append(text)
    assert j == len(lines), f"GRBL got the file's lines up to {j} of {len(lines)}"
    assert all(ADDED.fullmatch(t) for t in extra), extra
    assert len(received) == len(lines) + len(extra)
    return extra
