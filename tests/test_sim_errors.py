"""The simulator's sensor error models (fusionkit.sim.errors): each one does what it says, on the
recording that isolates it, and all of them off changes nothing."""

from __future__ import annotations

import numpy as np
import pytest

from fusionkit import sim
from fusionkit.errors import InputError
from fusionkit.rotations import quat_to_matrix

from conftest import fit_ellipsoid

DEG = np.pi / 180.0
FIELD = np.asarray(sim.KYIV_FIELD_ENU)


def _turning(rate=100.0, **kw):
    """Rotations about many axes: the magnetometer sweeps its sphere (ellipsoid) all round."""
    axes = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1), (1, -1, 1), (-1, 1, 1)]
    segs = [sim.Rest(0.5)] + [sim.Rotate(ax, 200 * DEG, 1.0) for ax in axes] + [sim.Rest(0.5)]
    return sim.simulate(segs, rate=rate, gnss_rate=None, **kw)


def _earth(rec, x):
    """Body vectors ``x`` (N, 3) seen in the earth frame, ``R(q) x``."""
    return np.einsum("nij,nj->ni", quat_to_matrix(rec.truth), x)


# ---- all off ------------------------------------------------------------------------------------

@pytest.mark.parametrize("sampling", ["mean", "point"])
def test_no_errors_changes_nothing(sampling):
    segs = [sim.Rest(0.5), sim.Rotate((1, 2, 3), 2.0, 1.0), sim.Translate((1, 0, 1), 1.0, 1.0)]
    a = sim.simulate(segs, noise=sim.Noise.mems(), sampling=sampling, gnss_vel_noise=0.1)
    b = sim.simulate(segs, noise=sim.Noise.mems(), sampling=sampling, gnss_vel_noise=0.1, errors=sim.SensorErrors())
    for name in ("gyr", "acc", "mag", "truth", "movement"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.gnss.vel, b.gnss.vel)
    assert sim.SensorErrors().active == []
    assert b.meta["errors"].active == [] and b.rate == a.rate


def test_bad_errors_are_refused_by_name():
    for kw, name in ((dict(mag_matrix=np.zeros((3, 3))), "mag_matrix"), (dict(gyr_lowpass=-1.0), "gyr_lowpass"),
                     (dict(drop_rate=1.0), "drop_rate"), (dict(gyr_bias_rw=-1e-3), "gyr_bias_rw"),
                     (dict(gyr_misalignment=np.eye(3)), "gyr_misalignment"), (dict(mag_offset=(1, 2)), "mag_offset"),
                     (dict(gaps=((1.0, 0.0),)), "gaps"), (dict(taps=(1.0,)), "taps"),
                     (dict(lowpass_order=True), "lowpass_order"), (dict(drop_rate="x"), "drop_rate")):
        with pytest.raises(InputError, match=name):
            sim.SensorErrors(**kw)
    with pytest.raises(InputError, match="errors"):
        sim.simulate([sim.Rest(1.0)], errors={"gyr_delay": 0.01})
    # (ignored: a magnetometer read faster than the IMU gave the IMU's samples)
    with pytest.raises(InputError, match=r"SensorErrors.mag_rate \(500.0 Hz\) is above the IMU's rate \(100.0 Hz\)"):
        sim.simulate([sim.Rest(1.0)], rate=100.0, errors=sim.SensorErrors(mag_rate=500.0))


# ---- magnetometer -------------------------------------------------------------------------------

def test_hard_and_soft_iron_are_the_ellipsoid():
    """The measured field lies on the ellipsoid with centre = the hard-iron offset and shape
    ``(A A^T)^-1 / |m|^2`` for the soft-iron matrix ``A``."""
    offset = (12.0, -30.0, 7.5)
    a = np.array([[1.10, 0.05, -0.02], [0.05, 0.92, 0.03], [-0.02, 0.03, 1.04]])
    rec = _turning(sampling="point", errors=sim.SensorErrors(mag_offset=offset, mag_matrix=a))
    centre, shape = fit_ellipsoid(rec.mag)
    np.testing.assert_allclose(centre, offset, atol=1e-6)
    np.testing.assert_allclose(shape, np.linalg.inv(a @ a.T) / (FIELD @ FIELD), rtol=1e-6)
    hard = _turning(sampling="point", errors=sim.SensorErrors(mag_offset=offset))
    centre, shape = fit_ellipsoid(hard.mag)
    np.testing.assert_allclose(centre, offset, atol=1e-6)
    np.testing.assert_allclose(shape, np.eye(3) / (FIELD @ FIELD), atol=1e-9)
    clean = _turning(sampling="point")
    np.testing.assert_allclose(rec.mag, clean.mag @ a.T + offset, atol=1e-12)
    np.testing.assert_array_equal(rec.gyr, clean.gyr)  # the other sensors are untouched
    np.testing.assert_array_equal(rec.acc, clean.acc)


