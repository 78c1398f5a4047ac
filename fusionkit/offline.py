"""Offline (acausal) mode: a filter run forward and backward in time, the two estimates fused.

``fk.make("recommended", offline=True)`` wraps a filter in :class:`OfflineFilter`. For a recording
processed after the fact, every sample's orientation can use the samples after it too:

1. **forward pass**: the filter's own ``run(rec, state=...)``.
2. **backward pass**: the same filter on the time-reversed recording (:func:`reverse_recording`:
   samples in reverse order, gyroscope negated). Gyro sample ``k``'s step covers
   ``(t[k-1], t[k]]``; reversed, the same step runs from ``t[k]`` back to ``t[k-1]``, so the
   backward pass's output after its sample ``j`` (sample ``m = N-1-j`` of the recording) is the
   orientation at ``t[m-1]``: the forward output of sample ``m - 1``. A sensor paired with the
   middle of the step (``acc_delay`` / ``mag_delay`` None) stays in the middle; one paired ``d``
   before the end of the step is, reversed, ``dt - d`` before the end of the reversed step, so
   the backward filter's ``acc_delay`` / ``mag_delay`` are mirrored (:func:`reversed_config`).
   A gyro-only pass reversed reproduces the forward orientations to rounding (tested).
3. **fusion**, per sample, of the two estimates by their *information*: each pass's estimate of
   inclination (heading) is an exponentially weighted average of the accelerometer
   (magnetometer) with the filter's time constant ``tau_acc`` (``tau_mag``), started from
   nothing. Its information, relative to the steady state, follows
   ``I <- I exp(-dt/tau) + (1 - exp(-dt/tau)) [the sensor was used]``: it rises from 0 at the
   pass's start (or after a timestamp gap, where the filter re-levels), and it decays while the
   filter rejects the sensor (a magnetic disturbance, an invalid or rejected sample), as the
   pass then coasts on the gyroscope. The backward estimate's weight is ``I_b / (I_f + I_b)``
   (1/2 where both are 0), applied separately to the inclination and the heading: the
   difference ``q_b (x) q_f^-1`` (earth frame) is split into a rotation about the vertical
   (heading) and one about a horizontal axis (inclination), and each is taken by its weight.
   Without a magnetometer (6D) the heading of either pass is arbitrary: the heading is the
   forward pass's, only the inclination is fused.

What the fusion does, physically: the two passes' errors from linear accelerations, from
magnetometer noise and from a gyro bias not yet learned come from the past and from the future
respectively, so they are partly independent and average down (a bias error drifts the two
passes in opposite directions and cancels to first order); the start of a recording, where the
forward pass has not converged, is taken from the backward pass (and the end from the forward
one); a pass that rejected the magnetometer for long gives way to the one that saw it last. What
it does not do: a gyroscope late against the time base lags *both* passes alike (each integrates
the same delayed rate, anchored where the recording is still), so that delay stays (the
filter's ``output_lead`` is the answer to it, offline too).

**Magnetic disturbances decided with the whole recording** (``disturbance_gap``, default 1 s;
None: off): a sample either pass rejected, and every sample between two such samples at most
``disturbance_gap`` apart, is left out of both passes, which then run again
(:func:`disturbance_mask`). Online, the detector judges each sample on its own and lets through
the samples of a disturbance whose field happens to pass its norm and dip test; offline, the
disturbance around them is known. Costs two more passes where a sample is left out that a pass
had used.

Flags: REST where either pass detects rest (the future confirms a rest the past could not yet
see), MAG_DISTURBED where the magnetometer was left out (the mask above) or both passes reject it
(VQF's offline rule), the other bits where either pass sets them.

The readable reference is :func:`fuse_reference`; :func:`_fuse_kernel` (numba) does the same
arithmetic (tests hold them to 1e-9).
"""

from __future__ import annotations

import copy
import math
from typing import ClassVar

import numpy as np

