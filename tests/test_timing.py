"""Sensor lags against the reference (fusionkit.benchmarking.timing): known lags are recovered
on simulated data, the search is robust to reference glitches and gaps, bad input is refused."""

import dataclasses
import math

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.timing import sensor_lags
from fusionkit.conventions import change_frame
from fusionkit.errors import InputError

DEG = np.pi / 180.0
RATE = 200.0


def _rotations(sampling="mean"):
    segs = [sim.Rest(1.0)] + [sim.Rotate(ax, 150 * DEG * s, 0.8) for s in (1, -1)
                              for ax in ((1, 0, 0), (0, 1, 0), (1, 1, 1), (0, 1, -1))] + [sim.Rest(1.0)]
    return sim.simulate(segs, rate=RATE, gnss_rate=None, sampling=sampling)


def _delayed(x, lag):
    """``x`` seen ``lag`` samples late: sample k holds the value at k - lag (linear interpolation
    of a signal sampled 20 times finer would be better; at these rates linear is exact enough)."""
    n = len(x)
    return np.stack([np.interp(np.arange(n) - lag, np.arange(n), x[:, i]) for i in range(3)], axis=1)


def test_the_conventions_are_measured():
    """Interval means (the default, fusionkit's convention) lag by half a sample; a point sample
    at t[k] by none; the gyro (a mean rate) by half a sample in both."""
    mean, point = sensor_lags(_rotations("mean")), sensor_lags(_rotations("point"))
    assert mean.gyr == pytest.approx(0.5, abs=0.03)
    assert mean.acc == pytest.approx(0.5, abs=0.03)
    assert mean.mag == pytest.approx(0.5, abs=0.03)
    assert point.gyr == pytest.approx(0.5, abs=0.03)
    assert point.acc == pytest.approx(0.0, abs=0.03)
    assert point.mag == pytest.approx(0.0, abs=0.03)
    assert mean.mag_rms < 0.05  # uT, the simulator's field is constant
    assert math.isnan(sensor_lags(dataclasses.replace(_rotations(), mag=None)).mag)
    assert mean.rate == pytest.approx(RATE)
    assert mean.gyr_seconds == pytest.approx(mean.gyr / RATE)
    assert "samples" in str(mean)


@pytest.mark.parametrize("gyr_lag, acc_lag, mag_lag", [(0.75, 0.0, 3.7), (-0.4, 1.3, 0.0), (2.0, 0.5, -1.2)])
def test_a_known_delay_is_recovered(gyr_lag, acc_lag, mag_lag):
    rec = _rotations("mean")
    rec = dataclasses.replace(rec, gyr=_delayed(rec.gyr, gyr_lag), acc=_delayed(rec.acc, acc_lag),
                              mag=_delayed(rec.mag, mag_lag))
    lags = sensor_lags(rec)
    assert lags.gyr == pytest.approx(0.5 + gyr_lag, abs=0.05)
    assert lags.acc == pytest.approx(0.5 + acc_lag, abs=0.05)
    assert lags.mag == pytest.approx(0.5 + mag_lag, abs=0.05)


def _translations():
    """Translations with rotations between them, and the true position (m, ENU) at each sample."""
    segs = [sim.Rest(1.0)]
    for i, d in enumerate(((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 1, 0), (0, -1, -1))):
        segs += [sim.Translate(d, 0.4, 0.6), sim.Rotate((i % 2, 1, 1), 60 * DEG, 0.7)]
    rec = sim.simulate(segs, rate=RATE, gnss_rate=None)
    pos, p = [np.zeros(3)], np.zeros(3)
    for seg in segs:
        m = max(1, round(seg.duration * RATE))
        u = np.arange(1, m + 1) / m
        if isinstance(seg, sim.Translate):
            d = np.asarray(seg.direction, float) / np.linalg.norm(seg.direction)
            pos.extend(p + seg.distance * (u - np.sin(2 * np.pi * u) / (2 * np.pi))[:, None] * d)
            p = p + seg.distance * d
        else:
            pos.extend(np.tile(p, (m, 1)))
    return rec, np.array(pos)


