"""Photo styles (stipple, tsp, flow): what they draw, rendered at the pen's width by a rasteriser of
this file's own, follows the picture's tone; tsp is one stroke that never crosses itself; stipple
dots and flow lines are spaced by the tone; the same picture at 1x and 4x gives the same job."""

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from conftest import PROFILE, save
from doodlecam import registry
from doodlecam.machine import parse_machine
from doodlecam.pipeline import Settings, convert
from doodlecam.trace.raster import load_gray

SAMPLES = Path(__file__).resolve().parents[1] / "samples" / "images"
PEN = 0.5
RES = 0.1  # mm per pixel of the test rasteriser


def _trace(name, path, mm_per_px, **opts):
    """The tracer run as the pipeline runs it, told the drawn size; polylines in mm from the top left."""
    tracer = registry.get("tracer", name)()
    tracer.mm_per_px, tracer.pen_mm = mm_per_px, PEN
    d = tracer.trace(Path(path), {k: str(v) for k, v in opts.items()})
    return [(p + 0.5) * mm_per_px for p in d.polylines], d


def render(polylines, size, pen=PEN, res=RES):
    """Ink (bool raster, res mm per pixel) of polylines (mm, y down) drawn with a round pen of width ``pen``:
    every pixel within pen / 2 of a point sampled every res / 2 along the lines."""
    w, h = size
    centre = np.zeros((int(np.ceil(h / res)), int(np.ceil(w / res))), bool)
    for p in polylines:
        d = np.diff(p, axis=0)
        k = np.maximum(np.ceil(np.hypot(*d.T) / (res / 2)).astype(int), 1)
        seg = np.repeat(np.arange(len(d)), k)
        f = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)) / np.repeat(k, k)
        q = np.vstack([p[seg] + d[seg] * f[:, None], p[-1:]]) / res
        c = np.clip(q.astype(int), 0, [centre.shape[1] - 1, centre.shape[0] - 1])
        centre[c[:, 1], c[:, 0]] = True
    return ndi.distance_transform_edt(~centre) * res <= pen / 2


def tone_correlation(polylines, path, mm_per_px, blur_mm=3.0):
    """Pearson correlation of the drawn darkness and the picture's, both blurred by blur_mm (the lightest
    tones' flow lines are 8 mm apart: the blur of a look from a step back)."""
    gray = load_gray(path)
    size = (gray.shape[1] * mm_per_px, gray.shape[0] * mm_per_px)
    ink = render(polylines, size).astype(float)
    from skimage.transform import resize

    dark = resize(1.0 - gray, ink.shape, order=1, anti_aliasing=True)
    a, b = (ndi.gaussian_filter(x, blur_mm / RES) for x in (ink, dark))
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


def _synthetic(tmp_path):
    """A tone ramp left to right with a dark disc and a light square on it (160 x 120 px)."""
    y, x = np.mgrid[0:120, 0:160]
    grey = 0.95 - 0.8 * x / 159
    grey = np.where((x - 50) ** 2 + (y - 60) ** 2 < 30 ** 2, 0.15, grey)
    grey = np.where((abs(x - 120) < 18) & (abs(y - 60) < 18), 0.85, grey)
    return save(tmp_path, "ramp.png", (255 * grey).astype(np.uint8))


def _halves(tmp_path, left=0.75, right=0.25):
    """Two flat tones side by side (grey levels), 120 x 60 px."""
    grey = np.empty((60, 120))
    grey[:, :60], grey[:, 60:] = left, right
    return save(tmp_path, "halves.png", (255 * grey).astype(np.uint8))


# ---------------------------------------------------------------- the tone

@pytest.mark.parametrize("style", ["stipple", "tsp", "flow"])
@pytest.mark.parametrize("picture", ["camera.png", "chelsea.png", "synthetic"])
def test_the_drawn_darkness_follows_the_picture(tmp_path, style, picture):
    path = _synthetic(tmp_path) if picture == "synthetic" else SAMPLES / picture
    w = Image.open(path).size[0]
    mm = (80.0 if picture == "synthetic" else 150.0) / w  # photos 150 mm wide: enough dots for a cat's face
    polylines, d = _trace(style, path, mm)
    assert d.meta["made"]
    r = tone_correlation(polylines, path, mm)
    assert r >= 0.85, f"{style} on {picture}: correlation {r:.3f}"


