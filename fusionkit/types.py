"""Data types: :class:`Recording` (input), :class:`Gnss` (aiding stream), :class:`Result` (output)
and the per-sample :class:`Flag` bitmask."""

from __future__ import annotations

import enum
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .conventions import DEFAULT_FRAME, change_frame, check_frame, quat_to_euler, to_scipy
from .errors import InputError
from .validation import as_vectors, check_positive, check_time


class Flag(enum.IntFlag):
    """Per-sample flags of a :class:`Result` (a bitmask, ``Result.flags`` is ``uint32``).

    Each bit says why a sample was treated specially; ``Result.flag_names(i)`` spells them out.
    """

    NONE = 0
    ALIGNING = 1 << 0  #: initial alignment still running: output is the alignment attitude
    MOTION = 1 << 1  #: the motion detector fires on this sample
    GYR_INVALID = 1 << 2  #: gyroscope sample not finite: state held, not propagated
    ACC_INVALID = 1 << 3  #: accelerometer sample not finite or zero: its correction skipped
    MAG_INVALID = 1 << 4  #: magnetometer sample not finite or zero: its correction skipped
    GYR_SATURATED = 1 << 5  #: a gyroscope axis at or above the configured range
    ACC_SATURATED = 1 << 6  #: an accelerometer axis at or above the configured range
    REST = 1 << 7  #: a rest detector says the sensor is still
    MAG_DISTURBED = 1 << 8  #: a magnetic disturbance detector rejects the magnetometer
    ACC_REJECTED = 1 << 9  #: accelerometer correction rejected (dynamic acceleration)
    GNSS_GAP = 1 << 10  #: no usable GNSS on this sample


def flag_names(value: int) -> list[str]:
    """Names of the :class:`Flag` bits set in ``value``."""
    return [f.name for f in Flag if f.value and (int(value) & f.value)]


_GYR_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
_ACC_UNITS = {"m/s^2": 1.0, "g": 9.80665}


def sample_validity(gyr, acc, mag, gyr_range, acc_range) -> tuple[bool, bool, bool, int]:
    """``(gyr_ok, acc_ok, mag_ok, flags)`` of one sample, as every reference path judges it:
    non-finite gyr -> GYR_INVALID; non-finite or all-zero acc / mag (free fall, dropout) ->
    ACC_INVALID / MAG_INVALID; an axis at or above ``gyr_range`` / ``acc_range`` (None: no
    range) -> SATURATED (still used). ``mag`` None: no magnetometer, no flag."""
    gyr_ok = bool(np.isfinite(gyr).all())
    acc_ok = bool(np.isfinite(acc).all() and np.any(acc != 0.0))
    mag_ok = mag is not None and bool(np.isfinite(mag).all() and np.any(mag != 0.0))
    flags = 0
    if not gyr_ok:
        flags |= Flag.GYR_INVALID
    elif gyr_range is not None and np.max(np.abs(gyr)) >= gyr_range:
        flags |= Flag.GYR_SATURATED
    if not acc_ok:
        flags |= Flag.ACC_INVALID
    elif acc_range is not None and np.max(np.abs(acc)) >= acc_range:
        flags |= Flag.ACC_SATURATED
    if mag is not None and not mag_ok:
        flags |= Flag.MAG_INVALID
    return gyr_ok, acc_ok, mag_ok, flags


@dataclass
class Gnss:
    """A GNSS stream at its own rate: time (s, IMU clock), velocity (m/s) in ``frame``, validity.

    Epochs with ``valid == False`` or a non-finite velocity are gaps, not errors.
    """

    t: np.ndarray
    vel: np.ndarray
    valid: np.ndarray | None = None
    frame: str = "NED"
    pos: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vel = as_vectors("gnss.vel", self.vel)
        n = self.vel.shape[0]
        self.t = check_time(self.t, n, "gnss.t", "gnss.vel")
        check_frame(self.frame)
        valid = np.ones(n, bool) if self.valid is None else np.asarray(self.valid).astype(bool).reshape(-1)
        if valid.shape[0] != n:
            raise InputError(f"gnss.valid has {valid.shape[0]} epochs but gnss.vel has {n}")
        self.valid = valid & np.isfinite(self.vel).all(axis=1)
        if self.pos is not None:
            self.pos = as_vectors("gnss.pos", self.pos, n)


