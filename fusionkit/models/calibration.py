"""A fixed sensor calibration, as a pipeline sensor model (``models: ["calibration"]``).

What a calibration procedure (a turntable, a six-position test, a magnetometer figure-eight)
gives is a set of constants per sensor. This model applies them to every sample before anything
else reads it:

- gyroscope: ``w = S_g^-1 (w_raw - b_g)``;
- accelerometer: ``a = S_a^-1 (a_raw - b_a)``;
- magnetometer: ``m = W (m_raw - h)``, the hard-iron offset ``h`` (a body-fixed field: a magnet,
  a magnetised part carried with the sensor) and the soft-iron matrix ``W`` (the inverse of the
  distortion a ferrous part carried with the sensor applies).

``S`` are the scale-factor/misalignment matrices (identity: none). The magnetometer's unit is
whatever the recording's is (``h`` in the same unit). Nothing is estimated: an online estimate is
a different model with its own state. A sensor missing from the sample (no magnetometer, an
invalid sample) passes through untouched. The readable reference is
:meth:`CalibrationModel.apply`; :func:`calibration_apply` is its kernel.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import field_validator

from .._numba import njit
from ..config import PluginConfig, param
from ..errors import ConfigError
from ..protocols import Sample, SensorModel, SensorModelKernel

__all__ = ["CalibrationConfig", "CalibrationModel", "calibration_apply"]

_I3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


class CalibrationConfig(PluginConfig):
    gyr_bias: list[float] = param([0.0, 0.0, 0.0], unit="rad/s", description="gyroscope bias b_g (subtracted)")
    gyr_scale: list[list[float]] = param(
        _I3, unit="-", description="gyroscope scale factor and misalignment S_g (w_raw = S_g w + b_g)")
    acc_bias: list[float] = param([0.0, 0.0, 0.0], unit="m/s^2", description="accelerometer bias b_a (subtracted)")
    acc_scale: list[list[float]] = param(
        _I3, unit="-", description="accelerometer scale factor and misalignment S_a (a_raw = S_a a + b_a)")
    hard_iron: list[float] = param(
        [0.0, 0.0, 0.0], unit="mag unit", description="magnetometer hard-iron offset h (a body-fixed field, subtracted)")
    soft_iron: list[list[float]] = param(
        _I3, unit="-", description="magnetometer soft-iron correction W (m = W (m_raw - h))")

    @field_validator("gyr_bias", "acc_bias", "hard_iron")
    @classmethod
    def _vec(cls, v):
        if len(v) != 3 or not all(np.isfinite(v)):
            raise ValueError(f"must be 3 finite numbers, got {v}")
        return v

    @field_validator("gyr_scale", "acc_scale", "soft_iron")
    @classmethod
    def _mat(cls, v):
        m = np.asarray(v, dtype=float)
        if m.shape != (3, 3) or not np.isfinite(m).all():
            raise ValueError(f"must be a finite 3x3 matrix, got shape {m.shape}")
        if abs(np.linalg.det(m)) < 1e-6:
            raise ValueError("must be invertible (its determinant is ~0)")
        return v


class CalibrationModel(SensorModel):
    """Fixed biases, scale factors and hard/soft iron applied to every sample."""

    name: ClassVar[str] = "calibration"
    Config = CalibrationConfig
    source: ClassVar[str] = "fusionkit (the standard sensor error model, applied with known constants)"
    summary: ClassVar[str] = "a fixed calibration: gyro/acc bias and scale, magnetometer hard and soft iron"

    def __init__(self, config=None, **params) -> None:
        super().__init__(config, **params)
        c = self.config
        try:
            self._mats = (np.linalg.inv(np.asarray(c.gyr_scale, float)), np.linalg.inv(np.asarray(c.acc_scale, float)),
                          np.asarray(c.soft_iron, float))
        except np.linalg.LinAlgError as exc:  # pragma: no cover - the validators refuse singular matrices
            raise ConfigError(f"calibration: {exc}") from None

    def apply(self, state: np.ndarray, sample: Sample, quat: np.ndarray) -> tuple[Sample, int]:
        c = self.config
        g_inv, a_inv, w = self._mats
        gyr = _affine_ref(g_inv, c.gyr_bias, sample.gyr)
        acc = None if sample.acc is None else _affine_ref(a_inv, c.acc_bias, sample.acc)
        mag = None if sample.mag is None else _affine_ref(w, c.hard_iron, sample.mag)
        return sample._replace(gyr=gyr, acc=acc, mag=mag), 0

    def report(self, state: np.ndarray) -> dict:
        """The constants it applies (``Result.diagnostics["models"]["calibration"]``; nothing is
        estimated, so the same at every sample), in the body axes of the recording:
        ``gyr_bias_rad_s`` (3,) and ``gyr_scale`` (3, 3) ``S_g``; ``acc_bias_m_s2`` and ``acc_scale``
        ``S_a``; ``hard_iron`` (3,, the magnetometer's unit) and ``soft_iron`` (3, 3) ``W``; ``applied``
        True. Reported so that every model of a pipeline says what it did to the samples."""
        c = self.config
        return {"gyr_bias_rad_s": np.array(c.gyr_bias, dtype=float), "gyr_scale": np.array(c.gyr_scale, dtype=float),
                "acc_bias_m_s2": np.array(c.acc_bias, dtype=float), "acc_scale": np.array(c.acc_scale, dtype=float),
                "hard_iron": np.array(c.hard_iron, dtype=float), "soft_iron": np.array(c.soft_iron, dtype=float),
                "applied": True}

    def params(self) -> np.ndarray:
        """The kernel's parameters: the three biases, then the three matrices row by row."""
        c = self.config
        g_inv, a_inv, w = self._mats
        return np.concatenate([c.gyr_bias, c.acc_bias, c.hard_iron, g_inv.ravel(), a_inv.ravel(), w.ravel()])

    def kernel(self) -> SensorModelKernel:
        return SensorModelKernel(calibration_apply, self.params())


def _affine_ref(m, b, v) -> np.ndarray:
    """``M (v - b)``, written out in the kernel's order of operations (a filter downstream may
    amplify the last bit; the tests hold the two paths to 1e-9)."""
    x0, x1, x2 = v[0] - b[0], v[1] - b[1], v[2] - b[2]
    return np.array([m[i, 0] * x0 + m[i, 1] * x1 + m[i, 2] * x2 for i in range(3)])


@njit
def _affine(v, o, p, bo, mo):
    """``v[o:o+3] = M (v[o:o+3] - b)`` with ``b = p[bo:bo+3]``, ``M = p[mo:mo+9]`` row by row."""
    x0, x1, x2 = v[o] - p[bo], v[o + 1] - p[bo + 1], v[o + 2] - p[bo + 2]
    for i in range(3):
        v[o + i] = p[mo + 3 * i] * x0 + p[mo + 3 * i + 1] * x1 + p[mo + 3 * i + 2] * x2


@njit
def calibration_apply(s, v, gyr_ok, acc_ok, mag_ok, q, dt, p):
    """Kernel of :class:`CalibrationModel` (``SensorModelKernel.apply``)."""
    if gyr_ok:
        _affine(v, 0, p, 0, 9)
    if acc_ok:
        _affine(v, 3, p, 3, 18)
    if mag_ok:
        _affine(v, 6, p, 6, 27)
    return 0
