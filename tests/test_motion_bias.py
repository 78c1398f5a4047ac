"""The gyro bias of ``recommended`` at short rests and in motion: the rest learner's Kalman gain
(``rest_bias_gain``, rest-bias-lowpass's ``gain``) and the inertial-tilt bias filter's cached noise."""

import math

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.correctors.rest_bias import _P
from fusionkit.correctors.tilt import _DT, _N, _kf_noise

DEG = math.pi / 180.0
BIAS = np.array([0.004, -0.006, 0.003])  # a MEMS gyro's turn-on bias, 0.45 deg/s


def short_rest(rest=2.0, seed=0):
    """``rest`` s still (the rest detector needs 1.5 s: 0.5 s of REST samples), then brisk turns."""
    axes = ((0, 0, 1), (1, 0, 0), (0, 1, 0), (1, 1, 0), (0, 1, 1), (1, 0, 1))
    segs = [sim.Rest(rest)] + [sim.Rotate(axes[i % 6], (-1) ** i * 90 * DEG, 0.8) for i in range(8)] + [sim.Rest(0.5)]
    return sim.simulate(segs, rate=200.0, noise=sim.Noise(gyr_noise=0.005, gyr_bias=tuple(BIAS), acc_noise=0.03),
                        seed=seed)


def inclination(res, rec):
    up = lambda q: np.stack([2 * (q[:, 1] * q[:, 3] - q[:, 0] * q[:, 2]),  # noqa: E731
                             2 * (q[:, 2] * q[:, 3] + q[:, 0] * q[:, 1]), 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2)], 1)
    return np.degrees(np.arccos(np.clip(np.sum(up(res.quat) * up(rec.truth), 1), -1.0, 1.0)))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_short_rest_teaches_a_turn_on_bias(seed):
    # half a second of REST samples: the fixed gain (tau 1 s) learns 40 % of the bias (0.29 deg/s left); the
    # Kalman gain starts near 1 (the bias was never measured, the low-pass has settled) and leaves the
    # low-pass's noise (0.07 deg/s with this noise); the motion after it is that much better
    r = short_rest(seed=seed)
    end = int(2.0 * 200)
    runs = {g: fk.make("recommended", use_mag=False, rest_bias_gain=g) for g in ("kalman", "fixed")}
    err = {g: np.linalg.norm(f.run(r.slice(0, end)).diagnostics["bias"] - BIAS) for g, f in runs.items()}
    assert err["kalman"] < 0.1 * DEG < 0.5 * err["fixed"]
    incl = {g: inclination(f.run(r), r)[end:].mean() for g, f in runs.items()}
    assert incl["kalman"] < 0.6 * incl["fixed"]


def test_a_long_rest_settles_at_the_fixed_gain():
    # the process noise is the random walk for which the steady-state gain is 1 - exp(-dt / tau): after
    # a long rest the Kalman gain is the fixed one, and the variance that of the steady state, k sigma_rest^2
    r = sim.simulate([sim.Rest(12.0)], rate=100.0, noise=sim.Noise(gyr_noise=0.005, gyr_bias=tuple(BIAS)), seed=0)
    f = fk.make("recommended", use_mag=False, rest_bias_tau=2.0)
    res = f.run(r)
    k = 1.0 - math.exp(-0.01 / 2.0)
    p = res.diagnostics["state"]["cor"][0][_P]
    np.testing.assert_allclose(p, k * (0.03 * DEG) ** 2, rtol=1e-3)
    fixed = fk.make("recommended", use_mag=False, rest_bias_tau=2.0, rest_bias_gain="fixed").run(r)
    # both end on the low-passed gyro's recent values: the same bias to the noise's level
    np.testing.assert_allclose(res.diagnostics["bias"], fixed.diagnostics["bias"], atol=0.02 * DEG)
    np.testing.assert_allclose(res.diagnostics["bias"], BIAS, atol=0.05 * DEG)


def test_rest_gain_and_cached_noise_reference_equals_numba_with_changing_dt():
    # a lossy link: dt changes from sample to sample (dropped rows), so the coefficients and the bias
    # filter's noise terms are recomputed often; both paths agree on every sample
    r = fk.sim.scenario("lossy").slice(0, 1100)  # before its 1 s gap
    assert len(np.unique(np.round(np.diff(r.time), 6))) > 1
    for params in ({}, {"rest_bias_gain": "fixed", "bias_sigma_rest": 0.03 * DEG}):
        f = fk.make("recommended", use_mag=False, **params)
        a, b = f.run(r, backend="numba"), f.run(r, backend="reference")
        np.testing.assert_allclose(a.quat, b.quat, atol=1e-9, err_msg=str(params))
        np.testing.assert_allclose(a.diagnostics["bias"], b.diagnostics["bias"], atol=1e-12)
        tilt = a.diagnostics["state"]["cor"][1]
        # the cache holds the noise terms of the last dt seen
        c = f.correctors[1].config
        expect = _kf_noise(tilt[_DT], c.motion_bias_tau, c.bias_sigma_init, c.bias_sigma_motion,
                           c.bias_sigma_rest or 0.0, c.bias_vertical_forgetting)
        np.testing.assert_array_equal(tilt[_N:_N + 5], expect)


def test_rest_gain_options_are_validated():
    with pytest.raises(fk.FusionkitError):
        fk.make("recommended", rest_bias_gain="mean")
    with pytest.raises(fk.FusionkitError):
        fk.make("rest-bias-lowpass", kind="corrector", sigma_rest=0.0)
