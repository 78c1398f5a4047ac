"""Other libraries' filters as fusionkit plugins, for side-by-side comparison.

Installed with the ``peers`` extra (``pip install "fusionkit[peers]"``) and registered through
entry points in fusionkit's ``pyproject.toml`` exactly as a third party would register them.
Each adapter maps the peer's units and frames to fusionkit's (verified against the BROAD
reference and, in ``tests/test_peers.py``, against calling the peer directly):

=================  ==========================  ==============================================
name               peer                        conventions mapped
=================  ==========================  ==============================================
``vqf``            ``vqf.VQF`` (C++, online)   rad/s, m/s^2; quaternion body->ENU
``vqf-offline``    ``vqf.offlineVQF``          same; batch only (uses future samples)
``vqf-basic``      ``vqf.BasicVQF``            same
``imufusion``      ``imufusion.Ahrs``          deg/s, g; convention set as a *property*
                                               (the ``AhrsSettings`` constructor ignores it)
``ahrs-madgwick``  ``ahrs.filters.Madgwick``   rad/s, m/s^2; body->NWU
``ahrs-mahony``    ``ahrs.filters.Mahony``     rad/s, m/s^2; body->ENU
``ahrs-ekf``       ``ahrs.filters.EKF``        frame 'NED' takes the gravity vector: acc is
                                               negated; body->NED
=================  ==========================  ==============================================

A peer sees only valid samples, judged as every fusionkit filter judges them
(:func:`fusionkit.types.sample_validity`, with ``gyr_range`` / ``acc_range``): with
``nan_policy="skip"`` a sample with an invalid gyroscope is not passed to it and the previous
orientation is held; an invalid or saturated accelerometer, or an invalid magnetometer, is left
out of that sample only (VQF's separate updates; imufusion's zero vector, which it ignores; a
gyro-only step for the ahrs filters), so the integration goes on. Timestamp gaps are held
(Flag.GAP). The offline VQF, which cannot skip, gets the last fully valid sample repeated instead.
"""

from __future__ import annotations

import copy
import importlib
from typing import Any, ClassVar, Literal

import numpy as np

from ..config import FilterConfig, param
from ..conventions import change_frame
from ..errors import InputError, PluginError
from ..protocols import Filter
from .._kernels import validity_all
from ..rotations import quat_from_rotvec, quat_mul, quat_normalize
from ..types import (HUGE, TINY, Flag, Recording, Result, gap_flags, gap_threshold, hold_gaps, mark_gaps,
                     sample_validity, stream_gap)
from ..validation import as_vector, check_finite_all, check_positive, check_sample_finite

__all__ = ["PeerFilter", "VqfFilter", "VqfOffline", "VqfBasic", "ImufusionFilter", "AhrsMadgwick", "AhrsMahony",
           "AhrsEkf"]


_VERSIONS: dict[str, str] = {}


class PeerConfig(FilterConfig):
    mode: Literal["auto", "6D", "9D"] = param(
        "auto", unit="-", description="'auto': 9D when the recording has mag, else 6D; '6D' ignores mag"
    )


