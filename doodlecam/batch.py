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

import dataclasses
import fnmatch
import hashlib
import json
import os
import shutil
import socket
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from . import __version__
from .atomic import write_bytes
from .errors import DoodleError, InputError, OutputError
from .options import ConvertOptions

MANIFEST_NAME = ".doodlecam-manifest.json"
LOCK_NAME = ".doodlecam-lock"
STAGING_NAME = ".doodlecam-tmp"
REPORT_NAME = "report.json"
INDEX_NAME = "index.html"
MANIFEST_VERSION = 1
# Files a local worker converts before a fresh process replaces it: bounds what a long
# batch can leak, while start-up (imports, plugins, JIT warm-up) stays rare.
RECYCLE_AFTER = 250



class BatchFailed(DoodleError):
    """Some files of a batch failed (each one is listed in the report)."""

    exit_code = 1


class BatchInterrupted(DoodleError):
    """A batch was stopped (Ctrl-C); what finished is kept and a re-run resumes."""

    exit_code = 130


# ---------------------------------------------------------------- options


@dataclass(frozen=True, kw_only=True)
class BatchOptions(ConvertOptions):
    """Everything ``convert`` takes, as plain picklable values: the machine by name.

    ``settings()`` builds the pipeline's ``Settings`` (importing the pipeline),
    which only workers do.
    """

    machine: str = "doodlebot"

    def settings(self):
        from .machine import load_machine
        from .pipeline import Settings

        # the same fields as Settings, copied (asdict copies the dicts), the profile loaded
        return Settings(**{**dataclasses.asdict(self), "machine": load_machine(self.machine)})

    def fingerprint(self) -> str:
        """Hash of everything that changes the outputs: options, the machine profile as
        parsed, drop-in plugin sources and the doodlecam version."""
        from .machine import load_machine

        machine = dataclasses.asdict(load_machine(self.machine))
        machine.pop("source", None)  # where the profile lives does not change the output
        plugin_sources = {}
        for d in self.plugin_dirs:
            for p in sorted(Path(d).glob("*.py")):
                plugin_sources[str(p)] = hashlib.blake2b(p.read_bytes(), digest_size=16).hexdigest()
        blob = {
            "doodlecam": __version__,
            "options": {k: v for k, v in dataclasses.asdict(self).items() if k not in ("machine", "plugin_dirs")},
            "machine": machine,
            "plugins": plugin_sources,
        }
        text = json.dumps(blob, sort_keys=True, default=str)
        return hashlib.blake2b(text.encode(), digest_size=16).hexdigest()


# ---------------------------------------------------------------- finding inputs


def supported_extensions(tracer: str | None = None, plugin_dirs: Iterable[str] = ()) -> set[str]:
    """File extensions (lower case, with the dot) some tracer reads; the named one's only if given."""
    from . import registry

    if tracer:
        return set(registry.get("tracer", tracer, plugin_dirs).extensions)
    exts: set[str] = set()
    for info in registry.discover(plugin_dirs):
        if info.kind == "tracer":
            try:
                exts |= set(info.load().extensions)
            except DoodleError:
                continue
    return exts


def check_posts(posts: Iterable[str], plugin_dirs: Iterable[str] = ()) -> None:
    """A misspelt post is one error now, not one per file (names only: loading stays in the workers)."""
    from . import registry

    known = {i.name for i in registry.discover(plugin_dirs) if i.kind == "postprocessor"}
    for post in posts:
        if post not in known:
            registry.get("postprocessor", post, plugin_dirs)  # raises the usual "unknown ...; available: ..."


