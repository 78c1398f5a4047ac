import re

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.errors import InputError
from fusionkit.io import load_csv, write_csv

from conftest import data_dir


def rec(**kw):
    n = kw.pop("n", 10)
    base = dict(gyr=np.zeros((n, 3)), acc=np.tile([0, 0, 9.81], (n, 1)), rate=100.0)
    base.update(kw)
    return fk.Recording(**base)


def test_shapes_and_lengths_are_checked():
    with pytest.raises(InputError, match=r"gyr must have shape \(N, 3\), got \(10, 4\)"):
        rec(gyr=np.zeros((10, 4)))
    with pytest.raises(InputError, match="acc has 9 samples but gyr has 10"):
        rec(acc=np.zeros((9, 3)) + 9.81)
    with pytest.raises(InputError, match="truth must have shape"):
        rec(truth=np.zeros((10, 3)))
    with pytest.raises(InputError, match="exactly one of rate"):
        rec(rate=None)
    with pytest.raises(InputError, match="rate must be a finite number > 0"):
        rec(rate=-5)
    with pytest.raises(InputError, match="numeric"):
        rec(gyr=[["a", "b", "c"]] * 10)


@pytest.mark.parametrize("kw, match", [
    (dict(gyr=[[0.0, 0.0, 0.0]] * 9 + [[0.0, 0.0]]), "gyr must be a numeric array with rows of equal length"),
    (dict(gyr=np.zeros((10, 3)) + 1j), "gyr is complex"),
    (dict(rate=None, t=["a"] * 10), r"t must be numbers \(timestamps in s\)"),
    (dict(rate=None, t=np.datetime64("2026-01-01") + np.arange(10).astype("timedelta64[ms]")), "t is a date"),
    (dict(rate=None, t=np.arange(10) * 10.0), r"t's typical interval \(median\) is 10 s: t must be in seconds"),
    (dict(rate=None, t=np.arange(10) * 10_000_000), "t must be in seconds"),
    (dict(rate=0.01), "rate is 0.01 Hz, one sample every 100 s: rate is in Hz"),
    (dict(rate=True), "rate must be one finite number > 0, got True"),
    (dict(rate=np.array([100.0, 100.0])), "rate must be one finite number"),
    (dict(rate="100 Hz"), "rate must be a finite number > 0, got '100 Hz'"),
    (dict(rate="100"), r"rate must be a finite number > 0, got '100' \(text"),
    (dict(rate=None, t=[f"{0.01 * k:.2f}" for k in range(10)]), r"t must be numbers \(timestamps in s\).*not text"),
    (dict(rate=None, t=np.array([0.01 * k for k in range(10)]).astype(str)), "t must be numbers .*not text"),
    (dict(gyr=[["0.0", "0.0", "0.0"]] * 10), "gyr must be numbers .*not text such as '0.0'"),
    (dict(gyr=np.array([[0.0, "0.5", 0.0]] + [[0.0, 0.0, 0.0]] * 9, dtype=object)),
     "gyr must be numbers .*not text such as '0.5'"),  # an object column: numpy would parse the text
    (dict(acc=np.array([[0.0, 0.0, True]] + [[0.0, 0.0, 9.81]] * 9, dtype=object)), "acc holds a boolean"),
    (dict(gyr=np.array([[0.0, 1j, 0.0]] + [[0.0, 0.0, 0.0]] * 9, dtype=object)), "gyr holds a complex number"),
    (dict(gyr=[[0.0, True, 0.0]] + [[0.0, 0.0, 0.0]] * 9), "gyr holds a boolean"),  # numpy: all floats
    (dict(gyr=[[0.1, "0.5", 0.0]] + [[0.0, 0.0, 0.0]] * 9), "not text such as '0.5'"),  # the text, not 0.1
    (dict(gyr=np.array([[np.array("0.5"), 0.0, 0.0]] + [[0.0, 0.0, 0.0]] * 9, dtype=object)), "not text such as"),
    (dict(movement=["False"] * 10), "movement must be booleans .*not text"),  # "False" is True to numpy
    (dict(movement=np.ones((10, 2), bool)), r"movement must have shape \(N,\)"),
    (dict(movement=True), r"movement must have shape \(N,\)"),
    (dict(truth=np.zeros((10, 4))), r"truth\[0\] is \[0.0, 0.0, 0.0, 0.0\]: a zero quaternion"),
    (dict(truth=np.tile([1.0, 0, 0, 0], (10, 1)), truth_frame="XYZ"), "truth_frame must be one of"),
])
def test_what_a_new_user_might_pass_is_refused_by_name(kw, match):
    """Input numpy would take silently and wrongly (complex, dates, a bool rate, timestamps in ms
    or ns, the interval passed as the rate: filters then ran into NaN or a division by zero deep in
    a kernel) or refuse with its own error (a ragged list, text timestamps, an array rate): an
    InputError (ConfigError for a frame) naming the argument."""
    with pytest.raises(fk.FusionkitError, match=match):
        rec(**kw)
    rec(rate=None, t=np.arange(10) * 1.0)  # 1 Hz, the slowest taken


