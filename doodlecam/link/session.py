"""What every machine link shares: its errors, the resume-state file kept next to a job, and
Ctrl-C handling that stops a job cleanly with the pen up.
"""

from __future__ import annotations

import json
import os
import zlib
from pathlib import Path

from doodlecam.atomic import write_bytes
from doodlecam.errors import DoodleError


class LinkError(DoodleError):
    """The machine link failed: no answer, refused, port missing, machine fault."""


class Paused(DoodleError):
    """The user stopped the job (Ctrl-C); it can be resumed by sending it again."""

    exit_code = 130




# ---------------------------------------------------------------- state file

def state_file_for(job_path: Path) -> Path:
    """Where the resume record of a job lives: next to it, else in the user's cache."""
    job_path = Path(job_path)
    here = job_path.with_name(job_path.name + ".send.json")
    if os.access(job_path.parent, os.W_OK):
        return here
    base = Path(os.environ.get("XDG_STATE_HOME", Path.home() / ".local" / "state")) / "doodlecam"
    return base / f"{zlib.crc32(str(job_path.resolve()).encode()):08x}-{job_path.name}.send.json"


def load_state(path: Path | None, crc: int) -> dict | None:
    """The saved record for the job with this CRC, or None (missing, unreadable or another job)."""
    if path is None:
        return None
    try:
        st = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(st, dict) or st.get("job_crc") != crc or not isinstance(st.get("job_id"), int):
        return None
    return st


def save_state(path: Path | None, state: dict) -> None:
    """Write the record atomically (temp file + rename): a kill never leaves half a file."""
    if path is None:
        return
    write_bytes(Path(path), json.dumps(state).encode(), mode=0o600)  # a private record, as mkstemp makes it


def clear_state(path: Path | None) -> None:
    if path is not None:
        try:
            Path(path).unlink()
        except FileNotFoundError:
            pass


# ---------------------------------------------------------------- Ctrl-C

class Interrupts:
    """Ctrl-C as a counter, turned into KeyboardInterrupt only at safe points.

    A KeyboardInterrupt raised in the middle of writing a line to the port
    would lose track of what the machine received; instead the handler only
    counts, and ``check()`` (called where no I/O is half done) raises once
    the count reaches ``raise_at``. A third Ctrl-C raises at once, as an
    escape hatch.
    """

    def __init__(self):
        self.count = 0
        self.raise_at = 1
        self._old = None

    def _handler(self, signum, frame):
        self.count += 1
        if self.count >= max(self.raise_at, 2) + 1:
            raise KeyboardInterrupt

    def check(self) -> None:
        if self.count >= self.raise_at:
            self.raise_at = self.count + 1
            raise KeyboardInterrupt

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
