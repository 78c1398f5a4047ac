"""The filterpy EKF baseline: consistency (NEES/NIS in the chi-square bounds), filterpy's array
shapes, the magnetometer's reach, bad input, and the BROAD target where the data is present."""

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors, rms_errors
from fusionkit.errors import PluginError
from fusionkit.filters.ekf import _B, _P, _Q
from fusionkit.rotations import quat_conj, quat_mul, quat_to_rotvec
from fusionkit.types import Flag

from conftest import broad_mean

DEG = np.pi / 180
RATE = 100.0
G_NOISE, A_NOISE, M_NOISE = 0.004, 0.05, 0.3  # per sample: rad/s, m/s^2, uT
FIELD_H = 18.964  # the simulator's horizontal field, uT


def matched_ekf(**extra):
    """An EKF whose noise model is the simulator's (densities = per-sample std x sqrt(dt))."""
    dt = 1.0 / RATE
    return fk.make("ekf", gyr_noise=G_NOISE * np.sqrt(dt), acc_noise=A_NOISE * np.sqrt(dt), acc_dynamic=0.0,
                   mag_noise=M_NOISE / FIELD_H * np.sqrt(dt), bias_walk=1e-7, initial_bias_std=0.02,
                   initial_tilt_std=0.02, initial_heading_std=0.05, mag_rejection=False, **extra)


def trajectory(seed):
    rng = np.random.default_rng(seed)
    bias = tuple(rng.normal(scale=0.01, size=3))
    segs = [sim.Rest(1.0)]
    for _ in range(3):
        axis = tuple(rng.normal(size=3))
        segs += [sim.Rotate(axis, rng.uniform(0.5, 1.5), 2.0), sim.Rest(0.5)]
    noise = sim.Noise(gyr_noise=G_NOISE, gyr_bias=bias, acc_noise=A_NOISE, mag_noise=M_NOISE)
    # point-sampled accelerometer: the EKF's model pairs it with the predicted state, the end of
    # the gyro's step (the simulator's interval means sit half a sample earlier: ANEES 27)
    return (sim.simulate(segs, rate=RATE, noise=noise, seed=seed, gnss_rate=None, sampling="point"),
            np.array(bias))


def nees_run(seed):
    """Per-sample NEES of the 6 error states and the recorded NIS of one simulated run."""
    rec, bias = trajectory(seed)
    diag = matched_ekf().run(rec, record=True).diagnostics  # the filterpy path, each sample's state
    nees = np.empty(len(rec))
    for k, x in enumerate(diag["states"]):
        e_theta = quat_to_rotvec(quat_mul(quat_conj(x[_Q:_Q + 4]), rec.truth[k]))  # q_true = q (x) exp(e)
        e = np.concatenate([e_theta, bias - x[_B:_B + 3]])
        nees[k] = e @ np.linalg.solve(x[_P:_P + 36].reshape(6, 6), e)
    return nees, diag["nis"]


@pytest.fixture(scope="module")
def monte_carlo():
    runs = [nees_run(seed) for seed in range(20)]
    return np.array([r[0] for r in runs]), np.array([r[1] for r in runs])


def test_nees_within_chi_square_bounds(monte_carlo):
    """Average NEES over 20 runs at each sample: within the two-sided 95% chi-square bounds
    (6 x 20 dof, divided by 20) on at least 90% of the samples after the first half second."""
    nees, _ = monte_carlo
    m = nees.shape[0]
    anees = nees[:, 50:].mean(axis=0)
    lo, hi = chi2.ppf([0.025, 0.975], 6 * m) / m
    inside = np.mean((anees > lo) & (anees < hi))
    assert inside > 0.9, f"ANEES inside [{lo:.2f}, {hi:.2f}] on {inside:.0%} of the samples (mean {anees.mean():.2f})"
    assert 0.7 * 6 < anees.mean() < 1.3 * 6


