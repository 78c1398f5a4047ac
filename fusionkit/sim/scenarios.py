"""Ready-made simulated recordings: the demo's, and the scenarios that isolate one sensor error.

Each scenario is the recording a plugin that handles one error is tested on: a motion that
makes the error visible, a consumer MEMS IMU's noise (:meth:`Noise.mems`, biases and all, unless
``noise`` says otherwise) and that one error switched on (:class:`~fusionkit.sim.SensorErrors`,
also in ``meta["errors"]``; ``meta["scenario"]`` names the scenario). The defaults are plausible
values for a consumer MEMS IMU, not numbers fitted to any data set. ``SCENARIOS`` maps the
names (also ``sim:NAME`` on the command line) to the functions, called with their defaults.
"""

from __future__ import annotations

import contextvars
import dataclasses
import math

import numpy as np

from ..errors import InputError
from ..types import Recording
from .errors import MagneticDipole, SensorErrors, Tap, Vibration
from .motion import Rest, Rotate, Translate
from .noise import Noise
from .sensors import simulate

__all__ = ["demo_recordings", "hard_iron_turning", "carried_magnet", "magnet_nearby", "late_gyro", "late_mag",
           "lowpass_gyro", "scaled_gyro", "drifting_bias_long", "vibrating", "tapped", "lossy", "hand_held",
           "SCENARIOS", "scenario", "perturbed"]

_DEG = math.pi / 180.0

#: axes that together turn a body through every orientation family (the field sweeps its sphere)
_AXES = ((0, 0, 1), (1, 0, 0), (0, 1, 0), (1, 1, 0), (0, 1, 1), (1, 0, 1), (1, -1, 1), (-1, 1, 1))


def demo_recordings(rate: float = 200.0, seed: int = 0) -> list[Recording]:
    """Three short noisy recordings for the demo: slow rotations, fast rotations, translations."""
    deg = np.pi / 180.0
    noise = Noise.mems()
    slow = [Rest(12.0), Rotate((0, 0, 1), 90 * deg, 4.0), Rotate((1, 0, 0), 45 * deg, 3.0), Rest(2.0),
            Rotate((0, 1, 0), -60 * deg, 4.0), Rotate((0, 0, 1), -90 * deg, 4.0), Rest(5.0)]
    fast = [Rest(12.0)] + [Rotate(ax, 120 * deg * s, 1.0) for s in (1, -1) for ax in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0))] + [Rest(5.0)]
    trans = [Rest(12.0)] + [Translate(d, 0.5, 1.5) for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1))] + [Rotate((0, 0, 1), 30 * deg, 2.0), Rest(5.0)]
    return [simulate(s, rate=rate, noise=noise, seed=seed + i, name=nm)
            for i, (nm, s) in enumerate((("slow-rotation", slow), ("fast-rotation", fast), ("translation", trans)))]


def _tumbling(turns: int, angle: float, duration: float, pause: float = 0.0) -> list:
    """A rest, then ``turns`` rotations by ``angle`` (deg) of ``duration`` s each, about the
    axes in turn, alternating sense, with ``pause`` s of rest after each, then a rest."""
    segs = [Rest(2.0)]
    for i in range(turns):
        segs.append(Rotate(_AXES[i % len(_AXES)], (1 if i % 2 == 0 else -1) * angle * _DEG, duration))
        if pause:
            segs.append(Rest(pause))
    return segs + [Rest(2.0)]


#: set by :func:`perturbed` while it calls a scenario: (first rest in s or None, extra error fields)
_PERTURB: contextvars.ContextVar = contextvars.ContextVar("_PERTURB", default=None)


def _run(name: str, segs, errors: SensorErrors, rate: float, noise: Noise | None, seed: int, **kw) -> Recording:
    perturb = _PERTURB.get()
    if perturb is not None:
        segs, errors = _perturbed(segs, errors, *perturb)
    rec = simulate(segs, rate=rate, noise=Noise.mems() if noise is None else noise, seed=seed, name=name,
                   errors=errors, **kw)
    rec.meta["scenario"] = name
    return rec


