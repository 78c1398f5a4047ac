"""Data types: :class:`Recording` (input), :class:`Gnss` (aiding stream), :class:`Result` (output)
the per-sample :class:`Flag` bitmask, and the :class:`Channel` quantities correctors pass on."""

from __future__ import annotations

import enum
import math
import operator
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .conventions import DEFAULT_FRAME, change_frame, check_body, check_frame, quat_to_euler, to_scipy
from .errors import InputError
from ._numba import HAVE_NUMBA
from .validation import (ACC_UNITS, GYR_UNITS, MAX_INTERVAL, SCAN_MIN_SAMPLES, as_mask, as_vectors, check_acc_declared,
                         check_positive, check_time, check_units, unit_rows_off)


class Flag(enum.IntFlag):
    """Per-sample flags of a :class:`Result` (a bitmask, ``Result.flags`` is ``uint32``).

    Each bit says why a sample was treated specially; ``Result.flag_names(i)`` spells them out.
    """

    NONE = 0
    ALIGNING = 1 << 0  #: initial alignment still running: output is the alignment attitude
    MOTION = 1 << 1  #: the motion detector fires on this sample
    GYR_INVALID = 1 << 2  #: gyroscope sample not finite: state held, not propagated
    ACC_INVALID = 1 << 3  #: accelerometer sample not finite, zero or beyond ACC_LIMIT: its correction skipped
    MAG_INVALID = 1 << 4  #: magnetometer sample not finite, zero or too small/large to square: its correction skipped
    GYR_SATURATED = 1 << 5  #: a gyroscope axis at or above the configured range (still integrated)
    ACC_SATURATED = 1 << 6  #: an accelerometer axis at or above the configured range: its correction skipped
    REST = 1 << 7  #: a rest detector says the sensor is still
    MAG_DISTURBED = 1 << 8  #: a magnetic disturbance detector rejects the magnetometer
    ACC_REJECTED = 1 << 9  #: accelerometer correction rejected (dynamic acceleration)
    GNSS_GAP = 1 << 10  #: no usable GNSS on this sample
    GAP = 1 << 11  #: the interval before this sample is a timestamp gap: the state is held across it, not integrated
    GNSS_REJECTED = 1 << 12  #: a GNSS measurement on this sample failed the innovation gate and was not used
    MAG_RECALIBRATED = 1 << 13  #: a sensor model started, replaced or stopped the magnetometer calibration it applies
    #: the magnetometer sample repeats the previous reading (a magnetometer slower than the IMU holds it), though a
    #: sensor model calibrates it otherwise than that one since: its value alone no longer tells it is held
    MAG_HELD = 1 << 14


class Channel(enum.IntEnum):
    """The pipeline's channel: named quantities a corrector publishes for the correctors after it.

    Correctors share the pipeline's gyro bias and the sample's flags; a quantity one corrector
    knows and another needs (the inclination's uncertainty, which the heading's measurement
    variance counts) goes through the channel. A corrector names what it writes in
    ``publishes`` and what it reads in ``reads`` (:class:`~fusionkit.protocols.Corrector`); each
    name is an index into the run state's channel block (``CHANNEL_SIZE`` numbers, all 0 at the
    start: "nothing known", which every reader must take as the method without the quantity).
    The pipeline refuses a composition where a corrector reads a quantity that only one that runs
    later in the sample publishes (it would read the previous sample's value; the bias correctors
    run first), or where two publish one that a corrector reads (what each publishes and reads
    with its configuration counts).
    A value stays until its publisher writes it again (a sample without its sensor leaves it)."""

    #: rad^2: the variance of the inclination error about one horizontal axis that has no direction
    #: (``inertial-tilt`` with ``tau_adapt``: the gyro bias's uncertainty accumulated over its time
    #: constant)
    INCLINATION_VARIANCE = 0
    #: s: the time over which the inclination error changes (``inertial-tilt``'s time constant)
    INCLINATION_TIME = 1
    #: rad, three numbers from here (x, y, z of the pipeline's frame, levelled): the linear
    #: acceleration the inclination lets through, as the tilt it makes (``inertial-tilt``: its
    #: velocity deviation over ``g tau``); the inclination error is a rotation about ``up x`` it
    LET_THROUGH = 2


#: the channel's length (LET_THROUGH is a 3-vector)
CHANNEL_SIZE = int(Channel.LET_THROUGH) + 3


