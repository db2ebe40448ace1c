"""MOTDES-style designs from TOML: segments, matching, envelopes, meandering, machine limits."""

from pathlib import Path

import numpy as np
import pytest

from doodlecam.errors import DoodleError, InputError
from doodlecam.machine import load_machine, parse_machine
from doodlecam.motion import MotionError
from doodlecam.motion.design import check, load_design, parse_design, solve_design
from doodlecam.motion.export import table

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "samples" / "motion"
ORDERS = ("pos", "vel", "acc", "jerk")


def given_values_met(traj):
    """Largest miss of a given value, relative to that order's scale on its axis."""
    worst = 0.0
    for a in traj.axes:
        scale = [max(1.0, np.abs(a.evaluate(np.linspace(a.t0, a.t1, 4001))[k]).max()) for k in range(4)]
        for seg in a.segments:
            for p in a.points[seg.first_point - 1: seg.last_point]:
                f = seg.evaluate([p.t])[:, 0]
                for o, v in p.values.items():
                    worst = max(worst, abs(f[o] - v) / scale[o])
    return worst


def joint_jumps(traj, upto):
    worst = 0.0
    for a in traj.axes:
        for left, right in zip(a.segments, a.segments[1:]):
            fl, fr = left.evaluate([left.t1])[:, 0], right.evaluate([right.t0])[:, 0]
            scale = np.maximum(1.0, np.abs(np.concatenate([fl, fr])).max())
            worst = max(worst, np.abs(fl[: upto + 1] - fr[: upto + 1]).max() / scale)
    return worst


@pytest.fixture(scope="module")
def fuse():
    d = load_design(SAMPLES / "fuse.toml")
    return d, solve_design(d)


def test_fuse_sample_meets_table_5_1_and_is_continuous(fuse):
    d, traj = fuse
    assert [a.name for a in traj.axes] == ["x", "y"] and len(traj.axis("x").segments) == 9
    assert traj.t1 - traj.t0 == pytest.approx(0.666)
    assert given_values_met(traj) < 1e-9
    assert joint_jumps(traj, 2) < 1e-9  # position, velocity and acceleration continuous
    rep = check(traj)
    assert rep.ok, [str(f) for f in rep.findings]
    header, rows = table(traj)
    assert header[:5] == ["t", "x_pos", "x_vel", "x_acc", "x_jerk"] and rows.shape == (300, 9)
    assert rows[0, 0] == 0 and rows[-1, 0] == pytest.approx(0.666)


def test_actuator_limits_through_the_cartesian_kinematics(fuse):
    d, traj = fuse
    machine = load_machine("doodlebot")
    rep = check(traj, machine)
    assert {f.kind for f in rep.findings} == {"limit"}
    t = np.linspace(traj.t0, traj.t1, 200_001)
    for act, name in zip(rep.actuators, ("x", "y")):
        f = traj.axis(name).evaluate(t)
        axis = machine.x if name == "x" else machine.y
        assert act["peak_velocity"] == pytest.approx(np.abs(f[1]).max(), rel=1e-3)
        assert act["acceleration_ratio"] == pytest.approx(np.abs(f[2]).max() / axis.max_acceleration, rel=1e-3)
    # run it as slowly as the report says it must be run: then it fits, and only just
    slow = solve_design(d.scaled(rep.fastest_cycle))
    again = check(slow, machine)
    assert again.ok, [str(f) for f in again.findings]
    worst = max(max(a["velocity_ratio"], a["acceleration_ratio"]) for a in again.actuators)
    assert worst == pytest.approx(1.0, abs=1e-3)


def test_design_outside_the_workspace_is_an_error(fuse):
    d, _ = fuse
    from dataclasses import replace

    with pytest.raises(MotionError, match=r"at t = 0\.0\d+ s the design leaves the workspace of 'doodlebot'.*origin"):
        check(solve_design(replace(d, origin=(300.0, 100.0))), load_machine("doodlebot"))