def test_nis_within_chi_square_bounds(monte_carlo):
    """The accelerometer's NIS and the heading's (1 dof), averaged over runs and samples. The
    accelerometer measures a direction, a / |a| on the unit sphere: its residual along the
    predicted vertical is second order, so the 3-vector carries 2 degrees of freedom (H = [v x]
    has rank 2) and its NIS averages 2, not 3."""
    _, nis = monte_carlo
    acc, head = nis[:, 50:, 0], nis[:, 50:, 1]
    assert np.isfinite(acc).all() and np.isfinite(head).all()
    assert 0.8 * 2 < acc.mean() < 1.2 * 2, acc.mean()
    assert 0.7 < head.mean() < 1.3, head.mean()


def test_mistuned_filter_is_inconsistent():
    """The NEES test can fail: a filter that claims 10x less gyro noise than there is is overconfident."""
    rec, bias = trajectory(3)
    f = fk.make("ekf", gyr_noise=0.1 * G_NOISE / np.sqrt(RATE), acc_noise=A_NOISE / np.sqrt(RATE),
                acc_dynamic=0.0, mag_noise=M_NOISE / FIELD_H / np.sqrt(RATE), bias_walk=1e-7,
                initial_bias_std=1e-4, mag_rejection=False)
    vals = []
    for k in range(len(rec)):
        f.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=1.0 / RATE)
        x = f.state
        e = np.concatenate([quat_to_rotvec(quat_mul(quat_conj(x[_Q:_Q + 4]), rec.truth[k])), bias - x[_B:_B + 3]])
        vals.append(e @ np.linalg.solve(x[_P:_P + 36].reshape(6, 6), e))
    assert np.mean(vals[50:]) > chi2.ppf(0.975, 6 * 20) / 20


def test_accuracy_and_bias_on_simulated_motion():
    rec, bias = trajectory(7)
    res = matched_ekf().run(rec)
    assert rms_errors(res, rec, mask=np.arange(len(rec)) > 100)["total"] < 1.0
    np.testing.assert_allclose(res.diagnostics["bias"], bias, atol=0.003)


def test_filterpy_shapes_are_checked():
    """filterpy broadcasts a 1-D measurement into a (6, 3) state without complaint; the filter's
    check after every predict and update catches it."""
    f = fk.make("ekf")
    f.kf.update(np.zeros(3), lambda x: np.zeros((3, 6)), lambda x: np.ones((3, 1)), R=np.eye(3))
    assert f.kf.x.shape != (6, 1)
    with pytest.raises(PluginError, match=r"expected \(6, 1\)"):
        f._check("update")


def test_a_state_that_is_no_array_is_an_input_error():
    """``set_state({"a": 1})`` (a dict: another filter's state, say) was numpy's TypeError from
    np.asarray; it says what a state is, as the pipelines do."""
    for bad in ({"a": 1}, "state"):
        with pytest.raises(fk.InputError, match=r"state must be Result.diagnostics\['state'\] of an earlier ekf run "
                                                r"\(or its .state\), an array of \d+ numbers; got (dict|str)"):
            fk.make("ekf").set_state(bad)


def test_magnetometer_reaches_tilt_only_through_correlations():
    """A constant magnetic offset moves heading a lot and tilt only a little (the heading
    measurement's H has no tilt part; the covariance's correlations carry a small share)."""
    rec, _ = trajectory(11)
    free = fk.make("ekf", use_mag=False).run(rec)
    dist = fk.make("ekf", mag_rejection=False).run(dataclasses.replace(rec, mag=rec.mag + [8.0, -6.0, 0.0]))
    e = broad_errors(dist.quat, free.quat)
    assert np.max(e["heading"]) > 10.0
    assert np.sqrt(np.mean(e["inclination"] ** 2)) < 0.1 * np.sqrt(np.mean(e["heading"] ** 2))


