"""Mistakes caught before the slow work: exit 2, one line, nothing written, and the tracer never ran."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from doodlecam.errors import InputError, PluginError
from doodlecam.machine import load_machine, parse_machine
from doodlecam.pipeline import Settings, convert

from conftest import PROFILE, save

ROOT = Path(__file__).resolve().parent.parent
CAMERA = ROOT / "samples" / "images" / "camera.png"

# A drop-in tracer that leaves a mark when it runs: a check that passes it has come too late.
SPY = '''
from pathlib import Path
from doodlecam.api import Tracer
from doodlecam.plugins.edges import EdgesTracer


class Spy(EdgesTracer):
    name = "spy"

    def trace(self, path, options):
        Path(__file__).with_name("traced").write_text("yes")
        return super().trace(path, options)
'''


def cli(*args):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, "-m", "doodlecam", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=300)


def refused(r, *words, out: Path):
    err = r.stderr.strip()
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(err.splitlines()) == 1, r.stderr
    assert all(w in err for w in words), err
    assert not out.exists()


@pytest.fixture
def spy(tmp_path):
    d = tmp_path / "plugins"
    d.mkdir()
    (d / "spy.py").write_text(SPY)
    return d


def test_layer_on_a_picture_is_refused_before_tracing(tmp_path, spy):
    out = tmp_path / "o"
    refused(cli("convert", CAMERA, "-o", out, "--plugin-dir", spy, "--tracer", "spy", "--layer", "red"),
            "--layer 'red'", "the spy tracer draws .png files as one layer", "SVG and DXF", out=out)
    assert not (spy / "traced").exists()
    refused(cli("convert", CAMERA, "-o", out, "--layer", "red"), "the auto tracer draws .png files as one layer",
            out=out)
    # hatch with layers=tone names its layers before tracing
    refused(cli("convert", CAMERA, "-o", out, "--tracer", "hatch", "--tracer-opt", "layers=tone", "--layer", "tone 7"),
            "'tone 1', 'tone 2', 'tone 3', 'tone 4'", out=out)


def test_a_layer_the_tracer_draws_is_accepted(tmp_path):
    path = save(tmp_path, "grey.png", np.tile(np.linspace(0, 255, 200, dtype=np.uint8), (120, 1)))
    m = parse_machine(PROFILE, "t.toml")
    s = convert(path, tmp_path / "o", Settings(machine=m, tracer="hatch", posts=("svg",), layer="tone 2",
                                               tracer_options={"layers": "tone", "levels": "2"})).summary()
    assert s["layers"] == ["tone 2"] and s["strokes"] > 0


def test_hatch_spacing_below_the_pen_is_refused_not_raised(tmp_path, spy):
    out = tmp_path / "o"
    for value in ("0", "0.2"):
        refused(cli("convert", CAMERA, "-o", out, "--tracer", "hatch", "--tracer-opt", f"spacing_mm={value}"),
                f"spacing_mm must be at least the pen's width (0.5 mm), got {value}", "leave it out", out=out)
    m = load_machine("doodlebot")
    with pytest.raises(PluginError, match="spacing_mm"):  # the API checks before the work as well
        convert(CAMERA, tmp_path / "o", Settings(machine=m, tracer="hatch", tracer_options={"spacing_mm": "0"}))
    assert not out.exists()


def test_plugin_names_ignore_case_and_suggest(tmp_path):
    out = tmp_path / "o"
    refused(cli("convert", CAMERA, "-o", out, "--post", "GCOD"), "unknown postprocessor 'GCOD' (did you mean 'gcode'?)",
            out=out)
    refused(cli("convert", CAMERA, "-o", out, "--tracer", "Edgs"), "(did you mean 'edges'?)", out=out)
    r = cli("convert", ROOT / "samples" / "images" / "text.png", "-o", out, "--post", "GCODE", "--tracer", "CenterLine",
            "--post-opt", "GCode.program_end=M30")
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(out)) == ["text.gcode"]
    assert (out / "text.gcode").read_text().rstrip().endswith("M30")


def test_settings_take_one_post_name_and_any_case():
    m = load_machine("doodlebot")
    assert Settings(machine=m, posts="gcode").posts == ("gcode",)
    s = Settings(machine=m, posts=("SVG", "Gcode"), tracer="EDGES", post_options={"GCODE": {"pen_up": "M5"}})
    assert (s.posts, s.tracer, s.post_options) == (("svg", "gcode"), "edges", {"gcode": {"pen_up": "M5"}})
    from doodlecam.batch.options import BatchOptions

    assert BatchOptions(posts="PLC").posts == ("plc",)


def test_a_layer_on_an_svg_is_still_checked_after_tracing(tmp_path):
    svg = tmp_path / "a.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">'
                   '<path d="M10 10 L90 90" stroke="red" fill="none"/></svg>')
    m = load_machine("doodlebot")
    with pytest.raises(InputError, match="no layer 'blue'"):
        convert(svg, tmp_path / "o", Settings(machine=m, posts=("svg",), layer="blue"))
    assert not (tmp_path / "o").exists()
