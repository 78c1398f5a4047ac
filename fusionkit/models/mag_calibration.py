"""Online hard-iron calibration of the magnetometer, from the gyroscope (a sensor model).

A magnet or a magnetised part carried with the sensor adds a field fixed in the *body* frame:
the magnetometer reads ``m = R^T h + b`` (``R`` body -> earth, ``h`` the earth's field there,
``b`` the hard-iron offset). The earth's field, seen from a turning body, turns with the
gyroscope's rotation; the offset does not. Between two samples ``a`` and ``k`` the gyroscope says
the body turned by ``C`` (body a -> body k), so ``m_k - b = C^T (m_a - b)``, that is

``(I - C^T) b = m_k - C^T m_a``,

three equations linear in ``b``. Every time the body has turned by ``segment_angle`` since the
last anchor sample (or ``segment_time`` has passed), the model adds one such segment to a
least-squares estimate with exponential forgetting (``forget_time``) and starts a new segment.
``b`` is observable only across rotations about different axes: ``(I - C^T)`` is blind along the
rotation axis. The information matrix ``A = sum (I - C^T)^T (I - C^T)`` says how well each
direction is known; the estimate's standard deviation is ``sigma_e / sqrt(lambda_min(A))``, with
``sigma_e`` the segments' residual noise (estimated from the fit's own residuals). The estimate is applied
(``m - b``) only once that standard deviation is below ``max_std`` of the field's norm: a
confidence, not a sample count. Until then the samples pass unchanged.

What it does not take for an offset: a field fixed in the *earth* frame (a magnet on the desk,
a steel beam) changes ``h``, not the relation above (a constant ``h`` still turns with the body),
so it leaves ``b`` alone; the magnetic disturbance detector deals with it. Recovery: when the
segments stop fitting (a residual above ``outlier_sigma`` standard deviations in
``outlier_count`` segments in a row: the magnet moved), the estimate is forgotten and learned
again; the last confident offset is applied meanwhile.

Assumptions and limits: soft iron (a distortion matrix) is not modelled (a soft-iron error
leaves a residual in every segment, which ``sigma_e`` absorbs and the gate then demands more
rotation); the gyroscope's own bias turns ``C`` by ``bias * segment_time`` (small against the
segment angle); the magnetometer and gyroscope are taken to be sampled at the same times (a
magnetometer late by ``d`` seconds adds an error of ``|w| d`` per segment, which averages over
rotations in both directions). The readable reference is :meth:`MagCalibrationModel.apply`;
:func:`mag_calibration_apply` is its kernel.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .._kernels import qmul_into, quat_to_dcm, rotvec_quat
from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import Sample, SensorModel, SensorModelKernel
from ..rotations import quat_from_rotvec, quat_mul, quat_to_matrix

__all__ = ["MagCalibrationConfig", "MagCalibrationModel", "mag_calibration_apply", "STATE"]

# state layout
_B, _A, _Y, _MA, _DQ, _T, _ANCHOR, _VAR, _N, _CONF, _BAD, _BEST = 0, 3, 12, 15, 18, 22, 23, 24, 25, 26, 27, 28
_RR, _NE = 31, 32  # the weighted sum of |r|^2 and of the weights (the fit's residual noise)
STATE = 33


class MagCalibrationConfig(PluginConfig):
    segment_angle: float = param(
        0.35, unit="rad", description="close a segment when the body has turned this far since its start", gt=0)
    segment_time: float = param(2.0, unit="s", description="or when this long has passed", gt=0)
    forget_time: float = param(
        300.0, unit="s", description="time constant with which old segments are forgotten (a slowly changing offset)",
        gt=0)
    max_std: float = param(
        0.02, unit="-", description="apply the estimate once its standard deviation is below this fraction of the "
        "field's norm", gt=0)
    min_segments: int = param(8, unit="-", description="segments before the noise estimate is trusted", ge=2)
    outlier_sigma: float = param(
        6.0, unit="-", description="a segment whose residual exceeds this many standard deviations does not fit",
        gt=0)
    outlier_count: int = param(
        3, unit="-", description="this many misfits in a row: the offset changed, learn it again", ge=1)


class MagCalibrationModel(SensorModel):
    """Learns the body-fixed magnetometer offset from how the field turns against the gyroscope."""

    name: ClassVar[str] = "mag-calibration"
    Config = MagCalibrationConfig
    source: ClassVar[str] = "fusionkit (gyro-aided hard-iron estimation: the field turns with the body, the offset not)"
    summary: ClassVar[str] = "online hard-iron offset from gyro-propagated field directions, applied when confident"

    def initial_state(self, dt: float) -> np.ndarray:
        s = np.zeros(STATE)
        s[_DQ] = 1.0
        return s

    def params(self) -> np.ndarray:
        c = self.config
        return np.array([c.segment_angle, c.segment_time, c.forget_time, c.max_std, float(c.min_segments),
                         c.outlier_sigma, float(c.outlier_count)])

    def kernel(self) -> SensorModelKernel:
        return SensorModelKernel(mag_calibration_apply, self.params())

    def apply(self, state: np.ndarray, sample: Sample, quat: np.ndarray) -> tuple[Sample, int]:
        c, s = self.config, state
        gyr_ok = bool(np.isfinite(sample.gyr).all())
        if not gyr_ok:  # no rotation known: the segment cannot be closed
            s[_ANCHOR] = 0.0
        elif s[_ANCHOR]:  # the body's turn since the anchor, body a -> body k
            s[_DQ:_DQ + 4] = quat_mul(s[_DQ:_DQ + 4], quat_from_rotvec(sample.gyr * sample.dt))
            s[_T] += sample.dt
        if sample.mag is None:
            if s[_T] > 2.0 * c.segment_time:
                s[_ANCHOR] = 0.0
            return sample, 0
        m = np.asarray(sample.mag, dtype=float)
        if gyr_ok and s[_ANCHOR]:
            dq = s[_DQ:_DQ + 4]
            angle = 2.0 * math.atan2(math.sqrt(dq[1] ** 2 + dq[2] ** 2 + dq[3] ** 2), abs(dq[0]))
            if angle >= c.segment_angle or s[_T] >= c.segment_time:
                self._segment(s, quat_to_matrix(dq).T, m)
                s[_ANCHOR] = 0.0
        if gyr_ok and not s[_ANCHOR]:  # this sample starts the next segment
            s[_MA:_MA + 3] = m
            s[_DQ:_DQ + 4] = (1.0, 0.0, 0.0, 0.0)
            s[_T] = 0.0
            s[_ANCHOR] = 1.0
        return sample._replace(mag=m - s[_B:_B + 3]), 0

    def _segment(self, s, ct, m) -> None:
        """One closed segment: ``(I - C^T) b = m_k - C^T m_a`` into the forgetting least squares."""
        c = self.config
        h = np.eye(3) - ct
        r = m - ct @ s[_MA:_MA + 3]
        n = s[_N]
        e = r - h @ s[_BEST:_BEST + 3]
        e2 = float(e @ e) / 3.0
        if n >= c.min_segments and e2 > c.outlier_sigma ** 2 * s[_VAR]:
            s[_BAD] += 1.0
            if s[_BAD] >= c.outlier_count:  # the offset changed: forget it and learn again
                s[_A:_A + 9] = 0.0
                s[_Y:_Y + 3] = 0.0
                s[_N] = s[_VAR] = s[_CONF] = s[_BAD] = s[_RR] = s[_NE] = 0.0
            return
        s[_BAD] = 0.0
        lam = math.exp(-s[_T] / c.forget_time)
        a = lam * s[_A:_A + 9].reshape(3, 3) + h.T @ h
        s[_A:_A + 9] = a.ravel()
        s[_Y:_Y + 3] = lam * s[_Y:_Y + 3] + h.T @ r
        s[_RR] = lam * s[_RR] + float(r @ r)
        s[_NE] = lam * s[_NE] + 1.0
        s[_N] = n + 1.0
        best = _solve3(a, s[_Y:_Y + 3])
        if best is None:
            return
        s[_BEST:_BEST + 3] = best
        # the fit's residual noise per axis: sum |r - H b|^2 = sum |r|^2 - y . b at the optimum
        if s[_NE] > 1.0:
            s[_VAR] = max(s[_RR] - float(s[_Y:_Y + 3] @ best), 0.0) / (3.0 * (s[_NE] - 1.0))
        lmin = _min_eig_sym3(a)
        field = float(np.linalg.norm(m - best))
        if s[_N] >= c.min_segments and lmin > 0.0 and math.sqrt(s[_VAR] / lmin) <= c.max_std * field:
            s[_B:_B + 3] = best
            s[_CONF] = 1.0


def _inverse3(a, inv) -> bool:
    """``inv = a^-1`` by the adjugate, False (``inv`` untouched) for a singular ``a``; the same
    statements in the reference and, compiled, in the kernel."""
    det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
           + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
    if not abs(det) > 1e-12:
        return False
    inv[0, 0], inv[0, 1], inv[0, 2] = (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1], a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2],
                                       a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1])
    inv[1, 0], inv[1, 1], inv[1, 2] = (a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2], a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0],
                                       a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2])
    inv[2, 0], inv[2, 1], inv[2, 2] = (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0], a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1],
                                       a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])
    for i in range(3):
        for j in range(3):
            inv[i, j] /= det
    return True


def _solve3(a, y):
    """``a^-1 y`` (:func:`_inverse3`), or None for a singular ``a``."""
    inv = np.empty((3, 3))
    if not _inverse3(a, inv):
        return None
    return np.array([inv[i, 0] * y[0] + inv[i, 1] * y[1] + inv[i, 2] * y[2] for i in range(3)])


def _min_eig_sym3(a) -> float:
    """The smallest eigenvalue of a symmetric 3x3 matrix (closed form, trigonometric)."""
    p1 = a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2
    q = (a[0, 0] + a[1, 1] + a[2, 2]) / 3.0
    p2 = (a[0, 0] - q) ** 2 + (a[1, 1] - q) ** 2 + (a[2, 2] - q) ** 2 + 2.0 * p1
    if p2 <= 0.0:
        return q
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (a[0, 0] - q) / p, (a[1, 1] - q) / p, (a[2, 2] - q) / p
    b01, b02, b12 = a[0, 1] / p, a[0, 2] / p, a[1, 2] / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = max(-1.0, min(1.0, r))
    phi = math.acos(r) / 3.0
    return q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)


_k_min_eig = njit(_min_eig_sym3)
_k_inverse3 = njit(_inverse3)


@njit
def mag_calibration_apply(s, v, gyr_ok, acc_ok, mag_ok, q, dt, p):
    """Kernel of :class:`MagCalibrationModel` (``SensorModelKernel.apply``)."""
    seg_angle, seg_time, forget, max_std, min_seg, out_sigma, out_count = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    if not gyr_ok:
        s[_ANCHOR] = 0.0
    elif s[_ANCHOR] != 0.0:
        e = np.empty(4)
        rotvec_quat(v[0] * dt, v[1] * dt, v[2] * dt, e)
        qmul_into(s[_DQ], s[_DQ + 1], s[_DQ + 2], s[_DQ + 3], e[0], e[1], e[2], e[3], s[_DQ:_DQ + 4])
        s[_T] += dt
    if not mag_ok:
        if s[_T] > 2.0 * seg_time:
            s[_ANCHOR] = 0.0
        return 0
    m0, m1, m2 = v[6], v[7], v[8]
    if gyr_ok and s[_ANCHOR] != 0.0:
        w, x, y, z = s[_DQ], s[_DQ + 1], s[_DQ + 2], s[_DQ + 3]
        angle = 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))
        if angle >= seg_angle or s[_T] >= seg_time:
            _k_segment(s, m0, m1, m2, forget, max_std, min_seg, out_sigma, out_count)
            s[_ANCHOR] = 0.0
    if gyr_ok and s[_ANCHOR] == 0.0:
        s[_MA], s[_MA + 1], s[_MA + 2] = m0, m1, m2
        s[_DQ], s[_DQ + 1], s[_DQ + 2], s[_DQ + 3] = 1.0, 0.0, 0.0, 0.0
        s[_T] = 0.0
        s[_ANCHOR] = 1.0
    v[6], v[7], v[8] = m0 - s[_B], m1 - s[_B + 1], m2 - s[_B + 2]
    return 0


@njit
def _k_segment(s, m0, m1, m2, forget, max_std, min_seg, out_sigma, out_count):
    c9 = np.empty(9)
    quat_to_dcm(s[_DQ:_DQ + 4], c9)
    ct = np.empty((3, 3))  # R(dq)^T, as quat_to_matrix(dq).T
    for i in range(3):
        for j in range(3):
            ct[i, j] = c9[3 * j + i]
    h = -ct
    for i in range(3):
        h[i, i] += 1.0
    ma = (s[_MA], s[_MA + 1], s[_MA + 2])
    mm = (m0, m1, m2)
    r = np.empty(3)
    e = np.empty(3)
    for i in range(3):
        r[i] = mm[i] - (ct[i, 0] * ma[0] + ct[i, 1] * ma[1] + ct[i, 2] * ma[2])
    for i in range(3):
        e[i] = r[i] - (h[i, 0] * s[_BEST] + h[i, 1] * s[_BEST + 1] + h[i, 2] * s[_BEST + 2])
    n = s[_N]
    e2 = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) / 3.0
    if n >= min_seg and e2 > out_sigma * out_sigma * s[_VAR]:
        s[_BAD] += 1.0
        if s[_BAD] >= out_count:
            for i in range(9):
                s[_A + i] = 0.0
            s[_Y], s[_Y + 1], s[_Y + 2] = 0.0, 0.0, 0.0
            s[_N] = s[_VAR] = s[_CONF] = s[_BAD] = s[_RR] = s[_NE] = 0.0
        return
    s[_BAD] = 0.0
    lam = math.exp(-s[_T] / forget)
    a = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            a[i, j] = lam * s[_A + 3 * i + j] + (h[0, i] * h[0, j] + h[1, i] * h[1, j] + h[2, i] * h[2, j])
            s[_A + 3 * i + j] = a[i, j]
    for i in range(3):
        s[_Y + i] = lam * s[_Y + i] + (h[0, i] * r[0] + h[1, i] * r[1] + h[2, i] * r[2])
    s[_RR] = lam * s[_RR] + (r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    s[_NE] = lam * s[_NE] + 1.0
    s[_N] = n + 1.0
    inv = np.empty((3, 3))
    if not _k_inverse3(a, inv):
        return
    for i in range(3):
        s[_BEST + i] = inv[i, 0] * s[_Y] + inv[i, 1] * s[_Y + 1] + inv[i, 2] * s[_Y + 2]
    if s[_NE] > 1.0:
        rss = s[_RR] - (s[_Y] * s[_BEST] + s[_Y + 1] * s[_BEST + 1] + s[_Y + 2] * s[_BEST + 2])
        s[_VAR] = max(rss, 0.0) / (3.0 * (s[_NE] - 1.0))
    lmin = _k_min_eig(a)
    f0, f1, f2 = m0 - s[_BEST], m1 - s[_BEST + 1], m2 - s[_BEST + 2]
    field = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if s[_N] >= min_seg and lmin > 0.0 and math.sqrt(s[_VAR] / lmin) <= max_std * field:
        s[_B], s[_B + 1], s[_B + 2] = s[_BEST], s[_BEST + 1], s[_BEST + 2]
        s[_CONF] = 1.0
