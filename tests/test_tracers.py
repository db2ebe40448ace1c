"""The `contours` and `hatch` tracers, default tracer choice, and bad pictures for every image tracer."""

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image
from scipy import ndimage as ndi
from scipy.spatial import cKDTree
from skimage import data, draw

from doodlecam import registry
from doodlecam.errors import InputError, PluginError
from doodlecam.geometry.fit import densify
from doodlecam.plugins.contours import ContoursTracer
from doodlecam.plugins.edges import EdgesTracer
from doodlecam.plugins.hatch import HatchTracer, hatch_mask

from conftest import assert_one_line, save

CONTOURS, HATCH = ContoursTracer(), HatchTracer()
IMAGE_TRACERS = [EdgesTracer(), CONTOURS, HATCH]


def ring_image(h=160, w=200, centre=(80, 90), r_out=50, r_in=20):
    img = np.full((h, w), 240, np.uint8)
    img[draw.disk(centre, r_out)] = 20
    img[draw.disk(centre, r_in)] = 240
    return img


# --- contours --------------------------------------------------------------------


def test_contours_outline_a_ring_with_its_hole(tmp_path):
    path = save(tmp_path, "ring.png", ring_image())
    d = CONTOURS.trace(path, {})
    assert d.units == "px" and d.y_down and d.extent == (200.0, 160.0)
    assert len(d.polylines) == 2 and d.meta["outlines"] == 2
    radii = sorted(np.hypot(p[:, 0] - 90, p[:, 1] - 80).mean() for p in d.polylines)
    assert radii == pytest.approx([20, 50], abs=1.0)
    for p in d.polylines:
        assert np.array_equal(p[0], p[-1])  # closed
        r = np.hypot(p[:, 0] - 90, p[:, 1] - 80)
        assert np.ptp(r) < 2.0  # smooth circles, not staircases


def test_contours_threshold_invert_and_edge_regions(tmp_path):
    img = np.full((100, 120), 250, np.uint8)
    img[:, :40] = 10  # dark band on the left edge
    img[30:70, 70:100] = 140  # mid-grey square
    path = save(tmp_path, "bands.png", img)
    otsu = CONTOURS.trace(path, {})
    light = CONTOURS.trace(path, {"threshold": "0.7"})
    assert len(light.polylines) == 2 and len(otsu.polylines) == 1  # 0.55 grey is dark only below 0.7
    band = otsu.polylines[0]
    assert np.array_equal(band[0], band[-1])  # closed along the picture's edge
    assert band[:, 0].min() == pytest.approx(-0.5, abs=0.01) and band[:, 0].max() == pytest.approx(39.5, abs=1)
    inverted = CONTOURS.trace(path, {"invert": True, "threshold": 0.3})
    xs = np.concatenate(inverted.polylines)[:, 0]
    assert xs.max() > 115  # the light right part is outlined now
    for bad in ({"threshold": "dark"}, {"threshold": "1.5"}, {"blur": -1}):
        with pytest.raises(PluginError):
            CONTOURS.trace(path, bad)


def test_contours_fill_stays_inside_and_covers(tmp_path):
    img = ring_image()
    path = save(tmp_path, "ring.png", img)
    d = CONTOURS.trace(path, {"fill": True, "fill_spacing": 3})
    dark = img < 128
    hatch = [p for p in d.polylines[d.meta["outlines"]:]]
    assert len(hatch) >= 2
    pts = np.vstack([densify(p, 0.5) for p in hatch])
    # every fill point is on the dark ring (or within a pixel of its edge)
    dist_out = ndi.distance_transform_edt(~dark)
    xi, yi = np.rint(pts[:, 0]).astype(int), np.rint(pts[:, 1]).astype(int)
    assert (dist_out[yi, xi] <= 1.5).all()
    # and every dark pixel is within half a spacing (+1 px) of a fill line
    near = cKDTree(pts).query(np.argwhere(dark)[:, ::-1])[0]
    assert (near <= 2.5).mean() > 0.99
    cross = CONTOURS.trace(path, {"fill": True, "fill_spacing": 3, "fill_cross": True})
    assert cross.length > 1.8 * d.length - sum(np.hypot(*np.diff(p, axis=0).T).sum() for p in d.polylines[:2])


