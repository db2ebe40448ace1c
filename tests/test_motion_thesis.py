"""Kirecci's tables as designs: the tolerance envelope between successive design
points (Fig. 3.6, §4.2), eq. 3.10 for given powers, per-axis segment overrides."""

import numpy as np
import pytest

from doodlecam.motion import MotionError
from doodlecam.motion.design import check, parse_design, solve_design
from doodlecam.motion.envelope import check_segment


def axis_design(points, segments=None, **head):
    data = {"motion": {"input": "time", **head}, "axis": {"x": {"point": points}}}
    if segments is not None:
        data["axis"]["x"]["segment"] = segments
    return parse_design(data, "t.toml")


def through(xs, ys, **ends):
    """One segment from the first to the last point, the others via points."""
    pts = [{"t": float(x), "pos": float(y)} for x, y in zip(xs, ys)]
    for p in pts[1:-1]:
        p["via"] = True
    pts[0].update(ends)
    pts[-1].update(ends)
    return pts


def test_table_3_1_dummy_constraints_stay_in_their_envelopes():
    # 11 positions of the Runge function 1/(1+x²) plus ten dummy derivative constraints: 21 conditions, degree 20
    xs = np.arange(-5, 6)
    pos = [0.0384, 0.0588, 0.1, 0.2, 0.5, 1.0, 0.5, 0.2, 0.1, 0.0588, 0.0384]
    pts = through(xs, pos, vel=0.0, acc=0.0, jerk=0.0)
    pts[1].update(vel=0.05, acc=0.07)
    pts[9].update(vel=-0.05, acc=0.07)
    traj = solve_design(axis_design(pts))
    seg = traj.axis("x").segments[0]
    assert seg.impl.degree == 20 and len(seg.impl.conditions) == 21
    t = np.linspace(-5, 5, 20001)
    f = traj.axis("x").evaluate(t)
    assert np.abs(f[0] - 1 / (1 + t**2)).max() == pytest.approx(0.031, abs=5e-4)  # the thesis's max error
    # independently: every stretch between successive points stays in its rectangle
    for (x0, p0), (x1, p1) in zip(zip(xs, pos), zip(xs[1:], pos[1:])):
        inside = f[0][(t >= x0) & (t <= x1)]
        assert min(p0, p1) - 1e-9 <= inside.min() and inside.max() <= max(p0, p1) + 1e-9
    rep = check(traj)
    assert rep.ok, [str(x) for x in rep.findings]


def test_table_2_1_newton_cubic_has_no_false_finding():
    traj = solve_design(axis_design(through([0, 1, 2, 3], [12, 32, 8, 19])))
    t = np.linspace(0, 3, 301)
    # Newton's divided differences of Table 2.1: b = 12, 20, -22, 79/6 (the scan prints 13.1)
    newton = 12 + 20 * t - 22 * t * (t - 1) + 79 / 6 * t * (t - 1) * (t - 2)
    assert np.allclose(traj.axis("x").evaluate(t)[0], newton, atol=1e-9)
    rep = check(traj)
    assert rep.ok, [str(x) for x in rep.findings]  # it turns at 32 and at 8, as the points ask


def test_table_2_5_spline_has_no_false_finding():
    ys = [5.541, 4.074, 5.900, 0.611, 5.000, 9.388, 5.541]
    traj = solve_design(axis_design(through(range(1, 8), ys, acc=0.0), [{"law": "cubic-spline"}]))
    f = traj.axis("x").evaluate(np.arange(1.0, 8.0))
    assert np.allclose(f[0], ys) and abs(f[2][0]) < 1e-12 and abs(f[2][-1]) < 1e-12  # natural ends, as tabled
    rep = check(traj)
    assert rep.ok, [str(x) for x in rep.findings]


def test_table_2_4_spline_is_judged_between_successive_points():
    ys = [0, 1, 2, 2.1, 2.2, 3.5, 2.2, 2.1, 2, 1, 0]
    traj = solve_design(axis_design(through(range(11), ys, acc=0.0), [{"law": "cubic-spline"}]))
    rep = check(traj)
    # not the old false finding (the rectangle between the equal end positions 0 and 0)...
    env = [x for x in rep.findings if x.kind == "envelope"]
    assert env and all("[0, 0]" not in x.message for x in env)
    # ...but a real one: on the rising plateau 2.0, 2.1, 2.2 the spline runs backwards (velocity < 0 at x = 3)
    t = np.linspace(2, 4, 2001)
    f = traj.axis("x").evaluate(t)
    assert f[1].min() < -0.2 and f[0][(t > 3) & (t < 4)].min() < 2.1 - 0.1
    assert all(2 < x.t < 4 or 6 < x.t < 8 for x in rep.findings)
    assert {x.kind for x in rep.findings} == {"envelope", "meander"}


