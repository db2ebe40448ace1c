"""The simulated PLC's non-volatile memory (docs/protocol.md, "Job identity"): what survives a power cycle.

A real PLC keeps retentive variables; the simulator keeps them in a file of
fixed layout, written in place with one ``pwrite`` each (a killed process
cannot leave one half done, and no rename per command is needed):

* bytes 0-15: the progress word ``magic "DPNV", job_id u32, executed u32,
  reserved u32``, rewritten after every executed command, so a PLC that
  restarts knows the last command it ran and never repeats one;
* bytes 16-...: a JSON record padded with spaces (``REGION`` bytes),
  rewritten when a job starts, is held, or ends: the jobs that ended (id,
  fault, content CRC, Unix time) and the current or held job (its header and
  the session it belongs to).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

_PROGRESS = struct.Struct("<4sIII")
_MAGIC = b"DPNV"
REGION = 32768  # bytes of JSON: 64 ended jobs and one header fit many times over


class NvRam:
    """Load on power-up, ``save()`` the JSON record, ``progress()`` after each command. ``path=None``: volatile."""

    def __init__(self, path: Path | None):
        self.path = Path(path) if path else None
        self.record: dict = {}
        self.executed: tuple[int, int] = (0, 0)  # (job_id, executed) of the progress word
        self._fd: int | None = None
        if self.path is None:
            return
        try:
            raw = self.path.read_bytes()
        except FileNotFoundError:
            raw = b""
        if len(raw) >= _PROGRESS.size:
            magic, job_id, executed, _ = _PROGRESS.unpack_from(raw)
            if magic == _MAGIC:
                self.executed = (job_id, executed)
        try:
            rec = json.loads(raw[_PROGRESS.size:].decode().strip() or "{}")
            self.record = rec if isinstance(rec, dict) else {}
        except (UnicodeDecodeError, ValueError):
            self.record = {}  # a damaged record: start empty, as a PLC with a failed checksum would
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)

    def save(self) -> None:
        if self._fd is None:
            return
        blob = json.dumps(self.record, separators=(",", ":")).encode()
        if len(blob) > REGION:
            raise ValueError(f"non-volatile record of {len(blob)} bytes exceeds {REGION}")
        os.pwrite(self._fd, blob.ljust(REGION, b" "), _PROGRESS.size)

    def progress(self, job_id: int, executed: int) -> None:
        self.executed = (job_id, executed)
        if self._fd is not None:
            os.pwrite(self._fd, _PROGRESS.pack(_MAGIC, job_id, executed, 0), 0)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
