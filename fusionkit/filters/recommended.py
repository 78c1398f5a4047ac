"""The ``recommended`` filter: the best of what the sources and the state of the art do, composed.

A preset (docs/algorithms/recommended.md; ``fusionkit describe recommended --toml`` prints the
composition). Orientation is split into three factors, each corrected by one sensor only
(source 002's channel separation, method 2, taken to its end):

``q = Rz(delta) (x) q_tilt (x) q_gyr``

1. ``q_gyr``: the gyroscope strapdown (estimator ``poisson-quat``, the exact exponential of
   ``(w - bias) dt``) from the body to an "almost inertial" frame I. Nothing corrects it.
2. ``q_tilt``: the inclination factor (corrector ``inertial-tilt``): the specific force low-passed
   in I (second-order Butterworth, ``tau_acc``; ``tau_adapt``: per sample from the linear acceleration
   against the gyro's error, ``tau_acc`` for a still sensor), made vertical each sample by the smallest rotation;
   it also learns the gyro bias in motion (``bias_filter``: VQF's Kalman model, the correction as
   the low-passed earth-frame bias error; ``motion_bias_tau`` its forgetting time); ``impulse_clip``
   (10 times the departure's running RMS) limits a knock's few samples before the low-pass.
3. ``delta``: heading only, about the vertical (corrector ``mag-heading``; its gain from the
   heading's variance, ``heading_gain``, or the time constant ``tau_mag``), with the magnetic
   disturbance rejection (``mag_rejection``, ``magnetic``): a
   magnetic disturbance can only reach heading (roll and pitch are those of a magnetometer-free
   run, tested to 1e-12).

In front (``mag_calibration``): the ``mag-calibration`` sensor model, the magnetometer's hard and
soft iron learned from the gyroscope, applied only where it behaves as body-fixed iron.

Around them: the ``rest`` detector (flag REST) and the bias at rest (corrector
``rest-bias-lowpass``: the gyro bias follows the low-passed gyro before the sample's propagation,
``rest_bias``, ``rest_bias_tau``; ``rest_bias_gain``: each rest sample weighed by the bias's variance,
so a short rest teaches a turn-on bias never measured); the acceleration gate (``acc_gate``: the ``acceleration``
detector with no hold and no recovery, off by default: it costs accuracy on BROAD, leaving out the
large samples makes the linear accelerations' average nonzero, which is exactly what the I-frame
low-pass relies on); the fast start (``fast_start``: running means for the first ``tau_acc`` s and
over ``magnetic.init_time`` s); the sensor pairing (``acc_delay``, ``mag_delay``: None pairs a
sample with the middle of the gyro's step); and the output lead (``output_lead``, corrector
``output-lead``: the output predicted ahead by the gyro rate, the state unchanged). Each part's
module documents it and what it assumes.

Bad input (:func:`fusionkit.types.sample_validity`, docs/reliability.md): an invalid gyroscope
sample holds the state (GYR_INVALID); an invalid accelerometer or magnetometer sample skips its
correction. After a timestamp gap (GAP, the state held across it) and after a saturated gyro
(GYR_SATURATED) the inclination low-pass restarts; heading and bias are held. ``use_mag=False``
does not read the recording's magnetometer at all.

The composition starts from the body's axes taken as ENU's and outputs in ``frame``: every frame
gives the same orientation up to the frame change (tested to 1e-9).
"""

from __future__ import annotations

import copy
import math
from typing import Annotated, Any, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from ..config import AlignmentConfig, FilterConfig, PipelineConfig, PluginSpec, param
from ..correctors._factor import initial_attitude
from ..correctors.heading import HEADING_VARIANCE, MAG_REFERENCE, MagHeadingConfig, measure_interval_error
from ..correctors.tilt import RATE_ERROR as TILT_RATE_ERROR
from ..correctors.tilt import RATE_KAPPA2 as TILT_KAPPA2
from ..correctors.tilt import InertialTiltConfig, lowpass_coefficients, slow_interval_bound
from ..detectors.magnetic import MagneticConfig
from ..detectors.rest import RestConfig
from ..pipeline import Pipeline

