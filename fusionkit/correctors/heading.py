"""The heading-only magnetometer correction (``mag-heading``, a factor corrector).

It keeps the factor ``Rz(delta)``, a rotation about the vertical by the heading correction
``delta``, and composes the output ``Rz(delta) (x) q`` from the orientation ``q`` the factors before
it give (``recommended``: ``q_tilt (x) q_gyr``, levelled). The field, seen in that levelled frame,
gives a heading (the angle that turns its horizontal part to north); ``delta`` follows it with time
constant ``tau`` (``gain="fixed"``) or with a gain from the heading's variance (``gain="kalman"``).
A rotation about the vertical cannot change roll and pitch: a magnetic disturbance reaches heading
only (source 002's channel separation; tested to 1e-12).

Around it, each a separate idea:

- **the gain from the heading's variance** (``gain="kalman"``): a scalar Kalman filter on
  ``delta``. Its variance ``P`` grows every sample with what drifts the heading: the gyro's white
  noise (``gyro_noise``) and the vertical bias and scale errors (``bias_sigma``, ``scale_sigma``),
  which are *considered*, not estimated (a Schmidt-Kalman filter: their covariances with the
  heading make a constant bias drift its standard deviation linearly in time). It grows so
  while the magnetometer is rejected (no measurement), and a magnetometer heading shrinks it
  with the gain ``P / (P + r)``. ``r``: the magnetometer's noise (``mag_noise``) and the field
  errors a calibration leaves (``field_error``, or the sample's own departure from the magnetic
  reference in norm and dip where that is larger: a disturbance under the rejection's thresholds)
  as fractions of the field's strength, divided by the horizontal part ``cos(dip)^2``; the field
  errors change over ``field_error_time`` and count as the white noise of the same low-frequency
  power (``2 e^2 field_error_time / dt``). While the reference is learned at the start, the
  heading's mean is what this filter gives from no prior (``P = r / n``). So after a rejection
  or at the start the gain is high, and in a long clean stretch it settles where drift and
  measurement balance (about ``(r dt / (2 bias_sigma^2))^(1/3)`` s; 11-14 s at the defaults and a
  dip of 60-70 deg). It assumes the field errors uncorrelated beyond ``field_error_time`` and
  the bias error no larger than ``bias_sigma``; it fails where an undetected field error lasts
  longer (a calibration that learned a disturbance as iron) right after a rejection, which
  it then follows faster than the fixed gain (docs/algorithms/recommended.md);

- **the inclination's error in the heading's variance** (``inclination_noise``, with ``gain="kalman"``;
  off by default): read in the levelled frame, the heading turns by ``tan(dip)`` times the
  inclination error about the field's horizontal axis; ``r`` counts that error's variance, which
  ``inertial-tilt`` publishes through the pipeline's channel (:func:`_inclination_noise`), as the
  white noise of the same low-frequency power over its time constant. Without a publisher it adds
  nothing;

- **magnetic disturbance rejection** (``rejection``; settings in ``magnetic``): the ``magnetic``
  detector's reference (:func:`fusionkit.detectors.magnetic.magnetic_step`) judged on the norm and
  dip of the field in the levelled frame (an estimated vertical is better than the
  accelerometer's under motion); a disturbed sample is not used (flag MAG_DISTURBED); a new field
  consistent for ``magnetic.new_time`` s while the sensor turns becomes the reference. The turning
  rate is the gyroscope low-passed with ``rate_tau`` (the ``rest`` detector's low-pass, kept on the
  same samples);
- **following the calibration** (``follow_calibration``): where a sensor model starts, replaces
  or stops the magnetometer's calibration (flag MAG_RECALIBRATED, ``mag-calibration``), the field
  from there on is another one than the reference was learned from (a carried magnet's offset
  removed: another norm and dip), so the reference is learned again over ``magnetic.init_time`` s
  (:func:`fusionkit.detectors.magnetic.follow_field`), as at the start, unless the reference
  describes that first sample of it (a calibrated field has the same norm and dip at every
  orientation, so one sample tells; a small calibration changes nothing) or the calibration cannot
  be what took it off the reference (:func:`_moved`: it moved the field by less than the thresholds
  and the field was off the reference before it too, an earth-fixed disturbance), except where the
  heading was re-expressed through it (below: the field the reference and heading were learned from,
  read through the new calibration, is this calibrated sample's, so the iron was there then and the
  departure before was the iron's). It assumes the learning
  seconds undisturbed, and the new-field test recovers where they were not. The heading keeps its
  filter meanwhile (no fast-start mean: it has a heading to follow from). False: the reference
  learned before is kept (calibrated samples of a large offset then look disturbed);
- **the heading re-expressed through the calibration** (``reexpress``, with ``follow_calibration``): a
  heading learned from the raw field of a magnetised body carries the iron's error at the orientation
  it was learned in, and the filter's variance does not know it. At a recalibration the field the
  heading was learned from is read through the new calibration (its mean plus the calibration's
  change of the field, this sample against the previous one, turned by the learning's mean
  orientation); where that matches the calibrated sample's norm and dip within a calibrated
  sample's precision and better than the learned field does (the iron was there when the heading
  was learned), the heading moves by the change of the learned field's heading (:func:`_reexpress`),
  as if it had been learned through the calibration. Where it is closer than the learned field but not
  yet within that precision (a calibration still imprecise, as ``mag-calibration``'s provisional
  offset) the move is deferred: nothing moves, the change is kept and summed with the next
  recalibration's, judged with as many changes' noise as it sums, and the heading moves then; a next
  change that undoes it (the sum within the noise) drops it. It assumes the calibration's change the same
  for the learned field as for this sample (a hard iron; a soft iron's change differs by its
  distortion of the two fields' difference); where the norm and dip do not tell the two apart (an
  iron across the field at the learning's orientation) it can move the heading by the iron's
  effect there though the iron came later;
- **fast start**: while the reference is learned (the first ``magnetic.init_time`` s), ``delta``
  is the mean heading of the samples so far; ``init_time = 0``: it starts from the first sample;
- **vertical bias** (``mag_bias``, with ``motion_bias_tau``): the correction as a rate about the
  vertical is the gyro's vertical drift; the pipeline's gyro bias takes it in (off by default: it
  is the one path by which the magnetometer reaches roll and pitch);
- **sensor pairing** (``mag_delay``): as ``inertial-tilt``'s ``acc_delay`` (None: the middle of the
  gyro's step);
- **sample and hold** (``mag_hold``): a magnetometer read at a lower rate than the gyro repeats its
  last reading until the next one; a sample equal to the previous one (every component exactly) is
  that held reading, as old as the samples since it changed, so it is paired with the orientation
  its fresh sample was paired with (its age is part of its delay); so is one a sensor model
  flags MAG_HELD (the reading repeated, calibrated otherwise since: ``mag-calibration`` changed
  its calibration on it). Where values never repeat it changes nothing;
- **the magnetometer's delay, estimated** (``mag_delay_estimate``, off by default): the
  ``time-offset`` model's estimate of the gyro's delay against the magnetometer (a late sensor
  leaves a residual proportional to the angular acceleration, ``fusionkit/models/time_offset.py``),
  computed here from the field's direction at two fresh samples ``_SEGMENT_TIME`` apart and the
  orientations the configured pairing gives them, so it is the *remaining* offset of that
  pairing. Only samples the magnetic reference uses enter (not while it learns, not disturbed)
  and, once the estimate is applied, no segment whose residual ``|r - d x|`` is over
  ``_RESIDUAL_GATE`` times the fit's RMS (a magnet moving with the body, an unrejected
  disturbance; earlier the gate would favour the segments that agree with an estimate still far
  off). Once its standard deviation is below ``delay_max_std`` samples the pairing is the
  configured one moved by the estimate (before that the configured one, to the bit). The output
  stays on the gyroscope's clock: the magnetometer is moved onto it.

Assumes: the field is homogeneous (the earth's) apart from the disturbances the reference
catches, and the orientation it gets is levelled (an inclination factor or corrector runs
before it). The readable reference is :meth:`MagHeading.compose`; :func:`mag_heading_kernel` does
the same arithmetic (tests: 1e-9 on every sample).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
from pydantic import model_validator

from .._numba import njit
from ..config import PluginConfig, param
from ..detectors.magnetic import (MAG_COUNT, MAG_DISTURBED, MAG_LEARNING, MAG_SIZE, MAG_SOFT, MAG_TIME, MAG_USE,
                                  MagneticConfig, MagneticDetector, field_norm_dip, follow_field, k_follow_field,
                                  magnetic_step)
from ..models.time_offset import _ANC, _DQ, _GA, _LINK, _NORM, _T, _U, CONF, EST, OFFSET, _enter, _k_enter
from ..models.time_offset import _BLOCK as _EST_SIZE
from ..protocols import CorrectorKernel, FactorCorrector
from ..rotations import cross, quat_mul, quat_to_matrix, wrap_angle
from ..types import Channel, Flag
from .._kernels import dcm_entries, rotvec_quat_entries
from ._factor import (atan2_small, bias_step, frame_axes, gyro_lowpass, k_bias_step, k_gyro_lowpass, k_paired, k_qmul,
                      k_rot, paired)

__all__ = ["MagHeadingConfig", "MagHeading", "mag_heading_kernel", "MAG_REFERENCE", "MAG_DELAY", "HEADING_VARIANCE"]

# state: the magnetic reference's state, delta, the low-passed gyro and its sample count, the frame's
# east, north, up axes, and the coefficients for the last dt (k of the heading, k of the gyro low-pass)
# (the reference's state first: the kernel hands the state itself to magnetic_step, no slice per sample)
_MAG, _DELTA, _LW, _SEEN = 0, MAG_SIZE, MAG_SIZE + 1, MAG_SIZE + 4
_AX, _DT, _KM, _KW = MAG_SIZE + 5, MAG_SIZE + 14, MAG_SIZE + 15, MAG_SIZE + 16
# the last magnetometer sample, whether there was one, and the orientation its fresh reading was paired with
_PM, _PMOK, _QH = MAG_SIZE + 17, MAG_SIZE + 20, MAG_SIZE + 21
# the delay estimate: a block laid out as the time-offset model's (its _enter runs on it); _DQ holds the
# orientation the segment's first sample was paired with, _NORM the forgetting-weighted segment count
_EB = MAG_SIZE + 25
_E2 = _EB + _EST_SIZE  # the forgetting-weighted sum of the segments' squared residuals |r - d x|^2
# 1 while the reference is learned again after a recalibration (the heading keeps its filter meanwhile)
_RELEARN = _E2 + 1
# gain "kalman": the heading's variance and its covariances with the vertical gyro bias error and scale error
_PHH, _PHB, _PHS = _E2 + 2, _E2 + 3, _E2 + 4
# cos and sin of delta / 2 (the output's Rz(delta) as a quaternion), turned with delta by each step (:func:`_turn`)
_HC, _HS = _E2 + 5, _E2 + 6
# the previous magnetometer sample's norm and dip in the levelled frame (follow_calibration: did a recalibration
# move the field?)
_PN, _PD = _E2 + 7, _E2 + 8
# the last magnetometer sample's dip as its sine, and its east and north parts in the levelled frame: a held
# sample (mag_hold) has the fresh one's reading and pairing, so the kernel takes these, its norm, its dip and its
# levelled field (_PL) from there instead of turning the field and taking the dip's arcsine again
_SD, _ME, _MN = _E2 + 9, _E2 + 10, _E2 + 11
# follow_calibration: the mean of the levelled field over the reference's learning, the mean of the levelled
# orientation's rotation matrix over the same samples (row-major), and the previous sample's levelled field
# (:func:`_reexpress`)
# and the weight the learned heading keeps in delta, delta's first-order sensitivity to a change of the
# calibration (body frame) through the steps since (:func:`_trace`)
_RL, _RM, _PL, _RW, _RS = _E2 + 12, _E2 + 15, _E2 + 24, _E2 + 27, _E2 + 28
# and a change of the calibration not yet re-expressed (a re-expression deferred: the field it gives was closer to
# this sample's than the learned one but not within a calibrated sample's precision): its sum (body frame) and its
# steps' first-order part over the learned heading's weight then, and how many changes it sums (:func:`_reexpress`)
_RD, _RP, _RN = _E2 + 31, _E2 + 34, _E2 + 35
# measure_interval: the seconds of magnetometer samples since the last heading measurement (the time it stands
# for), whether it found the field disturbed, and the seconds since it (every sample: when the next one is due)
_MT, _MDIS, _MC = _E2 + 36, _E2 + 37, _E2 + 38
_SIZE = _E2 + 39
#: where the heading's variance (gain kalman, rad^2) sits in the corrector's state
HEADING_VARIANCE = _PHH
#: the most the heading's variance grows to: a heading uniform on the circle (pi^2 / 3)
_P_MAX = math.pi * math.pi / 3.0
#: where the delay estimate's block sits in the corrector's state (``+ EST``, ``+ STD``, ``+ OFFSET``,
#: ``+ CONF``, ``+ NSEG`` of fusionkit.models.time_offset: the gyro's delay against the magnetometer, s)
MAG_DELAY = _EB
_W = _NORM
_SEGMENT_TIME = 0.02  #: s between a segment's two fresh samples (the time-offset model's default)
_MIN_SEGMENTS = 50.0  #: segments before the estimate may be applied
_MAX_OFFSET = 0.05  #: s: the estimate is clamped to +- this
#: once the estimate is applied, a segment whose residual ``|r - d x|`` is over this many RMS residuals
#: does not enter (a Gaussian residual's square is over 9 times its mean with probability 6e-6)
_RESIDUAL_GATE = 3.0
#: where the magnetic reference (norm, dip) sits in the corrector's state
MAG_REFERENCE = _MAG
_REST, _ACC_REJECTED, _MAG_DISTURBED = int(Flag.REST), int(Flag.ACC_REJECTED), int(Flag.MAG_DISTURBED)
_MAG_RECALIBRATED = int(Flag.MAG_RECALIBRATED)
_MAG_HELD = int(Flag.MAG_HELD)
_CH_VAR, _CH_TIME, _CH_LET = int(Channel.INCLINATION_VARIANCE), int(Channel.INCLINATION_TIME), int(Channel.LET_THROUGH)
_kwrap = njit(wrap_angle)


class MagHeadingConfig(PluginConfig):
    tau: float = param(15.0, unit="s", description="gain fixed: time constant of the heading correction", gt=0)
    gain: Literal["fixed", "kalman"] = param(
        "fixed", unit="-", description="how the heading follows the magnetometer: fixed, the time constant tau; "
        "kalman, weighed by the heading's variance (a scalar Kalman filter: it grows with the gyro's noise and the "
        "heading drift its bias and scale errors make, while the magnetometer is rejected or the reference learned, "
        "and shrinks with each magnetometer heading of the noise mag_noise and field_error give)")
    gyro_noise: float = param(math.radians(0.01), unit="rad/s/sqrt(Hz)", description="kalman: the gyro's noise "
                              "density (angle random walk; consumer MEMS 0.005-0.02 deg/s/sqrt(Hz))", ge=0)
    bias_sigma: float = param(math.radians(0.1), unit="rad/s", description="kalman: the standard deviation of the "
                              "vertical gyro bias error the heading integrates (VQF's biasSigmaMotion)", ge=0)
    scale_sigma: float = param(0.0, unit="-", description="kalman: the standard deviation of the gyro's scale "
                               "factor error about the vertical (a fraction; 0: none)", ge=0)
    mag_noise: float = param(0.01, unit="-", description="kalman: the magnetometer's noise per sample as a fraction "
                             "of the field's strength (0.5 uT of 50 uT)", ge=0)
    field_error: float = param(0.03, unit="-", description="kalman: the standard deviation of the field errors a "
                               "calibration leaves (residual iron, an inhomogeneous field) as a fraction of the "
                               "field's strength (1.5 uT of 50 uT)", gt=0)
    field_error_time: float = param(1.0, unit="s", description="kalman: the time over which those field errors "
                                    "change (the motion turns and moves the sensor through them)", gt=0)
    inclination_noise: bool = param(
        False, unit="-", description="kalman: count the inclination's error in a magnetometer heading's variance: "
        "read in the levelled frame, an inclination error about the field's horizontal axis turns the heading by "
        "tan(dip) times itself; its variance and time constant come from the corrector before that publishes them "
        "(inertial-tilt with tau_adapt, the pipeline's channel; none: nothing is added)")
    rejection: bool = param(True, unit="-", description="leave out samples the magnetic reference calls disturbed")
    magnetic: MagneticConfig = param(
        MagneticConfig(), unit="-", description="the magnetic reference (the magnetic detector's settings; its "
        "init_time is the fast start's heading averaging, 0: the first sample)")
    rate_tau: float = param(0.5, unit="s", description="time constant of the gyro low-pass whose norm is the turning "
                            "rate of the new-field test", gt=0)
    mag_bias: bool = param(
        False, unit="-", description="the gyro bias learns the vertical drift from the heading correction (lets the "
        "magnetometer reach roll and pitch through the bias)")
    motion_bias_tau: float = param(100.0, unit="s", description="time constant of that bias learning", gt=0)
    bias_max: float = param(math.radians(2.0), unit="rad/s", description="largest bias it teaches", gt=0)
    mag_delay: float | None = param(
        None, unit="s", description="how long before the end of the gyro's step the magnetometer sample describes "
        "(None: the middle of the step; 0: its end)")
    mag_hold: bool = param(
        True, unit="-", description="a magnetometer sample equal to the previous one is its held reading: pair it with "
        "the orientation the fresh one was paired with (False: with this step's, as a new reading)")
    mag_delay_estimate: bool = param(
        False, unit="-", description="estimate the magnetometer's delay against the gyroscope online and pair with it "
        "once confident (the configured mag_delay until then)")
    delay_max_std: float = param(0.1, unit="samples", description="apply the estimate once its standard deviation "
                                 "is below this many sample intervals", gt=0)
    delay_forget_time: float = param(60.0, unit="s", description="time constant with which the estimate forgets",
                                     gt=0)
    follow_calibration: bool = param(
        True, unit="-", description="when a sensor model changes the magnetometer's calibration (flag "
        "MAG_RECALIBRATED), learn the magnetic reference again from the calibrated field over magnetic.init_time s "
        "(the heading keeps its filter meanwhile); False: keep the reference learned from the field before (the "
        "method before issue 14)")
    measure_interval: float = param(
        0.0, unit="s", description="take a heading measurement (the field's norm, dip and heading, the magnetic "
        "reference's step, the heading's correction) once per this long instead of on every sample, and on a "
        "recalibration (follow_calibration: judged against the sample before, as every sample would be); the "
        "heading's variance still grows on every sample, a measurement stands for its readings' time since the last "
        "one (the interval itself is counted in time, readings or not). "
        "Samples between repeat the last measurement's verdict (MAG_DISTURBED); while the reference is learned "
        "every sample is measured; the delay estimate sees the measured samples only. At most 1 s (the magnetic "
        "reference's time scale), field_error_time (gain kalman) and tau (gain fixed); with mag_delay_estimate at most "
        "0.04 s. 0: every sample", ge=0)
    reexpress: bool = param(
        True, unit="-", description="follow_calibration: at each recalibration it follows, move the heading by "
        "what the new calibration changes in the field it was learned from (that field read through the new "
        "calibration), if that field then has this sample's norm and dip (the iron was there when it was learned); "
        "where it is closer to them than the learned field but not yet within a calibrated sample's precision (a "
        "provisional offset), the move waits for the next recalibration and is made with both changes. "
        "False: the heading keeps its filter alone")


    @model_validator(mode="after")
    def _measure_interval_bounds(self):
        """``measure_interval``'s bounds (:func:`measure_interval_error`), named as here."""
        error = measure_interval_error(self.measure_interval, self.mag_delay_estimate, self.field_error_time,
                                       self.tau if self.gain == "fixed" else None)
        if error:
            raise ValueError(error)
        return self