def hard_iron_turning(offset=(15.0, -25.0, 10.0), matrix=None, rate: float = 100.0, noise: Noise | None = None,
                      seed: int = 0) -> Recording:
    """Slow turns about many axes (the field sweeps its whole ellipsoid) with a hard-iron
    ``offset`` (uT, body) and optionally a soft-iron ``matrix``: what a magnetometer
    calibration is tested on (the centre it finds is ``offset``, the shape ``matrix``)."""
    return _run("hard-iron-turning", _tumbling(16, 200.0, 3.0, 0.5), SensorErrors(mag_offset=offset, mag_matrix=matrix),
                rate, noise, seed)


def carried_magnet(distance: float = 0.05, moment: float = 0.01, rate: float = 100.0, noise: Noise | None = None,
                   seed: int = 0) -> Recording:
    """Slow turns about many axes with a small magnet of ``moment`` A m^2 carried with the sensor,
    ``distance`` m from it (beside the sensor on its body y axis, pointing along body x): a field
    fixed in the *body* frame, hard iron ``mu0/(4 pi) (3 r (r . m) - m) / d^3`` (0.01 A m^2 adds
    8 uT at 5 cm, 37 uT at 3 cm, 1 uT at 10 cm). What an online magnetometer calibration is tested
    on against :func:`magnet_nearby`'s magnet fixed in the earth frame (``meta["mag_offset"]``)."""
    if not distance > 0:
        raise InputError(f"distance must be > 0 m, got {distance}")
    offset = MagneticDipole(position=(0.0, -distance, 0.0), moment=(moment, 0.0, 0.0)).field(np.zeros((1, 3)))[0]
    rec = _run("carried-magnet", _tumbling(16, 200.0, 3.0, 0.5), SensorErrors(mag_offset=tuple(offset)), rate,
               noise, seed)
    rec.meta["mag_offset"] = offset
    return rec


def magnet_nearby(distance: float = 0.3, moment: float = 3.0, rate: float = 100.0, noise: Noise | None = None,
                  seed: int = 0) -> Recording:
    """Turns far from any magnet, a walk to within ``distance`` m of a magnet of ``moment``
    A m^2 fixed in the earth frame (pointing up, beside the body: 3 A m^2 at 0.3 m adds 11 uT), turns
    there, and a walk back: what a magnetic-disturbance detector or a field-rejecting filter is
    tested on (``meta["ref_pos"]`` and the dipole give the true disturbance)."""
    if not distance > 0:
        raise InputError(f"distance must be > 0 m, got {distance}")
    magnet = MagneticDipole(position=(2.0 + distance, 0.0, 0.0), moment=(0.0, 0.0, moment))
    turns = _tumbling(4, 90.0, 2.0, 0.5)[1:-1]
    segs = [Rest(2.0)] + turns + [Translate((1, 0, 0), 2.0, 6.0), Rest(1.0)] + turns + \
        [Translate((-1, 0, 0), 2.0, 6.0)] + turns + [Rest(2.0)]
    return _run("magnet-nearby", segs, SensorErrors(dipoles=(magnet,)), rate, noise, seed)


def late_gyro(delay: float = 0.005, rate: float = 200.0, noise: Noise | None = None, seed: int = 0) -> Recording:
    """Brisk turns about many axes with the gyroscope ``delay`` s behind the accelerometer and
    magnetometer (one sample at 200 Hz by default): what a time-offset estimator is tested on
    (:func:`~fusionkit.benchmarking.timing.sensor_lags` shows ``0.5 + delay * rate`` samples)."""
    return _run("late-gyro", _tumbling(16, 150.0, 0.8, 0.3), SensorErrors(gyr_delay=delay), rate, noise, seed)


def late_mag(delay: float = 0.005, cutoff: float | None = None, order: int = 2, mag_rate: float | None = None,
             turns: int = 32, rate: float = 200.0, noise: Noise | None = None, seed: int = 0) -> Recording:
    """Brisk turns about many axes with the magnetometer's timing off the gyro's (and the
    accelerometer's): ``delay`` s late (one sample at 200 Hz by default), behind a Butterworth low-pass (``cutoff`` Hz, ``order``;
    :func:`~fusionkit.sim.lowpass_delay` samples of group delay), and/or read at ``mag_rate`` Hz
    and sampled and held (its held samples repeat the reading exactly). All off (``delay=0``): the
    sensors follow fusionkit's convention. What a magnetometer-timing estimate and a heading's pairing
    are tested on (``turns`` 1 s turns of 150 deg with 0.3 s rests)."""
    errors = SensorErrors(mag_delay=delay, mag_lowpass=cutoff, lowpass_order=order, mag_rate=mag_rate)
    return _run("late-mag", _tumbling(turns, 150.0, 0.8, 0.3), errors, rate, noise, seed)


