"""The loops users run inline their kernels; the suite's call them (``FUSIONKIT_LOOP_INLINE=0``,
tests/conftest.py, for a tenth of the compile time per composition). Here every registered
preset's composition is compiled both ways and gives the same numbers to the last bit, so what the
rest of the suite checks on the called loops holds for the inlined ones: here every preset but
``recommended``, whose compile (the suite's longest, online and offline) is test_inlined_loops_recommended.py's,
so that ``-n 2 --dist loadfile`` runs the two files on both workers at once."""

import pytest

import fusionkit as fk
import fusionkit._numba as fn
from fusionkit import _loopgen
from fusionkit._numba import HAVE_NUMBA, call_copy, njit
from inlined import assert_inlined_equals_called, recording

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")


@pytest.fixture(scope="module")
def rec():
    return recording()


# recommended (online and offline): test_inlined_loops_recommended.py, on the other xdist worker
@pytest.mark.parametrize("name, params", [("gradient-descent", {}), ("channel-dcm", {}), ("gst", {}),
                                          ("gst-gnss", {}), ("poisson", {})])
def test_inlined_loop_equals_the_called_one(name, params, rec, monkeypatch):
    assert_inlined_equals_called(name, params, rec, monkeypatch)


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
