"""EiBotBoard transport: streams an ``.ebb`` job to an AxiDraw (or another EBB machine) over USB serial.

One command in flight, answered ``OK`` once the board has room in its motion FIFO; stops at a
stroke's end with the pen up and resumes there; asks the operator at pen changes. The link
lives in ``doodlecam.link.ebb.sender``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from doodlecam.api import Option, Transport


class EbbTransport(Transport):
    name = "ebb"
    summary = "EiBotBoard (AxiDraw) over USB serial: .ebb jobs, flow control by OK, stop/resume at stroke ends"
    extension = ".ebb"
    options = (
        Option("timeout", float, 5.0, "seconds without an answer from the board (beyond the motion it holds)"),
    )

    def send(self, path: Path, target: str | None, options: dict[str, Any], *, restart: bool = False,
             progress: Callable | None = None, log: Callable[[str], None] | None = None,
             controls: Callable[[], str | None] | None = None,
             pen_change: Callable[[int, str], None] | None = None) -> dict:
        """Stream the job at ``path`` to the board on ``target`` (a serial port; "auto" or None finds it by
        its USB id). ``controls()`` may return pause, resume or stop; ``pen_change(pen, what)`` returns once
        the operator has fitted the pen (without it the send stops there, resumable)."""
        from doodlecam.link.ebb.sender import send_ebb
        from doodlecam.link.session import state_file_for

        port = None if target in (None, "", "auto") else target
        return send_ebb(port, Path(path), state_file=state_file_for(Path(path)), timeout=options["timeout"],
                        restart=restart, progress=progress, log=log, controls=controls, pen_change=pen_change)
