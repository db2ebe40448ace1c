"""Sharp corners of vector drawings are kept exact (issue 28).

Polygons, polylines and paths with tangent breaks are converted to G-code and a PLC file, and
both are read back with readers written from docs/formats.md: the pen-down length must be within
0.1 % of the exact length, and every corner of the file within 0.01 mm of a point the machine
reaches (a G-code end point; a PLC instant where the pen is at rest). Smooth paths must not be
cut: a corner is only where the file's path turns.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from doodlecam.machine import load_machine
from doodlecam.model import Drawing
from doodlecam.pipeline import Settings, convert
from doodlecam.trace.layout import fit_to_work_area

from svg_corpus import CORPUS, HEAD, write_corpus
from test_executed import execute, read_plc_file
from test_pen_lifts import PEN_DOWN, PEN_UP

STAR = [(150 + 30 * math.sin(k * math.pi / 5) * (1 if k % 2 == 0 else 0.4),
         60 - 30 * math.cos(k * math.pi / 5) * (1 if k % 2 == 0 else 0.4)) for k in range(10)]
SHAPES = {  # name: (SVG element, vertices in order, closed)
    "square": ('<rect x="10" y="10" width="40" height="30" stroke="black" fill="none"/>',
               [(10, 10), (50, 10), (50, 40), (10, 40)], True),
    "triangle": ('<polygon points="70,10 100,60 60,45" stroke="black" fill="none"/>',
                 [(70, 10), (100, 60), (60, 45)], True),
    "star": (f'<polygon points="{" ".join(f"{x:.6f},{y:.6f}" for x, y in STAR)}" stroke="black" fill="none"/>',
             STAR, True),
    "zigzag": ('<polyline points="10,60 30,90 50,60 70,90 90,62" stroke="black" fill="none"/>',
               [(10, 60), (30, 90), (50, 60), (70, 90), (90, 62)], False),
    "bracket": ('<path d="M 110 70 h 40 v 5 h -35 v 20 h -5 z" stroke="black" fill="none"/>',
                [(110, 70), (150, 70), (150, 75), (115, 75), (115, 95), (110, 95)], True),
}


def _exact_length(vertices, closed) -> float:
    v = np.asarray(vertices + vertices[:1] if closed else vertices, float)
    return float(np.hypot(*np.diff(v, axis=0).T).sum())


def gcode_runs(text: str) -> list[np.ndarray]:
    """The pen-down paths of a G-code file: where the pen goes down, then every G1 end point until it lifts."""
    runs, pos, down = [], np.zeros(2), False
    for raw in text.splitlines():
        line = raw.split(";")[0].strip()
        if line == PEN_DOWN:
            down = True
            runs.append([pos.copy()])
        elif line == PEN_UP:
            down = False
        elif re.match(r"G[0-3]\b", line):
            words = dict((w[0], float(w[1:])) for w in line.split()[1:])
            pos = np.array([words.get("X", pos[0]), words.get("Y", pos[1])])
            if down:
                runs[-1].append(pos.copy())
    return [np.array(r) for r in runs]


def plc_paths(data: bytes) -> tuple[list[np.ndarray], np.ndarray]:
    """(the executed position at every instant of each pen-down run, mm; the positions where the pen is at rest)."""
    header, strokes = read_plc_file(data)
    runs, rest = [], []
    for start, targets in strokes:
        x, v = execute(start, targets, header["delta_time"])
        x = x / header["steps_per_mm"]
        runs.append(x)
        rest.append(x[np.all(v == 0, axis=1)])
    return runs, np.vstack(rest)


def _length(runs) -> float:
    return float(sum(np.hypot(*np.diff(r, axis=0).T).sum() for r in runs))


def _on_machine(vertices, machine) -> np.ndarray:
    """The file's vertices where the layout puts them (the same placement as the drawing's)."""
    d = Drawing((np.asarray(vertices, float),), units="mm", y_down=True, meta={"canvas": (0.0, 0.0, 200.0, 100.0)})
    return fit_to_work_area(d, machine, {"scale": 1}).polylines[0]


def _nearest(points: np.ndarray, to: np.ndarray) -> np.ndarray:
    return np.hypot(*(points[:, None] - to[None]).transpose(2, 0, 1)).min(axis=1)


@pytest.fixture(scope="module")
def machine():
    return load_machine("doodlebot")


@pytest.fixture(scope="module")
def polygons(machine, tmp_path_factory):
    folder = tmp_path_factory.mktemp("corners")
    path = folder / "polygons.svg"
    path.write_text(HEAD + "".join(body for body, _, _ in SHAPES.values()) + "</svg>")
    res = convert(path, folder / "out", Settings(machine=machine, posts=("gcode", "plc"), layout={"scale": 1}))
    files = {p.suffix: p for p in res.outputs}
    return res, files[".gcode"].read_text(), files[".plc"].read_bytes()


def test_polygons_are_drawn_with_exact_corners_and_length(polygons, machine):
    res, gcode, plc = polygons
    exact = sum(_exact_length(v, c) for _, v, c in SHAPES.values())
    runs = gcode_runs(gcode)
    executed, rest = plc_paths(plc)
    assert len(runs) == len(executed) == len(SHAPES)  # one pen-down per shape: the corners are passed pen down
    assert _length(runs) == pytest.approx(exact, rel=1e-3)
    assert _length(executed) == pytest.approx(exact, rel=1e-3)
    corners = np.vstack([_on_machine(v, machine) for _, v, _ in SHAPES.values()])
    assert _nearest(corners, np.vstack(runs)).max() <= 0.01
    assert _nearest(corners, rest).max() <= 0.01  # the pen stops on every corner
    s = res.summary()
    inner = sum(len(v) - (1 if c else 2) for _, v, c in SHAPES.values())  # a loop starts on one of its corners
    assert s["corners_kept"] == inner and s["pen_lifts"] == len(SHAPES)


def test_the_summary_says_how_many_corners_are_kept(tmp_path, capsys):
    from doodlecam.cli import main

    path = tmp_path / "square.svg"
    path.write_text(HEAD + SHAPES["square"][0] + "</svg>")
    assert main(["convert", str(path), "-o", str(tmp_path / "o"), "--post", "json"]) == 0
    assert "corners kept       3: exact, the pen stops on each without lifting" in capsys.readouterr().out


SMOOTH = ('<circle cx="30" cy="30" r="20" stroke="black" fill="none"/>'
          '<circle cx="70" cy="30" r="0.4" stroke="black" fill="none"/>'  # a dot-sized circle is no polygon
          '<path d="M 90 80 C 100 40, 120 40, 130 80 S 160 120, 170 80" stroke="black" fill="none"/>'
          '<path d="M 100 10 h 40 a 10 10 0 0 1 10 10 v 20" stroke="black" fill="none"/>'  # line, tangent arc, line
          '<ellipse cx="60" cy="70" rx="25" ry="4" stroke="black" fill="none"/>')


def test_smooth_paths_are_not_cut(machine, tmp_path):
    path = tmp_path / "smooth.svg"
    path.write_text(HEAD + SMOOTH + "</svg>")
    job = convert(path, tmp_path / "o", Settings(machine=machine, posts=("json",), layout={"scale": 1})).job
    assert job.meta["corners_kept"] == 0 and len(job.strokes) == 5


@pytest.mark.parametrize("corner, kept", [("0", 0), ("80", 2), ("120", 1), ("30", 3)])
def test_the_corner_angle_is_an_option(machine, tmp_path, corner, kept):
    """The path turns by 142, 85 and 74 degrees at its inner vertices; corner=0 rounds every corner within
    the fit tolerance as before."""
    path = tmp_path / "t.svg"
    path.write_text(HEAD + '<polyline points="70,10 100,60 60,45 70,10 110,10" stroke="black" fill="none"/></svg>')
    job = convert(path, tmp_path / "o", Settings(machine=machine, posts=("json",), layout={"scale": 1},
                                                tracer_options={"corner": corner})).job
    assert job.meta["corners_kept"] == kept and job.pen_lifts == 1


def test_dxf_polylines_keep_their_corners(machine, tmp_path):
    """A CAD outline: straight sides, a bulge (a tangent arc) and its sharp corners, in inches."""
    import ezdxf

    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 1
    # (x, y, start width, end width, bulge): a 1 in square whose top right corner is rounded by a tangent arc
    doc.modelspace().add_lwpolyline([(0, 0, 0, 0, 0), (1, 0, 0, 0, 0), (1, 0.8, 0, 0, 0.41421356237),
                                     (0.8, 1, 0, 0, 0), (0, 1, 0, 0, 0)], format="xyseb", close=True)
    path = tmp_path / "plate.dxf"
    doc.saveas(path)
    res = convert(path, tmp_path / "o", Settings(machine=machine, posts=("gcode",), layout={"scale": 1}))
    runs = gcode_runs(res.outputs[0].read_text())
    exact = 25.4 * (1 + 0.8 + 0.8 + 1 + math.pi * 0.2 / 2)
    assert _length(runs) == pytest.approx(exact, rel=1e-3)
    assert res.job.meta["corners_kept"] == 2 and res.job.pen_lifts == 1  # (1, 0) and (0, 1); the loop starts at (0, 0)
    pts = np.vstack(runs)
    lo = pts.min(axis=0)
    corners = lo + 25.4 * np.array([(0, 0), (1, 0), (0, 1)])
    assert _nearest(corners, pts).max() <= 0.01


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_the_feature_corpus_is_drawn_within_0_1_percent(machine, tmp_path, name):
    """The fitted, planned job of every file of the feature corpus (not only the traced polylines)."""
    files = write_corpus(tmp_path)
    path = tmp_path / f"{name}.svg"
    job = convert(path, tmp_path / "o", Settings(machine=machine, posts=("json",), layout={"scale": 1})).job
    assert job.pen_down_length == pytest.approx(files[path], rel=1e-3)