#: the longest ``measure_interval`` with ``mag_delay_estimate``: a segment spans the time between two
#: measurements (under this plus half a sample) and one that waited over ``4 * _SEGMENT_TIME`` is dropped
#: (:func:`_segment_time`): two segment times keep it within that at up to 25 Hz, and measure every sample slower
MEASURE_INTERVAL_DELAY_MAX = 2.0 * _SEGMENT_TIME


#: the longest ``measure_interval`` with either gain: the magnetic reference steps once per measurement, its
#: new-field candidate low-passed over 1 s and its turning time counted per measurement (``magnetic_step``), so
#: a measurement may not stand for longer than that (rev26d: at 10 s, three measurements made a field 30 % off
#: the reference)
MEASURE_INTERVAL_MAX = 1.0


def measure_interval_error(interval, delay_estimate, field_error_time, tau,
                           names=("measure_interval", "mag_delay_estimate", "tau")) -> str:
    """What is wrong with a ``measure_interval`` of ``interval`` s (``""``: nothing), its
    parameters called ``names`` (mag-heading's, or a filter's that passes them on; ``tau``: the fixed
    gain's time constant, None with the Kalman gain). A measurement stands for the interval, so it may
    not be longer than the field errors' correlation time (``field_error_time``: one measurement would
    count them as less than one sample's, :func:`_kf_noise`; the Kalman gain) nor than the fixed gain's time constant
    (the heading would follow in steps larger than its filter), and with either gain not longer than the
    magnetic reference's time scale (:data:`MEASURE_INTERVAL_MAX`)."""
    if interval > MEASURE_INTERVAL_MAX:
        return (f"{names[0]} must be at most {MEASURE_INTERVAL_MAX:g} s (the magnetic reference's new-field candidate "
                f"is low-passed over 1 s and a measurement stands for the interval), got {interval:g} s")
    if tau is None and interval > field_error_time:  # (the Kalman gain's: the fixed gain has no field errors)
        return (f"{names[0]} must be at most mag-heading's field_error_time ({field_error_time:g} s: a measurement "
                f"stands for the interval, the field errors are correlated over that), got {interval:g} s")
    if tau is not None and interval > tau:
        return (f"{names[0]} must be at most the fixed gain's time constant {names[2]} ({tau:g} s), "
                f"got {interval:g} s")
    if delay_estimate and interval > MEASURE_INTERVAL_DELAY_MAX:
        return (f"{names[0]} must be at most {MEASURE_INTERVAL_DELAY_MAX:g} s with {names[1]} (the delay estimate's "
                f"segments span the time between two measurements and end after {4.0 * _SEGMENT_TIME:g} s: a longer "
                f"interval never closes one), got {interval:g} s")
    return ""


