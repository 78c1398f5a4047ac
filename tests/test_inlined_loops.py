"""The loops users run inline their kernels; the suite's call them (``FUSIONKIT_LOOP_INLINE=0``,
tests/conftest.py, for a tenth of the compile time per composition). Here the registered
presets' compositions are compiled both ways and give the same numbers to the last bit, so what
the rest of the suite checks on the called loops holds for the inlined ones: every kernel of the
presets inlined at least once (see the list below), ``recommended``'s compile (the suite's
longest) in test_inlined_loops_recommended.py, so that ``-n 2 --dist
loadfile`` runs the two files on both workers at once."""

import numpy as np
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


# recommended: test_inlined_loops_recommended.py, on the other xdist worker.
# gst's and poisson's compositions are not compiled a third time here: gst's corrector kernel is
# gst-gnss's step (``_gst_step``) with its GNSS input off, poisson's composition is gst's without
# a corrector, and the loop template without a GNSS column is gradient-descent's and channel-dcm's,
# so every kernel and both forms of the loop are inlined below (and in recommended's file).
@pytest.mark.parametrize("name, params", [("gradient-descent", {}), ("channel-dcm", {}), ("gst-gnss", {})])
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


def test_static_options_are_literals_inlined_and_parameters_called(monkeypatch):
    """A kernel's compile-time options (``static``) reach it as literals in the loop users run (so
    numba compiles only the branches they select) and, in the suite's called loops, from the end of
    its parameter vector, so that one loop serves every value of them; more than 30 arguments in a
    call (numba cannot inline CPython's ``*args`` call) and non-bool options are refused."""
    f = fk.make("gradient-descent")
    ek, mks, dks, cks = f._kernels()
    est = [("m", "p"), ("m", "t"), ("m", "f")]

    def text(inline, static):
        monkeypatch.setattr(fn, "LOOP_INLINE", inline)
        lay = _loopgen.Layout((ek.propagate, ek.to_quat, ek.from_quat), True,
                              (_loopgen.KernelSpec(cks[0].correct, "state", static=static),), 20, 23)
        return _loopgen.source(lay, True, {0: ("m", "k")}, est)

    inlined, called = text(True, (True, False)), text(False, (True, False))
    assert "p0, True, False)" in inlined
    assert "p0, p0[p0.shape[0] - 2] != 0.0, p0[p0.shape[0] - 1] != 0.0)" in called
    assert text(False, (False, True)) == called  # (one called loop for every value)
    assert text(True, (False, True)) != inlined
    with pytest.raises(fk.PluginError, match="gradient.*30"):
        text(True, (True,) * 20)
    with pytest.raises(fk.PluginError, match="gradient.*bool"):
        _loopgen.KernelSpec(cks[0].correct, "state", static=(np.True_,))
    blind = _loopgen._static_blind(_loopgen.Layout((ek.propagate, ek.to_quat, ek.from_quat), True, (
        _loopgen.KernelSpec(cks[0].correct, "state", static=(True, False)),), 20, 23))
    assert blind.kernels[0].static == (False, False)  # (the called loop's key: one module for every value)
    p = _loopgen.static_params(np.array([2.0, 3.0]), (True, False))
    assert p.tolist() == [2.0, 3.0, 1.0, 0.0]


@njit(cache=False, cold=True)
def _if_soft(x):
    return x + 1.0


@njit(cache=False, cold=True)
def _if_hard(x):
    return x + 2.0


@njit(cache=False, inline="always")
def _kernel_with_option(x, soft):
    return _if_soft(x) if soft else _if_hard(x)


def test_a_literal_static_option_prunes_the_branch_it_rules_out():
    """What the loop users run does with a static option: the kernel's twin inlined into a loop
    compiled by the loop's compiler with the option as a literal; the branch it rules out is never
    compiled (its cold helper, a call of its own, has no signature afterwards)."""
    twin = fn.inline_copy(_kernel_with_option)

    @njit(cache=False, forward_copies=True)
    def loop(x):
        return twin(x, True)

    assert loop(1.0) == 2.0
    assert _if_soft.signatures and not _if_hard.signatures
