import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fusionkit import _kernels as K
from fusionkit.conventions import euler_to_quat
from fusionkit.rotations import (
    cross, matrix_to_quat, orthonormalize, quat_angle, quat_conj, quat_from_rotvec, quat_mul, quat_normalize,
    quat_rotate, quat_to_matrix, quat_to_rotvec, rodrigues, skew, small_rotation_quat,
)

rng = np.random.default_rng(42)
R = Rotation.random(200, random_state=7)
Q = R.as_quat()[:, [3, 0, 1, 2]]


def test_quat_to_matrix_matches_scipy():
    np.testing.assert_allclose(quat_to_matrix(Q), R.as_matrix(), atol=1e-12)


def test_matrix_to_quat_roundtrip_all_branches():
    # include rotations near 180 deg about each axis so every Shepperd branch runs
    extra = Rotation.from_rotvec(np.array([[3.1, 0, 0], [0, 3.1, 0], [0, 0, 3.1], [0.1, 0.2, 0.3]]))
    for rot in (R, extra):
        q = matrix_to_quat(rot.as_matrix())
        assert np.all(quat_angle(q, rot.as_quat()[:, [3, 0, 1, 2]]) < 1e-7)
        assert np.all(q[:, 0] >= 0)


def test_hamilton_product_composes_like_matrices():
    a, b = Q[:100], Q[100:]
    np.testing.assert_allclose(quat_to_matrix(quat_mul(a, b)), quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-12)


def test_rotvec_roundtrip_and_scipy():
    rv = rng.normal(size=(100, 3))
    rv[:5] *= 1e-10  # small-angle branch
    q = quat_from_rotvec(rv)
    np.testing.assert_allclose(quat_to_matrix(q), Rotation.from_rotvec(rv).as_matrix(), atol=1e-12)
    big = np.linalg.norm(rv, axis=1) < np.pi
    np.testing.assert_allclose(quat_to_rotvec(q)[big], rv[big], atol=1e-9)


def test_rotate_and_conj():
    v = rng.normal(size=(200, 3))
    np.testing.assert_allclose(quat_rotate(Q, v), R.apply(v), atol=1e-12)
    np.testing.assert_allclose(quat_rotate(quat_conj(Q), quat_rotate(Q, v)), v, atol=1e-12)


def test_rodrigues_is_exponential_map():
    for rv in (rng.normal(size=3), 1e-6 * rng.normal(size=3), np.zeros(3)):
        np.testing.assert_allclose(rodrigues(rv), Rotation.from_rotvec(rv).as_matrix(), atol=1e-13)
    assert np.allclose(skew([1, 2, 3]) @ [4, 5, 6], np.cross([1, 2, 3], [4, 5, 6]))


def test_orthonormalize_reduces_error_quadratically():
    c = R[0].as_matrix() + 1e-4 * rng.normal(size=(3, 3))
    e0 = np.abs(c.T @ c - np.eye(3)).max()
    e1 = np.abs(orthonormalize(c).T @ orthonormalize(c) - np.eye(3)).max()
    assert e1 < 10 * e0**2


def test_small_rotation_quat_is_first_order():
    rv = np.array([1e-3, -2e-3, 5e-4])
    q = quat_normalize(small_rotation_quat(rv))
    assert quat_angle(q, quat_from_rotvec(rv)) < 1e-8  # O(|rv|^3)


@pytest.mark.parametrize("i", range(20))
def test_kernels_match_reference(i):
    p, q = Q[i], Q[100 + i]
    out = np.empty(4)
    K.qmul_into(*p, *q, out)
    np.testing.assert_allclose(out, quat_mul(p, q), atol=1e-15)
    c = np.empty(9)
    K.quat_to_dcm(p, c)
    np.testing.assert_allclose(c.reshape(3, 3), quat_to_matrix(p), atol=1e-15)
    K.dcm_to_quat(c, out)
    np.testing.assert_allclose(out, matrix_to_quat(quat_to_matrix(p)), atol=1e-12)
    rv = rng.normal(size=3) * (1e-9 if i % 2 else 1.0)
    K.rotvec_quat(*rv, out)
    np.testing.assert_allclose(out, quat_from_rotvec(rv), atol=1e-15)