def test_dipole_field_formula():
    """On the magnet's axis the field is ``2 mu0 m / (4 pi r^3)``, along the moment; across it
    half that, against the moment."""
    d = sim.MagneticDipole(position=(0.0, 0.2, 0.0), moment=(0.0, 1.0, 0.0))
    np.testing.assert_allclose(d.field(np.zeros((1, 3))), [[0.0, 2e-7 / 0.2**3 * 1e6, 0.0]], rtol=1e-12)
    np.testing.assert_allclose(d.field(np.array([[0.2, 0.2, 0.0]])), [[0.0, -1e-7 / 0.2**3 * 1e6, 0.0]],
                               rtol=1e-12, atol=1e-12)


def test_an_earth_fixed_magnet_does_not_turn_with_the_body():
    """Turning in place next to a magnet, the field seen in the earth frame stays the earth's
    plus the magnet's (a hard-iron offset would turn with the body); moving away, the magnet's
    part falls off as 1 / r^3."""
    magnet = sim.MagneticDipole(position=(0.25, 0.0, 0.0), moment=(0.0, 0.0, 2.0))
    segs = [sim.Rest(0.5), sim.Rotate((0, 0, 1), 270 * DEG, 1.5), sim.Rotate((1, 1, 0), 120 * DEG, 1.0),
            sim.Translate((-1, 0, 0), 0.75, 1.5), sim.Rest(0.5)]
    rec = sim.simulate(segs, rate=100.0, gnss_rate=None, sampling="point",
                       errors=sim.SensorErrors(dipoles=(magnet,)))
    seen = _earth(rec, rec.mag)
    expected = FIELD + magnet.field(rec.meta["ref_pos"])
    np.testing.assert_allclose(seen, expected, atol=1e-9)
    turning = np.flatnonzero(np.linalg.norm(rec.meta["ref_pos"], axis=1) == 0.0)
    near = magnet.field(np.zeros((1, 3)))[0]
    assert np.linalg.norm(near) > 5.0  # uT: a disturbance worth detecting
    np.testing.assert_allclose(seen[turning], np.tile(FIELD + near, (turning.size, 1)), atol=1e-9)
    far = seen[-1] - FIELD  # 1 m from the magnet instead of 0.25 m
    np.testing.assert_allclose(np.linalg.norm(far), np.linalg.norm(near) / 4**3, rtol=1e-9)
    hard = _earth(rec, sim.simulate(segs, rate=100.0, gnss_rate=None, sampling="point",
                                    errors=sim.SensorErrors(mag_offset=tuple(near))).mag)
    assert np.ptp(hard[turning], axis=0).max() > 5.0  # a body-fixed offset turns with the body


