"""Source 004: strapdown velocity/position, its filters and its error laws."""

import numpy as np
import pytest
from scipy import signal

import fusionkit as fk
from fusionkit import sim
from fusionkit.conventions import euler_to_quat
from fusionkit.navigation.strapdown import design_prefilter, highpass, prefilter, strapdown
from fusionkit.rotations import quat_angle

G = 9.81


def still(n, rate=50.0):
    return np.zeros((n, 3)), np.tile([0.0, 0.0, G], (n, 1)), 1.0 / rate


def test_prefilter_meets_the_documents_specification():
    h = design_prefilter()
    w, resp = signal.freqz(h, worN=8192)
    mag_db = 20 * np.log10(np.abs(resp))
    passband, stopband = mag_db[w <= 0.1], mag_db[w >= 0.8]
    assert passband.max() - passband.min() <= 1.0  # 1 dB ripple
    assert stopband.max() <= -60.0  # deep stop-band attenuation
    # the engine lines of the Pitts flight (rad/s at 50 Hz) fall in the stop band
    t = np.arange(5000) / 50.0
    for omega in (44.4, 90.3, 134.6):
        x = np.sin(omega * t)[:, None] * np.ones(3)
        y = prefilter(x, h)
        assert np.abs(y[500:-500]).max() < 2e-3
    slow = np.sin(2 * np.pi * 0.3 * t)[:, None] * np.ones(3)  # a manoeuvre: passes
    assert np.abs(prefilter(slow, h) - slow)[500:-500].max() < 0.13  # within 1 dB (zero-phase: squared)


def test_constant_acceleration_is_integrated_exactly():
    n, rate = 1501, 50.0
    gyr, acc, dt = still(n, rate)
    acc = acc + [0.3, -0.2, 0.1]
    r = strapdown(gyr, acc, dt, quat0=[1, 0, 0, 0], vel0=[1.0, 0, 0], pos0=[5.0, 0, 0])
    t = np.arange(n) * dt
    np.testing.assert_allclose(r.pos, np.array([5.0, 0, 0]) + np.outer(t, [1.0, 0, 0]) + 0.5 * np.outer(t**2, [0.3, -0.2, 0.1]),
                               atol=1e-9)


def test_tilt_error_law_and_the_documents_figure():
    """0.05 deg of tilt puts g sin(eps) = 0.0086 m/s^2 on a horizontal axis: after 30 s the
    double integral is 3.86 m. The document's 7.7 m is g sin(eps) t^2: its 1/2 is missing."""
    n, rate = 1501, 50.0
    gyr, acc, dt = still(n, rate)
    eps = np.radians(0.05)
    tilted = euler_to_quat(0.0, 0.0, eps, "ENU")  # the attitude believed is 0.05 deg off level
    r = strapdown(gyr, acc, dt, quat0=tilted)
    horizontal = np.hypot(r.pos[-1, 0], r.pos[-1, 1])
    assert G * np.sin(eps) == pytest.approx(0.0086, abs=1e-4)
    assert horizontal == pytest.approx(0.5 * G * np.sin(eps) * 30.0**2, rel=1e-6)
    assert horizontal == pytest.approx(3.86, abs=0.01)
    assert G * np.sin(eps) * 30.0**2 == pytest.approx(7.7, abs=0.05)  # the document's number


def test_accelerometer_bias_law():
    n, rate = 1001, 100.0
    gyr, acc, dt = still(n, rate)
    d0 = 0.02
    r = strapdown(gyr, acc + [d0, 0, 0], dt, quat0=[1, 0, 0, 0])
    t = np.arange(n) * dt
    np.testing.assert_allclose(r.vel[:, 0], d0 * t, atol=1e-12)
    np.testing.assert_allclose(r.pos[:, 0], d0 * t**2 / 2, atol=1e-12)


def test_rotating_motion_on_simulated_data():
    deg = np.pi / 180
    rec = sim.simulate([sim.Rest(1.0), sim.Rotate((0, 0, 1), 90 * deg, 2.0), sim.Translate((1, 0, 0), 2.0, 2.0),
                        sim.Rotate((1, 1, 0), 60 * deg, 2.0), sim.Translate((0, 0, 1), 1.0, 2.0)], rate=200.0,
                       gravity=G, seed=0, sampling="point")  # the trapezoidal rule's point samples
    r = strapdown(rec.gyr, rec.acc, rec.dt, quat0=rec.truth[0], gravity=G)
    assert quat_angle(r.quat, rec.truth).max() < 1e-9  # exact attitude for the simulator's mean rates
    assert np.abs(r.pos[-1] - [2.0, 0.0, 1.0]).max() < 5e-3  # trapezoidal rule, O(dt^2)
    given = strapdown(None, rec.acc, rec.dt, attitude=rec.truth, gravity=G)
    assert np.abs(given.pos - r.pos).max() < 1e-6


