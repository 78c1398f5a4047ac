"""The `poisson` filter (source 000 end to end) and the pipeline mechanics under it."""

import json

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.conventions import change_frame
from fusionkit.errors import ConfigError, InputError
from fusionkit.rotations import quat_angle
from fusionkit.types import AlignmentWarning, Flag


def test_alignment_ends_at_the_motion_onset(imu_rec):
    res = fk.make("poisson").run(imu_rec)
    d = res.diagnostics
    start = int(np.argmax(imu_rec.movement))
    assert d["onset_index"] is not None and start < d["onset_index"] < start + 30
    assert d["alignment_end_index"] == d["onset_index"]
    k = d["onset_index"]
    assert (res.flags[:k] & Flag.ALIGNING).all()
    assert not (res.flags[k:] & Flag.ALIGNING).any()
    assert res.flags[k] & Flag.MOTION


def test_bias_is_the_mean_gyro_of_the_alignment(imu_rec):
    res = fk.make("poisson").run(imu_rec)
    k = res.diagnostics["alignment_end_index"]
    np.testing.assert_allclose(res.diagnostics["bias"], imu_rec.gyr[:k].mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(res.diagnostics["bias"], imu_rec.meta["noise"].gyr_bias, atol=5e-4)


@pytest.mark.parametrize("estimator,step", [("poisson-quat", "first-order"), ("poisson-quat", "exact"),
                                            ("poisson-dcm", "first-order")])
@pytest.mark.parametrize("alignment", ["motion", "fixed"])
@pytest.mark.parametrize("frame", ["ENU", "NED", "NUE"])
def test_numba_equals_reference_on_every_sample(imu_rec, estimator, step, alignment, frame):
    f = fk.make("poisson", estimator=estimator, step=step, alignment=alignment, frame=frame, heading="magnetometer")
    ref, fast = f.run(imu_rec, backend="reference"), f.run(imu_rec, backend="numba")
    assert ref.diagnostics["backend"] == "reference" and fast.diagnostics["backend"] == "numba"
    np.testing.assert_allclose(fast.quat, ref.quat, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(fast.flags, ref.flags)
    assert fast.diagnostics["alignment_end_index"] == ref.diagnostics["alignment_end_index"]


def test_exact_step_on_clean_data_tracks_the_truth(clean_rec):
    res = fk.make("poisson", step="exact", heading="magnetometer").run(clean_rec)
    err = broad_errors(res.quat, clean_rec.truth)
    m = clean_rec.movement
    # the only error is the sub-threshold rotation before the detector fires
    assert np.sqrt(np.mean(err["total"][m] ** 2)) < 0.1
    assert err["inclination"][: res.diagnostics["alignment_end_index"]].max() < 1e-6


def test_first_order_is_worse_than_exact_on_fast_rotation():
    rec = sim.simulate([sim.Rest(11), sim.Rotate((1, 1, 0), 20.0, 2.0), sim.Rest(1)], rate=100.0, seed=0)
    e = {}
    for step in ("first-order", "exact"):
        q = fk.make("poisson", step=step, heading="magnetometer").run(rec).quat
        e[step] = quat_angle(q[-1], rec.truth[-1])
    assert e["first-order"] > 10 * e["exact"]


def test_frames_give_the_same_attitude(imu_rec):
    enu = fk.make("poisson").run(imu_rec)
    for frame in ("NED", "NWU", "NUE"):
        other = fk.make("poisson", frame=frame).run(imu_rec)
        assert other.frame == frame
        assert quat_angle(change_frame(enu.quat, "ENU", frame), other.quat).max() < 1e-9
    hpr = fk.make("poisson", frame="NUE").run(imu_rec).euler()
    k = fk.make("poisson").run(imu_rec).diagnostics["alignment_end_index"] - 1
    assert hpr[k, 0] == pytest.approx(0.0, abs=1e-9)  # source 000: heading 0 after alignment


def test_fixed_alignment_duration(imu_rec):
    res = fk.make("poisson", alignment="fixed", alignment_duration=5.0).run(imu_rec)
    assert res.diagnostics["alignment_end_index"] == 500
    assert (res.flags[:500] & Flag.ALIGNING).all() and not (res.flags[500:] & Flag.ALIGNING).any()
    assert "onset_index" not in res.diagnostics


def test_motion_during_the_mandatory_alignment_is_reported():
    """With the detector armed before the mandatory alignment ends (by default after 2 s of
    statistics), motion inside it is reported and ends the alignment there: it is never averaged
    in. ``early_motion=False``: armed when the mandatory alignment ends (source 000)."""
    rec = sim.simulate([sim.Rest(2), sim.Rotate((0, 0, 1), 0.5, 1.0), sim.Rest(5), sim.Rotate((1, 0, 0), 1, 1)],
                       rate=100.0, noise=sim.Noise.mems(), seed=0)
    with pytest.warns(AlignmentWarning):
        res = fk.make("poisson", alignment_duration=4.0, motion={"arm_after": 1.0}).run(rec)
    assert res.diagnostics["alignment_disturbed"]
    assert 200 < res.diagnostics["onset_index"] < 230
    assert res.diagnostics["alignment_end_index"] == res.diagnostics["onset_index"]
    quiet = fk.make("poisson", alignment_duration=4.0, early_motion=False).run(rec)
    assert not quiet.diagnostics["alignment_disturbed"]


def test_nan_policy(imu_rec):
    gyr = imu_rec.gyr.copy()
    acc = imu_rec.acc.copy()
    gyr[1500] = np.nan  # during navigation
    acc[200] = np.nan  # during alignment
    acc[300] = 0.0  # an all-zero sample is a dropout too
    rec = fk.Recording(gyr=gyr, acc=acc, rate=imu_rec.rate)
    with pytest.raises(InputError, match=r"acc\[200\]"):
        fk.make("poisson").run(rec)
    for backend in ("reference", "numba"):
        res = fk.make("poisson", nan_policy="skip").run(rec, backend=backend)
        assert np.isfinite(res.quat).all()
        assert res.flags[1500] & Flag.GYR_INVALID and res.flags[200] & Flag.ACC_INVALID
        assert res.flags[300] & Flag.ACC_INVALID
        np.testing.assert_array_equal(res.quat[1500], res.quat[1499])  # state held
        k = res.diagnostics["alignment_end_index"]
        ok = np.ones(k, bool)
        ok[[200, 300]] = False
        np.testing.assert_allclose(res.diagnostics["bias"], gyr[:k].mean(axis=0), atol=1e-12)


def test_saturation_is_flagged(imu_rec):
    res = fk.make("poisson", gyr_range=0.5, acc_range=10.5).run(imu_rec)
    sat = np.abs(imu_rec.gyr).max(axis=1) >= 0.5
    assert sat.any()
    np.testing.assert_array_equal((res.flags & Flag.GYR_SATURATED) != 0, sat)
    np.testing.assert_array_equal((res.flags & Flag.ACC_SATURATED) != 0, np.abs(imu_rec.acc).max(axis=1) >= 10.5)


def test_bad_configs_are_clear():
    with pytest.raises(ConfigError, match="alignment_durationn"):
        fk.make("poisson", alignment_durationn=3)
    with pytest.raises(ConfigError, match="alignment_duration.*greater than 0"):
        fk.make("poisson", alignment_duration=-1)
    with pytest.raises(ConfigError, match="step"):
        fk.make("poisson", step="second-order")
    with pytest.raises(ConfigError, match="no detector sets it"):
        fk.compose({"estimator": "poisson-quat"})  # mode 'motion' by default but no detector
    with pytest.raises(ConfigError, match="backend"):
        fk.make("poisson").run(fk.sim.simulate([fk.sim.Rest(1)]), backend="gpu")


def test_heading_from_magnetometer_needs_mag(imu_rec):
    rec = fk.Recording(gyr=imu_rec.gyr, acc=imu_rec.acc, rate=imu_rec.rate)
    with pytest.raises(InputError, match="needs mag"):
        fk.make("poisson", heading="magnetometer").run(rec)


PIPELINE = {
    "estimator": {"name": "poisson-quat", "params": {"step": "exact"}},
    "detectors": [{"name": "motion", "params": {"arm_after": 10.0}}],
    "alignment": {"mode": "motion", "duration": 10.0},
    "frame": "NED",
}


def test_pipeline_from_dict_json_toml_equals_the_preset(imu_rec, tmp_path):
    preset = fk.make("poisson", step="exact", frame="NED").run(imu_rec).quat
    (tmp_path / "p.json").write_text(json.dumps(PIPELINE))
    (tmp_path / "p.toml").write_text(
        'frame = "NED"\n[estimator]\nname = "poisson-quat"\nparams = { step = "exact" }\n'
        '[[detectors]]\nname = "motion"\n[alignment]\nmode = "motion"\nduration = 10.0\n'
    )
    for src in (PIPELINE, tmp_path / "p.json", str(tmp_path / "p.toml"), json.dumps(PIPELINE)):
        np.testing.assert_allclose(fk.compose(src).run(imu_rec).quat, preset, atol=1e-12)


def test_pipeline_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        fk.compose(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        fk.compose("estimator = = 1")
    with pytest.raises(fk.PluginError, match="unknown estimator plugin 'poisson-quatt'.*did you mean 'poisson-quat'"):
        fk.compose({**PIPELINE, "estimator": "poisson-quatt"})
    with pytest.raises(ConfigError, match="detectors.0.params|unknown parameter"):
        fk.compose({**PIPELINE, "detectors": [{"name": "motion", "params": {"sigma": 3}}]})


def test_streaming_update_with_state_copy(imu_rec):
    f = fk.make("poisson")
    ref = f.run(imu_rec, backend="reference").quat
    dt = imu_rec.dt
    for k in range(1400):
        f.update(imu_rec.gyr[k], imu_rec.acc[k], imu_rec.mag[k], dt[k])
    saved = f.state
    g = fk.make("poisson")
    g.set_state(saved)
    q = [g.update(imu_rec.gyr[k], imu_rec.acc[k], imu_rec.mag[k], dt[k]) for k in range(1400, len(imu_rec))]
    np.testing.assert_allclose(np.array(q), ref[1400:], atol=1e-12)
    with pytest.raises(InputError, match="dt"):
        g.update(imu_rec.gyr[0], imu_rec.acc[0])
    with pytest.raises(InputError, match="state"):
        g.set_state({"x": 1})
