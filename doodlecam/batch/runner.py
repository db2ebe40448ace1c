"""Batch conversion of a folder of pictures: parallel, incremental, resumable.

``run_batch`` finds every file a tracer reads under ``in_dir``, converts each
one in a pool of worker processes (or on a Dask cluster) with the same
settings ``doodlecam convert`` takes, and writes the outputs to ``out_dir``,
mirroring the input tree (``IN/sub/a.png`` -> ``OUT/sub/a.plc``, ``.gcode``,
``.svg``).

Safety and resumption:

* A manifest ``OUT/.doodlecam-manifest.json`` records, per input, its content
  hash (BLAKE2b), the hash of the options, the outputs and the figures. It is
  rewritten atomically (temp file + rename) as files finish, so a batch stopped
  at any moment (Ctrl-C, a killed process, a full disk) resumes where it stopped:
  a re-run converts only files whose content or options changed, whose outputs
  are missing, or that never finished. ``force=True`` redoes everything.
* A worker converts into a private staging folder under ``OUT/.doodlecam-tmp``
  and renames the finished outputs into place; a file is entered in the manifest
  only after all its outputs are in place, so nothing half-written is taken for done.
* A failing file never stops the batch: its one-line error is recorded. Errors a
  user can cause (``DoodleError``) are remembered in the manifest and not retried
  until the file or the options change; write errors and internal errors are retried.

* One batch per output folder: an exclusive lock on ``OUT/.doodlecam-lock``; a
  second batch stops with a one-line error. Every check a user can fail (nothing
  to convert, unknown plugin, ...) comes before anything is written.

Heavy imports (the pipeline, NumPy, scikit-image, numba kernels, plugins) load
once per worker process, in the pool initializer, never in the coordinator
when there is nothing to do: a re-run with nothing changed only hashes files.
Workers are replaced every ``recycle_after`` files, so memory cannot grow over
a long batch; report.json records each worker's memory.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from doodlecam.batch.inputs import (
    check_posts,
    file_hash,
    find_inputs,
    nothing_to_convert,
    output_stems,
    supported_extensions,
)
from doodlecam.batch.manifest import STAGING_NAME, _Manifest, _up_to_date, locked
from doodlecam.batch.options import BatchOptions
from doodlecam.batch.report import write_reports
from doodlecam.batch.worker import _one_line, _worker_init, convert_one
from doodlecam.errors import DoodleError, InputError, OutputError
from doodlecam.extras import require

# Files a local worker converts before a fresh process replaces it: bounds what a long
# batch can leak, while start-up (imports, plugins, JIT warm-up) stays rare.
RECYCLE_AFTER = 250



class BatchFailed(DoodleError):
    """Some files of a batch failed (each one is listed in the report)."""

    exit_code = 1


class BatchInterrupted(DoodleError):
    """A batch was stopped (Ctrl-C); what finished is kept and a re-run resumes."""

    exit_code = 130




# ---------------------------------------------------------------- the coordinator


def warnings_for(summary: dict[str, Any] | None) -> list[str]:
    """Things worth a look in an otherwise converted file."""
    if not summary:
        return []
    out = list(summary.get("warnings", []))
    if summary.get("strokes", 0) == 0:
        out.append("nothing to draw")
    for what in ("acceleration", "velocity"):
        r = summary.get(f"worst_{what}_ratio", 0.0)
        if r > 1.0 + 1e-6:
            out.append(f"{what} {r:.4f}x the limit")
    return out


@dataclass
class BatchResult:
    files: list[dict[str, Any]]
    elapsed_s: float
    interrupted: bool = False
    workers: list[dict[str, Any]] = field(default_factory=list)  # see _Workers

    @property
    def peak_rss_mb(self) -> float | None:
        """The largest peak resident memory of any worker, MB."""
        return max((w["peak_rss_mb"] for w in self.workers if w["peak_rss_mb"] is not None), default=None)

    def count(self, status: str) -> int:
        return sum(1 for f in self.files if f["status"] == status)

    @property
    def failed(self) -> int:
        return self.count("failed")

    @property
    def ok(self) -> bool:
        return self.failed == 0 and not self.interrupted


class _Workers:
    """Memory per worker process, from the figures each file's record brings back:
    resident memory after its first and its last file, and its peak."""

    def __init__(self):
        self.by_id: dict[tuple, dict[str, Any]] = {}

    def add(self, rec: dict[str, Any]) -> None:
        worker, rss = rec.pop("worker", None), rec.pop("rss_mb", None)
        if not worker:
            return
        w = self.by_id.setdefault(tuple(worker), {"host": worker[0], "pid": worker[1], "files": 0,
                                                  "rss_mb_first": rss, "rss_mb_last": rss, "peak_rss_mb": None})
        w["files"] += 1
        w["rss_mb_last"] = rss
        if rec.get("peak_rss_mb") is not None:
            w["peak_rss_mb"] = max(w["peak_rss_mb"] or 0.0, rec["peak_rss_mb"])




def run_batch(in_dir: str | os.PathLike, out_dir: str | os.PathLike, options: BatchOptions, *,
              recursive: bool = False, include: Iterable[str] = (), exclude: Iterable[str] = (),
              jobs: int | None = None, force: bool = False, scheduler: str | None = None,
              recycle_after: int = RECYCLE_AFTER, progress: bool | None = None,
              on_result: Callable[[dict[str, Any]], None] | None = None,
              before_work: Callable[[], None] | None = None) -> BatchResult:
    """Convert a folder. See the module docstring; ``doodlecam batch`` is the CLI.

    ``jobs``: worker processes (default ``os.cpu_count()``). ``recycle_after``: files per
    local worker before it is replaced by a fresh one (0 = never). ``scheduler``: a Dask
    distributed scheduler address; workers must see ``in_dir`` and ``out_dir`` at
    the same paths. ``progress``: a tqdm bar (None = only on a terminal). ``before_work``: called
    once every check passed, just before files are converted (the CLI's first-run notice).
    Writes the manifest, ``report.json`` and ``index.html`` into ``out_dir``.
    """
    t_start = time.perf_counter()
    in_dir, out_dir = Path(in_dir), Path(out_dir)
    if not in_dir.is_dir():
        raise InputError(f"{in_dir}: not a folder; give the folder of pictures to convert")
    if in_dir.resolve() == out_dir.resolve():
        raise OutputError(f"{out_dir}: the output folder is the input folder; choose another OUT_DIR")
    # Every check a user can fail comes before anything is written: a bad option
    # is one error (exit 2) now, not one failure per file after its planning.
    from doodlecam.checks import check_scheduler, check_settings
    from doodlecam.machine import load_machine

    key = options.fingerprint()
    check_posts(options.posts, options.plugin_dirs)
    exts = supported_extensions(options.tracer, options.plugin_dirs)
    rels, unsupported = find_inputs(in_dir, out_dir, recursive, include, exclude, exts)
    if not rels:
        raise nothing_to_convert(in_dir, out_dir, recursive, bool(include or exclude), unsupported)
    check_settings(options, load_machine(options.machine), [in_dir / r for r in rels], out_dir)
    if isinstance(scheduler, str):
        check_scheduler(scheduler)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{out_dir}: cannot create output folder ({e.strerror}); choose another OUT_DIR") from None
    with locked(out_dir):
        stems = output_stems(rels)
        manifest = _Manifest(out_dir)
        shutil.rmtree(out_dir / STAGING_NAME, ignore_errors=True)  # leftovers of a killed run (we hold the lock)

        records: dict[str, dict[str, Any]] = {}
        todo: list[str] = []
        digests: dict[str, str] = {}
        for rel in rels:
            try:
                digests[rel] = file_hash(in_dir / rel)
            except OSError as e:
                records[rel] = {"input": rel, "status": "failed", "outputs": [], "summary": None,
                                "error": _one_line(f"{in_dir / rel}: cannot read ({e.strerror}); check the file")}
                continue
            entry = manifest.files.get(rel)
            if not force and _up_to_date(entry, digests[rel], key, out_dir):
                records[rel] = {"input": rel, "status": "skipped" if entry["status"] == "converted" else "failed",
                                "error": entry.get("error"), "outputs": entry.get("outputs", []),
                                "summary": entry.get("summary"), "cached": True}
            else:
                todo.append(rel)
        for rel in unsupported:
            records[rel] = {"input": rel, "status": "unsupported",
                            "error": f"no tracer reads '{Path(rel).suffix.lower() or 'files without extension'}' files",
                            "outputs": [], "summary": None}

        workers = _Workers()

        def finished(rec: dict[str, Any]) -> None:
            rel = rec["input"]
            workers.add(rec)
            records[rel] = rec
            if rec["status"] == "converted" or not rec.get("retry", True):
                manifest.record(rel, {"input_hash": digests[rel], "options_hash": key, "status": rec["status"],
                                      "error": rec["error"], "retry": rec.get("retry", False),
                                      "outputs": rec["outputs"], "summary": rec["summary"]})
            else:
                manifest.record(rel, None)  # retried next time
            if on_result is not None:
                on_result(rec)

        interrupted = False
        if todo:
            if before_work is not None:
                before_work()
            try:
                if scheduler:
                    interrupted = _run_dask(todo, stems, options, key, in_dir, out_dir, scheduler, progress, finished)
                else:
                    interrupted = _run_local(todo, stems, options, key, in_dir, out_dir, jobs, progress, finished,
                                             recycle_after)
            finally:
                shutil.rmtree(out_dir / STAGING_NAME, ignore_errors=True)
                manifest.flush()
        manifest.flush()
        files = [records[r] for r in sorted(records)]
        for f in files:
            f["warnings"] = warnings_for(f.get("summary"))
        result = BatchResult(files=files, elapsed_s=round(time.perf_counter() - t_start, 3), interrupted=interrupted,
                             workers=list(workers.by_id.values()))
        write_reports(result, in_dir, out_dir, options, key)
        return result


def _progress_bar(total: int, progress: bool | None):
    from tqdm import tqdm

    return tqdm(total=total, unit="file", disable=None if progress is None else not progress,
                dynamic_ncols=True, file=sys.stderr,
                bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} files [{elapsed}<{remaining}]{postfix}")


def _run_local(todo, stems, options, key, in_dir, out_dir, jobs, progress, finished, recycle_after) -> bool:
    """Process pools ('spawn': safe with numba and threads). Returns True if interrupted.

    Recycling: a pool takes ``jobs * recycle_after`` files, then is retired (its workers
    finish the files they hold and exit) while a fresh pool takes the next files, so
    memory cannot grow over a long batch. Not ``max_tasks_per_child``: it deadlocks on
    Python 3.11-3.14 (cpython gh-115634).
    A worker that dies (killed, out of memory) breaks its pool and fails every file the
    pool holds; each of those is tried once more in a fresh pool, and fails if it happens again.
    """
    import multiprocessing
    from collections import deque
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    jobs = max(1, min(jobs or os.cpu_count() or 1, len(todo)))
    quota = jobs * recycle_after if recycle_after and recycle_after > 0 else 0
    ctx = multiprocessing.get_context("spawn")
    src, dst = str(in_dir.resolve()), str(out_dir.resolve())
    bar = _progress_bar(len(todo), progress)
    failures = 0
    pools: list = []  # every pool started; the last one takes new files
    used = 0  # files given to the current pool
    pending: dict = {}  # future -> input
    queue = deque(todo)
    died: set[str] = set()  # inputs whose worker died once
    interrupted = False

    def new_pool():
        nonlocal used
        pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_worker_init, initargs=(options, key))
        pools.append(pool)
        used = 0

    def submit_more():
        nonlocal used
        while queue and len(pending) < 2 * jobs:  # a short queue: Ctrl-C leaves little to cancel
            if not pools or (quota and used >= quota):
                if pools:
                    pools[-1].shutdown(wait=False)  # retire: its workers finish what they hold, then exit
                new_pool()
            rel = queue[0]
            try:
                fut = pools[-1].submit(convert_one, options, key, src, dst, rel, stems[rel])
            except BrokenProcessPool:
                new_pool()
                continue
            queue.popleft()
            used += 1
            pending[fut] = rel

    def take(fut):
        nonlocal failures
        rel = pending.pop(fut)
        try:
            rec = fut.result()
        except BrokenProcessPool:
            if rel not in died:  # maybe only a bystander of another file's crash: once more, in a fresh pool
                died.add(rel)
                queue.append(rel)
                return
            rec = {"input": rel, "status": "failed", "retry": True, "outputs": [], "summary": None,
                   "error": "internal error: the worker process died twice while converting it "
                            "(killed, or out of memory?); re-run to retry"}
        except Exception as e:
            rec = {"input": rel, "status": "failed", "retry": True, "outputs": [], "summary": None,
                   "error": _one_line(f"internal error: {type(e).__name__}: {e}")}
        if rec["status"] == "failed":
            failures += 1
        mem = rec.get("rss_mb")
        finished(rec)
        bar.update(1)
        bar.set_postfix_str(", ".join(([f"{failures} failed"] if failures else [])
                                      + ([f"worker {mem:.0f} MB"] if mem else [])), refresh=False)

    try:
        submit_more()
        while pending:
            done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
            for fut in done:
                take(fut)
            submit_more()
    except KeyboardInterrupt:
        interrupted = True
        bar.write("doodlecam: interrupted; finishing the files in progress (Ctrl-C again to stop now)", file=sys.stderr)
        queue.clear()
        for fut in list(pending):
            if fut.cancel():
                pending.pop(fut)
        try:
            while pending:
                done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                for fut in done:
                    take(fut)
        except KeyboardInterrupt:
            for p in multiprocessing.active_children():  # stop now: kill our own workers (every pool's)
                p.terminate()
    finally:
        for pool in pools:
            pool.shutdown(wait=True, cancel_futures=True)
        bar.close()
    return interrupted


def _run_dask(todo, stems, options, key, in_dir, out_dir, scheduler, progress, finished) -> bool:
    """Submit to a Dask distributed cluster; results come back to this process,
    which alone writes the manifest and reports. Returns True if interrupted."""
    require("dask", "--scheduler")
    from distributed import Client, as_completed

    bar = _progress_bar(len(todo), progress)
    failures = 0
    interrupted = False
    try:
        client = Client(scheduler, timeout=10) if isinstance(scheduler, str) else scheduler
    except (OSError, TimeoutError, ValueError) as e:  # reachable (checked before) but no Dask scheduler answers
        raise DoodleError(f"--scheduler {scheduler}: no Dask scheduler answers there ({type(e).__name__}: {_one_line(str(e))}); "
                          "check the address") from None
    own = isinstance(scheduler, str)
    futures = []
    try:
        futures = [client.submit(convert_one, options, key, str(in_dir.resolve()), str(out_dir.resolve()), rel, stems[rel],
                                 key=f"doodlecam-{key}-{hashlib.blake2b(rel.encode(), digest_size=8).hexdigest()}",
                                 pure=False)
                   for rel in todo]
        rel_of = {f.key: rel for f, rel in zip(futures, todo)}
        for fut in as_completed(futures):
            rel = rel_of[fut.key]
            try:
                rec = fut.result()
                rec["input"] = rel
            except Exception as e:
                rec = {"input": rel, "status": "failed", "retry": True, "outputs": [], "summary": None,
                       "error": _one_line(f"internal error: {type(e).__name__}: {e}")}
            failures += rec["status"] == "failed"
            finished(rec)
            bar.update(1)
            bar.set_postfix_str(f"{failures} failed" if failures else "", refresh=False)
    except KeyboardInterrupt:
        interrupted = True
        client.cancel(futures)
    finally:
        bar.close()
        if own:
            client.close()
    return interrupted