def test_fixes_reset_the_integration():
    n, rate = 3001, 50.0
    gyr, acc, dt = still(n, rate)
    biased = acc + [0.05, 0.0, 0.0]
    free = strapdown(gyr, biased, dt, quat0=[1, 0, 0, 0])
    fixes = [(i, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]) for i in range(0, n, 50)]  # a GNSS fix every second
    reset = strapdown(gyr, biased, dt, quat0=[1, 0, 0, 0], fixes=fixes)
    assert free.pos[-1, 0] == pytest.approx(0.05 * 60.0**2 / 2, rel=1e-6)
    assert np.abs(reset.pos[:, 0]).max() <= 0.05 * 1.0**2 / 2 + 1e-9
    assert reset.reset.sum() == len(fixes)


def test_highpass_removes_drift_with_a_start_transient():
    t = np.arange(0, 60, 0.02)
    motion = np.sin(2 * np.pi * 0.5 * t)
    drift = 0.3 * t
    y = highpass(np.column_stack([motion + drift] * 3), 0.05, 50.0)
    assert np.abs(y[500:-500, 0] - motion[500:-500]).max() < 0.1
    with pytest.raises(fk.InputError, match="cutoff"):
        highpass(y, 30.0, 50.0)


@pytest.mark.parametrize("given", [False, True])
def test_numba_equals_reference(given):
    rng = np.random.default_rng(0)
    n = 4000
    gyr, acc = rng.normal(size=(n, 3)) * 0.5, rng.normal(size=(n, 3)) + [0, 0, G]
    att = None
    if given:
        from fusionkit.rotations import quat_from_rotvec

        att = quat_from_rotvec(rng.normal(size=(n, 3)))
    kw = {"attitude": att} if given else {"quat0": [1, 0, 0, 0]}
    fixes = [(i, [np.nan, 1.0, 0.0], [0.0, np.nan, 0.0]) for i in range(0, n, 400)]
    a = strapdown(gyr, acc, 0.01, fixes=fixes, backend="reference", **kw)
    b = strapdown(gyr, acc, 0.01, fixes=fixes, backend="numba", **kw)
    scale = max(1.0, np.abs(a.pos).max())
    assert np.abs(a.pos - b.pos).max() / scale < 1e-12 and np.abs(a.vel - b.vel).max() < 1e-9
    assert np.abs(a.quat - b.quat).max() < 1e-9


def test_bad_input():
    with pytest.raises(fk.InputError, match="acc must have shape"):
        strapdown(None, np.zeros((5, 2)), 0.01, quat0=[1, 0, 0, 0])
    with pytest.raises(fk.InputError, match="attitude=.*or gyr and quat0"):
        strapdown(None, np.zeros((5, 3)), 0.01)
    with pytest.raises(fk.InputError, match="fix index"):
        strapdown(np.zeros((5, 3)), np.zeros((5, 3)), 0.01, quat0=[1, 0, 0, 0], fixes=[(9, [0, 0, 0], [0, 0, 0])])


def _bad(**kw):
    n = 20
    args = {"gyr": np.zeros((n, 3)), "acc": np.tile([0.0, 0.0, G], (n, 1)), "dt": 0.01, "quat0": [1, 0, 0, 0],
            "backend": "reference"}
    args.update(kw)
    if "attitude" in kw:
        args.pop("quat0")
    return strapdown(args.pop("gyr"), args.pop("acc"), args.pop("dt"), **args)