def test_linear_accelerations_from_the_reference_position():
    """With translations in the data, the reference position's second difference in the model
    explains the specific force (the gravity-only model leaves the linear accelerations in its
    residual; here they are not correlated with the rotations, so its lag still holds, unlike on
    BROAD's translation trials below); any earth frame; the position is read from ``meta``."""
    rec, pos = _translations()
    assert pos.shape == (len(rec), 3)
    with_pos = sensor_lags(rec, position=pos)
    assert with_pos.acc_model == "position"
    assert with_pos.acc == pytest.approx(0.5, abs=0.05)
    gravity = sensor_lags(rec, position=None)
    assert gravity.acc_model == "gravity"
    assert gravity.acc_rms > 5 * with_pos.acc_rms
    ned = dataclasses.replace(rec, truth=change_frame(rec.truth, "ENU", "NED"), truth_frame="NED",
                              meta={"ref_pos": pos[:, [1, 0, 2]] * [1, 1, -1]})
    assert sensor_lags(ned).acc == pytest.approx(with_pos.acc, abs=1e-9)  # "auto" reads meta["ref_pos"]
    # and meta["ref_pos_ned"] (the GNSS scenarios, simulated flights), in any truth frame: read as gravity alone
    # before, their vehicles' accelerations gave the GNSS flights +7.86 / -1.52 "samples" of lag
    flight = dataclasses.replace(ned, meta={"ref_pos_ned": ned.meta["ref_pos"]})
    assert sensor_lags(flight).acc_model == "position"
    assert sensor_lags(flight).acc == pytest.approx(with_pos.acc, abs=1e-9)
    enu = dataclasses.replace(rec, meta={"ref_pos_ned": ned.meta["ref_pos"]})
    assert sensor_lags(enu).acc == pytest.approx(with_pos.acc, abs=1e-9)
    part = ned.slice(100, 1500)  # per-sample arrays in meta are sliced with the samples
    assert part.meta["ref_pos"].shape == (1400, 3)
    assert sensor_lags(part).acc == pytest.approx(0.5, abs=0.05)
    with pytest.raises(InputError, match="shape"):
        sensor_lags(rec, position=pos[:-1])
    with pytest.raises(InputError, match="'auto' or None"):
        sensor_lags(rec, position="ENU")


def test_reference_in_another_frame_gives_the_same_lags():
    rec = _rotations("mean")
    ned = dataclasses.replace(rec, truth=change_frame(rec.truth, rec.truth_frame, "NED"), truth_frame="NED")
    a, b = sensor_lags(rec), sensor_lags(ned)
    assert b.gyr == pytest.approx(a.gyr, abs=1e-9)
    assert b.acc == pytest.approx(a.acc, abs=1e-9)


def test_glitches_and_gaps_in_the_reference_do_not_move_the_lag():
    """Optical references lose markers (NaN) and flip for a sample (a 90 degree jump): both are
    left out, the lag stays; the residual without glitches is small."""
    rec = _rotations("mean")
    truth = rec.truth.copy()
    truth[500:520] = np.nan
    truth[900] = np.array([truth[900, 1], -truth[900, 0], truth[900, 3], -truth[900, 2]])  # 180 deg off
    truth[1300] = np.array([0.5, 0.5, 0.5, 0.5])
    gyr = rec.gyr.copy()
    gyr[700] = np.nan
    lags = sensor_lags(dataclasses.replace(rec, truth=truth, gyr=gyr))
    assert lags.gyr == pytest.approx(0.5, abs=0.05)
    assert lags.acc == pytest.approx(0.5, abs=0.05)
    assert lags.samples < len(rec)
    assert sensor_lags(rec).gyr_rms < 0.05


