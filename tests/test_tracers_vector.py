"""The `vector` tracer: SVG and DXF through trimesh.path, STL sections and silhouettes."""

from pathlib import Path

import numpy as np
import pytest

from doodlecam.errors import InputError, PluginError
from doodlecam.trace.layout import fit_to_work_area
from doodlecam.plugins.vector import VectorTracer

SAMPLES = Path(__file__).resolve().parent.parent / "samples" / "vectors"
VEC = VectorTracer()


def one_line(err, path):
    msg = str(err.value)
    assert "\n" not in msg and Path(path).name in msg


def ring_near(d, centre, radius, tol=0.05):
    """Some polyline is a circle of that radius about that centre."""
    for p in d.polylines:
        r = np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1])
        if np.abs(r - radius).max() < tol:
            return p
    raise AssertionError(f"no circle of radius {radius} at {centre}")


# --- SVG --------------------------------------------------------------------------------


def test_badge_sample_units_transforms_and_shapes():
    d = VEC.trace(SAMPLES / "badge.svg", {})
    assert d.units == "mm" and d.y_down and d.meta["canvas"] == (0.0, 0.0, 100.0, 70.0)
    assert d.meta["mm_per_user_unit"] == 0.5
    ring_near(d, (30.0, 35.0), 21.0)  # circle r=42 at translate(60 70), half-mm user units
    (star,) = [p for p in d.polylines if len(p) == 11]  # ten corners, closed
    tip = star[np.argmin(star[:, 1])]  # the topmost point (y down)
    assert tip == pytest.approx([30.0, 18.0], abs=0.01)  # (34, 0) rotated -90 degrees: straight up
    frame = max(d.polylines, key=lambda p: np.ptp(p[:, 0]))
    assert np.ptp(frame, axis=0) == pytest.approx([96, 66], abs=0.01)
    corner = np.hypot(frame[:, 0] - 2, frame[:, 1] - 2).min()
    assert corner > 1.0  # rounded corners (rx), not a square one at (2, 2)
    assert all(np.array_equal(p[0], p[-1]) for p in d.polylines if np.ptp(p[:, 0]) > 40)  # closed shapes


def test_svg_units_and_viewbox(tmp_path):
    cases = {
        'width="2in" height="1in" viewBox="0 0 2 1"': 25.4,
        'width="50mm" height="50mm" viewBox="0 0 100 100"': 0.5,
        'width="100" height="100"': 25.4 / 96,  # px
        'viewBox="0 0 100 100"': 25.4 / 96,
    }
    for attrs, mm in cases.items():
        path = tmp_path / "u.svg"
        path.write_text(f'<svg xmlns="http://www.w3.org/2000/svg" {attrs}><line x1="0" y1="0" x2="1" y2="0"/>'
                        '<circle cx="1" cy="1" r="0.5"/></svg>')
        d = VEC.trace(path, {})
        assert d.meta["mm_per_user_unit"] == pytest.approx(mm), attrs
        ring_near(d, (mm, mm), 0.5 * mm, tol=0.05 * mm)
    # no viewBox, size in cm: user units are px; the canvas is the page
    path = tmp_path / "cm.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="10cm" height="5cm"><rect x="0" y="0" width="10" height="10"/></svg>')
    d = VEC.trace(path, {})
    assert d.meta["canvas"] == pytest.approx((0, 0, 100, 50))


def test_svg_true_size_through_the_layout(machine):
    d = fit_to_work_area(VEC.trace(SAMPLES / "badge.svg", {}), machine, {"scale": 1})
    pts = np.concatenate(d.polylines)
    assert np.ptp(pts, axis=0) == pytest.approx([96, 66], abs=0.01)  # the frame at its true size
    # The 100 x 70 mm page is centred on the 300 x 200 mm work area, y turned up:
    # the circle (centre 30, 35 from the page's top left) lands at (130, 100).
    ring_near(d, (100 + 30, 65 + 70 - 35), 21.0)


@pytest.mark.parametrize("body, words", [
    ("", "no shapes"),
    ('<text x="1" y="1">only words</text>', "no shapes"),
    ('<g transform="scale(2)"></g>', "no shapes"),
])
def test_svg_with_nothing_to_draw(tmp_path, body, words):
    path = tmp_path / "empty.svg"
    path.write_text(f'<svg xmlns="http://www.w3.org/2000/svg" width="10mm" height="10mm">{body}</svg>')
    with pytest.raises(InputError, match=words) as err:
        VEC.trace(path, {})
    one_line(err, path)


@pytest.mark.parametrize("content", ["<svg><path d=", "not xml at all", '<html xmlns="http://www.w3.org/1999/xhtml"/>', ""])
def test_broken_svg_files(tmp_path, content):
    path = tmp_path / "broken.svg"
    path.write_text(content)
    with pytest.raises(InputError) as err:
        VEC.trace(path, {})
    one_line(err, path)


