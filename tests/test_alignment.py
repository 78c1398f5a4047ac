import numpy as np
import pytest

from fusionkit import conventions as cv
from fusionkit.navigation.alignment import alignment_angles, alignment_quat
from fusionkit.rotations import quat_to_matrix

G = cv.GRAVITY


def still_specific_force(psi, theta, gamma):
    """f_r = -L g_e with g_e = [0, -g, 0] in source 000's N-Up-E frame (eq. 1)."""
    return cv.source000_matrix(psi, theta, gamma) @ np.array([0.0, G, 0.0])


@pytest.mark.parametrize("gamma_deg", [30.0, 120.0, -150.0, -60.0, 0.0, 180.0])
@pytest.mark.parametrize("theta_deg", [-70.0, -10.0, 0.0, 25.0, 80.0])
def test_round_trip_all_roll_quadrants(gamma_deg, theta_deg):
    theta, gamma = np.radians(theta_deg), np.radians(gamma_deg)
    f = still_specific_force(0.7, theta, gamma)  # the heading does not matter for f... except through L
    f0 = still_specific_force(0.0, theta, gamma)
    np.testing.assert_allclose(f, f0, atol=1e-12)  # f is heading-invariant
    th, ga = alignment_angles(f)
    assert th == pytest.approx(theta, abs=1e-12)
    assert np.angle(np.exp(1j * (ga - gamma))) == pytest.approx(0.0, abs=1e-12)


def test_printed_roll_formula_has_the_wrong_sign():
    """The document's gamma = atan(f3/f2) returns -gamma: the sign of f3 contradicts matrix (1)."""
    f = still_specific_force(0.0, 0.1, np.radians(30.0))
    assert np.arctan(f[2] / f[1]) == pytest.approx(-np.radians(30.0))
    assert alignment_angles(f)[1] == pytest.approx(np.radians(30.0))


@pytest.mark.parametrize("frame", cv.FRAMES)
def test_alignment_quat_explains_the_specific_force(frame):
    rng = np.random.default_rng(5)
    for _ in range(20):
        f = rng.normal(size=3)
        f *= 9.81 / np.linalg.norm(f)
        q = alignment_quat(f, frame=frame)
        # at rest R(q) f points up with magnitude |f|
        np.testing.assert_allclose(quat_to_matrix(q) @ f, 9.81 * cv.up_vector(frame), atol=1e-9)


@pytest.mark.parametrize("frame", ["ENU", "NED"])
def test_magnetometer_heading(frame):
    rng = np.random.default_rng(2)
    m_enu = np.array([0.0, 18.964, -46.962])  # north and down
    for _ in range(10):
        q_true = cv.euler_to_quat(rng.uniform(-3, 3), rng.uniform(-1, 1), rng.uniform(-3, 3), "ENU")
        r = quat_to_matrix(q_true)
        f, m = r.T @ [0, 0, 9.81], r.T @ m_enu
        q = alignment_quat(f, m, frame="ENU")
        np.testing.assert_allclose(quat_to_matrix(q) @ m, m_enu, atol=1e-9)  # full attitude recovered
        if frame == "NED":
            q2 = alignment_quat(f, m, frame="NED")
            np.testing.assert_allclose(q2, cv.change_frame(q, "ENU", "NED") * np.sign(q2[0] * cv.change_frame(q, "ENU", "NED")[0]), atol=1e-9)


def test_kernel_matches_reference():
    from fusionkit._kernels import alignment_quat as kq

    rng = np.random.default_rng(9)
    out = np.empty(4)
    for frame in cv.FRAMES:
        q_frame = cv.change_frame(np.array([1.0, 0, 0, 0]), "NUE", frame)
        for use_mag in (0, 1):
            f, m = rng.normal(size=3) * 5, rng.normal(size=3)
            kq(*f, *m, use_mag, q_frame, out)
            ref = alignment_quat(f, m if use_mag else None, frame)
            assert min(np.abs(out - ref).max(), np.abs(out + ref).max()) < 1e-12


def test_max_rate_ends_the_alignment_when_the_recording_starts_moving():
    """A recording that starts in motion: with max_rate the alignment ends at the first fast
    sample (no bias from moving samples); source 000 (max_rate None) averages through it."""
    import fusionkit as fk
    from fusionkit import sim

    deg = np.pi / 180
    moving = sim.simulate([sim.Rest(0.5), sim.Rotate((0, 0, 1), 180 * deg, 2.0), sim.Rest(1.0)], rate=100.0, seed=1)
    spec = {"estimator": "poisson-quat", "alignment": {"mode": "fixed", "duration": 3.0, "max_rate": 0.1}}
    for backend in ("reference", "numba"):
        res = fk.compose(spec).run(moving, backend=backend)
        end = res.diagnostics["alignment_end_index"]
        assert 58 <= end <= 65, end  # 0.5 s rest + about 11 samples until the smooth turn exceeds 0.1 rad/s
        # the turn's first samples, still below max_rate, are averaged in: a little bias (0.006 rad/s)
        assert np.linalg.norm(res.diagnostics["bias"]) < 0.01
    plain = fk.compose({**spec, "alignment": {"mode": "fixed", "duration": 3.0}}).run(moving)
    assert np.linalg.norm(plain.diagnostics["bias"]) > 0.3  # the mean of the turning gyro
    n = 200  # turning at 1 rad/s from the first sample: that sample's tilt, no bias
    first = fk.Recording(gyr=np.tile([1.0, 0.0, 0.0], (n, 1)), acc=np.tile([0.0, 0.0, 9.81], (n, 1)), rate=100.0)
    res = fk.compose(spec).run(first)
    assert res.diagnostics["alignment_end_index"] == 1
    np.testing.assert_array_equal(res.diagnostics["bias"], 0.0)


def test_attitude_first_holds_the_first_valid_sample_and_averages_the_bias():
    """attitude='first' (source 002's start): the attitude of the first sample with a valid
    accelerometer (and its field), held over the window; the bias is still the window's mean."""
    import fusionkit as fk
    from fusionkit import sim

    rec = sim.simulate([sim.Rest(2.0)], rate=100.0, noise=sim.Noise(gyr_noise=0.01, gyr_bias=(0.01, 0.0, -0.02),
                                                                   acc_noise=0.2, mag_noise=2.0), seed=3)
    acc = rec.acc.copy()
    acc[0] = np.nan  # the first valid accelerometer sample is sample 1
    bad = fk.Recording(gyr=rec.gyr, acc=acc, mag=rec.mag, rate=rec.rate)
    spec = {"estimator": "poisson-quat", "nan_policy": "skip",
            "alignment": {"mode": "fixed", "duration": 1.5, "heading": "auto", "attitude": "first"}}
    first = alignment_quat(acc[1], rec.mag[1], "ENU")
    for backend in ("reference", "numba"):
        res = fk.compose(spec).run(bad, backend=backend)
        np.testing.assert_allclose(res.quat[1:150] * np.sign(res.quat[1:150, :1]), np.tile(first, (149, 1)),
                                   atol=1e-12)
        np.testing.assert_allclose(res.diagnostics["bias"], rec.gyr[:150].mean(axis=0), atol=1e-12)
    mean = fk.compose({**spec, "alignment": {**spec["alignment"], "attitude": "mean"}}).run(bad)
    assert np.abs(mean.quat[149] - res.quat[149]).max() > 1e-4  # the mean moves on; 'first' does not
