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
again; the last confident offset is applied meanwhile (with ``provisional_std``, a provisional
offset of the new fit may replace it before the new estimate is confident). The standard deviation a segment is judged
by is the one its residual is expected to have (:func:`_spread`): the noise's and the estimate's
own, ``sigma_e^2 (1 + tr(H A^-1 H^T) / 3)``. Before the body has turned about enough axes the
estimate is poor along the directions not yet seen, so the first turn about a new axis has a
large residual that is no misfit (judged by the noise alone, it restarted the fit).

Soft iron (``soft_iron=True``, the default): ferrous material carried with the sensor, or a
magnetometer's unequal axis gains, distort the field seen from the body by a matrix: ``m = S R^T h
+ b``. The calibration is ``W = S^-1`` up to a scale: ``W (m_k - b) = C^T W (m_a - b)``. With ``W =
I + E`` (``E`` symmetric and traceless: the field's scale is not observable from directions, so
the calibrated field keeps about the raw one's unit) and ``c = W b`` this is

``(I - C^T) c - E m_k + C^T E m_a = m_k - C^T m_a``,

still linear: eight unknowns (five in ``E``, three in ``c``) in the same forgetting least squares,
and the calibrated sample is ``W m - c``. The confidence is then each unknown's own standard
deviation (``sigma_e^2`` times the diagonal of the inverse information matrix): the offset's
below ``max_std`` of the field's norm and the distortion's below ``max_std``. It needs more
rotation than the offset alone. ``soft_iron=False`` estimates the offset alone, as above (a
soft-iron error then leaves a residual in every segment, which ``sigma_e`` absorbs and the gate
then demands more rotation).

A provisional offset (``provisional_std`` > 0; off by default): before the estimate is confident
the samples carry the whole iron, though the offset may already be known to a few uT while the
distortion (five more unknowns, which need more rotation) is not. Where the offset's standard
deviation is below ``provisional_std`` of the field's norm and the offset exceeds three of them
(so applying it removes more error than it leaves: ``|b|^2`` against ``3 std^2``), and the gate
passes it, the offset alone is applied (``W = I``: the calibrated sample ``m - c``; confidence
0.5); the confident estimate replaces it. It assumes the distortion small against the offset
(a distortion of a few % leaves as much); it fails where its first sample lies inside an
earth-fixed disturbance (``mag-heading`` then learns its reference there, as for a confident
calibration applied there, only more often: the provisional offset comes earlier).

The distortion only where significant (``distortion_significance`` > 0, a probability; off by
default): a confident distortion may still be noise, and applied it turns the heading by that noise.
Its five entries' squared Mahalanobis distance from zero, ``dE = E^T (sigma_e^2 (A^-1)_EE)^-1 E``,
follows chi-squared with 5 degrees of freedom where there is no distortion; where it does not exceed
that distribution's quantile at ``distortion_significance``, the offset alone is applied (``W = I``),
fitted alone from the same normal equations (``A_cc c = y_c``: the whole fit's ``c`` carries ``E``'s
noise through their correlation) and judged by its own standard deviation (confidence and
``provisional_std``); a switch between the two is flagged as a recalibration. The fit itself (its
best estimate, misfit test and residual noise) stays the whole one. It assumes a field uniform where
the sensor moves and ``sigma_e`` the segments' noise: a field that changes with position puts its
change into the segments, and whether ``dE`` crosses the quantile then depends on the room
(docs/algorithms/models.md, "Stop 27").

Held readings: a magnetometer read at a lower rate than the gyroscope (10-100 Hz against
100-1000 Hz) repeats its last reading until the next one. With ``held_readings="once"`` a sample equal
in every component to the last valid one (invalid samples between or not) is that held reading: no new
observation, and as old as its fresh sample. It neither closes nor starts a segment, so every segment runs from one fresh reading to
another, paired with the gyro's turn between them, and the segment count, the residual noise,
the gate's ring and the confidence count independent readings only (closed on held samples, the
segments paired a reading up to one reading interval old with the gyro's turn to the current sample,
and the residual noise that misfit makes put the confidence off; docs/algorithms/models.md). A segment then closes at the first
fresh reading after ``segment_angle`` (one reading interval later at most), and what it changes
applies from the next sample with a valid gyro when it recalibrates (MAG_RECALIBRATED; across a gap the orientation is held: the change
would be read with the body's turn). A repeat is a hold only while younger than 0.5 s (no
magnetometer reads slower than 2 Hz): a reading repeated longer is a constant field (a quantised
magnetometer at rest), each sample a reading; one repeated by chance within 0.5 s closes its
segment at the next different reading (at rest a segment carries little rotation to learn from).

Limits: the gyroscope's own bias turns ``C`` by ``bias * segment_time`` (small against the
segment angle); the magnetometer and gyroscope are taken to be sampled at the same times (a
magnetometer late by ``d`` seconds adds an error of ``|w| d`` per segment, which averages over
rotations in both directions). The readable reference is :meth:`MagCalibrationModel.apply`;
:func:`mag_calibration_apply` is its kernel.

Consistency (``consistency=True``): a confident estimate is not yet body-fixed iron. Near a magnet
on the desk the field is not uniform where the sensor moves, the segments fit only in part, the
residual noise absorbs the misfit and the estimate can still become confident; and the few
segments that enter or leave an earth-fixed field can pull it. What tells them apart
(``consistency_test="earth"``, :func:`_gate`): body-fixed iron makes the raw field change in the
earth frame at every turn, and the calibrated field not; an earth-fixed field is already
constant in the earth frame, except across the few segments that enter or leave it. Over each
of the last 32 segments the gyro's turn ``C`` gives the earth-frame field's change seen from the
body, ``u_k - C^T u_a``, raw (``u = m``) and calibrated (``u = W m - c``); their medians
(:func:`_earth_change`, robust to those few segments) decide. A new calibration is applied where
it does not make the change larger and divides it by ``min_reduction`` (changing the field by at
least ``max_std`` of its norm, the precision the confidence asks for) or, for iron too weak to
stand out of the segments' noise that way, where the norm test below passes; otherwise the
samples pass unchanged. An applied one is withdrawn only where it makes the change
``min_reduction`` times larger (significantly less constant in the earth frame: not body-fixed
iron); a weak, right calibration would otherwise switch off and on with the noise, and each switch
makes ``mag-heading`` learn its reference again. ``consistency_test="norm"``, the test
of before: over the raw samples at the last 32 segment ends, the calibration divides the variance
of the field's relative norm by ``min_reduction`` (an F test of two variances) and does not raise
the dip's (against the accelerometer) (:func:`_consistent`); an earth-fixed field's step in the
norm makes it switch the calibration off and on. ``consistency=False``: the confidence alone.

What the correctors are told (flag MAG_RECALIBRATED): where a closed segment changes the field
the correctors see by more than the fit's refinement (a new estimate applied: the confidence
became 1, the first one or the first after the offset was learned again or the gate refused it,
or a provisional offset's 0.5, or from it 1; or the applied one stopped: the gate refused it), that sample carries the flag. A reader that
judges the field against something it learned from it (``mag-heading``'s disturbance reference,
``follow_calibration``) learns that again. Refinements of an applied estimate carry no flag: they
change the field by about the estimate's standard deviation, which a slowly following reference
absorbs.

Where this sits among the classic calibrations: an ellipsoid fit (the field's norm constant, the
offset and distortion its centre and shape) needs no gyroscope but takes any change of the field's
magnitude, a magnet on the desk included, for part of the ellipsoid; the gyro-aided relation
above is blind to a field that turns with the earth, which is the property that matters online.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar, Literal

import numpy as np
from pydantic import model_validator

from .._kernels import dcm_entries, qmul_entries, quat_to_dcm, rotvec_quat_entries
from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import Sample, SensorModel, SensorModelKernel
from ..rotations import quat_from_rotvec, quat_mul, quat_to_matrix
from ..types import Flag

__all__ = ["MagCalibrationConfig", "MagCalibrationModel", "mag_calibration_apply", "STATE"]

