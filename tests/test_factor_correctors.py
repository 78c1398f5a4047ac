"""Factor and bias correctors (the pipeline's ``factor`` and ``bias`` modes) and the plugins
``recommended`` is composed of: inertial-tilt, mag-heading, output-lead, rest-bias-lowpass.
Each plugin's reference equals its kernel (fusionkit.testing.check_plugin); each idea does its job
in a composition of its own."""

import dataclasses

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.testing import check_plugin
from fusionkit.types import Flag

from test_contract import WITHIN
from test_recommended import BIAS, DEG
from test_recommended import motion as _motion


def motion(n=2, **kw):
    return _motion(n=n, **kw)


def composition(correctors, detectors=("rest",), initial=(1.0, 0.0, 0.0, 0.0)):
    return fk.compose({"estimator": {"name": "poisson-quat", "params": {"step": "exact"}},
                       "detectors": list(detectors), "correctors": correctors,
                       "alignment": {"mode": "none", "initial_quat": initial}})


@pytest.fixture(scope="module")
def rec():
    """Without a gyro bias: the corrections alone."""
    return motion(bias=(0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def rec_b():
    return motion()


def incl(res, rec):
    return broad_errors(res.quat, rec.truth)["inclination"]


@pytest.mark.parametrize("name", ["inertial-tilt", "mag-heading", "output-lead", "rest-bias-lowpass"])
def test_kernel_equals_reference(name):
    check_plugin(name, within=WITHIN.get(("corrector", name)))  # in recommended's composition where it is one


def test_the_estimator_integrates_the_gyroscope_alone(rec_b):
    """Factor corrections never reach the estimator: its state is the plain strapdown's."""
    rec = rec_b
    plain = composition([], detectors=())
    with_factors = composition([{"name": "inertial-tilt", "params": {"motion_bias_tau": None}}, "mag-heading"])
    a, b = plain.run(rec), with_factors.run(rec)
    np.testing.assert_allclose(a.diagnostics["state"]["x"], b.diagnostics["state"]["x"], atol=1e-12)
    assert incl(b, rec)[-100:].mean() < 3.0  # while the output is corrected (the gyro bias drifts the estimator)
    assert incl(a, rec)[-100:].mean() > 5.0


def test_inclination_low_passed_in_the_inertial_frame(rec):
    """Linear accelerations average out in I: the inclination stays within a fraction of a degree
    through translations and rotations, where the accelerometer itself is off by several."""
    res = composition(["inertial-tilt"], detectors=()).run(dataclasses.replace(rec, mag=None))
    e = incl(res, rec)
    assert np.sqrt(np.mean(e[rec.movement] ** 2)) < 0.5  # measured 0.15 deg
    up_acc = rec.acc / np.linalg.norm(rec.acc, axis=1)[:, None]  # what a per-sample accelerometer tilt would give
    truth_up = np.einsum("nji,j->ni", fk.rotations.quat_to_matrix(rec.truth), [0, 0, 1.0])
    acc_err = np.degrees(np.arccos(np.clip(np.sum(up_acc * truth_up, axis=1), -1, 1)))
    assert acc_err[rec.movement].max() > 5.0 * e[rec.movement].max()


def test_heading_only_from_the_magnetometer(rec):
    """mag-heading turns about the vertical only: any field leaves roll and pitch as they are."""
    t = np.arange(len(rec)) * 0.01
    bad = dataclasses.replace(rec, mag=rec.mag + 50.0 * np.c_[np.cos(2 * t), np.sin(2 * t), 0 * t])
    yaw60 = tuple(fk.conventions.euler_to_quat(60 * DEG, 0.0, 0.0))  # the estimator starts 60 deg off in heading
    tilt_only = composition(["inertial-tilt"], initial=yaw60).run(dataclasses.replace(rec, mag=None))
    both = composition(["inertial-tilt", "mag-heading"], initial=yaw60).run(bad)
    up = lambda q: np.einsum("nji,j->ni", fk.rotations.quat_to_matrix(q), [0, 0, 1.0])  # noqa: E731
    np.testing.assert_allclose(up(both.quat), up(tilt_only.quat), atol=1e-12)
    good = composition(["inertial-tilt", "mag-heading"], initial=yaw60).run(rec)
    assert broad_errors(good.quat, rec.truth)["heading"].mean() < 1.0  # the mean over its first second at once
    assert broad_errors(tilt_only.quat, rec.truth)["heading"].mean() > 50.0


def test_heading_half_angle_stays_unit_and_follows_delta(rec):
    """mag-heading keeps cos/sin of delta / 2 in its state, turned by each step (no libm call per
    sample): after a run with a disturbed start (the heading 60 deg off, the field turning) it is
    still a unit vector to 1e-15 (one Newton step per sample: BROAD's inclination metric reads an
    output norm off by 1e-13 as 1e-8 rad) and the half angle of delta to 1e-12, in the reference
    and the kernel alike."""
    from fusionkit.correctors.heading import _DELTA, _HC, _HS

    t = np.arange(len(rec)) * 0.01
    turning = dataclasses.replace(rec, mag=rec.mag + 5.0 * np.c_[np.cos(0.5 * t), np.sin(0.5 * t), 0 * t])
    yaw60 = tuple(fk.conventions.euler_to_quat(60 * DEG, 0.0, 0.0))
    p = composition(["inertial-tilt", "mag-heading"], initial=yaw60)
    for backend in ("numba", "reference"):
        s = p.run(turning, backend=backend).diagnostics["state"]["cor"][1]
        assert abs(s[_HC] ** 2 + s[_HS] ** 2 - 1.0) < 1e-15
        assert abs(s[_HC] - np.cos(0.5 * s[_DELTA])) < 1e-12 and abs(s[_HS] - np.sin(0.5 * s[_DELTA])) < 1e-12
        assert abs(s[_DELTA]) > 0.1  # it did turn


def test_bias_at_rest_before_the_propagation(rec_b):
    """rest-bias-lowpass learns the bias on REST samples into the pipeline's bias, which the same
    sample's propagation subtracts (mode 'bias')."""
    rec = rec_b
    res = composition(["rest-bias-lowpass", {"name": "inertial-tilt", "params": {"motion_bias_tau": None}}]).run(rec)
    np.testing.assert_allclose(res.diagnostics["bias"], BIAS, atol=0.002)
    off = composition([{"name": "inertial-tilt", "params": {"motion_bias_tau": None}}]).run(rec)
    np.testing.assert_array_equal(off.diagnostics["bias"], 0.0)
    assert incl(res, rec)[rec.movement].mean() < 0.5 * incl(off, rec)[rec.movement].mean()


def test_bias_in_motion_from_the_tilt_correction():
    r = motion(rest_every=False, n=10, bias=(0.02, -0.015, 0.0))
    on = composition([{"name": "inertial-tilt", "params": {"motion_bias_tau": 20.0}}], detectors=()).run(r)
    off = composition([{"name": "inertial-tilt", "params": {"motion_bias_tau": None}}], detectors=()).run(r)
    late = np.arange(len(r)) > len(r) // 2
    assert incl(on, r)[late].mean() < 0.6 * incl(off, r)[late].mean()
    b = np.array([0.02, -0.015, 0.0])
    assert np.linalg.norm(on.diagnostics["bias"] - b) < 0.6 * np.linalg.norm(b)


def test_magnetic_disturbance_rejected(rec):
    mag = rec.mag.copy()
    k = slice(900, 1400)
    mag[k] = mag[k] * 1.6 + [30.0, 0.0, 0.0]
    dist = dataclasses.replace(rec, mag=mag)
    on = composition(["inertial-tilt", "mag-heading"]).run(dist)
    off = composition(["inertial-tilt", {"name": "mag-heading", "params": {"rejection": False}}]).run(dist)
    assert np.all(on.flags[k] & Flag.MAG_DISTURBED) and not np.any(on.flags[:900] & Flag.MAG_DISTURBED)
    assert not np.any(off.flags & Flag.MAG_DISTURBED)
    head = lambda res: broad_errors(res.quat, rec.truth)["heading"][900:1500].max()  # noqa: E731
    assert head(on) < 0.3 * head(off)


def test_adaptive_time_constant_under_a_turn():
    """``tau_adapt``: a steady turn with 1-2 % gyro scale errors drifts the almost-inertial frame at
    the scale error times the rate; the adaptive time constant shortens to follow the accelerometer
    (0.57 deg mean against 1.27 at tau = 2 s). Under translation it lengthens: test_recommended."""
    segs = [sim.Rest(5.0)] + [sim.Rotate((1, 0.5, 0.2), 360 * DEG, 2.0) for _ in range(10)]
    r = sim.simulate(segs, rate=100.0, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02), seed=0, gnss_rate=None,
                     errors=sim.SensorErrors(gyr_scale=(0.01, -0.015, 0.02)))
    on = composition([{"name": "inertial-tilt", "params": {"tau_adapt": True}}]).run(r)
    off = composition([{"name": "inertial-tilt", "params": {}}]).run(r)
    assert incl(on, r).mean() < 0.6 * incl(off, r).mean()


def test_adaptive_time_constant_bounds_are_checked():
    """A reversed ``[tau_min, tau_max]`` would pin every sample to ``tau_max``: a ConfigError naming it."""
    with pytest.raises(fk.ConfigError, match="tau_max"):
        composition([{"name": "inertial-tilt", "params": {"tau_adapt": True, "tau_min": 5.0, "tau_max": 1.0}}])
    composition([{"name": "inertial-tilt", "params": {"tau_adapt": True, "tau_min": 1.0, "tau_max": 1.0}}])


def test_fast_start():
    r = sim.simulate([sim.Rest(4.0)], rate=100.0, noise=sim.Noise(acc_noise=0.3, mag_noise=3.0), seed=4,
                     initial=tuple(fk.conventions.euler_to_quat(0.5, 0.2, -0.3)), gnss_rate=None)
    fast = composition([{"name": "inertial-tilt", "params": {"fast_start": True}}], detectors=()).run(r)
    slow = composition([{"name": "inertial-tilt", "params": {"fast_start": False}}], detectors=()).run(r)
    assert incl(fast, r)[50:100].mean() < 0.5 * incl(slow, r)[50:100].mean()


def test_output_lead_changes_the_output_only(rec):
    """In recommended's compositions with and without it (test_recommended compiles both): what
    output-lead does not touch is the same whatever the correctors before it."""
    lead = fk.make("recommended", output_lead=0.02)
    assert lead.correctors[-1].name == "output-lead"
    assert "output-lead" not in [c.name for c in fk.make("recommended").correctors]
    a, b = fk.make("recommended").run(rec), lead.run(rec)
    np.testing.assert_allclose(a.diagnostics["state"]["x"], b.diagnostics["state"]["x"], atol=1e-12)
    moving = rec.movement & (np.linalg.norm(rec.gyr, axis=1) > 0.5)
    assert broad_errors(a.quat, b.quat)["total"][moving].min() > 0.3  # |w| lead > 0.5 rad/s * 20 ms


def test_factor_correctors_come_last():
    with pytest.raises(fk.ConfigError, match="factor correctors"):
        composition(["inertial-tilt", "gradient-descent"])
    composition(["gradient-descent", "mag-heading"])  # a rate corrector before a factor one: fine


def test_restart_after_a_gap_and_streaming_equals_run():
    """After a timestamp gap the inclination low-pass restarts (the gravity seen in I before is
    stale), on both paths and in update()."""
    r = motion(n=1, rest_every=False)
    t = np.arange(len(r)) * 0.01
    t[800:] += 1.0  # a second lost in the middle of the rotations
    gap = dataclasses.replace(r, t=t, rate=None)
    f = fk.make("recommended", use_mag=False)
    with pytest.warns(fk.types.GapWarning):
        a = f.run(gap, backend="numba")
    with pytest.warns(fk.types.GapWarning):
        b = f.run(gap, backend="reference")
    np.testing.assert_allclose(a.quat, b.quat, atol=1e-9)
    assert a.flags[800] & Flag.GAP
    tilt = [i for i, c in enumerate(f.correctors) if c.name == "inertial-tilt"][0]
    g = fk.make("recommended", use_mag=False)
    dts = np.diff(t, prepend=-0.01)
    out = np.array([g.update(gyr, acc, None, dt=float(d)) for gyr, acc, d in zip(gap.gyr, gap.acc, dts)])
    np.testing.assert_allclose(out, a.quat, atol=1e-9)
    since = (len(r) - 800) * 0.01  # the low-pass's clock (seconds it has seen) started again at the gap
    assert abs(a.diagnostics["state"]["cor"][tilt][14] - since) < 0.015
    assert abs(g.state["cor"][tilt][14] - since) < 0.015
