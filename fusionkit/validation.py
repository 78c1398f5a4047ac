"""Input checks shared by every plugin: one place, clear messages, no ``assert``."""

from __future__ import annotations

import itertools
import math

import numpy as np

from ._numba import HAVE_NUMBA, njit
from .errors import InputError

NAN_POLICIES = ("raise", "skip")


def _no_bool(name: str, x, what: str = "", allow_bool: bool = False) -> None:
    """Refuse what float64 would take silently and wrongly: booleans (True/False become 1/0), complex
    numbers (the imaginary part dropped), dates or durations (their integer counts, in whatever unit
    they hold) and text (``"0.01"`` parses: the documented contract is numbers, text is a file read
    without its conversion), also as one element of a list or an object array (numpy makes a list
    holding one True all floats, and one text all text). A ragged list is refused here too (numpy's
    own error would not name the argument). ``what`` follows "must be numbers" in the text's message;
    ``allow_bool``: booleans are numbers here (a GNSS row's validity fields)."""
    if isinstance(x, (str, bytes)):
        _text(name, x, what)
    if isinstance(x, (list, tuple)):
        try:
            arr = np.asarray(x)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} must be a numeric array with rows of equal length: {exc}") from None
        if arr.dtype.kind not in "bcmM":  # numbers or text: numpy may have coerced a mixed list, so its elements
            _list_elements(name, x, what, allow_bool)
        x = arr
    kind = getattr(getattr(x, "dtype", None), "kind", None)
    if kind == "O":  # an object array (a table's column, a list of mixed types): each element's own type
        _elements(name, x, what, allow_bool)
    if kind in ("U", "S"):
        _text(name, x.flat[0].item() if x.size else "", what)
    if kind == "b" and not allow_bool:
        raise InputError(f"{name} is a boolean array: sensor samples must be numbers (a mask passed by mistake?)")
    if kind in ("c", "m", "M"):
        what = {"c": "complex", "m": "a duration (timedelta64)", "M": "a date (datetime64)"}[kind]
        raise InputError(f"{name} is {what}: it must be real numbers"
                         + (" in seconds, e.g. (t - t[0]) / np.timedelta64(1, 's')" if kind in "mM" else ""))


def _elements(name: str, x: np.ndarray, what: str, allow_bool: bool) -> None:
    """Refuse an object array's text, boolean or complex element (or a 0-d array holding one). The
    element types are collected first (one pass in C over a 1M-row array), the elements read only
    when one is wrong."""
    for tp in set(map(type, x.flat)):
        if issubclass(tp, (str, bytes)):
            _text(name, next(v for v in x.flat if isinstance(v, tp)), what)
        if issubclass(tp, (bool, np.bool_)) and not allow_bool:
            raise InputError(f"{name} holds a boolean ({next(v for v in x.flat if isinstance(v, tp))!r}): "
                             f"{name} must be numbers")
        if issubclass(tp, (complex, np.complexfloating)):
            raise InputError(f"{name} holds a complex number ({next(v for v in x.flat if isinstance(v, tp))!r}): "
                             "it must be real numbers")
        if issubclass(tp, np.ndarray):  # arrays inside: each judged as the argument itself
            for v in x.flat:
                if isinstance(v, np.ndarray):
                    _no_bool(name, v, what, allow_bool)


_PLAIN = (float, int, np.float64, np.float32, np.int64, np.int32)  # (int: bool is a subclass, told by type, not isinstance)


def _list_elements(name: str, x, what: str, allow_bool: bool) -> None:
    """:func:`_elements` for a list or tuple, read from its own Python objects (an object array of
    a 1M-row list would cost more than the conversion it guards): a flat list, a list of rows, or a
    list of arrays (each judged by its dtype)."""
    if all(type(v) is np.ndarray for v in x):
        for v in x:
            _no_bool(name, v, what, allow_bool)
        return
    rows = all(type(v) in (list, tuple) for v in x)
    types = set(map(type, itertools.chain.from_iterable(x) if rows else x))
    if types.issubset(_PLAIN):
        return
    _elements(name, np.array(x, dtype=object), what, allow_bool)  # something else inside: each element judged


def as_mask(name: str, x) -> np.ndarray:
    """``x`` as a boolean array (a mask), refusing text (``np.asarray(["False"], bool)`` is True)
    and numbers other than 0 and 1 (0.5 or NaN, a weight or a missing value, would be True)."""
    arr = np.asarray(x)
    if arr.dtype.kind in ("U", "S") or (arr.dtype.kind == "O" and any(
            issubclass(tp, (str, bytes)) for tp in set(map(type, arr.flat)))):
        raise InputError(f"{name} must be booleans (a mask), not text: convert it first, e.g. x == 'True'")
    if arr.dtype.kind != "b":
        try:
            other = np.flatnonzero((arr != 0) & (arr != 1))
        except TypeError:  # (objects that cannot be compared with numbers: numpy's bool() decides, as before)
            other = ()
        if len(other):
            i = int(other[0])
            raise InputError(f"{name} must be booleans (a mask) or 0/1, but {name}[{i}] is "
                             f"{np.asarray(arr.reshape(-1)[i]).tolist()!r:.40}: threshold it first, e.g. x > 0.5")
    return np.asarray(arr, dtype=bool)  # (a boolean array is kept, not copied)