# state layout
_B, _A, _Y, _MA, _DQ, _T, _ANCHOR, _VAR, _N, _CONF, _BAD, _BEST = 0, 3, 12, 15, 18, 22, 23, 24, 25, 26, 27, 28
_RR, _NE = 31, 32  # the weighted sum of |r|^2 and of the weights (the fit's residual noise)
STATE = 33
# soft iron: the unknowns (E's five entries, then c), their information matrix and right-hand side,
# the best and the applied estimate, after the offset's state
_NP = 8
_SA, _SY, _SBEST, _SAPP = 33, 33 + 64, 33 + 72, 33 + 80
STATE_SOFT = 33 + 88
# the consistency gate, after the fit's state (at STATE or STATE_SOFT): the ring's next slot and
# fill, then the raw field and the accelerometer's direction at the last _GK segment ends
_GK = 32
_GI, _GC, _GBUF = 0, 1, 2
_GE = 22  # per segment end: the raw field, the accelerometer, |m|, |a|, the raw dip's sine, the segment's
# first raw field and its turn (body a -> body k, as the rotation matrix C = R(dq), row-major: the earth-frame
# test turns every ring entry at each check, and the matrix is computed once here instead of from the
# quaternion at each check), and the raw field's squared change across it (the earth-frame test's raw term:
# it depends on the segment alone)
# gate_interval: the seconds of segments since the gate's last test, and its verdict then (0: none for the
# segment before this one, 1: passed, 2: refused)
_GT, _GV = 2 + _GE * _GK, 3 + _GE * _GK
GATE = 4 + _GE * _GK
# soft iron, after the gate: the inverse of the information matrix as of the last segment that entered the
# fit, and whether it exists (the next segment's misfit test needs it: computed once, not twice)
_SINV = STATE_SOFT + GATE
_SINVOK = _SINV + _NP * _NP
_SEG_BUF = 255  # the compiled soft-iron segment's working arrays (_k_segment_soft)
# at the end of either layout (soft iron: _H_SOFT, the offset alone: _H_HARD): the last raw magnetometer sample,
# what it was calibrated to, and whether the sample before was a valid one (h + 6: a held reading calibrated
# otherwise than that sample is flagged MAG_HELD, routine with held_readings="once": a segment closed on the fresh
# reading changes the calibration from the next sample, the held one); a change pending for the next valid sample
# (h + 7); whether there was a valid reading at all (h + 8: an invalid sample inside a held run does not make the
# rest of the run fresh); the seconds since the reading last changed (h + 9); the calibration applied before the
# pending change (h + 10 to h + 17: "once" keeps it on samples without a valid gyro, see apply)
_HELD, _H_SOFT, _H_HARD = 18, _SINVOK + 1, STATE + GATE
# "once": a repeat counts as held only while younger than this (s): no magnetometer reads slower than 2 Hz, so a
# reading repeated longer is a constant field (a quantised magnetometer at rest), each sample an observation
_HELD_AGE = 0.5
_RECALIBRATED = int(Flag.MAG_RECALIBRATED)
_MAG_HELD = int(Flag.MAG_HELD)
_PROVISIONAL = 0.5  # the confidence of an offset applied before the estimate is confident (provisional_std)
# the fit's residual sum of squares, sum |r|^2 - y . x, is known to the cancellation's rounding (about eps times the
# condition of the information matrix, times sum |r|^2): below this fraction of sum |r|^2 it is that rounding, not a
# noise (a real magnetometer's noise leaves 1e-6 or more), and is taken as this floor. Without it a noise-free fit
# (a simulation) had a residual of 0 or 1e-13 by the order of the sums, its std 0 or not, and the compiled path applied
# a calibration the reference refused (one that mapped the field to 1e-11 uT)
_RES_FLOOR = 1e-9


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
        6.0, unit="-", description="a segment whose residual exceeds this many standard deviations (of the residual "
        "expected: the noise's and the estimate's own uncertainty) does not fit",
        gt=0)
    outlier_count: int = param(
        3, unit="-", description="this many misfits in a row: the offset changed, learn it again", ge=1)
    first_check: bool = param(
        True, unit="-", description="when the residual noise is first trusted (min_segments segments, fewer than the "
        "gate ring's 32, which must hold exactly the fit's segments: no check with min_segments 32 or more), judge "
        "the segments it rests on, which no misfit test saw, by their deleted residuals: the worst quarter out "
        "whatever their misfit (two misfits hide in each other's noise), each put back that fits the rest within "
        "outlier_sigma standard deviations, any other over that removed, and the fit rebuilt from the rest. A "
        "segment that enters or leaves a field change fixed in the earth frame (a disturbance) does not fit "
        "body-fixed iron; kept, it pulls the estimate and inflates the noise estimate, which then asks for several "
        "times the rotation before the estimate is confident. False: the model before (every early segment kept)")
    soft_iron: bool = param(
        True, unit="-", description="estimate the soft-iron distortion (a symmetric matrix) with the offset; "
        "False: the offset alone, which needs less rotation to become confident")
    consistency: bool = param(
        True, unit="-", description="apply a confident estimate only where it is consistent with body-fixed iron: "
        "over the last 32 segment ends it divides the variance of the field's relative norm by min_reduction and "
        "does not raise the variance of its angle to the accelerometer's (the dip); otherwise the samples pass "
        "unchanged. False: the confidence alone (the model before this gate)")
    consistency_test: Literal["earth", "norm"] = param(
        "earth", unit="-", description="what consistency=True tests. earth: the calibration makes the field more "
        "constant in the earth frame across each of the last 32 segments (the gyro's turn over one segment): the "
        "median over them of the squared change of the calibrated field, turned into one frame, is below the raw "
        "field's by min_reduction, or not above it and the norm test passes; withdrawn where it is min_reduction "
        "times above it; an earth-fixed field (a steel structure, a magnet on the desk) changes only the segments "
        "that enter or leave it. norm: the field's norm and dip at the last 32 segment ends (the gate of "
        "before; an earth-fixed field's step in the norm makes it refuse iron it would otherwise accept)")
    min_reduction: float = param(
        2.0, unit="-", description="the factor by which the calibration must reduce the field norm's variance: an F "
        "test at the 32 segment ends' degrees of freedom (F(31, 31) at 97%)", gt=1)
    provisional_std: float = param(
        0.0, unit="-", description="before the estimate is confident (max_std), apply its offset alone (no "
        "distortion) once the offset's standard deviation is below this fraction of the field's norm and the offset "
        "exceeds three of its standard deviations (applying it then removes more error than it adds), where the "
        "consistency gate passes; the confident estimate replaces it. 0: nothing before the confidence. With "
        "soft_iron=False the estimate is the offset alone, so only a value over max_std does anything (one up to "
        "max_std is refused)", ge=0, le=1)
    gate_interval: float = param(
        0.5, unit="s", description="consistency: a confident estimate the gate refused is tested again only once the "
        "segments since that test span this long (the ring of 32 segment ends it judges changes by one entry per "
        "segment); the segments between stay refused. An applied estimate is tested at every segment, and a segment "
        "that is not confident ends the refusal. 0: a test at every segment", ge=0)
    held_readings: Literal["once", "each"] = param(
        "each", unit="-", description="a sample repeating the previous valid one exactly (a lower-rate "
        "magnetometer's held reading). each (default): every sample is a reading and a segment's change applies on "
        "the sample that closes it. once: one observation; it neither closes nor starts a segment, and what a "
        "segment changes applies from the next sample (segments pair a fresh reading with the gyro's turn to its own "
        "instant, and count, residual noise and gate count independent readings): far faster to converge with a "
        "10-20 Hz magnetometer, but not the default: on BROAD (whose magnetometer repeats 29 % of its samples) it "
        "moves the consistency gate's timing and its gain does not hold without trial 04 "
        "(docs/algorithms/models.md)")
    distortion_significance: float = param(
        0.0, unit="-", description="soft_iron: apply the distortion only where it is significant, its five entries' "
        "squared Mahalanobis distance from zero (with the fit's residual noise) above the chi-squared (5 degrees of "
        "freedom) quantile at this probability; otherwise the offset alone, fitted alone from the same normal "
        "equations, with its own standard deviation for the confidence and provisional_std. A distortion once applied "
        "with a confident estimate stays until the fit is learned again (no switching back and forth where the "
        "distance hovers at the quantile). It assumes a field "
        "uniform where the sensor moves (a non-uniform one makes a distortion look significant or hides one). 0: off, "
        "the distortion applied with the offset whenever confident (docs/algorithms/models.md, \"Stop 27\")",
        ge=0, lt=1)

    @model_validator(mode="after")
    def _significance_needs_soft_iron(self):
        """``distortion_significance`` chooses between the distortion and the offset alone: with
        ``soft_iron=False`` there is no distortion to test (silently nothing)."""
        if not self.soft_iron and self.distortion_significance > 0.0:
            raise ValueError(f"distortion_significance ({self.distortion_significance:g}) does nothing with "
                             "soft_iron=False: there is no distortion to test")
        return self

    @model_validator(mode="after")
    def _provisional_needs_room(self):
        """With ``soft_iron=False`` the confident estimate is the offset alone and is applied at ``max_std``:
        a provisional offset at a standard deviation up to that would never come first (silently nothing)."""
        if not self.soft_iron and 0.0 < self.provisional_std <= self.max_std:
            raise ValueError(f"provisional_std ({self.provisional_std:g}) does nothing with soft_iron=False unless "
                             f"over max_std ({self.max_std:g}): the confident offset comes first")
        return self


