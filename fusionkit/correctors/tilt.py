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
  on the horizontal axes. ``bias_filter="kalman"`` (default) learns the pipeline's gyro bias from it
  as VQF does: the drift the inclination low-pass sees is the earth-frame bias error *low-passed*,
  so the measurement matrix is the low-passed rotation ``LP(R)``, and a covariance ``P`` weighs it
  (``motion_bias_tau`` is the forgetting time in which ``P`` regains ``bias_sigma_motion^2``; a REST
  sample shrinks ``P`` as a measurement of noise ``bias_sigma_rest``, None: not). ``"lowpass"`` (the
  behaviour before): the pipeline's bias integrates the rate, seen in the body with the sample's
  own R, with this time constant; not on REST samples. Both limit the bias to ``bias_max``;
- **sensor pairing** (``acc_delay``): the gyro's step k covers ``(t[k-1], t[k]]``; an accelerometer
  sampled like the gyro describes its middle, so by default (None) the sample is rotated into I
  with ``q_gyr (x) exp(-w dt / 2)``; 0 pairs it with the end of the step; a larger value serves an
  accelerometer later than the gyroscope (``q_gyr (x) exp(-(w - bias) d)``).

- **adaptive time constant** (``tau_adapt``, off here, on in ``recommended``): per sample the
  ``tau`` where the linear acceleration let through, ``sigma_v / (g tau)``, and the gyro error
  accumulated, ``d tau``, have the least sum of squares: ``tau = sqrt(sigma_v / (g d))`` within
  ``[tau_min, tau_max]`` (:func:`_adapt_step`: ``sigma_v`` measured from the specific force in I,
  ``d`` from the bias's uncertainty and ``gyro_rate_error`` times the net turn rate); ``tau`` is
  then the time constant of a still sensor. The low-passes' delay lines are scaled to each new
  coefficient set (docs/algorithms/recommended.md, "The adaptive time constant"); a set is kept
  until ``tau / dt`` moves by 0.1 % (``_TAU_STEP``: a numerical tolerance, far finer than the
  10 s statistics tau comes from resolve; computing the set and scaling the delay lines every sample
  put a tangent, divisions and 30 products on each sample's chain).

- **the low-pass at ``tau_max``** (``tau_max_parallel``, off; ``recommended``: on): with ``tau_adapt``, a
  second low-pass at ``tau_max`` runs from the start; when ``tau`` reaches ``tau_max`` the inclination low-pass takes its delay
  lines (:func:`_parallel_switch`): a rescaled low-pass keeps what the shorter ``tau`` let through at the
  onset of a sustained shaking. ``q_tilt`` takes the jump apart from the correction, so the bias filter does
  not read it as drift.

- **impulses** (``impulse_clip``, off by default; ``recommended``: 10): before the low-pass, the
  specific force's departure from the low-passed vector is limited to ``impulse_clip`` times its
  running RMS (:func:`_impulse_clip`, a Huber step whose scale learns from the limited departures over
  ``impulse_window``): a knock on the
  sensor, tens of g for a few ms that the sampled accelerometer does not integrate to the velocity the
  body got, then does not tilt the estimate for the next ``tau``.
- **what its inclination error is, for the correctors after it** (with ``tau_adapt``; the pipeline's
  channel, :class:`fusionkit.types.Channel`): the linear acceleration the low-pass lets through now
  as the tilt it makes, the bias's part of the drift over ``tau``, and ``tau`` (:func:`_publish`;
  ``mag-heading`` with ``inclination_noise`` reads them; written only where a corrector after it
  reads them, else the channel stays 0).
- **the gyro's rate error estimated** (``rate_error_estimate``, off; ``recommended``'s
  ``gyro_rate_estimate``): the symmetric part of the gyro's scale and misalignment matrix E,
  learned by a Kalman filter from what the bias filter leaves of the correction
  (:func:`_rate_error_step`); ``tau_adapt`` then uses it and its uncertainty instead of
  ``gyro_rate_error`` (which becomes its prior), and ``rate_error_correct`` also removes ``E w``
  from the next propagation (through the pipeline's bias, taken off again before the bias filter).
  ``rate_error_interval``: its Kalman update once per that many seconds of motion, not every sample
  (its measurement changes over the inclination's time constant; the noise scaled to keep the
  information per second). ``rate_error_acc_bias``: the accelerometer's bias estimated beside E (a
  body-fixed bias's tilt moves as the body turns, as a rate error's drift does), so that it is not
  taken for E; it is not removed from the accelerometer.
  ``bias_update_interval`` likewise for the bias filter's Kalman update (its low-passes and its
  covariance's growth run once per block of ``slow_interval``, every sample with 0). With blocks, both
  intervals are counted in whole blocks: an update comes at the first block end after the interval
  (0.05 s becomes 0.063 s, three blocks of 6 samples, at 286 Hz). The seconds of motion counted towards
  either's next update expire after a rest longer than four of the inclination's time constants (:func:`_carry`).
- **the slow estimators once per block** (``slow_interval``, 0: every sample; ``recommended``: 0.02 s; at most a
  tenth of the shortest time constant): the
  bias filter's low-passes of ``R`` and ``R b``, its covariance's growth and a REST sample's downdate, the
  rate error's regressor low-pass and covariance, and ``tau_adapt``'s statistics run once per block of that
  many seconds, on the block's last rotation (the rate error's regressor: its middle one, the midpoint rule
  for the block's mean of ``R w``) and its mean rates (the low-passes with coefficients for the
  block's time, :func:`_slow_set`; the covariances grown by it; a block's ``n`` REST samples one measurement
  of noise ``wr / n``). They change over seconds; the inclination low-pass, its correction and ``E w``
  stay per sample (docs/algorithms/recommended.md).

After a timestamp gap or a saturated gyro (``restarts``) the low-pass starts again: the gravity
seen in I before is stale. A sample without a valid accelerometer reading (or one the
``acceleration`` detector rejected) leaves the factor as it is.