def nothing_to_convert(in_dir: Path, out_dir: Path, recursive: bool, filtered: bool,
                       unsupported: list[str]) -> InputError:
    """The one-line error for a folder with no file to convert, saying what to try."""
    where = " matching --include/--exclude" if filtered else ""
    if unsupported:
        types = sorted({Path(u).suffix.lower() or "(no extension)" for u in unsupported})
        found = (f"only {len(unsupported)} file{'s' if len(unsupported) != 1 else ''}{where}, of types no tracer reads "
                 f"({', '.join(types[:4])}{', ...' if len(types) > 4 else ''})")
    else:
        found = f"no files{where}"
    hints = []
    out_res = out_dir.resolve()
    if not recursive and any(p.is_dir() and not p.name.startswith(".") and p.resolve() != out_res
                             for p in in_dir.iterdir()):
        hints.append("add -r to convert sub-folders")
    if filtered:
        hints.append("loosen --include/--exclude")
    hints.append("put pictures there ('doodlecam plugins' lists the file types)")
    return InputError(f"{in_dir}: nothing to convert, {found}; " + " or ".join(hints))


def _matches(rel: str, patterns: Iterable[str]) -> bool:
    name = rel.rsplit("/", 1)[-1]
    return any(fnmatch.fnmatchcase(rel, p) or ("/" not in p and fnmatch.fnmatchcase(name, p)) for p in patterns)


def find_inputs(in_dir: Path, out_dir: Path | None = None, recursive: bool = False,
                include: Iterable[str] = (), exclude: Iterable[str] = (),
                extensions: set[str] = frozenset()) -> tuple[list[str], list[str]]:
    """(supported, unsupported) input paths relative to ``in_dir`` (POSIX style, sorted).

    Hidden files and folders (a leading dot) and the output folder are skipped.
    ``include``/``exclude`` are globs matched against the relative path, and
    against the file name when the pattern has no ``/``.
    """
    include, exclude = tuple(include), tuple(exclude)
    out_res = out_dir.resolve() if out_dir is not None else None
    supported, unsupported = [], []
    for root, dirs, files in os.walk(in_dir):
        rootp = Path(root)
        if not recursive:
            dirs[:] = []
        else:
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and (rootp / d).resolve() != out_res)
        for f in files:
            if f.startswith("."):
                continue
            rel = (rootp / f).relative_to(in_dir).as_posix()
            if include and not _matches(rel, include):
                continue
            if exclude and _matches(rel, exclude):
                continue
            (supported if Path(f).suffix.lower() in extensions else unsupported).append(rel)
    return sorted(supported), sorted(unsupported)


def output_stems(rels: list[str]) -> dict[str, str]:
    """Output path stem (relative, POSIX) per input: ``sub/a.png`` -> ``sub/a``.

    Two inputs that would share a stem in one folder (``a.png`` and ``a.jpg``)
    both get their extension in the name instead (``a_png``, ``a_jpg``), so names
    stay deterministic and nothing is overwritten.
    """
    def plain(rel):
        p = Path(rel)
        return (p.parent / p.stem).as_posix()

    counts: dict[str, int] = {}
    for rel in rels:
        k = plain(rel).lower()
        counts[k] = counts.get(k, 0) + 1
    out = {}
    for rel in rels:
        p = Path(rel)
        out[rel] = plain(rel) if counts[plain(rel).lower()] == 1 else (p.parent / (p.stem + "_" + p.suffix[1:])).as_posix()
    return out


def file_hash(path: Path) -> str:
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


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
    """Hold an exclusive lock on ``out_dir`` (``OUT/.doodlecam-lock``) for one batch.

    Two batches into one folder would clear each other's staging folder and
    overwrite each other's manifest, so the second one stops with a one-line
    error instead. The kernel drops the lock when its holder exits in any way
    (even SIGKILL), so a stale lock file never blocks a re-run.
    """
    path = out_dir / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as e:
        raise OutputError(f"{out_dir}: cannot create {LOCK_NAME} ({e.strerror}); check the folder's permissions") from None
    try:
        if not _try_lock(fd):
            holder = os.read(fd, 32).decode(errors="replace").strip()
            raise OutputError(f"{out_dir}: another doodlecam batch{f' (pid {holder})' if holder.isdigit() else ''} "
                              "is writing to this folder; wait for it to finish or choose another OUT_DIR")
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())  # only for the message above
        yield
    finally:
        os.close(fd)  # releases the lock


def _try_lock(fd: int) -> bool:
    try:
        import fcntl
    except ImportError:  # Windows
        import msvcrt

        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False


