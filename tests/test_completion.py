"""Shell completion of profile, tracer, post, solver and plugin names, through click's completion
API (what the shell's script asks), and the ``_DOODLECAM_COMPLETE`` hook of the real entry point."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.shell_completion import ShellComplete

from doodlecam.cli import cli, main
from doodlecam.options import SOLVERS

ROOT = Path(__file__).resolve().parent.parent
POSTS = ["csv", "ebb", "gcode", "json", "plc", "svg"]


def completions(args: list[str], incomplete: str) -> list[tuple[str, str]]:
    items = ShellComplete(cli, {}, "doodlecam", "_DOODLECAM_COMPLETE").get_completions(args, incomplete)
    return [(i.type, i.value) for i in items]


def values(args, incomplete) -> list[str]:
    return [v for _, v in completions(args, incomplete)]


@pytest.fixture(autouse=True)
def profiles(tmp_path, monkeypatch):
    """One profile of the user's own, found on the search path like the built-ins."""
    d = tmp_path / "machines"
    d.mkdir()
    (d / "doodle-mine.toml").write_bytes((ROOT / "doodlecam" / "machines" / "doodlebot.toml").read_bytes())
    monkeypatch.setenv("DOODLECAM_MACHINES", str(d))
    monkeypatch.chdir(tmp_path)


def test_post_tracer_and_solver_names():
    assert values(["convert", "x.png", "--post"], "") == POSTS
    assert values(["convert", "x.png", "--post"], "g") == ["gcode"]
    assert values(["convert", "x.png", "--post", "svg", "--post"], "G") == ["gcode"]  # without case, as names match
    assert values(["convert", "x.png", "--tracer"], "c") == ["centerline", "contours"]
    assert values(["batch", "in", "out", "--solver"], "qp") == sorted(s for s in SOLVERS if s.startswith("qp"))
    assert values(["plot", "x.png", "--solver"], "") == sorted(SOLVERS)


@pytest.mark.parametrize("command", [["convert", "x.png"], ["batch", "in", "out"], ["studio"], ["plot", "x.png"],
                                     ["calibrate"], ["motion", "d.toml"], ["send", "j.plc"], ["sim", "plc"],
                                     ["machines", "new", "p", "--from"], ["machines", "check"]])
def test_profile_names_wherever_a_profile_is_asked(command):
    args = command if command[-1] in ("--from", "check") else [*command, "-m"]
    assert values(args, "doodle") == ["doodle-mine", "doodlebot"]
    assert "grbl-servo" in values(args, "")


def test_a_path_gets_the_shells_file_completion():
    assert completions(["convert", "x.png", "-m"], "./my") == [("file", "./my")]
    assert completions(["machines", "check"], "profiles/a") == [("file", "profiles/a")]


def test_drop_in_plugins_count_and_plugins_show():
    dropins = str(ROOT / "samples" / "plugins")
    assert values(["convert", "x.png", "--plugin-dir", dropins, "--post"], "st") == ["stats"]
    assert values(["convert", "x.png", "--post"], "st") == []
    assert values(["plugins", "show"], "ax") == ["axidraw"]
    assert values(["plugins", "--plugin-dir", dropins, "show"], "s") == ["serial", "stats", "stipple", "svg"]
    assert values(["plugins", "show", "--kind", "transport"], "") == ["ebb", "serial", "udp"]
    # a missing plugin folder completes nothing rather than printing a traceback into the shell
    assert values(["convert", "x.png", "--plugin-dir", "nowhere", "--post"], "") == []


def test_the_entry_point_answers_the_shell(monkeypatch, capsys):
    monkeypatch.setenv("_DOODLECAM_COMPLETE", "bash_source")
    assert main([]) == 0
    assert "complete -o nosort -F _doodlecam_completion doodlecam" in capsys.readouterr().out
    monkeypatch.setenv("_DOODLECAM_COMPLETE", "bash_complete")
    monkeypatch.setenv("COMP_WORDS", "doodlecam convert x.png --post g")
    monkeypatch.setenv("COMP_CWORD", "4")
    assert main([]) == 0
    assert capsys.readouterr().out.split() == ["plain,gcode"]