class PeerFilter(Filter):
    """Base of the peer adapters: validation, NaN policy, frames, streaming."""

    package: ClassVar[str] = ""
    peer_frame: ClassVar[str] = "ENU"
    streaming: ClassVar[bool] = True
    Config = PeerConfig
    #: the magnetometer magnitudes (largest axis, any unit) the peer's arithmetic squares without
    #: over- or underflow; outside, a sample is MAG_INVALID for it (float32 peers: narrower)
    mag_limits: ClassVar[tuple[float, float]] = (TINY, HUGE)

    def __init__(self, config=None, **params: Any) -> None:
        super().__init__(config, **params)
        self._stream: dict[str, Any] | None = None
        self.last_flags = 0

    def peer(self):
        """The peer's module, or a PluginError saying how to install it."""
        try:
            return importlib.import_module(self.package)
        except ImportError as exc:
            raise PluginError(
                f"filter {self.name!r} needs the {self.package!r} package: pip install 'fusionkit[peers]' ({exc})"
            ) from None

    @classmethod
    def version(cls) -> str:
        """The installed version of the peer package ("missing" when it is not installed); read
        once per package (the metadata lookup costs ~20 ms, paid on every run before)."""
        from importlib import metadata

        if cls.package not in _VERSIONS:
            try:
                _VERSIONS[cls.package] = metadata.version(cls.package)
            except metadata.PackageNotFoundError:
                return "missing"
        return _VERSIONS[cls.package]

    # -- to implement ----------------------------------------------------------------------
    def _batch(self, obj, gyr, acc, mag, rate) -> np.ndarray:
        """Quaternions (peer frame) for finite arrays, continuing the peer object ``obj``; default:
        a loop of the streaming step."""
        return np.array([self._step(obj, gyr[k], acc[k], None if mag is None else mag[k], 1.0 / rate)
                         for k in range(gyr.shape[0])]).reshape(-1, 4)

    def _new(self, rate: float, use_mag: bool):
        raise NotImplementedError

    def _step(self, obj, g, a, m, dt) -> np.ndarray:
        raise NotImplementedError

    def _save(self, obj):
        """A snapshot of the peer object that a later run continues from (default: a deep copy)."""
        return copy.deepcopy(obj)

    def _load(self, saved, rate: float, use_mag: bool):
        """A peer object continuing from :meth:`_save`'s snapshot (default: a deep copy of it)."""
        return copy.deepcopy(saved)

    # -- public ----------------------------------------------------------------------------
    def dimension(self, rec) -> str:
        return "9D" if rec.mag is not None and self.config.mode != "6D" else "6D"

    def _use_mag(self, has_mag: bool) -> bool:
        if self.config.mode == "9D" and not has_mag:
            raise InputError(f"{self.name}: mode '9D' needs mag in the recording")
        return has_mag and self.config.mode != "6D"

    def _resume(self, state, rate: float, use_mag: bool) -> tuple[Any, np.ndarray]:
        """The peer object and held quaternion to continue from (``state``: ``Result.diagnostics
        ["state"]`` of an earlier run), or fresh ones."""
        if state is None:
            return self._new(rate, use_mag), np.array([1.0, 0.0, 0.0, 0.0])
        if not self.streaming:
            raise InputError(f"{self.name} is an offline filter (it uses future samples): a split run cannot "
                             "continue it, so run() takes no state=")
        if not isinstance(state, dict) or set(state) != {"filter", "rate", "use_mag", "peer", "q"} \
                or state["filter"] != self.name:
            raise InputError(f"state must be Result.diagnostics['state'] of an earlier {self.name} run")
        if state["use_mag"] != use_mag or abs(state["rate"] - rate) > 1e-6 * rate:  # (a clock's median interval)
            raise InputError(f"state was made at {state['rate']:.6g} Hz, {'9D' if state['use_mag'] else '6D'}; "
                             f"this run is at {rate:.6g} Hz, {'9D' if use_mag else '6D'}")
        return self._load(state["peer"], state["rate"], use_mag), np.array(state["q"], dtype=float)

    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None, state=None) -> Result:
        """Run the peer over ``rec``; from ``state`` (``Result.diagnostics["state"]`` of an earlier
        run: the peer's own state) to continue a split recording, the same numbers as one run."""
        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        if backend not in ("auto", "reference"):
            from ..errors import ConfigError

            raise ConfigError(f"{self.name} runs the peer's own code: backend must be 'auto' or 'reference'")
        self.peer()
        self.body_axes(rec)  # checked: a peer needs no forward axis, its output is in the recording's axes
        use_mag = self._use_mag(rec.mag is not None)
        mag = rec.mag if use_mag else None
        check_finite_all({"gyr": rec.gyr, "acc": rec.acc, "mag": mag}, self.config.nan_policy)
        n = len(rec)
        rate = rec.rate if rec.rate is not None else 1.0 / rec.nominal_dt
        obj, last = self._resume(state, rate, use_mag) if self.streaming or state is not None else (None, None)
        if state is not None:
            rate = state["rate"]  # the first run's, to the last bit: the peer's coefficients stay the same
        gyr, _, gaps = hold_gaps(rec.gyr, rec.dt, rec.nominal_dt, self.config.max_gap)
        c = self.config
        valid = np.zeros((n, 3), dtype=np.bool_)
        flags = np.zeros(n, dtype=np.uint32)
        validity_all(gyr, rec.acc, mag if mag is not None else np.zeros((n, 3)), mag is not None,
                     c.gyr_range if c.gyr_range is not None else np.inf,
                     c.acc_range if c.acc_range is not None else np.inf, valid, flags)
        if mag is not None:
            self._peer_mag(mag, valid, flags)
        ok = valid[:, 0] & valid[:, 1] & (valid[:, 2] | (mag is None))
        if ok.all():
            q = self._batch(obj, gyr, rec.acc, mag, rate)
        elif not self.streaming:  # a batch filter cannot skip: hold the last valid input instead
            if not ok.any():
                raise InputError(f"{self.name}: no sample with all sensors valid")
            idx = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
            idx[idx < 0] = int(np.argmax(ok))
            q = self._batch(obj, gyr[idx], rec.acc[idx], None if mag is None else mag[idx], rate)
        else:  # hold the orientation over a bad gyro sample; leave out a bad aiding sensor only
            q = np.empty((n, 4))
            for k in range(n):
                if valid[k, 0]:
                    last = self._step(obj, gyr[k], rec.acc[k] if valid[k, 1] else None,
                                      mag[k] if mag is not None and valid[k, 2] else None, 1.0 / rate)
                q[k] = last
        q = np.asarray(q, dtype=float)
        diag = {"backend": f"peer:{self.package} {self.version()}", "filter": self.name,
                "config": self.config.model_dump(), "mode": "9D" if use_mag else "6D"}
        if self.streaming:
            diag["state"] = {"filter": self.name, "rate": rate, "use_mag": use_mag, "peer": self._save(obj),
                             "q": q[-1].copy()}
        if self.peer_frame != self.config.frame:  # (the same frame: no product with the identity, a pass less)
            q = change_frame(q, self.peer_frame, self.config.frame)
        mark_gaps(flags, gaps, rec.gyr, diag, gap_threshold(rec.nominal_dt, self.config.max_gap))
        return Result(q, flags, self.config.frame, diag)

    def _peer_mag(self, mag, valid, flags) -> None:
        """Magnetometer samples outside :attr:`mag_limits` become invalid for this peer."""
        lo, hi = self.mag_limits
        if (lo, hi) == (TINY, HUGE):
            return
        with np.errstate(invalid="ignore"):
            m = np.abs(mag).max(axis=1)
        out = valid[:, 2] & ~((m >= lo) & (m <= hi))
        valid[out, 2] = False
        flags[out] |= np.uint32(Flag.MAG_INVALID)

    def reset(self) -> None:
        self._stream = None

    def update(self, gyr, acc, mag=None, dt: float | None = None) -> np.ndarray:
        if not self.streaming:
            raise PluginError(f"{self.name} is an offline (batch) filter: use run()")
        if dt is None:
            raise InputError("update() needs dt, the sample interval in s")
        dt = check_positive("dt", dt)
        g, a = as_vector("gyr", gyr), as_vector("acc", acc)
        use_mag = self._use_mag(mag is not None)
        m = as_vector("mag", mag) if use_mag else None
        c = self.config
        check_sample_finite(c.nan_policy, gyr=g, acc=a, mag=m)
        self.check_stream_units(g, a)
        if self._stream is None:
            self._stream = {"obj": self._new(1.0 / dt, use_mag), "q": np.array([1.0, 0.0, 0.0, 0.0]), "dt": dt}
        g, dt, gap = stream_gap(g, dt, self._stream["dt"], c.max_gap)
        gyr_ok, acc_ok, mag_ok, flags = sample_validity(g, a, m, c.gyr_range, c.acc_range)
        if mag_ok:
            valid, f = np.array([[True, True, True]]), np.zeros(1, np.uint32)
            self._peer_mag(m[None], valid, f)
            mag_ok, flags = bool(valid[0, 2]), flags | int(f[0])
        if gyr_ok:
            self._stream["q"] = self._step(self._stream["obj"], g, a if acc_ok else None, m if mag_ok else None, dt)
        self.last_flags = gap_flags(flags, gap)
        return change_frame(np.asarray(self._stream["q"], dtype=float), self.peer_frame, self.config.frame)


