"""The ``recommended`` filter: the best of what the sources and the state of the art do, composed.

Orientation is split into three factors, each corrected by one sensor only (source 002's channel
separation, method 2, taken to its end):

``q = Rz(delta) (x) q_tilt (x) q_gyr``

1. ``q_gyr``: the gyroscope strapdown (exact exponential of ``(w - bias) dt``) from the body to an
   "almost inertial" frame I. Nothing corrects it.
2. ``q_tilt``: the inclination correction from I to a levelled frame. The specific force is
   rotated into I and low-passed there (second-order Butterworth, time constant ``tau_acc``).
   In I, gravity is a constant (up to the slow gyro drift) and linear accelerations integrate to
   velocity changes, which average out: the low-passed vector is gravity, free of the lag a
   body-frame low-pass has under rotation. Each sample ``q_tilt`` is turned by the smallest
   rotation (about a horizontal axis) that makes it vertical.
3. ``delta``: heading only, a rotation about the vertical. The magnetometer, seen in the
   levelled frame, gives a heading; ``delta`` follows it with time constant ``tau_mag``. A
   magnetic disturbance can only reach heading: roll and pitch are those of a magnetometer-free
   run (tested to 1e-12).

Around it, each switchable (``tests/test_recommended.py`` shows each one doing its job):

- **rest detection and bias re-estimation** (``rest``, ``rest_bias``): the ``rest`` detector;
  at rest the bias follows the low-passed gyroscope with time constant ``rest_bias_tau``.
- **bias estimation in motion** (``motion_bias_tau``): the inclination correction, turned into
  a body rate, is the gyro's drift on the horizontal axes; the bias integrates it with this time
  constant (slow: linear accelerations must average out), limited to ``bias_max``.
  With ``mag_bias`` the heading correction teaches the vertical part too (off by default: on
  BROAD it costs 0.08 deg, and it is the one path by which the magnetometer reaches roll and
  pitch).
- **magnetic disturbance detection and rejection** (``mag_rejection``, settings in ``magnetic``):
  the ``magnetic`` detector (:mod:`fusionkit.detectors.magnetic`) learns the field's norm and
  dip (in the levelled frame) at the start; a sample whose norm or dip departs from them by more
  than its thresholds is not used (flag MAG_DISTURBED). Recovery: undisturbed samples keep the
  reference tracking slowly; a new field that stays consistent for ``magnetic.new_time`` s
  *while the sensor turns* (a field constant in the earth frame, not one carried along with the
  body) becomes the new reference.
- **acceleration rejection** (``acc_gate``, off by default): samples whose ``| |a| - g |``
  exceeds the gate are left out of the low-pass (flag ACC_REJECTED). Measured on BROAD it costs
  accuracy (0.72 -> 6.1 deg 6D inclination at 4 m/s^2): leaving out the large samples makes the
  linear accelerations' average nonzero, which is exactly what the I-frame low-pass relies on.
- **fast start** (``fast_start``): for the first ``tau_acc`` s the low-pass is replaced by the
  running mean of the samples so far (from the first sample on, no start transient), and the
  heading and field reference are the mean over the first ``magnetic.init_time`` s. Off: the
  low-pass and the heading start from the first sample.
- **output lead** (``output_lead``, 0 by default): the output is predicted ahead by the gyro rate,
  ``q (x) exp((w - bias) lead)``, to compensate a gyroscope that is late against the time base
  (its filter's group delay); the state is not changed. ``fusionkit lags`` measures the delay
  against a reference (:mod:`fusionkit.benchmarking.timing`): on every BROAD trial the gyroscope
  is 1.2 samples behind the optical reference, 0.7 samples (2.45 ms) later than fusionkit's
  convention, while the accelerometer is near it (0.4-0.8). A lead there is a property of that
  hardware, not a default for every sensor.
- **sensor pairing** (``acc_delay``, ``mag_delay``): gyro sample k's step covers
  ``(t[k-1], t[k]]`` and ends at ``q_gyr``. An accelerometer or magnetometer sampled like the
  gyro describes the middle of that step (a mean over the interval is centred there; with point
  samples the step itself runs half a sample ahead of ``t[k]``), so by default (None) each
  specific force is rotated into I with ``q_gyr (x) exp(-(w - bias) dt / 2)`` and each field
  into the levelled frame with ``q6 (x) exp(-(w - bias) dt / 2)``. 0 pairs the sample with the
  end of the step (a sensor sampled at ``t[k]`` next to a mean-rate gyro, the simulator's
  ``sampling="point"``); a larger value serves a sensor later than the gyroscope (a longer
  filter). The wrong choice costs a rotation of ``|w| dt / 2`` about the rotation axis (on a
  100 Hz simulation at 2 rad/s: 0.19 deg inclination, 0.07 deg heading; tested both ways). On
  BROAD the defaults give 0.72 deg 6D inclination (0.79 at the end of the step) and 2.15 deg 9D
  total (2.19). A longer pairing helps there too (a one-sample ``acc_delay`` gives 0.68, a
  one-sample ``mag_delay`` 2.09; BENCHMARKS.md), but not because BROAD's accelerometer is late:
  it is near the convention (``fusionkit lags``), and on simulated data a longer ``acc_delay``
  does not make up for a late gyro, it adds to its error. Why it helps on BROAD is not known.

Bad input (judged by :func:`fusionkit.types.sample_validity`, docs/reliability.md): an invalid
gyroscope sample holds the state (GYR_INVALID); an invalid accelerometer (free fall, dropout, a
glitch beyond 16 g, a reading at ``acc_range``) or magnetometer sample skips its correction
(ACC_INVALID / ACC_SATURATED / MAG_INVALID). After a timestamp gap (GAP, the state held across
it) and after a saturated gyro (GYR_SATURATED) the inclination restarts (:meth:`_relevel`):
the gravity seen in I before has become stale; heading and bias are held. The state cannot
become NaN (tested).

Computed in ENU (z up, y north); the output is turned into ``frame``. The readable reference is
:meth:`RecommendedFilter._step`; the numba loop :func:`_rec_loop` does the same arithmetic
(tests hold them to 1e-9 on every sample).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from .._kernels import rotvec_quat, validity_flags
from .._numba import njit
from ..config import FilterConfig, param
from ..detectors.magnetic import (MAG_COUNT, MAG_DISTURBED, MAG_LEARNING, MAG_SIZE, MagneticConfig,
                                  MagneticDetector, field_norm_dip, magnetic_step)
from ..detectors.rest import REST_SIZE, RestConfig, RestDetector, rest_step
from ..protocols import Sample
from ..rotations import quat_from_rotvec, quat_mul, quat_normalize, quat_to_matrix, wrap_angle
from ..types import Flag, sample_validity
from ._step_filter import StepFilter

__all__ = ["RecommendedFilter", "RecommendedConfig", "lowpass_coefficients"]

# state layout
_QG, _QA, _DELTA, _Z1, _Z2, _MEAN, _NMEAN, _TACC, _READY, _BIAS, _Y = 0, 4, 8, 9, 12, 15, 18, 19, 20, 21, 24
_REST = 27
_MAG = _REST + REST_SIZE  # the magnetic disturbance detector's state
_SIZE = _MAG + MAG_SIZE


class RecommendedConfig(FilterConfig):
    tau_acc: float = param(
        2.0, unit="s", description="time constant of the inclination low-pass (in the almost-inertial frame)", gt=0)
    tau_mag: float = param(15.0, unit="s", description="time constant of the heading correction", gt=0)
    use_mag: bool = param(True, unit="-", description="use the magnetometer when the recording has one (9D)")
    fast_start: bool = param(
        True, unit="-", description="running means instead of the low-passes at the start (first tau_acc s, "
        "magnetic.init_time s)")
    rest: RestConfig = param(RestConfig(), unit="-", description="the rest detector")
    rest_bias: bool = param(True, unit="-", description="re-estimate the gyro bias at rest")
    rest_bias_tau: float = param(1.0, unit="s", description="time constant of the bias at rest", gt=0)
    motion_bias_tau: float | None = param(
        100.0, unit="s", description="time constant of the bias estimation in motion; None: off", gt=0)
    bias_max: float = param(math.radians(2.0), unit="rad/s", description="largest bias estimated in motion", gt=0)
    mag_bias: bool = param(
        False, unit="-", description="the in-motion bias also learns from the heading correction (vertical axis); "
        "lets the magnetometer reach roll and pitch through the bias (costs 0.08 deg on BROAD)")
    mag_rejection: bool = param(True, unit="-", description="reject magnetic disturbances (the magnetic detector)")
    magnetic: MagneticConfig = param(
        MagneticConfig(), unit="-", description="the magnetic disturbance detector (its init_time is the fast start's "
        "heading averaging; 0 without fast_start)")
    acc_gate: float | None = param(
        None, unit="m/s^2", description="leave out samples with | |a| - gravity | above this; None: off "
        "(costs accuracy on BROAD, see the module docs)", gt=0)
    gravity: float = param(9.81, unit="m/s^2", description="g for acc_gate", gt=0)
    output_lead: float = param(
        0.0, unit="s", description="output the orientation this far ahead, q (x) exp((w - bias) lead): compensates a "
        "known delay of the gyroscope against the time base (its filter's group delay; `fusionkit lags` measures it: "
        "on BROAD 0.7 samples, see BENCHMARKS.md); the state is not changed. 0: the estimate itself", ge=0)
    acc_delay: float | None = param(
        None, unit="s", description="how long before the end of the gyro's step the accelerometer sample describes: "
        "it is paired with the orientation R(q_gyr (x) exp(-(w - bias) d)). None: half the sample interval, the middle "
        "of the step (right when both sensors are sampled alike: point samples, or means over the interval). 0: the "
        "end of the step (an accelerometer sampled at the instant a mean-rate gyro's interval ends). Larger: an "
        "accelerometer later than the gyroscope (a longer filter; `fusionkit lags` measures it against a reference)")
    mag_delay: float | None = param(
        None, unit="s", description="the same for the magnetometer: it is paired with R(q (x) exp(-(w - bias) d)). "
        "None: half the sample interval (the middle of the step); 0: the end of the step")


def lowpass_coefficients(tau: float, dt: float) -> tuple[float, float, float, float, float]:
    """Second-order Butterworth low-pass (bilinear transform, cutoff ``1 / (2 pi tau)``):
    ``(b0, b1, b2, a1, a2)`` of ``y = b0 x + b1 x' + b2 x'' - a1 y' - a2 y''``; unit gain at DC."""
    k = math.tan(0.5 * dt / tau)
    n = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b0 = k * k * n
    return b0, 2.0 * b0, b0, 2.0 * (k * k - 1.0) * n, (1.0 - math.sqrt(2.0) * k + k * k) * n


_lp_coeffs = njit(lowpass_coefficients)


_wrap = wrap_angle
_kwrap = njit(wrap_angle)


def _paired(q_end, q_mid, delay, rate, gyr_ok):
    """The orientation a sample belongs to (``acc_delay`` / ``mag_delay``): ``q_mid``, the middle of
    the step (``delay`` None); ``q_end (x) exp(-rate delay)``, ``delay`` before its end; or ``q_end``
    (0, or no valid gyro sample)."""
    if delay is None:
        return q_mid
    if delay != 0.0 and gyr_ok:
        return quat_mul(q_end, quat_from_rotvec(-rate * delay))
    return q_end


class RecommendedFilter(StepFilter):
    """Gyro strapdown + inclination from the inertially low-passed accelerometer + separate
    heading from the magnetometer; rest/motion bias, magnetic disturbance rejection, fast start."""

    name: ClassVar[str] = "recommended"
    Config = RecommendedConfig
    source: ClassVar[str] = "fusionkit (sources 000-003 composed with the state of the art)"
    summary: ClassVar[str] = "channel-separated inclination/heading, inertial low-pass, bias and disturbance handling"
    state_size: ClassVar[int] = _SIZE

    def __init__(self, config=None, **params: Any) -> None:
        super().__init__(config, **params)
        self.rest_detector = RestDetector(self.config.rest)
        mc = self.config.magnetic
        self.magnetic = MagneticDetector(mc if self.config.fast_start else mc.model_copy(update={"init_time": 0.0}))

    def new_state(self) -> np.ndarray:
        x = np.zeros(_SIZE)
        x[_QG] = x[_QA] = 1.0
        return x

    def _kernel(self):
        return _rec_loop

    def _diagnostics(self, x) -> dict:
        return {"bias": x[_BIAS:_BIAS + 3].copy(), "mag_reference": (x[_MAG], x[_MAG + 1])}

    def _relevel(self, x) -> None:
        """After a timestamp gap or a saturated gyro the inclination restarts (the fast start's
        running mean, or the low-pass from the next sample): the gravity seen in I before is
        stale. Heading, bias and the detectors' states are held."""
        x[_READY] = x[_NMEAN] = x[_TACC] = 0.0
        x[_MEAN:_MEAN + 3] = 0.0

    def params(self) -> np.ndarray:
        """The kernel's parameter vector."""
        c = self.config
        return np.array([
            c.tau_acc, c.tau_mag, float(c.fast_start), c.rest.tau, c.rest.gyr_threshold, c.rest.acc_threshold,
            c.rest.max_rate, c.rest.min_time, float(c.rest_bias), c.rest_bias_tau,
            c.motion_bias_tau if c.motion_bias_tau is not None else 0.0, c.bias_max, float(c.mag_rejection),
            *self.magnetic.params(), c.acc_gate if c.acc_gate is not None else math.inf, c.gravity,
            c.gyr_range if c.gyr_range is not None else math.inf,
            c.acc_range if c.acc_range is not None else math.inf, float(c.use_mag), float(c.mag_bias), c.output_lead,
            c.acc_delay if c.acc_delay is not None else math.nan,
            c.mag_delay if c.mag_delay is not None else math.nan,
        ])

    # -- the readable reference --------------------------------------------------------------
    def _step(self, x: np.ndarray, gyr, acc, mag, dt: float) -> tuple[np.ndarray, int]:
        """One sample (``mag`` None without a magnetometer); returns (q body->frame, flags)."""
        # Durations (fast start) are sums of dt compared with half a sample of margin, so that the
        # sample count does not hinge on the last bit of the sum (a split run equals one run).
        c = self.config
        gyr_ok, acc_ok, mag_ok, flags = sample_validity(gyr, acc, mag if c.use_mag else None, c.gyr_range,
                                                        c.acc_range)
        bias = x[_BIAS:_BIAS + 3]
        rest_state = x[_REST:_REST + REST_SIZE]

        # 1. rest detection; at rest the bias follows the low-passed gyroscope
        rest = False
        if gyr_ok and acc_ok:
            rest = bool(self.rest_detector.step(rest_state, Sample(gyr, acc, None, dt)))
            if rest:
                flags |= Flag.REST
                if c.rest_bias:
                    bias += (1.0 - math.exp(-dt / c.rest_bias_tau)) * (RestDetector.lowpassed_gyr(rest_state) - bias)

        # 2. gyroscope strapdown, body -> I, in two half steps; q_mid: the middle of the step
        q_mid = x[_QG:_QG + 4].copy()
        if gyr_ok:
            half_step = quat_from_rotvec((gyr - bias) * (0.5 * dt))
            q_mid = quat_mul(q_mid, half_step)
            x[_QG:_QG + 4] = quat_normalize(quat_mul(q_mid, half_step))

        # 3. inclination: the specific force low-passed in I, made vertical by q_tilt
        if acc_ok:
            if c.acc_gate is not None and abs(np.linalg.norm(acc) - c.gravity) > c.acc_gate:
                flags |= Flag.ACC_REJECTED
            else:
                qg = _paired(x[_QG:_QG + 4], q_mid, c.acc_delay, gyr - bias, gyr_ok)
                self._tilt(x, quat_to_matrix(qg) @ acc, dt, rest)
        q6 = quat_mul(x[_QA:_QA + 4], x[_QG:_QG + 4])

        # 4. heading from the magnetometer, about the vertical only
        if mag_ok:
            qm = _paired(q6, quat_mul(x[_QA:_QA + 4], q_mid), c.mag_delay, gyr - bias, gyr_ok)
            flags |= self._heading(x, quat_to_matrix(qm) @ mag, q6, dt, rest)
        half = 0.5 * x[_DELTA]
        q = quat_mul(np.array([math.cos(half), 0.0, 0.0, math.sin(half)]), q6)
        if c.output_lead > 0.0 and gyr_ok:  # a prediction for the output only
            q = quat_mul(q, quat_from_rotvec((gyr - bias) * c.output_lead))
        return quat_mul(self.qf, q), flags

    def _tilt(self, x, a_i, dt, rest) -> None:
        c = self.config
        y = x[_Y:_Y + 3]
        x[_TACC] += dt
        if c.fast_start and not x[_READY] and x[_TACC] + 0.5 * dt < c.tau_acc:  # margin: see _step
            x[_NMEAN] += 1.0  # fast start: the running mean of the samples so far
            x[_MEAN:_MEAN + 3] += (a_i - x[_MEAN:_MEAN + 3]) / x[_NMEAN]
            y[:] = x[_MEAN:_MEAN + 3]
        else:
            b0, b1, b2, a1, a2 = lowpass_coefficients(c.tau_acc, dt)
            z1, z2 = x[_Z1:_Z1 + 3], x[_Z2:_Z2 + 3]
            if not x[_READY]:  # start in the steady state of the mean (or of the first sample)
                start = x[_MEAN:_MEAN + 3] if x[_NMEAN] > 0 else a_i
                z1[:], z2[:] = start * (1.0 - b0), start * (b2 - a2)
                x[_READY] = 1.0
            y[:] = b0 * a_i + z1  # transposed direct form II
            z1[:] = b1 * a_i - a1 * y + z2
            z2[:] = b2 * a_i - a2 * y
        # the smallest rotation taking the low-passed vector (levelled frame) to the vertical
        v = quat_to_matrix(x[_QA:_QA + 4]) @ y
        v = v / np.linalg.norm(v)
        qc = np.array([1.0 + v[2], v[1], -v[0], 0.0])
        n = np.linalg.norm(qc)
        qc = qc / n if n > 1e-12 else np.array([0.0, 1.0, 0.0, 0.0])
        x[_QA:_QA + 4] = quat_mul(qc, x[_QA:_QA + 4])
        if c.motion_bias_tau is not None and not rest and x[_READY]:
            # the correction as a rate in the levelled frame is the gyro drift; seen in the body,
            # it is the (horizontal part of the) bias error
            s = math.hypot(qc[1], qc[2])
            if s > 0.0:
                angle = 2.0 * math.atan2(s, qc[0])
                r_level = np.array([qc[1], qc[2], 0.0]) * (angle / (s * dt))
                self._bias_from_correction(x, r_level, quat_mul(x[_QA:_QA + 4], x[_QG:_QG + 4]), dt)

    def _bias_from_correction(self, x, r_level, q6, dt) -> None:
        """A correction rate ``r_level`` (levelled frame) means the gyro drifted by ``-r_level``:
        the bias takes it in, seen in the body, with time constant ``motion_bias_tau``."""
        c = self.config
        bias = x[_BIAS:_BIAS + 3]
        bias -= (dt / c.motion_bias_tau) * (quat_to_matrix(q6).T @ r_level)
        nb = np.linalg.norm(bias)
        if nb > c.bias_max:
            bias *= c.bias_max / nb

    def _heading(self, x, m_level, q6, dt, rest) -> int:
        """Heading correction from the field ``m_level`` in the levelled frame; returns flags."""
        c = self.config
        norm, dip = field_norm_dip(m_level, np.array([0.0, 0.0, 1.0]))
        target = 0.5 * math.pi - math.atan2(m_level[1], m_level[0])  # turns the field's azimuth to north
        rate = float(np.linalg.norm(RestDetector.lowpassed_gyr(x[_REST:_REST + REST_SIZE])))
        code = self.magnetic.reference_step(x[_MAG:_MAG + MAG_SIZE], norm, dip, rate, dt)
        if code == MAG_LEARNING:  # start: the heading is the mean over the detector's learning time
            n = x[_MAG + MAG_COUNT]
            x[_DELTA] = _wrap(target if n == 1.0 else x[_DELTA] + _wrap(target - x[_DELTA]) / n)
            return 0
        if code == MAG_DISTURBED and c.mag_rejection:
            return int(Flag.MAG_DISTURBED)
        step = (1.0 - math.exp(-dt / c.tau_mag)) * _wrap(target - x[_DELTA])
        x[_DELTA] = _wrap(x[_DELTA] + step)
        if c.motion_bias_tau is not None and c.mag_bias and not rest:
            # the heading correction as a rate about the vertical: the gyro's vertical drift
            self._bias_from_correction(x, np.array([0.0, 0.0, step / dt]), q6, dt)
        return 0