def test_xy_and_time_input_give_the_same_trajectory(fuse):
    _, traj = fuse
    from doodlecam.motion.design import tomllib

    data = tomllib.loads((SAMPLES / "fuse.toml").read_text())
    axes = {}
    for name, cols in (("x", ("x", "vx", "ax")), ("y", ("y", "vy", "ay"))):
        pts = [{"t": r["t"], **{o: r[c] for o, c in zip(("pos", "vel", "acc"), cols) if c in r}} for r in data["point"]]
        axes[name] = {"point": pts, "segment": data["segment"]}
    other = solve_design(parse_design({"motion": {"input": "time"}, "axis": axes}, "fuse-time.toml"))
    t = np.linspace(0, 0.666, 997)
    for name in ("x", "y"):
        assert np.allclose(other.axis(name).evaluate(t), traj.axis(name).evaluate(t), rtol=1e-12, atol=1e-9)


def test_matched_conditions_table_3_7():
    d = load_design(SAMPLES / "powers.toml")
    traj = solve_design(d)
    plain = traj.axis("plain")
    # the thesis's counts: five conditions in segments 1 and 2 (acceleration matched, not given), six in 3
    assert [s.impl.degree for s in plain.segments] == [4, 4, 5]
    assert [len(s.impl.powers) for s in traj.axis("thesis").segments] == [5, 5, 6]
    assert given_values_met(traj) < 1e-9
    assert joint_jumps(traj, 2) < 1e-9
    rep = check(traj)
    bad = {(f.where.split(" (")[0], f.kind) for f in rep.findings}
    assert bad == {("axis plain segment 2", "envelope"), ("axis plain segment 2", "meander")}
    peak = {a.name: rep.peaks[a.name]["velocity"] for a in traj.axes}
    assert peak["optimised"] < peak["thesis"] < peak["plain"]


def test_meandering_slider_table_3_2():
    rep = check(solve_design(load_design(SAMPLES / "slider.toml")))
    found = {(f.where.split(" (")[0], f.kind) for f in rep.findings}
    assert found == {("axis table32 segment 1", "envelope"), ("axis table32 segment 1", "meander")}
    meander = next(f for f in rep.findings if f.kind == "meander")
    assert meander.t < 0.05  # it starts backwards at once (Fig. 3.8)


def design(points, segments=None, **head):
    data = {"motion": {"input": "time", **head}, "axis": {"x": {"point": points}}}
    if segments is not None:
        data["axis"]["x"]["segment"] = segments
    return parse_design(data, "d.toml")


def test_continuity_takes_over_what_a_point_leaves_open():
    # §3.5: the end values of one segment become the start conditions of the next, up to `continuity`
    pts = [{"t": 0, "pos": 0, "vel": 0, "acc": 0}, {"t": 1, "pos": 10, "vel": 4}, {"t": 2, "pos": 3},
           {"t": 3, "pos": 0, "vel": 0, "acc": 0}]
    for cont, degrees in ((2, [4, 3, 5]), (1, [4, 2, 4]), (0, [4, 2, 3])):
        traj = solve_design(design(pts, continuity=cont))
        assert [s.impl.degree for s in traj.axis("x").segments] == degrees
        assert given_values_met(traj) < 1e-9
        assert joint_jumps(traj, cont) < 1e-9
        if cont < 2:  # what is not carried over jumps
            assert joint_jumps(traj, cont + 1) > 1e-3
            assert "discontinuity" not in {f.kind for f in check(traj).findings}  # as asked


