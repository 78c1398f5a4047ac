"""Time offsets between the IMU's sensors, estimated online from the IMU alone (a sensor model).

A direction fixed in the earth frame (gravity ``a``, the magnetic field ``m``) turns, seen from
the body, against the body rate ``w``: ``du/dt = -w x u``. A gyroscope that is late by ``d``
seconds against the accelerometer (its digital low-pass, a later sampling instant) reads
``w_meas(t) = w(t - d)``, so ``w(t) ~ w_meas(t) + d dw_meas/dt``, and between two accelerometer
samples ``i`` and ``j`` the body turned by the gyro's rotation plus ``d (g_j - g_i)``. With
``C`` the gyro's rotation from sample ``i`` to ``j`` (body j -> body i) and ``u`` unit directions:

``r = u_j - C^T u_i  ~  d x``,  ``x = -(g_j - g_i) x C^T u_i``,

one scalar unknown in three equations. Every ``segment_time`` (the segments follow one another)
one segment enters a least-squares estimate of ``d`` with exponential forgetting
(``forget_time``). Only a change of the rate (angular acceleration) informs it: at rest and at a
constant rate ``x`` is zero. Linear accelerations turn the measured gravity too; they do not
correlate with ``x`` on average, and samples whose norm is off gravity's by more than
``acc_tol`` do not enter. The magnetometer's offset against the gyro is estimated the same way,
separately, from the field's direction (its norm changing by more than ``mag_tol`` across a
segment: a disturbance, the segment does not enter; a sample repeating the previous one exactly
is a lower-rate magnetometer's held value and neither starts nor closes a segment).

**Timing convention.** Gyro sample ``k`` is taken to describe the middle of its step ``(t[k-1],
t[k]]`` (a mean over the interval is centred there), and so is an accelerometer or
magnetometer sample (fusionkit's pairing, ``recommended``'s ``acc_delay`` default): the
rotation from sample ``i``'s centre to ``j``'s is the gyro's integral from the second half of
step ``i`` to the first half of step ``j``, ``(g_i dt_i + g_j dt_j) / 2 + sum g_k dt_k`` in
between, and the rate change ``g_j - g_i`` is taken at those centres. Sensors that follow the
convention (the simulator's default, interval means) estimate zero; a point-sampled
accelerometer (its value at ``t[k]``) is half a sample later than a mean-sampled gyro and
estimates ``d = +0.5`` samples, which is what it is.

**Confidence.** The estimate's standard deviation is ``sigma / sqrt(sum |x|^2)`` (``sigma`` the
fit's residual noise, from the fit itself). It is applied once that is below ``max_std``
sample intervals and ``min_segments`` segments entered; until then ``offset`` (``mag_offset``)
is applied, 0 by default, and afterwards the last confident estimate is held when confidence
is lost (long rests forget the information).

**Re-timing** (``retime``). ``"gyro"`` (default): the gyroscope is moved forward by ``d``
(linear extrapolation through its last two samples, ``g + d (g_k - g_{k-1}) / dt``) and the
magnetometer onto the accelerometer's instant (rotated by the gyro rate over its offset from
the accelerometer, ``exp(-[w tau]x) m``, ``tau = d_acc - d_mag``, once both offsets have the same
standing: both estimated, or both as configured): **the output follows the accelerometer's
clock**. An orientation integrated from the extrapolated rate is the one from
the raw rate plus ``d g_k`` (the extrapolation's sum telescopes), so the gyro's extra noise does
not accumulate. This is the default because a gyro's delay is usually its digital filter's,
which the truth (and any reference) does not share, while the accelerometer's is usually the
smaller. ``"acc"``: the gyroscope is left alone and the accelerometer and magnetometer are
rotated back by their offsets (``exp([w d]x) a``): **the output follows the gyroscope's clock**
(no extra noise, but the whole output is as late as the gyro).

The model reads only the IMU's own samples (never the filter's orientation), so running it over
a recording (:func:`retime_recording`) and feeding a filter the result is what composing it in a
pipeline's ``models`` does. The readable reference is :meth:`TimeOffsetModel.apply`;
:func:`time_offset_apply` is its kernel.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._kernels import qmul_into, quat_to_dcm, rodrigues_entries, rotvec_quat
from .._numba import njit
from ..config import PluginConfig, param
from ..conventions import GRAVITY
from ..protocols import Sample, SensorModel, SensorModelKernel
from ..rotations import cross, quat_from_rotvec, quat_mul, quat_to_matrix, rodrigues
from ..types import GYR_LIMIT

__all__ = ["ACC", "CONF", "EST", "MAG", "NSEG", "OFFSET", "STATE", "STD", "TimeOffsetConfig", "TimeOffsetModel",
           "retime_recording", "time_offset_apply"]

# state layout: the previous gyro sample, then one block per sensor (accelerometer, magnetometer)
_PG, _PDT, _PGOK, _PM, _PMOK, _DT0 = 0, 3, 4, 5, 8, 9
ACC, MAG = 10, 34  #: the blocks' starts
# offsets within a block
_ANC, _U, _GA, _DQ, _T, _XX, _XR, _ZZ, _ZL = 0, 1, 4, 7, 11, 12, 13, 14, 15
NSEG, EST, STD, OFFSET, CONF, _NORM, _Z1, _LINK = 16, 17, 18, 19, 20, 21, 22, 23
_BLOCK = 24
STATE = MAG + _BLOCK

#: the lag-1 covariance may at most cancel this fraction of the lag-0 one (a sum of few terms
#: can come out negative; the floor keeps the standard deviation from collapsing to zero)
_VAR_FLOOR = 0.01
_GAP = 1.5  #: an interval over this many nominal ones is a gap: segments restart after it


class TimeOffsetConfig(PluginConfig):
    retime: Literal["gyro", "acc"] = param(
        "gyro", unit="-", description="which sensor is moved: 'gyro' extrapolates the gyroscope forward (the output "
        "follows the accelerometer's clock), 'acc' rotates the accelerometer and magnetometer back (the gyroscope's)")
    estimate: bool = param(True, unit="-", description="estimate the offsets online (False: apply offset and "
                           "mag_offset as given)")
    offset: float = param(0.0, unit="s", description="the gyro's delay against the accelerometer applied until the "
                          "estimate is confident (or always, without estimate)", ge=-0.1, le=0.1)
    mag_offset: float = param(0.0, unit="s", description="the gyro's delay against the magnetometer applied until "
                              "its estimate is confident (negative: the magnetometer is the later)", ge=-0.1, le=0.1)
    use_mag: bool = param(True, unit="-", description="estimate and correct the magnetometer's offset too")
    segment_time: float = param(0.02, unit="s", description="length of one segment (gyro rotation and rate change "
                                "between its two end samples)", gt=0)
    forget_time: float = param(60.0, unit="s", description="time constant with which old segments are forgotten",
                               gt=0)
    max_std: float = param(0.05, unit="samples", description="apply the estimate once its standard deviation is "
                           "below this many sample intervals", gt=0)
    min_segments: int = param(50, unit="-", description="segments before the estimate may be applied", ge=2)
    max_offset: float = param(0.05, unit="s", description="estimates are clamped to +-this", gt=0)
    acc_tol: float = param(0.1, unit="-", description="an accelerometer sample whose norm differs from gravity's by "
                           "more than this fraction does not enter the estimate (linear acceleration)", gt=0)
    mag_tol: float = param(0.05, unit="-", description="a segment across which the field's norm changes by more than "
                           "this fraction does not enter (a magnetic disturbance)", gt=0)


class TimeOffsetModel(SensorModel):
    """Estimates the gyro's delay against the accelerometer and the magnetometer, and re-times."""

    name: ClassVar[str] = "time-offset"
    Config = TimeOffsetConfig
    source: ClassVar[str] = ("fusionkit (the earth-fixed direction's kinematics du/dt = -w x u: a late gyro leaves a "
                             "residual proportional to the angular acceleration)")
    summary: ClassVar[str] = ("online gyro-vs-accelerometer/magnetometer time offsets from the IMU alone; re-times "
                              "the samples onto one clock")

    def initial_state(self, dt: float) -> np.ndarray:
        c = self.config
        s = np.zeros(STATE)
        s[_DT0] = dt
        for b, off in ((ACC, c.offset), (MAG, c.mag_offset)):
            s[b + _DQ] = 1.0
            s[b + OFFSET] = off
        return s

    def params(self) -> np.ndarray:
        c = self.config
        return np.array([1.0 if c.retime == "gyro" else 0.0, float(c.estimate), float(c.use_mag), c.segment_time,
                         c.forget_time, c.max_std, float(c.min_segments), c.max_offset, c.acc_tol, c.mag_tol])

    def kernel(self) -> SensorModelKernel:
        return SensorModelKernel(time_offset_apply, self.params())

    def report(self, state: np.ndarray) -> dict:
        """The offsets at the end of a run (``Result.diagnostics["models"]["time-offset"]``), in
        seconds; ``offset_*`` the gyro's delay against the accelerometer (positive: the gyro is the
        later, as the config's ``offset``), ``mag_offset_*`` against the magnetometer (as
        ``mag_offset``; negative: the magnetometer is the later):

        - ``offset_s``: the estimate, NaN before a segment with an angular acceleration entered (or
          with ``estimate=False``); ``offset_std_s`` its standard deviation (inf then);
        - ``offset_applied_s``: the offset the model re-times with (the configured ``offset`` until an
          estimate is confident, then the last confident one, clamped to ``max_offset``);
        - ``offset_confident``: an estimate was confident (``max_std``, ``min_segments``) and applied;
        - ``offset_segments``: the segments that entered its fit;
        - the same five for ``mag_offset_`` (``mag_offset_applied_s`` 0 with ``use_mag=False``);
        - ``sample_interval_s``: the nominal sample interval (the docs state offsets in samples);
        - ``applied``: whether the re-timing changes a sample now (a nonzero offset in use)."""
        c, s = self.config, state
        out: dict = {}
        for key, b in (("offset", ACC), ("mag_offset", MAG)):
            known = s[b + _XX] > 0.0
            out[f"{key}_s"] = float(s[b + EST]) if known else math.nan
            out[f"{key}_std_s"] = float(s[b + STD]) if known else math.inf
            out[f"{key}_applied_s"] = float(s[b + OFFSET]) if (b == ACC or c.use_mag) else 0.0
            out[f"{key}_confident"] = bool(s[b + CONF])
            out[f"{key}_segments"] = int(s[b + NSEG])
        out["sample_interval_s"] = float(s[_DT0])
        da, dm = out["offset_applied_s"], out["mag_offset_applied_s"]
        if c.retime == "gyro":  # (the conditions of apply's step 3, for the sensors' state at the end)
            mag_moved = self._moves_mag(s, da, dm)
        else:
            mag_moved = dm != 0.0
        out["applied"] = bool(da != 0.0 or mag_moved)
        return out

    # -- the readable reference ---------------------------------------------------------------
    def apply(self, state: np.ndarray, sample: Sample, quat: np.ndarray) -> tuple[Sample, int]:
        c, s = self.config, state
        g, dt = np.asarray(sample.gyr, dtype=float), float(sample.dt)
        gyr_ok = bool(np.isfinite(g).all()) and float(np.abs(g).max()) <= GYR_LIMIT
        if not gyr_ok:  # no rate: segments cannot continue, nothing can be re-timed
            s[ACC + _ANC] = s[MAG + _ANC] = 0.0
            s[_PGOK] = 0.0
            return sample, 0
        # 1. the rotation from the previous sample's centre to this one's (halves of both steps)
        cont = s[_PGOK] != 0.0 and dt <= _GAP * s[_DT0] and s[_PDT] <= _GAP * s[_DT0]
        if cont:
            rv = 0.5 * (s[_PG:_PG + 3] * s[_PDT] + g * dt)
            step = 0.5 * (s[_PDT] + dt)
            for b in (ACC, MAG):
                if s[b + _ANC]:
                    s[b + _DQ:b + _DQ + 4] = quat_mul(s[b + _DQ:b + _DQ + 4], quat_from_rotvec(rv))
                    s[b + _T] += step
        else:
            s[ACC + _ANC] = s[MAG + _ANC] = 0.0
        # 2. the estimates
        mag = None if sample.mag is None else np.asarray(sample.mag, dtype=float)
        if c.estimate:
            if sample.acc is not None:
                a = np.asarray(sample.acc, dtype=float)
                na = float(np.linalg.norm(a))
                self._segment(s, ACC, a / na, g, abs(na - GRAVITY) <= c.acc_tol * GRAVITY, na)
            elif s[ACC + _T] > 4.0 * c.segment_time:
                s[ACC + _ANC] = 0.0
            fresh = mag is not None and not (s[_PMOK] and np.array_equal(mag, s[_PM:_PM + 3]))
            if c.use_mag and fresh:
                nm = float(np.linalg.norm(mag))
                self._segment(s, MAG, mag / nm, g, True, nm)
            elif s[MAG + _T] > 4.0 * c.segment_time:
                s[MAG + _ANC] = 0.0
        if mag is not None:
            s[_PM:_PM + 3] = mag
        s[_PMOK] = float(mag is not None)
        # 3. re-time with the offsets applied
        da, dm = s[ACC + OFFSET], s[MAG + OFFSET] if c.use_mag else 0.0
        acc, gyr = sample.acc, g
        if c.retime == "gyro":
            if cont and da != 0.0:
                gyr = g + da * (g - s[_PG:_PG + 3]) / (0.5 * (s[_PDT] + dt))
            if mag is not None and self._moves_mag(s, da, dm):
                mag = rodrigues(-gyr * (da - dm)) @ mag
        else:
            if acc is not None and da != 0.0:
                acc = rodrigues(g * da) @ np.asarray(acc, dtype=float)
            if mag is not None and dm != 0.0:
                mag = rodrigues(g * dm) @ mag
        s[_PG:_PG + 3] = g
        s[_PDT] = dt
        s[_PGOK] = 1.0
        return sample._replace(gyr=gyr, acc=acc, mag=mag), 0

    def _moves_mag(self, s, da, dm) -> bool:
        """Whether re-timing the gyro (``retime="gyro"``, offsets ``da`` of the accelerometer and ``dm``
        of the magnetometer in use) moves the magnetometer: by its offset from the accelerometer,
        ``da - dm``, taken only from two offsets of the same standing (both estimated, or both as
        configured): one alone says nothing. :meth:`apply`'s step 3 and :meth:`report` ask it."""
        return da != dm and (s[ACC + CONF] == s[MAG + CONF] or not self.config.estimate)

    def _segment(self, s, b, u, g, ok, norm) -> None:
        """A new sample ``u`` (unit direction) of the sensor whose block starts at ``b``: it closes
        the running segment once ``segment_time`` has passed, and starts the next one."""
        c = self.config
        closed = False
        if s[b + _ANC] and s[b + _T] >= c.segment_time - 0.5 * s[_DT0]:  # (the sample nearest to it: no tie)
            if b == MAG:
                ok = abs(norm / s[b + _NORM] - 1.0) <= c.mag_tol
            if ok:
                v = quat_to_matrix(s[b + _DQ:b + _DQ + 4]).T @ s[b + _U:b + _U + 3]
                x = -cross(g - s[b + _GA:b + _GA + 3], v)
                _enter(s, b, float(x @ x), float(x @ (u - v)), math.exp(-s[b + _T] / c.forget_time),
                       c.max_std * s[_DT0], float(c.min_segments), c.max_offset)
            s[b + _ANC] = 0.0
            closed = ok
        if not s[b + _ANC] and ok:
            s[b + _ANC] = 1.0
            s[b + _LINK] = float(closed)  # this segment starts where the last one entered ended
            s[b + _U:b + _U + 3] = u
            s[b + _GA:b + _GA + 3] = g
            s[b + _DQ:b + _DQ + 4] = (1.0, 0.0, 0.0, 0.0)
            s[b + _T] = 0.0
            s[b + _NORM] = norm


