"""What a conversion tells the user: which tracer ran and why, dropped strokes, long jobs,
figures over their bounds (an error unless --allow-deviation), and a stroke order that does
not depend on the machine's load."""

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import lineart
from conftest import PROFILE, save
from doodlecam.errors import PlanError
from doodlecam.machine import parse_machine
from doodlecam.pipeline import Settings, convert

ROOT = Path(__file__).resolve().parents[1]
CAMERA = ROOT / "samples" / "images" / "camera.png"


def _grid(tmp_path):
    polys, shape = lineart.grid()
    return save(tmp_path, "grid.png", lineart.render(polys, shape, 5))


def _circle(tmp_path):
    """One small ink circle: a single curved stroke, quick to plan."""
    t = np.linspace(0, 2 * np.pi, 361)
    return save(tmp_path, "grid.png", lineart.render([np.column_stack([40 + 25 * np.cos(t), 40 + 25 * np.sin(t)])],
                                                     (80, 80), 5))


def test_the_summary_says_which_tracer_ran_and_why(tmp_path):
    m = parse_machine(PROFILE, "t.toml")
    chosen = convert(_grid(tmp_path), tmp_path / "a", Settings(machine=m, tracer="centerline", posts=("svg",))).summary()
    assert chosen["tracer"] == "centerline" and chosen["tracer_reason"] == "chosen with --tracer"
    assert chosen["line_width_mm"] == pytest.approx(5 * chosen["scale_mm_per_px"], rel=0.12)
    assert chosen["warnings"] == []
    default = convert(_grid(tmp_path), tmp_path / "b", Settings(machine=m, posts=("svg",))).summary()
    assert default["tracer"] == "centerline" and default["tracer_reason"].startswith("auto: line art")


def test_strokes_dropped_at_a_small_size_are_reported(tmp_path):
    img = np.full((200, 200), 255, np.uint8)
    img[20:180, 98:103] = 0  # one long line ...
    for k in range(8):  # ... and eight dashes, shorter than the pen once the picture is 5 mm wide
        img[20 + 20 * k:25 + 20 * k, 20:36] = 0
    path = save(tmp_path, "dots.png", img)
    m = parse_machine(PROFILE, "t.toml")
    s = convert(path, tmp_path / "o", Settings(machine=m, tracer="centerline", posts=("svg",),
                                               layout={"width": 5})).summary()
    assert s["dropped_strokes"]["shorter_than_pen"] == 8 and s["strokes"] == 1
    assert any("8 of 9 traced strokes dropped" in w and "pen width" in w for w in s["warnings"])


def test_a_job_over_an_hour_is_warned_about(tmp_path):
    slow = dict(PROFILE, axes={k: dict(v, max_velocity=0.1) for k, v in PROFILE["axes"].items()},
                sampling={"delta_time": 1.0})
    m = parse_machine(slow, "slow.toml")
    s = convert(_circle(tmp_path), tmp_path / "o", Settings(machine=m, tracer="centerline", posts=("svg",))).summary()
    assert s["job_time_s"] > 3600
    assert any(w.startswith(f"the job takes {s['job_time_s'] / 3600:.1f} hours") for w in s["warnings"])


def test_a_figure_over_its_bound_fails_unless_allowed(tmp_path):
    m = parse_machine(PROFILE, "t.toml")
    path = _circle(tmp_path)
    strict = Settings(machine=m, tracer="centerline", posts=("svg",), path_tolerance=0.001)
    with pytest.raises(PlanError) as e:
        convert(path, tmp_path / "no", strict)
    msg = str(e.value)
    assert "\n" not in msg and "over the path tolerance of 0.001 mm" in msg and "--allow-deviation" in msg
    assert not (tmp_path / "no").exists()  # nothing written
    s = convert(path, tmp_path / "yes", replace(strict, allow_deviation=True)).summary()
    assert (tmp_path / "yes" / "grid.svg").exists()
    assert any("over the path tolerance" in w and "allowed by --allow-deviation" in w for w in s["warnings"])


def test_cli_prints_warnings_and_exits_non_zero_over_a_bound(tmp_path):
    path = _circle(tmp_path)
    cmd = [sys.executable, "-m", "doodlecam", "convert", str(path), "-o", str(tmp_path / "o"), "--tracer",
           "centerline", "--post", "svg", "--path-tolerance", "0.001"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode != 0 and "Traceback" not in r.stderr and "over the path tolerance" in r.stderr
    r = subprocess.run(cmd + ["--allow-deviation"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "warning: the pen strays" in r.stderr and "tracer             centerline (chosen with --tracer)" in r.stdout


def test_stroke_order_is_the_same_under_load(tmp_path):
    """Byte-identical outputs, alone and with a CPU hog on every core beside the run."""
    small = np.asarray(Image.open(CAMERA).convert("L").resize((160, 160)))
    path = save(tmp_path, "cam.png", small)
    m = parse_machine(PROFILE, "t.toml")
    settings = Settings(machine=m, tracer="edges", posts=("plc", "svg"))
    from doodlecam.geometry.order import order_strokes

    rng = np.random.default_rng(1)
    many = [p for p in rng.random((3000, 2, 2)) * 200]  # enough strokes for the search to run for a while
    alone = convert(path, tmp_path / "alone", settings)
    first = order_strokes(many, (0.0, 0.0), budget=None)
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        loaded = convert(path, tmp_path / "loaded", settings)
        again = order_strokes(many, (0.0, 0.0), budget=None)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    assert first.source == again.source and first.travel == again.travel
    assert len(alone.job.strokes) > 10
    for a, b in zip(alone.outputs, loaded.outputs):
        assert a.read_bytes() == b.read_bytes()