# ---- the compiled loop (the same arithmetic as RecommendedFilter._step) ----------------------

@njit
def _rot(q, v0, v1, v2, out, transpose):
    """``out = R(q) v`` (or ``R(q)^T v``)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    if transpose:
        x, y, z = -x, -y, -z
    out[0] = (1 - 2 * (y * y + z * z)) * v0 + 2 * (x * y - w * z) * v1 + 2 * (x * z + w * y) * v2
    out[1] = 2 * (x * y + w * z) * v0 + (1 - 2 * (x * x + z * z)) * v1 + 2 * (y * z - w * x) * v2
    out[2] = 2 * (x * z - w * y) * v0 + 2 * (y * z + w * x) * v1 + (1 - 2 * (x * x + y * y)) * v2


@njit
def _qmul(p, q, out):
    p0, p1, p2, p3 = p[0], p[1], p[2], p[3]
    q0, q1, q2, q3 = q[0], q[1], q[2], q[3]
    out[0] = p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3
    out[1] = p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2
    out[2] = p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1
    out[3] = p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0


@njit
def _bias_step(x, e, k, bias_max):
    """``bias -= k e``, limited to ``bias_max`` (RecommendedFilter._bias_from_correction)."""
    for i in range(3):
        x[_BIAS + i] -= k * e[i]
    nb = math.sqrt(x[_BIAS] ** 2 + x[_BIAS + 1] ** 2 + x[_BIAS + 2] ** 2)
    if nb > bias_max:
        for i in range(3):
            x[_BIAS + i] *= bias_max / nb


@njit
def _rec_loop(gyr, acc, mag, dt, has_mag, x, p, qf, out_q, out_f):
    tau_acc, tau_mag, fast_start = p[0], p[1], p[2] != 0.0
    r_tau, r_gyr, r_acc, r_rate, r_time = p[3], p[4], p[5], p[6], p[7]
    rest_bias, rest_bias_tau, mb_tau, bias_max = p[8] != 0.0, p[9], p[10], p[11]
    mag_rej = p[12] != 0.0
    m_init, m_nth, m_dth, m_new_t, m_new_rate, m_ref_tau = p[13], p[14], p[15], p[16], p[17], p[18]
    acc_gate, grav, gyr_range, acc_range, mag_bias, lead = p[19], p[20], p[21], p[22], p[24] != 0.0, p[25]
    acc_delay, mag_delay = p[26], p[27]
    ms = x[_MAG:_MAG + MAG_SIZE]
    rs = x[_REST:_REST + REST_SIZE]
    qg = x[_QG:_QG + 4]
    qa = x[_QA:_QA + 4]
    t4 = np.empty(4)
    u4 = np.empty(4)
    q6 = np.empty(4)
    qm = np.empty(4)
    v3 = np.empty(3)
    l4 = np.empty(4)
    last_dt = -1.0
    b0 = b1 = b2 = a1 = a2 = k_rb = k_mag = 0.0
    for k in range(gyr.shape[0]):
        h = dt[k]
        if h != last_dt:  # coefficients once per distinct dt
            b0, b1, b2, a1, a2 = _lp_coeffs(tau_acc, h)
            k_rb = 1.0 - math.exp(-h / rest_bias_tau)
            k_mag = 1.0 - math.exp(-h / tau_mag)
            last_dt = h
        g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]
        a0, a1_, a2_ = acc[k, 0], acc[k, 1], acc[k, 2]
        m0, m1, m2 = mag[k, 0], mag[k, 1], mag[k, 2]
        gyr_ok, acc_ok, mag_ok, flags = validity_flags(g0, g1, g2, a0, a1_, a2_, m0, m1, m2, has_mag, gyr_range,
                                                                acc_range)
        # 1. rest
        rest = False
        if gyr_ok and acc_ok:
            rest = rest_step(rs, g0, g1, g2, a0, a1_, a2_, h, r_tau, r_gyr, r_acc, r_rate, r_time) == 1
            if rest:
                flags |= 128
                if rest_bias:
                    for i in range(3):
                        x[_BIAS + i] += k_rb * (rs[i] - x[_BIAS + i])
        # 2. strapdown in two half steps; qm: the middle of the step (the default pairing)
        for i in range(4):
            qm[i] = qg[i]
        if gyr_ok:
            hh = 0.5 * h
            rotvec_quat((g0 - x[_BIAS]) * hh, (g1 - x[_BIAS + 1]) * hh, (g2 - x[_BIAS + 2]) * hh, t4)
            _qmul(qg, t4, qm)
            _qmul(qm, t4, u4)
            n = math.sqrt(u4[0] * u4[0] + u4[1] * u4[1] + u4[2] * u4[2] + u4[3] * u4[3])
            for i in range(4):
                qg[i] = u4[i] / n
        # 3. inclination
        if acc_ok:
            if abs(math.sqrt(a0 * a0 + a1_ * a1_ + a2_ * a2_) - grav) > acc_gate:
                flags |= 512
            else:
                if math.isnan(acc_delay):  # the orientation the sample belongs to (as _paired)
                    _rot(qm, a0, a1_, a2_, v3, False)
                elif acc_delay != 0.0 and gyr_ok:
                    d = acc_delay
                    rotvec_quat((x[_BIAS] - g0) * d, (x[_BIAS + 1] - g1) * d, (x[_BIAS + 2] - g2) * d, l4)
                    _qmul(qg, l4, u4)
                    _rot(u4, a0, a1_, a2_, v3, False)
                else:
                    _rot(qg, a0, a1_, a2_, v3, False)
                x[_TACC] += h
                if fast_start and x[_READY] == 0.0 and x[_TACC] + 0.5 * h < tau_acc:
                    x[_NMEAN] += 1.0
                    for i in range(3):
                        x[_MEAN + i] += (v3[i] - x[_MEAN + i]) / x[_NMEAN]
                        x[_Y + i] = x[_MEAN + i]
                else:
                    if x[_READY] == 0.0:
                        for i in range(3):
                            st = x[_MEAN + i] if x[_NMEAN] > 0 else v3[i]
                            x[_Z1 + i] = st * (1.0 - b0)
                            x[_Z2 + i] = st * (b2 - a2)
                        x[_READY] = 1.0
                    for i in range(3):
                        yi = b0 * v3[i] + x[_Z1 + i]
                        x[_Y + i] = yi
                        x[_Z1 + i] = b1 * v3[i] - a1 * yi + x[_Z2 + i]
                        x[_Z2 + i] = b2 * v3[i] - a2 * yi
                _rot(qa, x[_Y], x[_Y + 1], x[_Y + 2], v3, False)
                n = math.sqrt(v3[0] * v3[0] + v3[1] * v3[1] + v3[2] * v3[2])
                vx, vy, vz = v3[0] / n, v3[1] / n, v3[2] / n
                t4[0], t4[1], t4[2], t4[3] = 1.0 + vz, vy, -vx, 0.0
                n = math.sqrt(t4[0] * t4[0] + t4[1] * t4[1] + t4[2] * t4[2])
                if n > 1e-12:
                    t4[0], t4[1], t4[2] = t4[0] / n, t4[1] / n, t4[2] / n
                else:
                    t4[0], t4[1], t4[2] = 0.0, 1.0, 0.0
                _qmul(t4, qa, u4)
                for i in range(4):
                    qa[i] = u4[i]
                if mb_tau > 0.0 and not rest and x[_READY] != 0.0:
                    s = math.hypot(t4[1], t4[2])
                    if s > 0.0:
                        f = 2.0 * math.atan2(s, t4[0]) / (s * h)
                        _qmul(qa, qg, q6)
                        _rot(q6, t4[1] * f, t4[2] * f, 0.0, v3, True)
                        _bias_step(x, v3, h / mb_tau, bias_max)
        _qmul(qa, qg, q6)
        # 4. heading
        if mag_ok:
            if math.isnan(mag_delay):  # the orientation the sample belongs to (as _paired)
                _qmul(qa, qm, u4)
                _rot(u4, m0, m1, m2, v3, False)
            elif mag_delay != 0.0 and gyr_ok:
                d = mag_delay
                rotvec_quat((x[_BIAS] - g0) * d, (x[_BIAS + 1] - g1) * d, (x[_BIAS + 2] - g2) * d, l4)
                _qmul(q6, l4, u4)
                _rot(u4, m0, m1, m2, v3, False)
            else:
                _rot(q6, m0, m1, m2, v3, False)
            norm = math.sqrt(v3[0] * v3[0] + v3[1] * v3[1] + v3[2] * v3[2])
            dip = math.asin(max(-1.0, min(1.0, v3[2] / norm)))
            target = 0.5 * math.pi - math.atan2(v3[1], v3[0])
            rate = math.sqrt(rs[0] * rs[0] + rs[1] * rs[1] + rs[2] * rs[2])
            code = magnetic_step(ms, norm, dip, rate, h, m_init, m_nth, m_dth, m_new_t, m_new_rate, m_ref_tau)
            if code == MAG_LEARNING:
                n = ms[MAG_COUNT]
                x[_DELTA] = _kwrap(target if n == 1.0 else x[_DELTA] + _kwrap(target - x[_DELTA]) / n)
            elif code == MAG_DISTURBED and mag_rej:
                flags |= 256
            else:
                step = k_mag * _kwrap(target - x[_DELTA])
                x[_DELTA] = _kwrap(x[_DELTA] + step)
                if mb_tau > 0.0 and mag_bias and not rest:
                    _rot(q6, 0.0, 0.0, step / h, v3, True)
                    _bias_step(x, v3, h / mb_tau, bias_max)
        half = 0.5 * x[_DELTA]
        t4[0], t4[1], t4[2], t4[3] = math.cos(half), 0.0, 0.0, math.sin(half)
        _qmul(t4, q6, u4)
        if lead > 0.0 and gyr_ok:  # a prediction for the output only
            r0, r1, r2 = (g0 - x[_BIAS]) * lead, (g1 - x[_BIAS + 1]) * lead, (g2 - x[_BIAS + 2]) * lead
            rotvec_quat(r0, r1, r2, l4)
            _qmul(u4, l4, q6)
            u4[0], u4[1], u4[2], u4[3] = q6[0], q6[1], q6[2], q6[3]
        _qmul(qf, u4, t4)
        out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = t4[0], t4[1], t4[2], t4[3]
        out_f[k] = flags
