"""The offline mode's magnetometer timing decided with the whole recording (fusionkit.offline:
mag_delay_recording, retime_mag, OfflineFilter(mag_timing=...)): a late magnetometer offsets the
heading of both passes alike, which no fusion removes; re-timing the stream removes it."""

import copy

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.errors import ConfigError
from fusionkit.offline import (OfflineFilter, gyro_delay_lever, gyro_delay_recording, mag_delay_recording, retime_gyro,
                               retime_mag)
from fusionkit.sim.motion import Rest, Rotate
from fusionkit.sim.scenarios import perturbed

RATE = 200.0


def tilted_turns(delay_samples=0.0, mag_rate=None, noise=None, seed=0, turns=30):
    """Fast turns (300 deg/s) back and forth about a body axis between two horizontal ones,
    with the magnetometer ``delay_samples`` late (and read at ``mag_rate`` and held)."""
    segs = [Rest(6.0)] + [Rotate((1, 1, 0), (1 if i % 2 == 0 else -1) * np.pi, 0.6) for i in range(turns)] + [Rest(6.0)]
    errors = sim.SensorErrors(mag_delay=delay_samples / RATE, mag_rate=mag_rate)
    return sim.simulate(segs, rate=RATE, noise=sim.Noise.mems() if noise is None else noise, seed=seed,
                        errors=errors, gnss_rate=None)


def moving(rec):
    m = np.zeros(len(rec), bool)
    m[int(6 * RATE):-int(6 * RATE)] = True
    return m


def test_late_magnetometer_offsets_both_passes_and_retiming_removes_it():
    late, on_time = tilted_turns(3.0), tilted_turns(0.0)
    inner = fk.make("recommended", heading_gain="fixed")  # (the Kalman gain weighs the late samples' departure down)
    head = {}
    for name, rec in (("late", late), ("on time", on_time)):
        for timing in ("as-is", "recording"):
            res = OfflineFilter(inner, mag_timing=timing).run(rec)
            head[name, timing] = rms_errors(res, rec, mask=moving(rec))["heading"]
            if name == "late" and timing == "recording":
                t = res.diagnostics["mag_timing"]
                assert t["applied"] and abs(t["delay"] * RATE - 3.0) < 0.1, t
    # the delay's heading offset (second order in the rate, the same in both passes) stays in the fusion as-is
    assert head["late", "as-is"] > 3.0 * head["on time", "as-is"]
    # re-timed, the late magnetometer is as good as one on time
    assert head["late", "recording"] < head["on time", "as-is"] + 0.03
    assert head["on time", "recording"] == head["on time", "as-is"]  # on time: not applied, the same result


def test_retime_mag_puts_a_late_held_magnetometer_on_time():
    quiet = sim.Noise()  # noiseless: the comparison is the timing alone
    late = tilted_turns(2.5, mag_rate=70.0, noise=quiet, turns=6)
    truth = tilted_turns(0.0, noise=quiet, turns=6)
    out = retime_mag(late.gyr, late.mag, late.time, late.dt, 2.5 / RATE)
    m = moving(late)

    def angle(a, b):
        c = np.sum(a * b, axis=1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        return np.degrees(np.arccos(np.clip(c, -1, 1)))[m]

    before, after = angle(late.mag, truth.mag), angle(out, truth.mag)
    assert before.max() > 5.0  # up to 5.4 samples old at 300 deg/s
    assert after.max() < 0.1 * before.max() and np.sqrt(np.mean(after**2)) < 0.05 * np.sqrt(np.mean(before**2))
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), np.linalg.norm(late.mag, axis=1), rtol=1e-4)  # turned only


def test_retime_mag_passes_invalid_samples_and_keeps_a_fresh_stream_on_time():
    rec = tilted_turns(0.0, turns=4)
    mag = rec.mag.copy()
    mag[100:105] = np.nan
    mag[300] = 0.0
    out = retime_mag(rec.gyr, mag, rec.time, rec.dt, 0.0)
    assert np.isnan(out[100:105]).all() and (out[300] == 0.0).all()
    ok = np.isfinite(mag).all(axis=1) & (np.linalg.norm(mag, axis=1) > 0)
    np.testing.assert_allclose(out[ok], mag[ok], atol=1e-12)  # no delay, every sample fresh: itself


