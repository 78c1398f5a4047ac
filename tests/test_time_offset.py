"""The ``time-offset`` sensor model: the gyro's delay against the accelerometer and the
magnetometer, estimated from the IMU alone (fusionkit/models/time_offset.py), on simulated
recordings with known offsets (fusionkit.sim's timing error models)."""

import dataclasses
import math

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.errors import ConfigError
from fusionkit.models.time_offset import ACC, CONF, EST, MAG, NSEG, OFFSET, retime_recording
from fusionkit.testing import assert_reports_equal

RATE = 200.0
DEG = np.pi / 180


def _final(states, block, field=EST):
    """A state field at the end of the run, in samples."""
    return states[-1, block + field] * RATE


def _pipeline(models=()):
    return fk.compose({"estimator": {"name": "poisson-quat", "params": {"step": "exact"}},
                       "correctors": [{"name": "gradient-descent", "params": {"use_mag": True}}],
                       "models": list(models), "alignment": {"mode": "fixed", "duration": 1.0, "heading": "auto"}})


def _inclination_rms(q, truth):
    """RMS of the angle between the true and the estimated vertical (deg)."""
    from fusionkit.rotations import quat_to_matrix

    up = np.array([quat_to_matrix(a)[2] for a in q])
    up_t = np.array([quat_to_matrix(a)[2] for a in truth])
    return float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip((up * up_t).sum(1), -1, 1)) ** 2))))


@pytest.mark.parametrize("delay", [0.3, 0.7, 1.5])
def test_recovers_a_late_gyro(delay):
    """The ``late-gyro`` scenario (16 brisk turns, 22 s, MEMS noise) with the gyro ``delay``
    samples late: the applied offset is within a tenth of a sample of it by the end, and the
    estimate was confident (applied) within 20 s."""
    rec = sim.scenario("late-gyro", delay=delay / RATE)
    _, st = retime_recording(rec)
    assert abs(_final(st, ACC, OFFSET) - delay) < 0.1
    assert st[-1, ACC + CONF] == 1.0 and np.argmax(st[:, ACC + CONF] > 0) < 20 * RATE
    assert abs(_final(st, MAG, OFFSET) - delay) < 0.1  # the magnetometer is on the accelerometer's clock


@pytest.mark.parametrize("order,cutoff", [(1, 25.0), (2, 20.0)])
def test_recovers_a_lowpass_group_delay(order, cutoff):
    """A gyro behind its digital low-pass (first order at 25 Hz: 1.21 samples; second order at
    20 Hz: 2.18): the estimate is its low-frequency group delay to a tenth of a sample."""
    rec = sim.scenario("lowpass-gyro", cutoff=cutoff, order=order)
    _, st = retime_recording(rec, backend="numba")
    assert abs(_final(st, ACC, OFFSET) - sim.lowpass_delay(cutoff, RATE, order)) < 0.1


def test_no_offset_estimates_zero_and_costs_no_accuracy():
    """The simulator's sensors follow fusionkit's convention (interval means, all centred on the
    middle of the step): the estimate is zero to a few hundredths of a sample, and the pipeline's
    accuracy is the same with and without the model (within 0.01 deg RMS)."""
    rec = sim.scenario("late-gyro", delay=0.0)
    _, st = retime_recording(rec)
    assert abs(_final(st, ACC)) < 0.03 and abs(_final(st, MAG)) < 0.03
    base = _inclination_rms(_pipeline().run(rec).quat, rec.truth)
    with_model = _inclination_rms(_pipeline(["time-offset"]).run(rec).quat, rec.truth)
    assert abs(with_model - base) < 0.01


def test_point_sampled_accelerometer_is_half_a_sample_early():
    """An accelerometer sampled at ``t[k]`` (not a mean over the step) describes an instant half a
    sample after the gyro's mean: the model says the gyro is 0.5 samples late against it."""
    rec = sim.simulate(sim.scenarios._tumbling(16, 150.0, 0.8, 0.3), rate=RATE, noise=sim.Noise.mems(),
                       sampling="point", seed=1)
    _, st = retime_recording(rec, backend="numba")
    assert abs(_final(st, ACC) - 0.5) < 0.05


