"""The sampler's compiled passes against the array formulas they replace, bit for bit.

kernels.sample_aim is Profile.state_at at the sample instants, Spline's derivative there and
curve_frame in one pass; kernels.relinearise is the check after a solve (numpy.clip, the frame,
the error per axis, numpy.maximum.accumulate). The samples of a job depend on their bits, so
any other rounding would change the files; these tests fail on the first bit that differs.
"""

from dataclasses import replace

import numpy as np
import pytest
from test_sample_dense import _limits, _strokes

from doodlecam.errors import PlanError
from doodlecam.geometry.fit import fit_pieces
from doodlecam.model import Stroke
from doodlecam.plan import sample as sampling
from doodlecam.plan.kernels import curve_frame, relinearise, sample_aim
from doodlecam.plan.planner import plan_stroke
from doodlecam.plan.sample import TRUST_MM, whole_step_limits

DT = 0.04


def _same(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def _all_strokes():
    lim, k = _limits("doodlebot")
    low = whole_step_limits(lim, k, DT)
    out = _strokes(low, 6, 3)
    rng = np.random.default_rng(4)
    for _ in range(3):  # degree 2: the general span evaluation of curve_frame
        th = np.linspace(0.0, rng.uniform(1.0, 4.0), 50)
        pts = np.column_stack([5 * np.cos(th), 3 * np.sin(th)]) + 60.0
        spline = fit_pieces(pts, 2, 0.1)[0][0]
        out.append(Stroke(spline, plan_stroke(spline, low)))
    return out


def _frame(stroke, u, start, L, follow):
    m = len(u)
    pu, tang = np.empty((m, 3)), np.empty((m, 2))
    nrm, trust = (np.empty((m, 2)), np.empty(m)) if follow else (np.empty((0, 2)), np.empty(0))
    dc, sp = stroke.spline.derivative_controls, stroke.spline
    curve_frame(dc[0], dc[1], sp.degree, len(sp.control) - sp.degree, u, start, L, pu, tang, nrm, trust, TRUST_MM,
                np.empty(0), np.empty((0, 2)))
    return pu, tang, nrm, trust


@pytest.mark.parametrize("follow", [False, True])
def test_sample_aim_is_state_at_and_the_spline_to_the_bit(follow):
    for stroke in _all_strokes():
        prof, sp = stroke.profile, stroke.spline
        start, L = np.round(sp.start * 80.0) / 80.0, sp.length
        m0 = max(int(np.ceil(prof.duration / DT - 1e-9)), 2)
        for m in (m0, m0 + 1, 2 * m0 + 3):
            c = prof.duration / (m * DT)
            # the array steps sample_aim replaces
            u, ud, _ = prof.state_at(c * (DT * np.arange(1, m + 1)))
            u[-1] = 1.0
            v_plan = sp(u, 1) * (c * ud)[:, None]
            v_plan[-1] = 0.0
            want = _frame(stroke, u, start, L, follow)
            got_u, got_v = np.empty(m), np.empty((m, 2))
            pu, tang = np.empty((m, 3)), np.empty((m, 2))
            nrm, trust = (np.empty((m, 2)), np.empty(m)) if follow else (np.empty((0, 2)), np.empty(0))
            dc = sp.derivative_controls
            sample_aim(prof.t, prof.u, prof.b, prof.a, c, DT, dc[0], dc[1], sp.degree, len(sp.control) - sp.degree,
                       start, L, got_u, got_v, pu, tang, nrm, trust, TRUST_MM)
            assert _same(got_u, u) and _same(got_v, v_plan)
            for a, b in zip((pu, tang, nrm, trust), want):
                assert _same(a, b)


def test_relinearise_is_the_array_steps():
    rng = np.random.default_rng(9)
    seen = {"ok": 0, "not": 0, "remade": 0}
    for stroke in _all_strokes():
        sp = stroke.spline
        start, L = np.round(sp.start * 80.0) / 80.0, sp.length
        dc = sp.derivative_controls
        for trial in range(12):
            m = int(rng.integers(2, 30))
            u = np.sort(rng.uniform(0.0, 1.0, m))
            u[-1] = 1.0
            d = rng.normal(0.0, (0.3, 0.002, 1e-6)[trial % 3], m)  # shifts: often non-monotone, some off [0, 1]
            here = np.clip(u + d / L, 0.0, 1.0)
            here[-1] = 1.0
            x = sp(here)[:, :2] - start + rng.normal(0.0, (1e-6, 1e-2)[trial % 2], (m, 2))  # within tol or not
            tol = 0.005
            # the array steps relinearise replaces
            want_new = np.clip(u + d / L, 0.0, 1.0)
            want_new[-1] = 1.0
            frame_new = _frame(stroke, want_new, start, L, True)
            err = np.abs(x - frame_new[0][:, :2])[:-1]
            want_ok = err.size == 0 or err.max() <= tol
            want_mono = np.maximum.accumulate(want_new)
            remade = not want_ok and not np.array_equal(want_mono, want_new)
            want_frame = _frame(stroke, want_mono, start, L, True) if remade else frame_new
            pu, tang, nrm, trust = np.empty((m, 3)), np.empty((m, 2)), np.empty((m, 2)), np.empty(m)
            u_new, u_mono = np.empty(m), np.empty(m)
            ok = relinearise(dc[0], dc[1], sp.degree, len(sp.control) - sp.degree, u, d, L, x, start, tol, pu, tang,
                             nrm, trust, TRUST_MM, u_new, u_mono)
            assert ok == want_ok and _same(u_new, want_new)
            if not ok:
                assert _same(u_mono, want_mono)
            for a, b in zip((pu, tang, nrm, trust), want_frame):
                assert _same(a, b)
            seen["ok" if ok else "not"] += 1
            seen["remade"] += remade
    assert min(seen.values()) > 0  # every branch was compared


def test_lowered_limits_are_remade_for_other_limits_steps_or_periods():
    lim, k = _limits("doodlebot")
    for args in ((lim, k, DT), (lim, k, 0.02), (lim, k * 2, DT), (replace(lim, vmax=lim.vmax / 2), k, DT), (lim, k, DT)):
        low, bounds = sampling._lowered(*args)
        want = whole_step_limits(*args)
        assert _same(low.vmax, want.vmax) and _same(low.amax, want.amax) and _same(bounds.vmax, want.vmax)
    # too low for whole steps: refused on every call, not only the first
    slow = replace(lim, vmax=np.array([0.01, 0.01]))
    stroke = _strokes(whole_step_limits(lim, k, DT), 1, 5)[0]
    for _ in range(2):
        with pytest.raises(PlanError, match="below one machine step"):
            sampling.sample_stroke(stroke, DT, slow, k, follow=True)


def test_written_samples_are_the_plc_posts_whole_steps_to_the_bit():
    """sample.written_samples (compiled: kernels.written_velocity) against the PLC post's own
    whole_step_targets, on targets whose running sums land on halves of a step (rounded to even),
    on zeros and on signed zeros."""
    from doodlecam.link.plc.packetfile import whole_step_targets
    from doodlecam.model import StrokeSamples

    rng = np.random.default_rng(11)
    k = np.array([80.0, 57.0])
    for m in (1, 2, 7, 200):
        for vel in (rng.normal(scale=300, size=(m, 2)), np.round(rng.normal(scale=40, size=(m, 2))) / (2 * k),
                    np.zeros((m, 2)), -np.zeros((m, 2))):
            smp = StrokeSamples(start=rng.random(2), velocity=vel, delta_time=0.04, sample_u=np.linspace(0, 1, m + 1))
            got = sampling.written_samples(smp, tuple(k))
            want = whole_step_targets(vel, k) / k
            assert got.velocity.tobytes() == want.tobytes()
            assert got.start is smp.start and got.sample_u is smp.sample_u and got.delta_time == smp.delta_time
