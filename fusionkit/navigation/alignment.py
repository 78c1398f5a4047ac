"""Initial alignment of a still IMU (source 000, section 3).

At rest the accelerometers measure ``f_r = -L g_e``; with matrix (1) and heading 0::

    f = [g sin(theta), g cos(theta) cos(gamma), -g cos(theta) sin(gamma)]

so ``theta = atan(f1 / sqrt(f2^2 + f3^2))`` and ``gamma = atan2(-f3, f2)``. The document prints
``gamma = atan(f3 / f2)``, which contradicts its own matrix in the sign of ``f3``; the form here
is derived from (1) and proven by round trips in all four roll quadrants
(``tests/test_alignment.py``). Heading is 0 (source 000 has no magnetometer), or, as an
extension, the heading that points the horizontal magnetic field to north.
"""

from __future__ import annotations

import math

import numpy as np

from .._kernels import alignment_quat as _k_alignment_quat
from .._numba import njit
from ..conventions import change_frame, source000_quat
from ..rotations import quat_from_axis_angle, quat_mul, quat_rotate

__all__ = ["alignment_angles", "alignment_quat", "Aligner", "align_step", "report_disturbed", "STATISTICS_TIME"]

#: How long a motion detector gathers its statistics before it may end an alignment early (its
#: thresholds are 10-20 sigma; 2 s, 200 samples at 100 Hz, estimate a sigma to about 5 %).
STATISTICS_TIME = 2.0


def alignment_angles(acc_mean) -> tuple[float, float]:
    """``(theta, gamma)``: source 000's pitch and roll (rad) from the mean specific force."""
    f1, f2, f3 = np.asarray(acc_mean, dtype=float)
    theta = np.arctan2(f1, np.hypot(f2, f3))  # = atan(f1 / sqrt(f2^2 + f3^2)), cos(theta) >= 0
    gamma = np.arctan2(-f3, f2)  # from matrix (1): f2 = g cos(theta) cos(gamma), f3 = -g cos(theta) sin(gamma)
    return float(theta), float(gamma)


def alignment_quat(acc_mean, mag_mean=None, frame: str = "ENU") -> np.ndarray:
    """Body->``frame`` quaternion of a still IMU from its mean specific force.

    With ``mag_mean`` the heading is turned about the vertical so that the horizontal part of
    the magnetic field points to (magnetic) north; without it the heading is source 000's 0.
    """
    theta, gamma = alignment_angles(acc_mean)
    q = source000_quat(0.0, theta, gamma)  # body -> NUE
    if mag_mean is not None:
        m_nue = quat_rotate(q, mag_mean)
        beta = np.arctan2(m_nue[2], m_nue[0])  # angle of the field from North towards East
        q = quat_mul(quat_from_axis_angle([0.0, 1.0, 0.0], beta), q)  # rotate about Up (axis 2)
    q = change_frame(q, "NUE", frame)
    return q / np.linalg.norm(q)


# ---- the alignment as a state machine, shared by the pipeline and monolithic filters ------------

# layout of the alignment state array (a caller may append its own fields after ALIGN_SIZE)
# (ELAPSED: the seconds the alignment has averaged, the sum of its samples' intervals: its mandatory
# ``duration`` is a time, so a stream that meets its samples one at a time and a run that sees the
# whole recording end it at the same sample, whatever the intervals' jitter)
PHASE, SEEN, NACC, SACC, NGYR, SGYR, NMAG, SMAG, BIAS, END, DISTURBED, ELAPSED = \
    0, 1, 2, 3, 6, 7, 10, 11, 14, 17, 18, 19
ALIGN_SIZE = 20
#: the alignment ends with the sample that brings its elapsed time within half an interval of its
#: duration, less this relative margin: at a fixed rate ``round(duration / dt)`` samples, a half
#: rounded down whatever the sum's rounding (Python's ``round``, the count before stop 33, took a
#: half to the even number: 12.5 -> 12 but 7.5 -> 8)
_TIE = 1.0 - 1e-9
MODES = {"none": 0.0, "fixed": 1.0, "motion": 2.0}
#: what :meth:`Aligner.step` / :func:`align_step` say about a sample
NAVIGATING, ALIGNING, ALIGNED_NOW, ALIGNED_BEFORE = 0, 1, 2, 3


