"""The shared frame of the monolithic filters (``ekf``).

Such a filter keeps its whole state in one flat ``float64`` array (copyable, splittable, the same
array its numba loop works on) and has

- a readable reference, :meth:`StepFilter._step` (one sample, returns the quaternion and the
  sample's flags), and
- optionally a compiled loop over a whole recording (:meth:`StepFilter._kernel`) that does the
  same arithmetic; tests hold the two to 1e-9 on every sample.

This class does the rest once: input checks, the backend choice, ``run`` with a state carried
over from an earlier run, streaming ``update`` (the same numbers as ``run``), ``state`` /
``set_state`` / ``reset``, and a progress bar on long reference runs.
"""

from __future__ import annotations

from typing import Any, Callable, ClassVar

import numpy as np

from .._numba import HAVE_NUMBA, resolve_backend
from ..conventions import change_frame
from ..errors import InputError
from ..protocols import Filter
from ..types import Recording, Result, gap_flags, gap_threshold, hold_gaps, mark_gaps, stream_gap
from ..validation import as_vector, check_finite_all, check_dt, check_sample_finite, finite_sample

__all__ = ["StepFilter"]


class StepFilter(Filter):
    """A filter computed sample by sample on one flat state array (see the module docs).

    Subclasses set ``state_size`` and implement :meth:`new_state` and :meth:`_step`; those with
    a compiled loop implement :meth:`_kernel` and :meth:`params`.
    """

    state_size: ClassVar[int] = 0

    def __init__(self, config=None, **params: Any) -> None:
        super().__init__(config, **params)
        #: the ENU -> ``frame`` change, applied to every output quaternion (left factor)
        self.qf = change_frame(np.array([1.0, 0.0, 0.0, 0.0]), "ENU", self.config.frame)
        self._stream: np.ndarray | None = None
        self._buffers: tuple | None = None  # the compiled stream's one-sample arrays (see update)
        self._fast_dt = 0.0  # update()'s fast path takes intervals up to this (0: not yet, see update)
        #: "auto": update() runs the compiled loop on one sample when the filter has one;
        #: "reference": the readable step (the same numbers to 1e-9)
        self.update_backend = "auto"
        self.last_flags = 0

    # -- what a subclass provides ----------------------------------------------------------
    def new_state(self) -> np.ndarray:
        """A fresh state array of ``state_size``."""
        return np.zeros(self.state_size)

    def _step(self, x: np.ndarray, gyr, acc, mag, dt: float) -> tuple[np.ndarray, int]:
        """One sample (``mag`` None without a magnetometer): update ``x`` in place, return
        (quaternion body -> frame, flags)."""
        raise NotImplementedError

    def _kernel(self) -> Callable | None:
        """The compiled loop ``loop(gyr, acc, mag, dt, has_mag, x, params, qf, out_q, out_flags)``,
        or None (reference path only)."""
        return None

    def params(self) -> np.ndarray:
        """The compiled loop's parameter vector."""
        return np.zeros(0)

    def _diagnostics(self, x: np.ndarray) -> dict[str, Any]:
        """Extra entries of ``Result.diagnostics`` from the final state."""
        return {}

    def _relevel(self, x: np.ndarray) -> None:
        """Called before a sample that follows a timestamp gap (Flag.GAP; the gap's gyro step is
        held, see :func:`fusionkit.types.hold_gaps`) and before the first unsaturated gyro sample
        after saturated ones (the attitude is off by what the range clipped): a filter that can
        re-level quickly restarts what became stale. Default: nothing (the state is held)."""

    # -- shared ----------------------------------------------------------------------------
    def dimension(self, rec) -> str:
        return "9D" if getattr(self.config, "use_mag", True) and rec.mag is not None else "6D"

    def _uses_mag(self, rec: Recording) -> bool:
        return rec.mag is not None and getattr(self.config, "use_mag", True)

    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: np.ndarray | None = None) -> Result:
        """Process ``rec``, from ``state`` (``Result.diagnostics["state"]`` of an earlier run) or
        from the start; ``progress``: a progress bar (None: on a terminal for long reference runs)."""
        from ..pipeline import _progress

        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        self.body_axes(rec)  # checked: these filters need no forward axis, the output is in the recording's axes
        # a magnetometer it does not read (use_mag=False) is not refused for a non-finite sample
        check_finite_all({"gyr": rec.gyr, "acc": rec.acc, "mag": rec.mag if self._uses_mag(rec) else None},
                         self.config.nan_policy)
        loop = self._kernel()
        used = resolve_backend(backend, loop is not None)
        n = len(rec)
        x = self._checked_state(state).copy() if state is not None else self.new_state()
        has_mag = self._uses_mag(rec)
        mag = rec.mag if has_mag else np.zeros((n, 3))
        intervals, first_known = rec.run_intervals(continued=state is not None)
        gyr, dt, gaps = hold_gaps(rec.gyr, intervals, rec.nominal_dt, self.config.max_gap, first_known)
        restart = gaps | _after_saturation(rec.gyr, self.config.gyr_range)
        q = np.empty((n, 4))
        flags = np.zeros(n, np.uint32)
        if used == "numba":
            params = self.params()
            bounds = [0, *np.flatnonzero(restart).tolist(), n]  # one compiled run per stretch between restarts
            for s, e in zip(bounds[:-1], bounds[1:]):
                if restart[s]:
                    self._relevel(x)
                if e > s:
                    loop(gyr[s:e], rec.acc[s:e], mag[s:e], dt[s:e], has_mag, x, params, self.qf, q[s:e], flags[s:e])
        else:
            bar = _progress(n, progress, self.name)
            for k in range(n):
                if restart[k]:
                    self._relevel(x)
                q[k], flags[k] = self._step(x, gyr[k], rec.acc[k], mag[k] if has_mag else None, dt[k])
                if bar is not None and k % 10_000 == 9_999:
                    bar.update(10_000)
            if bar is not None:
                bar.close()
        diag = {"backend": used, "filter": self.name, "config": self.config.model_dump(), "state": x,
                **self._diagnostics(x)}
        mark_gaps(flags, gaps, rec.gyr, diag, gap_threshold(rec.nominal_dt, self.config.max_gap))
        diag["aiding"] = self.aiding(rec)
        return Result(q, flags, self.config.frame, diag)

    def _checked_state(self, x) -> np.ndarray:
        """``x`` as this filter's state vector, or an InputError saying what a state is (a dict or a
        string, e.g. another filter's state, was numpy's TypeError or ValueError)."""
        try:
            x = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"state must be Result.diagnostics['state'] of an earlier {self.name} run (or its "
                             f".state), an array of {self.state_size} numbers; got {type(x).__name__}") from None
        if x.shape != (self.state_size,):
            raise InputError(f"state has shape {x.shape}, expected ({self.state_size},): "
                             "pass Result.diagnostics['state'] of the same filter")
        if not np.isfinite(x).all():
            raise InputError("state is not finite")
        return x

    @property
    def state(self) -> np.ndarray | None:
        """A copy of the streaming state (None before the first :meth:`update`)."""
        return None if self._stream is None else self._stream.copy()

    def set_state(self, state) -> None:
        self._stream = self._checked_state(state).copy()
        # the state carries no interval: the next dt is bounded and sets the nominal rate (and the gap
        # threshold), not the interval of a stream this filter ran before
        self._nominal_dt = None
        self._fast_dt = 0.0

    def reset(self) -> None:
        self._stream = None
        self._buffers = None
        self._nominal_dt = None
        self._fast_dt = 0.0

    def update(self, gyr, acc, mag=None, dt: float | None = None) -> np.ndarray:
        """One sample of a stream; the same numbers as :meth:`run`. It runs the compiled loop on
        the one sample when the filter has one (``update_backend``), else the reference step."""
        b = self._buffers if self._stream is not None and self.update_backend == "auto" else None
        if b and type(dt) is float and 0.0 < dt <= self._fast_dt:
            # the fast path (the units checked, no gap, no saturated gyro): plain float64 vectors,
            # all finite, written into the loop's arrays
            use_mag = mag is not None and getattr(self.config, "use_mag", True)
            sample = finite_sample(gyr, acc, mag if use_mag else None)
            if sample is not None:
                return self._update_compiled(b, *sample, dt, use_mag)
        return self._update_checked(gyr, acc, mag, dt)

    def _update_compiled(self, b, g, a, m, dt, has_mag) -> np.ndarray:
        loop, p, Z, G, A, M, DT, Q, F = b
        Z[:] = [*g, *a, *m, dt]  # one write: G, A, M and DT are views of Z
        loop(G, A, M, DT, has_mag, self._stream, p, self.qf, Q, F)
        self.last_flags = int(F[0])
        return Q[0].copy()

    def _update_checked(self, gyr, acc, mag, dt) -> np.ndarray:
        """:meth:`update` with every check, on either path."""
        if dt is None:
            raise InputError("update() needs dt, the sample interval in s")
        dt = check_dt(dt, bounded=self.__dict__.get("_nominal_dt") is None)  # (set_state leaves no nominal interval)
        g, a = as_vector("gyr", gyr), as_vector("acc", acc)
        m = None if mag is None or not getattr(self.config, "use_mag", True) else as_vector("mag", mag)
        check_sample_finite(self.config.nan_policy, gyr=g, acc=a, mag=m)
        self.check_stream_units(g, a)
        if self._stream is None:
            self._stream = self.new_state()
        nominal = self.__dict__.setdefault("_nominal_dt", None) or dt  # the stream's first interval
        self._nominal_dt = nominal
        g, dt, gap = stream_gap(g, dt, nominal, self.config.max_gap)
        saturated = self.config.gyr_range is not None and bool(np.max(np.abs(g)) >= self.config.gyr_range)
        if gap or (self.__dict__.get("_saturated", False) and not saturated):
            self._relevel(self._stream)
        self._saturated = saturated
        if self._buffers is None:
            loop = self._kernel() if self.update_backend != "reference" and HAVE_NUMBA else None
            Z = np.zeros(10)  # the sample's gyr, acc, mag and dt, as the loop's (1, 3) and (1,) arrays
            self._buffers = False if loop is None else (
                loop, self.params(), Z, Z[0:3].reshape(1, 3), Z[3:6].reshape(1, 3), Z[6:9].reshape(1, 3), Z[9:10],
                np.zeros((1, 4)), np.zeros(1, np.uint32))
        if self._buffers and self.update_backend != "reference":
            q = self._update_compiled(self._buffers, g, a, (0.0, 0.0, 0.0) if m is None else m, dt, m is not None)
            self.last_flags = gap_flags(self.last_flags, gap)
            # the fast path may run once the units are checked, without a range to watch
            done = len(self.__dict__.get("_unit_samples", ())) >= self.UNIT_CHECK_SAMPLES
            ok = done and self.config.gyr_range is None
            self._fast_dt = gap_threshold(nominal, self.config.max_gap) if ok else 0.0
            return q
        q, f = self._step(self._stream, g, a, m, dt)
        self.last_flags = gap_flags(f, gap)
        return q


def _after_saturation(gyr: np.ndarray, gyr_range: float | None) -> np.ndarray:
    """Mask of the first gyro samples below ``gyr_range`` after one at or above it."""
    if gyr_range is None:
        return np.zeros(gyr.shape[0], bool)
    with np.errstate(invalid="ignore"):
        sat = np.abs(gyr).max(axis=1) >= gyr_range
    out = np.zeros_like(sat)
    out[1:] = sat[:-1] & ~sat[1:]
    return out
