"""The ``recommended`` filter and the ``rest`` detector: each feature doing its job, bad input,
reference == numba, and the BROAD targets where the data is present."""

import dataclasses

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors, rms_errors
from fusionkit.conventions import change_frame, euler_to_quat, up_vector
from fusionkit.correctors.tilt import _PMAX, _TAU
from fusionkit.rotations import quat_to_matrix
from fusionkit.types import CHANNEL_SIZE, Flag

from conftest import broad_mean

DEG = np.pi / 180
BIAS = (0.01, -0.008, 0.006)  # rad/s: 0.3-0.6 deg/s


def motion(seed=1, bias=BIAS, rest_every=True, rate=100.0, n=4):
    segs = [sim.Rest(6.0)]
    for i in range(n):
        segs += [sim.Rotate((1, 0.3 * i, 0), 60 * DEG, 2.0), sim.Rotate((0, 0, 1), 120 * DEG, 2.0),
                 sim.Translate((1, 1, 0), 0.3, 1.0), sim.Rotate((1, 0.3 * i, 0), -60 * DEG, 2.0)]
        if rest_every:
            segs.append(sim.Rest(5.0))
    noise = sim.Noise(gyr_noise=0.003, gyr_bias=bias, acc_noise=0.03, mag_noise=0.3)
    return sim.simulate(segs, rate=rate, noise=noise, seed=seed, gnss_rate=None)


def flat_state(res, correctors=True):
    """The run state end to end (the estimator's, the correctors' and the pipeline's), or without
    the correctors' (``correctors=False``)."""
    st = res.diagnostics["state"]
    return np.concatenate([st["x"], *(st["cor"] if correctors else []), st["align"]])


def inclination(res, rec):
    return broad_errors(res.quat, rec.truth)["inclination"]  # deg


def body_up(q, frame="ENU"):
    """The earth's up axis seen in the body: roll and pitch, independent of heading."""
    return np.einsum("nji,j->ni", quat_to_matrix(q), up_vector(frame))


@pytest.fixture(scope="module")
def rec():
    return motion()


def test_reference_equals_numba_every_option(rec):
    short = motion(n=1)  # rest, every motion, rest again: each branch, a third of the reference's time
    bad = dataclasses.replace(short, gyr=short.gyr.copy(), acc=short.acc.copy(), mag=short.mag.copy())
    bad.gyr[500] = np.nan
    bad.acc[600:603] = 0.0
    bad.mag[700] = np.nan
    # options that change only parameter values share a run (one reference run each costs more than
    # the compiled one); an option that adds or drops a plugin makes a composition, a compile of its
    # own (README, "Run the tests"): each runs where its composition is one the suite compiles anyway
    # (the acceleration gate's and the output lead's tests below; 6D without the bias at rest is
    # test_factor_correctors' inertial-tilt after a rest detector)
    for params in [{}, {"fast_start": False, "acc_delay": 0.02, "mag_delay": 0.02, "bias_filter": "lowpass",
                        "rest_bias_gain": "fixed", "tau_adapt": False},
                   {"acc_gate": 1.0}, {"output_lead": 0.02},
                   {"mag_rejection": False, "frame": "NED", "acc_delay": 0.0, "mag_delay": 0.0, "motion_bias_tau": None},
                   {"use_mag": False, "gyr_range": 1.0}, {"acc_delay": -0.01, "use_mag": False, "rest_bias": False, "gyro_rate_estimate": "correct"},
                   {"bias_sigma_rest": 0.0005, "frame": "NWU", "gyro_rate_estimate": "tau", "bias_update_interval": 0.02,
                    "gyro_rate_acc_bias": 0.1},
                   {"frame": "NED", "gyro_rate_estimate": "correct", "gyro_rate_interval": 0.0,
                    "bias_update_interval": 0.0, "gyro_rate_acc_bias": 0.1, "slow_interval": 0.0}]:
        f = fk.make("recommended", nan_policy="skip", **params)
        a, b = f.run(bad, backend="numba"), f.run(bad, backend="reference")
        np.testing.assert_allclose(a.quat, b.quat, atol=1e-9, err_msg=str(params))
        np.testing.assert_array_equal(a.flags, b.flags)
        np.testing.assert_allclose(flat_state(a), flat_state(b), atol=1e-9)
    f = fk.make("recommended")
    assert f.run(rec).diagnostics["backend"] == "numba"