def test_mag_delay_recording_kernel_equals_reference():
    rec = tilted_turns(1.5, mag_rate=120.0, turns=8)
    a = mag_delay_recording(rec, backend="numba")
    b = mag_delay_recording(rec, backend="reference")
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    assert abs(a[0] * RATE - 1.5) < 0.2
    # a declared pairing moves the estimate: the delay is counted from where the filter pairs the sample
    c = mag_delay_recording(rec, pairing=0.0)
    assert abs((c[0] - a[0]) - 0.5 / RATE) < 1e-12


def test_mag_timing_is_not_applied_without_the_information():
    rest = sim.simulate([Rest(20.0)], rate=RATE, noise=sim.Noise.mems(), seed=3, gnss_rate=None)
    d, s = mag_delay_recording(rest)
    assert np.isnan(mag_delay_recording(sim.simulate([Rest(0.1)], rate=RATE, gnss_rate=None))[0])  # no segments
    assert s * RATE > 5.0 and abs(d) < OfflineFilter.MAG_DELAY_SIGMAS * s  # at rest only noise informs it
    res = OfflineFilter(fk.make("recommended")).run(rest)
    assert res.diagnostics["mag_timing"]["applied"] is False
    six = copy.copy(rest)
    six.mag = None
    assert OfflineFilter(fk.make("recommended")).run(six).diagnostics["mag_timing"] is None


def test_mag_timing_option_is_checked():
    with pytest.raises(ConfigError, match="mag_timing"):
        OfflineFilter(fk.make("recommended"), mag_timing="late")


@pytest.mark.parametrize("pairing", [None, 0.002])
def test_retime_kernel_equals_reference(pairing):
    rec = sim.scenario("lossy", rate=RATE)  # dropped rows and gaps: uneven steps
    mag = sim.scenario("late-mag", mag_rate=70.0).mag[:len(rec)].copy()  # held copies
    gyr = rec.gyr.copy()
    gyr[50] = np.nan
    mag[200:203] = np.nan
    for delay in (0.0, 0.012, -0.007):
        a = retime_mag(gyr, mag, rec.time, rec.dt, delay, pairing, backend="numba")
        b = retime_mag(gyr, mag, rec.time, rec.dt, delay, pairing, backend="reference")
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
        assert np.isnan(a[200:203]).all()


def test_retimed_result_does_not_depend_on_the_direction_of_time():
    """Played backwards, a late magnetometer is an early one: the estimate changes sign, the
    re-timed stream is the same, and so (re-indexed) is the fused result."""
    from fusionkit.offline import reverse_recording

    rec = tilted_turns(3.0, turns=12)
    n = len(rec)
    f = fk.make("recommended", offline=True)
    a, b = f.run(rec), f.run(reverse_recording(rec))
    ta, tb = a.diagnostics["mag_timing"], b.diagnostics["mag_timing"]
    assert ta["applied"] and tb["applied"]
    assert abs(ta["delay"] + tb["delay"]) < 0.05 / RATE  # the same delay, seen from the other side
    back = b.quat[n - 2::-1]
    angle = 2 * np.degrees(np.arccos(np.clip(np.abs(np.sum(a.quat[:-1] * back, axis=1)), 0, 1)))
    assert angle.max() < 1e-3


# The gyroscope's timing against the accelerometer (OfflineFilter(gyro_timing="recording"), an option).


