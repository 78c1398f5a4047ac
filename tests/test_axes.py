"""Recordings know their body axes: conventions, loaders, and one ``body=`` for every filter."""

import dataclasses
import itertools

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.conventions import body_axis, body_matrix, change_body, check_body, euler_to_quat, resolve_body
from fusionkit.filters.gst import BODY_AXES
from fusionkit.io.loaders import load_csv, write_csv
from fusionkit.rotations import quat_angle

from conftest import data_dir


def test_body_conventions_are_the_24_right_handed_axis_sets():
    names = ["".join(p) for p in itertools.product("FBLRUD", repeat=3)]
    ok = []
    for n in names:
        try:
            ok.append(check_body(n))
        except fk.ConfigError:
            pass
    assert len(ok) == 24 and {"FLU", "FRD", "RFU", "LBU"} <= set(ok)
    for a, b in itertools.product(["FLU", "FRD", "RFU", "LBU"], repeat=2):
        m = body_matrix(a, b)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=0)
        assert np.linalg.det(m) == pytest.approx(1.0)
        np.testing.assert_allclose(body_matrix(b, a), m.T)
    for body, m in BODY_AXES.items():  # source 001's table is the general rule's special case
        np.testing.assert_allclose(body_matrix(body, "RFU"), m)
    np.testing.assert_allclose(body_axis("FRD", "U"), [0, 0, -1])
    np.testing.assert_allclose(body_axis("RFU", "F"), [0, 1, 0])
    assert check_body("frd") == "FRD"


@pytest.mark.parametrize("bad, why", [("FLD", "left-handed"), ("FFU", "same direction"), ("FBU", "same direction"),
                                      ("XYZ", "three letters"), ("FL", "three letters"), (3, "three letters")])
def test_bad_body_names_the_argument(bad, why):
    with pytest.raises(fk.ConfigError, match=why):
        check_body(bad)
    with pytest.raises(fk.ConfigError, match="body"):
        fk.make("recommended", body=bad)
    with pytest.raises(fk.InputError, match="body"):
        fk.Recording(gyr=np.zeros((3, 3)), acc=np.tile([0, 0, 9.8], (3, 1)), rate=10.0, body=bad)


def test_resolve_body():
    assert resolve_body(None, None, "f") is None
    assert resolve_body("FRD", None, "f") == "FRD"
    assert resolve_body(None, "flu", "f") == "FLU"
    assert resolve_body("FRD", "frd", "f") == "FRD"
    with pytest.raises(fk.ConfigError, match=r"'FLU'.*'FRD'"):
        resolve_body("FRD", "FLU", "f")


