"""Source 002: channel-separated DCM correction."""

import dataclasses

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors, rms_errors
from fusionkit.rotations import quat_conj, quat_mul
from fusionkit.types import Flag

from conftest import broad_mean

DEG = np.pi / 180


@pytest.fixture(scope="module")
def rec():
    segs = [sim.Rest(4.0)]
    for i in range(3):
        segs += [sim.Rotate((1, 0.2 * i, 0), 50 * DEG, 2.0), sim.Rotate((0, 0, 1), 100 * DEG, 2.0),
                 sim.Translate((1, 0, 0), 0.3, 1.0), sim.Rotate((0, 1, 0.3), -40 * DEG, 2.0), sim.Rest(1.0)]
    noise = sim.Noise(gyr_noise=0.003, gyr_bias=(0.004, -0.003, 0.002), acc_noise=0.03, mag_noise=0.3)
    return sim.simulate(segs, rate=100.0, noise=noise, seed=5, gnss_rate=None)


def disturbed_fields(rec):
    t = np.arange(len(rec)) * 0.01
    spikes = np.where(np.arange(len(rec)) % 53 == 0, 1.0, 0.0)[:, None] * [300.0, -200.0, 0.0]
    return {"offset": rec.mag + [40.0, -30.0, 25.0],
            "rotating": rec.mag + 50.0 * np.c_[np.cos(2 * t), np.sin(2 * t), 0 * t],
            "spikes": rec.mag + spikes}


def roll_pitch_axis(q):
    from fusionkit.rotations import quat_to_matrix
    return quat_to_matrix(q)[:, 2, :]  # the earth's up axis in the body: row 3 of R(body->ENU)


@pytest.mark.parametrize("method", ["columns", "vectors", "unseparated"])
def test_reference_equals_numba(rec, method):
    short = rec.slice(0, 1300)  # the rest and the first round of motions: every branch, half the reference's time
    bad = dataclasses.replace(short, gyr=short.gyr.copy(), acc=short.acc.copy(), mag=short.mag.copy())
    bad.gyr[100] = np.nan
    bad.gyr[350:360] += 0.5  # ends the initial rest early
    bad.acc[600:620] = 0.0
    bad.mag[700] = np.nan
    for params in [{}, {"initial_rest": 0.0, "frame": "NED"}, {"use_mag": False}]:
        f = fk.make("channel-dcm", method=method, nan_policy="skip", **params)
        a, b = f.run(bad, backend="numba"), f.run(bad, backend="reference")
        np.testing.assert_allclose(a.quat, b.quat, atol=1e-9)
        np.testing.assert_array_equal(a.flags, b.flags)
        assert np.isfinite(a.quat).all()
    assert np.all(a.flags[600:620] & Flag.ACC_INVALID)


@pytest.mark.parametrize("method", ["columns", "vectors"])
def test_separation_leaves_roll_and_pitch_to_the_accelerometer(rec, method):
    """The paper's claim: with separated channels any magnetometer disturbance leaves roll and
    pitch exactly as a magnetometer-free run gives them."""
    free = fk.make("channel-dcm", method=method, use_mag=False).run(rec)
    for name, mag in disturbed_fields(rec).items():
        res = fk.make("channel-dcm", method=method).run(dataclasses.replace(rec, mag=mag))
        np.testing.assert_allclose(roll_pitch_axis(res.quat), roll_pitch_axis(free.quat), atol=1e-9, err_msg=name)
        head = broad_errors(res.quat, free.quat)["heading"]
        assert np.nanmax(head) > 1.0  # the disturbance did reach heading


def test_without_separation_disturbances_tilt(rec):
    free = fk.make("channel-dcm", method="unseparated", use_mag=False).run(rec)
    for name, mag in disturbed_fields(rec).items():
        res = fk.make("channel-dcm", method="unseparated").run(dataclasses.replace(rec, mag=mag))
        incl = broad_errors(res.quat, free.quat)["inclination"]
        assert np.nanmax(incl) > 0.5, name


def test_accuracy_bias_extension_and_paper_mode(rec):
    for method in ("columns", "vectors"):
        res = fk.make("channel-dcm", method=method).run(rec)
        assert rms_errors(res, rec)["total"] < 2.0
        assert np.all(res.flags[1:300] & Flag.ALIGNING) and not np.any(res.flags[400:] & Flag.ALIGNING)
        np.testing.assert_allclose(res.diagnostics["bias"], (0.004, -0.003, 0.002), atol=0.001)
    paper = fk.make("channel-dcm", initial_rest=0.0).run(rec)
    assert not np.any(paper.flags[1:] & Flag.ALIGNING)  # the first sample gives the attitude, nothing else aligns
    np.testing.assert_array_equal(paper.diagnostics["bias"], 0.0)
    assert rms_errors(paper, rec)["total"] > rms_errors(fk.make("channel-dcm").run(rec), rec)["total"]


def test_update_equals_run(rec):
    f = fk.make("channel-dcm", method="vectors")
    whole = f.run(rec.slice(0, 500), backend="reference")  # the samples the stream is compared on
    stream = np.array([f.update(g, a, m, dt=0.01) for g, a, m in zip(rec.gyr[:500], rec.acc[:500], rec.mag[:500])])
    np.testing.assert_allclose(stream, whole.quat, atol=1e-12)


def test_broad_target(broad_dir):
    """9D total below 5.2 deg, default parameters, mean over the trials."""
    assert broad_mean(broad_dir, "channel-dcm", "total") < 5.2


def test_a_preset_over_plugins():
    """channel-dcm is a composition: poisson-dcm plus the DCM correctors of its method."""
    expect = {"columns": ["dcm-vertical", "dcm-north"], "vectors": ["dcm-vertical", "dcm-north"],
              "unseparated": ["dcm-vertical", "dcm-field"]}
    for method, names in expect.items():
        f = fk.make("channel-dcm", method=method)
        assert f.spec.estimator.name == "poisson-dcm" and not f.spec.estimator.params["orthonormalize"]
        assert [c.name for c in f.spec.correctors] == names
        assert not f.correctors[0].config.orthonormalize  # the magnetometer corrector restores orthogonality
        assert f.correctors[0].config.method == ("vectors" if method == "vectors" else "columns")
    free = fk.make("channel-dcm", use_mag=False, k_acc=0.7)
    assert [c.name for c in free.spec.correctors] == ["dcm-vertical"] and free.correctors[0].config.orthonormalize
    assert free.correctors[0].config.k_acc == 0.7


def test_a_dead_accelerometer_does_not_freeze_the_output(rec):
    """With nan_policy='skip' and no valid accelerometer sample at all, the gyroscope still turns
    the estimate (the monolith waited for one and held identity); every sample is flagged."""
    dead = dataclasses.replace(rec, acc=np.full_like(rec.acc, np.nan))
    for use_mag in (True, False):
        res = fk.make("channel-dcm", nan_policy="skip", use_mag=use_mag).run(dead)
        assert np.all(res.flags & Flag.ACC_INVALID) and np.isfinite(res.quat).all()
        # from 5 s on, the estimate turns with the truth (relative rotations agree within 2 deg)
        k0, k1 = 500, 2500
        rel = lambda q: quat_mul(quat_conj(q[k0]), q[k1])  # noqa: E731  body(k1) in body(k0)
        rel_est, rel_true = rel(res.quat), rel(rec.truth)
        assert 2 * np.degrees(np.arccos(min(1.0, abs(rel_true[0])))) > 20  # it did turn
        assert 2 * np.degrees(np.arccos(min(1.0, abs(rel_est @ rel_true)))) < 2.0
