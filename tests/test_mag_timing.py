"""The magnetometer's timing against the gyroscope: the simulator's sample-and-hold and delays
(``late-mag``), ``mag-heading``'s held samples (``mag_hold``), and the ``time-offset`` model's
magnetometer-only mode that ``recommended`` composes with ``mag_offset_estimate``."""

import dataclasses

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.sim.errors import held_source

RATE = 200.0


def _total(rec, **params):
    return rms_errors(fk.make("recommended", **params).run(rec), rec)["total"]


def _fixed(rec, **params):
    """with the fixed heading gain, the one the timing costs most (the Kalman gain weighs a late
    sample's departure from the reference down)"""
    return _total(rec, heading_gain="fixed", **params)


def test_held_source_is_the_newest_reading():
    """Read at 50 Hz on a 200 Hz grid: every fourth sample fresh, the others repeat it (ages 1-3);
    at a rate that does not divide (70 of 200 Hz) the ages are 0-2 and a fresh sample is never
    later than its reading's instant."""
    assert held_source(9, 50.0, 200.0).tolist() == [0, 0, 0, 0, 4, 4, 4, 4, 8]
    src = held_source(2000, 70.0, 200.0)
    age = np.arange(2000) - src
    assert age.min() == 0 and age.max() == 2 and abs((age == 0).mean() - 0.35) < 0.01
    assert np.all(src / 200.0 >= np.floor(np.arange(2000) * 0.35 + 1e-9) / 70.0 - 1e-12)
    assert held_source(5, 300.0, 200.0).tolist() == [0, 1, 2, 3, 4]


def test_simulated_sample_and_hold_repeats_readings_exactly():
    """``mag_rate``: held samples repeat their reading to the bit (noise included), fresh ones are
    the on-time recording's; the gyro and accelerometer are untouched."""
    on_time = sim.scenario("late-mag", delay=0.0, turns=4)
    held = sim.scenario("late-mag", delay=0.0, turns=4, mag_rate=50.0)
    src = held_source(len(held), 50.0, RATE)
    assert np.array_equal(held.mag, on_time.mag[src])
    assert np.array_equal(held.gyr, on_time.gyr) and np.array_equal(held.acc, on_time.acc)
    fresh = np.r_[True, np.any(held.mag[1:] != held.mag[:-1], axis=1)]
    assert abs(fresh.mean() - 0.25) < 0.01
    with pytest.raises(fk.errors.InputError, match="mag_rate"):
        sim.SensorErrors(mag_rate=0.0)


def test_heading_pairs_a_held_sample_with_its_fresh_orientation():
    """A magnetometer read at 50 Hz and held on a 200 Hz IMU: paired as new readings
    (``mag_hold=False``) its held samples are up to 3 samples late and cost heading accuracy in
    brisk turns; paired with their fresh sample's orientation the error is within 0.01 deg of the
    on-time magnetometer's (0.015 with all of recommended's defaults). Where values never repeat the switch changes nothing, to the bit."""
    on_time = sim.scenario("late-mag", delay=0.0)
    held = sim.scenario("late-mag", delay=0.0, mag_rate=50.0)
    base, hold, no_hold = _fixed(on_time), _fixed(held), _fixed(held, mag_hold=False)
    assert no_hold > base + 0.02
    assert hold < base + 0.01
    # (the defaults since stop 21, the gyro's rate error learned: 0.183 against 0.173; before, 0.188 against 0.178)
    assert _total(held) < _total(on_time) + 0.015
    a = fk.make("recommended").run(on_time)
    b = fk.make("recommended", mag_hold=False).run(on_time)
    assert np.array_equal(a.quat, b.quat)


@pytest.mark.parametrize("hold", [True, False])
def test_heading_hold_reference_equals_numba(hold):
    """Held samples, an invalid magnetometer sample between two equal ones (not a hold: the
    reading was lost) and the state carried across a split run: reference == numba to 1e-9."""
    rec = sim.scenario("late-mag", delay=0.0, turns=3, mag_rate=70.0)
    mag = rec.mag.copy()
    mag[400] = np.nan
    mag[401] = mag[399]
    rec = dataclasses.replace(rec, mag=mag)
    f = fk.make("recommended", mag_hold=hold, nan_policy="skip")
    ref, fast = f.run(rec, backend="reference"), f.run(rec, backend="numba")
    assert fast.diagnostics["backend"] == "numba"
    assert np.abs(fast.quat - ref.quat).max() < 1e-9
    # every corrector's state, mag-heading's last levelled field (dip's sine, east, north) included: the
    # kernel takes a held sample's from the fresh one's instead of turning the field again
    for sf, sr in zip(fast.diagnostics["state"]["cor"], ref.diagnostics["state"]["cor"]):
        assert np.abs(sf - sr).max() < 1e-9
    half = len(rec) // 2  # (the held value across the split: the state carries the last sample)
    parts = {}
    for backend in ("reference", "numba"):
        first = f.run(rec.slice(0, half), backend=backend)
        second = f.run(rec.slice(half, len(rec)), backend=backend, state=first.diagnostics["state"])
        parts[backend] = np.vstack([first.quat, second.quat])
    assert np.abs(parts["numba"] - parts["reference"]).max() < 1e-9
    assert np.abs(parts["reference"][half:] - ref.quat[half:]).max() < 1e-4


