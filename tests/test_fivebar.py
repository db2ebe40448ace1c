"""Kirecci's five-bar arm (plugins/fivebar.py): kinematics, derivatives, feasibility."""

import copy

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from doodlecam.errors import MachineError, PlanError
from doodlecam.machine import load_machine
from doodlecam.model import Spline
from doodlecam.registry import kinematics_for
from doodlecam.plugins.fivebar import FiveBar

MACHINE = load_machine("fivebar")
KIN = kinematics_for(MACHINE)
PARAMS = copy.deepcopy(MACHINE.kinematics_params)
W, H = MACHINE.width, MACHINE.height

coord = st.tuples(st.floats(-60, W + 60), st.floats(-60, H + 60))


def _cross(u, v):
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def test_profile_loads_the_plugin():
    assert isinstance(KIN, FiveBar) and KIN.linear_map is None
    assert KIN.actuator_names == ("theta1", "theta4") and KIN.actuator_units == "rad"
    vmax, amax = KIN.actuator_limits()
    assert vmax.shape == amax.shape == (2,) and (vmax > 0).all() and (amax > 0).all()


def test_inverse_is_the_thesis_formula():
    """eq. 6.1-6.10 literally (atan, 180 - atan) where the pen is between the pivots."""
    a0, a1, a2, a3, a4 = (PARAMS[k] for k in ("a0", "a1", "a2", "a3", "a4"))
    X, Y = np.meshgrid(np.linspace(0, W, 15), np.linspace(0, H, 11))
    xy = np.column_stack([X.ravel(), Y.ravel()])
    x, y = (xy - PARAMS["origin"]).T
    assert (x > 0).all() and (x < a0).all()
    b, c = np.hypot(x, y), np.hypot(a0 - x, y)
    theta1 = np.arccos((b**2 + a1**2 - a2**2) / (2 * a1 * b)) + np.arctan(y / x)
    theta_c = np.pi - np.arctan(y / (a0 - x))
    theta4 = theta_c - np.arccos((c**2 + a4**2 - a3**2) / (2 * c * a4))
    np.testing.assert_allclose(KIN.inverse(xy), np.column_stack([theta1, theta4]), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.lists(coord, min_size=1, max_size=20))
def test_forward_inverts_inverse(points):
    p = np.array(points)
    ok = KIN.feasible(p)
    assume(ok.any())
    p = p[ok]
    theta = KIN.inverse(p)
    np.testing.assert_allclose(KIN.forward(theta), p, atol=1e-8)
    np.testing.assert_allclose(KIN.inverse(KIN.forward(theta)), theta, atol=1e-10)


@settings(max_examples=60, deadline=None)
@given(st.floats(250, 900), st.floats(60, 400), st.floats(60, 400), st.floats(-80, 80), st.floats(-300, 300))
def test_forward_inverts_inverse_for_other_arms(a0, crank, coupler, ox, oy):
    """Any valid geometry, not just the sample's: links of random lengths."""
    assume(coupler > crank * 1.2)
    params = dict(PARAMS, a0=a0, a1=crank, a4=crank, a2=coupler, a3=coupler, origin=[ox, oy], min_transmission_angle=10.0)
    try:
        kin = FiveBar(MACHINE, params)
    except MachineError:
        assume(False)
    rng = np.random.default_rng(0)
    reach = crank + coupler
    p = np.column_stack([rng.uniform(-reach, a0 + reach, 4000), rng.uniform(0, reach, 4000)]) + [ox, oy]
    p = p[kin.feasible(p)]
    assume(len(p) > 0)
    np.testing.assert_allclose(kin.forward(kin.inverse(p)), p, atol=1e-7)


def _fd_check(kin, spline, n=400, h=1e-5):
    u = np.linspace(h, 1 - h, n)
    theta, d1, d2 = kin.derivatives(spline(u), spline(u, 1), spline(u, 2))
    tp, tm = kin.inverse(spline(u + h)), kin.inverse(spline(u - h))
    fd1 = (tp - tm) / (2 * h)
    fd2 = (tp - 2 * theta + tm) / (h * h)
    np.testing.assert_allclose(theta, kin.inverse(spline(u)), atol=0)
    np.testing.assert_allclose(d1, fd1, rtol=1e-6, atol=1e-7 * np.abs(fd1).max())
    np.testing.assert_allclose(d2, fd2, rtol=1e-3, atol=2e-4 * np.abs(fd2).max())
    # the same through the Jacobian: theta' = J q'
    J = kin.jacobian(spline(u))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", J, spline(u, 1)), d1, rtol=1e-12, atol=1e-12)


def test_derivatives_match_finite_differences_on_the_report_curve():
    ctrl = np.array([[20, 20], [60, 90], [110, 30], [150, 110], [90, 150], [40, 120], [100, 60], [160, 40]], float)
    spline = Spline(3, ctrl + [50, 0])
    assert KIN.feasible(spline(np.linspace(0, 1, 500))).all()
    _fd_check(KIN, spline)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.floats(5, W - 5), st.floats(5, H - 5)), min_size=4, max_size=12),
       st.sampled_from([3, 4, 5]))