def test_cam_law_segments_join_polynomials_smoothly():
    pts = [{"t": 0, "pos": 0, "vel": 0, "acc": 0}, {"t": 0.3, "pos": 5}, {"t": 0.8, "pos": 25}, {"t": 1.0, "pos": 25},
           {"t": 1.5, "pos": 0, "vel": 0, "acc": 0}]
    segs = [{"law": "polynomial"}, {"law": "cycloidal"}, {"law": "dwell"}, {"law": "modified-sine", "b": 0.2}]
    traj = solve_design(design(pts, segs))
    # the polynomial ends at rest with zero acceleration because a cycloidal rise follows it
    f = traj.axis("x").segments[0].evaluate([0.3])[:, 0]
    assert abs(f[1]) < 1e-9 and abs(f[2]) < 1e-9
    assert joint_jumps(traj, 2) < 1e-9
    cyc = traj.axis("x").segments[1].evaluate(np.linspace(0.3, 0.8, 10001))
    assert np.abs(cyc[2]).max() == pytest.approx(2 * np.pi * 20 / 0.5**2, rel=1e-6)
    assert check(traj).ok


def test_cam_law_conflicts_and_discontinuities():
    with pytest.raises(MotionError, match=r"segment 1 .*point 2 asks vel = 3, but cycloidal gives 0"):
        solve_design(design([{"t": 0, "pos": 0}, {"t": 1, "pos": 1, "vel": 3}], [{"law": "cycloidal"}]))
    with pytest.raises(MotionError, match="a dwell holds its position"):
        solve_design(design([{"t": 0, "pos": 0}, {"t": 1, "pos": 1}], [{"law": "dwell"}]))
    with pytest.raises(MotionError, match="between its two end points only"):
        solve_design(design([{"t": 0, "pos": 0}, {"t": 0.5, "pos": 0.4, "via": True}, {"t": 1, "pos": 1}],
                            [{"law": "cycloidal"}]))
    traj = solve_design(design([{"t": 0, "pos": 0}, {"t": 1, "pos": 1}, {"t": 2, "pos": 2}],
                               [{"law": "constant-velocity"}, {"law": "cycloidal"}]))
    kinds = [(f.kind, f.message.split(" jumps")[0]) for f in check(traj).findings if f.kind == "discontinuity"]
    assert kinds == [("discontinuity", "vel")]
    low = check(solve_design(design([{"t": 0, "pos": 0}, {"t": 1, "pos": 1}], [{"law": "bang-bang"}])))
    assert [f.kind for f in low.findings] == ["smoothness"]


def test_cubic_spline_segment_through_via_points():
    pts = [{"t": 0, "pos": 0, "vel": 0}, {"t": 0.3, "pos": 2, "via": True}, {"t": 0.7, "pos": 5, "via": True},
           {"t": 1, "pos": 6, "vel": 0}]
    traj = solve_design(design(pts, [{"law": "cubic-spline"}]))
    assert given_values_met(traj) < 1e-12


def test_time_scaling_keeps_the_shape():
    pts = [{"t": 0, "pos": 0, "vel": 0, "acc": 0}, {"t": 1, "pos": 10, "vel": 5, "acc": -3}, {"t": 2, "pos": 0, "vel": 0, "acc": 0}]
    d = design(pts)
    a, b = solve_design(d), solve_design(d.scaled(8.0))
    s = np.linspace(0, 1, 101)
    fa, fb = a.axis("x").evaluate(2 * s), b.axis("x").evaluate(8 * s)
    for k in range(4):
        assert np.allclose(fb[k] * 4.0**k, fa[k], rtol=1e-9, atol=1e-9)
    c = solve_design(design(pts, cycle_time=8.0))  # the same through [motion] cycle_time
    assert np.allclose(c.axis("x").evaluate(8 * s), fb)
    with pytest.raises(MotionError, match="cycle time must be a positive, finite number"):
        design(pts, cycle_time=0.0)


