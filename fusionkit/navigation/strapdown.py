"""Strapdown velocity and position integration (source 004, Pitts S-2B parabolic flight).

Per sample ``k`` (rate ``1/dt``):

* attitude ``C`` (body -> earth) by the exact Rodrigues increment of the rate held over the
  sample, ``C <- C (I + sin(s)/s B + (1 - cos s)/s^2 B^2)``, ``B = [w dt x]``, ``s = |w dt|``
  (or an attitude given from elsewhere, e.g. a filter's result); as everywhere in fusionkit,
  sample ``k``'s rate is held over ``(t[k-1], t[k]]`` and ``dt[k] = t[k] - t[k-1]``;
* acceleration in the earth frame ``a = C f + g_vec`` (specific force plus gravity: "1 g is
  subtracted from the vertical");
* trapezoidal integration ``v += (a_k + a_{k+1}) dt / 2``, ``p += (v_k + v_{k+1}) dt / 2``
  from the initial velocity and position;
* optionally a GNSS fix resets velocity and position at its epochs (source 004: "GNSS fixes
  should reset the integration").

Around it: :func:`design_prefilter` (the document's low-pass FIR against engine vibration: pass
band edge 0.1 rad/sample, stop band 0.8 rad/sample, 1 dB ripple, deep stop-band attenuation),
applied to gyro and accelerometer before integration, and :func:`highpass` against drift after
integration (with its start transient).

Error laws (``tests/test_strapdown.py``): a tilt error ``eps`` puts ``g sin(eps)`` on the
horizontal axes, so the position error grows as ``g sin(eps) t^2 / 2``: 3.86 m after 30 s for
0.05 deg. The document says 7.7 m, which is ``g sin(eps) t^2`` (the 1/2 of the double integral
is missing there). An accelerometer bias ``d0`` gives ``d0 t`` in velocity and ``d0 t^2 / 2`` in
position.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field

import numpy as np

from .._kernels import dcm_to_quat, matmul3_into, quat_to_dcm, rodrigues_into
from .._numba import njit, resolve_backend
from ..conventions import check_frame, up_vector
from ..errors import InputError
from ..rotations import matrix_to_quat, quat_to_matrix, rodrigues
from ..types import Result
from ..validation import _no_bool, as_vector, as_vectors, check_positive, finite_rows

__all__ = ["velocity_increment", "design_prefilter", "prefilter", "highpass", "strapdown", "StrapdownResult"]


def velocity_increment(c_earth_body, f_sum_dt, gravity_up, duration):
    """Earth-frame velocity change ``C (sum f dt) - g_up * T`` over a window of length ``T``.

    ``c_earth_body`` (3, 3) body->earth matrix held over the window, ``f_sum_dt`` the body-frame
    specific force integrated over it (m/s), ``gravity_up`` the specific force at rest in earth
    coordinates (e.g. ``[0, g, 0]`` in source 000's N-Up-E frame), ``duration`` T in s. Source
    000's velocity-integral motion criterion is this increment.
    """
    return np.asarray(c_earth_body) @ np.asarray(f_sum_dt) - np.asarray(gravity_up) * duration


# ---- filters around the integration ---------------------------------------------------------------


def design_prefilter(pass_edge: float = 0.1, stop_edge: float = 0.8, ripple_db: float = 1.0,
                     attenuation_db: float = 60.0, max_taps: int = 201) -> np.ndarray:
    """Source 004's low-pass FIR (equiripple, ``scipy.signal.remez``): the fewest taps meeting
    the specification. Edges in rad/sample (0.1 and 0.8 in the document)."""
    from scipy import signal

    if not 0 < pass_edge < stop_edge < math.pi:
        raise InputError(f"need 0 < pass_edge < stop_edge < pi rad/sample, got {pass_edge}, {stop_edge}")
    dp = (10 ** (ripple_db / 20) - 1) / (10 ** (ripple_db / 20) + 1)
    ds = 10 ** (-attenuation_db / 20)
    bands = [0.0, pass_edge / (2 * math.pi), stop_edge / (2 * math.pi), 0.5]
    for numtaps in range(5, max_taps + 1, 2):
        h = signal.remez(numtaps, bands, [1.0, 0.0], weight=[1.0 / dp, 1.0 / ds], fs=1.0)
        w, resp = signal.freqz(h, worN=4096)
        mag = np.abs(resp)
        passband, stopband = mag[w <= pass_edge], mag[w >= stop_edge]
        if 20 * np.log10(passband.max() / passband.min()) <= ripple_db and stopband.max() <= ds * 1.0001:
            return h
    raise InputError(f"no FIR up to {max_taps} taps meets the specification")


def prefilter(x: np.ndarray, taps: np.ndarray | None = None, zero_phase: bool = True) -> np.ndarray:
    """Low-pass each column of ``x`` (N, 3) with the FIR ``taps`` (default: the document's).

    ``zero_phase`` (default, offline processing as in the document) runs it forwards and
    backwards (no delay; the magnitude response is squared); otherwise a causal FIR with a
    delay of ``(len(taps) - 1) / 2`` samples.
    """
    from scipy import signal

    h = design_prefilter() if taps is None else np.asarray(taps, dtype=float)
    x = np.asarray(x, dtype=float)
    if zero_phase:
        if x.shape[0] <= 3 * len(h):
            raise InputError(f"prefilter needs more than {3 * len(h)} samples, got {x.shape[0]}")
        return signal.filtfilt(h, [1.0], x, axis=0)
    return signal.lfilter(h, [1.0], x, axis=0)


def highpass(x: np.ndarray, cutoff: float, rate: float, order: int = 2) -> np.ndarray:
    """Butterworth high-pass (zero phase) of each column against integration drift. It has a
    start transient of a few ``1 / cutoff``: the first samples are not meaningful."""
    from scipy import signal

    if not 0 < cutoff < rate / 2:
        raise InputError(f"cutoff must be in (0, rate/2) = (0, {rate / 2}) Hz, got {cutoff}")
    sos = signal.butter(order, cutoff, btype="highpass", fs=rate, output="sos")
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float), axis=0)


# ---- the integration -------------------------------------------------------------------------


@dataclass
class StrapdownResult:
    """Velocity (N, 3) m/s and position (N, 3) m in ``frame``, the attitude used (N, 4) body ->
    ``frame``, and which samples a GNSS fix reset."""

    vel: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    frame: str
    reset: np.ndarray
    diagnostics: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        """A one-line summary (samples, frame, GNSS resets, the final velocity and position), never the arrays."""
        n = len(self.vel)
        last = (f"; final velocity {np.round(self.vel[-1], 3).tolist()} m/s, position "
                f"{np.round(self.pos[-1], 2).tolist()} m" if n else "")
        return (f"StrapdownResult({n} samples, {self.frame}, {int(np.count_nonzero(self.reset))} GNSS resets{last}; "
                f"diagnostics: {', '.join(sorted(self.diagnostics))})")


def strapdown(gyr, acc, dt, *, quat0=None, attitude=None, vel0=(0.0, 0.0, 0.0), pos0=(0.0, 0.0, 0.0),
              gravity: float = 9.81, frame: str | None = None, fixes=None, backend: str = "auto") -> StrapdownResult:
    """Integrate specific force ``acc`` (N, 3, m/s^2, body) to velocity and position.

    Attitude: integrate ``gyr`` (N, 3, rad/s) from ``quat0`` (body->``frame``), or take
    ``attitude`` as given: an (N, 4) array body->``frame``, or a filter's :class:`~fusionkit.Result`.
    A Result states its own frame, so it is re-expressed in ``frame`` (exact; an ENU result
    integrated as NED quaternions was 62 m off on heli_cruise instead of 8 m), and ``frame``
    left out is the Result's (else ENU). Quaternions (``quat0``, ``attitude``'s rows) are
    normalised as everywhere in fusionkit; a zero or non-finite one is an :class:`InputError`.
    ``dt`` is the sample interval (s, finite, > 0) or an (N,) array of ``t[k] - t[k-1]`` (its
    first entry is not used: nothing is integrated before sample 0).
    ``fixes``: optional ``(index, vel (3,), pos (3,))`` rows (e.g. GNSS epochs mapped to samples,
    ``index`` an integer sample number): at those samples velocity and position are reset to the
    fix (NaN components are kept). There is no ``nan_policy`` here: a non-finite ``acc`` or
    ``gyr`` sample would make every later velocity and position NaN, so it is an
    :class:`InputError` naming the first such sample.
    """
    acc = as_vectors("acc", acc)
    n = acc.shape[0]
    if n == 0:
        raise InputError("acc has no samples: give at least one (N, 3) row")
    dts = _intervals(dt, n)
    if attitude is None:
        if quat0 is None or gyr is None:
            raise InputError("give attitude=(N, 4), or gyr and quat0 to integrate it")
        gyr = as_vectors("gyr", gyr)
        if gyr.shape != acc.shape:
            raise InputError(f"gyr has shape {gyr.shape}, acc {acc.shape}: they must match")
        _finite_rows("gyr", gyr)
        q0 = _unit_quats("quat0", as_vector("quat0", quat0, 4)[None, :], one=True)[0]
        att = None
        frame = "ENU" if frame is None else frame
    else:
        if isinstance(attitude, Result):  # (float() of a Result raised a TypeError naming nothing)
            frame = attitude.frame if frame is None else frame
            att = np.ascontiguousarray(attitude.to_frame(check_frame(frame)), dtype=float)
        else:
            shape = np.shape(attitude)  # (as_vectors makes one quaternion (4,) a row: named as given)
            att = as_vectors("attitude", attitude, width=4)
        if att.shape != (n, 4):
            given = att.shape if isinstance(attitude, Result) else shape
            raise InputError(f"attitude must have shape ({n}, 4), one quaternion per acc sample, got {given}")
        att = _unit_quats("attitude", att)
        frame = "ENU" if frame is None else frame
    _finite_rows("acc", acc)
    v0, p0 = as_vector("vel0", vel0), as_vector("pos0", pos0)
    _finite_rows("vel0", v0[None, :], one=True)
    _finite_rows("pos0", p0[None, :], one=True)
    g_vec = -_gravity(gravity) * up_vector(check_frame(frame))
    fix_idx, fix_val = _fixes(fixes, n)
    used = resolve_backend(backend, True)
    vel, pos, quat = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 4))
    c0 = quat_to_matrix(q0 if att is None else att[0]).reshape(9).copy()
    if used == "numba":
        _strapdown_kernel(gyr if att is None else np.zeros((n, 3)), acc, dts,
                          att if att is not None else np.zeros((n, 4)), att is not None, c0, v0, p0, g_vec, fix_idx,
                          fix_val, vel, pos, quat)
    else:
        c = c0.reshape(3, 3)
        v, p = v0.copy(), p0.copy()
        a_prev = None
        for k in range(n):
            if k > 0:  # the attitude at sample k: Rodrigues step over (t[k-1], t[k]] with sample k's rate
                c = quat_to_matrix(att[k]) if att is not None else c @ rodrigues(gyr[k] * dts[k])
            a = c @ acc[k] + g_vec
            if k > 0:  # trapezoidal rule over the same interval
                v_new = v + 0.5 * (a_prev + a) * dts[k]
                p = p + 0.5 * (v + v_new) * dts[k]
                v = v_new
            if fix_idx[k] >= 0:
                fv = fix_val[fix_idx[k]]
                v = np.where(np.isfinite(fv[:3]), fv[:3], v)
                p = np.where(np.isfinite(fv[3:]), fv[3:], p)
            a_prev = a
            vel[k], pos[k] = v, p
            quat[k] = matrix_to_quat(c)
    return StrapdownResult(vel, pos, quat, frame, fix_idx >= 0, {"backend": used})


@njit(cache=True)
def _strapdown_kernel(gyr, acc, dts, att, given, c0, v0, p0, g_vec, fix_idx, fix_val, vel, pos, quat):
    c = c0.copy()
    r = np.empty(9)
    t = np.empty(9)
    v = v0.copy()
    p = p0.copy()
    a_prev = np.zeros(3)
    a = np.zeros(3)
    q = np.empty(4)
    for k in range(acc.shape[0]):
        if k > 0:
            if given:
                quat_to_dcm(att[k], c)
            else:
                h = dts[k]
                rodrigues_into(gyr[k, 0] * h, gyr[k, 1] * h, gyr[k, 2] * h, r)
                matmul3_into(c, r, t)
                for i in range(9):
                    c[i] = t[i]
        for i in range(3):
            a[i] = c[3 * i] * acc[k, 0] + c[3 * i + 1] * acc[k, 1] + c[3 * i + 2] * acc[k, 2] + g_vec[i]
        if k > 0:
            h = dts[k]
            for i in range(3):
                v_new = v[i] + 0.5 * (a_prev[i] + a[i]) * h
                p[i] = p[i] + 0.5 * (v[i] + v_new) * h
                v[i] = v_new
        j = fix_idx[k]
        if j >= 0:
            for i in range(3):
                if math.isfinite(fix_val[j, i]):
                    v[i] = fix_val[j, i]
                if math.isfinite(fix_val[j, 3 + i]):
                    p[i] = fix_val[j, 3 + i]
        for i in range(3):
            a_prev[i] = a[i]
            vel[k, i] = v[i]
            pos[k, i] = p[i]
        dcm_to_quat(c, q)
        quat[k, 0], quat[k, 1], quat[k, 2], quat[k, 3] = q[0], q[1], q[2], q[3]


def _finite_rows(name: str, x: np.ndarray, one: bool = False) -> None:
    """An :class:`InputError` naming the first row of ``x`` with a NaN or inf (``one``: ``x`` is
    one vector, named without an index): one such sample makes every later velocity and position
    NaN (or inf), silently."""
    ok = finite_rows(x)
    if not ok.all():
        i = int(np.argmin(ok))
        raise InputError(f"{name if one else f'{name}[{i}]'} is not finite ({x[i].tolist()}): strapdown "
                         "integrates it into every later velocity and position; clean or cut the data first")


def _unit_quats(name: str, q: np.ndarray, one: bool = False) -> np.ndarray:
    """``q`` (N, 4) with unit rows (normalised where off by more than rounding, as ``quat0`` always
    was and a Recording's truth is); a non-finite or zero row is an :class:`InputError` by index
    (``quat_to_matrix`` of a zero quaternion is all zeros: no gravity removed; of ``3 q`` nine
    times the rotation)."""
    _finite_rows(name, q, one)
    n2 = np.einsum("ij,ij->i", q, q)
    if (n2 == 0.0).any():
        i = int(np.argmax(n2 == 0.0))
        raise InputError(f"{name if one else f'{name}[{i}]'} is a zero quaternion: no orientation")
    off = np.abs(n2 - 1.0) > 2e-9
    if off.any():
        q = q.copy()
        q[off] /= np.sqrt(n2[off])[:, None]
    return q


def _intervals(dt, n: int) -> np.ndarray:
    """``dt`` (a number or (N,) array of s) as (N,) intervals; every interval used (a scalar, or an
    array's entries from 1 on) finite and > 0: a negative one ran the integration backwards, a
    zero one stood still, a NaN one made every later sample NaN."""
    if np.ndim(dt) == 0:
        return np.full(n, check_positive("dt", dt))
    _no_bool("dt", dt, " (sample intervals in s)")
    try:
        dts = np.ascontiguousarray(dt, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"dt must be a number or an ({n},) array of intervals in s: {exc}") from None
    if dts.shape != (n,):
        raise InputError(f"dt must be a number or have shape ({n},), got {np.shape(dt)}")
    bad = ~(np.isfinite(dts[1:]) & (dts[1:] > 0))
    if bad.any():
        i = int(np.argmax(bad)) + 1
        raise InputError(f"dt[{i}] is {float(dts[i])!r}: every sample interval must be a finite number > 0 s "
                         "(dt[0] is not used)")
    return dts


def _gravity(gravity) -> float:
    """``gravity`` (m/s^2) checked: a finite number >= 0. Zero is an acceleration with gravity
    already removed (a phone's linear acceleration), integrated as it is."""
    if isinstance(gravity, (bool, np.bool_, str, bytes)) or np.ndim(gravity) != 0:
        raise InputError(f"gravity must be one finite number >= 0 (m/s^2), got {gravity!r:.80}")
    try:
        g = float(gravity)
    except (TypeError, ValueError):
        raise InputError(f"gravity must be one finite number >= 0 (m/s^2), got {gravity!r:.80}") from None
    if not (math.isfinite(g) and g >= 0.0):
        raise InputError(f"gravity must be one finite number >= 0 (m/s^2), got {gravity!r:.80}")
    return g


def _fixes(fixes, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``fixes`` as (per-sample row number or -1, (M, 6) velocity and position), each row checked:
    an integer index in ``0..n-1``, a velocity and a position of 3 numbers each (NaN: kept)."""
    fix_idx = np.full(n, -1, dtype=np.int64)
    if fixes is None:
        return fix_idx, np.full((0, 6), np.nan)
    rows = list(fixes)
    fix_val = np.empty((len(rows), 6))
    for j, row in enumerate(rows):
        try:
            i, v, p = row
        except (TypeError, ValueError):
            raise InputError(f"fixes[{j}] must be (index, vel (3,), pos (3,)), got {row!r:.80}") from None
        if isinstance(i, (bool, np.bool_)):
            raise InputError(f"fixes[{j}]'s index must be an integer sample number, got {i!r}")
        try:
            k = operator.index(i)
        except TypeError:  # a float that is a whole number (np.round's 3.0) is that sample; 3.5 is none
            if not (isinstance(i, (float, np.floating)) and math.isfinite(i) and float(i).is_integer()):
                raise InputError(f"fixes[{j}]'s index must be an integer sample number, got {i!r:.40} "
                                 "(map times to samples with np.searchsorted)") from None
            k = int(i)
        if not 0 <= k < n:
            raise InputError(f"fixes[{j}]: fix index {k} outside 0..{n - 1}")
        fix_val[j, :3] = as_vector(f"fixes[{j}] velocity", v)
        fix_val[j, 3:] = as_vector(f"fixes[{j}] position", p)
        fix_idx[k] = j
    return fix_idx, fix_val