class MagHeading(FactorCorrector):
    """Heading only, from the magnetometer in the levelled frame, with disturbance rejection (a factor)."""

    name: ClassVar[str] = "mag-heading"
    Config = MagHeadingConfig
    uses_mag: ClassVar[bool] = True
    source: ClassVar[str] = "fusionkit (source 002's channel separation; magnetic disturbance rejection)"
    summary: ClassVar[str] = "heading factor about the vertical from the magnetometer; disturbances rejected"
    #: ``inclination_noise``: the inclination error's variance, time constant and let-through tilt
    #: (``inertial-tilt``)
    reads: ClassVar[tuple[Channel, ...]] = (Channel.INCLINATION_VARIANCE, Channel.INCLINATION_TIME,
                                            Channel.LET_THROUGH)

    def __init__(self, config=None, **params) -> None:
        super().__init__(config, **params)
        self.magnetic = MagneticDetector(self.config.magnetic)

    def channel_reads(self) -> tuple[Channel, ...]:
        """The inclination's error with ``inclination_noise`` and the Kalman gain, else nothing."""
        return self.reads if self.config.inclination_noise and self.config.gain == "kalman" else ()

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        s = np.zeros(_SIZE)
        s[_AX:_AX + 9] = frame_axes(frame)
        s[_HC] = 1.0
        return s

    def compose(self, state, quat, sample, bias, rate, flags, channel=None):
        c, x, dt = self.config, state, sample.dt
        out = 0
        g = sample.gyr
        # per sample on 3-vectors: Python floats where numpy's per-call overhead is most of the cost
        # (the same comparisons, so the same decisions)
        g_ok = _finite3(g)
        rate_ok = bool(np.isfinite(rate).all())
        if x[_DT] != dt:  # the coefficients, once per distinct dt
            x[_DT], x[_KM], x[_KW] = dt, 1.0 - math.exp(-dt / c.tau), 1.0 - math.exp(-dt / c.rate_tau)
        if g_ok and (sample.acc is not None or flags & _ACC_REJECTED):
            gyro_lowpass(x, _LW, _SEEN, g, x[_KW])  # the turning rate, on the samples the rest detector sees
        if c.mag_delay_estimate:
            _segment_time(x, dt, rate_ok)
        if c.measure_interval > 0.0:  # the time since the last measurement, with a magnetometer reading or not
            x[_MC] += dt
        if c.gain == "kalman":  # the heading's variance grows with the vertical rate's errors
            w = quat_to_matrix(quat) @ (g - bias) if g_ok else np.zeros(3)
            _kf_predict(x, float(w @ x[_AX + 6:_AX + 9]), dt, c.gyro_noise ** 2, c.bias_sigma ** 2,
                        c.scale_sigma ** 2)
        if sample.mag is not None:
            m = np.asarray(sample.mag, dtype=float)
            # (MAG_HELD: a sensor model calibrated the held reading otherwise than the previous sample)
            fresh = not (c.mag_hold and x[_PMOK] and (flags & _MAG_HELD or m.tolist() == x[_PM:_PM + 3].tolist()))
            pq = x[_QH:_QH + 4].copy()  # the sample before's pairing
            if fresh:
                qm = qc = paired(quat, c.mag_delay, rate, g, bias, dt)  # the configured pairing
                if x[_EB + CONF]:  # the estimate's: the configured one moved by the remaining offset
                    qm = paired(quat, (0.5 * dt if c.mag_delay is None else c.mag_delay) - x[_EB + OFFSET], rate, g,
                                bias, dt)
                x[_QH:_QH + 4] = qm
            else:
                qm = x[_QH:_QH + 4].copy()  # the held reading: as old as its fresh sample
            recalibrated = c.follow_calibration and bool(flags & _MAG_RECALIBRATED)
            dm = dt  # the time the measurement stands for
            if c.measure_interval > 0.0:  # a heading measurement once per interval (and at a recalibration)
                x[_MT] += dt
                learning = x[_MAG + MAG_COUNT] == 0.0 or x[_MAG + MAG_TIME] + 0.5 * dt < c.magnetic.init_time
                if not recalibrated and not learning and x[_MC] < c.measure_interval - 0.5 * dt:
                    x[_PM:_PM + 3] = m
                    x[_PMOK] = 1.0
                    if x[_MDIS] and c.rejection:  # the last measurement's verdict
                        out = _MAG_DISTURBED
                    return self._applied(x, quat), out
                dm, x[_MT], x[_MC] = x[_MT], 0.0, 0.0
                if recalibrated and pq @ pq > 0.0:  # the last valid sample (an invalid one since keeps _PM, _QH) as
                    # a measurement leaves it (_moved, _reexpress)
                    ml0 = quat_to_matrix(pq) @ x[_PM:_PM + 3]
                    x[_PN], x[_PD] = field_norm_dip(ml0, x[_AX + 6:_AX + 9])
                    x[_PL:_PL + 3] = ml0
            x[_PM:_PM + 3] = m
            ml = quat_to_matrix(qm) @ m  # the field in the levelled frame
            incl = 0.0
            if c.inclination_noise and channel is not None:
                ax = x[_AX:_AX + 6]
                incl = _inclination_noise(channel, float(ml @ ax[0:3]), float(ml @ ax[3:6]), float(channel[
                    _CH_LET:_CH_LET + 3] @ ax[0:3]), float(channel[_CH_LET:_CH_LET + 3] @ ax[3:6]))
            out, code = self._heading(x, ml, quat, bias, dm, bool(flags & _REST), recalibrated, incl, qm)
            x[_MDIS] = float(code == MAG_DISTURBED or code == MAG_SOFT)
            if c.mag_delay_estimate and fresh:
                self._estimate(x, qc, m, g - bias, dt, code == MAG_USE and rate_ok)
        x[_PMOK] = float(sample.mag is not None)
        return self._applied(x, quat), out

    @staticmethod
    def _applied(x, quat):
        """``quat`` with the heading's correction turned onto it (``delta`` about the frame's up)."""
        return quat_mul(np.array([x[_HC], *(x[_HS] * x[_AX + 6:_AX + 9])]), quat)

    def _estimate(self, x, qc, m, w, dt, use) -> None:
        """A fresh magnetometer sample ``m``, paired as configured with ``qc``, at the rate ``w``:
        it closes the running segment once ``_SEGMENT_TIME`` has passed (the time-offset model's
        residual ``r = u_j - C^T u_i ~ d x``, ``x = -(w_j - w_i) x C^T u_i``, ``C`` the turn between
        the two pairings) and starts the next one; ``use``: the magnetic reference used it."""
        b = _EB
        if not use:
            x[b + _ANC] = 0.0
            return
        u = m / np.linalg.norm(m)
        closed = False
        if x[b + _ANC] and x[b + _T] >= _SEGMENT_TIME - 0.5 * dt:
            v = quat_to_matrix(qc).T @ (quat_to_matrix(x[b + _DQ:b + _DQ + 4]) @ x[b + _U:b + _U + 3])
            xv = -cross(w - x[b + _GA:b + _GA + 3], v)
            r = u - v
            closed = _fit(x, b, float(xv @ xv), float(xv @ r), float(r @ r),
                          math.exp(-x[b + _T] / self.config.delay_forget_time), self.config.delay_max_std * dt)
            x[b + _ANC] = 0.0
        if not x[b + _ANC]:  # the next segment starts here
            x[b + _ANC] = 1.0
            x[b + _LINK] = float(closed)  # where the last one that entered ended
            x[b + _U:b + _U + 3] = u
            x[b + _GA:b + _GA + 3] = w
            x[b + _DQ:b + _DQ + 4] = qc
            x[b + _T] = 0.0

    def _heading(self, x, m, q6, bias, dt, rest, recalibrated, incl=0.0, qm=None) -> tuple[int, int]:
        """One magnetometer sample (``m`` in the levelled frame): the reference's verdict and the
        heading step; the flag bits and the verdict (MAG_USE, MAG_DISTURBED, MAG_LEARNING).
        ``recalibrated``: the first sample of a new calibration, to follow; ``incl``: the
        inclination error's variance times its time constant (``inclination_noise``; rad^2 s); ``qm``: the
        orientation ``m`` was levelled with (body -> levelled)."""
        c = self.config
        east, north, up = x[_AX:_AX + 3], x[_AX + 3:_AX + 6], x[_AX + 6:_AX + 9]
        norm, dip = field_norm_dip(m, up)
        mc = c.magnetic
        kalman = c.gain == "kalman"
        qm = q6 if qm is None else qm
        rm = quat_to_matrix(qm)
        ok = False
        if recalibrated and c.reexpress:
            d = rm.T @ (m - x[_PL:_PL + 3])  # the calibration's change of the field, body frame
            dt_ = d + x[_RD:_RD + 3]  # with a deferred one's
            rl = x[_RL:_RL + 3]
            v = rl + x[_RM:_RM + 9].reshape(3, 3) @ dt_
            ok, step = _reexpress(x, float(rl @ east), float(rl @ north), float(rl @ up), float(v @ east),
                                  float(v @ north), float(v @ up), float(x[_RS:_RS + 3] @ d), float(dt_ @ dt_), norm,
                                  dip, 2.0 * c.mag_noise ** 2 + c.field_error ** 2, float(d[0]), float(d[1]),
                                  float(d[2]))
            if ok:
                x[_RL:_RL + 3] = v  # the learned field, through the calibration now applied
                _turn(x, step)
        # (re-expressed: the learned field, read through the calibration, is this calibrated sample's, so the iron
        # was there when the reference was learned too: whatever the calibration moved here, it is what takes the
        # field off that reference)
        if recalibrated and (ok or _moved(x, norm, dip, mc.norm_threshold, mc.dip_threshold)) and follow_field(
                x[_MAG:_MAG + MAG_SIZE], norm, dip, mc.norm_threshold, mc.dip_threshold, mc.relearn_evidence):
            x[_RELEARN] = 1.0  # learned again; the heading keeps its filter meanwhile
        x[_PN], x[_PD] = norm, dip
        x[_PL:_PL + 3] = m
        rn, rd = _kf_noise(x, norm, dip, dt, c.mag_noise ** 2, c.field_error ** 2, c.field_error_time, None,
                           incl) if kalman else (0.0, 1.0)
        me, mn = float(m @ east), float(m @ north)
        x[_SD], x[_ME], x[_MN] = max(-1.0, min(1.0, float(m @ up) / norm)), me, mn
        err = _heading_error(me, mn, x[_HC], x[_HS])  # wrap(target - delta)
        code = self.magnetic.reference_step(x[_MAG:_MAG + MAG_SIZE], norm, dip, _norm3(x[_LW:_LW + 3]),
                                            dt)
        if code != MAG_LEARNING:
            x[_RELEARN] = 0.0
        if code == MAG_LEARNING and not x[_RELEARN]:  # the heading is the mean over the reference's learning time
            n = x[_MAG + MAG_COUNT]
            _learn(x, n, m[0], m[1], m[2], qm[0], qm[1], qm[2], qm[3])  # the field and orientation it is learned from
            x[_DELTA] = wrap_angle(x[_DELTA] + (err if n == 1.0 else err / n))
            _set_half(x)
            if kalman:
                _kf_mean(x, rn / rd, n)
            return 0, code
        if code == MAG_DISTURBED and c.rejection:
            return _MAG_DISTURBED, code
        soft = code == MAG_SOFT and c.rejection  # (magnetic.max_rejection_mode "soft": rejected long enough, used
        # weighed by its departure, which the Kalman variance counts; the fixed gain halved, VQF's magRejectionFactor;
        # without rejection a disturbed sample is used as any other, and so is this one)
        # (fixed: the gain for the time the measurement stands for, measure_interval's dt > the sample's)
        k = _kf_gain(x, rn, rd) if kalman else (x[_KM] if dt == x[_DT] else 1.0 - math.exp(-dt / c.tau)) * (
            0.5 if soft else 1.0)
        step = k * err
        _turn(x, step)
        if c.reexpress:  # delta's sensitivity to the calibration: this sample's field, R^T g
            g = rm.T @ ((mn * east - me * north) / max(me * me + mn * mn, 1e-300))
            _trace(x, k, g[0], g[1], g[2])
        if c.mag_bias and not rest and not soft:  # the correction as a rate about the vertical: the gyro's vertical
            bias_step(bias, up * (step / dt), q6, dt, c.motion_bias_tau, c.bias_max)  # drift
        return (_MAG_DISTURBED if soft else 0), code

    def kernel(self, estimator) -> CorrectorKernel:
        c = self.config
        p = np.array([c.tau, float(c.rejection), c.mag_delay if c.mag_delay is not None else math.nan,
                      c.rate_tau, float(c.mag_bias), c.motion_bias_tau, c.bias_max, *self.magnetic.params(),
                      float(c.mag_hold), float(c.mag_delay_estimate), c.delay_max_std, c.delay_forget_time,
                      float(c.follow_calibration), float(c.gain == "kalman"), c.gyro_noise ** 2, c.bias_sigma ** 2,
                      c.scale_sigma ** 2, c.mag_noise ** 2, c.field_error ** 2, c.field_error_time,
                      float(c.inclination_noise), float(c.reexpress), 2.0 * c.mag_noise ** 2 + c.field_error ** 2,
                      c.measure_interval, float(self.magnetic.config.relearn_evidence),
                      self.magnetic.config.max_rejection or 0.0, float(self.magnetic.config.start_evidence),
                      float(self.magnetic.config.max_rejection_mode == "soft")])
        static = (c.gain == "kalman", c.mag_delay_estimate, c.measure_interval > 0.0, c.scale_sigma ** 2 > 0.0,
                  c.inclination_noise, c.reexpress, c.mag_bias)  # (p[18], p[14], p[28], p[21], p[25], p[26], p[4])
        return CorrectorKernel(mag_heading_kernel, p, mode="factor", static=static)


