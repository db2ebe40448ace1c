"""doodlecam batch: mixed folders, skip/--force, resume after a kill, Dask parity."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from doodlecam.cli import main

FAST = ["--jobs", "2", "--no-progress", "--width", "30"]


def _picture(path: Path, kind: int) -> None:
    """A small black-on-white drawing: few strokes, so it converts in well under a second."""
    from skimage.draw import circle_perimeter, line, rectangle_perimeter
    from skimage.io import imsave

    img = np.full((64, 64), 255, np.uint8)
    if kind % 3 == 0:
        rr, cc = circle_perimeter(32, 32, 20 - kind % 5)
    elif kind % 3 == 1:
        rr, cc = rectangle_perimeter((12, 12 + kind % 4), (48, 50))
    else:
        rr, cc = line(8, 8, 56, 40 + kind % 7)
    img[rr, cc] = 0
    path.parent.mkdir(parents=True, exist_ok=True)
    imsave(path, img, check_contrast=False)


def _mixed(root: Path) -> Path:
    src = root / "in"
    _picture(src / "circle.png", 0)
    _picture(src / "box.png", 1)
    _picture(src / "sub" / "Grüße mit Leerzeichen.png", 2)
    (src / "sub" / "broken.png").write_bytes(b"this is not a picture")
    (src / "notes.txt").write_text("not a picture either")
    (src / "empty folder").mkdir()
    return src


def _files(out: Path) -> dict[str, str]:
    """Output files (no manifest/report) -> sha256."""
    return {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and not p.name.startswith(".")
            and p.name not in ("report.json", "index.html")}


def _report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text(encoding="utf-8"))


def test_mixed_folder_skip_and_force(tmp_path, capsys):
    src, out = _mixed(tmp_path), tmp_path / "out"
    rc = main(["batch", str(src), str(out), "-r", *FAST])
    text = capsys.readouterr()
    assert rc == 1, text
    rep = _report(out)
    status = {f["input"]: f["status"] for f in rep["files"]}
    assert status == {"box.png": "converted", "circle.png": "converted", "sub/Grüße mit Leerzeichen.png": "converted",
                      "sub/broken.png": "failed", "notes.txt": "unsupported"}
    bad = {f["input"]: f["error"] for f in rep["files"] if f["error"]}
    assert "broken.png" in bad["sub/broken.png"] and "\n" not in bad["sub/broken.png"]
    assert "'.txt'" in bad["notes.txt"]
    assert "sub/broken.png" in text.out and "1 of 5 files failed" in text.err
    for stem in ("box", "circle", "sub/Grüße mit Leerzeichen"):
        for ext in (".plc", ".gcode", ".svg"):
            assert (out / (stem + ext)).stat().st_size > 0
    assert not (out / "sub" / "broken.plc").exists() and not (out / "empty folder").exists()
    good = next(f for f in rep["files"] if f["input"] == "circle.png")
    assert good["summary"]["strokes"] >= 1 and good["summary"]["pen_down_mm"] > 0
    html = (out / "index.html").read_text(encoding="utf-8")
    assert "circle.svg" in html and "Gr%C3%BC%C3%9Fe%20mit%20Leerzeichen.svg" in html and "not a readable" in html
    manifest = json.loads((out / ".doodlecam-manifest.json").read_text())
    assert set(manifest["files"]) == {"box.png", "circle.png", "sub/Grüße mit Leerzeichen.png", "sub/broken.png"}
    first = _files(out)
    assert not list(out.rglob("*.tmp")) and not (out / ".doodlecam-tmp").exists()

    # nothing changed: every file skipped, the failure remembered, same bytes
    assert main(["batch", str(src), str(out), "-r", *FAST]) == 1
    rep = _report(out)
    assert rep["counts"] == {"converted": 0, "skipped": 3, "failed": 1, "unsupported": 1}
    assert _files(out) == first

    # a changed input is redone, the others are not
    _picture(src / "box.png", 4)
    main(["batch", str(src), str(out), "-r", *FAST])
    status = {f["input"]: f["status"] for f in _report(out)["files"]}
    assert status["box.png"] == "converted" and status["circle.png"] == "skipped"

    # --force redoes everything, with the same bytes for unchanged inputs
    capsys.readouterr()
    main(["batch", str(src), str(out), "-r", "--force", *FAST])
    rep = _report(out)
    assert rep["counts"]["converted"] == 3 and rep["counts"]["skipped"] == 0
    again = _files(out)
    assert {k: v for k, v in again.items() if not k.startswith("box.")} == \
           {k: v for k, v in first.items() if not k.startswith("box.")}


def test_filters_and_options_hash(tmp_path):
    from doodlecam.batch.options import BatchOptions

    src, out = _mixed(tmp_path), tmp_path / "out"
    assert main(["batch", str(src), str(out), *FAST, "--exclude", "box*", "--post", "svg"]) == 0  # not recursive
    assert {f["input"] for f in _report(out)["files"]} == {"circle.png", "notes.txt"}
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["circle.svg", "index.html", "report.json"]
    # any option that changes the outputs changes the hash the manifest compares
    base = BatchOptions().fingerprint()
    assert base == BatchOptions().fingerprint()
    for changed in (BatchOptions(posts=("svg",)), BatchOptions(layout={"width": 30.0}), BatchOptions(machine="fivebar"),
                    BatchOptions(tracer_options={"sigma": "2"}), BatchOptions(post_options={"gcode": {"pen_up": "M5"}})):
        assert changed.fingerprint() != base


def test_a_new_version_redoes_what_an_older_one_wrote(monkeypatch):
    """Defaults change between versions (a tracer option, the path tolerance), so
    outputs written by another version are never taken as up to date."""
    import doodlecam.batch.options as batch

    base = batch.BatchOptions().fingerprint()
    monkeypatch.setattr(batch, "__version__", "0.1.0")
    assert batch.BatchOptions().fingerprint() != base


SLOW_POST = '''
import time
from doodlecam.api import PostProcessor

class SlowPost(PostProcessor):
    name = "slow"
    summary = "test post that takes its time"
    extension = ".slow"

    def write(self, job, options):
        time.sleep(0.3)
        return f"{len(job.strokes)} strokes\\n".encode()
'''


def _batch_cmd(src, out, plugins):
    return [sys.executable, "-m", "doodlecam", "batch", str(src), str(out), "-r", *FAST, "--plugin-dir", str(plugins),
            "--post", "plc", "--post", "svg", "--post", "slow"]


def test_killed_batch_resumes_to_identical_outputs(tmp_path):
    src = tmp_path / "in"
    for i in range(6):
        _picture(src / ("sub" if i % 2 else "") / f"p{i}.png", i)
    plugins = tmp_path / "plugins"
    plugins.mkdir()
    (plugins / "slowpost.py").write_text(SLOW_POST)

    ref = tmp_path / "ref"
    subprocess.run(_batch_cmd(src, ref, plugins), check=True, capture_output=True, timeout=120)

    out = tmp_path / "out"
    proc = subprocess.Popen(_batch_cmd(src, out, plugins), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    manifest = out / ".doodlecam-manifest.json"
    deadline = time.monotonic() + 60
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if manifest.exists() and json.loads(manifest.read_text())["files"]:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the batch finished before it could be killed"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the coordinator and its workers, mid-batch
        proc.wait()
    done_before = set(json.loads(manifest.read_text())["files"])
    assert 0 < len(done_before) < 6

    subprocess.run(_batch_cmd(src, out, plugins), check=True, capture_output=True, timeout=120)
    rep = _report(out)
    assert rep["counts"]["converted"] + rep["counts"]["skipped"] == 6
    assert {f["input"] for f in rep["files"] if f["status"] == "skipped"} >= done_before
    assert _files(out) == _files(ref)
    assert not (out / ".doodlecam-tmp").exists() and not list(out.rglob("*.tmp"))


def test_dask_gives_identical_outputs(tmp_path):
    pytest.importorskip("distributed")
    from distributed import Client, LocalCluster

    from doodlecam.batch.options import BatchOptions
    from doodlecam.batch.runner import run_batch

    src = _mixed(tmp_path)
    opts = BatchOptions(layout={"width": 30.0})
    local = run_batch(src, tmp_path / "local", opts, recursive=True, jobs=2, progress=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        dask = run_batch(src, tmp_path / "dask", opts, recursive=True, scheduler=client.scheduler.address,
                         progress=False)
    assert [f["status"] for f in dask.files] == [f["status"] for f in local.files]
    assert _files(tmp_path / "dask") == _files(tmp_path / "local")
