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
