"""The error models real IMUs have, for the simulator (:func:`fusionkit.sim.simulate`'s ``errors``).

Every model is off by default (an empty :class:`SensorErrors` simulates exactly what no errors
does, to the bit) and is given in physical units. They act in the order a real sensor applies
them to what it feels (see ``docs/simulator.md``):

1. the world: the earth-frame magnetic disturbances (:class:`MagneticDipole`, :class:`FieldPatch`)
   add to the earth's field where (and when) the body is, so they do not turn with the body;
   vibration (:class:`Vibration`) and taps (:class:`Tap`) add to the specific force in the body;
2. the sensor's timing: a delay per sensor (the sample reports the signal ``delay`` seconds
   earlier), then a causal low-pass (a Butterworth filter, whose group delay is
   :func:`lowpass_delay`);
3. the sensor's geometry: scale factor and misalignment, ``(I + S + M) x`` (gyro,
   accelerometer); hard and soft iron, ``A m + b`` (magnetometer);
4. slowly varying biases: a random walk of the given density (plus :class:`~fusionkit.sim.Noise`'s
   constant bias and white noise, drawn exactly as without errors);
   a magnetometer read at a lower rate (``mag_rate``) then holds each reading, noise and all,
   until the next one (sample and hold: the held samples repeat it exactly);
5. the transport: dropped samples (rows lost at random) and timestamp gaps (every row in a time
   span lost). The samples that remain are as the sensor made them: after a lost row the gyro's
   mean rate still covers its own interval, so ``(t[k-1], t[k]]`` spans more than it.

The random parts (random walks, band-limited vibration, dropped rows) draw from their own stream
of the simulation's ``seed``, so switching a model on never changes the white noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..errors import InputError

__all__ = ["SensorErrors", "MagneticDipole", "FieldPatch", "Vibration", "Tap", "lowpass_delay"]

_MU0_4PI = 1e-7  # mu_0 / (4 pi), T m / A


def _vec(name: str, v, size: int = 3) -> tuple[float, ...]:
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        a = np.full(0, np.nan)  # (refused below, by name)
    if a.shape != (size,) or not np.isfinite(a).all():
        raise InputError(f"{name} must be {size} finite numbers, got {v!r}")
    return tuple(float(x) for x in a)


def _mat(name: str, v) -> np.ndarray | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=float)
    if a.shape != (3, 3) or not np.isfinite(a).all():
        raise InputError(f"{name} must be a finite 3x3 matrix, got shape {a.shape}")
    return a


def _real(name: str, v, what: str = "a finite number") -> float:
    """``v`` as a finite float, or an InputError naming ``name`` (also for text and booleans, which
    ``float`` would take: ``"100"`` parses, True is 1)."""
    try:
        scalar = np.ndim(v) == 0
    except ValueError:  # (a ragged list: numpy's own error)
        scalar = False
    if isinstance(v, (bool, np.bool_, str, bytes)) or not scalar:
        raise InputError(f"{name} must be {what}, got {v!r:.80}")
    try:  # (a number of any kind: numpy's scalars and 0-d arrays, a Fraction)
        v = float(v)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be {what}, got {v!r:.80}") from None
    if not math.isfinite(v):
        raise InputError(f"{name} must be {what}, got {v}")
    return v


def _positive(name: str, v, unit: str) -> float:
    """``v`` as a finite float > 0 (in ``unit``), or an InputError naming ``name``."""
    v = _real(name, v, f"a finite number > 0 ({unit})")
    if not v > 0.0:
        raise InputError(f"{name} must be > 0 {unit}, got {v}")
    return v


def _direction(name: str, v) -> tuple[float, ...]:
    """``v`` as 3 finite numbers, not all zero (a direction), or an InputError naming ``name``."""
    d = _vec(name, v)
    if not any(d):
        raise InputError(f"{name} must be a direction (3 finite numbers, not all zero), got {v!r}")
    return d


def _nonneg(name: str, v: float) -> float:
    v = _real(name, v, "finite and >= 0")
    if not v >= 0.0:
        raise InputError(f"{name} must be finite and >= 0, got {v}")
    return v


@dataclass(frozen=True)
class MagneticDipole:
    """A magnet fixed in the earth frame: its field ``mu0/(4 pi) (3 r (r . m) - m) / |r|^3``
    (``r`` the unit vector from the magnet to the body) adds to the earth's field at the body.

    ``position``: m, ENU, relative to where the body starts; ``moment``: A m^2, ENU (a small
    fridge magnet has about 0.1-1). The field is in uT, the simulator's magnetometer unit.
    """

    position: tuple[float, float, float]
    moment: tuple[float, float, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _vec("MagneticDipole.position", self.position))
        object.__setattr__(self, "moment", _vec("MagneticDipole.moment", self.moment))

    def field(self, pos: np.ndarray) -> np.ndarray:
        """The dipole's field (uT, ENU) at positions ``pos`` ((n, 3) m, ENU)."""
        r = np.asarray(pos, dtype=float) - np.asarray(self.position)
        d = np.linalg.norm(r, axis=-1, keepdims=True)
        if np.any(d < 1e-3):
            raise InputError(f"the body passes within 1 mm of the magnet at {self.position}: its field is undefined")
        u = r / d
        m = np.asarray(self.moment)
        return 1e6 * _MU0_4PI * (3.0 * u * (u @ m)[..., None] - m) / d**3