@dataclass
class Recording:
    """One IMU recording.

    Parameters
    ----------
    gyr : (N, 3) angular rate, rad/s (or ``gyr_unit="deg/s"``).
    acc : (N, 3) specific force, m/s^2 (or ``acc_unit="g"``); about +g on "up" at rest.
    mag : (N, 3) magnetic field in any unit, optional.
    rate : sampling rate in Hz, or
    t : (N,) timestamps in s, strictly increasing (one of the two is required).
    gnss : optional :class:`Gnss` stream.
    truth : optional (N, 4) reference orientation, body -> ``truth_frame``, ``[w, x, y, z]``.
    movement : optional (N,) bool mask of the samples the metrics are computed on.
    name, meta : free description.

    Values are converted to the library's units on construction; a unit mistake that is
    obvious from the data (an accelerometer reading in g, a gyroscope in deg/s) raises
    :class:`InputError` naming the argument to pass. Non-finite samples are kept: each filter
    handles them by its ``nan_policy``.
    """

    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray | None = None
    rate: float | None = None
    t: np.ndarray | None = None
    gnss: Gnss | None = None
    truth: np.ndarray | None = None
    truth_frame: str = DEFAULT_FRAME
    movement: np.ndarray | None = None
    name: str = ""
    meta: dict[str, Any] = field(default_factory=dict)
    gyr_unit: str = "rad/s"
    acc_unit: str = "m/s^2"

    def __post_init__(self) -> None:
        self.gyr = as_vectors("gyr", self.gyr)
        n = self.gyr.shape[0]
        if n == 0:
            raise InputError("gyr is empty: a recording needs at least one sample")
        self.acc = as_vectors("acc", self.acc, n)
        if self.mag is not None:
            self.mag = as_vectors("mag", self.mag, n)
        if self.gyr_unit not in _GYR_UNITS:
            raise InputError(f"gyr_unit must be one of {list(_GYR_UNITS)}, got {self.gyr_unit!r}")
        if self.acc_unit not in _ACC_UNITS:
            raise InputError(f"acc_unit must be one of {list(_ACC_UNITS)}, got {self.acc_unit!r}")
        self.gyr = self.gyr * _GYR_UNITS[self.gyr_unit]
        self.acc = self.acc * _ACC_UNITS[self.acc_unit]
        self.gyr_unit, self.acc_unit = "rad/s", "m/s^2"
        self._check_units()
        if (self.rate is None) == (self.t is None):
            raise InputError("give exactly one of rate= (Hz) or t= (timestamps in s)")
        if self.rate is not None:
            self.rate = check_positive("rate", self.rate)
        else:
            self.t = check_time(self.t, n)
        if self.truth is not None:
            self.truth = as_vectors("truth", self.truth, n, width=4)
            check_frame(self.truth_frame)
        if self.movement is not None:
            self.movement = np.asarray(self.movement).astype(bool).reshape(-1)
            if self.movement.shape[0] != n:
                raise InputError(f"movement has {self.movement.shape[0]} samples but gyr has {n}")
        if self.gnss is not None:
            if not isinstance(self.gnss, Gnss):
                raise InputError(f"gnss must be a fusionkit.Gnss, got {type(self.gnss).__name__}")
            self._clip_gnss()

    def _clip_gnss(self) -> None:
        """GNSS epochs outside the IMU's time span are dropped, with a warning."""
        t = self.time
        inside = (self.gnss.t >= t[0]) & (self.gnss.t <= t[-1])
        if not inside.all():
            warnings.warn(
                f"{int((~inside).sum())} GNSS epochs lie outside the IMU time [{t[0]:.3f}, {t[-1]:.3f}] s and "
                "were dropped", stacklevel=3)
            g = self.gnss
            self.gnss = Gnss(t=g.t[inside], vel=g.vel[inside], valid=g.valid[inside], frame=g.frame,
                             pos=None if g.pos is None else g.pos[inside])

    def _check_units(self) -> None:
        norm = np.linalg.norm(self.acc, axis=1)
        norm = norm[np.isfinite(norm) & (norm > 0)]
        if norm.size and 0.3 < np.median(norm) < 3.0:
            raise InputError(
                f"acc looks like it is in g (median norm {np.median(norm):.3g}); fusionkit expects "
                "m/s^2: pass acc_unit='g' to convert"
            )
        w = np.abs(self.gyr[np.isfinite(self.gyr).all(axis=1)])
        if w.size and np.median(w) > 2.0 * np.pi:
            raise InputError(
                f"gyr looks like it is in deg/s (median |component| {np.median(w):.3g} > 2 pi rad/s); "
                "fusionkit expects rad/s: pass gyr_unit='deg/s' to convert"
            )

    def __len__(self) -> int:
        return self.gyr.shape[0]

    def __repr__(self) -> str:
        """A one-line summary (samples, clock, sensors, frames, GNSS), never the arrays."""
        n = len(self)
        if self.t is not None:
            clock = f"t {self.t[0]:.3f}..{self.t[-1]:.3f} s (~{1.0 / self.nominal_dt:.4g} Hz)"
        else:
            clock = f"rate {self.rate:.4g} Hz ({n / self.rate:.1f} s)"
        sensors = "gyr, acc" + (", mag" if self.mag is not None else "")
        parts = [f"{n} samples", clock, sensors]
        body = getattr(self, "body", None)  # sensor axes, where the recording declares them
        if body:
            parts.append(f"body {body}")
        if self.truth is not None:
            parts.append(f"truth (body -> {self.truth_frame})")
        if self.movement is not None:
            parts.append(f"movement {int(self.movement.sum())}/{n}")
        if self.gnss is not None:
            parts.append(f"gnss {self.gnss.t.size} epochs ({int(self.gnss.valid.sum())} valid, {self.gnss.frame})")
        name = f"{self.name!r}: " if self.name else ""
        return f"Recording({name}{'; '.join(parts)})"

    @property
    def dt(self) -> np.ndarray:
        """(N,) sample intervals in s: ``dt[k] = t[k] - t[k-1]`` (``dt[0] = dt[1]``).

        Sample ``k``'s rate is held over the interval that ends at ``t[k]``, the way a
        streaming filter sees it.
        """
        n = len(self)
        if self.rate is not None:
            return np.full(n, 1.0 / self.rate)
        if n == 1:
            return np.array([0.01])
        d = np.diff(self.t)
        return np.concatenate([d[:1], d])

    @property
    def nominal_dt(self) -> float:
        """The typical sample interval in s (``1/rate``, or the median of ``dt``)."""
        return 1.0 / self.rate if self.rate is not None else float(np.median(self.dt))

    @property
    def time(self) -> np.ndarray:
        """(N,) sample times in s (from ``t``, or ``k / rate``)."""
        return self.t if self.t is not None else np.arange(len(self)) / self.rate

    def slice(self, start: int | None = None, stop: int | None = None) -> "Recording":
        """A new recording of samples ``[start, stop)``. With GNSS, the slice keeps the original
        clock (its ``t`` are the original sample times) and the GNSS epochs from the one current
        at its first sample to its last sample, so that a run split in two equals one run.
        Per-sample arrays in ``meta`` (first dimension ``len(self)``, e.g. a reference position)
        are sliced with the samples."""
        s = slice(start, stop)
        n = len(self)
        meta = {k: (v[s] if isinstance(v, np.ndarray) and v.ndim >= 1 and v.shape[0] == n else v)
                for k, v in self.meta.items()}
        keep_clock = self.gnss is not None
        out = Recording(
            gyr=self.gyr[s], acc=self.acc[s], mag=None if self.mag is None else self.mag[s],
            rate=None if keep_clock else self.rate, t=self.time[s] if keep_clock else (None if self.t is None else self.t[s]),
            truth=None if self.truth is None else self.truth[s], truth_frame=self.truth_frame,
            movement=None if self.movement is None else self.movement[s], name=self.name,
            meta=meta,
        )
        if keep_clock:  # the epoch current at the first sample, and those up to the last one
            g, t = self.gnss, out.time
            first = max(0, int(np.searchsorted(g.t, t[0], side="right")) - 1)
            keep = (np.arange(g.t.size) >= first) & (g.t <= t[-1])
            out.gnss = Gnss(t=g.t[keep], vel=g.vel[keep], valid=g.valid[keep], frame=g.frame,
                            pos=None if g.pos is None else g.pos[keep])
        return out