def flag_names(value: int) -> list[str]:
    """Names of the :class:`Flag` bits set in ``value``."""
    return [f.name for f in Flag if f.value and (int(value) & f.value)]


#: A gyroscope axis beyond this (rad/s, about 1600 turns per second: no gyroscope measures that
#: much) is not a measurement; the sample is GYR_INVALID (and its rate cannot overflow a product).
GYR_LIMIT = 1.0e4
#: Without ``acc_range``, an accelerometer axis beyond 16 g (the largest range of consumer MEMS
#: accelerometers, which cannot report more) is a glitch: ACC_INVALID.
ACC_LIMIT = 16.0 * 9.80665
#: Vectors whose largest entry is outside ``[TINY, HUGE]`` cannot be squared and normalised in
#: float64 (underflow to 0, overflow to inf): an accelerometer or magnetometer sample that small
#: or (magnetometer, any unit) that large is invalid.
TINY, HUGE = 1e-150, 1e150
#: An interval longer than this many nominal intervals (and than the filter's ``max_gap`` s) is a
#: timestamp gap (Flag.GAP).
GAP_INTERVALS = 5.0


def sample_validity(gyr, acc, mag, gyr_range, acc_range) -> tuple[bool, bool, bool, int]:
    """``(gyr_ok, acc_ok, mag_ok, flags)`` of one sample, as every reference path judges it:
    a gyr axis not finite or beyond :data:`GYR_LIMIT` -> GYR_INVALID (state held); acc / mag not
    finite, (all) zero or too small to normalise (free fall, dropout), acc beyond
    :data:`ACC_LIMIT` without ``acc_range`` (a glitch), mag beyond :data:`HUGE` -> ACC_INVALID /
    MAG_INVALID (correction skipped); an axis at or above ``gyr_range`` / ``acc_range`` (None: no
    range) -> SATURATED: a saturated gyro is still integrated (the best rate there is), a
    saturated accelerometer never reaches a correction. ``mag`` None: no magnetometer, no flag.
    :func:`fusionkit._kernels.validity_flags` is the numba twin."""
    g, a = gyr.tolist(), acc.tolist()  # plain floats: this runs per sample
    gmax, amax = _largest(g), _largest(a)  # NaN if an entry is not finite
    gyr_ok = gmax <= GYR_LIMIT
    acc_lim = acc_range if acc_range is not None else ACC_LIMIT
    acc_ok = TINY <= amax < math.inf
    flags = 0
    if not gyr_ok:
        flags |= Flag.GYR_INVALID
    elif gyr_range is not None and gmax >= gyr_range:
        flags |= Flag.GYR_SATURATED
    if acc_ok and amax >= acc_lim:
        acc_ok = False
        flags |= Flag.ACC_SATURATED if acc_range is not None else Flag.ACC_INVALID
    elif not acc_ok:
        flags |= Flag.ACC_INVALID
    mag_ok = False
    if mag is not None:
        mmax = _largest(mag.tolist())
        mag_ok = TINY <= mmax <= HUGE
        if not mag_ok:
            flags |= Flag.MAG_INVALID
    return gyr_ok, acc_ok, mag_ok, flags


def _largest(v) -> float:
    """The largest ``|v_i|``; NaN when an entry is not finite."""
    if not (math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])):
        return math.nan
    return max(abs(v[0]), abs(v[1]), abs(v[2]))


def gap_threshold(nominal_dt: float, max_gap: float | None) -> float:
    """The longest interval integrated as one step: ``max(max_gap, GAP_INTERVALS * nominal_dt)``
    (``inf`` with ``max_gap`` None: no gap handling)."""
    return math.inf if max_gap is None else max(float(max_gap), GAP_INTERVALS * float(nominal_dt))


def hold_gaps(gyr: np.ndarray, dt: np.ndarray, nominal_dt: float, max_gap: float | None, first_known: bool = False):
    """``(gyr, dt, gaps)`` for a run: at a timestamp gap (an interval above :func:`gap_threshold`)
    the gyro sample is replaced by NaN (the state is held across the gap, not integrated with a
    rate known only at its end) and its interval by the nominal one (so that no time constant
    sees the gap as one step); the sample's other sensors are used as usual. Without gaps the
    arrays are returned as they are. :func:`mark_gaps` turns the flags back. ``first_known``: ``dt[0]``
    is the real interval before the first sample (:meth:`Recording.run_intervals`), judged as the
    others; else a copy of ``dt[1]``, never a gap."""
    gaps = dt > gap_threshold(nominal_dt, max_gap)
    if not first_known:
        gaps[:1] = False
    if not gaps.any():
        return gyr, dt, gaps
    gyr = gyr.copy()
    dt = dt.copy()
    gyr[gaps] = np.nan
    dt[gaps] = nominal_dt
    return gyr, dt, gaps