def test_update_loop_and_split_state_equal_run(rec):
    f = fk.make("recommended")
    part = rec.slice(0, 2500)  # the split mid-turn, then a rest and the next turns (the reference costs per sample)
    whole = f.run(part, backend="reference")
    stream = np.array([f.update(g, a, m, dt=0.01) for g, a, m in zip(rec.gyr[:800], rec.acc[:800], rec.mag[:800])])
    np.testing.assert_allclose(stream, whole.quat[:800], atol=1e-12)
    first = f.run(rec.slice(0, 1000))
    second = f.run(part.slice(1000, None), state=first.diagnostics["state"])
    np.testing.assert_allclose(second.quat, whole.quat[1000:], atol=1e-9)
    with pytest.raises(fk.InputError, match="state must be a dict"):
        f.run(rec, state=np.zeros(3))


def test_accurate_on_simulated_motion_and_in_any_frame(rec):
    res = fk.make("recommended").run(rec)
    err = broad_errors(res.quat, rec.truth)["total"]  # deg
    assert np.sqrt(np.mean(err[1000:] ** 2)) < 1.0
    ned = fk.make("recommended", frame="NED").run(rec)
    np.testing.assert_allclose(np.abs(np.sum(ned.quat * change_frame(res.quat, "ENU", "NED"), axis=1)), 1.0,
                               atol=1e-9)


def test_magnetic_disturbance_reaches_heading_only(rec):
    """Source 002's claim for this filter's separation: any field leaves roll and pitch as a
    magnetometer-free run gives them."""
    t = np.arange(len(rec)) * 0.01
    bad_fields = [rec.mag + [40.0, -30.0, 25.0],  # constant offset
                  rec.mag + 50.0 * np.c_[np.cos(2 * t), np.sin(2 * t), 0 * t],  # rotating field
                  rec.mag * np.where(np.arange(len(rec)) % 97 == 0, 20.0, 1.0)[:, None]]  # spikes
    free = fk.make("recommended", use_mag=False).run(rec)
    for mag in bad_fields:
        res = fk.make("recommended").run(dataclasses.replace(rec, mag=mag))
        np.testing.assert_allclose(body_up(res.quat), body_up(free.quat), atol=1e-12)


def test_rest_detector_marks_rest_and_gives_the_bias(rec):
    det = fk.make("rest", kind="detector")
    r = det.run(rec)
    truth_rest = ~rec.movement
    fired = r.fired
    assert fired[truth_rest].mean() > 0.3 and fired[rec.movement].mean() < 0.03  # the slow ends of motions
    assert np.array_equal(r.fired, det.run(rec, backend="reference").fired)
    res = fk.make("recommended", motion_bias_tau=None).run(rec)
    assert np.all(res.flags[fired] & Flag.REST)
    np.testing.assert_allclose(res.diagnostics["bias"], BIAS, atol=0.002)
    off = fk.make("recommended", rest_bias=False, motion_bias_tau=None).run(rec)
    np.testing.assert_array_equal(off.diagnostics["bias"], 0.0)
    assert inclination(res, rec)[rec.movement].mean() < 0.5 * inclination(off, rec)[rec.movement].mean()


def test_bias_in_motion_without_rest():
    """No rest at all (the rest detector cannot help): the in-motion estimate takes the bias's
    horizontal part out of the inclination."""
    r = motion(rest_every=False, n=10, bias=(0.02, -0.015, 0.0))
    r = dataclasses.replace(r, gyr=r.gyr, acc=r.acc)
    on = fk.make("recommended", motion_bias_tau=20.0, rest_bias=False).run(r)
    off = fk.make("recommended", motion_bias_tau=None, rest_bias=False).run(r)
    late = np.arange(len(r)) > len(r) // 2
    assert inclination(on, r)[late].mean() < 0.6 * inclination(off, r)[late].mean()
    b_true = np.array([0.02, -0.015, 0.0])
    assert np.linalg.norm(on.diagnostics["bias"] - b_true) < 0.6 * np.linalg.norm(b_true)


def tumbling(seed=0, rest=0.2, turns=30, errors=None, bias=(0.008, -0.006, 0.004)):
    """Fast turns (270 deg in 1.5 s, 180 deg/s on average) about many axes, after ``rest`` s."""
    axes = ((0, 0, 1), (1, 0, 0), (0, 1, 0), (1, 1, 0), (0, 1, 1), (1, 0, 1), (1, -1, 1), (-1, 1, 1))
    segs = [sim.Rest(rest)] + [sim.Rotate(axes[i % 8], (-1) ** i * 270 * DEG, 1.5) for i in range(turns)]
    noise = sim.Noise(gyr_noise=0.005, gyr_bias=bias, acc_noise=0.03)
    return sim.simulate(segs + [sim.Rest(1.0)], rate=200.0, noise=noise, seed=seed, errors=errors)


