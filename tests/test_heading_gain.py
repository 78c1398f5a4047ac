"""``mag-heading``'s gain from the heading's variance (``gain="kalman"``): a scalar Kalman filter on
the heading correction whose variance grows with what drifts the heading (the gyro's noise, the
vertical bias error it considers) and while the magnetometer is rejected, and shrinks with each
magnetometer heading (its noise and the residual field errors against the horizontal field).
The fixed time constant (``gain="fixed"``) stays as it was."""

import math

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.correctors import heading as H
from fusionkit.errors import ConfigError
from fusionkit.types import Flag

from conftest import backend_quats

DEG = math.pi / 180.0
RATE = 100.0
DIST = (20.0, 40.0)  # s: an earth-fixed field the rejection catches (norm +31 %)


def _motion(bias_z=0.2, patch=(15.0, 0.0, -15.0), seed=3, **errors):
    """Turns about the vertical and small tilts for 74 s, a vertical gyro bias no rest teaches,
    an earth-fixed magnetic disturbance over ``DIST``."""
    segs = [sim.Rest(2.0)]
    for _ in range(12):
        segs += [sim.Rotate((0, 0, 1), 90 * DEG, 2.0), sim.Rotate((1, 0.5, 0), 30 * DEG, 1.0),
                 sim.Rotate((1, 0.5, 0), -30 * DEG, 1.0), sim.Rotate((0, 0, 1), -60 * DEG, 2.0)]
    noise = sim.Noise(gyr_noise=0.003, gyr_bias=(0.0, 0.0, bias_z * DEG), acc_noise=0.03, mag_noise=0.3)
    err = sim.SensorErrors(patches=(sim.FieldPatch(patch, *DIST),), **errors)
    return sim.simulate(segs, rate=RATE, noise=noise, seed=seed, gnss_rate=None, errors=err)


@pytest.fixture(scope="module")
def rec():
    return _motion()


def _heading_only(**params):
    """inertial-tilt (no bias learning) + mag-heading: the heading's gain alone decides."""
    return fk.compose({"estimator": {"name": "poisson-quat", "params": {"step": "exact"}}, "detectors": ["rest"],
                       "correctors": [{"name": "inertial-tilt", "params": {"motion_bias_tau": None}},
                                      {"name": "mag-heading", "params": params}],
                       "alignment": {"mode": "none", "initial_quat": (1.0, 0.0, 0.0, 0.0)}})


def _rms(x):
    return float(np.sqrt(np.mean(x ** 2)))


def test_recovers_faster_after_a_rejected_disturbance(rec):
    """The bias drifts the heading while the disturbance is rejected (20 s); afterwards the
    variance that grew meanwhile makes the gain high, so the heading returns faster than with the
    fixed 15 s (the gyro's bias uncertainty stated as the sensor's: 0.2 deg/s)."""
    fixed = _heading_only().run(rec)
    kalman = _heading_only(gain="kalman", bias_sigma=0.2 * DEG).run(rec)
    assert np.all(kalman.flags[2100:3950] & Flag.MAG_DISTURBED)  # the disturbance is rejected
    h = {k: broad_errors(r.quat, rec.truth)["heading"] for k, r in (("fixed", fixed), ("kalman", kalman))}
    end = int(DIST[1] * RATE)
    after = slice(end, end + int(10 * RATE))
    assert _rms(h["kalman"][after]) < 0.5 * _rms(h["fixed"][after])  # 2.2 against 5.3 deg
    assert _rms(h["kalman"][end + 1000:]) < 0.6 * _rms(h["fixed"][end + 1000:])  # and in the clean stretch
    assert _rms(h["kalman"][1000:2000]) < _rms(h["fixed"][1000:2000])  # before it: not worse


def _state(res, f):
    return res.diagnostics["state"]["cor"][[c.name for c in f.correctors].index("mag-heading")]


def test_variance_grows_as_the_model_says_while_rejected(rec):
    """Over the rejected stretch no magnetometer heading enters: the variance is the propagation's
    closed form ``P + 2 T P_hb + T^2 P_bb + q T`` (scale error 0), the covariance ``P_hb + T P_bb``."""
    sb, ng = 0.2 * DEG, 0.01 * DEG
    f = _heading_only(gain="kalman", bias_sigma=sb, gyro_noise=ng)
    a, b = int(21 * RATE), int(39 * RATE)  # inside the rejected stretch
    first = f.run(rec.slice(0, a))
    mid = f.run(rec.slice(a, b), state=first.diagnostics["state"])
    assert np.all(mid.flags & Flag.MAG_DISTURBED)
    s0, s1 = _state(first, f), _state(mid, f)
    t = (b - a) / RATE
    expect = s0[H._PHH] + 2 * t * s0[H._PHB] + t * t * sb * sb + ng * ng * t
    assert s1[H._PHH] == pytest.approx(expect, rel=1e-6)
    assert s1[H._PHB] == pytest.approx(s0[H._PHB] + t * sb * sb, rel=1e-6)
    # the bias's drift, linear in time, on top of the error it had already made (the covariance)
    assert s1[H._PHH] > s0[H._PHH] + (sb * t) ** 2 + 2 * t * s0[H._PHB] * 0.99 and s0[H._PHB] > 0


