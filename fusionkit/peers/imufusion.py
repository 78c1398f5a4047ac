"""x-io Fusion AHRS (the ``imufusion`` package) as the fusionkit filter ``imufusion``."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ..config import param
from ..errors import InputError
from ._base import PeerConfig, PeerFilter, _c


class ImufusionConfig(PeerConfig):
    gain: float = param(0.5, unit="-", description="Fusion AHRS gain (recommended 0.5)", ge=0)
    gyroscope_range: float = param(2000.0, unit="deg/s", description="gyroscope range", gt=0)
    acceleration_rejection: float = param(10.0, unit="deg", description="acceleration rejection threshold", ge=0)
    magnetic_rejection: float = param(10.0, unit="deg", description="magnetic rejection threshold", ge=0)
    rejection_timeout: float = param(5.0, unit="s", description="rejection timeout", gt=0)
    gyro_offset: bool = param(True, unit="-", description="run imufusion's gyroscope offset (Bias) correction")


class ImufusionFilter(PeerFilter):
    """x-io's Fusion AHRS (imufusion) with its recommended settings."""
    fixed_rate: ClassVar[bool] = True  #: one fixed sample time (the library's)

    name: ClassVar[str] = "imufusion"
    package: ClassVar[str] = "imufusion"
    Config = ImufusionConfig
    mag_limits: ClassVar[tuple[float, float]] = (1e-15, 1e15)  # Fusion computes in float32
    copyable: ClassVar[bool] = False  # (see _save)
    source: ClassVar[str] = "peer: imufusion (x-io Technologies Fusion)"
    summary: ClassVar[str] = "peer: Fusion AHRS (imufusion), recommended settings"

    def _new(self, rate, use_mag):
        imf = self.peer()
        c = self.config
        s = imf.AhrsSettings()
        s.convention = imf.CONVENTION_ENU  # a property: the constructor's convention argument is ignored
        s.sample_rate = rate
        s.gain = c.gain
        s.gyroscope_range = c.gyroscope_range
        s.acceleration_rejection = c.acceleration_rejection
        s.magnetic_rejection = c.magnetic_rejection
        s.rejection_timeout = int(round(c.rejection_timeout * rate))
        ahrs = imf.Ahrs()
        ahrs.set_settings(s)
        bias = None
        if c.gyro_offset:
            bias = imf.Bias()
            bs = imf.BiasSettings()
            bs.sample_rate = rate
            bias.set_settings(bs)
        return {"ahrs": ahrs, "bias": bias, "generation": 0}

    def _save(self, obj):
        # imufusion's objects cannot be copied (nor is their whole state exposed): the state holds
        # the live object, and a generation count lets it be continued once only
        obj["generation"] += 1
        return {"obj": obj, "generation": obj["generation"]}

    def _load(self, saved, rate, use_mag):
        obj = saved["obj"]
        if obj["generation"] != saved["generation"]:
            raise InputError(f"{self.name}: this state was already continued; imufusion's objects cannot be "
                             "copied, so each state continues one run only (use the latest run's state)")
        return obj

    def _step(self, obj, g, a, m, dt):
        gd = np.degrees(_c(g))
        if obj["bias"] is not None:
            gd = obj["bias"].update(gd)
        ag = _c(a) / 9.80665 if a is not None else np.zeros(3)  # Fusion ignores a zero accelerometer
        if m is None:
            obj["ahrs"].update_no_magnetometer(gd, ag)
        else:
            obj["ahrs"].update(gd, ag, _c(m))
        return np.array(obj["ahrs"].get_quaternion(), dtype=float)