def test_change_body_is_the_same_attitude():
    rng = np.random.default_rng(0)
    q = rng.standard_normal((5, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v_flu = rng.standard_normal(3)
    from fusionkit.rotations import quat_to_matrix

    q_frd = change_body(q, "FLU", "FRD")
    np.testing.assert_allclose(quat_to_matrix(q_frd) @ (body_matrix("FLU", "FRD") @ v_flu), quat_to_matrix(q) @ v_flu,
                               atol=1e-12)
    assert quat_angle(change_body(q_frd, "FRD", "FLU"), q).max() < 1e-7


def _flight(rate=50.0):
    """A short drive with turns and a roll, sensors in FLU (this simulator's trajectory has the
    nose on x), with a magnetometer and GNSS velocity."""
    q0 = euler_to_quat(np.radians(60.0), 0.02, -0.01, "ENU")  # FLU: x forward, heading 60 deg from east
    segs = [sim.Rest(11.0), sim.Translate((0.5, 0.8660254, 0.0), 300.0, 20.0), sim.Rotate((0, 0, 1), 0.5, 5.0),
            sim.Rotate((1, 0, 0), 0.3, 3.0), sim.Rest(2.0)]
    rec = sim.simulate(segs, rate=rate, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02, mag_noise=0.2), seed=4,
                       initial=q0, gnss_vel_noise=0.05)
    return dataclasses.replace(rec, body="FLU")


def _in_axes(rec, body):
    """The same recording with the sensors' axes named ``body``."""
    m = body_matrix(rec.body, body)
    return dataclasses.replace(rec, gyr=rec.gyr @ m.T, acc=rec.acc @ m.T, mag=rec.mag @ m.T,
                               truth=change_body(rec.truth, rec.body, body), body=body)


def test_slice_copy_and_csv_keep_the_axes(tmp_path):
    rec = _flight()
    assert rec.slice(10, 100).body == "FLU" and dataclasses.replace(rec).body == "FLU"
    assert rec.gnss.frame == "ENU"
    write_csv(rec, tmp_path / "a.csv")
    assert fk.load(tmp_path / "a.csv").body == "FLU"
    assert load_csv(tmp_path / "a.csv", body="FLU").body == "FLU"
    bare = dataclasses.replace(rec, body=None)
    write_csv(bare, tmp_path / "b.csv")
    assert fk.load(tmp_path / "b.csv").body is None


def _filter(name, **kw):
    if name == "pipeline":
        return fk.make(name, config={"estimator": "poisson-quat", "detectors": ["motion"], **kw})
    return fk.make(name, **kw)


@pytest.mark.parametrize("name", fk.available()["filters"])
def test_every_filter_takes_body_and_answers_in_the_recordings_axes(name):
    """The same motion with the sensors named FLU and FRD: every filter's output, mapped from
    one set of axes to the other, is the same attitude once converged (in the last second: the
    peers' initialisations differ between axis sets); ``body=`` equal to the recording's
    changes nothing, a contradicting one raises naming both."""
    flu = _flight()
    frd = _in_axes(flu, "FRD")
    try:
        a, b = _filter(name).run(flu), _filter(name).run(frd)
    except fk.PluginError as exc:  # a peer that is not installed
        pytest.skip(str(exc))
    late = flu.time > flu.time[-1] - 1.0
    assert np.degrees(quat_angle(change_body(a.quat, "FLU", "FRD"), b.quat))[late].max() < 0.1
    np.testing.assert_array_equal(_filter(name, body="FRD").run(frd).quat, b.quat)
    with pytest.raises(fk.ConfigError, match=r"body='FLU'.*'FRD'"):
        _filter(name, body="FLU").run(frd)


def test_gst_gnss_uses_the_recordings_axes():
    """Without ``body=``, gst-gnss maps the recording's axes (before, it took every sensor for
    RFU): the result equals the explicit argument's, and both equal the RFU run mapped."""
    flu = _flight()
    frd = _in_axes(flu, "FRD")
    bare = dataclasses.replace(frd, body=None)
    f = fk.make("gst-gnss")
    res = f.run(frd)
    np.testing.assert_array_equal(res.quat, fk.make("gst-gnss", body="FRD").run(bare).quat)
    assert res.diagnostics["body"] == "FRD" and f.run(bare).diagnostics["body"] == "RFU"
    # source 000's alignment puts heading 0 on the sensor's axis 1 (another axis in RFU); once the
    # track angle sets the heading the attitudes agree
    moving = frd.time > 15.0
    rfu = fk.make("gst-gnss").run(_in_axes(flu, "RFU"))
    assert np.degrees(quat_angle(change_body(rfu.quat, "RFU", "FRD"), res.quat))[moving].max() < 1e-9
    wrong = f.run(bare)  # FRD sensors taken for RFU: the forward axis is wrong
    assert np.degrees(quat_angle(wrong.quat, res.quat))[moving].max() > 10.0
    with pytest.raises(fk.ConfigError, match=r"'RFU'.*'FRD'"):
        fk.make("gst-gnss", body="RFU").run(frd)


def test_pipeline_corrector_gets_the_recordings_axes():
    flu = _flight()
    frd = _in_axes(flu, "FRD")
    spec = {"estimator": "poisson-quat", "detectors": ["motion"], "correctors": ["gst-gnss"]}
    auto = fk.compose(spec).run(frd)
    explicit = fk.compose({**spec, "correctors": [{"name": "gst-gnss", "params": {"body": "FRD"}}]})
    np.testing.assert_array_equal(auto.quat, explicit.run(dataclasses.replace(frd, body=None)).quat)
    np.testing.assert_allclose(auto.quat, fk.compose(spec).run(frd, backend="reference").quat, atol=1e-9)
    with pytest.raises(fk.ConfigError, match=r"'FLU'.*'FRD'"):
        fk.compose({**spec, "correctors": [{"name": "gst-gnss", "params": {"body": "FLU"}}]}).run(frd)
    with pytest.raises(fk.ConfigError, match=r"'RFU'.*'FRD'"):
        fk.compose({**spec, "body": "RFU"}).run(frd)


def _gnss_file(name):
    p = data_dir() / "gnss" / name / f"{name}.h5"
    if not p.exists():
        pytest.skip(f"GNSS scenario not found at {p}")
    return fk.load(p)


def test_loaders_set_the_axes(broad_dir):
    assert fk.load(next(iter(sorted(broad_dir.glob("*.hdf5"))))).body is None  # a hand-held IMU: no vehicle axes
    heli = _gnss_file("heli_cruise")
    assert heli.body == "FRD" and heli.gnss.frame == "NED"


def test_ulog_loader_sets_frd():
    pytest.importorskip("pyulog")
    p = data_dir() / "ulog" / "sample.ulg"
    if not p.exists():
        pytest.skip(f"no PX4 log at {p}")
    rec = fk.load(p)
    assert rec.body == "FRD" and (rec.gnss is None or rec.gnss.frame == "NED")


def test_gst_gnss_on_the_helicopter_needs_no_body_argument():
    from fusionkit.benchmarking.metrics import trial_metrics

    heli = _gnss_file("heli_cruise")
    res = fk.make("gst-gnss").run(heli)
    np.testing.assert_array_equal(res.quat, fk.make("gst-gnss", body="FRD").run(heli).quat)
    assert trial_metrics(res, heli, "6D")["tilt"] <= 0.3