def test_one_item_paths_give_the_stacked_numbers_to_the_bit():
    """The reference filters call these per sample on one item, which takes a path on Python
    floats (numpy's per-call cost is most of a step): the same operations as the stacked path, so
    the same numbers, signs of zero included."""
    g = np.random.default_rng(8)
    v = np.vstack([g.normal(size=(300, 3)), g.normal(size=(100, 3)) * 1e-6, np.zeros((1, 3))])
    w = g.normal(size=v.shape)
    m = np.vstack([quat_to_matrix(Q), g.normal(size=(100, 3, 3)) * 3.0])
    q4 = g.normal(size=(200, 4))
    ang = g.uniform(-4.0, 4.0, size=(200, 3))
    checks = [(lambda x: quat_normalize(x), q4), (skew, v), (rodrigues, v), (matrix_to_quat, m)]
    for f, x in checks:
        stacked = f(x)
        one = np.array([f(item) for item in x])
        assert np.array_equal(one, stacked) and np.array_equal(np.signbit(one), np.signbit(stacked)), f
    one = np.array([cross(a, b) for a, b in zip(v, w)])
    assert np.array_equal(one, np.cross(v, w)) and np.array_equal(np.signbit(one), np.signbit(np.cross(v, w)))
    one = np.array([euler_to_quat(*a, frame=fr) for a in ang for fr in ("ENU", "NUE")])
    stacked = np.stack([euler_to_quat(*ang.T, frame=fr) for fr in ("ENU", "NUE")], axis=1).reshape(-1, 4)
    assert np.array_equal(one, stacked) and np.array_equal(np.signbit(one), np.signbit(stacked))


def test_matrix_to_quat_of_a_non_finite_matrix_is_nan():
    """A matrix with a non-finite entry has no rotation: NaN in all four components, one matrix or a
    stack (before: numpy's arithmetic on it, e.g. ``[nan, 0, 0, 0]`` for an infinite diagonal entry),
    and the finite matrices of the stack are unaffected."""
    bad = np.eye(3)
    bad[0, 0] = np.inf
    good = quat_to_matrix(Q[:2])
    assert np.isnan(matrix_to_quat(bad)).all()
    out = matrix_to_quat(np.stack([good[0], bad, good[1]]))
    assert np.isnan(out[1]).all() and np.array_equal(out[[0, 2]], matrix_to_quat(good))
    # a stack with no finite matrix, or none at all (the stacked path once crashed on an empty assignment)
    assert matrix_to_quat(np.zeros((0, 3, 3))).shape == (0, 4)
    assert np.isnan(matrix_to_quat(np.full((2, 3, 3), np.nan))).all()
    assert np.isnan(matrix_to_quat(np.stack([bad, bad]))).all()


@pytest.mark.parametrize("call, name, shape", [
    (lambda x: quat_normalize(x), "q", r"\(4,\)"), (lambda x: quat_mul(x, Q[0]), "p", r"\(4,\)"),
    (lambda x: quat_mul(Q[0], x), "q", r"\(4,\)"), (lambda x: quat_conj(x), "q", r"\(4,\)"),
    (lambda x: quat_to_matrix(x), "q", r"\(4,\)"), (lambda x: quat_to_rotvec(x), "q", r"\(4,\)"),
    (lambda x: quat_angle(x, Q[0]), "p", r"\(4,\)"), (lambda x: quat_rotate(Q[0], x), "v", r"\(3,\)"),
    (lambda x: quat_from_rotvec(x), "rv", r"\(3,\)"), (lambda x: small_rotation_quat(x), "rv", r"\(3,\)"),
    (lambda x: skew(x), "v", r"\(3,\)"), (lambda x: cross(x, [1.0, 0.0, 0.0]), "a", r"\(3,\)"),
    (lambda x: rodrigues(x), "rv", r"\(3,\)"), (lambda x: matrix_to_quat(x), "m", r"\(3, 3\)"),
    (lambda x: orthonormalize(x), "c", r"\(3, 3\)")])
def test_wrong_shapes_name_the_argument(call, name, shape):
    """Wrong-length items, a scalar, a transposed stack and text: an InputError naming the argument
    and the shape expected, not numpy's broadcasting error or an unpacking error from inside."""
    from fusionkit.errors import InputError

    bad = [np.zeros(5), np.zeros(2), 1.0, np.zeros((4, 7)), np.zeros((3, 4, 5)), ["a", "b", "c", "d"]]
    for x in bad:
        with pytest.raises(InputError, match=rf"^{name} must .*shape {shape}"):
            call(x)
