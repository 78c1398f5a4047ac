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
    on-time magnetometer's. Where values never repeat the switch changes nothing, to the bit."""
    on_time = sim.scenario("late-mag", delay=0.0)
    held = sim.scenario("late-mag", delay=0.0, mag_rate=50.0)
    base, hold, no_hold = _total(on_time), _total(held), _total(held, mag_hold=False)
    assert no_hold > base + 0.02
    assert hold < base + 0.01
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
    half = len(rec) // 2  # (the held value across the split: the state carries the last sample)
    parts = {}
    for backend in ("reference", "numba"):
        first = f.run(rec.slice(0, half), backend=backend)
        second = f.run(rec.slice(half, len(rec)), backend=backend, state=first.diagnostics["state"])
        parts[backend] = np.vstack([first.quat, second.quat])
    assert np.abs(parts["numba"] - parts["reference"]).max() < 1e-9
    assert np.abs(parts["reference"][half:] - ref.quat[half:]).max() < 1e-4
