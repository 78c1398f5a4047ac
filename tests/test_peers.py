"""Peer adapters give the peers' own numbers, in fusionkit's conventions."""

import warnings

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.conventions import change_frame

vqf = pytest.importorskip("vqf")
imufusion = pytest.importorskip("imufusion")
ahrs_filters = pytest.importorskip("ahrs.filters")

PEERS = ["vqf", "vqf-offline", "vqf-basic", "imufusion", "ahrs-madgwick", "ahrs-mahony", "ahrs-ekf"]


@pytest.fixture(scope="module")
def rec():
    deg = np.pi / 180
    segs = [sim.Rest(2.0), sim.Rotate((0, 0, 1), 90 * deg, 2.0), sim.Rotate((1, 0, 0), 40 * deg, 1.5),
            sim.Rotate((0, 1, 0), -30 * deg, 1.5), sim.Rest(1.0)]
    return sim.simulate(segs, rate=100.0, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02, mag_noise=0.2), seed=1)


def c(x):
    return np.ascontiguousarray(x)


def direct(name, rec):
    """The peer called directly, as its documentation shows; returns (quat, peer frame)."""
    ts = 1 / rec.rate
    if name == "vqf":
        return vqf.VQF(ts).updateBatch(c(rec.gyr), c(rec.acc), c(rec.mag))["quat9D"], "ENU"
    if name == "vqf-offline":
        return vqf.offlineVQF(c(rec.gyr), c(rec.acc), c(rec.mag), ts)["quat9D"], "ENU"
    if name == "vqf-basic":
        return vqf.BasicVQF(ts).updateBatch(c(rec.gyr), c(rec.acc), c(rec.mag))["quat9D"], "ENU"
    if name == "ahrs-madgwick":
        return ahrs_filters.Madgwick(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, frequency=rec.rate).Q, "NWU"
    if name == "ahrs-mahony":
        return ahrs_filters.Mahony(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, frequency=rec.rate).Q, "ENU"
    if name == "ahrs-ekf":
        return ahrs_filters.EKF(gyr=rec.gyr, acc=-rec.acc, mag=rec.mag, frequency=rec.rate, frame="NED").Q, "NED"
    if name == "imufusion":
        s = imufusion.AhrsSettings()
        s.convention, s.sample_rate, s.gain = imufusion.CONVENTION_ENU, rec.rate, 0.5
        s.gyroscope_range, s.acceleration_rejection, s.magnetic_rejection = 2000, 10, 10
        s.rejection_timeout = int(5 * rec.rate)
        a, b, bs = imufusion.Ahrs(), imufusion.Bias(), imufusion.BiasSettings()
        a.set_settings(s)
        bs.sample_rate = rec.rate
        b.set_settings(bs)
        q = []
        for g, acc, m in zip(np.degrees(rec.gyr), rec.acc / 9.80665, rec.mag):
            a.update(b.update(g), acc, m)
            q.append(a.get_quaternion())
        return np.array(q), "ENU"
    raise KeyError(name)


@pytest.mark.parametrize("name", PEERS)
def test_same_numbers_as_calling_the_peer_directly(name, rec):
    q_peer, frame = direct(name, rec)
    for out_frame in ("ENU", "NED"):
        res = fk.make(name, frame=out_frame).run(rec)
        np.testing.assert_allclose(res.quat, change_frame(q_peer, frame, out_frame), atol=1e-12)


@pytest.mark.parametrize("name", PEERS)
def test_frames_are_mapped_right(name, rec):
    """Independently of the direct call: against the simulator's truth (body->ENU, magnetic north)."""
    e = rms_errors(fk.make(name).run(rec), rec)
    assert e["inclination"] < 3.0, e
    assert e["total"] < 15.0, e  # heading converges from the first samples; 15 deg excludes any frame mix-up


def test_imufusion_constructor_ignores_its_convention():
    s = imufusion.AhrsSettings(convention=imufusion.CONVENTION_ENU)
    assert s.convention != imufusion.CONVENTION_ENU  # the quirk the adapter works around


