"""The `centerline` tracer on generated line art of known centre geometry (tests/lineart.py)."""

import numpy as np
import pytest

import lineart
from conftest import assert_one_line, save
from doodlecam.errors import InputError, PluginError
from doodlecam.plugins.centerline import CenterlineTracer

TRACER = CenterlineTracer()


def _trace(tmp_path, shape_name, width, **opts):
    # lettering: letters 15 line widths tall, a normal-weight font (bolder sharp corners lose more, see docs)
    polys, shape = lineart.text(size=2.5 * width) if shape_name == "text" else getattr(lineart, shape_name)()
    path = save(tmp_path, f"{shape_name}_{width}.png", lineart.render(polys, shape, width))
    return polys, path, TRACER.trace(path, opts)


@pytest.mark.parametrize("shape_name", ["circles", "grid", "text", "scribble"])
@pytest.mark.parametrize("width", [5, 7])
def test_one_stroke_along_the_middle_of_each_line(tmp_path, shape_name, width):
    polys, _, d = _trace(tmp_path, shape_name, width)
    true = lineart.polyline_length(polys)
    drawn = lineart.polyline_length([np.asarray(p) for p in d.polylines])
    assert drawn == pytest.approx(true, rel=0.03)  # outline tracers draw about twice this
    pts = np.vstack([lineart._dense(np.asarray(p), 0.2) for p in d.polylines])
    assert lineart.distance_to(polys, pts).max() <= width / 2
    assert d.meta["line_width_px"] == pytest.approx(width, rel=0.12)
    assert d.meta["tracer"] == "centerline" and d.units == "px" and d.y_down


def test_spurs_and_specks_are_not_drawn(tmp_path):
    polys, shape = lineart.grid()
    img = lineart.render(polys, shape, 5)
    img[100:102, 5:7] = 0  # a speck of dust
    img[60:63, 100:104] = 0  # a bump on a line: its skeleton grows a short spur
    path = save(tmp_path, "dusty.png", img)
    d = TRACER.trace(path, {})
    drawn = lineart.polyline_length([np.asarray(p) for p in d.polylines])
    assert drawn == pytest.approx(lineart.polyline_length(polys), rel=0.03)
    pts = np.vstack(d.polylines)
    assert lineart.distance_to(polys, pts).max() <= 2.5


def test_the_machine_draws_the_centre_line(tmp_path):
    """The PLC file read back and integrated as the PLC does: its pen-down length
    is the true centre line's, scaled into the work area."""
    from conftest import plc_strokes
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, convert

    polys, shape = lineart.scribble()
    path = save(tmp_path, "scribble.png", lineart.render(polys, shape, 5))
    machine = load_machine("doodlebot")
    res = convert(path, tmp_path / "out", Settings(machine=machine, tracer="centerline", posts=("plc",)))
    header, strokes = plc_strokes(tmp_path / "out" / "scribble.plc")
    dt = machine.delta_time
    length = sum(np.hypot(*np.asarray(s["v"]).T).sum() * dt for s in strokes)
    scale = res.summary()["scale_mm_per_px"]
    assert length == pytest.approx(lineart.polyline_length(polys) * scale, rel=0.03)
    assert res.summary()["tracer"] == "centerline"
    assert res.summary()["line_width_mm"] == pytest.approx(5 * scale, rel=0.12)


def test_bad_options_and_blank_pictures_are_one_line_errors(tmp_path):
    path = save(tmp_path, "blank.png", np.full((50, 60), 255, np.uint8))
    with pytest.raises(InputError) as e:
        TRACER.trace(path, {})
    assert_one_line(e, path)
    with pytest.raises(PluginError):
        TRACER.trace(path, {"threshold": 2.0})
    with pytest.raises(PluginError):
        TRACER.trace(path, {"spur": -1})


def test_auto_draws_line_art_along_its_centre_and_photos_by_their_edges(tmp_path):
    from pathlib import Path

    from doodlecam.plugins.centerline import AutoTracer

    auto = AutoTracer()
    for shape_name in ("grid", "text", "scribble"):
        polys, path, _ = _trace(tmp_path, shape_name, 5)
        d = auto.trace(path, {})
        assert d.meta["tracer"] == "centerline" and d.meta["tracer_reason"].startswith("auto: line art")
        drawn = lineart.polyline_length([np.asarray(p) for p in d.polylines])
        assert drawn == pytest.approx(lineart.polyline_length(polys), rel=0.03)
    samples = Path(__file__).resolve().parents[1] / "samples" / "images"
    for name in ("camera.png", "coins.png", "horse.png", "text.png"):
        d = auto.trace(samples / name, {})
        assert d.meta["tracer"] == "edges" and d.meta["tracer_reason"].startswith("auto: a picture")
    # options reach the chosen tracer; one it lacks is a one-line error naming the choice
    _, path, _ = _trace(tmp_path, "grid", 5)
    assert auto.trace(path, {"simplify": "1.0"}).meta["options"]["simplify"] == 1.0
    with pytest.raises(PluginError, match="chose 'centerline'.*no option 'sigma'"):
        auto.trace(path, {"sigma": "3"})


def test_auto_applies_the_profiles_table_of_the_tracer_it_chose(tmp_path):
    from conftest import PROFILE
    from doodlecam.machine import parse_machine
    from doodlecam.pipeline import Settings, trace

    _, path, _ = _trace(tmp_path, "grid", 5)
    m = parse_machine(dict(PROFILE, trace={"centerline": {"simplify": 2.0}, "edges": {"sigma": 5.0}}), "t.toml")
    d = trace(path, Settings(machine=m))
    assert d.meta["tracer"] == "centerline" and d.meta["options"]["simplify"] == 2.0


@pytest.mark.parametrize("angle", [30, 40, 60])
@pytest.mark.parametrize("width", [5, 7, 9])
def test_a_sharp_corner_of_a_thick_line_is_not_cut(tmp_path, angle, width):
    """A V of a round pen: its arms' centre lines meet at the apex. The skeleton
    cuts across the corner there (by up to a line width at 40 degrees before);
    the drawn stroke must reach the apex."""
    a = np.radians(angle)
    apex = np.array([150.0, 40.0])
    polys = [np.array([apex + 120 * np.array([np.sin(a / 2), np.cos(a / 2)]), apex,
                       apex + 120 * np.array([-np.sin(a / 2), np.cos(a / 2)])])]
    path = save(tmp_path, "v.png", lineart.render(polys, (200, 300), width))
    d = TRACER.trace(path, {})
    assert len(d.polylines) == 1
    pts = lineart._dense(np.asarray(d.polylines[0]), 0.2)
    assert np.hypot(*(pts - apex).T).min() <= width / 2  # it reaches the corner
    assert lineart.distance_to(polys, pts).max() <= width / 4
    drawn = lineart.polyline_length([np.asarray(d.polylines[0])])
    assert drawn == pytest.approx(lineart.polyline_length(polys), rel=0.02)


@pytest.mark.parametrize("width", [7, 9])
def test_bold_lettering_with_sharp_corners_keeps_its_length(tmp_path, width):
    polys, shape = lineart.text("ZN", size=2.0 * width)  # 12 line widths tall: bold
    path = save(tmp_path, "zn.png", lineart.render(polys, shape, width))
    d = TRACER.trace(path, {})
    drawn = lineart.polyline_length([np.asarray(p) for p in d.polylines])
    assert drawn == pytest.approx(lineart.polyline_length(polys), rel=0.03)
    pts = np.vstack([lineart._dense(np.asarray(p), 0.2) for p in d.polylines])
    assert lineart.distance_to(polys, pts).max() <= width / 4