def mark_gaps(flags: np.ndarray, gaps: np.ndarray, gyr: np.ndarray, diagnostics: dict, threshold: float) -> None:
    """Flags of the gap samples (from :func:`hold_gaps`): GAP instead of the GYR_INVALID the held
    gyro caused (kept when the original sample was invalid too); ``diagnostics["gaps"]`` counts
    them and a warning says so."""
    count = int(np.count_nonzero(gaps))  # not gaps.sum(): that adds a million booleans as integers
    diagnostics["gaps"] = count
    if not count:
        return
    idx = np.flatnonzero(gaps)
    g = np.abs(gyr[idx])
    still_bad = ~(np.isfinite(g).all(axis=1) & (g.max(axis=1) <= GYR_LIMIT))
    f = flags[idx] & np.uint32(~int(Flag.GYR_INVALID) & 0xFFFFFFFF)
    flags[idx] = f | np.uint32(Flag.GAP) | np.where(still_bad, np.uint32(Flag.GYR_INVALID), np.uint32(0))
    warnings.warn(f"{idx.size} timestamp gap(s) longer than {threshold:.3g} s (first before sample {idx[0]}): "
                  "the state is held across each, not integrated (flag GAP)", GapWarning, stacklevel=3)


def stream_gap(gyr: np.ndarray, dt: float, nominal_dt: float, max_gap: float | None):
    """:func:`hold_gaps` for one ``update()`` sample: ``(gyr, dt, gap)``; with ``gap`` the
    sample's flags take :func:`gap_flags`."""
    if dt > gap_threshold(nominal_dt, max_gap):
        return np.full(3, np.nan), nominal_dt, True
    return gyr, dt, False


def gap_flags(flags: int, gap: bool) -> int:
    """A streamed sample's flags: GAP instead of the GYR_INVALID of the held gyro (see
    :func:`stream_gap`)."""
    return int(flags) if not gap else (int(flags) & ~int(Flag.GYR_INVALID)) | int(Flag.GAP)


class GapWarning(UserWarning):
    """A recording has timestamp gaps (:data:`Flag.GAP`)."""


class AlignmentWarning(UserWarning):
    """Motion inside a mandatory alignment ended it early."""


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
        check_frame(self.frame, "gnss.frame")
        valid = np.ones(n, bool) if self.valid is None else as_mask("gnss.valid", self.valid).reshape(-1)
        if valid.shape[0] != n:
            raise InputError(f"gnss.valid has {valid.shape[0]} epochs but gnss.vel has {n}")
        self.valid = valid & np.isfinite(self.vel).all(axis=1)
        if self.pos is not None:
            self.pos = as_vectors("gnss.pos", self.pos, n)


def _unit_rows(q: np.ndarray, block: int = 16384) -> np.ndarray:
    """``q`` (N, 4) with every row of unit length, as scipy's Rotation takes a quaternion: the
    metrics read angles off the error's w (``2 acos |w|``, clipped at 1: a truth scaled by 3 once
    scored a total error of 0) and the lags the truth's derivative. ``q`` itself when every row is
    within 1e-9 of unit length (NaN rows, no reference, are kept); else a normalised copy. Checked in
    one compiled pass from ``SCAN_MIN_SAMPLES`` rows (:func:`fusionkit.validation.unit_rows_off`), else
    in blocks: no (N,) temporary for a long recording's truth."""
    if HAVE_NUMBA and q.shape[0] >= SCAN_MIN_SAMPLES and q.dtype == np.float64:  # one compiled pass
        off = unit_rows_off(q, 2e-9)
    else:
        off = any((np.abs(np.einsum("ij,ij->i", b, b) - 1.0) > 2e-9).any()  # |q|^2 - 1 = 2 (|q| - 1) near 1
                  for b in (q[i:i + block] for i in range(0, q.shape[0], block)))
    if off:
        norm = np.sqrt(np.einsum("ij,ij->i", q, q))
        return q / np.where(np.abs(norm - 1.0) > 1e-9, norm, 1.0)[:, None]
    return q


