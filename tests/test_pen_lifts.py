"""The pen is never lifted and lowered at the same point (issue 18).

The pictures are converted with the ``contours`` tracer and the written
G-code and PLC files are read back with readers written from docs/formats.md
(no doodlecam code): every pen-down must be somewhere else than the pen-up
before it, and the pen goes down once per outline: at most once per
connected dark region and once per hole in it.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np
import pytest

from doodlecam.machine import load_machine
from doodlecam.model import Job, Spline, Stroke, Travel
from doodlecam.pipeline import Settings, convert

IMAGES = Path(__file__).resolve().parent.parent / "samples" / "images"
PEN_DOWN, PEN_UP = "M3 S1000", "M3 S0"  # the grbl servo dialect's defaults (docs/formats.md)


def gcode_pen_downs(text: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(where the pen goes down, where it went up before each), from the G-code text."""
    pos, up_at, downs, ups = np.zeros(2), None, [], []
    for raw in text.splitlines():
        line = raw.split(";")[0].strip()
        if not line:
            continue
        if line == PEN_DOWN:
            downs.append(pos.copy())
            ups.append(up_at)
        elif line == PEN_UP:
            up_at = pos.copy()
        elif re.match(r"G[0-3]\b", line):
            words = dict((w[0], float(w[1:])) for w in line.split()[1:])
            pos = np.array([words.get("X", pos[0]), words.get("Y", pos[1])])
    return downs, ups


def plc_pen_downs(data: bytes) -> tuple[list[np.ndarray], list[np.ndarray | None]]:
    """(where the pen goes down, where it went up before each), in steps, from the
    PLC file: the pen follows the command type; DRAWs ramp the velocity linearly."""
    version, = struct.unpack_from("<H", data, 8)
    n, dt = struct.unpack_from("<Id", data, 12)
    size = {1: 56, 2: 64}[version]  # version 2: draw_accel in the header, PAUSE commands
    pos, vel, pen, up_at, downs, ups = np.zeros(2), np.zeros(2), False, None, [], []
    for i in range(n):
        _, kind, _, x, y = struct.unpack_from("<IHHii", data, size + 16 * i)
        if kind == 2:  # PAUSE (pen change): the pen lifts where it stands
            if pen:
                up_at, pen = pos.copy(), False
        elif kind == 1:  # MOVE, pen up
            if pen:
                up_at, pen = pos.copy(), False
            pos, vel = np.array([x, y], float), np.zeros(2)
        else:  # DRAW, pen down
            if not pen:
                downs.append(pos.copy())
                ups.append(up_at)
                pen = True
            target = np.array([x, y], float)
            pos = pos + 0.5 * dt * (vel + target)
            vel = target
    return downs, ups


def as_traced(picture: Path, drawing_meta: dict) -> tuple[np.ndarray, float]:
    """(the picture as the tracer saw it, its px per picture px): image tracers work on the
    pen-width grid (``meta["working_px"]``), resampled as ``working_picture`` does."""
    from doodlecam.trace.raster import load_gray, working_picture

    gray = load_gray(picture)
    if "working_px" not in drawing_meta:
        return gray, 1.0
    k = drawing_meta["working_px"][0] / gray.shape[1]
    return working_picture(gray, k, 1.0, upscale=True)[0], k


def dark_regions_and_holes(drawing_meta: dict, picture: Path) -> tuple[int, int]:
    """(connected dark regions (8-neighbours), light holes in them (4-neighbours, not
    touching the frame)) of the blurred picture at the traced threshold: the
    boundaries an outline tracer can draw."""
    from scipy import ndimage as ndi
    from skimage import measure

    gray, _ = as_traced(picture, drawing_meta)
    gray = ndi.gaussian_filter(gray.astype(np.float32), drawing_meta["blur_px"], mode="nearest")
    dark = gray < drawing_meta["threshold"]
    light = measure.label(np.pad(~dark, 1, constant_values=True), connectivity=1)
    return int(measure.label(dark, connectivity=2).max()), int(light.max()) - 1  # less the one around the frame