def _enter(s, b, xx, xr, lam, max_std, min_seg, max_offset) -> None:
    """One segment's sums into the forgetting least squares of block ``b``; the estimate, its
    standard deviation, and the applied offset once confident (the same statements run in the
    reference and, compiled, in the kernel).

    The standard deviation is that of ``sum x.r / sum |x|^2`` with the residuals' own
    covariance at lags 0 and 1 (``z_k = x_k . (r_k - d x_k)``, ``var = sum z_k^2 + 2 sum z_k
    z_{k-1}``): consecutive segments share their end sample, so a perturbation of a direction
    sample (noise, a linear acceleration) enters two residuals with opposite signs and mostly
    cancels where ``x`` changes slowly; a white-noise formula would overstate it many times."""
    z = xr - s[b + EST] * xx  # with the estimate so far (online)
    s[b + _XX] = lam * s[b + _XX] + xx
    s[b + _XR] = lam * s[b + _XR] + xr
    s[b + _ZZ] = lam * s[b + _ZZ] + z * z
    s[b + _ZL] = lam * s[b + _ZL] + (z * s[b + _Z1] if s[b + _LINK] != 0.0 else 0.0)
    s[b + _Z1] = z
    s[b + NSEG] += 1.0
    if not s[b + _XX] > 0.0:
        return
    est = s[b + _XR] / s[b + _XX]
    s[b + EST] = est
    var = max(s[b + _ZZ] + 2.0 * s[b + _ZL], _VAR_FLOOR * s[b + _ZZ])
    s[b + STD] = math.sqrt(var) / s[b + _XX]
    if s[b + NSEG] >= min_seg and s[b + STD] <= max_std:
        s[b + OFFSET] = min(max(est, -max_offset), max_offset)
        s[b + CONF] = 1.0


