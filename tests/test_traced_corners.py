"""Corners of lines traced from pictures are found and kept exact (issue 28, doodlecam.geometry.corners).

Pictures the tests make: a star, an L-shaped bracket and a triangle (19 true corners) beside an
ellipse and a small circle (none), filled black and anti-aliased, at 0.25, 0.5 and 1 mm per pixel
as drawn and turned by three angles, traced by `contours`. Every true corner must be the end of a
fitted piece within 0.5 mm (a pixel of the pen-width grid on doodlebot; `contours`' sub-pixel
outlines put them 0.47 mm off at worst, at 1 mm per pixel), the pieces of an outline drawn without
lifting, and no corner anywhere else.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image, ImageDraw

from doodlecam.errors import PluginError
from doodlecam.geometry.corners import find_corners, split_traced
from doodlecam.geometry.fit import turn_angles
from doodlecam.machine import load_machine
from doodlecam.model import Drawing
from doodlecam.pipeline import Settings, convert
from doodlecam.trace.layout import fit_to_work_area

SUPER = 8  # supersampling of the rendering: the picture is anti-aliased as a scan would be
LAYOUT = {"width": 100}


def _star(cx, cy, big, small, turn):
    return [(cx + (big if k % 2 == 0 else small) * math.sin(turn + k * math.pi / 5),
             cy - (big if k % 2 == 0 else small) * math.cos(turn + k * math.pi / 5)) for k in range(10)]


def _turned(pts, cx, cy, a):
    c, s = math.cos(a), math.sin(a)
    return [(cx + c * (x - cx) - s * (y - cy), cy + s * (x - cx) + c * (y - cy)) for x, y in pts]


def polygons(w: int, turn: float) -> list[list[tuple[float, float]]]:
    """The corner shapes of a picture ``w`` px wide (px, pixel centres at integers)."""
    u = w / 100
    bracket = [(55, 12), (90, 12), (90, 20), (65, 20), (65, 48), (55, 48)]
    triangle = [(20, 55), (45, 58), (28, 72)]
    return [_star(25 * u, 30 * u, 20 * u, 8 * u, turn),
            _turned([(x * u, y * u) for x, y in bracket], 72 * u, 30 * u, turn),
            _turned([(x * u, y * u) for x, y in triangle], 31 * u, 62 * u, turn)]


def render(path, w: int, turn: float) -> list[list[tuple[float, float]]]:
    h = int(w * 0.75)
    u = w / 100
    im = Image.new("L", (w * SUPER, h * SUPER), 255)
    draw = ImageDraw.Draw(im)
    at = lambda v: (v + 0.5) * SUPER  # noqa: E731 - a pixel's centre at its index
    shapes = polygons(w, turn)
    for p in shapes:
        draw.polygon([(at(x), at(y)) for x, y in p], fill=0)
    draw.ellipse([at(60 * u), at(55 * u), at(95 * u), at(72 * u)], fill=0)  # smooth: no corner
    draw.ellipse([at(49 * u), at(52 * u), at(57 * u), at(60 * u)], fill=0)
    im.reduce(SUPER).save(path)
    return shapes


@pytest.fixture(scope="module")
def machine():
    return load_machine("doodlebot")


def _joins(strokes) -> np.ndarray:
    """Where one piece of a traced line ends and the next goes on, pen down."""
    return np.array([a.spline.end for a, b in zip(strokes, strokes[1:])
                     if a.source_index == b.source_index and np.array_equal(a.spline.end, b.spline.start)])


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each point of a, the distance to the nearest point of b."""
    return np.hypot(*(a[:, None] - b[None]).transpose(2, 0, 1)).min(axis=1)


@pytest.mark.parametrize("w", [100, 200, 400])  # 1, 0.5, 0.25 mm per pixel as drawn
@pytest.mark.parametrize("turn", [0.0, 0.3, 0.7])
def test_every_corner_of_a_traced_shape_is_kept_and_no_other(tmp_path, machine, w, turn):
    path = tmp_path / f"shapes{w}.png"
    shapes = render(path, w, turn)
    res = convert(path, tmp_path / "out", Settings(machine=machine, tracer="contours", posts=("svg",), layout=LAYOUT))
    true = fit_to_work_area(Drawing(tuple(np.array(p + p[:1], float) for p in shapes), units="px", y_down=True,
                                    extent=(float(w), float(int(w * 0.75)))), machine, LAYOUT).polylines
    corners = np.vstack([t[:-1] for t in true])
    strokes = res.job.strokes
    ends = np.array([e for s in strokes for e in (s.spline.start, s.spline.end)])
    assert _distances(corners, ends).max() <= 0.5  # every corner is where a piece ends
    joins = _joins(strokes)
    assert _distances(joins, corners).max() <= 0.5  # and no corner elsewhere (the ellipse, the circle)
    s = res.summary()
    # each outline starts on one of its corners and is one pen-down: five outlines, 19 - 3 corners passed
    assert s["pen_lifts"] == 5 and s["corners_kept"] == len(joins) == len(corners) - len(shapes)
    off = convert(path, tmp_path / "off", Settings(machine=machine, tracer="contours", posts=("svg",), layout=LAYOUT,
                                                  tracer_options={"corner": "0"})).summary()
    assert off["corners_kept"] == 0 and off["strokes"] == 5


