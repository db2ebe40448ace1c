"""End to end through the real CLI, and every user error through it too."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from doodlecam.machine import load_machine
from doodlecam.link.plc.packetfile import read_plc
from doodlecam.pipeline import Settings, convert
from doodlecam.plan.follow import path_deviation
from doodlecam.model import StrokeSamples
from doodlecam.plan.sample import reference_positions

from conftest import plc_pieces, plc_strokes

ROOT = Path(__file__).resolve().parent.parent
CAMERA = ROOT / "samples" / "images" / "camera.png"
# Integrating the PLC file's whole-steps/s velocity samples must stay within
# half a step (per axis, 80 steps/mm) of the fitted stroke at every sample
# instant, and land on the stroke's end in whole steps.
DRIFT_TOLERANCE_MM = 0.5 / 80


def run(*args, cwd=None):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, "-m", "doodlecam", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=env, timeout=600)


@pytest.fixture(scope="module")
def camera_job(tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    r = run("convert", CAMERA, "-o", out, "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout)


def test_convert_writes_all_outputs_and_summary_matches_files(camera_job):
    out, s = camera_job
    assert sorted(p.name for p in out.iterdir()) == ["camera.gcode", "camera.plc", "camera.svg"]
    header, cmds = read_plc((out / "camera.plc").read_bytes())
    types = np.array([c.type for c in cmds])
    # a move to each stroke drawn after a lift, then home (the pieces of a traced line between its
    # corners follow each other pen down)
    assert (types == 1).sum() == s["pen_lifts"] + 1 and s["pen_lifts"] + s["corners_kept"] <= s["strokes"]
    assert (types == 0).sum() == s["samples"]
    assert header.no_commands == len(cmds)
    assert header.delta_time == pytest.approx(0.04)
    # planned time >= time the PLC spends on its draw samples (the rest is travel and pen)
    assert s["job_time_s"] >= s["samples"] * header.delta_time * 0.999
    gcode = (out / "camera.gcode").read_text()
    assert gcode.count("G0 ") >= s["pen_lifts"]
    assert f"{s['strokes']} strokes" in gcode
    assert s["worst_acceleration_ratio"] <= 1 + 1e-9 and s["worst_velocity_ratio"] <= 1 + 1e-9
    assert 20 <= s["strokes"] <= 2000 and s["pen_down_mm"] > 500
    assert s["max_fit_error_mm"] <= 0.1


def test_plc_samples_reproduce_every_fitted_stroke(tmp_path):
    machine = load_machine("doodlebot")
    res = convert(CAMERA, tmp_path, Settings(machine=machine, posts=("plc",)))
    header, runs = plc_strokes(tmp_path / "camera.plc")
    kx, ky = header.steps_per_mm_x, header.steps_per_mm_y
    assert len(runs) == res.job.pen_lifts  # the pieces of a traced line between corners: one run
    strokes = plc_pieces(header, runs, res.job.samples)
    assert len(strokes) == len(res.job.strokes)
    worst = between = 0.0
    for st, stroke, smp in zip(strokes, res.job.strokes, res.job.samples):
        v = np.vstack([[0, 0], st["v"]])
        pos = st["start"] + np.vstack([[0, 0], np.cumsum(0.5 * header.delta_time * (v[1:] + v[:-1]), axis=0)])
        ref = reference_positions(stroke, smp)
        assert np.abs(st["start"] - stroke.spline.start).max() <= 0.5 / kx + 1e-9
        worst = max(worst, float(np.abs(pos - ref)[:-1].max(initial=0.0)))
        end_steps = pos[-1] * [kx, ky]
        assert np.allclose(end_steps, np.round(stroke.spline.end * [kx, ky]), atol=1e-6)  # 0 steps off at the end
        # between instants: what the file makes the PLC draw, against the spline
        from_file = StrokeSamples(start=st["start"], velocity=np.array(st["v"]), delta_time=header.delta_time,
                                  sample_u=smp.sample_u)  # the file's targets, aimed where the sampler aimed
        between = max(between, float(path_deviation(stroke.spline, from_file).max()))
    assert worst <= DRIFT_TOLERANCE_MM
    # the summary's figure is what the PLC file draws (whole steps/s change it by a hair)
    assert between == pytest.approx(res.job.meta["max_between_samples_mm"], rel=0.02)


def test_help_on_every_command():
    for cmd in ([], ["convert"], ["plugins"], ["machines"], ["inspect"]):
        r = run(*cmd, "--help")
        assert r.returncode == 0 and "Usage" in r.stdout


def test_plugins_and_machines_listed():
    r = run("plugins")
    assert r.returncode == 0
    for name in ("edges", "cartesian", "plc", "gcode", "svg"):
        assert f"  {name} " in r.stdout
    r = run("machines")
    assert "doodlebot" in r.stdout


def test_inspect_prints_header_and_csv(camera_job):
    out, s = camera_job
    r = run("inspect", out / "camera.plc", "--limit", "3")
    assert r.returncode == 0 and "no_commands" in r.stdout and "MOVE" in r.stdout
    r = run("inspect", out / "camera.plc", "--csv")
    assert r.returncode == 0 and len(r.stdout.strip().splitlines()) > s["samples"]


# ---------------------------------------------------------------- errors


def assert_user_error(r, *words, out=None):
    assert r.returncode != 0
    err = r.stderr.strip()
    assert "Traceback" not in r.stderr and len(err.splitlines()) == 1, r.stderr
    for w in words:
        assert w in err, err
    if out is not None:
        assert not out.exists() or not any(out.iterdir()), list(out.iterdir())


def write_profile(tmp_path, edit):
    text = (ROOT / "doodlecam" / "machines" / "doodlebot.toml").read_text()
    p = tmp_path / "bad.toml"
    p.write_text(edit(text))
    return p


def test_missing_file(tmp_path):
    assert_user_error(run("convert", tmp_path / "nope.png", "-o", tmp_path / "o"), "nope.png", out=tmp_path / "o")


def test_folder_given(tmp_path):
    assert_user_error(run("convert", tmp_path, "-o", tmp_path / "o"), str(tmp_path), "folder", out=tmp_path / "o")


def test_not_an_image(tmp_path):
    bad = tmp_path / "notes.png"
    bad.write_text("this is not a picture")
    assert_user_error(run("convert", bad, "-o", tmp_path / "o"), "notes.png", out=tmp_path / "o")


def test_truncated_image(tmp_path):
    bad = tmp_path / "cut.png"
    bad.write_bytes(CAMERA.read_bytes()[:3000])
    assert_user_error(run("convert", bad, "-o", tmp_path / "o"), "cut.png", out=tmp_path / "o")


def test_unsupported_type(tmp_path):
    bad = tmp_path / "drawing.xyz"
    bad.write_text("x")
    assert_user_error(run("convert", bad, "-o", tmp_path / "o"), "drawing.xyz", out=tmp_path / "o")


def test_picture_without_edges(tmp_path):
    from skimage.io import imsave

    blank = tmp_path / "blank.png"
    imsave(blank, np.full((64, 64), 200, np.uint8), check_contrast=False)
    assert_user_error(run("convert", blank, "-o", tmp_path / "o"), "blank.png", "edges", out=tmp_path / "o")


@pytest.mark.parametrize("edit,words", [
    (lambda t: t.replace("max_acceleration = 2000.0\n", "", 1), ["max_acceleration", "[axes.x]"]),
    (lambda t: t.replace("max_velocity = 150.0", "max_velocty = 150.0", 1), ["max_velocty", "max_velocity"]),
    (lambda t: t.replace("max_velocity = 150.0", "max_velocity = -150.0", 1), ["max_velocity", "positive"]),
    (lambda t: t.replace("max_velocity = 150.0", 'max_velocity = "fast"', 1), ["max_velocity", "number"]),
    (lambda t: t.replace('kinematics = "cartesian"', 'kinematics = "scara"'), ["scara"]),
])
def test_bad_machine_profiles(tmp_path, edit, words):
    prof = write_profile(tmp_path, edit)
    assert_user_error(run("convert", CAMERA, "-o", tmp_path / "o", "-m", prof), *words, out=tmp_path / "o")


def test_unknown_plugins_and_machine(tmp_path):
    o = tmp_path / "o"
    assert_user_error(run("convert", CAMERA, "-o", o, "--tracer", "nosuch"), "nosuch", "edges", out=o)
    assert_user_error(run("convert", CAMERA, "-o", o, "--post", "nosuch"), "nosuch", "gcode", out=o)
    assert_user_error(run("convert", CAMERA, "-o", o, "-m", "nosuch"), "nosuch", "doodlebot", out=o)
    assert_user_error(run("convert", CAMERA, "-o", o, "--tracer-opt", "sigmaa=2"), "sigmaa", out=o)
    assert_user_error(run("convert", CAMERA, "-o", o, "--tracer-opt", "sigma=abc"), "sigma", out=o)


# ---------------------------------------------------------------- plugins

DROPIN = '''
from doodlecam.api import Option, PostProcessor


class CountPost(PostProcessor):
    name = "count"
    summary = "Counts strokes (a drop-in example)"
    extension = ".count.txt"
    options = (Option("prefix", str, "strokes:", "text before the number"),)

    def write(self, job, options):
        return f"{options['prefix']} {len(job.strokes)}\\n".encode()
'''


def test_dropin_plugin_dir(tmp_path):
    plug = tmp_path / "plug"
    plug.mkdir()
    (plug / "count.py").write_text(DROPIN)
    (plug / "broken.py").write_text("import no_such_module_anywhere\n")
    r = run("plugins", "--plugin-dir", plug)
    assert r.returncode == 0
    assert "count" in r.stdout and "broken" in r.stdout and "no_such_module_anywhere" in r.stdout
    assert "edges" in r.stdout  # a broken drop-in breaks nothing else
    out = tmp_path / "o"
    r = run("convert", CAMERA, "-o", out, "--plugin-dir", plug, "--post", "count", "--post", "svg",
            "--post-opt", "count.prefix=n=")
    assert r.returncode == 0, r.stderr
    assert (out / "camera.count.txt").read_text().startswith("n= ")


def test_failing_post_leaves_no_partial_output(tmp_path):
    plug = tmp_path / "plug"
    plug.mkdir()
    (plug / "boom.py").write_text(DROPIN.replace('"count"', '"boom"').replace("return f", "raise RuntimeError('kaput'); f"))
    out = tmp_path / "o"
    r = run("convert", CAMERA, "-o", out, "--plugin-dir", plug, "--post", "svg", "--post", "boom")
    assert_user_error(r, "boom", "kaput")
    assert not out.exists() or not list(out.iterdir())


def test_path_tolerance_option(tmp_path):
    horse = ROOT / "samples" / "images" / "horse.png"
    r = run("convert", horse, "-o", tmp_path, "--post", "plc", "--path-tolerance", "0.1", "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["path_tolerance_mm"] == 0.1 and 0 < s["max_between_samples_mm"] <= 0.1
    r = run("convert", horse, "-o", tmp_path / "bad", "--path-tolerance", "-1")
    assert r.returncode == 2 and "--path-tolerance" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "bad").exists()


def test_exit_freezes_the_collector_after_the_command_and_still_runs_atexit_handlers():
    """The console script freezes every live object once the command is done (Python's shutdown collections
    then skip them: ~0.25 s per run), and only then: atexit handlers still run and see it frozen."""
    code = ("import atexit, gc, sys\n"
            "from doodlecam.__main__ import entry\n"
            "atexit.register(lambda: print('handler ran, frozen', gc.get_freeze_count()))\n"
            "print('before', gc.get_freeze_count())\n"
            "sys.argv = ['doodlecam', '--version']\n"
            "entry()\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == "before 0"
    assert lines[-1].startswith("handler ran, frozen ") and int(lines[-1].split()[-1]) > 1000