def test_late_gyro_costs_accuracy_and_the_model_gives_it_back():
    """A gyro 1.5 samples late costs an attitude filter accuracy during turns. Once the estimate
    is applied (the last 6 s) the re-timed run is as accurate as the one without the offset; with
    the offset known (``estimate=False``) the whole run is better than the raw one. Re-timed onto
    the gyro's clock (``retime="acc"``) the output is as late as the gyro: worse than raw."""
    clean = sim.scenario("late-gyro", delay=0.0)
    late = sim.scenario("late-gyro", delay=1.5 / RATE)
    tail = slice(int(16 * RATE), None)

    def rms(models, rec, part=slice(None)):
        return _inclination_rms(_pipeline(models).run(rec).quat[part], rec.truth[part])

    base, raw = rms([], clean, tail), rms([], late, tail)
    assert raw > base + 0.03
    assert rms(["time-offset"], late, tail) < base + 0.01
    known = {"estimate": False, "offset": 1.5 / RATE}
    assert rms([{"name": "time-offset", "params": known}], late) < rms([], late) - 0.05
    assert rms([{"name": "time-offset", "params": dict(known, retime="acc")}], late) > rms([], late) + 0.3


def test_linear_accelerations_do_not_bias_it():
    """Brisk translations (up to ~4 m/s^2) between the turns: they turn the measured gravity but
    carry no angular acceleration, so the estimate stays within a tenth of a sample."""
    segs = [sim.Rest(2.0)]
    for i, ax in enumerate(sim.scenarios._AXES * 2):
        segs.append(sim.Rotate(ax, (1 if i % 2 == 0 else -1) * 150 * DEG, 0.8))
        segs.append(sim.Translate(((-1) ** i, 1, 0.5 * (-1) ** i), 0.4, 0.6))
    rec = sim.simulate(segs + [sim.Rest(1.0)], rate=RATE, noise=sim.Noise.mems(), seed=3,
                       errors=sim.SensorErrors(gyr_delay=0.7 / RATE))
    assert np.abs(rec.acc - rec.acc.mean(0)).max() > 3.0  # the translations shake the accelerometer
    _, st = retime_recording(rec, backend="numba")
    assert abs(_final(st, ACC, OFFSET) - 0.7) < 0.1


