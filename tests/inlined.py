"""What the inlined-loop tests share (test_inlined_loops.py and test_inlined_loops_recommended.py,
two files so that ``--dist loadfile`` compiles their presets on both workers): the recording and
the check that a preset's inlined loop gives its called loop's numbers to the last bit."""

import dataclasses

import numpy as np

import fusionkit as fk
import fusionkit._numba as fn
from fusionkit import sim

DEG = np.pi / 180


def recording() -> fk.Recording:
    """Rest, rotations, a translation, rest again (GNSS included), with an invalid gyro sample,
    an accelerometer dropout and an invalid magnetometer sample."""
    segs = [sim.Rest(6.0), sim.Rotate((1, 0.3, 0), 60 * DEG, 2.0), sim.Rotate((0, 0, 1), 120 * DEG, 2.0),
            sim.Translate((1, 1, 0), 0.3, 1.0), sim.Rotate((1, 0.3, 0), -60 * DEG, 2.0), sim.Rest(3.0)]
    r = sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=4, gnss_vel_noise=0.05)
    r = dataclasses.replace(r, gyr=r.gyr.copy(), acc=r.acc.copy(), mag=r.mag.copy())
    r.gyr[700] = np.nan
    r.acc[800:803] = 0.0
    r.mag[900] = np.nan
    return r


def _run(name, params, rec, inline, monkeypatch):
    monkeypatch.setattr(fn, "LOOP_INLINE", inline)
    f = fk.make(name, nan_policy="skip", **params)
    res = f.run(rec, backend="numba")
    assert res.diagnostics["backend"] == "numba"
    return res


def assert_inlined_equals_called(name, params, rec, monkeypatch):
    """Preset ``name`` with ``params`` run through its called loop and its inlined loop: the same
    quaternions, flags and (where the filter reports one) final state, to the bit."""
    called = _run(name, params, rec, False, monkeypatch)
    inlined = _run(name, params, rec, True, monkeypatch)
    np.testing.assert_array_equal(inlined.quat, called.quat)
    np.testing.assert_array_equal(inlined.flags, called.flags)
    st_c, st_i = called.diagnostics.get("state"), inlined.diagnostics.get("state")
    if st_c is not None:
        for key in ("x", "align"):
            np.testing.assert_array_equal(np.asarray(st_i[key]), np.asarray(st_c[key]))
