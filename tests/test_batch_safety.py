"""doodlecam batch: nothing to convert, one batch per output folder, worker recycling,
killed workers, Ctrl-C, per-worker memory in the report. Real processes throughout."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from doodlecam.cli import main
from test_batch import FAST, SLOW_POST, _batch_cmd, _files, _picture, _report


@pytest.mark.parametrize("setup, args, expect", [
    ("empty", [], "nothing to convert, no files; put pictures there"),
    ("text", [], "only 2 files, of types no tracer reads (.doc, .txt); add -r to convert sub-folders"),
    ("text", ["-r", "--include", "*.jpg"], "no files matching --include/--exclude; loosen --include/--exclude"),
])
def test_nothing_to_convert_is_one_line_error_and_writes_nothing(tmp_path, capsys, setup, args, expect):
    src = tmp_path / "in"
    src.mkdir()
    if setup == "text":
        (src / "a.txt").write_text("x")
        (src / "b.doc").write_text("y")
        _picture(src / "sub" / "p.png", 0)
    out = tmp_path / "out"
    rc = main(["batch", str(src), str(out), *FAST, *args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and expect in err and str(src) in err, err
    assert not out.exists()


def test_unknown_post_is_one_error_before_any_work(tmp_path, capsys):
    src = tmp_path / "in"
    _picture(src / "p.png", 0)
    rc = main(["batch", str(src), str(tmp_path / "out"), *FAST, "--post", "nosuch"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "unknown postprocessor 'nosuch'" in err
    assert not (tmp_path / "out").exists()


def _slow_folder(tmp_path: Path, n: int = 6) -> tuple[Path, Path]:
    """n small pictures and a drop-in post that sleeps 0.3 s per file, so a batch is still running when poked."""
    src = tmp_path / "in"
    for i in range(n):
        _picture(src / ("sub" if i % 2 else "") / f"p{i}.png", i)
    plugins = tmp_path / "plugins"
    plugins.mkdir()
    (plugins / "slowpost.py").write_text(SLOW_POST)
    return src, plugins


def _wait_for(cond, proc, what: str, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert proc.poll() is None, f"the batch ended before {what}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def _manifest_files(out: Path) -> dict:
    try:
        return json.loads((out / ".doodlecam-manifest.json").read_text())["files"]
    except (OSError, ValueError):
        return {}


def test_second_batch_into_same_folder_is_refused(tmp_path):
    src, plugins = _slow_folder(tmp_path)
    out = tmp_path / "out"
    first = subprocess.Popen(_batch_cmd(src, out, plugins), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    lock = out / ".doodlecam-lock"
    _wait_for(lambda: lock.exists() and lock.read_text().strip() == str(first.pid), first, "it took the lock")
    second = subprocess.run(_batch_cmd(src, out, plugins), capture_output=True, text=True, timeout=120)
    assert second.returncode == 2
    err = second.stderr.strip()
    assert "\n" not in err and str(out) in err and f"another doodlecam batch (pid {first.pid})" in err, err
    assert first.wait(timeout=120) == 0, first.stderr.read()
    assert _report(out)["counts"]["converted"] == 6
    # the lock goes with its holder: the next batch runs (and finds everything up to date)
    again = subprocess.run(_batch_cmd(src, out, plugins), capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and _report(out)["counts"]["skipped"] == 6, again.stderr


def _workers(pid: int) -> list[int]:
    """The pool worker processes under a batch process (Linux /proc)."""
    found = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
                cmd = (d / "cmdline").read_bytes()
            except (OSError, IndexError, ValueError):
                continue
            if ppid == pid and b"multiprocessing-fork" in cmd:
                found.append(int(d.name))
    return found


def test_recycled_workers_give_the_same_outputs(tmp_path):
    src = tmp_path / "in"
    for i in range(6):
        _picture(src / f"p{i}.png", i)
    one = tmp_path / "one"
    assert main(["batch", str(src), str(one), *FAST, "--recycle-after", "0"]) == 0
    rep = _report(one)
    assert 1 <= len(rep["workers"]) <= 2 and sum(w["files"] for w in rep["workers"]) == 6
    for w in rep["workers"]:  # the per-worker memory figures report.json promises
        assert w["pid"] > 0 and 20 < w["rss_mb_first"] <= w["peak_rss_mb"] and w["rss_mb_last"] <= w["peak_rss_mb"]
    assert rep["peak_worker_rss_mb"] == max(w["peak_rss_mb"] for w in rep["workers"])

    many = tmp_path / "many"
    assert main(["batch", str(src), str(many), *FAST, "--recycle-after", "1"]) == 0
    rep = _report(many)
    # 2 jobs x 1 file per pool: three pools, each worker gone after at most 2 files
    assert len({w["pid"] for w in rep["workers"]}) >= 3 and max(w["files"] for w in rep["workers"]) <= 2
    assert _files(many) == _files(one)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the workers through /proc")
def test_killed_worker_is_retried_and_the_batch_completes(tmp_path):
    src, plugins = _slow_folder(tmp_path)
    ref = tmp_path / "ref"
    subprocess.run(_batch_cmd(src, ref, plugins), check=True, capture_output=True, timeout=120)

    out = tmp_path / "out"
    proc = subprocess.Popen(_batch_cmd(src, out, plugins), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _wait_for(lambda: _manifest_files(out) and _workers(proc.pid), proc, "a file was done")
    victim = _workers(proc.pid)[0]
    os.kill(victim, signal.SIGKILL)  # as the out-of-memory killer would
    assert proc.wait(timeout=120) == 0, proc.stderr.read()
    rep = _report(out)
    assert rep["counts"]["converted"] == 6 and rep["counts"]["failed"] == 0
    assert _files(out) == _files(ref)
    assert not (out / ".doodlecam-tmp").exists() and not list(out.rglob("*.tmp"))


def test_ctrl_c_keeps_finished_files_and_a_rerun_completes_them(tmp_path):
    src, plugins = _slow_folder(tmp_path, n=10)
    ref = tmp_path / "ref"
    subprocess.run(_batch_cmd(src, ref, plugins), check=True, capture_output=True, timeout=120)

    out = tmp_path / "out"
    proc = subprocess.Popen(_batch_cmd(src, out, plugins), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    _wait_for(lambda: _manifest_files(out), proc, "a file was done")
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal reaches the whole process group
    assert proc.wait(timeout=120) == 130
    err = proc.stderr.read()
    assert "finishing the files in progress" in err and "Traceback" not in err, err
    rep = _report(out)
    assert rep["interrupted"] and 0 < rep["counts"]["converted"] < 10
    kept = set(_manifest_files(out))
    assert kept == {f["input"] for f in rep["files"] if f["status"] == "converted"}

    again = subprocess.run(_batch_cmd(src, out, plugins), capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    rep = _report(out)
    assert {f["input"] for f in rep["files"] if f["status"] == "skipped"} == kept
    assert _files(out) == _files(ref)


def test_full_disk_ends_in_one_line_and_a_rerun_completes(tmp_path):
    """A disk that fills up mid-batch, simulated with RLIMIT_FSIZE: writes past the limit
    fail (EFBIG) the way they would on a full disk (ENOSPC), in the workers and in the
    batch process alike. Nothing half-written may be taken for done."""
    resource = pytest.importorskip("resource")
    src = tmp_path / "in"
    for i in range(6):
        _picture(src / f"p{i}.png", i)
    ref = tmp_path / "ref"
    assert main(["batch", str(src), str(ref), *FAST]) == 0
    sizes = sorted(p.stat().st_size for p in ref.iterdir() if p.suffix in (".plc", ".gcode", ".svg"))
    limit = sizes[len(sizes) // 2]  # about half the outputs fit

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "doodlecam", "batch", str(src), str(out), *FAST]
    full = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit)))
    assert full.returncode in (1, 2) and "Traceback" not in full.stderr, full.stderr
    assert full.stderr.strip().splitlines()[-1].startswith("doodlecam: error:")
    assert "File too large" in full.stdout + full.stderr
    assert not list(out.rglob("*.tmp")) and not (out / ".doodlecam-tmp").exists()

    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert _files(out) == _files(ref)


def _alive(pid: int) -> bool:
    """A process that still runs (a zombie waiting for a parent to reap it has ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def _descendants(pid: int) -> set[int]:
    kids = {p: int(Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[1])
            for p in (int(d) for d in os.listdir("/proc") if d.isdigit()) if Path(f"/proc/{p}/stat").exists()}
    out, frontier = set(), {pid}
    while frontier:
        frontier = {c for c, parent in kids.items() if parent in frontier} - out
        out |= frontier
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to list processes")
def test_killed_coordinator_leaves_no_worker_running(tmp_path):
    """kill -9 of the coordinator: its workers notice (multiprocessing's parent sentinel) and exit
    instead of converting on as orphans; a re-run then completes the batch."""
    src, plugins = _slow_folder(tmp_path, n=12)
    out = tmp_path / "out"
    proc = subprocess.Popen(_batch_cmd(src, out, plugins), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _wait_for(lambda: _manifest_files(out), proc, "a file was done")  # the workers are busy now
    workers = _descendants(proc.pid)
    assert len(workers) >= 2, workers  # two workers (and multiprocessing's resource tracker)
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 60
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in workers if _alive(p)]
    for p in left:  # a failing run must not leave them behind either
        os.kill(p, signal.SIGKILL)
    assert not left, "workers outlived their coordinator"
    again = subprocess.run(_batch_cmd(src, out, plugins), capture_output=True, text=True, timeout=120)
    assert again.returncode == 0, again.stderr
    assert not list((out / ".doodlecam-tmp").rglob("*")) if (out / ".doodlecam-tmp").exists() else True