def test_magnetic_disturbance_is_rejected():
    rec, _ = trajectory(12)
    mag = rec.mag.copy()
    mag[500:800] += [60.0, 0.0, 0.0]  # a magnet nearby: the norm jumps
    res = fk.make("ekf").run(dataclasses.replace(rec, mag=mag))
    assert np.all(res.flags[510:790] & Flag.MAG_DISTURBED) and not np.any(res.flags[:500] & Flag.MAG_DISTURBED)
    off = fk.make("ekf", mag_rejection=False).run(dataclasses.replace(rec, mag=mag))
    mask = np.arange(len(rec)) >= 500
    assert rms_errors(res, rec, mask=mask)["total"] < 0.5 * rms_errors(off, rec, mask=mask)["total"]


def test_bad_input_skips_and_flags():
    rec, _ = trajectory(13)
    bad = dataclasses.replace(rec, gyr=rec.gyr.copy(), acc=rec.acc.copy(), mag=rec.mag.copy())
    bad.gyr[300] = np.nan
    bad.acc[400:420] = 0.0  # free fall / dropout
    bad.mag[500] = np.nan
    bad.gyr[600] = [9.0, 0.0, 0.0]
    res = fk.make("ekf", nan_policy="skip", gyr_range=8.0).run(bad)
    assert np.isfinite(res.quat).all() and np.isfinite(res.diagnostics["state"]).all()
    assert res.flags[300] & Flag.GYR_INVALID and np.all(res.flags[400:420] & Flag.ACC_INVALID)
    assert res.flags[500] & Flag.MAG_INVALID and res.flags[600] & Flag.GYR_SATURATED


def test_broad_target(broad_dir):
    """9D total RMSE below 5.2 deg on average over the BROAD trials, default parameters."""
    assert broad_mean(broad_dir, "ekf", "total") < 5.2


@pytest.mark.parametrize("params", [
    {"gate": 0.3, "nan_policy": "skip", "gyr_range": 8.0},  # the gate rejects some samples
    {"heading_jacobian": "vertical", "dynamic": "norm", "dynamic_tau": 0.0},
    {"use_mag": False, "frame": "NED"},
    {"magnetic": {"norm_threshold": 0.02}, "mag_rejection": True},
    {"magnetic": {"max_rejection": 0.3}},  # the detector's clock fires inside the 0.6 s disturbance: learned again
])
def test_compiled_path_equals_filterpy(params):
    """run()'s compiled loop does filterpy's predict and update arithmetic: the same quaternions,
    flags and covariance to 1e-9 on every sample, through bad samples, gate rejections and
    magnetic disturbances; the filterpy object stays what update() and users call."""
    rec, _ = trajectory(21)
    bad = dataclasses.replace(rec, gyr=rec.gyr.copy(), acc=rec.acc.copy(), mag=rec.mag.copy())
    if params.get("nan_policy") == "skip":
        bad.gyr[300] = np.nan
        bad.acc[400:420] = 0.0
        bad.mag[500] = np.nan
        bad.gyr[600] = [9.0, 0.0, 0.0]
    bad.mag[700:760] += [40.0, 0.0, 0.0]
    f = fk.make("ekf", **params)
    ref = f.run(bad, backend="reference")
    fast = f.run(bad)
    assert fast.diagnostics["backend"] == "numba" and ref.diagnostics["backend"] == "reference"
    np.testing.assert_allclose(fast.quat, ref.quat, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(fast.flags, ref.flags)
    np.testing.assert_allclose(fast.diagnostics["P"], ref.diagnostics["P"], rtol=0, atol=1e-9)
    if "gate" in params:
        assert np.any(ref.flags & (Flag.ACC_REJECTED | Flag.MAG_DISTURBED))


def test_record_runs_the_filterpy_path():
    rec, _ = trajectory(22)
    f = fk.make("ekf")
    res = f.run(rec.slice(0, 200), record=True)
    assert res.diagnostics["backend"] == "reference" and res.diagnostics["nis"].shape == (200, 2)
    for k in range(200):  # each sample's state, as a stream of update() holds it
        f.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=1.0 / RATE)
        np.testing.assert_allclose(res.diagnostics["states"][k], f.state, rtol=0, atol=1e-12)
    with pytest.raises(fk.errors.ConfigError, match="record"):
        fk.make("ekf").run(rec.slice(0, 200), record=True, backend="numba")
