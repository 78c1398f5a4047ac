"""Magnetic disturbance detector: is the magnetometer reading the earth's field?

The earth's field has a fixed norm and a fixed dip (its angle below the horizontal) wherever the
sensor points; a ferromagnetic object nearby, a magnet carried along or a motor change one or
both. The detector learns a **reference** norm and dip as the mean over the first ``init_time``
s of magnetometer samples, and calls a sample **disturbed** when its norm differs from the
reference by more than ``norm_threshold`` (relative) or its dip by more than ``dip_threshold``.

Recovery:

- undisturbed samples keep the reference tracking slowly (time constant ``ref_tau``), so slow
  changes (temperature, moving across a building) are followed;
- a *new* field that stays consistent (within the same thresholds of a candidate that is
  low-passed over 1 s) for ``new_time`` s **while the sensor turns** (rate at least
  ``new_min_rate``) becomes the new reference. Turning is the test that tells a new homogeneous
  field (constant in the earth frame: norm and dip stay put while the body turns) from a magnet
  carried along with the body (its norm and dip seen against the vertical change as the body
  turns, or it is never consistent);
- a reference *learned again* (:func:`follow_field`: ``mag-heading`` relearns it where a
  recalibration of the magnetometer moved the field) is learned over ``init_time`` s wherever the
  body then is, inside a disturbance as likely as outside. With ``relearn_evidence`` (the default) a
  new consistent field replaces it once it has been consistent while turning for as long as the
  relearned reference was learned (``init_time``) and then used while turning, at least the
  candidate's own 1 s and at most ``new_time``: two homogeneous fields, and the one seen longer is
  taken for the earth's. A reference learned at the start keeps ``new_time``, unless
- its learning began while the sensor turned and ``start_evidence`` (an option, off by default) is
  set: a recording that starts in motion measures the dip against the accelerometer's first guess of
  the vertical, which may be off by that second's linear acceleration, while the norm does not depend
  on the vertical. Such a reference is provisional: a new field consistent while turning with its norm
  (within ``norm_threshold``) and another dip replaces it by the rule above, once; a field of another
  norm still needs ``new_time``. Not the default: an earth-fixed disturbance of about the earth's norm
  met while the reference is provisional is taken in as quickly, and the earth's field after it then
  needs ``new_time`` (measured: docs/algorithms/models.md);
- ``max_rejection`` (an option, off by default): a reference that describes no sample for that long
  (60 s, say) is learned again from the next samples, as at the start. Its clock counts each rejected
  sample's time and takes off twice the time of each sample it describes (the pay-back of VQF's
  ``magRejectionFactor``), so a field rejected two samples in three never trips it. It catches what the
  new-field test cannot: a reference learned inside a disturbance or against a vertical still wrong at
  a start in motion (BROAD cut to start in motion, a helicopter starting in a banked turn: every later
  sample rejected for minutes), where the sensor then turns slower than ``new_min_rate`` or the
  field's dip wanders enough to restart the candidate. Its cost, and why it is not the default: a real
  disturbance that outlasts it while the sensor turns slowly becomes the reference (the heading jumps
  to it), and the earth's field after it is then a new field, rejected until the new-field test or
  the clock accepts it (measured both ways: docs/generalisation.md, "Stop 30"). VQF's
  ``magMaxRejectionTime`` (60 s, on by default) differs: after it, VQF uses the disturbed samples at
  half its gain and keeps its reference. ``max_rejection_mode="soft"`` (an option) does that: the
  reference is kept, the clock starts full when a reference starts being learned (it earns twice the
  time of each sample it describes), and beyond it a disturbed sample of a field consistent while
  turning for 1 s is MAG_SOFT: ``mag-heading`` uses it with the variance its departure gives it
  (docs/algorithms/models.md).

The core, :func:`magnetic_step`, works on scalars: the ``mag-heading`` corrector and the ``ekf`` filter call
it with the norm and dip of the field seen in their own levelled frame (the dip needs a vertical;
an estimated one is better than the accelerometer's under motion). As a plugin (in a pipeline or
alone), :class:`MagneticDetector` takes the vertical from the accelerometer and the rate from the
gyroscope. Criterion bit 0 (``disturbed``) sets ``Flag.MAG_DISTURBED``, and a pipeline then
withholds that sample's magnetometer from its correctors.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
from pydantic import model_validator

from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import Detector, DetectorKernel, Sample
from ..types import Flag

__all__ = ["MagneticDetector", "MagneticConfig", "magnetic_step", "MAG_SIZE", "MAG_COUNT", "MAG_TIME", "MAG_USE",
           "MAG_DISTURBED", "MAG_LEARNING", "MAG_SOFT", "field_norm_dip", "follow_field", "k_follow_field"]

# state: reference norm, reference dip, samples learned, seconds learned, candidate norm, candidate dip,
# seconds the candidate has been consistent while turning; for a reference learned again (follow_field with
# relearn_evidence), 1 + the seconds it has been used while turning (0: a reference learned at the start, or again after
# max_rejection); the seconds since the reference last described a sample, each described one paying back twice its
# time (max_rejection); 1 while the reference is provisional (start_evidence: its learning began while the sensor
# turned; _EV then counts its evidence as for a relearned one), else 0
_RN, _RD, _N, _T, _CN, _CD, _CT, _EV, _RJ, _PV = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
MAG_SIZE = 10
MAG_COUNT = _N  #: index of the number of samples the reference was learned from
MAG_TIME = _T  #: index of the seconds it was learned over
#: what :func:`magnetic_step` says of a sample (MAG_SOFT: disturbed, but the reference has rejected for
#: max_rejection already, max_rejection_mode "soft": used with the weight its departure gives it)
MAG_USE, MAG_DISTURBED, MAG_LEARNING, MAG_SOFT = 0, 1, 2, 3


class MagneticConfig(PluginConfig):
    norm_threshold: float = param(0.1, unit="-", description="disturbed when |norm - reference| > this x reference",
                                  gt=0)
    dip_threshold: float = param(math.radians(10.0), unit="rad", description="disturbed when |dip - reference| > this",
                                 gt=0)
    init_time: float = param(1.0, unit="s", description="the reference is the mean over the first samples this long",
                             ge=0)
    ref_tau: float = param(60.0, unit="s", description="the reference follows undisturbed fields this slowly", gt=0)
    new_time: float = param(
        20.0, unit="s", description="a new consistent field becomes the reference after this long while turning", gt=0)
    new_min_rate: float = param(
        math.radians(20.0), unit="rad/s", description="turning rate that counts towards new_time", ge=0)
    max_rejection: float | None = param(
        None, unit="s", description="a reference that has described no sample for this long (each described sample "
        "paying back twice its time) is learned again from the next samples, as at the start: for a reference learned "
        "in a disturbance or against a vertical still wrong at a start in motion, which the new-field test cannot "
        "replace where the sensor turns slowly or its field's dip wanders. Its cost: a real disturbance that lasts "
        "longer becomes the reference. None: kept however long (the default)",
        gt=0)
    max_rejection_mode: Literal["relearn", "soft"] = param(
        "relearn", unit="-", description="what max_rejection does. relearn: the reference is learned again from the "
        "next samples. soft (VQF's magMaxRejectionTime): the reference is kept, and a disturbed sample beyond the "
        "clock, of a field consistent while turning (new_min_rate) for at least 1 s (fixed in the earth frame, not "
        "a magnet carried along), is used with the weight its departure from the reference gives it (mag-heading's "
        "Kalman variance "
        "counts the norm's and dip's departure as the field's error; the fixed gain is halved, VQF's "
        "magRejectionFactor); the clock starts full when a reference starts being learned (at the start, or again "
        "at a recalibration): a reference that has described nothing yet may not reject, it earns twice the time "
        "of each sample it describes. The ekf and the detector plugin keep such a sample out (flagged)")
    relearn_evidence: bool = param(
        True, unit="-", description="a reference learned again (mag-heading's, where a recalibration moved the "
        "field) is replaced by a new field consistent while turning for as long as it was itself learned (init_time) "
        "and then used while turning (at least 1 s, at most new_time): the second it was learned over may lie in a "
        "disturbance. False: new_time for every reference (the detector before). A reference learned at the start "
        "keeps new_time, unless start_evidence")
    start_evidence: bool = param(
        False, unit="-", description="a reference learned at the start (or again after max_rejection) whose learning "
        "begins while the sensor turns (at least new_min_rate: a recording that starts in motion, where the vertical "
        "its dip is measured against is the accelerometer's first guess) is provisional: a new field consistent while "
        "turning with the reference's norm (within norm_threshold) and another dip replaces it after as long as the "
        "reference was learned (init_time) and then used while turning (at least 1 s, at most new_time), and the "
        "field it took is then kept as one learned at rest (new_time). The norm does not depend on the vertical, the "
        "dip does. Its cost, and why it is not the default: an earth-fixed disturbance of about the earth's norm met "
        "while the reference is provisional is taken in as quickly, and the earth's field after it then needs "
        "new_time (docs/algorithms/models.md). False (the default): a reference learned at the start keeps new_time "
        "however it began")

    @model_validator(mode="after")
    def _soft_needs_a_clock(self):
        """``max_rejection_mode="soft"`` without ``max_rejection`` would do nothing, silently."""
        if self.max_rejection_mode == "soft" and self.max_rejection is None:
            raise ValueError("max_rejection_mode 'soft' needs max_rejection, the seconds of rejection after which a "
                             "consistent field is used (VQF's magMaxRejectionTime: 60)")
        return self


@njit
def magnetic_step(s, norm, dip, rate, dt, init_time, norm_th, dip_th, new_time, new_min_rate, ref_tau, max_rej,
                  start_ev, soft):
    """The kernel of :meth:`MagneticDetector.reference_step` (same arguments and arithmetic, with
    the parameters as scalars; ``max_rej``: ``max_rejection``, 0 for None; ``start_ev``: ``start_evidence``,
    1 or 0; ``soft``: ``max_rejection_mode`` "soft", 1 or 0)."""
    if soft == 0.0 and max_rej > 0.0 and s[_RJ] + 0.5 * dt >= max_rej:  # described nothing for max_rejection s:
        # learned again, as at the start
        s[_RN], s[_RD], s[_N], s[_T], s[_CT], s[_RJ], s[_EV], s[_PV] = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if s[_N] == 0.0 or s[_T] + 0.5 * dt < init_time:
        if s[_N] == 0.0 and s[_RN] == 0.0 and start_ev != 0.0 and rate >= new_min_rate:  # the first reference (not
            s[_EV], s[_PV] = 1.0, 1.0  # one learned again at a recalibration) learned in motion: provisional
        if s[_N] == 0.0 and soft != 0.0 and max_rej > 0.0:  # soft: a reference that has described nothing yet may
            s[_RJ] = max_rej  # not reject (the clock starts full)
        s[_N] += 1.0
        s[_T] += dt
        s[_RN] += (norm - s[_RN]) / s[_N]
        s[_RD] += (dip - s[_RD]) / s[_N]
        return MAG_LEARNING
    if abs(norm - s[_RN]) <= norm_th * s[_RN] and abs(dip - s[_RD]) <= dip_th:
        x = dt / ref_tau  # k = 1 - exp(-x); for a small x its series (relative error under 1e-17), no libm call
        k = x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0))))) if x < 1e-3 \
            else 1.0 - math.exp(-x)
        s[_RN] += k * (norm - s[_RN])
        s[_RD] += k * (dip - s[_RD])
        if s[_EV] > 0.0 and rate >= new_min_rate:  # a relearned (provisional) reference's time in use while turning
            s[_EV] += dt
        s[_RJ] = max(s[_RJ] - 2.0 * dt, 0.0)
        return MAG_USE
    # disturbed: is it a new homogeneous field (consistent while the sensor turns)?
    if abs(norm - s[_CN]) < norm_th * s[_CN] and abs(dip - s[_CD]) < dip_th:
        if rate >= new_min_rate:
            s[_CT] += dt
        k = 1.0 - math.exp(-dt)  # the candidate: low-passed over 1 s
        s[_CN] += k * (norm - s[_CN])
        s[_CD] += k * (dip - s[_CD])
    else:
        s[_CN], s[_CD], s[_CT] = norm, dip, 0.0
    # a relearned (or provisional) reference's evidence: the init_time it was learned over and its time in use while
    # turning (s[_EV] - 1); a candidate needs as much time consistent while turning, and at least its own low-pass's
    # 1 s; a provisional one yields only to a field of its own norm (its dip was measured against a vertical not
    # yet known)
    if s[_CT] >= new_time or (s[_EV] > 0.0 and s[_CT] >= max(s[_EV] - 1.0 + init_time, 1.0) and (
            s[_PV] == 0.0 or abs(s[_CN] - s[_RN]) <= norm_th * s[_RN])):
        if s[_PV] != 0.0:  # the field seen with the vertical known: kept as one learned at rest
            s[_EV], s[_PV] = 0.0, 0.0
        elif s[_EV] > 0.0:  # the new reference's time consistent while turning, against the next one
            s[_EV] = 1.0 + s[_CT]
        s[_RN], s[_RD], s[_CT] = s[_CN], s[_CD], 0.0
        s[_RJ] = 0.0
    elif soft != 0.0 and max_rej > 0.0 and s[_RJ] + 0.5 * dt >= max_rej and s[_CT] >= 1.0:  # rejected for
        return MAG_SOFT  # max_rejection, a field consistent while turning for 1 s: used, weighed
    else:
        s[_RJ] += dt
    return MAG_DISTURBED


def follow_field(s, norm, dip, norm_th, dip_th, evidence) -> bool:
    """The field the detector judges changed for a known reason (a sensor model changed the
    magnetometer's calibration) and this sample of it has ``norm`` and ``dip``: unless the
    reference describes it (within the thresholds, as a usable sample; or none is learned yet),
    the reference learned before describes another field, so it is learned again from the next
    samples (the next ``init_time`` s, as at the start). Whether it restarts. One sample is
    enough to judge: a calibrated field's norm and dip are the same at every orientation.
    ``evidence`` (``relearn_evidence``): the relearned reference yields to a new consistent field
    after as long as it was itself learned and then used while turning (:func:`magnetic_step`). The same
    statements in the reference and, compiled, in the kernel."""
    if s[_N] == 0.0 or (abs(norm - s[_RN]) <= norm_th * s[_RN] and abs(dip - s[_RD]) <= dip_th):
        return False
    s[_N] = 0.0
    s[_T] = 0.0
    s[_CT] = 0.0
    s[_RJ] = 0.0
    s[_EV] = 1.0 if evidence else 0.0
    s[_PV] = 0.0
    return True


k_follow_field = njit(follow_field)


def field_norm_dip(mag, up) -> tuple[float, float]:
    """Norm of the field ``mag`` and its dip (rad, the angle above the plane normal to ``up``,
    both in the same frame; ``up`` a unit vector)."""
    norm = math.sqrt(float(mag @ mag))
    return norm, math.asin(max(-1.0, min(1.0, float(mag @ up) / norm)))


@njit
def _magnetic_kernel(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p):
    if m0 == 0.0 and m1 == 0.0 and m2 == 0.0:  # no magnetometer (a 6D recording) or no sample: nothing to do
        return 0
    nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if not math.isfinite(nm):  # an invalid sample
        return 0
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    dip = math.asin(max(-1.0, min(1.0, (m0 * a0 + m1 * a1 + m2 * a2) / (nm * na))))
    rate = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    code = magnetic_step(s, nm, dip, rate, dt, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8])
    return 1 if code == MAG_DISTURBED or code == MAG_SOFT else 0


class MagneticDetector(Detector):
    """Fires on samples whose field norm or dip departs from the learned earth field."""

    name: ClassVar[str] = "magnetic"
    Config = MagneticConfig
    flag: ClassVar[Flag] = Flag.MAG_DISTURBED
    criteria_names: ClassVar[tuple[str, ...]] = ("disturbed",)
    needs_mag: ClassVar[bool] = True
    source: ClassVar[str] = "fusionkit (state of the art: field norm and dip against a learned reference)"
    summary: ClassVar[str] = "magnetic disturbance: field norm or dip off the learned reference; recovers on a new field"

    def initial_state(self, dt: float) -> np.ndarray:
        return np.zeros(MAG_SIZE)

    def params(self) -> tuple[float, ...]:
        c = self.config
        return c.init_time, c.norm_threshold, c.dip_threshold, c.new_time, c.new_min_rate, c.ref_tau

    def step_params(self) -> tuple[float, ...]:
        """:meth:`params`, ``max_rejection`` (0 for None), ``start_evidence`` (1 or 0) and ``max_rejection_mode``
        "soft" (1 or 0): :func:`magnetic_step`'s arguments after ``dt``."""
        return (*self.params(), self.config.max_rejection or 0.0, float(self.config.start_evidence),
                float(self.config.max_rejection_mode == "soft"))

    def reference_step(self, s: np.ndarray, norm: float, dip: float, rate: float, dt: float) -> int:
        """One magnetometer sample with field ``norm`` (any unit), ``dip`` (rad, any sign
        convention used consistently) and turning ``rate`` (rad/s): updates the state ``s`` and
        returns MAG_LEARNING (the reference is being learned; use the sample), MAG_USE,
        MAG_DISTURBED or MAG_SOFT (``max_rejection_mode`` "soft": disturbed, rejected for
        ``max_rejection`` already; use it with the weight its departure gives it). Elapsed times
        are compared with half a sample of margin (a split run equals one run)."""
        c = self.config
        ref = s[_RN:_RD + 1]  # norm, dip
        soft = c.max_rejection is not None and c.max_rejection_mode == "soft"
        if c.max_rejection is not None and not soft and s[_RJ] + 0.5 * dt >= c.max_rejection:  # described nothing:
            s[_RN] = s[_RD] = s[_N] = s[_T] = s[_CT] = s[_RJ] = s[_EV] = s[_PV] = 0.0  # learned again, as at the
            # start
        if s[_N] == 0.0 or s[_T] + 0.5 * dt < c.init_time:  # learning: the running mean
            if s[_N] == 0.0 and ref[0] == 0.0 and c.start_evidence and rate >= c.new_min_rate:  # the first reference
                s[_EV] = s[_PV] = 1.0  # learned in motion: provisional (start_evidence)
            if s[_N] == 0.0 and soft:  # nothing described yet: it may not reject (the clock starts full)
                s[_RJ] = c.max_rejection
            s[_N] += 1.0
            s[_T] += dt
            ref += (np.array([norm, dip]) - ref) / s[_N]
            return MAG_LEARNING
        if abs(norm - ref[0]) <= c.norm_threshold * ref[0] and abs(dip - ref[1]) <= c.dip_threshold:
            ref += (1.0 - math.exp(-dt / c.ref_tau)) * (np.array([norm, dip]) - ref)  # follow slowly
            if s[_EV] > 0.0 and rate >= c.new_min_rate:  # a relearned (provisional) reference's time in use, turning
                s[_EV] += dt
            s[_RJ] = max(s[_RJ] - 2.0 * dt, 0.0)  # (VQF's magRejectionFactor)
            return MAG_USE
        cand = s[_CN:_CD + 1]
        if abs(norm - cand[0]) < c.norm_threshold * cand[0] and abs(dip - cand[1]) < c.dip_threshold:
            if rate >= c.new_min_rate:  # consistent while turning: fixed in the earth frame
                s[_CT] += dt
            cand += (1.0 - math.exp(-dt)) * (np.array([norm, dip]) - cand)
        else:  # a different field: a new candidate
            cand[:], s[_CT] = (norm, dip), 0.0
        # replaced after new_time, or a relearned reference after as long as it was learned and used while turning
        # (relearn_evidence), or a provisional one so by a field of its norm (start_evidence)
        if s[_CT] >= c.new_time or (s[_EV] > 0.0 and s[_CT] >= max(s[_EV] - 1.0 + c.init_time, 1.0) and (
                s[_PV] == 0.0 or abs(cand[0] - ref[0]) <= c.norm_threshold * ref[0])):
            if s[_PV] != 0.0:
                s[_EV] = s[_PV] = 0.0
            elif s[_EV] > 0.0:
                s[_EV] = 1.0 + s[_CT]
            ref[:], s[_CT] = cand, 0.0
            s[_RJ] = 0.0
        elif soft and s[_RJ] + 0.5 * dt >= c.max_rejection and s[_CT] >= 1.0:  # rejected for max_rejection, a field
            return MAG_SOFT  # consistent while turning for 1 s: used, weighed (VQF's)
        else:
            s[_RJ] += dt
        return MAG_DISTURBED

    def step(self, state: np.ndarray, sample: Sample) -> int:
        """The vertical from the accelerometer, the rate from the gyroscope; 0 without a
        magnetometer sample."""
        if sample.mag is None:
            return 0
        norm, dip = field_norm_dip(sample.mag, sample.acc / np.linalg.norm(sample.acc))
        rate = float(np.linalg.norm(sample.gyr))
        return 1 if self.reference_step(state, norm, dip, rate, sample.dt) in (MAG_DISTURBED, MAG_SOFT) else 0

    def kernel(self) -> DetectorKernel:
        return DetectorKernel(_magnetic_kernel, np.array(self.step_params()))
