"""G-code dialects (GRBL servo/Z, Marlin, LinuxCNC) and the GRBL 1.1 job-time model."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy.spatial import cKDTree

from doodlecam.errors import PluginError
from doodlecam.link.grbl.timing import GrblSettings, estimate_gcode, estimate_program
from doodlecam.machine import parse_machine
from doodlecam.postprocessors.gcode import DIALECTS, GcodePost
from test_posts import MACHINE, make_job

LIMITS = {"grbl": 79, "marlin": 95, "linuxcnc": 255}  # characters per line, newline excluded
NUM = r"-?\d+(?:\.\d{1,3})?"


@pytest.fixture(scope="module")
def job():
    return make_job(parse_machine(MACHINE, "test.toml"))


def write(job, **opts) -> str:
    return GcodePost().write(job, GcodePost.resolve_options(opts)).decode("ascii")


def strict_parse(text: str, dialect: str, pen_up: str, pen_down: str, dwell: str):
    """Every line must be one this dialect accepts; returns strokes [(points, feeds)]."""
    assert text.endswith("\n") and "\r" not in text
    lines = text.split("\n")[:-1]
    for line in lines:
        assert len(line) <= LIMITS[dialect], f"{dialect}: line of {len(line)} characters: {line!r}"
        assert line.isascii() and line == line.strip()
    preamble = {"grbl": ["G21 G90 G94", "G17"], "marlin": ["G21", "G90"],
                "linuxcnc": ["G21 G90 G94", "G17", "G64 P0.05"]}[dialect]
    body = [line for line in lines if not line.startswith(";")]
    assert body[:len(preamble)] == preamble
    end = {"grbl": "M2", "marlin": "M84", "linuxcnc": "M2"}[dialect]
    assert body[-1] == end
    pen, strokes, due = "?", [], False
    g1 = re.compile(rf"^G1 X({NUM}) Y({NUM})(?: F(\d+(?:\.\d)?))?$")
    g0 = re.compile(rf"^G0 X({NUM}) Y({NUM})$")
    feed = None
    for line in body[len(preamble):-1]:
        if due:
            assert line == dwell, f"expected the settle dwell {dwell!r}, got {line!r}"
            due = False
        elif line in (pen_up, pen_down):
            pen, due = ("down" if line == pen_down else "up"), True
            if pen == "down":
                strokes.append(([], []))
                feed = None
        elif (m := g0.match(line)):
            assert pen == "up"
        elif (m := g1.match(line)):
            assert pen == "down"
            feed = float(m.group(3)) if m.group(3) else feed
            assert feed is not None and feed > 0, "first G1 of a stroke without F"
            strokes[-1][0].append((float(m.group(1)), float(m.group(2))))
            strokes[-1][1].append(feed)
        else:
            raise AssertionError(f"{dialect}: unexpected line {line!r}")
    assert pen == "up"
    return strokes


CASES = [
    ("grbl", "servo", "M3 S0", "M3 S1000", "G4 P0.15"),
    ("grbl", "z", "G0 Z2", "G1 Z0 F1000", "G4 P0.15"),
    ("marlin", "servo", "M280 P0 S90", "M280 P0 S0", "G4 P150"),
    ("marlin", "z", "G0 Z2", "G1 Z0 F1000", "G4 P150"),
    ("linuxcnc", "z", "G0 Z2", "G1 Z0 F1000", "G4 P0.15"),
    ("linuxcnc", "servo", "M3 S0", "M3 S1000", "G4 P0.15"),
]


def _dist_to_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    a, d = poly[:-1], np.diff(poly, axis=0)
    dd = np.maximum((d * d).sum(1), 1e-300)
    s = np.clip(((points[:, None] - a) * d).sum(2) / dd, 0, 1)
    return np.linalg.norm(points[:, None] - (a + s[..., None] * d), axis=2).min(1)


@pytest.mark.parametrize("feeds", ["cap", "plan"])
@pytest.mark.parametrize("dialect, pen, up, down, dwell", CASES)
def test_dialect_lines_and_path(job, dialect, pen, up, down, dwell, feeds):
    text = write(job, dialect=dialect, pen=pen if pen != DIALECTS[dialect].pen else "", feeds=feeds)
    strokes = strict_parse(text, dialect, up, down, dwell)
    assert len(strokes) == len(job.strokes)
    cap = 60 * min(a.max_velocity for a in job.machine.axes)
    spm = np.array([a.steps_per_mm for a in job.machine.axes])
    starts = [[float(w[1:]) for w in x.split()[1:3]] for x in text.splitlines() if x.startswith("G0 X")]
    for (pts, fs), st, start in zip(strokes, job.strokes, starts):
        pts, fs = np.vstack([start, pts]), np.array(fs)
        dense = st.spline(np.linspace(0, 1, 100_001))
        if feeds == "plan":
            assert cKDTree(dense).query(pts)[0].max() < 3e-3  # every end point on the spline
        else:  # the vertices on GRBL's steps near the curve: every point of the chords within the tolerance
            along = pts[:-1, None] + np.linspace(0.0, 1.0, 20)[:, None] * np.diff(pts, axis=0)[:, None]
            assert cKDTree(dense).query(along.reshape(-1, 2))[0].max() <= 0.05 + 1e-6
        # every chord within the tolerance of the spline, both ways: the chords near the curve,
        # the curve near the chords (each probe against its own chord's span is covered by the polyline)
        assert _dist_to_polyline(dense[::50], pts).max() <= 0.05 + 1e-6
        steps = np.round(pts * spm)
        assert (np.abs(np.diff(steps, axis=0)).max(1) >= 1).all()  # no segment GRBL would drop, none with a feed
        assert (fs <= cap + 0.05).all() and (fs > 0).all()  # F never above the pen-speed cap
        chord = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        if feeds == "plan":
            assert sum(60 * chord / fs) == pytest.approx(st.profile.duration, rel=0.01)  # planned feeds
        else:
            assert set(fs.tolist()) == {cap}


def test_line_limits_are_enforced(job):
    long = "M3 S1000 " + "(servo)" * 13  # 100 characters: too long for GRBL and Marlin
    assert 95 < len(long) <= 255
    for dialect in ("grbl", "marlin"):
        with pytest.raises(PluginError, match="at most"):
            write(job, dialect=dialect, pen_down=long)
    assert long in write(job, dialect="linuxcnc", pen_down=long).splitlines()
    with pytest.raises(PluginError, match="dialect"):
        GcodePost.resolve_options({"dialect": "mach3"})
    with pytest.raises(PluginError, match="z_up"):
        write(job, pen="z", z_up=0.0, z_down=1.0)


def test_header_carries_the_grbl_estimate(job):
    text = write(job)
    line = next(x for x in text.splitlines() if x.startswith("; GRBL 1.1 estimate"))
    shown = float(re.search(r"estimate ([\d.]+) s", line).group(1))
    body = "\n".join(x for x in text.splitlines() if not x.startswith(";"))
    est = estimate_gcode(body, GrblSettings.from_machine(job.machine)).total
    assert shown == pytest.approx(est, abs=0.051)
    # the settings the estimate assumes, as GRBL takes them
    assert "; assumes $100=80 $101=80 $110=9000 $111=9000" in text.splitlines()
    assert "; assumes $120=2000 $121=2000 $11=0.01 $1=25" in text.splitlines()
    # $1=255 keeps the motors on: no 25 ms at each of the 2 stops per stroke and the last travel
    quiet = write(job, idle_delay=255)
    shown255 = float(re.search(r"estimate ([\d.]+) s", quiet).group(1))
    assert shown - shown255 == pytest.approx(0.025 * (2 * len(job.strokes) + 1), abs=0.11)
    # GRBL cannot beat the plan's own feeds: its time is at least the pen-down plan plus dwells.
    plan = write(job, feeds="plan")
    est_plan = estimate_gcode(plan, GrblSettings.from_machine(job.machine)).total
    assert est_plan >= sum(s.profile.duration for s in job.strokes) + 0.3 * len(job.strokes)
    assert est < est_plan  # the default G-code runs faster on GRBL
    assert "GRBL 1.1 estimate" not in write(job, estimate="no")


def test_grbl_settings_for_a_profile():
    from doodlecam.link.grbl.timing import grbl_settings_for

    m = parse_machine(MACHINE, "test.toml")
    d = grbl_settings_for(m)
    assert d["$100"] == m.x.steps_per_mm and d["$110"] == pytest.approx(60 * m.x.max_velocity)
    assert d["$120"] == m.x.max_acceleration and d["$130"] == m.width and d["$131"] == m.height
    assert d["$11"] == 0.01 and d["$1"] == 25
    assert list(d) == sorted(d, key=lambda k: int(k[1:]))


def test_cap_chords_never_outrun_the_serial_line(job):
    """Every 15 consecutive blocks take GRBL longer than sending their lines at 115200 baud."""
    from doodlecam.link.grbl.timing import parse_gcode
    from doodlecam.postprocessors.gcode import _serial_keeps_up

    text = write(job)
    s = GrblSettings.from_machine(job.machine)
    for pts, _ in strict_parse(text, "grbl", "M3 S0", "M3 S1000", "G4 P0.15"):
        p = np.array(pts)
        prog = [("G1", x, y, None, 9000.0) for x, y in p[1:]]
        bt = estimate_program(prog, s, start=tuple(p[0])).block_times
        assert _serial_keeps_up(p, bt, 115200)
    assert parse_gcode(text)  # the whole file parses for the model


# ------------------------------------------------------------ GRBL 1.1 time model, by hand

def NoIdle(*args, **kw) -> GrblSettings:
    """Settings with $1=255 (motors always on): the motion and dwell times alone."""
    return GrblSettings(*args, idle_delay_ms=255, **kw)


def test_grbl_idle_delay_at_every_stop():
    # $1 = 25 ms: GRBL's st_go_idle waits each time motion stops, i.e. once per run of moves
    # between synchronisations (M3 S, G4) and at the program end; a sync without motion before
    # it (the dwell after a pen command) adds nothing.
    prog = [("G1", 10, 0, 600), ("M", "M3 S1000"), ("G4", 0.1), ("G1", 20, 0, None), ("G1", 30, 0, None),
            ("M", "M3 S0"), ("G4", 0.1), ("G0", 0, 0, None)]
    s = GrblSettings((100.0,) * 3, (1000.0,) * 3, 0.01)
    est, bare = estimate_program(prog, s), estimate_program(prog, NoIdle((100.0,) * 3, (1000.0,) * 3, 0.01))
    assert est.stops == 3 and est.total - bare.total == pytest.approx(0.075, abs=1e-12)
    s1 = GrblSettings((100.0,) * 3, (1000.0,) * 3, 0.01, idle_delay_ms=0)
    assert estimate_program(prog, s1).total == pytest.approx(bare.total, abs=1e-12)

def test_a_long_program_is_timed_in_parts_between_synchronisations(monkeypatch):
    # 10^6 blocks of a generated drawing are timed a part at a time (memory); each part starts at a
    # synchronisation, so the times are the one call's (to rounding: the forward pass sums from the start)
    from doodlecam.link.grbl import timing

    rng = np.random.default_rng(3)
    prog = [("G1", 0.0, 0.0, 3000)]
    for run in range(60):
        prog += [("G1", float(x), float(y), None) for x, y in rng.uniform(0, 50, (int(rng.integers(1, 40)), 2))]
        prog += [("M", "M3 S0"), ("G4", 0.1), ("G0", float(rng.uniform(0, 50)), 0.0, None), ("M", "M3 S1000")]
    whole = estimate_program(prog)
    for chunk in (1, 7, 50):
        monkeypatch.setattr(timing, "RUN_CHUNK", chunk)
        parts = estimate_program(prog)
        assert parts.stops == whole.stops and parts.blocks == whole.blocks
        assert np.allclose(parts.block_times, whole.block_times, rtol=1e-9, atol=1e-12)


def test_grbl_straight_line():
    # 100 mm at F6000 (100 mm/s), a = 1000 mm/s²: 0.1 s up (5 mm), 90 mm cruise 0.9 s, 0.1 s down.
    s = NoIdle((1e3,) * 3, (1000.0,) * 3, 0.01)
    assert estimate_program([("G1", 100, 0, 6000)], s).total == pytest.approx(1.1, rel=1e-9)
    # A diagonal: per-axis limits bind along the unit vector (a = 1000·√2, rate = 100·√2 mm/s).
    s2 = NoIdle((100.0, 100.0, 100.0), (1000.0,) * 3, 0.01)
    d = 100 * math.sqrt(2)
    v, a = 100 * math.sqrt(2), 1000 * math.sqrt(2)
    assert estimate_program([("G1", 100, 100, 60000)], s2).total == pytest.approx(v / a + d / v, rel=1e-9)


def test_grbl_square_junctions():
    # Square of 50 mm at F3000 (50 mm/s), a = 500, δ = 0.01. Each 90° corner:
    # cos θ = 0, sin(θ/2) = √½, junction acceleration along (u − u_prev) = 500/√½ = 707.107,
    # v² = 707.107·0.01·0.70711/(1 − 0.70711) = 17.0711 → v = 4.13172 mm/s.
    # Side 1 (and 4): 0.1 s up, 0.0917366 s down to 4.13, 45.01707 mm cruise → 1.0920780 s.
    # Sides 2, 3: 0.0917366 s up and down, 45.03414 mm cruise → 1.0841560 s. Sum 4.352468 s.
    s = NoIdle((1e3,) * 3, (500.0,) * 3, 0.01)
    square = [("G1", 50, 0, 3000), ("G1", 50, 50, None), ("G1", 0, 50, None), ("G1", 0, 0, None)]
    assert estimate_program(square, s).total == pytest.approx(4.352468, rel=1e-5)
    # An M-code after side 1 empties the planner: side 1 runs rest to rest (1.1 s), side 2
    # starts from rest (1.0920780 s), sides 3 and 4 as before: 4.368312 s.
    stop = [square[0], ("M", "M3 S0"), *square[1:]]
    assert estimate_program(stop, s).total == pytest.approx(1.1 + 2 * 1.0920780 + 1.0841560, rel=1e-6)
    # A dwell stops the same way and adds its time.
    assert estimate_program([square[0], ("G4", 0.5), *square[1:]], s).total == pytest.approx(4.368312 + 0.5, rel=1e-6)


def test_grbl_circle_of_chords():
    # 36 chords on r = 20 at F1200 (20 mm/s), a = 500: each 10° junction allows
    # v² ≥ 500·0.01·cos5°/(1 − cos5°) = 1309 > 20², so only the ends ramp:
    # time = L/v + v/a with L = 36·40·sin 5° = 125.4998 mm.
    pts = [(20 * math.cos(k * math.pi / 18), 20 * math.sin(k * math.pi / 18)) for k in range(37)]
    prog = [("G1", x, y, 1200) for x, y in pts[1:]]
    s = NoIdle((1e3,) * 3, (500.0,) * 3, 0.01)
    L = 36 * 40 * math.sin(math.radians(5))
    assert estimate_program(prog, s, start=pts[0]).total == pytest.approx(L / 20 + 20 / 500, rel=1e-3)


def test_grbl_lookahead_window_caps_speed():
    # 200 collinear 0.1 mm blocks at F6000, a = 1000. The 15 planned blocks must be able
    # to stop, so a block leaves at most at v² = 2·a·(14·0.1) = 2800 (52.915 mm/s):
    # 14 blocks ramp up (0.052915 s), 14 ramp down, and the 172 blocks between peak inside
    # at v² = (2aL + 2·2800)/2 = 2900: 2·(√2900 − √2800)/1000 s each.
    s = NoIdle((1e3,) * 3, (1000.0,) * 3, 0.01)
    prog = [("G1", 0.1 * (k + 1), 0, 6000) for k in range(200)]
    hand = 2 * math.sqrt(2800) / 1000 + 172 * 2 * (math.sqrt(2900) - math.sqrt(2800)) / 1000
    assert estimate_program(prog, s).total == pytest.approx(hand, rel=1e-6)
    # With unbounded look-ahead it would reach 100 mm/s: 20 mm in 2·0.1 s + 10 mm at 100 mm/s.
    big = NoIdle((1e3,) * 3, (1000.0,) * 3, 0.01, blocks=1000)
    assert estimate_program(prog, big).total == pytest.approx(0.2 + 0.1, rel=1e-6)


def test_grbl_reversal_stops_and_parse():
    s = NoIdle((1e3,) * 3, (1000.0,) * 3, 0.01)
    there_and_back = estimate_gcode("G1 X100 F6000\nX0\n", s).total  # modal G1, a reversal junction
    assert there_and_back == pytest.approx(2.2, rel=1e-9)
    assert estimate_gcode("G21 G90\nG0 X100\nG4 P1.5\nM2\n", NoIdle((100.0,) * 3, (1000.0,) * 3)).total \
        == pytest.approx(1.1 + 1.5, rel=1e-9)


def test_runs_timed_together_equal_runs_timed_one_by_one():
    # estimate_program times every run between synchronisations in one call; a run
    # timed alone (from rest to rest) must give the same block times
    from doodlecam.link.grbl.timing import _segment_time

    rng = np.random.default_rng(7)
    s = NoIdle((150.0, 150.0, 20.0), (2000.0, 2000.0, 500.0))
    for _ in range(50):
        runs, prog = [], [("G1", None, None, None, 1200.0)]
        pos = np.zeros(3)
        for _ in range(rng.integers(1, 6)):
            pts, feeds = [pos.copy()], []
            for _ in range(rng.integers(1, 12)):
                xy = np.round(rng.uniform(0, 40, 2), 1) if rng.random() < 0.85 else pts[-1][:2]  # some zero-length
                f = float(rng.choice([600.0, 3000.0, 9000.0]))
                prog.append(("G1", float(xy[0]), float(xy[1]), None, f))
                pts.append(np.array([xy[0], xy[1], 0.0]))
                feeds.append(f / 60.0)
            prog.append(("G4", 0.1))
            runs.append(_segment_time(np.array(pts), np.array(feeds), s))
            pos = pts[-1]
        alone = np.concatenate(runs)
        together = estimate_program(prog, s)
        assert np.allclose(together.block_times, alone[alone > 0], rtol=1e-12, atol=1e-12)