_k_enter = njit(_enter, cold=True)  # once per segment


@njit
def _k_segment(s, b, u0, u1, u2, g0, g1, g2, ok, norm, seg_time, forget, max_std, min_seg, max_offset, mag_tol):
    closed = False
    if s[b + _ANC] != 0.0 and s[b + _T] >= seg_time - 0.5 * s[_DT0]:
        if b == MAG:
            ok = abs(norm / s[b + _NORM] - 1.0) <= mag_tol
        if ok:
            c = np.empty(9)
            quat_to_dcm(s[b + _DQ:b + _DQ + 4], c)
            p0, p1, p2 = s[b + _U], s[b + _U + 1], s[b + _U + 2]
            v0 = c[0] * p0 + c[3] * p1 + c[6] * p2  # C^T u_i
            v1 = c[1] * p0 + c[4] * p1 + c[7] * p2
            v2 = c[2] * p0 + c[5] * p1 + c[8] * p2
            d0, d1, d2 = g0 - s[b + _GA], g1 - s[b + _GA + 1], g2 - s[b + _GA + 2]
            x0, x1, x2 = -(d1 * v2 - d2 * v1), -(d2 * v0 - d0 * v2), -(d0 * v1 - d1 * v0)
            r0, r1, r2 = u0 - v0, u1 - v1, u2 - v2
            _k_enter(s, b, x0 * x0 + x1 * x1 + x2 * x2, x0 * r0 + x1 * r1 + x2 * r2,
                     math.exp(-s[b + _T] / forget), max_std, min_seg, max_offset)
        s[b + _ANC] = 0.0
        closed = ok
    if s[b + _ANC] == 0.0 and ok:
        s[b + _ANC] = 1.0
        s[b + _LINK] = 1.0 if closed else 0.0
        s[b + _U], s[b + _U + 1], s[b + _U + 2] = u0, u1, u2
        s[b + _GA], s[b + _GA + 1], s[b + _GA + 2] = g0, g1, g2
        s[b + _DQ], s[b + _DQ + 1], s[b + _DQ + 2], s[b + _DQ + 3] = 1.0, 0.0, 0.0, 0.0
        s[b + _T] = 0.0
        s[b + _NORM] = norm