def _finite3(v) -> bool:
    """``np.isfinite(v).all()`` for a 3-vector, on Python floats."""
    a, b, c = v.tolist()
    return math.isfinite(a) and math.isfinite(b) and math.isfinite(c)


def _norm3(v) -> float:
    """``np.linalg.norm(v)`` of a 3-vector on Python floats (numpy's ``sqrt(v @ v)``: the same sum in
    the same order, the same number)."""
    a, b, c = v.tolist()
    return math.sqrt(a * a + b * b + c * c)


def _kf_predict(x, wv, dt, q_gyro, p_bias, p_scale) -> None:
    """gain kalman, every sample: the heading error ``e`` grows as ``e + (n + b + s wv) dt`` (``wv``
    the rate about the vertical, ``n`` the gyro's white noise of density ``sqrt(q_gyro)``, ``b`` and
    ``s`` the vertical bias and scale errors of variances ``p_bias``, ``p_scale``). ``b`` and ``s``
    are not estimated here, only considered (a Schmidt-Kalman filter): their covariances with
    ``e`` make a constant bias drift the heading's standard deviation linearly in time, not as a
    random walk. Capped at a heading uniform on the circle, the covariances within
    Cauchy-Schwarz's bound (the same statements in the reference and, compiled, in the kernel)."""
    hb, hs = x[_PHB], x[_PHS]
    if p_scale > 0.0:
        p = x[_PHH] + 2.0 * dt * (hb + wv * hs) + dt * dt * (p_bias + wv * wv * p_scale) + q_gyro * dt
    else:  # without a scale error its covariance stays 0: wv is not read (nor computed by the kernel), no square root
        p = x[_PHH] + 2.0 * dt * hb + dt * dt * p_bias + q_gyro * dt
    p = min(p, _P_MAX)
    hb = min(hb + p_bias * dt, math.sqrt(p * p_bias))
    if p_scale > 0.0:
        lim = math.sqrt(p * p_scale)
        hs = max(-lim, min(hs + p_scale * wv * dt, lim))
    x[_PHH], x[_PHB], x[_PHS] = p, hb, hs


