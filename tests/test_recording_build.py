"""Building a long Recording (issue 17: 1M samples in under 10 ms): no array the size of the
recording that the checks do not need (no ``dt`` array for a constant rate, no interval array
for timestamps), one pass over the timestamps, the turning check's compiled twins deciding as
the numpy reference does, and every check still raising. No timing is asserted
(``benchmarks/recording_build.py`` measures it)."""

from __future__ import annotations

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim, types, validation
from fusionkit._numba import HAVE_NUMBA
from fusionkit.errors import InputError

DEG = np.pi / 180.0
RATE = 1100.0  # 46 s of the scenario below: more samples than SCAN_MIN_SAMPLES (the compiled path)


@pytest.fixture(scope="module")
def slow_turns():
    """Mostly still, a few slow turns: a gyro in deg/s stays below the magnitude bound, and only
    the turning of mag / acc tells its unit."""
    segs = [sim.Rest(20)] + [sim.Rotate(ax, 60 * DEG, 2.0) for ax in ((1, 0, 0), (0, 1, 0), (0, 0, 1))] + [sim.Rest(20)]
    rec = sim.simulate(segs, rate=RATE, noise=sim.Noise.mems(), seed=1, gnss_rate=None)
    assert len(rec) > validation.SCAN_MIN_SAMPLES
    return rec


class _NoIntervals:
    """Replaces ``Recording.dt``: the recording's (N,) interval array must not be asked for."""

    def __get__(self, obj, owner=None):
        raise AssertionError("Recording.dt was computed")


def test_building_a_recording_computes_no_interval_array(slow_turns, monkeypatch):
    """Before, the turning check took ``self.dt``: an (N,) array of 1/rate (or of np.diff(t))."""
    rec = slow_turns
    monkeypatch.setattr(types.Recording, "dt", _NoIntervals())
    for clock in ({"rate": RATE}, {"t": rec.time}):
        for mag in (rec.mag, None):
            fk.Recording(gyr=rec.gyr, acc=rec.acc, mag=mag, **clock)
            with pytest.raises(InputError, match="gyr_unit='deg/s'"):  # the turning check still runs
                fk.Recording(gyr=np.degrees(rec.gyr), acc=rec.acc, mag=mag, **clock)


def test_a_gyro_in_rad_s_declared_deg_s_is_refused_on_the_compiled_path(slow_turns):
    """The turning check's fit on the gyro as given (before the deg/s conversion), compiled."""
    rec = slow_turns
    for clock in ({"rate": RATE}, {"t": rec.time}):
        for mag in (rec.mag, None):
            with pytest.raises(InputError, match="gyr looks like it is in rad/s already"):
                fk.Recording(gyr=rec.gyr, acc=rec.acc, mag=mag, gyr_unit="deg/s", **clock)
            fk.Recording(gyr=np.degrees(rec.gyr), acc=rec.acc, mag=mag, gyr_unit="deg/s", **clock)


def test_a_long_recording_shares_the_callers_arrays(slow_turns):
    rec = slow_turns
    gyr, acc, mag, t = (np.ascontiguousarray(x, dtype=np.float64) for x in (rec.gyr, rec.acc, rec.mag, rec.time))
    for clock in ({"rate": RATE}, {"t": t}):
        r = fk.Recording(gyr=gyr, acc=acc, mag=mag, **clock)
        assert np.shares_memory(r.gyr, gyr) and np.shares_memory(r.acc, acc) and np.shares_memory(r.mag, mag)
    assert np.shares_memory(fk.Recording(gyr=gyr, acc=acc, t=t).t, t)


