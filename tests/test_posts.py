"""Built-in post-processors (plc, gcode, svg) and the PLC packet file format."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
import zlib
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from doodlecam.link.plc import packetfile as plcfile
from doodlecam.api import PostProcessor
from doodlecam.errors import InputError, PluginError
from doodlecam.machine import parse_machine
from doodlecam.model import Job, Profile, Spline, Stroke, StrokeSamples, Travel
from doodlecam.link.plc.packetfile import (DRAW, MOVE, PlcCommand, PlcHeader, commands_from_job, read_plc, to_csv, write_plc)
from doodlecam.postprocessors.gcode import GcodePost
from doodlecam.postprocessors.plc import PlcPost
from doodlecam.postprocessors.svg import SvgPost

SPM = 80.0

MACHINE = {
    "machine": {"name": "testbot", "kinematics": "cartesian"},
    "work_area": {"width": 400.0, "height": 300.0, "margin": 10.0, "home": [0.0, 0.0]},
    "axes": {
        "x": {"steps_per_mm": SPM, "max_velocity": 150.0, "max_acceleration": 2000.0},
        "y": {"steps_per_mm": SPM, "max_velocity": 150.0, "max_acceleration": 2000.0},
    },
    "pen": {"width": 0.5, "up_delay": 0.15, "down_delay": 0.15},
    "travel": {"speed": 150.0},
    "sampling": {"delta_time": 0.04},
}


def trapezoid_profile(spline: Spline, vmax: float = 60.0, amax: float = 800.0, n: int = 400) -> Profile:
    """b = udot^2 rising linearly in u (constant u-ddot), a plateau, then falling.

    The limits are nominal (u is not arc length); the posts only need a valid profile.
    """
    u = np.linspace(0.0, 1.0, n + 1)
    L = spline.length
    b = np.minimum.reduce([2 * amax / L * u, np.full_like(u, (vmax / L) ** 2), 2 * amax / L * (1 - u)])
    du = u[1] - u[0]
    sb = np.sqrt(b)
    t = np.concatenate([[0.0], np.cumsum(2 * du / (sb[:-1] + sb[1:]))])
    return Profile(u=u, b=b, a=np.diff(b) / (2 * du), t=t)


def samples_for(spline: Spline, prof: Profile, dt: float) -> StrokeSamples:
    m = math.ceil(prof.duration / dt - 1e-9)
    u, ud, _ = prof.state_at(dt * np.arange(1, m + 1))
    v = spline(u, 1) * ud[:, None]
    v[-1] = 0.0  # every stroke ends at rest
    return StrokeSamples(start=spline(0.0), velocity=v, delta_time=dt)


def make_job(machine) -> Job:
    splines = [
        Spline(3, [[50, 50], [80, 120], [140, -10], [180, 90], [220, 60]]),  # an S curve
        Spline(3, [[300, 250], [350, 250], [350, 200], [300, 200], [300, 240]]),  # a tight hook, high up
    ]
    strokes, samples = [], []
    for s in splines:
        p = trapezoid_profile(s)
        strokes.append(Stroke(spline=s, profile=p))
        samples.append(samples_for(s, p, machine.delta_time))
    pts = [np.asarray(machine.home)] + [x for s in splines for x in (s.start, s.end)] + [np.asarray(machine.home)]
    travels = [Travel(start=pts[2 * i], end=pts[2 * i + 1], duration=1.0) for i in range(len(splines) + 1)]
    return Job(machine=machine, strokes=tuple(strokes), travels=tuple(travels), samples=tuple(samples), source="test.png")


@pytest.fixture(scope="module")
def machine():
    return parse_machine(MACHINE, "test.toml")


@pytest.fixture(scope="module")
def job(machine):
    return make_job(machine)


def test_fixture_samples_follow_the_spline(job):
    # Guards the hand-built fixture: the ramp model lands near each stroke's end.
    for st, sm in zip(job.strokes, job.samples):
        assert np.linalg.norm(sm.integrate()[-1] - st.spline.end) < 0.5


# ---------------------------------------------------------------- plugins

@pytest.mark.parametrize("cls, ext", [(PlcPost, ".plc"), (GcodePost, ".gcode"), (SvgPost, ".svg")])
def test_posts_are_registered_plugins(cls, ext):
    from importlib.metadata import entry_points

    loaded = {ep.name: ep.load() for ep in entry_points(group="doodlecam.postprocessors")}
    assert loaded[cls.name] is cls
    assert issubclass(cls, PostProcessor) and cls.extension == ext
    assert cls.summary and "\n" not in cls.summary
    assert all(o.help for o in cls.options)


# ---------------------------------------------------------------- PLC file

def test_commands_from_job_structure(job):
    header, cmds = commands_from_job(job)
    n_draw = sum(len(s.velocity) for s in job.samples)
    assert header.no_commands == len(cmds) == n_draw + len(job.strokes) + 1
    assert [c.command_no for c in cmds] == list(range(1, len(cmds) + 1))
    assert header.delta_time == 0.04
    assert (header.max_accel_x, header.max_accel_y) == (160000, 160000)  # 2000 mm/s^2 * 80
    assert (header.move_speed_x, header.move_speed_y) == (12000, 12000)  # 150 mm/s * 80
    assert (header.steps_per_mm_x, header.steps_per_mm_y) == (SPM, SPM)

    # Pen convention: each stroke is one MOVE (pen up) then its DRAWs (pen down); a final MOVE home.
    i = 0
    for st, sm in zip(job.strokes, job.samples):
        mv = cmds[i]
        assert mv.type == MOVE and (mv.x, mv.y) == tuple(np.round(st.spline.start * SPM).astype(int))
        draws = cmds[i + 1:i + 1 + len(sm.velocity)]
        assert all(c.type == DRAW for c in draws)
        v = np.array([(c.x, c.y) for c in draws], float)
        assert np.abs(v - sm.velocity * SPM).max() < 1.0  # integer steps/s, each within a step/s
        assert tuple(v[-1]) == (0.0, 0.0)
        # The PLC's linear ramp from the MOVE target ends where the plan ends.
        ramp = np.array([mv.x, mv.y]) + 0.5 * sm.delta_time * (v + np.vstack([[0, 0], v[:-1]])).sum(0)
        assert np.abs(ramp - sm.integrate()[-1] * SPM).max() <= 1.0
        i += 1 + len(sm.velocity)
    assert i == len(cmds) - 1
    assert cmds[-1] == PlcCommand(len(cmds), MOVE, 0, 0)


def test_plc_round_trip(job):
    header, cmds = commands_from_job(job)
    data = write_plc(header, cmds)
    assert len(data) == 64 + 16 * len(cmds) + 4
    h2, c2 = read_plc(data, "x.plc")
    assert h2 == header and c2 == cmds
    # The post writes the same bytes through the array fast path.
    assert PlcPost().write(job, PlcPost.resolve_options()) == data


def test_plc_layout_is_little_endian_and_documented(job):
    header, cmds = commands_from_job(job)
    data = write_plc(header, cmds)
    assert data[:8] == b"\x89DCPLC\r\n"
    assert int.from_bytes(data[8:10], "little") == 2  # version
    assert int.from_bytes(data[12:16], "little") == len(cmds)
    assert np.frombuffer(data[16:24], "<f8")[0] == 0.04
    # version 2: the DRAW ramps' largest acceleration, within the profile's on a Cartesian machine
    ax, ay = np.frombuffer(data[56:64], "<i4")
    assert (ax, ay) == (header.draw_accel_x, header.draw_accel_y) and 0 < ax <= header.max_accel_x
    rec = data[64:80]  # first command: MOVE to the first stroke's start
    assert int.from_bytes(rec[0:4], "little") == 1 and int.from_bytes(rec[4:6], "little") == MOVE
    assert int.from_bytes(rec[8:12], "little", signed=True) == cmds[0].x
    assert int.from_bytes(data[-4:], "little") == zlib.crc32(data[:-4])


def test_plc_negative_values_round_trip():
    h = PlcHeader(0.1, 3, 1000, 2000, 300, 400, 12.5, 40.0)
    cmds = [PlcCommand(1, MOVE, -5, 7), PlcCommand(2, DRAW, -2**31, 2**31 - 1), PlcCommand(3, DRAW, 0, 0)]
    h2, c2 = read_plc(write_plc(h, cmds))
    assert c2 == cmds and h2 == replace(h, draw_accel_x=2**31 - 1, draw_accel_y=2**31 - 1)  # clamped to int32


def test_plc_large_file_round_trip():
    n = 100_000
    rng = np.random.default_rng(1)
    arr = np.zeros(n, plcfile.RECORD_DTYPE)
    arr["command_no"] = np.arange(1, n + 1)
    arr["type"] = rng.integers(0, 2, n)
    arr["x"], arr["y"] = rng.integers(-50000, 50000, (2, n))
    h = PlcHeader(0.04, n, 1, 1, 1, 1, 80.0, 80.0)
    h2, back = plcfile.read_plc_array(write_plc(h, arr))
    assert h2 == replace(h, draw_accel_x=h2.draw_accel_x, draw_accel_y=h2.draw_accel_y) and np.array_equal(back, arr)


def _one_line_error(data, name="job.plc") -> str:
    with pytest.raises(InputError) as e:
        read_plc(data, name)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{name}: ")
    return msg


def test_plc_every_corrupted_byte_is_rejected(machine):
    small = Job(machine=machine, strokes=(), travels=(Travel([0, 0], [10, 20]),))  # just a MOVE home
    header, cmds = commands_from_job(small)
    data = write_plc(header, cmds)
    for i in range(len(data)):
        bad = bytearray(data)
        bad[i] ^= 0x04
        _one_line_error(bytes(bad))
    assert read_plc(data)[1] == [PlcCommand(1, MOVE, 800, 1600)]


def test_plc_corrupt_command_reports_crc(job):
    data = bytearray(write_plc(*commands_from_job(job)))
    data[64 + 16 * 5 + 9] ^= 0xFF  # inside a command's x
    assert "corrupt" in _one_line_error(bytes(data)) and "CRC" in _one_line_error(bytes(data))


def test_plc_truncated_and_trailing(job):
    data = write_plc(*commands_from_job(job))
    for cut in (len(data) - 1, len(data) - 16, 60, 40, 3, 0):
        assert "truncated" in _one_line_error(data[:cut])
    assert "trailing" in _one_line_error(data + b"\0")


def test_plc_bad_magic_and_version(job):
    data = write_plc(*commands_from_job(job))
    assert "bad magic" in _one_line_error(b"GIF89a" + data[6:], "pic.gif")
    assert "bad magic" in _one_line_error(data.replace(b"\r\n", b"\n", 1))  # text-mode mangled
    v3 = bytearray(data)
    v3[8] = 3
    v3[-4:] = zlib.crc32(bytes(v3[:-4])).to_bytes(4, "little")
    assert "version 3" in _one_line_error(bytes(v3))


def _as_version_1(data: bytes) -> bytes:
    """The same commands in a version 1 file: 56-byte header, no draw_accel."""
    body = bytearray(data[:56] + data[64:-4])
    body[8:10] = (1).to_bytes(2, "little")
    return bytes(body) + zlib.crc32(bytes(body)).to_bytes(4, "little")


def test_plc_version_1_files_are_still_read(job):
    header, cmds = commands_from_job(job)
    h1, c1 = read_plc(_as_version_1(write_plc(header, cmds)), "old.plc")
    assert c1 == cmds and h1.version == 1 and (h1.draw_accel_x, h1.draw_accel_y) == (0, 0)
    assert replace(h1, version=2, draw_accel_x=header.draw_accel_x, draw_accel_y=header.draw_accel_y) == header
    # a PAUSE needs version 2
    arr = plcfile.to_array(cmds).copy()
    arr["type"][-2], arr["x"][-2], arr["y"][-2] = plcfile.PAUSE, 1, 0  # (the stroke's last DRAW is at rest)
    assert "PAUSE needs version 2" in _one_line_error(_as_version_1(write_plc(header, arr)))


def test_plc_pause_and_draw_accel_are_checked(job):
    header, cmds = commands_from_job(job)
    arr = plcfile.to_array(cmds).copy()
    arr["type"][5], arr["x"][5], arr["y"][5] = plcfile.PAUSE, 2, 0  # in the middle of a stroke
    assert "while the machine moves" in _one_line_error(write_plc(header, arr))
    arr = plcfile.to_array(cmds).copy()
    arr["type"][-2], arr["x"][-2], arr["y"][-2] = plcfile.PAUSE, 0, 0
    assert "pen number" in _one_line_error(write_plc(header, arr))
    # a header that understates the DRAW ramps (written by something else than write_plc)
    data = bytearray(write_plc(header, cmds))
    data[56:60] = (header.draw_accel_x - 1).to_bytes(4, "little", signed=True)
    data[-4:] = zlib.crc32(bytes(data[:-4])).to_bytes(4, "little")
    assert "above its header's draw_accel" in _one_line_error(bytes(data))


def test_plc_bad_numbering_and_type_with_valid_crc(job):
    header, cmds = commands_from_job(job)
    arr = plcfile.to_array(cmds).copy()
    arr["command_no"][3] = 99
    assert "numbered 99" in _one_line_error(write_plc(header, arr))
    arr = plcfile.to_array(cmds).copy()
    arr["type"][2] = 7
    assert "unknown type 7" in _one_line_error(write_plc(header, arr))


def test_plc_csv(job):
    header, cmds = commands_from_job(job)
    text = to_csv(header, cmds)
    lines = text.splitlines()
    assert "# delta_time=0.04" in lines and "# steps_per_mm_x=80.0" in lines
    body = lines[lines.index("command_no,type,x,y") + 1:]
    assert [tuple(map(int, r.split(","))) for r in body] == [(c.command_no, c.type, c.x, c.y) for c in cmds]


def test_plc_refuses_unsampled_job(machine, job):
    from doodlecam.errors import OutputError

    with pytest.raises(OutputError):
        commands_from_job(Job(machine=machine, strokes=job.strokes, travels=job.travels))


# ---------------------------------------------------------------- G-code

NUM = r"-?\d+(?:\.\d{1,3})?"
GLINE = re.compile(rf"^(G[01]) X({NUM}) Y({NUM})(?: F(\d+(?:\.\d)?))?$")


def parse_gcode(text: str, pen_up: str = "M3 S0", pen_down: str = "M3 S1000"):
    """Strict parser: returns [(G0 target before stroke, [points], [feeds]) ...], home, footer."""
    assert "\r" not in text and text.endswith("\n")
    lines = text.split("\n")[:-1]
    assert all(len(line) <= 80 for line in lines)
    pen, pos, feed, strokes, dwell_due = "unknown", None, None, [], False
    for line in lines:
        if dwell_due:
            assert re.fullmatch(r"G4 P0\.15", line), f"pen command not followed by its dwell: {line!r}"
            dwell_due = False
            continue
        if line.startswith(";") or line in ("G21 G90 G94", "G17", "M2"):
            continue
        if line in (pen_up, pen_down):
            pen, dwell_due = ("down" if line == pen_down else "up"), True
            if pen == "down":
                strokes.append((pos, [pos], []))
            continue
        m = GLINE.match(line)
        assert m, f"unexpected line {line!r}"
        g, x, y, f = m.groups()
        pos = (float(x), float(y))
        if g == "G0":
            assert pen == "up", "travel with the pen down"
            assert f is None
        else:
            assert pen == "down", "G1 with the pen up"
            feed = float(f) if f is not None else feed
            assert feed is not None, "G1 without a feed"
            strokes[-1][1].append(pos)
            strokes[-1][2].append(feed)
    assert pen == "up" and lines[-1] == "M2"
    return strokes, pos


def _dist_to_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, d = poly[:-1], np.diff(poly, axis=0)
    dd = np.maximum((d * d).sum(1), 1e-300)
    s = np.clip(((points[:, None] - a) * d).sum(2) / dd, 0, 1)
    return np.linalg.norm(points[:, None] - (a + s[..., None] * d), axis=2).min(1)


def _planned_speed(stroke, u):
    p = stroke.profile
    return np.linalg.norm(stroke.spline(u, 1), axis=1) * np.sqrt(np.maximum(np.interp(u, p.u, p.b), 0))


@pytest.mark.parametrize("tol", [0.05, 0.01, 0.5])
def test_gcode_follows_splines_and_profile(job, tol):
    post = GcodePost()
    text = post.write(job, post.resolve_options({"chord_tolerance": tol, "feeds": "plan"})).decode("ascii")
    strokes, home = parse_gcode(text)
    assert home == (0.0, 0.0)
    assert len(strokes) == len(job.strokes)
    for (start, pts, feeds), st in zip(strokes, job.strokes):
        pts, feeds = np.array(pts), np.array(feeds)
        uu = np.linspace(0, 1, 200_001)
        dense = st.spline(uu)  # points < 0.002 mm apart
        assert np.allclose(pts[0], st.spline.start, atol=6e-4) and np.allclose(pts[-1], st.spline.end, atol=6e-4)
        # Every G1 end point is on the spline, and the spline never strays from the chords.
        gap, nearest = cKDTree(dense).query(pts)
        assert gap.max() < 2e-3
        assert _dist_to_polyline(dense[::40], pts).max() <= tol + 1e-6
        # Feeds carry the plan: positive, the program's time is the planned time, and
        # each segment's speed lies within the planned speeds along it.
        assert (feeds > 0).all()
        chord = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        assert sum(60 * chord / feeds) == pytest.approx(st.profile.duration, rel=0.01)
        ends = uu[nearest]
        probe = ends[:-1, None] + (ends[1:] - ends[:-1])[:, None] * np.linspace(0, 1, 9)
        v = _planned_speed(st, probe.ravel()).reshape(probe.shape)
        f = feeds / 60
        assert (f >= v.min(1) * 0.98 - 0.5).all() and (f <= v.max(1) * 1.02 + 0.5).all()
    if tol == 0.01:  # here the sample instants alone are too far apart: segments were split
        assert text.count("\nG1 ") > sum(len(s.velocity) for s in job.samples)


def test_gcode_header_and_options(job):
    post = GcodePost()
    opts = post.resolve_options({"pen_up": "M5", "pen_down": "M3 S90", "program_end": "M30", "min_feed": 1e6})
    text = post.write(job, opts).decode("ascii")
    lines = text.splitlines()
    assert lines[0].startswith(";") and "testbot" in lines[0]
    assert any(line.startswith("; planned time") and f"{job.duration:.1f} s" in line for line in lines)
    assert any("bounds" in line for line in lines)
    assert "G21 G90 G94" in lines and lines[-1] == "M30" and lines[-2] == "G0 X0 Y0"
    assert lines[-4:-2] == ["M5", "G4 P0.15"]  # pen up (and settle) before going home
    assert lines.count("M3 S90") == len(job.strokes)
    body = "\n".join(x for x in lines if not x.startswith(";"))
    assert set(re.findall(r"F([\d.]+)", body)) == {"1000000"}  # the floor applies everywhere
    with pytest.raises(PluginError):
        post.write(job, post.resolve_options({"chord_tolerance": 0}))
    with pytest.raises(PluginError):
        post.write(job, post.resolve_options({"pen_up": "M5\nM3"}))


def test_gcode_default_pen_matches_profile_comment(job):
    text = GcodePost().write(job, GcodePost.resolve_options()).decode("ascii")
    parse_gcode(text)  # the defaults are the servo pen "M3 S0" / "M3 S1000"


# ---------------------------------------------------------------- SVG

SVGNS = "{http://www.w3.org/2000/svg}"
INK = "{http://www.inkscape.org/namespaces/inkscape}"


def _points(d: str) -> np.ndarray:
    return np.array([float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", d)]).reshape(-1, 2)


def test_svg_preview(job):
    post = SvgPost()
    root = ET.fromstring(post.write(job, post.resolve_options()))
    assert root.tag == f"{SVGNS}svg"
    assert root.get("width").endswith("mm") and root.get("height").endswith("mm")
    vx, vy, vw, vh = map(float, root.get("viewBox").split())
    assert float(root.get("width")[:-2]) == vw and vw >= 400 and vh >= 300  # 1 unit = 1 mm
    assert root.find(f"{SVGNS}rect[@id='work-area']") is not None
    layers = [g for g in root.iter(f"{SVGNS}g") if g.get(f"{INK}groupmode") == "layer"]
    assert len(layers) == 2
    down, up = layers
    assert down.get("stroke") == "#000" and up.get("stroke") != down.get("stroke") and up.get("stroke-dasharray")
    assert len(down.findall(f"{SVGNS}path")) == len(job.strokes)
    assert len(up.findall(f"{SVGNS}path")) == len(job.travels)
    for path, st in zip(down.findall(f"{SVGNS}path"), job.strokes):
        d = path.get("d")
        assert d.startswith("M") and d.count("C") == 1  # one cubic Bezier per piece of the spline
        p = _points(d)
        assert len(p) == 1 + 3 * (len(st.spline.breakpoints) - 1)
        # Bezier i at t is the spline at u = bp_i + t (bp_i+1 - bp_i): the same curve,
        # traced at the same pace (exact up to the 3-decimal rounding)
        t = np.linspace(0.0, 1.0, 33)[:, None, None]
        b0, b1, b2, b3 = p[:-1:3][None], p[1::3][None], p[2::3][None], p[3::3][None]
        curve = (1 - t) ** 3 * b0 + 3 * (1 - t) ** 2 * t * b1 + 3 * (1 - t) * t ** 2 * b2 + t ** 3 * b3
        bp = st.spline.breakpoints
        u = bp[None, :-1] + t[:, :, 0] * np.diff(bp)[None, :]
        on_machine = np.stack([curve[..., 0], 300.0 - curve[..., 1]], axis=-1)  # undo the y flip
        assert np.abs(on_machine - st.spline(u.ravel()).reshape(on_machine.shape)).max() < 3e-3
        assert (p[:, 0] >= vx).all() and (p[:, 1] >= vy).all() and (p[:, 0] <= vx + vw).all() and (p[:, 1] <= vy + vh).all()
    # Upright: the hook at machine y ~ 200..250 is near the top of the picture.
    assert _points(down.findall(f"{SVGNS}path")[1].get("d"))[:, 1].max() < 110


def test_svg_without_travels(job):
    post = SvgPost()
    root = ET.fromstring(post.write(job, post.resolve_options({"show_travels": "no"})))
    layers = [g for g in root.iter(f"{SVGNS}g") if g.get(f"{INK}groupmode") == "layer"]
    assert [len(g.findall(f"{SVGNS}path")) for g in layers] == [len(job.strokes), 0]


def test_docs_worked_example_is_a_valid_file():
    from pathlib import Path

    doc = (Path(__file__).resolve().parent.parent / "docs" / "formats.md").read_text()
    block = doc.split("### Worked example")[1].split("```")[1]
    data = bytes.fromhex("".join(line[6:] for line in block.strip().splitlines()))
    header, cmds = read_plc(data, "formats.md")  # a version 1 file: still read
    assert header == PlcHeader(0.04, 4, 160000, 160000, 12000, 12000, 80.0, 80.0, version=1)
    assert cmds == [PlcCommand(1, MOVE, 800, 1600), PlcCommand(2, DRAW, 1600, -800),
                    PlcCommand(3, DRAW, 0, 0), PlcCommand(4, MOVE, 0, 0)]