def _kf_noise(x, norm, dip, dt, mag_noise2, field_error2, field_time, cos2=None, incl=0.0):
    """gain kalman: the variance of one magnetometer heading (``norm`` and ``dip`` its field's): the
    field errors, as a fraction of the field's strength, are ``field_error2`` plus what this sample
    shows of them, its norm's and dip's departure from the magnetic reference (a disturbance
    under the rejection's thresholds turns the horizontal field by as much as it changes those
    two); as a heading they are divided by the horizontal part ``cos(dip)^2``. Correlated over
    ``field_time``, they count as the white noise of the same low-frequency power (``2 e2
    field_time / dt`` per sample: the heading does not average them away faster than they
    change), plus the magnetometer's noise (the same statements in the reference and, compiled,
    in the kernel). ``cos2``: ``cos(dip)^2`` where the caller has it (the kernel: ``1 - sin^2`` from the
    sine it took the dip's arcsine of, no libm call).

    ``incl`` (``inclination_noise``): the inclination error's variance about the horizontal field's
    axis times its time constant (:func:`_inclination_noise`). Read in the levelled frame, an
    inclination error ``e`` about that axis moves the field's vertical part across it: the heading
    turns by ``tan(dip) e``.
    Correlated over its time constant as the field errors are over theirs, it counts as the white
    noise of the same low-frequency power, ``2 tan(dip)^2 incl / dt`` per sample (0: the heading
    as if the levelled frame were exact).

    Returned as a numerator and a denominator (the variance is their quotient): the gain divides once
    (:func:`_kf_gain`), the heading's chain from the magnetometer sample to the output has one division
    where the quotient and the gain took two in a row."""
    e2 = field_error2
    if x[_MAG + MAG_COUNT] != 0.0:  # a reference to depart from
        dn = (norm - x[_MAG]) / x[_MAG]
        dd = dip - x[_MAG + 1]
        e2 = max(e2, dn * dn + dd * dd)
    h2 = max(math.cos(dip) ** 2 if cos2 is None else cos2, 1e-6)
    return mag_noise2 * dt + 2.0 * (e2 * field_time + (1.0 - h2) * incl), h2 * dt


def _inclination_noise(ch, me, mn, le, ln) -> float:
    """``inclination_noise``: the inclination error's variance about the horizontal field's axis
    times its time constant (rad^2 s), from the channel ``ch``: its part without a direction plus
    the square of the let-through tilt's part across that axis (the tilt a linear acceleration
    makes is about ``up x`` it, so an acceleration along the field's horizontal direction changes the
    dip, one across it the heading). ``me``, ``mn``: the field's east and north parts in the
    levelled frame; ``le``, ``ln``: the let-through tilt's (the same statements in the reference
    and, compiled, in the kernel)."""
    h = me * me + mn * mn
    c = (mn * le - me * ln) ** 2 / h if h > 0.0 else 0.0
    return (ch[_CH_VAR] + c) * ch[_CH_TIME]


def _moved(x, norm, dip, norm_th, dip_th) -> bool:
    """At a recalibration (``follow_calibration``): whether the new calibration can be what takes
    this sample (``norm``, ``dip``) away from the reference: it moved the field by more than the
    thresholds (against the previous sample, read through the calibration before; the
    orientation between two samples is the gyro's, so what differs is the calibration), or the
    previous sample was one the reference describes. Where neither holds, the field was off the
    reference before the calibration changed too (an earth-fixed disturbance the calibration was
    applied during) and the reference is kept: learned again there, it would describe the
    disturbance, and the earth's field after it would be rejected until the new-field test
    accepts it. The same statements in the reference and, compiled, in the kernel."""
    pn, pd, rn, rd = x[_PN], x[_PD], x[_MAG], x[_MAG + 1]
    return (abs(norm - pn) > norm_th * pn or abs(dip - pd) > dip_th
            or (abs(pn - rn) <= norm_th * rn and abs(pd - rd) <= dip_th))


def _learn(x, n, m0, m1, m2, w, a, b, c) -> None:
    """While the reference is learned (``n`` samples so far, this one included): the running means of
    the levelled field (``m0, m1, m2``) and of the rotation matrix of the orientation it was levelled
    with (the unit quaternion ``w, a, b, c``, body -> levelled; row-major), what :func:`_reexpress` turns
    the calibration's change with. The same statements in the reference and, compiled, in the kernel."""
    f = 1.0 / n if n > 1.0 else 1.0
    x[_RW] = 1.0  # the heading is this learning's mean alone
    x[_RS] = x[_RS + 1] = x[_RS + 2] = 0.0
    x[_RD] = x[_RD + 1] = x[_RD + 2] = x[_RP] = x[_RN] = 0.0
    x[_RL] += f * (m0 - x[_RL])
    x[_RL + 1] += f * (m1 - x[_RL + 1])
    x[_RL + 2] += f * (m2 - x[_RL + 2])
    r = dcm_entries(w, a, b, c)
    for i in range(9):
        x[_RM + i] += f * (r[i] - x[_RM + i])


@njit(inline="always")
def _untraced(x) -> bool:
    """``reexpress``: whether the heading is no longer traced to the learned field (weight and
    sensitivity 0: nothing learned yet, or a re-expression refused)."""
    return x[_RW] == 0.0 and x[_RS] == 0.0 and x[_RS + 1] == 0.0 and x[_RS + 2] == 0.0