def _estimate(rec, **params):
    """recommended with the delay estimate: the result and the estimate's block (samples)."""
    from fusionkit.correctors.heading import MAG_DELAY
    from fusionkit.models.time_offset import CONF, EST, STD

    f = fk.make("recommended", mag_delay_estimate=True, **params)
    res = f.run(rec)
    s = res.diagnostics["state"]["cor"][[c.name for c in f.correctors].index("mag-heading")]
    return res, s[MAG_DELAY + EST] * RATE, s[MAG_DELAY + STD] * RATE, bool(s[MAG_DELAY + CONF])


@pytest.mark.parametrize("delay", [0.0, 0.4, 1.0, 2.5])
def test_estimate_recovers_a_late_magnetometer(delay):
    """``late-mag`` (32 brisk turns, 35 s, MEMS noise) with the magnetometer ``delay`` samples
    late: the estimate (gyro against magnetometer) is ``-delay`` to a tenth of a sample and
    applied; the heading is then as accurate as with an on-time magnetometer (within 0.01 deg).
    With no delay it costs nothing (within 0.002 deg of the run without the estimate)."""
    rec = sim.scenario("late-mag", delay=delay / RATE)
    res, est, std, conf = _estimate(rec)
    assert abs(est + delay) < 0.1 and conf and std < 0.1
    on_time = _total(sim.scenario("late-mag", delay=0.0))
    assert rms_errors(res, rec)["total"] < on_time + 0.01
    if delay == 0.0:
        assert abs(rms_errors(res, rec)["total"] - _total(rec)) < 0.002
    else:
        assert _total(rec) > on_time + 0.005 * delay  # the late magnetometer costs, the estimate gives it back


def test_estimate_of_a_lowpass_and_a_held_magnetometer():
    """A magnetometer behind a second-order 20 Hz low-pass estimates its group delay (2.18
    samples) to a tenth; one read at 70 Hz, held, and a sample late estimates the fresh samples'
    delay (1 sample; the held ones are paired by their age)."""
    lp = sim.scenario("late-mag", delay=0.0, cutoff=20.0)
    _, est, _, conf = _estimate(lp)
    assert abs(est + sim.lowpass_delay(20.0, RATE, 2)) < 0.1 and conf
    held = sim.scenario("late-mag", delay=1.0 / RATE, mag_rate=70.0)
    res, est, _, conf = _estimate(held)
    assert abs(est + 1.0) < 0.1 and conf
    assert rms_errors(res, held)["total"] < _total(held) - 0.01


def test_estimate_is_not_misled_by_magnetic_disturbances():
    """A walk to within 0.3 m of a magnet, brisk turns there, and back (``magnet-nearby``'s
    magnet; the magnetometer a sample late): the disturbance is constant while the body turns in
    place and the walks carry no angular acceleration, so the estimate is -1 sample to 0.1. A hard
    iron offset it cannot fit (an uncalibrated magnetometer: the field's direction does not follow
    the body's turns) is never applied."""
    dipoles = sim.scenarios.magnet_nearby(rate=RATE).meta["errors"].dipoles
    turns = sim.scenarios._tumbling(24, 150.0, 0.8, 0.3)[1:-1]
    walk = [sim.Rest(2.0)] + turns[:8] + [sim.Translate((1, 0, 0), 2.0, 6.0), sim.Rest(1.0)] + turns + \
        [sim.Translate((-1, 0, 0), 2.0, 6.0), sim.Rest(2.0)]
    rec = sim.scenarios._run("walk", walk, sim.SensorErrors(mag_delay=1.0 / RATE, dipoles=dipoles), RATE, None, 0)
    assert np.ptp(np.linalg.norm(rec.mag, axis=1)) > 8.0  # the magnet changes the field's norm by 8+ uT
    _, est, _, conf = _estimate(rec)
    assert conf and abs(est + 1.0) < 0.1
    iron = sim.scenarios._run("iron", sim.scenarios._tumbling(32, 150.0, 0.8, 0.3),
                              sim.SensorErrors(mag_delay=1.0 / RATE, mag_offset=(15.0, -25.0, 10.0)), RATE, None, 0)
    _, _, _, conf = _estimate(iron)
    assert not conf


