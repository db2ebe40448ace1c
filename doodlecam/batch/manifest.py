"""The batch's state on disk: the manifest of finished files (rewritten atomically) and the
one-batch-per-folder lock.
"""

from __future__ import annotations

import json
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from doodlecam.atomic import write_bytes
from doodlecam.errors import OutputError

MANIFEST_NAME = ".doodlecam-manifest.json"
LOCK_NAME = ".doodlecam-lock"
STAGING_NAME = ".doodlecam-tmp"
MANIFEST_VERSION = 1


# ---------------------------------------------------------------- atomic writes


def write_atomic(path: Path, data: bytes) -> None:
    """Atomically, or an OutputError that says what to do: a full disk ends in one line, not a traceback."""
    try:
        write_bytes(path, data)
    except OSError as e:
        raise OutputError(f"{path}: cannot write ({e.strerror or e}); free some space or fix permissions and re-run "
                          "the same command: finished files are kept") from None


@contextmanager
def locked(out_dir: Path):
    """Hold an exclusive lock on ``out_dir`` (``OUT/.doodlecam-lock``, a filelock.FileLock) for one batch.

    Two batches into one folder would clear each other's staging folder and
    overwrite each other's manifest, so the second one stops with a one-line
    error instead. The kernel drops the lock when its holder exits in any way
    (even SIGKILL), so a lock file left behind never blocks a re-run.
    """
    from filelock import FileLock, Timeout

    path = out_dir / LOCK_NAME
    lock = FileLock(path, timeout=0)  # one attempt: a second batch is refused, not queued
    try:
        lock.acquire()
    except Timeout:
        try:
            holder = path.read_text(errors="replace").strip()
        except OSError:
            holder = ""
        raise OutputError(f"{out_dir}: another doodlecam batch{f' (pid {holder})' if holder.isdigit() else ''} "
                          "is writing to this folder; wait for it to finish or choose another OUT_DIR") from None
    except OSError as e:
        raise OutputError(f"{out_dir}: cannot create {LOCK_NAME} ({e.strerror}); check the folder's permissions") from None
    try:
        path.write_text(f"{os.getpid()}\n")  # only for the message above; the lock is the kernel's, on the inode
        yield
    finally:
        lock.release()


def load_manifest(out_dir: Path) -> dict[str, Any]:
    try:
        data = json.loads((out_dir / MANIFEST_NAME).read_text(encoding="utf-8"))
        if data.get("version") == MANIFEST_VERSION and isinstance(data.get("files"), dict):
            return data
    except (OSError, ValueError):
        pass
    return {"version": MANIFEST_VERSION, "files": {}}




class _Manifest:
    """The manifest, rewritten atomically at most every ``interval`` seconds."""

    def __init__(self, out_dir: Path, interval: float = 0.5):
        self.path = out_dir / MANIFEST_NAME
        self.data = load_manifest(out_dir)
        self.interval = interval
        self._dirty = False
        self._last = 0.0

    @property
    def files(self) -> dict[str, Any]:
        return self.data["files"]

    def record(self, rel: str, entry: dict[str, Any] | None) -> None:
        if entry is None:
            self.files.pop(rel, None)
        else:
            self.files[rel] = entry
        self._dirty = True
        if time.monotonic() - self._last >= self.interval:
            self.flush()

    def flush(self) -> None:
        if self._dirty:
            self.data["files"] = dict(sorted(self.files.items()))
            write_atomic(self.path, json.dumps(self.data, indent=1, sort_keys=True).encode())
            self._dirty = False
        self._last = time.monotonic()


def _up_to_date(entry: dict[str, Any] | None, digest: str, key: str, out_dir: Path) -> bool:
    if not entry or entry.get("input_hash") != digest or entry.get("options_hash") != key:
        return False
    if entry.get("status") == "converted":
        return all((out_dir / o).is_file() for o in entry.get("outputs", []))
    return entry.get("status") == "failed" and not entry.get("retry", True)
