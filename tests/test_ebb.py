"""The EBB post: its .ebb stream executed as the EiBotBoard does (tests/ebb_reader.py, written from the
command reference) keeps every motor's limits, the pen-speed cap and the path, ends every stroke on its
last step and stays on the paper; the LM arithmetic agrees with Evil Mad Scientist's plotink."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest

from ebb_reader import execute

ROOT = Path(__file__).resolve().parents[1]
INPUTS = [("samples/vectors/badge.svg", "axidraw-v3"), ("samples/vectors/layers.svg", "axidraw-v3"),
          ("samples/images/text.png", "axidraw-v3"), ("samples/images/camera.png", "axidraw-v3"),
          ("samples/images/horse.png", "axidraw-se-a3")]


def _convert(src: str, machine: str, out: Path):
    from doodlecam import pipeline
    from doodlecam.machine import load_machine

    m = load_machine(machine)
    r = pipeline.convert(ROOT / src, out, pipeline.Settings(machine=m, posts=("ebb",)))
    return r.job, r.outputs[0].read_text()


@pytest.fixture(scope="module", params=INPUTS, ids=lambda p: f"{Path(p[0]).name}-{p[1]}")
def converted(request, tmp_path_factory):
    return _convert(*request.param, tmp_path_factory.mktemp("ebb"))


def _motor(job, xy):
    """Motor steps of work-area points, as the AxiDraw documentation defines them (motor 1 = x + y,
    motor 2 = x - y on the page, y down from the home corner, 80 steps per mm)."""
    p = np.atleast_2d(xy)
    x, y = p[:, 0], job.machine.height - p[:, 1]
    return np.column_stack([x + y, x - y]) * 80.0


def test_executed_motion_keeps_limits_path_and_paper(converted):
    check_executed(*converted)


def check_executed(job, text):
    """The .ebb stream run as the board runs it keeps the profile's limits, the path, the plan's instants and
    the paper, and ends every stroke exactly."""
    m = job.machine
    kin = m.kinematics_params
    k, dt = 80.0, m.delta_time
    lines = text.splitlines()
    runs = list(execute(lines))
    assert runs, "no motion"
    draw = [r for r in runs if r.pen_down and r.line.startswith("LM")]
    travel = [r for r in runs if not r.pen_down and r.line.startswith("LM")]
    # motors: velocity (every tick) and acceleration (every LM) within the profile's limits
    vmax = np.array(kin["max_velocity"]) * k
    amax = np.array(kin["max_acceleration"]) * k
    to_pen = np.array([[0.5, 0.5], [0.5, -0.5]])  # motor steps -> pen steps (x, y on the page)
    for r in draw:
        assert (np.abs(r.rate).max(axis=0) <= vmax * (1 + 1e-9)).all(), r.line
        assert (np.abs(r.accel) <= amax * (1 + 1e-6)).all(), r.line
        # the pen's acceleration (the maker's limit is on the path) in every direction
        assert np.linalg.norm(np.array(r.accel) @ to_pen) / k <= kin["pen_acceleration"] * (1 + 1e-6), r.line
    # pen speed: the planner's cap; whole steps shift a period's rates by at most 1 step / dT per motor,
    # which moves the pen by at most 1 / (k dT) mm/s = 0.31 mm/s (a split piece tau: 1 / (k tau); docs/ebb.md)
    margin = 1.0 / (k * dt)
    for r in draw:
        pen_speed = np.linalg.norm(r.rate @ to_pen, axis=1).max() / k
        tau = len(r.rate) * 40e-6  # merged periods keep a period's bound; a split piece 1 step over its length
        assert pen_speed <= m.pen.max_speed + 1.0 / (k * min(tau, dt)) + 1e-9, r.line
    # pen-up travel: the profile's pen-up speed and acceleration along the path, motors below 25 kHz
    for r in travel:
        sp = np.linalg.norm(r.rate @ to_pen, axis=1).max() / k
        assert sp <= m.travel_speed * (1 + 1e-6) + 1.0 / (k * len(r.rate) * 40e-6), r.line
        acc = np.linalg.norm(np.array(r.accel) @ to_pen) / k
        assert acc <= m.x.max_acceleration * (1 + 1e-6) + margin / dt, r.line
        assert np.abs(r.rate).max() < 25000
    # nothing outside the paper (the AxiDraw's travel), anywhere
    allpos = np.vstack([r.pos for r in runs])
    x = (allpos[:, 0] + allpos[:, 1]) / 2 / k
    y = (allpos[:, 0] - allpos[:, 1]) / 2 / k
    assert x.min() >= -1e-9 and y.min() >= -1e-9 and x.max() <= m.width + 1e-9 and y.max() <= m.height + 1e-9
    # strokes: pen-down runs between an SP,0 and an SP,1
    strokes, cur = [], []
    for r in runs:
        if r.pen_down and r.line.startswith(("LM", "SM")):
            cur.append(r)
        elif cur and not r.pen_down:
            strokes.append(cur)
            cur = []
    groups = [[0]]
    for i, lift in enumerate(job.lifts[1:], 1):  # strokes joined without a lift share one pen-down run
        (groups.append([i]) if lift else groups[-1].append(i))
    assert len(strokes) == len(groups)
    for run, members in zip(strokes, groups):
        pos = np.vstack([run[0].pos[:1]] + [r.pos[1:] for r in run])
        # every stroke ends exactly on its last point, on the machine's step grid (x and y in whole steps)
        end = np.round(_motor(job, np.round(job.strokes[members[-1]].spline.end * k) / k)[0])
        assert (pos[-1] == end).all()
        # the pen within the path tolerance of the curves at every tick (and at the move ends: half a step
        # from the planned instants, below)
        curve = np.vstack([_motor(job, job.strokes[s].spline(np.linspace(0, 1, max(4000, int(job.strokes[s].spline.length
                                                                                          / 0.01)))))
                           for s in members])  # points 0.01 mm apart: the nearest is within 0.005 mm of the curve
        from scipy.spatial import cKDTree

        d, _ = cKDTree(curve / k).query(pos / k)  # motor mm; pen mm = motor mm / sqrt(2) at most... exact:
        pen_d = d / np.sqrt(2)  # |pen| = |motor| / sqrt 2 (the map is sqrt 2 times a rotation)
        assert pen_d.max() <= m.path_tolerance + 1.5 / k, pen_d.max()
        # at every sample instant (t = j dT into the run) the motors are within half a step of the plan
        planned, off = [], 0
        for s_ in members:
            P = _motor(job, job.samples[s_].integrate())
            planned += [(off + j, P[j]) for j in range(1, len(P))]
            off += len(P) - 1
        per = round(dt / 40e-6)
        for j, P in planned:  # the board's step counters at the instant's tick (an LM may span several)
            tick = min(j * per, len(pos) - 1)
            assert np.abs(pos[tick] - P).max() <= 0.5 + 1e-6, (j, pos[tick], P)


def test_commands_per_second_of_drawing(converted):
    """About one LM per sample period: a period is split where a motor turns back inside it by more
    than a step, and periods whose ramps one LM reproduces are merged (README: 24-26 per second)."""
    job, text = converted
    head = dict(l[2:].split(": ", 1) for l in text.splitlines() if l.startswith("; ") and ": " in l)
    periods = sum(len(s.velocity) for s in job.samples)
    assert abs(float(head["draw_time"]) - periods * job.machine.delta_time) < 1e-3 * periods
    assert int(head["draw_commands"]) / float(head["draw_time"]) <= 1.1 / job.machine.delta_time


def test_planned_time_is_the_executed_time(converted):
    job, text = converted
    lines = text.splitlines()
    runs = list(execute(lines))
    head = dict(l[2:].split(": ", 1) for l in lines if l.startswith("; ") and ": " in l)
    pen = sum(int(l.split(",")[2]) / 1000 for l in lines if l.startswith("SP,"))
    executed = sum(len(r.rate) for r in runs) * 40e-6 + pen
    assert executed == pytest.approx(float(head["planned_time"]), abs=2e-3)


def test_lm_arithmetic_matches_plotink():
    """doodlecam's exact LM (board.axis_move) against plotink's ebb_calc.calculate_lm (firmware 3.0), moves whose
    rate passes through zero (the motor turns back mid-move, Steps counting out and back) included; with
    turn=False (firmware 2.7/2.8) the moves that keep their rate's sign agree too."""
    from plotink import ebb_calc

    from doodlecam.link.ebb.board import axis_move, trunc_half

    rnd = random.Random(7)
    checked = turned = 0
    for _ in range(1500):
        steps = rnd.choice([1, 2, 7, 40, 300, 2000]) * rnd.choice([1, -1])
        rate = max(rnd.randint(1, 2 ** 31 - 1) // rnd.choice([1, 10, 1000, 10 ** 5]), 1)
        accel = rnd.randint(-3000, 3000) * rnd.choice([0, 1, 10, 100])
        t_ref, pos_ref, acc_ref = ebb_calc.calculate_lm(steps, rate, accel, "clear")
        r0 = rate - trunc_half(accel)
        if t_ref == 0 or max(abs(r0 + accel), abs(r0 + accel * t_ref)) >= 2 ** 31:
            continue  # more than one step per tick: outside what the board runs
        ticks, pos, acc = axis_move(rate, steps, accel)
        assert (ticks, pos, acc) == (t_ref, pos_ref, acc_ref), (rate, steps, accel)
        back = (r0 + accel > 0) != (r0 + accel * t_ref > 0)
        turned += back and abs(pos) < abs(steps)  # turned back by at least a step
        if r0 + accel > 0 and r0 + accel * t_ref > 0:  # the rate stays positive: the direction Steps gives
            assert axis_move(rate, steps, accel, turn=False) == (t_ref, pos_ref, acc_ref)
        checked += 1
    assert checked > 1000 and turned > 40, (checked, turned)


def test_turn_params_turn_a_motor_back_inside_one_lm():
    """stream.turn_params: a ramp through zero as one LM, net steps exact, the steps out and back counted, the
    acceleration never above the plan's; its last step on the period's last tick, or (the other axis setting
    the LM's length) ending where the plan does, the rates within a step per period of the plan's."""
    from doodlecam.link.ebb.board import ACC, TICK_HZ, axis_move, trunc_half
    from doodlecam.link.ebb.stream import turn_params

    rnd = random.Random(5)
    made = back = free = 0
    for _ in range(300):
        vs = rnd.uniform(50, 3000) * rnd.choice([1, -1])
        ve = -np.sign(vs) * rnd.uniform(50, 3000)
        T = rnd.choice([250, 1000, 2000])
        planned = (vs + ve) / 2 * T / TICK_HZ  # steps, from a start on a whole step
        n = int(round(planned))
        for frac in (None, planned - n):
            p = turn_params(n, vs, ve, T, frac)
            if p is None:
                continue
            made += 1
            ticks, pos, _ = axis_move(*p)
            assert pos == n and (ticks == T if frac is None else ticks <= T)
            assert abs(p[1]) >= abs(n)  # out and back (a turn inside one step cell takes no step back)
            back += abs(p[1]) > abs(n)
            assert abs(p[2]) <= abs(ve - vs) * ACC / TICK_HZ / T
            if frac is not None:
                free += 1
                sign = -1 if p[1] < 0 else 1
                r0 = p[0] - trunc_half(p[2])
                ends = sign * np.array([r0 + p[2], r0 + p[2] * T]) * TICK_HZ / ACC
                assert (np.abs(ends - [vs, ve]) * T / TICK_HZ <= 1.0).all(), (ends, vs, ve)
    assert made > 500 and back > 400 and free > 250, (made, back, free)


def _circles(path: Path, n: int = 40) -> Path:
    """Small circles (r 3-7 mm once fitted to the work area): on each, both motors (x + y, x - y) turn back
    twice per turn of the pen."""
    rings = "".join(f'<circle cx="{6 + 12 * (i % 10)}" cy="{6 + 12 * (i // 10)}" r="{1.2 + 0.04 * i}" fill="none" '
                    'stroke="black"/>' for i in range(n))
    path.write_text(f'<svg xmlns="http://www.w3.org/2000/svg" width="120mm" height="60mm" viewBox="0 0 120 48">{rings}</svg>')
    return path


def test_turning_motors_cost_no_extra_commands(tmp_path):
    """On circles a motor reverses in about one period in four. Firmware 3.0's LM turns it back inside the
    period's one LM: at most one command per period in every stroke (<= 1 / delta_time per second of drawing),
    and the stream, run as the board runs it, still keeps every limit, the path and the plan's instants
    (check_executed). firmware=2.7 splits those periods: more commands than periods, the same checks pass."""
    from doodlecam import pipeline
    from doodlecam.machine import load_machine

    from ebb_reader import execute

    src = _circles(tmp_path / "circles.svg")
    m = load_machine("axidraw-v3")
    out = {}
    for fw in ("3.0", "2.7"):
        r = pipeline.convert(src, tmp_path / fw, pipeline.Settings(machine=m, posts=("ebb",),
                                                                   post_options={"ebb": {"firmware": fw}}))
        out[fw] = (r.job, r.outputs[0].read_text())
    job, text = out["3.0"]
    periods = sum(len(s.velocity) for s in job.samples)
    vel = [np.vstack([np.zeros((1, 2)), s.velocity]) @ np.array([[1.0, -1.0], [1.0, 1.0]]).T for s in job.samples]
    reversing = sum(int(((v[1:] * v[:-1]) < 0).any(axis=1).sum()) for v in vel)
    assert reversing > 0.15 * periods, (reversing, periods)
    head = {fw: dict(l[2:].split(": ", 1) for l in t.splitlines() if l.startswith("; ") and ": " in l)
            for fw, (_, t) in out.items()}
    assert head["3.0"]["firmware"].startswith("3.0.0") and head["2.7"]["firmware"].startswith("2.7.0")
    # per stroke (a pen-down run between SP,0 and SP,1): its LMs and waits against its periods
    runs, cur = [], None
    for line in text.splitlines():
        if line.startswith("SP,0"):
            cur = 0
        elif line.startswith("SP,1") and cur is not None:
            runs.append(cur)
            cur = None
        elif cur is not None and line.startswith(("LM", "SM")):
            cur += 1
    assert runs == [n for n in runs] and len(runs) == len(job.samples)
    assert all(n <= len(s.velocity) for n, s in zip(runs, job.samples)), list(zip(runs, [len(s.velocity) for s in job.samples]))
    assert int(head["3.0"]["draw_commands"]) / float(head["3.0"]["draw_time"]) <= 1 / m.delta_time
    # the LMs really turn motors back (a rate through zero inside one command)
    turned = sum(1 for r in execute(text.splitlines()) if r.pen_down and len(r.rate)
                 and ((r.rate.max(axis=0) > 0) & (r.rate.min(axis=0) < 0)).any())
    assert turned > 0.1 * periods
    assert int(head["2.7"]["draw_commands"]) > int(head["3.0"]["draw_commands"]) + turned // 2
    for fw in ("3.0", "2.7"):
        check_executed(*out[fw])
        assert head[fw]["draw_time"] == head["3.0"]["draw_time"]


def test_axidraw_kinematics_map_and_profiles():
    from doodlecam import registry
    from doodlecam.machine import load_machine

    for name, (w, h) in {"axidraw-v3": (300, 218), "axidraw-se-a3": (430, 297)}.items():
        m = load_machine(name)
        kin = registry.kinematics_for(m)
        assert (m.width, m.height) == (w, h)
        # a move right turns both motors forward; a move away from home (down the page) turns motor 1
        # forward and motor 2 back (plotink: motor_dist1 = dx + dy, motor_dist2 = dx - dy)
        assert kin.inverse(np.array([[1.0, 0.0]]))[:, :2].tolist() == [[1.0, 1.0]]
        assert kin.inverse(np.array([[0.0, -1.0]]))[:, :2].tolist() == [[1.0, -1.0]]
        v, a = kin.actuator_limits()
        assert (v[:2] < 312.5).all() and (a > 0).all()
        # the pen's rows: acceleration along every 22.5 degrees within 762 cos 11.25 (a 16-gon in the
        # circle: every pen acceleration they admit is <= 762, and every one <= 762 cos 11.25 passes)
        rows = kin.linear_map[2:]
        assert rows.shape == (8, 2) and np.allclose(a[2:], 762 * np.cos(np.pi / 16))
        ang = np.linspace(0, 2 * np.pi, 3601)
        dirs = np.column_stack([np.cos(ang), np.sin(ang)])
        reach = 1 / np.abs(dirs @ rows.T).max(axis=1) * a[2]  # the largest admitted acceleration per direction
        assert reach.max() <= 762 * (1 + 1e-9) and reach.min() >= 762 * np.cos(np.pi / 16) * (1 - 1e-9)


def test_lift_clear_overlaps_the_lift_with_travel(tmp_path):
    """post ebb lift_clear: after each lift SP,1 waits only that long (the travel starts while the servo
    finishes rising); the plan saves the difference per lift and the motion is the same."""
    from doodlecam import pipeline
    from doodlecam.machine import load_machine

    m = load_machine("axidraw-v3")
    src = ROOT / "samples/vectors/layers.svg"
    texts = []
    for opts in ({}, {"lift_clear": 0.05}):
        r = pipeline.convert(src, tmp_path / str(len(texts)), pipeline.Settings(machine=m, posts=("ebb",),
                                                                               post_options={"ebb": opts}))
        texts.append(r.outputs[0].read_text().splitlines())
    head = [dict(l[2:].split(": ", 1) for l in t if l.startswith("; ") and ": " in l) for t in texts]
    ups = [[l for l in t if l.startswith("SP,1")] for t in texts]
    assert set(ups[0]) == {"SP,1,130"} and ups[1][0] == "SP,1,130" and set(ups[1][1:]) == {"SP,1,50"}
    saved = float(head[0]["planned_time"]) - float(head[1]["planned_time"])
    assert saved == pytest.approx(0.08 * (len(ups[1]) - 1), abs=1e-6)
    assert [l for l in texts[0] if not l.startswith(("SP", ";"))] == [l for l in texts[1] if not l.startswith(("SP", ";"))]
    from doodlecam.errors import OutputError

    with pytest.raises(OutputError, match="lift_clear must be 0..60 s"):
        pipeline.convert(src, tmp_path / "bad", pipeline.Settings(machine=m, posts=("ebb",),
                                                                  post_options={"ebb": {"lift_clear": -0.1}}))
    assert not (tmp_path / "bad").exists() or not any((tmp_path / "bad").iterdir())
    pen_down_after = [r.pen_down for r in execute(texts[1]) if r.line.startswith("LM")]
    assert pen_down_after.count(True) == [r.pen_down for r in execute(texts[0]) if r.line.startswith("LM")].count(True)


def test_the_sampler_adds_the_fewest_periods_it_needs(tmp_path, monkeypatch):
    """Where whole-period ramps cannot follow a stroke's plan in ceil(T / dT) periods the sampler adds
    periods; it bisects back from its 5 % steps, so on a stroke of fewer than 100 periods the one-fewer
    count has been tried (and failed): the stroke is not slower than the sampler can make it."""
    import doodlecam.plan.sample as sample
    from doodlecam import pipeline
    from doodlecam.machine import load_machine

    tried = set()
    qp = sample._qp

    def spy(p, *args, **kw):
        tried.add(len(p))  # one row per period
        return qp(p, *args, **kw)

    monkeypatch.setattr(sample, "_qp", spy)
    m = load_machine("axidraw-v3")
    job = pipeline.convert(ROOT / "samples/images/text.png", tmp_path, pipeline.Settings(machine=m, posts=("ebb",))).job
    dt = m.delta_time
    added = [(int(np.ceil(s.profile.duration / dt - 1e-9)), len(smp.velocity)) for s, smp in zip(job.strokes, job.samples)]
    added = [(m0, n) for m0, n in added if n > max(m0, 2) and m0 < 100]
    assert any(n - m0 >= 2 for m0, n in added), added  # strokes that needed more than one extra period
    for m0, n in added:
        assert n - 1 in tried, (m0, n)