def test_truth_zero_quaternion_check_is_cheap_and_exact():
    """The zero-quaternion test on truth looks at one column first (a (N, 4) temporary per
    check made a 1M-sample Recording with truth 10x slower to build): no more memory than the
    same Recording without truth; a zero row is still found by index, a NaN row (no reference)
    or a row with only w = 0 is kept."""
    import tracemalloc
    n = 100_000
    truth = np.tile([1.0, 0, 0, 0], (n, 1))

    def peak(**kw):
        tracemalloc.start()
        rec(n=n, **kw)
        p = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return p

    rec(n=n, truth=truth)  # (first-call imports and caches outside the measurement)
    assert peak(truth=truth) < peak() + 4 * n  # (it was 38 bytes a sample more)
    q = np.tile([1.0, 0, 0, 0], (10, 1))
    q[2] = np.nan
    q[4] = [0.0, 0.0, 0.0, 1.0]
    rec(truth=q)
    q[7] = 0.0
    with pytest.raises(InputError, match=r"truth\[7\] is \[0.0, 0.0, 0.0, 0.0\]: a zero quaternion"):
        rec(truth=q)


def test_truth_is_made_unit_length():
    """A reference quaternion that is not of unit length (scaled, or rounded by a file) is the
    orientation it points to: the metrics and the lags read it normalised. truth * 3 once scored a
    total error of 0 against any estimate (2 acos |w| with |w| clipped at 1)."""
    from fusionkit.benchmarking.metrics import rms_errors
    from fusionkit.rotations import quat_from_axis_angle

    q = quat_from_axis_angle([0.0, 0.0, 1.0], np.linspace(0.0, 1.0, 10))
    unit = np.ascontiguousarray(q)
    assert rec(truth=unit).truth is unit  # unit already: kept, not copied
    scaled = 3.0 * q
    scaled[4] = np.nan
    r = rec(truth=scaled)
    np.testing.assert_allclose(np.linalg.norm(r.truth[~np.isnan(r.truth[:, 0])], axis=1), 1.0, rtol=1e-15)
    assert np.isnan(r.truth[4]).all() and scaled[0, 0] == 3.0  # the caller's array untouched
    est = fk.Result(quat=quat_from_axis_angle([1.0, 0.0, 0.0], np.full(10, np.radians(2.0))), flags=np.zeros(10, np.uint32))
    keep = np.arange(10) != 4
    want = rms_errors(est, rec(truth=unit), mask=keep)
    assert want["total"] > 2.0 and rms_errors(est, r, mask=keep) == pytest.approx(want, rel=1e-9)