def test_ref_pos_and_the_magnets_field_move_with_the_initial_velocity():
    """``ref_pos`` ignored ``initial_velocity`` (3 m east, 4 m north and 4 s at 1 m/s east ended at
    [3, 4, 0], not [7, 4, 0]) while the GNSS velocity had it; the earth-fixed disturbances were felt
    where the body would have been without it. Both now follow the drifting body."""
    magnet = sim.MagneticDipole(position=(2.0, 0.5, 0.0), moment=(0.0, 0.0, 2.0))
    rec = sim.simulate([sim.Rest(1.0), sim.Translate((3, 4, 0), 5.0, 2.0), sim.Rest(1.0)], rate=100.0,
                       initial_velocity=(1.0, 0.0, 0.0), sampling="point", errors=sim.SensorErrors(dipoles=(magnet,)))
    pos = rec.meta["ref_pos"]
    np.testing.assert_allclose(pos[[100, -1]], [[1.0, 0.0, 0.0], [7.0, 4.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(rec.gnss.vel[-1], [1.0, 0.0, 0.0], atol=1e-9)  # (it had it)
    np.testing.assert_allclose(_earth(rec, rec.mag), FIELD + magnet.field(pos), atol=1e-9)


@pytest.mark.parametrize("sampling", ["mean", "point"])
def test_a_field_patch_is_added_in_the_earth_frame_while_it_lasts(sampling):
    patch = sim.FieldPatch(field=(5.0, -3.0, 8.0), start=1.0, stop=2.0)
    rec = _turning(sampling=sampling, errors=sim.SensorErrors(patches=(patch,)))
    clean = _turning(sampling=sampling)
    extra = _earth(rec, rec.mag - clean.mag)
    t = rec.time
    inside, outside = (t > 1.0 + 0.01) & (t < 2.0 - 1e-9), (t < 1.0 - 1e-9) | (t > 2.0 + 0.01)
    # a mean over a turning sample smears the patch by up to half the sample's turn (peak 7 rad/s * 10 ms)
    np.testing.assert_allclose(extra[inside], np.tile(patch.field, (inside.sum(), 1)),
                               atol=1e-9 if sampling == "point" else 0.04 * np.linalg.norm(patch.field))
    np.testing.assert_allclose(extra[outside], 0.0, atol=1e-12)


# ---- timing -------------------------------------------------------------------------------------

RATE = 200.0


def _rotations(errors=None, rate=RATE):
    """Rotations about several axes (test_timing's recording): what sensor_lags times best."""
    segs = [sim.Rest(1.0)] + [sim.Rotate(ax, 150 * DEG * s, 0.8) for s in (1, -1)
                              for ax in ((1, 0, 0), (0, 1, 0), (1, 1, 1), (0, 1, -1))] + [sim.Rest(1.0)]
    return sim.simulate(segs, rate=rate, gnss_rate=None, errors=errors)


@pytest.mark.parametrize("gyr, acc, mag", [(0.75, 0.0, 3.7), (-0.4, 1.3, 0.0), (2.0, 0.5, -1.2)])
def test_inter_sensor_delays_are_recovered_by_sensor_lags(gyr, acc, mag):
    """A delay of d samples shows as 0.5 + d (the interval mean's half sample plus d); the issue
    asks for 0.1 sample, the spline delay gives 0.01."""
    from fusionkit.benchmarking.timing import sensor_lags

    rec = _rotations(sim.SensorErrors(gyr_delay=gyr / RATE, acc_delay=acc / RATE, mag_delay=mag / RATE))
    lags = sensor_lags(rec)
    assert lags.gyr == pytest.approx(0.5 + gyr, abs=0.02)
    assert lags.acc == pytest.approx(0.5 + acc, abs=0.02)
    assert lags.mag == pytest.approx(0.5 + mag, abs=0.02)


@pytest.mark.parametrize("order, cutoff", [(1, 25.0), (2, 30.0), (2, 12.0)])
def test_a_lowpass_group_delay_is_recovered_by_sensor_lags(order, cutoff):
    from fusionkit.benchmarking.timing import sensor_lags

    delay = sim.lowpass_delay(cutoff, RATE, order)
    analog = (1.0 if order == 1 else np.sqrt(2.0)) * RATE / (2 * np.pi * cutoff)
    assert delay == pytest.approx(analog, rel=0.1)  # near the analog filter's (bilinear transform)
    rec = _rotations(sim.SensorErrors(gyr_lowpass=cutoff, mag_lowpass=cutoff, lowpass_order=order))
    lags = sensor_lags(rec)
    assert lags.gyr == pytest.approx(0.5 + delay, abs=0.05)
    assert lags.mag == pytest.approx(0.5 + delay, abs=0.05)
    assert lags.acc == pytest.approx(0.5, abs=0.05)  # not filtered
    clean = _rotations()
    np.testing.assert_allclose(rec.gyr[:150], clean.gyr[:150], atol=1e-12)  # started at steady state


# ---- geometry and biases -----------------------------------------------------------------------

def test_scale_factor_and_misalignment_are_I_plus_S_plus_M():
    s = (0.02, -0.01, 0.005)
    m = np.array([[0.0, 0.003, -0.002], [0.001, 0.0, 0.004], [-0.003, 0.002, 0.0]])
    rec = _turning(errors=sim.SensorErrors(gyr_scale=s, gyr_misalignment=m, acc_scale=(0.01, 0.0, -0.02)))
    clean = _turning()
    t = np.eye(3) + np.diag(s) + m
    np.testing.assert_allclose(rec.gyr, clean.gyr @ t.T, atol=1e-14)
    np.testing.assert_allclose(rec.acc, clean.acc * [1.01, 1.0, 0.98], atol=1e-14)
    np.testing.assert_array_equal(rec.mag, clean.mag)
    # what it does to the rate: a 2 % scale error on x shows as 2 % of the x rate
    big = np.abs(clean.gyr[:, 0]) > 1.0
    np.testing.assert_allclose((rec.gyr[big, 0] - clean.gyr[big, 0]) / clean.gyr[big, 0], 0.02, atol=0.01)


def test_bias_random_walk_has_the_given_density():
    """The bias' increments per sample have variance density^2 dt (to the 3 % a long rest
    estimates it), the measured rate at rest is that bias (no other noise), and the bias wanders
    as sqrt(t)."""
    rate, dens_g, dens_a = 100.0, 1e-3, 4e-3
    rec = sim.simulate([sim.Rest(600.0)], rate=rate, gnss_rate=None,
                       errors=sim.SensorErrors(gyr_bias_rw=dens_g, acc_bias_rw=dens_a))
    for name, dens in (("gyr", dens_g), ("acc", dens_a)):
        bias = rec.meta[f"{name}_bias"]
        assert bias.shape == (len(rec), 3) and np.all(bias[0] == 0.0)
        inc = np.diff(bias, axis=0)
        assert inc.var() == pytest.approx(dens**2 / rate, rel=0.03)
        assert np.abs(inc.mean()) < 4 * dens / np.sqrt(rate) / np.sqrt(inc.size)
    np.testing.assert_allclose(rec.gyr, rec.meta["gyr_bias"], atol=1e-15)
    np.testing.assert_allclose(rec.acc - [0.0, 0.0, 9.81], rec.meta["acc_bias"], atol=1e-12)
    # many walks: the spread after T seconds is density sqrt(T)
    ends = np.array([sim.simulate([sim.Rest(10.0)], rate=rate, gnss_rate=None, seed=i,
                                  errors=sim.SensorErrors(gyr_bias_rw=dens_g)).meta["gyr_bias"][-1]
                     for i in range(60)])
    assert ends.std() == pytest.approx(dens_g * np.sqrt(10.0), rel=0.15)


def test_bias_walk_adds_to_the_constant_bias_and_keeps_the_white_noise():
    noise = sim.Noise(gyr_noise=0.01, gyr_bias=(0.1, 0.0, -0.1))
    a = sim.simulate([sim.Rest(5.0)], noise=noise, gnss_rate=None)
    b = sim.simulate([sim.Rest(5.0)], noise=noise, gnss_rate=None, errors=sim.SensorErrors(gyr_bias_rw=1e-3))
    walk = b.meta["gyr_bias"] - np.asarray(noise.gyr_bias)
    np.testing.assert_allclose(b.gyr - walk, a.gyr, atol=1e-15)  # the same white noise draws
    assert np.abs(walk).max() > 1e-4


# ---- specific force -----------------------------------------------------------------------------

def test_sinusoidal_vibration_at_its_frequency_and_amplitude():
    amp, f, rate = np.array([0.5, 0.0, 2.0]), 37.0, 400.0
    vib = sim.Vibration(amplitude=amp, frequency=f, start=1.0)
    segs = [sim.Rest(1.0), sim.Rotate((0, 0, 1), 90 * DEG, 4.0), sim.Rest(5.0)]
    clean = sim.simulate(segs, rate=rate, gnss_rate=None, sampling="point")
    rec = sim.simulate(segs, rate=rate, gnss_rate=None, sampling="point", errors=sim.SensorErrors(vibration=vib))
    t, extra = rec.time, rec.acc - clean.acc
    np.testing.assert_allclose(extra, (t > 1.0)[:, None] * np.sin(2 * np.pi * f * t)[:, None] * amp, atol=1e-12)
    np.testing.assert_array_equal(rec.truth, clean.truth)  # the orientation does not shake
    np.testing.assert_array_equal(rec.gyr, clean.gyr)
    # as the spectrum shows it: one line at f of the given amplitude; the interval mean scales it by sinc(f dt)
    mean = sim.simulate(segs, rate=rate, gnss_rate=None, errors=sim.SensorErrors(vibration=vib))
    x = (mean.acc - sim.simulate(segs, rate=rate, gnss_rate=None).acc)[t > 1.0]
    spec = np.abs(np.fft.rfft(x[:, 2])) * 2 / len(x)
    freqs = np.fft.rfftfreq(len(x), 1 / rate)
    assert freqs[np.argmax(spec)] == pytest.approx(f, abs=rate / len(x))
    assert spec.max() == pytest.approx(2.0 * np.sinc(f / rate), rel=0.02)


def test_band_limited_vibration_has_its_rms_in_its_band():
    vib = sim.Vibration(amplitude=(1.0, 1.0, 3.0), frequency=60.0, bandwidth=20.0)
    rec = sim.simulate([sim.Rest(20.0)], rate=500.0, gnss_rate=None, sampling="point",
                       errors=sim.SensorErrors(vibration=vib))
    x = rec.acc - [0.0, 0.0, 9.81]
    np.testing.assert_allclose(x.std(axis=0), [1.0, 1.0, 3.0], rtol=0.05)
    power = np.abs(np.fft.rfft(x, axis=0)) ** 2
    freqs = np.fft.rfftfreq(len(x), 1 / 500.0)
    inband = (freqs > 45.0) & (freqs < 75.0)
    assert power[inband].sum() / power.sum() > 0.9
    again = sim.simulate([sim.Rest(20.0)], rate=500.0, gnss_rate=None, sampling="point",
                         errors=sim.SensorErrors(vibration=vib))
    np.testing.assert_array_equal(again.acc, rec.acc)  # seeded


@pytest.mark.parametrize("sampling", ["mean", "point"])
def test_taps_are_short_impulses(sampling):
    """A tap is a half-sine of its peak over its duration: point samples see the peak, interval
    means keep its impulse (peak * 2 duration / pi); nothing happens outside it."""
    rate, tap = 1000.0, sim.Tap(time=2.0, amplitude=(0.0, 30.0, -10.0), duration=0.006)
    late = sim.Tap(time=4.0001, amplitude=(5.0, 0.0, 0.0), duration=0.0023)
    segs = [sim.Rest(1.0), sim.Rotate((1, 0, 0), 60 * DEG, 2.0), sim.Rest(3.0)]
    clean = sim.simulate(segs, rate=rate, gnss_rate=None, sampling=sampling)
    rec = sim.simulate(segs, rate=rate, gnss_rate=None, sampling=sampling, errors=sim.SensorErrors(taps=(tap, late)))
    extra, t = rec.acc - clean.acc, rec.time
    hit = np.flatnonzero(np.any(extra != 0.0, axis=1))
    assert t[hit].min() > 2.0 - 1e-9 and t[hit].max() < 4.0001 + 0.0023 + 1e-3
    first = t < 3.0
    np.testing.assert_allclose(extra[first].sum(axis=0) / rate, np.multiply(tap.amplitude, 2 * tap.duration / np.pi),
                               rtol=0.05 if sampling == "point" else 1e-9)
    np.testing.assert_allclose(extra[~first].sum(axis=0) / rate, np.multiply(late.amplitude, 2 * late.duration / np.pi),
                               rtol=0.15 if sampling == "point" else 1e-9)
    if sampling == "point":
        np.testing.assert_allclose(extra[first].max(axis=0)[1], 30.0, rtol=1e-9)  # a sample at the peak (2.003)


# ---- transport ----------------------------------------------------------------------------------

def test_dropped_samples_are_missing_rows_at_the_rate():
    full = _turning(rate=200.0, noise=sim.Noise.mems())
    rec = _turning(rate=200.0, noise=sim.Noise.mems(), errors=sim.SensorErrors(drop_rate=0.1))
    kept = rec.meta["kept"]
    n = len(full)
    assert rec.rate is None and len(rec) == kept.size < n
    assert (n - kept.size) / (n - 1) == pytest.approx(0.1, abs=3 * np.sqrt(0.1 * 0.9 / n))
    np.testing.assert_allclose(rec.time, kept / 200.0, atol=1e-12)  # timestamps skip the lost rows
    skips = np.diff(kept)
    assert skips.max() >= 2 and np.all(skips >= 1)
    for name in ("gyr", "acc", "mag", "truth", "movement"):  # what is left is what the sensor made
        np.testing.assert_array_equal(getattr(rec, name), getattr(full, name)[kept], err_msg=name)


def test_a_timestamp_gap_of_given_length():
    rec = _turning(rate=100.0, errors=sim.SensorErrors(gaps=((2.0, 0.5), (5.005, 0.02))))
    t = rec.time
    assert not np.any((t >= 2.0 - 1e-9) & (t < 2.5 - 1e-9))
    dt = np.diff(t)
    big = np.sort(dt[dt > 0.015])
    np.testing.assert_allclose(big, [0.03, 0.51], atol=1e-9)  # the gap plus the one interval that spans it
    assert len(rec) == len(_turning(rate=100.0)) - 50 - 2
    np.testing.assert_allclose(rec.dt[1:], dt)