from ._numba import resolve_backend, njit
from .config import FilterConfig
from .conventions import change_frame
from .errors import ConfigError, InputError, PluginError
from .protocols import Filter
from .rotations import quat_conj, quat_from_rotvec, quat_mul, quat_to_rotvec
from .types import Flag, Recording, Result

__all__ = ["OfflineFilter", "reverse_recording", "reversed_config", "information", "fuse_reference",
           "supports_offline", "disturbance_mask"]

#: the bits that mean a pass did not use its accelerometer / magnetometer on a sample
_ACC_UNUSED = int(Flag.ACC_INVALID | Flag.ACC_SATURATED | Flag.ACC_REJECTED)
_MAG_UNUSED = int(Flag.MAG_INVALID | Flag.MAG_DISTURBED)
#: bits after which a filter restarts its inclination (timestamp gap): the information restarts
_RESTART = int(Flag.GAP)


def supports_offline(filt: Filter) -> str | None:
    """None when ``filt`` can run offline, else why not. A filter can when it streams (it is not
    itself offline), runs ``run(rec, state=...)``, and declares how it pairs its accelerometer
    and magnetometer with the gyro's step (``acc_delay`` / ``mag_delay`` in its config): only then
    is its time-reversed pass exact (:func:`reversed_config`)."""
    if isinstance(filt, OfflineFilter) or not getattr(type(filt), "streaming", True):
        return "it is already an offline filter"
    if getattr(filt, "requires_gnss", False):
        return "it needs a GNSS stream, which is not time-reversible (velocities, epochs)"
    missing = [k for k in ("acc_delay", "mag_delay", "tau_acc") if not hasattr(filt.config, k)]
    if missing:
        return (f"its config does not declare {', '.join(missing)}: the backward pass needs the sensors' pairing "
                "with the gyro's step (acc_delay, mag_delay) and the inclination time constant (tau_acc)")
    return None


def reversed_config(filt: Filter, dt: float) -> FilterConfig:
    """The config of the backward pass: the forward one with the pairing mirrored. A sensor paired
    ``d`` before the end of the gyro's step (``acc_delay`` / ``mag_delay``) is, in reversed time,
    ``dt - d`` before the end of the reversed step; None (the middle) stays None."""
    c = filt.config
    update = {}
    for key in ("acc_delay", "mag_delay"):
        d = getattr(c, key)
        if d is None:
            continue
        if not 0.0 <= d <= dt * (1.0 + 1e-9):
            raise ConfigError(f"offline: {key}={d} s is outside [0, dt={dt:.6g} s]: its time-reversed pass "
                              "would pair the sensor with a step the recording does not reverse exactly")
        update[key] = max(dt - d, 0.0)
    return c.model_copy(update=update) if update else c


def reverse_recording(rec: Recording) -> Recording:
    """The recording backwards in time: samples reversed, gyroscope negated. Sample ``j`` of the
    result is sample ``N-1-j`` of ``rec``; its step ends at the time of sample ``N-2-j`` (the step
    reversed), so the timestamps are ``-t`` shifted by one sample (intervals preserved; the first
    reversed interval follows the Recording convention ``dt[0] = dt[1]``). Truth, movement and
    GNSS are not carried over."""
    if not isinstance(rec, Recording):
        raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
    # a shallow copy, not a new Recording: the same samples passed its checks already
    out = copy.copy(rec)
    out.gyr = np.negative(rec.gyr[::-1])
    out.acc = np.ascontiguousarray(rec.acc[::-1])
    out.mag = None if rec.mag is None else np.ascontiguousarray(rec.mag[::-1])
    if rec.t is not None:
        t = rec.t
        tr = np.empty_like(t)
        tr[:-1] = -t[-2::-1]
        tr[-1] = -(t[0] - rec.dt[0])
        out.t = tr
    out.truth = out.movement = out.gnss = None
    out.meta = {}
    out.name = f"{rec.name} (reversed)" if rec.name else "reversed"
    return out


