"""The almost-inertial inclination correction (``inertial-tilt``, a factor corrector).

The estimator integrates the gyroscope alone, from the body to an "almost inertial" frame I
(``q_gyr``; nothing corrects it). This corrector keeps the factor ``q_tilt`` from I to a levelled
frame and composes the output ``q_tilt (x) q_gyr``:

- the specific force is rotated into I and low-passed there (second-order Butterworth, time
  constant ``tau``). In I, gravity is a constant (up to the slow gyro drift) and linear
  accelerations integrate to velocity changes, which average out: the low-passed vector is
  gravity, free of the lag a body-frame low-pass has under rotation;
- each sample ``q_tilt`` is turned by the smallest rotation (about a horizontal axis) that makes
  the low-passed vector vertical (the pipeline frame's up).

Options, each a separate idea:

- **fast start** (``fast_start``): for the first ``tau`` s the low-pass is replaced by the running
  mean of the samples so far (from the first sample on, no start transient); off: the low-pass
  starts in the steady state of the first sample;
- **bias in motion** (``motion_bias_tau``): the correction, turned into a rate, is the gyro's drift
  on the horizontal axes; the pipeline's gyro bias integrates it (seen in the body) with this time
  constant (slow: linear accelerations must average out), limited to ``bias_max``; not on REST
  samples (the ``rest-bias-lowpass`` corrector learns there);
- **sensor pairing** (``acc_delay``): the gyro's step k covers ``(t[k-1], t[k]]``; an accelerometer
  sampled like the gyro describes its middle, so by default (None) the sample is rotated into I
  with ``q_gyr (x) exp(-w dt / 2)``; 0 pairs it with the end of the step; a larger value serves an
  accelerometer later than the gyroscope (``q_gyr (x) exp(-(w - bias) d)``).

After a timestamp gap or a saturated gyro (``restarts``) the low-pass starts again: the gravity
seen in I before is stale. A sample without a valid accelerometer reading (or one the
``acceleration`` detector rejected) leaves the factor as it is.

Assumes: the linear accelerations average out over ``tau`` in I (true of motion that starts and
ends at rest, not of a sustained acceleration like a car's), and the gyro drifts slowly against
``tau``. The readable reference is :meth:`InertialTilt.compose`; :func:`inertial_tilt_kernel`
does the same arithmetic (tests: 1e-9 on every sample).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import CorrectorKernel, FactorCorrector
from ..rotations import quat_mul, quat_to_matrix
from ..types import Flag
from ._factor import bias_step, frame_axes, k_bias_step, k_paired, k_qmul, k_rot, paired

__all__ = ["InertialTiltConfig", "InertialTilt", "inertial_tilt_kernel", "lowpass_coefficients"]

# state: q_tilt, the low-pass's two delay lines, the fast start's mean and count, seconds seen, ready,
# the low-passed vector, the frame's up and east axes, and the coefficients for the last dt
_QA, _Z1, _Z2, _MEAN, _NMEAN, _TACC, _READY, _Y = 0, 4, 7, 10, 13, 14, 15, 16
_UP, _EAST, _DT, _B = 19, 22, 25, 26  # _B: b0, b1, b2, a1, a2
_SIZE = 31
_REST = int(Flag.REST)


def lowpass_coefficients(tau: float, dt: float) -> tuple[float, float, float, float, float]:
    """Second-order Butterworth low-pass (bilinear transform, cutoff ``1 / (2 pi tau)``):
    ``(b0, b1, b2, a1, a2)`` of ``y = b0 x + b1 x' + b2 x'' - a1 y' - a2 y''``; unit gain at DC."""
    k = math.tan(0.5 * dt / tau)
    n = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * n
    return b0, 2.0 * b0, b0, 2.0 * (k * k - 1.0) * n, (1.0 - math.sqrt(2.0) * k + k * k) * n


_lp_coeffs = njit(lowpass_coefficients)


class InertialTiltConfig(PluginConfig):
    tau: float = param(2.0, unit="s", description="time constant of the inclination low-pass (in the almost-inertial "
                       "frame)", gt=0)
    fast_start: bool = param(True, unit="-", description="the running mean instead of the low-pass for the first "
                             "tau s")
    motion_bias_tau: float | None = param(
        100.0, unit="s", description="time constant of the bias estimation in motion (the correction is the "
        "horizontal gyro drift); None: off", gt=0)
    bias_max: float = param(math.radians(2.0), unit="rad/s", description="largest bias estimated in motion", gt=0)
    acc_delay: float | None = param(
        None, unit="s", description="how long before the end of the gyro's step the accelerometer sample describes. "
        "None: half the sample interval (the middle of the step); 0: the end of the step; larger: an accelerometer "
        "later than the gyroscope")


class InertialTilt(FactorCorrector):
    """Inclination from the specific force low-passed in the almost-inertial frame (a factor)."""

    name: ClassVar[str] = "inertial-tilt"
    Config = InertialTiltConfig
    restarts: ClassVar[bool] = True
    source: ClassVar[str] = "fusionkit (source 002's channel separation; low-pass in the inertial frame)"
    summary: ClassVar[str] = "inclination factor: the accelerometer low-passed in the almost-inertial frame"

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        s = np.zeros(_SIZE)
        s[_QA] = 1.0
        axes = frame_axes(frame)
        s[_UP:_UP + 3], s[_EAST:_EAST + 3] = axes[6:9], axes[0:3]
        return s

    def restart(self, state: np.ndarray) -> None:
        """The low-pass starts again (the fast start's running mean, or the next sample)."""
        state[_READY] = state[_NMEAN] = state[_TACC] = 0.0
        state[_MEAN:_MEAN + 3] = 0.0

    def compose(self, state, quat, sample, bias, rate, flags):
        if sample.acc is not None:
            qg = paired(quat, self.config.acc_delay, rate, sample.gyr, bias, sample.dt)
            self._tilt(state, quat_to_matrix(qg) @ sample.acc, quat, bias, sample.dt, bool(flags & _REST))
        return quat_mul(state[_QA:_QA + 4], quat), 0

    def _tilt(self, x, a_i, quat, bias, dt, rest) -> None:
        c = self.config
        y = x[_Y:_Y + 3]
        x[_TACC] += dt
        # durations are sums of dt compared with half a sample of margin (a split run equals one run)
        if c.fast_start and not x[_READY] and x[_TACC] + 0.5 * dt < c.tau:
            x[_NMEAN] += 1.0  # fast start: the running mean of the samples so far
            x[_MEAN:_MEAN + 3] += (a_i - x[_MEAN:_MEAN + 3]) / x[_NMEAN]
            y[:] = x[_MEAN:_MEAN + 3]
        else:
            if x[_DT] != dt:
                x[_DT], x[_B:_B + 5] = dt, lowpass_coefficients(c.tau, dt)
            b0, b1, b2, a1, a2 = x[_B:_B + 5]
            z1, z2 = x[_Z1:_Z1 + 3], x[_Z2:_Z2 + 3]
            if not x[_READY]:  # start in the steady state of the mean (or of the first sample)
                start = x[_MEAN:_MEAN + 3] if x[_NMEAN] > 0 else a_i
                z1[:], z2[:] = start * (1.0 - b0), start * (b2 - a2)
                x[_READY] = 1.0
            y[:] = b0 * a_i + z1  # transposed direct form II
            z1[:] = b1 * a_i - a1 * y + z2
            z2[:] = b2 * a_i - a2 * y
        # the smallest rotation taking the low-passed vector (levelled frame) to the vertical
        up = x[_UP:_UP + 3]
        v = quat_to_matrix(x[_QA:_QA + 4]) @ y
        v = v / np.linalg.norm(v)
        qc = np.array([1.0 + v @ up, *np.cross(v, up)])
        n = np.linalg.norm(qc)
        qc = qc / n if n > 1e-12 else np.array([0.0, *x[_EAST:_EAST + 3]])
        x[_QA:_QA + 4] = quat_mul(qc, x[_QA:_QA + 4])
        if c.motion_bias_tau is not None and not rest and x[_READY]:
            # the correction as a rate in the levelled frame is the gyro drift; seen in the body,
            # it is the (horizontal part of the) bias error
            s = float(np.linalg.norm(qc[1:]))
            if s > 0.0:
                r_level = qc[1:] * (2.0 * math.atan2(s, qc[0]) / (s * dt))
                bias_step(bias, r_level, quat_mul(x[_QA:_QA + 4], quat), dt, c.motion_bias_tau, c.bias_max)

    def kernel(self, estimator) -> CorrectorKernel:
        c = self.config
        p = np.array([c.tau, float(c.fast_start), c.acc_delay if c.acc_delay is not None else math.nan,
                      c.motion_bias_tau if c.motion_bias_tau is not None else 0.0, c.bias_max])
        return CorrectorKernel(inertial_tilt_kernel, p, mode="factor")


@njit(inline="always")
def inertial_tilt_kernel(q, s, b, g0, g1, g2, h0, h1, h2, h3, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p):
    """The kernel of :meth:`InertialTilt.compose`: ``p = (tau, fast_start, acc_delay (NaN: None),
    motion_bias_tau (0: off), bias_max)``."""
    if acc_ok:
        p0, p1, p2, p3 = k_paired(q, p[2], h0, h1, h2, h3, g0, g1, g2, b, dt)
        v0, v1, v2 = k_rot(p0, p1, p2, p3, a0, a1, a2)
        s[_TACC] += dt
        if p[1] != 0.0 and s[_READY] == 0.0 and s[_TACC] + 0.5 * dt < p[0]:
            s[_NMEAN] += 1.0
            s[_MEAN] += (v0 - s[_MEAN]) / s[_NMEAN]
            s[_MEAN + 1] += (v1 - s[_MEAN + 1]) / s[_NMEAN]
            s[_MEAN + 2] += (v2 - s[_MEAN + 2]) / s[_NMEAN]
            s[_Y], s[_Y + 1], s[_Y + 2] = s[_MEAN], s[_MEAN + 1], s[_MEAN + 2]
        else:
            if s[_DT] != dt:
                s[_DT] = dt
                s[_B], s[_B + 1], s[_B + 2], s[_B + 3], s[_B + 4] = _lp_coeffs(p[0], dt)
            b0, b1, b2, c1, c2 = s[_B], s[_B + 1], s[_B + 2], s[_B + 3], s[_B + 4]
            if s[_READY] == 0.0:  # start in the steady state of the mean (or of the first sample)
                t0, t1, t2 = (s[_MEAN], s[_MEAN + 1], s[_MEAN + 2]) if s[_NMEAN] > 0 else (v0, v1, v2)
                s[_Z1], s[_Z1 + 1], s[_Z1 + 2] = t0 * (1.0 - b0), t1 * (1.0 - b0), t2 * (1.0 - b0)
                s[_Z2], s[_Z2 + 1], s[_Z2 + 2] = t0 * (b2 - c2), t1 * (b2 - c2), t2 * (b2 - c2)
                s[_READY] = 1.0
            y0, y1, y2 = b0 * v0 + s[_Z1], b0 * v1 + s[_Z1 + 1], b0 * v2 + s[_Z1 + 2]
            s[_Y], s[_Y + 1], s[_Y + 2] = y0, y1, y2
            s[_Z1], s[_Z1 + 1], s[_Z1 + 2] = (b1 * v0 - c1 * y0 + s[_Z2], b1 * v1 - c1 * y1 + s[_Z2 + 1],
                                              b1 * v2 - c1 * y2 + s[_Z2 + 2])
            s[_Z2], s[_Z2 + 1], s[_Z2 + 2] = b2 * v0 - c2 * y0, b2 * v1 - c2 * y1, b2 * v2 - c2 * y2
        v0, v1, v2 = k_rot(s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3], s[_Y], s[_Y + 1], s[_Y + 2])
        n = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        v0, v1, v2 = v0 / n, v1 / n, v2 / n
        u0, u1, u2 = s[_UP], s[_UP + 1], s[_UP + 2]
        c0, c1, c2, c3 = 1.0 + v0 * u0 + v1 * u1 + v2 * u2, v1 * u2 - v2 * u1, v2 * u0 - v0 * u2, v0 * u1 - v1 * u0
        n = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2 + c3 * c3)
        if n > 1e-12:
            c0, c1, c2, c3 = c0 / n, c1 / n, c2 / n, c3 / n
        else:
            c0, c1, c2, c3 = 0.0, s[_EAST], s[_EAST + 1], s[_EAST + 2]
        t0, t1, t2, t3 = k_qmul(c0, c1, c2, c3, s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3])
        s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3] = t0, t1, t2, t3
        e0, e1, e2, e3 = k_qmul(t0, t1, t2, t3, q[0], q[1], q[2], q[3])  # the output (and the bias step's q6)
        if p[3] > 0.0 and (flags & _REST) == 0 and s[_READY] != 0.0:
            sn = math.sqrt(c1 * c1 + c2 * c2 + c3 * c3)
            if sn > 0.0:
                f = 2.0 * math.atan2(sn, c0) / (sn * dt)
                k_bias_step(b, e0, e1, e2, e3, c1 * f, c2 * f, c3 * f, dt / p[3], p[4])
        q[0], q[1], q[2], q[3] = e0, e1, e2, e3
        return 0
    q[0], q[1], q[2], q[3] = k_qmul(s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3], q[0], q[1], q[2], q[3])
    return 0
