"""The simulator's basic sensor errors: white noise and constant biases."""

from __future__ import annotations

from dataclasses import dataclass

from .errors import _nonneg, _vec

__all__ = ["Noise"]


@dataclass(frozen=True)
class Noise:
    """Sensor errors: white noise std per sample and constant biases (SI units)."""

    gyr_noise: float = 0.0
    gyr_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    acc_noise: float = 0.0
    acc_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_noise: float = 0.0

    def __post_init__(self) -> None:  # (a bias of 2 numbers was numpy's broadcast error; a negative noise taken)
        for name in ("gyr_noise", "acc_noise", "mag_noise"):
            object.__setattr__(self, name, _nonneg(f"Noise.{name}", getattr(self, name)))
        for name in ("gyr_bias", "acc_bias"):
            object.__setattr__(self, name, _vec(f"Noise.{name}", getattr(self, name)))

    @classmethod
    def mems(cls) -> "Noise":
        """A consumer MEMS IMU: 0.005 rad/s and 0.03 m/s^2 noise, gyro bias about 0.3 deg/s."""
        return cls(gyr_noise=0.005, gyr_bias=(0.004, -0.006, 0.003), acc_noise=0.03, acc_bias=(0.0, 0.0, 0.0),
                   mag_noise=0.3)