def information(flags: np.ndarray, dt: np.ndarray, tau: float, unused: int, start: float = 0.0) -> np.ndarray:
    """Per sample, the relative information of a pass's exponentially weighted estimate (time
    constant ``tau``) after the sample: ``I <- I exp(-dt/tau) + (1 - exp(-dt/tau))`` when the
    sample's sensor was used (no bit of ``unused`` set), ``I exp(-dt/tau)`` when not; 0 before a
    sample flagged GAP (the filter restarted). ``start``: the information before the first sample."""
    out = np.empty(flags.shape[0])
    info = start
    for k in range(flags.shape[0]):
        if int(flags[k]) & _RESTART:
            info = 0.0
        a = math.exp(-float(dt[k]) / tau)
        info = info * a + ((1.0 - a) if not int(flags[k]) & unused else 0.0)
        out[k] = info
    return out


def fuse_reference(q_f: np.ndarray, q_b: np.ndarray, w_incl: np.ndarray, w_head: np.ndarray) -> np.ndarray:
    """The fused orientation, sample by sample (both ``(N, 4)`` body -> ENU, ``q_b`` already aligned
    with ``q_f``): ``d = q_b (x) q_f^-1 = Rz(psi) (x) T`` (T about a horizontal axis), the result is
    ``Rz(w_head psi) (x) T^w_incl (x) q_f``."""
    out = np.empty_like(q_f)
    for k in range(q_f.shape[0]):
        d = quat_mul(q_b[k], quat_conj(q_f[k]))
        if d[0] < 0.0:
            d = -d
        n = math.hypot(d[0], d[3])
        if n < 1e-12:  # a half-turn about a horizontal axis: no heading part
            tw = np.array([1.0, 0.0, 0.0, 0.0])
        else:
            tw = np.array([d[0] / n, 0.0, 0.0, d[3] / n])
        tilt = quat_mul(quat_conj(tw), d)
        out[k] = quat_mul(quat_mul(_power(tw, w_head[k]), _power(tilt, w_incl[k])), q_f[k])
    return out


def _power(q, w):
    """``q^w`` for a unit quaternion with ``q[0] >= 0``: the rotation scaled by ``w``."""
    s = math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if s < 1e-300:
        return np.array([1.0, 0.0, 0.0, 0.0])
    half = w * math.atan2(s, q[0])
    f = math.sin(half) / s
    return np.array([math.cos(half), q[1] * f, q[2] * f, q[3] * f])


@njit
def _information_kernel(flags, dt, tau, unused, start, out):
    info = start
    last_dt, a = -1.0, 0.0
    for k in range(flags.shape[0]):
        if flags[k] & 2048:  # GAP
            info = 0.0
        if dt[k] != last_dt:  # once per distinct interval
            a = math.exp(-dt[k] / tau)
            last_dt = dt[k]
        info = info * a + ((1.0 - a) if (flags[k] & unused) == 0 else 0.0)
        out[k] = info


@njit
def _qm(p0, p1, p2, p3, q0, q1, q2, q3):
    return (p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3, p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1, p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0)


@njit
def _pow(q0, q1, q2, q3, w):
    s = math.sqrt(q1 * q1 + q2 * q2 + q3 * q3)
    if s < 1e-300:
        return 1.0, 0.0, 0.0, 0.0
    half = w * math.atan2(s, q0)
    f = math.sin(half) / s
    return math.cos(half), q1 * f, q2 * f, q3 * f


