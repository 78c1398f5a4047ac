import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusionkit import conventions as cv
from fusionkit.errors import ConfigError, InputError
from fusionkit.rotations import quat_angle, quat_to_matrix

rng = np.random.default_rng(0)
Q = Rotation.random(100, random_state=1).as_quat()[:, [3, 0, 1, 2]]


@pytest.mark.parametrize("src", cv.FRAMES)
@pytest.mark.parametrize("dst", cv.FRAMES)
def test_frame_changes_round_trip_and_compose(src, dst):
    back = cv.change_frame(cv.change_frame(Q, src, dst), dst, src)
    assert np.all(quat_angle(back, Q) < 1e-12)
    m = cv.frame_matrix(src, dst)
    assert np.isclose(np.linalg.det(m), 1.0)
    # a body vector expressed in dst equals the src expression mapped by the frame matrix
    v = rng.normal(size=3)
    np.testing.assert_allclose(quat_to_matrix(cv.change_frame(Q[0], src, dst)) @ v, m @ (quat_to_matrix(Q[0]) @ v),
                               atol=1e-12)


def test_named_axes():
    np.testing.assert_array_equal(cv.up_vector("ENU"), [0, 0, 1])
    np.testing.assert_array_equal(cv.up_vector("NED"), [0, 0, -1])
    np.testing.assert_array_equal(cv.up_vector("NUE"), [0, 1, 0])
    np.testing.assert_array_equal(cv.north_vector("NWU"), [1, 0, 0])
    np.testing.assert_array_equal(cv.frame_matrix("ENU", "NWU") @ [1, 0, 0], [0, -1, 0])  # East is -West
    with pytest.raises(ConfigError, match="frame must be one of"):
        cv.check_frame("XYZ")


@pytest.mark.parametrize("frame", ["ENU", "NED", "NWU"])
def test_euler_zyx_matches_scipy(frame):
    hpr = cv.quat_to_euler(Q, frame)
    ref = Rotation.from_quat(Q[:, [1, 2, 3, 0]]).as_euler("ZYX")
    np.testing.assert_allclose(hpr, ref, atol=1e-9)
    back = cv.euler_to_quat(hpr[:, 0], hpr[:, 1], hpr[:, 2], frame)
    assert np.all(quat_angle(back, Q) < 1e-9)


def test_source000_matrix_is_the_transpose_of_the_quaternion_matrix():
    for _ in range(50):
        psi, gamma = rng.uniform(-np.pi, np.pi, 2)
        theta = rng.uniform(-1.5, 1.5)
        L = cv.source000_matrix(psi, theta, gamma)
        np.testing.assert_allclose(L @ L.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(quat_to_matrix(cv.source000_quat(psi, theta, gamma)), L.T, atol=1e-12)
        np.testing.assert_allclose(cv.source000_euler(cv.source000_quat(psi, theta, gamma)), [psi, theta, gamma],
                                   atol=1e-9)
        # the sequence is scipy's intrinsic y-z'-x''
        np.testing.assert_allclose(Rotation.from_euler("YZX", [psi, theta, gamma]).as_matrix(), L.T, atol=1e-12)


def test_source000_printed_quaternions_disagree_with_matrix_1():
    """Documents the ambiguity of SEEDS.md: as extracted, (3) for a pure pitch puts -sin(theta/2) in
    the third vector component, while the body->earth quaternion of matrix (1) has +sin(theta/2)."""
    theta = 0.3
    printed_3 = np.array([np.cos(theta / 2), 0.0, 0.0, -np.sin(theta / 2)])
    ours = cv.source000_quat(0.0, theta, 0.0)
    np.testing.assert_allclose(ours, [np.cos(theta / 2), 0, 0, np.sin(theta / 2)], atol=1e-15)
    assert not np.allclose(quat_to_matrix(printed_3), cv.source000_matrix(0.0, theta, 0.0).T)


def test_euler_nue_uses_source000_sequence():
    q = cv.euler_to_quat(0.2, -0.1, 0.4, "NUE")
    np.testing.assert_allclose(cv.quat_to_euler(q, "NUE"), [0.2, -0.1, 0.4], atol=1e-12)


@pytest.mark.parametrize("frame", ["ENU", "NED", "NUE"])
def test_euler_of_a_quaternion_not_of_unit_length(frame):
    """quat_to_euler and to_scipy read a quaternion as the rotation it stands for: 2 q once gave a
    yaw of 1.815 rad for q's 1 rad (quat_to_matrix assumes unit length); a zero quaternion is an
    error by index, a NaN one stays NaN, a wrong shape is an InputError (to_scipy's was an IndexError)."""
    q = cv.euler_to_quat(1.0, -0.2, 0.3, frame)
    np.testing.assert_allclose(cv.quat_to_euler(2.0 * q, frame), cv.quat_to_euler(q, frame), atol=1e-12)
    np.testing.assert_allclose(cv.to_scipy(0.5 * q).as_matrix(), cv.to_scipy(q).as_matrix(), atol=1e-12)
    assert np.isnan(cv.quat_to_euler(np.array([[np.nan, 0, 0, 0]]), frame)).all()
    stack = np.array([q, np.zeros(4)])
    for f in (lambda x: cv.quat_to_euler(x, frame), cv.to_scipy):
        with pytest.raises(InputError, match=r"quat\[1\] is a zero quaternion: no orientation"):
            f(stack)
        with pytest.raises(InputError, match=r"quat must have shape \(4,\) or \(N, 4\), got \(5, 3\)"):
            f(np.zeros((5, 3)))


def test_scipy_interop():
    r = cv.to_scipy(Q)
    np.testing.assert_allclose(cv.from_scipy(r), Q, atol=1e-15)
