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

**The inclination smoothed in the other direction of time** (``inclination``, default
``"smoothed"``; ``"average"``: the passes fused as they are, the mode before). Before the fusion,
each pass's vertical is low-passed again in the other direction of time with the ``inertial-tilt``
corrector's low-pass and time-constant model (:func:`smooth_reference`), in the frame of the gyro
minus the bias that pass used (:func:`bias_trace`). A pass is ``H`` on the accelerometer and
``1 - H`` on the gyro's errors; the average of two passes is ``Re H``, which for the second-order
Butterworth falls only as ``(f_c / f)^2`` above the cutoff, and ``1 - Re H`` as ``(f / f_c)^2``
below; a pass low-passed again the other way is the forward-backward ``|H|^2 = 1 / (1 + (f / f_c)^4)``,
fourth order on both sides (VQF's offline mode filters the accelerometer so, with a fixed time
constant). What it gives up: a linear acceleration sustained over about the time constant (a walk
that speeds up for seconds) is passed more by ``|H|^2`` than by ``Re H``.

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

**The magnetometer's calibration decided with the whole recording** (``calibration``,
default ``"recording"``). A filter with the ``mag-calibration`` sensor model in front
(``recommended``'s ``mag_calibration``) learns a carried magnet's hard and soft iron online, and a
pass applies what it has learned so far: the forward pass nothing before it has seen enough
rotation, the backward pass nothing at the recording's end; and where the iron changes (a magnet
put on or taken off during the recording), each pass keeps applying, or mixes into its estimate,
the iron of the stretch it came from until its segments contradict it. Each pass's calibration is
right only on one side of such a change, and a pass that applies the other side's calibration
pulls its heading away by the difference. So the offline mode runs the calibration model alone
forward and backward over the recording (:func:`calibration_passes`; cheap next to the filter's
passes), which gives three candidate magnetometer streams: raw, calibrated by the forward model,
calibrated by the backward model. Per sample it takes the stream whose field norm is most nearly
constant over ``CALIBRATION_SPAN`` (half a turn) of the way either side of the sample: the
rotation, and at rest the time at the model's own ``segment_angle / segment_time``
(:func:`select_calibration`): body-fixed iron, correctly removed, leaves the earth's field, whose
norm does not depend on the orientation, while a wrong offset ``e`` makes the norm swing by up to
``2|e|`` over one turn (the same test as the model's consistency gate, with samples from both
sides). Both passes then run on that stream, without the model. ``calibration="per-pass"``: each
pass with its own model, as online (the mode before this).

The two calibration passes gate with the model's norm test (``calibration_test="norm"``, default;
``"model"``: the model's own ``consistency_test``). Online, the model's earth-frame test keeps a
calibration from switching on and off inside an earth-fixed field, because each switch makes
``mag-heading`` learn its reference again there. Here no pass sees a switch: the per-sample choice
above already compares the streams with samples from both sides, and the earth test's later
application and reluctant withdrawal only leave it fewer calibrated stretches to choose from.

**The magnetometer's timing decided with the whole recording** (``mag_timing``, default
``"recording"``). A magnetometer several samples late against the gyroscope (a sensor's filter,
its read-out, a lower rate held) reads the field turned by the rotation over its delay: the
heading error this leaves does not average out over back-and-forth turns about tilted axes
(second order in the rate), and it is the same in both passes, so no fusion removes it; and in
reversed time the delay is a lead, which no causal pairing expresses. The offline mode estimates
the delay over the whole recording from the IMU alone (:func:`mag_delay_recording`, the
``time-offset`` model's estimator without forgetting) and, where it differs from the filter's
pairing by more than ``MAG_DELAY_SIGMAS`` standard deviations, gives both passes a stream with
every sample replaced by the reading nearest its instant, turned by the gyroscope over the time
between (:func:`retime_mag`). It runs after the calibration (the iron does not turn with the
earth's field). The output stays on the gyroscope's clock. ``mag_timing="as-is"``: the stream as
recorded (the mode before).

**The gyroscope's timing against the accelerometer** (``gyro_timing``, default ``"as-is"``;
``"recording"``: an option). A gyroscope late against the accelerometer (its digital low-pass's group
delay, a later sampling instant) lags both passes alike. With ``"recording"`` its delay is estimated
over the whole recording from the IMU alone (:func:`gyro_delay_recording`, the magnetometer's
estimator on gravity's direction) and, where it is one delay (past the same ``MAG_DELAY_SIGMAS``
test, and so is the estimate over ``GYRO_CHECK_SEGMENT`` s segments, and the two agree), the gyro is
moved earlier by it before every other step (:func:`retime_gyro`): the output then follows the
accelerometer's clock. Not the default: the estimate assumes linear accelerations that do not
correlate with the angular acceleration, which a hand-held sensor's do (on BROAD it is several
samples off; the second time scale refuses it there). ``"lever"``: the delay fitted jointly with
the accelerometer's lever arm from the point the body turns about (:func:`gyro_delay_lever`), which
removes the tangential and centripetal accelerations of a sensor turned about a fixed point, and
applied only where the model explains the accelerometer well enough that the worst case of what it
leaves could not undo the move (on BROAD, where the hand's turning point itself accelerates, it is
refused on every trial). A number (s) is a delay the user knows, applied as given.