# --- hatch ------------------------------------------------------------------------


def test_hatch_lines_are_spaced_and_angled(tmp_path):
    mask = np.ones((100, 140), bool)
    for angle in (0.0, 30.0, 90.0):
        segs = hatch_mask(mask, 5.0, angle, join=False)
        d = np.array([s[1] - s[0] for s in segs])
        ang = np.degrees(np.arctan2(-d[:, 1], d[:, 0])) % 180  # y down: counter-clockwise is -y
        assert np.allclose(ang, angle % 180, atol=0.01)
        u = np.array([np.cos(np.radians(angle)), -np.sin(np.radians(angle))])
        offs = np.unique(np.round([s[0] @ np.array([-u[1], u[0]]) for s in segs], 6))
        assert np.allclose(np.diff(offs), 5.0)
        ends = np.vstack(segs)
        assert ends.min() >= -0.5 - 1e-9 and ends[:, 0].max() <= 139.5 + 1e-9 and ends[:, 1].max() <= 99.5 + 1e-9
    zig = hatch_mask(mask, 5.0, 0.0, join=True, turns=True)
    assert len(zig) == 1  # a full rectangle is one meander: each line, then a U-turn of 6 points
    n = len(hatch_mask(mask, 5.0, 0.0))
    assert len(zig[0]) == 2 * n + 6 * (n - 1)
    straight = hatch_mask(mask, 5.0, 0.0, join=True)  # ... or one zig-zag: line, a 5 px move across, line
    assert len(straight) == 1 and len(straight[0]) == 2 * n
    steps = np.diff(straight[0], axis=0)
    assert np.allclose(np.abs(steps[1::2, 1]), 5.0) and np.allclose(steps[1::2, 0], 0.0)
    turn = np.diff(zig[0], axis=0)
    heading = np.arctan2(turn[:, 1], turn[:, 0])
    assert np.abs(np.angle(np.exp(1j * np.diff(heading)))).max() < np.radians(60)  # no sharp corner


def test_hatch_density_follows_the_grey_level(tmp_path):
    ramp = np.tile(np.linspace(255, 0, 256).astype(np.uint8), (120, 1))  # white left, black right
    path = save(tmp_path, "ramp.png", ramp)
    d = HATCH.trace(path, {"blur": 0})
    pts = np.vstack([densify(p, 0.5) for p in d.polylines])
    ink = np.histogram(pts[:, 0], bins=8, range=(-0.5, 255.5))[0]
    assert ink[0] < 0.05 * ink[-1]  # paper stays (nearly) white
    assert np.all(np.diff(ink) >= -0.1 * ink.max())  # darker, more ink
    assert ink[-1] > 3 * ink[2]
    flat = HATCH.trace(path, {"blur": 0, "cross": False, "levels": 2})
    crossed = HATCH.trace(path, {"blur": 0, "levels": 2})
    def angles(dr):
        segs = np.vstack([np.diff(p, axis=0) for p in dr.polylines])
        long = np.hypot(*segs.T) > 6
        return np.unique(np.round(np.degrees(np.arctan2(-segs[long, 1], segs[long, 0])) % 180))
    assert set(angles(flat)) == {45.0} and {45.0, 135.0} <= set(angles(crossed))