def test_bias_in_motion_learned_under_fast_rotation():
    # the correction is the drift low-passed over tau_acc; in 1 s the body turns by 180 deg, so the
    # sample's own R puts it on the wrong body axes (the lowpass model learns nothing: 0.59 deg over the
    # second half, as with no bias in motion); the Kalman filter's LP(R) knows which axes it came from (0.41)
    r = tumbling()
    runs = {k: fk.make("recommended", use_mag=False, **kw).run(r) for k, kw in
            {"kalman": {}, "lowpass": {"bias_filter": "lowpass"}, "off": {"motion_bias_tau": None}}.items()}
    late = np.arange(len(r)) > len(r) // 2
    err = {k: inclination(v, r)[late].mean() for k, v in runs.items()}
    assert err["kalman"] < 0.8 * err["lowpass"]
    assert err["lowpass"] > 0.9 * err["off"]
    b_true = np.array([0.008, -0.006, 0.004])
    # in 45 s of fast turns the Kalman filter has learned about half of it (0.57 of |b| left, every seed), the
    # lowpass model nothing (0.98)
    assert np.linalg.norm(runs["kalman"].diagnostics["bias"] - b_true) < 0.7 * np.linalg.norm(b_true)
    assert np.linalg.norm(runs["lowpass"].diagnostics["bias"] - b_true) > 0.9 * np.linalg.norm(b_true)


def test_a_rest_does_not_pin_the_bias_in_motion():
    # a gyro with scale factor errors (1-2%) spinning about one axis: its error in motion is b + E w, a
    # constant the rest before cannot see. VQF's model (bias_sigma_rest 0.03 deg/s) takes the rest's
    # bias as known to that and hardly learns in motion (2.47 deg over the second half); the default
    # (None: a rest says nothing about the error in motion) learns it (0.60); lowpass 2.00, none 2.74. The
    # bias filters compared at the fixed time constant (tau_adapt=False); the adaptive one (default) shortens
    # it under this turn (the scale factor's drift): 0.43, and lowpass 0.91. The bias models compared without
    # the rate error's estimate (gyro_rate_estimate "off"), which takes E w out of the bias's way (the default):
    # with it the rest's bias is the bias in motion, and the default pins it (bias_sigma_rest 0.03 deg/s since
    # issue 14's tau_max_parallel stop): 0.21, the same as without the pin (0.21)
    segs = [sim.Rest(8.0)] + [sim.Rotate((1, 0.5, 0.2), 360 * DEG, 2.0) for _ in range(25)] + [sim.Rest(1.0)]
    r = sim.simulate(segs, rate=200.0, noise=sim.Noise(gyr_noise=0.005, gyr_bias=(0.004, -0.006, 0.003),
                     acc_noise=0.03), seed=0, errors=sim.SensorErrors(gyr_scale=(0.01, -0.015, 0.02)))
    late = np.arange(len(r)) > len(r) // 2
    err = {k: inclination(fk.make("recommended", use_mag=False, **kw).run(r), r)[late].mean() for k, kw in
           {"fixed": {"tau_adapt": False, "gyro_rate_estimate": "off", "bias_sigma_rest": None},
            "vqf": {"tau_adapt": False, "bias_sigma_rest": 0.03 * DEG, "gyro_rate_estimate": "off"},
            "lowpass": {"tau_adapt": False, "bias_filter": "lowpass"}, "default": {},
            "unpinned": {"bias_sigma_rest": None}}.items()}
    assert err["fixed"] < 0.4 * err["vqf"]
    assert err["fixed"] < 0.4 * err["lowpass"]
    assert err["default"] < 0.8 * err["fixed"]
    assert err["default"] < err["unpinned"] + 0.02


def translation(seed=1, n=40):
    """A board tilted by 10 deg pushed back and forth (0.6 m in 1.2 s, random horizontal directions) for
    n x 2.4 s, a small turn every fourth push; a gyro with 1 % scale errors."""
    segs = [sim.Rest(5.0), sim.Rotate((1, 0, 0), 10 * DEG, 1.0)]
    rng = np.random.default_rng(seed)
    for i in range(n):
        d = rng.normal(size=2)
        d /= np.linalg.norm(d)
        segs += [sim.Translate((d[0], d[1], 0.0), 0.6, 1.2), sim.Translate((-d[0], -d[1], 0.0), 0.6, 1.2)]
        if i % 4 == 3:
            segs.append(sim.Rotate((0, 1, 0.2), (-1) ** i * 15 * DEG, 1.0))
    noise = sim.Noise(gyr_noise=0.002, gyr_bias=(0.004, -0.003, 0.002), acc_noise=0.02)
    return sim.simulate(segs, rate=100.0, noise=noise, seed=seed, gnss_rate=None,
                        errors=sim.SensorErrors(gyr_scale=(0.01, -0.01, 0.01)))