def test_derivatives_match_finite_differences_on_random_splines(ctrl, degree):
    assume(len(ctrl) > degree)
    spline = Spline(degree, np.array(ctrl))
    assume(np.linalg.norm(spline(np.linspace(0, 1, 50), 1), axis=1).min() > 1.0)
    _fd_check(KIN, spline, n=200)


def test_time_derivatives_by_the_chain_rule():
    """With u = u(t): theta-dot = theta' u-dot, theta-ddot = theta' u-ddot + theta'' u-dot^2."""
    spline = Spline(3, np.array([[30, 30], [200, 40], [250, 160], [40, 150]], float))
    u = np.linspace(0.05, 0.95, 50)
    ud, udd = 3.0 + u, -2.0 + 5 * u
    _, d1, d2 = KIN.derivatives(spline(u), spline(u, 1), spline(u, 2))
    q_t, qdd_t = spline(u, 1) * ud[:, None], spline(u, 1) * udd[:, None] + spline(u, 2) * (ud**2)[:, None]
    _, v, a = KIN.derivatives(spline(u), q_t, qdd_t)
    np.testing.assert_allclose(v, d1 * ud[:, None], rtol=1e-12)
    np.testing.assert_allclose(a, d1 * udd[:, None] + d2 * (ud**2)[:, None], rtol=1e-9, atol=1e-12)


def test_sample_profile_covers_its_work_area_with_a_margin():
    margin = 10.0
    X, Y = np.meshgrid(np.linspace(-margin, W + margin, 141), np.linspace(-margin, H + margin, 96))
    p = np.column_stack([X.ravel(), Y.ravel()])
    KIN.check_reachable(p)  # raises if any point fails
    mu = np.degrees(KIN.transmission_angles(p))
    lim = PARAMS["min_transmission_angle"]
    assert mu.min() >= lim and mu.max() <= 180 - lim
    KIN.check_reachable([MACHINE.home])


def test_one_assembly_mode_across_the_workspace():
    """Elbows out everywhere (Fig. 6.7): B left of A->P, C right of D->P, P left
    of B->C, and the crank angles change continuously along a raster over the
    work area (no branch switch)."""
    xs = np.linspace(0, W, 300)
    rows = [np.column_stack([xs if i % 2 == 0 else xs[::-1], np.full_like(xs, y)]) for i, y in enumerate(np.linspace(0, H, 61))]
    p = np.concatenate(rows)
    theta = KIN.inverse(p)
    local = p - PARAMS["origin"]
    A, D = np.zeros(2), np.array([PARAMS["a0"], 0.0])
    B = PARAMS["a1"] * np.column_stack([np.cos(theta[:, 0]), np.sin(theta[:, 0])])
    C = D + PARAMS["a4"] * np.column_stack([np.cos(theta[:, 1]), np.sin(theta[:, 1])])
    assert (_cross(local - A, B - A) > 0).all()
    assert (_cross(local - D, C - D) < 0).all()
    assert (_cross(C - B, local - B) > 0).all()
    np.testing.assert_allclose(np.linalg.norm(local - B, axis=1), PARAMS["a2"], rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(local - C, axis=1), PARAMS["a3"], rtol=1e-12)
    step = np.abs(np.diff(theta, axis=0)).max()
    assert step < 0.05  # neighbouring raster points are <= ~3 mm apart
    assert (KIN.transmission_angles(p)[:, 2] > 0).all()


def _one_line_plan_error(points):
    with pytest.raises(PlanError) as e:
        KIN.check_reachable(points)
    msg = str(e.value)
    assert "\n" not in msg and "workspace" in msg
    return msg


def test_unreachable_points_are_named_first_first():
    msg = _one_line_plan_error([[100, 100], [140, 600], [-500, 20]])
    assert "(140.00, 600.00)" in msg and "out of reach" in msg and "|AP|" in msg
    assert "too close to pivot A" in _one_line_plan_error([[140, -330]])
    assert "not above the line" in _one_line_plan_error([[140, -400]])


def test_singular_pose_is_refused():
    """Near the outer edge on A's side crank a1 and coupler a2 stretch out collinear."""
    p = np.array(PARAMS["origin"]) + [80.45, 348.85]
    msg = _one_line_plan_error([[100, 100], p])
    assert "(-89.55, -9.15)" in msg and "crank a1 and coupler a2 near collinear" in msg
    mirrored = np.array(PARAMS["origin"]) + [PARAMS["a0"] - 80.45, 348.85]
    assert "crank a4 and coupler a3 near collinear" in _one_line_plan_error([mirrored])


