"""Sending the studio's job to a PLC over UDP (the same UdpSender as ``doodlecam send``).

The send runs in its own thread, owned by the server, not by a page: closing
the tab does not touch it, so the job runs to its end (the PLC never sees a
half-sent job). Stop asks the sender as Ctrl-C does: the PLC stops at the end
of the current stroke with the pen up and holds the job; sending the same job
again resumes it after the last executed command (the PLC's count is the
truth, as for ``doodlecam send``). The built-in simulator lives as long as the
server, so a job it holds can be resumed too.
"""

from __future__ import annotations

import math
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from doodlecam.errors import DoodleError, InputError


@dataclass
class SendState:
    state: str = "idle"  # idle | sending | done | stopped | failed
    target: str = ""
    executed: int = 0
    total: int = 0
    time_left_s: float = 0.0
    position_mm: tuple[float, float] | None = None
    message: str = ""
    version: int = 0  # bumped on every change, for the event stream
    started: float = field(default_factory=time.monotonic)

    def public(self) -> dict[str, Any]:
        pct = 100.0 * self.executed / self.total if self.total else 0.0
        return {"state": self.state, "target": self.target, "executed": self.executed, "total": self.total,
                "percent": round(pct, 2), "time_left_s": round(self.time_left_s, 2),
                "position_mm": self.position_mm, "message": self.message,
                "elapsed_s": round(time.monotonic() - self.started, 2)}


class Sender:
    """At most one send at a time; ``start`` returns at once, ``state`` reports progress."""

    def __init__(self):
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self.s = SendState()
        self._sender = None
        self._sim = None
        self._thread: threading.Thread | None = None
        # The sender's record (job id, owner token, progress): with it a stopped job resumes on the
        # PLC that holds it, which takes it only from the computer that started it (docs/protocol.md).
        self._records = tempfile.TemporaryDirectory(prefix="doodlecam-studio-")

    def _update(self, **kw) -> None:
        with self.changed:
            for k, v in kw.items():
                setattr(self.s, k, v)
            self.s.version += 1
            self.changed.notify_all()

    def snapshot(self) -> tuple[int, dict]:
        with self.lock:
            return self.s.version, self.s.public()

    def wait(self, version: int, timeout: float) -> tuple[int, dict]:
        """The state once its version differs from ``version`` (or after ``timeout`` s)."""
        with self.changed:
            self.changed.wait_for(lambda: self.s.version != version, timeout)
            return self.s.version, self.s.public()

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self, plc_bytes: bytes, machine, target: str, speed: float | None = None, again: bool = False) -> dict:
        """Send to ``target``: 'simulator' (a built-in PLC simulator, ``speed`` x real time;
        None = as fast as it can) or 'HOST:PORT' of a PLC. ``again``: run a job the PLC has
        already finished once more (``doodlecam send --again``)."""
        from doodlecam.link.plc.sender import UdpSender, parse_target, planned_time_left
        from doodlecam.link.plc.simulator import PlcConfig, PlcSimulator

        if self.busy:
            raise InputError("a send is running; stop it or wait for it to finish")
        if speed is not None and not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
            raise InputError(f"speed must be a positive number, got {speed!r}")
        sim = None
        if target == "simulator":
            want = speed or math.inf
            if self._sim is None or self._sim.cfg.speed != want:  # one simulator per speed: it keeps held jobs
                self.close()
                self._sim = PlcSimulator(PlcConfig.from_machine(machine, speed=want)).start()
            sim = self._sim
            host, port = sim.address
        else:
            host, port = parse_target(target, 5005)
        header = None

        def progress(executed: int, total: int, status) -> None:
            pos = None
            if status is not None and header is not None:
                pos = (round(status.x / header.steps_per_mm_x, 2), round(status.y / header.steps_per_mm_y, 2))
            self._update(executed=executed, total=total, position_mm=pos,
                         time_left_s=float(left[min(executed, len(left) - 1)]))

        sender = UdpSender(host, port, plc_bytes, "studio.plc", progress=progress, again=again,
                           state_file=Path(self._records.name) / "send-record.json")
        header = sender.plc_header
        left = planned_time_left(sender.records, header)
        self._sender = sender
        with self.changed:
            self.s = SendState(state="sending", target=target if sim is None else f"PLC simulator {host}:{port}",
                               total=sender.n, time_left_s=float(left[0]), version=self.s.version + 1)
            self.changed.notify_all()
        self._thread = threading.Thread(target=self._run, name="studio-send", daemon=True)
        self._thread.start()
        return self.snapshot()[1]

    def _run(self) -> None:
        from doodlecam.link.session import Paused

        try:
            r = self._sender.run()
            end = dict(state="done", executed=r.commands, time_left_s=0.0,
                       message=f"{r.commands} commands in {r.elapsed:.2f} s"
                       + (f", resumed at command {r.start_at}" if r.resumed else ""))
        except Paused as e:  # the PLC's count, confirmed by its stop (progress reports lag behind it)
            end = dict(state="stopped", message=str(e), executed=self._sender.executed)
        except DoodleError as e:
            end = dict(state="failed", message=str(e))
        except Exception as e:  # never let a send kill the server quietly
            end = dict(state="failed", message=f"send failed: {type(e).__name__}: {e}")
        self._thread = None  # the next send may start as soon as the state says this one ended
        self._update(**end)

    def stop(self) -> dict:
        """Stop at the end of the current stroke, pen up (the sender's Ctrl-C)."""
        if not self.busy:
            raise InputError("no send is running")
        self._sender.interrupts.count += 1  # the sender raises at its next safe point, then stops the PLC
        self._update(message="stopping at the end of the current stroke")
        return self.snapshot()[1]

    def close(self) -> None:
        """Stop the built-in simulator (at server shutdown, or for another speed)."""
        if self._sim is not None:
            self._sim.stop()
            self._sim = None