def _trace(x, k, g0, g1, g2) -> None:
    """``reexpress``, after a heading step of gain ``k``: delta is ``(1 - k)`` of what it was plus ``k``
    of this sample's heading, so the learned heading's weight in it shrinks by ``1 - k`` and its
    first-order sensitivity to a change ``d`` of the calibration (body frame) becomes ``(1 - k)`` of
    the one before plus ``k`` of this sample's (a heading no longer traced, weight and sensitivity 0
    after :func:`_reexpress` refused, stays untraced), ``g = R^T (n e - e n) / h^2`` (``e, n``: the field's
    east and north, ``h^2`` their squares' sum; the heading ``atan2(e, n)`` moves by ``g . d`` when the
    field moves by ``R d``). The same statements in the reference and, compiled, in the kernel."""
    if _untraced(x):
        return  # no longer traced (a re-expression refused): so until the reference is learned again
    u = 1.0 - k
    x[_RW] *= u
    x[_RS] = u * x[_RS] + k * g0
    x[_RS + 1] = u * x[_RS + 1] + k * g1
    x[_RS + 2] = u * x[_RS + 2] + k * g2


def _reexpress(x, e0, n0, u0, e1, n1, u1, sd, dd, norm, dip, var, d0, d1, d2):
    """``reexpress``, at a recalibration (``follow_calibration``): the heading was learned from the
    field before it (``e0, n0, u0``: the learning's mean field, east, north and up in the levelled
    frame). That field read through the new calibration is ``(e1, n1, u1)``: the mean plus the
    calibration's change of the field (this sample's field less the previous one's, in the body
    frame: one sample apart, what differs is the calibration), turned by the learning's mean
    orientation. A right calibration gives the same norm and dip at every orientation, so where that
    field matches this calibrated sample's (``norm``, ``dip``) within two standard deviations of a
    calibrated sample's error (``var``: the magnetometer's noise twice and the field error a
    calibration leaves, as fractions of the field; the squared relative norm plus the squared dip
    difference within ``4 var``) and better than the learned field itself does, the iron was there
    when the heading was learned. Then the heading is moved as if every sample it was made of had
    been read through the new calibration: the learned heading's change (exact) times the weight it
    keeps in delta, plus the steps since, to first order (``sd``: their sensitivity times the
    calibration's change, :func:`_trace`); its
    variance grows by that sample's (over the horizontal part ``cos(dip)^2``). A change of the
    calibration (``dd``: its squared norm) within two standard deviations of a calibrated sample's
    error (``4 var norm^2``) is one the heading's filter already weighed its samples as carrying (its
    ``field_error``), and it is two noisy samples' difference: nothing moves, the trace is kept.
    Whether it does and the step (the caller turns the heading by it and keeps ``(e1, n1, u1)`` as
    the learned field).
    Deferred: where the field it gives is closer to this sample's than the learned field but not within
    that precision (a calibration not yet precise, as ``mag-calibration``'s provisional offset), nothing
    moves and the change is kept (``d0, d1, d2``: this recalibration's, body frame; ``sd`` its steps'
    part): the next recalibration is judged, and moves the heading, with the sum of both (the caller
    adds ``x[_RD:_RD + 3]`` to its change, and this adds ``x[_RW] x[_RP]``, the deferred steps' part
    scaled as the learned heading's weight has shrunk since). Each change summed is a difference of two
    noisy samples, so ``var`` is taken ``1 + x[_RN]`` times (``x[_RN]``: the changes deferred) in both
    tests and in the variance added. A sum within the noise (the deferred change undone: the calibration
    withdrawn) drops the deferral, so a later recalibration does not count it again.
    Otherwise (the iron came after the heading was learned, a disturbed sample, a calibration the
    learned field does not fit) nothing moves, and the heading is no longer traced to the learned
    field (weight and sensitivity 0). The same statements in the reference and, compiled, in the
    kernel."""
    h0, h1 = e0 * e0 + n0 * n0, e1 * e1 + n1 * n1
    var = var * (1.0 + x[_RN])
    if dd <= 4.0 * var * norm * norm:  # a change within a calibrated sample's error (with a deferred one's)
        x[_RD] = x[_RD + 1] = x[_RD + 2] = x[_RP] = x[_RN] = 0.0  # a deferral withdrawn: nothing left to make
        return False, 0.0
    if _untraced(x) or h0 == 0.0 or h1 == 0.0:
        return False, 0.0  # nothing learned, or the heading no longer traced to it
    v0, v1 = math.sqrt(h0 + u0 * u0), math.sqrt(h1 + u1 * u1)
    a0 = (v0 - norm) / norm
    b0 = math.asin(max(-1.0, min(1.0, u0 / v0))) - dip
    a1 = (v1 - norm) / norm
    b1 = math.asin(max(-1.0, min(1.0, u1 / v1))) - dip
    mis = a1 * a1 + b1 * b1  # the squared misfit of the field it gives (d1 is the change's y)
    if mis >= a0 * a0 + b0 * b0 or (mis > 4.0 * var and x[_RW] == 0.0):  # (a weight 0 cannot scale a deferral)
        x[_RW] = x[_RS] = x[_RS + 1] = x[_RS + 2] = 0.0
        x[_RD] = x[_RD + 1] = x[_RD + 2] = x[_RP] = x[_RN] = 0.0
        return False, 0.0
    if mis > 4.0 * var:  # closer than the learned field, not yet within the precision: deferred
        x[_RD] += d0
        x[_RD + 1] += d1
        x[_RD + 2] += d2
        x[_RP] += sd / x[_RW]
        x[_RN] += 1.0
        return False, 0.0
    x[_PHH] = min(x[_PHH] + var * v1 * v1 / h1, _P_MAX)
    step = _kwrap(x[_RW] * (_kwrap(math.atan2(e1, n1) - math.atan2(e0, n0)) + x[_RP]) + sd)
    x[_RD] = x[_RD + 1] = x[_RD + 2] = x[_RP] = x[_RN] = 0.0
    return True, step


def _kf_gain(x, rn, rd) -> float:
    """gain kalman: the gain for a magnetometer heading of variance ``rn / rd`` (:func:`_kf_noise`),
    ``P / (P + rn / rd)`` as ``P rd / (P rd + rn)``; the heading's variance and covariances it leaves (the
    considered errors' own are not measured)."""
    pd = x[_PHH] * rd
    k = pd / (pd + rn)
    x[_PHH] *= 1.0 - k
    x[_PHB] *= 1.0 - k
    x[_PHS] *= 1.0 - k
    return k


def _kf_mean(x, r, n) -> None:
    """gain kalman, while the reference is learned: the heading is the mean of ``n`` headings of
    variance ``r`` (what a Kalman filter from no prior knowledge gives), no covariances yet."""
    x[_PHH], x[_PHB], x[_PHS] = min(r / n, _P_MAX), 0.0, 0.0


def _segment_time(x, dt, ok) -> None:
    """Every sample: the running segment's time grows by ``dt``; one that waited over four
    segment times (a long hold, a lost magnetometer) or a sample without a valid rate ends it."""
    if x[_EB + _ANC] != 0.0:
        x[_EB + _T] += dt
        if not ok or x[_EB + _T] > 4.0 * _SEGMENT_TIME:
            x[_EB + _ANC] = 0.0


def _gate(x, b, xx, xr, rr, lam) -> bool:
    """Whether one segment (``xx = |x|^2``, ``xr = x.r``, ``rr = |r|^2``) enters the estimate: not
    when, once it is applied, its residual ``|r - d x|^2`` is over ``_RESIDUAL_GATE^2`` times the
    mean one; if it does, its residual joins that mean (the same statements run in the reference
    and, compiled, in the kernel)."""
    d = x[b + EST]
    e2 = rr - 2.0 * d * xr + d * d * xx
    if x[b + CONF] != 0.0 and e2 * x[b + _W] > _RESIDUAL_GATE * _RESIDUAL_GATE * x[_E2]:
        return False
    x[b + _W] = lam * x[b + _W] + 1.0
    x[_E2] = lam * x[_E2] + e2
    return True


def _fit(x, b, xx, xr, rr, lam, max_std) -> bool:
    """One segment into the estimate if :func:`_gate` lets it: whether it entered."""
    if not _gate(x, b, xx, xr, rr, lam):
        return False
    _enter(x, b, xx, xr, lam, max_std, _MIN_SEGMENTS, _MAX_OFFSET)
    return True