def report_disturbed(al, duration: float) -> None:
    """Warn when motion ended the alignment inside its mandatory ``duration`` (state ``al``): the
    attitude and bias come from the shorter rest before it."""
    if al[DISTURBED]:
        import warnings

        from ..types import AlignmentWarning

        warnings.warn(f"motion detected {al[ELAPSED]:.3g} s into the mandatory {duration:.3g} s alignment: the "
                      "alignment ended there (the moving samples are not averaged in); attitude and gyro bias come "
                      "from the shorter rest (diagnostics['alignment_disturbed'])", AlignmentWarning, stacklevel=3)


class Aligner:
    """Source 000's initial alignment over a flat state array (the readable reference).

    Per sample, :meth:`step` returns a status: ``ALIGNING`` (the sample was averaged; ``q`` is
    the current alignment attitude), ``ALIGNED_NOW`` (averaged, and the alignment ended with it:
    start the estimator from ``q``), ``ALIGNED_BEFORE`` (mode ``motion``: the sample moves, the
    alignment ended before it: start from ``q`` and navigate this sample) or ``NAVIGATING``.
    :func:`align_step` is the numba twin, driven by :meth:`params`. With the config's
    ``attitude="first"`` only the first sample with a valid accelerometer (and its field) enters
    the attitude, held over the window, while the gyro is averaged as usual (source 002's start).

    The mandatory ``duration`` is counted in time, the sum of the averaged samples' intervals: the
    alignment ends with the sample that brings that sum within half an interval of ``duration`` (at
    a fixed rate ``round(duration / dt)`` samples, source 000's count, a half rounded down). A count
    of samples fixed from a nominal interval ended it at another sample in a stream (which knows the
    intervals it has met) than in a run over the whole recording (which knows their median) wherever
    timestamps jitter. (The motion detector of mode ``motion`` still sizes its window in samples
    from the nominal interval: a stream of ``poisson`` or ``gst`` on a jittered clock is not its run.)
    """

    def __init__(self, config, frame: str) -> None:
        self.config = config
        self.frame = frame

    def new_state(self, size: int = ALIGN_SIZE) -> np.ndarray:
        al = np.zeros(size)
        al[END] = -1.0
        if self.config.mode == "none":
            al[PHASE] = 1.0
        return al

    def attitude(self, al) -> np.ndarray:
        if al[NACC] == 0:
            return np.array(self.config.initial_quat)
        use_mag = self.config.heading != "zero" and al[NMAG] > 0
        mag = al[SMAG:SMAG + 3] / al[NMAG] if use_mag else None
        return alignment_quat(al[SACC:SACC + 3] / al[NACC], mag, self.frame)

    def _finish(self, al) -> np.ndarray:
        if self.config.estimate_bias and al[NGYR] > 0:
            al[BIAS:BIAS + 3] = al[SGYR:SGYR + 3] / al[NGYR]
        al[END] = al[SEEN]
        al[PHASE] = 1.0
        return self.attitude(al)

    def step(self, al, gyr, acc, mag, gyr_ok: bool, acc_ok: bool, mag_ok: bool, motion: bool, dt: float):
        """Returns ``(status, q)``; ``q`` is None while navigating. ``dt``: the sample's interval (s)."""
        if al[PHASE] != 0.0:
            return NAVIGATING, None
        mode = self.config.mode
        if self.config.max_rate is not None and gyr_ok and np.linalg.norm(gyr) > self.config.max_rate:
            if al[SEEN] > 0:  # moving: the alignment ends before this sample
                return ALIGNED_BEFORE, self._finish(al)
            gyr_ok = False  # moving from the first sample: its tilt (and heading), no bias
        if mode == "motion" and motion and al[SEEN] > 0:  # never averaged in: the alignment ends before it
            if al[ELAPSED] + 0.5 * dt < self.config.duration * _TIE:  # inside the mandatory time: reported
                al[DISTURBED] = 1.0
            return ALIGNED_BEFORE, self._finish(al)
        if self.config.attitude == "first":  # only the first valid accelerometer sample (and its field) counts
            first = acc_ok and al[NACC] == 0
            acc_ok, mag_ok = first, mag_ok and first
        if acc_ok:
            al[NACC] += 1.0
            al[SACC:SACC + 3] += acc
        if gyr_ok:
            al[NGYR] += 1.0
            al[SGYR:SGYR + 3] += gyr
        if mag_ok:
            al[NMAG] += 1.0
            al[SMAG:SMAG + 3] += mag
        al[SEEN] += 1.0
        al[ELAPSED] += dt
        q = self.attitude(al)
        if mode == "fixed" and al[ELAPSED] + 0.5 * dt >= self.config.duration * _TIE:
            self._finish(al)
            return ALIGNED_NOW, q
        return ALIGNING, q

    def params(self) -> np.ndarray:
        """The parameter vector of :func:`align_step`."""
        from ..conventions import change_frame

        c = self.config
        ap = np.zeros(14)
        ap[0] = MODES[c.mode]
        ap[1] = c.duration
        ap[2] = float(c.heading != "zero")
        ap[3:7] = change_frame(np.array([1.0, 0.0, 0.0, 0.0]), "NUE", self.frame)
        ap[7:11] = c.initial_quat
        ap[11] = float(c.estimate_bias)
        ap[12] = c.max_rate if c.max_rate is not None else np.inf
        ap[13] = float(c.attitude == "first")
        return ap


