"""What the machine executes keeps every limit (issue 14).

The ``.plc`` file is read here by a reader written from docs/formats.md alone
(``struct``, not doodlecam's packetfile module) and executed as the PLC does
(docs/sampling.md, report 2.1.0.5): each axis ramps its velocity linearly from
one whole-steps/s DRAW target to the next over ``delta_time``, from rest after
a MOVE. Against the machine profile and the file's own header:

* per axis, |target| <= max_velocity and |change| / delta_time <= max_acceleration
  (and <= the header's max_accel): the ramps are linear, so the largest velocity
  on a period is at one of its ends and the acceleration is constant on it;
* pen speed <= [pen] max_speed: the velocity is linear in time on a period, so
  its norm is convex there and largest at an end;
* at every instant, the pen within half a step (per axis) of the curve point
  aimed at; between instants, within the path tolerance of the curve;
* five-bar: the cranks, through the inverse kinematics, along the ramps at 32
  points per period.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from doodlecam.machine import load_machine
from doodlecam.model import Drawing, StrokeSamples
from doodlecam.pipeline import Settings, convert, plan_job, run_posts
from doodlecam.plan.follow import path_deviation
from doodlecam.registry import kinematics_for

IMAGES = Path(__file__).resolve().parent.parent / "samples" / "images"
RATIO = 1 + 1e-9


def read_plc_file(data: bytes):
    """(header dict, list of strokes): each stroke a start (steps) and its DRAW
    targets (steps/s), straight from the byte layout of docs/formats.md
    (version 1, or version 2 with draw_accel and PAUSE commands)."""
    assert data[:8] == b"\x89DCPLC\r\n"
    version, record_size, n, dt, sx, sy, ax, ay, mx, my = struct.unpack_from("<HHIdddiiii", data, 8)
    size = {1: 56, 2: 64}[version]
    assert record_size == 16 and len(data) == size + 16 * n + 4
    assert struct.unpack_from("<I", data, size + 16 * n)[0] == zlib.crc32(data[:size + 16 * n])
    header = dict(delta_time=dt, steps_per_mm=np.array([sx, sy]), max_accel=np.array([ax, ay], float),
                  move_speed=np.array([mx, my], float), pauses=[])
    if version == 2:
        header["draw_accel"] = np.array(struct.unpack_from("<ii", data, 56), float)
    strokes, cur = [], None
    for i in range(n):
        no, kind, _, x, y = struct.unpack_from("<IHHii", data, size + 16 * i)
        assert no == i + 1
        if kind == 1:  # MOVE: absolute position in steps, pen up
            cur = {"start": np.array([x, y], float), "v": []}
            strokes.append(cur)
        elif kind == 2:  # PAUSE (version 2): pen change to pen x, before the next stroke
            assert version == 2 and y == 0 and x >= 1
            header["pauses"].append((len(strokes), x))  # (strokes before it, pen number)
        else:  # DRAW: velocity target in steps/s, pen down
            assert kind == 0
            cur["v"].append((x, y))
    return header, [(s["start"], np.array(s["v"], float)) for s in strokes if s["v"]]


def execute(start, targets, dt):
    """Positions (steps) at every instant and velocities (steps/s) at every
    instant, t = 0, dT, ..., of the PLC's linear ramps from rest."""
    v = np.vstack([np.zeros((1, 2)), targets])
    x = start + np.vstack([np.zeros((1, 2)), np.cumsum(0.5 * dt * (v[1:] + v[:-1]), axis=0)])
    return x, v


def executed_ratios(data: bytes, job, path_tol: float):
    """Worst executed ratios of a written PLC file against the job's machine."""
    m = job.machine
    header, runs = read_plc_file(data)
    dt, k = header["delta_time"], header["steps_per_mm"]
    # A run of DRAWs holds the strokes the pen draws without lifting (job.lifts): the
    # machine goes on from where the last one left it, so integrate the whole run.
    assert len(runs) == sum(job.lifts)
    strokes, it = [], iter(job.samples)
    for start, targets in runs:
        x0, at = start, 0
        while at < len(targets):
            n = len(next(it).velocity)
            part = targets[at:at + n]
            strokes.append((x0, part))
            x0 = execute(x0, part, dt)[0][-1]
            at += n
    assert len(strokes) == len(job.strokes)
    vmax = np.array([m.x.max_velocity, m.y.max_velocity]) * k
    amax = np.array([m.x.max_acceleration, m.y.max_acceleration]) * k
    nonlinear = m.kinematics != "cartesian"
    kin = kinematics_for(m) if nonlinear else None
    out = dict(acc=0.0, vel=0.0, header_acc=0.0, pen=0.0, instant_steps=0.0, between_mm=0.0, crank_acc=0.0,
               crank_vel=0.0)
    for (start, targets), stroke, smp in zip(strokes, job.strokes, job.samples):
        x, v = execute(start, targets, dt)
        acc = np.abs(np.diff(v, axis=0)) / dt
        if not nonlinear:  # the five-bar's axes limits are for pen-up MOVEs only
            out["acc"] = max(out["acc"], float((acc / amax).max()))
            out["vel"] = max(out["vel"], float((np.abs(v) / vmax).max()))
            out["header_acc"] = max(out["header_acc"], float((acc / header["max_accel"]).max()))
        # version 2's draw_accel: what the DRAW ramps ask of the drives, on every machine
        out["draw_header_acc"] = max(out.get("draw_header_acc", 0.0), float((acc / header["draw_accel"]).max()))
        if m.pen.max_speed:
            out["pen"] = max(out["pen"], float(np.linalg.norm(v / k, axis=1).max() / m.pen.max_speed))
        aim = stroke.spline(smp.sample_u) * k
        out["instant_steps"] = max(out["instant_steps"], float(np.abs(x - aim).max()))
        executed = StrokeSamples(start=start / k, velocity=targets / k, delta_time=dt, sample_u=smp.sample_u)
        if path_tol > 0:
            out["between_mm"] = max(out["between_mm"], float(path_deviation(stroke.spline, executed).max()))
        if nonlinear:
            sub = 32
            tau = np.linspace(0.0, dt, sub + 1)[None, :, None]
            vmm, xmm = v / k, x / k
            a = (vmm[1:] - vmm[:-1])[:, None, :] / dt
            pos = xmm[:-1, None, :] + vmm[:-1, None, :] * tau + a * tau ** 2 / 2
            vel = vmm[:-1, None, :] + a * tau
            _, w, wd = kin.derivatives(pos.reshape(-1, 2), vel.reshape(-1, 2), np.broadcast_to(a, pos.shape).reshape(-1, 2))
            cv, ca = kin.actuator_limits()
            out["crank_vel"] = max(out["crank_vel"], float((np.abs(w) / cv).max()))
            out["crank_acc"] = max(out["crank_acc"], float((np.abs(wd) / ca).max()))
    return out