Flags: REST where either pass detects rest (the future confirms a rest the past could not yet
see), MAG_DISTURBED where the magnetometer was left out (the mask above) or both passes reject it
(VQF's offline rule), the other bits where either pass sets them.

The readable reference is :func:`fuse_reference`; :func:`_fuse_kernel` (numba) does the same
arithmetic (tests hold them to 1e-9); likewise the re-timing (:func:`retime_mag`'s two backends)
and the smoothing (:func:`smooth_reference`, :func:`_smooth_kernel`).
"""

from __future__ import annotations

import copy
import math
import numbers
import warnings
from typing import Any, ClassVar

import numpy as np

from ._kernels import rotvec_quat_exact_entries, validity_all
from ._numba import inline_copy, njit, resolve_backend
from .config import FilterConfig
from .conventions import change_frame
from .errors import ConfigError, InputError, PluginError
from .models.mag_calibration import mag_calibration_apply
from .models.time_offset import ACC, EST, MAG, NSEG, STD, TimeOffsetModel, time_offset_apply
from .protocols import Filter
from .rotations import quat_conj, quat_from_rotvec, quat_mul, quat_to_matrix, quat_to_rotvec, skew
from .types import Flag, GapWarning, Recording, Result, hold_gaps, sample_validity
from .correctors._factor import k_qmul, k_rot
from .correctors.tilt import _FORGET, _Y as _T_Y, _NST as _T_NST, _TAU as _T_TAU
from .correctors.tilt import _k_adapt_step, _k_lowpass_vertical, _k_set_tau, _lp_coeffs

__all__ = ["OfflineFilter", "reverse_recording", "reversed_config", "information", "fuse_reference",
           "supports_offline", "disturbance_mask", "calibration_passes", "select_calibration", "mag_delay_recording",
           "retime_mag", "smooth_reference", "smoothing_params", "bias_trace", "gyro_trace", "rate_rows",
           "gyro_delay_recording", "gyro_delay_lever", "retime_gyro"]

#: the sensor model whose magnetometer calibration the offline mode decides with the whole recording
_MAG_CALIBRATION = "mag-calibration"
#: how the offline mode treats that model (``OfflineFilter(calibration=...)``)
_CALIBRATIONS = ("recording", "per-pass")
#: which gate the whole-recording calibration's passes use (``OfflineFilter(calibration_test=...)``):
#: ``"norm"`` the model's norm test, ``"model"`` the model's own setting
_CALIBRATION_TESTS = ("norm", "model")
#: how the offline mode treats the magnetometer's timing (``OfflineFilter(mag_timing=...)``)
_MAG_TIMINGS = ("recording", "as-is")
#: how the offline mode treats the gyroscope's timing against the accelerometer (``OfflineFilter(gyro_timing=...)``)
_GYRO_TIMINGS = ("as-is", "recording", "lever")
#: how the two passes' inclinations are combined (``OfflineFilter(inclination=...)``): ``"smoothed"``
#: each pass's low-passed again in the other direction of time, then fused; ``"average"`` fused as they are
_INCLINATIONS = ("smoothed", "average")
#: the delay estimate's forgetting time (s): none within any recording
_NO_FORGETTING = 1e12

#: the bits that mean a pass did not use its accelerometer / magnetometer on a sample
_ACC_UNUSED = int(Flag.ACC_INVALID | Flag.ACC_SATURATED | Flag.ACC_REJECTED)
_MAG_UNUSED = int(Flag.MAG_INVALID | Flag.MAG_DISTURBED)
#: bits after which a filter restarts its inclination (timestamp gap): the information restarts
_RESTART = int(Flag.GAP)


def supports_offline(filt: Filter) -> str | None:
    """None when ``filt`` can run offline, else why not (every reason that applies). A filter can
    when it is not offline itself (``acausal``: it uses later samples), reads no GNSS, streams
    (its ``run(rec, state=...)`` is the causal pass each direction of the offline mode is) and
    declares how it pairs its accelerometer and magnetometer with the gyro's step (``acc_delay`` /
    ``mag_delay`` in its config): only then is its time-reversed pass exact
    (:func:`reversed_config`). The GNSS and streaming checks came after "it is already an offline
    filter", which ``ins-gnss`` (a causal EKF that reads GNSS and does not stream) was told."""
    if isinstance(filt, OfflineFilter) or getattr(type(filt), "acausal", False):
        return "it is already an offline filter (it uses later samples)"
    why = []
    if getattr(filt, "requires_gnss", False):
        why.append("it needs a GNSS stream, which the offline mode does not time-reverse (velocities, positions "
                   "at their epochs)")
    if not getattr(type(filt), "streaming", True):
        why.append("it does not stream (streaming = False: its run() is not a causal pass continued from a state, "
                   "which each of the offline mode's passes is)")
    missing = [k for k in ("acc_delay", "mag_delay", "tau_acc") if not hasattr(filt.config, k)]
    if missing:
        why.append(f"its config does not declare {', '.join(missing)}: the backward pass needs the sensors' pairing "
                   "with the gyro's step (acc_delay, mag_delay) and the inclination time constant (tau_acc)")
    return "; ".join(why) if why else None


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


#: the second low-pass's parameters (:func:`smooth_reference`): tau, adapt_window, bias_sigma_motion,
#: bias_sigma_init, the bias variance's forgetting time, gyro_rate_error, tau_min, tau_max, tau_adapt (0/1), g
_SMOOTH_PARAMS = 10


def smoothing_params(config) -> np.ndarray:
    """The second low-pass's parameters from a filter's config (:func:`smooth_reference`): its
    ``tau_acc`` and, where it has them, the adaptive time constant's settings (``tau_adapt``,
    ``gyro_rate_error``, the bias's uncertainties; the ``inertial-tilt`` corrector's defaults for
    the rest), so that the second low-pass chooses its time constant as the passes do."""
    from .correctors.tilt import InertialTiltConfig

    d = InertialTiltConfig()
    def get(key, default):
        value = getattr(config, key, None)
        return default if value is None else value

    return np.array([float(config.tau_acc), d.adapt_window, get("bias_sigma_motion", d.bias_sigma_motion),
                     get("bias_sigma_init", d.bias_sigma_init), get("motion_bias_tau", _FORGET),
                     get("gyro_rate_error", d.gyro_rate_error), d.tau_min, d.tau_max,
                     float(bool(getattr(config, "tau_adapt", False))), get("gravity", 9.81)])


def bias_trace(filt: Filter, rec: Recording, state=None, step: float = 1.0, backend: str = "auto") -> np.ndarray | None:
    """The gyro bias ``filt`` uses over ``rec``, per sample ``(N, 3)``: the filter run in pieces of
    ``step`` s, each continuing the state of the one before (a split run gives the numbers of one
    run), its ``diagnostics["bias"]`` read at the end of each piece and interpolated linearly between
    (held before the first). None when the filter reports no bias or no state. ``state``: the
    initial state, as for ``run``. Costs one more run of the filter: a pipeline's in one call
    (``run(..., bias_at=...)``), any other filter's a call per piece."""
    read = _probe(filt, rec, state, step, backend)
    return None if read is None else _interp(len(rec), read[0], read[1])


def gyro_trace(filt: Filter, rec: Recording, state=None, step: float = 1.0,
               backend: str = "auto") -> tuple[np.ndarray, np.ndarray | None] | None:
    """What ``filt`` takes off the gyroscope over ``rec`` and the time constant of its inclination
    low-pass, per sample, read as :func:`bias_trace` reads the bias: ``(bias (N, 3), model (N, 7) or
    None)``. ``model``: a pipeline's ``diagnostics["inclination_model_at"]`` (``inertial-tilt``'s
    ``inclination_model``): the gyro's rate error E it removes (symmetric part 00, 11, 22, 01, 02,
    12; zeros without ``rate_error_correct``: only where the pass removed it) and the low-pass's time constant ``tau``; None where
    the filter has none. ``bias`` is then the bias itself: with ``rate_error_correct`` the
    pipeline's bias also carries the sample's ``E w`` for the next propagation, a term of that
    instant's rate, which interpolated over a second would be a wrong bias (on BROAD up to 2
    deg/s); it is taken off, and ``E`` is applied per sample instead (:func:`smooth_reference`).
    None when the filter reports no bias or no state."""
    read = _probe(filt, rec, state, step, backend)
    if read is None:
        return None
    ends, bias, rate = read
    n = len(rec)
    if rate is None:
        return _interp(n, ends, bias), None
    return _interp(n, ends, bias - rate[:, 6:9]), _interp(n, ends, rate[:, [0, 1, 2, 3, 4, 5, 9]])


def _interp(n: int, ends: list[int], v: np.ndarray) -> np.ndarray:
    """The values ``v`` read after the samples ``ends``, per sample of ``n``: interpolated linearly,
    held before the first."""
    k = np.arange(n)
    return np.stack([np.interp(k, ends, v[:, i]) for i in range(v.shape[1])], axis=1)


def _probe(filt, rec, state, step, backend):
    """``filt`` run over ``rec`` (from ``state``) and read every ``step`` s: ``(ends, bias (m, 3),
    inclination model (m, 10) or None)`` (:func:`bias_trace`, :func:`gyro_trace`), None when the filter
    reports no bias or no state."""
    n = len(rec)
    m = max(2, int(round(step / rec.nominal_dt)))
    cuts = list(range(0, n, m)) + [n]
    if len(cuts) > 2 and n - cuts[-2] < 2:  # no piece of one sample (a recording needs two)
        del cuts[-2]
    from .pipeline import Pipeline

    ends, values, rate = [], [], None
    if isinstance(filt, Pipeline):  # one run, read at the pieces' ends: the same numbers
        res = filt.run(rec, backend=backend, progress=False, state=state, bias_at=[b - 1 for b in cuts[1:]])
        ends, values = [b - 1 for b in cuts[1:]], list(res.diagnostics["bias_at"])
        rate = res.diagnostics.get("inclination_model_at")
    for a, b in zip(cuts[:-1], cuts[1:]) if not ends else ():
        res = filt.run(_piece(rec, a, b), backend=backend, progress=False, state=state)
        state, bias = res.diagnostics.get("state"), res.diagnostics.get("bias")
        if state is None or bias is None:
            return None
        ends.append(b - 1)
        values.append(np.asarray(bias, dtype=float))
    return ends, np.array(values), rate


def _piece(rec: Recording, a: int, b: int) -> Recording:
    """Samples ``[a, b)`` of ``rec`` as a shallow copy: the samples passed the Recording's checks
    already (a second of them alone may not pass its units heuristics). Its first interval follows
    the Recording convention; truth, movement and GNSS are not carried."""
    out = copy.copy(rec)
    out.gyr, out.acc = rec.gyr[a:b], rec.acc[a:b]
    out.mag = None if rec.mag is None else rec.mag[a:b]
    if rec.t is not None:
        out.t = rec.t[a:b]
    out.truth = out.movement = out.gnss = None
    out.meta = {}
    return out


def _smooth_state(p: np.ndarray) -> np.ndarray:
    """A fresh state of the second low-pass: the ``inertial-tilt`` corrector's layout (its low-pass
    and adaptive time constant), the bias's covariance at its initial uncertainty."""
    from .correctors import tilt

    x = np.zeros(tilt._SIZE)
    x[tilt._P:tilt._P + 9] = np.eye(3).ravel() * p[3] * p[3]
    x[tilt._VR] = p[3] * p[3]
    return x


def rate_rows(n: int, rate: np.ndarray | None = None) -> np.ndarray:
    """The pass's model per sample for :func:`smooth_reference` ``(n, 7)``: ``rate`` (:func:`gyro_trace`:
    E's symmetric part, the time constant) as a contiguous array, or, where the filter reports none,
    no ``E`` and no time constant (NaN: the second low-pass chooses its own, :func:`smooth_reference`)."""
    if rate is not None:
        out = np.ascontiguousarray(rate, dtype=float).copy()
        out[:, :6] = np.where(np.isfinite(out[:, :6]), out[:, :6], 0.0)
        return out
    out = np.zeros((n, 7))
    out[:, 6] = np.nan
    return out


def smooth_reference(q_est: np.ndarray, gyr: np.ndarray, acc: np.ndarray, dt: np.ndarray, bias: np.ndarray,
                     rest: np.ndarray, gap: np.ndarray, reverse: bool, p: np.ndarray,
                     rate: np.ndarray | None = None) -> np.ndarray:
    """One pass's inclination smoothed by the inclination low-pass run in the *other* direction of
    time (the readable reference of :func:`_smooth_kernel`): ``q_est`` ``(N, 4)`` body -> ENU, at the
    end of each gyro step; the result has the same heading and the inclination of the low-passed
    vertical.

    The vertical that ``q_est`` says (``g R^T e_up`` in the body) is rotated into an almost-inertial
    frame I (the gyroscope minus ``bias`` ``(N, 3)``, the bias the pass used at each sample,
    integrated in the direction of the low-pass: backward in time with ``reverse``) and low-passed
    there with the ``inertial-tilt`` corrector's second-order Butterworth, whose time constant is
    chosen per sample as the passes choose it (``p``, :func:`smoothing_params`; with the adaptive
    time constant from the specific force, rotated into I at the middle of each step, and the REST
    samples ``rest``). ``rate`` ``(N, 7)`` (:func:`rate_rows`): the pass's model per sample, E's
    symmetric part and its time constant. The frame's rate is then ``(I - E) (gyr - bias)`` (a gyro
    reading ``(I + E) w + b``), as the pass removed it, and the low-pass takes the pass's own time
    constant where it is given (finite): a pass is ``H(tau(t))``, and the same low-pass run the
    other way makes the forward-backward ``|H|^2`` at every sample, where a time constant chosen
    again from the statistics of the other direction of time would pair two different filters.
    None: no ``E``, the time constant chosen here by the passes' model. A sample flagged ``gap`` (a
    timestamp gap before it) starts the low-pass again. A pass is ``H`` on the accelerometer and
    ``1 - H`` on the gyroscope's errors; this low-pass, run the other way, makes that ``|H|^2`` and
    ``1 - |H|^2`` (a forward-backward filter): see :class:`OfflineFilter`'s ``inclination``."""
    from .correctors import tilt

    n = q_est.shape[0]
    out = np.empty_like(q_est)
    x = _smooth_state(p)
    g = p[9]
    err = rate_rows(n, rate)

    def body_rate(k):  # the gyro minus the bias, less the rate error E w
        w = np.where(np.isfinite(gyr[k]), gyr[k] - bias[k], 0.0)
        e00, e11, e22, e01, e02, e12 = err[k, :6]
        return w - np.array([[e00, e01, e02], [e01, e11, e12], [e02, e12, e22]]) @ w

    qi = np.array([1.0, 0.0, 0.0, 0.0])
    order = range(n - 1, -1, -1) if reverse else range(n)
    first = True
    for k in order:
        if not first:
            s = k + 1 if reverse else k  # the gyro step between this sample and the one before it
            qi = quat_mul(qi, quat_from_rotvec(body_rate(s) * dt[s] * (-1.0 if reverse else 1.0)))
            qi = qi / np.linalg.norm(qi)
            if gap[s]:
                x = _smooth_state(p)
        first = False
        r = quat_to_matrix(qi)
        v = r @ (quat_to_matrix(q_est[k]).T @ np.array([0.0, 0.0, g]))  # the estimate's vertical, in I
        tau = p[0]
        if np.isfinite(err[k, 6]):  # the pass's own time constant
            tau = err[k, 6]
        elif p[8] != 0.0 and np.all(np.isfinite(acc[k])):
            w = body_rate(k)
            mid = quat_to_matrix(quat_mul(qi, quat_from_rotvec(-0.5 * w * dt[k])))  # the middle of the step
            y = x[tilt._Y:tilt._Y + 3]
            z = r.T @ (y / np.linalg.norm(y)) if x[tilt._NST] > 0.0 else np.zeros(3)
            tau = tilt._adapt_step(x, *(mid @ acc[k]), *(mid @ w), *z, bool(rest[k]), dt[k], p[0], p[1], p[2],
                                   p[3], p[4], p[5], p[6], p[7])
        elif p[8] != 0.0 and x[tilt._TAU] > 0.0:
            tau = x[tilt._TAU]
        tilt._set_tau(x, *tilt.lowpass_coefficients(tau, dt[k]), False)
        y = tilt._lowpass_vertical(x, v)  # (no fast start: its first step starts in v's steady state)
        u = quat_to_matrix(q_est[k]) @ (r.T @ y)  # the low-passed vertical in the estimate's earth frame
        u = u / np.linalg.norm(u)
        c = np.array([1.0 + u[2], u[1], -u[0], 0.0])  # the smallest rotation taking it to the vertical
        out[k] = quat_mul(c / np.linalg.norm(c), q_est[k])
    return out


@njit
def _smooth_kernel(q_est, gyr, acc, dt, bias, err, rest, gap, reverse, p, x0, out):
    """:func:`smooth_reference` compiled (``err``: :func:`rate_rows`; ``x0``: a fresh state,
    :func:`_smooth_state`)."""
    n = q_est.shape[0]
    x = x0.copy()
    g = p[9]
    i0, i1, i2, i3 = 1.0, 0.0, 0.0, 0.0
    sg = -1.0 if reverse else 1.0
    for j in range(n):
        k = n - 1 - j if reverse else j
        if j > 0:
            s = k + 1 if reverse else k
            r0, r1, r2 = _rate(gyr, s, bias, err)
            i0, i1, i2, i3 = _turn(i0, i1, i2, i3, sg * r0 * dt[s], sg * r1 * dt[s], sg * r2 * dt[s])
            nq = math.sqrt(i0 * i0 + i1 * i1 + i2 * i2 + i3 * i3)
            i0, i1, i2, i3 = i0 / nq, i1 / nq, i2 / nq, i3 / nq
            if gap[s]:
                x[:] = x0
        e0, e1, e2, e3 = q_est[k, 0], q_est[k, 1], q_est[k, 2], q_est[k, 3]
        u0, u1, u2 = k_rot(e0, -e1, -e2, -e3, 0.0, 0.0, g)
        v0, v1, v2 = k_rot(i0, i1, i2, i3, u0, u1, u2)
        tau = p[0]
        if math.isfinite(err[k, 6]):
            tau = err[k, 6]
        elif p[8] != 0.0 and math.isfinite(acc[k, 0]) and math.isfinite(acc[k, 1]) and math.isfinite(acc[k, 2]):
            r0, r1, r2 = _rate(gyr, k, bias, err)
            m0, m1, m2, m3 = _turn(i0, i1, i2, i3, -0.5 * r0 * dt[k], -0.5 * r1 * dt[k], -0.5 * r2 * dt[k])
            a0, a1, a2 = k_rot(m0, m1, m2, m3, acc[k, 0], acc[k, 1], acc[k, 2])
            w0, w1, w2 = k_rot(m0, m1, m2, m3, r0, r1, r2)
            z0 = z1 = z2 = 0.0
            if x[_T_NST] > 0.0:
                ny = math.sqrt(x[_T_Y] * x[_T_Y] + x[_T_Y + 1] * x[_T_Y + 1] + x[_T_Y + 2] * x[_T_Y + 2])
                z0, z1, z2 = k_rot(i0, -i1, -i2, -i3, x[_T_Y] / ny, x[_T_Y + 1] / ny, x[_T_Y + 2] / ny)
            tau = _k_adapt_step(x, a0, a1, a2, w0, w1, w2, z0, z1, z2, rest[k], dt[k], p[0], p[1], p[2], p[3], p[4],
                                p[5], p[6], p[7])
        elif p[8] != 0.0 and x[_T_TAU] > 0.0:
            tau = x[_T_TAU]
        b0, b1, b2, c1, c2 = _lp_coeffs(tau, dt[k])
        _k_set_tau(x, b0, b1, b2, c1, c2, False)
        y0, y1, y2 = _k_lowpass_vertical(x, v0, v1, v2)
        m0, m1, m2 = k_rot(i0, -i1, -i2, -i3, y0, y1, y2)
        v0, v1, v2 = k_rot(e0, e1, e2, e3, m0, m1, m2)
        nv = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        c0, c1, c2 = 1.0 + v2 / nv, v1 / nv, -v0 / nv
        nc = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = k_qmul(c0 / nc, c1 / nc, c2 / nc, 0.0, e0, e1, e2, e3)


@njit(inline="always")
def _rate(gyr, k, bias, err):
    """The gyro's rate minus ``bias[k]`` at sample ``k``, less the rate error ``E w`` (``err[k]``:
    :func:`rate_rows`; 0 where the gyro is not finite)."""
    g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]
    if not (math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2)):
        return 0.0, 0.0, 0.0
    w0, w1, w2 = g0 - bias[k, 0], g1 - bias[k, 1], g2 - bias[k, 2]
    e00, e11, e22, e01, e02, e12 = err[k, 0], err[k, 1], err[k, 2], err[k, 3], err[k, 4], err[k, 5]
    return (w0 - (e00 * w0 + e01 * w1 + e02 * w2), w1 - (e01 * w0 + e11 * w1 + e12 * w2),
            w2 - (e02 * w0 + e12 * w1 + e22 * w2))