def test_the_estimate_is_read_as_the_rotation_it_stands_for():
    """broad_errors normalises the estimate's rows as the Recording does the truth's: an estimate
    scaled by 3 scored a total error of 0 (and one scaled by 0.5 a larger one); a zero or a
    non-finite estimate row is an InputError naming it (a NaN reference row stays a sample
    without a reference)."""
    from fusionkit.benchmarking.metrics import broad_errors
    from fusionkit.rotations import quat_from_axis_angle

    truth = quat_from_axis_angle([0.0, 0.0, 1.0], np.linspace(0.0, 1.0, 10))
    est = quat_from_axis_angle([1.0, 0.0, 0.0], np.full(10, np.radians(2.0)))
    want = broad_errors(est, truth)
    assert want["total"].min() > 1.9
    for scale in (3.0, 0.5):
        got = broad_errors(scale * est, truth)
        for k in want:
            np.testing.assert_allclose(got[k], want[k], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(broad_errors(est, scale * truth)["total"], want["total"], rtol=1e-9)
    ref = truth.copy()
    ref[3] = np.nan
    assert np.isnan(broad_errors(est, ref)["total"][3]) and np.isfinite(broad_errors(est, ref)["total"]).sum() == 9
    for bad, value in (("q_est", 0.0), ("q_est", np.nan), ("q_est", np.inf), ("q_ref", 0.0)):
        q = (est if bad == "q_est" else truth).copy()
        q[6] = value
        args = (q, truth) if bad == "q_est" else (est, q)
        with pytest.raises(InputError, match=rf"{bad}\[6\] is"):
            broad_errors(*args)


def test_a_long_truth_is_checked_in_one_compiled_pass():
    """From 50,000 samples the unit-length test is one compiled pass (``unit_rows_off``: numpy's two
    passes doubled a 1M-sample ``Recording``'s build, review rev27b); it decides as numpy's does: a
    unit truth kept as it is, one row off by more than 1e-9 normalised, NaN rows kept."""
    from fusionkit.validation import unit_rows_off

    n = 60_000
    q = np.zeros((n, 4))
    q[:, 0] = 1.0
    q[7] = np.nan
    rate = {"gyr": np.zeros((n, 3)), "acc": np.tile([0.0, 0.0, 9.81], (n, 1)), "rate": 100.0}
    assert fk.Recording(truth=q, **rate).truth is q and not unit_rows_off(q, 2e-9)
    q2 = q.copy()
    q2[n - 1, 0] = 1.0 + 1e-6
    assert unit_rows_off(q2, 2e-9) and unit_rows_off.py_func(q2, 2e-9)
    r = fk.Recording(truth=q2, **rate)
    assert r.truth is not q2 and r.truth[n - 1, 0] == 1.0 and np.isnan(r.truth[7]).all()


def test_movement_column_is_taken():
    """A movement column (N, 1) or row (1, N), what loadmat and h5py give, is one bool a sample:
    flattened, as before the shape check; a true 2-D mask is refused (above)."""
    m = np.arange(10) > 4
    for shape in [(10, 1), (1, 10), (10, 1, 1)]:
        r = rec(movement=m.reshape(shape))
        assert r.movement.shape == (10,) and (r.movement == m).all()
    with pytest.raises(InputError, match="movement has 9 samples but gyr has 10"):
        rec(movement=np.ones((9, 1), bool))


def test_a_mask_of_numbers_is_0_or_1():
    """movement and gnss.valid as numbers: 0 and 1 are False and True, anything else (a weight
    0.5, a missing NaN, a 2) is refused by index; each was True before, counted in the metrics."""
    assert (rec(movement=(np.arange(10) > 4).astype(float)).movement == (np.arange(10) > 4)).all()
    for bad, shown in ((0.5, "0.5"), (np.nan, "nan"), (2, "2")):
        m = np.zeros(10)
        m[3] = bad
        with pytest.raises(InputError, match=rf"movement must be booleans \(a mask\) or 0/1, but movement\[3\] is {shown}"):
            rec(movement=m)
    assert fk.Gnss(t=[0.0, 1.0], vel=np.zeros((2, 3)), valid=[1, 0]).valid.tolist() == [True, False]
    with pytest.raises(InputError, match=r"gnss.valid\[0\] is nan"):
        fk.Gnss(t=[0.0, 1.0], vel=np.zeros((2, 3)), valid=[np.nan, 1.0])


def test_slice_across_a_gap_is_not_refused():
    """A slice of a checked recording is not checked for its typical interval again: a few
    samples across a 60 s gap have a 60 s median interval, but no unit mistake (slice refused it)."""
    t = np.arange(20) * 0.01
    t[10:] += 60.0
    r = rec(n=20, rate=None, t=t)
    for a, b in [(9, 11), (8, 11)]:
        s = r.slice(a, b)
        assert len(s) == b - a and s.t[-1] - s.t[0] > 60.0
    with pytest.raises(InputError, match="t's typical interval"):
        rec(n=2, rate=None, t=t[9:11])  # (a new recording is still checked)


def test_time_must_increase():
    with pytest.raises(InputError, match=r"strictly increasing, but t\[3\]"):
        rec(rate=None, t=[0, 1, 2, 2, 4, 5, 6, 7, 8, 9])
    r = rec(rate=None, t=np.arange(10) * 0.01 + 5)
    np.testing.assert_allclose(r.dt, 0.01)
    assert r.nominal_dt == pytest.approx(0.01)


def test_units_are_checked_and_converted():
    with pytest.raises(InputError, match="acc_unit='g'"):
        rec(acc=np.tile([0, 0, 1.0], (10, 1)))
    r = rec(acc=np.tile([0, 0, 1.0], (10, 1)), acc_unit="g")
    assert r.acc[0, 2] == pytest.approx(9.80665)
    with pytest.raises(InputError, match=r"acc looks like it is in m/s\^2 already \(median norm 9.81 > 3\), but "
                                         r"acc_unit='g' would multiply it by 9.81"):
        rec(acc_unit="g")  # (it became 96 m/s^2, unsaid)
    with pytest.raises(InputError, match="gyr_unit='deg/s'"):
        rec(gyr=np.full((10, 3), 45.0))
    r = rec(gyr=np.full((10, 3), 45.0), gyr_unit="deg/s")
    assert r.gyr[0, 0] == pytest.approx(np.pi / 4)


def test_nan_is_kept_for_the_filters_policy():
    g = np.zeros((10, 3))
    g[4] = np.nan
    assert np.isnan(rec(gyr=g).gyr[4]).all()


def test_csv_round_trip(tmp_path):
    r = sim.simulate([sim.Rest(1), sim.Rotate((0, 0, 1), 1, 1)], rate=50.0, seed=0)
    write_csv(r, tmp_path / "r.csv")
    back = fk.load(tmp_path / "r.csv")
    np.testing.assert_allclose(back.gyr, r.gyr, atol=1e-8)
    np.testing.assert_allclose(back.truth, r.truth, atol=1e-8)
    np.testing.assert_allclose(back.time, r.time, atol=1e-9)
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="missing columns"):
        load_csv(tmp_path / "bad.csv")
    (tmp_path / "norate.csv").write_text("gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n0,0,0,0,0,9.8\n")
    with pytest.raises(InputError, match="no 't' column and no rate"):
        load_csv(tmp_path / "norate.csv")
    (tmp_path / "rate.csv").write_text("# rate=200\ngyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n0,0,0,0,0,9.8\n0,0,0,0,0,9.8\n")
    assert load_csv(tmp_path / "rate.csv").rate == 200.0


