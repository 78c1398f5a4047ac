"""The state of the art as pipeline plugins: the ``acceleration`` detector (acceleration
rejection with recovery), the ``rest-bias`` corrector (bias re-estimation at rest), and the
compiled pipeline with several detectors."""

import dataclasses
import math

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.errors import ConfigError
from fusionkit.rotations import quat_conj, quat_mul
from fusionkit.types import Flag


def _gradient_pipeline(detectors=(), correctors=(), use_mag=False, **grad):
    cfg = fk.make("gradient-descent", use_mag=use_mag, **grad).pipeline_config().model_dump()
    cfg["detectors"] += [{"name": n, "params": p} for n, p in detectors]
    cfg["correctors"] += [{"name": n, "params": p} for n, p in correctors]
    return fk.make("pipeline", **cfg)


def _inclination_deg(q, truth):
    e = quat_mul(q, quat_conj(truth))
    return np.degrees(2 * np.arccos(np.clip(np.sqrt(e[:, 0] ** 2 + e[:, 3] ** 2), 0, 1)))


def _heading_deg(q, truth):
    e = quat_mul(q, quat_conj(truth))
    return np.degrees(2 * np.arctan2(np.abs(e[:, 3]), np.abs(e[:, 0])))


def _acc_rec(acc, rate=100.0):
    n = len(acc)
    return fk.Recording(gyr=np.zeros((n, 3)), acc=np.asarray(acc, float), rate=rate)


# ---- acceleration detector ----------------------------------------------------------------------

def test_acceleration_fires_on_the_norm_and_holds_after():
    acc = np.tile([0.0, 0.0, 9.81], (300, 1))
    acc[100:110, 0] = 5.0  # | |a| - g | = 1.2 m/s^2 (below 2) ...
    acc[200:210, 0] = 8.0  # ... and 3.1 m/s^2 (above)
    det = fk.make("acceleration", "detector", hold=0.1)
    r = det.run(_acc_rec(acc))
    fired = np.flatnonzero(r.fired)
    assert fired[0] == 200 and fired[-1] == 219  # 10 disturbed samples + 0.1 s = 10 samples of hold
    assert r.which(205) == ["norm"] and r.which(215) == ["hold"]
    assert not r.fired[:200].any() and not r.fired[220:].any()


def test_acceleration_recovers_under_a_lasting_acceleration_and_rearms():
    rate = 100.0
    acc = np.tile([0.0, 0.0, 9.81], (4000, 1))
    acc[100:1600, 0] = 8.0  # a car accelerating at 8 m/s^2 for 15 s: | |a| - g | = 2.9 m/s^2
    acc[3000:3050, 1] = 8.0  # a short disturbance long after
    det = fk.make("acceleration", "detector", max_time=2.0, hold=0.0, max_fraction=0.5)
    r = det.run(_acc_rec(acc, rate))
    # rejected for the budget (2 s = 200 samples), then the accelerometer is used again
    assert r.fired[100:300].all() and not r.fired[300:1600].any()
    # after the acceleration the budget drains (as long as it was filled, at fraction 0.5)
    # and the next disturbance is rejected again
    assert r.fired[3000:3050].all()


def test_acceleration_budget_counts_intermittent_disturbance():
    """Disturbed on 3 of every 4 samples: no run of rejections is long, but the budget fills and
    the detector recovers; at 1 in 4 it never does."""
    acc = np.tile([0.0, 0.0, 9.81], (4000, 1))
    often = acc.copy()
    often[np.arange(4000) % 4 != 0, 0] = 8.0
    rarely = acc.copy()
    rarely[np.arange(4000) % 4 == 0, 0] = 8.0
    det = fk.make("acceleration", "detector", max_time=2.0, hold=0.0)
    r_often = det.run(_acc_rec(often))
    r_rarely = det.run(_acc_rec(rarely))
    assert r_often.fired[:1000].sum() < 0.5 * 750  # recovered early on: most disturbed samples used
    assert r_rarely.fired.sum() == 1000  # every disturbed sample rejected


