"""A small IMU simulator for tests, the demo and users without data.

A trajectory is a list of segments run one after the other, each with a smooth (raised-cosine)
profile that starts and ends at rest:

* :class:`Rest` ``(duration)``;
* :class:`Rotate` ``(axis, angle, duration)``: about a fixed *body* axis by ``angle`` rad;
* :class:`Translate` ``(direction, distance, duration)``: along an ENU direction, no rotation.

:func:`simulate` returns a :class:`~fusionkit.types.Recording` with the true orientation
(body->ENU) as ``truth`` and ``movement`` marking the non-rest segments. Gyro sample ``k`` is
the mean rate over ``(t[k-1], t[k]]`` (so integrating it with the exact step reproduces the
truth). Accelerometer and magnetometer sample ``k`` are, by default (``sampling="mean"``), the
means of the specific force ``R^T (a + [0, 0, g])`` and of the field ``R^T m`` over the same
interval, as an IMU that samples all its sensors alike reports them (Gauss-Legendre quadrature,
exact to far below the noise); ``sampling="point"`` gives their values at ``t[k]`` instead.

Sensor errors: :class:`Noise` (white noise, constant biases) and :class:`SensorErrors` (hard and
soft iron, earth-fixed magnetic disturbances, inter-sensor delays and low-pass group delays,
scale factor and misalignment, bias random walks, vibration, taps, dropped samples, timestamp
gaps; every one off by default, :mod:`fusionkit.sim.errors`). :mod:`fusionkit.sim.scenarios`
builds the recording that isolates each error (``scenario(name)``, ``SCENARIOS``).

Modules: ``motion`` (segments), ``sensors`` (:func:`simulate`), ``noise``, ``errors``,
``scenarios``. See ``docs/simulator.md``.
"""

from __future__ import annotations

from . import scenarios
from .errors import FieldPatch, MagneticDipole, SensorErrors, Tap, Vibration, lowpass_delay
from .motion import Rest, Rotate, Translate
from .noise import Noise
from .scenarios import SCENARIOS, demo_recordings, load_sim, scenario
from .sensors import KYIV_FIELD_ENU, simulate

__all__ = ["Rest", "Rotate", "Translate", "Noise", "simulate", "demo_recordings", "KYIV_FIELD_ENU",
           "SensorErrors", "MagneticDipole", "FieldPatch", "Vibration", "Tap", "lowpass_delay", "scenarios",
           "SCENARIOS", "scenario", "load_sim"]
