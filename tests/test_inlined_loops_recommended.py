"""The inlined loop of the ``recommended`` preset equals its called loop to the last bit, online and
through the offline mode's passes (see test_inlined_loops.py; the check is tests/inlined.py). A
file of its own: this compile (``inertial-tilt`` and ``mag-heading`` inlined) is the suite's
longest, and under ``--dist loadfile`` it runs on one worker while the other compiles the remaining
presets.

The offline mode runs with ``calibration="per-pass"``, so both passes keep the calibration model
and run the online composition: its inlined loop, compiled once for both tests, over the time-
reversed recording, the reversed configuration and the re-runs without disturbed samples. The
default offline passes run that composition without the model (decided over the whole recording
beforehand): the same template with the model's lines left out, as in every other preset, and the
same four kernels inlined, so it is covered by the loop checked here and the presets' loops
(test_inlined_loops.py), without a third inlined compile: checked as a third case
(``OfflineFilter(recommended)`` with its defaults), this file cold (empty caches, the loaded 2-core
machine) went from 82 to 109 s of CPU (user; wall 138 -> 174 s), the default passes' own compile 28 s."""

import pytest

from fusionkit._numba import HAVE_NUMBA
from inlined import assert_inlined_equals_called, recording

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="numba is not installed")


@pytest.fixture(scope="module")
def rec():
    return recording()


@pytest.mark.parametrize("offline", [None, {"calibration": "per-pass"}], ids=["online", "offline"])
def test_inlined_loop_equals_the_called_one(offline, rec, monkeypatch):
    assert_inlined_equals_called("recommended", {}, rec, monkeypatch, offline)