def lowpass_gyro(cutoff: float = 20.0, order: int = 2, rate: float = 200.0, noise: Noise | None = None,
                 seed: int = 0) -> Recording:
    """Brisk turns with the gyroscope behind a Butterworth low-pass (``cutoff`` Hz, ``order``)
    as a sensor's digital filter: a delay of :func:`~fusionkit.sim.lowpass_delay` samples at low
    frequency that grows less than linearly with the motion's bandwidth."""
    return _run("lowpass-gyro", _tumbling(16, 150.0, 0.8, 0.3), SensorErrors(gyr_lowpass=cutoff, lowpass_order=order),
                rate, noise, seed)


def scaled_gyro(scale=(0.01, -0.015, 0.02), misalignment=None, rate: float = 200.0, noise: Noise | None = None,
                seed: int = 0) -> Recording:
    """Fast full turns about many axes with a gyroscope scale factor (fractions) and, when
    given, a misalignment (3x3, zero diagonal): heading errors grow with the turned angle."""
    if misalignment is None:
        misalignment = np.array([[0.0, 0.004, -0.003], [-0.002, 0.0, 0.005], [0.003, -0.004, 0.0]])
    return _run("scaled-gyro", _tumbling(16, 360.0, 1.5, 1.0),
                SensorErrors(gyr_scale=scale, gyr_misalignment=misalignment), rate, noise, seed)