def _check(r, path_tol):
    for key in ("acc", "vel", "header_acc", "draw_header_acc", "pen", "crank_acc", "crank_vel"):
        assert r[key] <= RATIO, (key, r)
    assert r["instant_steps"] <= 0.5 + 1e-9, r  # the ends: the nearest whole step
    if path_tol > 0:
        assert r["between_mm"] <= path_tol + 1e-9, r


def _plc(job):
    from doodlecam.pipeline import Settings as S

    (_, _, data), = run_posts(job, S(machine=job.machine, posts=("plc",)))
    return data


@pytest.mark.parametrize("picture", ["horse.png", "text.png"])
def test_cartesian_picture_with_a_pen_cap_keeps_every_limit(tmp_path, picture):
    machine = load_machine("doodlebot")
    machine = replace(machine, pen=replace(machine.pen, max_speed=100.0))
    res = convert(IMAGES / picture, tmp_path, Settings(machine=machine, posts=("plc",)))
    data = (tmp_path / (Path(picture).stem + ".plc")).read_bytes()
    r = executed_ratios(data, res.job, machine.path_tolerance)
    _check(r, machine.path_tolerance)
    assert r["pen"] > 0.9  # the cap binds somewhere: the check had work to do


def _circle(c, r, n=200):
    t = np.linspace(0, 2 * np.pi, n)
    return np.column_stack([c[0] + r * np.cos(t), c[1] + r * np.sin(t)])


def fivebar_drawings():
    cross = (np.array([[40.0, 40.0], [240.0, 140.0]]), np.array([[40.0, 140.0], [240.0, 40.0]]))
    zig = np.column_stack([np.linspace(30, 250, 23), 90 + 40 * (np.arange(23) % 2)])  # like text strokes
    letters = (np.array([[60, 40], [80, 120], [100, 40]], float), np.array([[70, 80], [90, 80]], float),
               np.array([[120, 40], [120, 120], [150, 110], [150, 90], [120, 80], [155, 65], [150, 45], [120, 40]], float),
               _circle((200, 80), 30, 60)[:50])
    # (the random walk below also converts on the five-bar within every limit, in ~30 s: left to the Cartesian test)
    return {"circle": (_circle((140, 90), 70),), "cross": cross, "zigzag": (zig,), "text": letters}


def _walk():
    """A 300-point random walk inside both machines' sheets: one long stroke the
    sampler solves as a whole, so local re-plans alone kept moving where it strays."""
    rng = np.random.default_rng(1)
    rng.uniform(size=(20, 2))
    return np.clip(140 + np.cumsum(rng.normal(0, 2, (300, 2)), axis=0) * [1, 0.6], [5, 5], [275, 175])


def test_cartesian_random_walk_stays_within_the_path_tolerance():
    machine = load_machine("doodlebot")
    job = plan_job(Drawing(polylines=(_walk(),), units="mm"), machine)
    r = executed_ratios(_plc(job), job, machine.path_tolerance)
    _check(r, machine.path_tolerance)


@pytest.mark.parametrize("name", sorted(fivebar_drawings()))
def test_fivebar_drawing_keeps_every_crank_limit(name):
    machine = load_machine("fivebar")
    job = plan_job(Drawing(polylines=fivebar_drawings()[name], units="mm"), machine)
    r = executed_ratios(_plc(job), job, machine.path_tolerance)
    _check(r, machine.path_tolerance)


def test_degree_2_keeps_every_limit(tmp_path):
    machine = load_machine("doodlebot")
    machine = replace(machine, degree=2)
    res = convert(IMAGES / "horse.png", tmp_path, Settings(machine=machine, posts=("plc",)))
    r = executed_ratios((tmp_path / "horse.plc").read_bytes(), res.job, machine.path_tolerance)
    _check(r, machine.path_tolerance)
    assert res.job.meta["worst_acceleration_ratio"] <= RATIO


@pytest.mark.parametrize("picture", ["text.png", "coins.png"])
def test_fivebar_converts_sample_pictures_at_40_ms_within_every_limit(tmp_path, picture):
    machine = load_machine("fivebar")
    assert machine.delta_time == 0.04
    res = convert(IMAGES / picture, tmp_path, Settings(machine=machine, posts=("plc",)))
    r = executed_ratios((tmp_path / (Path(picture).stem + ".plc")).read_bytes(), res.job, machine.path_tolerance)
    _check(r, machine.path_tolerance)
    assert r["crank_acc"] > 0.85  # the cranks' limits bind: the check had work to do (coins: 0.875)
