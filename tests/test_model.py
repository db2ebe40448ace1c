"""The data model's own computations."""

import numpy as np

from doodlecam.model import Spline


def test_spline_evaluation_matches_scipy_at_every_derivative():
    from scipy.interpolate import BSpline

    rng = np.random.default_rng(3)
    for degree in (1, 2, 3, 5):
        for n in (degree + 1, degree + 3, 40):
            s = Spline(degree, rng.normal(size=(n, 2)) * 10)
            u = np.concatenate([rng.random(300), s.knots, [0.0, 1.0]])
            ref = BSpline(s.knots, s.control, degree)
            for der in range(degree + 1):
                x = u  # the top derivative jumps at the knots: right-continuous, as scipy
                want = ref.derivative(der)(x) if der else ref(x)
                assert np.allclose(s(x, der), want, rtol=1e-11, atol=1e-9 * np.abs(want).max())
            assert np.array_equal(s(np.array([-0.5, 1.5])), s(np.array([0.0, 1.0])))  # clipped to [0, 1]
            assert s(0.5).shape == (2,) and s(u.reshape(-1, 1)).shape == (len(u), 1, 2)


def test_handed_constructors_equal_the_copying_ones_and_freeze_in_place():
    from dataclasses import fields

    from doodlecam.model import Profile, StrokeSamples

    rng = np.random.default_rng(5)
    u, b, a, t = np.linspace(0, 1, 6), rng.random(6), rng.random(5), np.cumsum(rng.random(6))
    copied, handed = Profile(u, b, a, t, "reach"), Profile.handed(u, b, a, t, "reach")
    start, vel, su = rng.random(2), rng.random((4, 2)), np.linspace(0, 1, 5)
    s_copied = StrokeSamples(start, vel, 0.04, 0.9, su)
    s_handed = StrokeSamples.handed(start, vel, 0.04, 0.9, su)
    for one, other in ((copied, handed), (s_copied, s_handed)):
        for f in fields(one):
            x, y = getattr(one, f.name), getattr(other, f.name)
            assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
    # handed over: the very arrays, now read-only (the copying constructor left the originals alone)
    assert handed.u is u and s_handed.velocity is vel and s_handed.sample_u is su
    assert not (u.flags.writeable or b.flags.writeable or start.flags.writeable or vel.flags.writeable)
    assert copied.u is not u and s_copied.start is not start
    from doodlecam.model import Travel

    a0, a1 = rng.random(2), rng.random(2)
    t_copied, t_handed = Travel(a0, a1, 1.5), Travel.handed(a0, a1, 1.5)
    assert t_handed.start is a0 and t_handed.end is a1 and not a0.flags.writeable and t_handed.duration == 1.5
    assert np.array_equal(t_copied.start, t_handed.start) and t_copied.length == t_handed.length