def test_late_gyro_lags_both_passes_and_gyro_retiming_removes_it():
    # a gyro 1 sample late (its sampling) or behind a 20 Hz low-pass (2.2 samples of group delay) lags both
    # passes alike; its delay estimated over the recording and the gyro moved onto the accelerometer's clock
    # removes it. Measured (6D inclination RMSE, deg): late-gyro 0.840 -> 0.021, lowpass-gyro 1.836 -> 0.022;
    # estimates +1.00 +- 0.04 and +2.17 +- 0.04 samples
    for name, expected in (("late-gyro", 1.0), ("lowpass-gyro", 2.17)):
        rec = sim.scenario(name)
        inner = fk.make("recommended", use_mag=False)
        as_is = rms_errors(OfflineFilter(inner).run(rec), rec)["inclination"]
        res = OfflineFilter(inner, gyro_timing="recording").run(rec)
        t = res.diagnostics["gyro_timing"]
        assert t["applied"] and abs(t["delay"] / rec.nominal_dt - expected) < 0.1
        assert rms_errors(res, rec)["inclination"] < 0.1 * as_is


@pytest.mark.parametrize("name", ["scaled-gyro", "magnet-nearby", "hand-held"])
def test_gyro_timing_is_not_applied_where_the_sensors_are_in_step(name):
    # no delay: the estimate is within its noise of 0 (scaled-gyro -0.01 +- 0.03 samples; the walks and the
    # hand's linear accelerations leave a wider estimate, not a confident one), the result is the default's
    rec = sim.scenario(name)
    inner = fk.make("recommended", use_mag=False)
    res = OfflineFilter(inner, gyro_timing="recording").run(rec)
    t = res.diagnostics["gyro_timing"]
    assert not t["applied"] and abs(t["delay"]) < OfflineFilter.MAG_DELAY_SIGMAS * t["std"]
    np.testing.assert_array_equal(res.quat, OfflineFilter(inner).run(rec).quat)
    assert OfflineFilter(inner).run(rec).diagnostics["gyro_timing"] is None  # the default: as recorded


def test_gyro_delay_recording_kernel_equals_reference_and_counts_from_the_pairing():
    rec = sim.scenario("late-gyro").slice(0, 2400)  # 12 s: the reference runs per sample in Python
    a = gyro_delay_recording(rec, backend="numba")
    b = gyro_delay_recording(rec, backend="reference")
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    assert abs(a[0] / rec.nominal_dt - 1.0) < 0.15
    # an accelerometer paired at the end of the step is half a step later than the middle: the gyro half a
    # step less late against it
    c = gyro_delay_recording(rec, pairing=0.0)
    assert abs((a[0] - c[0]) - 0.5 * rec.nominal_dt) < 1e-12
    six = copy.copy(rec)
    six.mag = None  # 6D: the magnetometer's block stays empty, the accelerometer's is the same
    np.testing.assert_allclose(gyro_delay_recording(six), a, rtol=0, atol=1e-12)
    assert np.isnan(gyro_delay_recording(sim.simulate([Rest(0.1)], rate=RATE, gnss_rate=None))[0])  # no segments


def test_retime_gyro_moves_the_rate_earlier_and_keeps_invalid_samples():
    t = np.arange(400) * 0.005
    w = np.stack([np.sin(2 * np.pi * t), np.cos(3 * t), t], axis=1)
    out = retime_gyro(w, t, 0.0125)  # 2.5 samples earlier
    np.testing.assert_allclose(out[10:-10, 2], t[10:-10] + 0.0125, atol=1e-12)  # linear: exact
    np.testing.assert_allclose(out[10:-10, 0], np.sin(2 * np.pi * (t[10:-10] + 0.0125)), atol=1e-3)
    np.testing.assert_array_equal(out[-1], w[-1])  # held past the end
    w[100] = np.nan
    out = retime_gyro(w, t, 0.0125)
    assert np.isnan(out[100]).all() and np.isfinite(np.delete(out, 100, axis=0)).all()
    np.testing.assert_array_equal(out[97:99], w[97:99])  # the samples that would read it keep their own
    assert not np.array_equal(out[99], w[99])


@pytest.mark.parametrize("bad", ["late", 0.2, float("nan"), True, None])
def test_gyro_timing_option_is_checked(bad):
    with pytest.raises(ConfigError, match="gyro_timing"):
        OfflineFilter(fk.make("recommended"), gyro_timing=bad)


