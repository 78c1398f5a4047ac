"""Rest detector: the motion detector's question asked the other way round ("is it still?").

Both sensors are low-passed (first order, ``tau``); the sensor is at rest when, for at least
``min_time`` s without a break, every sample stays within ``gyr_threshold`` of the low-passed
gyroscope and within ``acc_threshold`` of the low-passed accelerometer, and the low-passed
gyroscope itself is below ``max_rate`` on each axis (the largest gyro bias to expect, an offset each
axis has of its own, as VQF's ``biasClip``: a slow, steady rotation is otherwise "quiet" too; on the
norm until stop 30, where a gyro 1 deg/s off on each axis, 1.7 as a norm, showed no rest). While at
rest, the low-passed gyroscope output is the gyro bias (the ``rest-bias-lowpass`` corrector keeps the
same low-pass and learns the bias from it).

Deviations from a low-pass rather than absolute levels: a gyro bias or a tilted accelerometer
must not look like motion. Criterion bit 0 (``rest``) fires on rest samples; the pipeline sets
``Flag.REST``.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import Detector, DetectorKernel, Sample
from ..types import Flag

__all__ = ["RestDetector", "RestConfig", "rest_step", "REST_SIZE"]

# state: low-passed gyr (3), low-passed acc (3), seconds quiet, samples seen, and the low-pass
# coefficient for the last dt (dt, k: an exponential per distinct interval, not per sample)
_LW, _LA, _QUIET, _SEEN, _DT, _K = 0, 3, 6, 7, 8, 9
REST_SIZE = 10


class RestConfig(PluginConfig):
    tau: float = param(0.5, unit="s", description="time constant of the low-pass the samples are compared with", gt=0)
    gyr_threshold: float = param(
        math.radians(2.0), unit="rad/s", description="largest |gyr - lowpass(gyr)| at rest", gt=0)
    acc_threshold: float = param(0.5, unit="m/s^2", description="largest |acc - lowpass(acc)| at rest", gt=0)
    max_rate: float = param(
        math.radians(2.0), unit="rad/s", description="largest lowpass(gyr) at rest on each axis (the largest gyro "
        "bias expected; per axis since stop 30, on the norm before, unlike the alignment's max_rate, still a norm)",
        gt=0)
    min_time: float = param(1.5, unit="s", description="quiet this long before rest is declared", ge=0)


@njit
def rest_step(s, g0, g1, g2, a0, a1, a2, dt, tau, gyr_th, acc_th, max_rate, min_time):
    """One sample of the rest detector (state ``s``, layout above); returns 1 at rest, else 0.
    The detector's kernel."""
    if s[_SEEN] == 0.0:
        s[_LW], s[_LW + 1], s[_LW + 2] = g0, g1, g2
        s[_LA], s[_LA + 1], s[_LA + 2] = a0, a1, a2
    s[_SEEN] += 1.0
    if s[_DT] != dt:
        s[_DT], s[_K] = dt, 1.0 - math.exp(-dt / tau)
    k = s[_K]
    s[_LW] += k * (g0 - s[_LW])
    s[_LW + 1] += k * (g1 - s[_LW + 1])
    s[_LW + 2] += k * (g2 - s[_LW + 2])
    s[_LA] += k * (a0 - s[_LA])
    s[_LA + 1] += k * (a1 - s[_LA + 1])
    s[_LA + 2] += k * (a2 - s[_LA + 2])
    # the norms against the thresholds as their squares: no square root per sample
    dw2 = (g0 - s[_LW]) ** 2 + (g1 - s[_LW + 1]) ** 2 + (g2 - s[_LW + 2]) ** 2
    da2 = (a0 - s[_LA]) ** 2 + (a1 - s[_LA + 1]) ** 2 + (a2 - s[_LA + 2]) ** 2
    if dw2 < gyr_th * gyr_th and da2 < acc_th * acc_th and abs(s[_LW]) < max_rate and abs(s[_LW + 1]) < max_rate \
            and abs(s[_LW + 2]) < max_rate:
        s[_QUIET] += dt
    else:
        s[_QUIET] = 0.0
    return 1 if s[_QUIET] >= min_time else 0


@njit
def _rest_kernel(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p):
    return rest_step(s, g0, g1, g2, a0, a1, a2, dt, p[0], p[1], p[2], p[3], p[4])


class RestDetector(Detector):
    """Fires while the sensor is still (gyro and accelerometer quiet around their low-pass)."""

    name: ClassVar[str] = "rest"
    Config = RestConfig
    flag: ClassVar[Flag] = Flag.REST
    criteria_names: ClassVar[tuple[str, ...]] = ("rest",)
    source: ClassVar[str] = "fusionkit (source 000's motion criteria in reverse)"
    summary: ClassVar[str] = "rest: gyro and accelerometer quiet around their low-pass for min_time"

    def initial_state(self, dt: float) -> np.ndarray:
        return np.zeros(REST_SIZE)

    def params(self) -> tuple[float, float, float, float, float]:
        c = self.config
        return c.tau, c.gyr_threshold, c.acc_threshold, c.max_rate, c.min_time

    def step(self, state: np.ndarray, sample: Sample) -> int:
        """The readable form of :func:`rest_step` (same arithmetic, numpy vectors)."""
        tau, gyr_th, acc_th, max_rate, min_time = self.params()
        g, a = sample.gyr, sample.acc
        lw, la = state[_LW:_LW + 3], state[_LA:_LA + 3]
        if state[_SEEN] == 0.0:
            lw[:], la[:] = g, a
        state[_SEEN] += 1.0
        if state[_DT] != sample.dt:
            state[_DT], state[_K] = sample.dt, 1.0 - math.exp(-sample.dt / tau)
        k = state[_K]
        lw += k * (g - lw)
        la += k * (a - la)
        quiet = (np.sum((g - lw) ** 2) < gyr_th * gyr_th and np.sum((a - la) ** 2) < acc_th * acc_th
                 and float(np.abs(lw).max()) < max_rate)  # (the deviations' norms' squares: no square root)
        state[_QUIET] = state[_QUIET] + sample.dt if quiet else 0.0
        return 1 if state[_QUIET] >= min_time else 0

    def kernel(self) -> DetectorKernel:
        return DetectorKernel(_rest_kernel, np.array(self.params()))

    @staticmethod
    def lowpassed_gyr(state: np.ndarray) -> np.ndarray:
        """The low-passed gyroscope output (the bias estimate while at rest)."""
        return state[_LW:_LW + 3]