@njit(inline="always")
def _turn(q0, q1, q2, q3, r0, r1, r2):
    """``q (x) exp(r)``, ``r`` a rotation vector (rad); :func:`quat_from_rotvec`'s operations."""
    e0, e1, e2, e3 = rotvec_quat_exact_entries(r0, r1, r2)
    return k_qmul(q0, q1, q2, q3, e0, e1, e2, e3)


class OfflineFilter(Filter):
    """A filter run forward and backward in time, fused by each pass's information (see the
    module docs). Built by ``fk.make(name, offline=True)``; runs whole recordings only."""

    name: ClassVar[str] = "offline"
    streaming: ClassVar[bool] = False
    acausal: ClassVar[bool] = True  #: it uses later samples (:func:`supports_offline`)
    summary: ClassVar[str] = "a filter run forward and backward in time, fused per sample (acausal)"
    source: ClassVar[str] = "fusionkit (after VQF's offline mode, Laidig and Seel 2023)"

    #: the options of the offline mode itself (``__init__``'s keywords): ``make(name, offline=True, ...)``
    #: passes these to it and the other parameters to the filter
    OPTIONS: ClassVar[tuple[str, ...]] = ("disturbance_gap", "calibration", "mag_timing", "calibration_test",
                                          "inclination", "gyro_timing")
    #: default of ``disturbance_gap`` (s): see :func:`disturbance_mask`
    DISTURBANCE_GAP: ClassVar[float] = 1.0
    #: the way (rad: rotation, or at rest time at the model's segment rate) either side of a sample
    #: over which :func:`select_calibration` compares the candidate streams' field norms: half a
    #: turn each side, one turn in all, over which a wrong offset swings the norm through its range
    CALIBRATION_SPAN: ClassVar[float] = math.pi
    #: the magnetometer is re-timed (:func:`retime_mag`) when the delay estimated over the recording
    #: is this many of its standard deviations away from the filter's pairing: a two-sided test at
    #: the 0.3% level that the sensor does not keep the pairing the filter assumes (a recording
    #: with little angular acceleration, e.g. at rest, informs the estimate little and keeps it)
    MAG_DELAY_SIGMAS: ClassVar[float] = 3.0
    #: the segment length (s) of the second estimate of the gyro's delay (``gyro_timing="recording"``):
    #: five times the ``time-offset`` model's 0.02 s, a band five times lower (below 50 Hz, where that
    #: segment is one sample, five samples). A pure delay is the same
    #: at every time scale; a bias from linear accelerations that come with the rotation (a hand's) is
    #: not, as their share of the direction's change and the delay's (the angular acceleration times
    #: the delay) scale differently with the frequency
    GYRO_CHECK_SEGMENT: ClassVar[float] = 0.1
    #: the interval (s) at which :func:`bias_trace` reads each pass's gyro bias for the smoothed
    #: inclination (``inclination="smoothed"``): the bias moves fastest at a rest, where
    #: ``recommended``'s rest corrector learns it with a time constant of 1 s (``rest_bias_tau``)
    BIAS_STEP: ClassVar[float] = 1.0

    def __init__(self, inner: Filter, disturbance_gap: float | None = DISTURBANCE_GAP,
                 calibration: str = "recording", mag_timing: str = "recording",
                 calibration_test: str = "norm", inclination: str = "smoothed",
                 gyro_timing: str | float = "as-is") -> None:
        why = supports_offline(inner)
        if why is not None:
            raise PluginError(f"filter {inner.name!r} does not support offline=True: {why}")
        if disturbance_gap is not None and not (isinstance(disturbance_gap, (int, float))
                                                and math.isfinite(disturbance_gap) and disturbance_gap >= 0.0):
            raise ConfigError(f"disturbance_gap must be None or a finite number of seconds >= 0, "
                              f"got {disturbance_gap!r}")
        if calibration not in _CALIBRATIONS:
            raise ConfigError(f"calibration must be one of {', '.join(map(repr, _CALIBRATIONS))}, got {calibration!r}")
        if calibration_test not in _CALIBRATION_TESTS:
            raise ConfigError(f"calibration_test must be one of {', '.join(map(repr, _CALIBRATION_TESTS))}, "
                              f"got {calibration_test!r}")
        if inclination not in _INCLINATIONS:
            raise ConfigError(f"inclination must be one of {', '.join(map(repr, _INCLINATIONS))}, got {inclination!r}")
        if mag_timing not in _MAG_TIMINGS:
            raise ConfigError(f"mag_timing must be one of {', '.join(map(repr, _MAG_TIMINGS))}, got {mag_timing!r}")
        limit = TimeOffsetModel.Config().max_offset
        given = isinstance(gyro_timing, numbers.Real) and not isinstance(gyro_timing, (bool, np.bool_))
        if not (gyro_timing in _GYRO_TIMINGS if isinstance(gyro_timing, str)
                else given and math.isfinite(gyro_timing) and abs(gyro_timing) <= limit):
            raise ConfigError(f"gyro_timing must be one of {', '.join(map(repr, _GYRO_TIMINGS))} or the gyro's delay "
                              f"against the accelerometer in s (|delay| <= {limit}), got {gyro_timing!r}")
        self.gyro_timing = float(gyro_timing) if given else gyro_timing
        self.inner = inner
        self.mag_timing = mag_timing
        self.disturbance_gap = None if disturbance_gap is None else float(disturbance_gap)
        self.calibration = calibration
        self.calibration_test = calibration_test
        self.inclination = inclination
        self.config = inner.config
        self.name = f"{inner.name} (offline)"

    def __repr__(self) -> str:
        return f"OfflineFilter({self.inner!r})"

    def options(self) -> dict[str, Any]:
        """The offline mode's own options (its ``config`` is the inner filter's): what tells this
        filter from the inner one run online, and from another offline setting (the bench's cache
        key: an offline row showed the online run's numbers on a re-run)."""
        return {k: getattr(self, k) for k in self.OPTIONS}

    def dimension(self, rec) -> str:
        return self.inner.dimension(rec)

    def body_axes(self, rec):
        return self.inner.body_axes(rec)

    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: np.ndarray | None = None) -> Result:
        """:meth:`_run`, its passes' warnings of the recording's gaps said once: the first, the forward
        pass's, at the recording's own sample index (each pass warned, the backward ones at their index in
        the reversed recording: a 5 s gap gave three, "first before sample 2000" for a gap at 3000)."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = self._run(rec, backend=backend, progress=progress, state=state)
        said = False
        for w in caught:
            if issubclass(w.category, GapWarning):
                if said:
                    continue
                said = True
            warnings.warn(w.message, w.category, stacklevel=2)
        return res

    def _run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
             state: np.ndarray | None = None) -> Result:
        """Forward pass (from ``state`` when given: an earlier run's ``diagnostics["state"]``),
        backward pass, fusion. How far a given state had converged is not known from it (an earlier
        run that started in motion hands on a poor bias), so the forward pass's information
        counts from this run's first sample either way. ``diagnostics["state"]`` is the forward pass's final
        state (an online run can continue from it); ``diagnostics["backward_weight"]`` holds the
        per-sample weights of the backward pass (``inclination``, ``heading``);
        ``diagnostics["mag_disturbed"]`` the magnetometer samples left out (:func:`disturbance_mask`;
        None without a magnetometer or with ``disturbance_gap=None``);
        ``diagnostics["models"]`` the forward pass's sensor models' reports at its end (with
        ``calibration="recording"`` the mag-calibration's the forward model's over the recording);
        ``diagnostics["mag_calibration"]`` per sample the magnetometer stream both passes used (0 raw,
        1 calibrated by the forward model, 2 by the backward one; None where the filter has no
        calibration model or ``calibration="per-pass"``); ``diagnostics["mag_timing"]`` the
        magnetometer's delay estimated over the recording, its standard deviation (s) and whether the
        stream was re-timed (``{"delay", "std", "applied"}``; None in 6D or with
        ``mag_timing="as-is"``); ``diagnostics["gyro_timing"]`` the gyroscope's delay against the
        accelerometer, likewise (None with ``gyro_timing="as-is"``); ``inclination="smoothed"`` runs each pass once more in pieces for
        its bias (:func:`bias_trace`); ``backend`` is the passes',
        ``fusion_backend`` the fusion's."""
        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        inner = self.inner
        used = resolve_backend(backend, True)
        lead = float(getattr(inner.config, "output_lead", 0.0) or 0.0)
        if lead > 0.0:  # the passes without it; the fused trajectory is read ahead instead (_read_ahead)
            inner = type(inner)(inner.config.model_copy(update={"output_lead": 0.0}))
        gyro_timing = None
        if self.gyro_timing == "recording" and len(rec) >= 2:  # first: every later step reads the gyro
            rec, gyro_timing = self._gyro_retimed(rec, inner.config, used)
        elif self.gyro_timing == "lever" and len(rec) >= 2:
            rec, gyro_timing = self._gyro_retimed_lever(rec, inner.config, used)
        elif isinstance(self.gyro_timing, float) and self.gyro_timing != 0.0:  # a delay the user knows
            gyro_timing = {"delay": self.gyro_timing, "std": 0.0, "applied": True}
            rec = _with_gyro_retimed(rec, self.gyro_timing)
        choice = None
        if state is not None:  # judged whole, before the calibration's part is taken out of it
            inner._check_state(state)
        if self.calibration == "recording" and len(rec) >= 2 and self.dimension(rec) == "9D":
            split = _split_calibration(inner)
            if split is not None:  # the calibration decided with the whole recording, the passes without the model
                inner, model, index = split
                model_state = None
                if state is not None:  # the forward pass continues the given state, its model too
                    state = copy.deepcopy(state)
                    model_state = state["mod"].pop(index)
                rec, choice, model_end = self._calibrated(rec, model, inner.config, used, model_state)
        timing = None
        if self.mag_timing == "recording" and len(rec) >= 2 and self.dimension(rec) == "9D":
            rec, timing = self._retimed(rec, inner.config, used)
        fwd = inner.run(rec, backend=backend, progress=progress, state=state)
        n = len(rec)
        if n < 2:  # nothing after the sample: the forward pass is all there is
            fwd.diagnostics.update({"offline": True, "mag_timing": timing, "gyro_timing": gyro_timing})
            return fwd
        back = type(inner)(reversed_config(inner, rec.nominal_dt))
        bwd = back.run(reverse_recording(rec), backend=backend, progress=progress)
        passes = (inner, back, rec, state)  # what the passes ran: the smoothing retraces their bias
        has_mag = self.dimension(rec) == "9D"
        disturbed = None
        if has_mag and self.disturbance_gap is not None:
            # the disturbances as both passes saw them (the backward pass's flags j are input sample N-1-j)
            disturbed = disturbance_mask(fwd.flags, bwd.flags[::-1], rec.time, self.disturbance_gap)
            took = ((fwd.flags & _MAG_UNUSED) == 0) | ((bwd.flags[::-1] & _MAG_UNUSED) == 0)
            if (disturbed & took).any():  # the passes again, without the disturbed samples either had used
                fwd, bwd, passes = self._without(rec, disturbed, inner, back, backend, progress, state)
        c = self.config
        # the intervals the passes integrated: a gap's is the nominal one (the state was held across it; its
        # own 5 s gave the pass that had just restarted there 0.93 of full information, the weights 0.5 / 0.5)
        _, dt, gaps = hold_gaps(rec.gyr, rec.dt, rec.nominal_dt, getattr(c, "max_gap", None))
        if n > 1 and gaps[1]:  # dt[0] is a copy of dt[1]: the held one's (a gap at sample 1 gave sample 0 its 5 s)
            dt = dt.copy()
            dt[0] = dt[1]
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
        if self.inclination == "smoothed":
            qf, qb = self._smoothed(rec, qf, qb, fwd, bwd, passes, used)
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
        if choice is not None and isinstance(fwd.diagnostics.get("state"), dict):
            fwd.diagnostics["state"]["mod"].insert(index, model_end)  # it fits the filter with the model again
            # the forward pass ran without the model: its reports again, the forward model's among them
            fwd.diagnostics["models"] = self.inner.model_reports(fwd.diagnostics["state"])
        diag = dict(fwd.diagnostics)
        diag.update({"filter": self.name, "fusion_backend": used, "offline": True, "config": self.config.model_dump(),
                     "backward_weight": {"inclination": w_i, "heading": w_h}, "mag_disturbed": disturbed,
                     "mag_calibration": choice, "mag_timing": timing, "gyro_timing": gyro_timing,
                     "backward_diagnostics": {k: v for k, v in bwd.diagnostics.items() if k != "config"},
                     "aiding": self.aiding(rec)})
        return Result(q, flags, frame, diag)

    def _calibrated(self, rec, model, config, used, model_state):
        """``rec`` with the magnetometer stream :func:`select_calibration` chooses from the model's
        forward and backward passes (``rec`` itself where neither applied a calibration), the
        choice per sample, and the forward model's final state."""
        gyr_range, acc_range = getattr(config, "gyr_range", None), getattr(config, "acc_range", None)
        if self.calibration_test == "norm" and getattr(model.config, "consistency_test", "norm") != "norm":
            model = type(model)(model.config.model_copy(update={"consistency_test": "norm"}))
        fwd, bwd, end = calibration_passes(model, rec, getattr(config, "max_gap", None), gyr_range, acc_range,
                                           used, model_state)
        choice = np.zeros(len(rec), dtype=np.int8)
        if np.array_equal(fwd, rec.mag, equal_nan=True) and np.array_equal(bwd, rec.mag, equal_nan=True):
            return rec, choice, end
        c = model.config
        mag, choice = select_calibration(rec.gyr, rec.dt, [rec.mag, fwd, bwd], self.CALIBRATION_SPAN,
                                         c.segment_angle / c.segment_time)
        out = copy.copy(rec)  # a shallow copy: the samples passed the Recording's checks already
        out.mag = mag
        return out, choice, end

    @classmethod
    def _retimed(cls, rec, config, used):
        """``rec`` with its magnetometer on the filter's pairing (:func:`retime_mag`) where the
        delay estimated over the whole recording (:func:`mag_delay_recording`) differs from that
        pairing by more than ``MAG_DELAY_SIGMAS`` standard deviations (clamped, as the ``time-offset`` model
        clamps it, to its ``max_offset``), else ``rec`` itself; and
        ``{"delay", "std", "applied"}`` (s)."""
        gyr_range, acc_range = getattr(config, "gyr_range", None), getattr(config, "acc_range", None)
        pairing = getattr(config, "mag_delay", None)
        delay, std = mag_delay_recording(rec, gyr_range, acc_range, pairing, used)
        applied = bool(math.isfinite(delay) and math.isfinite(std) and abs(delay) > cls.MAG_DELAY_SIGMAS * std)
        info = {"delay": delay, "std": std, "applied": applied}
        if not applied:
            return rec, info
        out = copy.copy(rec)  # a shallow copy: the samples passed the Recording's checks already
        limit = TimeOffsetModel.Config().max_offset  # the model's bound on a sensor's delay, as it applies it
        out.mag = retime_mag(rec.gyr, rec.mag, rec.time, rec.dt, min(max(delay, -limit), limit), pairing, used)
        return out, info

    @classmethod
    def _gyro_retimed(cls, rec, config, used):
        """``rec`` with its gyroscope moved onto the accelerometer's clock (:func:`retime_gyro`) where
        the gyro's delay estimated over the whole recording (:func:`gyro_delay_recording`) is a delay:
        it differs from the filter's pairing by more than ``MAG_DELAY_SIGMAS`` standard deviations (the
        magnetometer's test), so does the estimate over ``GYRO_CHECK_SEGMENT`` s segments, and the two
        agree within ``MAG_DELAY_SIGMAS`` of their combined standard deviation (clamped to the
        ``time-offset`` model's ``max_offset``); else ``rec`` itself. And ``{"delay", "std", "check",
        "check_std", "applied"}`` (s; ``check`` the estimate over the longer segments)."""
        args = (rec, getattr(config, "gyr_range", None), getattr(config, "acc_range", None),
                getattr(config, "acc_delay", None), used)
        delay, std = gyro_delay_recording(*args)
        # a segment closes on a sample: below 50 Hz the model's 0.02 s segment is one sample long, and the
        # check's stays GYRO_CHECK_SEGMENT / 0.02 times longer (at 10 Hz a 0.1 s one would be the same estimate)
        short = TimeOffsetModel.Config().segment_time
        check, check_std = gyro_delay_recording(*args, segment_time=cls.GYRO_CHECK_SEGMENT
                                                * max(1.0, rec.nominal_dt / short))
        k = cls.MAG_DELAY_SIGMAS
        applied = bool(np.all(np.isfinite([delay, std, check, check_std])) and abs(delay) > k * std
                       and abs(check) > k * check_std and abs(delay - check) < k * math.hypot(std, check_std))
        info = {"delay": delay, "std": std, "check": check, "check_std": check_std, "applied": applied}
        return cls._gyro_moved(rec, info), info

    @staticmethod
    def _gyro_moved(rec, info):
        """``rec`` with its gyroscope moved by an estimate's ``info["delay"]`` where ``info["applied"]``
        (clamped to the ``time-offset`` model's ``max_offset``, as the model clamps a sensor's delay),
        else ``rec`` itself: what both gyro estimates do with their verdict."""
        if not info["applied"]:
            return rec
        limit = TimeOffsetModel.Config().max_offset
        return _with_gyro_retimed(rec, min(max(info["delay"], -limit), limit))

    @classmethod
    def _gyro_retimed_lever(cls, rec, config, used):
        """``rec`` with its gyroscope moved onto the accelerometer's clock where :func:`gyro_delay_lever`'s
        estimate is a delay the model accounts for: beyond ``MAG_DELAY_SIGMAS`` standard deviations, and
        with the model's ``bound`` under half of it (then even a residual that all went into the
        estimate leaves the gyro nearer its true timing after the move than before); clamped to the
        ``time-offset`` model's ``max_offset``. Else ``rec`` itself. And ``{"delay", "std", "bound",
        "lever", "applied"}`` (s; the lever arm in m)."""
        delay, std, bound, lever = gyro_delay_lever(rec, getattr(config, "acc_delay", None), backend=used)
        applied = bool(np.all(np.isfinite([delay, std, bound])) and abs(delay) > cls.MAG_DELAY_SIGMAS * std
                       and bound < 0.5 * abs(delay))
        info = {"delay": delay, "std": std, "bound": bound, "lever": lever, "applied": applied}
        return cls._gyro_moved(rec, info), info

    @staticmethod
    def _without(rec, disturbed, inner, back, backend, progress, state):
        """Both passes on ``rec`` with the magnetometer's ``disturbed`` samples left out (made
        invalid, the passes skipping them); their flags say MAG_DISTURBED there, not MAG_INVALID.
        Also what they ran: ``(forward filter, backward filter, recording, state)``."""
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
        return fwd, bwd, (inner, back, masked, state)

    def _smoothed(self, rec, qf, qb, fwd, bwd, passes, used):
        """Each pass's estimate (ENU, ``qb`` in the recording's order) with its inclination low-passed
        again in the other direction of time (:func:`smooth_reference`), each in the frame of the
        gyroscope minus the bias that pass used (:func:`bias_trace`; ``passes``: the forward and
        backward filters, the recording they ran on and the forward pass's initial state). A filter
        that reports no bias: the recording's gyro as it is (``diagnostics["bias"]`` missing)."""
        p = smoothing_params(self.inner.config)
        rest = ((fwd.flags | bwd.flags[::-1]) & np.uint32(Flag.REST)) != 0
        gap = (fwd.flags & np.uint32(Flag.GAP)) != 0
        inner, back, prec, state = passes
        out = []
        for q, filt, r, st, reverse in ((qf, inner, prec, state, True), (qb, back, None, None, False)):
            if r is None:  # the backward pass: its bias, of the negated gyro, in the recording's order (E: the same)
                t = gyro_trace(filt, reverse_recording(prec), None, self.BIAS_STEP, used)
                t = None if t is None else (-t[0][::-1], None if t[1] is None else t[1][::-1])
            else:
                t = gyro_trace(filt, r, st, self.BIAS_STEP, used)
            bias, rate = (np.zeros((len(rec), 3)), None) if t is None else t
            bias = np.ascontiguousarray(np.where(np.isfinite(bias), bias, 0.0))
            err = rate_rows(len(rec), rate)
            q = np.ascontiguousarray(q, dtype=float)
            if used == "numba":
                o = np.empty_like(q)
                gyr, acc = np.ascontiguousarray(rec.gyr, dtype=float), np.ascontiguousarray(rec.acc, dtype=float)
                _smooth_kernel(q, gyr, acc, np.ascontiguousarray(rec.dt, dtype=float), bias, err, rest, gap, reverse,
                               p, _smooth_state(p), o)
            else:
                o = smooth_reference(q, rec.gyr, rec.acc, rec.dt, bias, rest, gap, reverse, p, err)
            out.append(o)
        return out[0], out[1]

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


def _split_calibration(filt):
    """``(filt without its mag-calibration model, the model, its index among the filter's models)``,
    or None when the filter has no such model. The filter is rebuilt from its config: with
    ``mag_calibration=False`` (``recommended``) or without the model in ``models`` (a pipeline)."""
    models = getattr(filt, "models", None) or []
    index = next((i for i, m in enumerate(models) if m.name == _MAG_CALIBRATION), None)
    if index is None:
        return None
    c = filt.config
    if getattr(c, "mag_calibration", None) is True:
        bare = type(filt)(c.model_copy(update={"mag_calibration": False}))
    elif isinstance(getattr(c, "models", None), list):
        bare = type(filt)(c.model_copy(update={"models": [m for m in c.models if m.name != _MAG_CALIBRATION]}))
    else:
        return None
    if len(getattr(bare, "models", [])) != len(models) - 1:
        return None
    return bare, models[index], index


def calibration_passes(model, rec: Recording, max_gap: float | None = None, gyr_range: float | None = None,
                       acc_range: float | None = None, backend: str = "numba",
                       state: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The magnetometer as a calibration ``model`` (``mag-calibration``) run alone over ``rec``
    calibrates it, forward and backward in time: ``(forward, backward, final forward state)``, the
    backward stream in the recording's order. Each sample is judged valid as the pipeline judges it
    (``gyr_range``, ``acc_range``; a timestamp gap beyond ``max_gap`` holds the gyro); an invalid
    magnetometer sample is passed on unchanged. The model does not read the orientation (it gets
    the identity). ``state``: the forward model's initial state (default: a fresh one).
    ``backend``: ``"numba"`` (:func:`mag_calibration_apply <fusionkit.models.mag_calibration.mag_calibration_apply>`)
    or ``"reference"`` (:meth:`~fusionkit.models.mag_calibration.MagCalibrationModel.apply`)."""
    out = []
    end = None
    fresh = model.initial_state(rec.nominal_dt)
    if state is not None and np.shape(state) != fresh.shape:  # (the kernel writes without bounds checks)
        raise InputError(f"state has shape {np.shape(state)}, but this model's state is {fresh.shape} (a state "
                         "saved by another configuration or an older fusionkit?)")
    kern = model.kernel() if resolve_backend(backend, True) == "numba" else None  # (params and static, once)
    for k, r in enumerate((rec, reverse_recording(rec))):
        s = fresh.copy() if k or state is None else np.array(state, dtype=float)
        gyr, dt, _ = hold_gaps(r.gyr, r.dt, r.nominal_dt, max_gap)
        m = np.empty_like(r.mag)
        if kern is not None:
            _calibration_kernel(s, gyr, r.acc, r.mag, dt, _validity(gyr, r.acc, r.mag, gyr_range, acc_range), kern, m)
        else:
            _model_reference(model, s, gyr, r.acc, r.mag, dt, gyr_range, acc_range, m)
        out.append(m if k == 0 else m[::-1])
        if k == 0:
            end = s
    return out[0], out[1], end


def _validity(gyr, acc, mag, gyr_range, acc_range) -> np.ndarray:
    """Per sample, whether the gyroscope, accelerometer and magnetometer are valid, as the pipeline
    judges them (``validity_all``): what a model's kernel run alone over a recording is given."""
    ok = np.zeros((gyr.shape[0], 3), dtype=np.bool_)
    validity_all(gyr, acc, mag, True, math.inf if gyr_range is None else float(gyr_range),
                 math.inf if acc_range is None else float(acc_range), ok, np.zeros(gyr.shape[0], np.uint32))
    return ok


def _model_reference(model, s, gyr, acc, mag, dt, gyr_range, acc_range, out=None) -> None:
    """The readable twin of :func:`_calibration_kernel` and :func:`_delay_kernel`: the sensor
    ``model``'s reference ``apply`` per sample, on the identity orientation (``out``: the
    magnetometer it gives, an invalid sample passed on unchanged; None: not kept)."""
    from .protocols import Sample

    from .detectors._run import read_only

    q = np.array([1.0, 0.0, 0.0, 0.0])
    nan3 = np.full(3, np.nan)
    acc, mag = read_only(acc), read_only(mag)  # (the recording's rows, as the pipeline hands them)
    for k in range(gyr.shape[0]):
        g_ok, a_ok, m_ok, _ = sample_validity(gyr[k], acc[k], mag[k], gyr_range, acc_range)
        smp, _ = model.apply(s, Sample(gyr[k].copy() if g_ok else nan3, acc[k] if a_ok else None,
                                       mag[k] if m_ok else None, float(dt[k])), q)
        if out is not None:
            out[k] = smp.mag if m_ok else mag[k]


@njit(inline="always")
def _sample_vector(v, gyr, acc, mag, ok, k):
    """Sample ``k`` as a model kernel reads it: ``v = (gyr, acc, mag)``, the gyro NaN where invalid."""
    for i in range(3):
        v[i] = gyr[k, i] if ok[k, 0] else np.nan
        v[3 + i] = acc[k, i]
        v[6 + i] = mag[k, i]


_calibration_apply = inline_copy(mag_calibration_apply)


@njit(inline="always")
def _calibration_loop(s, gyr, acc, mag, dt, ok, p, out, soft, once):
    """The ``mag-calibration`` kernel alone over a recording; ``out`` the magnetometer it gives.
    ``soft``, ``once``: the kernel's static options (``soft_iron``, ``held_readings == "once"``), literals in
    each of the four entry points below, so each compiles only the branches it runs (as in a pipeline's loop)."""
    q = np.zeros(4)
    q[0] = 1.0
    v = np.empty(9)
    for k in range(gyr.shape[0]):
        _sample_vector(v, gyr, acc, mag, ok, k)
        _calibration_apply(s, v, ok[k, 0], ok[k, 1], ok[k, 2], q, dt[k], p, soft, once)
        for i in range(3):
            out[k, i] = v[6 + i] if ok[k, 2] else mag[k, i]


@njit
def _calibration_soft_each(s, gyr, acc, mag, dt, ok, p, out):
    _calibration_loop(s, gyr, acc, mag, dt, ok, p, out, True, False)


@njit
def _calibration_soft_once(s, gyr, acc, mag, dt, ok, p, out):
    _calibration_loop(s, gyr, acc, mag, dt, ok, p, out, True, True)


@njit
def _calibration_hard_each(s, gyr, acc, mag, dt, ok, p, out):
    _calibration_loop(s, gyr, acc, mag, dt, ok, p, out, False, False)


@njit
def _calibration_hard_once(s, gyr, acc, mag, dt, ok, p, out):
    _calibration_loop(s, gyr, acc, mag, dt, ok, p, out, False, True)


def _calibration_kernel(s, gyr, acc, mag, dt, ok, kern, out):
    """:func:`_calibration_loop` with the model's kernel ``kern`` (``MagCalibrationModel.kernel()``: its
    parameters, and its static options soft_iron and held_readings once, which choose the entry point)."""
    soft, once = kern.static
    run = ((_calibration_hard_each, _calibration_hard_once), (_calibration_soft_each, _calibration_soft_once))
    run[soft][once](s, gyr, acc, mag, dt, ok, kern.params, out)


def mag_delay_recording(rec: Recording, gyr_range: float | None = None, acc_range: float | None = None,
                        pairing: float | None = None, backend: str = "numba") -> tuple[float, float]:
    """The magnetometer's delay against the gyroscope over the whole recording, from the IMU alone:
    ``(delay, std)`` in s, ``delay`` the time by which a magnetometer sample describes the body
    *before* the instant the filter pairs it with (``pairing``: the filter's ``mag_delay``, None the
    middle of the gyro's step), NaN without enough segments.

    The estimator is the ``time-offset`` model's (:mod:`fusionkit.models.time_offset`: a field
    direction that the gyro's turn between two fresh samples does not explain is proportional to
    the angular acceleration times the delay; held samples neither start nor close a segment, a
    segment across which the field's norm changes is a disturbance and does not enter), run once
    over the recording without forgetting: offline every segment of the recording informs the
    one delay of the hardware. ``backend``: ``"numba"`` (its kernel) or ``"reference"`` (the
    model's ``apply``, the same numbers)."""
    s, model = _delay_state(rec, gyr_range, acc_range, backend)
    if s[MAG + NSEG] < model.config.min_segments or not s[MAG + STD] > 0.0:
        return math.nan, math.nan
    # the model's estimate is the gyro's delay against the magnetometer, both taken at the middle of
    # the step (negative: the magnetometer is the later); the filter pairs it pairing before the end
    middle = 0.5 * rec.nominal_dt
    return -float(s[MAG + EST]) + (middle - pairing if pairing is not None else 0.0), float(s[MAG + STD])


def gyro_delay_recording(rec: Recording, gyr_range: float | None = None, acc_range: float | None = None,
                         pairing: float | None = None, backend: str = "numba",
                         segment_time: float | None = None) -> tuple[float, float]:
    """The gyroscope's delay against the accelerometer over the whole recording, from the IMU alone:
    ``(delay, std)`` in s, ``delay`` the time by which a gyro sample describes the body *after* the
    instant the filter pairs the accelerometer with (``pairing``: the filter's ``acc_delay``, None the
    middle of the gyro's step; positive: the gyro is late, its digital low-pass's group delay or a
    later sampling instant), NaN without enough segments.

    The same estimator as :func:`mag_delay_recording` on gravity's direction (the ``time-offset``
    model's accelerometer block, without forgetting): between two accelerometer samples the
    direction the gyro's turn does not explain is proportional to the angular acceleration times
    the delay; a sample whose norm is off gravity's by more than the model's ``acc_tol`` does not
    enter. It assumes the linear accelerations do not correlate with the angular acceleration; a
    hand's do where the sensor sits away from the wrist (tangential accelerations), and then the
    estimate is biased by several samples (BROAD: docs/algorithms/offline.md). ``segment_time``: the
    model's segment length (s; None its default, 0.02 s): the time scale over which the direction's
    change is compared, which a pure delay does not depend on."""
    s, model = _delay_state(rec, gyr_range, acc_range, backend, segment_time)
    if s[ACC + NSEG] < model.config.min_segments or not s[ACC + STD] > 0.0:
        return math.nan, math.nan
    # the model's estimate is the gyro's delay against the accelerometer, both at the middle of the
    # step; the filter pairs the accelerometer pairing before the end of the step
    middle = 0.5 * rec.nominal_dt
    return float(s[ACC + EST]) + (pairing - middle if pairing is not None else 0.0), float(s[ACC + STD])


#: the band (Hz) in which :func:`gyro_delay_lever` compares the accelerometer with the gyro: a hand's
#: and a body's turns, above the strapdown's drift and gravity, below where the angular acceleration's
#: difference quotient departs from the derivative
LEVER_BAND = (0.5, 3.0)


def gyro_delay_lever(rec: Recording, pairing: float | None = None, band: tuple[float, float] = LEVER_BAND,
                     backend: str = "auto", blocks: int = 20,
                     iterations: int = 6) -> tuple[float, float, float, np.ndarray]:
    """The gyroscope's delay against the accelerometer over the whole recording, fitted jointly with
    the accelerometer's lever arm from the point the body turns about: ``(delay, std, bound, lever)``
    (s, s, s, m body), ``delay`` counted from ``pairing`` as :func:`gyro_delay_recording` counts it
    (positive: the gyro is late). NaN where there is too little to fit.

    In the gyro's own strapdown frame ``I`` (no filter: the gyro integrated from the first sample, at
    the accelerometer's instant in the step) the specific force is
    ``y = R_I f = g_I + a_c + R_I K r - d (w_I x y)``: gravity (constant in I up to the strapdown's
    slow drift), the turning point's own acceleration ``a_c``, the lever arm ``r``'s tangential and
    centripetal terms (``K = [w_dot]x + [w]x^2`` from the gyro) and the delay ``d``'s. ``y`` and the
    regressors are band-passed (``band``: a second-order Butterworth run forward and backward,
    which removes gravity, the drift and the accelerometer's bias) and ``[d, r]`` fitted by least
    squares; the lever arm's term computed from a late gyro is late too, so the delay's column gets
    ``R_I d/dt (K r)`` with the fitted ``r`` and the fit is repeated (``iterations``, Gauss-Newton). The
    strapdown's own errors are fitted with them: the gyro's scale and misalignment ``E`` (9) and its
    bias (3) turn I by ``th = int R_I (E w + b) dt``, which tilts gravity by ``-th x g_I`` (an angle,
    where the delay's term is a rate: they separate).
    ``std``: a jackknife over ``blocks`` blocks of the recording. ``bound``: the residual's RMS over
    that of the delay's column with the lever arm's columns projected out, the most the residual
    could move the delay if all of it correlated with the delay's signature: small where the model
    (a rigid body turning about a fixed point, one delay) explains the accelerometer, large where the
    turning point's own acceleration (a hand's wrist and elbow) does not fit it. A disturbance that
    looks exactly like a delay is not seen by any test. Assumes uniform sampling (the band-pass runs
    on samples); invalid samples are interpolated over. Known limit: ``pairing`` (clamped to one
    step) moves the rotation to the accelerometer's instant but not the lever arm's regressors, which
    stay on the gyro's samples, so with a lever arm the delay moves by less than a change of
    ``pairing`` (about 0.6 of it on the hand-held simulation); the offline mode uses the default
    (``None``, the middle of the step), where the simulated delays are recovered."""
    nan = (math.nan, math.nan, math.nan, np.full(3, np.nan))
    fit = _lever_fit(rec, pairing, band, backend, iterations)
    if fit is None:
        return nan
    a, yf, sol = fit
    n = len(rec)
    res = yf - a @ sol
    c = a[:, 0] - a[:, 1:] @ np.linalg.lstsq(a[:, 1:], a[:, 0], rcond=None)[0]
    cc = float(np.mean(c ** 2))  # 0: nothing in the band turns (a still recording); no delay can be told
    bound = float(np.sqrt(np.mean(res ** 2) / cc)) if cc > 0.0 else math.inf
    edges = 3 * np.linspace(0, n, blocks + 1).astype(int)  # the rows of each block (3 per sample)
    ab = [(a[i:j].T @ a[i:j], a[i:j].T @ yf[i:j]) for i, j in zip(edges[:-1], edges[1:])]
    aa, ay = sum(x for x, _ in ab), sum(x for _, x in ab)
    est = [np.linalg.lstsq(aa - x, ay - z, rcond=None)[0][0] for x, z in ab]  # each block left out
    std = float(np.sqrt((blocks - 1) / blocks * np.sum((np.array(est) - np.mean(est)) ** 2)))
    # the fit is against the accelerometer at its instant in the step (pairing): counted from there
    return float(sol[0]), std, bound, np.asarray(sol[1:4], dtype=float)


def _lever_fit(rec: Recording, pairing: float | None, band: tuple[float, float], backend: str,
               iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`gyro_delay_lever`'s least-squares system and its solution: ``(a, y, sol)``, ``a`` the
    band-passed regressors ``(3 N, 16)`` (the delay's column, the lever arm's three, the strapdown's
    twelve; three rows per sample), ``y`` the band-passed specific force in the gyro's strapdown frame
    ``(3 N,)`` and ``sol`` ``[delay (s), lever arm (m, 3), the strapdown's errors (12)]``; None where
    there is too little to fit. Kept apart so that a diagnostic can look at the residual per stretch
    of the recording (``benchmarks/offline_accuracy.py --lever-blocks``)."""
    from scipy.signal import butter, sosfiltfilt

    from .navigation.strapdown import strapdown

    n = len(rec)
    fs = 1.0 / rec.nominal_dt
    lo, hi = float(band[0]), min(float(band[1]), 0.45 * fs)
    t = np.asarray(rec.time, dtype=float)
    # at least ten periods of the band's lowest frequency, in time: the samples' span and the first one's
    # interval (n / fs where the sampling is uniform; not the count at the median interval, which a
    # jittery clock's shorter intervals make a larger rate)
    if not (0.0 < lo < hi) or t[-1] - t[0] + rec.nominal_dt < 10.0 / lo:
        return None
    gyr, acc = np.array(rec.gyr, dtype=float), np.array(rec.acc, dtype=float)
    for x in (gyr, acc):
        ok = np.isfinite(x).all(axis=1)
        if ok.sum() < 2:
            return None
        for i in range(3):
            x[~ok, i] = np.interp(t[~ok], t[ok], x[ok, i])
    dt = np.ascontiguousarray(rec.dt, dtype=float)
    r_end = quat_to_matrix(strapdown(gyr, acc, dt, quat0=(1.0, 0.0, 0.0, 0.0), backend=backend).quat)
    frac = 0.5 if pairing is None else min(max(pairing / rec.nominal_dt, 0.0), 1.0)  # before the step's end
    rot = r_end.copy()
    rot[1:] = (1.0 - frac) * r_end[1:] + frac * r_end[:-1]  # body -> I at the accelerometer's instant
    y = np.einsum("nij,nj->ni", rot, acc)
    sig = -np.cross(np.einsum("nij,nj->ni", rot, gyr), y)  # d/d(delay) of y
    w = skew(gyr)
    k = skew(np.gradient(gyr, t, axis=0)) + w @ w
    rk = rot @ k
    sos = butter(2, [lo, hi], btype="band", fs=fs, output="sos")
    bp = lambda v: sosfiltfilt(sos, v, axis=0)  # noqa: E731
    yf, sigf, rkf = bp(y), bp(sig), bp(rk)
    # the strapdown's own errors: a gyro reading (I + E) w + b turns I by th = int R_I (E w + b) dt, which
    # tilts gravity in I by -th x g_I (g_I: y low-passed at a fifth of the band's lowest frequency)
    g_i = sosfiltfilt(butter(2, 0.2 * lo, fs=fs, output="sos"), y, axis=0)
    rates = np.concatenate([gyr, np.ones((n, 1))], axis=1) * dt[:, None]  # w_j dt, and dt for the bias
    own = np.stack([bp(-np.cross(np.cumsum(rot[:, :, i] * rates[:, j:j + 1], axis=0), g_i))
                    for i in range(3) for j in range(4)], axis=2)
    lever, delay = np.zeros(3), 0.0
    for _ in range(iterations):
        # the lever arm's term from a late gyro is late: the accelerometer has R_I (K r)(t), the fit R_I (K r)(t - d)
        kr_dot = np.gradient(np.einsum("nij,j->ni", k, lever), t, axis=0)
        col = sigf + bp(np.einsum("nij,nj->ni", rot, kr_dot))
        a = np.concatenate([col[:, :, None], rkf, own], axis=2).reshape(-1, 4 + own.shape[2])
        sol = np.linalg.lstsq(a, yf.reshape(-1), rcond=None)[0]
        step, delay, lever = abs(sol[0] - delay), float(sol[0]), sol[1:4]
        if step < 1e-3 * rec.nominal_dt:
            break
    return a, yf.reshape(-1), sol


def _delay_state(rec, gyr_range, acc_range, backend, segment_time=None):
    """The ``time-offset`` model run once over ``rec`` without forgetting (with ``segment_time`` when
    given): its state (both sensors' estimates; without a magnetometer its block stays empty) and the
    model."""
    extra = {} if segment_time is None else {"segment_time": float(segment_time)}
    model = TimeOffsetModel(forget_time=_NO_FORGETTING, **extra)
    s = model.initial_state(rec.nominal_dt)
    dt = np.ascontiguousarray(rec.dt, dtype=float)
    mag = np.full_like(rec.acc, np.nan) if rec.mag is None else rec.mag
    if resolve_backend(backend, True) == "numba":
        _delay_kernel(s, rec.gyr, rec.acc, mag, dt, _validity(rec.gyr, rec.acc, mag, gyr_range, acc_range),
                      model.params())
    else:
        _model_reference(model, s, rec.gyr, rec.acc, mag, dt, gyr_range, acc_range)
    return s, model


def _with_gyro_retimed(rec: Recording, delay: float) -> Recording:
    """``rec`` with its gyroscope ``delay`` s earlier (:func:`retime_gyro`): a shallow copy, the
    samples passed the Recording's checks already."""
    out = copy.copy(rec)
    out.gyr = retime_gyro(rec.gyr, rec.time, delay)
    return out


def retime_gyro(gyr: np.ndarray, time: np.ndarray, delay: float) -> np.ndarray:
    """The gyroscope ``delay`` s earlier (:func:`gyro_delay_recording`): each sample replaced by the
    rate at its instant plus ``delay``, interpolated linearly between the samples around it (held
    past the ends). Offline the later samples are there, so no extrapolation (the ``time-offset``
    model's online re-timing extrapolates). A sample with a non-finite axis stays as it is, and a
    sample whose interpolation would read one keeps its own value. The orientation integrated from the result
    follows the accelerometer's clock."""
    gyr = np.asarray(gyr, dtype=float)
    t = np.asarray(time, dtype=float)
    out = np.stack([np.interp(t + delay, t, gyr[:, i]) for i in range(3)], axis=1)
    bad = ~(np.isfinite(out).all(axis=1) & np.isfinite(gyr).all(axis=1))
    out[bad] = gyr[bad]
    return out


@njit
def _delay_kernel(s, gyr, acc, mag, dt, ok, p):
    """The ``time-offset`` kernel alone over a recording (its estimate is all that is kept)."""
    q = np.zeros(4)
    q[0] = 1.0
    v = np.empty(9)
    for k in range(gyr.shape[0]):
        _sample_vector(v, gyr, acc, mag, ok, k)
        time_offset_apply(s, v, ok[k, 0], ok[k, 1], ok[k, 2], q, dt[k], p)


def retime_mag(gyr: np.ndarray, mag: np.ndarray, time: np.ndarray, dt: np.ndarray, delay: float,
               pairing: float | None = None, backend: str = "numba") -> np.ndarray:
    """The magnetometer on the filter's pairing: every valid sample ``k`` replaced by the reading
    nearest to its instant, turned by the gyroscope over the time between (``u(t) = exp(-[theta]x)
    u(t')``, ``theta`` the gyro's integral from ``t'`` to ``t``: a direction fixed in the earth turns
    against the body rate).

    A sample's instant is where the filter pairs it: ``pairing`` (the filter's ``mag_delay``)
    before the end of its step, None the middle. A reading is a valid sample that differs from the
    one before it (an equal one is a lower-rate sensor's held copy, :mod:`fusionkit.correctors.heading`'s
    ``mag_hold``), and it describes its own instant minus ``delay`` (s; :func:`mag_delay_recording`).
    The nearest reading may come before or after a sample, so for a stream without held copies
    the result does not depend on the direction of time (a held copy is causal: it repeats a
    past reading); the backward pass gets a stream as well paired as the forward one (a delay of
    several samples, or a held copy, is otherwise a *lead* in reversed time, which no causal
    pairing can express). The gyro's rate is constant over its step (a non-finite rate: 0).
    Invalid magnetometer samples are passed on as they are. ``backend``: ``"numba"``
    (:func:`_retime_kernel`) or ``"reference"`` (array operations, the same numbers to 1e-9)."""
    mag = np.ascontiguousarray(mag, dtype=float)
    gyr = np.ascontiguousarray(gyr, dtype=float)
    time = np.ascontiguousarray(time, dtype=float)
    dt = np.ascontiguousarray(dt, dtype=float)
    if resolve_backend(backend, True) == "numba":
        out = mag.copy()
        _retime_kernel(gyr, mag, time, dt, float(delay), pairing is None, 0.0 if pairing is None else float(pairing),
                       out)
        return out
    return _retime_reference(gyr, mag, time, dt, delay, pairing)


def _retime_reference(gyr, mag, time, dt, delay, pairing):
    """The readable twin of :func:`_retime_kernel` (:func:`retime_mag`'s arithmetic in arrays)."""
    norm = np.linalg.norm(mag, axis=1)
    valid = np.isfinite(norm) & (norm > 0.0)
    fresh = valid.copy()
    fresh[1:] &= ~(valid[:-1] & np.all(mag[1:] == mag[:-1], axis=1))
    j = np.flatnonzero(fresh)
    if j.size == 0:
        return mag.copy()
    inst = time - (0.5 * dt if pairing is None else pairing)  # each sample's instant
    described = inst[j] - delay  # each reading's
    i = np.clip(np.searchsorted(described, inst), 1, max(j.size - 1, 1))
    i0 = np.minimum(i - 1, j.size - 1)
    i1 = np.minimum(i, j.size - 1)
    pick = np.where(np.abs(described[i0] - inst) <= np.abs(described[i1] - inst), i0, i1)
    # the gyro's integral at the steps' ends, linear within each step
    ends = np.concatenate(([time[0] - dt[0]], time))
    rate = np.where(np.isfinite(gyr), gyr, 0.0)
    cum = np.vstack((np.zeros((1, 3)), np.cumsum(rate * dt[:, None], axis=0)))
    theta = np.stack([np.interp(inst, ends, cum[:, a]) - np.interp(described[pick], ends, cum[:, a])
                      for a in range(3)], axis=1)
    turned = _rotate_back(theta, mag[j[pick]])
    return np.where(valid[:, None], turned, mag)


@njit
def _step_at(x, ends, i):
    """``(step, fraction)`` of time ``x`` among the steps' ``ends``, searching from step ``i`` (``x``
    grows from call to call): the gyro's integral there is linear between the step's ends, and held
    beyond the first and the last."""
    m = ends.shape[0]
    if x <= ends[0]:
        return 0, 0.0
    if x >= ends[m - 1]:
        return m - 2, 1.0
    while i < m - 2 and ends[i + 1] < x:
        i += 1
    while i > 0 and ends[i] > x:
        i -= 1
    return i, (x - ends[i]) / (ends[i + 1] - ends[i])


@njit
def _retime_kernel(gyr, mag, time, dt, delay, middle, pairing, out):
    """:func:`retime_mag` compiled: one sweep for the readings, one for the samples (both in time order)."""
    n = mag.shape[0]
    valid = np.zeros(n, dtype=np.bool_)
    fresh = np.empty(n, dtype=np.int64)
    nf = 0
    for k in range(n):
        s = mag[k, 0] * mag[k, 0] + mag[k, 1] * mag[k, 1] + mag[k, 2] * mag[k, 2]
        valid[k] = math.isfinite(s) and math.sqrt(s) > 0.0
        if valid[k] and not (k > 0 and valid[k - 1] and mag[k, 0] == mag[k - 1, 0] and mag[k, 1] == mag[k - 1, 1]
                             and mag[k, 2] == mag[k - 1, 2]):
            fresh[nf] = k
            nf += 1
    if nf == 0:
        return
    inst = np.empty(n)
    for k in range(n):
        inst[k] = time[k] - (0.5 * dt[k] if middle else pairing)
    described = np.empty(nf)
    for r in range(nf):
        described[r] = inst[fresh[r]] - delay
    ends = np.empty(n + 1)
    ends[0] = time[0] - dt[0]
    cum = np.zeros((n + 1, 3))
    for k in range(n):
        ends[k + 1] = time[k]
        for a in range(3):
            g = gyr[k, a]
            cum[k + 1, a] = cum[k, a] + (g if math.isfinite(g) else 0.0) * dt[k]
    i = 0  # the first reading described at or after the sample's instant (searchsorted, left)
    si, sr = 0, 0  # the steps the integrals were last found in
    th = np.empty(3)
    for k in range(n):
        if not valid[k]:
            continue
        x = inst[k]
        while i < nf and described[i] < x:
            i += 1
        c = min(max(i, 1), max(nf - 1, 1))
        i0, i1 = min(c - 1, nf - 1), min(c, nf - 1)
        p = i0 if abs(described[i0] - x) <= abs(described[i1] - x) else i1
        si, f1 = _step_at(x, ends, si)
        sr, f0 = _step_at(described[p], ends, sr)
        for a in range(3):
            th[a] = (cum[si, a] + f1 * (cum[si + 1, a] - cum[si, a])) - (cum[sr, a] + f0 * (cum[sr + 1, a] - cum[sr, a]))
        ang = math.sqrt(th[0] * th[0] + th[1] * th[1] + th[2] * th[2])
        v0, v1, v2 = mag[fresh[p], 0], mag[fresh[p], 1], mag[fresh[p], 2]
        if ang < 1e-300:
            out[k, 0], out[k, 1], out[k, 2] = v0, v1, v2
            continue
        u0, u1, u2 = th[0] / ang, th[1] / ang, th[2] / ang
        co, sn = math.cos(ang), math.sin(ang)
        d = (u0 * v0 + u1 * v1 + u2 * v2) * (1.0 - co)
        # exp(-[theta]x) v = v cos - (u x v) sin + u (u.v)(1 - cos)
        out[k, 0] = v0 * co - (u1 * v2 - u2 * v1) * sn + u0 * d
        out[k, 1] = v1 * co - (u2 * v0 - u0 * v2) * sn + u1 * d
        out[k, 2] = v2 * co - (u0 * v1 - u1 * v0) * sn + u2 * d


def _rotate_back(theta: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``exp(-[theta]x) v`` per row (Rodrigues)."""
    a = np.linalg.norm(theta, axis=1, keepdims=True)
    small = a < 1e-300
    u = theta / np.where(small, 1.0, a)
    c, s = np.cos(a), np.sin(a)
    return v * c - np.cross(u, v) * s + u * np.sum(u * v, axis=1, keepdims=True) * (1.0 - c)


def select_calibration(gyr: np.ndarray, dt: np.ndarray, streams: list[np.ndarray], span: float = math.pi,
                       min_rate: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, the magnetometer stream (of ``streams``, ``(N, 3)`` each; the first is the raw
    one) whose field norm varies least, relative to its mean, over ``span`` rad of the way along
    the recording either side of the sample: ``(the chosen samples, the index of the stream per
    sample)``.

    The way is the rotation, ``max(|gyr|, min_rate) dt`` per sample, and each sample weighs its
    share of it: a turn shows a wrong offset as a swing of the norm, a rest shows only a change of
    the field itself (iron put on or taken off). With ``min_rate`` the calibration model's own
    ``segment_angle / segment_time`` (it closes a segment after either), a rest counts as the
    model counts it. ``min_rate = 0``: a rest weighs nothing and takes the choice of the turns
    around it. Ties, and samples with no way around them, go to the first stream. Symmetric in
    time: the window is measured from the middle of each sample's share. Invalid samples (a
    non-finite field or gyro) weigh nothing and are passed on as they are."""
    g = np.maximum(np.linalg.norm(np.where(np.isfinite(gyr), gyr, 0.0), axis=1), min_rate) * dt
    path = np.cumsum(g) - 0.5 * g  # the rotation turned up to the middle of each sample
    lo = np.searchsorted(path, path - span, side="left")
    hi = np.searchsorted(path, path + span, side="right")
    variances = []
    for m in streams:
        norm = np.linalg.norm(m, axis=1)
        fine = np.isfinite(norm)
        w = np.where(fine, g, 0.0)
        x = np.where(fine, norm, 0.0)
        c0, c1, c2 = (np.concatenate(([0.0], np.cumsum(v))) for v in (w, w * x, w * x * x))
        n = c0[hi] - c0[lo]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = (c1[hi] - c1[lo]) / n
            var = np.maximum((c2[hi] - c2[lo]) / n - mean * mean, 0.0) / (mean * mean)
        variances.append(np.where(n > 0.0, var, np.inf))
    v = np.array(variances)
    choice = np.argmin(np.where(np.isfinite(v), v, np.inf), axis=0)  # a column of inf (no way around): 0, the raw
    out = np.take_along_axis(np.stack(streams), choice[None, :, None], axis=0)[0]
    return out, choice.astype(np.int8)


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