@pytest.mark.parametrize("name", ["camera", "coins", "horse", "chelsea"])
def test_contours_never_lift_in_place_and_lift_once_per_outline(tmp_path, name):
    """(before: a long outline's pieces were drawn with a lift in place between them)"""
    picture = IMAGES / f"{name}.png"
    res = convert(picture, tmp_path, Settings(machine=load_machine("doodlebot"), tracer="contours",
                                               posts=("gcode", "plc")))
    job = res.job
    outlines = res.drawing_meta["outlines"]
    downs, ups = gcode_pen_downs((tmp_path / f"{name}.gcode").read_text())
    assert len(downs) == job.pen_lifts
    for d, u in zip(downs, ups):
        assert u is None or np.hypot(*(d - u)) > 1e-3, (d, u)  # lowered where it was lifted
    pdowns, pups = plc_pen_downs((tmp_path / f"{name}.plc").read_bytes())
    steps = job.machine.x.steps_per_mm
    assert len(pdowns) == len(downs)
    for d, u in zip(pdowns, pups):
        assert u is None or np.hypot(*(d - u)) > 2.0, (d / steps, u / steps)  # steps
    # One lift per traced outline (a closed ring: a region's boundary or a hole's),
    # though long outlines are split into several strokes ...
    assert len(downs) == outlines <= len(job.strokes)
    # ... and no more than the boundaries at the traced threshold: one per connected
    # dark region and one per hole in it (a region with holes cannot be outlined in one
    # pen-down without drawing across it).
    regions, holes = dark_regions_and_holes(res.drawing_meta, picture)
    assert len(downs) <= regions + holes


def test_horse_outline_is_split_yet_drawn_in_one_pen_down(tmp_path):
    """The horse's one outline needs several splines (control-point cap): they meet
    exactly, run one after another, and the pen stays down across them."""
    res = convert(IMAGES / "horse.png", tmp_path, Settings(machine=load_machine("doodlebot"), tracer="contours",
                                                           posts=("gcode", "plc", "svg", "csv", "json")))
    job = res.job
    assert len(job.strokes) > 1 and job.pen_lifts == 1
    for a, b in zip(job.strokes, job.strokes[1:]):
        assert np.array_equal(a.spline.end, b.spline.start)
    text = (tmp_path / "horse.gcode").read_text()
    assert text.count(PEN_DOWN) == 1 and text.count(PEN_UP) == 2  # the first lift is at the start
    assert len(re.findall(r"^G0 ", text, re.M)) == 2  # to the start, home
    svg = (tmp_path / "horse.svg").read_text()
    travels = svg.split('id="pen-up"')[1]
    assert travels.count("<path") == 2
    import json

    doc = json.loads((tmp_path / "horse.json").read_text())
    assert [s["pen_lift"] for s in doc["strokes"]] == [True] + [False] * (len(job.strokes) - 1)
    assert doc["figures"]["pen_lifts"] == 1
    rows = [r for r in (tmp_path / "horse.csv").read_text().splitlines() if r and not r.startswith("#")][1:]
    pen = np.array([int(r.rsplit(",", 1)[1]) for r in rows])
    assert np.count_nonzero(np.diff(pen) == 1) == 1  # lowered once
    m = job.machine
    draw = job.draw_time + sum(t.duration for t in job.travels)
    assert job.duration == pytest.approx(draw + m.pen.up_delay + m.pen.down_delay)
    assert res.summary()["pen_lifts"] == 1


def _stroke(a, b, layer=""):
    return Stroke(Spline(3, np.linspace(a, b, 4)), layer=layer)


def test_lifts_are_a_property_of_the_job():
    """Zero travel on one layer: no lift; a pen change or any travel: a lift."""
    m = load_machine("doodlebot")
    pts = [np.array(p, float) for p in ((10, 10), (20, 10), (20, 20), (30, 20), (40, 20))]
    strokes = (_stroke(pts[0], pts[1]), _stroke(pts[1], pts[2]), _stroke(pts[2], pts[3], "b"),
               _stroke(pts[3] + [0, 1e-3], pts[4], "b"))
    home = np.zeros(2)
    travels = (Travel(home, pts[0]), Travel(pts[1], pts[1]), Travel(pts[2], pts[2]),
               Travel(pts[3], pts[3] + [0, 1e-3]), Travel(pts[4], home))
    job = Job(m, strokes, travels)
    assert job.lifts == (True, False, True, True)  # joined; pen change; 1 um apart
    assert job.pen_lifts == 3
    assert job.duration == pytest.approx(3 * (m.pen.up_delay + m.pen.down_delay))


# --- hatching: the pen goes on along short moves in the dark instead of lifting


def _ink_map(d, cell=16):
    """Drawn length (px) in each cell x cell square of the picture."""
    from doodlecam.geometry.fit import densify

    pts = np.vstack([densify(p, 0.25) for p in d.polylines])
    w, h = d.extent
    bins = (int(np.ceil(w / cell)), int(np.ceil(h / cell)))
    return np.histogram2d(pts[:, 0], pts[:, 1], bins=bins, range=((-0.5, w - 0.5), (-0.5, h - 0.5)))[0] * 0.25