def test_magnetometer_offset_is_estimated_separately():
    """A magnetometer 2 samples late (the gyro and accelerometer on time): the gyro's offset
    against the magnetometer is -2 samples, against the accelerometer 0 (the magnetometer's
    noise leaves its estimate a standard deviation of 0.1 sample after 22 s, above the default
    gate: the test applies it at 0.15); re-timed onto the
    accelerometer's clock the magnetometer matches the field seen at the true instant."""
    rec = sim.simulate(sim.scenarios._tumbling(16, 150.0, 0.8, 0.3), rate=RATE, noise=sim.Noise.mems(), seed=2,
                       errors=sim.SensorErrors(mag_delay=2.0 / RATE))
    out, st = retime_recording(rec, backend="numba", max_std=0.15)  # (the field's noise: std 0.1 sample here)
    assert abs(_final(st, MAG, OFFSET) + 2.0) < 0.1
    assert abs(_final(st, ACC)) < 0.05
    on_time = sim.simulate(sim.scenarios._tumbling(16, 150.0, 0.8, 0.3), rate=RATE, noise=sim.Noise.mems(), seed=2)
    tail = slice(len(rec) // 2, None)  # once the estimate is applied
    before = np.linalg.norm(rec.mag[tail] - on_time.mag[tail], axis=1).mean()
    after = np.linalg.norm(out.mag[tail] - on_time.mag[tail], axis=1).mean()
    assert after < 0.5 * before


@pytest.mark.parametrize("retime", ["gyro", "acc"])
def test_kernel_equals_reference_in_a_pipeline_and_streams(retime):
    """Both clocks: the compiled pipeline equals the reference on every sample (and the model's
    state), and so does a stream of update() calls and a run split in two (the state carried)."""
    rec = sim.scenario("late-gyro", delay=0.7 / RATE)
    p = _pipeline([{"name": "time-offset", "params": {"retime": retime}}])
    ref, fast = p.run(rec, backend="reference"), p.run(rec, backend="numba")
    assert fast.diagnostics["backend"] == "numba"
    assert np.abs(fast.quat - ref.quat).max() < 1e-9
    s_ref, s_fast = ref.diagnostics["state"]["mod"][0], fast.diagnostics["state"]["mod"][0]
    assert np.abs(s_fast - s_ref).max() < 1e-9 and s_ref[ACC + CONF] == 1.0
    assert_reports_equal(fast.diagnostics["models"], ref.diagnostics["models"])
    half = len(rec) // 2
    first = p.run(rec.slice(0, half), backend="numba")
    second = p.run(rec.slice(half, len(rec)), backend="numba", state=first.diagnostics["state"])
    assert np.abs(np.vstack([first.quat, second.quat]) - ref.quat).max() < 1e-9
    p.reset()
    n = 1500
    streamed = np.array([p.update(g, a, m, dt=d) for g, a, m, d in zip(rec.gyr[:n], rec.acc[:n], rec.mag[:n],
                                                                         rec.dt[:n])])
    assert np.abs(streamed - ref.quat[:n]).max() < 1e-9


def test_the_pipeline_reports_the_offsets():
    """``diagnostics["models"]["time-offset"]`` on ``late-gyro`` (the gyro one sample, 5 ms, late;
    reference path): the gyro's delay against the accelerometer and against the magnetometer (on
    the accelerometer's clock) in s, each within a tenth of a sample, confident and applied, their
    standard deviations below ``max_std`` (0.05 sample); with ``estimate=False`` no estimate (NaN,
    inf) and the configured offset applied."""
    rec = sim.scenario("late-gyro")
    delay = rec.meta["errors"].gyr_delay
    rep = _pipeline(["time-offset"]).run(rec, backend="reference").diagnostics["models"]["time-offset"]
    assert rep["sample_interval_s"] == 1.0 / RATE and rep["applied"] is True
    for key in ("offset", "mag_offset"):
        assert abs(rep[f"{key}_s"] - delay) < 0.1 / RATE and rep[f"{key}_applied_s"] == rep[f"{key}_s"]
        assert 0.0 < rep[f"{key}_std_s"] < 0.05 / RATE and rep[f"{key}_confident"] is True
        assert rep[f"{key}_segments"] >= 50
    fixed = _pipeline([{"name": "time-offset", "params": {"estimate": False, "offset": 0.002}}])
    rep = fixed.run(rec.slice(0, 400), backend="reference").diagnostics["models"]["time-offset"]
    assert math.isnan(rep["offset_s"]) and rep["offset_std_s"] == math.inf and rep["offset_segments"] == 0
    assert rep["offset_applied_s"] == 0.002 and rep["offset_confident"] is False and rep["applied"] is True


def test_acc_clock_moves_the_accelerometer_not_the_gyro():
    """``retime="acc"``: the gyro passes unchanged and the accelerometer is rotated back by the
    offset (its norm kept); ``"gyro"``: the accelerometer passes unchanged."""
    rec = sim.scenario("late-gyro", delay=1.0 / RATE)
    out, _ = retime_recording(rec, retime="acc", estimate=False, offset=1.0 / RATE)
    assert np.array_equal(out.gyr, rec.gyr)
    assert np.allclose(np.linalg.norm(out.acc, axis=1), np.linalg.norm(rec.acc, axis=1))
    moved = np.linalg.norm(out.acc - rec.acc, axis=1)
    assert moved.max() > 0.05
    out_g, _ = retime_recording(rec, estimate=False, offset=1.0 / RATE)
    assert np.array_equal(out_g.acc, rec.acc)
    k = 900  # a linear extrapolation of the gyro through its last two samples, by one sample
    assert np.allclose(out_g.gyr[k], 2 * rec.gyr[k] - rec.gyr[k - 1])


def test_invalid_samples_and_gaps():
    """NaN gyro and accelerometer samples, lost rows and timestamp gaps: no NaN reaches the
    output, the samples pass flagged, and the estimate still recovers the offset."""
    segs = sim.scenarios._tumbling(28, 150.0, 0.8, 0.3)
    rec = sim.simulate(segs, rate=RATE, noise=sim.Noise.mems(), seed=4,
                       errors=sim.SensorErrors(gyr_delay=0.7 / RATE, drop_rate=0.02, gaps=((6.0, 0.25), (14.0, 1.0))))
    gyr, acc = rec.gyr.copy(), rec.acc.copy()
    gyr[300:305] = np.nan
    acc[2000:2010] = np.nan
    bad = dataclasses.replace(rec, gyr=gyr, acc=acc)
    out, st = retime_recording(bad, backend="numba")
    assert np.isfinite(st).all()
    assert np.array_equal(np.isfinite(out.gyr), np.isfinite(gyr)) and np.array_equal(np.isfinite(out.acc),
                                                                                       np.isfinite(acc))
    assert abs(_final(st, ACC, OFFSET) - 0.7) < 0.1
    p = fk.compose({"estimator": "poisson-quat", "models": ["time-offset"], "correctors": ["gradient-descent"],
                    "alignment": {"mode": "fixed", "duration": 1.0}, "nan_policy": "skip"})
    ref, fast = p.run(bad, backend="reference"), p.run(bad, backend="numba")
    assert np.isfinite(ref.quat).all() and np.abs(fast.quat - ref.quat).max() < 1e-9


def test_without_rotation_it_stays_at_the_configured_offset():
    """Translations only: no angular acceleration, nothing to estimate from; the configured
    offset stays applied and the estimate never becomes confident."""
    segs = [sim.Rest(2.0)] + [sim.Translate(((-1) ** i, 1, 0), 0.5, 0.8) for i in range(12)] + [sim.Rest(1.0)]
    rec = sim.simulate(segs, rate=RATE, noise=sim.Noise.mems(), seed=5)
    _, st = retime_recording(rec, backend="numba", offset=0.002)
    assert not st[:, ACC + CONF].any()
    assert np.all(st[:, ACC + OFFSET] == 0.002)


def test_config_is_checked():
    with pytest.raises(ConfigError, match="retime"):
        fk.make("time-offset", kind="model", retime="mag")
    with pytest.raises(ConfigError, match="offset"):
        fk.make("time-offset", kind="model", offset=1.0)


def test_a_magnetometer_at_a_lower_rate_is_timed_by_its_fresh_samples():
    """A magnetometer at 40 Hz held over five 200 Hz samples: repeated samples neither start nor
    close a segment, so the fresh ones (on time) give an offset of ~0, not the hold's mean delay
    of two samples, and fewer segments enter than at the full rate."""
    rec = sim.simulate(sim.scenarios._tumbling(16, 150.0, 0.8, 0.3), rate=RATE, noise=sim.Noise.mems(), seed=6)
    held = dataclasses.replace(rec, mag=rec.mag[(np.arange(len(rec)) // 5) * 5])
    _, full = retime_recording(rec, backend="numba")
    _, st = retime_recording(held, backend="numba")
    assert abs(_final(st, MAG)) < 0.05
    assert st[-1, MAG + NSEG] < 0.9 * full[-1, MAG + NSEG]