@pytest.mark.parametrize("name", [p for p in PEERS if p != "vqf-offline"])
def test_a_stream_continues_a_run_and_its_state_is_saved(name, rec):
    """A peer has state / set_state like every filter (they were missing: AttributeError):
    set_state takes a run's Result.diagnostics['state'] and update() continues it with the run's
    numbers; a stream's state restores it (imufusion's objects cannot be copied: its stream's
    state is an error saying so)."""
    h = 300
    full = fk.make(name).run(rec).quat
    f = fk.make(name)
    assert f.state is None
    f.set_state(fk.make(name).run(rec.slice(0, h)).diagnostics["state"])
    q = np.array([f.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=1 / rec.rate) for k in range(h, len(rec))])
    np.testing.assert_allclose(q, full[h:], atol=1e-12)
    if name == "imufusion":
        with pytest.raises(fk.PluginError, match="cannot be copied"):
            f.state
        return
    g = fk.make(name)
    g.set_state(f.state)
    for k in range(5):
        np.testing.assert_array_equal(g.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=1 / rec.rate),
                                      f.update(rec.gyr[k], rec.acc[k], rec.mag[k], dt=1 / rec.rate))
    with pytest.raises(fk.InputError, match=f"state must be Result.diagnostics\\['state'\\] of an earlier {name}"):
        g.set_state({"filter": name})


def test_offline_peer_has_no_stream_state():
    with pytest.raises(fk.PluginError, match="offline"):
        fk.make("vqf-offline").set_state({})


def test_mode_6d_ignores_mag(rec):
    six = fk.make("vqf", mode="6D").run(rec)
    np.testing.assert_allclose(six.quat, vqf.VQF(1 / rec.rate).updateBatch(c(rec.gyr), c(rec.acc))["quat6D"], atol=1e-12)
    assert six.diagnostics["mode"] == "6D"
    with pytest.raises(fk.InputError, match="9D"):
        fk.make("vqf", mode="9D").run(fk.Recording(gyr=rec.gyr, acc=rec.acc, rate=rec.rate))


def test_offline_vqf_holds_input_over_nan(rec):
    acc = rec.acc.copy()
    acc[150] = np.nan
    r = fk.Recording(gyr=rec.gyr, acc=acc, mag=rec.mag, rate=rec.rate)
    res = fk.make("vqf-offline", nan_policy="skip").run(r)
    assert np.isfinite(res.quat).all() and res.flags[150] & fk.Flag.ACC_INVALID
    with pytest.raises(fk.PluginError, match="offline"):
        fk.make("vqf-offline").update(rec.gyr[0], rec.acc[0], None, 0.01)


def test_vqf_reproduces_its_published_broad_number(broad_dir):
    r = fk.load(broad_dir / "01_undisturbed_slow_rotation_A.hdf5")
    e = rms_errors(fk.make("vqf").run(r), r)
    assert e["total"] == pytest.approx(1.99, abs=0.005)
    assert e["inclination"] == pytest.approx(0.60, abs=0.005)


@pytest.mark.parametrize("name", ["vqf", "imufusion"])
def test_a_fixed_rate_peer_warns_once_when_a_stream_changes_its_interval(name):
    """vqf and imufusion integrate every sample over one sample time (a stream's first dt): a later
    dt was accepted and ignored without a word, so a stream on uneven timestamps silently differed
    from run()."""
    pytest.importorskip(name)
    from fusionkit.errors import PluginWarning

    f = fk.make(name)
    g, a = np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.0, 9.81])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f.update(g, a, dt=0.005)
        f.update(g, a, dt=0.005 * (1 + 1e-5))  # the intervals' rounding: no warning
    with pytest.warns(PluginWarning, match=r"fixed sample time.*0\.005 s.*0\.01 s"):
        f.update(g, a, dt=0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f.update(g, a, dt=0.02)  # once per stream
    f.reset()
    with pytest.warns(PluginWarning):  # a new stream warns again
        f.update(g, a, dt=0.005)
        f.update(g, a, dt=0.0075)
