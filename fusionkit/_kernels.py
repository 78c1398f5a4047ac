"""Scalar numba kernels of the rotation math in :mod:`fusionkit.rotations` and of the alignment.

Private: plain floats and preallocated float64 arrays in, results written into ``out``; no
allocation, no Python objects. Each function mirrors a reference function (named in its
docstring) and ``tests/test_kernels.py`` compares the pair.
"""

from __future__ import annotations

import math

from ._numba import njit
from .types import ACC_LIMIT as _ACC_LIMIT, GYR_LIMIT as _GYR_LIMIT, HUGE as _HUGE, TINY as _TINY


@njit(inline="always")
def qmul_entries(p0, p1, p2, p3, q0, q1, q2, q3):
    """``p (x) q`` as four scalars (rotations.quat_mul): a kernel that keeps the product in
    registers (no store and reload of an array on its per-sample dependency chain)."""
    return (p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3, p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1, p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0)


@njit(inline="always")
def dcm_entries(w, x, y, z):
    """``R(q)`` (rotations.quat_to_matrix) as a row-major 9-tuple: a kernel that keeps the matrix
    in registers."""
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


@njit
def qmul_into(p0, p1, p2, p3, q0, q1, q2, q3, out):
    """``out = p (x) q`` (:func:`qmul_entries` stored)."""
    out[0], out[1], out[2], out[3] = qmul_entries(p0, p1, p2, p3, q0, q1, q2, q3)


@njit
def qnormalize(q):
    """Normalise the first four entries of ``q`` in place (rotations.quat_normalize)."""
    r = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])  # one division, not four
    q[0] *= r
    q[1] *= r
    q[2] *= r
    q[3] *= r


@njit(inline="always")
def rotvec_quat_exact_entries(r0, r1, r2):
    """Exact quaternion of a rotation vector as a tuple (rotations.quat_from_rotvec: the same
    operations, its series below 1e-8 rad)."""
    a = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    if a < 1e-8:
        k = 0.5 - a * a / 48.0
    else:
        k = math.sin(0.5 * a) / a
    return math.cos(0.5 * a), k * r0, k * r1, k * r2


@njit
def rotvec_quat(r0, r1, r2, out):
    """Exact quaternion of a rotation vector (rotations.quat_from_rotvec), stored in ``out[0:4]``."""
    out[0], out[1], out[2], out[3] = rotvec_quat_exact_entries(r0, r1, r2)


@njit(inline="always")
def rotvec_quat_entries(r0, r1, r2):
    """:func:`rotvec_quat` as a tuple, with a polynomial below 0.05 rad (its error under 1e-22,
    no square root or sine on the per-sample path), sin/cos above. The polynomial multiplies by
    the coefficients (a division by a constant that is no power of two stays a division: seven
    of them, each several times a multiplication's cost, in a call made a few times per sample)."""
    s2 = r0 * r0 + r1 * r1 + r2 * r2
    if s2 < 0.0025:
        x = 0.25 * s2  # (s/2)^2
        c = 1.0 - x * 0.5 + x * x * (1.0 / 24.0) - x * x * x * (1.0 / 720.0) + x * x * x * x * (1.0 / 40320.0)
        k = 0.5 * (1.0 - x * (1.0 / 6.0) + x * x * (1.0 / 120.0) - x * x * x * (1.0 / 5040.0)
                   + x * x * x * x * (1.0 / 362880.0))
    else:
        s = math.sqrt(s2)
        c = math.cos(0.5 * s)
        k = math.sin(0.5 * s) / s
    return c, k * r0, k * r1, k * r2


@njit
def quat_to_dcm(q, c):
    """Row-major rotation matrix of ``q`` into ``c[0:9]`` (rotations.quat_to_matrix; :func:`dcm_entries` stored)."""
    c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8] = dcm_entries(q[0], q[1], q[2], q[3])


