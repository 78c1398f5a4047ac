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
learn). The readable reference is :meth:`RestBiasCorrector.correct`; :func:`rest_bias_correct`
is its kernel (rate mode, any estimator), held to it on every sample by the tests.

``rest-bias-lowpass`` (:class:`RestBiasLowpass`, ``mode = "bias"``) is the same idea as
``recommended`` runs it: on REST samples the pipeline's gyro bias itself (the one the
propagation subtracts, shared with the alignment's and with the bias learned in motion by
``inertial-tilt``) follows the low-passed gyroscope, *before* the sample's propagation:

``bias += (1 - exp(-dt / tau)) (lowpass(w) - bias)``.

``gain="kalman"`` weighs each rest sample by what is known of the bias instead (a scalar Kalman
filter per axis, the same variance ``P`` for all three): the low-passed gyro measures the bias
with the standard deviation ``sigma_rest``; ``P`` starts at ``sigma_init^2`` (a gyro not yet seen
at rest) and grows, up to that, by the process noise ``Q = k^2 sigma_rest^2 / (1 - k)`` per sample
(``k = 1 - exp(-dt / tau)``: the random walk for which the steady-state gain of a long rest is
the fixed gain's). A rest then begins with the gain ``P / (P + sigma_rest^2)`` (about 1 for a bias
never measured: the low-pass has settled over the detector's ``min_time``), which falls as the
running mean's ``1 / n`` to the fixed gain within ``tau``: a short rest teaches a turn-on bias,
and a rest after a long motion weighs its first samples by how far the bias can have wandered.
It is VQF's rest update (``vqf.cpp``: the low-passed gyro against the bias, weighed by ``biasP``;
with the bias in motion off, a scalar ``P`` and ``k = P / (P + biasRestW)``), with the process noise
taken from ``tau``. ``gain="fixed"``: the low-pass above (the behaviour before).