@dataclass(frozen=True)
class FieldPatch:
    """A uniform field ``field`` (uT, ENU) added to the earth's field from ``start`` to ``stop``
    (s): a disturbance fixed in the earth frame, the same wherever the body is (a steel
    structure the body sits in for a while)."""

    field: tuple[float, float, float]
    start: float
    stop: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "field", _vec("FieldPatch.field", self.field))
        if not (math.isfinite(self.start) and math.isfinite(self.stop) and self.stop > self.start):
            raise InputError(f"FieldPatch needs finite start < stop, got {self.start}, {self.stop}")


@dataclass(frozen=True)
class Vibration:
    """An acceleration that shakes the body (engine, rotor, vehicle), added to the specific
    force in the body frame; the orientation (``truth``) does not move with it.

    ``amplitude``: m/s^2 per body axis (the peak of the sinusoid; the RMS of band-limited
    vibration). ``frequency``: Hz. ``bandwidth`` 0 (default): a sinusoid
    ``amplitude sin(2 pi f t + phase)``; > 0: Gaussian noise band-passed to
    ``frequency +- bandwidth / 2`` (a 4th-order Butterworth, drawn on a grid 16 times finer
    than the samples). ``start`` / ``stop`` (s) bound it in time.
    """

    amplitude: tuple[float, float, float]
    frequency: float
    bandwidth: float = 0.0
    phase: float = 0.0
    start: float = 0.0
    stop: float = math.inf

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude", _vec("Vibration.amplitude", self.amplitude))
        if not (math.isfinite(self.frequency) and self.frequency > 0):
            raise InputError(f"Vibration.frequency must be > 0 Hz, got {self.frequency}")
        _nonneg("Vibration.bandwidth", self.bandwidth)
        if self.bandwidth >= 2 * self.frequency:
            raise InputError(f"Vibration.bandwidth ({self.bandwidth} Hz) must be below twice the frequency "
                             f"({self.frequency} Hz)")
        if not self.stop > self.start:
            raise InputError(f"Vibration needs start < stop, got {self.start}, {self.stop}")


@dataclass(frozen=True)
class Tap:
    """A short knock on the body at ``time`` (s): a half-sine pulse of specific force
    ``amplitude`` (m/s^2, body frame, its peak) lasting ``duration`` (s, 5 ms by default)."""

    time: float
    amplitude: tuple[float, float, float]
    duration: float = 0.005

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude", _vec("Tap.amplitude", self.amplitude))
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise InputError(f"Tap.duration must be > 0 s, got {self.duration}")
        if not math.isfinite(self.time):
            raise InputError(f"Tap.time must be finite, got {self.time}")