@pytest.mark.parametrize("kw, match", [
    ({"dt": -0.01}, r"dt must be a finite number > 0"),  # ran backwards to a finite position
    ({"dt": 0}, r"dt must be a finite number > 0"),  # all zeros
    ({"dt": np.nan}, r"dt must be a finite number > 0"),
    ({"dt": np.inf}, r"dt must be a finite number > 0"),
    ({"dt": np.r_[np.full(10, 0.01), -0.01, np.full(9, 0.01)]}, r"dt\[10\] is -0.01"),
    ({"acc": np.where(np.arange(20)[:, None] == 5, np.nan, np.tile([0.0, 0.0, G], (20, 1)))},
     r"acc\[5\] is not finite"),
    ({"gyr": np.where(np.arange(20)[:, None] == 7, np.inf, np.zeros((20, 3)))}, r"gyr\[7\] is not finite"),
    ({"attitude": np.zeros((20, 4))}, r"attitude\[0\] is a zero quaternion"),
    ({"attitude": np.where(np.arange(20)[:, None] == 3, np.nan, [1.0, 0, 0, 0])}, r"attitude\[3\] is not finite"),
    ({"quat0": [0, 0, 0, 0]}, r"quat0 is a zero quaternion"),  # NaN and a RuntimeWarning
    ({"fixes": [(3, [0, 0], [0, 0, 0])]}, r"fixes\[0\] velocity must have shape \(3,\)"),  # numpy's reshape error
    ({"fixes": [(3, [0, 0, 0])]}, r"fixes\[0\] must be \(index, vel"),
    ({"fixes": [(3.5, [0, 0, 0], [0, 0, 0])]}, r"fixes\[0\]'s index must be an integer"),  # was taken as 3
    ({"vel0": [np.nan, 0, 0]}, r"vel0 is not finite"),
    ({"gravity": -9.81}, r"gravity must be one finite number >= 0"),
    ({"attitude": [1.0, 0, 0, 0]}, r"attitude must have shape \(20, 4\), one quaternion per acc sample, got \(4,\)"),
])
def test_bad_input_is_named(kw, match):
    """Each of a new user's inputs that ran silently to a wrong (or NaN) answer, or failed in numpy
    naming nothing, is an InputError naming the argument (and the first bad sample)."""
    with pytest.raises(fk.InputError, match=match):
        _bad(**kw)


def test_gravity_removed_and_a_whole_float_fix_index_are_taken():
    """gravity=0 integrates an acceleration with gravity already removed (a phone's linear
    acceleration); a fix index that is a whole float (np.round's 3.0) is that sample (review rev33b:
    the input checks of the stop refused both)."""
    r = _bad(acc=np.tile([0.5, 0.0, 0.0], (20, 1)), gravity=0)
    assert r.vel[-1, 0] == pytest.approx(0.5 * 19 * 0.01)
    a, b = (_bad(fixes=[(k, [1.0, 0, 0], [0, 0, 0])]) for k in (3, np.float64(3.0)))
    np.testing.assert_array_equal(a.pos, b.pos)


def test_interval_array_first_entry_and_scaled_quaternions():
    """dt[0] is not used (np.diff with a 0 prepended is fine); a scaled quaternion is normalised, as
    quat0 always was (the matrix of 3 q is no rotation: gravity was not removed)."""
    from fusionkit.rotations import quat_from_rotvec, quat_to_matrix

    n = 20
    q = np.tile(quat_from_rotvec([0.5, 0.2, 0.0]), (n, 1))
    acc = np.tile(quat_to_matrix(q[0]).T @ [0.0, 0.0, G], (n, 1))  # at rest, tilted
    r = _bad(acc=acc, dt=np.r_[0.0, np.full(n - 1, 0.01)], attitude=3 * q)
    np.testing.assert_allclose(r.pos, 0.0, atol=1e-12)
    np.testing.assert_allclose(r.quat, q, atol=1e-12)


def test_a_result_is_taken_in_its_own_frame():
    """A filter's Result as ``attitude``: re-expressed in ``frame`` (an ENU result read as NED
    quaternions was 62 m off on heli_cruise); ``frame`` left out is the Result's."""
    rng = np.random.default_rng(1)
    n = 50
    from fusionkit.conventions import change_frame
    from fusionkit.rotations import quat_from_rotvec

    q_enu = quat_from_rotvec(0.3 * rng.normal(size=(n, 3)))
    acc = rng.normal(size=(n, 3)) + [0, 0, G]
    res = fk.Result(quat=q_enu, flags=np.zeros(n, np.uint32), frame="ENU")
    ned = strapdown(None, acc, 0.01, attitude=change_frame(q_enu, "ENU", "NED"), frame="NED", backend="reference")
    got = strapdown(None, acc, 0.01, attitude=res, frame="NED", backend="reference")
    assert got.frame == "NED"
    np.testing.assert_allclose(got.pos, ned.pos, atol=1e-12)
    own = strapdown(None, acc, 0.01, attitude=res, backend="reference")
    assert own.frame == "ENU"
    np.testing.assert_allclose(own.pos, strapdown(None, acc, 0.01, attitude=q_enu, backend="reference").pos, atol=1e-12)