@pytest.mark.parametrize("given", [0.005, np.float32(0.005), np.float64(0.005), np.int64(0), 0])
def test_gyro_timing_takes_any_real_number(given):
    # a delay read from a numpy array (float32, an integer type) is a delay like a float
    assert OfflineFilter(fk.make("recommended"), gyro_timing=given).gyro_timing == float(given)


def test_a_known_gyro_delay_is_applied_as_given():
    # a delay the user knows (a datasheet's group delay): the gyro moved by it, nothing estimated
    rec = sim.scenario("late-gyro")  # the gyro 5 ms late
    inner = fk.make("recommended", use_mag=False)
    as_is = rms_errors(OfflineFilter(inner).run(rec), rec)["inclination"]
    res = OfflineFilter(inner, gyro_timing=0.005).run(rec)
    assert res.diagnostics["gyro_timing"] == {"delay": 0.005, "std": 0.0, "applied": True}
    assert rms_errors(res, rec)["inclination"] < 0.1 * as_is
    np.testing.assert_array_equal(OfflineFilter(inner, gyro_timing=0).run(rec).quat, OfflineFilter(inner).run(rec).quat)


def test_gyro_retimed_result_does_not_depend_on_the_direction_of_time():
    # played backwards a late gyro is an early one: the estimate changes sign, the re-timed gyro is the same
    # (interpolation reads either side), so is the fused inclination (measured: +-2.17 samples, 5e-4 deg)
    from fusionkit.offline import reverse_recording

    rec = sim.scenario("lowpass-gyro")
    n = len(rec)
    f = OfflineFilter(fk.make("recommended", use_mag=False), gyro_timing="recording")
    a, b = f.run(rec), f.run(reverse_recording(rec))
    ta, tb = a.diagnostics["gyro_timing"], b.diagnostics["gyro_timing"]
    assert ta["applied"] and tb["applied"] and abs(ta["delay"] + tb["delay"]) < 0.05 / RATE
    up = np.array([0.0, 0.0, 1.0])
    up_a = fk.rotations.quat_rotate(fk.rotations.quat_conj(a.quat[1:-1]), up)
    up_b = fk.rotations.quat_rotate(fk.rotations.quat_conj(b.quat[-3::-1][:n - 2]), up)
    ang = np.degrees(np.arccos(np.clip(np.sum(up_a * up_b, axis=1), -1, 1)))
    assert np.percentile(ang[500:-500], 99) < 0.01


@pytest.mark.parametrize("short, long, applied", [
    ((1.00, 0.04), (1.02, 0.08), True),  # late-gyro: the same delay at both time scales
    ((5.64, 0.70), (2.68, 1.30), False),  # BROAD 03: significant over 0.02 s, not over 0.1 s (the hand's accelerations)
    ((6.34, 0.92), (-0.89, 1.60), False),  # BROAD 04: the two disagree
    ((5.23, 1.08), (3.49, 1.26), False),  # BROAD 06: agree, the longer one not significant (2.8 sigma)
    ((2.00, 0.10), (1.00, 0.10), False),  # both significant, they disagree: not one delay
])
def test_gyro_delay_is_applied_only_where_both_time_scales_show_one_delay(monkeypatch, short, long, applied):
    import fusionkit.offline as offline

    def fake(rec, *args, segment_time=None):
        d, s = long if segment_time == OfflineFilter.GYRO_CHECK_SEGMENT else short
        return d * rec.nominal_dt, s * rec.nominal_dt

    monkeypatch.setattr(offline, "gyro_delay_recording", fake)
    rec = sim.scenario("late-gyro").slice(0, 400)
    out, info = OfflineFilter._gyro_retimed(rec, fk.make("recommended").config, "numba")
    assert info["applied"] is applied
    assert (out is rec) is not applied