@njit
def _k_attitude(al, ap, q):
    if al[NACC] == 0.0:
        q[0], q[1], q[2], q[3] = ap[7], ap[8], ap[9], ap[10]
        return
    n = al[NACC]
    use_mag = ap[2] != 0.0 and al[NMAG] > 0.0
    nm = al[NMAG] if use_mag else 1.0
    _k_alignment_quat(al[SACC] / n, al[SACC + 1] / n, al[SACC + 2] / n, al[SMAG] / nm, al[SMAG + 1] / nm,
                      al[SMAG + 2] / nm, 1 if use_mag else 0, ap[3:7], q)


@njit
def _k_finish(al, ap, q):
    if ap[11] != 0.0 and al[NGYR] > 0.0:
        al[BIAS] = al[SGYR] / al[NGYR]
        al[BIAS + 1] = al[SGYR + 1] / al[NGYR]
        al[BIAS + 2] = al[SGYR + 2] / al[NGYR]
    al[END] = al[SEEN]
    al[PHASE] = 1.0
    _k_attitude(al, ap, q)


@njit
def align_step(al, ap, g0, g1, g2, a0, a1, a2, m0, m1, m2, gyr_ok, acc_ok, mag_ok, motion, dt, q):
    """numba twin of :meth:`Aligner.step`; writes the attitude into ``q``, returns the status."""
    if al[PHASE] != 0.0:
        return NAVIGATING
    mode = ap[0]
    if gyr_ok and math.sqrt(g0 * g0 + g1 * g1 + g2 * g2) > ap[12]:
        if al[SEEN] > 0.0:
            _k_finish(al, ap, q)
            return ALIGNED_BEFORE
        gyr_ok = False
    if mode == 2.0 and motion and al[SEEN] > 0.0:
        if al[ELAPSED] + 0.5 * dt < ap[1] * _TIE:
            al[DISTURBED] = 1.0
        _k_finish(al, ap, q)
        return ALIGNED_BEFORE
    if ap[13] != 0.0:  # attitude "first": only the first valid accelerometer sample (and its field) counts
        first = acc_ok and al[NACC] == 0.0
        acc_ok, mag_ok = first, mag_ok and first
    if acc_ok:
        al[NACC] += 1.0
        al[SACC] += a0
        al[SACC + 1] += a1
        al[SACC + 2] += a2
    if gyr_ok:
        al[NGYR] += 1.0
        al[SGYR] += g0
        al[SGYR + 1] += g1
        al[SGYR + 2] += g2
    if mag_ok:
        al[NMAG] += 1.0
        al[SMAG] += m0
        al[SMAG + 1] += m1
        al[SMAG + 2] += m2
    al[SEEN] += 1.0
    al[ELAPSED] += dt
    _k_attitude(al, ap, q)
    if mode == 1.0 and al[ELAPSED] + 0.5 * dt >= ap[1] * _TIE:
        _k_finish(al, ap, q)  # the same sums: the same attitude
        return ALIGNED_NOW
    return ALIGNING
