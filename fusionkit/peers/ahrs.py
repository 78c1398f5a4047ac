"""The ``ahrs`` package's Madgwick, Mahony and EKF filters as fusionkit filters."""

from __future__ import annotations

import importlib
from typing import ClassVar

import numpy as np

from ..config import param
from ..rotations import quat_from_rotvec, quat_mul, quat_normalize
from ._base import PeerConfig, PeerFilter, _c


class MadgwickConfig(PeerConfig):
    gain: float | None = param(None, unit="-", description="Madgwick beta (None: ahrs' default)", gt=0)


class AhrsMadgwick(PeerFilter):
    name: ClassVar[str] = "ahrs-madgwick"
    package: ClassVar[str] = "ahrs"
    peer_frame: ClassVar[str] = "NWU"
    Config = MadgwickConfig
    source: ClassVar[str] = "peer: ahrs.filters.Madgwick"
    summary: ClassVar[str] = "peer: Madgwick gradient-descent filter (ahrs package)"

    def _kwargs(self) -> dict:
        return {} if self.config.gain is None else {"gain": self.config.gain}

    def _cls(self):
        return importlib.import_module("ahrs.filters").Madgwick

    def _new(self, rate, use_mag):
        return {"f": None, "q": None, "rate": rate, "mag": use_mag}

    def _first(self, obj, g, a, m):
        """The peer's batch run on this one sample: its own initial quaternion, and the object
        to update from then on (ahrs picks defaults, e.g. Madgwick's gain, from the data given)."""
        kw = {"gyr": g[None], "acc": a[None], "frequency": obj["rate"], **self._kwargs()}
        if m is not None:
            kw["mag"] = m[None]
        obj["f"] = self._cls()(**kw)
        return obj["f"].Q[0]

    def _gyro_only(self, obj, g, dt):
        """The sample without its accelerometer: the gyro integrated (before the first
        accelerometer sample starts the peer, from identity)."""
        key = "q" if obj["q"] is not None else "pre"
        q = obj.get(key)
        q = np.array([1.0, 0.0, 0.0, 0.0]) if q is None else np.asarray(q, dtype=float)
        obj[key] = quat_normalize(quat_mul(q, quat_from_rotvec(_c(g) * dt)))
        return obj[key]

    def _step(self, obj, g, a, m, dt):
        if a is None:
            return self._gyro_only(obj, g, dt)
        g, a = _c(g), _c(a)
        m = None if m is None else _c(m)
        if obj["q"] is None:
            obj["q"] = self._first(obj, g, a, m)
        elif m is None:
            obj["q"] = obj["f"].updateIMU(obj["q"], g, a)
        else:
            obj["q"] = obj["f"].updateMARG(obj["q"], g, a, m)
        return np.asarray(obj["q"], dtype=float)


class MahonyConfig(PeerConfig):
    k_p: float = param(1.0, unit="-", description="Mahony proportional gain", ge=0)
    k_i: float = param(0.3, unit="-", description="Mahony integral gain", ge=0)


class AhrsMahony(AhrsMadgwick):
    name: ClassVar[str] = "ahrs-mahony"
    peer_frame: ClassVar[str] = "ENU"
    Config = MahonyConfig
    source: ClassVar[str] = "peer: ahrs.filters.Mahony"
    summary: ClassVar[str] = "peer: Mahony complementary filter (ahrs package)"

    def _kwargs(self):
        return {"k_P": self.config.k_p, "k_I": self.config.k_i}

    def _cls(self):
        return importlib.import_module("ahrs.filters").Mahony


class AhrsEkf(AhrsMadgwick):
    name: ClassVar[str] = "ahrs-ekf"
    peer_frame: ClassVar[str] = "NED"
    Config = PeerConfig
    source: ClassVar[str] = "peer: ahrs.filters.EKF"
    summary: ClassVar[str] = "peer: quaternion EKF (ahrs package), frame NED"

    def _kwargs(self):
        return {"frame": "NED"}

    def _cls(self):
        return importlib.import_module("ahrs.filters").EKF

    def _step(self, obj, g, a, m, dt):
        if a is None or (obj["mag"] and m is None):  # its measurement model is fixed at 9D once started with mag
            return self._gyro_only(obj, g, dt)
        # ahrs' EKF in frame NED models the accelerometer as the gravity vector: negate specific force
        g, a = _c(g), -_c(a)
        m = None if m is None else _c(m)
        if obj["q"] is None:
            obj["q"] = self._first(obj, g, a, m)
        else:
            obj["q"] = obj["f"].update(obj["q"], g, a, m) if m is not None else obj["f"].update(obj["q"], g, a)
        return np.asarray(obj["q"], dtype=float)