def test_adaptive_time_constant_under_translation():
    # sustained back-and-forth translation with few turns: the linear acceleration, not the gyro, limits the
    # inclination, and the adaptive time constant (default) lengthens to tau_max: 0.24-0.30 deg against
    # 0.46 with tau_acc = 2 s throughout (tau_adapt=False, the behaviour before; VQF 0.41-0.43)
    r = translation()
    f = fk.make("recommended", use_mag=False)
    res = f.run(r)
    fixed = fk.make("recommended", use_mag=False, tau_adapt=False).run(r)
    assert inclination(res, r).mean() < 0.2  # 0.17 (the per-sample mean; the RMS over the motion 0.24)
    assert inclination(fixed, r).mean() > 2.0 * inclination(res, r).mean()  # 0.42
    tilt = next(i for i, c in enumerate(f.correctors) if c.name == "inertial-tilt")
    assert res.diagnostics["state"]["cor"][tilt][_TAU] == pytest.approx(4.0)  # at tau_max
    # a still sensor keeps tau_acc (a turn shortens it: test_a_rest_does_not_pin_the_bias_in_motion)
    still = sim.simulate([sim.Rest(20.0)], rate=100.0, noise=sim.Noise(gyr_noise=0.002, acc_noise=0.02), seed=0)
    assert f.run(still).diagnostics["state"]["cor"][tilt][_TAU] == pytest.approx(2.0, abs=0.01)


def test_tau_max_parallel_drops_what_the_onset_let_through():
    # the pushes start after a rest: tau climbs from tau_acc (2 s) to tau_max (4 s) in the first seconds, and the
    # adaptive low-pass (its delay lines rescaled) keeps what 2 s let through; tau_max_parallel takes the low-pass
    # at tau_max run from the start instead (issue 14, BROAD trial 15's onset). Seed 1, RMS over 6-20 s (the
    # onset) / the whole motion, deg: before (neither, bias_sigma_rest None) 0.53 / 0.235; tau_max_parallel 0.43 /
    # 0.206; the rest's pin alone 0.91 / 0.360 (a known bias lengthens tau sooner, and the onset is kept longer);
    # both (the default) 0.17 / 0.152, as tau_max throughout (0.15 / 0.147)
    r = translation()
    t = np.arange(len(r.gyr)) * 0.01
    onset = r.movement & (t > 6.0) & (t < 20.0)
    err = {k: inclination(fk.make("recommended", use_mag=False, **kw).run(r), r) for k, kw in
           {"before": {"tau_max_parallel": False, "bias_sigma_rest": None}, "parallel": {"bias_sigma_rest": None},
            "pin": {"tau_max_parallel": False}, "default": {}}.items()}

    def rms(k, m):
        return float(np.sqrt(np.mean(err[k][m] ** 2)))

    assert rms("parallel", onset) < 0.85 * rms("before", onset)
    assert rms("parallel", r.movement) < 0.92 * rms("before", r.movement)
    assert rms("default", onset) < 0.4 * rms("before", onset)
    assert rms("default", r.movement) < 0.75 * rms("before", r.movement)
    assert rms("pin", r.movement) > 1.5 * rms("default", r.movement)
    # a motion whose tau never reaches tau_max is not touched
    c = fk.make("recommended", use_mag=False).run(knocked(0))
    np.testing.assert_array_equal(c.quat, fk.make("recommended", use_mag=False, tau_max_parallel=False)
                                  .run(knocked(0)).quat)


def test_the_rest_pin_follows_the_rate_error():
    """bias_sigma_rest "auto": a rest pins the bias in motion (VQF's 0.03 deg/s) only where the gyro's rate
    error is removed (gyro_rate_estimate correct); with "tau" or "off" the bias in motion carries E w, which
    a rest cannot see, so the rest leaves its covariance alone. A value the user gives is taken as given."""
    def pin(**kw):
        (c,) = [c for c in fk.make("recommended", **kw).correctors if c.name == "inertial-tilt"]
        return c.config.bias_sigma_rest

    assert pin() == pytest.approx(0.03 * DEG)
    assert pin(gyro_rate_estimate="tau") is None and pin(gyro_rate_estimate="off") is None
    assert pin(gyro_rate_estimate="off", bias_sigma_rest=0.001) == 0.001
    assert pin(bias_sigma_rest=None) is None and pin(rest_bias=False) is None
    for bad in ("often", -0.001):
        with pytest.raises(fk.ConfigError, match="bias_sigma_rest"):
            fk.make("recommended", bias_sigma_rest=bad)