def test_epoch_timestamps_survive_a_csv_round_trip(tmp_path):
    """Timestamps of a logger's epoch clock (1.7e9 s) are written to the last bit: at 9-10 digits
    every row of a Result's CSV had the same t, and write_csv's file no longer loaded ("t must be
    strictly increasing")."""
    r = sim.simulate([sim.Rest(1.0)], rate=200.0, seed=0)
    rec = fk.Recording(gyr=r.gyr, acc=r.acc, mag=r.mag, t=1.7e9 + r.time)
    write_csv(rec, tmp_path / "r.csv")
    back = fk.load(tmp_path / "r.csv")
    np.testing.assert_array_equal(back.t, rec.t)
    fk.make("poisson").run(rec, backend="reference").to_csv(tmp_path / "o.csv", time=rec.t)
    np.testing.assert_array_equal(np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=1)[:, 0], rec.t)


def test_a_csv_rate_does_not_replace_its_t_column(tmp_path):
    """A rate (argument or '# rate=' line) with a 't' column only confirms it: 't' stays the clock
    (its gap kept), and a rate that contradicts it is an error naming both. The rate once replaced
    't' silently: 100 Hz on a 200 Hz file halved every rate, 94 deg of inclination error."""
    t = np.r_[np.arange(10) * 0.005, 1.0 + np.arange(10) * 0.005]  # 200 Hz with a 0.955 s gap
    rows = "\n".join(f"{x},0,0,0,0,0,9.8" for x in t)
    path = tmp_path / "t.csv"
    path.write_text("t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + rows + "\n")
    for rec in (load_csv(path, rate=200.0), load_csv(path, rate=199.0)):
        assert rec.rate is None
        np.testing.assert_array_equal(rec.time, t)
    with pytest.raises(InputError, match=r"^t.csv: the rate 100 Hz \(the rate argument\) contradicts the 't' "
                                         r"column \(typical interval 0.005 s, 200 Hz\)"):
        load_csv(path, rate=100.0)
    (tmp_path / "c.csv").write_text("# rate=100\n" + path.read_text())
    with pytest.raises(InputError, match=r"the rate 100 Hz \(its '# rate=' line\) contradicts"):
        load_csv(tmp_path / "c.csv")
    with pytest.raises(InputError, match="rate must be a finite number > 0"):
        load_csv(path, rate=-200.0)
    # a 't' that repeats (ms stamps at 2 kHz) is said to repeat, not "typical interval 0 s, inf Hz" (review rev27b)
    coarse = "\n".join(f"{np.floor(k * 0.5) / 1000:.3f},0,0,0,0,0,9.8" for k in range(40))
    (tmp_path / "ms.csv").write_text("# rate=2000\nt,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + coarse + "\n")
    with pytest.raises(InputError, match=r"^ms.csv: the 't' column repeats its values \(20 of its 39 intervals"):
        load_csv(tmp_path / "ms.csv")


def test_load_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        fk.load(tmp_path / "nope.hdf5")
    (tmp_path / "x.bin").write_text("")
    with pytest.raises(InputError, match="supported are"):
        fk.load(tmp_path / "x.bin")
    with pytest.raises(InputError, match=r"is a folder: give one recording file"):
        fk.load(tmp_path)
    for name in ("x.ulg", "x.h5", "x.hdf5"):  # (a log or GNSS scenario ignored body=FLU and kept FRD)
        (tmp_path / name).write_text("")
        with pytest.raises(InputError, match=rf"^{name}: body=, rate= apply to a .csv file only"):
            fk.load(tmp_path / name, rate=100.0, body="FLU")
        with pytest.raises(InputError, match=rf"^{name}: rate= applies to a .csv file only"):
            fk.load(tmp_path / name, rate=100.0, body=None)
    # None is "not given" (a caller passing an optional value on): a ULog reads as it did (review rev27b)
    ulog = data_dir() / "ulog" / "sample_px4_events.ulg"
    if ulog.exists():
        assert len(fk.load(ulog, rate=None, body=None)) == len(fk.load(ulog))


def test_result_helpers(imu_rec, tmp_path):
    res = fk.make("poisson").run(imu_rec)
    assert res.euler().shape == (len(imu_rec), 3)
    assert res.flag_names(0) == ["ALIGNING"]
    np.testing.assert_allclose(res.to_scipy().as_quat()[:, [3, 0, 1, 2]], res.quat)
    res.to_csv(tmp_path / "o.csv", time=imu_rec.time)
    data = np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=1)
    assert data.shape == (len(imu_rec), 9)
    for bad in (imu_rec.time[:-1], imu_rec.time[:, None]):  # numpy's hstack error, once
        with pytest.raises(InputError, match=rf"time must have shape \({len(imu_rec)},\), one time in s per "
                                             "sample of the result, got " + re.escape(str(bad.shape))):
            res.to_csv(tmp_path / "o.csv", time=bad)


def test_broad_trial_loads(broad_dir):
    r = fk.load(sorted(broad_dir.glob("*.hdf5"))[0])
    assert r.rate == pytest.approx(285.71, abs=0.01)
    assert r.mag is not None and r.truth is not None and r.movement.any()
    assert r.truth_frame == "ENU"


def test_gnss_stream_checks():
    r = sim.simulate([sim.Rest(2.0)], rate=50.0)
    t = r.gnss.t.copy()
    t[5] = t[4]
    with pytest.raises(InputError, match=r"gnss.t must be strictly increasing, but gnss.t\[5\]"):
        fk.Gnss(t=t, vel=r.gnss.vel)
    vel = r.gnss.vel.copy()
    vel[3] = np.nan
    g = fk.Gnss(t=r.gnss.t, vel=vel, valid=np.ones(len(vel), bool))
    assert not g.valid[3] and g.valid[4]  # a NaN epoch is a gap, not an error
    late = fk.Gnss(t=r.gnss.t + 1.0, vel=r.gnss.vel)
    with pytest.warns(UserWarning, match="outside the IMU time"):
        rec = fk.Recording(gyr=r.gyr, acc=r.acc, rate=50.0, gnss=late)
    assert rec.gnss.t.max() <= rec.time[-1]
    with pytest.raises(InputError, match="gnss must be a fusionkit.Gnss"):
        fk.Recording(gyr=r.gyr, acc=r.acc, rate=50.0, gnss={"t": 1})


def _csv_in(tmp_path, name, gyr_scale=1.0, acc_scale=1.0, comments=""):
    """8 s of the demo's fast rotations as a CSV, its gyro and accelerometer columns multiplied."""
    r = sim.demo_recordings()[1].slice(2400, 4000)
    path = tmp_path / name
    write_csv(fk.Recording(gyr=r.gyr, acc=r.acc, mag=r.mag, rate=200.0), path)
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    data[:, 1:4] *= gyr_scale
    data[:, 4:7] *= acc_scale
    header = path.read_text().splitlines()[0]
    np.savetxt(path, data, delimiter=",", header=comments + header, comments="", fmt="%.10g")
    return r, path


def test_a_csv_in_deg_s_and_g_loads_with_the_unit_its_message_names(tmp_path):
    """``load("deg.csv")`` said "pass gyr_unit='deg/s'", and ``load("deg.csv", gyr_unit="deg/s")``
    failed (load_csv took no unit): the units are load()'s arguments and the CSV's comment lines,
    and the message names both (and the command line's option)."""
    r, path = _csv_in(tmp_path, "deg.csv", gyr_scale=180 / np.pi, acc_scale=1 / 9.80665)
    with pytest.raises(InputError, match=r"deg\.csv: .*acc_unit='g'.*'# acc_unit=UNIT' line.*--acc-unit UNIT"):
        fk.load(path)
    with pytest.raises(InputError, match=r"gyr_unit='deg/s'.*--gyr-unit UNIT"):
        fk.load(path, acc_unit="g")
    rec = fk.load(path, gyr_unit="deg/s", acc_unit="g")
    np.testing.assert_allclose(rec.gyr, r.gyr, atol=1e-8)
    np.testing.assert_allclose(rec.acc, r.acc, atol=1e-8)
    _, commented = _csv_in(tmp_path, "commented.csv", gyr_scale=180 / np.pi, acc_scale=1000 / 9.80665,
                           comments="# gyr_unit=deg/s\n# acc_unit=mg\n")
    rec = fk.load(commented)
    np.testing.assert_allclose(rec.gyr, r.gyr, atol=1e-8)
    np.testing.assert_allclose(rec.acc, r.acc, atol=1e-8)
    assert fk.load(commented, acc_unit="mg").acc[0] == pytest.approx(rec.acc[0])  # the argument overrides
    with pytest.raises(InputError, match=r"gyr_unit= applies to a \.csv file only; .* clock, body axes and units"):
        fk.load(_hdf5(tmp_path), gyr_unit="deg/s")


def _hdf5(tmp_path):
    h5py = pytest.importorskip("h5py")
    path = tmp_path / "trial.hdf5"
    with h5py.File(path, "w") as f:
        f["imu_gyr"] = np.zeros((10, 3))
        f["imu_acc"] = np.tile([0, 0, 9.81], (10, 1))
        f.attrs["sampling_rate"] = 100.0
    return path


def test_load_reads_a_simulated_recording_as_the_cli_does():
    """``fk.load("sim:slow-rotation")`` said "no such file", though every command reads ``sim:NAME``."""
    rec = fk.load("sim:slow-rotation")
    assert rec.name == "slow-rotation" and rec.truth is not None
    assert fk.load("sim:late-gyro").name == sim.scenario("late-gyro").name
    with pytest.raises(InputError, match=r"unknown simulated recording 'nosuch'; choose from \['fast-rotation'"):
        fk.load("sim:nosuch")
    with pytest.raises(InputError, match="rate= applies to a .csv file only"):
        fk.load("sim:slow-rotation", rate=100.0)


def test_result_output_mistakes_are_input_errors_naming_the_argument(tmp_path):
    """``to_csv`` into a missing folder raised numpy's FileNotFoundError, ``flag_names`` past the end
    a bare IndexError."""
    res = fk.make("poisson").run(sim.demo_recordings()[0].slice(0, 2400))
    with pytest.raises(InputError, match=r"path: cannot write '.*nonexist.*r\.csv'"):
        res.to_csv(tmp_path / "nonexist" / "r.csv")
    with pytest.raises(InputError, match=r"i is 1000000, but the result has 2400 samples: give an index from 0 to 2399"):
        res.flag_names(10**6)
    with pytest.raises(InputError, match="i must be a sample index"):
        res.flag_names(1.5)
    assert res.flag_names(-1) == res.flag_names(2399)
