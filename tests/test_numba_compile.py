"""What fusionkit does to numba's compile to make a first run shorter (fusionkit/_numba.py): no
colour markup of the error messages numba writes (and discards) while it types, one compile of a
function for every integer constant it is called with, one copy of an inlined function's IR per
call site instead of two, and each call's typing resolved once. The numbers compiled are the same: the inlined loops are checked
against the called ones to the bit in test_inlined_loops*.py."""

import os
import subprocess
import sys

import numpy as np
import pytest

import fusionkit._numba as fn
from fusionkit._numba import njit

pytestmark = pytest.mark.skipif(not fn.HAVE_NUMBA, reason="numba is not installed")


def test_numbas_error_messages_are_not_marked_up():
    from numba.core import errors

    assert os.environ.get("NUMBA_DISABLE_ERROR_MESSAGE_HIGHLIGHTING")
    assert type(errors.termcolor()).__name__ == "NOPColorScheme"


def test_numba_imported_first_is_unmarked_too_and_a_users_colours_stay():
    """numba imported before fusionkit (it read the switch already): its scheme's markup is made a
    no-op; a user who set numba's colour scheme keeps it."""
    code = ("import numba, fusionkit; from numba.core import errors; "
            "print(errors.termcolor().errmsg('x') == 'x')")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_COLOR") and "HIGHLIGHTING" not in k}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    kept = subprocess.run([sys.executable, "-c", code], env={**env, "NUMBA_COLOR_SCHEME": "dark_bg"},
                          capture_output=True, text=True, check=True)
    try:
        import colorama  # noqa: F401  (without it numba marks nothing up in the first place)
    except ImportError:
        assert out.stdout.strip() == kept.stdout.strip() == "True"
        return
    assert out.stdout.strip() == "True" and kept.stdout.strip() == "False"


@njit(cache=False)
def _at(s, i):
    return s[i]


@njit(cache=False)
def _flagged(x, on):
    return x + 1.0 if on else x - 1.0


@njit(cache=False)
def _caller(s):
    return _at(s, 3) + _at(s, 5) + _flagged(s[0], True)


def test_integer_constants_share_one_compile_and_booleans_keep_their_value():
    from numba.core import types

    assert _caller(np.arange(8.0)) == 3.0 + 5.0 + 1.0
    (sig,) = _at.overloads  # one compile for 3 and 5 (numba alone: one for each)
    assert sig[1] == types.int64
    (sig,) = _flagged.overloads  # a boolean constant's value still selects the branch at compile time
    assert isinstance(sig[1], types.BooleanLiteral)


@njit(cache=False, inline="always")
def _helper(x):
    y = x * 2.0
    if y > 3.0:
        return y - 1.0
    return y


@njit(cache=False)
def _inlines(x):
    return _helper(x) + _helper(x + 1.0)


def test_the_inliner_copies_a_callee_once_per_call_site():
    """The shim numba's inliner copies through: a block of the copy it made (the "unmutated"
    second copy numba's callers discard) comes back as it is; any other block is copied; with
    numba's sources unlike those it was checked against, both copies are made."""
    from numba.core import inline_closurecall as icc
    from numba.core import ir

    assert _inlines(1.0) == 2.0 + 3.0  # (compiled with the shim installed)
    if not fn._copy_once_checked():
        pytest.skip("numba's inliner is not the one the single copy was checked against")
    shim = icc.copy
    assert isinstance(shim, fn._BlockCopy) and shim.once
    scope = ir.Scope(None, ir.Loc("f", 1))
    block = ir.Block(scope, ir.Loc("f", 1))
    block.append(ir.Assign(ir.Const(1.0, block.loc), scope.redefine("a", block.loc), block.loc))
    saved = shim.memos, shim.made
    try:
        shim.memos, shim.made = {}, {}
        first = shim.deepcopy(block)
        assert first is not block and first.scope is not scope and first.body[0].target.name == "a"
        assert shim.deepcopy(first) is first
        shim.once = False
        assert shim.deepcopy(first) is not first
    finally:
        shim.memos, shim.made = saved
        shim.once = True


def test_a_numba_with_other_inliner_sources_copies_twice(monkeypatch):
    fn._install_linear_inline_copy()
    if not fn._copy_once_checked():
        pytest.skip("numba's inliner is not the one the single copy was checked against")
    for name in ("inline_ir", "inline_function", "_do_work", "_run_inliner"):
        with monkeypatch.context() as m:
            m.setitem(fn._NUMBA_SOURCES, name, "0" * 16)
            assert not fn._copy_once_checked()


def test_a_resolved_call_is_kept_and_a_failure_raises_each_time():
    """numba's typing of a call of a function or an operator: a resolution that succeeded is kept
    (the same signature, numba's own, without searching the templates again); one that failed is
    searched again and raises as numba does."""
    import operator

    from numba.core import errors, types
    from numba.core.registry import cpu_target
    from numba.core.types import functions

    assert _inlines(2.0) == 4.0 - 1.0 + 5.0  # (a compile: the memo installed)
    original = fn.NUMBA_ORIGINAL.get("get_call_type", functions.BaseFunction.get_call_type)
    if "get_call_type" in fn._NUMBA_SOURCES and not fn._same_source(original):
        pytest.skip("numba's get_call_type is not the one the memo was checked against")
    ctx = cpu_target.typing_context
    ctx.refresh()
    fnty = ctx.resolve_value_type(operator.add)
    assert getattr(functions.BaseFunction.get_call_type, "_fusionkit_memo", False)
    args = (types.float64, types.intp)
    first = fnty.get_call_type(ctx, args, {})
    assert fnty.get_call_type(ctx, args, {}) is first  # kept
    numbas = fn.NUMBA_ORIGINAL["get_call_type"](fnty, ctx, args, {})
    assert numbas == first and first.return_type == types.float64
    bad = (types.float64, types.unicode_type)
    for _ in range(2):
        with pytest.raises(errors.TypingError):
            fnty.get_call_type(ctx, bad, {})


def test_a_numba_with_another_get_call_type_keeps_its_own(monkeypatch):
    from numba.core.types import functions

    _inlines(1.0)
    original = fn.NUMBA_ORIGINAL.get("get_call_type", functions.BaseFunction.get_call_type)
    if "get_call_type" in fn._NUMBA_SOURCES and not fn._same_source(original):
        pytest.skip("numba's get_call_type is not the one the memo was checked against")
    installed = functions.BaseFunction.get_call_type
    try:
        functions.BaseFunction.get_call_type = original
        monkeypatch.setitem(fn._NUMBA_SOURCES, "get_call_type", "0" * 16)
        fn._install_call_memo()
        assert functions.BaseFunction.get_call_type is original
    finally:
        functions.BaseFunction.get_call_type = installed