def load_manifest(out_dir: Path) -> dict[str, Any]:
    try:
        data = json.loads((out_dir / MANIFEST_NAME).read_text(encoding="utf-8"))
        if data.get("version") == MANIFEST_VERSION and isinstance(data.get("files"), dict):
            return data
    except (OSError, ValueError):
        pass
    return {"version": MANIFEST_VERSION, "files": {}}


# ---------------------------------------------------------------- the worker side

_SETTINGS: dict[str, Any] = {}  # options fingerprint -> Settings, per worker process


def _worker_init(options: BatchOptions, key: str) -> None:
    """Pool initializer: import the pipeline and load plugins once per worker."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the coordinator decides how to stop
    try:
        _settings_for(options, key)
    except Exception:  # an initializer that raises breaks the pool; convert_one reports it per file instead
        pass


def _settings_for(options: BatchOptions, key: str):
    s = _SETTINGS.get(key)
    if s is None:
        from . import pipeline, registry  # noqa: F401  (the heavy import, once)

        s = options.settings()
        for post in s.posts:  # load the plugins now, not per file
            registry.get("postprocessor", post, s.plugin_dirs)
        _SETTINGS.clear()
        _SETTINGS[key] = s
    return s


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _memory_mb() -> tuple[float | None, float | None]:
    """(current, peak) resident memory of this process in MB. /proc's VmHWM is this
    process's own peak; ru_maxrss (the fallback) also counts the parent's memory at fork."""
    try:
        with open("/proc/self/status") as f:
            kb = {k: int(v.split()[0]) for k, _, v in (line.partition(":") for line in f) if k in ("VmRSS", "VmHWM")}
        return round(kb["VmRSS"] / 1024, 1), round(kb["VmHWM"] / 1024, 1)
    except (OSError, KeyError, ValueError, IndexError):
        pass
    try:
        import resource

        kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return None, round(kb / (1024 * 1024 if sys.platform == "darwin" else 1024), 1)
    except Exception:  # pragma: no cover - not on POSIX
        return None, None


def convert_one(options: BatchOptions, key: str, in_dir: str, out_dir: str, rel: str, stem: str) -> dict[str, Any]:
    """Convert one input; never raises. Returns a result record for the coordinator."""
    from .pipeline import convert

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
    rec["rss_mb"], rec["peak_rss_mb"] = _memory_mb()
    rec["worker"] = [socket.gethostname(), os.getpid()]
    return rec


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


def run_batch(in_dir: str | os.PathLike, out_dir: str | os.PathLike, options: BatchOptions, *,
              recursive: bool = False, include: Iterable[str] = (), exclude: Iterable[str] = (),
              jobs: int | None = None, force: bool = False, scheduler: str | None = None,
              recycle_after: int = RECYCLE_AFTER, progress: bool | None = None,
              on_result: Callable[[dict[str, Any]], None] | None = None) -> BatchResult:
    """Convert a folder. See the module docstring; ``doodlecam batch`` is the CLI.

    ``jobs``: worker processes (default ``os.cpu_count()``). ``recycle_after``: files per
    local worker before it is replaced by a fresh one (0 = never). ``scheduler``: a Dask
    distributed scheduler address; workers must see ``in_dir`` and ``out_dir`` at
    the same paths. ``progress``: a tqdm bar (None = only on a terminal).
    Writes the manifest, ``report.json`` and ``index.html`` into ``out_dir``.
    """
    t_start = time.perf_counter()
    in_dir, out_dir = Path(in_dir), Path(out_dir)
    if not in_dir.is_dir():
        raise InputError(f"{in_dir}: not a folder; give the folder of pictures to convert")
    if in_dir.resolve() == out_dir.resolve():
        raise OutputError(f"{out_dir}: the output folder is the input folder; choose another OUT_DIR")
    # Every check a user can fail comes before anything is written.
    key = options.fingerprint()
    check_posts(options.posts, options.plugin_dirs)
    exts = supported_extensions(options.tracer, options.plugin_dirs)
    rels, unsupported = find_inputs(in_dir, out_dir, recursive, include, exclude, exts)
    if not rels:
        raise nothing_to_convert(in_dir, out_dir, recursive, bool(include or exclude), unsupported)
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
    processes: list[dict] = []  # each pool's pid -> process map (shutdown(wait=False) drops the pool's own reference)
    used = 0  # files given to the current pool
    pending: dict = {}  # future -> input
    queue = deque(todo)
    died: set[str] = set()  # inputs whose worker died once
    interrupted = False

    def new_pool():
        nonlocal used
        pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_worker_init, initargs=(options, key))
        pools.append(pool)
        processes.append(pool._processes)
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
            for procs in processes:  # stop now: kill our own workers
                for p in list(procs.values()):
                    p.terminate()
    finally:
        for pool in pools:
            pool.shutdown(wait=True, cancel_futures=True)
        bar.close()
    return interrupted


def _run_dask(todo, stems, options, key, in_dir, out_dir, scheduler, progress, finished) -> bool:
    """Submit to a Dask distributed cluster; results come back to this process,
    which alone writes the manifest and reports. Returns True if interrupted."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise DoodleError("--scheduler needs Dask: pip install 'doodlecam[dask]'") from None
    bar = _progress_bar(len(todo), progress)
    failures = 0
    interrupted = False
    client = Client(scheduler) if isinstance(scheduler, str) else scheduler
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


