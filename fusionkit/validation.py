"""Input checks shared by every plugin: one place, clear messages, no ``assert``."""

from __future__ import annotations

import numpy as np

from .errors import InputError

NAN_POLICIES = ("raise", "skip")


def _no_bool(name: str, x) -> None:
    if getattr(x, "dtype", None) == np.bool_ or (isinstance(x, (list, tuple)) and np.asarray(x).dtype == np.bool_):
        raise InputError(f"{name} is a boolean array: sensor samples must be numbers (a mask passed by mistake?)")


def as_vectors(name: str, x, n: int | None = None, width: int = 3) -> np.ndarray:
    """``x`` as a C-contiguous float64 ``(N, width)`` array, or :class:`InputError` (also for a
    boolean array: True/False would become 1/0 rad/s)."""
    _no_bool(name, x)
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
    _no_bool(name, x)
    try:
        arr = np.asarray(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric vector of length {width}: {exc}") from None
    if arr.shape != (width,):
        raise InputError(f"{name} must have shape ({width},), got {np.shape(x)}")
    return arr


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


def check_sample_finite(policy: str, **vectors) -> None:
    """``update()``'s :func:`check_finite`: with ``policy="raise"`` a non-finite vector (None: not
    given) raises naming it."""
    if policy != "raise":
        return
    for name, v in vectors.items():
        if v is not None and not np.isfinite(v).all():
            raise InputError(f"{name} is not finite ({v.tolist()}); pass nan_policy='skip' to hold and flag")


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


DEG = np.pi / 180.0


def check_units(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None = None, dt: np.ndarray | None = None) -> None:
    """:class:`InputError` naming the fix when the data betray a unit mistake: an accelerometer in
    g (median norm near 1), a gyroscope in deg/s (median axis above one turn per second, or, with
    ``dt``, a gyro whose turning the accelerometer and magnetometer contradict: see
    :func:`turning_scale`). Medians are taken on about 3000 evenly spread samples."""
    step = max(1, gyr.shape[0] // 3000)
    with np.errstate(over="ignore", invalid="ignore"):
        norm = np.linalg.norm(acc[::step], axis=1)
    norm = norm[np.isfinite(norm) & (norm > 0)]
    if norm.size and 0.3 < np.median(norm) < 3.0:
        raise InputError(
            f"acc looks like it is in g (median norm {np.median(norm):.3g}); fusionkit expects "
            "m/s^2: pass acc_unit='g' to convert"
        )
    g = gyr[::step]
    w = np.abs(g[np.isfinite(g).all(axis=1)])
    if w.size and np.median(w) > 2.0 * np.pi:
        raise InputError(
            f"gyr looks like it is in deg/s (median |component| {np.median(w):.3g} > 2 pi rad/s); "
            "fusionkit expects rad/s: pass gyr_unit='deg/s' to convert"
        )
    if dt is None or gyr.shape[0] < 4:
        return
    turns = window_turns(gyr, dt)
    for name, vec in (("mag", mag), ("acc", acc)):
        if vec is None:
            continue
        scale = turning_scale(turns, vec, quasi_static=name == "acc")
        if scale is None or scale > np.sqrt(DEG):
            continue
        # the specific force may not follow gravity (a multicopter's thrust stays on its z axis):
        # from it alone, a deg/s gyro must also turn faster than a turn per second as given
        if name == "acc" and w.size and np.percentile(np.linalg.norm(w, axis=1), 99) < 2 * np.pi:
            continue
        raise InputError(
            f"gyr looks like it is in deg/s: the {name} turns as the gyro scaled by pi/180 predicts, not as given "
            f"(fitted scale {scale:.3g}, deg/s would be {DEG:.3g}); fusionkit expects rad/s: pass gyr_unit='deg/s' "
            "to convert")


def window_turns(gyr: np.ndarray, dt: np.ndarray, window: float = 0.05):
    """The gyro's rotation vectors over consecutive windows of about ``window`` s:
    ``(i0, i1, th, duration)``, ``th[j]`` the integral of ``w dt`` over ``(t[i0[j]], t[i1[j]]]``
    (NaN over a non-finite sample)."""
    n = gyr.shape[0]
    h = float(np.median(dt[:: max(1, n // 1000)]))
    lag = max(1, int(round(window / h)))
    i0 = np.arange(0, max(0, n - lag), lag)
    i1 = i0 + lag
    with np.errstate(over="ignore", invalid="ignore"):
        th = np.add.reduceat(gyr * dt[:, None], i0 + 1, axis=0) if i0.size else np.zeros((0, 3))
        span = np.add.reduceat(dt, i0 + 1) if i0.size else np.zeros(0)
    if i0.size and i1[-1] < n - 1:  # reduceat's last window runs to the end: cut it to lag samples
        th, span = (th[:-1], span[:-1]) if i0.size > 1 else (th[:0], span[:0])
        i0, i1 = i0[:th.shape[0]], i1[:th.shape[0]]
    th[np.abs(span - lag * h) > 0.5 * lag * h] = np.nan  # a window over a timestamp gap is left out
    return i0, i1, th, lag * h


def turning_scale(turns, vec: np.ndarray, min_rate: float = 0.1, quasi_static: bool = False) -> float | None:
    """The scale ``c`` with which the gyroscope explains the turning of a vector fixed in the
    earth frame (the magnetic field; gravity, seen by the accelerometer when ``quasi_static``
    keeps windows whose ends have a norm within 10 % of the median): over the windows of
    :func:`window_turns`, ``u1 - u0 ~ -c th x u0`` in least squares. A gyro in rad/s gives about
    1, one in deg/s read as rad/s about pi/180. Only windows where the gyro, as given, says the
    vector turns faster than ``min_rate`` rad/s (beyond any gyro bias) count; None when the two
    hypotheses (1 and pi/180) are not told apart by a factor 4 in squared error, or fewer than 10
    windows count."""
    i0, i1, th, duration = turns
    if i0.size < 10:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        v0, v1 = vec[i0], vec[i1]
        n0, n1 = np.linalg.norm(v0, axis=1), np.linalg.norm(v1, axis=1)
        ok = np.isfinite(th).all(axis=1) & np.isfinite(n0) & np.isfinite(n1) & (n0 > 0) & (n1 > 0)
        if quasi_static and ok.any():
            m = np.median(n0[ok])
            ok &= (np.abs(n0 - m) < 0.1 * m) & (np.abs(n1 - m) < 0.1 * m)
        u0 = v0[ok] / n0[ok, None]
        du = v1[ok] / n1[ok, None] - u0
        p = -np.cross(th[ok], u0)
        use = np.linalg.norm(p, axis=1) > min_rate * duration
        if use.sum() < 10:
            return None
        p, du = p[use], du[use]
        e_rad = np.sum((du - p) ** 2)
        e_deg = np.sum((du - DEG * p) ** 2)
        c = float(np.sum(du * p) / np.sum(p * p))
    if not (np.isfinite(c) and (e_deg < 0.25 * e_rad or e_rad < 0.25 * e_deg)):
        return None
    return c