__all__ = ["RecommendedFilter", "RecommendedConfig", "lowpass_coefficients"]

#: the largest gyro bias ``recommended`` learns in motion (norm, rad/s). At least sqrt(3) times the rest detector's
#: ``max_rate`` (judged per axis: a rest can teach up to 3.5 deg/s as a norm), so that a bias a rest learned is not
#: clipped at the first motion; a consumer MEMS gyro's turn-on offset is about +-1 deg/s calibrated or for recent
#: parts, up to +-3 deg/s per axis for some. 2 deg/s until stop 30 (docs/algorithms/recommended.md, "The largest gyro
#: bias")
GYRO_BIAS_MAX = math.radians(5.0)
#: the rest detector's ``max_rate`` in ``recommended``, on each axis (VQF's ``biasClip``): a low-passed gyro above it
#: on an axis is a slow rotation, not a bias. On the norm until stop 30, where a gyro 1 deg/s off per axis showed no
#: rest; not raised to 5 deg/s, where slow coordinated turns (a helicopter's, under 5 deg/s) became rests
REST_MAX_RATE = math.radians(2.0)

#: the acceleration detector as the gate (``acc_gate``): every sample judged on its own, no recovery
_NO_RECOVERY = 1e9


class RecommendedConfig(FilterConfig):
    tau_acc: float = param(
        2.0, unit="s", description="time constant of the inclination low-pass (in the almost-inertial frame)", gt=0)
    tau_adapt: bool = param(
        True, unit="-", description="inertial-tilt's adaptive time constant: per sample sqrt(sigma_v / (g d)), the "
        "least linear acceleration let through plus gyro drift accumulated (sigma_v: the velocity's deviation, d: "
        "the bias's uncertainty and gyro_rate_error times the net turn rate), tau_acc for a still sensor, within "
        "0.5-4 s (recommended.md). False: tau_acc throughout (the behaviour before issue 14's stop 19)")
    gyro_rate_error: float = param(
        0.015, unit="-", description="tau_adapt: the gyro's error proportional to the rate (scale factor, "
        "misalignment; consumer MEMS data sheets: 1-3 %)", ge=0)
    tau_max_parallel: bool = param(
        True, unit="-", description="tau_adapt: inertial-tilt's second low-pass at the longest time constant (4 s), "
        "run from the start; when the adaptive time constant reaches it, the inclination is taken from it, so what "
        "the shorter one let through at a shaking's onset is not kept (recommended.md). False: the adaptive "
        "low-pass's delay lines rescaled (the behaviour before)")
    impulse_clip: float | None = param(
        10.0, unit="-", description="inertial-tilt's impulse clip: the specific force's departure from the "
        "low-passed vector limited to this many times its running RMS (over about 1 s) before the inclination "
        "low-pass: a knock's few samples of tens of g, which the sampled accelerometer does not integrate to the "
        "velocity the body got, do not tilt the estimate (recommended.md). None: off (the behaviour before stop 21)",
        gt=1)
    gyro_rate_estimate: Literal["off", "tau", "correct"] = param(
        "correct", unit="-", description="the gyro's rate error (scale factors and non-orthogonality, E's "
        "symmetric part) estimated online from what the bias in motion leaves of the inclination correction, "
        "gyro_rate_error its prior (inertial-tilt's rate_error_estimate; recommended.md). correct: removed from the "
        "gyro, and the adaptive time constant uses the estimate's uncertainty; tau: only the adaptive time constant "
        "uses it (the estimate and its uncertainty instead of gyro_rate_error); off: gyro_rate_error throughout (the "
        "default before stop 21). Needs the bias in motion (motion_bias_tau, bias_filter kalman): without it the "
        "default is off, asking for it an error. With correct, diagnostics['bias'] is what the next propagation "
        "removes: the bias and the last sample's E w")
    gyro_rate_interval: float = param(
        0.05, unit="s", description="gyro_rate_estimate: the time of motion between the rate error's Kalman updates "
        "(inertial-tilt's rate_error_interval): its measurement is low-passed at the inclination's time constant "
        "(0.5-4 s), so consecutive samples say almost the same; each update's noise is divided by the samples it "
        "spans (the same information per second). 0.05 s: a tenth of the shortest time constant, 0.5 s "
        "(recommended.md). Counted in whole blocks of slow_interval (0.063 s at 286 Hz); the motion counted towards "
        "the next update expires after a rest longer than four inclination time constants. 0: an update every block "
        "(every sample with slow_interval 0, the behaviour before)", ge=0)
    gyro_rate_acc_bias: float = param(
        0.0, unit="m/s^2", description="gyro_rate_estimate: the accelerometer's bias (standard deviation per axis) "
        "estimated beside the rate error, so that the drift of the tilt a body-fixed accelerometer bias makes as "
        "the body turns is not taken for the gyro's (inertial-tilt's rate_error_acc_bias; recommended.md); the bias "
        "is not removed from the accelerometer. 0: not modelled", ge=0)
    bias_update_interval: float = param(
        0.05, unit="s", description="bias_filter kalman: the time of motion between the bias filter's Kalman updates "
        "(inertial-tilt's bias_update_interval): like gyro_rate_interval, its measurement is the correction low-passed "
        "at the inclination's time constant, each update's noise divided by the samples it spans (the same "
        "information per second); the low-passes and the covariance's growth run once per block of slow_interval "
        "(recommended.md), and the interval is counted in whole blocks (0.063 s at 286 Hz); the motion counted towards "
        "the next update expires after a rest longer than four inclination time constants. 0: an update every "
        "block in motion (every sample with slow_interval 0, the behaviour before)", ge=0)
    slow_interval: float = param(
        0.02, unit="s", description="the slow estimators once per block of this many seconds: the bias filter's and "
        "the rate error's per-sample work (their low-passes of the rotation, covariances, updates; bias_filter "
        "kalman) and tau_adapt's statistics and time constant, on the block's last rotation and its mean rates and "
        "specific force weighted by time (inertial-tilt's slow_interval; recommended.md): they change over "
        "seconds. The inclination low-pass and correction stay per sample; the update intervals are counted in "
        "whole blocks. At most a tenth of the shortest time constant (0.05 s: tau_adapt's 0.5 s; or tau_acc): "
        "as the default it shrinks to that, asked for above it is an error. 0: every sample (the behaviour "
        "before)", ge=0)
    tau_mag: float = param(15.0, unit="s", description="heading_gain fixed: time constant of the heading correction",
                           gt=0)
    heading_gain: Literal["fixed", "kalman"] = param(
        "kalman", unit="-", description="how the heading follows the magnetometer (mag-heading's gain): kalman, "
        "weighed by the heading's variance, which grows with the gyro's noise and the vertical bias error "
        "(bias_sigma_motion) and while the magnetometer is rejected, and shrinks with each magnetometer heading (its "
        "noise and the field errors, a departure from the magnetic reference counting as one, against the horizontal "
        "field); fixed: the time constant tau_mag (the behaviour before issue 14's heading gain)")
    heading_inclination_noise: bool = param(
        False, unit="-", description="heading_gain kalman: a magnetometer heading's variance counts the inclination's "
        "error times tan(dip) (mag-heading's inclination_noise; the variance inertial-tilt's adaptive time constant "
        "models, passed through the pipeline's channel; nothing without tau_adapt)")
    use_mag: bool = param(True, unit="-", description="use the magnetometer when the recording has one (9D)")
    fast_start: bool = param(
        True, unit="-", description="running means instead of the low-passes at the start (first tau_acc s, "
        "magnetic.init_time s)")
    rest: RestConfig = param(
        RestConfig(max_rate=REST_MAX_RATE), unit="-", description="the rest detector (its max_rate, on each axis: "
        "the largest gyro bias taken for one at rest)")
    rest_bias: bool = param(True, unit="-", description="re-estimate the gyro bias at rest")
    rest_bias_tau: float = param(1.0, unit="s", description="time constant of the bias at rest", gt=0)
    rest_bias_gain: Literal["fixed", "kalman"] = param(
        "kalman", unit="-", description="how a rest sample teaches the bias (rest-bias-lowpass's gain): kalman, "
        "weighed by the bias's variance (a rest's first samples teach a bias never measured at once, then the "
        "fixed gain of rest_bias_tau); fixed: the time constant rest_bias_tau from the rest's start (the behaviour "
        "before issue 14's stop 18)")
    motion_bias_tau: float | None = param(
        100.0, unit="s", description="time constant of the bias estimation in motion; None: off", gt=0)
    bias_max: float = param(
        GYRO_BIAS_MAX, unit="rad/s", description="largest bias estimated in motion (norm); keep it at least sqrt(3) "
        "times rest.max_rate (per axis), or a bias a rest learned is clipped at the first motion", gt=0)
    bias_filter: Literal["kalman", "lowpass"] = param(
        "kalman", unit="-", description="how the inclination correction teaches the bias in motion (inertial-tilt's "
        "bias_filter): kalman, VQF's model (the correction measures the low-passed earth-frame bias error, weighed "
        "by the bias's covariance, which the rests shrink); lowpass: mapped with the sample's own rotation at the "
        "fixed rate 1/motion_bias_tau (the behaviour before issue 14's stop 17)")
    bias_sigma_init: float = param(
        math.radians(0.5), unit="rad/s", description="the standard deviation of a bias not yet measured (a MEMS "
        "gyro's turn-on bias; VQF's biasSigmaInit): the variance the bias at rest (rest_bias_gain kalman) and the "
        "bias in motion (bias_filter kalman) start from and grow back to", gt=0)
    bias_sigma_motion: float = param(
        math.radians(0.1), unit="rad/s", description="kalman: the steady-state standard deviation of a bias learned "
        "in motion (VQF's biasSigmaMotion)", gt=0)
    bias_sigma_rest: Annotated[float, Field(gt=0)] | Literal["auto"] | None = param(
        "auto", unit="rad/s", description="kalman: how well a rest tells the bias in motion (the rest's bias learned "
        "with this standard deviation shrinks the covariance; VQF's biasSigmaRest, 0.03 deg/s). A rest measures the "
        "zero-rate bias; the error in motion adds the scale factor's and misalignment's, proportional to the rate, "
        "which only gyro_rate_estimate correct removes (recommended.md). auto: 0.03 deg/s with gyro_rate_estimate "
        "correct, None otherwise. None: a rest does not touch the covariance (the default before "
        "tau_max_parallel)")
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
    lever_arm: bool = param(
        False, unit="-", description="the `lever-arm` sensor model in front: learns where the accelerometer sits from "
        "the rotation centre and removes the rotation's tangential and centripetal accelerations once confident "
        "(off by default: on BROAD it gains only together with output_lead, see recommended.md)")
    mag_calibration: bool = param(
        True, unit="-", description="the `mag-calibration` sensor model in front: learns the magnetometer's hard "
        "and soft iron (a magnet or iron carried with the sensor) from how the field turns against the gyroscope, "
        "applied only while confident and consistent with body-fixed iron (docs/algorithms/models.md); False: the "
        "raw magnetometer")
    mag_held_readings: Literal["once", "each"] = param(
        "each", unit="-", description="mag_calibration's held_readings: a sample repeating the previous magnetometer "
        "reading exactly (a lower-rate magnetometer's hold) counts as a reading each time (the default) or once (one "
        "observation, a segment's change applies from the next sample: for a 10-20 Hz magnetometer; not the default, "
        "its BROAD gain does not hold without trial 04: docs/algorithms/models.md)")
    mag_distortion_significance: float = param(
        0.0, unit="-", description="mag_calibration's distortion_significance: apply the soft-iron distortion only "
        "where it is significant (its five entries' squared Mahalanobis distance from zero above the chi-squared "
        "5-dof quantile at this probability, e.g. 0.99), otherwise the hard-iron offset alone, fitted alone; it "
        "assumes a field uniform where the sensor moves. 0 (the default): the distortion applied whenever "
        "confident (not the default: on BROAD its gain does not hold without trial 04, docs/algorithms/models.md)",
        ge=0, lt=1)
    acc_delay: float | None = param(
        None, unit="s", description="how long before the end of the gyro's step the accelerometer sample describes: "
        "it is paired with the orientation R(q_gyr (x) exp(-(w - bias) d)). None: half the sample interval, the middle "
        "of the step (right when both sensors are sampled alike: point samples, or means over the interval). 0: the "
        "end of the step (an accelerometer sampled at the instant a mean-rate gyro's interval ends). Larger: an "
        "accelerometer later than the gyroscope (a longer filter; `fusionkit lags` measures it against a reference)")
    mag_delay: float | None = param(
        None, unit="s", description="the same for the magnetometer: it is paired with R(q (x) exp(-(w - bias) d)). "
        "None: half the sample interval (the middle of the step); 0: the end of the step")
    mag_hold: bool = param(
        True, unit="-", description="a magnetometer sample equal to the previous one is a lower-rate magnetometer's "
        "held reading: it is paired with the orientation of its fresh sample (its age is part of its delay); "
        "changes nothing where values never repeat")
    mag_measure_interval: float = param(
        0.0, unit="s", description="mag-heading's measure_interval: one heading measurement (the magnetic reference's "
        "step and the heading's correction) per this long instead of per sample, and at each recalibration "
        "(at most 1 s, the magnetic reference's time scale, and tau_mag with heading_gain fixed; mag_delay_estimate: "
        "at most 0.04 s); 0: every sample", ge=0)
    mag_delay_estimate: bool = param(
        False, unit="-", description="estimate the magnetometer's delay against the gyroscope online (mag-heading's "
        "estimate; mag_delay until its standard deviation is below mag_delay_max_std)")
    mag_delay_max_std: float = param(0.1, unit="samples", description="apply the delay estimate once its standard "
                                     "deviation is below this many sample intervals", gt=0)

    @model_validator(mode="after")
    def _gyro_rate_estimate_needs_the_bias_filter(self):
        """The rate error is learned from the Kalman bias filter's residual (inertial-tilt): without it,
        nothing would be learned. Asked for, that is an error; as the default it is off there (the
        compositions without the bias filter in motion stay what they were)."""
        if self.gyro_rate_estimate != "off" and (self.motion_bias_tau is None or self.bias_filter != "kalman"):
            if "gyro_rate_estimate" not in self.model_fields_set:
                self.__dict__["gyro_rate_estimate"] = "off"
            else:
                raise ValueError(f"gyro_rate_estimate {self.gyro_rate_estimate!r} needs the bias in motion "
                                 "(motion_bias_tau, bias_filter 'kalman'; inertial-tilt's rate_error_estimate)")
        if self.gyro_rate_acc_bias > 0 and self.gyro_rate_estimate == "off":  # (it would be silently ignored)
            raise ValueError("gyro_rate_acc_bias is estimated beside the gyro's rate error: it needs "
                             "gyro_rate_estimate 'tau' or 'correct' (with the bias in motion)")
        return self

    @model_validator(mode="after")
    def _mag_measure_interval_bounds(self):
        """mag-heading's ``measure_interval`` bounds, named as here (its own error would name its own)."""
        error = measure_interval_error(self.mag_measure_interval, self.mag_delay_estimate,
                                       MagHeadingConfig.model_fields["field_error_time"].default,
                                       self.tau_mag if self.heading_gain == "fixed" else None,
                                       ("mag_measure_interval", "mag_delay_estimate", "tau_mag"))
        if error:
            raise ValueError(error)
        return self

    @model_validator(mode="after")
    def _slow_interval_within_the_time_constants(self):
        """inertial-tilt refuses a block longer than a tenth of its shortest time constant (tau_acc, or the
        adaptive one's lower bound, 0.5 s): as the default the block shrinks to that (a tau_acc of 0.15 s
        gets 0.015 s blocks), asked for it is an error naming tau_acc."""
        bound, adaptive = slow_interval_bound(self.tau_acc, self.tau_adapt,
                                              InertialTiltConfig.model_fields["tau_min"].default)
        if self.slow_interval > bound:
            if "slow_interval" not in self.model_fields_set:
                self.__dict__["slow_interval"] = bound
            else:
                raise ValueError(f"slow_interval must be at most a tenth of the shortest time constant "
                                 f"({'the adaptive one, 0.5 s' if adaptive else 'tau_acc'}): "
                                 f"{bound:g} s, got {self.slow_interval:g} s (or 0: every sample)")
        return self


