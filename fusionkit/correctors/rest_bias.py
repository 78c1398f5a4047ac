"""Gyro bias re-estimation at rest, as a pipeline corrector (any estimator, any other correctors).

Source 000 measures the gyro bias once, over the initial alignment. A MEMS gyro's bias moves
with temperature and time, so the state of the art measures it again whenever the sensor is
still: the ``rest`` detector (the motion detector's criteria run in reverse) flags the samples;
on each of them this corrector moves its bias estimate ``b`` towards the gyro output (the
alignment's bias already removed) with time constant ``tau``:

``b += (1 - exp(-dt / tau)) (w - b)`` on REST samples, held otherwise,

and returns the correction rate ``-b`` (``mode = "rate"``: added to the gyroscope on the next
propagation, summed with the other rate correctors). So the estimator integrates
``w - bias_alignment - b``. ``max_bias`` bounds ``|b|`` (a slow steady turn that the rest
detector took for rest cannot teach a bias larger than any the gyro has).

The pipeline refuses this corrector without a detector that sets ``Flag.REST`` (it would never
learn). The ``recommended`` filter does the same inside its own loop (``rest_bias``). The
readable reference is :meth:`RestBiasCorrector.correct`; :func:`rest_bias_correct` is its
kernel (rate mode, any estimator), held to it on every sample by the tests.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import Correction, Corrector, CorrectorKernel
from ..types import Flag

__all__ = ["RestBiasConfig", "RestBiasCorrector", "rest_bias_correct"]

_REST = int(Flag.REST)


class RestBiasConfig(PluginConfig):
    tau: float = param(1.0, unit="s", description="time constant of the bias estimate at rest", gt=0)
    max_bias: float = param(math.radians(5.0), unit="rad/s", description="largest bias it estimates", gt=0)


class RestBiasCorrector(Corrector):
    """At rest (``Flag.REST``), learn the gyro bias; always subtract what was learned."""

    name: ClassVar[str] = "rest-bias"
    Config = RestBiasConfig
    mode: ClassVar[str] = "rate"
    requires_flag: ClassVar[Flag] = Flag.REST
    source: ClassVar[str] = "fusionkit (source 000's bias estimate, repeated at every rest)"
    summary: ClassVar[str] = "re-estimate the gyro bias whenever a rest detector says the sensor is still"

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        return np.zeros(3)

    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        if flags & Flag.REST and np.isfinite(sample.gyr).all():
            state += (1.0 - math.exp(-sample.dt / self.config.tau)) * (sample.gyr - state)
            n = float(np.linalg.norm(state))
            if n > self.config.max_bias:
                state *= self.config.max_bias / n
        return Correction(-state.copy(), 0)

    def kernel(self, estimator) -> CorrectorKernel:
        return CorrectorKernel(rest_bias_correct, np.array([self.config.tau, self.config.max_bias]), mode="rate")


@njit
def rest_bias_correct(q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate):
    """The kernel of :meth:`RestBiasCorrector.correct`: ``s`` the bias, ``p = (tau, max_bias)``."""
    if (flags & _REST) != 0 and math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2):
        k = 1.0 - math.exp(-dt / p[0])
        s[0] += k * (g0 - s[0])
        s[1] += k * (g1 - s[1])
        s[2] += k * (g2 - s[2])
        n = math.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
        if n > p[1]:
            f = p[1] / n
            s[0] *= f
            s[1] *= f
            s[2] *= f
    rate[0] -= s[0]
    rate[1] -= s[1]
    rate[2] -= s[2]
    return 0
