"""Input checks shared by every plugin: one place, clear messages, no ``assert``."""

from __future__ import annotations

import numpy as np

from .errors import InputError

NAN_POLICIES = ("raise", "skip")


def as_vectors(name: str, x, n: int | None = None, width: int = 3) -> np.ndarray:
    """``x`` as a C-contiguous float64 ``(N, width)`` array, or :class:`InputError`."""
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric array of shape (N, {width}): {exc}") from None
    if arr.ndim == 1 and arr.shape[0] == width and n in (None, 1):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise InputError(f"{name} must have shape (N, {width}), got {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name} has {arr.shape[0]} samples but gyr has {n}; lengths must match")
    return np.ascontiguousarray(arr)


def as_vector(name: str, x, width: int = 3) -> np.ndarray:
    """One sample as a float64 ``(width,)`` array, or :class:`InputError`."""
    try:
        arr = np.asarray(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric vector of length {width}: {exc}") from None
    if arr.shape != (width,):
        raise InputError(f"{name} must have shape ({width},), got {np.shape(x)}")
    return arr


def floats3(v):
    """A float64 vector of 3 as a list of floats, cheaply, or None for anything else (the streaming
    fast paths then take the checked path, which names what is wrong)."""
    if type(v) is np.ndarray and v.shape == (3,) and v.dtype == np.float64:
        return v.tolist()
    if type(v) in (list, tuple) and len(v) == 3 and all(type(e) is float for e in v):
        return v
    return None


def finite_rows(x: np.ndarray) -> np.ndarray:
    """Boolean mask of the rows of ``x`` whose entries are all finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(x.sum()):  # fast path: a NaN or inf anywhere makes the sum non-finite
            return np.ones(x.shape[0], bool)
    return np.isfinite(x).all(axis=1)


def check_finite(name: str, x: np.ndarray, policy: str) -> np.ndarray:
    """Mask of usable rows; with ``policy="raise"`` a non-finite row raises naming its index."""
    if policy not in NAN_POLICIES:
        raise InputError(f"nan_policy must be one of {NAN_POLICIES}, got {policy!r}")
    ok = finite_rows(x)
    if policy == "raise" and not ok.all():
        i = int(np.argmin(ok))
        raise InputError(
            f"{name}[{i}] is not finite ({x[i].tolist()}); clean the data or pass nan_policy='skip' "
            "to hold the state over such samples and flag them"
        )
    return ok


def check_finite_all(arrays: dict, policy: str) -> None:
    """Like :func:`check_finite` for several sensors; ``"raise"`` names the earliest bad sample."""
    bad = []
    for name, x in arrays.items():
        if x is None:
            continue
        ok = check_finite(name, x, "skip" if policy == "raise" else policy)
        if not ok.all():
            bad.append((int(np.argmin(ok)), name, x))
    if policy == "raise" and bad:
        _, name, x = min(bad, key=lambda b: b[0])
        check_finite(name, x, "raise")


def check_time(t, n: int, name: str = "t", other: str = "gyr") -> np.ndarray:
    """Timestamps as float64 ``(n,)``, finite and strictly increasing."""
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if t.shape[0] != n:
        raise InputError(f"{name} has {t.shape[0]} samples but {other} has {n}; lengths must match")
    if not np.isfinite(t).all():
        i = int(np.argmin(np.isfinite(t)))
        raise InputError(f"{name}[{i}] is not finite ({t[i]})")
    if n > 1:
        d = np.diff(t)
        if (d <= 0).any():
            i = int(np.argmax(d <= 0)) + 1
            raise InputError(f"{name} must be strictly increasing, but {name}[{i}]={t[i]} <= {name}[{i - 1}]={t[i - 1]}")
    return t


def check_positive(name: str, value: float) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a finite number > 0, got {value!r}")
    return v