def test_tau_max_parallel_reference_equals_numba():
    r = translation(n=6)  # the switch to the low-pass at tau_max at about 9 s
    f = fk.make("recommended", use_mag=False, tau_max_parallel=True)
    a, b = f.run(r, backend="numba"), f.run(r, backend="reference")
    np.testing.assert_allclose(a.quat, b.quat, atol=1e-9)
    np.testing.assert_allclose(flat_state(a), flat_state(b), atol=1e-9)
    tilt = next(i for i, c in enumerate(f.correctors) if c.name == "inertial-tilt")
    assert a.diagnostics["state"]["cor"][tilt][_PMAX] == 1.0  # at tau_max at the end, switched on the way
    plain = fk.make("recommended", use_mag=False, tau_max_parallel=False).run(r)
    assert np.abs(inclination(a, r) - inclination(plain, r)).max() > 0.05  # deg: the switch moved the output


def knocked(seed, knocks=True):
    """Slow turns knocked 12 times (60 m/s^2 per body axis for 5 ms, the body does not move with it)."""
    times = tuple(2.5 + 1.1 * i for i in range(12)) if knocks else ()
    return sim.scenarios.tapped(times=times, amplitude=(60.0, 60.0, 60.0), seed=seed)


@pytest.mark.parametrize("seed", [0, 1])
def test_impulse_clip_takes_knocks_out(seed):
    # a knock's specific force is far outside the motion's: clipped to impulse_clip times the departure's
    # RMS, it no longer tilts the low-pass (issue 14, BROAD's tapping group; seed 0 / 1: 1.28 / 1.18 deg
    # without the clip, 0.15 / 0.09 with it, 0.10 / 0.08 without knocks); motion alone is not touched
    def rms(rec, **kw):
        res = fk.make("recommended", use_mag=False, **kw).run(rec)
        return float(np.sqrt(np.mean(inclination(res, rec)[rec.movement] ** 2)))

    r, clean = knocked(seed), knocked(seed, knocks=False)
    assert fk.make("recommended").config.impulse_clip == 10.0  # the default since stop 21
    assert rms(r) < 0.2 * rms(r, impulse_clip=None)
    assert rms(r) < rms(clean) + 0.06
    a = fk.make("recommended", use_mag=False).run(clean)
    np.testing.assert_allclose(a.quat, fk.make("recommended", use_mag=False, impulse_clip=None).run(clean).quat,
                               atol=1e-12)


def test_impulse_clip_reference_equals_numba():
    r = knocked(0)
    f = fk.make("recommended", impulse_clip=10.0)
    a, b = f.run(r, backend="numba"), f.run(r, backend="reference")
    np.testing.assert_allclose(a.quat, b.quat, atol=1e-9)
    np.testing.assert_allclose(flat_state(a), flat_state(b), atol=1e-9)
    with pytest.raises(fk.ConfigError, match="impulse_clip"):
        fk.make("recommended", impulse_clip=1.0)


def test_heading_corrections_teach_the_vertical_bias():
    # with the inclination's bias in motion as before issue 14's stop 17 (lowpass): it learns the body axis
    # that is vertical slowly; the heading corrections teach it
    r = motion(rest_every=False, n=10, bias=(0.0, 0.0, 0.02))
    on = fk.make("recommended", motion_bias_tau=20.0, rest_bias=False, mag_bias=True, bias_filter="lowpass").run(r)
    off = fk.make("recommended", motion_bias_tau=20.0, rest_bias=False, bias_filter="lowpass").run(r)
    late = np.arange(len(r)) > len(r) // 2
    head = lambda res: broad_errors(res.quat, r.truth)["heading"][late].mean()  # noqa: E731
    assert head(on) < 0.7 * head(off)
    assert abs(on.diagnostics["bias"][2] - 0.02) < abs(off.diagnostics["bias"][2] - 0.02)
    # the Kalman bias filter (default) learns it from the inclination alone: the turns bring the body's
    # z axis to the horizontal, and LP(R) says which body axis the drift was on
    # (without the rate error's estimate, which shares the inclination's residual with the bias: measured 0.0020)
    kal = fk.make("recommended", motion_bias_tau=20.0, rest_bias=False, gyro_rate_estimate="off").run(r)
    assert abs(kal.diagnostics["bias"][2] - 0.02) < 0.1 * abs(off.diagnostics["bias"][2] - 0.02)
    assert head(kal) < head(on)