class MagCalibrationModel(SensorModel):
    """Learns the body-fixed magnetometer offset from how the field turns against the gyroscope."""

    name: ClassVar[str] = "mag-calibration"
    Config = MagCalibrationConfig
    source: ClassVar[str] = "fusionkit (gyro-aided hard-iron estimation: the field turns with the body, the offset not)"
    summary: ClassVar[str] = ("online hard- and soft-iron calibration from gyro-propagated field directions, applied "
                              "when confident")

    def initial_state(self, dt: float) -> np.ndarray:
        s = np.zeros((_H_SOFT if self.config.soft_iron else _H_HARD) + _HELD)
        s[_DQ] = 1.0
        return s

    def params(self) -> np.ndarray:
        c = self.config
        return np.array([c.segment_angle, c.segment_time, c.forget_time, c.max_std, float(c.min_segments),
                         c.outlier_sigma, float(c.outlier_count), float(c.soft_iron), _gate_code(c),
                         c.min_reduction, math.cos(0.5 * c.segment_angle), c.gate_interval, c.provisional_std,
                         float(c.held_readings == "each"), _quantile(c.distortion_significance), float(c.first_check)])

    def kernel(self) -> SensorModelKernel:
        c = self.config
        return SensorModelKernel(mag_calibration_apply, self.params(), static=(c.soft_iron, c.held_readings == "once"))

    def report(self, state: np.ndarray) -> dict:
        """The calibration at the end of a run (``Result.diagnostics["models"]["mag-calibration"]``),
        in the magnetometer's unit (the recording's, uT for fusionkit's loaders and simulator) and
        the body axes of the recording; the calibrated field is ``W (m - b)``:

        - ``hard_iron``: the fit's body-fixed offset ``b`` (3,), NaN while the fit is not solvable
          (before rotations about two axes, or just after it was learned again);
        - ``hard_iron_std``: its standard deviation, the least-known direction's (offset alone) or
          the largest axis's (soft iron, of ``c = W b``): what the confidence compares with
          ``max_std`` of the field's norm; inf before ``min_segments`` segments;
        - ``soft_iron``: the fit's ``W = I + E`` (3, 3; ``E`` symmetric with zero trace, so ``W``
          keeps about the raw field's scale), ``soft_iron_std`` the largest standard deviation of
          ``E``'s entries (dimensionless); both None with ``soft_iron=False``;
        - ``confidence``: 1 confident, 0.5 a provisional offset (``provisional_std``), 0 none (also
          while the gate refuses a confident estimate, and after a misfit restarted the fit);
        - ``applied``: whether a calibration corrects the samples; ``applied_hard_iron`` /
          ``applied_soft_iron`` the ``b`` and ``W`` it applies (zeros and the identity for none;
          the last confident one is kept through a restart; ``applied_soft_iron`` None with
          ``soft_iron=False``). They differ from the fit where it is not (yet) applied;
        - ``segments``: the segments in the current fit (from 0 again after a restart)."""
        c, s = self.config, state
        n = int(s[_N])
        var = float(s[_VAR])
        if c.soft_iron:
            best = s[_SBEST:_SBEST + _NP]
            known = s[_SINVOK] != 0.0 and n > 0
            w = np.eye(3) + _distortion(best)
            try:
                hard = np.linalg.solve(w, best[5:8]) if known else np.full(3, math.nan)
            except np.linalg.LinAlgError:  # (a degenerate fit: W singular)
                hard = np.full(3, math.nan)
            soft = w if known else np.full((3, 3), math.nan)
            if known and n >= c.min_segments:
                std = np.sqrt(np.maximum(var * np.diag(s[_SINV:_SINV + _NP * _NP].reshape(_NP, _NP)), 0.0))
                hard_std, soft_std = float(std[5:8].max()), float(std[:5].max())
            else:
                hard_std = soft_std = math.inf
            applied_w = np.eye(3) + _distortion(s[_SAPP:_SAPP + 5])
        else:
            a, inv = s[_A:_A + 9].reshape(3, 3), np.empty((3, 3))
            known = n > 0 and _inverse3(a, inv)
            hard = s[_BEST:_BEST + 3].copy() if known else np.full(3, math.nan)
            lmin = _min_eig_sym3(a) if known else 0.0
            hard_std = math.sqrt(var / lmin) if known and n >= c.min_segments and lmin > 0.0 else math.inf
            soft = soft_std = applied_w = None
        return {"hard_iron": hard, "hard_iron_std": hard_std, "soft_iron": soft, "soft_iron_std": soft_std,
                "confidence": float(s[_CONF]), "applied": _applied(s, c.soft_iron) != 0,
                "applied_hard_iron": s[_B:_B + 3].copy(), "applied_soft_iron": applied_w, "segments": n}

    def apply(self, state: np.ndarray, sample: Sample, quat: np.ndarray) -> tuple[Sample, int]:
        c, s = self.config, state
        gyr_ok = bool(np.isfinite(sample.gyr).all())
        if not gyr_ok:  # no rotation known: the segment cannot be closed
            s[_ANCHOR] = 0.0
        elif s[_ANCHOR]:  # the body's turn since the anchor, body a -> body k
            s[_DQ:_DQ + 4] = quat_mul(s[_DQ:_DQ + 4], quat_from_rotvec(sample.gyr * sample.dt))
            s[_T] += sample.dt
        h = _H_SOFT if c.soft_iron else _H_HARD
        s[h + 9] += sample.dt
        if sample.mag is None:
            s[h + 6] = 0.0  # (an invalid sample between two equal ones: not held as MAG_HELD tells it)
            if s[_T] > 2.0 * c.segment_time:
                s[_ANCHOR] = 0.0
            return sample, 0
        m = np.asarray(sample.mag, dtype=float)
        # a held reading (a lower-rate magnetometer's, repeated exactly) is not a new observation: it neither
        # closes nor starts a segment (its reading belongs to the fresh sample's instant, not this one's);
        # held_readings="each" takes every sample as a reading (the model before). A repeat of the last valid
        # reading, invalid samples between or not, while it is young (_HELD_AGE)
        once = c.held_readings == "once"
        same = bool(s[h + 8]) and m.tolist() == s[h:h + 3].tolist()
        held = same and bool(s[h + 6])
        if not same:
            s[h + 9] = 0.0
        fresh = not once or not same or s[h + 9] >= _HELD_AGE
        # "once": the sample is calibrated as the segments before it left the calibration: a segment this sample
        # closes changes it from the next sample on (with its flags), so a held next sample is the same reading
        # calibrated both ways, which mag-heading's re-expression reads the calibration's change from; "each": a
        # segment's change applies on the sample that closes it (s[h + 7] is then always 0 here). The change waits
        # for a sample with a valid gyro: across a gap the orientation is held, and the calibrated field's change
        # from the sample before is then the body's turn as much as the calibration's
        if once:
            out, flags = self._deliver(s, h, m, held, bool(s[h + 7]) and not gyr_ok)
        if gyr_ok and s[_ANCHOR] and fresh:
            dq = s[_DQ:_DQ + 4]
            if _turned(dq[0], dq[1], dq[2], dq[3], math.cos(0.5 * c.segment_angle)) or s[_T] >= c.segment_time:
                acc = sample.acc if sample.acc is not None and np.isfinite(sample.acc).all() else np.zeros(3)
                _ring_push(s, STATE_SOFT if c.soft_iron else STATE, m, acc, s[_MA:_MA + 3], dq)
                conf, applied = s[_CONF], _applied(s, c.soft_iron)
                if once and c.soft_iron:  # the calibration applied until the change is delivered
                    s[h + 10:h + 10 + _NP] = s[_SAPP:_SAPP + _NP]
                elif once:
                    s[h + 10:h + 13] = s[_B:_B + 3]
                if c.soft_iron:
                    self._segment_soft(s, quat_to_matrix(dq).T, m)
                else:
                    self._segment(s, quat_to_matrix(dq).T, m)
                s[h + 7] = _changed(conf, applied, s[_CONF], _applied(s, c.soft_iron))
                s[_ANCHOR] = 0.0
        if gyr_ok and not s[_ANCHOR] and fresh:  # this sample starts the next segment
            s[_MA:_MA + 3] = m
            s[_DQ:_DQ + 4] = (1.0, 0.0, 0.0, 0.0)
            s[_T] = 0.0
            s[_ANCHOR] = 1.0
        if not once:
            out, flags = self._deliver(s, h, m, held, False)
        return sample._replace(mag=out), flags

    def _deliver(self, s, h, m, held, wait):
        """``m`` calibrated, with the flags of the change pending since a segment closed (h + 7), which
        is delivered now unless the change ``wait``s (then ``m`` gets the calibration before it)."""
        flags = 0 if wait else int(s[h + 7])
        if not wait:
            s[h + 7] = 0.0
        out, f = self._calibrate(s, h, m, held, wait)
        return out, flags | f

    def _calibrate(self, s, h, m, held, before):
        """``m`` through the calibration applied now (``before``: the one before the pending change),
        remembered as the last reading (raw and calibrated); flag MAG_HELD if a held reading comes out
        otherwise than before (a reader still knows it is held)."""
        if self.config.soft_iron:
            t = s[h + 10:h + 10 + _NP] if before else s[_SAPP:_SAPP + _NP]
            out = (np.eye(3) + _distortion(t)) @ m - t[5:8]
        else:
            out = m - (s[h + 10:h + 13] if before else s[_B:_B + 3])
        flags = _MAG_HELD if held and out.tolist() != s[h + 3:h + 6].tolist() else 0
        s[h:h + 3], s[h + 3:h + 6], s[h + 6], s[h + 8] = m, out, 1.0, 1.0
        return out, flags

    def _segment(self, s, ct, m) -> None:
        """One closed segment: ``(I - C^T) b = m_k - C^T m_a`` into the forgetting least squares."""
        c = self.config
        prev, s[STATE + _GV] = s[STATE + _GV], 0.0  # (gate_interval: the last verdict, for this segment only)
        h = np.eye(3) - ct
        r = m - ct @ s[_MA:_MA + 3]
        n = s[_N]
        e = r - h @ s[_BEST:_BEST + 3]
        e2 = float(e @ e) / 3.0
        lam = math.exp(-s[_T] / c.forget_time)
        inv = np.empty((3, 3))
        if n >= c.min_segments and e2 > c.outlier_sigma ** 2 * s[_VAR] * _spread(
                h, inv, _invert_spd(s[_A:_A + 9].reshape(3, 3).copy(), np.empty((3, 3)), inv, 3), lam, 3):
            s[_BAD] += 1.0
            if s[_BAD] >= c.outlier_count:  # the offset changed: forget it and learn again
                s[_A:_A + 9] = 0.0
                s[_Y:_Y + 3] = 0.0
                s[_N] = s[_VAR] = s[_CONF] = s[_BAD] = s[_RR] = s[_NE] = 0.0
                s[STATE + _GC] = 0.0
            return
        s[_BAD] = 0.0
        a = lam * s[_A:_A + 9].reshape(3, 3) + h.T @ h
        s[_A:_A + 9] = a.ravel()
        s[_Y:_Y + 3] = lam * s[_Y:_Y + 3] + h.T @ r
        s[_RR] = lam * s[_RR] + float(r @ r)
        s[_NE] = lam * s[_NE] + 1.0
        s[_N] = n + 1.0
        if c.first_check and s[_N] == c.min_segments < _GK and s[STATE + _GC] == c.min_segments:
            _first_check(s, 3, c.min_segments, c.outlier_sigma)
            a = s[_A:_A + 9].reshape(3, 3).copy()
        best = _solve3(a, s[_Y:_Y + 3])
        if best is None:
            return
        s[_BEST:_BEST + 3] = best
        # the fit's residual noise per axis: sum |r - H b|^2 = sum |r|^2 - y . b at the optimum
        if s[_NE] > 1.0:
            s[_VAR] = max(s[_RR] - float(s[_Y:_Y + 3] @ best), _RES_FLOOR * s[_RR]) / (3.0 * (s[_NE] - 1.0))
        lmin = _min_eig_sym3(a)
        field = float(np.linalg.norm(m - best))
        if s[_N] < c.min_segments or not lmin > 0.0:
            return
        std = math.sqrt(s[_VAR] / lmin)
        if std <= c.max_std * field:
            conf = 1.0  # confident
        elif _provisional(s[_CONF], std, best, c.provisional_std * field):
            conf = _PROVISIONAL
        else:
            return
        # (the gate's "applied": a confident estimate, or for a provisional offset any)
        applied = s[_CONF] == 1.0 if conf == 1.0 else s[_CONF] != 0.0
        if c.consistency and not _gate_timed(_gate_code(c), s, STATE, np.eye(3), best, c.min_reduction, applied,
                                              c.max_std, np.empty(2 * _GK), prev, s[_T], c.gate_interval):
            s[_B:_B + 3] = 0.0  # confident, but not body-fixed iron: pass the samples unchanged
            s[_CONF] = 0.0
            return
        s[_B:_B + 3] = best
        s[_CONF] = conf

    def _segment_soft(self, s, ct, m) -> None:
        """One closed segment, soft iron: ``(I - C^T) c - E m_k + C^T E m_a = m_k - C^T m_a``."""
        c = self.config
        prev, s[STATE_SOFT + _GV] = s[STATE_SOFT + _GV], 0.0  # (gate_interval: the last verdict, for this segment only)
        h = np.empty((3, _NP))
        _soft_rows(ct, s[_MA:_MA + 3], m, h)
        r = m - ct @ s[_MA:_MA + 3]
        n = s[_N]
        e = r - h @ s[_SBEST:_SBEST + _NP]
        lam = math.exp(-s[_T] / c.forget_time)
        inv = s[_SINV:_SINV + _NP * _NP].reshape(_NP, _NP)  # A^-1, kept since A last changed (below)
        if n >= c.min_segments and float(e @ e) / 3.0 > c.outlier_sigma ** 2 * s[_VAR] * _spread(
                h, inv, s[_SINVOK] != 0.0, lam, _NP):
            s[_BAD] += 1.0
            if s[_BAD] >= c.outlier_count:  # the calibration changed: forget it and learn again
                s[_SA:_SA + _NP * _NP] = 0.0
                s[_SY:_SY + _NP] = 0.0
                s[_N] = s[_VAR] = s[_CONF] = s[_BAD] = s[_RR] = s[_NE] = s[_SINVOK] = 0.0
                s[STATE_SOFT + _GC] = 0.0
            return
        s[_BAD] = 0.0
        a = lam * s[_SA:_SA + _NP * _NP].reshape(_NP, _NP) + h.T @ h
        s[_SA:_SA + _NP * _NP] = a.ravel()
        s[_SY:_SY + _NP] = lam * s[_SY:_SY + _NP] + h.T @ r
        s[_RR] = lam * s[_RR] + float(r @ r)
        s[_NE] = lam * s[_NE] + 1.0
        s[_N] = n + 1.0
        if c.first_check and s[_N] == c.min_segments < _GK and s[STATE_SOFT + _GC] == c.min_segments:
            _first_check(s, _NP, c.min_segments, c.outlier_sigma)
            a = s[_SA:_SA + _NP * _NP].reshape(_NP, _NP).copy()
        s[_SINVOK] = float(_invert_spd(a.copy(), np.empty((_NP, _NP)), inv, _NP))  # inv: untouched if not invertible
        if not s[_SINVOK]:
            return
        best = inv @ s[_SY:_SY + _NP]
        s[_SBEST:_SBEST + _NP] = best
        if 3.0 * s[_NE] > _NP:  # the residual noise: sum |r - H x|^2 = sum |r|^2 - y . x at the optimum
            s[_VAR] = max(s[_RR] - float(s[_SY:_SY + _NP] @ best), _RES_FLOOR * s[_RR]) / (3.0 * s[_NE] - _NP)
        w = np.eye(3) + _distortion(best)
        field = float(np.linalg.norm(w @ m - best[5:8]))
        std = np.sqrt(s[_VAR] * np.diag(inv))
        std_c, std_e = std[5:8].max(), std[:5].max()
        if s[_N] < c.min_segments:
            return
        q, alone = _quantile(c.distortion_significance), False
        # distortion_significance: the offset alone (W = I) where the distortion is not significant; a distortion once
        # applied with a confident estimate stays until the fit is learned again (no switching back and forth, each
        # switch a recalibration, where the distance hovers at the quantile)
        if q > 0.0 and not (s[_CONF] == 1.0 and _applied(s, True) == 2):
            ai, o = np.empty((3, 3)), np.empty(4)
            alone = _inverse3(s[_SA:_SA + _NP * _NP].reshape(_NP, _NP)[5:8, 5:8].copy(), ai) and _offset_alone(
                s, ai, q, o)
            if alone:
                best, w = np.concatenate((np.zeros(5), o[0:3])), np.eye(3)
                field = float(np.linalg.norm(m - best[5:8]))
                std_c, std_e = o[3], 0.0
        if std_c <= c.max_std * field and std_e <= c.max_std:
            conf, wg = 1.0, w  # confident: the whole calibration (or the offset alone, fitted alone)
        elif _provisional(s[_CONF], std_c, best[5:8], c.provisional_std * field):
            conf, wg = _PROVISIONAL, np.eye(3)  # the offset alone: W = I
        else:
            return
        # (the gate's "applied": a confident estimate, or for a provisional offset any)
        applied = s[_CONF] == 1.0 if conf == 1.0 else s[_CONF] != 0.0
        if c.consistency and not _gate_timed(_gate_code(c), s, STATE_SOFT, wg, best[5:8], c.min_reduction, applied,
                                              c.max_std, np.empty(2 * _GK), prev, s[_T], c.gate_interval):
            s[_SAPP:_SAPP + _NP] = 0.0  # confident, but not body-fixed iron: pass the samples unchanged
            s[_B:_B + 3] = 0.0
            s[_CONF] = 0.0
            return
        if conf == 1.0 and not alone:
            s[_SAPP:_SAPP + _NP] = best
            s[_B:_B + 3] = np.linalg.solve(w, best[5:8])  # the offset in the raw field's units, b = W^-1 c
        else:
            s[_SAPP:_SAPP + 5] = 0.0  # the offset alone: W = I, so b = c
            s[_SAPP + 5:_SAPP + _NP] = best[5:8]
            s[_B:_B + 3] = best[5:8]
        s[_CONF] = conf