@njit
def _k_rotate(v, o, r0, r1, r2):
    """``v[o:o+3] = exp([r x]) v[o:o+3]`` (rotations.rodrigues)."""
    e = rodrigues_entries(r0, r1, r2)
    x0, x1, x2 = v[o], v[o + 1], v[o + 2]
    for i in range(3):
        v[o + i] = e[3 * i] * x0 + e[3 * i + 1] * x1 + e[3 * i + 2] * x2


@njit
def time_offset_apply(s, v, gyr_ok, acc_ok, mag_ok, q, dt, p):
    """Kernel of :class:`TimeOffsetModel` (``SensorModelKernel.apply``)."""
    retime_gyro, estimate, use_mag, seg_time, forget = p[0] != 0.0, p[1] != 0.0, p[2] != 0.0, p[3], p[4]
    max_std, min_seg, max_offset, acc_tol, mag_tol = p[5] * s[_DT0], p[6], p[7], p[8], p[9]
    if not gyr_ok:
        s[ACC + _ANC] = 0.0
        s[MAG + _ANC] = 0.0
        s[_PGOK] = 0.0
        return 0
    g0, g1, g2 = v[0], v[1], v[2]
    pdt = s[_PDT]
    cont = s[_PGOK] != 0.0 and dt <= _GAP * s[_DT0] and pdt <= _GAP * s[_DT0]
    if cont:
        e = np.empty(4)
        rotvec_quat(0.5 * (s[_PG] * pdt + g0 * dt), 0.5 * (s[_PG + 1] * pdt + g1 * dt),
                    0.5 * (s[_PG + 2] * pdt + g2 * dt), e)
        step = 0.5 * (pdt + dt)
        for b in (ACC, MAG):
            if s[b + _ANC] != 0.0:
                qmul_into(s[b + _DQ], s[b + _DQ + 1], s[b + _DQ + 2], s[b + _DQ + 3], e[0], e[1], e[2], e[3],
                          s[b + _DQ:b + _DQ + 4])
                s[b + _T] += step
    else:
        s[ACC + _ANC] = 0.0
        s[MAG + _ANC] = 0.0
    if estimate:
        if acc_ok:
            na = math.sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5])
            _k_segment(s, ACC, v[3] / na, v[4] / na, v[5] / na, g0, g1, g2, abs(na - GRAVITY) <= acc_tol * GRAVITY,
                       na, seg_time, forget, max_std, min_seg, max_offset, mag_tol)
        elif s[ACC + _T] > 4.0 * seg_time:
            s[ACC + _ANC] = 0.0
        fresh = mag_ok and not (s[_PMOK] != 0.0 and v[6] == s[_PM] and v[7] == s[_PM + 1] and v[8] == s[_PM + 2])
        if use_mag and fresh:
            nm = math.sqrt(v[6] * v[6] + v[7] * v[7] + v[8] * v[8])
            _k_segment(s, MAG, v[6] / nm, v[7] / nm, v[8] / nm, g0, g1, g2, True, nm, seg_time, forget, max_std,
                       min_seg, max_offset, mag_tol)
        elif s[MAG + _T] > 4.0 * seg_time:
            s[MAG + _ANC] = 0.0
    if mag_ok:
        s[_PM], s[_PM + 1], s[_PM + 2] = v[6], v[7], v[8]
    s[_PMOK] = 1.0 if mag_ok else 0.0
    da = s[ACC + OFFSET]
    dm = s[MAG + OFFSET] if use_mag else 0.0
    if retime_gyro:
        if cont and da != 0.0:
            h = da / (0.5 * (pdt + dt))
            v[0] = g0 + h * (g0 - s[_PG])
            v[1] = g1 + h * (g1 - s[_PG + 1])
            v[2] = g2 + h * (g2 - s[_PG + 2])
        if mag_ok and da != dm and (s[ACC + CONF] == s[MAG + CONF] or not estimate):
            tau = da - dm
            _k_rotate(v, 6, -v[0] * tau, -v[1] * tau, -v[2] * tau)
    else:
        if acc_ok and da != 0.0:
            _k_rotate(v, 3, g0 * da, g1 * da, g2 * da)
        if mag_ok and dm != 0.0:
            _k_rotate(v, 6, g0 * dm, g1 * dm, g2 * dm)
    s[_PG], s[_PG + 1], s[_PG + 2] = g0, g1, g2
    s[_PDT] = dt
    s[_PGOK] = 1.0
    return 0


