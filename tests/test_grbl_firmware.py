"""The GRBL time model against GRBL 1.1h's own firmware code: ``../shared/grbl-fw`` (gnea/grbl's planner and
stepper in a load-independent simulator) is built with gcc and runs G-code; its job time is the reference.

GRBL plans from targets rounded to whole steps (planner.c), so on chords of a fraction of a millimetre a half
step turns a junction by a degree or two and the firmware slows there; the model rounds as GRBL does."""

from __future__ import annotations


import numpy as np
import pytest

from doodlecam.link.grbl import timing

# the simulator's EEPROM (its README): $100..$102=80, $110..$112=9000 mm/min, $120..$122=2000 mm/s^2, $11=0.010, $1=25
SETTINGS = timing.GrblSettings((150.0, 150.0, 150.0), (2000.0, 2000.0, 2000.0), 0.01, steps_per_mm=(80.0, 80.0, 80.0))


@pytest.fixture(scope="module")
def firmware(grbl_firmware):  # tests/conftest.py builds the firmware once
    def run(gcode: str) -> float:
        _, fields = grbl_firmware(gcode, "-s", "trace.txt")
        assert fields["error"] == "0" and fields["alarm"] == "0", fields
        return float(fields["job_s"])

    return run


def wiggle(chord: float, turn_deg: float, n: int, seed: int) -> np.ndarray:
    """A stroke of n chords of ``chord`` mm turning by +-turn_deg at random: a traced curve's G-code."""
    rng = np.random.default_rng(seed)
    heading = np.cumsum(rng.choice([-1.0, 1.0], n) * np.radians(turn_deg) * rng.uniform(0.5, 1.0, n))
    steps = chord * np.column_stack([np.cos(heading), np.sin(heading)])
    return 20.0 + np.cumsum(np.vstack([[0.0, 0.0], steps]), axis=0)


@pytest.mark.parametrize("chord, turn", [(0.3, 0.05), (0.3, 1.0), (0.5, 2.0), (0.8, 4.0)])
def test_the_estimate_is_within_one_percent_of_the_firmware_on_short_chords(firmware, chord, turn):
    p = wiggle(chord, turn, 1500, seed=int(chord * 10))
    p = p - p.min(axis=0) + 5.0
    lines = ["G21 G90", f"G0 X{p[0, 0]:.3f} Y{p[0, 1]:.3f}", "G1 F6000"] + [f"X{x:.3f} Y{y:.3f}" for x, y in p[1:]]
    gcode = "\n".join(lines + ["M2", ""])
    fw = firmware(gcode)
    model = timing.estimate_gcode(gcode, SETTINGS).total
    assert abs(model / fw - 1) <= 0.01, (model, fw)



def test_default_chords_on_grbls_steps_run_faster_on_the_firmware_within_the_tolerance(grbl_firmware, tmp_path,
                                                                                       monkeypatch):
    """feeds=cap puts each vertex on one of GRBL's step positions so the rounded chords turn smoothly: on the
    firmware the stroke is drawn faster than with the same chords rounded as printed, every executed step stays within
    the tolerance of the curve (plus half a step: GRBL's line stepping)."""
    import doodlecam.postprocessors.gcode as post
    from test_gcode_dialects import _dist_to_polyline, write
    from test_gcode_grbl import one_stroke_job

    t = np.linspace(0.0, 90.0, 181)  # a traced curve: slow bends and small wiggles, control points 0.5 mm apart
    job = one_stroke_job(np.c_[40.0 + t, 60.0 + 8.0 * np.sin(t / 6.0) + 0.05 * np.sin(3.1 * t)])
    dense = job.strokes[0].spline(np.linspace(0.0, 1.0, 20_001))

    def run(text: str) -> tuple[float, np.ndarray]:
        trace = tmp_path / f"trace{len(list(tmp_path.iterdir()))}.txt"
        _, fields = grbl_firmware(text, "-s", str(trace))
        assert fields["error"] == "0" and fields["alarm"] == "0", fields
        steps, ticks, pen = [], [], 0
        for line in trace.read_text().splitlines():
            w = line.split()
            if w[0] == "P":
                pen = int(w[3])
            elif w[0] == "S" and pen:
                steps.append((int(w[2]), int(w[3])))
                ticks.append(int(w[1]))
        return (ticks[-1] - ticks[0]) / 16e6, np.array(steps) / 80.0  # the drawing's time (16 MHz clock)

    snapped = write(job, chord_tolerance=0.05)
    fw, executed = run(snapped)
    assert _dist_to_polyline(executed, dense).max() <= 0.05 + 0.5 * np.sqrt(2) / 80.0
    assert _dist_to_polyline(dense[::10], executed).max() <= 0.05 + 0.5 * np.sqrt(2) / 80.0
    # the same search with every vertex where rounding the curve's point puts it
    monkeypatch.setattr(post, "SNAP", False)
    rounded = write(job, chord_tolerance=0.05)
    assert rounded != snapped
    fw_rounded, _ = run(rounded)
    assert fw < 0.95 * fw_rounded, (fw, fw_rounded)