def test_configured_pairing_until_confident_and_reference_equals_numba():
    """Until the estimate is confident the configured pairing is used, to the bit (the middle of
    the step, or a given ``mag_delay``); once applied, reference == numba to 1e-9 on every sample
    and in the corrector's state, held samples included."""
    rec = sim.scenario("late-mag", delay=2.0 / RATE, turns=6, mag_rate=150.0)
    for params in ({}, {"mag_delay": 0.004}):
        never = fk.make("recommended", mag_delay_estimate=True, mag_delay_max_std=1e-6, **params).run(rec)
        assert np.array_equal(never.quat, fk.make("recommended", **params).run(rec).quat)
    f = fk.make("recommended", mag_delay_estimate=True, mag_delay_max_std=0.5)
    ref, fast = f.run(rec, backend="reference"), f.run(rec, backend="numba")
    assert fast.diagnostics["backend"] == "numba"
    assert np.abs(fast.quat - ref.quat).max() < 1e-9
    s_ref, s_fast = ref.diagnostics["state"]["cor"][2], fast.diagnostics["state"]["cor"][2]
    assert np.abs(s_ref - s_fast).max() < 1e-9
    _, est, _, conf = _estimate(rec, mag_delay_max_std=0.5)
    assert conf and abs(est + 2.0) < 0.3  # 6 turns: applied, near the 2 samples


def test_a_recalibration_applies_on_the_held_reading_after_its_segment():
    """A magnetometer read at 10 Hz and held on a 100 Hz IMU, with a hard iron that
    ``mag-calibration`` learns: its segments close on fresh readings only (a held one is no new
    observation), and what a segment changes applies from the next sample on, here the same reading
    held: flagged MAG_HELD (calibrated otherwise than the sample before), ``mag-heading`` keeps it
    paired with its fresh sample's orientation (the pairing in its state does not move) and re-expresses
    its heading by the calibration's change of that one reading, so the heading is within 20 deg of
    the truth 1 s later (from 111). Before (segments closed on held samples too): first applied at
    28.7 s. Applied on the fresh sample itself, the change would be read from two readings 0.1 s apart,
    the body turned between them (docs/algorithms/models.md). Reference and kernel alike."""
    from fusionkit.correctors.heading import _QH
    from fusionkit.sim.errors import SensorErrors
    from fusionkit.sim.scenarios import _tumbling

    rec = sim.simulate(_tumbling(8, 200.0, 3.0, 0.5), rate=100.0, noise=sim.Noise.mems(), seed=0,
                       errors=SensorErrors(mag_offset=(15.0, -25.0, 10.0), mag_rate=10.0))
    f = fk.make("recommended", mag_held_readings="once")  # (the option; the default counts each sample)
    ref, fast = f.run(rec, backend="reference"), f.run(rec, backend="numba")
    assert np.array_equal(ref.flags, fast.flags) and np.abs(fast.quat - ref.quat).max() < 1e-9
    recal = np.flatnonzero(fast.flags & fk.Flag.MAG_RECALIBRATED)
    fresh = np.r_[True, np.any(rec.mag[1:] != rec.mag[:-1], axis=1)]
    k = int(recal[0])
    assert k < 1000 and fresh[recal - 1].all() and not fresh[recal].any()
    assert np.all(fast.flags[recal] & fk.Flag.MAG_HELD)
    error = np.degrees(2.0 * np.arccos(np.abs(np.sum(fast.quat * rec.truth, axis=1)).clip(0.0, 1.0)))
    assert error[k - 1] > 90.0 and error[k + 100] < 20.0
    i = [c.name for c in f.correctors].index("mag-heading")
    for backend in ("reference", "numba"):
        before = f.run(rec.slice(0, k), backend=backend)
        at = f.run(rec.slice(k, k + 1), backend=backend, state=before.diagnostics["state"])
        qh = [r.diagnostics["state"]["cor"][i][_QH:_QH + 4] for r in (before, at)]
        assert np.abs(qh[1] - qh[0]).max() < 1e-9, backend