def test_hatch_camera_and_options(tmp_path):
    path = save(tmp_path, "camera.png", data.camera())
    d = HATCH.trace(path, {"join": False})
    assert 100 < len(d.polylines) < 5000 and d.extent == (512.0, 512.0)
    pts = np.vstack(d.polylines)
    assert pts.min() >= -0.5 - 1e-9 and pts.max() <= 511.5 + 1e-9
    assert all(len(p) == 2 for p in d.polylines)  # straight lines, each its own pen-down
    joined = HATCH.trace(path, {})  # joined by default
    assert 4 * len(joined.polylines) < len(d.polylines)
    assert np.vstack(joined.polylines).min() >= -0.5 - 1e-9 and np.vstack(joined.polylines).max() <= 511.5 + 1e-9
    dense = HATCH.trace(path, {"spacing": 0.5, "levels": 8, "blur": 0})  # the extreme setting
    assert dense.length > 10 * d.length
    for bad in ({"spacing": 0.1}, {"levels": 0}, {"levels": 9}, {"gamma": 0}):
        with pytest.raises(PluginError):
            HATCH.trace(path, bad)


# --- every image tracer: bad and odd pictures ----------------------------------------


@pytest.mark.parametrize("tracer", IMAGE_TRACERS, ids=lambda t: t.name)
def test_blank_and_tiny_pictures_are_one_line_errors(tmp_path, tracer):
    for name, img in (("blank.png", np.full((80, 100), 255, np.uint8)),
                      ("grey.png", np.full((80, 100), 200, np.uint8)),
                      ("one.png", np.full((1, 1), 255, np.uint8))):
        path = save(tmp_path, name, img)
        if tracer.name == "hatch" and name == "grey.png":
            assert tracer.trace(path, {}).polylines  # a flat grey is a tone: hatched
            continue
        with pytest.raises(InputError) as err:
            tracer.trace(path, {})
        assert_one_line(err, path)


@pytest.mark.parametrize("tracer", IMAGE_TRACERS, ids=lambda t: t.name)
def test_odd_formats_trace(tmp_path, tracer):
    base = ring_image()
    rgba = np.dstack([np.zeros_like(base)] * 3 + [255 - base])  # shape only in alpha
    cases = [("deep.png", Image.fromarray(base.astype(np.uint16) * 257)),
             ("alpha.png", Image.fromarray(rgba, "RGBA")),
             ("palette.png", Image.fromarray(base).convert("P")),
             ("cmyk.jpg", Image.fromarray(base).convert("CMYK"))]
    for name, im in cases:
        path = tmp_path / name
        im.save(path)
        d = tracer.trace(path, {})
        pts = np.vstack(d.polylines)
        r = np.hypot(pts[:, 0] - 90, pts[:, 1] - 80)
        assert r.max() < 53 and len(d.polylines) >= 2, name  # only the ring is drawn


def _png_header_only(path, w, h):
    import struct
    import zlib

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))
                     + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("tracer", IMAGE_TRACERS, ids=lambda t: t.name)
def test_absurd_sizes_are_refused_from_the_header(tmp_path, tracer):
    import resource

    for w, h in ((20_000, 20_000), (8_000, 6_000)):
        path = _png_header_only(tmp_path / f"huge_{w}.png", w, h)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        with pytest.raises(InputError, match="megapixels") as err:
            tracer.trace(path, {})
        assert_one_line(err, path)
        assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 200_000  # KiB: nothing allocated
    truncated = _png_header_only(tmp_path / "cut.png", 300, 200)  # a small header, no real pixel data
    with pytest.raises(InputError, match="truncated|damaged") as err:
        tracer.trace(truncated, {})
    assert_one_line(err, truncated)


# --- choosing a tracer, the plugin contract, the CLI ---------------------------------------


def test_default_tracer_per_file_type(tmp_path):
    from doodlecam.machine import parse_machine
    from doodlecam.pipeline import Settings, pick_tracer

    from conftest import PROFILE

    s = Settings(machine=parse_machine(PROFILE, "t.toml"))
    for name, tracer in (("a.png", "auto"), ("a.JPG", "auto"), ("a.svg", "vector"), ("a.dxf", "vector"),
                         ("a.stl", "vector")):
        assert pick_tracer(tmp_path / name, s).name == tracer
    from dataclasses import replace

    assert pick_tracer(tmp_path / "a.png", replace(s, tracer="hatch")).name == "hatch"


