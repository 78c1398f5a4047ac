"""Bad input, the same for every attitude filter of issue 3: all-zero or NaN accelerometer and
magnetometer samples skip their correction and are flagged (free fall, dropouts), a gyro above its
configured range is flagged, a NaN gyro sample holds the state, and nothing becomes NaN, on every
backend."""

import dataclasses

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.rotations import quat_angle
from fusionkit.types import Flag

FILTERS = ["gradient-descent", "channel-dcm", "ekf", "recommended"]
DEG = np.pi / 180


@pytest.fixture(scope="module")
def damaged():
    segs = [sim.Rest(4.0), sim.Rotate((1, 0.2, 0), 60 * DEG, 2.0), sim.Rest(2.0), sim.Rotate((0, 0, 1), 90 * DEG, 2.0),
            sim.Rest(2.0)]
    rec = sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=9, gnss_rate=None)
    bad = dataclasses.replace(rec, gyr=rec.gyr.copy(), acc=rec.acc.copy(), mag=rec.mag.copy())
    bad.acc[650:700] = 0.0  # free fall / dropout (during a rest: nothing to correct, nothing may jump)
    bad.acc[720] = np.nan
    bad.mag[1050:1100] = 0.0  # during the last rest
    bad.mag[1110] = np.nan
    bad.gyr[1150] = np.nan
    bad.gyr[500] = [12.0, 0.0, 0.0]  # beyond a 10 rad/s range
    return rec, bad


def all_finite(state) -> bool:
    """Every number in a state (an array, or a pipeline's dict of arrays and lists)."""
    if isinstance(state, dict):
        return all(all_finite(v) for v in state.values())
    if isinstance(state, (list, tuple)):
        return all(all_finite(v) for v in state)
    return bool(np.isfinite(np.asarray(state, dtype=float)).all())


def backends(name):
    return ["reference"] if name == "ekf" else ["reference", "numba"]


@pytest.mark.parametrize("name", FILTERS)
def test_flags_and_no_nan(damaged, name):
    rec, bad = damaged
    for backend in backends(name):
        res = fk.make(name, nan_policy="skip", gyr_range=10.0).run(bad, backend=backend)
        assert np.isfinite(res.quat).all() and all_finite(res.diagnostics["state"]), backend
        f = res.flags
        assert np.all(f[650:700] & Flag.ACC_INVALID) and f[720] & Flag.ACC_INVALID
        assert np.all(f[1050:1100] & Flag.MAG_INVALID) and f[1110] & Flag.MAG_INVALID
        assert f[1150] & Flag.GYR_INVALID and f[500] & Flag.GYR_SATURATED
        assert not np.any(f[:500] & (Flag.ACC_INVALID | Flag.MAG_INVALID | Flag.GYR_INVALID))


@pytest.mark.parametrize("name", FILTERS)
def test_skipped_corrections_do_not_jump(damaged, name):
    """Over the dropouts (at rest) the attitude moves no more per sample than the undamaged run
    does there (gradient descent dithers by its fixed step beta dt around the minimum, the others
    by the noise), and before any damage the runs are equal."""
    rec, bad = damaged
    good = fk.make(name).run(rec)
    res = fk.make(name, nan_policy="skip", gyr_range=10.0).run(bad)
    for a, b in ((650, 700), (1050, 1100)):
        steps = np.degrees(quat_angle(res.quat[a:b], res.quat[a - 1:b - 1]))
        usual = np.degrees(quat_angle(good.quat[a:b], good.quat[a - 1:b - 1]))
        assert steps.max() <= 1.2 * usual.max() + 0.01, (a, steps.max(), usual.max())
    assert np.degrees(np.max(quat_angle(res.quat[:500], good.quat[:500]))) < 1e-9  # before any damage


@pytest.mark.parametrize("name", FILTERS)
def test_nan_raises_by_default_naming_the_sample(damaged, name):
    _, bad = damaged
    with pytest.raises(fk.InputError, match=r"acc\[720\]"):
        fk.make(name).run(dataclasses.replace(bad, acc=np.where(np.isnan(bad.acc), np.nan, bad.acc + 0.0)))
    with pytest.raises(fk.InputError, match="not finite"):
        fk.make(name).update([np.nan, 0.0, 0.0], [0.0, 0.0, 9.81], None, dt=0.01)


@pytest.mark.parametrize("name", FILTERS)
def test_degenerate_poses_and_fields(name):
    """Starting with the body's y axis vertical and no magnetometer, or with a field along the
    vertical (no heading in it): finite, unit quaternions on every backend."""
    n = 300
    up_y = fk.Recording(gyr=np.zeros((n, 3)) + 0.001, acc=np.tile([0.0, 9.81, 0.0], (n, 1)), rate=100.0)
    vertical_field = fk.Recording(gyr=np.zeros((n, 3)) + 0.001, acc=np.tile([0.0, 0.0, 9.81], (n, 1)),
                                  mag=np.tile([0.0, 0.0, -45.0], (n, 1)), rate=100.0)
    for rec in (up_y, vertical_field):
        for backend in backends(name):
            q = fk.make(name).run(rec, backend=backend).quat
            assert np.isfinite(q).all(), (name, backend)
            np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-9)


def test_a_long_gap_integrated_as_one_step_stays_finite_on_both_paths():
    """``max_gap=None`` integrates a 100 s gap as one step: the rest learner's Kalman process noise
    divided by ``1 - kb`` = 0 there (the compiled loop raised ZeroDivisionError, the reference ran
    on with an infinite variance); capped at the turn-on variance, both paths agree and stay finite."""
    rng = np.random.default_rng(0)
    n = 300
    gyr = rng.normal(0, 0.05, (n, 3))
    acc = np.tile([0, 0, 9.81], (n, 1)) + rng.normal(0, 0.05, (n, 3))
    t = np.arange(n) / 100.0
    t[150:] += 100.0
    rec = fk.Recording(gyr=gyr, acc=acc, mag=np.tile([0, 20.0, -40.0], (n, 1)), t=t)
    out = {}
    for backend in ("reference", "numba"):
        res = fk.make("recommended", max_gap=None).run(rec, backend=backend)
        assert np.isfinite(res.quat).all() and all_finite(res.diagnostics["state"]), backend
        out[backend] = res.quat
    assert np.abs(out["numba"] - out["reference"]).max() < 1e-9