@dataclass(frozen=True, eq=False)
class SensorErrors:
    """The sensor errors to simulate; every field's default is "off". Units: s, Hz, rad/s, m/s^2,
    uT (the simulator's magnetometer unit), fractions for scale factors.

    Magnetometer: ``mag_offset`` hard iron ``b`` (uT, body) and ``mag_matrix`` soft iron ``A``
    (3x3, identity when None): the sensor reads ``A m + b``. ``dipoles`` (:class:`MagneticDipole`)
    and ``patches`` (:class:`FieldPatch`): disturbances fixed in the earth frame.

    Timing: ``gyr_delay`` / ``acc_delay`` / ``mag_delay`` (s): sample ``k`` holds what the sensor
    would have reported at ``t[k] - delay`` (a cubic spline through the samples, the ends held).
    ``gyr_lowpass`` / ``acc_lowpass`` / ``mag_lowpass`` (Hz): a causal Butterworth low-pass of
    order ``lowpass_order`` (an int, 1 to 4) at that cutoff (started at steady state), as a
    sensor's digital filter; its low-frequency group delay is :func:`lowpass_delay`. ``mag_rate``
    (Hz, at most the IMU's rate: :func:`~fusionkit.sim.simulate` refuses one above it): the
    magnetometer is read at this rate (readings at ``j / mag_rate``) and every sample reports
    the newest reading, taken at the first sample at or after its instant, so a sample is either
    fresh (on time) or repeats an older one exactly, as many samples old as have passed since
    (:func:`held_source`).

    Geometry: ``gyr_scale`` / ``acc_scale`` (3 fractions, ``S = diag``) and
    ``gyr_misalignment`` / ``acc_misalignment`` (3x3 ``M``, its diagonal must be 0): the sensor
    reads ``(I + S + M) x``. ``lever_arm`` (m, body): the accelerometer sits there, away from
    the point the body rotates about (the trajectory's point): it feels the rotation's tangential
    and centripetal accelerations too, ``w_dot x r + w x (w x r)`` (in the body). The orientation,
    ``ref_pos`` and the GNSS velocity stay the rotation centre's.

    Biases: ``gyr_bias_rw`` (rad/s/sqrt(s)) and ``acc_bias_rw`` (m/s^2/sqrt(s)): the bias
    random-walk density; each sample adds a Gaussian step of std ``density sqrt(dt)`` per axis
    (starting from 0, on top of :class:`~fusionkit.sim.Noise`'s constant bias).

    Specific force: ``vibration`` (a :class:`Vibration` or a tuple of them), ``taps``
    (:class:`Tap` s).

    Transport: ``drop_rate`` (0-1): each row is lost with this probability; ``gaps``:
    ``(start, length)`` pairs (s): every row with ``start <= t < start + length`` is lost. The
    first and last rows are always kept (the time span stays). The recording then has
    timestamps ``t`` instead of a ``rate``.
    """

    mag_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_matrix: np.ndarray | None = None
    dipoles: tuple[MagneticDipole, ...] = ()
    patches: tuple[FieldPatch, ...] = ()
    gyr_delay: float = 0.0
    acc_delay: float = 0.0
    mag_delay: float = 0.0
    gyr_lowpass: float | None = None
    acc_lowpass: float | None = None
    mag_lowpass: float | None = None
    lowpass_order: int = 2
    mag_rate: float | None = None
    gyr_scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyr_misalignment: np.ndarray | None = None
    acc_scale: tuple[float, float, float] = (0.0, 0.0, 0.0)
    acc_misalignment: np.ndarray | None = None
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gyr_bias_rw: float = 0.0
    acc_bias_rw: float = 0.0
    vibration: Vibration | tuple[Vibration, ...] | None = None
    taps: tuple[Tap, ...] = ()
    drop_rate: float = 0.0
    gaps: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        s = object.__setattr__
        for name in ("mag_offset", "gyr_scale", "acc_scale", "lever_arm"):
            s(self, name, _vec(name, getattr(self, name)))
        for name in ("mag_matrix", "gyr_misalignment", "acc_misalignment"):
            s(self, name, _mat(name, getattr(self, name)))
        for name in ("gyr_misalignment", "acc_misalignment"):
            m = getattr(self, name)
            if m is not None and np.any(np.diag(m) != 0.0):
                raise InputError(f"{name} must have a zero diagonal (scale factors go in the *_scale fields)")
        if self.mag_matrix is not None and abs(np.linalg.det(self.mag_matrix)) < 1e-9:
            raise InputError("mag_matrix (soft iron) must be invertible")
        for name in ("gyr_delay", "acc_delay", "mag_delay"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise InputError(f"{name} must be finite (s), got {v}")
            s(self, name, v)
        for name in ("gyr_lowpass", "acc_lowpass", "mag_lowpass"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise InputError(f"{name} must be None or a cutoff > 0 Hz, got {v}")
        if self.mag_rate is not None and not (math.isfinite(self.mag_rate) and self.mag_rate > 0):
            raise InputError(f"mag_rate must be None or a rate > 0 Hz, got {self.mag_rate}")
        order = self.lowpass_order  # (an int: True == 1 and 2.0 == 2 passed the range test)
        if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) or order not in (1, 2, 3, 4):
            raise InputError(f"lowpass_order must be 1, 2, 3 or 4 (an int), got {order!r}")
        s(self, "lowpass_order", int(order))
        for name in ("gyr_bias_rw", "acc_bias_rw"):
            s(self, name, _nonneg(name, getattr(self, name)))
        if not 0.0 <= _real("drop_rate", self.drop_rate, "in [0, 1)") < 1.0:
            raise InputError(f"drop_rate must be in [0, 1), got {self.drop_rate}")
        vib = self.vibration
        vib = () if vib is None else (vib,) if isinstance(vib, Vibration) else tuple(vib)
        for name, items, cls in (("vibration", vib, Vibration), ("taps", self.taps, Tap),
                                 ("dipoles", self.dipoles, MagneticDipole), ("patches", self.patches, FieldPatch)):
            items = tuple(items)
            if not all(isinstance(x, cls) for x in items):
                raise InputError(f"{name} must hold {cls.__name__} objects, got {items!r}")
            s(self, name, items)
        gaps = tuple((float(a), float(b)) for a, b in self.gaps)
        if any(not (math.isfinite(a) and b > 0 and math.isfinite(b)) for a, b in gaps):
            raise InputError(f"gaps must be (start, length > 0) pairs in s, got {self.gaps!r}")
        s(self, "gaps", gaps)

    @property
    def active(self) -> list[str]:
        """The names of the fields that are not at their "off" default."""
        off = SensorErrors()
        return [f.name for f in fields(self)
                if isinstance(getattr(self, f.name), np.ndarray) or getattr(self, f.name) != getattr(off, f.name)]


def lowpass_delay(cutoff: float, rate: float, order: int = 2) -> float:
    """The group delay (samples) at low frequency of the simulator's low-pass: a digital
    Butterworth filter of ``order`` at ``cutoff`` Hz, sampled at ``rate`` Hz. (For a first-order
    filter about ``rate / (2 pi cutoff)``, for the second-order one ``sqrt(2)`` times that.)"""
    from scipy.signal import butter, group_delay

    b, a = butter(order, min(cutoff / (0.5 * rate), 0.999))
    return float(group_delay((b, a), w=[1e-4])[1][0])


# ---- applying them (called by simulate) --------------------------------------------------------

def earth_disturbance(errors: SensorErrors, pos: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The earth-frame field (uT, ENU) the disturbances add at positions ``pos`` (n, 3) and times
    ``t`` (n,)."""
    out = np.zeros((len(t), 3))
    for d in errors.dipoles:
        out += d.field(pos)
    for p in errors.patches:
        out += ((t >= p.start) & (t < p.stop))[:, None] * np.asarray(p.field)
    return out


def specific_force_extra(errors: SensorErrors, t: np.ndarray, dt: float, sampling: str,
                         rng: np.random.Generator) -> np.ndarray:
    """Vibration and taps (m/s^2, body) at the samples ``t``: their values at ``t[k]``
    (``sampling="point"``) or their exact means over ``(t[k] - dt, t[k]]`` (``"mean"``)."""
    out = np.zeros((len(t), 3))
    t0 = t - dt
    for v in errors.vibration:
        amp = np.asarray(v.amplitude)
        if v.bandwidth == 0.0:
            w = 2.0 * np.pi * v.frequency
            if sampling == "point":
                x = np.sin(w * t + v.phase)
            else:  # the mean of sin over (t0, t]
                x = (np.cos(w * t0 + v.phase) - np.cos(w * t + v.phase)) / (w * dt)
            on = (t > v.start) & (t <= v.stop)
            out += (on * x)[:, None] * amp
        else:
            out += _band_limited(v, t, dt, sampling, rng)
    for tap in errors.taps:
        a, b = tap.time, tap.time + tap.duration
        amp = np.asarray(tap.amplitude)
        if sampling == "point":
            x = np.where((t >= a) & (t <= b), np.sin(np.pi * np.clip(t - a, 0.0, tap.duration) / tap.duration), 0.0)
        else:  # integral of the half-sine over (t0, t] clipped to [a, b], divided by dt
            lo, hi = np.clip(t0, a, b), np.clip(t, a, b)
            x = tap.duration / np.pi * (np.cos(np.pi * (lo - a) / tap.duration)
                                        - np.cos(np.pi * (hi - a) / tap.duration)) / dt
        out += x[:, None] * amp
    return out


_FINE = 16  # band-limited vibration is drawn on a grid this many times finer than the samples


def _band_limited(v: Vibration, t: np.ndarray, dt: float, sampling: str, rng: np.random.Generator) -> np.ndarray:
    from scipy.signal import butter, sosfilt

    fine_rate = _FINE / dt
    lo, hi = v.frequency - 0.5 * v.bandwidth, v.frequency + 0.5 * v.bandwidth
    if hi >= 0.5 * fine_rate:
        raise InputError(f"Vibration band up to {hi} Hz is beyond what the simulator draws ({0.5 * fine_rate} Hz)")
    sos = butter(4, [lo / (0.5 * fine_rate), hi / (0.5 * fine_rate)], btype="band", output="sos")
    settle = int(20 * fine_rate / v.bandwidth)  # let the filter forget its start
    n_fine = (len(t) + 1) * _FINE
    x = sosfilt(sos, rng.standard_normal((settle + n_fine, 3)), axis=0)[settle:]
    x = x / x.std(axis=0) * np.asarray(v.amplitude)
    if sampling == "point":
        s = x[_FINE::_FINE][:len(t)]
    else:
        s = x[1:len(t) * _FINE + 1].reshape(len(t), _FINE, 3).mean(axis=1)
    on = (t > v.start) & (t <= v.stop)
    return s * on[:, None]


def delayed(x: np.ndarray, delay_samples: float) -> np.ndarray:
    """``x`` (n, 3) as seen ``delay_samples`` late: sample ``k`` holds ``x`` at ``k - delay``
    (a cubic spline through the samples; before the first and after the last, held)."""
    if delay_samples == 0.0:
        return x
    from scipy.interpolate import CubicSpline

    k = np.arange(len(x), dtype=float)
    return CubicSpline(k, x, axis=0)(np.clip(k - delay_samples, 0.0, len(x) - 1.0))


def held_source(n: int, mag_rate: float, rate: float) -> np.ndarray:
    """For each of ``n`` samples at ``rate`` Hz, the sample whose value it reports when the sensor is
    read at ``mag_rate`` Hz and sampled and held: the newest reading ``j`` (at ``j / mag_rate``,
    not after the sample) appears at the first sample at or after its instant. ``k - src[k]`` is
    the sample's age (0: fresh)."""
    k = np.arange(n)
    if mag_rate >= rate:
        return k
    eps = 1e-9
    j = np.floor(k * (mag_rate / rate) + eps)  # the newest reading at or before sample k
    return np.minimum(np.ceil(j * (rate / mag_rate) - eps), k).astype(int)


def lowpassed(x: np.ndarray, cutoff: float | None, rate: float, order: int) -> np.ndarray:
    """``x`` (n, 3) through the causal Butterworth low-pass, started at steady state on ``x[0]``."""
    if cutoff is None:
        return x
    from scipy.signal import butter, sosfilt, sosfilt_zi

    sos = butter(order, min(cutoff / (0.5 * rate), 0.999), output="sos")
    zi = sosfilt_zi(sos)[:, :, None] * x[0][None, None, :]
    return sosfilt(sos, x, axis=0, zi=zi)[0]


def scaled(x: np.ndarray, scale, misalignment) -> np.ndarray:
    """``(I + S + M) x`` per sample."""
    if not any(scale) and misalignment is None:
        return x
    t = np.eye(3) + np.diag(scale)
    if misalignment is not None:
        t = t + misalignment
    return x @ t.T


def random_walk(n: int, density: float, dt: float, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) bias random walk from 0: Gaussian steps of std ``density sqrt(dt)`` per sample."""
    steps = density * math.sqrt(dt) * rng.standard_normal((n, 3))
    steps[0] = 0.0
    return np.cumsum(steps, axis=0)


def kept_rows(errors: SensorErrors, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of the rows that survive dropped samples and timestamp gaps (the first and the
    last always: the recording keeps its time span, and the GNSS stream with it)."""
    keep = np.ones(len(t), dtype=bool)
    if errors.drop_rate > 0:
        keep[1:] = rng.random(len(t) - 1) >= errors.drop_rate
    for start, length in errors.gaps:
        keep &= ~((t >= start) & (t < start + length))
    keep[0] = keep[-1] = True
    return np.flatnonzero(keep)