@pytest.mark.parametrize("timing", ["recording", 0.002])
def test_a_one_sample_recording_reports_its_timings(timing):
    # nothing after the sample: the forward pass is all there is, and its diagnostics still say what
    # the offline mode did with the timings (None: nothing estimated or applied; a given delay: applied)
    rec = sim.scenario("late-gyro").slice(0, 1)
    res = OfflineFilter(fk.make("recommended"), gyro_timing=timing).run(rec)
    assert res.diagnostics["offline"] and res.diagnostics["mag_timing"] is None
    assert res.diagnostics["gyro_timing"] == (None if timing == "recording" else
                                              {"delay": 0.002, "std": 0.0, "applied": True})


@pytest.mark.parametrize("rate", [200.0, 50.0, 20.0, 10.0])
def test_the_check_segment_is_five_of_the_estimates_at_any_rate(monkeypatch, rate):
    # the model's segment closes on a sample: below 50 Hz the 0.02 s one is a sample long, so a 0.1 s check
    # would be as short (10 Hz: the same estimate twice, a check that always agrees). The check's segments
    # stay five times the estimate's
    import fusionkit.offline as offline

    seen = []

    def fake(rec, *args, segment_time=None):
        seen.append(segment_time)
        return 0.0, 1.0

    monkeypatch.setattr(offline, "gyro_delay_recording", fake)
    rec = sim.simulate([Rest(1.0)], rate=rate, gnss_rate=None)
    OfflineFilter._gyro_retimed(rec, fk.make("recommended").config, "numba")
    assert seen[0] is None and seen[1] == pytest.approx(max(OfflineFilter.GYRO_CHECK_SEGMENT, 5.0 / rate))


# The gyroscope's delay fitted jointly with the accelerometer's lever arm (OfflineFilter(gyro_timing="lever")).


def test_lever_fit_finds_a_late_gyro_on_a_hand_held_sensor_and_retiming_removes_it():
    # a sensor 15 cm from the point it turns about, its gyro 1 sample late: the tangential and centripetal
    # accelerations come with the angular acceleration and keep the segment estimate from applying
    # (+1.78 +- 1.26 samples, refused); the fit with the lever arm finds the delay (measured 1.008 +- 0.071
    # samples, the lever arm (0.150, 0.030, -0.050) m) and the re-timed result is the on-time one:
    # 6D 0.553 -> 0.079 deg (0.079 without the delay)
    rec = perturbed("hand-held", errors={"gyr_delay": 1.0 / RATE})
    inner = fk.make("recommended", use_mag=False)
    as_is = rms_errors(OfflineFilter(inner).run(rec), rec)["inclination"]
    res = OfflineFilter(inner, gyro_timing="lever").run(rec)
    t = res.diagnostics["gyro_timing"]
    assert t["applied"] and abs(t["delay"] * RATE - 1.0) < 0.1
    np.testing.assert_allclose(t["lever"], (0.15, 0.03, -0.05), atol=0.005)
    assert as_is > 0.4 and rms_errors(res, rec)["inclination"] < 0.15


@pytest.mark.parametrize("name, errors, expected", [
    ("late-gyro", {}, 1.0), ("lowpass-gyro", {}, sim.lowpass_delay(20.0, RATE)),
    ("hand-held", {"gyr_lowpass": 40.0}, sim.lowpass_delay(40.0, RATE))])
def test_lever_fit_recovers_simulated_delays_to_a_tenth_of_a_sample(name, errors, expected):
    # the rule for a self-estimated offset: a delay, a low-pass's group delay, with a lever arm
    # (measured 1.000, 2.175 for 2.176, 0.982 for 0.973 samples), and applied
    rec = perturbed(name, errors=errors)
    out, t = OfflineFilter._gyro_retimed_lever(rec, fk.make("recommended").config, "numba")
    assert t["applied"] and out is not rec and abs(t["delay"] * RATE - expected) < 0.1


@pytest.mark.parametrize("name", ["hand-held", "scaled-gyro", "magnet-nearby", "tapped", "vibrating"])
def test_lever_fit_gives_zero_where_the_sensors_are_in_step(name):
    # no delay: not applied (hand-held 0.021 +- 0.028 samples; vibrating -2.4 +- 9.1, its bound 44 samples)
    rec = sim.scenario(name)
    out, t = OfflineFilter._gyro_retimed_lever(rec, fk.make("recommended").config, "numba")
    assert out is rec and not t["applied"]


