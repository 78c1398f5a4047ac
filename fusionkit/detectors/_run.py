"""Running one detector over a recording on its own (:meth:`fusionkit.protocols.Detector.run`).

Lives below the pipeline (which re-exports :func:`run_detector`) so that the protocols and the
detectors never import the composition layer.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from .._numba import njit, resolve_backend
from ..errors import InputError, PluginError
from ..gnss_rows import NO_GNSS, gnss_sample_rows
from ..protocols import DetectionResult, Detector, Sample
from ..types import Recording
from ..validation import check_finite_all

__all__ = ["run_detector", "checked_bits", "read_only", "wrote_input"]


def read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (``a`` itself stays writable): what the reference paths hand a
    plugin of the user's arrays, so that one editing a sample in place (``acc = sample.acc;
    acc *= k``) raises instead of silently changing the user's recording. One view per array, not
    per sample: its rows are read-only views too."""
    v = a.view()
    v.flags.writeable = False
    return v


#: numpy's own messages for a write into a read-only array (``a[...] = x``, ``a *= k``, ``a.sort()``, ``np.put``,
#: ``a.flat[...] = x``, ``np.place``); a plugin's own error that mentions "read-only" is its own
_NUMPY_READ_ONLY = re.compile(r"(put: )?(assignment destination|output array|sort array|underlying array|"
                              r"WRITEBACKIFCOPY base) is read-only")


def wrote_input(kind: str, plugin: Any, exc: ValueError) -> None:
    """Called with the ValueError a plugin's call raised: a PluginError naming the plugin when it
    is numpy's refusal to write into a :func:`read_only` array ("assignment destination is
    read-only", "output array is read-only"), which named neither the plugin nor the rule; returns
    (the caller re-raises) for any other error."""
    if type(exc) is ValueError and _NUMPY_READ_ONLY.fullmatch(str(exc)):
        raise PluginError(f"{kind} {plugin.name!r} wrote into a read-only array, likely the sample it was given "
                          f"({exc}): a plugin must not change its input (the arrays are the recording's or the "
                          "caller's); "
                          "compute on a copy, e.g. acc = sample.acc * k, not sample.acc *= k") from exc


def checked_bits(det: Detector, bits: Any) -> Any:
    """``bits``, what ``det.step()`` returned, when it is a criteria bitmask (an int from 0 to
    2**32 - 1), else a PluginError naming the detector and what it must return, as for a corrector
    (a string gave "invalid literal for int()", a negative number numpy's OverflowError). A bool
    (Python's or numpy's: a comparison, "fired or not") is bit 0."""
    if isinstance(bits, np.bool_):
        return int(bits)
    if isinstance(bits, (int, np.integer)) and 0 <= bits <= 0xFFFFFFFF:
        return bits
    raise PluginError(f"detector {det.name!r}: step() returned {type(bits).__name__} {bits!r:.40}; it must return "
                      "its criteria bitmask, an int >= 0 (bit b: criteria_names[b]; 0: not fired)")


# ---- detectors on their own -------------------------------------------------------------------

_DET_LOOPS: dict[Any, Any] = {}


def _get_det_loop(step, gnss=False):
    key = (step, gnss)
    if key not in _DET_LOOPS:

        @njit(cache=False)
        def loop(gyr, acc, mag, dt, ok, s, p, out, gn):
            last = gn.shape[0] - 1
            for k in range(gyr.shape[0]):
                if ok[k]:
                    if gnss:
                        r = min(k, last)
                        out[k] = step(s, gyr[k, 0], gyr[k, 1], gyr[k, 2], acc[k, 0], acc[k, 1], acc[k, 2],
                                      mag[k, 0], mag[k, 1], mag[k, 2], dt[k], p, gn[r, 0], gn[r, 1], gn[r, 2],
                                      gn[r, 3], gn[r, 4], gn[r, 5])
                    else:
                        out[k] = step(s, gyr[k, 0], gyr[k, 1], gyr[k, 2], acc[k, 0], acc[k, 1], acc[k, 2],
                                      mag[k, 0], mag[k, 1], mag[k, 2], dt[k], p)

        _DET_LOOPS[key] = loop
    return _DET_LOOPS[key]


def run_detector(det: Detector, rec: Recording, *, nan_policy: str = "raise", backend: str = "auto",
                 every_sample: bool = False) -> DetectionResult:
    """Run one detector over a recording (see :meth:`Detector.run`): on the samples with a valid
    gyroscope and accelerometer (as in a pipeline), or on ``every_sample``. Detectors that read
    GNSS get the sample's GNSS row (:func:`~fusionkit.detectors.gnss_gap.gnss_sample_rows`)."""
    if not isinstance(rec, Recording):
        raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
    check_finite_all({"gyr": rec.gyr, "acc": rec.acc}, nan_policy)
    if every_sample:
        ok = np.ones(len(rec), dtype=bool)
    else:
        ok = np.isfinite(rec.gyr).all(axis=1) & np.isfinite(rec.acc).all(axis=1)
        ok &= np.any(rec.acc != 0.0, axis=1)
    kernel = det.kernel()
    used = resolve_backend(backend, kernel is not None)
    s = det.initial_state(rec.nominal_dt)
    n = len(rec)
    out = np.zeros(n, dtype=np.uint32)
    mag = rec.mag if rec.mag is not None else np.zeros((n, 3))
    dt = rec.dt
    gn = gnss_sample_rows(rec) if rec.gnss is not None else None
    if used == "numba":
        _get_det_loop(kernel.step, kernel.gnss)(rec.gyr, rec.acc, mag, dt, ok, s, kernel.params, out,
                                                gn if gn is not None else NO_GNSS[None, :])
    else:
        gyr, acc, mag = read_only(rec.gyr), read_only(rec.acc), read_only(mag)  # (the recording's: never written)
        for k in range(n):
            if ok[k]:
                m = mag[k] if rec.mag is not None else None
                try:
                    bits = det.step(s, Sample(gyr[k], acc[k], m, dt[k], None if gn is None else gn[k]))
                except ValueError as exc:
                    wrote_input("detector", det, exc)
                    raise
                out[k] = checked_bits(det, bits)
    fired = np.flatnonzero(out)
    return DetectionResult(out, int(fired[0]) if fired.size else None, det.criteria_names, used)
