"""The accelerometer's lever arm from the rotation centre, estimated online (a sensor model).

An accelerometer at ``r`` (body frame) from the point the body rotates about reads

``f = R^T (a_c - g) + w_dot x r + w x (w x r) = R^T (a_c - g) + K r``,  ``K = [w_dot]x + [w]x^2``

(``a_c`` the centre's acceleration, ``R`` body -> earth). A sensor turned by hand about the wrist
or the elbow feels the rotation's tangential and centripetal accelerations (of order 1-3 m/s^2
in fast turns). They are correlated with the rotation itself, so they do not average out in an
inclination low-pass, even one in the almost-inertial frame (``recommended``'s). Both ``w`` and
``w_dot`` are known from the gyroscope, so ``r`` (three numbers) is linearly identifiable:

- the model integrates the gyroscope alone into its own almost-inertial frame I (a strapdown
  from the raw rate; its slow drift does not matter, see below) and rotates the sample and ``K``
  there, ``y = R f``, ``P = R K``;
- in I, gravity is a constant: the high-pass of both (``y - lowpass(y)``, a first-order
  low-pass of time constant ``hp_tau``) removes it, the drift of I and the accelerometer's bias,
  and leaves ``y_h = P_h r + (a_c)_h`` (the same linear filter on both sides keeps the equation);
- ``r`` is the least-squares fit of ``y_h`` on ``P_h``, with exponential forgetting
  (``forget_time``: a grip that changes is learned again); the centre's own acceleration is the
  fit's noise.

**Confidence** (as ``mag-calibration``'s). The information matrix ``A = sum P_h^T P_h`` says how
well each direction of ``r`` is known: a rotation about one axis says nothing about ``r`` along
it, a pure translation nothing at all. The estimate's standard deviation is
``sigma sqrt(hp_tau / dt) / sqrt(lambda_min(A))``: ``sigma`` the fit's residual noise per axis
(from the fit itself), and the residual counted as one independent value per ``hp_tau``
(the high-passed centre acceleration is correlated over about that long; counting every sample
would overstate the information by that factor). The fit is applied, ``f - K r``, only while
that is below ``max_std`` and at least ten such independent values entered; otherwise the
sample passes unchanged (no lever arm is better than a wrong one).

**Timing and noise.** The gyro's sample ``k`` and the accelerometer's describe the middle of the
step ``(t[k-1], t[k]]`` (fusionkit's pairing; ``recommended``'s ``acc_delay`` default): the
sample is rotated with the strapdown at that middle, ``w`` is the gyro sample, and ``w_dot`` the
difference to the gyro sample ``n`` back over the distance of their middles, ``n`` samples
spanning ``rate_diff_time`` (20 ms). A one-sample difference would put the gyro's white noise,
times ``1/dt``, into every corrected sample, at rest too (0.4 m/s^2 for 30 cm on a MEMS gyro
at 200 Hz: enough to hide rests from a rest detector); hand motion has nothing above about
20 Hz, so the longer span loses nothing there and divides that noise by ``n``. It describes the
time ``n dt / 2`` before the sample's: a phase of ``pi f n dt`` at the motion's frequency ``f``
(0.13 rad at 2 Hz). In I, ``R K r`` is the second derivative of ``R r``: a shift of the
correction only shifts what the inclination low-pass sees by as much.

Assumes: a rigid body turning about a point that moves less than the lever arm turns (the rest
of the centre's motion is the fit's noise and only widens its standard deviation); the
accelerometer's scale and the gyro's scale correct (errors there enter ``r``). The model reads
only the IMU's own samples, never the filter's orientation. The readable reference is
:meth:`LeverArmModel.apply`; :func:`lever_arm_apply` is its kernel (tests: 1e-9).
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
from ..types import GYR_LIMIT
from .mag_calibration import _inverse3, _k_inverse3, _k_min_eig, _min_eig_sym3, k_forget_accumulate

__all__ = ["LeverArmConfig", "LeverArmModel", "lever_arm_apply", "STATE", "LEVER", "BEST", "STD", "CONF"]

# state layout: own strapdown quaternion (end of the last step), the time at its end, how many gyro
# samples the ring buffer holds, where the next goes, the difference's span (samples), the
# low-passes of y and P (and whether they started), the forgetting sums (A, P_h^T y_h, |y_h|^2,
# weights), the fit, the applied lever arm, its standard deviation, confident; then the ring buffer
# of the last gyro samples and their middles' times
_Q, _TIME, _CNT, _HEAD, _NWIN, _LY, _LP, _LOK = 0, 4, 5, 6, 7, 8, 11, 20
_A, _BV, _YY, _NE = 21, 30, 33, 34
BEST, LEVER, STD, CONF = 35, 38, 41, 42  #: the fit, the applied lever arm (m, body), its std (m), confident
_BUF, _CAP = 43, 16  # (g0, g1, g2, t_mid) per entry
STATE = _BUF + 4 * _CAP

#: independent residual values (one per hp_tau) before the fit's noise estimate is trusted
_MIN_INDEPENDENT = 10.0
#: A's smallest eigenvalue must exceed this fraction of its trace for the fit to be solved
_COND = 1e-9


class LeverArmConfig(PluginConfig):
    hp_tau: float = param(1.0, unit="s", description="time constant of the high-pass in the almost-inertial frame "
                          "(removes gravity, the frame's drift, the accelerometer bias)", gt=0)
    forget_time: float = param(30.0, unit="s", description="time constant with which old samples are forgotten "
                               "(a changed grip is learned again)", gt=0)
    max_std: float = param(0.02, unit="m", description="apply the fit once its standard deviation is below this",
                           gt=0)
    rate_diff_time: float = param(
        0.02, unit="s", description="w_dot is the gyro's difference over this span (rounded to whole samples, 1-15): "
        "hand motion has nothing above ~20 Hz, and the difference's noise falls as the span grows", gt=0)


def _skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class LeverArmModel(SensorModel):
    """Learns where the accelerometer sits from the rotation centre and removes the rotation's
    tangential and centripetal accelerations."""

    name: ClassVar[str] = "lever-arm"
    Config = LeverArmConfig
    source: ClassVar[str] = ("fusionkit (rigid-body kinematics: a point at r feels w_dot x r + w x (w x r); "
                             "r fitted by least squares in the almost-inertial frame)")
    summary: ClassVar[str] = "online accelerometer lever arm from the gyro; its rotational acceleration removed"

    def initial_state(self, dt: float) -> np.ndarray:
        s = np.zeros(STATE)
        s[_Q] = 1.0
        s[STD] = math.inf
        s[_NWIN] = min(max(round(self.config.rate_diff_time / dt), 1), _CAP - 1)
        return s

    def params(self) -> np.ndarray:
        c = self.config
        return np.array([c.hp_tau, c.forget_time, c.max_std])

    def kernel(self) -> SensorModelKernel:
        return SensorModelKernel(lever_arm_apply, self.params())

    def report(self, state: np.ndarray) -> dict:
        """The lever arm the fit holds at the end of a run (``Result.diagnostics["models"]["lever-arm"]``):

        - ``lever_arm_m``: ``r`` (m, the body axes of the recording: the accelerometer's position from
          the rotation centre), NaN while the fit is not solved (too little rotation, about one axis
          only, or fewer than ten ``hp_tau`` of samples);
        - ``std_m``: its standard deviation per body axis (m), inf while not solved;
        - ``std_max_m``: along its least-known direction (m), the one compared with ``max_std``;
        - ``confident`` / ``applied``: whether it is below ``max_std``, so subtracted (``f - K r``)
          from the accelerometer (the model applies the fit exactly while confident)."""
        s = state
        std = float(s[STD])
        a, inv = s[_A:_A + 9].reshape(3, 3), np.empty((3, 3))
        if math.isfinite(std) and _inverse3(a, inv):
            lever = s[BEST:BEST + 3].copy()
            # std = sqrt(X / lambda_min(A)) with X the residual variance per independent value: per axis,
            # sqrt(X (A^-1)_ii) = std sqrt(lambda_min (A^-1)_ii)
            axes = std * np.sqrt(np.maximum(_min_eig_sym3(a) * np.diag(inv), 0.0))
        else:
            lever, axes = np.full(3, math.nan), np.full(3, math.inf)
        confident = bool(s[CONF])
        return {"lever_arm_m": lever, "std_m": axes, "std_max_m": std, "confident": confident, "applied": confident}

    def apply(self, state: np.ndarray, sample: Sample, quat: np.ndarray) -> tuple[Sample, int]:
        s, dt = state, sample.dt
        g = np.asarray(sample.gyr, dtype=float)
        t_mid = s[_TIME] + 0.5 * dt  # the middle of this step
        s[_TIME] += dt
        if not (np.isfinite(g).all() and float(np.abs(g).max()) <= GYR_LIMIT):
            s[_CNT] = 0.0  # no rate: no K, no derivative across this sample
            return sample, 0
        have = s[_CNT] >= 1.0
        if have:  # the difference to the sample _NWIN back (fewer after a start)
            j = int(min(s[_CNT], s[_NWIN]))
            old = _BUF + 4 * ((int(s[_HEAD]) - j) % _CAP)
            wdot = (g - s[old:old + 3]) / (t_mid - s[old + 3])
        else:
            wdot = np.zeros(3)
        new = _BUF + 4 * int(s[_HEAD])
        s[new:new + 3], s[new + 3] = g, t_mid
        s[_HEAD], s[_CNT] = (s[_HEAD] + 1.0) % _CAP, min(s[_CNT] + 1.0, _CAP)
        k = _skew(wdot) + _skew(g) @ _skew(g)
        half = quat_from_rotvec(g * (0.5 * dt))
        q_mid = quat_mul(s[_Q:_Q + 4], half)
        acc = sample.acc
        if acc is not None and have:
            rot = quat_to_matrix(q_mid)
            self._fit(s, rot @ acc, rot @ k, dt)
        q = quat_mul(q_mid, half)
        s[_Q:_Q + 4] = q / np.linalg.norm(q)
        if acc is None or not s[CONF]:
            return sample, 0
        return sample._replace(acc=acc - k @ s[LEVER:LEVER + 3]), 0

    def _fit(self, s, y, p, dt) -> None:
        """One sample into the forgetting least squares of ``y_h = P_h r``."""
        c = self.config
        if not s[_LOK]:  # the low-passes start at the first sample
            s[_LY:_LY + 3], s[_LP:_LP + 9], s[_LOK] = y, p.ravel(), 1.0
        a_lp = 1.0 - math.exp(-dt / c.hp_tau)
        s[_LY:_LY + 3] += a_lp * (y - s[_LY:_LY + 3])
        s[_LP:_LP + 9] += a_lp * (p.ravel() - s[_LP:_LP + 9])
        yh = y - s[_LY:_LY + 3]
        ph = p - s[_LP:_LP + 9].reshape(3, 3)
        lam = math.exp(-dt / c.forget_time)
        a = lam * s[_A:_A + 9].reshape(3, 3) + ph.T @ ph
        s[_A:_A + 9] = a.ravel()
        s[_BV:_BV + 3] = lam * s[_BV:_BV + 3] + ph.T @ yh
        s[_YY] = lam * s[_YY] + float(yh @ yh)
        s[_NE] = lam * s[_NE] + 1.0
        # solved once ten independent values entered and A is numerically invertible (a rotation
        # about one axis only, or none, leaves it singular: the fit is not defined there)
        lmin = _min_eig_sym3(a)
        inv = np.empty((3, 3))
        if (s[_NE] * dt / c.hp_tau >= _MIN_INDEPENDENT and lmin > _COND * (a[0, 0] + a[1, 1] + a[2, 2])
                and _inverse3(a, inv)):
            s[BEST:BEST + 3] = inv @ s[_BV:_BV + 3]
            # the residual per axis and sample, sum |y_h - P_h r|^2 = sum |y_h|^2 - b . r at the optimum
            var = max(s[_YY] - float(s[_BV:_BV + 3] @ s[BEST:BEST + 3]), 0.0) / (3.0 * s[_NE])
            s[STD] = math.sqrt(var * (c.hp_tau / dt) / lmin)
        else:
            s[STD] = math.inf
        s[CONF] = 1.0 if s[STD] <= c.max_std else 0.0
        s[LEVER:LEVER + 3] = s[BEST:BEST + 3] if s[CONF] else 0.0


@njit
def lever_arm_apply(s, v, gyr_ok, acc_ok, mag_ok, q, dt, p):
    """Kernel of :class:`LeverArmModel` (``SensorModelKernel.apply``): ``p = (hp_tau, forget_time,
    max_std)``."""
    t_mid = s[_TIME] + 0.5 * dt
    s[_TIME] += dt
    if not gyr_ok:
        s[_CNT] = 0.0
        return 0
    g0, g1, g2 = v[0], v[1], v[2]
    have = s[_CNT] >= 1.0
    if have:
        j = int(min(s[_CNT], s[_NWIN]))
        old = _BUF + 4 * ((int(s[_HEAD]) - j) % _CAP)
        h = t_mid - s[old + 3]
        d0, d1, d2 = (g0 - s[old]) / h, (g1 - s[old + 1]) / h, (g2 - s[old + 2]) / h
    else:
        d0, d1, d2 = 0.0, 0.0, 0.0
    new = _BUF + 4 * int(s[_HEAD])
    s[new], s[new + 1], s[new + 2], s[new + 3] = g0, g1, g2, t_mid
    s[_HEAD] = (s[_HEAD] + 1.0) % _CAP
    s[_CNT] = min(s[_CNT] + 1.0, _CAP)
    # K = [w_dot]x + [w]x^2, [w]x^2 = w w^T - |w|^2 I
    ww = g0 * g0 + g1 * g1 + g2 * g2
    k = np.empty((3, 3))
    k[0, 0], k[0, 1], k[0, 2] = g0 * g0 - ww, g0 * g1 - d2, g0 * g2 + d1
    k[1, 0], k[1, 1], k[1, 2] = g1 * g0 + d2, g1 * g1 - ww, g1 * g2 - d0
    k[2, 0], k[2, 1], k[2, 2] = g2 * g0 - d1, g2 * g1 + d0, g2 * g2 - ww
    e = np.empty(4)
    rotvec_quat(g0 * (0.5 * dt), g1 * (0.5 * dt), g2 * (0.5 * dt), e)
    qm = np.empty(4)
    qmul_into(s[_Q], s[_Q + 1], s[_Q + 2], s[_Q + 3], e[0], e[1], e[2], e[3], qm)
    if acc_ok and have:
        c9 = np.empty(9)
        quat_to_dcm(qm, c9)
        y = np.empty(3)
        pk = np.empty((3, 3))
        for i in range(3):
            y[i] = c9[3 * i] * v[3] + c9[3 * i + 1] * v[4] + c9[3 * i + 2] * v[5]
            for j in range(3):
                pk[i, j] = c9[3 * i] * k[0, j] + c9[3 * i + 1] * k[1, j] + c9[3 * i + 2] * k[2, j]
        _k_fit(s, y, pk, dt, p[0], p[1], p[2])
    qn = np.empty(4)
    qmul_into(qm[0], qm[1], qm[2], qm[3], e[0], e[1], e[2], e[3], qn)
    n = math.sqrt(qn[0] * qn[0] + qn[1] * qn[1] + qn[2] * qn[2] + qn[3] * qn[3])
    s[_Q], s[_Q + 1], s[_Q + 2], s[_Q + 3] = qn[0] / n, qn[1] / n, qn[2] / n, qn[3] / n
    if acc_ok and s[CONF] != 0.0:
        r0, r1, r2 = s[LEVER], s[LEVER + 1], s[LEVER + 2]
        a0 = v[3] - (k[0, 0] * r0 + k[0, 1] * r1 + k[0, 2] * r2)
        a1 = v[4] - (k[1, 0] * r0 + k[1, 1] * r1 + k[1, 2] * r2)
        a2 = v[5] - (k[2, 0] * r0 + k[2, 1] * r1 + k[2, 2] * r2)
        v[3], v[4], v[5] = a0, a1, a2
    return 0


@njit
def _k_fit(s, y, pk, dt, hp_tau, forget, max_std):
    if s[_LOK] == 0.0:
        for i in range(3):
            s[_LY + i] = y[i]
        for i in range(9):
            s[_LP + i] = pk[i // 3, i % 3]
        s[_LOK] = 1.0
    a_lp = 1.0 - math.exp(-dt / hp_tau)
    yh = np.empty(3)
    ph = np.empty((3, 3))
    for i in range(3):
        s[_LY + i] += a_lp * (y[i] - s[_LY + i])
        yh[i] = y[i] - s[_LY + i]
    for i in range(9):
        s[_LP + i] += a_lp * (pk[i // 3, i % 3] - s[_LP + i])
        ph[i // 3, i % 3] = pk[i // 3, i % 3] - s[_LP + i]
    lam = math.exp(-dt / forget)
    a = np.empty((3, 3))
    k_forget_accumulate(s, _A, _BV, _YY, _NE, ph, yh, lam, a)
    lmin = _k_min_eig(a)
    inv = np.empty((3, 3))
    if s[_NE] * dt / hp_tau >= _MIN_INDEPENDENT and lmin > _COND * (a[0, 0] + a[1, 1] + a[2, 2]) and \
            _k_inverse3(a, inv):
        for i in range(3):
            s[BEST + i] = inv[i, 0] * s[_BV] + inv[i, 1] * s[_BV + 1] + inv[i, 2] * s[_BV + 2]
        rss = s[_YY] - (s[_BV] * s[BEST] + s[_BV + 1] * s[BEST + 1] + s[_BV + 2] * s[BEST + 2])
        var = max(rss, 0.0) / (3.0 * s[_NE])
        s[STD] = math.sqrt(var * (hp_tau / dt) / lmin)
    else:
        s[STD] = math.inf
    s[CONF] = 1.0 if s[STD] <= max_std else 0.0
    for i in range(3):
        s[LEVER + i] = s[BEST + i] if s[CONF] != 0.0 else 0.0