# --- DXF --------------------------------------------------------------------------------


def test_bracket_dxf():
    d = VEC.trace(SAMPLES / "bracket.dxf", {})
    assert d.units == "mm" and not d.y_down
    assert d.meta["units"] == "millimeters" and d.meta["skipped_entities"] == {"TEXT": 1}
    assert d.bounds == pytest.approx((0, 0, 80, 60), abs=1e-6)
    for c in [(10, 50), (10, 30), (50, 6), (70, 6)]:
        ring_near(d, c, 3.0, tol=0.03)
    outline = max(d.polylines, key=len)
    assert np.array_equal(outline[0], outline[-1])  # lines and the fillet joined into one closed stroke
    assert len(d.polylines) == 6  # outline, 4 holes, the slot


def _dxf(tmp_path, units, entities):
    head = f"0\nSECTION\n2\nHEADER\n9\n$INSUNITS\n70\n{units}\n0\nENDSEC\n" if units is not None else ""
    path = tmp_path / "t.dxf"
    path.write_text(head + "0\nSECTION\n2\nENTITIES\n" + entities + "0\nENDSEC\n0\nEOF\n")
    return path


def test_dxf_units_and_unsupported_entities(tmp_path):
    line = "0\nLINE\n8\n0\n10\n0\n20\n0\n30\n0\n11\n2\n21\n0\n31\n0\n"
    text = "0\nTEXT\n8\n0\n10\n0\n20\n0\n30\n0\n40\n1\n1\nHELLO\n"
    inch = VEC.trace(_dxf(tmp_path, 1, line + text), {})
    assert inch.bounds == pytest.approx((0, 0, 50.8, 0)) and inch.meta["skipped_entities"] == {"TEXT": 1}
    bare = VEC.trace(_dxf(tmp_path, None, line), {})
    assert bare.bounds == pytest.approx((0, 0, 2, 0)) and "assumed" in bare.meta["units"]
    import ezdxf

    doc = ezdxf.new("R2010")
    doc.modelspace().add_text("HELLO", height=1)
    doc.modelspace().add_hatch().paths.add_polyline_path([(0, 0), (1, 0), (1, 1)])
    path = tmp_path / "words.dxf"
    doc.saveas(path)
    with pytest.raises(InputError, match="HATCH, TEXT") as err:
        VEC.trace(path, {})
    one_line(err, path)
    garbage = tmp_path / "garbage.dxf"
    garbage.write_bytes(np.random.default_rng(0).bytes(3000))
    with pytest.raises(InputError) as err:
        VEC.trace(garbage, {})
    one_line(err, garbage)


# --- meshes -----------------------------------------------------------------------------


def test_gear_section():
    d = VEC.trace(SAMPLES / "gear.stl", {})
    assert d.meta["closed_outlines"] == 6 and d.meta["open_outlines"] == 0 and d.meta["watertight"]
    ring_near(d, (0, 0), 6.0, tol=0.05)  # the bore
    for k in range(4):
        a = k * np.pi / 2 + np.pi / 4
        ring_near(d, (17 * np.cos(a), 17 * np.sin(a)), 5.0, tol=0.05)
    outer = max(d.polylines, key=len)
    r = np.hypot(*outer.T)
    assert r.min() == pytest.approx(27, abs=0.1) and r.max() == pytest.approx(33, abs=0.1)
    assert VEC.trace(SAMPLES / "gear.stl", {"plane": "z=1.5"}).meta["closed_outlines"] == 6
    side = VEC.trace(SAMPLES / "gear.stl", {"plane": "y=50%"})
    assert side.bounds[3] - side.bounds[1] == pytest.approx(6.0)  # the 6 mm thickness, seen in x-z
    tilted = VEC.trace(SAMPLES / "gear.stl", {"plane": "0,1,1=50%"})
    assert tilted.polylines


def test_gear_silhouettes():
    top = VEC.trace(SAMPLES / "gear.stl", {"mesh": "silhouette", "direction": "z"})
    assert len(top.polylines) == 6  # outline and the five holes you can see through
    ring_near(top, (0, 0), 6.0, tol=0.05)
    side = VEC.trace(SAMPLES / "gear.stl", {"mesh": "silhouette", "direction": "x"})
    assert len(side.polylines) == 1
    assert np.ptp(side.polylines[0], axis=0) == pytest.approx([66, 6], abs=0.1)