def test_magnetic_disturbance_is_rejected_and_a_new_field_accepted(rec):
    mag = rec.mag.copy()
    k = slice(900, 1400)  # a magnet nearby for 5 s: the field is 60 % stronger and turned
    mag[k] = mag[k] * 1.6 + [30.0, 0.0, 0.0]
    dist = dataclasses.replace(rec, mag=mag)
    on = fk.make("recommended", heading_gain="fixed").run(dist)
    off = fk.make("recommended", heading_gain="fixed", mag_rejection=False).run(dist)
    assert np.all(on.flags[k] & Flag.MAG_DISTURBED)
    assert not np.any(on.flags[:900] & Flag.MAG_DISTURBED)
    heading = lambda res: broad_errors(res.quat, rec.truth)["heading"]  # noqa: E731
    assert heading(on)[900:1500].max() < 0.3 * heading(off)[900:1500].max()
    # the Kalman heading gain (default) weighs such samples by their departure from the reference: even
    # without the rejection they barely reach the heading
    kal = fk.make("recommended").run(dist)
    assert np.all(kal.flags[k] & Flag.MAG_DISTURBED)
    assert heading(kal)[900:1500].max() < 0.3 * heading(off)[900:1500].max()
    assert heading(fk.make("recommended", mag_rejection=False).run(dist))[900:1500].max() < 0.5 * heading(off)[
        900:1500].max()
    # a lasting change of the homogeneous field (a new room), seen while turning, becomes the reference
    r2 = motion(rest_every=False, n=12)
    m2 = r2.mag.copy()
    m2[1000:] *= 1.5
    res = fk.make("recommended", magnetic={"new_time": 5.0}).run(dataclasses.replace(r2, mag=m2))
    disturbed = res.flags & Flag.MAG_DISTURBED != 0
    assert disturbed[1000:1200].all() and not disturbed[-1000:].any()


def test_fast_start_averages_the_first_samples():
    r = sim.simulate([sim.Rest(4.0)], rate=100.0, noise=sim.Noise(acc_noise=0.3, mag_noise=3.0), seed=4,
                     initial=tuple(euler_to_quat(0.5, 0.2, -0.3)), gnss_rate=None)
    fast = fk.make("recommended").run(r)
    slow = fk.make("recommended", fast_start=False).run(r)
    e_fast, e_slow = inclination(fast, r)[:100], inclination(slow, r)[:100]
    assert e_fast[50:].mean() < 0.5 * e_slow[50:].mean()


def test_acceleration_gate_flags_and_skips(rec):
    res = fk.make("recommended", acc_gate=0.2).run(rec)
    dev = np.abs(np.linalg.norm(rec.acc, axis=1) - 9.81)
    np.testing.assert_array_equal(res.flags & Flag.ACC_REJECTED != 0, dev > 0.2)


def test_bad_input_is_flagged_and_never_nan(rec):
    bad = dataclasses.replace(rec, gyr=rec.gyr.copy(), acc=rec.acc.copy(), mag=rec.mag.copy())
    bad.acc[400:450] = 0.0  # free fall / dropout
    bad.acc[460] = np.nan
    bad.mag[470:480] = 0.0
    bad.mag[490] = np.inf
    bad.gyr[495] = np.nan
    with pytest.raises(fk.InputError, match="not finite"):
        fk.make("recommended").run(bad)
    res = fk.make("recommended", nan_policy="skip", gyr_range=35.0).run(bad)
    assert np.isfinite(res.quat).all() and np.isfinite(flat_state(res)).all()
    assert np.all(res.flags[400:450] & Flag.ACC_INVALID) and res.flags[460] & Flag.ACC_INVALID
    assert np.all(res.flags[470:480] & Flag.MAG_INVALID) and res.flags[490] & Flag.MAG_INVALID
    assert res.flags[495] & Flag.GYR_INVALID
    clean = fk.make("recommended").run(rec)
    assert broad_errors(res.quat[600:], clean.quat[600:])["total"].max() < 2.0
    bad.gyr[510, 0] = 40.0  # beyond a 35 rad/s range
    res = fk.make("recommended", nan_policy="skip", gyr_range=35.0).run(bad)
    assert res.flags[510] & Flag.GYR_SATURATED and np.sum(res.flags & Flag.GYR_SATURATED != 0) == 1