The low-pass (time constant ``lowpass_tau``, the ``rest`` detector's ``tau``) is the one the rest
detector keeps, on the same samples (valid gyr and acc): at rest it is the gyro output without
its noise. ``max_bias`` None: no limit (the low-pass at rest is below the rest detector's
``max_rate`` anyway).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import BiasCorrector, Correction, Corrector, CorrectorKernel
from ..types import Flag
from ._factor import gyro_lowpass, k_clamp3, k_gyro_lowpass

__all__ = ["RestBiasConfig", "RestBiasCorrector", "rest_bias_correct", "RestBiasLowpassConfig", "RestBiasLowpass",
           "rest_bias_lowpass_kernel"]

_REST = int(Flag.REST)
_ACC_REJECTED = int(Flag.ACC_REJECTED)


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
        k_clamp3(s, p[1])
    rate[0] -= s[0]
    rate[1] -= s[1]
    rate[2] -= s[2]
    return 0


class RestBiasLowpassConfig(PluginConfig):
    tau: float = param(1.0, unit="s", description="time constant of the bias at rest", gt=0)
    lowpass_tau: float = param(0.5, unit="s", description="time constant of the gyro low-pass it learns from (the "
                               "rest detector's tau)", gt=0)
    max_bias: float | None = param(None, unit="rad/s", description="largest bias it leaves; None: no limit", gt=0)
    gain: Literal["fixed", "kalman"] = param(
        "fixed", unit="-", description="fixed: the bias follows the low-passed gyro with time constant tau; kalman: "
        "each rest sample weighed by the bias's variance (a short rest learns a bias never measured at once; the "
        "same time constant tau once the rest is long)")
    sigma_init: float = param(math.radians(0.5), unit="rad/s", description="kalman: the standard deviation of a "
                              "bias not yet measured (a MEMS gyro's turn-on bias), the most the variance grows to",
                              gt=0)
    sigma_rest: float = param(math.radians(0.03), unit="rad/s", description="kalman: the standard deviation with "
                              "which one sample of the low-passed gyro at rest measures the bias", gt=0)


# state: the low-passed gyro, its sample count, the coefficients for the last dt (the fixed gain, the
# low-pass's, the Kalman filter's process noise), the bias's variance (kalman)
_LW, _SEEN, _DT, _KB, _KL, _Q, _P = 0, 3, 4, 5, 6, 7, 8


@njit(inline="always")
def _process_noise(kb: float, var_rest: float, var_init: float) -> float:
    """The Kalman gain's process noise per step, ``kb^2 var_rest / (1 - kb)`` (the fixed gain ``kb``
    in a long rest), at most ``var_init``: an interval many times ``tau`` long (``max_gap=None``
    across a 100 s gap) makes ``1 - kb`` zero (the compiled loop raised ZeroDivisionError, the
    reference ran on with an infinite variance); the bias is then as unknown as at turn-on."""
    d = 1.0 - kb
    return kb ** 2 * var_rest / d if kb ** 2 * var_rest < var_init * d else var_init


_process_noise_ref = getattr(_process_noise, "py_func", _process_noise)  # (the reference path: no compile)


class RestBiasLowpass(BiasCorrector):
    """At rest (``Flag.REST``), the pipeline's gyro bias follows the low-passed gyro, before the propagation."""

    name: ClassVar[str] = "rest-bias-lowpass"
    Config = RestBiasLowpassConfig
    requires_flag: ClassVar[Flag] = Flag.REST
    source: ClassVar[str] = "fusionkit (source 000's bias estimate, repeated at every rest)"
    summary: ClassVar[str] = "at rest, the gyro bias follows the low-passed gyro (before the propagation)"

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        s = np.zeros(9)
        s[_P] = self.config.sigma_init ** 2
        return s

    def update_bias(self, state, bias, sample, flags) -> int:
        c, s, dt = self.config, state, sample.dt
        if s[_DT] != dt:  # the coefficients, once per distinct dt
            s[_DT], s[_KB], s[_KL] = dt, 1.0 - math.exp(-dt / c.tau), 1.0 - math.exp(-dt / c.lowpass_tau)
            s[_Q] = _process_noise_ref(s[_KB], c.sigma_rest ** 2, c.sigma_init ** 2)
        kalman = c.gain == "kalman"
        if kalman and s[_P] < c.sigma_init ** 2:  # the bias wanders (VQF's P += V below the initial P)
            s[_P] += s[_Q]
        g = sample.gyr
        if np.isfinite(g).all() and (sample.acc is not None or flags & _ACC_REJECTED):  # the rest detector's samples
            gyro_lowpass(s, _LW, _SEEN, g, s[_KL])
            if flags & _REST:
                k = s[_KB]
                if kalman:  # the Kalman gain, and the variance the measurement leaves
                    k = s[_P] / (s[_P] + c.sigma_rest ** 2)
                    s[_P] -= k * s[_P]
                bias += k * (s[_LW:_LW + 3] - bias)
                n = float(np.linalg.norm(bias))
                if c.max_bias is not None and n > c.max_bias:
                    bias *= c.max_bias / n
        return 0

    def kernel(self, estimator) -> CorrectorKernel:
        c = self.config
        p = np.array([c.tau, c.lowpass_tau, c.max_bias if c.max_bias is not None else math.inf,
                      float(c.gain == "kalman"), c.sigma_init ** 2, c.sigma_rest ** 2])
        return CorrectorKernel(rest_bias_lowpass_kernel, p, mode="bias")


@njit(inline="always")
def rest_bias_lowpass_kernel(s, b, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p):
    """The kernel of :meth:`RestBiasLowpass.update_bias`: ``p = (tau, lowpass_tau, max_bias (inf: none),
    kalman (1) or fixed (0), sigma_init^2, sigma_rest^2)``."""
    if s[_DT] != dt:
        s[_DT], s[_KB], s[_KL] = dt, 1.0 - math.exp(-dt / p[0]), 1.0 - math.exp(-dt / p[1])
        s[_Q] = _process_noise(s[_KB], p[5], p[4])
    kalman = p[3] != 0.0
    if kalman and s[_P] < p[4]:
        s[_P] += s[_Q]
    if math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2) and (acc_ok or (flags & _ACC_REJECTED) != 0):
        k_gyro_lowpass(s, _LW, _SEEN, g0, g1, g2, s[_KL])
        if (flags & _REST) != 0:
            k = s[_KB]
            if kalman:
                k = s[_P] / (s[_P] + p[5])
                s[_P] -= k * s[_P]
            b[0] += k * (s[_LW] - b[0])
            b[1] += k * (s[_LW + 1] - b[1])
            b[2] += k * (s[_LW + 2] - b[2])
            k_clamp3(b, p[2])
    return 0
