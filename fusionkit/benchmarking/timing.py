"""How far each sensor runs behind a recording's reference orientation (a diagnostic).

A filter compared with a reference (optical motion capture, a simulator's truth) is judged on
both the estimate and the clocks. A gyroscope whose digital filter delays it by a sample shows
up as an error of ``|w| dt`` at every rotation, in every filter alike, and no choice of
parameters removes it. :func:`sensor_lags` measures those delays from the data:

* gyroscope: the reference's body rate, by central differences of the reference quaternions
  (``2 log(q[k-1]* q[k+1]) / (t[k+1] - t[k-1])``, centred on ``t[k]``), against the gyro;
* accelerometer: the reference's specific force in the body, ``R(q[k])^T (a[k] + |g| up)``,
  against the specific force, with ``a`` the second difference of the reference position when
  there is one (``position``; BROAD's loader keeps it in ``meta["ref_pos"]``). Without a position the model is gravity alone, and the accelerometer's
  lag means something only where gravity's turning dominates the linear accelerations
  (rotation trials); its residual says how well the model fits;
* magnetometer (when the recording has one): the reference's field in the body,
  ``R(q[k])^T m``, with ``m`` the median of ``R(q[k]) mag[k + L]`` over the samples used (a
  constant field, estimated again once the lag ``L`` is known; a disturbed one shows in the
  residual).

Both sides are low-passed (zero phase, ``cutoff`` Hz). The lag ``L`` (samples) minimises the
mean squared difference between ``x[k + L]`` (the sensor, linearly interpolated) and the
reference at ``k``: a grid of 0.25 samples over ``[-max_lag, max_lag]`` (8 by default), then one
of ``step`` around its best point and a parabola through the best three points, after one pass that leaves out samples whose residual exceeds ``outlier`` times the median (optical
glitches). A lag is NaN when the best one lies on the edge of the range (no minimum inside it:
the model does not fit, e.g. linear accelerations dominate). Only the ``movement`` samples are
used when the recording has that mask (at rest there is nothing to time). Timestamps may jitter:
lags are found on the clock ``(t - t[0]) / median(dt)``, and the samples next to a dropout (an
interval over 1.5 nominal ones) are left out.

Reading the result: ``L`` > 0 means sample ``k`` describes the reference at ``k - L``. A sensor
that follows fusionkit's timing convention (a mean over the interval ``(t[k-1], t[k]]``, like the
simulator's default) shows **0.5**; a point sample at ``t[k]`` shows 0. On BROAD the gyroscope
shows 1.2, the accelerometer 0.4-0.8 and the magnetometer 2.6-5 on every trial (BENCHMARKS.md):
the gyro is 0.6-0.7 samples later than the accelerometer, which is what ``recommended``'s
``output_lead`` is for, and the magnetometer later still (``mag_delay``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..conventions import change_frame, frame_matrix
from ..errors import InputError
from ..rotations import (
    quat_conj,
    quat_mul,
    quat_normalize,
    quat_to_matrix,
    quat_to_rotvec,
)

__all__ = ["SensorLags", "sensor_lags"]


@dataclass(frozen=True)
class SensorLags:
    """Sensor lags against the reference, in samples (``L`` > 0: the sensor is late; NaN: no
    minimum inside the search range).

    ``gyr_rms`` (rad/s) and ``acc_rms`` (m/s^2) are the residuals at the lag; ``samples`` how
    many samples the fit used; ``rate`` the sampling rate (Hz) that turns samples into seconds;
    ``acc_model`` ``"position"`` (the reference position's acceleration was in the model) or
    ``"gravity"`` (gravity alone); ``mag`` / ``mag_rms`` (the magnetometer's unit) NaN without a
    magnetometer.
    """

    gyr: float
    acc: float
    gyr_rms: float
    acc_rms: float
    samples: int
    rate: float
    acc_model: str = "gravity"
    mag: float = math.nan
    mag_rms: float = math.nan

    @property
    def gyr_seconds(self) -> float:
        return self.gyr / self.rate

    @property
    def acc_seconds(self) -> float:
        return self.acc / self.rate

    @property
    def mag_seconds(self) -> float:
        return self.mag / self.rate

    def __str__(self) -> str:
        return (f"gyr {self.gyr:+.2f} samples ({1e3 * self.gyr_seconds:+.2f} ms, residual {self.gyr_rms:.3f} rad/s), "
                f"acc {self.acc:+.2f} samples ({1e3 * self.acc_seconds:+.2f} ms, residual {self.acc_rms:.3f} m/s^2, "
                f"{self.acc_model} model), mag {self.mag:+.2f} samples (residual {self.mag_rms:.3f})")


def _lowpass(x: np.ndarray, cutoff: float, rate: float) -> np.ndarray:
    from scipy.signal import butter, filtfilt

    if cutoff >= 0.5 * rate:
        return x
    b, a = butter(2, cutoff / (0.5 * rate))
    return filtfilt(b, a, x, axis=0)


def _near(bad: np.ndarray, reach: int) -> np.ndarray:
    """The samples within ``reach`` of a ``bad`` one (filters and differences reach that far)."""
    return np.convolve(bad.astype(float), np.ones(2 * reach + 1), mode="same") > 0


def _shifted(x: np.ndarray, s: float, u: np.ndarray) -> np.ndarray:
    """``x`` at the sample clock ``u + s`` (``u`` = time in nominal samples, ``k`` when uniform),
    by linear interpolation between samples (ends held)."""
    n = len(x)
    idx = np.interp(u + s, u, np.arange(n, dtype=float))
    i0 = np.minimum(np.floor(idx).astype(int), n - 2)
    f = (idx - i0)[:, None]
    return x[i0] * (1.0 - f) + x[i0 + 1] * f


def _fit_lag(x: np.ndarray, ref: np.ndarray, mask: np.ndarray, max_lag: float, step: float, outlier: float,
             u: np.ndarray):
    """Lag (samples) minimising the mean squared ``x[k + L] - ref[k]`` over ``mask``, its RMS and
    the number of samples used: a coarse grid over ``[-max_lag, max_lag]``, then ``step`` around
    its best point."""
    def costs(lags, m):
        return np.array([np.mean(np.sum((_shifted(x, s, u)[m] - ref[m]) ** 2, axis=1)) for s in lags])

    coarse = np.arange(-max_lag, max_lag + 1e-9, max(step, min(0.25, max_lag / 4)))
    c = costs(coarse, mask)
    resid = np.linalg.norm(_shifted(x, coarse[np.argmin(c)], u) - ref, axis=1)
    keep = mask & (resid <= outlier * np.median(resid[mask]))
    if keep.sum() >= 0.5 * mask.sum():
        mask = keep
        c = costs(coarse, mask)
    i = int(np.argmin(c))
    if i == 0 or i == len(coarse) - 1:  # no minimum inside the range: the model does not fit
        return math.nan, math.nan, int(mask.sum())
    lags = np.arange(coarse[i - 1], coarse[i + 1] + 1e-9, step)
    c = costs(lags, mask)
    i = int(np.argmin(c))
    lag = float(lags[i])
    if 0 < i < len(lags) - 1:
        den = c[i - 1] - 2.0 * c[i] + c[i + 1]  # parabola through the best three points
        if den > 0:
            lag += 0.5 * (c[i - 1] - c[i + 1]) / den * step
    rms = float(np.sqrt(np.mean(np.sum((_shifted(x, lag, u)[mask] - ref[mask]) ** 2, axis=1))))
    return lag, rms, int(mask.sum())


def sensor_lags(rec, max_lag: float = 8.0, step: float = 0.05, cutoff: float = 20.0,
                outlier: float = 5.0, position="auto") -> SensorLags:
    """Lags (samples) of ``rec``'s gyroscope, accelerometer and magnetometer against ``rec.truth``
    (module doc).

    ``max_lag``: the search range ``[-max_lag, max_lag]`` samples; ``step``: its grid;
    ``cutoff``: the low-pass (Hz) applied to both sides; ``outlier``: residuals above this many
    times the median are left out after a first pass; ``position``: (N, 3) reference positions
    (m, in ``rec.truth_frame``, NaN where missing) for the accelerometer's model, ``"auto"``
    (default) ``rec.meta["ref_pos"]`` when the loader kept one (BROAD), else ``rec.meta["ref_pos_ned"]``
    (the GNSS scenarios and simulated flights, their local NED), or None (gravity alone).
    """
    if rec.truth is None:
        raise InputError(f"recording {rec.name!r} has no reference orientation (truth) to time the sensors against")
    if not (0 < max_lag < np.inf and 0 < step <= max_lag and cutoff > 0 and outlier > 1):  # (inf: no grid)
        raise InputError(f"need a finite max_lag > 0 (samples), 0 < step <= max_lag, cutoff > 0 (Hz), outlier > 1; "
                         f"got max_lag={max_lag}, step={step}, cutoff={cutoff}, outlier={outlier}")
    n = len(rec)
    if n < 10:  # (no interval to take a median of below 2; the edges below need more anyway)
        raise InputError(f"recording {rec.name!r} is too short to time ({n} samples)")
    t = rec.time
    dt = np.diff(t)
    rate = 1.0 / float(np.median(dt))
    u = (t - t[0]) * rate  # the sample clock: time in nominal samples
    gap = np.zeros(n, dtype=bool)  # samples next to a dropout (an interval over 1.5 nominal ones)
    gap[1:] |= dt * rate > 1.5
    gap[:-1] |= dt * rate > 1.5
    edge = int(np.ceil(max_lag)) + int(rate / cutoff) + 2
    if n < 4 * edge + 10:
        raise InputError(f"recording {rec.name!r} is too short to time ({n} samples)")

    if isinstance(position, str):
        if position != "auto":
            raise InputError(f"position must be an (N, 3) array, 'auto' or None, got {position!r}")
        position = rec.meta.get("ref_pos")
        ned = rec.meta.get("ref_pos_ned")  # (the GNSS scenarios, fusionkit.sim.flight: their local NED)
        if position is None and isinstance(ned, np.ndarray) and ned.shape == (n, 3):
            position = ned @ frame_matrix("NED", rec.truth_frame).T
    if position is not None:
        position = np.asarray(position, dtype=float)
        if position.shape != (n, 3):
            raise InputError(f"position must have shape ({n}, 3) like the recording, got {position.shape}")
        position = position @ frame_matrix(rec.truth_frame, "ENU").T
    q = change_frame(rec.truth, rec.truth_frame, "ENU")
    ok = np.isfinite(q).all(axis=1)
    if position is not None:
        ok &= np.isfinite(position).all(axis=1)
    if ok.sum() < 10:
        raise InputError(f"recording {rec.name!r} has fewer than 10 finite reference samples")
    hold = np.maximum.accumulate(np.where(ok, np.arange(n), 0))  # hold the last finite sample
    hold[:np.argmax(ok)] = np.argmax(ok)
    q = quat_normalize(q[hold])  # (rotvec takes the shorter of q and -q: no sign continuity needed)

    w_ref = np.empty((n, 3))
    w_ref[1:-1] = quat_to_rotvec(quat_mul(quat_conj(q[:-2]), q[2:])) / (t[2:] - t[:-2])[:, None]
    w_ref[0], w_ref[-1] = w_ref[1], w_ref[-2]
    acc_norm = np.linalg.norm(rec.acc, axis=1)
    g = float(np.median(acc_norm[np.isfinite(acc_norm)]))
    force = np.tile([0.0, 0.0, g], (n, 1))  # the reference's specific force, ENU
    if position is not None:
        p = _lowpass(position[hold], cutoff, rate)
        force[1:-1] += (p[2:] - 2.0 * p[1:-1] + p[:-2]) * rate * rate
    rot = quat_to_matrix(q)
    f_body = np.einsum("nji,nj->ni", rot, force)

    gyr_ok = np.isfinite(rec.gyr).all(axis=1)
    acc_ok = np.isfinite(rec.acc).all(axis=1)
    # samples near a missing reference or sensor sample, or a dropout, are left out
    reach = int(rate / cutoff) + 2
    mask = ~_near(~(ok & gyr_ok & acc_ok) | gap, reach)
    mask[:edge] = mask[-edge:] = False
    if rec.movement is not None:
        mask &= rec.movement
    if mask.sum() < 10:
        raise InputError(f"recording {rec.name!r} has too few usable samples to time "
                         "(movement samples with a finite reference and sensors)")

    gyr = _lowpass(np.where(gyr_ok[:, None], rec.gyr, 0.0), cutoff, rate)
    acc = _lowpass(np.where(acc_ok[:, None], rec.acc, 0.0), cutoff, rate)
    w_ref = _lowpass(w_ref, cutoff, rate)
    f_ref = _lowpass(f_body, cutoff, rate)
    lg, rg, used = _fit_lag(gyr, w_ref, mask, max_lag, step, outlier, u)
    la, ra, _ = _fit_lag(acc, f_ref, mask, max_lag, step, outlier, u)
    lm = rm = math.nan
    if rec.mag is not None:
        mag_ok = np.isfinite(rec.mag).all(axis=1)
        m_mask = mask & ~_near(~mag_ok, reach)
        if m_mask.sum() >= 10:
            mag = _lowpass(np.where(mag_ok[:, None], rec.mag, 0.0), cutoff, rate)
            shift = 0.0
            for _ in range(2):  # the earth field (median of R mag), then again with the lagged samples
                field = np.median(np.einsum("nij,nj->ni", rot[m_mask], _shifted(mag, shift, u)[m_mask]), axis=0)
                m_ref = _lowpass(np.einsum("nji,j->ni", rot, field), cutoff, rate)
                lm, rm, _ = _fit_lag(mag, m_ref, m_mask, max_lag, step, outlier, u)
                if math.isnan(lm):
                    break
                shift = lm
    return SensorLags(gyr=lg, acc=la, gyr_rms=rg, acc_rms=ra, samples=used, rate=rate,
                      acc_model="gravity" if position is None else "position", mag=lm, mag_rms=rm)

