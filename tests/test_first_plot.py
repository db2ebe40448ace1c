"""From install to a first plot: built-in profiles, `machines new/check`, `calibrate`, and every
mistake caught before any work (one line, exit 2, nothing written, the tracer never called)."""

from __future__ import annotations

import re
import socket
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from conftest import plc_strokes
from doodlecam.cli import main
from doodlecam.machine import builtin_machine_dir, find_machines, load_machine

BUILTINS = ("doodlebot", "fivebar", "grbl-servo", "grbl-z")


@pytest.fixture
def user_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.delenv("DOODLECAM_MACHINES", raising=False)
    return tmp_path / "config" / "doodlecam" / "machines"


def cli(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


# ---------------------------------------------------------------- profiles


def test_builtin_profiles_are_package_data_and_valid(user_dir, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # far from the checkout
    found = find_machines()
    for name in BUILTINS:
        assert found[name].origin == "built-in" and found[name].path.parent == builtin_machine_dir()
        assert load_machine(name).name == name


def test_search_order_user_before_builtin_env_first(user_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    text = (builtin_machine_dir() / "doodlebot.toml").read_text()
    user_dir.mkdir(parents=True)
    (user_dir / "doodlebot.toml").write_text(text.replace("width = 400.0", "width = 390.0"))
    assert load_machine("doodlebot").width == 390.0
    (tmp_path / "machines").mkdir()
    (tmp_path / "machines" / "doodlebot.toml").write_text(text.replace("width = 400.0", "width = 380.0"))
    assert load_machine("doodlebot").width == 390.0  # the user folder comes before ./machines
    env = tmp_path / "env"
    env.mkdir()
    (env / "doodlebot.toml").write_text(text.replace("width = 400.0", "width = 370.0"))
    monkeypatch.setenv("DOODLECAM_MACHINES", str(env))
    assert load_machine("doodlebot").width == 370.0
    code, out, _ = cli(capsys, "machines")
    assert code == 0
    line = next(l for l in out.splitlines() if l.split()[:1] == ["doodlebot"])
    assert "$DOODLECAM_MACHINES" in line and "hides" in line and str(user_dir / "doodlebot.toml") in line
    assert re.search(r"^\s+grbl-z\s+built-in\s", out, re.M)


def test_machines_new_then_check(user_dir, capsys):
    code, out, err = cli(capsys, "machines", "new", "my-plotter", "--from", "grbl-servo")
    assert code == 0, err
    path = user_dir / "my-plotter.toml"
    assert str(path) in out
    text = path.read_text()
    assert 'name = "my-plotter"' in text and text.startswith("# Profile 'my-plotter'")
    assert "GRBL $100" in text  # the comments come along
    m = load_machine("my-plotter")
    assert (m.name, m.width, m.plugin_options["post.gcode"]["pen"]) == ("my-plotter", 297.0, "servo")

    code, out, err = cli(capsys, "machines", "check", "my-plotter")
    assert code == 0, err
    assert "(user)" in out and out.rstrip().endswith("OK: the profile is valid")
    # GRBL's $ settings, from the profile: steps/mm, mm/min, mm/s^2
    assert "$100=80 $101=80" in out and "$110=6000 $111=6000" in out and "$120=1000 $121=1000" in out
    # pen up corner to corner: 297 x 210 mm at 100 mm/s, 1000 mm/s^2 per axis -> x decides: 2.97 + 0.1 s
    assert "corner to corner (364 mm) in 3.07 s" in out

    # a second 'new' does not overwrite; --force does
    path.write_text(text.replace("width = 297.0", "width = 300.0"))
    code, _, err = cli(capsys, "machines", "new", "my-plotter")
    assert code == 2 and "exists" in err and "--force" in err
    assert "width = 300.0" in path.read_text()
    assert cli(capsys, "machines", "new", "my-plotter", "--force", "--from", "grbl-z")[0] == 0
    assert load_machine("my-plotter").width == 420.0


@pytest.mark.parametrize("args, message", [
    (("machines", "new", "bad name"), "'bad name' is not a profile name"),
    (("machines", "new", "x", "--from", "grbl-sevro"), "unknown machine 'grbl-sevro' (did you mean 'grbl-servo'?)"),
    (("machines", "check", "doodlebto"), "unknown machine 'doodlebto' (did you mean 'doodlebot'?)"),
])
def test_machines_mistakes(user_dir, capsys, args, message):
    code, out, err = cli(capsys, *args)
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert not user_dir.exists()


def test_check_finds_misspelt_plugin_sections(user_dir, capsys):
    assert cli(capsys, "machines", "new", "mine")[0] == 0
    path = user_dir / "mine.toml"
    good = path.read_text()
    for bad, message in [
        (good.replace("[post.gcode]", "[post.gcod]"), "[post.gcod] names no postprocessor (did you mean 'gcode'?)"),
        (good + "\n[trace.edgse]\nsigma = 3\n", "[trace.edgse] names no tracer (did you mean 'edges'?)"),
        (good.replace("pen_up =", "pen_upp ="), "[post.gcode]: postprocessor 'gcode' has no option 'pen_upp' "
                                                "(did you mean 'pen_up'?)"),
        (good + "\n[trace.edges]\nsigma = 'wide'\n", "option 'sigma' must be a float"),
    ]:
        path.write_text(bad)
        code, _, err = cli(capsys, "machines", "check", "mine")
        assert code == 2 and message in err and err.count("\n") == 1, err


# ---------------------------------------------------------------- every mistake before any work


@pytest.fixture(scope="module")
def big_picture(tmp_path_factory) -> Path:
    """A 2400 x 1800 picture full of edges: tracing and planning it takes many seconds."""
    rng = np.random.default_rng(16)
    img = (rng.random((180, 240)) > 0.5).astype(np.uint8) * 255
    path = tmp_path_factory.mktemp("pics") / "big.png"
    Image.fromarray(np.kron(img, np.ones((10, 10), np.uint8))).save(path)
    return path


@pytest.fixture
def no_work(monkeypatch):
    """Fails the test if any tracer starts tracing."""
    from doodlecam import registry

    calls = []
    for info in registry.discover():
        if info.kind == "tracer":
            monkeypatch.setattr(info.load(), "trace", lambda self, *a, **k: calls.append(a))
    return calls


def _profile(tmp_path, edit) -> Path:
    path = tmp_path / "profile.toml"
    path.write_text(edit((builtin_machine_dir() / "doodlebot.toml").read_text()))
    return path


MISTAKES = [
    (["--post", "gcod"], "unknown postprocessor 'gcod' (did you mean 'gcode'?)"),
    (["--post-opt", "gcode.pen_upp=M5"], "postprocessor 'gcode' has no option 'pen_upp' (did you mean 'pen_up'?)"),
    (["--post-opt", "svg.step=wide"], "option 'step' must be a float"),
    (["--tracer", "edgse"], "unknown tracer 'edgse' (did you mean 'edges'?)"),
    (["--tracer-opt", "sigm=3"], "tracer 'auto' has no option 'sigm' (did you mean 'sigma'?)"),
    (["--solver", "reachh"], "unknown solver 'reachh'"),
    (["-m", "doodlebto"], "unknown machine 'doodlebto' (did you mean 'doodlebot'?)"),
    ([("profile", lambda t: t.replace("[post.gcode]", "[post.gcod]"))],
     "[post.gcod] names no postprocessor (did you mean 'gcode'?)"),
    ([("profile", lambda t: t + "\n[trace.edgse]\nsigma = 3\n")], "[trace.edgse] names no tracer"),
    ([("profile", lambda t: t.replace("pen_up =", "pen_upp ="))], "no option 'pen_upp' (did you mean 'pen_up'?)"),
    ([("out", "a-file/out")], "a-file is a file, not a folder"),
]


def _args(tmp_path, extra):
    args, out = [], tmp_path / "out"
    for a in extra:
        if isinstance(a, tuple) and a[0] == "profile":
            args += ["-m", _profile(tmp_path, a[1])]
        elif isinstance(a, tuple):
            (tmp_path / "a-file").write_text("not a folder")
            out = tmp_path / a[1]
        else:
            args.append(a)
    return args, out


def _files(root: Path) -> set[Path]:
    return {p for p in root.rglob("*")}


@pytest.mark.parametrize("extra, message", MISTAKES, ids=[str(m[0][0])[:20] for m in MISTAKES])
def test_convert_mistakes_fail_before_work(tmp_path, capsys, big_picture, no_work, extra, message):
    args, out = _args(tmp_path, extra)
    before = _files(tmp_path)
    code, stdout, err = cli(capsys, "convert", big_picture, "-o", out, *args)
    assert code == 2 and err.startswith("doodlecam: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert _files(tmp_path) == before and not no_work  # nothing written, nothing traced


@pytest.mark.parametrize("extra, message", MISTAKES + [
    (["--scheduler", "tcp://127.0.0.1"], "give the Dask scheduler's address as tcp://HOST:PORT"),
    (["--scheduler", "nowhere:x"], "give the Dask scheduler's address as tcp://HOST:PORT"),
    (["--scheduler", "tcp://127.0.0.1:{free}"], "cannot reach it"),
    (["--scheduler", "tcp://127.0.0.1:{mute}"], "no Dask scheduler answers"),
], ids=[str(m[0][0])[:20] for m in MISTAKES] + ["portless", "badport", "unreachable", "mute"])
def test_batch_mistakes_fail_before_work(tmp_path, capsys, big_picture, no_work, extra, message):
    src = tmp_path / "in"
    src.mkdir()
    for k in range(3):
        (src / f"p{k}.png").write_bytes(big_picture.read_bytes())
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    with socket.socket() as mute:  # a port that accepts connections and never says a word
        mute.bind(("127.0.0.1", 0))
        mute.listen(4)
        args, out = _args(tmp_path, [a.format(free=free, mute=mute.getsockname()[1]) if isinstance(a, str) else a
                                     for a in extra])
        before = _files(tmp_path)
        code, stdout, err = cli(capsys, "batch", src, out, "--no-progress", *args)
    assert code == 2 and err.startswith("doodlecam: error: ") and err.count("\n") == 1, err
    assert message in err, err
    assert _files(tmp_path) == before and not no_work  # no lock file, no manifest, nothing traced


# ---------------------------------------------------------------- calibrate


def test_calibrate_pattern_follows_its_rows(tmp_path, capsys, user_dir):
    """Read the PLC file back and integrate it as the PLC does: the rulers are as long as
    printed, and each row keeps its factor's limits, reaching higher speeds row by row."""
    code, out, err = cli(capsys, "calibrate", "-m", "grbl-servo", "-o", tmp_path, "--factors", "0.5,1,1.5")
    assert code == 0, err
    assert "bottom 200 mm" in out and "left 190 mm" in out
    assert re.search(r"row 3\s+\|\|\|\s+x1.5: 150 mm/s, 1500 mm/s\^2", out)
    assert {p.name for p in tmp_path.iterdir()} >= {"calibrate.plc", "calibrate.gcode", "calibrate.svg"}
    m = load_machine("grbl-servo")
    header, strokes = plc_strokes(tmp_path / "calibrate.plc")
    dt = header.delta_time
    k = m.x.steps_per_mm
    paths = []
    rows: dict[int, list[float]] = {}
    row_h = (m.height - m.margin - (m.margin + 15.0)) / 3
    for s in strokes:
        v = np.array(s["v"])
        # the PLC ramps linearly from one velocity target to the next over each period
        pos = s["start"] + np.cumsum(0.5 * (v + np.vstack([[0, 0], v[:-1]])), axis=0) * dt
        paths.append(np.vstack([s["start"], pos]))
        y = min(s["start"][1], pos[:, 1].min()) + 0.5  # just above the stroke's lowest point
        if y >= m.margin + 15.0:  # a row's stroke (the rulers lie below)
            n = int((y - m.margin - 15.0) // row_h)
            speed = np.abs(v).max()
            acc = np.abs(np.diff(np.vstack([[0, 0], v, [0, 0]]), axis=0)).max() / dt
            rows.setdefault(n, []).append(speed)
            f = (0.5, 1.0, 1.5)[n]
            assert speed <= f * m.x.max_velocity + 1 / k / dt and acc <= f * m.x.max_acceleration * 1.01 + 2 / k / dt ** 2
    # the bottom ruler: from (10, 10) to (210, 10), within a step
    # (a tick may be drawn on from the ruler's end: ends that meet are joined into one stroke)
    # (the fit rounds the ruler's corners and the pen takes them at speed: a sample
    # instant falls within 0.3 mm of each)
    def visits(path, point):
        return np.linalg.norm(path - point, axis=1).min() < 0.3

    on_ruler = [p[np.abs(p[:, 1] - 10) < 0.05] for p in paths if visits(p, [10, 10]) and visits(p, [210, 10])]
    assert len(on_ruler) == 1 and np.ptp(on_ruler[0][:, 0]) > 199.0
    top = [max(rows[n]) for n in range(3)]
    assert top[0] < top[1] < top[2] and top[2] > m.x.max_velocity  # row 3 passes the profile, on purpose


def test_an_invalid_user_profile_is_listed_not_fatal(user_dir, capsys):
    user_dir.mkdir(parents=True)
    (user_dir / "broken.toml").write_text("[machine]\nname = 'broken'\n")
    code, out, _ = cli(capsys, "machines")
    assert code == 0
    line = next(l for l in out.splitlines() if l.split()[:1] == ["broken"])
    assert "user" in line and "INVALID" in line and "missing table [work_area]" in line
    assert re.search(r"^\s+doodlebot\s+built-in\s", out, re.M)  # the others still listed
    code, _, err = cli(capsys, "machines", "check", "broken")
    assert code == 2 and "missing table [work_area]" in err and err.count("\n") == 1


@pytest.mark.parametrize("args, message", [
    (["--tracer-opt", "sigm=3"], "tracer 'auto' has no option 'sigm' (did you mean 'sigma'?)"),
    (["-o", "a-file/fig.png"], "a-file is a file, not a folder"),
    (["--rotate", "90", "--scale", "1", "--width", "50"], "give a scale or a target width/height, not both"),
])
def test_plot_mistakes_fail_before_work(tmp_path, capsys, big_picture, no_work, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a-file").write_text("not a folder")
    before = _files(tmp_path)
    code, _, err = cli(capsys, "plot", big_picture, *args)
    assert code == 2 and message in err and err.count("\n") == 1, err
    assert _files(tmp_path) == before and not no_work