def test_acceleration_kernel_matches_reference():
    rng = np.random.default_rng(3)
    acc = np.tile([0.0, 0.0, 9.81], (5000, 1)) + rng.normal(0, 1.5, (5000, 3))
    acc[2000:2600] += [6.0, 0.0, 0.0]
    rec = fk.Recording(gyr=rng.normal(0, 0.1, (5000, 3)), acc=acc, rate=200.0)
    det = fk.make("acceleration", "detector")
    a, b = det.run(rec, backend="numba"), det.run(rec, backend="reference")
    assert a.backend == "numba" and b.backend == "reference"
    assert np.array_equal(a.criteria, b.criteria) and a.fired.any() and not a.fired.all()


def _shaken(rate=100.0, seed=0):
    """Still, a 1 s horizontal shake (a linear acceleration the accelerometer cannot tell from a
    tilt), still again: the attitude never changes."""
    rec = sim.simulate([sim.Rest(10.0), sim.Translate((1.0, 0.0, 0.0), 0.3, 0.6), sim.Rest(5.0)], rate=rate,
                       noise=sim.Noise(gyr_noise=0.002, acc_noise=0.05), seed=seed, gnss_rate=None)
    return rec


def test_acceleration_rejection_keeps_the_tilt_through_a_shake():
    rec = _shaken()
    move = slice(int(10.0 * rec.rate), int(11.0 * rec.rate))
    plain = _gradient_pipeline().run(rec)
    # (with the rest detector, which changes no orientation: the composition of the test below)
    guarded = _gradient_pipeline(detectors=[("acceleration", {"threshold": 0.5}), ("rest", {})]).run(rec)
    e_plain = _inclination_deg(plain.quat, rec.truth)[move].max()
    e_guard = _inclination_deg(guarded.quat, rec.truth)[move].max()
    assert (guarded.flags[move] & Flag.ACC_REJECTED).any()
    assert e_plain > 3.0 and e_guard < 0.5 * e_plain


@pytest.mark.parametrize("use_mag", [False, True])
def test_pipeline_with_several_detectors_compiled_matches_reference(use_mag):
    rec = _shaken()
    mag_field = rec.mag
    if not use_mag:
        rec = dataclasses.replace(rec, mag=None)
    assert mag_field is not None
    p = _gradient_pipeline(detectors=[("acceleration", {"threshold": 0.5}), ("rest", {})], use_mag=use_mag)
    a, b = p.run(rec, backend="numba"), p.run(rec, backend="reference")
    assert a.diagnostics["backend"] == "numba"
    assert np.abs(a.quat - b.quat).max() < 1e-9
    assert np.array_equal(a.flags, b.flags) and np.array_equal(a.diagnostics["criteria"], b.diagnostics["criteria"])
    assert (a.flags & Flag.ACC_REJECTED).any() and (a.flags & Flag.REST).any()
    for da, db in zip(a.diagnostics["state"]["det"], b.diagnostics["state"]["det"]):
        assert np.allclose(da, db, rtol=0, atol=1e-12)
    # split in two compiled runs (each detector's state carried through the chain) = one run
    n1 = len(rec) // 3
    r1 = p.run(rec.slice(0, n1), backend="numba")
    r2 = p.run(rec.slice(n1, len(rec)), backend="numba", state=r1.diagnostics["state"])
    assert np.abs(np.vstack([r1.quat, r2.quat]) - a.quat).max() < 1e-12


# ---- rest-bias corrector ---------------------------------------------------------------------------

def test_rest_bias_needs_a_rest_detector():
    with pytest.raises(ConfigError, match="REST"):
        _gradient_pipeline(correctors=[("rest-bias", {})])


def _bias_change(rate=100.0):
    """The alignment measures the gyro bias over the first rest; then the bias changes
    (temperature) and the sensor turns, rests, turns, rests."""
    segs = [sim.Rest(5.0), sim.Rotate((0, 0, 1), 1.0, 2.0), sim.Rest(10.0), sim.Rotate((1, 0, 0), 0.5, 2.0),
            sim.Rest(20.0)]
    rec = sim.simulate(segs, rate=rate, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02), seed=1, gnss_rate=None)
    gyr = rec.gyr.copy()
    gyr[int(6.0 * rate):] += np.radians([0.3, -0.2, 0.5])  # after the alignment's rest
    return dataclasses.replace(rec, gyr=gyr, mag=None)