def test_steady_gain_is_the_closed_form():
    """A long clean stretch: the gain settles where measurement and drift balance. With the
    measurement's variance ``r`` per sample (``R = r dt``) and the bias's ``sb^2`` considered, a
    continuous Schmidt-Kalman filter settles at the time constant ``tau = (R / (2 sb^2))^(1/3)``
    (``P_hb = sb^2 tau``, ``P = R / tau``): the discrete one within a few percent."""
    r = _motion(bias_z=0.0, patch=(0.0, 0.0, 0.0))
    sb = 0.1 * DEG
    f = _heading_only(gain="kalman", bias_sigma=sb, gyro_noise=0.0, mag_noise=0.0)
    res = f.run(r)
    s = _state(res, f)
    c = f.correctors[-1].config
    dip = s[H._MAG + 1]  # the reference's dip (the field's, up to noise)
    big_r = 2 * c.field_error ** 2 * c.field_error_time / math.cos(dip) ** 2  # r dt (no departure: undisturbed)
    tau = (big_r / (2 * sb * sb)) ** (1 / 3)
    dt = 1.0 / RATE
    k = s[H._PHH] / (s[H._PHH] + big_r / dt)
    assert dt / k == pytest.approx(tau, rel=0.1)
    assert 5.0 < tau < 30.0  # the defaults give a VQF-like time constant (9-15 s) at this dip (68 deg)


def test_a_departing_field_counts_as_a_field_error():
    """A sample whose norm departs from the reference by 8 % (under the 10 % rejection threshold)
    weighs less: its variance is that departure's, not the calibrated floor's."""
    x = np.zeros(H._SIZE)
    x[H._MAG], x[H._MAG + 1], x[H._MAG + H.MAG_COUNT] = 50.0, -1.0, 100.0
    num, den = H._kf_noise(x, 50.0, -1.0, 0.01, 0.0, 0.03 ** 2, 1.0)  # (the variance as a quotient)
    clean = num / den
    num, den = H._kf_noise(x, 54.0, -1.0, 0.01, 0.0, 0.03 ** 2, 1.0)
    off = num / den
    assert clean == pytest.approx(2 * 0.03 ** 2 * 1.0 / 0.01 / math.cos(1.0) ** 2)
    assert off == pytest.approx(clean * (0.08 / 0.03) ** 2)


def test_the_variance_without_a_scale_error_does_not_read_the_vertical_rate():
    """``scale_sigma`` 0 (the default): the heading's variance grows by the noise and the bias alone, so
    the rate about the vertical is not read (the kernel does not compute it: a NaN there changes
    nothing), and the gain divides once: ``P rd / (P rd + rn)`` equals ``P / (P + rn / rd)``."""
    x = np.zeros(H._SIZE)
    x[H._PHH], x[H._PHB] = 1e-3, 1e-5
    H._kf_predict(x, math.nan, 0.01, 1e-6, 1e-8, 0.0)
    p = x[H._PHH]
    assert math.isfinite(p) and x[H._PHS] == 0.0
    assert p == 1e-3 + 2.0 * 0.01 * 1e-5 + 0.01 * 0.01 * 1e-8 + 1e-6 * 0.01
    k = H._kf_gain(x, 3e-2, 0.5)
    assert k == pytest.approx(p / (p + 3e-2 / 0.5), rel=1e-15)


@pytest.mark.parametrize("split", [False, True])
def test_reference_equals_numba(split):
    """recommended with the Kalman heading gain on a recording with a rejected disturbance, residual
    hard iron (the calibration model runs), a magnetometer held at 50 Hz and a gyro scale error
    (scale_sigma on): reference == numba to 1e-9 on every sample, also across a split run."""
    r = _motion(mag_rate=50.0, mag_offset=(2.0, -1.5, 1.0), gyr_scale=(0.0, 0.0, 0.01)).slice(0, 5000)
    f = fk.make("recommended", heading_gain="kalman")
    cfg = f.pipeline_config().model_dump()
    for c in cfg["correctors"]:
        if c["name"] == "mag-heading":
            c["params"]["scale_sigma"] = 0.01
    out = backend_quats(fk.compose(cfg), r, 2500 if split else None)
    assert np.abs(out["numba"] - out["reference"]).max() < 1e-9


def test_fixed_gain_ignores_the_kalman_parameters(rec):
    """gain fixed (mag-heading's default and the method before): the time constant alone; the
    Kalman filter's parameters change nothing and its variance is never touched."""
    a = _heading_only().run(rec)
    f = _heading_only(bias_sigma=1.0 * DEG, field_error=0.2, gyro_noise=0.1)
    b = f.run(rec)
    assert np.array_equal(a.quat, b.quat)
    s = _state(b, f)
    assert s[H._PHH] == s[H._PHB] == s[H._PHS] == 0.0


def test_recommended_reports_the_heading_std(rec):
    """The run's diagnostics carry the heading's standard deviation at its end (gain kalman only):
    after the clean stretch it is the steady state's, a few degrees at most."""
    res = fk.make("recommended").run(rec)
    assert 0.1 * DEG < res.diagnostics["heading_std"] < 5.0 * DEG
    assert "heading_std" not in fk.make("recommended", heading_gain="fixed").run(rec).diagnostics


def test_recommended_passes_the_gain_and_the_bias_sigma():
    f = fk.make("recommended", heading_gain="kalman", bias_sigma_motion=0.2 * DEG)
    (h,) = [c for c in f.correctors if c.name == "mag-heading"]
    assert h.config.gain == "kalman" and h.config.bias_sigma == pytest.approx(0.2 * DEG)
    with pytest.raises(ConfigError, match="heading_gain"):
        fk.make("recommended", heading_gain="fast")
    with pytest.raises(ConfigError, match="field_error"):
        fk.make("mag-heading", "corrector", field_error=0.0)