def _applied(s, soft) -> int:
    """Which calibration is applied: 0 none (its entries all zero), 1 an offset alone, 2 (soft iron) an
    offset with a distortion. The same statements in the reference and, compiled, in the kernel."""
    if soft:
        for j in range(5):
            if s[_SAPP + j] != 0.0:
                return 2
    i = _SAPP + 5 if soft else _B
    for j in range(3):
        if s[i + j] != 0.0:
            return 1
    return 0


def _provisional(conf, std, b, level) -> bool:
    """``provisional_std``: whether an estimate not yet confident may be applied as the offset
    alone: none confident is applied (``conf`` below 1), the offset's standard deviation ``std`` is
    at most ``level`` (``provisional_std`` times the field's norm), and the offset ``b`` exceeds three
    of it (its expected squared error after, ``3 std^2`` over three axes, is then well below the
    ``|b|^2`` it removes). The same statements in the reference and, compiled, in the kernel."""
    if conf == 1.0 or not (level > 0.0 and std <= level):  # (level 0: provisional_std off)
        return False
    return b[0] * b[0] + b[1] * b[1] + b[2] * b[2] >= 9.0 * std * std


def _offset_alone(s, ai, q, out) -> bool:
    """``distortion_significance``: whether the soft-iron estimate's distortion ``E`` (its first five
    unknowns, ``s[_SBEST:]``) is not significant, and if so the offset fitted alone. ``E``'s squared
    Mahalanobis distance from zero is ``dE = E^T (sigma_e^2 (A^-1)_EE)^-1 E``; the inverse of that block
    of ``A^-1`` is the Schur complement ``A_EE - A_Ec A_cc^-1 A_cE`` (``A`` the information matrix,
    ``ai = A_cc^-1`` its offset block's inverse), so ``sigma_e^2 dE = E^T A_EE E - g^T A_cc^-1 g`` with
    ``g = A_cE E``: no 5x5 inverse. ``E`` is significant where ``dE`` exceeds ``q`` (the chi-squared
    quantile with 5 degrees of freedom, 0 never here): False, the estimate kept whole. Otherwise ``E``
    is noise in the heading: ``out[0:3]`` is the offset fitted alone from the same normal equations,
    ``c = A_cc^-1 y_c`` (not the whole fit's ``c``, which carries ``E``'s noise through their
    correlation), and ``out[3]`` its largest standard deviation, ``sigma_e`` times the square root of
    ``A_cc^-1``'s diagonal. The same statements in the reference and, compiled, in the kernel."""
    ee = 0.0
    for i in range(5):
        x = 0.0
        for j in range(5):
            x += s[_SA + _NP * i + j] * s[_SBEST + j]
        ee += s[_SBEST + i] * x
    for k in range(3):  # g = A_cE E, in out[0:3] until the offset replaces it
        x = 0.0
        for j in range(5):
            x += s[_SA + _NP * (5 + k) + j] * s[_SBEST + j]
        out[k] = x
    gg = 0.0
    for k in range(3):
        gg += out[k] * (ai[k, 0] * out[0] + ai[k, 1] * out[1] + ai[k, 2] * out[2])
    if ee - gg > q * s[_VAR]:
        return False
    std = 0.0
    for k in range(3):
        out[k] = ai[k, 0] * s[_SY + 5] + ai[k, 1] * s[_SY + 6] + ai[k, 2] * s[_SY + 7]
        std = max(std, math.sqrt(max(s[_VAR] * ai[k, k], 0.0)))
    out[3] = std
    return True


@functools.lru_cache(maxsize=8)
def _quantile(p) -> float:
    """``distortion_significance``'s threshold: the chi-squared quantile with 5 degrees of freedom
    (``E``'s entries) at ``p``; 0 for ``p`` 0 (off). Computed in ``params()`` and by the reference,
    never in the kernel (scipy.stats is imported only where the option is on)."""
    if not p > 0.0:
        return 0.0
    from scipy.stats import chi2

    return float(chi2.ppf(p, 5))


def _changed(conf, applied, conf_now, applied_now) -> int:
    """The flag bits of a closed segment, from the confidence and whether a calibration is applied
    before (``conf``, ``applied``) and after it (``conf_now``, ``applied_now``): MAG_RECALIBRATED where the field the correctors see changes by more than
    the fit's refinement: a new estimate is applied (the confidence rose: to 1, the first one, or the
    first one after the offset was learned again or the gate refused it, or to a provisional offset's
    0.5, or from it to 1), the applied one stopped (the gate refused it: the samples pass unchanged),
    or changed its kind (``distortion_significance``: the distortion became significant or stopped
    being so, a change of the field by several of its standard deviations; ``applied``: which one,
    :func:`_applied`). The same statements in the reference and, compiled, in the kernel."""
    if conf_now > conf or (applied != 0 and applied_now != applied):
        return _RECALIBRATED
    return 0


def _distortion(t):
    """``E`` from its five entries: symmetric and traceless."""
    return np.array([[t[0], t[2], t[3]], [t[2], t[1], t[4]], [t[3], t[4], -t[0] - t[1]]])


def _turned(w, x, y, z, c) -> bool:
    """Whether the rotation ``(w, x, y, z)`` (any norm) turns by ``angle`` or more, given
    ``c = cos(angle / 2)``: ``2 atan2(|(x, y, z)|, |w|) >= angle`` as ``w^2 <= c^2 |q|^2`` (no
    trigonometry or square root per sample; an ``angle`` beyond pi, ``c < 0``, is never reached)."""
    return c >= 0.0 and w * w <= c * c * (w * w + x * x + y * y + z * z)


def _ring_push(s, g, m, a, ma, dq):
    """A segment's end into the gate's ring (at ``s[g:]``): the raw field ``m`` and the
    accelerometer ``a`` (zeros when invalid), the segment's first raw field ``ma`` and its turn
    ``dq`` (body a -> body k, stored as its rotation matrix). The same statements in the reference
    and, compiled, in the kernel."""
    i = int(s[g + _GI])
    k = g + _GBUF + _GE * i
    for j in range(3):
        s[k + j] = m[j]
        s[k + 3 + j] = a[j]
        s[k + 9 + j] = ma[j]
    (s[k + 12], s[k + 13], s[k + 14], s[k + 15], s[k + 16], s[k + 17], s[k + 18], s[k + 19],
     s[k + 20]) = dcm_entries(dq[0], dq[1], dq[2], dq[3])
    s[k + 21] = _field_change(m[0], m[1], m[2], ma[0], ma[1], ma[2], s, k + 12)
    # what the gate computes of the raw field at every check, once: its norm, the accelerometer's, the dip's sine
    nr = math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    na = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    s[k + 6], s[k + 7] = nr, na
    s[k + 8] = (m[0] * a[0] + m[1] * a[1] + m[2] * a[2]) / (nr * na) if na > 0.0 and nr > 0.0 else 0.0
    s[g + _GI] = float((i + 1) % _GK)
    s[g + _GC] = min(s[g + _GC] + 1.0, float(_GK))


def _consistent(s, g, w, c, min_reduction) -> bool:
    """Whether the calibration ``W m - c`` behaves as body-fixed iron over the ring's segment ends:
    it divides the variance of the field's relative norm (``|m| / mean |m|``) by ``min_reduction``
    and does not raise the variance of the sine of the dip (the field's angle to the horizontal
    plane the accelerometer gives). A field fixed in the earth frame but not uniform where the
    sensor moves changes with position, which no body-frame calibration makes constant. The same
    statements in the reference and, compiled, in the kernel."""
    n = int(s[g + _GC])
    if n < 3:
        return False
    r1 = r2 = c1 = c2 = 0.0
    nd = 0
    rd1 = rd2 = cd1 = cd2 = 0.0
    for i in range(n):
        k = g + _GBUF + _GE * i
        m0, m1, m2 = s[k], s[k + 1], s[k + 2]
        a0, a1, a2 = s[k + 3], s[k + 4], s[k + 5]
        x0 = w[0, 0] * m0 + w[0, 1] * m1 + w[0, 2] * m2 - c[0]
        x1 = w[1, 0] * m0 + w[1, 1] * m1 + w[1, 2] * m2 - c[1]
        x2 = w[2, 0] * m0 + w[2, 1] * m1 + w[2, 2] * m2 - c[2]
        nr = s[k + 6]
        nc = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        r1 += nr
        r2 += nr * nr
        c1 += nc
        c2 += nc * nc
        na = s[k + 7]
        if na > 0.0 and nr > 0.0 and nc > 0.0:
            dr = s[k + 8]
            dc = (x0 * a0 + x1 * a1 + x2 * a2) / (nc * na)
            nd += 1
            rd1 += dr
            rd2 += dr * dr
            cd1 += dc
            cd2 += dc * dc
    if not (r1 > 0.0 and c1 > 0.0):
        return False
    var_raw = max(r2 / n - (r1 / n) ** 2, 0.0) / (r1 / n) ** 2
    var_cal = max(c2 / n - (c1 / n) ** 2, 0.0) / (c1 / n) ** 2
    if not min_reduction * var_cal <= var_raw:
        return False
    if nd >= 3:
        return max(cd2 / nd - (cd1 / nd) ** 2, 0.0) <= max(rd2 / nd - (rd1 / nd) ** 2, 0.0)
    return True