@dataclass
class Recording:
    """One IMU recording.

    Parameters
    ----------
    gyr : (N, 3) angular rate, rad/s (or ``gyr_unit="deg/s"``, ``"mrad/s"``, ``"mdeg/s"``).
    acc : (N, 3) specific force, m/s^2 (or ``acc_unit="g"``, ``"mg"``); about +g on "up" at rest.
    mag : (N, 3) magnetic field in any unit, optional.
    rate : sampling rate in Hz, or
    t : (N,) timestamps in s, strictly increasing (one of the two is required).
    gnss : optional :class:`Gnss` stream.
    truth : optional (N, 4) reference orientation, body -> ``truth_frame``, ``[w, x, y, z]``
        (normalised to unit length: a copy where a row is not; a NaN row is a sample without one).
    movement : optional (N,) bool mask of the samples the metrics are computed on.
    name, meta : free description.
    body : the sensors' body axis convention (``"FLU"``, ``"FRD"``, ``"RFU"``, ... see
        :mod:`fusionkit.conventions`), or None when not known. Filters that need a forward axis
        (``gst``, ``gst-gnss``) use it; an explicit ``body=`` that contradicts it is an error.
        The GNSS velocity's earth frame is ``gnss.frame``.

    Values are converted to the library's units on construction; a unit mistake that is
    obvious from the data raises :class:`InputError` naming the argument to pass: an
    accelerometer whose median norm is about 1 (g) or 1000 (mg), or far from gravity in every
    unit; a gyroscope in deg/s (median |component| above 2 pi rad/s, or the accelerometer and
    magnetometer turning 57 times slower than it says), or one turning faster than any gyroscope
    measures in rad/s (mrad/s, mdeg/s, raw counts; ``gyr_unit="rad/s"`` said explicitly: a gyro that
    does turn that fast). A declared unit the data contradict too. Non-finite samples are kept: each
    filter handles them by its ``nan_policy``. C-contiguous float64 arrays already in rad/s and m/s^2
    are kept as given, not copied (the recording shares their memory: change them and it changes), as is
    a boolean ``movement`` mask.
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
    gyr_unit: str | None = None  # None: rad/s, range-checked (below); "rad/s" given: a gyro that does turn that fast
    acc_unit: str = "m/s^2"
    body: str | None = None

    def __post_init__(self) -> None:
        # a gyro in rad/s beyond any consumer range (GYR_RATE_BOUND) is taken for mrad/s unless rad/s was said
        trust_range = self.gyr_unit == "rad/s"
        if self.gyr_unit is None:
            self.gyr_unit = "rad/s"
        self.gyr = as_vectors("gyr", self.gyr)
        n = self.gyr.shape[0]
        if n == 0:
            raise InputError("gyr is empty: a recording needs at least one sample")
        self.acc = as_vectors("acc", self.acc, n)
        if self.mag is not None:
            self.mag = as_vectors("mag", self.mag, n)
        if self.gyr_unit not in GYR_UNITS:
            raise InputError(f"gyr_unit must be one of {list(GYR_UNITS)}, got {self.gyr_unit!r}")
        if self.acc_unit not in ACC_UNITS:
            raise InputError(f"acc_unit must be one of {list(ACC_UNITS)}, got {self.acc_unit!r}")
        # converted only when the unit asks for it: C-contiguous float64 input in the library's
        # units is kept, not copied (the Recording shares its memory)
        declared = self.gyr_unit  # (the turning check asks whether a gyro declared in another unit was in rad/s)
        if GYR_UNITS[self.gyr_unit] != 1.0:
            self.gyr = self.gyr * GYR_UNITS[self.gyr_unit]
        if ACC_UNITS[self.acc_unit] != 1.0:
            check_acc_declared(self.gyr, self.acc, self.acc_unit)
            self.acc = self.acc * ACC_UNITS[self.acc_unit]
        self.gyr_unit, self.acc_unit = "rad/s", "m/s^2"
        if (self.rate is None) == (self.t is None):
            raise InputError("give exactly one of rate= (Hz) or t= (timestamps in s)")
        if self.rate is not None:
            self.rate = check_positive("rate", self.rate)
        else:
            self.t = check_time(self.t, n)
        self._check_interval()
        if self.body is not None:
            self.body = check_body(self.body, "body", InputError)
        self._check_units(declared, check_range=not trust_range)
        if self.truth is not None:
            self.truth = as_vectors("truth", self.truth, n, width=4)
            # a zero quaternion (a NaN row is a sample without a reference: the metrics skip it, and
            # NaN == 0 is False). One column first: the whole test only when some w is 0 (10x cheaper)
            w0 = self.truth[:, 0] == 0.0
            zero = w0 & (self.truth[:, 1:] == 0.0).all(axis=1) if w0.any() else w0
            if zero.any():
                i = int(np.argmax(zero))
                raise InputError(f"truth[{i}] is {self.truth[i].tolist()}: a zero quaternion is no orientation (a "
                                 "sample without a reference is NaN)")
            self.truth = _unit_rows(self.truth)
            check_frame(self.truth_frame, "truth_frame")
        if self.movement is not None:
            self.movement = as_mask("movement", self.movement)
            if sum(d > 1 for d in self.movement.shape) > 1 or self.movement.ndim == 0:
                raise InputError(f"movement must have shape (N,) (one bool per sample), got {self.movement.shape}")
            # a column (N, 1) or row (1, N), as loadmat and h5py give, is the same mask
            self.movement = self.movement.reshape(-1)
            if self.movement.shape[0] != n:
                raise InputError(f"movement has {self.movement.shape[0]} samples but gyr has {n}")
        if self.gnss is not None:
            if not isinstance(self.gnss, Gnss):
                raise InputError(f"gnss must be a fusionkit.Gnss, got {type(self.gnss).__name__}")
            self._clip_gnss()

    def _check_interval(self) -> None:
        """Refuse a typical interval above :data:`~fusionkit.validation.MAX_INTERVAL` (1 s: a unit
        mistake, e.g. timestamps in ms, that would otherwise run into NaN). Not for a
        :meth:`slice`: its parent was checked."""
        if self.__dict__.pop("_interval_checked", False):
            return
        n = len(self)
        if self.rate is None and (n < 2 or (self.t[-1] - self.t[0]) / (n - 1) <= 0.5 * MAX_INTERVAL):
            return  # (a median above MAX_INTERVAL needs a mean above half of it: no (N,) array made here)
        dt = self.nominal_dt
        if dt <= MAX_INTERVAL:
            return
        if self.rate is not None:
            raise InputError(f"rate is {self.rate:.4g} Hz, one sample every {dt:.4g} s: rate is in Hz (not the "
                             f"interval in s), and an IMU recording needs at least {1.0 / MAX_INTERVAL:g} Hz")
        raise InputError(f"t's typical interval (median) is {dt:.4g} s: t must be in seconds (not ms or ns), and an "
                         f"IMU recording needs at least {1.0 / MAX_INTERVAL:g} Hz")

    def _clip_gnss(self) -> None:
        """GNSS epochs outside the IMU's time span are dropped, with a warning; where none is left the
        recording has no GNSS stream (``gnss`` None: a filter that needs one says so; an empty stream
        ran them without it, silently, and crashed the metrics)."""
        t = self.time
        inside = (self.gnss.t >= t[0]) & (self.gnss.t <= t[-1])
        if not inside.any():
            warnings.warn(
                f"all {inside.size} GNSS epochs lie outside the IMU time [{t[0]:.3f}, {t[-1]:.3f}] s (GNSS "
                f"{self.gnss.t[0]:.3f} to {self.gnss.t[-1]:.3f} s: another time base?): the recording has no GNSS "
                "stream", stacklevel=3)
            self.gnss = None
            return
        if not inside.all():
            warnings.warn(
                f"{int((~inside).sum())} GNSS epochs lie outside the IMU time [{t[0]:.3f}, {t[-1]:.3f}] s and "
                "were dropped", stacklevel=3)
            g = self.gnss
            self.gnss = Gnss(t=g.t[inside], vel=g.vel[inside], valid=g.valid[inside], frame=g.frame,
                             pos=None if g.pos is None else g.pos[inside])

    def _check_units(self, gyr_unit: str = "rad/s", check_range: bool = True) -> None:
        """Refuse data in g or deg/s (:func:`fusionkit.validation.check_units`: the medians in one
        pass, and whether the gyroscope explains the magnetometer's and accelerometer's turning;
        ``gyr_unit`` is the unit ``gyr`` was declared in, before its conversion; ``check_range``:
        also refuse rates beyond any consumer gyro's range, unless rad/s was given explicitly)."""
        if self.rate is not None:  # a constant interval: no (N,) array of it
            check_units(self.gyr, self.acc, self.mag, dt=1.0 / self.rate, gyr_unit=gyr_unit, check_range=check_range)
        else:
            check_units(self.gyr, self.acc, self.mag, t=self.t, gyr_unit=gyr_unit, check_range=check_range)

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
        """(N,) sample intervals in s: ``dt[k] = t[k] - t[k-1]`` (``dt[0] = dt[1]``: a run that
        starts here has nothing before its first sample; one that continues an earlier run's state
        takes :attr:`interval_before` where the recording is a slice that knows it).

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
    def interval_before(self) -> float | None:
        """The interval (s) from the sample before this recording's first to its first, where it is
        a :meth:`slice` of a recording with timestamps that did not start at its first sample (else
        None: ``1 / rate`` with a rate). A run continued from an earlier run's state integrates its
        first sample over it, so that a run split in two equals one run on any clock (a gap there is
        held as any other). Tied to ``t``: a copy with other timestamps does not carry it."""
        if self.rate is not None:
            return 1.0 / self.rate
        kept = self.__dict__.get("_interval_before")
        return kept[1] if kept is not None and kept[0] is self.t else None

    def run_intervals(self, continued: bool) -> tuple[np.ndarray, bool]:
        """``(dt, first_known)`` for a run over this recording: :attr:`dt`, with its first entry the
        :attr:`interval_before` where the run ``continued`` an earlier run's state and it is known
        (then ``first_known``: the first interval is a real one, judged for a gap as any other)."""
        dt = self.dt
        before = self.interval_before if continued and self.t is not None else None
        if before is None:
            return dt, False
        dt = dt.copy()
        dt[0] = before
        return dt, True

    @property
    def nominal_dt(self) -> float:
        """The typical sample interval in s (``1/rate``, or the median of ``dt``: computed once
        per ``t`` array, since a run asks for it several times and a median of a long recording
        costs more than the recording's checks)."""
        if self.rate is not None:
            return 1.0 / self.rate
        cached = self.__dict__.get("_nominal_dt")
        if cached is None or cached[0] is not self.t:
            cached = self.__dict__["_nominal_dt"] = (self.t, float(np.median(self.dt)))
        return cached[1]

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
        # the parent's typical interval was checked: a slice's own (a few samples across a gap)
        # is no unit mistake, so its construction skips _check_interval
        out = Recording.__new__(Recording)
        out.__dict__["_interval_checked"] = True
        out.__init__(
            gyr=self.gyr[s], acc=self.acc[s], mag=None if self.mag is None else self.mag[s],
            rate=None if keep_clock else self.rate, t=self.time[s] if keep_clock else (None if self.t is None else self.t[s]),
            truth=None if self.truth is None else self.truth[s], truth_frame=self.truth_frame,
            movement=None if self.movement is None else self.movement[s], name=self.name,
            meta=meta, body=self.body,
        )
        idx = range(n)[s]
        if idx and out.t is not None:  # a clock of its own: the interval before its first sample kept
            i = idx.start
            before = float(self.time[i] - self.time[i - 1]) if i > 0 else self.interval_before
            if before is not None:
                out.__dict__["_interval_before"] = (out.t, before)
        if keep_clock:  # the epoch current at the first sample, and those up to the last one
            g, t = self.gnss, out.time
            first = max(0, int(np.searchsorted(g.t, t[0], side="right")) - 1)
            keep = (np.arange(g.t.size) >= first) & (g.t <= t[-1])
            out.gnss = Gnss(t=g.t[keep], vel=g.vel[keep], valid=g.valid[keep], frame=g.frame,
                            pos=None if g.pos is None else g.pos[keep])
        return out


def _model_said(item) -> str:
    """``name applied`` / ``name not applied`` for a ``(name, report)`` of ``diagnostics["models"]``
    (:meth:`Result.__repr__`), the name alone where the report has no boolean ``applied``."""
    name, rep = item
    applied = rep.get("applied") if isinstance(rep, dict) else None
    if isinstance(applied, (bool, np.bool_)):
        return f"{name} {'applied' if applied else 'not applied'}"
    return name


@dataclass
class Result:
    """Output of a filter run: one row per input sample.

    ``quat`` (N, 4) ``[w, x, y, z]`` body -> ``frame``; ``flags`` (N,) ``uint32`` :class:`Flag`
    bits; ``diagnostics`` holds the run's extras (``backend``, ``onset_index``, the gyro bias,
    ``models``: a pipeline's sensor models' estimates at the end, by name, see
    :meth:`~fusionkit.protocols.SensorModel.report`; ...).
    """

    quat: np.ndarray
    flags: np.ndarray
    frame: str = DEFAULT_FRAME
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.quat.shape[0]

    def __repr__(self) -> str:
        """A one-line summary (samples, frame, flagged samples, the sensor models and whether each
        applied its estimate at the end, diagnostics' keys), never the arrays."""
        flagged = int(np.count_nonzero(self.flags))
        keys = ", ".join(sorted(self.diagnostics))
        aiding = self.diagnostics.get("aiding")  # (what corrected the run: a 6D or gyro-only heading is arbitrary)
        models = self.diagnostics.get("models")  # (an estimate not applied changed nothing: worth a glance)
        said = "; models: " + ", ".join(map(_model_said, models.items())) if isinstance(models, dict) and models else ""
        return (f"Result({len(self)} samples, body -> {self.frame}, {aiding + ', ' if aiding else ''}"
                f"{flagged} flagged; "
                f"backend {self.diagnostics.get('backend', '?')}{said}; diagnostics: {keys})")

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
        """Names of the :class:`Flag` bits of sample ``i`` (negative: from the end, as indexing)."""
        n = len(self)
        try:
            k = operator.index(i)
        except TypeError:
            raise InputError(f"i must be a sample index (an integer), got {i!r:.80}") from None
        if not -n <= k < n:  # (numpy's IndexError named no argument)
            raise InputError(f"i is {k}, but the result has {n} samples: give an index from 0 to {n - 1}")
        return flag_names(int(self.flags[k]))

    def to_csv(self, path, time: np.ndarray | None = None) -> None:
        """Write ``t`` (if given), ``qw, qx, qy, qz``, yaw/pitch/roll (deg) and ``flags``, and, for a
        result that carries them (``ins-gnss``: ``diagnostics["velocity"]``, ``["position"]``, (N, 3)
        in the frame's axes), the velocity (m/s) and position (m) after them, each column named for its
        axis (``vel_e_mps``, ``pos_n_m`` in ENU; ``vel_d_mps`` in NED). The yaw column is named for the
        frame (``yaw_enu_deg``: from East, counter-clockwise, so body x to North is 90; ``yaw_ned_deg`` is
        a compass heading). ``time``: (N,) s, one per sample."""
        if time is not None:
            time = np.asarray(time)
            if time.shape != (len(self),):  # (numpy's own error came from deep in hstack)
                raise InputError(f"time must have shape ({len(self)},), one time in s per sample of the result, "
                                 f"got {time.shape}")
        eul = np.degrees(self.euler())
        cols = [self.quat, eul, self.flags[:, None].astype(float)]
        names = ["qw", "qx", "qy", "qz", f"yaw_{self.frame.lower()}_deg", "pitch_deg", "roll_deg", "flags"]
        if time is not None:
            cols.insert(0, time.astype(float)[:, None])
            names.insert(0, "t")
        # the time to the last bit (%.17g): at 9 digits an epoch time (1.7e9 s) lost its seconds, every row
        # the same t; the quaternions and angles to 9 digits (1e-9, far below any filter's error)
        fmt = ["%.17g"] * (time is not None) + ["%.9g"] * (len(names) - 1 - (time is not None)) + ["%d"]
        axes = [a.lower() for a in self.frame]  # (ENU: e, n, u; NED: n, e, d; NWU: n, w, u)
        for key, unit in (("velocity", "mps"), ("position", "m")):  # a navigation result's (ins-gnss): it wrote
            v = self.diagnostics.get(key)  # the attitude alone, its velocity and position only in diagnostics
            if isinstance(v, np.ndarray) and v.shape == (len(self), 3) and len(axes) == 3:
                cols.append(v.astype(float))
                names += [f"{key[:3]}_{a}_{unit}" for a in axes]
                fmt += ["%.9g"] * 3
        try:
            np.savetxt(path, np.hstack(cols), delimiter=",", header=",".join(names), comments="", fmt=fmt)
        except OSError as exc:  # (numpy's FileNotFoundError named no argument: a missing folder, no permission)
            raise InputError(f"path: cannot write {str(path)!r}: {exc.strerror or exc}") from None