# ---------------------------------------------------------------- stipple

def test_stipple_dot_count_and_spacing_follow_the_tone(tmp_path):
    path = _halves(tmp_path)  # darkness 0.25 on the left, 0.75 on the right
    polylines, d = _trace("stipple", path, 0.5)  # 60 x 30 mm
    centres = np.array([p[:-1].mean(axis=0) for p in polylines])
    left = centres[:, 0] < 30
    ratio = (~left).sum() / left.sum()
    assert ratio == pytest.approx(3.0, rel=0.15)
    gap = cKDTree(centres).query(centres, k=2)[0][:, 1]
    inner = (np.abs(centres[:, 0] - 30) > 3) & (centres[:, 0] > 3) & (centres[:, 0] < 57)
    spacing = np.median(gap[inner & left]) / np.median(gap[inner & ~left])
    assert spacing == pytest.approx(np.sqrt(3.0), rel=0.15)
    # the dots' ink matches the tone: the dots' ink over the paper is the mean darkness
    ink = render(polylines, (60.0, 30.0)).mean()
    assert ink == pytest.approx(0.5, rel=0.15)


def test_stipple_taps_and_a_given_number_of_points(tmp_path):
    path = _halves(tmp_path)
    polylines, d = _trace("stipple", path, 0.5, dot="tap", points=500)
    assert len(polylines) == 500 == d.meta["points"]
    lengths = np.array([np.hypot(*np.diff(p, axis=0).T).sum() for p in polylines])
    assert np.all(lengths >= PEN) and np.all(lengths < 1.05 * PEN)  # kept by the layout, as short as it allows


# ---------------------------------------------------------------- tsp

def _segments_cross(line):
    """Number of pairs of non-adjacent segments of a polyline that cross properly (brute force)."""
    a, b = line[:-1], line[1:]

    def orient(p, q, r):
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    count = 0
    for i in range(len(a) - 2):
        j = slice(i + 2, len(a))
        o1, o2 = orient(a[i], b[i], a[j]), orient(a[i], b[i], b[j])
        o3, o4 = orient(a[j], b[j], a[i][None]), orient(a[j], b[j], b[i][None])
        count += int(np.sum((o1 * o2 < 0) & (o3 * o4 < 0)))
    return count


@pytest.mark.parametrize("curve", ["smooth", "straight"])
def test_tsp_is_one_stroke_that_never_crosses_itself_and_plans_within_limits(tmp_path, curve):
    path = _synthetic(tmp_path)
    m = parse_machine(PROFILE, "t.toml")
    r = convert(path, tmp_path / "o", Settings(machine=m, tracer="tsp", posts=("svg",), layout={"width": 40},
                                                tracer_options={"curve": curve}))
    s = r.summary()
    assert s["pen_lifts"] == 1  # one pen-down: the line's pieces meet exactly
    assert s["tracer_made"].startswith("one line through")
    assert s["worst_acceleration_ratio"] <= 1 + 1e-6 and s["worst_velocity_ratio"] <= 1 + 1e-6
    assert s["max_fit_error_mm"] <= m.tolerance + 1e-9
    assert s["max_between_samples_mm"] <= max(s["path_tolerance_mm"], s["max_fit_error_mm"]) + 1e-6
    polylines, d = _trace("tsp", path, 40 / 160, curve=curve)
    assert len(polylines) == 1 and _segments_cross(polylines[0]) == 0


def test_tsp_removes_every_crossing_a_2opt_move_would(tmp_path):
    from doodlecam.plugins.tsp import tour_length, uncross

    rng = np.random.default_rng(3)
    pts = rng.random((150, 2)) * 30  # a random order: hundreds of crossings
    assert _segments_cross(pts) > 100
    tour, fixed = uncross(pts)
    assert _segments_cross(tour) == 0 and fixed > 0
    assert tour_length(tour) < tour_length(pts)
    assert sorted(map(tuple, tour)) == sorted(map(tuple, pts))  # the same points, each once