Assumes: the linear accelerations average out over ``tau`` in I (true of motion that starts and
ends at rest, not of a sustained acceleration like a car's), and the gyro drifts slowly against
``tau`` (with ``tau_adapt``: at most at the bias's uncertainty plus ``gyro_rate_error`` of the net
turn rate; a gyro late against the accelerometer is not in that model). The readable reference is
:meth:`InertialTilt.compose`; :func:`inertial_tilt_kernel` does the same arithmetic (tests: 1e-9 on
every sample).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
from pydantic import field_validator, model_validator

from .._kernels import dcm_entries
from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import CorrectorKernel, FactorCorrector
from ..rotations import cross, quat_mul, quat_to_matrix
from ..types import Channel, Flag
from ._factor import bias_step, frame_axes, k_bias_step, k_clamp3, k_paired, k_qmul, k_rot, paired

__all__ = ["InertialTiltConfig", "InertialTilt", "inertial_tilt_kernel", "lowpass_coefficients", "RATE_ERROR",
           "RATE_KAPPA2"]

# state: q_tilt, the low-pass's two delay lines, the fast start's mean and count, seconds seen, ready,
# the low-passed vector, the frame's up and east axes, and the coefficients for the last dt
_QA, _Z1, _Z2, _MEAN, _NMEAN, _TACC, _READY, _Y = 0, 4, 7, 10, 13, 14, 15, 16
_UP, _EAST, _DT, _B = 19, 22, 25, 26  # _B: b0, b1, b2, a1, a2
# the bias filter (bias_filter "kalman"): the low-passed rotation matrix's and R bias's delay lines, the
# covariance P (3 x 3), whether the low-passes started, and its noise terms for the last dt (_kf_noise)
_RZ1, _RZ2, _BZ1, _BZ2, _P, _KREADY, _N = 31, 40, 49, 52, 55, 64, 65
# the adaptive time constant (tau_adapt): the velocity deviation (across the vertical, in I), the mean
# squares of that velocity and of the low-passed rate, the samples they average so far, the time constant
# now, the low-passed rate in I, and the bias's variance the rests tell
_VEL, _SV2, _SW2, _NST, _TAU, _WLP, _VR = 70, 73, 74, 75, 76, 77, 80
_TAUC = 81  # tau_adapt: tau / dt of the low-passes' coefficient set (0: none yet)
# impulse_clip: the mean square of the specific force's departure from the low-passed vector, the samples it averages
_IMS, _IMN = 82, 83
_IVAR = 84  # tau_adapt: the bias's part of the inclination error's variance about one horizontal axis at this tau
# the gyro's rate error estimated (rate_error_estimate): E's symmetric part (00, 11, 22, 01, 02, 12) and the
# accelerometer's bias it is told apart from (rate_error_acc_bias; x, y, z, m/s^2), their covariance (9 x 9), the
# regressor's low-pass delay lines (its east and north rows, 18 each), kappa^2 for tau_adapt, the delay lines'
# (1 - b0, b2 - a2) and whether the regressor's low-pass started
# and (rate_error_correct) the rate error E w the pipeline's bias carries for the next propagation
_NE = 9  # the rate error's states: E's 6 entries, then the accelerometer's bias (3)
_E, _PE, _HZ1, _HZ2, _KAP2, _ECO, _EREADY, _EW = 85, 94, 175, 193, 211, 212, 214, 215
_SCR = 218  # rate_error_estimate's working space for one sample (no allocation per sample in the compiled loop)
RATE_ERROR, RATE_KAPPA2 = _E, _KAP2  # where a run's state holds E and kappa^2 (the recommended filter's diagnostics)
# tau_adapt: the dt its per-sample factors are for, and those factors: min(dt / tau0, 1), dt / window, and the
# rests' variance's growth sigma_m^2 dt / forget (:func:`_adapt_step`: divisions once per distinct dt)
_ADT, _AF, _AK, _AV = _SCR + 54, _SCR + 55, _SCR + 56, _SCR + 57
# rate_error_interval: the seconds and the samples in motion since the rate error's last Kalman update
_ETACC, _ENACC = _SCR + 58, _SCR + 59
# bias_update_interval: the seconds and the samples in motion since the bias filter's last Kalman update (0, with
# slow_interval: those of blocks that ended at REST, for the next block's update)
_KTACC, _KNACC = _SCR + 60, _SCR + 61
# tau_max_parallel: the second low-pass's (at tau_max) delay lines, its coefficients for the last dt, whether it
# started, and whether the last sample's tau was tau_max
_PZ1, _PZ2, _PB, _PREADY, _PMAX = _SCR + 62, _SCR + 65, _SCR + 68, _SCR + 73, _SCR + 74
_BTAU = _SCR + 75  # the time constant of the inclination low-pass's coefficient set (_B)
# slow_interval: the block of samples since the last slow step (the bias filter's and the rate error's low-passes,
# covariances and updates run once per block): its seconds, its seconds and samples in motion, its REST samples,
# the rate error's seconds and samples in motion with a valid gyro, the body rate integrated over the samples with a
# valid gyro and their seconds (a mean weighted by time: dropped samples and jitter do not tilt it); then the slow
# low-passes' coefficient set (b0, b1, b2, a1, a2) and the block time and time constant it is for
_SLT, _SLM, _SLMN, _SLR, _SLE, _SLEN, _SLW, _SLWN = _SCR + 76, _SCR + 77, _SCR + 78, _SCR + 79, _SCR + 80, _SCR + 81, \
    _SCR + 82, _SCR + 85
_SB, _SBT, _SBTAU = _SCR + 86, _SCR + 91, _SCR + 92
# slow_interval with tau_adapt: the adaptive time constant's block: its seconds and samples, the specific force in I
# integrated over it, the valid rates in I integrated and their seconds, its REST samples (means weighted by time)
_ATT, _ATN, _AA, _AWS, _AWN, _AREST = _SCR + 93, _SCR + 94, _SCR + 95, _SCR + 98, _SCR + 101, _SCR + 102
# slow_interval with the rate error: the output at the block's middle (the regressor's rotation) and whether it is set
_SLQ, _SLQN = _SCR + 103, _SCR + 107
# bias_update_interval's carried motion (_KTACC, _KNACC): the seconds of the blocks ending at REST since it was carried;
# rate_error_interval's (_ETACC, _ENACC) likewise (:func:`_carry`)
_KAGE, _EAGE = _SCR + 108, _SCR + 109
_SIZE = _SCR + 110
# tau_adapt: a coefficient set is kept until tau / dt moves by this fraction of it (dt's rounding jitter does not)
_TAU_STEP = 1e-3
# the life of the motion carried to a decimated update across REST blocks, in inclination time constants: the
# measurement's second-order low-pass puts under 5 % of its weight on what is older than 4 of them (_carry)
_CARRY_LIFE = 4.0
_G_INV = 1.0 / 9.81  # rate_error_acc_bias: the accelerometer's bias as a tilt, 1 / g (m/s^2 -> rad)
_REST = int(Flag.REST)
_CH_VAR, _CH_TIME, _CH_LET = int(Channel.INCLINATION_VARIANCE), int(Channel.INCLINATION_TIME), int(Channel.LET_THROUGH)
_FORGET = 100.0  # tau_adapt without motion_bias_tau: the time in which the bias's variance grows by sigma_motion^2


def lowpass_coefficients(tau: float, dt: float) -> tuple[float, float, float, float, float]:
    """Second-order Butterworth low-pass (bilinear transform, cutoff ``1 / (2 pi tau)``):
    ``(b0, b1, b2, a1, a2)`` of ``y = b0 x + b1 x' + b2 x'' - a1 y' - a2 y''``; unit gain at DC."""
    x = 0.5 * dt / tau
    if x < 0.01:  # tan's series to x^9 (relative error under 1e-21), Estrin's grouping: tau_adapt's per-sample
        x2 = x * x  # chain from tau to the low-pass waits on it less than on libm's tan
        x4 = x2 * x2
        k = x + x * x2 * ((1.0 / 3.0 + x2 * (2.0 / 15.0)) + x4 * (17.0 / 315.0 + x2 * (62.0 / 2835.0)))
    else:
        k = math.tan(x)
    n = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * n
    return b0, 2.0 * b0, b0, 2.0 * (k * k - 1.0) * n, (1.0 - math.sqrt(2.0) * k + k * k) * n


_lp_coeffs = njit(lowpass_coefficients)


def _kf_noise(dt, forget, sigma_init, sigma_motion, sigma_rest, vertical):
    """The bias filter's noise for one sample of ``dt`` (VQF's parametrisation): the process noise
    ``v`` (variance ``sigma_motion^2`` gained in ``forget`` s), the measurement noises whose
    steady-state covariance is ``sigma_motion^2`` (horizontal), the vertical's (divided by
    ``vertical``), the rest's (``sigma_rest^2``; 0: none) and the covariance's ceiling. Computed
    once per distinct ``dt``, with the low-pass coefficients (state ``_N``)."""
    v = sigma_motion * sigma_motion * dt / forget
    pm, pr = sigma_motion * sigma_motion, sigma_rest * sigma_rest
    wm = pm * pm / v + pm
    return v, wm, wm / vertical, pr * pr / v + pr, sigma_init * sigma_init


_k_kf_noise = njit(inline="always")(_kf_noise)


def _adapt_step(x, a0, a1, a2, w0, w1, w2, z0, z1, z2, rest, dt, tau0, window, sigma_m, sigma_i, forget, kappa,
                tau_min, tau_max):
    """The time constant for this sample, or with ``slow_interval`` for this block (``tau_adapt``): state
    ``x``, the specific force ``a`` and the rate ``w`` in I (the block's means weighted by time; NaN
    without a valid gyro sample), the vertical ``z`` in the body, a REST sample (in the block), ``dt`` the
    sample's (the block's) seconds.

    The inclination error has two parts that a time constant trades: the linear acceleration the
    low-pass lets through, ``sigma_v / (g tau)`` (the low-passed derivative of a velocity that
    deviates by ``sigma_v`` from its mean), and the gyro drift the low-pass accumulates, ``d tau``.
    The sum of their squares is least at ``tau = sqrt(sigma_v / (g d))``, limited to ``[tau_min,
    tau_max]``. Across the vertical (the part that tilts), from the previous sample's low-passed
    vector: the specific force minus it is the linear acceleration; integrated with the leak
    ``tau0``, the velocity's deviation ``sigma_v`` (a velocity slower than ``tau0`` is not seen:
    ``tau_max`` a small multiple of it). The drift ``d^2 = sigma_b^2 + kappa^2 |LP(w)|^2``: the
    bias's uncertainty across the vertical, the bias filter's ``tr P - z^T P z`` and the rests'
    (``sigma_m^2`` per axis after a REST sample, growing by ``sigma_m^2`` in ``forget`` s up to
    ``sigma_i^2``) as independent informations; and the gyro's error proportional to the rate
    (scale factor, misalignment) of the rate in I low-passed with ``tau0``: the net turn, as a
    back-and-forth turn's error comes back with it. The mean squares are running means over the
    first ``window`` s, then exponential averages of that time constant. ``(sigma_b tau)^2 / 2`` at
    the ``tau`` returned is the bias's part of the inclination error's variance about one horizontal
    axis (state ``_IVAR``: what the corrector publishes as ``Channel.INCLINATION_VARIANCE``).

    Written for few divisions and square roots (the compiled loop is bound by them): the factors
    that depend on ``dt`` once per distinct ``dt`` (state ``_ADT``), ``tau^4`` as one quotient of
    squares (``g^2 = |y|^2``; one division and two square roots on the way to ``tau``), and the running
    mean's ``1 / n`` only while it is larger than ``dt / window``."""
    if x[_ADT] != dt:
        x[_ADT], x[_AF], x[_AK], x[_AV] = dt, min(dt / tau0, 1.0), dt / window, sigma_m * sigma_m * dt / forget
    x[_VR] = sigma_m * sigma_m if rest else min(x[_VR] + x[_AV], sigma_i * sigma_i)
    if x[_NST] == 0.0:  # no low-passed vector yet: the statistics start
        ok = math.isfinite(w0)
        x[_NST] = 1.0
        x[_SV2] = 0.0
        x[_VEL], x[_VEL + 1], x[_VEL + 2] = 0.0, 0.0, 0.0
        x[_WLP], x[_WLP + 1], x[_WLP + 2] = (w0, w1, w2) if ok else (0.0, 0.0, 0.0)
        x[_SW2] = w0 * w0 + w1 * w1 + w2 * w2 if ok else 0.0
        x[_TAU] = tau0
        return tau0
    y0, y1, y2 = x[_Y], x[_Y + 1], x[_Y + 2]
    yy = y0 * y0 + y1 * y1 + y2 * y2
    r0, r1, r2 = a0 - y0, a1 - y1, a2 - y2
    ru = (r0 * y0 + r1 * y1 + r2 * y2) / yy  # r's part along y without y / |y|: no square root on the chain
    f = x[_AF]
    x[_VEL] += (r0 - y0 * ru) * dt - x[_VEL] * f
    x[_VEL + 1] += (r1 - y1 * ru) * dt - x[_VEL + 1] * f
    x[_VEL + 2] += (r2 - y2 * ru) * dt - x[_VEL + 2] * f
    x[_NST] += 1.0
    n1 = x[_NST] - 1.0
    k = x[_AK] if n1 * x[_AK] >= 1.0 else 1.0 / n1  # max(dt / window, 1 / n1)
    x[_SV2] += (x[_VEL] * x[_VEL] + x[_VEL + 1] * x[_VEL + 1] + x[_VEL + 2] * x[_VEL + 2] - x[_SV2]) * k
    if math.isfinite(w0):
        x[_WLP] += (w0 - x[_WLP]) * f
        x[_WLP + 1] += (w1 - x[_WLP + 1]) * f
        x[_WLP + 2] += (w2 - x[_WLP + 2]) * f
        x[_SW2] += (x[_WLP] * x[_WLP] + x[_WLP + 1] * x[_WLP + 1] + x[_WLP + 2] * x[_WLP + 2] - x[_SW2]) * k
    ph = x[_P] + x[_P + 4] + x[_P + 8] - (x[_P] * z0 * z0 + x[_P + 4] * z1 * z1 + x[_P + 8] * z2 * z2
                                          + 2.0 * (x[_P + 1] * z0 * z1 + x[_P + 2] * z0 * z2 + x[_P + 5] * z1 * z2))
    ph = max(ph, 0.0)
    vr = 2.0 * x[_VR]  # (> 0: at least sigma_m^2)
    pv, ps = ph * vr, ph + vr  # db^2 = pv / ps
    # tau^4 = sv^2 / (g^2 d^2) with sv^2 = max(SV2, g^2 db^2 tau0^4), d^2 = db^2 + kappa^2 SW2, all over ps: one
    # division where sv / (g d) took two (db^2, then the quotient) and four square roots, two now
    den = yy * (pv + kappa * kappa * x[_SW2] * ps)
    if den > 0.0:
        t4 = max(x[_SV2] * ps, yy * pv * (tau0 * tau0) * (tau0 * tau0)) / den
        tau = min(max(math.sqrt(math.sqrt(t4)), tau_min), tau_max)
    else:
        tau = tau_max
    x[_TAU] = tau
    x[_IVAR] = 0.5 * (pv / ps) * tau * tau  # the bias's drift over tau about one horizontal axis (the channel's)
    return tau


_k_adapt_step = njit(inline="always")(_adapt_step)


def _publish(x, ch) -> None:
    """``tau_adapt``: what the inclination's error is now, for the correctors after this one (the
    pipeline's channel): the gyro bias's part of its variance about one horizontal axis (``_IVAR``:
    the uncertain bias drifting over ``tau``), the time constant, and the linear acceleration the
    low-pass lets through now, as the tilt it makes: the velocity deviation (``_VEL``, in I) over
    ``g tau``, in the levelled frame (``q_tilt``); the inclination error it causes is a rotation
    about ``up x`` it. The gyro's rate-proportional error (``gyro_rate_error``) is not published:
    a reader that weighs the inclination against the gyro (``mag-heading``) counts the gyro's
    errors on its own side with its own model, which has no rate error unless its
    ``scale_sigma`` says so; counted on one side only it tilts the balance (measured in
    docs/algorithms/recommended.md). The same statements in the reference and, compiled, in
    :func:`_k_publish`."""
    f = 1.0 / (math.sqrt(x[_Y] * x[_Y] + x[_Y + 1] * x[_Y + 1] + x[_Y + 2] * x[_Y + 2]) * x[_TAU])
    e0, e1, e2 = k_rot(x[_QA], x[_QA + 1], x[_QA + 2], x[_QA + 3], x[_VEL] * f, x[_VEL + 1] * f, x[_VEL + 2] * f)
    ch[_CH_VAR], ch[_CH_TIME] = x[_IVAR], x[_TAU]
    ch[_CH_LET], ch[_CH_LET + 1], ch[_CH_LET + 2] = e0, e1, e2


_k_publish = njit(inline="always")(_publish)


@njit(inline="always")
def _scale_slow_lines(x, f1, f2) -> None:
    """The bias filter's low-passes' (rotation and bias) delay lines scaled to a new coefficient set's
    steady state (``f1`` the first line's factor, ``f2`` the second's): :func:`_set_tau`, :func:`_slow_set`."""
    for i in range(3):
        x[_BZ1 + i] *= f1
        x[_BZ2 + i] *= f2
    for i in range(9):
        x[_RZ1 + i] *= f1
        x[_RZ2 + i] *= f2


def _set_tau(x, b0, b1, b2, a1, a2, every):
    """The low-passes' new coefficients (``tau_adapt``: this sample's ``tau`` and ``dt``). The
    transposed direct form's delay lines hold ``y (1 - b0)`` and ``y (b2 - a2)`` in the steady state:
    once the low-pass runs, they are scaled to the new coefficients' steady state, or a change of
    ``tau`` at a low cutoff (``a2`` moves by about ``sqrt(2) dt d(1/tau)``) would put a step into the
    output. ``every`` (``slow_interval`` 0): the bias filter's low-passes (rotation and bias) run every
    sample on this same set, and their delay lines are scaled with it (as before ``slow_interval``);
    with blocks they have their own set (:func:`_slow_set`)."""
    # (the old coefficients' reciprocals are ready before the new coefficients: a multiplication on the chain)
    f1 = (1.0 - b0) * (1.0 / (1.0 - x[_B])) if x[_READY] != 0.0 else 1.0
    f2 = (b2 - a2) * (1.0 / (x[_B + 2] - x[_B + 4])) if x[_READY] != 0.0 else 1.0
    x[_B], x[_B + 1], x[_B + 2], x[_B + 3], x[_B + 4] = b0, b1, b2, a1, a2
    for i in range(3):
        x[_Z1 + i] *= f1
        x[_Z2 + i] *= f2
    if every:
        _scale_slow_lines(x, f1, f2)


_k_set_tau = njit(inline="always")(_set_tau)


def _slow_set(x, t, b0, b1, b2, a1, a2):
    """The slow low-passes' new coefficients (``slow_interval``: the bias filter's rotation and bias
    low-passes, run once per block of ``t`` s, at the inclination low-pass's time constant ``_BTAU``):
    once they run, their delay lines are scaled to the new set's steady state, as :func:`_set_tau`
    does the inclination's. The caller computes the set when the block's length or the time
    constant changed (with ``slow_interval`` 0, the block is the sample: the inclination's set)."""
    if x[_KREADY] != 0.0:
        f1 = (1.0 - b0) * (1.0 / (1.0 - x[_SB]))
        f2 = (b2 - a2) * (1.0 / (x[_SB + 2] - x[_SB + 4]))
        _scale_slow_lines(x, f1, f2)
    x[_SB], x[_SB + 1], x[_SB + 2], x[_SB + 3], x[_SB + 4] = b0, b1, b2, a1, a2
    x[_SBT], x[_SBTAU] = t, x[_BTAU]


_k_slow_set = njit(inline="always")(_slow_set)


@njit(inline="always")
def _time_sum(x, i, w0, w1, w2, dt) -> bool:
    """A rate ``w`` into a block's time-weighted sum, if valid (every axis finite): ``w dt`` added to
    ``x[i:i + 3]`` and ``dt`` to ``x[i + 3]`` (their quotient the block's mean, dropped samples and jitter
    not tilting it): :func:`_block_add`'s and :func:`_adapt_add`'s. Returns whether it was valid."""
    if not (math.isfinite(w0) and math.isfinite(w1) and math.isfinite(w2)):
        return False
    x[i] += w0 * dt
    x[i + 1] += w1 * dt
    x[i + 2] += w2 * dt
    x[i + 3] += dt
    return True


def _block_add(x, dt, rest, w0, w1, w2, rate_error, e0, e1, e2, e3, half):
    """``slow_interval``: one sample into the block (its time; in motion, its time and count; at
    REST, its count; with the rate error and a valid gyro, the body rate ``w`` times ``dt`` summed and
    ``dt`` (the mean rate weighted by time), and in motion its time and count; the output ``e`` of the
    first sample at which the block reaches ``half`` s, half of ``slow_interval``: its middle); returns
    the block's seconds (the caller compares them with ``slow_interval``)."""
    x[_SLT] += dt
    if rate_error and x[_SLQN] == 0.0 and x[_SLT] + 0.5 * dt >= half:
        x[_SLQ], x[_SLQ + 1], x[_SLQ + 2], x[_SLQ + 3], x[_SLQN] = e0, e1, e2, e3, 1.0
    if rest:
        x[_SLR] += 1.0
    else:
        x[_SLM] += dt
        x[_SLMN] += 1.0
    if rate_error and _time_sum(x, _SLW, w0, w1, w2, dt):  # (_SLWN follows _SLW's three)
        if not rest:
            x[_SLE] += dt
            x[_SLEN] += 1.0
    return x[_SLT]


_k_block_add = njit(inline="always")(_block_add)


def _block_clear(x) -> None:
    """``slow_interval``: a new block starts (after a slow step, or a restart)."""
    for i in range(_SLT, _SLWN + 1):
        x[i] = 0.0
    x[_SLQN] = 0.0


_k_block_clear = njit(inline="always")(_block_clear)


def _carry(x, acc, blk, age) -> None:
    """A Kalman update decimated over its samples in motion (the bias filter's, ``bias_update_interval``:
    ``acc, blk, age`` = ``_KTACC, _SLM, _KAGE``; the rate error's, ``rate_error_interval``: ``_ETACC, _SLE,
    _EAGE``) at a block that ends at REST (no update): the block's seconds and samples in motion
    (``x[blk]``, ``x[blk + 1]``) are carried to the next update (``x[acc]``, ``x[acc + 1]``; its noise
    divided over them too), as an update per sample would have counted them. That update's measurement
    (the correction, or the bias filter's residual, and the rate error's regressor) is low-passed at the
    inclination's time constant ``tau`` (``_BTAU``; a second-order low-pass, whose weight on what is older
    than ``4 tau`` is under 5 %, while it still gives samples ``tau`` old its largest weight): carried motion
    is dropped once the blocks ending at REST since it was first carried (``x[age]``, their seconds) last
    longer than :data:`_CARRY_LIFE` time constants, not applied after a long rest as if it were fresh
    (before, it never expired: a rest with the detector flickering piled up samples for one update). The
    whole count goes at once, the motion carried later with it (one age for the count: the next update
    comes without them, conservative)."""
    if x[acc + 1] > 0.0:
        x[age] += x[_SLT]
        if x[age] > _CARRY_LIFE * x[_BTAU]:
            x[acc] = x[acc + 1] = x[age] = 0.0
    x[acc] += x[blk]
    x[acc + 1] += x[blk + 1]


_k_carry = njit(inline="always")(_carry)


def _adapt_add(x, dt, rest, a0, a1, a2, w0, w1, w2):
    """``slow_interval`` with ``tau_adapt``: one sample into the adaptive time constant's block (the
    specific force ``a`` and, when valid, the rate ``w``, both in I, times ``dt`` summed, and the valid
    rates' seconds: means weighted by time); returns the block's seconds."""
    x[_ATT] += dt
    x[_ATN] += 1.0
    x[_AA] += a0 * dt
    x[_AA + 1] += a1 * dt
    x[_AA + 2] += a2 * dt
    _time_sum(x, _AWS, w0, w1, w2, dt)  # (_AWN follows _AWS's three)
    if rest:
        x[_AREST] += 1.0
    return x[_ATT]


_k_adapt_add = njit(inline="always")(_adapt_add)


def _adapt_clear(x) -> None:
    """``slow_interval`` with ``tau_adapt``: the time constant's next block starts."""
    for i in range(_ATT, _AREST + 1):
        x[i] = 0.0


_k_adapt_clear = njit(inline="always")(_adapt_clear)


def _parallel_switch(x, at_max, dt, tau_max) -> bool:
    """``tau_max_parallel``: whether this sample switches the inclination low-pass to the one at ``tau_max``
    (``tau`` reaches ``tau_max`` now, the low-pass ran before). Why: the adaptive low-pass keeps, when ``tau``
    grows, what the shorter one let through (its delay lines are rescaled, not recomputed); a sustained
    shaking that starts at ``tau_acc`` is then held by ``tau_max`` for ``tau_max`` s. The low-pass at
    ``tau_max`` run from the start is the average over the whole past at the time constant now chosen.
    Its cost: a second low-pass per sample, and the gyro's drift over ``tau_max`` of the time before, which
    the statistics that chose ``tau_max`` now say is small against what the motion lets through."""
    sw = at_max and x[_PMAX] == 0.0 and x[_READY] != 0.0 and x[_PREADY] != 0.0
    x[_PMAX] = 1.0 if at_max else 0.0
    if sw:
        x[_TAUC] = tau_max / dt
    return sw


_k_parallel_switch = njit(inline="always")(_parallel_switch)


def _parallel_lowpass(x, v0, v1, v2) -> None:
    """``tau_max_parallel``: one step of the low-pass at ``tau_max`` (coefficients ``_PB``) on the specific
    force in I; it starts where the inclination low-pass starts (the fast start's mean, or the sample)."""
    b0, b1, b2, a1, a2 = x[_PB], x[_PB + 1], x[_PB + 2], x[_PB + 3], x[_PB + 4]
    if x[_PREADY] == 0.0:
        t0, t1, t2 = (x[_MEAN], x[_MEAN + 1], x[_MEAN + 2]) if x[_NMEAN] > 0 else (v0, v1, v2)
        x[_PZ1], x[_PZ1 + 1], x[_PZ1 + 2] = t0 * (1.0 - b0), t1 * (1.0 - b0), t2 * (1.0 - b0)
        x[_PZ2], x[_PZ2 + 1], x[_PZ2 + 2] = t0 * (b2 - a2), t1 * (b2 - a2), t2 * (b2 - a2)
        x[_PREADY] = 1.0
    for i, v in ((0, v0), (1, v1), (2, v2)):
        y = b0 * v + x[_PZ1 + i]
        x[_PZ1 + i] = b1 * v - a1 * y + x[_PZ2 + i]
        x[_PZ2 + i] = b2 * v - a2 * y


_k_parallel_lowpass = njit(inline="always")(_parallel_lowpass)


def _take_parallel(x, v0, v1, v2):
    """``tau_max_parallel``'s switch (the coefficients already ``_PB``): the inclination low-pass's delay lines
    become the one's at ``tau_max``; returns the low-passed vector the adaptive one would have given now
    (the caller turns ``q_tilt`` by the difference, so the bias filter's correction rate does not see it)."""
    b0 = x[_B]
    o0, o1, o2 = b0 * v0 + x[_Z1], b0 * v1 + x[_Z1 + 1], b0 * v2 + x[_Z1 + 2]
    for i in range(3):
        x[_Z1 + i], x[_Z2 + i] = x[_PZ1 + i], x[_PZ2 + i]
    return o0, o1, o2


_k_take_parallel = njit(inline="always")(_take_parallel)


@njit(inline="always")
def _atan_over(s, c):
    """``atan2(s, c) / s`` for ``s > 0``: a small angle (``s < c / 100``) by the series of ``atan(t) / t``
    to ``t^8`` (relative error under 1e-20), a division instead of a libm call every sample."""
    if c > 0.0 and s < 0.01 * c:
        ic = 1.0 / c
        t2 = s * s * ic * ic
        return ic * (1.0 + t2 * (-1.0 / 3.0 + t2 * (0.2 + t2 * (-1.0 / 7.0 + t2 * (1.0 / 9.0)))))
    return math.atan2(s, c) / s


def _lowpass_vertical(x, v):
    """One step of the inclination low-pass on ``v`` (the specific force in I) with the state's
    coefficients (transposed direct form II); its first step starts in the steady state of the
    fast start's mean (or of ``v`` without one). Returns the low-passed vector (``x[_Y:_Y + 3]``)."""
    b0, b1, b2, a1, a2 = x[_B:_B + 5]
    y, z1, z2 = x[_Y:_Y + 3], x[_Z1:_Z1 + 3], x[_Z2:_Z2 + 3]
    if not x[_READY]:  # start in the steady state of the mean (or of the first sample)
        start = x[_MEAN:_MEAN + 3] if x[_NMEAN] > 0 else v
        z1[:], z2[:] = start * (1.0 - b0), start * (b2 - a2)
        x[_READY] = 1.0
    y[:] = b0 * v + z1
    z1[:] = b1 * v - a1 * y + z2
    z2[:] = b2 * v - a2 * y
    return y


@njit(inline="always")
def _k_lowpass_vertical(s, v0, v1, v2):
    """:func:`_lowpass_vertical` compiled: the low-passed vector's three entries."""
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
    return y0, y1, y2


def _impulse_clip(x, v, dt, clip, window, floor):
    """The specific force ``v`` (in I) with an impulse's excess taken out (``impulse_clip``): its
    departure ``r`` from the previous low-passed vector is limited to ``clip`` times the running
    RMS of ``r`` (a Huber step; the RMS at least ``floor``), and the RMS learns from the limited
    departure (an exponential mean square of time constant ``window``, a running mean over its first
    samples), so an impulse does not raise its own limit.

    Why: a knock on the sensor is a specific force of tens of g over a few ms that the sampled
    accelerometer does not integrate to the velocity the body got (ringing above the sample rate,
    the range's saturation). The low-pass in I assumes every linear acceleration integrates to a
    velocity that returns; such a step does not, and turns into an inclination error of about
    ``dv / (g tau)`` for about ``tau``. A motion's own accelerations lie within a few RMS of their
    mean (a sinusoid's peak is 1.4 RMS), so the limit touches knocks, not motion. Off before the
    low-pass runs (the fast start's mean) and after a restart until the next low-passed vector."""
    if not x[_READY]:
        return v
    r = v - x[_Y:_Y + 3]
    r2 = float(r @ r)
    x[_IMN] += 1.0
    if x[_IMN] == 1.0:  # the first departure starts the mean square
        x[_IMS] = r2
        return v
    lim = clip * clip * max(x[_IMS], floor * floor)
    if r2 > lim:
        v = x[_Y:_Y + 3] + r * math.sqrt(lim / r2)
        r2 = lim
    x[_IMS] += (r2 - x[_IMS]) * max(dt / window, 1.0 / x[_IMN])
    return v


@njit(inline="always")
def _k_impulse_clip(s, v0, v1, v2, dt, clip, window, floor):
    """:func:`_impulse_clip` compiled: the sample's three entries."""
    if s[_READY] == 0.0:
        return v0, v1, v2
    r0, r1, r2 = v0 - s[_Y], v1 - s[_Y + 1], v2 - s[_Y + 2]
    rr = r0 * r0 + r1 * r1 + r2 * r2
    s[_IMN] += 1.0
    if s[_IMN] == 1.0:
        s[_IMS] = rr
        return v0, v1, v2
    lim = clip * clip * max(s[_IMS], floor * floor)
    if rr > lim:
        f = math.sqrt(lim / rr)
        v0, v1, v2 = s[_Y] + r0 * f, s[_Y + 1] + r1 * f, s[_Y + 2] + r2 * f
        rr = lim
    s[_IMS] += (rr - s[_IMS]) * max(dt / window, 1.0 / s[_IMN])
    return v0, v1, v2


@njit(inline="always")
def _lp_step(s, i, n, x, b0, b1, b2, c1, c2):
    """One step of the second-order low-pass whose delay lines are ``s[i]`` and ``s[i + n]``."""
    y = b0 * x + s[i]
    s[i] = b1 * x - c1 * y + s[i + n]
    s[i + n] = b2 * x - c2 * y
    return y


@njit(inline="always")
def _sym_store(s, i, q00, q01, q02, q11, q12, q22):
    """Store the symmetric matrix of 6 entries as a row-major 3 x 3 at ``s[i:i + 9]``."""
    s[i], s[i + 1], s[i + 2] = q00, q01, q02
    s[i + 3], s[i + 4], s[i + 5] = q01, q11, q12
    s[i + 6], s[i + 7], s[i + 8] = q02, q12, q22


@njit(inline="always")
def _sym_downdate(q00, q01, q02, q11, q12, q22, a00, a01, a02, a10, a11, a12, a20, a21, a22,
                  s00, s01, s02, s11, s12, s22, b=None, f0=0.0, f1=0.0, f2=0.0):
    """``Q - A S^-1 A^T`` for symmetric ``Q`` and ``S`` (6 entries each) and a 3 x 3 ``A``; with ``b``,
    also ``b += A S^-1 f`` (the Kalman update with gain ``K = A S^-1``)."""
    c00, c01, c02 = s11 * s22 - s12 * s12, s02 * s12 - s01 * s22, s01 * s12 - s02 * s11
    d = 1.0 / (s00 * c00 + s01 * c01 + s02 * c02)
    c00, c01, c02 = c00 * d, c01 * d, c02 * d
    c11, c12, c22 = (s00 * s22 - s02 * s02) * d, (s01 * s02 - s00 * s12) * d, (s00 * s11 - s01 * s01) * d
    k00 = a00 * c00 + a01 * c01 + a02 * c02
    k01 = a00 * c01 + a01 * c11 + a02 * c12
    k02 = a00 * c02 + a01 * c12 + a02 * c22
    k10 = a10 * c00 + a11 * c01 + a12 * c02
    k11 = a10 * c01 + a11 * c11 + a12 * c12
    k12 = a10 * c02 + a11 * c12 + a12 * c22
    k20 = a20 * c00 + a21 * c01 + a22 * c02
    k21 = a20 * c01 + a21 * c11 + a22 * c12
    k22 = a20 * c02 + a21 * c12 + a22 * c22
    if b is not None:
        b[0] += k00 * f0 + k01 * f1 + k02 * f2
        b[1] += k10 * f0 + k11 * f1 + k12 * f2
        b[2] += k20 * f0 + k21 * f1 + k22 * f2
    return (q00 - (k00 * a00 + k01 * a01 + k02 * a02), q01 - (k00 * a10 + k01 * a11 + k02 * a12),
            q02 - (k00 * a20 + k01 * a21 + k02 * a22), q11 - (k10 * a10 + k11 * a11 + k12 * a12),
            q12 - (k10 * a20 + k11 * a21 + k12 * a22), q22 - (k20 * a20 + k21 * a21 + k22 * a22))


@njit(inline="always")
def _k_kalman(s, b, e0, e1, e2, e3, r0, r1, r2, rest, dt, p):
    """:meth:`InertialTilt._kalman` (``e``: the output quaternion, ``r``: the correction rate; the block's
    fields in ``s``); returns the residual after the update with ``rate_error_estimate`` (zeros without it)."""
    rot = dcm_entries(e0, e1, e2, e3)
    rb0 = rot[0] * b[0] + rot[1] * b[1] + rot[2] * b[2]
    rb1 = rot[3] * b[0] + rot[4] * b[1] + rot[5] * b[2]
    rb2 = rot[6] * b[0] + rot[7] * b[1] + rot[8] * b[2]
    b0, b1, b2, c1, c2 = s[_SB], s[_SB + 1], s[_SB + 2], s[_SB + 3], s[_SB + 4]
    if s[_KREADY] == 0.0:
        for i in range(9):
            s[_RZ1 + i], s[_RZ2 + i] = rot[i] * (1.0 - b0), rot[i] * (b2 - c2)
        s[_BZ1], s[_BZ1 + 1], s[_BZ1 + 2] = rb0 * (1.0 - b0), rb1 * (1.0 - b0), rb2 * (1.0 - b0)
        s[_BZ2], s[_BZ2 + 1], s[_BZ2 + 2] = rb0 * (b2 - c2), rb1 * (b2 - c2), rb2 * (b2 - c2)
        s[_KREADY] = 1.0
    z = _RZ1
    h = (_lp_step(s, z, 9, rot[0], b0, b1, b2, c1, c2), _lp_step(s, z + 1, 9, rot[1], b0, b1, b2, c1, c2),
         _lp_step(s, z + 2, 9, rot[2], b0, b1, b2, c1, c2), _lp_step(s, z + 3, 9, rot[3], b0, b1, b2, c1, c2),
         _lp_step(s, z + 4, 9, rot[4], b0, b1, b2, c1, c2), _lp_step(s, z + 5, 9, rot[5], b0, b1, b2, c1, c2),
         _lp_step(s, z + 6, 9, rot[6], b0, b1, b2, c1, c2), _lp_step(s, z + 7, 9, rot[7], b0, b1, b2, c1, c2),
         _lp_step(s, z + 8, 9, rot[8], b0, b1, b2, c1, c2))
    hb0 = _lp_step(s, _BZ1, 3, rb0, b0, b1, b2, c1, c2)
    hb1 = _lp_step(s, _BZ1 + 1, 3, rb1, b0, b1, b2, c1, c2)
    hb2 = _lp_step(s, _BZ1 + 2, 3, rb2, b0, b1, b2, c1, c2)
    v, wm, wv, wr, p0 = s[_N], s[_N + 1], s[_N + 2], s[_N + 3], s[_N + 4]
    v *= s[_SLT] / dt  # (v is a sample's growth: the block's is its seconds' share)
    # P is symmetric and stays so (every update below is P - A S^-1 A^T): its 6 distinct entries
    q00, q01, q02, q11, q12, q22 = s[_P], s[_P + 1], s[_P + 2], s[_P + 4], s[_P + 5], s[_P + 8]
    q00 = q00 + v if q00 < p0 else q00
    q11 = q11 + v if q11 < p0 else q11
    q22 = q22 + v if q22 < p0 else q22
    if s[_SLR] > 0.0 and p[8] > 0.0:  # P -= P (P + wr / n I)^-1 P: the block's n REST samples, one measurement
        wr = wr / s[_SLR]
        q00, q01, q02, q11, q12, q22 = _sym_downdate(q00, q01, q02, q11, q12, q22,
                                                     q00, q01, q02, q01, q11, q12, q02, q12, q22,
                                                     q00 + wr, q01, q02, q11 + wr, q12, q22 + wr)
    if rest:  # (a block ends on its last sample's status: its samples in motion count towards the next update)
        _k_carry(s, _KTACC, _SLM, _KAGE)
        _sym_store(s, _P, q00, q01, q02, q11, q12, q22)
        return 0.0, 0.0, 0.0
    u0, u1, u2 = s[_UP], s[_UP + 1], s[_UP + 2]
    hu = u0 * hb0 + u1 * hb1 + u2 * hb2
    f0 = -r0 + hb0 - u0 * hu - (h[0] * b[0] + h[1] * b[1] + h[2] * b[2])
    f1 = -r1 + hb1 - u1 * hu - (h[3] * b[0] + h[4] * b[1] + h[5] * b[2])
    f2 = -r2 + hb2 - u2 * hu - (h[6] * b[0] + h[7] * b[1] + h[8] * b[2])
    if p[22] > 0.0:  # bias_update_interval: the update once per interval of motion, its noise over the samples
        s[_KTACC] += s[_SLM]
        s[_KNACC] += s[_SLMN]
        if s[_KTACC] + 0.5 * dt < p[22]:  # not yet: the covariance grew; the residual with the bias as it is
            _sym_store(s, _P, q00, q01, q02, q11, q12, q22)
            if p[18] == 0.0:
                return 0.0, 0.0, 0.0
            return f0, f1, f2
        wm, wv = wm / s[_KNACC], wv / s[_KNACC]
        s[_KTACC] = s[_KNACC] = s[_KAGE] = 0.0
    else:  # an update per block: the noise over its samples in motion (and those of blocks that ended at REST)
        n = s[_SLMN] + s[_KNACC]
        wm, wv = wm / n, wv / n
        s[_KTACC] = s[_KNACC] = s[_KAGE] = 0.0
    ne2 = f0 * f0 + f1 * f1 + f2 * f2  # (the square root only to clamp)
    if ne2 > p[4] * p[4]:
        g = p[4] / math.sqrt(ne2)
        f0, f1, f2 = f0 * g, f1 * g, f2 * g
    # A = P H^T, S = H A + W (symmetric), K = A S^-1; P -= K A^T
    a00 = q00 * h[0] + q01 * h[1] + q02 * h[2]
    a10 = q01 * h[0] + q11 * h[1] + q12 * h[2]
    a20 = q02 * h[0] + q12 * h[1] + q22 * h[2]
    a01 = q00 * h[3] + q01 * h[4] + q02 * h[5]
    a11 = q01 * h[3] + q11 * h[4] + q12 * h[5]
    a21 = q02 * h[3] + q12 * h[4] + q22 * h[5]
    a02 = q00 * h[6] + q01 * h[7] + q02 * h[8]
    a12 = q01 * h[6] + q11 * h[7] + q12 * h[8]
    a22 = q02 * h[6] + q12 * h[7] + q22 * h[8]
    dw = wv - wm
    q00, q01, q02, q11, q12, q22 = _sym_downdate(
        q00, q01, q02, q11, q12, q22, a00, a01, a02, a10, a11, a12, a20, a21, a22,
        h[0] * a00 + h[1] * a10 + h[2] * a20 + wm + dw * u0 * u0, h[0] * a01 + h[1] * a11 + h[2] * a21 + dw * u0 * u1,
        h[0] * a02 + h[1] * a12 + h[2] * a22 + dw * u0 * u2, h[3] * a01 + h[4] * a11 + h[5] * a21 + wm + dw * u1 * u1,
        h[3] * a02 + h[4] * a12 + h[5] * a22 + dw * u1 * u2, h[6] * a02 + h[7] * a12 + h[8] * a22 + wm + dw * u2 * u2,
        b, f0, f1, f2)
    _sym_store(s, _P, q00, q01, q02, q11, q12, q22)
    k_clamp3(b, p[4])
    if p[18] == 0.0:
        return 0.0, 0.0, 0.0
    # the residual after the update (rate_error_estimate): what the bias does not explain
    return (-r0 + hb0 - u0 * hu - (h[0] * b[0] + h[1] * b[1] + h[2] * b[2]),
            -r1 + hb1 - u1 * hu - (h[3] * b[0] + h[4] * b[1] + h[5] * b[2]),
            -r2 + hb2 - u2 * hu - (h[6] * b[0] + h[7] * b[1] + h[8] * b[2]))


def _rate_error_step(x, e0, e1, e2, e3, w0, w1, w2, f0, f1, f2, rest, dt, kappa0, rforget, emax, correct,
                     interval, acc_sigma):
    """The gyro's rate error estimated online (``rate_error_estimate``), one sample (with
    ``slow_interval``, one block: its middle sample's output, its mean rate; ``dt`` the last sample's): the output
    quaternion ``e`` (body -> levelled), the body rate ``w`` (gyro minus bias), the bias filter's
    residual ``f`` after its update (:meth:`InertialTilt._kalman`), a REST sample.

    A gyro reads ``(I + E) w + b``: the scale factors (E's diagonal) and the axes' non-orthogonality
    drift the strapdown at ``R E w`` in the levelled frame, and the inclination low-pass sees that
    low-passed. E's antisymmetric part is a rotation of the gyro's axes as a whole: it tilts the
    output by a constant, it does not drift, so it is not estimated (fitted, it takes up a mounting
    offset between gyro and accelerometer). What the bias filter leaves of the correction rate is
    the drift of the symmetric part: ``f = LP(R E w)``, linear in its 6 entries, the column of
    ``E_ii`` being ``LP(R[:, i] w_i)`` and that of ``E_ij = E_ji`` ``LP(R[:, i] w_j + R[:, j] w_i)``,
    low-passed with the inclination's coefficients (as the bias filter's ``LP(R)``), across the
    vertical only (the accelerometer does not see a turn about it). A Kalman filter for them: the
    prior is ``kappa0^2 / 3`` per entry of E (a gyro whose mean square rate error over the axes is
    ``kappa0``: ``gyro_rate_error``), growing back to it in ``forget`` s (``rforget``: its reciprocal), the
    measurement noise the bias filter's; entries limited to ``emax``. A turn only tells the entries it excites, the rest
    keep their prior. The result is the ``kappa^2`` tau_adapt uses, ``(|E|^2 + its variance) / 3``:
    the rate error the strapdown still has, with what is not known of it. The bias filter learns
    first: a steady turn's ``E w`` is a constant bias that it takes, so what this sees is the part of
    the rate error that changes with the rate, which is what drifts the inclination.

    ``correct`` (``rate_error_correct``): the estimate is removed from the gyro (the caller adds
    ``E w`` to the pipeline's bias for the next propagation), so the residual measures what is left,
    ``E - E_applied`` with ``E_applied`` the estimate itself: the innovation is the residual, and
    ``kappa^2`` is the variance alone.

    ``interval`` (``rate_error_interval``): the Kalman update runs once per ``interval`` s of motion
    (0: every call; with ``slow_interval`` it is called once per block, so the interval is counted in whole
    blocks). Its measurement is low-passed at the inclination's time constant (at least
    ``tau_min``), so consecutive samples carry almost the same information: the update of the
    interval's last sample, its noise divided by the samples the interval spans, keeps the
    information per second. The samples of a block ending at REST count towards the next update, and
    expire once the blocks at REST since outlast four of the inclination's time constants (:func:`_carry`, as
    the bias filter's; aged only in blocks with a valid gyro, where the regressor's low-pass runs): the
    measurement, and the regressor, then hold almost nothing of what they saw. The regressor's
    low-pass and the covariance's growth run once per block (``slow_interval``: the state's block, its
    seconds ``_SLT`` and its seconds and samples of motion with a valid gyro; ``w`` is then the block's
    mean rate, ``dt`` the sample's), ``E w`` every sample (:func:`_rate_error_correct`).

    ``acc_sigma`` (``rate_error_acc_bias``, m/s^2; 0: not modelled): the accelerometer's bias ``b_a``
    estimated beside E, so that its drift is not taken for E's. A bias fixed in the body tilts the
    low-passed vector by ``up x LP(R b_a) / g``; as the body turns, that tilt moves at
    ``up x LP(R [w]x b_a) / g`` (``d/dt R = R [w]x``), which the correction follows and the bias filter
    leaves in its residual: linear in ``b_a``, the column of ``b_a``'s axis ``j`` being
    ``up x LP(R (w x e_j)) / g`` (east row ``-n . LP(R (w x e_j)) / g``, north row
    ``s . LP(R (w x e_j)) / g``). Its prior is ``acc_sigma^2`` per axis, growing back in ``forget`` s
    as E's. It is only told apart, never removed from the accelerometer; with ``acc_sigma`` 0 its
    covariance stays 0 and the update is E's alone, to the bit."""
    c1, c2 = 1.0 - x[_SB], x[_SB + 2] - x[_SB + 4]
    r = dcm_entries(e0, e1, e2, e3)
    # the levelled frame's two horizontal axes (east and north = up x east): rows of R seen along them
    u0, u1, u2 = x[_UP], x[_UP + 1], x[_UP + 2]
    s0, s1, s2 = x[_EAST], x[_EAST + 1], x[_EAST + 2]
    n0, n1, n2 = u1 * s2 - u2 * s1, u2 * s0 - u0 * s2, u0 * s1 - u1 * s0
    # the regressor before the low-pass (x[_SCR:_SCR + 18]): east then north row of the columns 00, 11, 22, 01, 02, 12
    # and of the accelerometer's bias x, y, z (flat indices, no array views: this part runs every sample); ne: the
    # states estimated (without the bias its covariance is 0 and it would add nothing: not computed)
    g = _SCR
    ne = _NE if acc_sigma > 0.0 else 6
    for k in range(2):
        a0, a1, a2 = (s0, s1, s2) if k == 0 else (n0, n1, n2)
        r0 = a0 * r[0] + a1 * r[3] + a2 * r[6]
        r1 = a0 * r[1] + a1 * r[4] + a2 * r[7]
        r2 = a0 * r[2] + a1 * r[5] + a2 * r[8]
        i = g + _NE * k
        x[i], x[i + 1], x[i + 2] = r0 * w0, r1 * w1, r2 * w2
        x[i + 3], x[i + 4], x[i + 5] = r0 * w1 + r1 * w0, r0 * w2 + r2 * w0, r1 * w2 + r2 * w1
        # the bias's columns, rows swapped: up x v along east is -n . v, along north s . v; the row here is
        # east's (s^T R) for k 0, north's (n^T R) for k 1, each the other row's; w x e_j = (0, w2, -w1),
        # (-w2, 0, w0), (w1, -w0, 0)
        if ne > 6:
            j = g + _NE * (1 - k) + 6
            sg = _G_INV if k == 0 else -_G_INV
            x[j], x[j + 1], x[j + 2] = sg * (r1 * w2 - r2 * w1), sg * (r2 * w0 - r0 * w2), sg * (r0 * w1 - r1 * w0)
    if x[_EREADY] == 0.0:  # start in the steady state of this sample
        for k in range(2):
            for m in range(k * _NE, k * _NE + ne):
                x[_HZ1 + m], x[_HZ2 + m] = x[g + m] * c1, x[g + m] * c2
        x[_ECO], x[_ECO + 1], x[_EREADY] = c1, c2, 1.0
    elif c1 != x[_ECO] or c2 != x[_ECO + 1]:  # new coefficients (tau_adapt, dt): the delay lines' steady state
        q1, q2 = c1 / x[_ECO], c2 / x[_ECO + 1]
        for k in range(2):
            for m in range(k * _NE, k * _NE + ne):
                x[_HZ1 + m] *= q1
                x[_HZ2 + m] *= q2
        x[_ECO], x[_ECO + 1] = c1, c2
    b0, b1, b2, a1, a2 = x[_SB], x[_SB + 1], x[_SB + 2], x[_SB + 3], x[_SB + 4]
    for k in range(2):  # the low-passed regressor H (2 x 9) at x[_SCR + 18:_SCR + 36]
        for m in range(k * _NE, k * _NE + ne):
            gm = x[g + m]
            y = b0 * gm + x[_HZ1 + m]
            x[_HZ1 + m] = b1 * gm - a1 * y + x[_HZ2 + m]
            x[_HZ2 + m] = b2 * gm - a2 * y
            x[g + 2 * _NE + m] = y
    # (no division every sample: 1 / 3 a constant, rforget = 1 / forget a parameter)
    p0, pa = kappa0 * kappa0 * (1.0 / 3.0), acc_sigma * acc_sigma
    v, va = p0 * x[_SLT] * rforget, pa * x[_SLT] * rforget  # (the block's seconds)
    for m in range(6):
        if x[_PE + (_NE + 1) * m] < p0:
            x[_PE + (_NE + 1) * m] += v
    for m in range(6, ne):
        if x[_PE + (_NE + 1) * m] < pa:
            x[_PE + (_NE + 1) * m] += va
    # the interval: the block's seconds of motion added, compared with half a sample of margin (a split run equals
    # one run); a block ending at REST carries them, expiring after a rest longer than 4 time constants (_carry)
    if rest:
        _k_carry(x, _ETACC, _SLE, _EAGE)
    else:
        x[_ETACC] += x[_SLE]
        x[_ENACC] += x[_SLEN]
    if not rest and x[_ENACC] > 0.0 and x[_ETACC] + 0.5 * dt >= interval:
        h = x[_SCR + 2 * _NE:_SCR + 4 * _NE].reshape((2, _NE))
        # the linear acceleration the low-pass lets through turns its vector by sigma_v / (g tau), changing over tau:
        # as white noise of the same low-frequency power, 2 sigma_v^2 / (g^2 tau^3 dt) on the rate (tau_adapt's
        # statistics; 0 without them)
        wa = 0.0
        if x[_NST] > 1.0:
            t = x[_TAU]
            wa = 2.0 * x[_SV2] / ((x[_Y] * x[_Y] + x[_Y + 1] * x[_Y + 1] + x[_Y + 2] * x[_Y + 2]) * t * t * t * dt)
        v0, v1 = s0 * f0 + s1 * f1 + s2 * f2, n0 * f0 + n1 * f1 + n2 * f2  # the innovation
        for n in range(0 if not correct else 6, ne):  # (the bias is never removed: its estimate always is)
            v0 -= h[0, n] * x[_E + n]
            v1 -= h[1, n] * x[_E + n]
        a = x[_SCR + 4 * _NE:_SCR + 6 * _NE].reshape((_NE, 2))  # P H^T
        for m in range(ne):
            t0 = t1 = 0.0
            for n in range(ne):
                t0 += x[_PE + _NE * m + n] * h[0, n]
                t1 += x[_PE + _NE * m + n] * h[1, n]
            a[m, 0], a[m, 1] = t0, t1
        wn = (x[_N + 1] + wa) / x[_ENACC]  # the interval's samples, one update: each sample's noise / their count
        x[_ETACC] = x[_ENACC] = x[_EAGE] = 0.0
        m00, m01, m11 = wn, 0.0, wn  # S = H P H^T + (wm + wa) / n I
        for n in range(ne):
            m00 += h[0, n] * a[n, 0]
            m01 += h[0, n] * a[n, 1]
            m11 += h[1, n] * a[n, 1]
        d = 1.0 / (m00 * m11 - m01 * m01)
        i00, i01, i11 = m11 * d, -m01 * d, m00 * d
        for m in range(ne):  # K = P H^T S^-1 (row m), E += K nu, P -= K (P H^T)^T (symmetric: the upper half, mirrored)
            k0 = a[m, 0] * i00 + a[m, 1] * i01
            k1 = a[m, 0] * i01 + a[m, 1] * i11
            x[_E + m] = min(max(x[_E + m] + k0 * v0 + k1 * v1, -emax), emax) if m < 6 else x[_E + m] + k0 * v0 + k1 * v1
            for n in range(m, ne):
                x[_PE + _NE * m + n] -= k0 * a[n, 0] + k1 * a[n, 1]
                x[_PE + _NE * n + m] = x[_PE + _NE * m + n]
    k2 = 0.0
    for m in range(6):
        k2 += (1.0 if m < 3 else 2.0) * (x[_PE + (_NE + 1) * m] if correct
                                         else x[_E + m] * x[_E + m] + x[_PE + (_NE + 1) * m])
    x[_KAP2] = k2 * (1.0 / 3.0)


_k_rate_error_step = njit(inline="always")(_rate_error_step)


def _rate_error_correct(x, e0, e1, e2, e3, w0, w1, w2) -> None:
    """``rate_error_correct``: the rate error this sample's rate ``w`` (body, gyro minus bias) shows, ``E w``
    across the vertical of the output ``e``, for the next propagation (every sample with a valid gyro; E
    itself changes at the rate error's updates)."""
    r = dcm_entries(e0, e1, e2, e3)
    u0, u1, u2 = x[_UP], x[_UP + 1], x[_UP + 2]
    e00, e11, e22, e01, e02, e12 = x[_E], x[_E + 1], x[_E + 2], x[_E + 3], x[_E + 4], x[_E + 5]
    d0, d1, d2 = e00 * w0 + e01 * w1 + e02 * w2, e01 * w0 + e11 * w1 + e12 * w2, e02 * w0 + e12 * w1 + e22 * w2
    # (its part about the vertical drifts the heading, which the accelerometer never checks: left to the
    # heading's own correction)
    c = u0 * (r[0] * d0 + r[1] * d1 + r[2] * d2) + u1 * (r[3] * d0 + r[4] * d1 + r[5] * d2) \
        + u2 * (r[6] * d0 + r[7] * d1 + r[8] * d2)
    z0, z1, z2 = r[0] * u0 + r[3] * u1 + r[6] * u2, r[1] * u0 + r[4] * u1 + r[7] * u2, r[2] * u0 + r[5] * u1 + r[8] * u2
    x[_EW], x[_EW + 1], x[_EW + 2] = d0 - c * z0, d1 - c * z1, d2 - c * z2


_k_rate_error_correct = njit(inline="always")(_rate_error_correct)


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
    bias_filter: Literal["kalman", "lowpass"] = param(
        "kalman", unit="-", description="how the correction teaches the bias in motion. kalman: VQF's model, the "
        "correction rate is the low-passed earth-frame bias error, LP(R) b (the low-pass the inclination sees), "
        "weighed by the bias's covariance (a Kalman filter that knows what the rests taught); lowpass: the "
        "correction mapped to the body with the sample's own R, a fixed time constant (the behaviour before)")
    bias_sigma_init: float = param(math.radians(0.5), unit="rad/s", description="kalman: the bias's standard "
                                   "deviation at the start and the most it grows to", gt=0)
    bias_sigma_motion: float = param(math.radians(0.1), unit="rad/s", description="kalman: the steady-state "
                                     "standard deviation of a bias learned in motion (with motion_bias_tau: the "
                                     "measurement noise)", gt=0)
    bias_sigma_rest: float | None = param(
        None, unit="rad/s", description="kalman: the standard deviation to which a rest (REST samples) tells the bias "
        "in motion: they shrink the covariance as that measurement does (VQF's biasSigmaRest, 0.03 deg/s: a rest "
        "pins the bias). None: not at all (a rest sees the zero-rate bias only; in motion the scale factor's and "
        "misalignment's error, proportional to the rate, adds to it)", gt=0)
    tau_adapt: bool = param(
        False, unit="-", description="the time constant per sample from the motion: tau = sqrt(sigma_v / (g d)), the "
        "least linear acceleration let through plus gyro drift accumulated (sigma_v: the velocity's deviation in I, "
        "from the specific force; d: the bias's uncertainty and gyro_rate_error times the net turn rate), within "
        "[tau_min, tau_max]; tau is then the time constant of the velocity and net turn estimates. False: tau "
        "throughout (the behaviour before)")
    gyro_rate_error: float = param(
        0.015, unit="-", description="tau_adapt: the gyro's error proportional to the rate (scale factor and "
        "misalignment; consumer MEMS data sheets: 1-3 %)", ge=0)
    rate_error_estimate: bool = param(
        False, unit="-", description="tau_adapt: the gyro's rate error (the 3 x 3 scale and misalignment matrix E) "
        "estimated online from what the bias filter leaves of the correction (a Kalman filter, prior "
        "gyro_rate_error, needs bias_filter kalman with motion_bias_tau); tau_adapt's kappa is then "
        "sqrt((|E|^2 + tr P) / 3), the rate error not yet removed with its uncertainty. The gyro is not corrected. "
        "False: kappa = gyro_rate_error throughout")
    rate_error_correct: bool = param(
        False, unit="-", description="rate_error_estimate: the estimate removed from the gyro (E w, w the rate "
        "of the sample, added to the pipeline's bias for the next propagation and taken off again before the bias "
        "filter); kappa is then the estimate's uncertainty alone. False: the estimate only sets kappa")
    rate_error_max: float = param(0.05, unit="-", description="rate_error_estimate: the largest entry of E", gt=0)
    rate_error_acc_bias: float = param(
        0.0, unit="m/s^2", description="rate_error_estimate: the accelerometer's bias (its standard deviation per "
        "axis) estimated beside E: a bias fixed in the body tilts the low-passed vector, and as the body turns that "
        "tilt moves like a rate error's drift; modelled, it is not taken for E (it is not removed from the "
        "accelerometer). 0: not modelled (the behaviour before)", ge=0)
    rate_error_interval: float = param(
        0.0, unit="s", description="rate_error_estimate: the time of motion between the estimate's Kalman updates, "
        "each with the measurement noise divided by the samples it spans (the same information per second; the "
        "measurement is low-passed at tau, consecutive samples say almost the same). The regressor's low-pass "
        "runs once per block of slow_interval (every sample with 0), the correction E w every sample; with blocks "
        "the interval is counted in whole blocks (0.05 s is 0.063 s at 286 Hz with 0.02 s blocks); the motion "
        "counted towards the next update expires after a rest longer than four inclination time constants. 0: an "
        "update every block (every sample with slow_interval 0)", ge=0)
    bias_update_interval: float = param(
        0.0, unit="s", description="kalman: the time of motion between the bias filter's Kalman updates, each with "
        "the measurement noise divided by the samples it spans (the same information per second: the measurement "
        "is the correction rate low-passed at tau, consecutive samples say almost the same). The low-passes and "
        "the covariance's growth run once per block of slow_interval (every sample with 0); with blocks the "
        "interval is counted in whole blocks; the motion counted towards the next update (with 0, that of blocks "
        "ending at REST) expires after a rest longer than four inclination time constants. 0: an update every block "
        "in motion (every sample with slow_interval 0)", ge=0)
    slow_interval: float = param(
        0.0, unit="s", description="the slow estimators once per block of this many seconds instead of every "
        "sample: with bias_filter kalman, the bias filter's low-passes (the rotation's and the bias's), its "
        "covariance and its updates, and the rate error's (rate_error_estimate); with tau_adapt, its statistics "
        "and time constant. On the block's last sample's rotation (the rate error's regressor: its middle one), "
        "its mean rates and specific force weighted by time, the covariances grown by the block's time, a "
        "block's REST samples one measurement (a block ending at REST passes its samples in motion to the next "
        "update); update intervals are counted in whole blocks. They change over "
        "seconds (the inclination's time constant, motion_bias_tau); the inclination low-pass, the correction and "
        "(rate_error_correct) E w stay per sample. At most a tenth of the shortest time constant (tau_min with "
        "tau_adapt, else tau): the block's low-passes would wrap at pi tau, and turns faster than pi / slow_interval "
        "alias. 0: every sample (the behaviour before)", ge=0)
    tau_min: float = param(0.5, unit="s", description="tau_adapt: the shortest time constant", gt=0)
    tau_max: float = param(4.0, unit="s", description="tau_adapt: the longest time constant (the velocity estimate, "
                           "leaking with tau, does not see accelerations slower than a few tau)", gt=0)
    adapt_window: float = param(10.0, unit="s", description="tau_adapt: the time over which the velocity's and "
                                "the rate's mean squares are averaged", gt=0)
    tau_max_parallel: bool = param(
        False, unit="-", description="tau_adapt: a second inclination low-pass at tau_max runs beside the adaptive "
        "one from the start, and when tau reaches tau_max the adaptive one's delay lines are replaced by it (the "
        "output jumps to the average over the whole past at tau_max): what a shorter tau let through before "
        "(the onset of a sustained shaking) is not kept for the next tau_max s. The bias filter does not see the "
        "jump. False: the delay lines are rescaled to the new tau (the behaviour before)")
    impulse_clip: float | None = param(
        None, unit="-", description="impulses (knocks, taps): the specific force's departure from the low-passed "
        "vector limited to this many times its running RMS before the low-pass (a Huber step; the RMS learns from "
        "the limited departure). None: off (the behaviour before)", gt=1)
    impulse_window: float = param(1.0, unit="s", description="impulse_clip: the time constant of the departure's "
                                  "mean square (the motion's scale it follows)", gt=0)
    impulse_floor: float = param(0.05, unit="m/s^2", description="impulse_clip: the least RMS the limit is "
                                 "taken from (an accelerometer's noise; a noise-free input would otherwise clip "
                                 "every motion after a rest)", gt=0)
    bias_vertical_forgetting: float = param(
        1e-4, unit="-", description="kalman: the weight, relative to the horizontal axes, of the pseudo-measurement "
        "'no drift about the vertical' (unobservable from the accelerometer)", gt=0)

    @field_validator("tau_max")
    @classmethod
    def _tau_max_not_below_tau_min(cls, v: float, info) -> float:
        """``[tau_min, tau_max]`` bounds the adaptive time constant: reversed, every sample would get
        ``tau_max`` whatever the motion, silently."""
        lo = info.data.get("tau_min")
        if lo is not None and v < lo:
            raise ValueError(f"must be at least tau_min ({lo:g} s), got {v:g} s")
        return v

    @model_validator(mode="after")
    def _rate_error_needs_the_bias_filter(self):
        """The rate error is learned from the bias filter's residual: without it, nothing would be learned."""
        if self.rate_error_estimate and (self.motion_bias_tau is None or self.bias_filter != "kalman"):
            raise ValueError("rate_error_estimate needs bias_filter 'kalman' with a motion_bias_tau")
        if self.rate_error_correct and not self.rate_error_estimate:
            raise ValueError("rate_error_correct needs rate_error_estimate")
        if self.rate_error_acc_bias > 0 and not self.rate_error_estimate:  # (it would be silently ignored)
            raise ValueError("rate_error_acc_bias needs rate_error_estimate")
        # slow_interval: the block's low-passes are a bilinear transform at the block's rate, tan(T / (2 tau)),
        # which wraps at T = pi tau; and they see the rotation once per block, so turns faster than pi / T rad/s
        # alias (at 5 s the rate error came out with the wrong signs). A tenth of the shortest time constant keeps
        # the cutoff within 0.1 % of the per-sample one and puts the aliasing above pi / 0.05 = 63 rad/s at the
        # defaults (tau_min 0.5 s)
        bound, adaptive = slow_interval_bound(self.tau, self.tau_adapt, self.tau_min)
        if self.slow_interval > bound:
            raise ValueError(f"slow_interval must be at most a tenth of the shortest time constant "
                             f"({'tau_min' if adaptive else 'tau'}): {bound:g} s, got {self.slow_interval:g} s")
        return self


def slow_interval_bound(tau: float, tau_adapt: bool, tau_min: float) -> tuple[float, bool]:
    """The longest ``slow_interval`` a low-pass at ``tau`` (``tau_adapt``: down to ``tau_min``) allows: a
    tenth of the shortest time constant (:class:`InertialTiltConfig`'s check, and ``recommended``'s
    default); and whether that shortest one is ``tau_min``."""
    adaptive = tau_adapt and tau_min < tau
    return 0.1 * (tau_min if adaptive else tau), adaptive


class InertialTilt(FactorCorrector):
    """Inclination from the specific force low-passed in the almost-inertial frame (a factor)."""

    name: ClassVar[str] = "inertial-tilt"
    Config = InertialTiltConfig
    restarts: ClassVar[bool] = True
    #: with ``tau_adapt``, every sample with an accelerometer reading: the inclination error's bias
    #: part, time constant and let-through tilt (:func:`_publish`; without ``tau_adapt``, or with no
    #: corrector reading them, nothing)
    publishes: ClassVar[tuple[Channel, ...]] = (Channel.INCLINATION_VARIANCE, Channel.INCLINATION_TIME,
                                                Channel.LET_THROUGH)
    source: ClassVar[str] = "fusionkit (source 002's channel separation; low-pass in the inertial frame)"
    summary: ClassVar[str] = "inclination factor: the accelerometer low-passed in the almost-inertial frame"

    def channel_publishes(self) -> tuple[Channel, ...]:
        """Its inclination error with ``tau_adapt`` (what :func:`_publish` writes), else nothing."""
        return self.publishes if self.config.tau_adapt else ()

    def _publishing(self) -> bool:
        """Whether it writes the channel each sample: with ``tau_adapt`` and a corrector in the pipeline
        that reads it (:attr:`~fusionkit.protocols.Corrector.channel_read`; the sum, rotation, square root
        and division of :func:`_publish` every sample are ~1 % of ``recommended``'s loop). Nobody
        reading, the channel stays 0."""
        read = self.publishes if self.channel_read is None else self.channel_read
        return bool(self.config.tau_adapt and read)

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        s = np.zeros(_SIZE)
        s[_QA] = 1.0
        axes = frame_axes(frame)
        s[_UP:_UP + 3], s[_EAST:_EAST + 3] = axes[6:9], axes[0:3]
        s[_P:_P + 9] = np.eye(3).ravel() * self.config.bias_sigma_init ** 2
        s[_VR] = self.config.bias_sigma_init ** 2
        s[_PE:_PE + _NE * _NE] = np.diag([self.config.gyro_rate_error ** 2 / 3.0] * 6
                                         + [self.config.rate_error_acc_bias ** 2] * 3).ravel()
        s[_KAP2] = self.config.gyro_rate_error ** 2
        return s

    def inclination_model(self, state: np.ndarray) -> np.ndarray:
        """What this state's inclination low-pass assumes now: ``(E's symmetric part 00, 11, 22, 01,
        02, 12, c0, c1, c2, tau)``. ``E`` the gyro's rate error removed (``rate_error_correct``;
        zeros without it, also where E is only estimated: the pass's propagation kept ``E w`` then), ``c`` the ``E w`` the pipeline's bias carries for the next propagation
        (``rate_error_correct``; zeros without it), ``tau`` the low-pass's time constant (with
        ``tau_adapt`` the adaptive one, else ``tau``). The offline mode's smoothing reads it: the bias
        without ``c``, the frame turned by the gyro less ``E w``, and the low-pass run the other way
        with the pass's own ``tau`` (:func:`fusionkit.offline.gyro_trace`)."""
        c = self.config
        e = state[_E:_E + 6] if c.rate_error_correct else np.zeros(6)  # (estimated only: the pass kept E w)
        w = state[_EW:_EW + 3] if c.rate_error_correct else np.zeros(3)
        tau = state[_TAU] if c.tau_adapt and state[_TAU] > 0.0 else c.tau
        return np.concatenate([e, w, [tau]])

    def restart(self, state: np.ndarray) -> None:
        """The low-pass starts again (the fast start's running mean, or the next sample)."""
        state[_READY] = state[_NMEAN] = state[_TACC] = 0.0
        state[_MEAN:_MEAN + 3] = 0.0
        state[_KREADY] = 0.0  # the bias filter's low-passes start again with the inclination's
        state[_NST] = 0.0  # and the adaptive time constant's statistics
        state[_IMN] = 0.0  # and the impulse clip's mean square
        state[_PREADY] = state[_PMAX] = 0.0  # and the low-pass at tau_max (tau_max_parallel)
        state[_EREADY] = 0.0  # and the rate error's regressor (E and its covariance are the gyro's: kept)
        # and the samples counted towards the next decimated updates (bias filter, rate error)
        state[_KTACC] = state[_KNACC] = state[_KAGE] = 0.0
        state[_ETACC] = state[_ENACC] = state[_EAGE] = 0.0
        _block_clear(state)  # and the blocks (slow_interval)
        _adapt_clear(state)

    def compose(self, state, quat, sample, bias, rate, flags, channel=None):
        if sample.acc is not None:
            qg = paired(quat, self.config.acc_delay, rate, sample.gyr, bias, sample.dt)
            r = quat_to_matrix(qg)
            y = state[_Y:_Y + 3]
            z = r.T @ (y / np.linalg.norm(y)) if state[_NST] > 0.0 else np.zeros(3)  # the vertical in the body
            w_b = sample.gyr - bias  # (with rate_error_correct: the rate the propagation used, E w removed)
            if self.config.rate_error_correct:
                bias -= state[_EW:_EW + 3]  # the bias itself, for the bias filter
                if not state[_READY]:  # (a restart's fast start: the E w of a sample before it is stale)
                    state[_EW:_EW + 3] = 0.0
            self._tilt(state, r @ sample.acc, quat, bias, sample.dt, bool(flags & _REST), r @ w_b, z, w_b)
            if self.config.rate_error_correct:
                bias += state[_EW:_EW + 3]
            if channel is not None and self._publishing():
                _publish(state, channel)
        return quat_mul(state[_QA:_QA + 4], quat), 0

    def _tilt(self, x, a_i, quat, bias, dt, rest, w_i, z, w_b) -> None:
        c = self.config
        y = x[_Y:_Y + 3]
        par = c.tau_adapt and c.tau_max_parallel
        tau = c.tau
        if c.tau_adapt:  # once per block of slow_interval (0: every sample), on the block's means; the first at once
            tau = x[_TAU]
            if _adapt_add(x, dt, rest, *a_i, *w_i) + 0.5 * dt >= c.slow_interval or x[_NST] == 0.0:
                ma, mw = a_i, w_i  # (slow_interval 0: the block is this sample, its values as they are)
                if c.slow_interval > 0.0:  # the block's means, weighted by time
                    ma = x[_AA:_AA + 3] / x[_ATT]
                    mw = x[_AWS:_AWS + 3] / x[_AWN] if x[_AWN] > 0.0 else np.full(3, math.nan)
                tau = _adapt_step(x, *ma, *mw, *z, x[_AREST] > 0.0, x[_ATT], c.tau, c.adapt_window,
                                  c.bias_sigma_motion, c.bias_sigma_init, c.motion_bias_tau or _FORGET,
                                  math.sqrt(x[_KAP2]) if c.rate_error_estimate else c.gyro_rate_error,
                                  c.tau_min, c.tau_max)
                _adapt_clear(x)
        x[_TACC] += dt
        # durations are sums of dt compared with half a sample of margin (a split run equals one run)
        if c.fast_start and not x[_READY] and x[_TACC] + 0.5 * dt < c.tau:
            x[_NMEAN] += 1.0  # fast start: the running mean of the samples so far
            x[_MEAN:_MEAN + 3] += (a_i - x[_MEAN:_MEAN + 3]) / x[_NMEAN]
            y[:] = x[_MEAN:_MEAN + 3]
        else:
            if x[_DT] != dt:  # the coefficients (and the bias filter's noise), once per distinct dt
                x[_DT] = dt
                if not c.tau_adapt:
                    x[_B:_B + 5] = lowpass_coefficients(c.tau, dt)
                    x[_BTAU] = c.tau
                if c.motion_bias_tau is not None and c.bias_filter == "kalman":
                    x[_N:_N + 5] = _kf_noise(dt, c.motion_bias_tau, c.bias_sigma_init, c.bias_sigma_motion,
                                             c.bias_sigma_rest or 0.0, c.bias_vertical_forgetting)
                if par:
                    x[_PB:_PB + 5] = lowpass_coefficients(c.tau_max, dt)
            sw = par and _parallel_switch(x, tau >= c.tau_max, dt, c.tau_max)
            if sw:  # the low-pass at tau_max replaces the adaptive one (its coefficients, then its delay lines)
                _set_tau(x, *x[_PB:_PB + 5], c.slow_interval == 0.0)
                x[_BTAU] = c.tau_max
            elif c.tau_adapt and abs(tau - x[_TAUC] * dt) > _TAU_STEP * x[_TAUC] * dt:
                x[_TAUC] = tau / dt  # the coefficients of this sample's time constant
                _set_tau(x, *lowpass_coefficients(tau, dt), c.slow_interval == 0.0)
                x[_BTAU] = tau
            if c.impulse_clip is not None:
                a_i = _impulse_clip(x, a_i, dt, c.impulse_clip, c.impulse_window, c.impulse_floor)
            if sw:
                y_old = np.array(_take_parallel(x, *a_i))
            if par:
                _parallel_lowpass(x, *a_i)
            _lowpass_vertical(x, a_i)
            if sw:  # q_tilt turned by the switch's jump: the correction below is the one the old vector asks
                rq = quat_to_matrix(x[_QA:_QA + 4])
                u, w = rq @ y, rq @ y_old
                u, w = u / np.linalg.norm(u), w / np.linalg.norm(w)
                qj = np.array([1.0 + u @ w, *cross(u, w)])
                x[_QA:_QA + 4] = quat_mul(qj / np.linalg.norm(qj), x[_QA:_QA + 4])
        # the smallest rotation taking the low-passed vector (levelled frame) to the vertical
        up = x[_UP:_UP + 3]
        v = quat_to_matrix(x[_QA:_QA + 4]) @ y
        v = v / np.linalg.norm(v)
        qc = np.array([1.0 + v @ up, *cross(v, up)])
        n = np.linalg.norm(qc)
        qc = qc / n if n > 1e-12 else np.array([0.0, *x[_EAST:_EAST + 3]])
        x[_QA:_QA + 4] = quat_mul(qc, x[_QA:_QA + 4])
        if c.motion_bias_tau is not None and c.bias_filter == "kalman" and x[_READY]:
            out = quat_mul(x[_QA:_QA + 4], quat)
            # slow_interval: the bias filter and the rate error once per block of samples (0: every sample)
            if _block_add(x, dt, rest, *w_b, c.rate_error_estimate, *out, 0.5 * c.slow_interval) + 0.5 * dt \
                    >= c.slow_interval:
                s = float(np.linalg.norm(qc[1:]))
                r = qc[1:] * (2.0 * math.atan2(s, qc[0]) / (s * dt)) if s > 0.0 else np.zeros(3)
                if c.slow_interval == 0.0:  # every sample: the inclination's set, rescaled by _set_tau
                    x[_SB:_SB + 5] = x[_B:_B + 5]
                elif x[_SBT] != x[_SLT] or x[_SBTAU] != x[_BTAU]:  # the slow low-passes' set for this block and tau
                    _slow_set(x, x[_SLT], *lowpass_coefficients(x[_BTAU], x[_SLT]))
                res = self._kalman(x, quat_to_matrix(out), r, bias, dt, rest)
                if c.rate_error_estimate and x[_SLWN] > 0.0:  # (a block without a valid gyro: nothing to learn)
                    mw = x[_SLW:_SLW + 3] / x[_SLWN] if c.slow_interval > 0.0 else w_b  # (0: this sample's)
                    _rate_error_step(x, *x[_SLQ:_SLQ + 4], *mw, *res, rest, dt,
                                     c.gyro_rate_error,
                                     1.0 / c.motion_bias_tau, c.rate_error_max, c.rate_error_correct,
                                     c.rate_error_interval, c.rate_error_acc_bias)
                _block_clear(x)
            if c.rate_error_correct and np.all(np.isfinite(w_b)):
                _rate_error_correct(x, *out, *w_b)
        elif c.motion_bias_tau is not None and not rest and x[_READY]:
            # the correction as a rate in the levelled frame is the gyro drift; seen in the body,
            # it is the (horizontal part of the) bias error
            s = float(np.linalg.norm(qc[1:]))
            if s > 0.0:
                r_level = qc[1:] * (2.0 * math.atan2(s, qc[0]) / (s * dt))
                bias_step(bias, r_level, quat_mul(x[_QA:_QA + 4], quat), dt, c.motion_bias_tau, c.bias_max)

    def _kalman(self, x, rot, r, bias, dt, rest) -> np.ndarray:
        """The bias in motion as VQF learns it (``bias_filter="kalman"``). The gyro strapdown drifts
        at ``R (b_true - b)`` in the earth frame; the inclination low-pass sees that drift low-passed,
        so the correction rate ``r`` measures ``LP(R) b_true = -r + LP(R b)`` (the frame's vertical:
        no drift, a weak pseudo-measurement). A fast rotation averages ``LP(R)`` out: the measurement
        then says little, and the gain shrinks with it (mapping ``r`` with the sample's own R would
        put it on the wrong body axes). ``P`` grows by ``sigma_motion^2 dt / motion_bias_tau`` per
        ``dt`` s (per block of ``slow_interval``, by the block's seconds) up to ``sigma_init^2``; a REST
        sample is the rest corrector's measurement of the whole bias (noise ``bias_sigma_rest``): it
        shrinks ``P`` (the bias itself is the rest corrector's).
        With ``slow_interval`` this runs once per block (the state's): the low-passes on the block's
        last rotation, ``P`` grown by the block's seconds, its REST samples one measurement, the update
        (``bias_update_interval``) at the first block end after its interval of motion; a block ending on
        a REST sample passes its samples in motion to the next update (:func:`_carry`: dropped once the
        blocks at REST since outlast four of the inclination's time constants).
        Returns the residual after the update, ``-r + LP(R b) - LP(R) b`` with the frame's vertical
        part of ``LP(R b)`` removed (zeros on a REST sample): what the bias does not explain."""
        c = self.config
        b0, b1, b2, a1, a2 = x[_SB:_SB + 5]  # (the slow low-passes' set: one step per block of slow_interval)
        rb = rot @ bias
        z1, z2, w1, w2 = x[_RZ1:_RZ1 + 9], x[_RZ2:_RZ2 + 9], x[_BZ1:_BZ1 + 3], x[_BZ2:_BZ2 + 3]
        rv = rot.ravel()
        if not x[_KREADY]:  # start in the steady state of this sample
            z1[:], z2[:], w1[:], w2[:] = rv * (1.0 - b0), rv * (b2 - a2), rb * (1.0 - b0), rb * (b2 - a2)
            x[_KREADY] = 1.0
        h = b0 * rv + z1
        z1[:] = b1 * rv - a1 * h + z2
        z2[:] = b2 * rv - a2 * h
        hb = b0 * rb + w1
        w1[:] = b1 * rb - a1 * hb + w2
        w2[:] = b2 * rb - a2 * hb
        h = h.reshape(3, 3)
        v, wm, wv, wr, p0 = x[_N:_N + 5]
        v *= x[_SLT] / dt  # the block's growth: v is one sample's
        p = x[_P:_P + 9].reshape(3, 3)
        for i in range(3):
            if p[i, i] < p0:
                p[i, i] += v
        if x[_SLR] > 0.0 and c.bias_sigma_rest is not None:  # the block's REST samples: one measurement of wr / n
            p -= p @ np.linalg.inv(p + wr / x[_SLR] * np.eye(3)) @ p
        if rest:  # (a block ends on its last sample's status: its samples in motion count towards the next update)
            _carry(x, _KTACC, _SLM, _KAGE)
            return np.zeros(3)
        up = x[_UP:_UP + 3]
        e = -r + hb - up * (up @ hb) - h @ bias
        if c.bias_update_interval > 0.0:  # once per interval of motion, the noise over the samples it spans
            x[_KTACC] += x[_SLM]
            x[_KNACC] += x[_SLMN]
            if x[_KTACC] + 0.5 * dt < c.bias_update_interval:
                return e  # (the residual with the bias as it is)
            wm, wv = wm / x[_KNACC], wv / x[_KNACC]
            x[_KTACC] = x[_KNACC] = x[_KAGE] = 0.0
        else:  # an update per block, the noise over its samples in motion (and those of blocks that ended at REST)
            n = x[_SLMN] + x[_KNACC]
            wm, wv = wm / n, wv / n
            x[_KTACC] = x[_KNACC] = x[_KAGE] = 0.0
        ne = float(np.linalg.norm(e))
        if ne > c.bias_max:
            e *= c.bias_max / ne
        k = p @ h.T @ np.linalg.inv(h @ p @ h.T + wm * np.eye(3) + (wv - wm) * np.outer(up, up))
        bias += k @ e
        p -= k @ h @ p
        nb = float(np.linalg.norm(bias))
        if nb > c.bias_max:
            bias *= c.bias_max / nb
        return -r + hb - up * (up @ hb) - h @ bias

    def kernel(self, estimator) -> CorrectorKernel:
        c = self.config
        p = np.array([c.tau, float(c.fast_start), c.acc_delay if c.acc_delay is not None else math.nan,
                      c.motion_bias_tau if c.motion_bias_tau is not None else 0.0, c.bias_max,
                      float(c.bias_filter == "kalman"), c.bias_sigma_init, c.bias_sigma_motion,
                      c.bias_sigma_rest if c.bias_sigma_rest is not None else 0.0, c.bias_vertical_forgetting,
                      float(c.tau_adapt), c.gyro_rate_error, c.tau_min, c.tau_max, c.adapt_window,
                      c.impulse_clip if c.impulse_clip is not None else 0.0, c.impulse_window, c.impulse_floor,
                      float(c.rate_error_estimate), c.rate_error_max, float(c.rate_error_correct),
                      c.rate_error_interval, c.bias_update_interval, float(self._publishing()),
                      float(c.tau_adapt and c.tau_max_parallel), c.rate_error_acc_bias,
                      1.0 / c.motion_bias_tau if c.motion_bias_tau is not None else 0.0, c.slow_interval])
        static = (c.tau_adapt, p[3] > 0.0, c.bias_filter == "kalman", p[15] != 0.0, c.rate_error_estimate,
                  c.rate_error_correct, c.tau_adapt and c.tau_max_parallel, c.slow_interval > 0.0)
        return CorrectorKernel(inertial_tilt_kernel, p, mode="factor", static=tuple(bool(v) for v in static))


@njit(inline="always")
def inertial_tilt_kernel(q, s, b, g0, g1, g2, h0, h1, h2, h3, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p,
                         ch, adapt, motion_bias, kalman_bias, impulse, rate_est, rate_correct, parallel, slow):
    """The kernel of :meth:`InertialTilt.compose`: ``p = (tau, fast_start, acc_delay (NaN: None),
    motion_bias_tau (0: off), bias_max, kalman (1) or lowpass (0), bias_sigma_init, bias_sigma_motion,
    bias_sigma_rest (0: None), bias_vertical_forgetting, tau_adapt, gyro_rate_error, tau_min, tau_max,
    adapt_window, impulse_clip (0: None), impulse_window, impulse_floor, rate_error_estimate, rate_error_max,
    rate_error_correct, rate_error_interval, bias_update_interval, publish (1: a corrector reads the channel),
    tau_max_parallel (with tau_adapt), rate_error_acc_bias, 1 / motion_bias_tau (0: off), slow_interval)``;
    ``ch`` the pipeline's channel; the compile-time options (``static``, :meth:`InertialTilt.kernel`), which ``p``
    holds too: tau_adapt, the bias in motion (motion_bias_tau), its Kalman filter, impulse_clip,
    rate_error_estimate, rate_error_correct, tau_max_parallel and slow_interval > 0 (eight: a call of more than 30
    arguments is compiled by CPython as one with ``*args``, which numba cannot inline)."""
    if acc_ok:
        p0, p1, p2, p3 = k_paired(q, p[2], h0, h1, h2, h3, g0, g1, g2, b, dt)
        v0, v1, v2 = k_rot(p0, p1, p2, p3, a0, a1, a2)
        tau = p[0]
        wb0, wb1, wb2 = g0 - b[0], g1 - b[1], g2 - b[2]  # the body rate before the bias filter's update
        if rate_correct:  # rate_error_correct: the bias itself, for the bias filter
            b[0], b[1], b[2] = b[0] - s[_EW], b[1] - s[_EW + 1], b[2] - s[_EW + 2]
            if s[_READY] == 0.0:  # (a restart's fast start: the E w of a sample before it is stale)
                s[_EW], s[_EW + 1], s[_EW + 2] = 0.0, 0.0, 0.0
        if adapt:  # (once per block of slow_interval, on the block's means; the first at once)
            w0, w1, w2 = k_rot(p0, p1, p2, p3, wb0, wb1, wb2)
            tau = s[_TAU]
            if _k_adapt_add(s, dt, (flags & _REST) != 0, v0, v1, v2, w0, w1, w2) + 0.5 * dt >= p[27] \
                    or s[_NST] == 0.0:
                z0 = z1 = z2 = 0.0
                if s[_NST] > 0.0:  # the vertical in the body
                    rn = 1.0 / math.sqrt(s[_Y] * s[_Y] + s[_Y + 1] * s[_Y + 1] + s[_Y + 2] * s[_Y + 2])
                    z0, z1, z2 = k_rot(p0, -p1, -p2, -p3, s[_Y] * rn, s[_Y + 1] * rn, s[_Y + 2] * rn)
                ma0, ma1, ma2, mw0, mw1, mw2 = v0, v1, v2, w0, w1, w2  # (slow_interval 0: this sample's)
                if slow:  # the block's means, weighted by time
                    na, nw = s[_ATT], s[_AWN]
                    ma0, ma1, ma2 = s[_AA] / na, s[_AA + 1] / na, s[_AA + 2] / na
                    mw0 = mw1 = mw2 = math.nan
                    if nw > 0.0:
                        mw0, mw1, mw2 = s[_AWS] / nw, s[_AWS + 1] / nw, s[_AWS + 2] / nw
                tau = _k_adapt_step(s, ma0, ma1, ma2, mw0, mw1, mw2, z0, z1, z2,
                                    s[_AREST] > 0.0, s[_ATT], p[0], p[14], p[7], p[6], p[3] if motion_bias else _FORGET,
                                    math.sqrt(s[_KAP2]) if rate_est else p[11], p[12], p[13])
                _k_adapt_clear(s)
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
                if not adapt:
                    s[_B], s[_B + 1], s[_B + 2], s[_B + 3], s[_B + 4] = _lp_coeffs(p[0], dt)
                    s[_BTAU] = p[0]
                if motion_bias and kalman_bias:
                    s[_N], s[_N + 1], s[_N + 2], s[_N + 3], s[_N + 4] = _k_kf_noise(dt, p[3], p[6], p[7], p[8], p[9])
                if parallel:
                    s[_PB], s[_PB + 1], s[_PB + 2], s[_PB + 3], s[_PB + 4] = _lp_coeffs(p[13], dt)
            sw = parallel and _k_parallel_switch(s, tau >= p[13], dt, p[13])
            if sw:
                _k_set_tau(s, s[_PB], s[_PB + 1], s[_PB + 2], s[_PB + 3], s[_PB + 4], not slow)
                s[_BTAU] = p[13]
            elif adapt and abs(tau - s[_TAUC] * dt) > _TAU_STEP * s[_TAUC] * dt:
                s[_TAUC] = tau / dt
                t0, t1, t2, t3, t4 = _lp_coeffs(tau, dt)
                _k_set_tau(s, t0, t1, t2, t3, t4, not slow)
                s[_BTAU] = tau
            if impulse:
                v0, v1, v2 = _k_impulse_clip(s, v0, v1, v2, dt, p[15], p[16], p[17])
            o0 = o1 = o2 = 0.0
            if sw:
                o0, o1, o2 = _k_take_parallel(s, v0, v1, v2)
            if parallel:
                _k_parallel_lowpass(s, v0, v1, v2)
            y0, y1, y2 = _k_lowpass_vertical(s, v0, v1, v2)
            if sw:  # q_tilt turned by the switch's jump (the reference's comment)
                u0, u1, u2 = k_rot(s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3], y0, y1, y2)
                w0, w1, w2 = k_rot(s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3], o0, o1, o2)
                ru = 1.0 / math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
                rw = 1.0 / math.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
                u0, u1, u2, w0, w1, w2 = u0 * ru, u1 * ru, u2 * ru, w0 * rw, w1 * rw, w2 * rw
                j0 = 1.0 + u0 * w0 + u1 * w1 + u2 * w2
                j1, j2, j3 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
                rj = 1.0 / math.sqrt(j0 * j0 + j1 * j1 + j2 * j2 + j3 * j3)
                t0, t1, t2, t3 = k_qmul(j0 * rj, j1 * rj, j2 * rj, j3 * rj, s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3])
                s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3] = t0, t1, t2, t3
        # the rotation taking v = R(q_tilt) y to the vertical, (1 + v.u, v x u) for v unit, taken as (|v| + v.u,
        # v x u) for v as it is and normalised once: |v| = |y| (a rotation keeps the norm), whose square root
        # runs beside the rotation instead of after it (the loop is bound by the chain of divisions and square
        # roots from one sample's output to the next)
        ny = math.sqrt(s[_Y] * s[_Y] + s[_Y + 1] * s[_Y + 1] + s[_Y + 2] * s[_Y + 2])
        v0, v1, v2 = k_rot(s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3], s[_Y], s[_Y + 1], s[_Y + 2])
        u0, u1, u2 = s[_UP], s[_UP + 1], s[_UP + 2]
        c0, c1, c2, c3 = ny + v0 * u0 + v1 * u1 + v2 * u2, v1 * u2 - v2 * u1, v2 * u0 - v0 * u2, v0 * u1 - v1 * u0
        # q_tilt and the output turned by the correction before it is normalised, then scaled by 1 / |c| (the
        # reference's (c / |c|) (x) q_tilt and (c / |c|) (x) q_tilt (x) q_gyr to rounding): both products, and
        # q_tilt (x) q_gyr, run beside the square root and the division instead of after them
        x0, x1, x2, x3 = s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3]
        o0, o1, o2, o3 = k_qmul(x0, x1, x2, x3, q[0], q[1], q[2], q[3])
        n = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2 + c3 * c3)
        if n > 1e-12 * ny:
            t0, t1, t2, t3 = k_qmul(c0, c1, c2, c3, x0, x1, x2, x3)
            e0, e1, e2, e3 = k_qmul(c0, c1, c2, c3, o0, o1, o2, o3)
            rn = 1.0 / n
            t0, t1, t2, t3, e0, e1, e2, e3 = t0 * rn, t1 * rn, t2 * rn, t3 * rn, e0 * rn, e1 * rn, e2 * rn, e3 * rn
            c0, c1, c2, c3 = c0 * rn, c1 * rn, c2 * rn, c3 * rn
        else:
            c0, c1, c2, c3 = 0.0, s[_EAST], s[_EAST + 1], s[_EAST + 2]
            t0, t1, t2, t3 = k_qmul(c0, c1, c2, c3, x0, x1, x2, x3)
            e0, e1, e2, e3 = k_qmul(c0, c1, c2, c3, o0, o1, o2, o3)
        s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3] = t0, t1, t2, t3  # (e: the output, and the bias step's q6)
        if motion_bias and kalman_bias and s[_READY] != 0.0:
            # the correction as a rate is read only by an update (the bias filter's, or the rate error's, each once
            # per interval of motion: the tests below are theirs, on the sums they will have); on the samples
            # between, its square root, division and series are left out (0: a residual nothing reads)
            # (slow_interval: the bias filter and the rate error once per block of samples; 0: every sample)
            rest = (flags & _REST) != 0
            if _k_block_add(s, dt, rest, wb0, wb1, wb2, rate_est, e0, e1, e2, e3, 0.5 * p[27]) + 0.5 * dt >= p[27]:
                f = 0.0
                if not rest and (p[22] <= 0.0 or s[_KTACC] + s[_SLM] + 0.5 * dt >= p[22] or (
                        rate_est and s[_ETACC] + s[_SLE] + 0.5 * dt >= p[21])):
                    sn = math.sqrt(c1 * c1 + c2 * c2 + c3 * c3)
                    f = 2.0 * _atan_over(sn, c0) / dt if sn > 0.0 else 0.0
                if not slow:  # every sample: the inclination's set, rescaled by _k_set_tau
                    for i in range(5):
                        s[_SB + i] = s[_B + i]
                elif s[_SBT] != s[_SLT] or s[_SBTAU] != s[_BTAU]:
                    t0, t1, t2, t3, t4 = _lp_coeffs(s[_BTAU], s[_SLT])
                    _k_slow_set(s, s[_SLT], t0, t1, t2, t3, t4)
                f0, f1, f2 = _k_kalman(s, b, e0, e1, e2, e3, c1 * f, c2 * f, c3 * f, rest, dt, p)
                if rate_est and s[_SLWN] > 0.0:
                    mw0, mw1, mw2 = wb0, wb1, wb2  # (slow_interval 0: this sample's)
                    if slow:  # the block's mean, weighted by time
                        nw = s[_SLWN]
                        mw0, mw1, mw2 = s[_SLW] / nw, s[_SLW + 1] / nw, s[_SLW + 2] / nw
                    _k_rate_error_step(s, s[_SLQ], s[_SLQ + 1], s[_SLQ + 2], s[_SLQ + 3], mw0,
                                       mw1, mw2, f0, f1, f2, rest, dt, p[11], p[26], p[19],
                                       rate_correct, p[21], p[25])
                _k_block_clear(s)
            if rate_correct and math.isfinite(wb0) and math.isfinite(wb1) and math.isfinite(wb2):
                _k_rate_error_correct(s, e0, e1, e2, e3, wb0, wb1, wb2)
        elif motion_bias and (flags & _REST) == 0 and s[_READY] != 0.0:
            sn = math.sqrt(c1 * c1 + c2 * c2 + c3 * c3)
            if sn > 0.0:
                f = 2.0 * _atan_over(sn, c0) / dt
                k_bias_step(b, e0, e1, e2, e3, c1 * f, c2 * f, c3 * f, dt / p[3], p[4])
        if rate_correct:  # rate_error_correct: the next propagation removes this sample's E w
            b[0], b[1], b[2] = b[0] + s[_EW], b[1] + s[_EW + 1], b[2] + s[_EW + 2]
        q[0], q[1], q[2], q[3] = e0, e1, e2, e3
        if p[23] != 0.0:  # (tau_adapt, and something reads it)
            _k_publish(s, ch)
        return 0
    q[0], q[1], q[2], q[3] = k_qmul(s[_QA], s[_QA + 1], s[_QA + 2], s[_QA + 3], q[0], q[1], q[2], q[3])
    return 0