@pytest.mark.parametrize("n", [5, 60_000])
def test_timestamps_checked_in_one_pass_still_name_the_bad_sample(n):
    gyr = np.zeros((n, 3))
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    t = np.arange(n) / 100.0
    fk.Recording(gyr=gyr, acc=acc, t=t)
    bad = {"not finite": [(0, -np.inf), (n - 1, np.inf), (n // 2, np.nan), (0, np.nan), (n - 1, np.nan)],
           "strictly increasing": [(n // 2, t[n // 2 - 1]), (n - 1, t[n - 3]), (1, -1.0)]}
    for message, cases in bad.items():
        for i, value in cases:
            tt = t.copy()
            tt[i] = value
            with pytest.raises(InputError, match=message) as exc:
                fk.Recording(gyr=gyr, acc=acc, t=tt)
            assert "t[" in str(exc.value)
    with pytest.raises(InputError, match="t has"):
        fk.Recording(gyr=gyr, acc=acc, t=t[:-1])


def _both_paths(fn):
    """``fn()`` on the numpy reference and on the compiled path."""
    old = validation.SCAN_MIN_SAMPLES
    try:
        validation.SCAN_MIN_SAMPLES = 1 << 62
        ref = fn()
        validation.SCAN_MIN_SAMPLES = 0
        return ref, fn()
    finally:
        validation.SCAN_MIN_SAMPLES = old


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
def test_turning_check_compiled_twins_decide_as_numpy(slow_turns):
    """Window integrals and fitted scales of the compiled twins equal numpy's for the three
    clocks (a constant interval, the intervals, the timestamps), also over a timestamp gap and a
    non-finite sample; a gyro in deg/s gives pi/180 on both."""
    rec = slow_turns
    n = len(rec)
    t = rec.time.copy()
    t[n // 3:] += 0.5  # a timestamp gap: its window is left out
    gyr = rec.gyr.copy()
    gyr[n // 2] = np.nan
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    for g in (gyr, np.degrees(gyr)):
        for clock in ({"dt": 1.0 / RATE}, {"dt": dt}, {"t": t}):
            ref, fast = _both_paths(lambda: validation.window_turns(g, **clock))
            for a, b in zip(ref, fast):
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
            assert np.isnan(fast[2]).any()  # the NaN sample's window (and, with t, the gap's)
            for vec, quasi in ((rec.mag, False), (rec.acc, True)):
                s_ref, s_fast = _both_paths(lambda: validation.turning_scale(ref, vec, quasi_static=quasi))
                assert s_ref is not None and s_fast == pytest.approx(s_ref, rel=1e-9)
                if g is not gyr:
                    assert s_fast == pytest.approx(DEG, rel=0.2)
    with pytest.raises(InputError, match="mag turns"):
        fk.Recording(gyr=np.degrees(rec.gyr), acc=rec.acc, mag=rec.mag, t=t)


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
def test_unit_scan_counts_equal_numpy_when_no_sample_decides_early():
    """Data whose medians lie at the thresholds: the branch-free counts over every sample (and
    the extremes gathered after) equal numpy's, with zeros, NaN and inf rows counted out."""
    rng = np.random.default_rng(3)
    n = 3 * validation._BLOCK + 5
    thr = np.array([*validation.ACC_G_WINDOW, validation.GYR_DEG_BOUND])
    k = (n - 40) // 2  # as many norms below 0.3 as above 3: neither median is decided before the end
    acc = np.zeros((n, 3))
    acc[:, 0] = rng.permutation(np.r_[np.full(k, 0.29), np.full(k, 3.1), [0.3, 3.0] * 10, [0.0, np.nan, np.inf] * 6,
                                      np.full(n - 2 * k - 38, 0.25)])
    gyr = rng.permutation(np.r_[np.full(3 * k, 6.0), np.full(3 * k, -6.5), [2 * np.pi] * 7, [-np.inf, np.nan] * 3,
                                np.tile([6.0, 7.0], (3 * n - 6 * k - 13) // 2)]).reshape(n, 3)
    st = validation.unit_scan(gyr, acc, thr)
    norms = np.abs(acc[:, 0])
    norms = norms[np.isfinite(norms) & (norms > 0)]
    g = np.abs(gyr[np.isfinite(gyr).all(axis=1)]).ravel()
    for row, (v, th) in enumerate(((norms, thr[0]), (norms, thr[1]), (g, thr[2]))):
        m = np.median(v)
        side = int(m > th) - int(m < th)
        if st[row, 5] == 0:  # not decided before the end: complete counts, and the extremes
            assert st[row, :3].tolist() == [v.size, (v < th).sum(), (v == th).sum()]
            assert st[row, 3] == v[v < th].max() and st[row, 4] == v[v > th].min()
            assert validation.median_vs(int(st[row, 0]), int(st[row, 1]), int(st[row, 2]), st[row, 3], st[row, 4],
                                        th) == side
        else:
            assert st[row, 5] == side
    assert (st[:, 5] == 0).sum() >= 2  # medians left to the complete counts and the extremes


def test_nominal_dt_of_timestamps_is_computed_once_per_t(monkeypatch):
    """A run asks for ``nominal_dt`` several times: the median of a long recording's intervals
    once, again only when ``t`` is replaced."""
    n = 2000
    t = np.cumsum(np.full(n, 0.01) + 1e-4 * np.random.default_rng(0).standard_normal(n))
    rec = fk.Recording(gyr=np.zeros((n, 3)), acc=np.tile([0.0, 0.0, 9.81], (n, 1)), t=t)
    expect = float(np.median(rec.dt))
    calls = []
    real = types.Recording.dt

    def counted(self):
        calls.append(1)
        return real.fget(self)

    monkeypatch.setattr(types.Recording, "dt", property(counted))
    fk.make("gradient-descent").run(rec)
    assert rec.nominal_dt == pytest.approx(expect, rel=1e-12)
    assert len(calls) == 2  # one median, and run()'s own intervals
    rec.t = t * 2.0
    assert rec.nominal_dt == pytest.approx(2.0 * expect, rel=1e-12)


def test_post_run_finite_check_scans_only_when_a_flag_says_invalid(monkeypatch):
    """One OR-reduction of the flags decides whether the input is scanned: a single invalid bit
    anywhere (the last sample too) leads to the scan that raises naming the sample."""
    n = 70_000
    gyr = np.zeros((n, 3))
    invalid = int(types.Flag.GYR_INVALID | types.Flag.ACC_INVALID)
    flags = np.full(n, int(types.Flag.MOTION | types.Flag.REST), np.uint32)  # other bits: no scan
    scans = []
    real = validation.check_finite_all
    monkeypatch.setattr(validation, "check_finite_all", lambda *a: (scans.append(1), real(*a)))
    validation.check_finite_flagged({"gyr": gyr}, "raise", flags, invalid)
    validation.check_finite_flagged({"gyr": gyr}, "raise", flags[:0], invalid)
    assert scans == []
    gyr[-1, 2] = np.nan
    flags[-1] |= np.uint32(types.Flag.GYR_INVALID)
    validation.check_finite_flagged({"gyr": gyr}, "skip", flags, invalid)  # nothing to raise
    with pytest.raises(InputError, match=rf"gyr\[{n - 1}\] is not finite"):
        validation.check_finite_flagged({"gyr": gyr}, "raise", flags, invalid)
    assert scans == [1]