# ---- VQF -----------------------------------------------------------------------------------


class VqfConfig(PeerConfig):
    tau_acc: float = param(3.0, unit="s", description="VQF tauAcc: accelerometer low-pass time constant", gt=0)
    tau_mag: float = param(9.0, unit="s", description="VQF tauMag: magnetometer time constant", gt=0)
    motion_bias_est: bool = param(True, unit="-", description="VQF motionBiasEstEnabled")
    rest_bias_est: bool = param(True, unit="-", description="VQF restBiasEstEnabled")
    mag_dist_rejection: bool = param(True, unit="-", description="VQF magDistRejectionEnabled")


def _vqf_params(c) -> dict:
    return {"tauAcc": c.tau_acc, "tauMag": c.tau_mag, "motionBiasEstEnabled": c.motion_bias_est,
            "restBiasEstEnabled": c.rest_bias_est, "magDistRejectionEnabled": c.mag_dist_rejection}


def _c(x):
    return np.ascontiguousarray(x, dtype=np.float64)


class VqfFilter(PeerFilter):
    """VQF (Laidig and Seel, Information Fusion 2023, doi:10.1016/j.inffus.2022.10.014), C++ online."""

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


# ---- imufusion -----------------------------------------------------------------------------


class ImufusionConfig(PeerConfig):
    gain: float = param(0.5, unit="-", description="Fusion AHRS gain (recommended 0.5)", ge=0)
    gyroscope_range: float = param(2000.0, unit="deg/s", description="gyroscope range", gt=0)
    acceleration_rejection: float = param(10.0, unit="deg", description="acceleration rejection threshold", ge=0)
    magnetic_rejection: float = param(10.0, unit="deg", description="magnetic rejection threshold", ge=0)
    rejection_timeout: float = param(5.0, unit="s", description="rejection timeout", gt=0)
    gyro_offset: bool = param(True, unit="-", description="run imufusion's gyroscope offset (Bias) correction")


class ImufusionFilter(PeerFilter):
    """x-io's Fusion AHRS (imufusion) with its recommended settings."""

    name: ClassVar[str] = "imufusion"
    package: ClassVar[str] = "imufusion"
    Config = ImufusionConfig
    mag_limits: ClassVar[tuple[float, float]] = (1e-15, 1e15)  # Fusion computes in float32
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


# ---- ahrs ----------------------------------------------------------------------------------


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