def _gate_code(c) -> float:
    """The gate's test as the kernel's parameter: 0 none (``consistency=False``), 1 norm, 2 earth."""
    return 0.0 if not c.consistency else 1.0 if c.consistency_test == "norm" else 2.0


def _gate(code, s, g, w, c, min_reduction, applied, max_std, work) -> bool:
    """Whether the calibration ``W m - c`` passes the gate ``code`` (:func:`_gate_code`); ``applied``:
    whether the calibration before this segment was applied and confident (earth: see
    :func:`_earth_change`; a new calibration that changes the field by less than ``max_std`` of
    its norm, the precision the confidence asks for, is applied only where the norm test passes).
    ``work``: at least ``2 * 32`` entries of scratch for :func:`_earth_change`."""
    if code == 1.0:
        return _consistent(s, g, w, c, min_reduction)
    raw, cal, change = _earth_change(s, g, w, c, work, not applied)
    if applied:  # withdrawn where it makes the field significantly less constant in the earth frame
        return cal <= min_reduction * raw
    return cal <= raw and ((min_reduction * cal <= raw and change >= max_std)
                           or _consistent(s, g, w, c, min_reduction))


def _gate_kept(s, g, prev, seg_t, interval) -> bool:
    """``gate_interval``: whether the gate's refusal in the segment before (``prev`` 2; 1: it passed,
    0: not tested) stands for this segment of ``seg_t`` s, and if so counts the segment towards the
    next test. The gate judges a confident estimate over the ring of the last 32 segment ends, which
    a segment changes by one entry, while the estimate moves by about its standard deviation: tested
    at every segment while the body turns fast (a segment every 0.1 s), a refused estimate is judged
    again on nearly the same ring, at about 0.6 us each. So a refusal is kept for the segments of the
    next ``interval`` s: a calibration is applied up to ``interval`` s later. An applied one is
    tested at every segment (withdrawn as soon as before). The same statements in the reference and,
    compiled, in the kernel."""
    if prev == 2.0 and s[g + _GT] + seg_t < interval:
        s[g + _GT] += seg_t
        s[g + _GV] = prev
        return True
    return False


def _gate_timed(code, s, g, w, c, min_reduction, applied, max_std, work, prev, seg_t, interval) -> bool:
    """:func:`_gate`, or its refusal kept (:func:`_gate_kept`)."""
    if _gate_kept(s, g, prev, seg_t, interval):
        return False
    ok = _gate(code, s, g, w, c, min_reduction, applied, max_std, work)
    s[g + _GT], s[g + _GV] = 0.0, 1.0 if ok else 2.0
    return ok


def _earth_change(s, g, w, c, work, size_too):
    """The medians over the ring's segments of the squared change of the field in the earth frame
    across the segment, raw and calibrated by ``W m - c``. Over one segment (body a -> body k,
    the gyro's turn ``C``) a field constant in the earth frame seen from the body satisfies
    ``u_k = C^T u_a``: the change ``e = u_k - C^T u_a`` is the earth-frame field's change
    across the segment, seen from body k. Body-fixed iron makes the raw field's change nonzero at
    every turn and the calibrated one's zero; an earth-fixed field (uniform, or one the body
    turns in without moving far) is constant in the earth frame, so the raw change is already
    zero except in the few segments that enter or leave it, which the median ignores, and a
    calibration fitted to what it does to those segments makes the others' change larger. Third,
    the calibration's own size: the RMS over the segment ends of ``|W m - c - m| / |m|``, where
    ``size_too`` (0 otherwise: the test of an applied calibration does not read it, and it costs a
    division per segment end). (0, 0, 0) with fewer than 3 segments. ``work``: scratch of at least
    ``2 * 32`` entries for the two lists the medians sort (the compiled segment's own buffer: no
    allocation per segment). The same statements in the reference and, compiled, in the kernel."""
    n = int(s[g + _GC])
    if n < 3:
        return 0.0, 0.0, 0.0
    raw = work[0:_GK]
    cal = work[_GK:2 * _GK]
    size = 0.0
    # a segment starts at the sample that closed the one before (the next slot, unless the gyro or the
    # magnetometer broke the chain): its calibrated start field is then the one before's end field, taken
    # over instead of computed again (the same numbers: the same statements on the same values)
    pk0 = pk1 = pk2 = pu0 = pu1 = pu2 = math.nan
    for i in range(n):
        k = g + _GBUF + _GE * i
        mk0, mk1, mk2 = s[k], s[k + 1], s[k + 2]
        ma0, ma1, ma2 = s[k + 9], s[k + 10], s[k + 11]
        raw[i] = s[k + 21]  # _field_change, computed when the segment entered the ring
        uk0 = w[0, 0] * mk0 + w[0, 1] * mk1 + w[0, 2] * mk2 - c[0]
        uk1 = w[1, 0] * mk0 + w[1, 1] * mk1 + w[1, 2] * mk2 - c[1]
        uk2 = w[2, 0] * mk0 + w[2, 1] * mk1 + w[2, 2] * mk2 - c[2]
        if ma0 == pk0 and ma1 == pk1 and ma2 == pk2:
            ua0, ua1, ua2 = pu0, pu1, pu2
        else:
            ua0 = w[0, 0] * ma0 + w[0, 1] * ma1 + w[0, 2] * ma2 - c[0]
            ua1 = w[1, 0] * ma0 + w[1, 1] * ma1 + w[1, 2] * ma2 - c[1]
            ua2 = w[2, 0] * ma0 + w[2, 1] * ma1 + w[2, 2] * ma2 - c[2]
        pk0, pk1, pk2, pu0, pu1, pu2 = mk0, mk1, mk2, uk0, uk1, uk2
        cal[i] = _field_change(uk0, uk1, uk2, ua0, ua1, ua2, s, k + 12)
        if size_too:
            nm = mk0 * mk0 + mk1 * mk1 + mk2 * mk2
            if nm > 0.0:
                size += ((uk0 - mk0) ** 2 + (uk1 - mk1) ** 2 + (uk2 - mk2) ** 2) / nm
    return _median(raw, n), _median(cal, n), math.sqrt(size / n)