def test_heading_keeps_a_flagged_held_sample_paired_with_its_fresh_one():
    """MAG_HELD (a sensor model calibrated a held reading otherwise than the sample before: routine with
    ``mag-calibration``'s held_readings="once", whose change applies on the sample after its segment's
    fresh reading, often that reading held): ``mag-heading`` pairs
    such a sample with its fresh sample's orientation though its value changed (the pairing in its
    state does not move), unflagged it is a fresh one; reference and kernel alike."""
    from fusionkit.correctors.heading import _QH, mag_heading_kernel
    from fusionkit.protocols import Sample
    from fusionkit.rotations import quat_from_rotvec
    from fusionkit.types import CHANNEL_SIZE

    rec = sim.scenario("late-mag", delay=0.0, turns=2)
    cor = fk.make("mag-heading", kind="corrector")
    kern = cor.kernel(None)
    p, ch, bias = kern.params, np.zeros(CHANNEL_SIZE), np.zeros(3)
    s = cor.initial_state(rec.nominal_dt, "ENU")
    k = 500  # turning (after a 2 s rest)
    for i in range(k):
        cor.compose(s, rec.truth[i], Sample(rec.gyr[i], rec.acc[i], rec.mag[i], float(rec.dt[i])), bias,
                    rec.gyr[i], 0)
    g, a, m, dt = rec.gyr[k], rec.acc[k], rec.mag[k - 1] + 1.0, float(rec.dt[k])  # the reading, recalibrated
    h = quat_from_rotvec(-g * (0.5 * dt))
    for flags in (int(fk.Flag.MAG_HELD), 0):
        s_ref, s_fast = s.copy(), s.copy()
        cor.compose(s_ref, rec.truth[k], Sample(g, a, m, dt), bias, g, flags)
        mag_heading_kernel(rec.truth[k].copy(), s_fast, bias.copy(), *g, *h, *a, *m, True, True, flags, dt, p, ch, *kern.static)
        assert np.abs(s_fast - s_ref).max() < 1e-9
        moved = np.abs(s_ref[_QH:_QH + 4] - s[_QH:_QH + 4]).max()
        assert (moved == 0.0) if flags else (moved > 1e-3)


def test_a_reexpressed_heading_relearns_the_reference_it_was_learned_with():
    """A 50 Hz magnetometer held on a 100 Hz IMU, a (15, -25, 10) uT hard iron, slow turns: the
    magnetic reference and the heading are learned from the raw field at rest, and the raw field is
    off that reference once the body turns (the iron). The calibration, first applied at 7.57 s,
    moves the field by less than the thresholds at that orientation, so the change alone
    (``_moved``) read the departure as an earth-fixed disturbance's and kept the reference: every
    sample after was rejected and the heading stayed 31 deg off until the new-field test, 20 s of
    turning later. The re-expression says otherwise (the learned field, read through the new
    calibration, is this calibrated sample's: the iron was there when the reference was learned), so
    the reference is learned again: within 10 deg 4 s later. Reference and kernel alike. So too with a
    0.3 s gap right after the segment's closing sample: the change waits for the first sample with a
    valid gyro (before: delivered on the gap's sample, where the orientation was held, it read the body's
    turn across the gap as the calibration's change and the heading stayed 111 deg off for 25 s)."""
    from fusionkit.sim.errors import SensorErrors
    from fusionkit.sim.scenarios import _tumbling

    def held(gaps=()):
        return sim.simulate(_tumbling(16, 200.0, 3.0, 0.5), rate=100.0, noise=sim.Noise.mems(), seed=0,
                            errors=SensorErrors(mag_offset=(15.0, -25.0, 10.0), mag_rate=50.0, gaps=gaps))

    rec = held().slice(0, 1200)
    f = fk.make("recommended", mag_held_readings="once")  # (the held readings' option, as the change was found)
    ref, fast = f.run(rec, backend="reference"), f.run(rec, backend="numba")
    assert np.array_equal(ref.flags, fast.flags) and np.abs(fast.quat - ref.quat).max() < 1e-9
    k = int(np.flatnonzero(fast.flags & fk.Flag.MAG_RECALIBRATED)[0])
    error = np.degrees(2.0 * np.arccos(np.abs(np.sum(fast.quat * rec.truth, axis=1)).clip(0.0, 1.0)))
    assert 700 < k < 800 and error[k - 1] > 90.0
    assert error[k + 400] < 10.0
    assert not (fast.flags[k + 300:k + 400] & fk.Flag.MAG_DISTURBED).any()
    gap = held(((float(rec.time[k]) - 0.001, 0.3),))  # sample k and the 0.3 s after it lost
    gap = gap.slice(0, int(np.searchsorted(gap.time, rec.time[-1])))
    with pytest.warns(fk.types.GapWarning):
        ref, fast = f.run(gap, backend="reference"), f.run(gap, backend="numba")
    assert np.array_equal(ref.flags, fast.flags) and np.abs(fast.quat - ref.quat).max() < 1e-9
    j = int(np.flatnonzero(fast.flags & fk.Flag.MAG_RECALIBRATED)[0])
    assert fast.flags[j - 1] & fk.Flag.GAP and not fast.flags[j] & fk.Flag.GAP  # waited for a valid gyro
    error = np.degrees(2.0 * np.arccos(np.abs(np.sum(fast.quat * gap.truth, axis=1)).clip(0.0, 1.0)))
    assert error[int(np.searchsorted(gap.time, rec.time[k] + 4.0))] < 10.0
