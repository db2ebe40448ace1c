"""Writing files so that nobody ever sees half of one.

Every file goes to a temporary file beside its target and is renamed into
place only when all of them are complete; on any error the temporaries are
removed and the error re-raised for the caller to phrase. Used for every
output: post files, figures, reports, manifests, tables, state files.
"""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import threading
from pathlib import Path
from typing import BinaryIO, Callable, Iterable, Union

Content = Union[bytes, Callable[[BinaryIO], None]]  # the bytes, or a function that writes them


renamed = 0  # files this process has put in place (the CLI says whether Ctrl-C left any)


@contextlib.contextmanager
def _no_interrupt():
    """Ctrl-C held back while the block runs and delivered after it. (A handler, not a signal
    mask: NumPy's BLAS threads would take a process-directed SIGINT the main thread blocks.)"""
    old = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or old is None:
        yield  # Python runs handlers, and raises KeyboardInterrupt, only in the main thread
        return
    got: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
        if got:
            signal.raise_signal(signal.SIGINT)


def _usual_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def replace_all(items: Iterable[tuple[Path, Content]], mode: int | None = None) -> list[Path]:
    """Write each (path, content) atomically, all or none. ``mode``: file
    permissions (default the usual 0666 less the umask; mkstemp alone gives 0600)."""
    global renamed
    items = [(Path(p), c) for p, c in items]
    mode = _usual_mode() if mode is None else mode
    temps: list[str] = []
    try:
        for path, content in items:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
            temps.append(tmp)
            with os.fdopen(fd, "wb") as f:
                if callable(content):
                    content(f)
                else:
                    f.write(content)
            os.chmod(tmp, mode)
        with _no_interrupt():  # all renamed or none: Ctrl-C waits the microseconds this takes
            for tmp, (path, _) in zip(temps, items):
                os.replace(tmp, path)
                renamed += 1
    except BaseException:
        for tmp in temps:
            Path(tmp).unlink(missing_ok=True)
        raise
    return [p for p, _ in items]


def write_bytes(path: Path, data: Content, mode: int | None = None) -> Path:
    """One file, atomically."""
    return replace_all([(path, data)], mode)[0]