@pytest.mark.parametrize("turn", [0.0, 0.3, 0.7])
def test_edges_keeps_the_corners_canny_leaves(tmp_path, machine, turn):
    """Canny's blur (sigma 1 mm as drawn) cuts a sharp tip short and may break an outline at a
    corner: every corner is still where a piece ends, within 2 mm (measured 1.3-1.7 mm)."""
    w = 200
    path = tmp_path / "shapes.png"
    shapes = render(path, w, turn)
    res = convert(path, tmp_path / "out", Settings(machine=machine, tracer="edges", posts=("svg",), layout=LAYOUT))
    true = fit_to_work_area(Drawing(tuple(np.array(p + p[:1], float) for p in shapes), units="px", y_down=True,
                                    extent=(float(w), float(int(w * 0.75)))), machine, LAYOUT).polylines
    ends = np.array([e for s in res.job.strokes for e in (s.spline.start, s.spline.end)])
    assert _distances(np.vstack([t[:-1] for t in true]), ends).max() <= 2.0
    assert res.summary()["corners_kept"] >= 14


def test_the_drawn_length_comes_closer_to_the_shapes(tmp_path, machine):
    """Sharp corners drawn sharp: the pen-down length is nearer the true outlines' than with rounded ones."""
    w = 200
    path = tmp_path / "shapes.png"
    shapes = render(path, w, 0.3)
    mm = 100 / w
    exact = sum(np.hypot(*np.diff(np.array(p + p[:1]), axis=0).T).sum() for p in shapes) * mm
    a, b = 35 / 2, 17 / 2  # the ellipse's semi-axes (mm), Ramanujan's perimeter; the circle's radius 4 mm
    exact += math.pi * (3 * (a + b) - math.sqrt((3 * a + b) * (a + 3 * b))) + 2 * math.pi * 4
    drawn = {}
    for corner in ("30", "0"):
        s = convert(path, tmp_path / corner, Settings(machine=machine, tracer="contours", posts=("svg",), layout=LAYOUT,
                                                     tracer_options={"corner": corner})).summary()
        drawn[corner] = s["pen_down_mm"]
    assert abs(drawn["30"] - exact) < abs(drawn["0"] - exact)
    assert drawn["30"] == pytest.approx(exact, rel=0.01)


def _staircase(points, px=0.5):
    """A closed polyline through ``points`` as a pixel chain traces it: every point on a grid of
    ``px`` mm (a staircase whose every vertex turns by 45 or 90 degrees)."""
    p = np.array(points + points[:1], float)
    seg = np.hypot(*np.diff(p, axis=0).T)
    dense = np.array([p[k] + (p[k + 1] - p[k]) * t for k in range(len(seg)) for t in np.arange(0, seg[k], px / 4) / seg[k]])
    q = np.round(np.vstack([dense, dense[:1]]) / px) * px
    return q[np.r_[True, np.any(np.diff(q, axis=0) != 0, axis=1)]]


def test_corners_are_found_over_a_support_not_at_every_step():
    """A square on the pixel grid (0.5 mm) at 12 angles: a staircase whose vertices turn by 45 or
    90 degrees. Raw, its four corners are found and nothing else; smoothed as `edges` smooths its
    chains, each is put back within a pixel of the square's vertex. Circles and ellipses (radius
    of curvature 2.5 mm and more, five supports) have none."""
    from doodlecam.plugins.edges import unstair

    px = 0.5
    for turn in np.linspace(0.05, 1.5, 12):
        square = np.array(_turned([(0, 0), (20, 0), (20, 20), (0, 20)], 10, 10, turn))
        raw = _staircase([tuple(v) for v in square], px)
        assert (np.degrees(turn_angles(raw)) >= 45 - 1e-6).sum() >= 8  # the vertex rule would cut it to bits
        assert len(find_corners(raw, 3 * px, 30)) == 4
        pieces = split_traced(unstair(raw / px, 0.8) * px, 3 * px, 30)
        assert len(pieces) == 4 and _distances(square, np.array([p[0] for p in pieces])).max() <= px
        assert all(np.array_equal(a[-1], b[0]) for a, b in zip(pieces, pieces[1:] + pieces[:1]))  # one pen-down
    for r in (1.5, 2.0, 3.0, 4.0, 10.0, 40.0):  # circles on the grid, smoothed: no corner
        t = np.linspace(0, 2 * np.pi, int(2 * np.pi * r / 0.25))[:-1]
        c = unstair(_staircase([(r * np.cos(a), r * np.sin(a)) for a in t], px) / px, 0.8) * px
        assert len(find_corners(c, 3 * px, 30)) == 0
    for a, b in ((10, 5), (20, 8), (30, 10)):
        t = np.linspace(0, 2 * np.pi, 1000)
        e = np.column_stack([a * np.cos(t), b * np.sin(t)])
        e[-1] = e[0]
        assert len(find_corners(e, 3 * px, 30)) == 0
    line = _staircase([(0, 0), (30, 7)], px)  # a straight staircase, open
    assert len(find_corners(line[: len(line) // 2], 3 * px, 30)) == 0


@pytest.mark.parametrize("tracer", ["edges", "contours", "centerline", "auto"])
@pytest.mark.parametrize("corner", ["180", "-5"])
def test_a_bad_corner_angle_is_a_one_line_error(tmp_path, machine, tracer, corner):
    path = tmp_path / "shapes.png"
    render(path, 100, 0.0)
    with pytest.raises(PluginError, match="corner must be 0") as e:
        convert(path, tmp_path / "out", Settings(machine=machine, tracer=tracer, tracer_options={"corner": corner}))
    assert "\n" not in str(e.value)
    assert not (tmp_path / "out").exists()
