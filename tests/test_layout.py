"""Layout: drawings placed in the work area, with the options a user sets."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from doodlecam.errors import InputError, MachineError
from doodlecam.options import layout_options, order_options
from doodlecam.trace.layout import fit_to_work_area
from doodlecam.machine import parse_machine
from doodlecam.model import Drawing

from conftest import PROFILE  # noqa: E402  (tests/ is on sys.path under pytest)


def frame_drawing(w, h, units="px", y_down=True):
    """The outline of the canvas, as an image tracer would place it (pixel centres at integers)."""
    off = 0.5 if units == "px" else 0.0
    x0, y0, x1, y1 = -off, -off, w - off, h - off
    ring = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])
    return Drawing((ring,), units=units, y_down=y_down, source="frame.png", extent=(float(w), float(h)))


def bounds(d):
    pts = np.concatenate(d.polylines)
    return pts.min(axis=0), pts.max(axis=0)


def test_canvas_fills_the_area_inside_the_margin_exactly(machine):
    # 280 x 180 mm inside the margin of a 300 x 200 work area: a 280 x 180 px picture fills it.
    d = fit_to_work_area(frame_drawing(280, 180), machine)
    lo, hi = bounds(d)
    assert np.allclose(lo, [10, 10]) and np.allclose(hi, [290, 190])
    assert d.meta["scale_mm_per_unit"] == pytest.approx(1.0)
    assert d.units == "mm" and not d.y_down


def test_pixel_centres_and_y_flip(machine):
    # A dot in the top-left pixel (0, 0) lands half a pixel in from the top-left corner.
    frame = frame_drawing(280, 180)
    dot = np.array([[0.0, 0.0], [1.0, 0.0]])
    d = fit_to_work_area(Drawing((frame.polylines[0], dot), units="px", y_down=True, extent=(280.0, 180.0)), machine)
    assert np.allclose(d.polylines[1][0], [10.5, 189.5])


@settings(max_examples=30, deadline=None)
@given(st.floats(1, 5000), st.floats(1, 5000), st.sampled_from(["0", "90", "180", "270", "auto"]))
def test_aspect_kept_and_inside_margin(w, h, rotate):
    machine = parse_machine(PROFILE, "test.toml")
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0], [w, h], (20, 2))
    d = fit_to_work_area(Drawing((pts,), units="mm", extent=(w, h)), machine, {"rotate": rotate})
    q = d.polylines[0]
    lo, hi = q.min(axis=0), q.max(axis=0)
    assert (lo >= 10 - 1e-6).all() and hi[0] <= 290 + 1e-6 and hi[1] <= 190 + 1e-6
    s = d.meta["scale_mm_per_unit"]
    # distances scale uniformly: a similarity transform
    assert np.allclose(np.hypot(*(q[1:] - q[:-1]).T), s * np.hypot(*(pts[1:] - pts[:-1]).T), rtol=1e-9)
    turns = d.meta["rotation_deg"] // 90
    cw, ch = (w, h) if turns % 2 == 0 else (h, w)
    assert max(cw * s / 280, ch * s / 180) == pytest.approx(1.0)  # fills the area one way


def test_rotation(machine):
    tall = frame_drawing(100, 300, units="mm", y_down=False)
    up = fit_to_work_area(tall, machine)
    auto = fit_to_work_area(tall, machine, {"rotate": "auto"})
    assert auto.meta["rotation_deg"] == 90 and auto.meta["scale_mm_per_unit"] > 1.5 * up.meta["scale_mm_per_unit"]
    square = fit_to_work_area(frame_drawing(100, 100, "mm", False), machine, {"rotate": "auto"})
    assert square.meta["rotation_deg"] == 0  # no turn unless it helps
    arrow = Drawing((np.array([[0.0, 0.0], [10.0, 0.0]]),), units="mm", extent=(10.0, 10.0))
    q = fit_to_work_area(arrow, machine, {"rotate": "90"}).polylines[0]
    assert q[1][0] == pytest.approx(q[0][0]) and q[1][1] > q[0][1]  # +x turned to +y


def test_target_size_scale_and_fit(machine):
    d = frame_drawing(200, 100, "mm", False)
    lo, hi = bounds(fit_to_work_area(d, machine, {"width": 100}))
    assert hi - lo == pytest.approx([100, 50])
    lo, hi = bounds(fit_to_work_area(d, machine, {"height": 20, "width": 100}))
    assert hi - lo == pytest.approx([40, 20])  # fits both
    lo, hi = bounds(fit_to_work_area(d, machine, {"scale": 0.5}))
    assert hi - lo == pytest.approx([100, 50]) and (lo + hi) / 2 == pytest.approx([150, 100])  # centred
    with pytest.raises(InputError, match="does not fit") as err:
        fit_to_work_area(d, machine, {"scale": 2})
    assert "\n" not in str(err.value)
    ink = Drawing((np.array([[50.0, 50.0], [60.0, 55.0]]),), units="px", y_down=True, extent=(100.0, 100.0))
    lo, hi = bounds(fit_to_work_area(ink, machine, {"fit": "ink"}))
    assert hi[0] - lo[0] == pytest.approx(280)
    lo, hi = bounds(fit_to_work_area(ink, machine))
    assert hi[0] - lo[0] == pytest.approx(18)  # 10 px of a 100 px canvas 180 mm tall


def test_short_strokes_dropped(machine):
    tiny = np.array([[0.0, 0.0], [0.1, 0.0]])
    long = np.array([[0.0, 10.0], [100.0, 10.0]])
    d = fit_to_work_area(Drawing((tiny, long), units="mm", extent=(280.0, 180.0)), machine)
    assert len(d.polylines) == 1 and d.meta["dropped_short"] == 1
    assert len(fit_to_work_area(Drawing((tiny, long), units="mm", extent=(280.0, 180.0)), machine,
                                {"min_length": 0}).polylines) == 2
    with pytest.raises(InputError, match="shorter than"):
        fit_to_work_area(Drawing((tiny,), units="mm", extent=(280.0, 180.0), source="dots.png"), machine)
    with pytest.raises(InputError, match="nothing to draw"):
        fit_to_work_area(Drawing((), source="empty.png"), machine)


def test_option_checks():
    assert layout_options({"rotate": 90})["rotate"] == "90"
    assert layout_options({"width": "120"})["width"] == 120.0
    for bad, words in (({"rotate": "sideways"}, "rotate"), ({"width": -1}, "width"), ({"widht": 1}, "unknown"),
                       ({"scale": 1, "width": 10}, "not both"), ({"fit": "page"}, "fit"), ({"margin": "a"}, "number")):
        with pytest.raises(InputError, match=words):
            layout_options(bad)
    assert order_options({"reverse": "no"})["reverse"] is False
    with pytest.raises(InputError):
        order_options({"reverse": "maybe"})
    with pytest.raises(InputError):
        order_options({"budget": -1})


def test_profile_tables():
    data = dict(PROFILE, layout={"rotate": "auto", "margin": 0, "width": 150}, order={"reverse": False, "budget": 0.2})
    m = parse_machine(data, "p.toml")
    assert m.layout["rotate"] == "auto" and m.layout["margin"] == 0.0 and m.order["reverse"] is False
    with pytest.raises(MachineError, match=r"p.toml: layout.rotate must be one of"):
        parse_machine(dict(PROFILE, layout={"rotate": "sideways"}), "p.toml")
    with pytest.raises(MachineError, match="unknown key"):
        parse_machine(dict(PROFILE, layout={"sizee": 1}), "p.toml")
    d = frame_drawing(200, 100, "mm", False)
    lo, hi = bounds(fit_to_work_area(d, m))
    assert hi - lo == pytest.approx([150, 75])  # the profile's width
    lo, hi = bounds(fit_to_work_area(d, m, {"width": 100}))
    assert hi - lo == pytest.approx([100, 50])  # the CLI wins


# --- units and paper ----------------------------------------------------------------------

def test_lengths_take_units():
    from doodlecam.options import parse_length

    assert parse_length("20cm", "w") == pytest.approx(200)
    assert parse_length("2in", "w") == pytest.approx(50.8)
    assert parse_length("96px", "w") == pytest.approx(25.4)
    assert parse_length("72pt", "w") == pytest.approx(25.4)
    assert parse_length("12", "w") == 12 and parse_length(7.5, "w") == 7.5
    for bad in ("20 furlongs", "abc", "1e", "cm"):
        with pytest.raises(InputError, match="w"):
            parse_length(bad, "w")
    opt = layout_options({"width": "20cm", "margin": "0.5in", "height": "300px"})
    assert (opt["width"], opt["margin"], opt["height"]) == pytest.approx((200, 12.7, 79.375))


def test_pages_by_name_and_size():
    from doodlecam.options import parse_page

    assert parse_page("a4", "p") == pytest.approx((210, 297))
    assert parse_page("A3", "p") == pytest.approx((297, 420))
    assert parse_page("letter", "p") == pytest.approx((215.9, 279.4))
    assert parse_page("5x4in", "p") == pytest.approx((127, 101.6))
    assert parse_page("20cmx10cm", "p") == pytest.approx((200, 100))
    assert parse_page("210 x 297mm", "p") == pytest.approx((210, 297))
    for bad in ("b99", "10x", "x10", "0x10mm"):
        with pytest.raises(InputError, match="p"):
            parse_page(bad, "p")


def test_a_page_is_centred_and_checked_against_the_work_area(machine):
    # a 100 x 100 px square picture on an A5 page (148 x 210) on the 300 x 200 work area: landscape
    d = Drawing((np.array([[0.0, 0.0], [99.0, 0.0], [99.0, 99.0], [0.0, 99.0], [0.0, 0.0]]),), units="px",
                y_down=True, extent=(100, 100))
    out = fit_to_work_area(d, machine, {"page": "a5", "orientation": "landscape", "margin": 10})
    pts = np.concatenate(out.polylines)
    x0, y0, x1, y1 = *pts.min(0), *pts.max(0)
    assert (x0 + x1) / 2 == pytest.approx(machine.width / 2, abs=0.5)
    assert (y0 + y1) / 2 == pytest.approx(machine.height / 2, abs=0.5)
    assert y1 - y0 == pytest.approx((148 - 20) * 99 / 100, rel=1e-3)  # the page's short side, less the margins
    # the scale a picture is traced for (before tracing) is the one it is laid out at: on the page
    from doodlecam.trace.layout import picture_scale

    assert picture_scale(100, 100, machine, {"page": "a5", "orientation": "landscape", "margin": 10}) == \
        pytest.approx((148 - 20) / 100)
    with pytest.raises(InputError, match="page does not fit.*other orientation"):
        fit_to_work_area(d, machine, {"page": "a5", "orientation": "portrait"})
    with pytest.raises(InputError, match="page does not fit"):
        fit_to_work_area(d, machine, {"page": "a3"})


def test_cli_page_and_units(tmp_path):
    from doodlecam.cli import main

    svg = tmp_path / "sq.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="10mm" height="10mm"><rect width="10" height="10"/></svg>')
    assert main(["convert", str(svg), "-o", str(tmp_path / "o"), "--post", "json", "--width", "5cm", "--fit", "ink"]) == 0
    assert main(["convert", str(svg), "-o", str(tmp_path / "o2"), "--post", "json", "--page", "a5", "--landscape"]) == 0
    assert main(["convert", str(svg), "-o", str(tmp_path / "o3"), "--post", "json", "--page", "a2"]) == 2
    assert not (tmp_path / "o3").exists()


@pytest.mark.parametrize("y_down", [False, True])
def test_points_placed_a_block_at_a_time_equal_all_at_once(monkeypatch, y_down):
    """The transform and the step lengths run through small buffers a block at a time: any block size gives
    the same millimetres and drops the same short strokes (blocks that end inside a polyline, one point long)."""
    from doodlecam.trace import layout

    rng = np.random.default_rng(3)
    polys = [np.cumsum(rng.normal(0, s, (int(rng.integers(1, 40)), 2)), axis=0) + 500
             for s in rng.choice([1e-3, 0.3, 5.0], 300)]
    d = Drawing(tuple(polys), units="px", y_down=y_down, layers=tuple(f"l{k % 3}" for k in range(len(polys))))
    machine = parse_machine(PROFILE)
    whole = fit_to_work_area(d, machine, {"rotate": "auto"})
    for block in (1, 7, 64):
        monkeypatch.setattr(layout, "_BLOCK", block)
        got = fit_to_work_area(d, machine, {"rotate": "auto"})
        assert got.layers == whole.layers and len(got.polylines) == len(whole.polylines) < len(polys)
        assert all(np.array_equal(a, b) for a, b in zip(got.polylines, whole.polylines))
