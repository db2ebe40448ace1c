"""SVG and DXF files as design tools write them, against their exact geometry.

Each file is written here with a feature design tools use (ellipses, <use> of
<defs>, clip paths, hidden layers, arcs, entities, blocks, units, layers); the
drawn pen-down length must be within 0.1 % of the exact length, and drawn points
within the tracer's tolerance of the exact curve.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from doodlecam.errors import InputError
from doodlecam.model import polyline_length
from doodlecam.plugins.vector import VectorTracer

VEC = VectorTracer()
TOL = 0.02  # the tracer's default: mm between a curve and its polyline
from svg_corpus import CORPUS, HEAD, ellipse_perimeter, write_corpus  # noqa: E402  (tests/ is on sys.path)


def svg(tmp_path, body: str, name="t.svg", head=HEAD):
    path = tmp_path / name
    path.write_text(head + body + "</svg>")
    return VEC.trace(path, {})


def total(d) -> float:
    return sum(polyline_length(p) for p in d.polylines)


def assert_length(d, exact: float):
    assert total(d) == pytest.approx(exact, rel=1e-3), (total(d), exact)


def on_circle(p, centre, r):
    return np.abs(np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) - r).max()


def test_ellipse_rotated(tmp_path):
    d = svg(tmp_path, '<ellipse cx="100" cy="50" rx="30" ry="10" transform="rotate(30 100 50)"/>')
    assert len(d.polylines) == 1
    assert_length(d, ellipse_perimeter(30, 10))
    p = d.polylines[0]
    c, s = math.cos(math.radians(-30)), math.sin(math.radians(-30))
    x, y = p[:, 0] - 100, p[:, 1] - 50  # back into the ellipse's own frame
    u, v = c * x - s * y, s * x + c * y
    assert np.abs(np.hypot(u / 30, v / 10) - 1).max() * 10 < TOL  # every point on the ellipse


def test_use_copies_defs_offsets_and_transforms(tmp_path):
    d = svg(tmp_path, '<defs><circle id="dot" cx="0" cy="0" r="5"/></defs>'
                      '<use xlink:href="#dot" x="20" y="30"/>'
                      '<use href="#dot" transform="translate(60 40) scale(2)"/>')
    assert len(d.polylines) == 2  # the <defs> original is never drawn
    centres = sorted(tuple(np.round((p.min(0) + p.max(0)) / 2, 3)) for p in d.polylines)
    assert centres == [(20.0, 30.0), (60.0, 40.0)]
    assert_length(d, 2 * math.pi * 5 + 2 * math.pi * 10)


def test_clip_path_clips_and_is_not_ink(tmp_path):
    d = svg(tmp_path, '<defs><clipPath id="c"><rect x="0" y="0" width="10" height="10"/></clipPath></defs>'
                      '<g transform="translate(50 0)"><line x1="-20" y1="5" x2="30" y2="5" clip-path="url(#c)"/></g>'
                      '<g clip-path="url(#c)" transform="translate(100 0)"><circle cx="0" cy="0" r="5"/></g>')
    assert_length(d, 10 + 2 * math.pi * 5 / 4)  # 10 mm of the line, the circle's quarter in the clip
    pts = np.concatenate(d.polylines)
    line = pts[(np.abs(pts[:, 1] - 5) < 1e-9) & (pts[:, 0] < 90)]
    assert line[:, 0].min() == pytest.approx(50) and line[:, 0].max() == pytest.approx(60)


def test_hidden_elements_and_layers_are_not_drawn(tmp_path):
    d = svg(tmp_path, '<g inkscape:groupmode="layer" inkscape:label="shown"><line x1="0" y1="0" x2="10" y2="0"/></g>'
                      '<g inkscape:groupmode="layer" inkscape:label="off" style="display:none"><line x1="0" y1="9" x2="90" y2="9"/></g>'
                      '<line x1="0" y1="20" x2="50" y2="20" display="none"/>'
                      '<g visibility="hidden"><line x1="0" y1="30" x2="50" y2="30"/></g>'
                      '<line x1="0" y1="40" x2="50" y2="40" style="visibility:hidden"/>')
    assert_length(d, 10)
    assert d.layers == ("shown",)


def test_elliptical_arcs_land_on_the_curve(tmp_path):
    # a circle of radius 20 about (60, 50) as two arcs, and a quarter ellipse
    d = svg(tmp_path, '<path d="M 40 50 A 20 20 0 0 1 80 50 A 20 20 0 0 1 40 50 Z"/>'
                      '<path d="M 150 50 a 30 15 0 0 0 30 -15"/>')
    circle = max(d.polylines, key=len)
    assert on_circle(circle, (60, 50), 20) < TOL
    assert_length(d, 2 * math.pi * 20 + ellipse_perimeter(30, 15) / 4)


def test_internal_entities(tmp_path):
    head = '<?xml version="1.0"?><!DOCTYPE svg [<!ENTITY r "12">]>' + HEAD
    d = svg(tmp_path, '<circle cx="50" cy="50" r="&r;"/>', head=head)
    assert_length(d, 2 * math.pi * 12)


def test_external_entities_are_never_read(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("M 0 0 L 100 100")
    head = f'<?xml version="1.0"?><!DOCTYPE svg [<!ENTITY x SYSTEM "file://{secret}">]>' + HEAD
    path = tmp_path / "xxe.svg"
    path.write_text(head + '<path d="&x;"/><line x1="0" y1="0" x2="10" y2="0"/></svg>')
    try:
        d = VEC.trace(path, {})
    except InputError as e:
        assert "\n" not in str(e)
    else:
        assert total(d) == pytest.approx(10)  # the file's contents never became a path


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_corpus_pen_down_length_is_exact(tmp_path, name):
    """Every file of the feature corpus (benchmarks/bench_vector.py measures vpype on the same)."""
    files = write_corpus(tmp_path)
    path = tmp_path / f"{name}.svg"
    assert_length(VEC.trace(path, {}), files[path])


def test_design_tool_file_layers_and_warnings(tmp_path):
    d = VEC.trace(tmp_path / "design-tool.svg", {}) if write_corpus(tmp_path) else None
    assert set(d.layers) == {"Black", "Red"}
    assert d.meta["layer_colours"]["Red"] == "#ff0000"
    assert d.meta["warnings"] == ["not drawn: 1 text (convert text to paths)"]


def test_bezier_length_against_fine_sampling(tmp_path):
    d = svg(tmp_path, '<path d="M 10 80 C 40 10, 65 10, 95 80 S 150 150, 180 80"/>')

    def cubic(p0, p1, p2, p3, t):
        t = t[:, None]
        return (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t ** 2 * p2 + t ** 3 * p3

    t = np.linspace(0, 1, 200_001)
    a = cubic(*map(np.array, [(10, 80), (40, 10), (65, 10), (95, 80)]), t)
    b = cubic(*map(np.array, [(95, 80), (125, 150), (150, 150), (180, 80)]), t)
    exact = polyline_length(a) + polyline_length(b)
    assert_length(d, exact)
    ref = np.vstack([a, b])
    for p in d.polylines[0][:: max(1, len(d.polylines[0]) // 50)]:
        assert np.hypot(*(ref - p).T).min() < TOL


@pytest.mark.parametrize("by, expected", [("layer", {"A", "B"}), ("colour", {"#ff0000", "#0000ff"}),
                                          ("none", {"0"}), ("auto", {"A", "B"})])
def test_layers_by(tmp_path, by, expected):
    path = tmp_path / "l.svg"
    path.write_text(HEAD + '<g inkscape:groupmode="layer" inkscape:label="A"><line x1="0" y1="0" x2="10" y2="0" stroke="red"/></g>'
                    '<g inkscape:groupmode="layer" inkscape:label="B"><line x1="0" y1="5" x2="10" y2="5" stroke="blue"/>'
                    '<line x1="0" y1="9" x2="10" y2="9" stroke="blue"/></g></svg>')
    d = VEC.trace(path, {"layers": by})
    assert set(d.layers) == expected and len(d.layers) == len(d.polylines)


# --- DXF --------------------------------------------------------------------------------


def dxf(tmp_path, build, units=4, name="t.dxf"):
    import ezdxf

    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = units
    build(doc, doc.modelspace())
    path = tmp_path / name
    doc.saveas(path)
    return VEC.trace(path, {})


def test_dxf_ellipses_full_and_partial(tmp_path):
    def build(doc, msp):
        msp.add_ellipse((50, 50), major_axis=(30, 0), ratio=0.5)  # full: a = 30, b = 15
        msp.add_ellipse((150, 50), major_axis=(0, 20), ratio=0.5, start_param=0, end_param=math.pi / 2)
    d = dxf(tmp_path, build)
    assert_length(d, ellipse_perimeter(30, 15) + ellipse_perimeter(20, 10) / 4)


def test_dxf_spline_against_its_exact_curve(tmp_path):
    from scipy.interpolate import BSpline

    ctrl = np.array([(0, 0), (20, 40), (50, -10), (80, 30), (100, 0)], float)
    knots = np.r_[[0] * 4, 0.5, [1] * 4]

    def build(doc, msp):
        msp.add_open_spline(ctrl, degree=3, knots=knots)
    d = dxf(tmp_path, build)
    curve = BSpline(knots, ctrl, 3)(np.linspace(0, 1, 200_001))
    assert_length(d, polyline_length(curve))
    for p in d.polylines[0]:
        assert np.hypot(*(curve - p).T).min() < TOL


def test_dxf_blocks_bulges_layers_and_inches(tmp_path):
    def build(doc, msp):
        doc.layers.add("CUT", color=1)  # ACI red
        blk = doc.blocks.new("HOLE")
        blk.add_circle((0, 0), 0.25)
        msp.add_blockref("HOLE", (1, 1), dxfattribs={"xscale": 2, "yscale": 2, "layer": "CUT"})
        msp.add_blockref("HOLE", (3, 1), dxfattribs={"layer": "CUT"})
        # a 1 x 0.5 slot: straight sides and two half-circle ends (bulge 1)
        msp.add_lwpolyline([(5, 1, 0), (6, 1, 1), (6, 1.5, 0), (5, 1.5, 1)], format="xyb", close=True)
        msp.add_text("PART 7", height=0.2)
        msp.add_mtext("note")
    d = dxf(tmp_path, build, units=1)  # inches
    inch = 25.4
    exact = (2 * math.pi * 0.5 + 2 * math.pi * 0.25 + 2 * 1 + math.pi * 0.5) * inch
    assert_length(d, exact)
    big = [p for p in d.polylines if on_circle(p, (inch, inch), 0.5 * inch) < TOL]
    assert len(big) == 1  # the scaled block copy, in place
    assert sorted(set(d.layers)) == ["0", "CUT"]
    assert d.meta["layer_colours"] == {"CUT": "#ff0000", "0": "#000000"}
    assert d.meta["units"] == "inches"
    assert d.meta["warnings"] == ["not drawn: 1 MTEXT, 1 TEXT"]


def test_cli_prints_what_is_not_drawn(tmp_path):
    from click.testing import CliRunner

    from doodlecam.cli import cli

    path = tmp_path / "t.svg"
    path.write_text(HEAD + '<circle cx="50" cy="50" r="20"/><text x="1" y="1">hi</text></svg>')
    res = CliRunner().invoke(cli, ["convert", str(path), "-o", str(tmp_path / "out"), "--post", "svg", "--scale", "1"])
    assert res.exit_code == 0, res.output
    assert "not drawn: 1 text (convert text to paths)" in res.output


def test_an_output_never_replaces_the_input(tmp_path, capsys):
    from doodlecam.cli import main

    path = tmp_path / "x.svg"
    path.write_text(HEAD + '<circle cx="50" cy="50" r="20"/></svg>')
    before = path.read_bytes()
    assert main(["convert", str(path), "-o", str(tmp_path), "--post", "svg", "--scale", "1"]) == 2
    err = capsys.readouterr().err
    assert "would replace the input" in err and "-o" in err and err.count("\n") == 1
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.svg"]


# --- layers through the job -------------------------------------------------------------

THREE = (HEAD + '<g inkscape:groupmode="layer" inkscape:label="Black">'
         '<line x1="10" y1="10" x2="90" y2="10" stroke="black"/><circle cx="50" cy="50" r="20" stroke="black"/></g>'
         '<g inkscape:groupmode="layer" inkscape:label="Red"><rect x="100" y="10" width="40" height="30" stroke="red"/>'
         '<line x1="10" y1="90" x2="190" y2="90" stroke="red"/></g>'
         '<g inkscape:groupmode="layer" inkscape:label="Blue"><circle cx="150" cy="60" r="15" stroke="blue"/></g></svg>')


def test_a_multi_layer_file_plots_layer_after_layer(tmp_path, capsys):
    import xml.etree.ElementTree as ET

    from doodlecam.cli import main

    path = tmp_path / "three.svg"
    path.write_text(THREE)
    out = tmp_path / "out"
    assert main(["convert", str(path), "-o", str(out), "--post", "svg", "--post", "json", "--scale", "1"]) == 0
    text = capsys.readouterr().out
    assert "layers             3, plotted one after another: Black with pen 1, Red with pen 2, Blue with pen 3" in text
    assert "pen changes        2: the job pauses for each" in text
    import json

    plan = json.loads((out / "three.json").read_text())
    # the strokes of each layer together, layers in the file's order
    svg = ET.parse(out / "three.svg").getroot()
    ns = {"s": "http://www.w3.org/2000/svg", "i": "http://www.inkscape.org/namespaces/inkscape"}
    groups = [g for g in svg.findall("s:g", ns) if g.get("id", "").startswith("pen-down")]
    labels = [g.get("{http://www.inkscape.org/namespaces/inkscape}label") for g in groups]
    assert labels == ["pen down: Black", "pen down: Red", "pen down: Blue"]
    assert [g.get("stroke") for g in groups] == ["#000000", "#ff0000", "#0000ff"]
    # a path per stroke: the rectangle is four, its sides drawn pen down, stopping on its corners
    assert [len(g.findall("s:path", ns)) for g in groups] == [2, 5, 1]
    assert len(plan["strokes"]) == 8


def test_one_layer_only_stays_in_place(tmp_path, machine):
    from doodlecam.pipeline import Settings, convert

    path = tmp_path / "three.svg"
    path.write_text(THREE)
    full = convert(path, tmp_path / "a", Settings(machine=machine, posts=("json",), layout={"scale": 1})).job
    red = convert(path, tmp_path / "b", Settings(machine=machine, posts=("json",), layout={"scale": 1}, layer="Red")).job
    assert red.layers == ("Red",) and not red.pen_changes
    starts = {tuple(np.round(s.spline.start, 6)) for s in full.strokes if s.layer == "Red"}
    ends = {tuple(np.round(s.spline.end, 6)) for s in full.strokes if s.layer == "Red"}
    assert {tuple(np.round(s.spline.start, 6)) for s in red.strokes} <= starts | ends
    with pytest.raises(InputError, match="no layer 'Green'.*'Black', 'Red', 'Blue'"):
        convert(path, tmp_path / "c", Settings(machine=machine, posts=("json",), layout={"scale": 1}, layer="Green"))
    assert not (tmp_path / "c").exists()


def test_a_multi_layer_file_takes_no_longer_than_its_layers(tmp_path, machine):
    """Planning cost: the same strokes in three layers cost about what they cost in one
    (ordering per layer, the rest unchanged); pen changes are pauses, not motion."""
    from doodlecam.pipeline import Settings, convert

    path = tmp_path / "three.svg"
    path.write_text(THREE)
    layered = convert(path, tmp_path / "a", Settings(machine=machine, posts=("json",), layout={"scale": 1})).job
    one = convert(path, tmp_path / "b", Settings(machine=machine, posts=("json",), layout={"scale": 1},
                                                 tracer_options={"layers": "none"})).job
    assert len(layered.strokes) == len(one.strokes) and len(layered.pen_changes) == 2 and not one.pen_changes
    assert layered.pen_down_length == pytest.approx(one.pen_down_length, rel=1e-9)
    assert layered.draw_time == pytest.approx(one.draw_time, rel=0.02)


def rsvg_ink_boxes(path, px_per_mm: int = 10) -> tuple[float, float, float, float]:
    """The ink's bounding box (mm, y down) as rsvg-convert (librsvg, a real renderer) draws the file."""
    import subprocess

    from PIL import Image

    png = path.with_suffix(".png")
    subprocess.run(["rsvg-convert", "--width", str(200 * px_per_mm), "--height", str(100 * px_per_mm),
                    "--background-color", "white", "-o", str(png), str(path)], check=True, timeout=60)
    ink = np.asarray(Image.open(png).convert("L")) < 128
    rows, cols = np.flatnonzero(ink.any(axis=1)), np.flatnonzero(ink.any(axis=0))
    return cols[0] / px_per_mm, rows[0] / px_per_mm, (cols[-1] + 1) / px_per_mm, (rows[-1] + 1) / px_per_mm