@dataclass
class Result:
    """Output of a filter run: one row per input sample.

    ``quat`` (N, 4) ``[w, x, y, z]`` body -> ``frame``; ``flags`` (N,) ``uint32`` :class:`Flag`
    bits; ``diagnostics`` holds the run's extras (``backend``, ``onset_index``, the gyro bias,
    ...).
    """

    quat: np.ndarray
    flags: np.ndarray
    frame: str = DEFAULT_FRAME
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.quat.shape[0]

    def __repr__(self) -> str:
        """A one-line summary (samples, frame, flagged samples, diagnostics' keys), never the arrays."""
        flagged = int(np.count_nonzero(self.flags))
        keys = ", ".join(sorted(self.diagnostics))
        return (f"Result({len(self)} samples, body -> {self.frame}, {flagged} flagged; "
                f"backend {self.diagnostics.get('backend', '?')}; diagnostics: {keys})")

    def euler(self, frame: str | None = None) -> np.ndarray:
        """(N, 3) heading, pitch, roll in rad, in ``frame``'s convention (default: the result's)."""
        frame = frame or self.frame
        return quat_to_euler(self.to_frame(frame), frame)

    def to_frame(self, frame: str) -> np.ndarray:
        """The quaternions re-expressed body -> ``frame``."""
        return change_frame(self.quat, self.frame, frame) if frame != self.frame else self.quat

    def to_scipy(self):
        """The orientations as one scipy ``Rotation`` (body -> ``frame``)."""
        return to_scipy(self.quat)

    def flag_names(self, i: int) -> list[str]:
        return flag_names(int(self.flags[i]))

    def to_csv(self, path, time: np.ndarray | None = None) -> None:
        """Write ``t`` (if given), ``qw, qx, qy, qz``, yaw/pitch/roll (deg) and ``flags``. The yaw
        column is named for the frame (``yaw_enu_deg``: from East, counter-clockwise, so body x
        to North is 90; ``yaw_ned_deg`` is a compass heading)."""
        eul = np.degrees(self.euler())
        cols = [self.quat, eul, self.flags[:, None].astype(float)]
        names = ["qw", "qx", "qy", "qz", f"yaw_{self.frame.lower()}_deg", "pitch_deg", "roll_deg", "flags"]
        if time is not None:
            cols.insert(0, np.asarray(time, dtype=float)[:, None])
            names.insert(0, "t")
        fmt = ["%.9g"] * (len(names) - 1) + ["%d"]
        np.savetxt(path, np.hstack(cols), delimiter=",", header=",".join(names), comments="", fmt=fmt)