def test_envelope_and_turns_follow_the_design_points():
    t = np.linspace(0, 2, 2001)
    # rises through (0,0) (1,1) (2,2) but wobbles back twice on the way: meanders, stays in the rectangles
    pos = t + 0.25 * np.sin(2 * np.pi * t)
    vel = np.gradient(pos, t)
    knots = [(0.0, 0.0, None), (1.0, 1.0, None), (2.0, 2.0, None)]
    f = np.stack([pos, vel, vel, vel])
    found = check_segment(t, f, "s", knots=knots)
    assert [x.kind for x in found] == ["meander"]
    # a turn the points ask for (0 -> 1 -> 0) is not meandering; going past the turning point is allowed...
    pos = np.sin(np.pi * t / 2) * 1.1
    f = np.stack([pos, np.gradient(pos, t), pos, pos])
    assert check_segment(t, f, "s", knots=[(0.0, 0.0, None), (1.0, 1.0, None), (2.0, 0.0, None)]) == []
    # ...unless the point says the velocity is zero there: then the rectangle's top holds
    found = check_segment(t, f, "s", knots=[(0.0, 0.0, None), (1.0, 1.0, 0.0), (2.0, 0.0, None)])
    assert [x.kind for x in found] == ["envelope"] and "by 0.1" in found[0].message
    # the same curve judged against the end positions only would have been flagged: (0, 0) is a point
    assert [x.kind for x in check_segment(t, f, "s")] == ["envelope"]


ENDS = {"vel": 0.0, "acc": 0.0}


@pytest.mark.parametrize("powers,continuity,bad", [
    ([0, 1, 2, 2.1, 2.2, 2.3], 2, "2.1"),
    ([0, 1, 2, 3, 4, 2.5], 2, "2.5"),  # the rule is strict: q > m + 0.5
    ([0, 1, 2, 3.2, 3.4, 3.5], 3, "3.2"),
])
def test_eq_3_10_refuses_low_real_powers(powers, continuity, bad):
    d = axis_design([{"t": 0, "pos": 0, **ENDS}, {"t": 1, "pos": 10, **ENDS}], [{"powers": powers}],
                    continuity=continuity)
    with pytest.raises(MotionError, match=rf"power {bad} breaks eq. 3.10 .*m \+ 0.5 = {continuity + 0.5:g}") as e:
        solve_design(d)
    assert "\n" not in str(e.value)


def test_eq_3_10_accepts_what_it_allows():
    for powers, continuity in (([0, 1, 2, 2.52, 2.56, 2.7], 2), ([0, 1, 2, 2.1, 2.2, 2.3], 1),
                               ([0, 1, 2, 3, 4, 5], 3)):
        d = axis_design([{"t": 0, "pos": 0, **ENDS}, {"t": 1, "pos": 10, **ENDS}], [{"powers": powers}],
                        continuity=continuity)
        f = solve_design(d).axis("x").evaluate(np.linspace(0, 1, 11))
        assert f[0][-1] == pytest.approx(10)


def test_per_axis_segment_override():
    data = {"motion": {}, "point": [{"t": 0, "x": 0, "y": 0, "vx": 0, "vy": 0, "ax": 0, "ay": 0},
                                    {"t": 1, "x": 10, "y": 5, "vx": 0, "vy": 0, "ax": 0, "ay": 0}],
            "segment": [{"law": "polynomial", "powers": [0, 1, 2, 3, 4, 5], "y": {"law": "cycloidal"}}]}
    traj = solve_design(parse_design(data, "o.toml"))
    x, y = traj.axis("x").segments[0], traj.axis("y").segments[0]
    assert x.spec.law == "polynomial" and y.spec.law == "cycloidal" and y.spec.powers is None
    t = np.linspace(0, 1, 1001)
    assert np.abs(y.evaluate(t)[2]).max() == pytest.approx(2 * np.pi * 5, rel=1e-6)  # the cycloid's peak 2πh/T²
    data["segment"][0]["y"] = {"lw": "cycloidal"}
    with pytest.raises(MotionError, match=r"unknown key 'lw' in \[\[segment\]\] 1 \[segment.y\] \(did you mean 'law'"):
        parse_design(data, "o.toml")
    data["segment"][0]["y"] = "cycloidal"
    with pytest.raises(MotionError, match=r"\[segment.y\] must be a table"):
        parse_design(data, "o.toml")


def test_constant_velocity_joining_smoothly_is_not_flagged():
    # accelerate to 10 mm/s, run at it, slow to rest: every join continuous to acceleration
    pts = [{"t": 0, "pos": 0, "vel": 0, "acc": 0}, {"t": 1, "pos": 5, "vel": 10, "acc": 0},
           {"t": 2, "pos": 15, "vel": 10, "acc": 0}, {"t": 3, "pos": 20, "vel": 0, "acc": 0}]
    traj = solve_design(axis_design(pts, ["polynomial", "constant-velocity", "polynomial"]))
    rep = check(traj)
    assert rep.ok, [str(x) for x in rep.findings]
    # joined to rest it still jumps, and the joint check says so
    rough = check(solve_design(axis_design([pts[0], {"t": 1, "pos": 0}, {"t": 2, "pos": 10}, {"t": 3, "pos": 10}],
                                           ["dwell", "constant-velocity", "dwell"])))
    assert {x.kind for x in rough.findings} == {"discontinuity"}


