"""What the fast paths do to stay fast: the generated loop calls its kernels inline, a run does not
scan its input for non-finite values when the loop's flags already say there are none, and the
same numbers come out (the compiled = reference tests are in test_loopgen.py and test_contract.py)."""

import numpy as np
import pytest

import fusionkit as fk
import fusionkit._numba
from fusionkit import _loopgen, sim
from fusionkit._numba import HAVE_NUMBA, inline_copy, njit
from fusionkit.errors import InputError

DEG = np.pi / 180


@pytest.fixture(scope="module")
def rec():
    segs = [sim.Rest(2.0), sim.Rotate((0, 0, 1), 90 * DEG, 1.5), sim.Rest(0.5)]
    return sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=5)


@njit(cache=False)
def _leaf(x):
    return 2.0 * x


@njit(cache=False)
def _branch(x):
    return _leaf(x) + 1.0


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
def test_inline_copy_makes_inline_twins_of_the_whole_call_tree():
    twin = inline_copy(_branch)
    assert twin is not _branch and twin.targetoptions["inline"] == "always"
    assert _branch.targetoptions["inline"] == "never"  # the original is untouched
    assert twin.py_func.__globals__["_leaf"].targetoptions["inline"] == "always"
    assert inline_copy(_branch) is twin  # one twin per function
    assert twin(3.0) == _branch(3.0) == 7.0
    assert inline_copy(len) is len  # not a numba function: returned as it is


def test_the_loop_calls_its_kernels_inline_and_step_calls_the_loop(monkeypatch):
    """The loop inlines every per-sample kernel; ``step`` (``update()``'s) runs that loop over one
    sample instead of a second body of its own (one compile per composition). (The suite's own
    loops call their kernels, ``FUSIONKIT_LOOP_INLINE=0``; what users get is inlined.)"""
    monkeypatch.setattr(fusionkit._numba, "LOOP_INLINE", True)
    f = fk.make("gradient-descent")
    ek, mks, dks, cks = f._kernels()
    for unit in (False, True):  # a unit-quaternion state is the output itself: no to_quat
        lay = _loopgen.Layout((ek.propagate, ek.to_quat, ek.from_quat), unit,
                              (_loopgen.KernelSpec(cks[0].correct, "state"),), 20, 23)
        text = _loopgen.source(lay, False, None)
        loop, step = text.split("def step(")
        loop = loop.split("def loop(")[1]
        for name in ("k0", "e_propagate", "e_to_quat", "validity_flags"):
            if name == "e_to_quat" and unit:
                assert "e_to_quat(" not in loop + step and "q[0], q[1], q[2], q[3] = x[0]" in loop
                continue
            assert f"i_{name}(" in loop and f"{name} = inline_copy({name})" in text
            assert f"{name}(" not in step  # no second body: the loop's compiled code serves update()
        assert " loop(" in step and "np.int64(0), np.int64(1)" in step  # int64 bounds: run()'s signature


def test_a_non_finite_sample_still_raises_and_a_gap_does_not(rec):
    """The check for non-finite input runs only where the loop flagged an invalid sample: it
    still raises naming the sample, and a sample flagged for another reason (a timestamp gap, a
    reading beyond the sensor's limits) does not make it raise."""
    f = fk.make("gradient-descent")
    bad = rec.gyr.copy()
    bad[150, 1] = np.nan
    with pytest.raises(InputError, match=r"gyr\[150\]"):
        f.run(fk.Recording(gyr=bad, acc=rec.acc, mag=rec.mag, rate=rec.rate))
    t = rec.time.copy()
    t[300:] += 1.0  # a 1 s gap
    with pytest.warns(fk.types.GapWarning):
        r = f.run(fk.Recording(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, t=t))
    assert np.isfinite(r.quat).all() and r.diagnostics["gaps"] == 1
    zero = rec.acc.copy()
    zero[200] = 0.0  # an accelerometer reading of zero: flagged invalid, finite
    r = f.run(fk.Recording(gyr=rec.gyr, acc=zero, mag=rec.mag, rate=rec.rate))
    assert r.flags[200] & fk.Flag.ACC_INVALID
    skip = fk.make("gradient-descent", nan_policy="skip").run(fk.Recording(gyr=bad, acc=rec.acc, mag=rec.mag,
                                                                           rate=rec.rate))
    assert skip.flags[150] & fk.Flag.GYR_INVALID and np.isfinite(skip.quat).all()


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
def test_numbas_first_start_skips_scipy_linalg_and_blas_still_works():
    """numba's BLAS check finds scipy.linalg.cython_blas without importing all of scipy.linalg; a
    later np.dot compiles, and scipy.linalg imported later has its cython_blas."""
    import subprocess
    import sys
    import textwrap

    pytest.importorskip("scipy")
    code = textwrap.dedent("""
        import sys
        import numpy as np
        import fusionkit
        from fusionkit._numba import njit

        @njit(cache=False)
        def total(a):
            return a.sum()

        total(np.ones(3))
        import numba.np.arraymath
        print("scipy.linalg" in sys.modules, numba.np.arraymath._HAVE_BLAS)

        @njit(cache=False)
        def dot(a, b):
            return np.dot(a, b)

        print(dot(np.eye(2), np.ones(2)).tolist())
        import scipy.linalg
        print(scipy.linalg.cython_blas.__name__, "fusionkit.sim" in sys.modules, fusionkit.sim.__name__)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:3] == ["False True", "[1.0, 1.0]", "scipy.linalg.cython_blas False fusionkit.sim"]


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")
def test_unit_scan_stops_when_the_median_is_decided_and_decides_as_numpy():
    """The compiled unit scan stops once more than half of every possible count lies on one side
    of a threshold; its decisions are still numpy's median's, for data decided early, late (the
    deciding values at the end) and not at all until the last sample."""
    from fusionkit import validation

    rng = np.random.default_rng(7)
    n = 5 * validation._BLOCK + 17
    thr = np.array([*validation.ACC_G_WINDOW, validation.GYR_DEG_BOUND])
    g_in_rad = 0.3 * rng.standard_normal((n, 3))
    a_in_ms2 = np.array([0.0, 0.0, 9.81]) + 0.1 * rng.standard_normal((n, 3))
    st = validation.unit_scan(g_in_rad, a_in_ms2, thr)
    assert list(st[:, 5]) == [1.0, 1.0, -1.0] and st[0, 0] < n and st[2, 0] < 3 * n  # stopped early
    late = a_in_ms2.copy()
    late[: n // 2 + 1] /= 9.81  # in g for the first half and one sample: the median is in g
    g_late = g_in_rad.copy()
    g_late[n // 2:] *= 100.0  # the second half far above 2 pi
    for gyr, acc in ((g_in_rad, a_in_ms2), (g_late, late), (g_in_rad, late[::-1].copy())):
        scan = validation._unit_medians(gyr, acc)
        norms = np.linalg.norm(acc, axis=1)
        expect = tuple(int(m > t) - int(m < t) for m, t in ((np.median(norms), thr[0]), (np.median(norms), thr[1]),
                                                            (np.median(np.abs(gyr)), thr[2])))
        assert scan == expect