def test_tsp_points_follow_the_tone_squared(tmp_path):
    """The line's ink grows like the square root of the point density, so the density goes as the darkness squared."""
    path = _halves(tmp_path)
    polylines, d = _trace("tsp", path, 0.5, curve="straight")
    pts = polylines[0]
    left = pts[:, 0] < 30
    assert (~left).sum() / left.sum() == pytest.approx(9.0, rel=0.2)


# ---------------------------------------------------------------- flow

def _flow_gaps(polylines):
    """The nearest two different lines come (sampled finely), and the nearest one line comes to itself
    farther than 3 pen widths along it."""
    pts, line, arc = [], [], []
    for i, p in enumerate(polylines):
        d = np.diff(p, axis=0)
        k = np.maximum(np.ceil(np.hypot(*d.T) / 0.02).astype(int), 1)
        seg = np.repeat(np.arange(len(d)), k)
        f = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)) / np.repeat(k, k)
        q = p[seg] + d[seg] * f[:, None]
        pts.append(q)
        line.append(np.full(len(q), i))
        arc.append(np.r_[0, np.cumsum(np.hypot(*np.diff(q, axis=0).T))])
    pts, line, arc = np.concatenate(pts), np.concatenate(line), np.concatenate(arc)
    pairs = cKDTree(pts).query_pairs(2 * PEN, output_type="ndarray")
    dist = np.hypot(*(pts[pairs[:, 0]] - pts[pairs[:, 1]]).T)
    other = line[pairs[:, 0]] != line[pairs[:, 1]]
    far = ~other & (np.abs(arc[pairs[:, 0]] - arc[pairs[:, 1]]) > 3 * PEN)
    return dist[other].min(initial=np.inf), dist[far].min(initial=np.inf)


def test_flow_lines_keep_their_minimum_separation(tmp_path):
    polylines, d = _trace("flow", SAMPLES / "camera.png", 60 / 512)  # gap 0.7 of a 1 mm separation
    assert d.meta["min_gap_mm"] == pytest.approx(0.7)
    assert min(_flow_gaps(polylines)) >= 0.7 * (1 - 1e-6)
    # settings that would bring lines nearer than the pen still keep its width
    polylines, d = _trace("flow", SAMPLES / "camera.png", 60 / 512, spacing_mm=0.2, gap=0.3)
    assert d.meta["min_gap_mm"] == PEN
    assert min(_flow_gaps(polylines)) >= PEN * (1 - 1e-6)


def test_flow_separation_follows_the_tone(tmp_path):
    path = _halves(tmp_path)  # darkness 0.25 left, 0.75 right: lines three times closer on the right
    polylines, d = _trace("flow", path, 0.5, angle=0)
    ink = np.concatenate([np.c_[(p[:-1] + p[1:]) / 2, np.hypot(*np.diff(p, axis=0).T)] for p in polylines])
    inner = (ink[:, 1] > 3) & (ink[:, 1] < 27)
    left = ink[inner & (ink[:, 0] > 3) & (ink[:, 0] < 27), 2].sum()
    right = ink[inner & (ink[:, 0] > 33) & (ink[:, 0] < 57), 2].sum()
    assert right / left == pytest.approx(3.0, rel=0.25)


# ---------------------------------------------------------------- scale

@pytest.mark.parametrize("style", ["stipple", "tsp", "flow"])
def test_the_same_picture_at_1x_and_4x_gives_the_same_job(tmp_path, style):
    m = parse_machine(dict(PROFILE, sampling={"delta_time": 0.04, "path_tolerance": 0.0}), "t.toml")
    src = Image.open(SAMPLES / "coins.png").convert("L").crop((60, 60, 180, 150))
    times, strokes = [], []
    for k in (1, 4):
        path = tmp_path / f"c{k}.png"
        src.resize((120 * k, 90 * k), Image.BICUBIC).save(path)
        s = convert(path, tmp_path / "o", Settings(machine=m, tracer=style, posts=("svg",),
                                                   layout={"width": 36})).summary()
        times.append(s["job_time_s"])
        strokes.append(s["strokes"])
    assert max(times) <= 1.15 * min(times), times
    assert max(strokes) <= 1.15 * min(strokes), strokes