@pytest.mark.skipif(__import__("shutil").which("rsvg-convert") is None, reason="rsvg-convert (librsvg2-bin) not installed")
@pytest.mark.parametrize("par, size, want", [
    ("", (40, 40), (54, 14, 86, 46)),  # xMidYMid meet: an 8-unit square in a 10-unit box, 40 mm viewport
    ("xMinYMin meet", (80, 40), (54, 14, 86, 46)),  # a wide viewport: the box sits at its left
    ("xMaxYMid meet", (80, 40), (94, 14, 126, 46)),  # ... at its right
    ("none", (80, 40), (58, 14, 122, 46)),  # stretched
])
def test_symbols_are_drawn_as_a_real_renderer_draws_them(tmp_path, par, size, want):
    """A <symbol viewBox> placed by <use x y width height> fills the use's viewport (its preserveAspectRatio);
    a symbol outside <use> and a shape with no stroke and no fill draw nothing; checked against librsvg."""
    body = (f'<symbol id="s" viewBox="0 0 10 10" {f"preserveAspectRatio={chr(34)}{par}{chr(34)}" if par else ""}>'
            '<rect x="1" y="1" width="8" height="8" stroke="black" stroke-width="0.05" fill="none"/></symbol>'
            '<rect x="5" y="60" width="10" height="10" fill="none" stroke="none"/>'
            f'<use xlink:href="#s" x="50" y="10" width="{size[0]}" height="{size[1]}"/>')
    path = tmp_path / "symbol.svg"
    path.write_text(HEAD + body + "</svg>")
    d = VEC.trace(path, {})
    pts = np.vstack(d.polylines)
    ours = (*pts.min(axis=0), *pts.max(axis=0))
    np.testing.assert_allclose(ours, want, atol=1e-6)
    np.testing.assert_allclose(rsvg_ink_boxes(path), want, atol=0.25)  # 0.1 mm pixels; the line is up to 0.4 mm wide
    assert len(d.polylines) == 1  # the symbol where it stands and the invisible rectangle draw nothing