@pytest.mark.parametrize("data,message", [
    ({"motion": {"input": "time"}, "axis": {"x": {"point": [{"t": 0, "pos": 0}, {"t": 0, "pos": 1}]}}},
     r"d.toml: axis x: point 2 at t = 0 s does not come after point 1 .*positive duration"),
    ({"motion": {"input": "time"}, "axis": {"x": {"point": [{"t": 0, "vel": 1}, {"t": 1, "vel": 0}]}}},
     r"d.toml: axis x segment 1 \(points 1-2, polynomial\): no position condition"),
    ({"motion": {"input": "time"}, "axis": {"x": {"point": [{"t": 0, "pos": 0, "acc": 1}, {"t": 1, "acc": 1}]}}},
     r"axis x segment 1 \(points 1-2, polynomial\): under-determined"),
    ({"motion": {"input": "time"}, "axis": {"x": {"point": [{"t": 0, "pos": 0, "acc": "match"}, {"t": 1, "pos": 1}]}}},
     r"point 1 asks to match acc, but no segment precedes it"),
    ({"motion": {"input": "time"}, "axis": {"x": {"point": [{"t": 0, "pos": 0, "velo": 1}, {"t": 1, "pos": 1}]}}},
     r"unknown key 'velo' .*did you mean 'vel'"),
    ({"motion": {"input": "time"}, "axis": {"x": {"point": [{"t": 0, "pos": 0}, {"t": 1, "pos": 1}],
                                                  "segment": [{"law": "polynomial"}, {"law": "dwell"}]}}},
     r"2 \[\[axis.x.segment\]\] rows for 1 segments"),
    ({"motion": {"input": "time"}, "axis": {"x": {"point": [{"t": 0, "pos": 0}, {"t": 1, "pos": 1}],
                                                  "segment": [{"law": "cycloid"}]}}},
     r"unknown motion law 'cycloid' \(did you mean 'cycloidal'\?\)"),
    ({"motion": {"continuity": 7}, "point": [{"t": 0, "x": 0, "y": 0}, {"t": 1, "x": 1, "y": 1}]},
     r"continuity = 7"),
    ({"point": [{"t": 0, "x": 0, "y": 0}, {"t": 1, "x": 1, "y": "fast"}]}, r"y = 'fast': give a number or \"match\""),
])
def test_design_errors_are_one_line_and_name_the_place(data, message):
    with pytest.raises(DoodleError, match=message) as e:
        solve_design(parse_design(data, "d.toml"))
    assert "\n" not in str(e.value)


def test_unreadable_design_files(tmp_path):
    with pytest.raises(InputError, match="no such design file"):
        load_design(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[motion\nname = 1")
    with pytest.raises(InputError, match="not valid TOML"):
        load_design(bad)


def test_machine_check_uses_the_machine_kinematics_plugin():
    # a plugin whose actuators are scaled pen axes: the check must go through its derivatives, not assume identity
    from doodlecam.api import Kinematics

    class Geared(Kinematics):
        name = "geared"
        linear_map = np.diag([2.0, 0.5])

        def actuator_limits(self):
            return np.array([100.0, 100.0]), np.array([1000.0, 1000.0])

    machine = parse_machine({
        "machine": {"name": "m"}, "work_area": {"width": 300.0, "height": 300.0},
        "axes": {a: {"steps_per_mm": 80.0, "max_velocity": 100.0, "max_acceleration": 1000.0} for a in "xy"},
    })
    d = parse_design({"motion": {}, "point": [{"t": 0, "x": 10, "y": 10, "vx": 0, "vy": 0, "ax": 0, "ay": 0},
                                              {"t": 1, "x": 40, "y": 40, "vx": 0, "vy": 0, "ax": 0, "ay": 0}]}, "g.toml")
    rep = check(solve_design(d), machine, Geared(machine, {}))
    vx = 1.875 * 30  # quintic peak velocity of a 30 mm rise in 1 s
    assert rep.actuators[0]["peak_velocity"] == pytest.approx(2 * vx, rel=1e-6)
    assert rep.actuators[1]["peak_velocity"] == pytest.approx(0.5 * vx, rel=1e-6)
    assert [f.where for f in rep.findings] == ["actuator x"]  # 112.5 > 100 on the geared-up actuator only