def test_output_lead_compensates_a_delayed_gyro():
    """A gyroscope whose samples arrive 2 samples late: the estimate lags the truth; an output
    lead of that delay predicts it back. The state is the same with and without the lead (only
    the output changes), and on data without delay the lead costs accuracy (default 0). A longer
    ``acc_delay`` does not do the lead's work."""
    rec = motion(seed=3, n=2)
    late = dataclasses.replace(rec, gyr=np.vstack([np.zeros((2, 3)) + BIAS, rec.gyr[:-2]]))
    # at the fixed time constant (the adaptive one, default, shortens it under the late gyro's turns:
    # 0.42 vs 0.69 deg, asserted at the end)
    plain = fk.make("recommended", tau_adapt=False)
    lead = fk.make("recommended", tau_adapt=False, output_lead=0.02)
    a, b = plain.run(late), lead.run(late)
    # the state without the pipeline's last output (4 numbers before the channel, what sensor models read)
    sa, sb = flat_state(a), flat_state(b)
    keep = np.ones(sa.size, bool)
    keep[sa.size - CHANNEL_SIZE - 4:sa.size - CHANNEL_SIZE] = False
    np.testing.assert_allclose(sa[keep], sb[keep], atol=1e-12)
    def err(r, x):
        return np.sqrt(np.mean(inclination(r, x)[600:] ** 2))

    assert err(b, late) < 0.6 * err(a, late)  # measured: 0.31 vs 0.63 deg
    # the best lead is the delay itself
    assert err(b, late) < min(err(fk.make("recommended", tau_adapt=False, output_lead=t).run(late), late)
                              for t in (0.01, 0.03))
    assert err(lead.run(rec), rec) > err(plain.run(rec), rec)
    # a late gyro is not a late accelerometer the other way round: pairing the accelerometer with
    # an older orientation (a longer acc_delay) adds to the error instead of removing it
    assert err(fk.make("recommended", tau_adapt=False, acc_delay=0.02).run(late), late) > err(a, late)
    default = err(fk.make("recommended").run(late), late)
    assert err(fk.make("recommended", output_lead=0.02).run(late), late) < 0.7 * default


def test_sensors_paired_with_the_middle_of_the_step_by_default():
    """The gyro's step k covers (t[k-1], t[k]]. An accelerometer and magnetometer sampled like the
    gyro (the simulator's default: means over the interval) describe its middle: the default
    pairing (half a sample) is exact where the end of the step (``acc_delay=0``, ``mag_delay=0``)
    is not. Point samples at t[k] are the other way round."""
    fast = [sim.Rest(3.0)] + [sim.Rotate(ax, 120 * DEG * s, 1.0) for s in (1, -1)
                              for ax in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0))] * 2
    def err(rec, **kw):  # (inclination, heading) RMSE, deg
        e = broad_errors(fk.make("recommended", **kw).run(rec).quat, rec.truth)
        return np.sqrt(np.mean(e["inclination"] ** 2)), np.sqrt(np.mean(e["heading"] ** 2))

    end = {"acc_delay": 0.0, "mag_delay": 0.0}
    mean = sim.simulate(fast, rate=100.0, gnss_rate=None)
    point = sim.simulate(fast, rate=100.0, gnss_rate=None, sampling="point")
    # measured: (0.0006, 0.0009) vs (0.19, 0.09) deg, and the same the other way round
    assert max(err(mean)) < 0.005 and max(err(point, **end)) < 0.005
    assert err(mean, acc_delay=0.0)[0] > 0.1 and err(point)[0] > 0.1
    assert err(mean, mag_delay=0.0)[1] > 0.05 and err(point, acc_delay=0.0)[1] > 0.05
    # half of 10 ms: the same pairing, to rounding (the rate error's estimate feeds rounding back: 1e-8 measured)
    assert err(mean, acc_delay=0.005, mag_delay=0.005) == pytest.approx(err(mean), abs=1e-7)


def test_acc_delay_compensates_a_late_accelerometer():
    """An accelerometer 3 samples later than the gyroscope describes an earlier orientation;
    pairing it with the orientation ``acc_delay`` before (the gyro's rotation taken back: the
    3 samples and the half sample of the default) removes the inclination error that costs, and
    on data without delay the option costs accuracy."""
    rec = motion(seed=5, n=2, rest_every=False)
    late = dataclasses.replace(rec, acc=np.vstack([rec.acc[:1].repeat(3, axis=0), rec.acc[:-3]]))
    def err(r, x):
        return np.sqrt(np.mean(inclination(r, x)[600:] ** 2))

    plain = err(fk.make("recommended", use_mag=False).run(late), late)
    fixed = err(fk.make("recommended", use_mag=False, acc_delay=0.035).run(late), late)
    assert fixed < 0.7 * plain
    # the best delay is the delay itself
    assert fixed < min(err(fk.make("recommended", use_mag=False, acc_delay=t).run(late), late) for t in (0.015, 0.055))
    assert err(fk.make("recommended", use_mag=False, acc_delay=0.035).run(rec), rec) > err(
        fk.make("recommended", use_mag=False).run(rec), rec)