R10 = 0.1 * math.sqrt((200 ** 2 + 100 ** 2) / 2)  # r="10%": of the viewport's normalised diagonal


@pytest.mark.skipif(__import__("shutil").which("rsvg-convert") is None, reason="rsvg-convert (librsvg2-bin) not installed")
@pytest.mark.parametrize("head, body, want", [
    (HEAD, '<circle cx="50%" cy="50%" r="10%"/>', (100 - R10, 50 - R10, 100 + R10, 50 + R10)),
    (HEAD, '<ellipse cx="80%" cy="70%" rx="5%" ry="10%"/>', (150, 60, 170, 80)),
    (HEAD, '<rect x="10%" y="10%" width="20%" height="30%" rx="5%"/>', (20, 10, 60, 40)),
    (HEAD, '<line x1="0%" y1="95%" x2="50%" y2="5%"/>', (0, 5, 100, 95)),
    # a nested viewport: percentages of its own viewBox (50 units drawn 100 mm wide)
    (HEAD, '<svg x="100" y="0" width="100" height="100" viewBox="0 0 50 50"><circle cx="50%" cy="50%" r="20%"/></svg>',
     (130, 30, 170, 70)),
    # no viewBox: the viewport is the root's size in px (200 mm = 755.9 px), drawn at 96 px per inch
    ('<svg xmlns="http://www.w3.org/2000/svg" width="200mm" height="100mm">', '<circle cx="25%" cy="50%" r="10%"/>',
     (50 - R10, 50 - R10, 50 + R10, 50 + R10)),
])
def test_percentages_are_of_the_viewport_as_a_real_renderer_draws_them(tmp_path, head, body, want):
    """x-like lengths are of the viewport's width, y-like of its height, r of its normalised diagonal
    (svgelements alone draws r="10%" as an ellipse 20 x 10 units); checked against librsvg."""
    path = tmp_path / "percent.svg"
    width = 0.1 if "viewBox" in head else 0.4  # 0.1 mm: user units are mm, else px
    path.write_text(head + body.replace("/>", f' stroke="black" stroke-width="{width}" fill="none"/>') + "</svg>")
    d = VEC.trace(path, {})
    pts = np.vstack(d.polylines)
    np.testing.assert_allclose((*pts.min(axis=0), *pts.max(axis=0)), want, atol=1e-4)  # px: svgelements' 1e-6
    np.testing.assert_allclose(rsvg_ink_boxes(path), want, atol=0.25)


