"""The inlined loop of the ``recommended`` preset equals its called loop to the last bit (see
test_inlined_loops.py; the check is tests/inlined.py). A file of its own: this compile
(``inertial-tilt`` and ``mag-heading`` inlined) is the suite's longest, and under ``--dist loadfile``
it runs on one worker while the other compiles the remaining presets.

The offline mode's passes run compositions of the same kernels: with ``calibration="per-pass"`` this
very composition (the same inlined loop over the time-reversed recording, with the reversed
configuration's parameter values), by default the same template with the model's lines left out, as
in every other preset. Until stop 31 a second case ran ``OfflineFilter(recommended,
calibration="per-pass")`` through both loops: the same compiled loop on other input, 6.7 s of one
worker's time in a cold run of a suite at its 3-minute line, for no line of code this case does not
already check (the offline mode's own kernels do not depend on the inlining; test_offline.py holds
them to their reference). Checking the default offline passes' loop as well would cost its own
inlined compile (measured at stop 29: this file cold 82 -> 109 s of CPU)."""

import pytest

from fusionkit._numba import HAVE_NUMBA
from inlined import assert_inlined_equals_called, recording

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")


@pytest.fixture(scope="module")
def rec():
    return recording()


def test_inlined_loop_equals_the_called_one(rec, monkeypatch):
    assert_inlined_equals_called("recommended", {}, rec, monkeypatch)