def _text(name: str, example, what: str) -> None:
    raise InputError(f"{name} must be numbers{what} (a numeric array), not text such as {example!r:.40}: "
                     "convert it first, e.g. np.asarray(x, dtype=float)")


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


def as_vector(name: str, x, width: int = 3, allow_bool: bool = False) -> np.ndarray:
    """One sample as a float64 ``(width,)`` array, or :class:`InputError` (``allow_bool``: see
    :func:`_no_bool`)."""
    _no_bool(name, x, allow_bool=allow_bool)
    try:
        arr = np.asarray(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric vector of length {width}: {exc}") from None
    if arr.shape != (width,):
        raise InputError(f"{name} must have shape ({width},), got {np.shape(x)}")
    return arr


_F64 = np.dtype(np.float64)  # numpy's float64 dtype is one object: ``is`` tells it, ``==`` converts first
_SHAPE3 = (3,)


def _floats3(v):
    """A float64 vector of 3 as a list of floats, cheaply, or None for anything else."""
    if type(v) is np.ndarray:
        return v.tolist() if v.dtype is _F64 and v.shape == _SHAPE3 else None
    if type(v) in (list, tuple) and len(v) == 3 and all(type(e) is float for e in v):
        return v
    return None


_NO_MAG = (0.0, 0.0, 0.0)
_isfinite = math.isfinite


def finite_sample(gyr, acc, mag):
    """``(gyr, acc, mag)`` as lists of floats when each is a float64 vector of 3 and all are finite
    (``mag`` None: zeros), else None: the streaming fast paths take the sample as it is, and
    anything else goes to the checked path, which names what is wrong. (It runs once per sample
    of a stream: every attribute look-up and call in it shows in ``update()``'s time.)"""
    g, a = _floats3(gyr), _floats3(acc)
    m = _NO_MAG if mag is None else _floats3(mag)
    if g is None or a is None or m is None or not _isfinite(g[0] + g[1] + g[2] + a[0] + a[1] + a[2] + m[0] + m[1]
                                                            + m[2]):
        return None
    return g, a, m


def finite_rows(x: np.ndarray) -> np.ndarray:
    """Boolean mask of the rows of ``x`` whose entries are all finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(x.sum()):  # fast path: a NaN or inf anywhere makes the sum non-finite
            return np.ones(x.shape[0], bool)
    return np.isfinite(x).all(axis=1)


def has_finite(x: np.ndarray) -> bool:
    """Whether ``x`` has one finite entry, read in blocks of 4096 rows (no mask the size of the
    input; the first block nearly always decides): a magnetometer without one is no magnetometer."""
    return any(np.isfinite(x[k:k + 4096]).any() for k in range(0, len(x), 4096))


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


def check_finite_flagged(arrays: dict, policy: str, flags: np.ndarray, invalid: int) -> None:
    """:func:`check_finite_all` after a run whose per-sample ``flags`` mark every non-finite input
    sample with a bit of ``invalid``: the arrays are scanned only when some sample has one (a
    sample flagged for another reason, e.g. a zero reading or a gap, costs the scan and passes).
    A run of clean data then reads its input once, in the filter's loop, not twice."""
    if policy != "raise":
        return
    # some sample has an ``invalid`` bit iff the OR of all flags has one: one reduction, no temporary
    if flags.size and int(np.bitwise_or.reduce(flags)) & int(invalid):
        check_finite_all(arrays, policy)


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
    _no_bool(name, t, " (timestamps in s)")
    try:
        t = np.asarray(t, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numbers (timestamps in s): {exc}") from None
    if t.shape[0] != n:
        raise InputError(f"{name} has {t.shape[0]} samples but {other} has {n}; lengths must match")
    if n > 1 and math.isfinite(t[0]) and math.isfinite(t[-1]) and bool((t[1:] > t[:-1]).all()):
        return t  # increasing between finite ends: all finite (one pass; NaN compares False)
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
    """``value`` as a float, finite and > 0, or an :class:`InputError` naming ``name`` (a boolean, an
    array or text included: ``rate="100"`` parses, but text is refused as in the arrays)."""
    if isinstance(value, (str, bytes)):
        raise InputError(f"{name} must be a finite number > 0, got {value!r:.80} (text, not a number)")
    if isinstance(value, (bool, np.bool_)) or np.ndim(value) != 0:
        raise InputError(f"{name} must be one finite number > 0, got {value!r:.80}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a finite number > 0, got {value!r:.80}") from None
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def check_timestamp(name: str, value) -> float:
    """One streamed timestamp as a float (s), finite, or an :class:`InputError` naming ``name`` (a
    boolean or text included)."""
    if isinstance(value, (str, bytes, bool, np.bool_)) or np.ndim(value) != 0:
        raise InputError(f"{name} must be one finite number (a timestamp in s), got {value!r:.80}")
    v = float(value)
    if not math.isfinite(v):
        raise InputError(f"{name} must be one finite number (a timestamp in s), got {value!r}")
    return v


#: the longest sample interval a recording or a streamed sample may have (s; 1 Hz): below 1 Hz nothing
#: integrates a gyroscope, and such an interval is a unit mistake (the interval passed as the rate,
#: timestamps in ms or ns) that would otherwise run into time constants far shorter than a step (NaN)
MAX_INTERVAL = 1.0


def check_dt(dt: float, bounded: bool) -> float:
    """A streamed sample's interval ``dt``: :func:`check_positive`, and with ``bounded`` also at most
    :data:`MAX_INTERVAL` (an interval in ms is refused there). A stream bounds its first interval, which
    sets its nominal rate as a Recording's typical interval does; a later interval beyond the bound is a
    timestamp gap, handled as the filter handles one in a Recording (held across, flag GAP), not an
    error. A filter with no gap handling bounds every interval."""
    dt = check_positive("dt", dt)
    if bounded and dt > MAX_INTERVAL:
        raise InputError(f"dt must be at most {MAX_INTERVAL:g} s (the sample interval in s, not ms), got {dt:.4g}")
    return dt


# ---- the unit checks of a recording, in one pass -----------------------------------------------
#
# A Recording refuses an accelerometer that reads in g (median |a| in (0.3, 3)) and a gyroscope
# that reads in deg/s (median |component| above 2 pi). np.median partitions a copy of the data:
# on 1M samples these checks cost more than running a filter. The median's position against a
# threshold T needs no sorting: with lo = #(v < T), eq = #(v == T), the largest value below T and
# the smallest above it, the one or two middle order statistics are known exactly wherever they
# decide the comparison (:func:`median_vs`). :func:`unit_scan` gathers those counts for every
# threshold in one compiled pass over the arrays; small recordings take numpy's median (no
# compilation or cache load for them), which gives the same decisions (tests).

#: (accelerometer-in-g window on median |a|, gyroscope-in-deg/s bound on median |component|)
ACC_G_WINDOW = (0.3, 3.0)
GYR_DEG_BOUND = 2.0 * np.pi
#: below this many samples the checks run on numpy (the compiled scan's cache load costs more)
SCAN_MIN_SAMPLES = 50_000


def median_vs(n: int, lo: int, eq: int, max_lt: float, min_gt: float, thr: float) -> int:
    """Sign of ``median(v) - thr`` (-1, 0, 1) for ``n`` values of which ``lo`` are below ``thr``,
    ``eq`` equal to it, ``max_lt`` the largest below and ``min_gt`` the smallest above: the same
    comparison as with ``np.median(v)`` (the mean of the two middle values for even ``n``). In
    sorted order the values are ``lo`` below, ``eq`` at and the rest above ``thr``; a middle value
    not adjacent to ``thr`` is replaced by ``max_lt`` / ``min_gt``, which is on the same side, and
    one adjacent to it is exactly that value."""
    def at(i):
        return max_lt if i < lo else (thr if i < lo + eq else min_gt)

    k = n // 2
    m = at(k) if n % 2 else (at(k - 1) + at(k)) / 2
    return int(m > thr) - int(m < thr)


@njit
def unit_rows_off(q, tol):
    """Whether some finite row of ``q`` (N, 4) is off unit length, ``| |q|^2 - 1 | > tol``: one pass,
    stopping at the first (:func:`fusionkit.types._unit_rows`' test, compiled: numpy's took two passes
    and a temporary per block, 6 ms of a 1M-sample truth, most of a ``Recording``'s build)."""
    for i in range(q.shape[0]):
        n2 = q[i, 0] * q[i, 0] + q[i, 1] * q[i, 1] + q[i, 2] * q[i, 2] + q[i, 3] * q[i, 3]
        if abs(n2 - 1.0) > tol:  # (NaN rows: False, kept as they are)
            return True
    return False


@njit
def unit_scan(gyr, acc, thr):
    """One pass over ``gyr`` and ``acc`` for :func:`check_units`: row ``i`` of the result holds
    ``(n, lo, eq, max_lt, min_gt, sign)`` for threshold ``thr[i]``: ``thr[0]``, ``thr[1]`` on the
    norms of the accelerometer rows (finite and nonzero), ``thr[2]`` on the absolute components of
    the gyroscope rows that are finite. ``sign`` (+1 / -1) is the side of the median when the
    samples seen already decide it whatever the rest are (more than half of every possible total
    on one side: :func:`_decided`); each sensor's pass stops there, and its counts are partial
    (``max_lt`` / ``min_gt`` are then not gathered: -inf / inf). ``sign`` 0: the counts are
    complete, for :func:`median_vs`. (Typical data is decided halfway.)

    The counting runs without a branch per sample (integer sums of comparisons, which LLVM
    vectorises: the pass reads memory at the speed of a sum); the extremes beside each threshold,
    a float reduction that does not vectorise, are gathered in a second pass only when the whole
    recording left a median undecided."""
    out = np.zeros((3, 6))
    out[:, 3], out[:, 4] = -np.inf, np.inf
    t0, t1, t2 = thr[0], thr[1], thr[2]
    rows = acc.shape[0]
    n = lo0 = eq0 = lo1 = eq1 = 0
    s0 = s1 = 0
    for b in range(0, rows, _BLOCK):
        e = min(rows, b + _BLOCK)
        for k in range(b, e):
            v = math.sqrt(acc[k, 0] * acc[k, 0] + acc[k, 1] * acc[k, 1] + acc[k, 2] * acc[k, 2])
            pos = v > 0.0  # NaN compares False: not counted
            n += pos & (v < np.inf)
            lo0 += pos & (v < t0)
            eq0 += v == t0
            lo1 += pos & (v < t1)
            eq1 += v == t1
        rest = rows - e  # rows not seen: at most one value each
        s0, s1 = _decided(n, lo0, eq0, rest), _decided(n, lo1, eq1, rest)
        if s0 != 0 and s1 != 0:
            break
    if s0 == 0 or s1 == 0:  # the counts are complete: the extremes for median_vs
        for k in range(rows):
            v = math.sqrt(acc[k, 0] * acc[k, 0] + acc[k, 1] * acc[k, 1] + acc[k, 2] * acc[k, 2])
            if math.isfinite(v) and v > 0.0:
                for i in range(2):
                    if v < thr[i]:
                        out[i, 3] = max(out[i, 3], v)
                    elif v > thr[i]:
                        out[i, 4] = min(out[i, 4], v)
    out[0, 0], out[0, 1], out[0, 2], out[0, 5] = n, lo0, eq0, s0
    out[1, 0], out[1, 1], out[1, 2], out[1, 5] = n, lo1, eq1, s1
    rows = gyr.shape[0]
    n = lo0 = eq0 = 0
    s0 = 0
    for b in range(0, rows, _BLOCK):
        e = min(rows, b + _BLOCK)
        for k in range(b, e):
            g0, g1, g2 = abs(gyr[k, 0]), abs(gyr[k, 1]), abs(gyr[k, 2])
            ok = (g0 < np.inf) & (g1 < np.inf) & (g2 < np.inf)  # NaN compares False
            n += 3 * ok
            lo0 += ok * ((g0 < t2) + (g1 < t2) + (g2 < t2))
            eq0 += ok * ((g0 == t2) + (g1 == t2) + (g2 == t2))
        s0 = _decided(n, lo0, eq0, 3 * (rows - e))
        if s0 != 0:
            break
    if s0 == 0:
        for k in range(rows):
            g0, g1, g2 = abs(gyr[k, 0]), abs(gyr[k, 1]), abs(gyr[k, 2])
            if g0 < np.inf and g1 < np.inf and g2 < np.inf:
                for v in (g0, g1, g2):
                    if v < t2:
                        out[2, 3] = max(out[2, 3], v)
                    elif v > t2:
                        out[2, 4] = min(out[2, 4], v)
    out[2, 0], out[2, 1], out[2, 2], out[2, 5] = n, lo0, eq0, s0
    return out


_BLOCK = 8192


@njit(inline="always")
def _decided(n, lo, eq, rest):
    """The side of the median (+1 above, -1 below the threshold) that ``n`` counted values (``lo``
    below, ``eq`` at it) decide whatever up to ``rest`` more are, else 0. With ``m`` values in all,
    both middle order statistics lie above when more than ``m // 2`` values do; ``m`` is at most
    ``n + rest``, and the values not seen may all fall on the other side."""
    need = (n + rest) // 2 + 1
    if n - lo - eq >= need:
        return 1
    if lo >= need:
        return -1
    return 0


def _unit_medians(gyr: np.ndarray, acc: np.ndarray):
    """``(sign(median|a| - 0.3), sign(median|a| - 3), sign(median|w| - 2 pi))``, None where there
    is no usable sample."""
    thr = np.array([*ACC_G_WINDOW, GYR_DEG_BOUND])
    if HAVE_NUMBA and gyr.shape[0] >= SCAN_MIN_SAMPLES:
        st = unit_scan(gyr, acc, thr)
        return tuple(int(st[i, 5]) if st[i, 5] != 0 else None if st[i, 0] == 0 else
                     median_vs(int(st[i, 0]), int(st[i, 1]), int(st[i, 2]), st[i, 3], st[i, 4], thr[i])
                     for i in range(3))
    norm, w = _acc_norms(acc), _gyr_abs(gyr)
    sign = lambda v, t: None if v is None else int(v > t) - int(v < t)  # noqa: E731
    m_acc = float(np.median(norm)) if norm.size else None
    m_gyr = float(np.median(w)) if w.size else None
    return sign(m_acc, thr[0]), sign(m_acc, thr[1]), sign(m_gyr, thr[2])


def _acc_norms(acc):
    norm = np.linalg.norm(acc, axis=1)
    return norm[np.isfinite(norm) & (norm > 0)]


def _gyr_abs(gyr):
    return np.abs(gyr[np.isfinite(gyr).all(axis=1)])


#: the unit a median accelerometer norm (as given) points to: gravity, about 1 g, read in g, m/s^2
#: or mg, within the factor of about 3 the in-g window allows on either side (a recording's median
#: specific force stays near 1 g). Above the mg window (3000) no unit fusionkit converts fits: raw
#: counts (2048 to 16384 per g on common parts) or a wrong sensitivity. Below 0.3 nothing is said: a
#: free fall reads about 0 in every unit.
ACC_MG_WINDOW = (300.0, 3000.0)
#: the units a Recording converts from, to rad/s and m/s^2 (mrad/s, mdeg/s and mg: what some
#: drivers report, e.g. ST's mdps and mg)
GYR_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0, "mrad/s": 1e-3, "mdeg/s": np.pi / 180e3}
ACC_UNITS = {"m/s^2": 1.0, "g": 9.80665, "mg": 9.80665e-3}
#: rad/s: a gyroscope's 99th percentile of |component| beyond this is not a rate in rad/s. Consumer
#: and tactical gyros measure at most a few thousand deg/s (2000 deg/s = 35 rad/s, the widest ranges
#: 4000 deg/s = 70 rad/s); a gyro in mrad/s or mdeg/s (ST's mdps) reads thousands where it turns.
#: Nor, above 5730 rad/s (this bound's deg/s), is it in deg/s.
GYR_RATE_BOUND = 100.0
#: rows of the coarse statistics below (evenly spaced: the windows are factors of 3 to 100 apart)
_COARSE_ROWS = 8192


def _coarse_rows(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x[:: max(1, x.shape[0] // _COARSE_ROWS)])


def _coarse_acc_median(acc: np.ndarray) -> float | None:
    """The median norm of the finite, nonzero rows of about 8192 evenly spaced rows of ``acc``."""
    norm = _acc_norms(_coarse_rows(acc))
    return float(np.median(norm)) if norm.size else None


def acc_unit_of(median: float | None) -> str | None:
    """The unit whose window (:data:`ACC_G_WINDOW`, :data:`ACC_MG_WINDOW`, m/s^2 between them) holds
    an accelerometer's median norm; None below the g window, "far" above the mg window."""
    if median is None or median <= ACC_G_WINDOW[0]:
        return None
    if median < ACC_G_WINDOW[1]:
        return "g"
    if median <= ACC_MG_WINDOW[0]:
        return "m/s^2"
    return "mg" if median < ACC_MG_WINDOW[1] else "far"


def _acc_far(median: float) -> str:
    return (f"acc's median norm is {median:.3g}, far from gravity in every unit fusionkit converts (about 9.8 in "
            "m/s^2, 1 in g, 1000 in mg): raw counts or a wrong sensitivity? Divide by the sensitivity (counts per "
            "g) and pass acc_unit='g'")


def check_acc_declared(gyr: np.ndarray, acc: np.ndarray, unit: str) -> None:
    """Refuse a declared ``acc_unit`` (``"g"``, ``"mg"``) that the data, as given, contradicts:
    its median norm in another unit's window (:func:`acc_unit_of`: data in m/s^2 declared g would
    become ~96 m/s^2, data in mg declared g ~9800, which the checks after the conversion do not all
    look for), or far above every window. A median below the g window (a free fall) says nothing."""
    median = _coarse_acc_median(acc)
    seen = acc_unit_of(median)
    if seen is None or seen == unit:
        return
    if seen == "far":
        raise InputError(_acc_far(median) + f" (acc_unit={unit!r} was given)")
    exact = float(np.median(_acc_norms(acc)))
    if seen == "m/s^2":
        raise InputError(f"acc looks like it is in m/s^2 already (median norm {exact:.3g} > "
                         f"{ACC_G_WINDOW[1]:g}), but acc_unit={unit!r} would multiply it by "
                         f"{ACC_UNITS[unit]:.3g}: leave acc_unit out")
    raise InputError(f"acc looks like it is in {seen} (median norm {exact:.3g}), not {unit}: pass acc_unit={seen!r}")


def _gyr_fast_share(gyr: np.ndarray) -> tuple[float, float]:
    """``(share, p99)`` of about 8192 evenly spaced finite rows of ``gyr``: the share of their
    components beyond :data:`GYR_RATE_BOUND` in this row and the next (a rate in another unit is
    so on consecutive samples; a glitch, one sample the filters flag GYR_INVALID, is not) and the
    99th percentile of |component|."""
    n = gyr.shape[0]
    if n < 2:
        return 0.0, 0.0
    idx = np.arange(0, n - 1, max(1, (n - 1) // _COARSE_ROWS))
    a, b = gyr[idx], gyr[idx + 1]
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    a, b = np.abs(a[ok]), np.abs(b[ok])
    if not a.size:
        return 0.0, 0.0
    return float(np.count_nonzero((a > GYR_RATE_BOUND) & (b > GYR_RATE_BOUND))) / a.size, float(np.percentile(a, 99))


def check_units(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None = None,
                dt: np.ndarray | float | None = None, t: np.ndarray | None = None, gyr_unit: str = "rad/s",
                check_range: bool = True) -> None:
    """Refuse an accelerometer in g or mg, or far from gravity in every unit (:func:`acc_unit_of`), a
    gyroscope in deg/s (see above) and one whose rates no gyroscope measures in rad/s (more than 1 %
    of the components beyond :data:`GYR_RATE_BOUND`: mrad/s, mdeg/s, raw counts), naming the
    argument that converts them; the medians are computed for the message only when one is
    refused. With the clock (``dt``: the (N,) intervals or one constant interval; or ``t``: the
    timestamps), also a gyroscope whose turning the magnetometer and accelerometer contradict
    (:func:`check_turning`: a deg/s gyro on a recording that never turns a turn per second, or
    ``gyr``, converted from the declared ``gyr_unit="deg/s"``, that was in rad/s already).
    ``gyr_unit`` is the unit ``gyr`` was declared in (the messages say what it was converted from).
    ``check_range=False``: not the range test (a stream's first samples, too few for a share; a
    Recording given ``gyr_unit="rad/s"`` explicitly: a gyro that does turn that fast)."""
    acc_lo, acc_hi, gyr_hi = _unit_medians(gyr, acc)
    if acc_lo is not None and acc_lo > 0 and acc_hi < 0:
        raise InputError(
            f"acc looks like it is in g (median norm {np.median(_acc_norms(acc)):.3g}); fusionkit expects "
            "m/s^2: pass acc_unit='g' to convert"
        )
    if acc_hi is not None and acc_hi > 0:  # (in m/s^2, as nearly all data are: one coarse median more)
        median = _coarse_acc_median(acc)
        seen = acc_unit_of(median)
        if seen == "mg":
            raise InputError(
                f"acc looks like it is in mg (median norm {np.median(_acc_norms(acc)):.3g}); fusionkit expects "
                "m/s^2: pass acc_unit='mg' to convert (or divide it by 1000 and pass acc_unit='g')")
        if seen == "far":
            raise InputError(_acc_far(median))
    share, p99 = _gyr_fast_share(gyr) if check_range else (0.0, 0.0)
    fast = share > 0.01  # more than 1 % of the components beyond any gyro's range in rad/s
    converted = "" if gyr_unit == "rad/s" else f", converted from gyr_unit={gyr_unit!r},"
    if gyr_unit != "rad/s" and ((gyr_hi is not None and gyr_hi > 0) or fast):  # still too fast once converted: the
        smaller = {"deg/s": "mdeg/s", "rad/s": "mrad/s"}.get(gyr_unit)  # data's unit is smaller than the one said
        raise InputError(
            f"gyr{converted} is still faster than a gyroscope turns (median |component| "
            f"{np.median(_gyr_abs(gyr)):.3g} rad/s, 99th percentile {p99:.3g}): its unit is smaller than "
            f"{gyr_unit}" + (f": if it is in {smaller}, pass gyr_unit={smaller!r}" if smaller else "")
            + "; raw counts: divide by the sensitivity")
    if gyr_hi is not None and gyr_hi > 0 and not p99 * DEG > GYR_RATE_BOUND:
        raise InputError(
            f"gyr{converted} looks like it is in deg/s (median |component| {np.median(_gyr_abs(gyr)):.3g} > 2 pi "
            "rad/s); fusionkit expects rad/s: pass gyr_unit='deg/s' to convert"
            + (f" (or gyr_unit='mrad/s' if it is in mrad/s: its 99th percentile of |component|, {p99:.3g}, is beyond "
               "the 35-70 rad/s of the widest gyro ranges)" if fast else "")
        )
    if dt is not None or t is not None:  # (a deg/s gyro told by its turning before the range says "mrad/s")
        check_turning(gyr, acc, mag, dt, t=t, gyr_unit=gyr_unit)
    if fast:
        raise InputError(
            f"gyr{converted} turns faster than a gyroscope measures in rad/s (99th percentile of |component| "
            f"{p99:.3g} rad/s; the widest ranges are 35-70 rad/s, 2000-4000 deg/s): if it is in mrad/s pass "
            "gyr_unit='mrad/s', in mdeg/s (mdps) gyr_unit='mdeg/s'"
            + (", in deg/s gyr_unit='deg/s'" if not p99 * DEG > GYR_RATE_BOUND and gyr_unit == "rad/s" else "")
            + "; raw counts: divide by the sensitivity; a gyroscope that does measure this fast: pass "
            "gyr_unit='rad/s' explicitly")


DEG = np.pi / 180.0


def check_turning(gyr: np.ndarray, acc: np.ndarray, mag: np.ndarray | None, dt: np.ndarray | float | None = None,
                  *, t: np.ndarray | None = None, gyr_unit: str = "rad/s") -> None:
    """:class:`InputError` when the magnetometer (or, nearly still, the accelerometer) turns as the
    gyroscope scaled by pi/180 predicts, not as given: a gyro in deg/s that never exceeds the
    magnitude bound of :func:`check_units` (:func:`turning_scale`). With ``gyr_unit="deg/s"``
    (``gyr`` already converted from it), also when they turn as the gyro read before the
    conversion predicts: a gyro in rad/s declared deg/s, mrad/s or mdeg/s (:func:`_check_declared`). The clock
    is ``dt`` (the (N,) intervals, or one constant interval) or ``t`` (the timestamps)."""
    if gyr.shape[0] < 4:
        return
    turns = window_turns(gyr, dt, t=t)
    if gyr_unit != "rad/s":
        _check_declared(turns, acc, mag, gyr_unit)
    for name, vec in (("mag", mag), ("acc", acc)):
        if vec is None:
            continue
        scale = turning_scale(turns, vec, quasi_static=name == "acc")
        # deg/s read as rad/s turns the vector at pi/180 of the gyro's word: a scale near 0 is a
        # vector that does not turn at all (a still sensor with a large gyro bias), not a unit
        if scale is None or not DEG / 4.0 < scale <= np.sqrt(DEG):
            continue
        # the specific force may not follow gravity (a multicopter's thrust stays on its z axis):
        # from it alone, a deg/s gyro must also turn faster than a turn per second as given
        if name == "acc" and _fast_turn_rare(gyr):
            continue
        raise InputError(
            f"gyr looks like it is in deg/s: the {name} turns as the gyro scaled by pi/180 predicts, not as given "
            f"(fitted scale {scale:.3g}, deg/s would be {DEG:.3g}); fusionkit expects rad/s: pass gyr_unit='deg/s' "
            "to convert")


def _check_declared(turns, acc: np.ndarray, mag: np.ndarray | None, unit: str) -> None:
    """:class:`InputError` when a gyro converted from ``unit`` (deg/s, mrad/s, mdeg/s) was in rad/s
    already: the vectors turn 1 / factor times faster than the converted gyro says (180/pi for
    deg/s). The fit of :func:`turning_scale` on the gyro as given (the converted windows divided by
    the factor), whose two hypotheses are then 1 (it was in rad/s) and the factor (the unit was
    right; turning_scale's own second hypothesis is pi/180, as far from 1 as a milli unit's for
    this decision). Silent where nothing turns enough to tell them apart (a recording at rest, a
    turn about gravity seen by the accelerometer alone), and where the vector does not follow the
    gyro at all (a fit near 0: a specific force that stays on the thrust axis, a gyro bias scaled
    by 180/pi on a still sensor)."""
    factor = GYR_UNITS[unit]
    i0, i1, th, duration = turns
    given = (i0, i1, th / factor, duration)
    for name, vec in (("mag", mag), ("acc", acc)):
        if vec is None:
            continue
        scale = turning_scale(given, vec, quasi_static=name == "acc")
        # the geometric middle of rad/s and deg/s, mirroring check_turning's bounds
        if scale is None or not np.sqrt(DEG) <= scale < 4.0:
            continue
        raise InputError(
            f"gyr looks like it is in rad/s already: the {name} turns {scale / factor:.3g} times as fast as the gyro "
            f"converted from {unit} predicts (a gyro in rad/s would give {1 / factor:.3g}, a right unit 1), but "
            f"gyr_unit={unit!r} multiplies it by {'pi/180' if unit == 'deg/s' else f'{factor:.3g}'}: leave gyr_unit out")


def _fast_turn_rare(gyr: np.ndarray) -> bool:
    """The gyro as given turns faster than a turn per second on fewer than 1% of its samples."""
    g = gyr[:: max(1, gyr.shape[0] // 3000)]
    w = np.linalg.norm(g[np.isfinite(g).all(axis=1)], axis=1)
    return bool(w.size) and float(np.percentile(w, 99)) < 2 * np.pi


# The turning check reads at most ``max_windows`` short windows of the recording. On numpy (small
# recordings, and the reference) that is a few dozen array operations on (windows, lag, 3)
# gathers; a long recording takes the compiled twins below (:func:`_window_integrals`,
# :func:`_turning_sums`), which compute the same sums window by window (tests: same decisions).
_CLOCK_RATE, _CLOCK_DT, _CLOCK_T = 0, 1, 2


def _clock(dt, t):
    """``(mode, array)`` of a recording's clock: a constant interval (``dt`` a number: no array
    the size of the recording), the intervals ``dt`` or the timestamps ``t``."""
    if t is not None:
        return _CLOCK_T, np.ascontiguousarray(t, dtype=np.float64)
    if dt is None:
        raise InputError("the turning check needs the clock: dt or t")
    if np.ndim(dt) == 0:
        return _CLOCK_RATE, np.full(1, float(dt))
    return _CLOCK_DT, np.ascontiguousarray(dt, dtype=np.float64)


def _intervals_at(mode: int, clock: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``dt[idx]`` (``dt[k] = t[k] - t[k-1]``, ``dt[0] = dt[1]``) without the (N,) array of
    intervals."""
    if mode == _CLOCK_RATE:
        return np.full(idx.shape, clock[0])
    if mode == _CLOCK_DT:
        return clock[idx]
    k = np.maximum(idx, 1)
    return clock[k] - clock[k - 1]


def window_turns(gyr: np.ndarray, dt: np.ndarray | float | None = None, window: float = 0.05,
                 max_windows: int = 3000, *, t: np.ndarray | None = None):
    """The gyro's rotation vectors over windows of about ``window`` s: ``(i0, i1, th, duration)``,
    ``th[j]`` the integral of ``w dt`` over ``(t[i0[j]], t[i1[j]]]`` (NaN over a non-finite
    sample or a timestamp gap). Consecutive windows, or ``max_windows`` of them spread evenly over
    a long recording: enough for the fit, and nothing the size of the recording is allocated.
    The clock is ``dt`` (the (N,) intervals, or one constant interval) or ``t`` (timestamps)."""
    n = gyr.shape[0]
    mode, clock = _clock(dt, t)
    h = float(np.median(_intervals_at(mode, clock, np.arange(0, n, max(1, n // 1000)))))
    lag = max(1, int(round(window / h)))
    i0 = np.arange(0, max(0, n - lag), lag)
    if i0.size > max_windows:
        i0 = i0[np.linspace(0, i0.size - 1, max_windows).astype(np.int64)]
    i1 = i0 + lag
    if HAVE_NUMBA and n >= SCAN_MIN_SAMPLES:
        return i0, i1, _window_integrals(gyr, mode, clock, i0, lag, h), lag * h
    idx = i0[:, None] + 1 + np.arange(lag)[None, :]  # the samples whose rates span each window
    with np.errstate(over="ignore", invalid="ignore"):
        d = _intervals_at(mode, clock, idx)
        th = np.einsum("wk,wkc->wc", d, gyr[idx]) if i0.size else np.zeros((0, 3))
        span = d.sum(axis=1)
    th[np.abs(span - lag * h) > 0.5 * lag * h] = np.nan  # a window over a timestamp gap is left out
    return i0, i1, th, lag * h


@njit
def _window_integrals(gyr, mode, clock, i0, lag, h):
    """:func:`window_turns`'s ``th``, window by window (no gathered copies)."""
    th = np.empty((i0.shape[0], 3))
    for j in range(i0.shape[0]):
        s0 = s1 = s2 = span = 0.0
        for k in range(i0[j] + 1, i0[j] + 1 + lag):
            if mode == _CLOCK_RATE:
                d = clock[0]
            elif mode == _CLOCK_DT:
                d = clock[k]
            else:
                d = clock[k] - clock[k - 1]
            s0 += d * gyr[k, 0]
            s1 += d * gyr[k, 1]
            s2 += d * gyr[k, 2]
            span += d
        if abs(span - lag * h) > 0.5 * lag * h:  # a window over a timestamp gap is left out
            s0 = s1 = s2 = np.nan
        th[j, 0], th[j, 1], th[j, 2] = s0, s1, s2
    return th


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
    sums = _turning_sums if HAVE_NUMBA and vec.shape[0] >= SCAN_MIN_SAMPLES else _turning_sums_numpy
    count, e_rad, e_deg, s_dp, s_pp = sums(th, vec, i0, i1, min_rate * duration, quasi_static)
    if count < 10:
        return None
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        c = float(np.float64(s_dp) / np.float64(s_pp))
    if not (np.isfinite(c) and (e_deg < 0.25 * e_rad or e_rad < 0.25 * e_deg)):
        return None
    return c


def _turning_sums_numpy(th, vec, i0, i1, min_turn, quasi_static):
    """``(count, e_rad, e_deg, sum du.p, sum p.p)`` of :func:`turning_scale` over the windows
    whose ends are usable and whose predicted turn ``|p|`` exceeds ``min_turn``."""
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
        use = np.linalg.norm(p, axis=1) > min_turn
        p, du = p[use], du[use]
        return (int(use.sum()), float(np.sum((du - p) ** 2)), float(np.sum((du - DEG * p) ** 2)),
                float(np.sum(du * p)), float(np.sum(p * p)))


@njit
def _turning_sums(th, vec, i0, i1, min_turn, quasi_static):
    """:func:`_turning_sums_numpy`, window by window (the median by sorting: np.median would make
    numba's cache load import its array-math module, a tenth of a second in a new process)."""
    w = i0.shape[0]
    n0, n1 = np.empty(w), np.empty(w)
    ok = np.zeros(w, np.bool_)
    good = 0
    for j in range(w):
        a, b = i0[j], i1[j]
        n0[j] = math.sqrt(vec[a, 0] * vec[a, 0] + vec[a, 1] * vec[a, 1] + vec[a, 2] * vec[a, 2])
        n1[j] = math.sqrt(vec[b, 0] * vec[b, 0] + vec[b, 1] * vec[b, 1] + vec[b, 2] * vec[b, 2])
        ok[j] = (math.isfinite(th[j, 0]) and math.isfinite(th[j, 1]) and math.isfinite(th[j, 2])
                 and math.isfinite(n0[j]) and math.isfinite(n1[j]) and n0[j] > 0.0 and n1[j] > 0.0)
        good += ok[j]
    if quasi_static and good > 0:
        s = np.sort(n0[ok])
        m = s[good // 2] if good % 2 else (s[good // 2 - 1] + s[good // 2]) / 2.0  # as np.median
        for j in range(w):
            ok[j] = ok[j] and abs(n0[j] - m) < 0.1 * m and abs(n1[j] - m) < 0.1 * m
    count = 0
    e_rad = e_deg = s_dp = s_pp = 0.0
    for j in range(w):
        if not ok[j]:
            continue
        a, b = i0[j], i1[j]
        u0, u1, u2 = vec[a, 0] / n0[j], vec[a, 1] / n0[j], vec[a, 2] / n0[j]
        d0, d1, d2 = vec[b, 0] / n1[j] - u0, vec[b, 1] / n1[j] - u1, vec[b, 2] / n1[j] - u2
        t0, t1, t2 = th[j, 0], th[j, 1], th[j, 2]
        p0, p1, p2 = -(t1 * u2 - t2 * u1), -(t2 * u0 - t0 * u2), -(t0 * u1 - t1 * u0)
        pp = p0 * p0 + p1 * p1 + p2 * p2
        if not math.sqrt(pp) > min_turn:
            continue
        count += 1
        e_rad += (d0 - p0) ** 2 + (d1 - p1) ** 2 + (d2 - p2) ** 2
        e_deg += (d0 - DEG * p0) ** 2 + (d1 - DEG * p1) ** 2 + (d2 - DEG * p2) ** 2
        s_dp += d0 * p0 + d1 * p1 + d2 * p2
        s_pp += pp
    return count, e_rad, e_deg, s_dp, s_pp
