"""Acceleration disturbance detector: is the accelerometer reading gravity alone?

An accelerometer at rest or in steady motion reads gravity (norm ``gravity``); a linear
acceleration changes its norm. The detector calls a sample **disturbed** when
``| |a| - gravity | > threshold`` (criterion bit 0, ``norm``) and keeps calling the next ``hold``
s disturbed too (bit 1, ``hold``): the low-passes of the correctors carry a disturbance for a
while after it ends. A nonzero mask sets ``Flag.ACC_REJECTED``, and a pipeline then withholds
that sample's accelerometer from its correctors (the gyroscope carries the attitude through).

Recovery: rejection cannot last. A constant acceleration (a car accelerating, a centrifuge), a
wrong ``gravity`` or motion that is disturbed most of the time would otherwise switch the
accelerometer off for good and let the gyro drift unbounded (worse: the few samples let through
are a biased choice). The detector keeps a budget ``b`` (s): ``b += dt`` on a disturbed sample,
``b -= dt f / (1 - f)`` on a quiet one (``f = max_fraction``; ``b`` stays within
``[0, max_time + dt]``), so ``b`` grows only while more than that fraction of the samples is
disturbed. When ``b`` exceeds ``max_time`` the detector **recovers**: it stops firing (the
accelerometer is used on every sample) until ``b`` has drained back to 0, ``max_time (1 - f) / f``
s after the disturbance ends.

This is the right tool for correctors that pull towards each sample (gradient descent,
complementary filters). It is the wrong one for a low-pass of the specific force in an
inertial frame (``recommended``'s inclination): there, linear accelerations average out *only*
if all of them are kept, and rejecting the large ones biases the average (BENCHMARKS.md).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import Detector, DetectorKernel, Sample
from ..types import Flag

__all__ = ["ACCEL_SIZE", "AccelerationConfig", "AccelerationDetector", "acceleration_step"]

# state: seconds since the norm test last fired (inf before it ever did), the rejection budget (s),
# recovering (1) or not (0)
_SINCE, _BUDGET, _RECOVER = 0, 1, 2
ACCEL_SIZE = 3
_NORM, _HOLD = 1, 2  # criteria bits


class AccelerationConfig(PluginConfig):
    gravity: float = param(9.81, unit="m/s^2", description="the norm the accelerometer reads without acceleration",
                           gt=0)
    threshold: float = param(2.0, unit="m/s^2", description="disturbed when | |a| - gravity | exceeds this", gt=0)
    hold: float = param(0.1, unit="s", description="samples this long after a disturbed one are disturbed too",
                        ge=0)
    max_time: float = param(
        2.0, unit="s", description="rejection budget: net seconds rejected before the detector recovers", gt=0)
    max_fraction: float = param(
        0.5, unit="-", description="the budget grows only while more than this fraction of samples is disturbed",
        gt=0, lt=1)


@njit
def acceleration_step(s, a0, a1, a2, dt, gravity, threshold, hold, max_time, max_fraction):
    """One sample (state ``s``); returns the criteria mask (bit 0 norm, bit 1 hold)."""
    norm = abs(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) - gravity) > threshold
    s[_SINCE] = 0.0 if norm else s[_SINCE] + dt
    crit = _NORM if norm else (_HOLD if s[_SINCE] - 0.5 * dt <= hold else 0)
    if crit != 0:
        s[_BUDGET] = min(s[_BUDGET] + dt, max_time + dt)
    else:
        s[_BUDGET] = max(0.0, s[_BUDGET] - dt * max_fraction / (1.0 - max_fraction))
    if s[_BUDGET] > max_time + 0.5 * dt:  # margin: a sum of dts
        s[_RECOVER] = 1.0
    elif s[_BUDGET] == 0.0:
        s[_RECOVER] = 0.0
    return 0 if s[_RECOVER] != 0.0 else crit


@njit
def _acceleration_kernel(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p):
    return acceleration_step(s, a0, a1, a2, dt, p[0], p[1], p[2], p[3], p[4])


class AccelerationDetector(Detector):
    """Fires while the accelerometer's norm is off gravity (and ``hold`` s after); recovers (stops
    firing) when its rejection budget runs out."""

    name: ClassVar[str] = "acceleration"
    Config = AccelerationConfig
    flag: ClassVar[Flag] = Flag.ACC_REJECTED
    criteria_names: ClassVar[tuple[str, ...]] = ("norm", "hold")
    source: ClassVar[str] = "fusionkit (acceleration rejection, as in the state of the art)"
    summary: ClassVar[str] = "acceleration rejection: | |a| - g | above a threshold, with hold and a recovery timeout"

    def initial_state(self, dt: float) -> np.ndarray:
        s = np.zeros(ACCEL_SIZE)
        s[_SINCE] = math.inf
        return s

    def params(self) -> tuple[float, float, float, float, float]:
        c = self.config
        return c.gravity, c.threshold, c.hold, c.max_time, c.max_fraction

    def step(self, state: np.ndarray, sample: Sample) -> int:
        """The readable form of :func:`acceleration_step`."""
        gravity, threshold, hold, max_time, max_fraction = self.params()
        dt = sample.dt
        norm = abs(float(np.linalg.norm(sample.acc)) - gravity) > threshold
        state[_SINCE] = 0.0 if norm else state[_SINCE] + dt
        if norm:
            crit = _NORM
        elif state[_SINCE] - 0.5 * dt <= hold:  # half a sample of margin: a sum of dts
            crit = _HOLD
        else:
            crit = 0
        if crit:  # the budget: grows while more than max_fraction of the samples is disturbed
            state[_BUDGET] = min(state[_BUDGET] + dt, max_time + dt)  # capped: recovery ends soon after
        else:
            state[_BUDGET] = max(0.0, state[_BUDGET] - dt * max_fraction / (1.0 - max_fraction))
        if state[_BUDGET] > max_time + 0.5 * dt:  # margin: a sum of dts
            state[_RECOVER] = 1.0  # recovering: the accelerometer is used until the budget drains
        elif state[_BUDGET] == 0.0:
            state[_RECOVER] = 0.0
        return 0 if state[_RECOVER] else crit

    def kernel(self) -> DetectorKernel:
        return DetectorKernel(_acceleration_kernel, np.array(self.params()))