def test_rest_bias_learns_a_bias_change_and_stops_the_heading_drift():
    rec = _bias_change()
    plain = _gradient_pipeline().run(rec)  # (a rest detector alone changes no orientation: the loop every
    # gradient-descent test compiles, not one of its own)
    p = _gradient_pipeline(detectors=[("rest", {})], correctors=[("rest-bias", {})])
    res = p.run(rec)
    assert res.diagnostics["backend"] == "numba"  # a rate-mode kernel in the compiled loop
    last = slice(-int(10 * rec.rate), None)
    # without a magnetometer nothing corrects the vertical bias: the heading drifts (0.36 deg/s
    # about the final vertical); the offset of "heading zero" is constant, so look at the spread
    h_plain = _heading_deg(plain.quat, rec.truth)
    h_rest = _heading_deg(res.quat, rec.truth)
    assert np.ptp(h_plain[last]) > 3.0
    assert np.ptp(h_rest[last]) < 0.2
    learned = res.diagnostics["state"]["cor"][1]
    assert np.allclose(np.degrees(learned), [0.3, -0.2, 0.5], atol=0.03)


def test_rest_bias_is_bounded_and_never_nan():
    rec = _bias_change()
    gyr = rec.gyr.copy()
    gyr[3000:3100] = np.nan
    rec = dataclasses.replace(rec, gyr=gyr)
    p = _gradient_pipeline(detectors=[("rest", {"max_rate": 1.0})],
                           correctors=[("rest-bias", {"max_bias": math.radians(0.2)})], nan_policy="skip")
    res = p.run(rec)
    learned = res.diagnostics["state"]["cor"][1]
    assert np.isfinite(res.quat).all() and np.isfinite(learned).all()
    assert np.linalg.norm(learned) <= math.radians(0.2) + 1e-15


@pytest.mark.parametrize("estimator", ["poisson-quat", "poisson-dcm"])
def test_rate_corrector_compiled_matches_reference(estimator):
    """rest-bias (rate mode) after gradient-descent (state mode), three detectors, 9D, NaN and a
    magnetic disturbance in the data: the compiled loop equals the reference on every sample
    (quaternion, flags, every plugin's state), on an estimator whose state is its quaternion
    and on one whose is not (a DCM); a split compiled run equals one run."""
    rec = sim.simulate([sim.Rest(5.0), sim.Rotate((0, 0, 1), 1.0, 2.0), sim.Rest(10.0),
                        sim.Rotate((1, 0, 0), 0.5, 2.0), sim.Rest(5.0)], rate=100.0,
                       noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02, mag_noise=0.2), seed=1, gnss_rate=None)
    gyr, mag = rec.gyr.copy(), rec.mag.copy()
    gyr[int(6.0 * rec.rate):] += np.radians([0.3, -0.2, 0.5])
    gyr[900] = np.nan
    mag[1500:1800] *= 1.8  # a magnetic disturbance
    rec = dataclasses.replace(rec, gyr=gyr, mag=mag)
    cfg = _gradient_pipeline(use_mag=True).pipeline_config().model_dump()
    cfg["estimator"] = {"name": estimator, "params": {}}
    cfg["detectors"] += [{"name": "rest", "params": {}}, {"name": "acceleration", "params": {"threshold": 0.5}}]
    cfg["correctors"] += [{"name": "rest-bias", "params": {}}]
    p = fk.make("pipeline", nan_policy="skip", **{k: v for k, v in cfg.items() if k != "nan_policy"})
    a, b = p.run(rec, backend="numba"), p.run(rec, backend="reference")
    assert a.diagnostics["backend"] == "numba" and b.diagnostics["backend"] == "reference"
    assert np.abs(a.quat - b.quat).max() < 1e-9
    assert np.array_equal(a.flags, b.flags)
    assert (a.flags & Flag.REST).any() and (a.flags & Flag.MAG_DISTURBED).any()
    sa, sb = a.diagnostics["state"], b.diagnostics["state"]
    for xa, xb in zip(sa["cor"] + sa["det"] + [sa["x"], sa["align"]], sb["cor"] + sb["det"] + [sb["x"], sb["align"]]):
        assert np.allclose(xa, xb, rtol=0, atol=1e-9)
    assert np.linalg.norm(sa["cor"][1]) > np.radians(0.3)  # it learned
    n1 = len(rec) // 3
    r1 = p.run(rec.slice(0, n1), backend="numba")
    r2 = p.run(rec.slice(n1, len(rec)), backend="numba", state=r1.diagnostics["state"])
    assert np.abs(np.vstack([r1.quat, r2.quat]) - a.quat).max() < 1e-12