@njit
def dcm_to_quat(c, out):
    """Unit quaternion (w >= 0) of the row-major matrix ``c[0:9]`` (rotations.matrix_to_quat)."""
    r00, r01, r02 = c[0], c[1], c[2]
    r10, r11, r12 = c[3], c[4], c[5]
    r20, r21, r22 = c[6], c[7], c[8]
    tr = r00 + r11 + r22
    if tr >= max(r00, max(r11, r22)):
        s = 2.0 * math.sqrt(1.0 + tr)
        out[0] = 0.25 * s
        out[1] = (r21 - r12) / s
        out[2] = (r02 - r20) / s
        out[3] = (r10 - r01) / s
    elif r00 >= r11 and r00 >= r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        out[0] = (r21 - r12) / s
        out[1] = 0.25 * s
        out[2] = (r01 + r10) / s
        out[3] = (r02 + r20) / s
    elif r11 >= r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        out[0] = (r02 - r20) / s
        out[1] = (r01 + r10) / s
        out[2] = 0.25 * s
        out[3] = (r12 + r21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        out[0] = (r10 - r01) / s
        out[1] = (r02 + r20) / s
        out[2] = (r12 + r21) / s
        out[3] = 0.25 * s
    if out[0] < 0:
        out[0] = -out[0]
        out[1] = -out[1]
        out[2] = -out[2]
        out[3] = -out[3]
    qnormalize(out)


@njit
def alignment_quat(a0, a1, a2, m0, m1, m2, use_mag, q_frame, out):
    """Body->frame alignment quaternion (navigation.alignment.alignment_quat).

    ``q_frame`` rotates NUE into the target frame; ``use_mag`` != 0 takes the heading from the
    magnetometer ``m``.
    """
    theta = math.atan2(a0, math.sqrt(a1 * a1 + a2 * a2))
    gamma = math.atan2(-a2, a1)
    # q = q_z(theta) (x) q_x(gamma): the y (heading) rotation is identity for psi = 0
    ct, st = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cg, sg = math.cos(0.5 * gamma), math.sin(0.5 * gamma)
    q0 = ct * cg
    q1 = ct * sg
    q2 = st * sg
    q3 = st * cg
    if use_mag != 0:
        # magnetometer in NUE: R(q) m; heading rotation about Up by beta = atan2(m_E, m_N)
        mn = (1 - 2 * (q2 * q2 + q3 * q3)) * m0 + 2 * (q1 * q2 - q0 * q3) * m1 + 2 * (q1 * q3 + q0 * q2) * m2
        me = 2 * (q1 * q3 - q0 * q2) * m0 + 2 * (q2 * q3 + q0 * q1) * m1 + (1 - 2 * (q1 * q1 + q2 * q2)) * m2
        beta = math.atan2(me, mn)
        cb, sb = math.cos(0.5 * beta), math.sin(0.5 * beta)
        r0 = cb * q0 - sb * q2
        r1 = cb * q1 + sb * q3
        r2 = cb * q2 + sb * q0
        r3 = cb * q3 - sb * q1
        q0, q1, q2, q3 = r0, r1, r2, r3
    qmul_into(q_frame[0], q_frame[1], q_frame[2], q_frame[3], q0, q1, q2, q3, out)
    qnormalize(out)


@njit
def rodrigues_entries(r0, r1, r2):
    """The nine entries (row-major) of ``exp([r x]) = I + sin(s)/s B + (1 - cos s)/s^2 B^2``
    (rotations.rodrigues, source 004); Taylor series below 1e-4 rad. Returned as a tuple: no
    allocation in a loop."""
    s2 = r0 * r0 + r1 * r1 + r2 * r2
    s = math.sqrt(s2)
    if s < 1e-4:
        a = 1.0 - s2 / 6.0 + s2 * s2 / 120.0
        b = 0.5 - s2 / 24.0 + s2 * s2 / 720.0
    else:
        a = math.sin(s) / s
        b = (1.0 - math.cos(s)) / s2
    # B^2 = r r^T - s^2 I
    return (1.0 + b * (r0 * r0 - s2), -a * r2 + b * r0 * r1, a * r1 + b * r0 * r2,
            a * r2 + b * r0 * r1, 1.0 + b * (r1 * r1 - s2), -a * r0 + b * r1 * r2,
            -a * r1 + b * r0 * r2, a * r0 + b * r1 * r2, 1.0 + b * (r2 * r2 - s2))


@njit
def rodrigues_into(r0, r1, r2, out):
    """:func:`rodrigues_entries` written into ``out[0:9]``."""
    (out[0], out[1], out[2], out[3], out[4], out[5], out[6], out[7], out[8]) = rodrigues_entries(r0, r1, r2)


@njit
def matmul3_into(a, b, out):
    """``out = a @ b`` for row-major 3x3 matrices in flat arrays (out must not alias a or b)."""
    for i in range(3):
        for j in range(3):
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j]


@njit
def validity_flags(g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, gyr_range, acc_range):
    """:func:`fusionkit.types.sample_validity` with scalars (a range of ``inf``: none):
    ``(gyr_ok, acc_ok, mag_ok, flags)``."""
    gmax = max(abs(g0), max(abs(g1), abs(g2)))
    amax = max(abs(a0), max(abs(a1), abs(a2)))
    gyr_ok = math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2) and gmax <= _GYR_LIMIT
    acc_ok = math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2) and amax >= _TINY
    flags = 0
    if not gyr_ok:
        flags |= 4  # GYR_INVALID
    elif gmax >= gyr_range:
        flags |= 32  # GYR_SATURATED
    ranged = acc_range != math.inf
    if acc_ok and amax >= (acc_range if ranged else _ACC_LIMIT):
        acc_ok = False
        flags |= 64 if ranged else 8  # ACC_SATURATED, or ACC_INVALID (beyond ACC_LIMIT)
    elif not acc_ok:
        flags |= 8  # ACC_INVALID
    mag_ok = False
    if has_mag:
        mmax = max(abs(m0), max(abs(m1), abs(m2)))
        mag_ok = (math.isfinite(m0) and math.isfinite(m1) and math.isfinite(m2) and mmax >= _TINY
                  and mmax <= _HUGE)
        if not mag_ok:
            flags |= 16  # MAG_INVALID
    return gyr_ok, acc_ok, mag_ok, flags


@njit
def validity_all(gyr, acc, mag, has_mag, gyr_range, acc_range, ok, flags):
    """:func:`validity_flags` of every sample: ``ok[k] = (gyr_ok, acc_ok, mag_ok)``, ``flags[k]``."""
    for k in range(gyr.shape[0]):
        g, a, m, f = validity_flags(gyr[k, 0], gyr[k, 1], gyr[k, 2], acc[k, 0], acc[k, 1], acc[k, 2],
                                    mag[k, 0], mag[k, 1], mag[k, 2], has_mag, gyr_range, acc_range)
        ok[k, 0], ok[k, 1], ok[k, 2], flags[k] = g, a, m, f


@njit(inline="always")
def rotvec_scalars(r0, r1, r2):
    """:func:`rotvec_quat` returning four scalars (no output array)."""
    a = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    k = 0.5 - a * a / 48.0 if a < 1e-8 else math.sin(0.5 * a) / a
    return math.cos(0.5 * a), k * r0, k * r1, k * r2