@pytest.mark.parametrize("name", ["horse"])  # all sample photos: benchmarks/bench_trace.py --lifts
def test_joined_hatching_is_a_third_faster_at_the_same_look(tmp_path, name):
    from doodlecam.plugins.hatch import HatchTracer

    machine = load_machine("doodlebot")
    jobs = {}
    for join in (False, True):
        res = convert(IMAGES / f"{name}.png", tmp_path / str(join), Settings(
            machine=machine, tracer="hatch", tracer_options={"join": join}, posts=("gcode",)))
        jobs[join] = res.job
        downs, ups = gcode_pen_downs((tmp_path / str(join) / f"{name}.gcode").read_text())
        assert len(downs) == res.job.pen_lifts
        assert all(u is None or np.hypot(*(d - u)) > 1e-3 for d, u in zip(downs, ups))
    assert jobs[True].duration <= 0.7 * jobs[False].duration
    assert jobs[True].pen_lifts <= 0.25 * jobs[False].pen_lifts
    # the same look: the same ink, cell by cell, plus the connecting moves (< 10 %)
    tr = HatchTracer()
    plain, joined = (_ink_map(tr.trace(IMAGES / f"{name}.png", {"join": j})) for j in (False, True))
    assert np.corrcoef(plain.ravel(), joined.ravel())[0, 1] > 0.97
    assert 1.0 < joined.sum() / plain.sum() < 1.10


def test_joined_hatching_stays_in_the_dark_region(tmp_path):
    """Every move of a joined hatch (lines and the moves between them) runs on or
    within a pixel of the region it hatches."""
    from scipy import ndimage as ndi

    from doodlecam.plugins.hatch import hatch_mask
    from doodlecam.geometry.fit import densify

    rng = np.random.default_rng(7)
    mask = ndi.gaussian_filter(rng.random((160, 200)), 6) > 0.5
    out = ndi.distance_transform_edt(~mask)
    lines = hatch_mask(mask, 3.0, 30.0, join=True)
    assert len(lines) < 0.2 * len(hatch_mask(mask, 3.0, 30.0))
    for p in lines:
        q = densify(p, 0.25)
        xi = np.clip(np.rint(q[:, 0]).astype(int), 0, 199)
        yi = np.clip(np.rint(q[:, 1]).astype(int), 0, 159)
        assert out[yi, xi].max() <= 1.5


def test_hatch_tone_layers_plot_one_after_another(tmp_path):
    from doodlecam.plugins.hatch import darkness

    machine = load_machine("doodlebot")
    res = convert(IMAGES / "camera.png", tmp_path, Settings(  # drawn 80 mm wide: fewer lines, a quicker test
        machine=machine, tracer="hatch", tracer_options={"layers": "tone", "levels": 4}, posts=("gcode",),
        layout={"width": 80.0}))
    job = res.job
    assert job.layers == ("tone 4", "tone 3", "tone 2", "tone 1")  # lightest first, as traced
    assert len(job.pen_changes) == 3
    assert [job.strokes[i].layer for i in job.pen_changes] == ["tone 3", "tone 2", "tone 1"]
    assert all(job.lifts[i] for i in job.pen_changes)  # a pen change always lifts
    downs, _ = gcode_pen_downs((tmp_path / "camera.gcode").read_text())
    assert len(downs) == job.pen_lifts
    # tone 1 is the darkest level: its lines lie on the darkest pixels of the picture hatched (the
    # pen-width grid, 0.5 mm per px: camera's 0.55 mm px are resampled to it), its links between lines
    # at most a pixel beside them (the join's rule), so every point within a pen width (1 mm) as drawn
    from doodlecam.pipeline import trace as trace_picture
    from scipy import ndimage as ndi

    d = trace_picture(IMAGES / "camera.png", Settings(machine=machine, tracer="hatch",
                                                      tracer_options={"layers": "tone", "levels": 4}))
    gray, k = as_traced(IMAGES / "camera.png", d.meta)
    assert k > 1.05  # resampled (else this checks nothing new)
    out = ndi.distance_transform_edt(~(darkness(gray, 1.0) > 4 / 5))
    from doodlecam.geometry.fit import densify

    ones = [densify(p, 0.5) for p, n in zip(d.polylines, d.layers) if n == "tone 1"]
    assert ones and len(ones) < len(d.polylines)
    q = (np.vstack(ones) + 0.5) * k - 0.5  # picture px -> grid px
    h, w = gray.shape
    far = out[np.clip(np.rint(q[:, 1]).astype(int), 0, h - 1), np.clip(np.rint(q[:, 0]).astype(int), 0, w - 1)]
    assert far.max() <= 2.0  # grid px: 1 mm as drawn
    assert np.mean(far <= 1.0) > 0.995  # all but a few link points on or next to the darkest pixels


def test_hatch_layers_option_is_checked():
    from doodlecam.errors import PluginError
    from doodlecam.plugins.hatch import HatchTracer

    with pytest.raises(PluginError, match="layers must be 'one' or 'tone'"):
        HatchTracer().trace(IMAGES / "camera.png", {"layers": "colour"})
