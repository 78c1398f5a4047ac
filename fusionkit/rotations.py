"""Quaternion, rotation-matrix and rotation-vector math: the readable reference.

Conventions (see :mod:`fusionkit.conventions`): quaternions are ``[w, x, y, z]``, Hamilton
product, and a quaternion ``q`` rotates body-frame vectors into the earth frame,
``v_earth = q (x) v_body (x) q*``, so ``quat_to_matrix(q) @ v_body == v_earth``. Matrices act on
column vectors. Every function accepts a single item (``(4,)``, ``(3,)``, ``(3, 3)``) or a stack
(``(N, 4)``, ...) and broadcasts like numpy.

The numba kernels in :mod:`fusionkit._kernels` implement the same operations on scalars; the
tests compare the two.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import InputError

__all__ = [
    "wrap_angle",
    "quat_mul",
    "quat_conj",
    "quat_normalize",
    "quat_from_rotvec",
    "quat_to_rotvec",
    "quat_from_axis_angle",
    "quat_to_matrix",
    "matrix_to_quat",
    "quat_rotate",
    "quat_angle",
    "small_rotation_quat",
    "skew",
    "cross",
    "rodrigues",
    "orthonormalize",
]

_SMALL = 1e-8  # below this rotation angle (rad) the Taylor branches are exact to double precision
_EYE3 = np.eye(3)  # read only (rodrigues, per sample in the reference filters)


def _arr(x, name: str, tail: tuple):
    """``x`` as a float array whose last axes are ``tail`` (one item, or a stack of them): a clear
    :class:`~fusionkit.errors.InputError` naming ``name`` otherwise, not numpy's or an unpacking error
    from inside the arithmetic."""
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError) as e:
        raise InputError(f"{name} must be an array of numbers of shape {_shape_text(tail)}, got {x!r:.80} ({e})") \
            from None
    if a.shape[-len(tail):] != tail:
        raise InputError(f"{name} must have shape {_shape_text(tail)}, got {a.shape}")
    return a


def _shape_text(tail: tuple) -> str:
    one = ", ".join(map(str, tail))
    return f"({one}{',' if len(tail) == 1 else ''}) or (N, {one})"


def quat_mul(p, q):
    """Hamilton product ``p (x) q`` (source 000, "quaternion operations")."""
    p, q = _arr(p, "p", (4,)), _arr(q, "q", (4,))
    # one product (a reference filter's per-sample step): the same operations on Python floats,
    # the same numbers at a tenth of the cost of numpy's per-call overhead
    single = p.ndim == q.ndim == 1
    p0, p1, p2, p3 = p.tolist() if single else np.moveaxis(p, -1, 0)
    q0, q1, q2, q3 = q.tolist() if single else np.moveaxis(q, -1, 0)
    out = [
        p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
        p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
        p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
        p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0,
    ]
    return np.array(out) if single else np.stack(out, axis=-1)


def quat_conj(q):
    """Conjugate ``[w, -x, -y, -z]`` (the inverse of a unit quaternion)."""
    q = _arr(q, "q", (4,))
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q):
    """Scale to unit norm."""
    q = _arr(q, "q", (4,))
    if q.ndim == 1:  # one quaternion: Python floats, as in quat_mul (the same sum and division)
        w, x, y, z = q.tolist()
        n = math.sqrt(w * w + x * x + y * y + z * z)
        if 0.0 < n < math.inf:  # (zero and non-finite norms: numpy's path, its NaNs)
            return np.array([w / n, x / n, y / n, z / n])
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_from_axis_angle(axis, angle):
    """Quaternion of a rotation by ``angle`` (rad) about the unit vector ``axis``."""
    axis = _arr(axis, "axis", (3,))
    angle = np.asarray(angle, dtype=float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * angle[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_from_rotvec(rv):
    """Exact quaternion of the rotation vector ``rv`` (axis times angle, rad)."""
    rv = _arr(rv, "rv", (3,))
    if rv.ndim == 1:  # one rotation: the same operations on Python floats, as in quat_mul
        x, y, z = rv.tolist()
        a = math.sqrt(x * x + y * y + z * z)
        if a < math.inf:  # (not NaN or inf, which math.sin refuses: numpy's path gives NaN)
            k = 0.5 - a * a / 48.0 if a < _SMALL else math.sin(0.5 * a) / a
            return np.array([math.cos(0.5 * a), k * x, k * y, k * z])
    angle = np.linalg.norm(rv, axis=-1, keepdims=True)
    small = angle < _SMALL
    safe = np.where(small, 1.0, angle)
    # sin(a/2)/a, with its Taylor series 1/2 - a^2/48 for tiny angles
    k = np.where(small, 0.5 - angle**2 / 48.0, np.sin(0.5 * safe) / safe)
    return np.concatenate([np.cos(0.5 * angle), k * rv], axis=-1)


def quat_to_rotvec(q):
    """Rotation vector (axis times angle in [0, pi]) of a unit quaternion."""
    q = _arr(q, "q", (4,))
    q = np.where(q[..., :1] < 0, -q, q)  # the shorter of q and -q
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    small = s < _SMALL
    k = np.where(small, 2.0 / np.where(small, q[..., :1], 1.0), angle / np.where(small, 1.0, s))
    return k * v


def small_rotation_quat(rv):
    """Source 000's first-order small-rotation quaternion ``[1, rv/2]`` (not normalised)."""
    rv = _arr(rv, "rv", (3,))
    return np.concatenate([np.ones(rv.shape[:-1] + (1,)), 0.5 * rv], axis=-1)


