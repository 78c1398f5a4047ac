"""numba's SSA reconstruction and liveness analysis as fusionkit runs them (fusionkit/_numba.py:
each violator's rewrites on the blocks that name it; the live map on bit sets) give numba's own
results: the same IR, statement for statement and name for name, and the same live sets, on the
kernels with the most branches and loops (the functions these passes were made cheaper for)."""

import io

import pytest

import fusionkit._numba as fn

pytestmark = pytest.mark.skipif(not fn.HAVE_NUMBA, reason="numba is not installed")


def _kernels():
    from fusionkit.correctors.heading import mag_heading_kernel
    from fusionkit.correctors.tilt import inertial_tilt_kernel
    from fusionkit.models.mag_calibration import mag_calibration_apply
    from fusionkit.navigation.alignment import align_step

    return [inertial_tilt_kernel, mag_heading_kernel, mag_calibration_apply, align_step]


def _originals():
    fn._install_local_ssa()
    fn._install_live_map_bits()
    return fn.NUMBA_ORIGINAL["_run_ssa"], fn.NUMBA_ORIGINAL["compute_live_map"]


def _dump(blocks) -> str:
    out = io.StringIO()
    for label, blk in blocks.items():
        out.write(f"label {label}:\n")
        blk.dump(file=out)
    return out.getvalue()


@pytest.mark.parametrize("kernel", _kernels(), ids=lambda k: k.py_func.__name__)
def test_ssa_and_live_map_equal_numbas(kernel):
    from numba.core.analysis import compute_cfg_from_blocks, compute_use_defs
    from numba.core.compiler import run_frontend

    numba_ssa, numba_live = _originals()
    ours = run_frontend(kernel.py_func).blocks
    theirs = run_frontend(kernel.py_func).blocks
    assert _dump(ours) == _dump(theirs)
    ours, theirs = fn._run_ssa_local(ours), numba_ssa(theirs)
    text = _dump(ours)
    assert "phi(" in text  # (branches and loops: the pass had variables to repair)
    assert text == _dump(theirs)
    assert list(ours) == list(theirs)
    cfg = compute_cfg_from_blocks(ours)
    ud = compute_use_defs(ours)
    expected = numba_live(cfg, ours, ud.usemap, ud.defmap)
    got = fn._live_map_bits(cfg, ours, ud.usemap, ud.defmap)
    assert got == expected
    assert sum(map(len, expected.values())) > 100  # (variables live across blocks: a real check)


def _restore_numbas():
    from numba.core import analysis, ir_utils, ssa

    numba_ssa, numba_live = _originals()
    ssa._run_ssa = numba_ssa
    analysis.compute_live_map = ir_utils.compute_live_map = numba_live


def test_the_passes_are_installed_at_the_first_compile():
    """numba's own passes restored: the next compile in the process installs fusionkit's."""
    import numba
    from numba.core import analysis, ir_utils, ssa

    _restore_numbas()
    fn.FIRST_COMPILE.done = False
    try:
        assert ssa._run_ssa is not fn._run_ssa_local
        numba.njit(lambda x: x + 1.0)(1.0)  # (a function of its own: compiled, not loaded)
    finally:
        fn._install_local_ssa()
        fn._install_live_map_bits()
    assert fn.FIRST_COMPILE.done
    assert ssa._run_ssa is fn._run_ssa_local
    assert analysis.compute_live_map is fn._live_map_bits
    assert ir_utils.compute_live_map is fn._live_map_bits


def test_a_numba_with_other_sources_keeps_its_own_passes(monkeypatch):
    from numba.core import analysis, ssa

    _restore_numbas()
    try:
        monkeypatch.setitem(fn._NUMBA_SOURCES, "_run_ssa", "0" * 16)
        monkeypatch.setitem(fn._NUMBA_SOURCES, "compute_live_map", "0" * 16)
        fn._install_local_ssa()
        fn._install_live_map_bits()
        assert ssa._run_ssa is fn.NUMBA_ORIGINAL["_run_ssa"]
        assert analysis.compute_live_map is fn.NUMBA_ORIGINAL["compute_live_map"]
    finally:
        monkeypatch.undo()
        fn._install_local_ssa()
        fn._install_live_map_bits()
    assert ssa._run_ssa is fn._run_ssa_local