def test_bad_meshes_and_planes(tmp_path):
    import trimesh

    gear = SAMPLES / "gear.stl"
    for plane in ("z=200", "z=-1", "z=0%", "x=101%"):
        with pytest.raises(InputError, match="misses the mesh") as err:
            VEC.trace(gear, {"plane": plane})
        one_line(err, gear)
    for bad in ({"plane": "w=3"}, {"plane": "z=deep"}, {"mesh": "slice"}, {"mesh": "silhouette", "direction": "0,0,0"},
                {"tolerance": 0}):
        with pytest.raises(PluginError):
            VEC.trace(gear, bad)
    box = trimesh.creation.box((10, 10, 10))
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:])  # one side missing
    assert not open_box.is_watertight
    path = tmp_path / "open.stl"
    open_box.export(path)
    d = VEC.trace(path, {})
    assert d.polylines and d.meta["open_outlines"] == 1 and not d.meta["watertight"]
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"\0" * 80 + b"\0\0\0\0")  # a binary STL with no triangles
    flat = tmp_path / "flat.stl"
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]).export(flat)
    for path, words in ((empty, "no triangles|not a readable"), (tmp_path / "zero.stl", "empty")):
        if path.name == "zero.stl":
            path.write_bytes(b"")
        with pytest.raises(InputError, match=words) as err:
            VEC.trace(path, {})
        one_line(err, path)
    with pytest.raises(InputError, match="flat that way") as err:
        VEC.trace(flat, {"mesh": "silhouette", "direction": "x"})
    with pytest.raises(InputError, match="misses"):
        VEC.trace(flat, {})  # a flat mesh has no height to cut


def test_cli_converts_vector_samples(tmp_path):
    from doodlecam.cli import main

    out = tmp_path / "out"
    assert main(["convert", str(SAMPLES / "bracket.dxf"), "-o", str(out), "--post", "svg", "--scale", "1"]) == 0
    assert (out / "bracket.svg").stat().st_size > 0
    bad = tmp_path / "nothing.svg"
    bad.write_text('<svg xmlns="http://www.w3.org/2000/svg"/>')
    assert main(["convert", str(bad), "-o", str(tmp_path / "none")]) != 0
    assert not (tmp_path / "none" / "nothing.svg").exists()


def test_a_cusp_is_one_corner_without_thousands_of_points(tmp_path):
    """A curve doubling back on itself (a folded quadratic, as clipping a generated random walk
    to the page makes) turns by pi at its cusp however finely it is cut: the chords stop
    doubling at the turn's cap instead of at 4 096 points, the fitter cuts the stroke there
    once, and the pieces still follow the curve within tolerance."""
    from doodlecam.geometry.fit import fit_pieces

    svg = tmp_path / "cusp.svg"
    svg.write_text('<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="100mm" viewBox="0 0 100 100">'
                   '<path d="M10,50 Q90,50.0 40,50.0 Q20,80 60,90" fill="none" stroke="black"/></svg>')
    d = VectorTracer().trace(svg, {})
    (p,) = d.polylines
    assert len(p) <= 2 * 1025  # two segments of at most 1 024 chords (4 096 made 6 306 points)
    pieces = fit_pieces(p, 3, 0.1, corner=float(d.meta["split_corners_deg"]))
    ends = [s.end for s, _ in pieces[:-1]]
    # the fold (the first quadratic's largest x) is a cut
    t = (90 - 10) / ((90 - 10) + (90 - 40))
    tip = (1 - t) ** 2 * 10 + 2 * (1 - t) * t * 90 + t ** 2 * 40
    assert any(abs(e[0] - tip) < 0.05 for e in ends)
    assert max(err for _, err in pieces) <= 0.1


def test_svg_parse_runs_without_collections_and_restores_the_collector(tmp_path, monkeypatch):
    """The parse allocates millions of objects: no cyclic collection walks them while it runs (even with the
    collector at its most eager), and the collector is on again afterwards, also after a malformed file."""
    import gc

    import svgelements as se
    from generated_art import generated_svg

    good, bad = tmp_path / "art.svg", tmp_path / "bad.svg"
    good.write_text(generated_svg(300, "mixed", seed=3))
    bad.write_text(generated_svg(3, "mixed", seed=3))  # the parser below fails on it
    seen, during = [], []
    parse = se.SVG.parse

    def counted(*args, **kwargs):
        before = len(seen)
        try:
            if "bad" in str(args[0]):
                raise ValueError("the parser fails")
            return parse(*args, **kwargs)
        finally:
            during.append(len(seen) - before)

    def count(phase, info):
        if phase == "start":
            seen.append(info["generation"])

    monkeypatch.setattr(se.SVG, "parse", counted)
    old = gc.get_threshold()
    gc.callbacks.append(count)
    gc.set_threshold(1)  # a young collection at every allocation of a tracked object
    try:
        d = VEC.trace(good, {})
        with pytest.raises(InputError, match="not a readable SVG"):
            VEC.trace(bad, {})
    finally:
        gc.set_threshold(*old)
        gc.callbacks.remove(count)
    assert len(d.polylines) >= 300 and gc.isenabled()
    assert during == [0, 0] and len(seen) > 0  # none in either parse; the collector ran outside them
