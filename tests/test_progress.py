"""Where convert is: a status line on a terminal (a real pseudo-terminal here), stage times with
the global -v, and help that works after an install without the source tree's samples/."""

import io
import os
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from doodlecam.cli.progress import Stages

ROOT = Path(__file__).resolve().parent.parent
CAMERA = ROOT / "samples" / "images" / "camera.png"
ENV = dict(os.environ, PYTHONWARNINGS="ignore", TERM="xterm")
STAGES = ["tracing", "ordering", "fitting", "planning", "writing"]  # planning: plan, sample and check each stroke


def test_status_line_is_drawn_in_place_and_erased():
    out = io.StringIO()
    with Stages("a.png", line=True, stream=out) as st:
        st("tracing")
        st("planning", 3, 10)
        st("planning", 4, 10)  # within the redraw period: not drawn
    text = out.getvalue()
    assert "\rdoodlecam: tracing a.png ...\x1b[K" in text
    assert "\rdoodlecam: planning and sampling time-optimal motion  3/10 strokes ...\x1b[K" in text and "4/10" not in text
    assert text.endswith("\r\x1b[K") and "\n" not in text  # nothing left on the terminal


def test_verbose_times_each_stage_without_a_status_line():
    out = io.StringIO()
    with Stages("a.png", verbose=1, line=False, stream=out) as st:
        st("tracing")
        st("planning", 0, 5)
    lines = out.getvalue().splitlines()
    assert [ln.split()[1] for ln in lines] == ["tracing", "planning", "total"]
    assert all(re.fullmatch(r"doodlecam: \w+ +\d+\.\d\d s", ln) for ln in lines[:-1])
    peak = re.fullmatch(r"doodlecam: total +\d+\.\d\d s, peak memory (\d+) MB", lines[-1])
    assert peak and 20 < int(peak.group(1)) < 100_000  # this process's own peak, in MB
    out = io.StringIO()
    with pytest.raises(KeyboardInterrupt):
        with Stages("a.png", verbose=1, line=True, stream=out) as st:
            st("tracing")
            raise KeyboardInterrupt
    assert out.getvalue().endswith("\r\x1b[K") and "total" not in out.getvalue()  # erased; no time for a cut stage


def test_cli_verbose_prints_every_stage_time(tmp_path):
    r = subprocess.run([sys.executable, "-m", "doodlecam", "-v", "convert", str(CAMERA), "-o", str(tmp_path / "o")],
                       capture_output=True, text=True, env=ENV, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "\r" not in r.stderr  # stderr is no terminal here: no status line
    names = [m.group(1) for m in re.finditer(r"^doodlecam: (\w+) +\d+\.\d\d s(?:, peak memory \d+ MB)?$",
                                             r.stderr, re.M)]
    assert names == STAGES + ["total"], r.stderr
    assert "camera.png ->" in r.stdout


def _on_a_terminal(tmp_path, until: str | None = None):
    """convert with stderr on a pseudo-terminal; SIGINT once ``until`` appears on it. (status, stderr)"""
    master, slave = os.openpty()
    p = subprocess.Popen([sys.executable, "-m", "doodlecam", "convert", str(CAMERA), "-o", str(tmp_path / "o")],
                         stdout=subprocess.PIPE, stderr=slave, env=ENV)
    os.close(slave)
    seen = b""
    sent = False
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the other end closed (Linux: EIO)
                break
            if not chunk:
                break
            seen += chunk
        if until and not sent and until.encode() in seen:
            p.send_signal(signal.SIGINT)
            sent = True
        if p.poll() is not None and not ready:
            break
    p.communicate(timeout=60)
    os.close(master)
    return p.returncode, seen.decode(errors="replace").replace("\r\n", "\n")


def _screen(text: str) -> list[str]:
    """The lines a terminal shows: \r returns to the line's start, \x1b[K erases the rest of it."""
    lines, line, col = [], "", 0
    for token in re.split(r"(\r|\n|\x1b\[K)", text):
        if token == "\r":
            col = 0
        elif token == "\n":
            lines.append(line)
            line, col = "", 0
        elif token == "\x1b[K":
            line = line[:col]
        else:
            line = line[:col] + token + line[col + len(token):]
            col += len(token)
    return [ln for ln in lines + [line] if ln]


def test_a_terminal_sees_the_stages_then_only_the_result(tmp_path):
    code, err = _on_a_terminal(tmp_path)
    assert code == 0
    for words in ("tracing camera.png", "ordering", "planning and sampling time-optimal motion", "strokes ..."):
        assert words in err, err
    assert _screen(err) == []  # erased: the summary (stdout) stands alone


@pytest.mark.parametrize("stage", ["tracing", "fitting", "planning", "writing"])
def test_ctrl_c_at_each_stage_on_a_terminal_is_one_line(tmp_path, stage):
    code, err = _on_a_terminal(tmp_path, until=stage)
    if code == 0:  # the stage was the last moment and the job finished first: then it is whole
        assert sorted(os.listdir(tmp_path / "o")) == ["camera.gcode", "camera.plc", "camera.svg"]
        return
    assert code == 130
    assert _screen(err) == ["doodlecam: interrupted; no file was written"], repr(err)
    assert not (tmp_path / "o").exists() or os.listdir(tmp_path / "o") == []


def test_help_names_no_file_an_install_lacks():
    from click.testing import CliRunner

    from doodlecam.cli import LAZY_COMMANDS, cli

    top = CliRunner().invoke(cli, ["--help"]).output
    assert "samples/" not in top and "doodlecam convert PICTURE" in top and "doodlecam calibrate" in top
    for name in LAZY_COMMANDS:
        text = CliRunner().invoke(cli, [name, "--help"]).output
        for m in re.finditer(r"samples/\S+", text):  # only as the source tree's, never as a path to type
            assert "source tree" in text[max(0, m.start() - 40):m.start()], (name, text)
