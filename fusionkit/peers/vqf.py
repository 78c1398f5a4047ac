"""VQF (C++, the ``vqf`` package) as fusionkit filters: ``vqf``, ``vqf-offline``, ``vqf-basic``."""

from __future__ import annotations

import copy
from typing import ClassVar

from ..config import param
from ..errors import PluginError
from ._base import PeerConfig, PeerFilter, _c


class VqfConfig(PeerConfig):
    tau_acc: float = param(3.0, unit="s", description="VQF tauAcc: accelerometer low-pass time constant", gt=0)
    tau_mag: float = param(9.0, unit="s", description="VQF tauMag: magnetometer time constant", gt=0)
    motion_bias_est: bool = param(True, unit="-", description="VQF motionBiasEstEnabled")
    rest_bias_est: bool = param(True, unit="-", description="VQF restBiasEstEnabled")
    mag_dist_rejection: bool = param(True, unit="-", description="VQF magDistRejectionEnabled")


def _vqf_params(c) -> dict:
    return {"tauAcc": c.tau_acc, "tauMag": c.tau_mag, "motionBiasEstEnabled": c.motion_bias_est,
            "restBiasEstEnabled": c.rest_bias_est, "magDistRejectionEnabled": c.mag_dist_rejection}


class VqfFilter(PeerFilter):
    """VQF (Laidig and Seel, Information Fusion 2023, doi:10.1016/j.inffus.2022.10.014), C++ online."""
    fixed_rate: ClassVar[bool] = True  #: one fixed sample time (the library's)

    name: ClassVar[str] = "vqf"
    package: ClassVar[str] = "vqf"
    Config = VqfConfig
    source: ClassVar[str] = "peer: vqf (doi:10.1016/j.inffus.2022.10.014)"
    summary: ClassVar[str] = "peer: VQF online (C++), rest and motion bias estimation, magnetic rejection"

    def _make(self, rate):
        return self.peer().VQF(1.0 / rate, **_vqf_params(self.config))

    def _batch(self, obj, gyr, acc, mag, rate):
        out = obj["vqf"].updateBatch(_c(gyr), _c(acc), None if mag is None else _c(mag))
        return out["quat9D" if mag is not None else "quat6D"]

    def _new(self, rate, use_mag):
        return {"vqf": self._make(rate), "mag": use_mag}

    def _save(self, obj):
        return copy.deepcopy(obj["vqf"].state)  # VQF's whole state, a dict of lists and numbers

    def _load(self, saved, rate, use_mag):
        v = self._make(rate)
        v.state = copy.deepcopy(saved)
        return {"vqf": v, "mag": use_mag}

    def _step(self, obj, g, a, m, dt):
        v = obj["vqf"]
        v.updateGyr(_c(g))  # VQF.update is these three: a missing sensor is left out
        if a is not None:
            v.updateAcc(_c(a))
        if m is not None:
            v.updateMag(_c(m))
        return v.getQuat9D() if obj["mag"] else v.getQuat6D()


class VqfOffline(VqfFilter):
    name: ClassVar[str] = "vqf-offline"
    streaming: ClassVar[bool] = False
    acausal: ClassVar[bool] = True  #: it uses later samples: already offline (fusionkit.offline.supports_offline)
    summary: ClassVar[str] = "peer: VQF offline (acausal, uses future samples)"

    def _batch(self, obj, gyr, acc, mag, rate):
        out = self.peer().offlineVQF(_c(gyr), _c(acc), None if mag is None else _c(mag), 1.0 / rate,
                                     _vqf_params(self.config))
        return out["quat9D" if mag is not None else "quat6D"]

    def _new(self, rate, use_mag):
        raise PluginError(f"{self.name} is an offline filter: it cannot skip samples or stream; clean the data")


class VqfBasicConfig(PeerConfig):
    tau_acc: float = param(3.0, unit="s", description="BasicVQF tauAcc", gt=0)
    tau_mag: float = param(9.0, unit="s", description="BasicVQF tauMag", gt=0)


class VqfBasic(VqfFilter):
    name: ClassVar[str] = "vqf-basic"
    Config = VqfBasicConfig
    summary: ClassVar[str] = "peer: BasicVQF (no bias estimation, no magnetic rejection)"

    def _make(self, rate):
        return self.peer().BasicVQF(1.0 / rate, tauAcc=self.config.tau_acc, tauMag=self.config.tau_mag)