@njit
def _fuse_kernel(q_f, q_b, w_incl, w_head, out):
    for k in range(q_f.shape[0]):
        f0, f1, f2, f3 = q_f[k, 0], q_f[k, 1], q_f[k, 2], q_f[k, 3]
        d0, d1, d2, d3 = _qm(q_b[k, 0], q_b[k, 1], q_b[k, 2], q_b[k, 3], f0, -f1, -f2, -f3)
        if d0 < 0.0:
            d0, d1, d2, d3 = -d0, -d1, -d2, -d3
        n = math.hypot(d0, d3)
        if n < 1e-12:
            t0, t3 = 1.0, 0.0
        else:
            t0, t3 = d0 / n, d3 / n
        s0, s1, s2, s3 = _qm(t0, 0.0, 0.0, -t3, d0, d1, d2, d3)
        h0, h1, h2, h3 = _pow(t0, 0.0, 0.0, t3, w_head[k])
        i0, i1, i2, i3 = _pow(s0, s1, s2, s3, w_incl[k])
        a0, a1, a2, a3 = _qm(h0, h1, h2, h3, i0, i1, i2, i3)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = _qm(a0, a1, a2, a3, f0, f1, f2, f3)


class OfflineFilter(Filter):
    """A filter run forward and backward in time, fused by each pass's information (see the
    module docs). Built by ``fk.make(name, offline=True)``; runs whole recordings only."""

    name: ClassVar[str] = "offline"
    streaming: ClassVar[bool] = False
    summary: ClassVar[str] = "a filter run forward and backward in time, fused per sample (acausal)"
    source: ClassVar[str] = "fusionkit (after VQF's offline mode, Laidig and Seel 2023)"

    #: default of ``disturbance_gap`` (s): see :func:`disturbance_mask`
    DISTURBANCE_GAP: ClassVar[float] = 1.0

    def __init__(self, inner: Filter, disturbance_gap: float | None = DISTURBANCE_GAP) -> None:
        why = supports_offline(inner)
        if why is not None:
            raise PluginError(f"filter {inner.name!r} does not support offline=True: {why}")
        if disturbance_gap is not None and not (isinstance(disturbance_gap, (int, float))
                                                and math.isfinite(disturbance_gap) and disturbance_gap >= 0.0):
            raise ConfigError(f"disturbance_gap must be None or a finite number of seconds >= 0, "
                              f"got {disturbance_gap!r}")
        self.inner = inner
        self.disturbance_gap = None if disturbance_gap is None else float(disturbance_gap)
        self.config = inner.config
        self.name = f"{inner.name} (offline)"

    def __repr__(self) -> str:
        return f"OfflineFilter({self.inner!r})"

    def dimension(self, rec) -> str:
        return self.inner.dimension(rec)

    def body_axes(self, rec):
        return self.inner.body_axes(rec)

    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: np.ndarray | None = None) -> Result:
        """Forward pass (from ``state`` when given: an earlier run's ``diagnostics["state"]``),
        backward pass, fusion. How far a given state had converged is not known from it (an earlier
        run that started in motion hands on a poor bias), so the forward pass's information
        counts from this run's first sample either way. ``diagnostics["state"]`` is the forward pass's final
        state (an online run can continue from it); ``diagnostics["backward_weight"]`` holds the
        per-sample weights of the backward pass (``inclination``, ``heading``);
        ``diagnostics["mag_disturbed"]`` the magnetometer samples left out (:func:`disturbance_mask`;
        None without a magnetometer or with ``disturbance_gap=None``); ``backend`` is the passes',
        ``fusion_backend`` the fusion's."""
        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        inner = self.inner
        used = resolve_backend(backend, True)
        lead = float(getattr(inner.config, "output_lead", 0.0) or 0.0)
        if lead > 0.0:  # the passes without it; the fused trajectory is read ahead instead (_read_ahead)
            inner = type(inner)(inner.config.model_copy(update={"output_lead": 0.0}))
        fwd = inner.run(rec, backend=backend, progress=progress, state=state)
        n = len(rec)
        if n < 2:  # nothing after the sample: the forward pass is all there is
            fwd.diagnostics["offline"] = True
            return fwd
        back = type(inner)(reversed_config(inner, rec.nominal_dt))
        bwd = back.run(reverse_recording(rec), backend=backend, progress=progress)
        has_mag = self.dimension(rec) == "9D"
        disturbed = None
        if has_mag and self.disturbance_gap is not None:
            # the disturbances as both passes saw them (the backward pass's flags j are input sample N-1-j)
            disturbed = disturbance_mask(fwd.flags, bwd.flags[::-1], rec.time, self.disturbance_gap)
            took = ((fwd.flags & _MAG_UNUSED) == 0) | ((bwd.flags[::-1] & _MAG_UNUSED) == 0)
            if (disturbed & took).any():  # the passes again, without the disturbed samples either had used
                fwd, bwd = self._without(rec, disturbed, inner, back, backend, progress, state)
        dt = rec.dt
        c = self.config
        # information of each pass in its own time order; the backward one's sample j is input
        # sample N-1-j and its output is the orientation at sample N-2-j
        i_f = self._info(fwd.flags, dt, c.tau_acc, _ACC_UNUSED, 0.0, used)
        i_b = self._info(bwd.flags, dt[::-1].copy(), c.tau_acc, _ACC_UNUSED, 0.0, used)
        w_i = np.empty(n)
        w_h = np.zeros(n)
        q_b = np.empty((n, 4))
        q_b[:-1] = bwd.quat[-2::-1]
        q_b[-1] = fwd.quat[-1]  # the backward pass's initial state: no information
        w_i[:-1] = _weights(i_f[:-1], i_b[-2::-1])
        w_i[-1] = 0.0
        if has_mag:
            tau_mag = getattr(c, "tau_mag", c.tau_acc)
            h_f = self._info(fwd.flags, dt, tau_mag, _MAG_UNUSED, 0.0, used)
            h_b = self._info(bwd.flags, dt[::-1].copy(), tau_mag, _MAG_UNUSED, 0.0, used)
            w_h[:-1] = _weights(h_f[:-1], h_b[-2::-1])
        frame = fwd.frame
        qf = change_frame(fwd.quat, frame, "ENU") if frame != "ENU" else fwd.quat
        qb = change_frame(q_b, frame, "ENU") if frame != "ENU" else q_b
        if used == "numba":
            q = np.empty((n, 4))
            _fuse_kernel(np.ascontiguousarray(qf), np.ascontiguousarray(qb), w_i, w_h, q)
        else:
            q = fuse_reference(qf, qb, w_i, w_h)
        if frame != "ENU":
            q = change_frame(q, "ENU", frame)
        if lead > 0.0:
            q = _read_ahead(q, rec.time, lead)
        flags = _fused_flags(fwd.flags, bwd.flags[::-1])
        diag = dict(fwd.diagnostics)
        diag.update({"filter": self.name, "fusion_backend": used, "offline": True, "config": self.config.model_dump(),
                     "backward_weight": {"inclination": w_i, "heading": w_h}, "mag_disturbed": disturbed,
                     "backward_diagnostics": {k: v for k, v in bwd.diagnostics.items() if k != "config"}})
        return Result(q, flags, frame, diag)

    @staticmethod
    def _without(rec, disturbed, inner, back, backend, progress, state):
        """Both passes on ``rec`` with the magnetometer's ``disturbed`` samples left out (made
        invalid, the passes skipping them); their flags say MAG_DISTURBED there, not MAG_INVALID."""
        masked = copy.copy(rec)  # a shallow copy: the samples passed the Recording's checks already
        masked.mag = rec.mag.copy()
        masked.mag[disturbed] = np.nan
        skip = {"nan_policy": "skip"}
        inner, back = type(inner)(inner.config.model_copy(update=skip)), type(back)(back.config.model_copy(update=skip))
        fwd = inner.run(masked, backend=backend, progress=progress, state=state)
        bwd = back.run(reverse_recording(masked), backend=backend, progress=progress)
        ours = disturbed & np.isfinite(rec.mag).all(axis=1)  # an invalid sample stays MAG_INVALID
        inv, dis = np.uint32(Flag.MAG_INVALID), np.uint32(Flag.MAG_DISTURBED)
        for res, mask in ((fwd, ours), (bwd, ours[::-1])):
            res.flags[mask] = (res.flags[mask] & ~inv) | dis
        return fwd, bwd

    @staticmethod
    def _info(flags, dt, tau, unused, start, used) -> np.ndarray:
        if used == "numba":
            out = np.empty(flags.shape[0])
            _information_kernel(flags, np.ascontiguousarray(dt, dtype=float), float(tau), unused, float(start), out)
            return out
        return information(flags, dt, tau, unused, start)

    def reset(self) -> None:
        self.inner.reset()

    def update(self, gyr, acc, mag=None, dt=None):
        raise PluginError(f"{self.name} is an offline filter: it needs the whole recording (run), it cannot "
                          "stream (update); make the filter without offline=True to stream")

    @property
    def state(self):
        return None

    def set_state(self, state) -> None:
        raise PluginError(f"{self.name} is an offline filter: it has no streaming state; pass state= to run()")