def test_broad_targets(broad_dir):
    """Default parameters, one set for all trials (BROAD's metrics): 9D total at or below 1.95 deg
    (VQF: 2.83; measured 1.837, 1.833 with tau_adapt=False); 6D inclination at or below
    0.67 deg (VQF: 0.80; measured 0.663 with the adaptive time constant, 0.708 before it, 0.724 before
    the Kalman bias filter; issue 14's 0.62 is not reached, see recommended.md)."""
    assert broad_mean(broad_dir, "recommended", "total") <= 1.95
    assert broad_mean(broad_dir, "recommended", "inclination", six_d=True) <= 0.67


def _biased_turns(bias_deg, first_rest: float, turns: int, last_rest: float = 0.0):
    """A gyro ``bias_deg`` (deg/s, per axis) off, ``first_rest`` s at rest, then ``turns`` 90 deg turns of 2 s about
    two alternating tilted axes (and ``last_rest`` s at rest), 100 Hz."""
    import math

    segs = [sim.Rest(first_rest)] + [sim.Rotate((0.3, -0.5, 1.0) if i % 2 else (1.0, 0.4, -0.2),
                                                math.radians(90) * (-1) ** i, 2.0) for i in range(turns)]
    if last_rest:
        segs.append(sim.Rest(last_rest))
    bias = tuple(np.radians(bias_deg))
    rec = sim.simulate(segs, rate=100.0, noise=sim.Noise(gyr_noise=0.003, acc_noise=0.03, mag_noise=0.2,
                                                         gyr_bias=bias), seed=4, gnss_rate=None)
    return rec, bias


def test_a_turn_on_gyro_bias_of_a_few_deg_per_s_is_learned():
    """A gyro 1.5 deg/s off on each axis (2.6 as a norm): the rest detector's ``max_rate`` (2 deg/s) is judged per
    axis, so the bias is learned at the first rest, and ``bias_max`` (5 deg/s) keeps it in motion: 6D inclination
    a quarter of a degree on the development machine. Each part matters: with ``bias_max`` at 2 deg/s (before stop
    30) the bias in motion is clipped (1.04 deg); a rest detector blind to the bias, as the norm test of before
    was to this one, leaves the bias to motion alone (4.5 deg)."""
    import math

    rec, bias = _biased_turns([1.5, -1.5, 1.5], 5.0, 16, 5.0)
    res = fk.make("recommended", use_mag=False).run(rec)
    assert (res.flags & Flag.REST).any() and rms_errors(res, rec)["inclination"] < 0.5
    np.testing.assert_allclose(res.diagnostics["bias"], bias, atol=math.radians(0.1))
    clipped = fk.make("recommended", use_mag=False, bias_max=math.radians(2.0)).run(rec)
    assert rms_errors(clipped, rec)["inclination"] > 0.8
    blind = fk.make("recommended", use_mag=False, rest={"max_rate": math.radians(1.4)}).run(rec)
    assert not (blind.flags & Flag.REST).any() and rms_errors(blind, rec)["inclination"] > 3.0


def test_a_turn_on_bias_over_the_rest_bound_is_learned_as_fast_as_its_prior_lets_it():
    """A gyro 3, -2.5, 3 deg/s off (over the rest detector's 2 deg/s on each axis: no rest can show it) and a minute
    of turns: only the bias in motion learns it, as fast as its prior (``bias_sigma_init``) lets it. The default
    (0.5 deg/s, VQF's) leaves 6D inclination 6.9 deg; set to such a gyro's turn-on offset (1 deg/s), 4.9 (VQF
    itself 4.7 on the development machine). Not the default: docs/algorithms/recommended.md, "The largest gyro
    bias", what a wider prior costs a calibrated gyro."""
    import math

    rec, bias = _biased_turns([3.0, -2.5, 3.0], 2.0, 30)
    default = fk.make("recommended", use_mag=False).run(rec)
    wide = fk.make("recommended", use_mag=False, bias_sigma_init=math.radians(1.0)).run(rec)
    assert not (default.flags & Flag.REST).any()
    assert rms_errors(wide, rec)["inclination"] < 0.8 * rms_errors(default, rec)["inclination"]  # (4.94, 6.94)
    err = np.linalg.norm(wide.diagnostics["bias"] - bias)
    assert err < 0.7 * np.linalg.norm(default.diagnostics["bias"] - bias)  # the bias learned further