@njit(inline="always")
def _field_change(mk0, mk1, mk2, ma0, ma1, ma2, s, i):
    """A field's squared change in the earth frame across one segment, ``|m_k - C^T m_a|^2``
    (:func:`_earth_change`; ``C = R(dq)``, the segment's turn, row-major at ``s[i:i + 9]``): the raw
    field's depends on the segment alone, so :func:`_ring_push` computes it once; the calibrated
    field's is taken at each check. The same statements in the reference and, compiled, in the kernel."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = s[i], s[i + 1], s[i + 2], s[i + 3], s[i + 4], s[i + 5], \
        s[i + 6], s[i + 7], s[i + 8]
    d0 = mk0 - (r00 * ma0 + r10 * ma1 + r20 * ma2)
    d1 = mk1 - (r01 * ma0 + r11 * ma1 + r21 * ma2)
    d2 = mk2 - (r02 * ma0 + r12 * ma1 + r22 * ma2)
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(inline="always")
def _median(a, n):
    """``np.median(a[:n])`` (NaN if any entry is): the ``n // 2 + 1`` smallest of the ring's at most 32
    values kept sorted at the front of ``a`` (an insertion sort that passes over a value larger
    than all of them, in place, no copy: about half a full sort's moves); the middle value, or the
    mean of the two middle ones as numpy takes it. The same statements in the reference and,
    compiled, in the kernel."""
    m = n // 2 + 1  # how many of the smallest values the median needs
    for i in range(n):
        x = a[i]
        if x != x:
            return math.nan
        j = i - 1
        if i >= m:  # the front holds the m smallest so far: x enters (its largest leaves) if smaller
            if not x < a[m - 1]:
                continue
            j = m - 2
        while j >= 0 and a[j] > x:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = x
    h = n // 2
    return a[h] if n % 2 == 1 else (a[h - 1] + a[h]) / 2.0


def _basis(j, v0, v1, v2):
    """``G_j v`` for the j-th basis matrix of the symmetric traceless ``E``: diag(1, 0, -1),
    diag(0, 1, -1), and the (0, 1), (0, 2), (1, 2) symmetric pairs."""
    if j == 0:
        return v0, 0.0, -v2
    if j == 1:
        return 0.0, v1, -v2
    if j == 2:
        return v1, v0, 0.0
    if j == 3:
        return v2, 0.0, v0
    return 0.0, v2, v1


def _soft_rows(ct, ma, mk, h):
    """The segment's 3x8 design matrix into ``h``: ``-G_j m_k + C^T G_j m_a`` for E's entries, then
    ``I - C^T`` for ``c``. The same statements in the reference and, compiled, in the kernel."""
    for j in range(5):
        k0, k1, k2 = _basis(j, mk[0], mk[1], mk[2])
        a0, a1, a2 = _basis(j, ma[0], ma[1], ma[2])
        for i in range(3):
            h[i, j] = -(k0, k1, k2)[i] + ct[i, 0] * a0 + ct[i, 1] * a1 + ct[i, 2] * a2
    for i in range(3):
        for j in range(3):
            h[i, 5 + j] = (1.0 if i == j else 0.0) - ct[i, j]


def _invert_spd(a, m, inv, n) -> bool:
    """``inv = a^-1`` of a symmetric positive definite ``a`` (the information matrix) by its
    Cholesky factor ``a = L L^T``: ``M = L^-1``, ``a^-1 = M^T M`` (about a third of Gauss-Jordan's
    operations, no pivoting: ``a``'s lower triangle is overwritten with ``L``, ``m`` is scratch);
    False for a matrix not positive definite to working precision (a pivot of ``L L^T`` at or
    below ``1e-12`` of ``a``'s largest diagonal entry). ``n``: ``a``'s size, passed as a constant so
    that the compiled twin, inlined into the segment, has loops of known length that LLVM unrolls and
    schedules (the same operations in the same order: the same numbers, in about half the time of
    loops over ``a.shape[0]``). The same statements in the reference and, compiled, in the kernel."""
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(a[i, i]))
    for j in range(n):
        d = a[j, j]
        for k in range(j):
            d -= a[j, k] * a[j, k]
        if not d > 1e-12 * scale:
            return False
        d = math.sqrt(d)
        a[j, j] = d
        for i in range(j + 1, n):
            x = a[i, j]
            for k in range(j):
                x -= a[i, k] * a[j, k]
            a[i, j] = x / d
    for j in range(n):  # M = L^-1, lower triangular, column by column
        m[j, j] = 1.0 / a[j, j]
        for i in range(j + 1, n):
            x = 0.0
            for k in range(j, i):
                x -= a[i, k] * m[k, j]
            m[i, j] = x / a[i, i]
    for i in range(n):  # a^-1 = M^T M, symmetric
        for j in range(i + 1):
            x = 0.0
            for k in range(i, n):
                x += m[k, i] * m[k, j]
            inv[i, j] = x
            inv[j, i] = x
    return True


def _spread(h, inv, ok, lam, n) -> float:
    """How much larger than the fit's residual noise a new segment's misfit ``e = r - H x`` is
    expected to be: ``1 + tr(H P H^T) / 3`` with ``P = (lam A)^-1`` the estimate's covariance over
    the noise's variance (``inv = A^-1``, ``A`` the information matrix before the segment, ``lam``
    its forgetting, ``n`` the unknowns' count). Where ``A`` still leaves a direction unknown
    (rotations about one axis so far), a turn about another axis shows a large misfit that is the
    estimate's own uncertainty, not a moved magnet; inf where ``A`` was not invertible (``ok``
    False: no misfit can be judged). The same statements in the reference and, compiled, in the
    kernel (there inlined with the size a constant: see :func:`_invert_spd`)."""
    if not ok:
        return math.inf
    t = 0.0
    for i in range(3):
        for j in range(n):
            x = 0.0
            for k in range(n):
                x += inv[j, k] * h[i, k]
            t += h[i, j] * x
    return 1.0 + t / (3.0 * lam)


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


def _ring_rows(s, g, q, soft, h, r) -> None:
    """The equations of the ring's segment ``q`` (0 the newest) into ``h`` (3 x unknowns) and ``r``:
    rebuilt from what the ring keeps of it (its first and last raw field and the gyro's turn ``C``)
    as the segment built them when it closed."""
    k = g + _GBUF + _GE * ((int(s[g + _GI]) - 1 - q) % _GK)
    ct = s[k + 12:k + 21].reshape(3, 3).T  # R(dq)^T
    ma, mk = s[k + 9:k + 12], s[k:k + 3]
    if soft:
        _soft_rows(ct, ma, mk, h)
    else:
        h[:, :] = np.eye(3) - ct
    r[:] = mk - ct @ ma


def _fit_sums(hs, rs, keep, n, npar, a, y) -> tuple[int, float]:
    """The normal equations of the kept segments among ``hs``/``rs`` (unit weights) into ``a`` and
    ``y``; returns their count and ``sum |r|^2``. The same statements in the reference and, compiled,
    in the kernel."""
    kept, rr = 0, 0.0
    for i in range(npar):
        y[i] = 0.0
        for j in range(npar):
            a[i, j] = 0.0
    for q in range(n):
        if keep[q]:
            kept += 1
            for i in range(npar):
                for j in range(npar):
                    a[i, j] += hs[q, 0, i] * hs[q, 0, j] + hs[q, 1, i] * hs[q, 1, j] + hs[q, 2, i] * hs[q, 2, j]
                y[i] += hs[q, 0, i] * rs[q, 0] + hs[q, 1, i] * rs[q, 1] + hs[q, 2, i] * rs[q, 2]
            rr += rs[q, 0] * rs[q, 0] + rs[q, 1] * rs[q, 1] + rs[q, 2] * rs[q, 2]
    return kept, rr


def _worst_deleted(hs, rs, keep, n, npar, inv, y, rr, dof, x, e, p, only) -> tuple[float, int]:
    """The kept segments' worst *deleted* residual, given the fit's inverse information matrix
    ``inv`` and right-hand side ``y`` (:func:`_fit_sums`). For a kept segment ``q`` with residual
    ``e = r - H x`` against the whole fit, ``d = e^T (I - H A^-1 H^T)^-1 e`` is what removing it
    takes off the residual sum of squares, so ``(RSS - d) / dof`` is the noise the other segments
    show, and ``d / 3`` over it is the segment's misfit in units of that noise. Returns ``(ratio,
    q)`` of the largest (q -1: none; a segment without which the fit would be undetermined,
    ``I - H A^-1 H^T`` singular, is not judged); ``only`` >= 0: that segment's alone (its residual
    against the fit of the others: whether it fits them). ``x``, ``e``, ``p``: scratch. The same
    statements in the reference and, compiled, in the kernel."""
    rss = rr
    for i in range(npar):
        t = 0.0
        for j in range(npar):
            t += inv[i, j] * y[j]
        x[i] = t
        rss -= y[i] * t
    worst, wq = 0.0, -1
    for q in range(n):
        if not keep[q] or (only >= 0 and q != only):
            continue
        for i in range(3):
            t = rs[q, i]
            for j in range(npar):
                t -= hs[q, i, j] * x[j]
            e[i] = t
        for i in range(3):
            for j in range(3):
                t = 1.0 if i == j else 0.0
                for u in range(npar):
                    for w in range(npar):
                        t -= hs[q, i, u] * inv[u, w] * hs[q, j, w]
                p[i, j] = t
        # d = e^T P^-1 e by the adjugate (P symmetric): e^T adj(P) e / det(P)
        c00, c11, c22 = p[1, 1] * p[2, 2] - p[1, 2] * p[2, 1], p[0, 0] * p[2, 2] - p[0, 2] * p[2, 0], \
            p[0, 0] * p[1, 1] - p[0, 1] * p[1, 0]
        c01, c02, c12 = p[0, 2] * p[2, 1] - p[0, 1] * p[2, 2], p[0, 1] * p[1, 2] - p[0, 2] * p[1, 1], \
            p[0, 2] * p[1, 0] - p[0, 0] * p[1, 2]
        det = p[0, 0] * c00 + p[0, 1] * (p[1, 2] * p[2, 0] - p[1, 0] * p[2, 2]) + p[0, 2] * (
            p[1, 0] * p[2, 1] - p[1, 1] * p[2, 0])
        if not det > 1e-12:
            continue
        d = (c00 * e[0] * e[0] + c11 * e[1] * e[1] + c22 * e[2] * e[2]
             + 2.0 * (c01 * e[0] * e[1] + c02 * e[0] * e[2] + c12 * e[1] * e[2])) / det
        var = (rss - d) / dof
        if var > 0.0 and d / 3.0 > worst * var:
            worst, wq = d / (3.0 * var), q
    return worst, wq


def _fit_worst(hs, rs, keep, n, npar, only, a, inv, m, y, x, e, p) -> tuple[float, int]:
    """The fit of the kept segments and :func:`_worst_deleted` of it ((0, -1) where the fit is
    undetermined or has fewer than 3 degrees of freedom); the arrays after ``only`` are scratch."""
    kept, rr = _fit_sums(hs, rs, keep, n, npar, a, y)
    dof = 3 * (kept - 1) - npar
    if dof < 3 or not _invert_spd(a, m, inv, npar):
        return 0.0, -1
    return _worst_deleted(hs, rs, keep, n, npar, inv, y, rr, dof, x, e, p, only)


def _first_check(s, npar, n, out_sigma) -> None:
    """``first_check``: the ``n`` segments the fit rests on when its residual noise is first trusted
    (``min_segments``), judged by their deleted residuals (:func:`_worst_deleted`): the worst quarter taken
    out one at a time whatever their misfit (two misfits, a short disturbance's two edges, would each hide in
    the other's noise), each put back if it fits the rest within ``out_sigma`` standard deviations, then any
    other over that removed one at a time; the fit's sums rebuilt from the rest (:func:`_fit_sums`; unit
    weights: they span seconds, the forgetting minutes). Before the noise is trusted no segment is
    tested, and a segment that straddles a change of the field in the earth frame (entering or leaving
    a disturbance) does not fit body-fixed iron: kept, it pulls the estimate and inflates the noise
    estimate for ``forget_time``, which then asks for several times the rotation before the estimate
    is confident and lets later misfits through. Nothing changes where all fit. The kernel's twin
    (:func:`_k_first_check`) calls the compiled twins of the same functions."""
    soft = npar == _NP  # (the unknowns' count, not a flag: one compile of the twin for both layouts)
    g, ia, iy = (STATE_SOFT, _SA, _SY) if soft else (STATE, _A, _Y)
    hs, rs = np.empty((n, 3, npar)), np.empty((n, 3))
    for q in range(n):
        _ring_rows(s, g, q, soft, hs[q], rs[q])
    keep = np.ones(n, dtype=bool)
    a, inv, m, y = np.empty((npar, npar)), np.empty((npar, npar)), np.empty((npar, npar)), np.empty(npar)
    x, e, p = np.empty(npar), np.empty(3), np.empty((3, 3))
    thr, out, k = out_sigma * out_sigma, np.empty(n // 4, dtype=np.int64), 0
    while k < n // 4:  # out: the worst, over the threshold or not, up to a quarter (two misfits mask each other)
        worst, q = _fit_worst(hs, rs, keep, n, npar, -1, a, inv, m, y, x, e, p)
        if q < 0:
            break
        keep[q], out[k], k = False, q, k + 1
    while True:  # back in, the best first: each that fits the rest
        best, bq = thr, -1
        for j in range(k):
            if not keep[out[j]]:
                keep[out[j]] = True
                ratio, q = _fit_worst(hs, rs, keep, n, npar, out[j], a, inv, m, y, x, e, p)
                keep[out[j]] = False
                if q >= 0 and ratio <= best:
                    best, bq = ratio, out[j]
        if bq < 0:
            break
        keep[bq] = True
    while True:  # then any other over the threshold, one at a time
        worst, q = _fit_worst(hs, rs, keep, n, npar, -1, a, inv, m, y, x, e, p)
        if q < 0 or not worst > thr:
            break
        keep[q] = False
    if not keep.all():  # the fit's sums from the rest
        kept, rr = _fit_sums(hs, rs, keep, n, npar, a, y)
        s[ia:ia + npar * npar] = a.ravel()
        s[iy:iy + npar] = y
        s[_RR], s[_NE], s[_N] = rr, float(kept), float(kept)


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
_k_invert_spd = njit(inline="always")(_invert_spd)  # (the size a constant at each call: see _invert_spd)
_k_spread = njit(inline="always")(_spread)
_k_basis = njit(_basis)
_k_ring_push = njit(_ring_push, cold=True)  # once per segment (as are _k_segment and _k_segment_soft)
_k_turned = njit(_turned)
_k_consistent = njit(_consistent)
_k_earth_change = njit(_earth_change)


@njit
def _k_gate(code, s, g, w, c, min_reduction, applied, max_std, work):
    """:func:`_gate`, compiled."""
    if code == 1.0:
        return _k_consistent(s, g, w, c, min_reduction)
    raw, cal, change = _k_earth_change(s, g, w, c, work, not applied)
    if applied:
        return cal <= min_reduction * raw
    return cal <= raw and ((min_reduction * cal <= raw and change >= max_std)
                           or _k_consistent(s, g, w, c, min_reduction))


_k_gate_kept = njit(_gate_kept)


@njit
def _k_gate_timed(code, s, g, w, c, min_reduction, applied, max_std, work, prev, seg_t, interval):
    """:func:`_gate_timed`, compiled."""
    if _k_gate_kept(s, g, prev, seg_t, interval):
        return False
    ok = _k_gate(code, s, g, w, c, min_reduction, applied, max_std, work)
    s[g + _GT], s[g + _GV] = 0.0, 1.0 if ok else 2.0
    return ok


_k_applied = njit(_applied)
_k_changed = njit(_changed)
_k_provisional = njit(_provisional)
_k_offset_alone = njit(_offset_alone, cold=True)  # (distortion_significance only: once per segment)


@njit
def _k_soft_rows(ct, ma, mk, h):
    """:func:`_soft_rows`, compiled (its basis products through the compiled :func:`_basis`)."""
    for j in range(5):
        k0, k1, k2 = _k_basis(j, mk[0], mk[1], mk[2])
        a0, a1, a2 = _k_basis(j, ma[0], ma[1], ma[2])
        kk = (k0, k1, k2)
        for i in range(3):
            h[i, j] = -kk[i] + ct[i, 0] * a0 + ct[i, 1] * a1 + ct[i, 2] * a2
    for i in range(3):
        for j in range(3):
            h[i, 5 + j] = (1.0 if i == j else 0.0) - ct[i, j]


@njit
def _k_ring_rows(s, g, q, soft, h, r):
    """:func:`_ring_rows`, compiled."""
    k = g + _GBUF + _GE * ((int(s[g + _GI]) - 1 - q) % _GK)
    ct = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            ct[i, j] = s[k + 12 + 3 * j + i]
    ma = (s[k + 9], s[k + 10], s[k + 11])
    mk = (s[k], s[k + 1], s[k + 2])
    if soft:
        _k_soft_rows(ct, ma, mk, h)
    else:
        for i in range(3):
            for j in range(3):
                h[i, j] = (1.0 if i == j else 0.0) - ct[i, j]
    for i in range(3):
        r[i] = mk[i] - (ct[i, 0] * ma[0] + ct[i, 1] * ma[1] + ct[i, 2] * ma[2])


_k_fit_sums = njit(inline="always")(_fit_sums)  # (inlined: one compile less, the same statements)
_k_worst_deleted = njit(inline="always")(_worst_deleted)


@njit
def _k_fit_worst(hs, rs, keep, n, npar, only, a, inv, m, y, x, e, p):
    """:func:`_fit_worst`, compiled."""
    kept, rr = _k_fit_sums(hs, rs, keep, n, npar, a, y)
    dof = 3 * (kept - 1) - npar
    if dof < 3 or not _k_invert_spd(a, m, inv, npar):
        return 0.0, -1
    return _k_worst_deleted(hs, rs, keep, n, npar, inv, y, rr, dof, x, e, p, only)


@njit(cold=True)
def _k_first_check(s, npar, n, out_sigma):
    """:func:`_first_check`, compiled (once per learning: a call, not inlined). A twin, not one body with the
    path's functions as arguments: a compiled function that passes dispatchers as arguments cannot be
    cached by numba ("dynamic globals"), and ``_k_segment_soft`` would compile again in every process."""
    soft = npar == _NP  # (the unknowns' count, not a flag: one compile of the twin for both layouts)
    g, ia, iy = (STATE_SOFT, _SA, _SY) if soft else (STATE, _A, _Y)
    hs, rs = np.empty((n, 3, npar)), np.empty((n, 3))
    for q in range(n):
        _k_ring_rows(s, g, q, soft, hs[q], rs[q])
    keep = np.ones(n, dtype=np.bool_)
    a, inv, m, y = np.empty((npar, npar)), np.empty((npar, npar)), np.empty((npar, npar)), np.empty(npar)
    x, e, p = np.empty(npar), np.empty(3), np.empty((3, 3))
    thr, out, k = out_sigma * out_sigma, np.empty(n // 4, dtype=np.int64), 0
    while k < n // 4:
        worst, q = _k_fit_worst(hs, rs, keep, n, npar, -1, a, inv, m, y, x, e, p)
        if q < 0:
            break
        keep[q], out[k], k = False, q, k + 1
    while True:
        best, bq = thr, -1
        for j in range(k):
            if not keep[out[j]]:
                keep[out[j]] = True
                ratio, q = _k_fit_worst(hs, rs, keep, n, npar, out[j], a, inv, m, y, x, e, p)
                keep[out[j]] = False
                if q >= 0 and ratio <= best:
                    best, bq = ratio, out[j]
        if bq < 0:
            break
        keep[bq] = True
    while True:
        worst, q = _k_fit_worst(hs, rs, keep, n, npar, -1, a, inv, m, y, x, e, p)
        if q < 0 or not worst > thr:
            break
        keep[q] = False
    if not keep.all():  # the fit's sums from the rest
        kept, rr = _k_fit_sums(hs, rs, keep, n, npar, a, y)
        for i in range(npar):
            for j in range(npar):
                s[ia + npar * i + j] = a[i, j]
            s[iy + i] = y[i]
        s[_RR], s[_NE], s[_N] = rr, float(kept), float(kept)


@njit
def mag_calibration_apply(s, v, gyr_ok, acc_ok, mag_ok, q, dt, p, soft, once):
    """Kernel of :class:`MagCalibrationModel` (``SensorModelKernel.apply``); ``soft`` (``soft_iron``)
    and ``once`` (``held_readings == "once"``) are its compile-time options (``static``; ``p[7]`` and
    ``p[13]`` say the same)."""
    seg_time, forget, max_std, min_seg, out_sigma, out_count = p[1], p[2], p[3], p[4], p[5], p[6]
    gate, min_red = p[8], p[9]
    if not gyr_ok:
        s[_ANCHOR] = 0.0
    elif s[_ANCHOR] != 0.0:
        e0, e1, e2, e3 = rotvec_quat_entries(v[0] * dt, v[1] * dt, v[2] * dt)
        # (entries, not a slice of s, here and below: no array view made at every sample)
        s[_DQ], s[_DQ + 1], s[_DQ + 2], s[_DQ + 3] = qmul_entries(s[_DQ], s[_DQ + 1], s[_DQ + 2], s[_DQ + 3],
                                                                  e0, e1, e2, e3)
        s[_T] += dt
    h = _H_SOFT if soft else _H_HARD
    s[h + 9] += dt
    if not mag_ok:
        s[h + 6] = 0.0
        if s[_T] > 2.0 * seg_time:
            s[_ANCHOR] = 0.0
        return 0
    m0, m1, m2 = v[6], v[7], v[8]
    same = s[h + 8] != 0.0 and m0 == s[h] and m1 == s[h + 1] and m2 == s[h + 2]
    held = same and s[h + 6] != 0.0
    if not same:
        s[h + 9] = 0.0
    fresh = not once or not same or s[h + 9] >= _HELD_AGE
    flags = 0
    if once:  # a segment closed before: its calibration applies from the next sample with a valid gyro
        flags = _k_deliver(s, h, soft, v, held, s[h + 7] != 0.0 and not gyr_ok)
    if gyr_ok and s[_ANCHOR] != 0.0 and fresh:
        if _k_turned(s[_DQ], s[_DQ + 1], s[_DQ + 2], s[_DQ + 3], p[10]) or s[_T] >= seg_time:
            acc = (v[3], v[4], v[5]) if acc_ok else (0.0, 0.0, 0.0)
            _k_ring_push(s, STATE_SOFT if soft else STATE, (m0, m1, m2), acc, s[_MA:_MA + 3], s[_DQ:_DQ + 4])
            conf, applied = s[_CONF], _k_applied(s, soft)
            if once:  # the calibration applied until the change is delivered
                for i in range(_NP if soft else 3):
                    s[h + 10 + i] = s[(_SAPP if soft else _B) + i]
            if soft:
                _k_segment_soft(s, m0, m1, m2, forget, max_std, min_seg, out_sigma, out_count, gate, min_red, p[11],
                                p[12], p[14], p[15] != 0.0)
            else:
                _k_segment(s, m0, m1, m2, forget, max_std, min_seg, out_sigma, out_count, gate, min_red, p[11], p[12],
                           p[15] != 0.0)
            s[h + 7] = float(_k_changed(conf, applied, s[_CONF], _k_applied(s, soft)))
            s[_ANCHOR] = 0.0
    if gyr_ok and s[_ANCHOR] == 0.0 and fresh:
        s[_MA], s[_MA + 1], s[_MA + 2] = m0, m1, m2
        s[_DQ], s[_DQ + 1], s[_DQ + 2], s[_DQ + 3] = 1.0, 0.0, 0.0, 0.0
        s[_T] = 0.0
        s[_ANCHOR] = 1.0
    if not once:  # held_readings="each": the change of a segment closed here applies here
        flags = _k_deliver(s, h, soft, v, held, False)
    return flags


@njit
def _k_deliver(s, h, soft, v, held, wait):
    """:meth:`MagCalibrationModel._deliver` on ``v[6:9]`` in place; returns the flags."""
    flags = 0
    if not wait:
        flags = int(s[h + 7])
        s[h + 7] = 0.0
    return flags | _k_calibrate(s, h, soft, v, held, wait)


@njit
def _k_calibrate(s, h, soft, v, held, before):
    """:meth:`MagCalibrationModel._calibrate` on ``v[6:9]`` in place (raw reading remembered first)."""
    m0, m1, m2 = v[6], v[7], v[8]
    if soft:
        a = h + 10 if before else _SAPP
        t0, t1, t2, t3, t4 = s[a], s[a + 1], s[a + 2], s[a + 3], s[a + 4]
        o0 = (1.0 + t0) * m0 + t2 * m1 + t3 * m2 - s[a + 5]
        o1 = t2 * m0 + (1.0 + t1) * m1 + t4 * m2 - s[a + 6]
        o2 = t3 * m0 + t4 * m1 + (1.0 - t0 - t1) * m2 - s[a + 7]
    else:
        a = h + 10 if before else _B
        o0, o1, o2 = m0 - s[a], m1 - s[a + 1], m2 - s[a + 2]
    flags = 0
    if held and not (o0 == s[h + 3] and o1 == s[h + 4] and o2 == s[h + 5]):
        flags = _MAG_HELD
    s[h], s[h + 1], s[h + 2], s[h + 3], s[h + 4], s[h + 5], s[h + 6], s[h + 8] = m0, m1, m2, o0, o1, o2, 1.0, 1.0
    v[6], v[7], v[8] = o0, o1, o2
    return flags


@njit
def k_forget_accumulate(s, ia, iy, irr, ine, h, r, lam, a):
    """One block of three equations ``h x = r`` into a least squares with forgetting factor ``lam``,
    kept in ``s``: the information matrix ``s[ia:ia + 9] = lam A + h^T h`` (also written to ``a``),
    ``s[iy:iy + 3] = lam y + h^T r``, ``s[irr] = lam sum |r|^2 + |r|^2``, ``s[ine] = lam n + 1``
    (the fit's residual noise). Shared by the compiled sensor models that fit three numbers."""
    for i in range(3):
        for j in range(3):
            a[i, j] = lam * s[ia + 3 * i + j] + (h[0, i] * h[0, j] + h[1, i] * h[1, j] + h[2, i] * h[2, j])
            s[ia + 3 * i + j] = a[i, j]
    for i in range(3):
        s[iy + i] = lam * s[iy + i] + (h[0, i] * r[0] + h[1, i] * r[1] + h[2, i] * r[2])
    s[irr] = lam * s[irr] + (r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    s[ine] = lam * s[ine] + 1.0


@njit(cold=True)
def _k_segment(s, m0, m1, m2, forget, max_std, min_seg, out_sigma, out_count, gate, min_red, interval, prov, first):
    prev, s[STATE + _GV] = s[STATE + _GV], 0.0
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
    lam = math.exp(-s[_T] / forget)
    inv = np.empty((3, 3))
    if n >= min_seg and e2 > out_sigma * out_sigma * s[_VAR] * _k_spread(
            h, inv, _k_invert_spd(s[_A:_A + 9].reshape((3, 3)).copy(), np.empty((3, 3)), inv, 3), lam, 3):
        s[_BAD] += 1.0
        if s[_BAD] >= out_count:
            for i in range(9):
                s[_A + i] = 0.0
            s[_Y], s[_Y + 1], s[_Y + 2] = 0.0, 0.0, 0.0
            s[_N] = s[_VAR] = s[_CONF] = s[_BAD] = s[_RR] = s[_NE] = 0.0
            s[STATE + _GC] = 0.0
        return
    s[_BAD] = 0.0
    a = np.empty((3, 3))
    k_forget_accumulate(s, _A, _Y, _RR, _NE, h, r, lam, a)
    s[_N] = n + 1.0
    if first and s[_N] == min_seg and min_seg < _GK and s[STATE + _GC] == min_seg:
        _k_first_check(s, 3, int(min_seg), out_sigma)
        for i in range(3):
            for j in range(3):
                a[i, j] = s[_A + 3 * i + j]
    inv = np.empty((3, 3))
    if not _k_inverse3(a, inv):
        return
    for i in range(3):
        s[_BEST + i] = inv[i, 0] * s[_Y] + inv[i, 1] * s[_Y + 1] + inv[i, 2] * s[_Y + 2]
    if s[_NE] > 1.0:
        rss = s[_RR] - (s[_Y] * s[_BEST] + s[_Y + 1] * s[_BEST + 1] + s[_Y + 2] * s[_BEST + 2])
        s[_VAR] = max(rss, _RES_FLOOR * s[_RR]) / (3.0 * (s[_NE] - 1.0))
    lmin = _k_min_eig(a)
    f0, f1, f2 = m0 - s[_BEST], m1 - s[_BEST + 1], m2 - s[_BEST + 2]
    field = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    if s[_N] < min_seg or not lmin > 0.0:
        return
    std = math.sqrt(s[_VAR] / lmin)
    if std <= max_std * field:
        conf = 1.0
    elif _k_provisional(s[_CONF], std, s[_BEST:_BEST + 3], prov * field):
        conf = _PROVISIONAL
    else:
        return
    applied = s[_CONF] == 1.0 if conf == 1.0 else s[_CONF] != 0.0
    if gate != 0.0 and not _k_gate_timed(gate, s, STATE, np.eye(3), s[_BEST:_BEST + 3], min_red, applied, max_std,
                                         np.empty(2 * _GK), prev, s[_T], interval):
        s[_B], s[_B + 1], s[_B + 2] = 0.0, 0.0, 0.0
        s[_CONF] = 0.0
        return
    s[_B], s[_B + 1], s[_B + 2] = s[_BEST], s[_BEST + 1], s[_BEST + 2]
    s[_CONF] = conf


@njit(cold=True)
def _k_segment_soft(s, m0, m1, m2, forget, max_std, min_seg, out_sigma, out_count, gate, min_red, interval,
                    prov, sigq, first):
    prev, s[STATE_SOFT + _GV] = s[STATE_SOFT + _GV], 0.0
    # one allocation for every working array (views into it): a segment closes every few samples
    # while the body turns, and each small array allocated and freed cost about as much as the arithmetic
    buf = np.empty(_SEG_BUF)
    c9 = buf[0:9]
    quat_to_dcm(s[_DQ:_DQ + 4], c9)
    ct = buf[9:18].reshape((3, 3))  # R(dq)^T
    for i in range(3):
        for j in range(3):
            ct[i, j] = c9[3 * j + i]
    ma = (s[_MA], s[_MA + 1], s[_MA + 2])
    mk = (m0, m1, m2)
    h = buf[18:18 + 3 * _NP].reshape((3, _NP))
    _k_soft_rows(ct, ma, mk, h)
    r = buf[42:45]
    for i in range(3):
        r[i] = mk[i] - (ct[i, 0] * ma[0] + ct[i, 1] * ma[1] + ct[i, 2] * ma[2])
    e2 = 0.0
    for i in range(3):
        ei = r[i]
        for j in range(_NP):
            ei -= h[i, j] * s[_SBEST + j]
        e2 += ei * ei
    n = s[_N]
    lam = math.exp(-s[_T] / forget)
    misfit = False
    if n >= min_seg:  # the spread from the information matrix's inverse kept since it last changed
        misfit = e2 / 3.0 > out_sigma * out_sigma * s[_VAR] * _k_spread(
            h, s[_SINV:_SINV + _NP * _NP].reshape((_NP, _NP)), s[_SINVOK] != 0.0, lam, _NP)
    if misfit:
        s[_BAD] += 1.0
        if s[_BAD] >= out_count:
            for i in range(_NP * _NP):
                s[_SA + i] = 0.0
            for i in range(_NP):
                s[_SY + i] = 0.0
            s[_N] = s[_VAR] = s[_CONF] = s[_BAD] = s[_RR] = s[_NE] = s[_SINVOK] = 0.0
            s[STATE_SOFT + _GC] = 0.0
        return
    s[_BAD] = 0.0
    a = buf[45:45 + _NP * _NP].reshape((_NP, _NP))
    # A stays symmetric (it starts at zero, and lam A + H^T H is symmetric to the bit: each entry's products are
    # the transposed entry's with their factors swapped), so its lower half is computed and mirrored
    for i in range(_NP):
        for j in range(i + 1):
            x = lam * s[_SA + _NP * i + j] + (h[0, i] * h[0, j] + h[1, i] * h[1, j] + h[2, i] * h[2, j])
            a[i, j] = a[j, i] = x
            s[_SA + _NP * i + j] = s[_SA + _NP * j + i] = x
    for i in range(_NP):
        s[_SY + i] = lam * s[_SY + i] + (h[0, i] * r[0] + h[1, i] * r[1] + h[2, i] * r[2])
    s[_RR] = lam * s[_RR] + (r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    s[_NE] = lam * s[_NE] + 1.0
    s[_N] = n + 1.0
    if first and s[_N] == min_seg and min_seg < _GK and s[STATE_SOFT + _GC] == min_seg:
        _k_first_check(s, _NP, int(min_seg), out_sigma)
        for i in range(_NP):
            for j in range(_NP):
                a[i, j] = s[_SA + _NP * i + j]
    inv = s[_SINV:_SINV + _NP * _NP].reshape((_NP, _NP))  # (untouched where a is not invertible)
    s[_SINVOK] = 1.0 if _k_invert_spd(a, buf[_SEG_BUF - _NP * _NP:_SEG_BUF].reshape((_NP, _NP)), inv, _NP) else 0.0
    if s[_SINVOK] == 0.0:
        return
    yb = 0.0
    for i in range(_NP):
        x = 0.0
        for j in range(_NP):
            x += inv[i, j] * s[_SY + j]
        s[_SBEST + i] = x
        yb += s[_SY + i] * x
    if 3.0 * s[_NE] > _NP:
        s[_VAR] = max(s[_RR] - yb, _RES_FLOOR * s[_RR]) / (3.0 * s[_NE] - _NP)
    t = s[_SBEST:_SBEST + _NP]
    w = buf[173:182].reshape((3, 3))
    w[0, 0], w[0, 1], w[0, 2] = 1.0 + t[0], t[2], t[3]
    w[1, 0], w[1, 1], w[1, 2] = t[2], 1.0 + t[1], t[4]
    w[2, 0], w[2, 1], w[2, 2] = t[3], t[4], 1.0 - t[0] - t[1]
    f0 = w[0, 0] * m0 + w[0, 1] * m1 + w[0, 2] * m2 - t[5]
    f1 = w[1, 0] * m0 + w[1, 1] * m1 + w[1, 2] * m2 - t[6]
    f2 = w[2, 0] * m0 + w[2, 1] * m1 + w[2, 2] * m2 - t[7]
    field = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    std_c, std_e = 0.0, 0.0
    for i in range(_NP):
        sd = math.sqrt(max(s[_VAR] * inv[i, i], 0.0))
        if i < 5:
            std_e = max(std_e, sd)
        else:
            std_c = max(std_c, sd)
    if s[_N] < min_seg:
        return
    alone = False
    # distortion_significance (buf[45:109], a's copy, is done with: the inverse is in s); a distortion once applied
    # with a confident estimate stays until the fit is learned again (the reference's comment)
    if sigq > 0.0 and not (s[_CONF] == 1.0 and _k_applied(s, True) == 2):
        acc, ai, o = buf[64:73].reshape((3, 3)), buf[73:82].reshape((3, 3)), buf[82:86]
        for i in range(3):
            for j in range(3):
                acc[i, j] = s[_SA + _NP * (5 + i) + 5 + j]
        alone = _k_inverse3(acc, ai) and _k_offset_alone(s, ai, sigq, o)
        if alone:  # the offset alone, fitted alone: W = I
            t = buf[109:117]
            for i in range(5):
                t[i] = 0.0
            for i in range(3):
                t[5 + i] = o[i]
                for j in range(3):
                    w[i, j] = 1.0 if i == j else 0.0
            f0, f1, f2 = m0 - t[5], m1 - t[6], m2 - t[7]
            field = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
            std_c, std_e = o[3], 0.0
    if std_c <= max_std * field and std_e <= max_std:
        conf, wg = 1.0, w  # confident: the whole calibration
    elif _k_provisional(s[_CONF], std_c, t[5:8], prov * field):
        conf, wg = _PROVISIONAL, buf[182:191].reshape((3, 3))  # the offset alone: W = I
        for i in range(3):
            for j in range(3):
                wg[i, j] = 1.0 if i == j else 0.0
    else:
        return
    applied = s[_CONF] == 1.0 if conf == 1.0 else s[_CONF] != 0.0
    if gate != 0.0 and not _k_gate_timed(gate, s, STATE_SOFT, wg, t[5:8], min_red, applied,
                                         max_std, buf[0:2 * _GK], prev, s[_T], interval):  # (the arrays in buf[0:64] are done with)
        for i in range(_NP):
            s[_SAPP + i] = 0.0
        s[_B], s[_B + 1], s[_B + 2] = 0.0, 0.0, 0.0
        s[_CONF] = 0.0
        return
    if conf == 1.0 and not alone:
        for i in range(_NP):
            s[_SAPP + i] = t[i]
        winv = buf[182:191].reshape((3, 3))
        if _k_inverse3(w, winv):
            for i in range(3):
                s[_B + i] = winv[i, 0] * t[5] + winv[i, 1] * t[6] + winv[i, 2] * t[7]
    else:
        for i in range(5):
            s[_SAPP + i] = 0.0
        for i in range(3):
            s[_SAPP + 5 + i] = t[5 + i]
            s[_B + i] = t[5 + i]
    s[_CONF] = conf