def _read_ahead(q: np.ndarray, t: np.ndarray, lead: float) -> np.ndarray:
    """The trajectory ``q`` (samples at ``t``) at ``t + lead``: interpolated on the geodesic between
    the samples around it (extrapolated by the last step's rotation past the end). A filter's
    ``output_lead`` extrapolates with the gyro rate because online the future is not known;
    offline it is, and the backward pass must not extrapolate (its ahead is the past)."""
    n = q.shape[0]
    i = np.clip(np.searchsorted(t, t + lead, side="right") - 1, 0, n - 2)
    frac = ((t + lead - t[i]) / (t[i + 1] - t[i]))[:, None]
    step = quat_to_rotvec(quat_mul(quat_conj(q[i]), q[i + 1]))
    return quat_mul(q[i], quat_from_rotvec(step * frac))


def disturbance_mask(flags_f: np.ndarray, flags_b: np.ndarray, time: np.ndarray, gap: float) -> np.ndarray:
    """The magnetometer samples the offline mode leaves out, decided with the whole recording:
    those either pass flagged MAG_DISTURBED (``flags_b`` in the recording's order), and those
    between two such samples at most ``gap`` seconds apart.

    Why: a magnetic disturbance (a magnet passing, carried along, a steel object nearby) lasts an
    interval, and inside it the detector judges each sample on its own: where the disturbed
    field's norm and dip happen to fall within the thresholds (the sensor turning through an
    orientation where the disturbance and the earth's field combine so), the sample is accepted
    and pulls the heading by the disturbance. Online a filter cannot know a later sample will be
    disturbed again; offline it can. The price of a gap closed wrongly is small: a clean stretch
    shorter than ``gap`` carries at most ``gap / tau_mag`` of the heading's information, and the
    samples around it and the other pass carry the rest. ``gap = 0``: the union of the passes'
    decisions only."""
    dist = ((flags_f | flags_b) & np.uint32(Flag.MAG_DISTURBED)) != 0
    idx = np.flatnonzero(dist)
    if idx.size < 2 or gap <= 0.0:
        return dist
    close = np.flatnonzero((np.diff(idx) > 1) & (np.diff(time[idx]) <= gap))
    if close.size:
        edges = np.zeros(dist.shape[0] + 1, dtype=np.int64)
        np.add.at(edges, idx[close] + 1, 1)
        np.add.at(edges, idx[close + 1], -1)
        dist |= np.cumsum(edges[:-1]) > 0
    return dist


def _weights(i_f: np.ndarray, i_b: np.ndarray) -> np.ndarray:
    s = i_f + i_b
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(s > 0.0, i_b / np.where(s > 0.0, s, 1.0), 0.5)


def _fused_flags(f: np.ndarray, b: np.ndarray) -> np.ndarray:
    """REST where either pass has it, MAG_DISTURBED where both have it, the rest OR-ed."""
    md = np.uint32(Flag.MAG_DISTURBED)
    return ((f | b) & ~md) | (f & b & md)
