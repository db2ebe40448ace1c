"""The compiled GRBL planner model gives the NumPy model's block times to the bit (the G-code post chooses
chords by comparing them, and prints their sum)."""

import numpy as np
import pytest

from doodlecam.link.grbl.timing import GrblSettings, _segment_time, _segment_time_numpy


def program(rng, n):
    """Points on a step grid with repeats (dropped blocks), straight runs, exact reversals and sharp turns."""
    steps = rng.integers(-3, 4, (n, 3)) * rng.choice([0.004, 0.25, 1.0, 7.0], (n, 1))
    steps[:, 2] *= rng.random(n) < 0.1
    steps[rng.random(n) < 0.1] = 0.0  # zero-length blocks
    run = rng.random(n) < 0.2
    steps[run] = steps[np.maximum(np.flatnonzero(run) - 1, 0)]  # straight on
    rev = rng.random(n) < 0.05
    steps[rev] = -steps[np.maximum(np.flatnonzero(rev) - 1, 0)]  # back the way it came
    pts = np.vstack([rng.uniform(0, 100, (1, 3)), 100 + np.cumsum(steps, axis=0)])
    feeds = rng.choice([5.0, 40.0, 83.3, np.inf], n)
    rest = rng.random(n) < 0.05
    return pts, feeds, rest


@pytest.mark.parametrize("seed", range(6))
def test_compiled_block_times_equal_the_numpy_model(seed):
    rng = np.random.default_rng(seed)
    s = GrblSettings(max_rate=(83.3, 50.0, 10.0), acceleration=(500.0, 300.0, 100.0),
                     junction_deviation=float(rng.choice([0.002, 0.01, 0.05])), blocks=int(rng.choice([2, 5, 16])),
                     steps_per_mm=(80.0, 100.0, 250.0))
    for n in (1, 2, 17, 3000):
        pts, feeds, rest = program(rng, n)
        for r in (rest, None):
            want = _segment_time_numpy(pts, feeds, s, r)
            got = _segment_time(pts, feeds, s, r)
            assert got.dtype == want.dtype and np.array_equal(got, want), (n, r is None)
            assert np.array_equal(np.signbit(got), np.signbit(want))
    assert (want > 0).any() and (want == 0).any()  # blocks timed and blocks dropped


def test_no_block_moves():
    s = GrblSettings()
    pts = np.zeros((4, 3))
    assert np.array_equal(_segment_time(pts, np.full(3, 10.0), s), np.zeros(3))
    assert _segment_time(np.zeros((1, 3)), np.zeros(0), s).shape == (0,)
