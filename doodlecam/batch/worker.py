"""The worker side of a batch: one file converted in a worker process.
"""

from __future__ import annotations

import os
import shutil
import socket
import tempfile
import time
from pathlib import Path
from typing import Any

from doodlecam.batch.manifest import STAGING_NAME
from doodlecam.batch.options import BatchOptions
from doodlecam.errors import DoodleError, OutputError
from doodlecam.memory import memory_mb

# ---------------------------------------------------------------- the worker side

_SETTINGS: dict[str, Any] = {}  # options fingerprint -> Settings, per worker process


def _worker_init(options: BatchOptions, key: str) -> None:
    """Pool initializer: import the pipeline and load plugins once per worker."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the coordinator decides how to stop
    _exit_with_parent()
    try:
        _settings_for(options, key)
    except Exception:  # an initializer that raises breaks the pool; convert_one reports it per file instead
        pass


def _exit_with_parent() -> None:
    """End this worker as soon as its coordinator process is gone (killed with -9, crashed):
    a watch thread waits on multiprocessing's parent sentinel (a pipe or handle that becomes
    ready when the parent exits, on every platform) and leaves without cleanup, as a killed
    coordinator would want; the next run of the batch removes the staging files."""
    import multiprocessing
    import threading
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    if parent is None or parent.sentinel is None:  # not started by a pool (tests call convert_one directly)
        return

    def watch():
        wait([parent.sentinel])
        os._exit(3)

    threading.Thread(target=watch, name="doodlecam-parent-watch", daemon=True).start()


def _settings_for(options: BatchOptions, key: str):
    s = _SETTINGS.get(key)
    if s is None:
        from doodlecam import registry

        s = options.settings()
        for post in s.posts:  # load the plugins now, not per file
            registry.get("postprocessor", post, s.plugin_dirs)
        _SETTINGS.clear()
        _SETTINGS[key] = s
    return s


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def convert_one(options: BatchOptions, key: str, in_dir: str, out_dir: str, rel: str, stem: str) -> dict[str, Any]:
    """Convert one input; never raises. Returns a result record for the coordinator."""
    from doodlecam.pipeline import convert

    t0 = time.perf_counter()
    src = Path(in_dir) / rel
    out_root = Path(out_dir)
    rec: dict[str, Any] = {"input": rel, "status": "failed", "error": None, "retry": False,
                           "outputs": [], "summary": None}
    staging = None
    try:
        settings = _settings_for(options, key)
        staging_root = out_root / STAGING_NAME
        staging_root.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix="job-", dir=staging_root))
        result = convert(src, staging, settings)
        final = out_root / stem
        final.parent.mkdir(parents=True, exist_ok=True)
        outputs = []
        for p in result.outputs:  # convert wrote them atomically with the usual mode: just move them
            suffix = p.name[len(src.stem):]
            target = final.parent / (final.name + suffix)
            os.replace(p, target)
            outputs.append(target.relative_to(out_root).as_posix())
        summary = result.summary()
        summary["source"] = rel
        summary["outputs"] = outputs
        rec.update(status="converted", outputs=outputs, summary=summary)
    except OutputError as e:
        rec.update(error=_one_line(e), retry=True)
    except DoodleError as e:
        rec.update(error=_one_line(e))
    except OSError as e:  # staging / rename trouble: a full disk, permissions
        rec.update(error=_one_line(f"{src}: cannot write output ({e}); check space and permissions"), retry=True)
    except Exception as e:
        rec.update(error=_one_line(f"internal error: {type(e).__name__}: {e}"), retry=True)
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
    rec["seconds"] = round(time.perf_counter() - t0, 3)
    rec["rss_mb"], rec["peak_rss_mb"] = memory_mb()
    rec["worker"] = [socket.gethostname(), os.getpid()]
    return rec
