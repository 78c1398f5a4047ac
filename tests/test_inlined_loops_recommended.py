"""The inlined loops of the ``recommended`` preset, online and offline, equal its called loops to
the last bit (see test_inlined_loops.py; the check is tests/inlined.py). A file of its own: these
two compiles (``inertial-tilt`` and ``mag-heading`` inlined) are the suite's longest, and under
``--dist loadfile`` they run on one worker while the other compiles the remaining presets. The two
modes share their kernels' compiles, so they stay in one file."""

import pytest

from fusionkit._numba import HAVE_NUMBA
from inlined import assert_inlined_equals_called, recording

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")


@pytest.fixture(scope="module")
def rec():
    return recording()


@pytest.mark.parametrize("params", [{}, {"offline": True}])
def test_inlined_loop_equals_the_called_one(params, rec, monkeypatch):
    assert_inlined_equals_called("recommended", params, rec, monkeypatch)