@njit
def _retime_all(gyr, acc, mag, ok, dt, s, p, states):
    """The kernel over every sample (``ok[k]``: gyr, acc, mag valid), in place; the state after
    each sample into ``states``."""
    v = np.empty(9)
    q = np.zeros(4)
    for k in range(gyr.shape[0]):
        for i in range(3):
            v[i], v[3 + i], v[6 + i] = gyr[k, i], acc[k, i], mag[k, i]
        time_offset_apply(s, v, ok[k, 0], ok[k, 1], ok[k, 2], q, dt[k], p)
        for i in range(3):
            if ok[k, 0]:
                gyr[k, i] = v[i]
            if ok[k, 1]:
                acc[k, i] = v[3 + i]
            if ok[k, 2]:
                mag[k, i] = v[6 + i]
        states[k, :] = s


def retime_recording(rec, model: TimeOffsetModel | None = None, backend: str = "reference", **params):
    """``rec`` re-timed by the model over every sample (what the model does as the first stage
    of a pipeline; it reads no orientation), and the model's state after every sample ((N,
    STATE): ``state[:, ACC + OFFSET]`` is the applied gyro-vs-accelerometer offset, ``ACC + EST``
    / ``ACC + STD`` the estimate and its standard deviation, ``MAG + ...`` the magnetometer's).
    Invalid samples pass through as they are. ``backend``: ``"reference"`` (:meth:`apply`) or
    ``"numba"`` (the kernel, the same numbers)."""
    import dataclasses

    from ..types import sample_validity

    model = model or TimeOffsetModel(**params)
    s = model.initial_state(rec.nominal_dt)
    gyr, acc = rec.gyr.astype(float).copy(), rec.acc.astype(float).copy()
    mag = None if rec.mag is None else rec.mag.astype(float).copy()
    states = np.empty((len(rec), STATE))
    ok = np.array([sample_validity(gyr[k], acc[k], None if mag is None else mag[k], None, None)[:3]
                   for k in range(len(rec))], dtype=bool)
    dts = np.asarray(rec.dt, dtype=float)
    if backend == "numba":
        m = np.zeros_like(gyr) if mag is None else mag
        _retime_all(gyr, acc, m, ok, dts, s, model.params(), states)
    else:
        q = np.array([1.0, 0.0, 0.0, 0.0])
        for k in range(len(rec)):
            out, _ = model.apply(s, Sample(gyr[k].copy(), acc[k].copy() if ok[k, 1] else None,
                                           mag[k].copy() if ok[k, 2] else None, float(dts[k])), q)
            if ok[k, 0]:
                gyr[k] = out.gyr
            if ok[k, 1]:
                acc[k] = out.acc
            if ok[k, 2]:
                mag[k] = out.mag
            states[k] = s
    return dataclasses.replace(rec, gyr=gyr, acc=acc, mag=mag), states
