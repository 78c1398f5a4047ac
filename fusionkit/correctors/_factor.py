"""Helpers shared by the factor correctors (``inertial-tilt``, ``mag-heading``, ``output-lead``):
the earth frame's axes, the orientation a sensor sample is paired with, the bias step, and their
scalar numba twins (no arrays allocated per sample).

A factor corrector works in the pipeline's earth frame through its axes (east, north, up seen in
that frame), so every frame runs the same arithmetic: the results of two frames differ by the
frame change only (tested to 1e-9).
"""

from __future__ import annotations

import math

import numpy as np

from .._kernels import qmul_entries as k_qmul  # ``p (x) q`` as four scalars
from .._kernels import rotvec_scalars as k_rotvec
from .._numba import njit
from ..conventions import frame_matrix
from ..rotations import quat_from_rotvec, quat_mul, quat_to_matrix

__all__ = ["frame_axes", "paired", "bias_step", "initial_attitude", "atan2_small"]


def frame_axes(frame: str) -> np.ndarray:
    """``[east, north, up]`` (9 numbers): the ENU axes written in ``frame``."""
    m = frame_matrix("ENU", frame)  # v_frame = m v_enu
    return np.concatenate([m[:, 0], m[:, 1], m[:, 2]]).astype(float)


def initial_attitude(frame: str) -> tuple[float, float, float, float]:
    """The start of a factor composition in ``frame``: the body's axes taken as ENU's (the
    estimator's quaternion is the frame change), so every frame gives the same physical start."""
    from ..conventions import change_frame

    return tuple(float(v) for v in change_frame(np.array([1.0, 0.0, 0.0, 0.0]), "ENU", frame))


def paired(quat, delay, rate, gyr, bias, dt):
    """The orientation a sensor sample belongs to when the estimator's step ended at ``quat``
    (``acc_delay`` / ``mag_delay``): ``delay`` None, the middle of the step,
    ``quat (x) exp(-rate dt / 2)`` (``rate``: what the estimator integrated); a number ``d``,
    ``quat (x) exp(-(gyr - bias) d)``; 0 or no valid gyro sample: ``quat``."""
    if not np.isfinite(rate).all():
        return quat
    if delay is None:
        return quat_mul(quat, quat_from_rotvec(-rate * (0.5 * dt)))
    if delay != 0.0:
        return quat_mul(quat, quat_from_rotvec(-(gyr - bias) * delay))
    return quat


@njit(inline="always")
def atan2_small(y, x) -> float:
    """``atan2(y, x)``; a small angle (``|y| < x / 10``) by the series of ``atan(t)`` to ``t^15``
    (relative error under 1e-17), arithmetic instead of a libm call: a correction's error, which
    is small once it has converged (compiled; the reference calls it too)."""
    if x > 0.0 and abs(y) < 0.1 * x:
        t = y / x
        u = t * t
        return t * (1.0 + u * (-1.0 / 3.0 + u * (0.2 + u * (-1.0 / 7.0 + u * (1.0 / 9.0 + u * (
            -1.0 / 11.0 + u * (1.0 / 13.0 + u * (-1.0 / 15.0))))))))
    return math.atan2(y, x)


def bias_step(bias, r_level, q6, dt, tau, bias_max) -> None:
    """A correction rate ``r_level`` (earth frame) is the gyro's drift: the bias takes it in, seen
    in the body, with time constant ``tau``, limited to ``bias_max`` (in place)."""
    bias -= (dt / tau) * (quat_to_matrix(q6).T @ r_level)
    nb = np.linalg.norm(bias)
    if nb > bias_max:
        bias *= bias_max / nb


# ---- scalar numba twins ------------------------------------------------------------------------

@njit(inline="always")
def k_rot(w, x, y, z, v0, v1, v2):
    """``R(q) v`` as three scalars (``R(q)^T v``: pass ``-x, -y, -z``)."""
    return ((1 - 2 * (y * y + z * z)) * v0 + 2 * (x * y - w * z) * v1 + 2 * (x * z + w * y) * v2,
            2 * (x * y + w * z) * v0 + (1 - 2 * (x * x + z * z)) * v1 + 2 * (y * z - w * x) * v2,
            2 * (x * z - w * y) * v0 + 2 * (y * z + w * x) * v1 + (1 - 2 * (x * x + y * y)) * v2)


@njit(inline="always")
def k_paired(q, delay, h0, h1, h2, h3, g0, g1, g2, b, dt):
    """:func:`paired` (``delay`` NaN for None) as four scalars; ``h = exp(-rate dt / 2)``, the step's
    way back to its middle (the pipeline computes it once per sample; NaN without a valid gyro)."""
    if not math.isfinite(h0):
        return q[0], q[1], q[2], q[3]
    if math.isnan(delay):
        return k_qmul(q[0], q[1], q[2], q[3], h0, h1, h2, h3)
    if delay != 0.0:
        d0, d1, d2, d3 = k_rotvec((b[0] - g0) * delay, (b[1] - g1) * delay, (b[2] - g2) * delay)
        return k_qmul(q[0], q[1], q[2], q[3], d0, d1, d2, d3)
    return q[0], q[1], q[2], q[3]


@njit(inline="always")
def k_clamp3(v, limit):
    """Scale the 3-vector ``v`` (in place) down to norm ``limit`` when it is longer (the square
    root only then: the squared norm against the squared limit)."""
    n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    if n2 > limit * limit:
        f = limit / math.sqrt(n2)
        v[0] *= f
        v[1] *= f
        v[2] *= f


@njit(inline="always")
def k_bias_step(b, q0, q1, q2, q3, r0, r1, r2, k, bias_max):
    """:func:`bias_step` with ``k = dt / tau``."""
    e0, e1, e2 = k_rot(q0, -q1, -q2, -q3, r0, r1, r2)
    b[0] -= k * e0
    b[1] -= k * e1
    b[2] -= k * e2
    k_clamp3(b, bias_max)


def gyro_lowpass(s, lw, seen, g, k) -> None:
    """The ``rest`` detector's gyro low-pass kept in ``s[lw:lw + 3]`` (``s[seen]`` counts the
    samples; the first one starts it): ``lw += k (g - lw)``."""
    if s[seen] == 0.0:
        s[lw:lw + 3] = g
    s[seen] += 1.0
    s[lw:lw + 3] += k * (g - s[lw:lw + 3])


@njit(inline="always")
def k_gyro_lowpass(s, lw, seen, g0, g1, g2, k):
    """:func:`gyro_lowpass` with scalars."""
    if s[seen] == 0.0:
        s[lw], s[lw + 1], s[lw + 2] = g0, g1, g2
    s[seen] += 1.0
    s[lw] += k * (g0 - s[lw])
    s[lw + 1] += k * (g1 - s[lw + 1])
    s[lw + 2] += k * (g2 - s[lw + 2])
