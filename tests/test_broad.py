"""Source 000 on the real BROAD recordings (skipped where ../shared/data is absent)."""

import numpy as np
import pytest

import fusionkit as fk
from fusionkit.benchmarking.metrics import broad_errors


@pytest.fixture(scope="module")
def trial(broad_dir):
    return fk.load(broad_dir / "06_undisturbed_fast_rotation_A.hdf5")


def test_reference_equals_numba_on_real_data(trial):
    rec = trial.slice(0, 14000)  # 49 s: alignment, onset and 12 s of fast rotation
    f = fk.make("poisson")
    ref, fast = f.run(rec, backend="reference"), f.run(rec, backend="numba")
    np.testing.assert_allclose(fast.quat, ref.quat, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(fast.flags, ref.flags)


def test_onset_and_alignment_on_real_data(trial):
    res = fk.make("poisson").run(trial)
    start = int(np.argmax(trial.movement))
    k = res.diagnostics["alignment_end_index"]
    assert res.diagnostics["onset_index"] == k
    assert start - 0.5 * trial.rate < k < start + 0.5 * trial.rate  # the flag is not the first touch: +-0.5 s
    assert not (fk.make("motion", kind="detector").run(trial).fired[: start - int(0.5 * trial.rate)]).any()
    # source 000's alignment against the optical reference: well below a degree of inclination
    incl = broad_errors(res.quat[k - 1:k], trial.truth[k - 1:k])["inclination"][0]
    assert incl < 1.0


def test_every_trial_runs_and_stays_finite(broad_dir):
    for path in sorted(broad_dir.glob("*.hdf5")):
        rec = fk.load(path)
        res = fk.make("poisson").run(rec)
        assert np.isfinite(res.quat).all(), path.name
        assert res.diagnostics["onset_index"] is not None, path.name