@pytest.mark.parametrize("body, words", [
    ('<path id="p" d="M 0 0 L 10 NaN" stroke="black"/>', "line 2: <path id='p'> has a number that is not finite in d="),
    ('<path d="M 0 0 L 1e999 10" stroke="black"/>', "line 2: <path> has a number that is not finite"),
    ('<path d="M 0 0 L ' + "9" * 400 + ' 10" stroke="black"/>', "line 2: <path> has a number that is not finite"),
    ('<circle cx="inf" cy="5" r="3" stroke="black"/>', "not finite in cx='inf'"),
    ('<g transform="translate(NaN,0)"><path d="M0 0 L1 1" stroke="black"/></g>', "not finite in transform="),
    ('<rect x="10" y="10" width="-5" height="5" stroke="black"/>', "negative width ('-5')"),
    ('<circle cx="5" cy="5" r="-3" stroke="black"/>', "negative r"),
])
def test_bad_numbers_are_one_line_naming_the_element_and_nothing_is_written(tmp_path, capsys, body, words):
    """svgelements drops a path with NaN quietly, turns 1e999 into NaN and inf into 0: each is refused first."""
    from doodlecam.cli import main

    path = tmp_path / "bad.svg"
    path.write_text(HEAD + "\n" + body + '\n<path d="M 0 0 L 50 50" stroke="black"/></svg>')
    out = tmp_path / "out"
    assert main(["convert", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not out.exists()


def test_a_viewbox_of_no_size_is_refused(tmp_path):
    path = tmp_path / "zero.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="10mm" height="10mm" viewBox="0 0 0 10">'
                    '<path d="M0 0 L1 1" stroke="black"/></svg>')
    with pytest.raises(InputError, match=r"line 1: <svg> has a viewBox of no size \('0 0 0 10'\)"):
        VEC.trace(path, {})


def test_damaged_dxf_files_are_one_line_each(tmp_path):
    """A NaN coordinate, a file cut short, garbage: each refused in one line that says what is wrong, never
    echoing raw bytes of the file."""
    import ezdxf

    doc = ezdxf.new()
    doc.modelspace().add_line((0, 0), (10, 10))
    doc.modelspace().add_line((0, 0), (float("nan"), 5))
    nan = tmp_path / "nan.dxf"
    doc.saveas(nan)
    cut = tmp_path / "cut.dxf"
    text = nan.read_text()
    cut.write_text(text[:len(text) // 2])
    junk = tmp_path / "junk.dxf"
    junk.write_bytes(b"\x00" * 80 + b"garbage\x01\x02" * 10)
    for path, words in ((nan, "LINE (handle"), (cut, "cut short"), (junk, "not a readable DXF file")):
        with pytest.raises(InputError) as e:
            VEC.trace(path, {})
        msg = str(e.value)
        assert words in msg and "\n" not in msg and all(c.isprintable() for c in msg), msg