def _heading_error(e, n, c, s) -> float:
    """``wrap(target - delta)``: the angle that turns the field's horizontal part (``e``, ``n``: east
    and north in the levelled frame) from where ``Rz(delta)`` puts it to north (``target``: the
    heading that does so), from ``(c, s)``, the cosine and sine of ``delta / 2``: the field turned
    by ``delta`` and that angle by :func:`atan2_small` (once converged a small one: no libm call).
    The same statements in the reference and, compiled, in the kernel."""
    cd, sd = c * c - s * s, 2.0 * c * s
    return atan2_small(e * cd - n * sd, e * sd + n * cd)


def _turn(x, step) -> None:
    """``delta += step`` (wrapped), and the cosine and sine of ``delta / 2`` turned by ``step / 2``
    (:func:`rotvec_quat_entries`: a polynomial for a small step, no libm call), brought back to unit
    length by one Newton step (the output's norm must not drift over the samples: an inclination
    error of a few 1e-6 rad, read from the output, moves by 1e-8 rad for a norm off by 1e-13), and
    negated where ``delta`` wraps (its half moves by pi). The same statements in the reference and,
    compiled, in the kernel."""
    ch, _, _, sh = rotvec_quat_entries(0.0, 0.0, step)
    c, s = x[_HC], x[_HS]
    c, s = c * ch - s * sh, s * ch + c * sh
    f = 1.5 - 0.5 * (c * c + s * s)
    c, s = c * f, s * f
    d = x[_DELTA] + step
    if d > math.pi or d <= -math.pi:
        c, s = -c, -s
    x[_DELTA] = _kwrap(d)
    x[_HC], x[_HS] = c, s


def _set_half(x) -> None:
    """The cosine and sine of ``delta / 2`` where ``delta`` was set (the learning's mean)."""
    x[_HC], x[_HS] = math.cos(0.5 * x[_DELTA]), math.sin(0.5 * x[_DELTA])


@njit(inline="always")
def _k_apply(s, q, ax) -> None:
    """The heading's correction (``delta`` about the frame's up, its half-angle cosine and sine ``_HC``,
    ``_HS``) turned onto the output ``q`` in place (none while ``delta`` is 0: Rz(0) is the identity; a
    run without a magnetometer never leaves 0). :meth:`MagHeading._applied` in the reference."""
    if s[_DELTA] != 0.0:
        c, sn = s[_HC], s[_HS]
        q[0], q[1], q[2], q[3] = k_qmul(c, sn * s[ax + 6], sn * s[ax + 7], sn * s[ax + 8], q[0], q[1], q[2], q[3])


_k_heading_error = njit(inline="always")(_heading_error)
_k_turn = njit(inline="always")(_turn)
_k_set_half = njit(_set_half)
_k_segment_time = njit(_segment_time)
_k_kf_predict = njit(_kf_predict)
_k_kf_noise = njit(_kf_noise)
_k_kf_gain = njit(_kf_gain)
_k_inclination_noise = njit(_inclination_noise)
_k_kf_mean = njit(_kf_mean)
_k_moved = njit(_moved)
_k_learn = njit(_learn)
_k_reexpress = njit(_reexpress)
_k_trace = njit(_trace)
_k_gate = njit(_gate)


@njit(cold=True)  # once per segment
def _k_fit(x, b, xx, xr, rr, lam, max_std):
    if not _k_gate(x, b, xx, xr, rr, lam):
        return False
    _k_enter(x, b, xx, xr, lam, max_std, _MIN_SEGMENTS, _MAX_OFFSET)
    return True


@njit(cold=True)  # at a recalibration
def _k_previous(s, w, a, b, c):
    """``measure_interval``, at a recalibration: the norm, dip and levelled field of the last valid
    sample (its reading ``s[_PM:_PM + 3]`` levelled with its pairing ``w, a, b, c``; an invalid sample
    since changes neither) where a measurement on every sample leaves them (:func:`_moved` and
    :func:`_reexpress` compare this sample with that one: the calibration's change, one valid sample
    apart): the kernel's statements for a measurement, so the same numbers. (The reference levels it
    as it does every sample, in :meth:`MagHeading.compose`.)"""
    v0, v1, v2 = k_rot(w, a, b, c, s[_PM], s[_PM + 1], s[_PM + 2])
    norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    vu = v0 * s[_AX + 6] + v1 * s[_AX + 7] + v2 * s[_AX + 8]
    s[_PN], s[_PD] = norm, math.asin(max(-1.0, min(1.0, vu / norm)))
    s[_PL], s[_PL + 1], s[_PL + 2] = v0, v1, v2


@njit
def _k_estimate(s, c0, c1, c2, c3, m0, m1, m2, w0, w1, w2, dt, use, max_std, forget):
    """:meth:`MagHeading._estimate` with scalars (``c``: the configured pairing's orientation)."""
    b = _EB
    if not use:
        s[b + _ANC] = 0.0
        return
    n = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    u0, u1, u2 = m0 / n, m1 / n, m2 / n
    closed = False
    if s[b + _ANC] != 0.0 and s[b + _T] >= _SEGMENT_TIME - 0.5 * dt:
        e0, e1, e2 = k_rot(s[b + _DQ], s[b + _DQ + 1], s[b + _DQ + 2], s[b + _DQ + 3], s[b + _U], s[b + _U + 1],
                           s[b + _U + 2])
        v0, v1, v2 = k_rot(c0, -c1, -c2, -c3, e0, e1, e2)  # C^T u_i
        d0, d1, d2 = w0 - s[b + _GA], w1 - s[b + _GA + 1], w2 - s[b + _GA + 2]
        x0, x1, x2 = -(d1 * v2 - d2 * v1), -(d2 * v0 - d0 * v2), -(d0 * v1 - d1 * v0)
        r0, r1, r2 = u0 - v0, u1 - v1, u2 - v2
        closed = _k_fit(s, b, x0 * x0 + x1 * x1 + x2 * x2, x0 * r0 + x1 * r1 + x2 * r2, r0 * r0 + r1 * r1 + r2 * r2,
                        math.exp(-s[b + _T] / forget), max_std * dt)
        s[b + _ANC] = 0.0
    if s[b + _ANC] == 0.0:
        s[b + _ANC] = 1.0
        s[b + _LINK] = 1.0 if closed else 0.0
        s[b + _U], s[b + _U + 1], s[b + _U + 2] = u0, u1, u2
        s[b + _GA], s[b + _GA + 1], s[b + _GA + 2] = w0, w1, w2
        s[b + _DQ], s[b + _DQ + 1], s[b + _DQ + 2], s[b + _DQ + 3] = c0, c1, c2, c3
        s[b + _T] = 0.0


