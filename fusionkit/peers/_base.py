"""The frame every peer adapter shares: config, input checks, batch and streaming runs, state."""

from __future__ import annotations

import copy
import importlib
import warnings
from typing import Any, ClassVar, Literal

import numpy as np

from ..config import FilterConfig, param
from ..conventions import change_frame
from ..errors import InputError, PluginError, PluginWarning
from ..protocols import Filter
from .._kernels import validity_all
from ..types import (HUGE, TINY, Flag, Recording, Result, gap_flags, gap_threshold, hold_gaps, mark_gaps,
                     sample_validity, stream_gap)
from ..validation import as_vector, check_finite_all, check_dt, check_sample_finite




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
    #: whether :meth:`_save` copies the peer's object (imufusion's cannot be copied: its snapshot is
    #: the live object, so a stream's ``state`` would keep changing with the stream)
    copyable: ClassVar[bool] = True
    #: whether the peer's library integrates every sample over one fixed sample time (``vqf*``,
    #: ``imufusion``: a stream's first ``dt``), not over each sample's own interval
    fixed_rate: ClassVar[bool] = False

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
        self._check_state(state)
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
        diag["aiding"] = self.aiding(rec)
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

    def _check_state(self, state) -> None:
        if not isinstance(state, dict) or set(state) != {"filter", "rate", "use_mag", "peer", "q"} \
                or state["filter"] != self.name:
            raise InputError(f"state must be Result.diagnostics['state'] of an earlier {self.name} run "
                             f"(or {self.name}'s .state)")

    @property
    def state(self) -> dict[str, Any] | None:
        """A copy of the stream's state (None before the first :meth:`update`), in the form of
        ``run()``'s ``Result.diagnostics["state"]``: :meth:`set_state` takes either, so a stream
        continues a run. (Peers had neither, an AttributeError where every filter has them.)"""
        s = self._stream
        if s is None:
            return None
        if not self.copyable:
            raise PluginError(f"{self.name}: the peer's objects cannot be copied, so a stream's state cannot be "
                              "saved (a run's Result.diagnostics['state'] continues once, by run(state=) or set_state)")
        return {"filter": self.name, "rate": 1.0 / s["dt"], "use_mag": s["use_mag"], "peer": self._save(s["obj"]),
                "q": np.array(s["q"], dtype=float)}

    def set_state(self, state) -> None:
        """Continue the stream from :attr:`state` or from a run's ``Result.diagnostics["state"]``."""
        if not self.streaming:
            raise PluginError(f"{self.name} is an offline (batch) filter: it has no streaming state to set")
        self._check_state(state)
        rate, use_mag = float(state["rate"]), bool(state["use_mag"])
        self._stream = {"obj": self._load(state["peer"], rate, use_mag), "q": np.array(state["q"], dtype=float),
                        "dt": 1.0 / rate, "use_mag": use_mag}

    def reset(self) -> None:
        self._stream = None

    def update(self, gyr, acc, mag=None, dt: float | None = None) -> np.ndarray:
        if not self.streaming:
            raise PluginError(f"{self.name} is an offline (batch) filter: use run()")
        if dt is None:
            raise InputError("update() needs dt, the sample interval in s")
        dt = check_dt(dt, bounded=self._stream is None)
        g, a = as_vector("gyr", gyr), as_vector("acc", acc)
        use_mag = self._use_mag(mag is not None)
        m = as_vector("mag", mag) if use_mag else None
        c = self.config
        check_sample_finite(c.nan_policy, gyr=g, acc=a, mag=m)
        self.check_stream_units(g, a)
        if self._stream is None:
            self._stream = {"obj": self._new(1.0 / dt, use_mag), "q": np.array([1.0, 0.0, 0.0, 0.0]), "dt": dt,
                            "use_mag": use_mag}
        g, dt, gap = stream_gap(g, dt, self._stream["dt"], c.max_gap)
        if self.fixed_rate and not gap and abs(dt - self._stream["dt"]) > 0.01 * self._stream["dt"] \
                and not self._stream.get("warned"):  # (1 %: far above the intervals' rounding, 4e-5)
            self._stream["warned"] = True
            warnings.warn(PluginWarning(
                f"{self.name} integrates every sample over one fixed sample time, the stream's first dt "
                f"({self._stream['dt']:g} s), as its library does; this sample's dt ({dt:g} s) is not used, so the "
                "stream and run() differ on uneven timestamps (docs/reliability.md; warned once per stream)"),
                stacklevel=2)
        gyr_ok, acc_ok, mag_ok, flags = sample_validity(g, a, m, c.gyr_range, c.acc_range)
        if mag_ok:
            valid, f = np.array([[True, True, True]]), np.zeros(1, np.uint32)
            self._peer_mag(m[None], valid, f)
            mag_ok, flags = bool(valid[0, 2]), flags | int(f[0])
        if gyr_ok:
            self._stream["q"] = self._step(self._stream["obj"], g, a if acc_ok else None, m if mag_ok else None, dt)
        self.last_flags = gap_flags(flags, gap)
        return change_frame(np.asarray(self._stream["q"], dtype=float), self.peer_frame, self.config.frame)


def _c(x):
    return np.ascontiguousarray(x, dtype=np.float64)
