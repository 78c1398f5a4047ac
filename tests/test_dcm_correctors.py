"""Source 002's DCM column correctors: dcm-vertical, dcm-north, dcm-field (the plugins the
channel-dcm preset composes; tests/test_channel_dcm.py tests the composition)."""

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.conventions import change_frame, frame_matrix
from fusionkit.correctors.dcm import DcmField, DcmNorth, DcmVertical, frame_rows
from fusionkit.errors import ConfigError
from fusionkit.protocols import Sample
from fusionkit.rotations import quat_from_axis_angle, quat_to_matrix
from fusionkit.testing import check_plugin

DEG = np.pi / 180


@pytest.mark.parametrize("cls,params", [(DcmVertical, {"method": "vectors"}), (DcmVertical, {"k_acc": 3.0}),
                                        (DcmNorth, {"method": "vectors", "k_mag": 0.5}), (DcmField, {"k_mag": 0.5})])
def test_contract(cls, params):
    check_plugin(cls, params)


def test_needs_the_dcm_estimator():
    for name in ("dcm-vertical", "dcm-north", "dcm-field"):
        with pytest.raises(ConfigError, match="'dcm'"):
            fk.compose({"estimator": "poisson-quat", "correctors": [name], "alignment": {"mode": "none"}})


@pytest.mark.parametrize("frame", ["ENU", "NED", "NWU", "NUE"])
def test_frame_rows_find_the_enu_axes(frame):
    rng = np.random.default_rng(4)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    c_enu = quat_to_matrix(q)  # body -> ENU: row j is ENU axis j seen in the body
    c = quat_to_matrix(change_frame(q, "ENU", frame))
    rows = frame_rows(frame)
    for j in range(3):
        np.testing.assert_allclose(rows[2 * j + 1] * c[int(rows[2 * j])], c_enu[j], atol=1e-12)
    np.testing.assert_allclose(rows[5] * frame_matrix("ENU", frame)[int(rows[4])], [0, 0, 1])


def _one_correction(cor, q, acc=None, mag=None, frame="ENU"):
    """One reference correction of the DCM of ``q``; returns (new DCM body->frame, corrector state)."""
    est = fk.make("poisson-dcm", kind="estimator", orthonormalize=False)
    x = est.initial_state(q)
    s = cor.initial_state(0.01, frame)
    cor.correct(est, x, s, Sample(np.zeros(3), acc, mag, 0.01), 0)
    return x.reshape(3, 3), s


def test_north_turns_heading_only_and_field_tilts():
    """The paper's point, on one correction: dcm-north leaves the vertical column (roll and pitch)
    alone whatever the field says; the unseparated dcm-field moves it."""
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        mag = rng.normal(size=3) * 40.0  # any field, any unit
        for method in ("columns", "vectors"):
            c, _ = _one_correction(DcmNorth(method=method, k_mag=20.0), q, mag=mag)
            np.testing.assert_allclose(c[2], quat_to_matrix(q)[2], atol=1e-12)  # up seen in the body: unchanged
            np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-12)
        c, s = _one_correction(DcmField(k_mag=20.0), q, mag=mag)
        assert s[7] > 0  # H learned from the first sample
        np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-12)
    # a disturbed field (not the learned one) tilts with dcm-field
    cor = DcmField(k_mag=20.0)
    est = fk.make("poisson-dcm", kind="estimator", orthonormalize=False)
    x = est.initial_state(np.array([1.0, 0, 0, 0]))
    s = cor.initial_state(0.01, "ENU")
    cor.correct(est, x, s, Sample(np.zeros(3), None, np.array([0.0, 20.0, -40.0]), 0.01), 0)
    cor.correct(est, x, s, Sample(np.zeros(3), None, np.array([15.0, 20.0, -40.0]), 0.01), 0)
    assert np.degrees(np.arccos(x.reshape(3, 3)[2, 2])) > 0.1


@pytest.mark.parametrize("method", ["columns", "vectors"])
def test_vertical_pulls_the_vertical_column_to_the_accelerometer(method):
    """From a 30 deg tilt error at rest, dcm-vertical brings the up axis in the body to a/|a| at
    about k_acc per second (columns: the error shrinks as exp(-k t) for small angles, vectors as
    tan(e/2) ~ exp(-k t)); the magnetometer-free heading stays where it was."""
    rec = sim.simulate([sim.Rest(6.0)], rate=100.0, seed=0)
    tilt = quat_from_axis_angle([1.0, 0.0, 0.0], 30 * DEG)
    rec = fk.Recording(gyr=rec.gyr, acc=rec.acc, rate=rec.rate)
    spec = {"estimator": {"name": "poisson-dcm", "params": {"orthonormalize": False}},
            "correctors": [{"name": "dcm-vertical", "params": {"method": method, "k_acc": 0.5}}],
            "alignment": {"mode": "none", "initial_quat": tuple(tilt)}}
    for backend in ("reference", "numba"):
        res = fk.compose(spec).run(rec, backend=backend)
        up = quat_to_matrix(res.quat)[:, 2, :]  # the earth's up in the body
        a = rec.acc / np.linalg.norm(rec.acc, axis=1)[:, None]
        err = np.degrees(np.arccos(np.clip(np.sum(up * a, axis=1), -1, 1)))
        expected = 30.0 * np.exp(-0.5 * 5.0)
        assert 0.5 * expected < err[500] < 1.5 * expected, err[500]
        assert np.all(np.diff(err[:500]) < 1e-6)  # monotone
        head = np.degrees(np.arctan2(-quat_to_matrix(res.quat)[:, 0, 1], quat_to_matrix(res.quat)[:, 1, 1]))
        assert np.abs(head).max() < 1e-6  # tilt about x from heading 0: heading stays 0


@pytest.mark.parametrize("method", ["columns", "vectors"])
def test_north_pulls_heading_to_the_field_in_every_frame(method):
    """A 40 deg heading error at rest decays at about k_mag per second; the same composition in
    NED (or NUE) gives the same rotation as in ENU (signed rows, exact)."""
    rec = sim.simulate([sim.Rest(6.0)], rate=100.0, seed=1, noise=sim.Noise.mems())
    q0 = quat_from_axis_angle([0.0, 0.0, 1.0], 40 * DEG)
    spec = {"estimator": {"name": "poisson-dcm", "params": {"orthonormalize": False}},
            "correctors": [{"name": "dcm-vertical", "params": {"orthonormalize": False}},
                           {"name": "dcm-north", "params": {"method": method, "k_mag": 0.5}}],
            "alignment": {"mode": "none", "initial_quat": tuple(q0)}}
    res = fk.compose(spec).run(rec)
    assert rec.truth is not None
    err = broad_errors(res.quat, change_frame(rec.truth, rec.truth_frame, "ENU"))["heading"]
    assert 0.5 * 40 * np.exp(-2.5) < err[500] < 1.5 * 40 * np.exp(-2.5) + 1.0, err[500]
    for frame in ("NED", "NUE"):
        q_frame = change_frame(q0, "ENU", frame)
        other = fk.compose({**spec, "frame": frame, "alignment": {**spec["alignment"], "initial_quat": tuple(q_frame)}})
        for backend in ("reference", "numba"):
            out = change_frame(other.run(rec, backend=backend).quat, frame, "ENU")
            out *= np.sign(np.sum(out * res.quat, axis=1))[:, None]
            np.testing.assert_allclose(out, res.quat, atol=1e-12)