def quat_to_matrix(q):
    """Rotation matrix of a unit quaternion: ``quat_to_matrix(q) @ v_body == v_earth``."""
    q = _arr(q, "q", (4,))
    single = q.ndim == 1  # one quaternion: Python floats, as in quat_mul
    w, x, y, z = q.tolist() if single else np.moveaxis(q, -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.array(rows) if single else np.stack([np.stack(r, -1) for r in rows], axis=-2)


def matrix_to_quat(m):
    """Unit quaternion (with ``w >= 0``) of a rotation matrix, Shepperd's method (:func:`_shepperd`,
    one matrix at a time on Python floats); a matrix with a non-finite entry gives NaN."""
    m = _arr(m, "m", (3, 3))
    if m.ndim == 2:  # (the per-sample call: no array made for the finiteness test)
        e = m.ravel().tolist()
        return np.array(_shepperd(*e) if all(map(math.isfinite, e)) else [math.nan] * 4)
    e = m.reshape(-1, 9)
    ok = np.isfinite(e).all(axis=1)
    out = np.full((e.shape[0], 4), math.nan)
    if ok.any():  # (no finite matrix, or none at all: NaN rows, or an empty (0, 4))
        out[ok] = [_shepperd(*r) for r in e[ok].tolist()]
    return out.reshape(m.shape[:-2] + (4,))


def _shepperd(r00, r01, r02, r10, r11, r12, r20, r21, r22) -> list:
    """Shepperd's method on one matrix with finite entries: the quaternion from the largest of the
    trace and the diagonal (the best-conditioned square root), its sign (``w >= 0``) and its
    normalisation, on Python floats."""
    tr = r00 + r11 + r22
    if tr >= r00 and tr >= r11 and tr >= r22:
        s = 2.0 * math.sqrt(1.0 + tr)
        w, x, y, z = 0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s
    elif r00 >= r11 and r00 >= r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        w, x, y, z = (r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s
    elif r11 >= r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        w, x, y, z = (r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        w, x, y, z = (r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return [w / n, x / n, y / n, z / n]


def quat_rotate(q, v):
    """Rotate body vectors ``v`` into the earth frame: ``q (x) v (x) q*``."""
    v = _arr(v, "v", (3,))  # (first: quat_to_matrix names q)
    return np.einsum("...ij,...j->...i", quat_to_matrix(q), v)


def quat_angle(p, q):
    """Rotation angle (rad, in [0, pi]) between two orientations.

    ``2 atan2(|vec(e)|, |w(e)|)`` of ``e = p* (x) q``: accurate for tiny angles, where
    ``2 acos(|p.q|)`` loses half the digits.
    """
    p, q = _arr(p, "p", (4,)), _arr(q, "q", (4,))
    e = quat_mul(quat_conj(quat_normalize(p)), quat_normalize(q))
    return 2.0 * np.arctan2(np.linalg.norm(e[..., 1:], axis=-1), np.abs(e[..., 0]))


def skew(v):
    """Skew-symmetric matrix ``[v x]`` with ``skew(a) @ b == cross(a, b)``."""
    v = _arr(v, "v", (3,))
    if v.ndim == 1:  # one vector: Python floats, as in quat_mul
        x, y, w = v.tolist()
        return np.array([[0.0, -w, y], [w, 0.0, -x], [-y, x, 0.0]])
    z = np.zeros(v.shape[:-1])
    x, y, w = np.moveaxis(v, -1, 0)
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def cross(a, b):
    """Cross product ``a x b`` of 3-vectors, broadcasting like ``np.cross``. One pair (a reference
    filter's per-sample step) on Python floats: the products and differences ``np.cross`` forms,
    the same numbers without its per-call cost (axis handling, temporaries)."""
    a, b = _arr(a, "a", (3,)), _arr(b, "b", (3,))
    if a.ndim == b.ndim == 1 and a.size == b.size == 3:
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    return np.cross(a, b)


def rodrigues(rv):
    """Source 004's exact DCM increment ``I + sin(s)/s B + (1 - cos(s))/s^2 B^2``, ``B = [rv x]``.

    ``s = |rv|``; for tiny ``s`` the Taylor series of both coefficients is used.
    """
    rv = _arr(rv, "rv", (3,))
    if rv.ndim == 1:  # one rotation: its norm on Python floats (the same sum), numpy's scalars after
        x, y, z = rv.tolist()
        s = np.float64(math.sqrt(x * x + y * y + z * z))
    else:
        s = np.linalg.norm(rv, axis=-1)[..., None, None]
    small = s < 1e-4
    safe = np.where(small, 1.0, s)
    a = np.where(small, 1.0 - s**2 / 6.0 + s**4 / 120.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - s**2 / 24.0 + s**4 / 720.0, (1.0 - np.cos(safe)) / safe**2)
    bm = skew(rv)
    return _EYE3 + a * bm + b * (bm @ bm)


def orthonormalize(c):
    """One symmetric (Bjorck) step ``C <- C - C (C^T C - I) / 2`` towards the nearest rotation."""
    c = _arr(c, "c", (3, 3))
    return c - 0.5 * c @ (np.swapaxes(c, -1, -2) @ c - np.eye(3))


def wrap_angle(a: float) -> float:
    """A scalar angle (rad) in (-pi, pi]."""
    while a > np.pi:
        a -= 2.0 * np.pi
    while a <= -np.pi:
        a += 2.0 * np.pi
    return a