def quintic_xy(**extra):
    data = {"motion": {}, "point": [{"t": 0, "x": 0, "y": 0, "vx": 0, "vy": 0, "ax": 0, "ay": 0},
                                    {"t": 1, "x": 30, "y": 40, "vx": 0, "vy": 0, "ax": 0, "ay": 0}]}
    for k, v in extra.items():
        if k == "motion":
            data["motion"].update(v)
        else:
            data[k] = v
    return data


def test_product_acceleration_limit_names_the_worst_point():
    # §4.5.3: a 50 mm straight quintic rise in 1 s peaks at 10√3·50/3 = 5.7735·50 mm/s² at t = 1/2 − √3/6
    peak, t_peak = 10 * np.sqrt(3) / 3 * 50, 0.5 - np.sqrt(3) / 6
    rep = check(solve_design(parse_design(quintic_xy(motion={"product_acceleration": 250.0}), "p.toml")))
    assert rep.product["peak"] == pytest.approx(peak, rel=1e-5)
    (f,) = rep.findings
    assert f.kind == "product" and min(abs(f.t - t_peak), abs(f.t - (1 - t_peak))) < 1e-3
    assert "segment 1 (points 1-2" in f.where and f"{peak:.4g} mm/s²" in f.message and "1.15x the 250" in f.message
    assert check(solve_design(parse_design(quintic_xy(motion={"product_acceleration": 300.0}), "p.toml"))).ok


def test_drive_torque_eq_4_1():
    drive = {"x": {"motor_inertia": 1e-5, "load_inertia": 2e-5, "lead": 40.0, "max_torque": 0.0025,
                   "friction_torque": 0.002, "viscous": 1e-5}}
    traj = solve_design(parse_design(quintic_xy(drive=drive), "p.toml"))
    rep = check(traj)
    # independently: T = (J_m + J_p)·a·2π/lead + T_f·sign(v) + c·v·2π/lead on a fine grid
    t = np.linspace(0, 1, 100001)
    f = traj.axis("x").evaluate(t)
    k = 2 * np.pi / 40.0
    torque = 3e-5 * f[2] * k + 0.002 * np.sign(f[1] * k) + 1e-5 * f[1] * k
    i = np.abs(torque).argmax()
    (dr,) = rep.drives
    assert dr["peak_torque"] == pytest.approx(abs(torque[i]), rel=1e-4) and dr["t"] == pytest.approx(t[i], abs=1e-3)
    assert [x.kind for x in rep.findings] == ["torque"] and "axis x segment 1" in rep.findings[0].where
    drive["x"]["max_torque"] = 0.01
    assert check(solve_design(parse_design(quintic_xy(drive=drive), "p.toml"))).ok
    # a rotation axis in degrees: Θ'' = ratio · a · π/180
    data = {"motion": {"input": "time"}, "axis": {"theta": {"point": [{"t": 0, "pos": 0, "vel": 0, "acc": 0},
                                                                       {"t": 1, "pos": 90, "vel": 0, "acc": 0}]}},
            "drive": {"theta": {"motor_inertia": 1e-4, "load_inertia": 0.0, "ratio": 10.0, "max_torque": 1.0}}}
    rep = check(solve_design(parse_design(data, "r.toml")))
    assert rep.drives[0]["peak_torque"] == pytest.approx(1e-4 * 10 * np.deg2rad(10 * np.sqrt(3) / 3 * 90), rel=1e-5)


@pytest.mark.parametrize("drive,message", [
    ({"z": {}}, r"\[drive.z\]: the design has no axis 'z'"),
    ({"x": {"motor_inertia": 1e-5, "load_inertia": 0, "max_torque": 1}}, r"\[drive.x\] needs lead"),
    ({"x": {"motor_inertia": 1e-5, "load_inertia": 0, "lead": 40}}, r"\[drive.x\] needs max_torque"),
    ({"x": {"motor_inertia": 1e-5, "load_inertia": 0, "lead": 0, "max_torque": 1}}, r"lead = 0 must be positive"),
    ({"x": {"motor_inertia": 1e-5, "load_inertia": 0, "lead": 4, "max_torque": 1, "torqe": 1}},
     r"unknown key 'torqe'"),
])
def test_drive_errors(drive, message):
    with pytest.raises(MotionError, match=message):
        parse_design(quintic_xy(drive=drive), "p.toml")
    with pytest.raises(MotionError, match="product_acceleration = -1 must be positive"):
        parse_design(quintic_xy(motion={"product_acceleration": -1}), "p.toml")
