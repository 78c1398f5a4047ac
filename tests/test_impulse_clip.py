"""inertial-tilt's impulse clip (``impulse_clip``, ``impulse_window``, ``impulse_floor``): the
specific force's departure from the low-passed vector limited to ``impulse_clip`` times its running
RMS before the low-pass. The step itself, reference and kernel; ``recommended``'s use of it:
test_recommended.py."""

import numpy as np
import pytest

from fusionkit._numba import HAVE_NUMBA
from fusionkit.correctors import tilt as T

G = np.array([0.0, 0.0, 9.81])


def _state(ms=None, n=0.0):
    """A tilt state whose low-pass runs (READY) with the low-passed vector at gravity, the departure's
    mean square ``ms`` over ``n`` samples."""
    x = np.zeros(T._SIZE)
    x[T._READY] = 1.0
    x[T._Y:T._Y + 3] = G
    x[T._IMS], x[T._IMN] = (0.0 if ms is None else ms), n
    return x


def test_the_floor_sets_the_least_limit():
    # after a noise-free rest the departure's RMS is 0: the limit is clip times the floor. 0.3 m/s^2 passes
    # under 10 x 0.05 and is cut to 0.1 under 10 x 0.01 (the direction kept)
    v = G + [0.3, 0.0, 0.0]
    out = T._impulse_clip(_state(0.0, 100.0), v.copy(), 0.01, 10.0, 1.0, 0.05)
    np.testing.assert_array_equal(out, v)
    out = T._impulse_clip(_state(0.0, 100.0), v.copy(), 0.01, 10.0, 1.0, 0.01)
    np.testing.assert_allclose(out, G + [0.1, 0.0, 0.0], atol=1e-15)


def test_the_window_sets_how_fast_the_limit_follows():
    # a clipped departure enters the mean square at the limit, with weight dt / window (after the
    # window's first samples): a longer window lets a motion that starts raise the limit more slowly
    v = G + [5.0, 0.0, 0.0]
    ms = {}
    for window in (0.5, 2.0):
        x = _state(0.01, 1000.0)
        T._impulse_clip(x, v.copy(), 0.01, 10.0, window, 0.05)
        ms[window] = x[T._IMS]
        lim = 100.0 * max(0.01, 0.05 ** 2)
        assert ms[window] == pytest.approx(0.01 + (lim - 0.01) * 0.01 / window, rel=1e-12)
    assert ms[2.0] < ms[0.5]


def test_off_before_the_low_pass_and_the_first_departure_starts_the_mean():
    v = G + [50.0, 0.0, 0.0]
    x = _state()
    x[T._READY] = 0.0  # the fast start's mean: nothing to depart from yet
    np.testing.assert_array_equal(T._impulse_clip(x, v.copy(), 0.01, 10.0, 1.0, 0.05), v)
    x = _state()
    np.testing.assert_array_equal(T._impulse_clip(x, v.copy(), 0.01, 10.0, 1.0, 0.05), v)
    assert x[T._IMN] == 1.0 and x[T._IMS] == pytest.approx(2500.0)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
@pytest.mark.parametrize("window, floor", [(1.0, 0.05), (0.2, 0.5)])
def test_kernel_equals_reference(window, floor):
    # knocks in a noisy motion, several rates: the same vectors and states to 1e-12
    rng = np.random.default_rng(3)
    xr, xk = _state(), _state()
    for k in range(2000):
        dt = 0.01 * (1.0 + 0.1 * rng.standard_normal())
        v = G + rng.standard_normal(3) * (0.2 if k % 150 else 40.0)
        a = T._impulse_clip(xr, v.copy(), dt, 10.0, window, floor)
        b = T._k_impulse_clip(xk, v[0], v[1], v[2], dt, 10.0, window, floor)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    np.testing.assert_allclose(xr, xk, rtol=0, atol=1e-12)
    assert 0.0 < xr[T._IMS] < 1.0  # the knocks did not raise their own limit