# ---------------------------------------------------------------- reports


def write_reports(result: BatchResult, in_dir: Path, out_dir: Path, options: BatchOptions, key: str) -> None:
    from .report import index_html

    report = {
        "doodlecam": __version__,
        "input_dir": str(in_dir),
        "output_dir": str(out_dir),
        "options": dataclasses.asdict(options),
        "options_hash": key,
        "elapsed_s": result.elapsed_s,
        "interrupted": result.interrupted,
        "counts": {s: result.count(s) for s in ("converted", "skipped", "failed", "unsupported")},
        "peak_worker_rss_mb": result.peak_rss_mb,
        "workers": result.workers,
        "files": result.files,
    }
    write_atomic(out_dir / REPORT_NAME, json.dumps(report, indent=1, ensure_ascii=False).encode("utf-8"))
    write_atomic(out_dir / INDEX_NAME, index_html(report).encode("utf-8"))


def summary_table(result: BatchResult, limit: int = 40) -> str:
    """The end-of-batch table: one row per file (failures always; others up to ``limit``)."""
    rows = [f for f in result.files if f["status"] in ("converted", "skipped")]
    bad = [f for f in result.files if f["status"] in ("failed", "unsupported")]
    lines = []
    hdr = f"{'file':<32} {'status':<11} {'strokes':>7} {'pen-down mm':>11} {'travel mm':>10} {'time s':>8}  notes"
    lines.append(hdr)
    lines.append("-" * len(hdr))
    shown = rows if len(rows) <= limit else rows[:limit]
    for f in shown + bad:
        s = f.get("summary") or {}
        name = f["input"] if len(f["input"]) <= 32 else "..." + f["input"][-29:]
        notes = f.get("error") or "; ".join(f.get("warnings", []))
        if s:
            lines.append(f"{name:<32} {f['status']:<11} {s['strokes']:>7} {s['pen_down_mm']:>11.1f} "
                         f"{s['travel_mm']:>10.1f} {s['job_time_s']:>8.1f}  {notes}")
        else:
            lines.append(f"{name:<32} {f['status']:<11} {'':>7} {'':>11} {'':>10} {'':>8}  {notes}")
    if len(rows) > len(shown):
        lines.append(f"... {len(rows) - len(shown)} more converted files (see report.json / index.html)")
    lines.append("-" * len(hdr))
    lines.append(f"{result.count('converted')} converted, {result.count('skipped')} up to date, "
                 f"{result.failed} failed, {result.count('unsupported')} unsupported in {result.elapsed_s:.1f} s"
                 + ("  (interrupted: re-run to resume)" if result.interrupted else ""))
    if result.workers:
        lines.append(f"{len(result.workers)} worker processes, peak memory {result.peak_rss_mb or 0:.0f} MB "
                     f"(per worker: report.json 'workers')")
    return "\n".join(lines)