class RecommendedFilter(Pipeline):
    """Gyro strapdown + inclination from the inertially low-passed accelerometer + separate
    heading from the magnetometer; rest/motion bias, magnetic disturbance rejection, fast start."""

    name: ClassVar[str] = "recommended"
    Config = RecommendedConfig
    source: ClassVar[str] = "fusionkit (sources 000-003 composed with the state of the art)"
    summary: ClassVar[str] = "channel-separated inclination/heading, inertial low-pass, bias and disturbance handling"

    @staticmethod
    def _bias_sigma_rest(c: RecommendedConfig) -> float | None:
        """inertial-tilt's ``bias_sigma_rest``: None without the rest's bias; ``"auto"`` pins a rest's bias
        (VQF's 0.03 deg/s) only where the gyro's rate error is removed, since otherwise the bias in motion
        carries the rate-proportional error ``E w`` that a rest cannot see."""
        if not c.rest_bias:
            return None
        if c.bias_sigma_rest == "auto":
            return math.radians(0.03) if c.gyro_rate_estimate == "correct" else None
        return c.bias_sigma_rest

    def pipeline_config(self) -> PipelineConfig:
        c = self.config
        detectors = [PluginSpec(name="rest", params=c.rest.model_dump())]
        if c.acc_gate is not None:
            detectors.append(PluginSpec(name="acceleration", params={
                "gravity": c.gravity, "threshold": c.acc_gate, "hold": 0.0, "max_time": _NO_RECOVERY}))
        correctors = []
        if c.rest_bias:
            # no limit needed: at rest the low-passed gyro is below rest.max_rate, and the bias in motion
            # below bias_max
            correctors.append(PluginSpec(name="rest-bias-lowpass", params={
                "tau": c.rest_bias_tau, "lowpass_tau": c.rest.tau, "gain": c.rest_bias_gain,
                "sigma_init": c.bias_sigma_init}))
        correctors.append(PluginSpec(name="inertial-tilt", params={
            "tau": c.tau_acc, "fast_start": c.fast_start, "motion_bias_tau": c.motion_bias_tau,
            "bias_max": c.bias_max, "acc_delay": c.acc_delay, "bias_filter": c.bias_filter,
            "bias_sigma_init": c.bias_sigma_init,
            "bias_sigma_motion": c.bias_sigma_motion, "bias_sigma_rest": self._bias_sigma_rest(c),
            "tau_adapt": c.tau_adapt, "gyro_rate_error": c.gyro_rate_error, "impulse_clip": c.impulse_clip,
            "tau_max_parallel": c.tau_max_parallel,
            "rate_error_estimate": c.gyro_rate_estimate != "off",
            "rate_error_correct": c.gyro_rate_estimate == "correct", "rate_error_interval": c.gyro_rate_interval,
            "rate_error_acc_bias": c.gyro_rate_acc_bias,
            "bias_update_interval": c.bias_update_interval, "slow_interval": c.slow_interval}))
        if c.use_mag:
            magnetic = c.magnetic if c.fast_start else c.magnetic.model_copy(update={"init_time": 0.0})
            correctors.append(PluginSpec(name="mag-heading", params={
                "tau": c.tau_mag, "gain": c.heading_gain, "bias_sigma": c.bias_sigma_motion,
                "rejection": c.mag_rejection, "magnetic": magnetic.model_dump(),
                "rate_tau": c.rest.tau, "mag_bias": c.mag_bias and c.motion_bias_tau is not None,
                "motion_bias_tau": c.motion_bias_tau if c.motion_bias_tau is not None else 100.0,
                "bias_max": c.bias_max, "mag_delay": c.mag_delay, "mag_hold": c.mag_hold,
                "mag_delay_estimate": c.mag_delay_estimate, "delay_max_std": c.mag_delay_max_std,
                "inclination_noise": c.heading_inclination_noise, "measure_interval": c.mag_measure_interval}))
        if c.output_lead > 0.0:
            correctors.append(PluginSpec(name="output-lead", params={"lead": c.output_lead}))
        return PipelineConfig(
            frame=c.frame, nan_policy=c.nan_policy, gyr_range=c.gyr_range, acc_range=c.acc_range,
            max_gap=c.max_gap, body=c.body,
            estimator=PluginSpec(name="poisson-quat", params={"step": "exact"}),
            detectors=detectors, correctors=correctors,
            models=([PluginSpec(name="mag-calibration", params={
                "held_readings": c.mag_held_readings, "distortion_significance": c.mag_distortion_significance})]
                    if c.mag_calibration and c.use_mag else [])
            + ([PluginSpec(name="lever-arm")] if c.lever_arm else []),
            alignment=AlignmentConfig(mode="none", initial_quat=initial_attitude(c.frame)),
        )

    def run(self, rec, *, backend: str = "auto", progress: bool | None = None, state: dict[str, Any] | None = None,
            bias_at=None):
        """:meth:`Pipeline.run`; ``use_mag=False`` does not read the recording's magnetometer at all
        (no MAG_INVALID flags either)."""
        if not self.config.use_mag and getattr(rec, "mag", None) is not None:
            rec = copy.copy(rec)  # a shallow copy: the samples passed the Recording's checks already
            rec.mag = None
        return super().run(rec, backend=backend, progress=progress, state=state, bias_at=bias_at)

    def __init__(self, config=None, **params: Any) -> None:
        super().__init__(config, **params)
        if not self.config.use_mag:  # (an instance attribute: the default's update() pays no extra call)
            self.update = self._update_without_mag

    def _update_without_mag(self, gyr, acc, mag=None, dt: float | None = None, gnss=None):
        return Pipeline.update(self, gyr, acc, None, dt, gnss)

    def _diagnostics(self, st, flags, crit, backend) -> dict[str, Any]:
        d = super()._diagnostics(st, flags, crit, backend)
        tilt = [i for i, c in enumerate(self.correctors) if c.name == "inertial-tilt"]
        if tilt and self.config.gyro_rate_estimate != "off":  # the rate error E (3 x 3) at the end, tau_adapt's kappa
            s = st["cor"][tilt[0]]
            e00, e11, e22, e01, e02, e12 = s[TILT_RATE_ERROR:TILT_RATE_ERROR + 6]  # its symmetric part
            d["gyro_rate_error"] = np.array([[e00, e01, e02], [e01, e11, e12], [e02, e12, e22]])
            d["gyro_rate_kappa"] = math.sqrt(float(s[TILT_KAPPA2]))
            if self.config.gyro_rate_acc_bias > 0:  # the accelerometer's bias told apart from it (m/s^2, body axes)
                d["gyro_rate_acc_bias"] = np.array(s[TILT_RATE_ERROR + 6:TILT_RATE_ERROR + 9])
        heading = [i for i, c in enumerate(self.correctors) if c.name == "mag-heading"]
        if heading:
            s = st["cor"][heading[0]]
            d["mag_reference"] = (float(s[MAG_REFERENCE]), float(s[MAG_REFERENCE + 1]))
            if self.config.heading_gain == "kalman":  # the heading's standard deviation at the end, rad
                d["heading_std"] = math.sqrt(float(s[HEADING_VARIANCE]))
        return d