def test_plugin_contract():
    for name, cls in (("contours", ContoursTracer), ("hatch", HatchTracer)):
        assert registry.get("tracer", name) is cls
        assert "\n" not in cls.summary and cls.extensions == EdgesTracer.extensions
        assert all(o.help for o in cls.options)
    code = ("import sys, doodlecam.plugins.contours, doodlecam.plugins.hatch, doodlecam.plugins.vector; "
            "print(*sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'skimage', 'PIL', 'trimesh', 'shapely', 'lxml'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == ""  # listing plugins stays fast


def test_cli_contours_end_to_end(tmp_path):
    from doodlecam.cli import main

    img = np.full((60, 80), 250, np.uint8)
    img[15:45, 20:60] = 10
    path = save(tmp_path, "box.png", img)
    out = tmp_path / "out"
    assert main(["convert", str(path), "-o", str(out), "--tracer", "contours", "--post", "svg",
                 "--width", "120", "--keep-direction"]) == 0
    svg = (out / "box.svg").read_text()
    assert "<path" in svg or "<polyline" in svg
    blank = save(tmp_path, "blank.png", np.full((60, 80), 250, np.uint8))
    assert main(["convert", str(blank), "-o", str(tmp_path / "none"), "--tracer", "contours"]) != 0
    assert not (tmp_path / "none").exists() or not any((tmp_path / "none").iterdir())
    assert main(["convert", str(path), "-o", str(out), "--tracer", "contours", "--scale", "100"]) != 0  # too big


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.5, 12), st.floats(-360, 360), st.floats(0, 1), st.booleans())
def test_hatch_lines_stay_on_the_mask_and_cover_it(seed, spacing, angle, offset, join):
    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 90, 2)
    mask = ndi.gaussian_filter(rng.random((h, w)), 3) > 0.5
    lines = hatch_mask(mask, spacing, angle, offset=offset, join=join)
    if not mask.any():
        assert lines == []
        return
    dist_out = ndi.distance_transform_edt(~mask)
    pad = np.pad(dist_out, 1, constant_values=np.inf)
    for p in lines:
        assert np.isfinite(p).all() and len(p) >= 2
        assert p[:, 0].min() >= -0.5 - 1e-9 and p[:, 0].max() <= w - 0.5 + 1e-9
        assert p[:, 1].min() >= -0.5 - 1e-9 and p[:, 1].max() <= h - 0.5 + 1e-9
    segs = [p for q in lines for p in (q[:2],)] if join else lines
    for s in segs:  # a hatch run lies on dark pixels (its ends within a pixel of them)
        pts = densify(s, 0.5)
        xi = np.clip(np.rint(pts[:, 0]).astype(int), 0, w - 1) + 1  # x = w - 0.5 rounds to w: the last pixel
        yi = np.clip(np.rint(pts[:, 1]).astype(int), 0, h - 1) + 1
        assert (pad[yi, xi] <= 1.5).all()
    if spacing <= 3 and lines:
        pts = np.vstack([densify(p, 0.5) for p in lines])
        near = cKDTree(pts).query(np.argwhere(mask)[:, ::-1])[0]
        assert (near <= spacing / 2 + 1.0).mean() > 0.97


def test_auto_on_a_photo_traces_exactly_as_edges():
    """auto hands a photo to edges on the same working picture (the pen-width grid, scaled up or
    down), so the studio's default and `convert --tracer edges` draw the same strokes."""
    from pathlib import Path

    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, trace

    photo = Path(__file__).resolve().parent.parent / "samples" / "images" / "coins.png"
    m = load_machine("doodlebot")
    auto = trace(photo, Settings(machine=m, tracer="auto", tracer_options={"sigma": 3}))
    edges = trace(photo, Settings(machine=m, tracer="edges", tracer_options={"sigma": 3}))
    assert auto.meta["tracer_reason"].startswith("auto: ")
    assert len(auto.polylines) == len(edges.polylines) > 5
    assert all(np.array_equal(a, b) for a, b in zip(auto.polylines, edges.polylines))