def test_lever_fit_bound_grows_where_the_turning_point_moves():
    # pushes of the turning point between the turns are not in the model (a body turning about a fixed
    # point): the residual they leave could move the estimate by more than a sample, and a delay that the
    # fit finds there is not applied; without them the bound is a fraction of a sample
    deg = np.pi / 180.0
    axes = ((1, 0, 0), (0, 1, 0), (0, 0, 1))

    def turns(pushes):
        segs = [Rest(2.0)]
        for i in range(24):
            segs.append(Rotate(axes[i % 3], (1 if i % 2 == 0 else -1) * 90 * deg, 0.8))
            if pushes:
                segs.append(sim.Translate(axes[(i + 1) % 3], 0.3 * (1 if i % 2 else -1), 0.4))
        segs.append(Rest(2.0))
        return sim.simulate(segs, rate=RATE, noise=sim.Noise.mems(), seed=0, gnss_rate=None,
                            errors=sim.SensorErrors(gyr_delay=1.0 / RATE))

    d, std, bound, _ = gyro_delay_lever(turns(False))
    assert abs(d * RATE - 1.0) < 0.1 and bound * RATE < 0.5
    d, std, bound, _ = gyro_delay_lever(turns(True))
    assert bound * RATE > 1.0 and not bound < 0.5 * abs(d)


def test_lever_fit_needs_ten_periods_of_its_band():
    rec = sim.scenario("late-gyro").slice(0, 400)  # 2 s: the band's lowest frequency, 0.5 Hz, needs 20 s
    d, std, bound, lever = gyro_delay_lever(rec)
    assert np.isnan([d, std, bound]).all() and np.isnan(lever).all()
    out, t = OfflineFilter._gyro_retimed_lever(rec, fk.make("recommended").config, "numba")
    assert out is rec and not t["applied"]


def test_lever_fit_counts_ten_periods_in_time_not_samples():
    """The ten periods are the recording's duration: 21.6 s of turns on a jittery clock (intervals
    of 4, 4 and 7 ms, 5 ms on average) are fitted as on a steady one, though its median interval (4
    ms) times its sample count says 17 s (before: refused, NaN)."""
    rec = sim.scenario("late-gyro")
    n = len(rec)
    t = np.cumsum(np.resize([0.004, 0.004, 0.007], n))
    jittery = fk.Recording(gyr=rec.gyr, acc=rec.acc, t=t - t[0])
    assert n * jittery.nominal_dt < 20.0 <= t[-1] - t[0]
    assert np.isfinite(gyro_delay_lever(jittery)[:3]).all() and np.isfinite(gyro_delay_lever(rec)[:3]).all()


def test_lever_fit_on_a_still_recording_tells_nothing_and_warns_nothing():
    """Nothing in the band turns: the delay's column is zero, so the bound is infinite (not a division
    by zero that warns) and nothing is applied."""
    import warnings

    rec = sim.simulate([Rest(30.0)], rate=200.0, gnss_rate=None)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        delay, std, bound, lever = gyro_delay_lever(rec)
        res = OfflineFilter(fk.make("recommended", use_mag=False), gyro_timing="lever").run(rec)
    assert bound == np.inf and not res.diagnostics["gyro_timing"]["applied"]


def test_lever_fit_reference_equals_numba():
    # the strapdown inside is the only compiled part: its reference gives the same fit to 1e-9
    rec = perturbed("hand-held", errors={"gyr_delay": 1.0 / RATE})
    a, b = gyro_delay_lever(rec, backend="numba"), gyro_delay_lever(rec, backend="reference")
    np.testing.assert_allclose(np.array(a[:3]) * RATE, np.array(b[:3]) * RATE, rtol=0, atol=1e-9)  # samples
    np.testing.assert_allclose(a[3], b[3], rtol=0, atol=1e-9)
