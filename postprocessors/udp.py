"""UDP transport: streams a PLC packet file to a DoodleBot PLC (docs/protocol.md).

A transport plugin is a ``doodlecam.api.Transport`` with ``name``, a one-line
``summary``, the job file ``extension`` it sends, ``options``, and a
``send`` method; register it under the ``doodlecam.transports`` entry-point
group. The link itself lives in ``doodlecam.link.plc.sender``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from doodlecam.api import Option, Transport


class UdpTransport(Transport):
    name = "udp"
    summary = "DoodleBot PLC over UDP: lossless, resumable command stream of a .plc job (docs/protocol.md)"
    extension = ".plc"
    options = (
        Option("timeout", float, 5.0, "seconds without an answer from the PLC before giving up"),
        Option("rto", float, 0.1, "seconds before an unanswered header or stop is sent again"),
        Option("key", str, "", "pre-shared key: sign every datagram with HMAC-SHA256 (the PLC must have the same key)"),
    )

    def send(self, path: Path, target: str, options: dict[str, Any], *, restart: bool = False, cancel: bool = False,
             again: bool = False, progress: Callable | None = None, log: Callable[[str], None] | None = None,
             pen_change: Callable[[int, str], None] | None = None) -> dict:
        """Send (or cancel) the job at ``path`` to ``target`` = HOST:PORT; return a summary dict.

        ``pen_change(pen, what)`` is called where the job pauses for a pen change (the PLC holds it,
        pen up) and returns once the operator has fitted the pen; without it the send stops there.
        """
        from doodlecam.errors import InputError
        from doodlecam.link.plc.sender import UdpSender, parse_target
        from doodlecam.link.session import state_file_for

        host, port = parse_target(target)
        try:
            data = Path(path).read_bytes()
        except OSError as e:
            raise InputError(f"{path}: cannot read ({e.strerror}); check the path") from None
        sender = UdpSender(host, port, data, str(path), state_file=state_file_for(Path(path)),
                           timeout=options["timeout"], rto=options["rto"], restart=restart, again=again,
                           key=options["key"].encode() or None, progress=progress, log=log, pen_change=pen_change)
        if cancel:
            return {"cancelled_job": sender.cancel(), "plc": f"{host}:{port}"}
        r = sender.run()
        return {"plc": f"{host}:{port}", "job_id": r.job_id, "commands": r.commands, "start_at": r.start_at,
                "resumed": r.resumed, "already_done": r.already_done, "underruns": r.underruns,
                "pen_changes": sender.pen_changes,
                "elapsed_s": r.elapsed, **r.stats}