def drifting_bias_long(duration: float = 600.0, gyr_bias_rw: float = 2e-4, acc_bias_rw: float = 0.0,
                       rate: float = 100.0, noise: Noise | None = None, seed: int = 0) -> Recording:
    """``duration`` s of turns with rests between them while the gyro's bias random-walks
    (``gyr_bias_rw`` rad/s/sqrt(s): 2e-4 drifts about 0.3 deg/s in 10 minutes): what a bias
    estimator that must track, not just find, the bias is tested on (``meta["gyr_bias"]`` is
    the true bias per sample)."""
    if not duration >= 20.0:
        raise InputError(f"duration must be >= 20 s, got {duration}")
    n = max(1, int((duration - 4.0) // 8.0))  # 3 s turn + 5 s rest
    segs = _tumbling(n, 90.0, 3.0, 5.0)
    segs[-1] = Rest(duration - sum(s.duration for s in segs[:-1]))
    return _run("drifting-bias-long", segs, SensorErrors(gyr_bias_rw=gyr_bias_rw, acc_bias_rw=acc_bias_rw),
                rate, noise, seed)


def vibrating(amplitude=(1.0, 1.0, 2.0), frequency: float = 45.0, bandwidth: float = 10.0, rate: float = 200.0,
              noise: Noise | None = None, seed: int = 0) -> Recording:
    """Slow turns and translations on a vibrating mount (``amplitude`` m/s^2 RMS per body axis,
    band ``frequency +- bandwidth / 2`` Hz, or a sinusoid with ``bandwidth=0``): what an
    accelerometer gating or low-pass is tested on (the orientation does not vibrate)."""
    segs = _tumbling(6, 90.0, 3.0, 1.0)[:-1] + [Translate((1, 0, 0), 1.0, 3.0), Rest(1.0),
                                               Translate((0, 1, 0), -1.0, 3.0), Rest(2.0)]
    return _run("vibrating", segs, SensorErrors(vibration=Vibration(amplitude, frequency, bandwidth)), rate, noise,
                seed)


def tapped(times=(4.0, 9.5, 15.0), amplitude=(0.0, 40.0, 20.0), duration: float = 0.005, rate: float = 200.0,
           noise: Noise | None = None, seed: int = 0) -> Recording:
    """Slow turns with knocks on the body at ``times`` (s): half-sine impulses of peak
    ``amplitude`` (m/s^2, body) lasting ``duration`` s: what a shock detector is tested on."""
    taps = tuple(Tap(t, amplitude, duration) for t in times)
    return _run("tapped", _tumbling(6, 90.0, 2.0, 1.0), SensorErrors(taps=taps), rate, noise, seed)


def lossy(drop_rate: float = 0.02, gaps=((6.0, 0.25), (14.0, 1.0)), rate: float = 200.0, noise: Noise | None = None,
          seed: int = 0) -> Recording:
    """Turns recorded over a lossy link: rows dropped at ``drop_rate`` and every row lost in the
    ``(start, length)`` ``gaps`` (s); the recording has timestamps, not a rate. What a filter's
    handling of uneven sampling is tested on."""
    return _run("lossy", _tumbling(8, 120.0, 1.5, 0.5), SensorErrors(drop_rate=drop_rate, gaps=gaps), rate, noise, seed)


def hand_held(lever_arm=(0.15, 0.03, -0.05), rate: float = 200.0, noise: Noise | None = None,
              seed: int = 0) -> Recording:
    """Turns by hand (90 deg in 0.8 s about many axes, up to 4 rad/s) with the accelerometer
    ``lever_arm`` m (body) from the point the body turns about, a sensor held at the wrist: the
    rotation's tangential and centripetal accelerations (1-3 m/s^2) are what a lever-arm model is
    tested on."""
    return _run("hand-held", _tumbling(24, 90.0, 0.8, 0.3), SensorErrors(lever_arm=lever_arm), rate, noise, seed)


#: scenario name -> function (called with its defaults by :func:`scenario` and ``sim:NAME``)
SCENARIOS = {n: f for n, f in (
    ("hard-iron-turning", hard_iron_turning), ("carried-magnet", carried_magnet), ("magnet-nearby", magnet_nearby),
    ("late-gyro", late_gyro), ("late-mag", late_mag),
    ("lowpass-gyro", lowpass_gyro), ("scaled-gyro", scaled_gyro), ("drifting-bias-long", drifting_bias_long),
    ("vibrating", vibrating), ("tapped", tapped), ("lossy", lossy), ("hand-held", hand_held))}


def _perturbed(segs, errors: SensorErrors, initial_rest, extra: dict):
    segs = list(segs)
    if initial_rest is not None:
        if isinstance(segs[0], Rest):
            segs[0] = Rest(initial_rest)
        else:
            segs.insert(0, Rest(initial_rest))
    unknown = set(extra) - {f.name for f in dataclasses.fields(SensorErrors)}
    if unknown:
        raise InputError(f"unknown SensorErrors fields {sorted(unknown)}")
    own = set(errors.active)
    return segs, dataclasses.replace(errors, **{k: v for k, v in extra.items() if k not in own})


def perturbed(name: str, initial_rest: float | None = None, errors: dict | None = None, **params) -> Recording:
    """The scenario ``name`` (``params`` as for :func:`scenario`, ``noise`` and ``seed`` among
    them) with more of a real sensor's errors on top of the one it isolates: its first rest lasts
    ``initial_rest`` s (a rest of that length is put first when it starts moving), and ``errors``
    (:class:`~fusionkit.sim.SensorErrors` field -> value) switches on further errors. The
    scenario's own error wins where both set a field, so the scenario keeps what it tests. What
    a held-out, physics-randomised comparison draws its recordings from
    (``benchmarks/generalisation.py``); ``meta["perturbed"]`` records the additions."""
    if initial_rest is not None and not (math.isfinite(initial_rest) and initial_rest > 0):
        raise InputError(f"initial_rest must be > 0 s, got {initial_rest}")
    token = _PERTURB.set((initial_rest, dict(errors or {})))
    try:
        rec = scenario(name, **params)
    finally:
        _PERTURB.reset(token)
    rec.meta["perturbed"] = {"initial_rest": initial_rest, "errors": dict(errors or {})}
    return rec


def scenario(name: str, **params) -> Recording:
    """The scenario ``name`` (a key of ``SCENARIOS``) with ``params`` overriding its defaults."""
    if name not in SCENARIOS:
        raise InputError(f"unknown scenario {name!r}; choose from {sorted(SCENARIOS)}")
    return SCENARIOS[name](**params)


def load_sim(name: str) -> Recording:
    """The built-in recording ``name`` that ``sim:NAME`` names (:func:`fusionkit.load`, every
    ``fusionkit`` command): a scenario of :data:`SCENARIOS` or one of :func:`demo_recordings`."""
    if name in SCENARIOS:
        return scenario(name)
    recs = {r.name: r for r in demo_recordings()}
    if name not in recs:
        raise InputError(f"unknown simulated recording {name!r}; choose from {sorted(recs) + sorted(SCENARIOS)}")
    return recs[name]
