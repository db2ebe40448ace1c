"""Serial transport: streams G-code to a GRBL-style controller (pyserial).

Character-counting flow control, ``$`` writes in send-and-wait mode, check
mode as a dry run, status reports for progress; the link lives in
``doodlecam.link.grbl.streamer``. Register transports under ``doodlecam.transports``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from doodlecam.api import Option, Transport


class SerialTransport(Transport):
    name = "serial"
    summary = "GRBL over serial: character-counting G-code streamer with check mode and resume"
    extension = ".gcode"
    options = (
        Option("baud", int, 115200, "serial baud rate (GRBL 1.1: 115200)"),
        Option("timeout", float, 5.0, "seconds without an answer from GRBL before giving up"),
        Option("connect_timeout", float, 3.0, "seconds to wait for GRBL after opening the port"),
    )

    def send(self, path: Path, target: str, options: dict[str, Any], *, restart: bool = False, check: bool = False,
             from_line: int | None = None, progress: Callable | None = None,
             log: Callable[[str], None] | None = None, controls: Callable[[], str | None] | None = None,
             pen_change: Callable[[int | None, str], None] | None = None) -> dict:
        """Stream the G-code file at ``path`` to the serial port ``target``; return a summary dict.

        ``controls()`` (optional) returns pause, resume, hold, feed+, feed-, feed= or stop while streaming.
        ``pen_change(pen, what)`` is called where GRBL holds at a pen change (M0, pen up) and returns once
        the operator has fitted the pen; without it the send stops there (resumable).
        """
        from doodlecam.link.grbl.streamer import send_gcode
        from doodlecam.link.session import state_file_for

        return send_gcode(target, Path(path), baud=options["baud"], check=check, restart=restart,
                          from_line=from_line, timeout=options["timeout"],
                          connect_timeout=options["connect_timeout"], state_file=state_file_for(Path(path)),
                          progress=progress, log=log, controls=controls, pen_change=pen_change)