def test_dropped_samples_and_jittered_timestamps():
    """Timestamps that jitter and samples that were dropped (logs): the lag is found on the
    recording's own clock and the samples next to a dropout are left out."""
    rec = _rotations("mean")
    keep = np.ones(len(rec), bool)
    keep[[400, 401, 402, 900, 1500, 1501]] = False
    t = rec.time + np.random.default_rng(1).uniform(-0.02, 0.02, len(rec)) / RATE
    cut = fk.Recording(gyr=rec.gyr[keep], acc=rec.acc[keep], mag=rec.mag[keep], t=t[keep], truth=rec.truth[keep],
                       movement=rec.movement[keep])
    lags = sensor_lags(cut)
    assert lags.gyr == pytest.approx(0.5, abs=0.05) and lags.acc == pytest.approx(0.5, abs=0.05)
    assert lags.rate == pytest.approx(RATE, rel=1e-3)


def test_no_minimum_inside_the_range_is_nan():
    rec = _rotations("mean")
    lags = sensor_lags(dataclasses.replace(rec, acc=_delayed(rec.acc, 6.0)), max_lag=3.0)
    assert sensor_lags(dataclasses.replace(rec, acc=_delayed(rec.acc, 6.0))).acc == pytest.approx(6.5, abs=0.05)
    assert math.isnan(lags.acc) and math.isnan(lags.acc_rms)
    assert lags.gyr == pytest.approx(0.5, abs=0.03)


def test_bad_input_is_refused():
    rec = _rotations("mean")
    with pytest.raises(InputError, match="no reference"):
        sensor_lags(dataclasses.replace(rec, truth=None))
    with pytest.raises(InputError, match="max_lag"):
        sensor_lags(rec, step=0.0)
    with pytest.raises(InputError, match=r"need a finite max_lag > 0 \(samples\).* got max_lag=inf"):
        sensor_lags(rec, max_lag=np.inf)  # (OverflowError from the grid's size, once)
    with pytest.raises(InputError, match="too short"):
        sensor_lags(rec.slice(0, 20))
    with pytest.raises(InputError, match="too few usable"):
        sensor_lags(dataclasses.replace(rec, movement=np.zeros(len(rec), bool)))
    with pytest.raises(InputError, match="finite reference"):
        sensor_lags(dataclasses.replace(rec, truth=np.full((len(rec), 4), np.nan)))


def test_broad_gyro_runs_behind_its_reference(broad_dir):
    """What BENCHMARKS.md states about BROAD's clocks (skipped without the data): the
    accelerometer is near fusionkit's convention (0.4-0.8 samples on every trial), the gyroscope
    runs behind it (1.2) and the magnetometer further behind (2.6-5). On each trial's first 70 s
    (20000 samples; the bounds hold there as on the whole trial, which takes three times longer)."""
    for name in ("03_undisturbed_slow_rotation_C.hdf5", "06_undisturbed_fast_rotation_A.hdf5",
                 "15_undisturbed_fast_translation_A.hdf5"):
        rec = fk.load(broad_dir / name).slice(0, 20000)
        lags = sensor_lags(rec)  # with the optical position (meta["ref_pos"])
        assert lags.acc_model == "position"
        assert lags.gyr == pytest.approx(1.2, abs=0.07), name
        assert 0.35 < lags.acc < 0.85, name
        assert lags.gyr - lags.acc > 0.3, name
        assert 2.5 < lags.mag < 5.0, name  # the magnetometer is later still
    # without the position, the fast translation cannot be timed (measured: 2.6 samples)
    assert not 0.35 < sensor_lags(rec, position=None).acc < 0.85


def test_gnss_ins_sim_holds_the_rate_forward(broad_dir):
    """gnss-ins-sim's documented timing (its README: the rate at t[k] is held over [t[k], t[k+1]))
    is measured as a gyro half a sample *ahead* of the reference (skipped without the data)."""
    path = broad_dir.parent / "gnss" / "heli_cruise" / "heli_cruise.h5"
    if not path.exists():
        pytest.skip("no gnss data")
    assert sensor_lags(fk.load(path).slice(0, 10000)).gyr == pytest.approx(-0.5, abs=0.03)  # its first 100 s
