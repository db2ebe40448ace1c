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