@njit(inline="always")
def mag_heading_kernel(q, s, b, g0, g1, g2, h0, h1, h2, h3, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p,
                       ch, kalman, estimate, interval, scale, incl_noise, reexpress, mag_bias):
    """The kernel of :meth:`MagHeading.compose`: ``p = (tau, rejection, mag_delay (NaN: None), rate_tau,
    mag_bias, motion_bias_tau, bias_max, *magnetic params (6), mag_hold, mag_delay_estimate, delay_max_std,
    delay_forget_time, follow_calibration, kalman (1) or fixed (0), gyro_noise^2, bias_sigma^2, scale_sigma^2,
    mag_noise^2, field_error^2, field_error_time, inclination_noise, reexpress, a calibrated sample's variance
    (2 mag_noise^2 + field_error^2), measure_interval (0: every sample), relearn_evidence, max_rejection (0: None),
    start_evidence, max_rejection_mode "soft" (1 or 0))``;
    ``ch`` the pipeline's channel; the
    compile-time options (``static``, :meth:`MagHeading.kernel`): the Kalman gain, mag_delay_estimate,
    measure_interval > 0, scale_sigma > 0, inclination_noise, reexpress and mag_bias, which ``p`` holds too."""
    if s[_DT] != dt:
        s[_DT], s[_KM], s[_KW] = dt, 1.0 - math.exp(-dt / p[0]), 1.0 - math.exp(-dt / p[3])
    if math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2) and (acc_ok or (flags & _ACC_REJECTED) != 0):
        k_gyro_lowpass(s, _LW, _SEEN, g0, g1, g2, s[_KW])
    out = 0
    ax = _AX
    if estimate:
        _k_segment_time(s, dt, math.isfinite(h0))
    if interval:  # measure_interval: the time since the last measurement, with a magnetometer reading or not
        s[_MC] += dt
    if kalman:
        wv = 0.0  # (read only with a scale error: p[21] > 0)
        if scale and math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2):
            w0, w1, w2 = k_rot(q[0], q[1], q[2], q[3], g0 - b[0], g1 - b[1], g2 - b[2])
            wv = w0 * s[ax + 6] + w1 * s[ax + 7] + w2 * s[ax + 8]
        _k_kf_predict(s, wv, dt, p[19], p[20], p[21])
    if mag_ok:
        same = m0 == s[_PM] and m1 == s[_PM + 1] and m2 == s[_PM + 2]
        fresh = not (p[13] != 0.0 and s[_PMOK] != 0.0 and (same or (flags & _MAG_HELD) != 0))
        pq0, pq1, pq2, pq3 = s[_QH], s[_QH + 1], s[_QH + 2], s[_QH + 3]  # the sample before's pairing
        if fresh:
            c0, c1, c2, c3 = k_paired(q, p[2], h0, h1, h2, h3, g0, g1, g2, b, dt)
            p0, p1, p2, p3 = c0, c1, c2, c3
            if s[_EB + CONF] != 0.0:
                p0, p1, p2, p3 = k_paired(q, (0.5 * dt if math.isnan(p[2]) else p[2]) - s[_EB + OFFSET], h0, h1, h2,
                                          h3, g0, g1, g2, b, dt)
            s[_QH], s[_QH + 1], s[_QH + 2], s[_QH + 3] = p0, p1, p2, p3
        else:
            p0, p1, p2, p3 = s[_QH], s[_QH + 1], s[_QH + 2], s[_QH + 3]
            c0, c1, c2, c3 = p0, p1, p2, p3
        recal = p[17] != 0.0 and (flags & _MAG_RECALIBRATED) != 0
        dm = dt  # the time the measurement stands for
        if interval:  # measure_interval: a heading measurement once per interval (and at a recalibration)
            s[_MT] += dt
            learning = s[_MAG + MAG_COUNT] == 0.0 or s[_MAG + MAG_TIME] + 0.5 * dt < p[7]  # (every sample)
            if not recal and not learning and s[_MC] < p[28] - 0.5 * dt:
                s[_PM], s[_PM + 1], s[_PM + 2] = m0, m1, m2
                s[_PMOK] = 1.0
                if s[_MDIS] != 0.0 and p[1] != 0.0:
                    out = _MAG_DISTURBED
                _k_apply(s, q, ax)
                return out
            dm, s[_MT], s[_MC] = s[_MT], 0.0, 0.0
            if recal and pq0 * pq0 + pq1 * pq1 + pq2 * pq2 + pq3 * pq3 > 0.0:  # the last valid sample's (an
                # invalid one since keeps _PM, _QH) norm, dip and levelled field, as measuring every sample leaves
                _k_previous(s, pq0, pq1, pq2, pq3)  # them (_moved, _reexpress)
        s[_PM], s[_PM + 1], s[_PM + 2] = m0, m1, m2
        if fresh or not same or interval:  # (held, calibrated otherwise: the fresh one's pairing, this value;
            # measure_interval: its fresh one may not have been measured)
            v0, v1, v2 = k_rot(p0, p1, p2, p3, m0, m1, m2)
            norm = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            vu = v0 * s[ax + 6] + v1 * s[ax + 7] + v2 * s[ax + 8]
            sd = max(-1.0, min(1.0, vu / norm))
            dip = math.asin(sd)
            me, mn = v0 * s[ax] + v1 * s[ax + 1] + v2 * s[ax + 2], v0 * s[ax + 3] + v1 * s[ax + 4] + v2 * s[ax + 5]
            s[_SD], s[_ME], s[_MN] = sd, me, mn
        else:  # a held sample: the fresh one's reading and pairing, so its levelled field (the same numbers)
            v0, v1, v2 = s[_PL], s[_PL + 1], s[_PL + 2]
            norm, dip, sd, me, mn = s[_PN], s[_PD], s[_SD], s[_ME], s[_MN]
        rate = math.sqrt(s[_LW] * s[_LW] + s[_LW + 1] * s[_LW + 1] + s[_LW + 2] * s[_LW + 2])
        rex = False
        if recal and reexpress:  # reexpress: the calibration's change of the field, body frame, as learned
            d0, d1, d2 = k_rot(p0, -p1, -p2, -p3, v0 - s[_PL], v1 - s[_PL + 1], v2 - s[_PL + 2])
            t0, t1, t2 = d0 + s[_RD], d1 + s[_RD + 1], d2 + s[_RD + 2]  # with a deferred one's
            f0 = s[_RL] + s[_RM] * t0 + s[_RM + 1] * t1 + s[_RM + 2] * t2
            f1 = s[_RL + 1] + s[_RM + 3] * t0 + s[_RM + 4] * t1 + s[_RM + 5] * t2
            f2 = s[_RL + 2] + s[_RM + 6] * t0 + s[_RM + 7] * t1 + s[_RM + 8] * t2
            ok, st = _k_reexpress(s, s[_RL] * s[ax] + s[_RL + 1] * s[ax + 1] + s[_RL + 2] * s[ax + 2],
                              s[_RL] * s[ax + 3] + s[_RL + 1] * s[ax + 4] + s[_RL + 2] * s[ax + 5],
                              s[_RL] * s[ax + 6] + s[_RL + 1] * s[ax + 7] + s[_RL + 2] * s[ax + 8],
                              f0 * s[ax] + f1 * s[ax + 1] + f2 * s[ax + 2],
                              f0 * s[ax + 3] + f1 * s[ax + 4] + f2 * s[ax + 5],
                              f0 * s[ax + 6] + f1 * s[ax + 7] + f2 * s[ax + 8],
                              s[_RS] * d0 + s[_RS + 1] * d1 + s[_RS + 2] * d2, t0 * t0 + t1 * t1 + t2 * t2, norm,
                              dip, p[27], d0, d1, d2)
            if ok:
                s[_RL], s[_RL + 1], s[_RL + 2] = f0, f1, f2
                _k_turn(s, st)
                rex = True
        if recal and (rex or _k_moved(s, norm, dip, p[8], p[9])) and k_follow_field(s, norm, dip, p[8], p[9],
                                                                                      p[29] != 0.0):
            s[_RELEARN] = 1.0  # (the reference's state sits at the start of the corrector's)
        s[_PN], s[_PD] = norm, dip
        s[_PL], s[_PL + 1], s[_PL + 2] = v0, v1, v2
        err = _k_heading_error(me, mn, s[_HC], s[_HS])  # (me, mn: the field's east and north in the levelled frame)
        incl = 0.0
        if incl_noise:
            le = ch[_CH_LET] * s[ax] + ch[_CH_LET + 1] * s[ax + 1] + ch[_CH_LET + 2] * s[ax + 2]
            ln = ch[_CH_LET] * s[ax + 3] + ch[_CH_LET + 1] * s[ax + 4] + ch[_CH_LET + 2] * s[ax + 5]
            incl = _k_inclination_noise(ch, me, mn, le, ln)
        rn, rd = _k_kf_noise(s, norm, dip, dm, p[22], p[23], p[24], 1.0 - sd * sd, incl) if kalman else (0.0, 1.0)
        code = magnetic_step(s, norm, dip, rate, dm, p[7], p[8], p[9], p[10], p[11], p[12], p[30], p[31], p[32])
        s[_MDIS] = 1.0 if code == MAG_DISTURBED or code == MAG_SOFT else 0.0
        if code != MAG_LEARNING:
            s[_RELEARN] = 0.0
        if code == MAG_LEARNING and s[_RELEARN] == 0.0:
            n = s[MAG_COUNT]
            _k_learn(s, n, v0, v1, v2, p0, p1, p2, p3)
            s[_DELTA] = _kwrap(s[_DELTA] + (err if n == 1.0 else err / n))
            _k_set_half(s)
            if kalman:
                _k_kf_mean(s, rn / rd, n)
        elif code == MAG_DISTURBED and p[1] != 0.0:
            out = _MAG_DISTURBED
        else:
            soft = code == MAG_SOFT and p[1] != 0.0
            k = _k_kf_gain(s, rn, rd) if kalman else (s[_KM] if dm == dt else 1.0 - math.exp(-dm / p[0])) * (
                0.5 if soft else 1.0)
            if soft:
                out = _MAG_DISTURBED
            step = k * err
            _k_turn(s, step)
            if reexpress:  # reexpress: delta's sensitivity to the calibration, R^T g
                hh = max(me * me + mn * mn, 1e-300)
                u0, u1, u2 = k_rot(p0, -p1, -p2, -p3, (mn * s[ax] - me * s[ax + 3]) / hh,
                                   (mn * s[ax + 1] - me * s[ax + 4]) / hh, (mn * s[ax + 2] - me * s[ax + 5]) / hh)
                _k_trace(s, k, u0, u1, u2)
            if mag_bias and (flags & _REST) == 0 and not soft:
                r = step / dm
                k_bias_step(b, q[0], q[1], q[2], q[3], s[ax + 6] * r, s[ax + 7] * r, s[ax + 8] * r, dm / p[5], p[6])
        if estimate and fresh:
            _k_estimate(s, c0, c1, c2, c3, m0, m1, m2, g0 - b[0], g1 - b[1], g2 - b[2], dt,
                        code == MAG_USE and math.isfinite(h0), p[15], p[16])
    s[_PMOK] = 1.0 if mag_ok else 0.0
    _k_apply(s, q, ax)
    return out