def test_couplers_collinear_and_other_assembly_mode_are_refused():
    """On a compact arm the couplers straighten out (angle BPC -> 180 deg) low
    between the pivots, and the elbows-out cranks can even put P on the other
    side of B->C (the other assembly mode, where forward() would not return P)."""
    kin = FiveBar(MACHINE, dict(PARAMS, origin=[0, 0], a0=200, a1=150, a4=150, a2=200, a3=200))
    with pytest.raises(PlanError, match=r"couplers near collinear \(angle BPC 173\.1 deg"):
        kin.check_reachable([[100, 200], [157.53, 101.50]])
    kin = FiveBar(MACHINE, dict(PARAMS, origin=[0, 0], a0=300, a1=250, a4=250, a2=300, a3=300))
    p = np.array([[172.58, 165.83]])
    assert kin.transmission_angles(p)[0, 2] < 0  # P right of B->C
    assert not np.allclose(kin.forward(kin.inverse(p)), p, atol=1e-3)
    with pytest.raises(PlanError, match=r"couplers near collinear \(angle BPC -167"):
        kin.check_reachable(p)


@pytest.mark.parametrize("edit, words", [
    (lambda p: p.pop("a2"), "kinematics.a2 is missing; add it under [kinematics]: a2 = the length of coupler B-P"),
    (lambda p: p.__setitem__("a3", -5), "kinematics.a3 = -5 must be positive"),
    (lambda p: p.__setitem__("a1", "long"), "kinematics.a1 = 'long' is not a number"),
    (lambda p: p.__setitem__("orgin", [0, 0]), "unknown key kinematics.orgin (did you mean 'origin'?)"),
    (lambda p: p.__setitem__("origin", [0]), "kinematics.origin = [0] has too few values; give pivot A"),
    (lambda p: p.__setitem__("max_velocity", [1, 0]), "kinematics.max_velocity[2] = 0 must be positive"),
    (lambda p: p.__setitem__("max_acceleration", "fast"), "kinematics.max_acceleration = 'fast' is not a list"),
    (lambda p: p.__setitem__("a0", 5000.0), "kinematics.a0 = 5000 mm is not shorter than a1 + a2 + a3 + a4"),
    (lambda p: p.__setitem__("a0", 1470.0), "no point with transmission angles"),
    (lambda p: p.__setitem__("min_transmission_angle", 75), "kinematics.min_transmission_angle = 75 must be less than 60"),
    (lambda p: p.__setitem__("min_transmission_angle", 0), "kinematics.min_transmission_angle = 0 must be positive"),
])
def test_impossible_params_give_one_line_errors(edit, words):
    params = copy.deepcopy(PARAMS)
    edit(params)
    with pytest.raises(MachineError) as e:
        FiveBar(MACHINE, params)
    msg = str(e.value)
    assert "\n" not in msg and words in msg and msg.startswith(f"{MACHINE.source}: ")


def test_scalar_limits_apply_to_both_cranks():
    kin = FiveBar(MACHINE, dict(PARAMS, max_velocity=2.0, max_acceleration=30))
    v, a = kin.actuator_limits()
    assert list(v) == [2.0, 2.0] and list(a) == [30.0, 30.0]


def test_the_cranks_follow_the_sampled_ramps_within_their_limits(tmp_path):
    """The PLC file's samples are pen motion; the cranks follow each constant-
    acceleration period with varying acceleration. Measured independently, by
    finite differences of the crank angles along the executed ramps (from the file)."""
    from pathlib import Path

    from doodlecam.model import StrokeSamples
    from doodlecam.plan.follow import executed_points, path_deviation
    from doodlecam.pipeline import Settings, convert
    from conftest import plc_pieces, plc_strokes

    machine = load_machine("fivebar")
    horse = Path(__file__).resolve().parent.parent / "samples" / "images" / "horse.png"
    res = convert(horse, tmp_path, Settings(machine=machine, posts=("plc",)))
    assert res.summary()["worst_ramp_ratio"] > 0.8  # the cranks run near their limits on this picture
    kin = kinematics_for(machine)
    vmax, amax = kin.actuator_limits()
    header, runs = plc_strokes(tmp_path / "horse.plc")
    sub = 32
    pieces = plc_pieces(header, runs, res.job.samples)  # strokes drawn without lifting share a run
    assert len(pieces) == len(res.job.strokes)
    for run, stroke, smp in zip(pieces, res.job.strokes, res.job.samples):
        executed = StrokeSamples(start=run["start"], velocity=np.array(run["v"]), delta_time=header.delta_time,
                                 sample_u=smp.sample_u)
        pts = executed_points(executed, sub)
        theta = kin.inverse(np.vstack([pts[:, :-1].reshape(-1, 2), pts[-1, -1:]]))
        h = header.delta_time / sub
        w = np.diff(theta, axis=0) / h
        assert (np.abs(w) / vmax).max() <= 1.0 + 1e-3
        assert (np.abs(np.diff(w, axis=0) / h) / amax).max() <= 1.0 + 1e-2  # whole steps/s in the file: a hair
        assert path_deviation(stroke.spline, executed).max() <= 0.1 + 1e-3
