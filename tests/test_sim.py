"""The simulator's sampling conventions: the gyro's mean rate, the accelerometer's mean or point
specific force."""

import numpy as np
import pytest

from fusionkit import sim
from fusionkit.errors import InputError
from fusionkit.rotations import quat_to_matrix

DEG = np.pi / 180.0
SEGMENTS = [sim.Rest(0.5), sim.Rotate((1, 1, 0), 120 * DEG, 1.0), sim.Translate((1, 0, 1), 0.5, 1.0),
            sim.Rotate((0, 0, 1), -90 * DEG, 0.5), sim.Rest(0.5)]


def test_mean_sampling_is_the_interval_mean():
    """Sample k of the default accelerometer (magnetometer) is the mean specific force (field) over
    (t[k-1], t[k]]: the trapezoid rule over a 40 times finer point-sampled run agrees to far below
    any sensor noise, and differs from the point sample by the rotation within half a sample."""
    coarse = sim.simulate(SEGMENTS, rate=100.0, gnss_rate=None)
    point = sim.simulate(SEGMENTS, rate=100.0, gnss_rate=None, sampling="point")
    fine = sim.simulate(SEGMENTS, rate=4000.0, gnss_rate=None, sampling="point")
    np.testing.assert_allclose(fine.truth[::40], coarse.truth, atol=1e-12)  # the same trajectory
    for name, atol in (("acc", 2e-5), ("mag", 1e-4)):  # m/s^2, uT
        blocks = getattr(fine, name)[1:].reshape(-1, 40, 3)
        starts = np.vstack([getattr(fine, name)[:1], blocks[:-1, -1]])
        trapezoid = (blocks.sum(axis=1) - 0.5 * blocks[:, -1] + 0.5 * starts) / 40.0
        np.testing.assert_allclose(getattr(coarse, name)[1:], trapezoid, atol=atol, err_msg=name)
        assert np.abs(getattr(coarse, name) - getattr(point, name)).max() > 100 * atol  # the convention matters
    np.testing.assert_array_equal(coarse.gyr, point.gyr)


def test_point_sampling_is_the_value_at_the_sample_time():
    rec = sim.simulate([sim.Rest(0.2), sim.Rotate((0, 1, 1), 90 * DEG, 0.5)], rate=50.0, gnss_rate=None,
                       sampling="point")
    np.testing.assert_allclose(rec.acc, np.einsum("nji,j->ni", quat_to_matrix(rec.truth), [0.0, 0.0, 9.81]),
                               atol=1e-12)
    np.testing.assert_allclose(rec.mag, np.einsum("nji,j->ni", quat_to_matrix(rec.truth), sim.KYIV_FIELD_ENU),
                               atol=1e-12)


def test_bad_sampling_is_refused():
    with pytest.raises(InputError, match="sampling"):
        sim.simulate([sim.Rest(1.0)], sampling="instant")


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("make, name", [
    (lambda: sim.Rest(-5), r"Rest.duration must be > 0 s"), (lambda: sim.Rest(0), r"Rest.duration must be > 0 s"),
    (lambda: sim.Rest(NAN), "Rest.duration must be a finite number"), (lambda: sim.Rest(INF), "Rest.duration"),
    (lambda: sim.Rotate((0, 0, 1), 1.0, -1), "Rotate.duration"), (lambda: sim.Rotate((0, 0, 0), 1.0, 1), "Rotate.axis"),
    (lambda: sim.Rotate((0, 0, 1), NAN, 1), "Rotate.angle"),
    (lambda: sim.Translate((0, 0, 0), 1.0, 1), "Translate.direction"),
    (lambda: sim.Translate((1, 0, 0), NAN, 1), "Translate.distance"),
    (lambda: sim.Noise(gyr_bias=(1, 2)), "Noise.gyr_bias"), (lambda: sim.Noise(mag_noise=-1.0), "Noise.mag_noise"),
    (lambda: sim.simulate([sim.Rest(1)], noise=0.01), "noise must be a fusionkit.sim.Noise"),
    (lambda: sim.simulate([sim.Rest(1)], mag_field=(1, 2)), "mag_field"),
    (lambda: sim.simulate([sim.Rest(1)], rate=NAN), "rate must be a finite number > 0"),
    (lambda: sim.simulate([sim.Rest(1)], rate="100"), "rate must be a finite number > 0"),
    (lambda: sim.simulate([sim.Rest(1)], gnss_rate=-5), "gnss_rate must be > 0"),
    (lambda: sim.simulate([sim.Rest(1)], initial=(0, 0, 0, 0)), "initial must be a quaternion"),
    (lambda: sim.simulate([(1, 2)]), "unknown segment"), (lambda: sim.simulate(sim.Rest(1)), "segments must be a list"),
])
def test_bad_segments_noise_and_arguments_are_refused_by_name(make, name):
    """The segments and Noise took anything: a negative or zero duration became one sample, a NaN or
    infinite one numpy's error, a zero axis or direction or a NaN angle a NaN truth, a bias of 2 numbers a
    broadcast error; simulate() gave Python's or numpy's error for noise=0.01, a field of 2 numbers, a NaN
    or text rate, and an epoch every sample for gnss_rate=-5. Each is now an InputError naming it."""
    with pytest.raises(InputError, match=name):
        make()


def test_durations_are_rounded_to_the_sample_grid():
    """(Documented, not changed: the scenarios depend on it.) A segment lasts round(duration * rate)
    samples, at least one, and turns by its whole angle."""
    rec = sim.simulate([sim.Rotate((0, 0, 1), 0.3, 0.015), sim.Rest(0.001)], rate=100.0, gnss_rate=None)
    assert len(rec) == 1 + 2 + 1
    np.testing.assert_allclose(rec.gyr[1:3, 2].sum() * 0.01, 0.3, atol=1e-12)


def test_gnss_epochs_are_at_the_imus_sample_times():
    """The epochs were stamped ``idx * dt``, which rounds past the recording's ``k / rate``: the last one
    fell after the last sample and was dropped with a false warning ("GNSS epochs ... dropped", also for
    sim:hand-held), and about one in six took effect a sample late. They are now the sample times."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = sim.simulate([sim.Rest(2.3)], rate=200.0)
    assert rec.gnss.t.size == 24 and rec.gnss.t[-1] == rec.time[-1]
    np.testing.assert_array_equal(rec.gnss.t, rec.time[::20])
