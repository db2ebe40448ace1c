"""Pens and pen changes: [[pen]] profiles, layers to pens, and the pause every post and link makes.

The written files are read back independently (the .plc reader of test_executed, written
from docs/formats.md; the G-code as text) and sent to the real simulators: the PLC over UDP
on loopback, GRBL over a pseudo-terminal. At each pen change the machine must be holding,
pen up, until the operator answers; every command must run exactly once.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from doodlecam.errors import MachineError
from doodlecam.link.grbl.emulator import GrblConfig, GrblEmulator
from doodlecam.link.grbl.protocol import prepare
from doodlecam.link.grbl.streamer import send_gcode
from doodlecam.link.plc.packetfile import read_plc_array
from doodlecam.link.plc.protocol import Fault
from doodlecam.link.plc.sender import UdpSender
from doodlecam.link.plc.simulator import PlcConfig, PlcSimulator
from doodlecam.link.session import Paused
from doodlecam.machine import load_machine, parse_machine
from doodlecam.pipeline import Settings, convert

from test_executed import execute, read_plc_file
from test_udp import bounded

ROOT = Path(__file__).resolve().parent.parent
LAYERS_SVG = ROOT / "samples" / "vectors" / "layers.svg"

PROFILE = """
[machine]
name = "twopens"
[work_area]
width = 400.0
height = 300.0
[axes.x]
steps_per_mm = 80.0
max_velocity = 150.0
max_acceleration = 2000.0
[axes.y]
steps_per_mm = 80.0
max_velocity = 150.0
max_acceleration = 2000.0
[sampling]
delta_time = 0.04
[[pen]]
name = "fineliner"
colour = "black"
width = 0.3
[[pen]]
name = "brush"
colour = "#d01010"
width = 1.0
max_speed = 40.0
max_accel = 400.0
up_delay = 0.3
"""


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    p = tmp_path_factory.mktemp("m") / "twopens.toml"
    p.write_text(PROFILE)
    return load_machine(p)


@pytest.fixture(scope="module")
def written(machine, tmp_path_factory):
    out = tmp_path_factory.mktemp("out")
    res = convert(LAYERS_SVG, out, Settings(machine=machine, posts=("plc", "gcode", "svg")))
    return res.job, {p.suffix: p for p in res.outputs}


def _toml(text: str):
    import tomllib

    return tomllib.loads(text)


# ---------------------------------------------------------------- profiles

def test_pens_from_the_profile(machine):
    assert [p.name for p in machine.pens] == ["fineliner", "brush"] and machine.pen is machine.pens[0]
    brush = machine.pens[1]
    assert (brush.max_speed, brush.max_accel, brush.up_delay, brush.width) == (40.0, 400.0, 0.3, 1.0)
    assert brush.describe(2) == "pen 2 'brush' (#d01010)"
    # layers go to the pen of their name or colour (any spelling), the rest to the unused pens in order
    assert machine.pen_assignment(["red", "black", "blue"], {"red": "rgb(208,16,16)"}) == {
        "red": 2, "black": 1, "blue": 1}
    assert machine.pen_assignment(["a", "b", "c"]) == {"a": 1, "b": 2, "c": 1}


def test_a_pen_lists_its_layers(machine):
    data = _toml(PROFILE.replace('name = "brush"', 'name = "brush"\nlayers = ["sky", "sea"]'))
    m = parse_machine(data, "p.toml")
    assert m.pen_assignment(["sea", "ground", "sky"]) == {"sea": 2, "ground": 1, "sky": 2}


@pytest.mark.parametrize("change, message", [
    ('max_speed = 40.0', "max_speed = -4.0"),
    ('width = 1.0', 'widht = 1.0'),
    ('name = "brush"', 'name = "Fineliner"'),
    ("", ""),
])
def test_bad_pen_entries_are_one_line_errors(change, message):
    if not message:
        data = {**_toml(PROFILE.split("[[pen]]")[0]), "pen": []}
        expect = "[[pen]] is empty"
    else:
        data = _toml(PROFILE.replace(change, message))
        expect = {"max_speed = -4.0": "p.toml: pen[2].max_speed = -4 must be positive",
                  "widht = 1.0": "unknown key pen[2].widht (did you mean 'width'?)",
                  'name = "Fineliner"': "two [[pen]] entries are named"}[message]
    with pytest.raises(MachineError) as e:
        parse_machine(data, "p.toml")
    assert expect in str(e.value) and "\n" not in str(e.value)


def test_pen_accel_cap_needs_paper_axes(tmp_path):
    text = (ROOT / "doodlecam" / "machines" / "fivebar.toml").read_text()
    text = re.sub(r"\[pen\][^\[]*", "[[pen]]\nname = \"a\"\n[[pen]]\nname = \"b\"\nmax_accel = 300.0\n\n", text)
    p = tmp_path / "fb.toml"
    p.write_text(text)
    r = subprocess.run([sys.executable, "-m", "doodlecam", "convert", str(LAYERS_SVG), "-o", str(tmp_path / "o"),
                        "-m", str(p)], capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "max_accel needs a machine whose axes are the paper's x and y" in r.stderr
    assert "Traceback" not in r.stderr


# ---------------------------------------------------------------- the job and its files

def test_layers_are_plotted_pen_by_pen(written):
    """black and red have pens of their colours, blue shares one: the layers are grouped by pen, so the
    pen is changed once (pens used - 1), and the job first asks for pen 1 (two pens: which one is in?)."""
    job, _ = written
    assert job.layers == ("black", "blue", "red")
    pens = job.pen_numbers
    assert set(pens) == {1, 2} and list(pens) == sorted(pens)
    changes = job.pen_changes
    assert len(changes) == 1 and all(pens[i] != pens[i - 1] for i in changes)
    assert all(job.strokes[i].layer != job.strokes[i - 1].layer for i in changes)
    assert job.pen_pauses == (0, *changes)


def test_gcode_pauses_once_between_layers_with_the_pen_up(written, machine):
    job, files = written
    text = files[".gcode"].read_text()
    lines = text.splitlines()
    pauses = [k for k, ln in enumerate(lines) if re.match(r"M0\b", ln)]
    assert len(pauses) == len(job.pen_pauses) == 2
    assert lines[pauses[0]] == "M0 (fit pen 1 'fineliner' [black])"  # before anything moves
    assert lines[pauses[1]] == "M0 (change to pen 2 'brush' [#d01010])"
    # the strokes between pauses: each pause sits after a stroke's pen-up and before the next travel
    g0 = [k for k, ln in enumerate(lines) if ln.startswith("G0 ")]
    starts = g0[:-1]  # the last G0 goes home
    assert len(starts) == len(job.strokes)
    first = [ln for ln in lines[:pauses[0]] if not ln.startswith(";")]
    assert first[-2:] == ["M3 S0", "G4 P0.1"] and not any(re.match(r"G[01] ", ln) for ln in first)  # pen up
    for k, i in zip(pauses[1:], job.pen_changes):
        assert starts[i - 1] < k < starts[i]
        pen_cmds = [ln for ln in lines[starts[i - 1]:k] if ln.startswith("M3")]
        assert pen_cmds[-1] == "M3 S0"  # lifted before the pause
    # the brush's slower lift: its G4 after the pen-up
    assert "G4 P0.3" in lines[starts[job.pen_changes[0]]:]


def test_plc_file_pauses_where_the_pen_changes(written):
    job, files = written
    header, strokes = read_plc_file(files[".plc"].read_bytes())
    pens = job.pen_numbers
    assert header["pauses"] == [(i, pens[i]) for i in job.pen_pauses] == [(0, 1), (job.pen_changes[0], 2)]
    assert len(strokes) == len(job.strokes)


def test_each_pen_keeps_its_own_caps_as_executed(written, machine):
    job, files = written
    header, strokes = read_plc_file(files[".plc"].read_bytes())
    dt, k = header["delta_time"], header["steps_per_mm"]
    worst = {1: [0.0, 0.0], 2: [0.0, 0.0]}
    ramps = np.zeros(2)  # steps/s^2 per axis, every pen
    for (start, targets), pen in zip(strokes, job.pen_numbers):
        _, v = execute(start, targets, dt)
        speed = np.linalg.norm(v / k, axis=1).max()
        acc = np.abs(np.diff(v, axis=0)) / dt
        ramps = np.maximum(ramps, acc.max(axis=0))
        worst[pen] = [max(worst[pen][0], speed), max(worst[pen][1], (acc / k).max())]
    assert worst[2][0] <= 40.0 * (1 + 1e-9) and worst[2][1] <= 400.0 * (1 + 1e-9)
    assert worst[1][0] > 40.0 and worst[1][1] > 400.0  # the fineliner is not slowed by the brush
    assert (ramps <= header["draw_accel"]).all() and (header["draw_accel"] < ramps + 1).all()  # the header says it


# ---------------------------------------------------------------- the links wait for the operator

def test_plc_simulator_holds_at_each_pen_change(written, machine):
    job, files = written
    data = files[".plc"].read_bytes()
    sim = PlcSimulator(PlcConfig.from_machine(machine)).start()
    asked = []

    def operator(pen, what):
        # the PLC holds the job, pen up, at rest, until the operator answers
        assert sim.held is not None and sim.held.reason == Fault.PEN_CHANGE and not sim.pen
        assert not np.any(sim.vel)
        asked.append((pen, what))

    try:
        sender = UdpSender(*sim.address, data, timeout=5.0, rto=0.03, pen_change=operator)
        r = bounded(sender.run)
        _, arr = read_plc_array(data)
        assert asked == [(1, "pen 1"), (2, "pen 2")] and sender.pen_changes == 2
        assert r.executed == len(arr)
        np.testing.assert_array_equal(sim.executed(r.job_id), np.arange(1, len(arr) + 1))  # each once, in order
        tr = sim.trajectory()
        paused = tr[tr["type"] == 2]
        assert len(paused) == 2 and not paused["pen"].any()
    finally:
        sim.stop()


def test_plc_send_without_an_operator_stops_and_asks_again(written, machine, tmp_path):
    job, files = written
    data = files[".plc"].read_bytes()
    sim = PlcSimulator(PlcConfig.from_machine(machine)).start()
    state = tmp_path / "job.plc.send.json"
    try:
        with pytest.raises(Paused, match="waits for a pen change"):
            bounded(UdpSender(*sim.address, data, state_file=state, timeout=5.0, rto=0.03).run)
        assert sim.held is not None and sim.held.reason == Fault.PEN_CHANGE and not sim.pen
        before = len(sim.executed())
        asked = []
        r = bounded(UdpSender(*sim.address, data, state_file=state, timeout=5.0, rto=0.03,
                              pen_change=lambda pen, what: asked.append(pen)).run)
        assert r.resumed and asked == [1, 2]  # the interrupted pen change is asked again first
        _, arr = read_plc_array(data)
        np.testing.assert_array_equal(sim.executed(r.job_id), np.arange(1, len(arr) + 1))
        assert before < len(arr)
    finally:
        sim.stop()


def test_grbl_emulator_holds_at_each_m0(written, tmp_path):
    job, files = written
    gcode = files[".gcode"]
    emu = GrblEmulator(GrblConfig(speed=200.0)).start()
    asked = []

    def operator(pen, what):
        assert emu.state == "Hold" and emu.m0_hold and emu.modal["s"] == 0  # held, pen up (M3 S0)
        asked.append((pen, what))

    try:
        r = bounded(lambda: send_gcode(emu.port, gcode, state_file=tmp_path / "s.json", pen_change=operator), 120)
        assert asked == [(1, "pen 1 'fineliner' (black)"), (2, "pen 2 'brush' (#d01010)")]
        assert r["pen_changes"] == 2 and emu.pauses == 2
        assert emu.received == [ln.text.upper() for ln in prepare(gcode.read_text())]  # every line once
        assert emu.overruns == 0 and emu.state == "Idle"
    finally:
        emu.stop()


def test_grbl_send_without_an_operator_resumes_at_the_pause(written, tmp_path):
    job, files = written
    gcode = files[".gcode"]
    lines = prepare(gcode.read_text())
    emu = GrblEmulator(GrblConfig(speed=200.0)).start()
    state = tmp_path / "s.json"
    try:
        with pytest.raises(Paused, match="pen change"):
            bounded(lambda: send_gcode(emu.port, gcode, state_file=state), 120)
        import json

        nxt = json.loads(state.read_text())["next"]
        assert lines[nxt].text == "M0"  # the resume point is the pause itself
        asked = []
        r = bounded(lambda: send_gcode(emu.port, gcode, state_file=state, pen_change=lambda p, w: asked.append(p)), 120)
        assert r["resumed"] and asked == [1, 2] and not state.exists()
    finally:
        emu.stop()


def test_send_command_prompts_the_operator(written, machine, tmp_path):
    job, files = written
    sim = PlcSimulator(PlcConfig.from_machine(machine)).start()
    prof = tmp_path / "twopens.toml"
    prof.write_text(PROFILE)
    try:
        r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(files[".plc"]), "--udp",
                            f"127.0.0.1:{sim.address[1]}", "--no-progress", "-m", str(prof), "--no-auth"],
                           input="\n\n", capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert r.returncode == 0, r.stderr
        assert "change to pen 2 'brush' (#d01010), then press Enter" in r.stderr
        assert "change to pen 1 'fineliner' (black), then press Enter" in r.stderr
        # no answer (standard input closed): stops at the pause with a one-line message, resumable
        r = subprocess.run([sys.executable, "-m", "doodlecam", "send", str(files[".plc"]), "--udp",
                            f"127.0.0.1:{sim.address[1]}", "--no-progress", "--again", "--no-auth"],
                           input="", capture_output=True, text=True, cwd=ROOT, timeout=120)
        assert r.returncode == 130 and "nobody answered the pen change" in r.stderr and "Traceback" not in r.stderr
    finally:
        sim.stop()


# ---------------------------------------------------------------- the order of layers (issue 28)

FOUR = ('<svg xmlns="http://www.w3.org/2000/svg" xmlns:inkscape="http://www.inkscape.org/namespaces/inkscape" '
        'width="120mm" height="90mm" viewBox="0 0 120 90">'
        + "".join(f'<g inkscape:groupmode="layer" inkscape:label="{name}" stroke="{colour}" fill="none">'
                  f'<circle cx="{20 + 25 * k}" cy="45" r="10"/></g>'
                  for k, (name, colour) in enumerate([("outline", "black"), ("roses", "#d01010"),
                                                      ("leaves", "green"), ("shadow", "black")]))
        + "</svg>")


def _four(tmp_path, machine, order=None):
    path = tmp_path / "four.svg"
    path.write_text(FOUR)
    res = convert(path, tmp_path / "out", Settings(machine=machine, posts=("gcode", "plc"), order=order or {}))
    files = {p.suffix: p for p in res.outputs}
    m0 = [ln for ln in files[".gcode"].read_text().splitlines() if re.match(r"M0\b", ln)]
    return res, m0, read_plc_file(files[".plc"].read_bytes())[0]["pauses"]


def test_four_colours_on_two_pens_change_pens_once(tmp_path, machine):
    """Two black layers, a red one and a green one (no pen of its own: it shares the nearest colour's, black):
    grouped by pen, one change; the files read back ask for pen 1 first, then pen 2 once; the summary says
    which colour went to which pen and why."""
    res, m0, pauses = _four(tmp_path, machine)
    job, s = res.job, res.summary()
    assert job.layers == ("outline", "leaves", "shadow", "roses")
    assert s["pen_changes"] == 1 == len(set(job.pen_numbers)) - 1
    assert m0 == ["M0 (fit pen 1 'fineliner' [black])", "M0 (change to pen 2 'brush' [#d01010])"]
    assert [pen for _, pen in pauses] == [1, 2] and pauses[0][0] == 0
    assert s["first_pen_prompt"] == "pen 1 'fineliner' (black)"
    why = {c["layer"]: (c["colour"], c["pen"], c["why"]) for c in s["pen_choice"]}
    assert why["outline"] == ("#000000", "pen 1 'fineliner' (black)", "the pen's colour")
    assert why["roses"] == ("#d01010", "pen 2 'brush' (#d01010)", "the pen's colour")
    assert why["leaves"] == ("#008000", "pen 1 'fineliner' (black)", "no pen of its own: shares the pen nearest in colour")
    assert any(w.startswith("no pen of their own") and "leaves (#008000) drawn with pen 1" in w for w in s["warnings"])


def test_file_order_is_kept_when_the_profile_says_so(tmp_path):
    m = parse_machine({**_toml(PROFILE), "order": {"layers": "file"}}, "p.toml")
    res, m0, pauses = _four(tmp_path, m)
    assert res.job.layers == ("outline", "roses", "leaves", "shadow")
    assert res.summary()["pen_changes"] == 2 and len(m0) == len(pauses) == 3  # the first pen, then two changes
    assert [pen for _, pen in pauses] == [1, 2, 1]  # outline, roses, leaves (nearest black), shadow
    with pytest.raises(MachineError, match="layers must be 'pen'.*or 'file'"):
        parse_machine({**_toml(PROFILE), "order": {"layers": "colour"}}, "p.toml")


def test_one_pen_profiles_ask_for_no_first_pen(tmp_path):
    """A profile with one [pen]: the pen in the holder is the one; each further layer is a change, in file order."""
    m = load_machine("doodlebot")
    res, m0, pauses = _four(tmp_path, m)
    assert res.job.layers == ("outline", "roses", "leaves", "shadow") and res.job.pen_pauses == res.job.pen_changes
    assert len(m0) == len(pauses) == 3 and pauses[0][0] > 0 and res.summary()["first_pen_prompt"] is None


def test_a_studio_edit_keeps_the_strokes_layer_and_pen(machine):
    """A stroke edited in the studio stays on its layer and is re-planned within its own pen's caps: the red
    circle is the brush's (40 mm/s), though re-planned alone its layer would take the first spare pen."""
    from doodlecam.studio.session import Session

    session = Session(Settings(machine=machine))
    session.load("layers.svg", LAYERS_SVG.read_bytes(), background=False)
    job = session.job
    k = next(i for i, st in enumerate(job.strokes) if st.layer == "red" and len(st.spline.control) > 4)
    assert job.pen_numbers[k] == 2
    control = np.array(job.strokes[k].spline.control)
    control[2] += 0.2
    session.edit("move", k, control=control.tolist())
    new = session.job
    assert new.strokes[k].layer == "red" and new.pen_numbers == job.pen_numbers and new.pen_changes == job.pen_changes
    speed = np.linalg.norm(new.samples[k].velocity, axis=1).max()
    assert 30.0 < speed <= 40.0 * (1 + 1e-9)
    session.summary()
    session.edit("reverse", k)  # its travels made again: the totals carried over equal a fresh job's
    from doodlecam.model import Job

    new = session.job
    fresh = Job(new.machine, new.strokes, new.travels, new.samples, new.source, dict(new.meta))
    assert new.pen_delays == pytest.approx(fresh.pen_delays) and new.duration == pytest.approx(fresh.duration, rel=1e-12)
