"""The loops users run inline their kernels; the suite's call them (``FUSIONKIT_LOOP_INLINE=0``,
tests/conftest.py, for a tenth of the compile time per composition). Here every registered
preset's composition is compiled both ways and gives the same numbers to the last bit, so what the
rest of the suite checks on the called loops holds for the inlined ones."""

import dataclasses

import numpy as np
import pytest

import fusionkit as fk
import fusionkit._numba as fn
from fusionkit import _loopgen, sim
from fusionkit._numba import HAVE_NUMBA, call_copy, njit

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
DEG = np.pi / 180


@pytest.fixture(scope="module")
def rec():
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
    res = fk.make(name, nan_policy="skip", **params).run(rec, backend="numba")
    assert res.diagnostics["backend"] == "numba"
    return res


@pytest.mark.parametrize("name, params", [("recommended", {}), ("recommended", {"offline": True}),
                                          ("gradient-descent", {}), ("channel-dcm", {}), ("gst", {}),
                                          ("gst-gnss", {}), ("poisson", {})])
def test_inlined_loop_equals_the_called_one(name, params, rec, monkeypatch):
    called = _run(name, params, rec, False, monkeypatch)
    inlined = _run(name, params, rec, True, monkeypatch)
    np.testing.assert_array_equal(inlined.quat, called.quat)
    np.testing.assert_array_equal(inlined.flags, called.flags)
    st_c, st_i = called.diagnostics.get("state"), inlined.diagnostics.get("state")
    if st_c is not None:
        for key in ("x", "align"):
            np.testing.assert_array_equal(np.asarray(st_i[key]), np.asarray(st_c[key]))


def test_the_two_kinds_of_loop_are_separate_cache_entries(monkeypatch):
    """The loop's source names what it calls its kernels through, so a session's called loops and
    a user's inlined ones never share a cache entry (or a module in the process)."""
    f = fk.make("gradient-descent")
    ek, mks, dks, cks = f._kernels()
    lay = _loopgen.Layout((ek.propagate, ek.to_quat, ek.from_quat), True,
                          (_loopgen.KernelSpec(cks[0].correct, "state"),), 20, 23)
    texts = {}
    for inline in (False, True):
        monkeypatch.setattr(fn, "LOOP_INLINE", inline)
        texts[inline] = _loopgen.source(lay, True, {0: ("m", "k")}, [("m", "p"), ("m", "t"), ("m", "f")])
    assert "k0 = call_copy(k0)" in texts[False] and "k0 = inline_copy(k0)" in texts[True]
    assert texts[False] != texts[True]


@njit(cache=False, inline="always")
def _always(x):
    return x + 1.0


@njit(cache=False)
def _plain(x):
    return x + 2.0


def test_call_copy_compiles_an_always_inlined_kernel_as_a_call():
    twin = call_copy(_always)
    assert twin is not _always and twin.py_func is _always.py_func
    assert twin.targetoptions["inline"] == "never" and _always.targetoptions["inline"] == "always"
    assert call_copy(_always) is twin  # one per function
    assert call_copy(_plain) is _plain and call_copy(len) is len
    assert twin(1.0) == 2.0
