"""``ins-gnss``: a loosely coupled INS/GNSS error-state extended Kalman filter (16 states).

Navigation frame: local-level NED about the GNSS stream's own origin (the coordinates its
positions are given in), on a WGS-84 earth (``fusionkit.navigation.earth``). Body axes FRD
inside; sensors in other axes are mapped from the recording's axes (``Recording.body``, or
``body=``; FRD when neither says).

Nominal state: attitude ``C`` (body FRD -> NED), velocity ``v`` (NED, m/s), position ``p``
(local NED, m), gyro bias ``b_g`` (rad/s) and accelerometer bias ``b_a`` (m/s^2), body axes,
and the IMU-to-GNSS time offset ``dt_s`` (s): the IMU's time stamps lag the receiver's clock
by it, so the INS after the sample stamped ``t`` is the state at GNSS time ``t + dt_s``.
Error state (16): ``phi`` (NED, ``C_true = (I + [phi x]) C``), ``dv``, ``dp``, ``db_g``,
``db_a``, ``d dt_s`` (true minus estimate), covariance ``P``.

Per IMU sample (rate held over ``(t[k-1], t[k]]``, ``dt[k] = t[k] - t[k-1]``):

1. strapdown, source 004's Rodrigues step: ``w = gyr - b_g``, ``f = acc - b_a``;
   ``dv_n = C (f + (w dt x f) / 2) dt`` (the rotation over the sample, to first order);
   ``C <- exp(-[w_in dt x]) C exp([w dt x])`` with ``w_in = w_ie + w_en`` (earth and transport
   rate); ``v <- v + dv_n + (g - (2 w_ie + w_en) x v) dt`` (WGS-84 normal gravity at the current
   latitude and height); ``p`` by the trapezoidal rule, scaled to the map projection of the
   local NED coordinates (``fusionkit.io.gnss``);
2. the error dynamics ``phi' = -w_in x phi - C db_g``, ``dv' = -[f_n x] phi - (2 w_ie + w_en) x
   dv - C db_a``, ``dp' = dv``, biases random walks, are accumulated over the samples (``int C
   dt``, ``int f_n dt``) and ``P`` is propagated with them at each GNSS epoch and at least every
   ``cov_interval`` s (the transition matrix to second order in the position rows): the
   16 x 16 products run at 10 Hz, not per IMU sample; the time offset is a constant;
3. at each GNSS epoch (``rec.gnss``, in its own time; an epoch is used at the first IMU sample at
   or after it, the INS ``lag = age + dt_s`` ahead of it): velocity update ``v + C (w x l) - a
   lag`` (``a`` the velocity's rate over the last sample) and position update ``p + C l - v
   lag`` (lever arm ``l``, body), their sensitivity to the time offset ``-a`` and ``-v``, each
   its 3 rows processed one by one;
   each gated on its normalised innovation squared (chi-square, 3 degrees of freedom, flag
   ``GNSS_REJECTED``); rejected for longer than ``gate_timeout`` s in a row, the filter resets
   that state to the measurement (the filter, not the receiver, is wrong then). Invalid epochs
   (outages, NaN), duplicates and epochs older than the last one used are skipped.

Start: source 000's alignment while still (roll, pitch, gyro bias as the mean rate, minus the
earth rate once the heading is known). Its tilt carries the horizontal accelerometer bias
(``phi_h = [(C b_a)_E, -(C b_a)_N] / g``): the initial covariance holds exactly that correlation,
so that the filter separates the two when the vehicle turns. Heading: from the magnetometer
(``heading="magnetometer"``, or "auto" with a magnetometer) plus the declination; otherwise
from the GNSS course, which assumes that the vehicle moves forward without sideslip (true for
cars and for aircraft flying with the nose along the track, not for a helicopter moving
sideways or a car reversing): until the speed reaches ``min_speed`` the attitude is integrated
from the gyros alone (flag ALIGNING) with an arbitrary heading; at the first epoch above it,
the heading difference to the course is applied to the alignment attitude and the filter runs
again from the end of the alignment over the buffered samples, now with its heading (``run``
rewrites those samples; a stream can only go on from there).

Outputs, at each sample's time on the GNSS clock (the INS moved back by ``dt_s``: ``C exp(-[w
dt_s x])``, ``v - a dt_s``, ``p - v dt_s``): ``Result.quat`` (sensor -> ``frame``) and in
``diagnostics``: ``velocity``, ``position`` (N, 3, in ``frame`` axes, m/s and m), ``gyr_bias``,
``acc_bias`` (N, 3, sensor axes), ``attitude_std`` (rad, about the ``frame`` axes),
``velocity_std``, ``position_std``, ``gyr_bias_std``, ``acc_bias_std`` (1-sigma from ``P``,
the diagonal of its last propagation), ``time_offset``, ``time_offset_std`` (N, s), ``P``
(final 16 x 16, NED/FRD, the time offset last), ``alignment_end_index`` and ``state`` (for
``run(rec, state=...)``, chunked runs).
"""

from __future__ import annotations

import copy
import math
from typing import Any, ClassVar, Literal

import numpy as np

from .._kernels import dcm_to_quat, matmul3_into, quat_to_dcm, rodrigues_into
from .._numba import njit, resolve_backend
from ..config import AlignmentConfig, FilterConfig, param
from ..conventions import body_matrix, frame_matrix
from ..detectors.motion import MotionConfig, MotionDetector, _motion_step
from ..errors import InputError
from ..navigation.alignment import (ALIGN_SIZE, ALIGNED_BEFORE, ALIGNED_NOW, ALIGNING, BIAS, END, NGYR, PHASE, Aligner,
                                     align_step)
from ..navigation.earth import EARTH_RATE, normal_gravity, radii
from ..protocols import Filter, Sample
from ..rotations import cross, matrix_to_quat, quat_mul, quat_to_matrix, rodrigues, skew
from ..types import Flag, Recording, Result
from ..validation import as_vector, check_finite_all, check_dt, check_timestamp

__all__ = ["InsGnssFilter", "InsGnssConfig", "gnss_epoch_rows"]

#: RFU -> FRD (the same matrix both ways)

# state layout: nominal state, covariance, accumulators, bookkeeping
_N = 16  # error states: phi, dv, dp, db_g, db_a (3 each), the IMU-to-GNSS time offset
_C, _V, _P, _BG, _BA, _DTS, _COV = 0, 9, 12, 15, 18, 21, 22  # _DTS: the time offset (s)
_SC = _COV + _N * _N
_DV, _T = _SC + 9, _SC + 12  # int C dt (9), int C f dt (3), accumulated time
# phase (0 aligning, 1 heading search, 2 navigating), last epoch used, time, start sample, sample number
_PHASE, _TLAST, _TIME, _KSTART, _K = _T + 1, _T + 2, _T + 3, _T + 4, _T + 5
_CAL, _GAL = _T + 6, _T + 15  # alignment attitude FRD -> NED (9), mean gyro at rest, FRD (3)
_RV, _RP, _TGOOD, _RESTART = _T + 18, _T + 19, _T + 20, _T + 21  # last accepted velocity / position, last usable epoch
_W = _T + 22  # the last bias-corrected rate (3), for the lever arm and the time offset
# the earth model at the last covariance step: gravity, map scale north / east, w_ie (3), w_en (3); the stds (_N)
_GRAV, _S0, _S1, _WIE, _WEN, _SD = _W + 3, _W + 4, _W + 5, _W + 6, _W + 9, _W + 12
_C0 = _SD + _N  # start attitude (9)
_HVAR, _LEVEL, _PHI0 = _C0 + 9, _C0 + 10, _C0 + 11  # its heading variance, re-levelled, tilt fix (3)
_ACC = _PHI0 + 3  # the last sample's acceleration, NED (3): the velocity's rate, for the time offset
# the non-holonomic check: exponentially weighted sums (times the epoch interval) of the GNSS
# velocity's body-frame products x x, x y, x z, y y, z z, the weights' sum, the moving time seen
_NXX, _NXY, _NXZ, _NYY, _NZZ, _NHW, _NHT = range(_ACC + 3, _ACC + 10)
_SIZE = _ACC + 10

# parameter vector layout
(_GN, _AN, _GQ, _AQ, _VH, _VV, _PH, _PV, _GATE, _GTO, _CI, _MINV, _SLIP, _BG0, _BA0, _TILT0, _MAGH, _LAT, _H0,
 _EARTH, _DECL, _MAXAGE, _HMAG, _V0, _P0, _LEV) = range(26)
_RELEVEL = _LEV + 3  # the lever arm is 3 wide
_TS0 = _RELEVEL + 1  # the time offset's initial std
_NHC, _NHM, _NHT0 = _TS0 + 1, _TS0 + 2, _TS0 + 3  # non-holonomic: std (m/s), mode (0 off, 1 on, 2 auto), check (s)
_NHGATE = 10.83  # the constraint's gate: chi-square, 1 dof, p = 1e-3 (a skid, a kerb)
_NPAR = _NHT0 + 1


class InsGnssConfig(FilterConfig):
    gyr_noise: float = param(
        2.2e-4, unit="rad/s/sqrt(Hz)", description="gyro white noise density (angle random walk; 0.75 deg/sqrt(h), "
        "a low-cost MEMS IMU)", gt=0)
    acc_noise: float = param(
        8.3e-4, unit="m/s^2/sqrt(Hz)", description="accelerometer white noise density (velocity random walk; "
        "0.05 m/s/sqrt(h))", gt=0)
    gyr_bias_instability: float = param(
        4.85e-5, unit="rad/s", description="gyro bias instability (10 deg/h), a Gauss-Markov process of time constant "
        "bias_tau, modelled as a random walk of the same short-term growth", gt=0)
    acc_bias_instability: float = param(
        2e-4, unit="m/s^2", description="accelerometer bias instability (20 ug)", gt=0)
    bias_tau: float = param(100.0, unit="s", description="correlation time of the bias instabilities", gt=0)
    initial_gyr_bias_std: float = param(
        1e-4, unit="rad/s", description="gyro bias std after the alignment's average at rest (noise over the "
        "average and the bias instability)", gt=0)
    initial_acc_bias_std: float = param(
        0.05, unit="m/s^2", description="accelerometer turn-on bias std (5 mg, MEMS); the alignment's tilt error is "
        "this over g, correlated with it", gt=0)
    initial_tilt_std: float = param(
        1e-3, unit="rad", description="alignment tilt noise beyond the accelerometer bias", gt=0)
    initial_velocity_std: float = param(0.5, unit="m/s", description="velocity std at the end of the alignment", gt=0)
    initial_position_std: float = param(
        1e4, unit="m", description="position std at the start (the first fix sets the position)", gt=0)
    gnss_vel_std: tuple[float, float] = param(
        (0.05, 0.075), unit="m/s", description="GNSS velocity noise (horizontal, vertical): Doppler velocity of a "
        "standalone receiver, vertical 1.5x")
    gnss_pos_std: tuple[float, float] = param(
        (5.0, 7.5), unit="m", description="GNSS position noise (horizontal, vertical): standalone single-frequency "
        "fix with multipath margin, vertical 1.5x")
    lever_arm: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0), unit="m", description="GNSS antenna position relative to the IMU, sensor axes")
    gate: float | None = param(
        21.1, unit="-", description="reject a GNSS velocity or position whose normalised innovation squared "
        "exceeds this (chi-square, 3 dof: 21.1 is p = 1e-4); None: off", gt=0)
    gate_timeout: float = param(
        5.0, unit="s", description="after this long with every epoch rejected, reset velocity / position to GNSS", gt=0)
    cov_interval: float = param(0.1, unit="s", description="the covariance is propagated at least this often", gt=0)
    heading: Literal["auto", "magnetometer", "course"] = param(
        "auto", unit="-", description="initial heading: magnetometer at the alignment ('auto': when there is one), "
        "or the GNSS course once the speed reaches min_speed (forward motion, no sideslip assumed)")
    min_speed: float = param(5.0, unit="m/s", description="ground speed for a course heading", gt=0)
    sideslip_std: float = param(
        0.035, unit="rad", description="course heading: the sideslip the no-sideslip assumption may miss (2 deg)", gt=0)
    mag_heading_std: float = param(
        0.1, unit="rad", description="magnetometer heading std (declination and iron errors)", gt=0)
    declination: float | None = param(
        None, unit="deg", description="magnetic declination (east positive); None: the recording's "
        "mag_declination_deg, else 0")
    latitude: float | None = param(
        None, unit="deg", description="latitude of the local frame's origin; None: the recording's origin_lla; "
        "without either the earth rate is left out and gravity is taken at 45 deg")
    altitude: float | None = param(None, unit="m", description="height of the origin; None: origin_lla, else 0")
    relevel: float | None = param(
        0.1, unit="-", description="once the horizontal accelerometer bias std is below this fraction of its initial "
        "value, level the alignment attitude with the bias estimate and run again from the alignment's end (run() also "
        "re-levels the alignment span's output); None: never (strictly causal output)", gt=0, lt=1)
    time_offset_std: float | None = param(
        0.05, unit="s", description="initial std of the IMU-to-GNSS time offset, estimated as a state (the IMU's "
        "time stamps against the receiver's: sampling conventions, buffering, an unsynchronised clock); None: not "
        "estimated (taken as 0, the 15-state filter)", gt=0)
    nonholonomic: Literal["auto", "on", "off"] = param(
        "auto", unit="-", description="a wheeled ground vehicle's constraint (its velocity has no lateral and no "
        "vertical part in the vehicle's axes: the IMU's, turned by a mounting yaw and pitch estimated from GNSS), a "
        "pseudo-measurement at every covariance step: 'on' always (a car), 'off' never (aircraft, helicopters, boats, "
        "people), 'auto' once GNSS has shown it holds: over nonholonomic_check s of motion (speed >= min_speed) the "
        "GNSS velocity's lateral and vertical parts, the mounting removed, have an RMS within nonholonomic_std, and "
        "for as long as they do")
    nonholonomic_std: float = param(
        0.2, unit="m/s", description="the constraint's std: sideslip, suspension, an IMU ahead of the rear axle in "
        "turns", gt=0)
    nonholonomic_check: float = param(
        60.0, unit="s", description="'auto': the moving time over which GNSS must confirm the constraint, and the "
        "time constant of that running check", gt=0)
    gnss_max_age: float = param(0.5, unit="s", description="an epoch older than this is a gap (GNSS_GAP)", gt=0)
    alignment: Literal["motion", "fixed"] = param("motion", unit="-", description="source 000 alignment mode")
    alignment_duration: float = param(10.0, unit="s", description="mandatory alignment time", gt=0)
    motion: MotionConfig = param(MotionConfig(), unit="-", description="motion detector ending the alignment")


def gnss_epoch_rows(rec: Recording) -> np.ndarray:
    """(N, 8) rows ``new, t_epoch, vN, vE, vD, pN, pE, pD`` (NED): the GNSS epoch used at each
    IMU sample, the first sample at or after the epoch (``new = 0``: none). Invalid epochs have
    NaN values; of several epochs before one sample, the latest is used. Without position the
    position columns are NaN."""
    n = len(rec)
    out = np.zeros((n, 8))
    out[:, 1:] = np.nan
    g = rec.gnss
    if g is None or g.t.size == 0:
        return out
    m = frame_matrix(g.frame, "NED")
    vel = np.asarray(g.vel, float) @ m.T
    pos = np.full_like(vel, np.nan) if g.pos is None else np.asarray(g.pos, float) @ m.T
    bad = ~np.asarray(g.valid, bool)
    vel[bad] = np.nan
    pos[bad] = np.nan
    order = np.argsort(g.t, kind="stable")
    k = np.searchsorted(rec.time, g.t[order], side="left")
    inside = k < n
    order, k = order[inside], k[inside]
    _, first = np.unique(k[::-1], return_index=True)  # by time: the latest epoch before a sample wins
    last = k.size - 1 - first
    j, k = order[last], k[last]
    out[k, 0] = 1.0
    out[k, 1] = g.t[j]
    out[k, 2:5] = vel[j]
    out[k, 5:8] = pos[j]
    return out


def _origin(rec: Recording | None, c: InsGnssConfig):
    """(lat rad, height m, known) of the local frame's origin, and the declination (rad)."""
    meta = {} if rec is None else rec.meta
    attrs = meta.get("attrs") or {}
    lla = meta.get("origin_lla", attrs.get("origin_lla"))
    lat = c.latitude if c.latitude is not None else (None if lla is None else float(lla[0]))
    h = c.altitude if c.altitude is not None else (0.0 if lla is None else float(lla[2]))
    decl = c.declination
    if decl is None:
        decl = meta.get("mag_declination_deg", attrs.get("mag_declination_deg", 0.0))
    known = lat is not None
    return math.radians(45.0 if lat is None else lat), float(h), known, math.radians(float(decl))


def _yaw(c) -> float:
    """Heading of the body's forward axis (FRD x) in NED."""
    return math.atan2(c[1, 0], c[0, 0])


def _wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


class InsGnssFilter(Filter):
    """Loosely coupled INS/GNSS error-state EKF: attitude, velocity, position, gyro and
    accelerometer biases (see the module docs)."""

    name: ClassVar[str] = "ins-gnss"
    Config = InsGnssConfig
    requires_gnss: ClassVar[bool] = True
    #: ``update()`` exists (GNSS epochs as ``(t, v, p)``), but ``run()`` rewrites the spans it goes over
    #: again (course heading, re-levelling) where a stream cannot: the two differ there by design
    streaming: ClassVar[bool] = False
    source: ClassVar[str] = "baseline (loosely coupled INS/GNSS EKF); strapdown step of source 004, alignment of 000"
    summary: ClassVar[str] = ("16-state error-state EKF: strapdown propagation, GNSS velocity and position updates, "
                              "IMU-to-GNSS time offset")

    def __init__(self, config=None, **params: Any) -> None:
        super().__init__(config, **params)
        c = self.config
        motion = c.motion
        if "arm_after" not in motion.model_fields_set:
            motion = motion.model_copy(update={"arm_after": c.alignment_duration})
        self.detector = MotionDetector(motion)
        self._aligners: dict[bool, Aligner] = {}
        self.M = body_matrix(c.body or "FRD", "FRD")  # sensor -> FRD (update(): the config's axes)
        self.F = frame_matrix("NED", c.frame)  # NED -> output frame
        self._stream: dict | None = None
        self._rec_meta: Recording | None = None
        self.last_flags = 0

    def dimension(self, rec) -> str:
        return "9D" if self._use_mag(rec) else "6D"

    def _use_mag(self, rec) -> bool:
        h = self.config.heading
        return rec is not None and rec.mag is not None and h in ("auto", "magnetometer")

    def aligner(self, use_mag: bool) -> Aligner:
        key = use_mag
        if key not in self._aligners:
            c = self.config
            cfg = AlignmentConfig(mode=c.alignment, duration=c.alignment_duration,
                                  heading="magnetometer" if use_mag else "zero")
            self._aligners[key] = Aligner(cfg, "NED")
        return self._aligners[key]

    def params(self, rec: Recording | None = None) -> np.ndarray:
        """The kernel's parameter vector (the origin and declination from ``rec``'s meta)."""
        c = self.config
        lat, h0, known, decl = _origin(rec, c)
        p = np.zeros(_NPAR)
        p[_GN], p[_AN] = c.gyr_noise, c.acc_noise
        p[_GQ] = c.gyr_bias_instability * math.sqrt(2.0 / c.bias_tau)
        p[_AQ] = c.acc_bias_instability * math.sqrt(2.0 / c.bias_tau)
        p[_VH], p[_VV] = c.gnss_vel_std
        p[_PH], p[_PV] = c.gnss_pos_std
        p[_GATE] = math.inf if c.gate is None else c.gate
        p[_GTO], p[_CI], p[_MINV], p[_SLIP] = c.gate_timeout, c.cov_interval, c.min_speed, c.sideslip_std
        p[_BG0], p[_BA0], p[_TILT0], p[_MAGH] = (c.initial_gyr_bias_std, c.initial_acc_bias_std, c.initial_tilt_std,
                                                 c.mag_heading_std)
        p[_LAT], p[_H0], p[_EARTH], p[_DECL] = lat, h0, float(known), decl
        p[_LEV:_LEV + 3] = self.M @ np.asarray(c.lever_arm, float)
        p[_MAXAGE] = c.gnss_max_age
        p[_HMAG] = float(self._use_mag(rec))
        p[_V0], p[_P0] = c.initial_velocity_std, c.initial_position_std
        p[_RELEVEL] = c.relevel * c.initial_acc_bias_std if c.relevel is not None else -1.0
        p[_TS0] = 0.0 if c.time_offset_std is None else c.time_offset_std
        p[_NHC], p[_NHT0] = c.nonholonomic_std, c.nonholonomic_check
        p[_NHM] = {"off": 0.0, "on": 1.0, "auto": 2.0}[c.nonholonomic]
        return p

    def new_state(self, dt: float, rec: Recording | None = None) -> dict[str, Any]:
        x = np.zeros(_SIZE)
        x[_C:_C + 9] = np.eye(3).reshape(9)
        x[_TLAST] = x[_TGOOD] = -np.inf
        x[_TIME] = np.nan
        use_mag = self._use_mag(rec)
        # "M": the body axes the samples are read in (run(): the recording's; update(): the config's), kept with
        # the state so that a stream or run continuing it reads its samples in the same axes
        return {"filter": self.name, "dt": dt, "x": x, "det": self.detector.initial_state(dt), "use_mag": use_mag,
                "align": self.aligner(use_mag).new_state(), "p": self.params(rec), "M": self.M.copy()}

    # -- the readable reference ----------------------------------------------------------------
    def _step(self, st, gyr, acc, mag, dt, t, gn) -> tuple[np.ndarray, int]:
        """One sample at time ``t``; ``gn`` its :func:`gnss_epoch_rows` row. Returns
        (q sensor -> frame, flags). Sets ``x[_RESTART]`` when the run must go back to
        ``x[_KSTART]`` (the heading was found from the course)."""
        x, al, p = st["x"], st["align"], st["p"]
        gyr_ok = bool(np.isfinite(gyr).all())
        acc_ok = bool(np.isfinite(acc).all() and np.any(acc != 0))
        mag_ok = st["use_mag"] and mag is not None and bool(np.isfinite(mag).all() and np.any(mag != 0))
        flags = (0 if gyr_ok else Flag.GYR_INVALID) | (0 if acc_ok else Flag.ACC_INVALID)
        x[_TIME] = t
        k = x[_K]
        x[_K] += 1.0
        if x[_PHASE] == 0.0:  # source 000's alignment, ended by the motion detector
            if al[PHASE] == 0.0 and gyr_ok and acc_ok and self.detector.step(st["det"], Sample(gyr, acc, None, dt)):
                flags |= Flag.MOTION
            status, q = self.aligner(st["use_mag"]).step(
                al, gyr, acc, mag if mag_ok else None, gyr_ok, acc_ok, mag_ok, bool(flags & Flag.MOTION), dt)
            if status in (ALIGNED_NOW, ALIGNED_BEFORE):
                self._aligned(x, quat_to_matrix(q) @ self.M.T, al, k + (1.0 if status == ALIGNED_NOW else 0.0), p)
            if status in (ALIGNING, ALIGNED_NOW):  # (with the declination when the magnetometer gives the heading)
                decl = _rz(p[_DECL] if p[_HMAG] else 0.0)
                return matrix_to_quat(self.F @ decl @ quat_to_matrix(q)), flags | Flag.ALIGNING
        c = x[_C:_C + 9].reshape(3, 3)
        if gn[0] != 0.0 and np.isfinite(gn[2:8]).any() and gn[1] <= t:
            x[_TGOOD] = max(x[_TGOOD], gn[1])
        if not (t - x[_TGOOD] <= p[_MAXAGE]):
            flags |= Flag.GNSS_GAP
        if not (gyr_ok and acc_ok):  # hold the state over a bad sample
            return self._output(x), flags | (Flag.ALIGNING if x[_PHASE] == 1.0 else 0)
        w = self.M @ gyr - x[_BG:_BG + 3]
        f = self.M @ acc - x[_BA:_BA + 3]
        if x[_PHASE] == 1.0:  # heading search: gyros alone, then the course
            x[_C:_C + 9] = (c @ rodrigues(w * dt)).reshape(9)
            if gn[0] != 0.0 and np.isfinite(gn[2:5]).all() and 0.0 <= t - gn[1] <= p[_MAXAGE]:
                speed = math.hypot(gn[2], gn[3])
                if speed >= p[_MINV]:
                    dpsi = _wrap(math.atan2(gn[3], gn[2]) - _yaw(x[_C:_C + 9].reshape(3, 3)))
                    var = (p[_VH] / speed) ** 2 + p[_SLIP] ** 2
                    self._start(x, _rz(dpsi) @ x[_CAL:_CAL + 9].reshape(3, 3), var, p, t)
                    x[_RESTART] = 1.0
            return self._output(x), flags | Flag.ALIGNING
        # 1. strapdown
        v = x[_V:_V + 3].copy()
        w_ie, w_en = x[_WIE:_WIE + 3], x[_WEN:_WEN + 3]  # the earth model of the last covariance step
        th = w * dt
        dv = c @ (f + 0.5 * cross(th, f)) * dt
        c_new = rodrigues(-(w_ie + w_en) * dt) @ c @ rodrigues(th)
        v_new = v + dv + (np.array([0.0, 0.0, x[_GRAV]]) - cross(2.0 * w_ie + w_en, v)) * dt
        x[_P:_P + 3] += np.array([x[_S0], x[_S1], 1.0]) * (0.5 * (v + v_new) * dt)
        x[_V:_V + 3] = v_new
        x[_C:_C + 9] = c_new.reshape(9)
        x[_SC:_SC + 9] += c_new.reshape(9) * dt
        x[_DV:_DV + 3] += dv
        x[_T] += dt
        x[_W:_W + 3] = w
        x[_ACC:_ACC + 3] = (v_new - v) / dt
        # 2. and 3. covariance at the epochs (and every cov_interval), GNSS updates
        new = gn[0] != 0.0 and gn[1] > x[_TLAST] and 0.0 <= t - gn[1] <= p[_MAXAGE] and np.isfinite(gn[2:8]).any()
        if new or x[_T] >= p[_CI] * (1.0 - 1e-9):  # (a sum of dt a rounding short of it counts)
            self._propagate(x, p)
            if _nonholonomic_on(x, p):
                self._nonholonomic(x, p)
        if new:
            flags |= self._update(x, p, gn, t)
            if x[_LEVEL] == 0.0 and max(x[_SD + 12], x[_SD + 13]) < p[_RELEVEL]:
                self._relevel(x, p, t)
        return self._output(x), flags

    def _relevel(self, x, p, t) -> None:
        """The alignment's tilt error is ``phi = J C0 b_a / g`` (module docs): with the
        accelerometer bias now known, start again from the re-levelled attitude and that bias."""
        c0 = x[_C0:_C0 + 9].reshape(3, 3)
        a = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]) @ c0 / normal_gravity(p[_LAT], p[_H0])
        phi = a @ x[_BA:_BA + 3]
        x[_LEVEL] = 1.0
        x[_PHI0:_PHI0 + 3] = phi
        self._start(x, rodrigues(phi) @ c0, x[_HVAR], p, t, x[_BA:_BA + 3].copy(), x[_DTS])
        x[_RESTART] = 1.0

    def _geo(self, x, p):
        """Latitude, height and the radii of curvature at the current position."""
        rm0, _ = radii(p[_LAT])
        lat = p[_LAT] + x[_P] / (rm0 + p[_H0])
        h = p[_H0] - x[_P + 2]
        rm, rn = radii(lat)
        return lat, h, rm, rn

    def _refresh(self, x, p) -> None:
        """The earth model at the current position and velocity (gravity, the map scale of the
        local coordinates, earth and transport rates), and the stds from ``P``; updated at every
        covariance step (they change by parts per million over it)."""
        lat, h, rm, rn = self._geo(x, p)
        rm0, rn0 = radii(p[_LAT])
        v = x[_V:_V + 3]
        e = p[_EARTH] * EARTH_RATE
        x[_GRAV] = normal_gravity(lat, h)
        x[_S0] = (rm0 + p[_H0]) / (rm + h)
        x[_S1] = (rn0 + p[_H0]) * math.cos(p[_LAT]) / ((rn + h) * math.cos(lat))
        x[_WIE:_WIE + 3] = e * math.cos(lat), 0.0, -e * math.sin(lat)
        x[_WEN:_WEN + 3] = v[1] / (rn + h), -v[0] / (rm + h), -v[1] * math.tan(lat) / (rn + h)
        x[_SD:_SD + _N] = np.sqrt(np.maximum(np.diag(x[_COV:_COV + _N * _N].reshape(_N, _N)), 0.0))

    def _aligned(self, x, c_align, al, k_start, p) -> None:
        """The alignment ended: keep its attitude (FRD -> NED, with the declination when the
        magnetometer set the heading) and mean rate; navigate or search the heading."""
        if p[_HMAG]:
            c_align = _rz(p[_DECL]) @ c_align
        x[_CAL:_CAL + 9] = c_align.reshape(9)
        x[_GAL:_GAL + 3] = self.M @ al[BIAS:BIAS + 3] if al[NGYR] > 0 else 0.0
        x[_KSTART] = k_start
        if p[_HMAG]:
            self._start(x, c_align, p[_MAGH] ** 2, p, x[_TIME])
        else:
            x[_C:_C + 9] = c_align.reshape(9)
            x[_BG:_BG + 3] = x[_GAL:_GAL + 3]
            x[_PHASE] = 1.0

    def _start(self, x, c0, heading_var, p, t, ba0=None, dts0=0.0) -> None:
        """Start navigating from attitude ``c0`` (FRD -> NED) at rest (see the module docs),
        with the accelerometer bias ``ba0`` (default 0) and the time offset ``dts0``."""
        x[_C:_C + 9] = c0.reshape(9)
        x[_C0:_C0 + 9] = c0.reshape(9)
        x[_HVAR] = heading_var
        x[_V:_V + 3] = 0.0
        x[_P:_P + 3] = 0.0
        lat, h = p[_LAT], p[_H0]
        w_ie = p[_EARTH] * EARTH_RATE * np.array([math.cos(lat), 0.0, -math.sin(lat)])
        x[_BG:_BG + 3] = x[_GAL:_GAL + 3] - c0.T @ w_ie
        x[_BA:_BA + 3] = 0.0 if ba0 is None else ba0
        x[_DTS] = dts0
        x[_ACC:_ACC + 3] = 0.0
        g = normal_gravity(lat, h)
        a = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]) @ c0 / g
        pm = np.zeros((_N, _N))
        sa = p[_BA0] ** 2
        pm[0:3, 0:3] = sa * a @ a.T + np.diag([p[_TILT0] ** 2, p[_TILT0] ** 2, heading_var])
        pm[0:3, 12:15] = sa * a
        pm[12:15, 0:3] = sa * a.T
        pm[3:6, 3:6] = p[_V0] ** 2 * np.eye(3)
        pm[6:9, 6:9] = p[_P0] ** 2 * np.eye(3)
        pm[9:12, 9:12] = p[_BG0] ** 2 * np.eye(3)
        pm[12:15, 12:15] = sa * np.eye(3)
        pm[15, 15] = p[_TS0] ** 2
        x[_COV:_COV + _N * _N] = pm.reshape(_N * _N)
        x[_SC:_T + 1] = 0.0
        x[_NXX:_NHT + 1] = 0.0
        x[_TLAST] = x[_TGOOD] = -np.inf
        x[_RV] = x[_RP] = t
        x[_PHASE] = 2.0
        self._refresh(x, p)

    def _propagate(self, x, p) -> None:
        """``P <- F P F^T + Q`` over the accumulated interval."""
        tt = x[_T]
        if tt <= 0.0:
            return
        w_ie, w_en = x[_WIE:_WIE + 3], x[_WEN:_WEN + 3]
        sc = x[_SC:_SC + 9].reshape(3, 3)
        sdv = skew(x[_DV:_DV + 3])
        f = np.eye(_N)
        f[0:3, 0:3] -= skew(w_ie + w_en) * tt
        f[0:3, 9:12] = -sc
        f[3:6, 0:3] = -sdv
        f[3:6, 3:6] -= skew(2.0 * w_ie + w_en) * tt
        f[3:6, 12:15] = -sc
        f[6:9, 0:3] = -0.5 * tt * sdv
        f[6:9, 3:6] = tt * np.eye(3)
        f[6:9, 12:15] = -0.5 * tt * sc
        pm = x[_COV:_COV + _N * _N].reshape(_N, _N)
        pm = f @ pm @ f.T
        _add_process_noise(pm, p, tt)
        x[_COV:_COV + _N * _N] = (0.5 * (pm + pm.T)).reshape(_N * _N)
        x[_SC:_T + 1] = 0.0
        self._refresh(x, p)

    def _update(self, x, p, gn, t) -> int:
        """The GNSS velocity and position updates of one epoch; returns flags."""
        flags = 0
        age = t - gn[1]
        lag = age + x[_DTS]  # the INS state is this far ahead of the epoch
        interval = gn[1] - x[_TLAST]
        x[_TLAST] = gn[1]
        c = x[_C:_C + 9].reshape(3, 3)
        lev = p[_LEV:_LEV + 3]
        pm = x[_COV:_COV + _N * _N].reshape(_N, _N).copy()
        dx = np.zeros(_N)
        cl = c @ lev
        cwl = c @ cross(x[_W:_W + 3], lev)
        for kind, z in ((0, gn[2:5]), (1, gn[5:8])):
            if not np.isfinite(z).all():
                continue
            hm = np.zeros((3, _N))
            if kind == 0:
                y = z - (x[_V:_V + 3] + cwl - x[_ACC:_ACC + 3] * lag)
                hm[:, 3:6] = np.eye(3)
                hm[:, 15] = -x[_ACC:_ACC + 3]
                hm[:, 0:3] = -skew(cwl)
                hm[:, 9:12] = c @ skew(lev)
                r = np.array([p[_VH], p[_VH], p[_VV]]) ** 2
                blk, last = 3, _RV
            else:
                y = z - (x[_P:_P + 3] + cl - x[_V:_V + 3] * lag)
                hm[:, 6:9] = np.eye(3)
                hm[:, 15] = -x[_V:_V + 3]
                hm[:, 0:3] = -skew(cl)
                r = np.array([p[_PH], p[_PH], p[_PV]]) ** 2
                blk, last = 6, _RP
            yg = y - hm @ dx  # the innovation after this epoch's earlier rows
            s = hm @ pm @ hm.T + np.diag(r)
            nis = float(yg @ np.linalg.solve(s, yg))
            if nis <= p[_GATE]:
                if kind == 0 and p[_NHM] != 0.0:
                    _nonholonomic_check(x, p, c.T @ (z - cwl), interval)
                for i in range(3):
                    hp = hm[i] @ pm
                    si = hp @ hm[i] + r[i]
                    kg = hp / si
                    dx += kg * (y[i] - hm[i] @ dx)
                    pm -= np.outer(kg, kg) * si
                x[last] = t
            elif t - x[last] > p[_GTO]:  # rejected for too long: the filter is wrong, reset
                sl = slice(blk, blk + 3)
                if kind == 0:
                    x[_V:_V + 3] += yg
                else:
                    x[_P:_P + 3] += yg
                dx[sl] = 0.0
                pm[sl, :] = 0.0
                pm[:, sl] = 0.0
                pm[sl, sl] = np.diag(r)
                x[last] = t
                flags |= Flag.GNSS_REJECTED
            else:
                flags |= Flag.GNSS_REJECTED
        self._correct(x, dx, pm)
        return flags

    def _nonholonomic(self, x, p) -> None:
        """A wheeled vehicle does not slide sideways or leave the road: its velocity has no
        lateral and no vertical part in the vehicle's axes, which are the IMU's (FRD) turned by the
        mounting ``(a_y, a_z)``: ``u_i . v_b = 0`` with ``u_i = e_i - a_i e_x``, each a scalar
        pseudo-measurement of std ``p[_NHC]``. With ``C_true = (I + [phi x]) C`` and ``v_b = C^T v``,
        ``u . v_b_true = (C u) . v + (C u) . dv + ((C u) x v) . phi``."""
        c = x[_C:_C + 9].reshape(3, 3)
        v = x[_V:_V + 3]
        pm = x[_COV:_COV + _N * _N].reshape(_N, _N).copy()
        dx = np.zeros(_N)
        for i, a in zip((1, 2), _nonholonomic_mount(x)):
            cu = c @ (np.eye(3)[i] - a * np.eye(3)[0])
            hm = np.zeros(_N)
            hm[0:3] = cross(cu, v)
            hm[3:6] = cu
            hp = hm @ pm
            si = hp @ hm + p[_NHC] ** 2
            innov = -(cu @ v) - hm @ dx
            if innov ** 2 > _NHGATE * si:  # not a vehicle on its wheels just now
                continue
            kg = hp / si
            dx += kg * innov
            pm -= np.outer(kg, kg) * si
        self._correct(x, dx, pm)

    def _correct(self, x, dx, pm) -> None:
        """The error state ``dx`` into the nominal state, ``pm`` the updated covariance."""
        c = x[_C:_C + 9].reshape(3, 3)
        x[_C:_C + 9] = (rodrigues(dx[0:3]) @ c).reshape(9)
        x[_V:_V + 3] += dx[3:6]
        x[_P:_P + 3] += dx[6:9]
        x[_BG:_BG + 3] += dx[9:12]
        x[_BA:_BA + 3] += dx[12:15]
        x[_DTS] += dx[15]
        x[_COV:_COV + _N * _N] = (0.5 * (pm + pm.T)).reshape(_N * _N)
        x[_SD:_SD + _N] = np.sqrt(np.maximum(np.diag(x[_COV:_COV + _N * _N].reshape(_N, _N)), 0.0))

    def _output(self, x) -> np.ndarray:
        """The attitude at the sample's time on the GNSS clock: the INS is ``x[_DTS]`` ahead."""
        c = x[_C:_C + 9].reshape(3, 3)
        if x[_DTS] != 0.0:
            c = c @ rodrigues(-x[_W:_W + 3] * x[_DTS])
        return matrix_to_quat(self.F @ c @ self.M)

    def _extras(self, x) -> np.ndarray:
        """The per-sample outputs (29): velocity, position (at the sample's time on the GNSS
        clock), biases (output axes), their stds, the time offset and its std."""
        f, mt = self.F, self.M.T
        d = x[_SD:_SD + _N] if x[_PHASE] == 2.0 else np.full(_N, np.nan)
        af, am = np.abs(f), np.abs(mt)
        dts = x[_DTS]
        v, pos = x[_V:_V + 3] - x[_ACC:_ACC + 3] * dts, x[_P:_P + 3] - x[_V:_V + 3] * dts
        return np.concatenate([f @ v, f @ pos, mt @ x[_BG:_BG + 3], mt @ x[_BA:_BA + 3],
                               af @ d[0:3], af @ d[3:6], af @ d[6:9], am @ d[9:12], am @ d[12:15], [dts, d[15]]])

    # -- public ----------------------------------------------------------------------------------
    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: dict | None = None) -> Result:
        """Process ``rec``; with ``state`` (``diagnostics["state"]`` of the run over the samples
        before it, e.g. ``rec.slice``) go on from there: the chunks give the samples one run
        gives. A re-run (course heading, re-levelling) that goes back into an earlier chunk goes
        over the samples the state keeps (from the alignment's end until the re-levelling) and
        updates the state and this chunk's output; the earlier chunks' returned outputs stay as
        they were (as with :meth:`update`)."""
        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        if rec.gnss is None:
            raise InputError(f"{self.name} needs a GNSS stream (Recording(gnss=...))")
        # a magnetometer it does not read (heading="course") is not refused for a non-finite sample
        check_finite_all({"gyr": rec.gyr, "acc": rec.acc, "mag": rec.mag if self._use_mag(rec) else None},
                         self.config.nan_policy)
        # the recording's body axes (or body=; a contradiction raises); not known: FRD
        self.M = body_matrix(self.body_axes(rec) or "FRD", "FRD")
        used = resolve_backend(backend, True)
        n = len(rec)
        gn = gnss_epoch_rows(rec)
        dt, t = rec.dt, rec.time
        if state is None:
            st = self.new_state(rec.nominal_dt, rec)
        else:
            st = self._continued(state, rec)
            t_last = st["x"][_TIME]
            if np.isfinite(t_last):
                old = (gn[:, 0] != 0.0) & (gn[:, 1] <= t_last)  # the epoch current at the slice's start: used
                gn[old, 0] = 0.0
                gn[old, 1:] = np.nan
                if n and t[0] > t_last:
                    dt = dt.copy()
                    dt[0] = t[0] - t_last
        mag = rec.mag if (st["use_mag"] and rec.mag is not None) else np.zeros((n, 3))
        gyr, acc = rec.gyr, rec.acc
        kept = st.pop("kept", None)  # the samples a re-run may go back to (an earlier chunk's)
        nk = 0 if kept is None else kept[0].shape[0]
        if nk:
            gyr, acc, mag, dt, t, gn = (np.concatenate([a, b]) for a, b in zip(kept, (gyr, acc, mag, dt, t, gn)))
        q = np.empty((nk + n, 4))
        flags = np.zeros(nk + n, np.uint32)
        ext = np.empty((nk + n, 29))
        k0 = st["x"][_K] - nk  # the sample number of the arrays' first row
        if used == "numba":
            _ins_loop(gyr, acc, mag, dt, t, gn, st["use_mag"], self.M, self.F, st["p"], st["x"], st["det"],
                      self.detector.kernel().params, st["align"], self.aligner(st["use_mag"]).params(),
                      q, flags, ext, nk)
        else:
            x = st["x"]
            k = nk
            while k < nk + n:
                q[k], flags[k] = self._step(st, gyr[k], acc[k], mag[k] if st["use_mag"] else None, dt[k], t[k], gn[k])
                ext[k] = self._extras(x)
                if x[_RESTART]:
                    x[_RESTART] = 0.0
                    k = int(x[_KSTART] - k0)
                    x[_K] = x[_KSTART]
                    continue
                k += 1
        x = st["x"]
        if x[_PHASE] == 2.0:  # the alignment span turned like its end: the course heading and the re-levelling
            end = min(nk + n, max(0, int(x[_KSTART] - k0)))
            turn = x[_C0:_C0 + 9].reshape(3, 3) @ x[_CAL:_CAL + 9].reshape(3, 3).T
            q[:end] = quat_mul(matrix_to_quat(self.F @ turn @ self.F.T), q[:end])
        if x[_PHASE] == 1.0 or (x[_PHASE] == 2.0 and x[_LEVEL] == 0.0 and st["p"][_RELEVEL] > 0.0):
            s0 = max(0, int(x[_KSTART] - k0))  # a re-run may still come: keep the samples from its start
            st["kept"] = tuple(a[s0:].copy() for a in (gyr, acc, mag, dt, t, gn))
        q, flags, ext = q[nk:], flags[nk:], ext[nk:]
        names = ("velocity", "position", "gyr_bias", "acc_bias", "attitude_std", "velocity_std", "position_std",
                 "gyr_bias_std", "acc_bias_std")
        diag = {"backend": used, "filter": self.name, "config": self.config.model_dump(), "state": st,
                "P": x[_COV:_COV + _N * _N].reshape(_N, _N).copy(),
                "alignment_end_index": None if st["align"][END] < 0 else int(st["align"][END]),
                "relevel_tilt": x[_PHI0:_PHI0 + 3].copy() if x[_LEVEL] == 1.0 else None,
                "time_offset": ext[:, 27].copy(), "time_offset_std": ext[:, 28].copy(),
                **{nm: ext[:, 3 * i:3 * i + 3] for i, nm in enumerate(names)}, "aiding": self.aiding(rec)}
        return Result(q, flags, self.config.frame, diag)

    def _check_state(self, state) -> None:
        if not (isinstance(state, dict) and isinstance(state.get("x"), np.ndarray) and state["x"].shape == (_SIZE,)
                and isinstance(state.get("align"), np.ndarray) and state["align"].shape == (ALIGN_SIZE,)
                and state.get("filter") == self.name):
            raise InputError(f"state must be the diagnostics['state'] of an earlier {self.name} run (or its .state)")

    def _continued(self, state, rec: Recording) -> dict:
        """A copy of an earlier run's state, checked against this filter and ``rec``."""
        self._check_state(state)
        if not math.isclose(state["dt"], rec.nominal_dt, rel_tol=1e-6):
            raise InputError(f"state is of a {1.0 / state['dt']:g} Hz run, rec is {1.0 / rec.nominal_dt:g} Hz")
        if bool(state["use_mag"]) != self._use_mag(rec):
            raise InputError("state was run with a magnetometer heading and rec is not (or the other way round)")
        if "M" in state and not np.array_equal(state["M"], self.M):
            raise InputError(f"state was run with other body axes than rec's ({self.body_axes(rec) or 'FRD'}): give "
                             "rec the body axes of the run the state comes from")
        return {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in state.items()}

    @property
    def state(self) -> dict[str, Any] | None:
        """A copy of the stream's state (None before the first :meth:`update`). (It had neither
        this nor :meth:`set_state`, which every filter has: an AttributeError.)"""
        return None if self._stream is None else copy.deepcopy(self._stream)

    def set_state(self, state) -> None:
        """Continue the stream from :attr:`state`, or from a run's ``diagnostics["state"]`` (the
        samples it keeps for a re-run become the stream's buffer). The stream's GNSS epochs are the
        ones that arrive after it (the run's last one is not given again)."""
        self._check_state(state)
        st = copy.deepcopy(state)
        kept = st.pop("kept", None)
        if "buffer" not in st:  # a run's state: its kept rows, as update() buffers them
            use = bool(st["use_mag"])
            st["buffer"] = [] if kept is None else [(g, a, m if use else None, float(d), float(t), gn)
                                                   for g, a, m, d, t, gn in zip(*kept)]
        if "M" in st:  # the samples go on in the body axes the state's run read them in (review rev27b)
            self.M = np.array(st["M"], dtype=float)
        self._stream = st

    def reset(self) -> None:
        self._stream = None
        self.M = body_matrix(self.config.body or "FRD", "FRD")  # (set_state may have taken a run's axes)

    def update(self, gyr, acc, mag=None, dt: float | None = None, gnss=None, t: float | None = None) -> np.ndarray:
        """One sample of a stream. ``gnss``: an epoch that arrived with this sample, ``(t_epoch,
        vN, vE, vD, pN, pE, pD)`` NED (NaN for what it lacks), on the clock of ``t`` (default: the
        previous ``t`` + ``dt``, starting at 0). The samples are buffered until the heading is
        known (course heading) and the alignment re-levelled (``relevel``); at each, the filter
        goes over them again (the outputs already returned stay as they were)."""
        if dt is None:
            raise InputError("update() needs dt, the sample interval in s")
        dt = check_dt(dt, bounded=True)  # (every interval: no gap handling here, a long one would be integrated as one step)
        t = None if t is None else check_timestamp("t", t)
        g, a = as_vector("gyr", gyr), as_vector("acc", acc)
        m = None if mag is None else as_vector("mag", mag)
        if self.config.nan_policy == "raise":
            for nm, v in (("gyr", g), ("acc", a), ("mag", m)):
                if v is not None and not np.isfinite(v).all():
                    raise InputError(f"{nm} is not finite ({v.tolist()}); pass nan_policy='skip' to hold and flag")
        if self._stream is None:
            st = self.new_state(dt)
            st["use_mag"] = m is not None and self.config.heading in ("auto", "magnetometer")
            st["align"] = self.aligner(st["use_mag"]).new_state()
            st["p"][_HMAG] = float(st["use_mag"])
            st["buffer"] = []
            self._stream = st
        st = self._stream
        x = st["x"]
        if t is None:
            t = 0.0 if not np.isfinite(x[_TIME]) else x[_TIME] + dt
        gn = np.zeros(8)
        gn[1:] = np.nan
        if gnss is not None:
            gn[0] = 1.0
            gn[1:] = as_vector("gnss", gnss, width=7)
        keep = x[_PHASE] != 2.0 or (x[_LEVEL] == 0.0 and st["p"][_RELEVEL] > 0.0)
        if keep:
            st["buffer"].append((g, a, m, dt, t, gn))
        q, f = self._step(st, g, a, m, dt, t, gn)
        while x[_RESTART]:  # go over the buffered samples again from the new start
            x[_RESTART] = 0.0
            start = len(st["buffer"]) - int(x[_K] - x[_KSTART])
            x[_K] = x[_KSTART]
            for row in st["buffer"][start:]:
                q, f = self._step(st, *row)
                if x[_RESTART]:
                    break
        if x[_PHASE] == 2.0 and (x[_LEVEL] == 1.0 or st["p"][_RELEVEL] <= 0.0):
            st["buffer"] = []
        self.last_flags = int(f)
        return q


def _nonholonomic_check(x, p, vb, interval) -> None:
    """One accepted GNSS velocity (``vb`` in body axes, at the IMU) into the running check of the
    constraint; only while moving (``min_speed``), over epoch intervals of up to a second."""
    if not (p[_NHM] != 0.0 and 0.0 < interval <= 1.0 and vb[0] ** 2 + vb[1] ** 2 + vb[2] ** 2 >= p[_MINV] ** 2):
        return
    lam = math.exp(-interval / p[_NHT0])
    for i, v in ((_NXX, vb[0] * vb[0]), (_NXY, vb[0] * vb[1]), (_NXZ, vb[0] * vb[2]), (_NYY, vb[1] * vb[1]),
                 (_NZZ, vb[2] * vb[2]), (_NHW, 1.0)):
        x[i] = lam * x[i] + interval * v
    x[_NHT] += interval


def _nonholonomic_mount(x) -> tuple[float, float]:
    """The IMU's mounting in the vehicle, from the check's sums: the least-squares ratios of the
    GNSS velocity's lateral and vertical body parts to its forward part (``v_y = a_y v_x``,
    ``v_z = a_z v_x``: the yaw and pitch of the IMU against the wheels' direction, small angles)."""
    if not x[_NXX] > 0.0:
        return 0.0, 0.0
    return x[_NXY] / x[_NXX], x[_NXZ] / x[_NXX]


def _nonholonomic_on(x, p) -> bool:
    """Whether the constraint applies now: 'on' (once moving: the mounting is estimated on the
    way), or 'auto' once the check has seen ``nonholonomic_check`` s of motion whose lateral and
    vertical velocity, the mounting removed, has an RMS within the constraint's std."""
    if p[_NHM] == 1.0:
        return True
    if not (p[_NHM] == 2.0 and x[_NHT] >= p[_NHT0] and x[_NXX] > 0.0):
        return False
    rss = x[_NYY] - x[_NXY] ** 2 / x[_NXX] + x[_NZZ] - x[_NXZ] ** 2 / x[_NXX]  # (the mounting removed)
    return rss <= 2.0 * x[_NHW] * p[_NHC] ** 2


_k_nonholonomic_check = njit(_nonholonomic_check)
_k_nonholonomic_mount = njit(_nonholonomic_mount)
_k_nonholonomic_on = njit(_nonholonomic_on)


def _rz(a: float) -> np.ndarray:
    """Rotation by ``a`` about NED's down axis (heading + a)."""
    ca, sa = math.cos(a), math.sin(a)
    return np.array([[ca, -sa, 0.0], [sa, ca, 0.0], [0.0, 0.0, 1.0]])


# ---- numba kernel: the same steps as InsGnssFilter._step ------------------------------------------


@njit
def _add_process_noise(pm, p, tt):
    """Add the process noise over an interval ``tt`` to the covariance ``pm`` (in place): gyro and
    accelerometer white noise (the latter integrated into velocity and position), the biases'
    random walks. One function for the reference and the kernel."""
    qa = p[_AN] ** 2
    for i in range(3):
        pm[i, i] += p[_GN] ** 2 * tt
        pm[3 + i, 3 + i] += qa * tt
        pm[6 + i, 6 + i] += qa * tt ** 3 / 3.0
        pm[3 + i, 6 + i] += qa * tt ** 2 / 2.0
        pm[6 + i, 3 + i] += qa * tt ** 2 / 2.0
        pm[9 + i, 9 + i] += p[_GQ] ** 2 * tt
        pm[12 + i, 12 + i] += p[_AQ] ** 2 * tt


@njit
def _k_geo(x, p):
    rm0, _ = radii(p[_LAT])
    lat = p[_LAT] + x[_P] / (rm0 + p[_H0])
    h = p[_H0] - x[_P + 2]
    rm, rn = radii(lat)
    return lat, h, rm, rn


@njit
def _k_skew_into(a, r0, c0, v0, v1, v2, s):
    """``a[r0:r0+3, c0:c0+3] = s [v x]``."""
    a[r0, c0], a[r0, c0 + 1], a[r0, c0 + 2] = 0.0, -s * v2, s * v1
    a[r0 + 1, c0], a[r0 + 1, c0 + 1], a[r0 + 1, c0 + 2] = s * v2, 0.0, -s * v0
    a[r0 + 2, c0], a[r0 + 2, c0 + 1], a[r0 + 2, c0 + 2] = -s * v1, s * v0, 0.0


@njit
def _k_refresh(x, p):
    lat, h, rm, rn = _k_geo(x, p)
    rm0, rn0 = radii(p[_LAT])
    e = p[_EARTH] * EARTH_RATE
    x[_GRAV] = normal_gravity(lat, h)
    x[_S0] = (rm0 + p[_H0]) / (rm + h)
    x[_S1] = (rn0 + p[_H0]) * math.cos(p[_LAT]) / ((rn + h) * math.cos(lat))
    x[_WIE], x[_WIE + 1], x[_WIE + 2] = e * math.cos(lat), 0.0, -e * math.sin(lat)
    v0, v1 = x[_V], x[_V + 1]
    x[_WEN], x[_WEN + 1], x[_WEN + 2] = v1 / (rn + h), -v0 / (rm + h), -v1 * math.tan(lat) / (rn + h)
    for i in range(_N):
        x[_SD + i] = math.sqrt(max(x[_COV + (_N + 1) * i], 0.0))


@njit
def _k_start(x, c0, heading_var, p, t, ba0, dts0):
    for i in range(9):
        x[_C + i] = c0[i]
        x[_C0 + i] = c0[i]
    x[_HVAR] = heading_var
    lat, h = p[_LAT], p[_H0]
    e = p[_EARTH] * EARTH_RATE
    wie = (e * math.cos(lat), 0.0, -e * math.sin(lat))
    for i in range(3):
        x[_V + i] = 0.0
        x[_P + i] = 0.0
        x[_BG + i] = x[_GAL + i] - (c0[i] * wie[0] + c0[3 + i] * wie[1] + c0[6 + i] * wie[2])
        x[_BA + i] = ba0[i]
        x[_ACC + i] = 0.0
    x[_DTS] = dts0
    g = normal_gravity(lat, h)
    a = np.zeros((3, 3))
    for j in range(3):  # rows N, E of J C0 / g: phi_N = (C b)_E / g, phi_E = -(C b)_N / g
        a[0, j] = c0[3 + j] / g
        a[1, j] = -c0[j] / g
    pm = x[_COV:_COV + _N * _N].reshape((_N, _N))
    pm[:, :] = 0.0
    sa = p[_BA0] ** 2
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += a[i, k] * a[j, k]
            pm[i, j] = sa * acc
            pm[i, 12 + j] = sa * a[i, j]
            pm[12 + j, i] = sa * a[i, j]
    pm[0, 0] += p[_TILT0] ** 2
    pm[1, 1] += p[_TILT0] ** 2
    pm[2, 2] += heading_var
    for i in range(3):
        pm[3 + i, 3 + i] = p[_V0] ** 2
        pm[6 + i, 6 + i] = p[_P0] ** 2
        pm[9 + i, 9 + i] = p[_BG0] ** 2
        pm[12 + i, 12 + i] = sa
    pm[15, 15] = p[_TS0] ** 2
    for i in range(_SC, _T + 1):
        x[i] = 0.0
    for i in range(_NXX, _NHT + 1):
        x[i] = 0.0
    x[_TLAST] = -np.inf
    x[_TGOOD] = -np.inf
    x[_RV] = t
    x[_RP] = t
    x[_PHASE] = 2.0
    _k_refresh(x, p)


@njit
def _k_relevel(x, p, t, c0, r9):
    g = normal_gravity(p[_LAT], p[_H0])
    phi0, phi1, phi2 = 0.0, 0.0, 0.0
    for j in range(3):  # (J C0 / g) b_a
        phi0 += x[_C0 + 3 + j] / g * x[_BA + j]
        phi1 += -x[_C0 + j] / g * x[_BA + j]
    x[_LEVEL] = 1.0
    x[_PHI0], x[_PHI0 + 1], x[_PHI0 + 2] = phi0, phi1, phi2
    rodrigues_into(phi0, phi1, phi2, r9)
    for i in range(3):
        for j in range(3):
            c0[3 * i + j] = r9[3 * i] * x[_C0 + j] + r9[3 * i + 1] * x[_C0 + 3 + j] + r9[3 * i + 2] * x[_C0 + 6 + j]
    ba = x[_BA:_BA + 3].copy()
    _k_start(x, c0, x[_HVAR], p, t, ba, x[_DTS])
    x[_RESTART] = 1.0


@njit
def _k_propagate(x, p, fm, tmp, fmt):
    tt = x[_T]
    if tt <= 0.0:
        return
    wie = x[_WIE:_WIE + 3]
    wen = x[_WEN:_WEN + 3]
    fm[:, :] = 0.0  # E = F - I: non-zero in rows 0..8 only
    _k_skew_into(fm, 0, 0, wie[0] + wen[0], wie[1] + wen[1], wie[2] + wen[2], -tt)
    _k_skew_into(fm, 3, 0, x[_DV], x[_DV + 1], x[_DV + 2], -1.0)
    _k_skew_into(fm, 3, 3, 2.0 * wie[0] + wen[0], 2.0 * wie[1] + wen[1], 2.0 * wie[2] + wen[2], -tt)
    _k_skew_into(fm, 6, 0, x[_DV], x[_DV + 1], x[_DV + 2], -0.5 * tt)
    for i in range(3):
        fm[6 + i, 3 + i] = tt
        for j in range(3):
            s = x[_SC + 3 * i + j]
            fm[i, 9 + j] = -s
            fm[3 + i, 12 + j] = -s
            fm[6 + i, 12 + j] = -0.5 * tt * s
    pm = x[_COV:_COV + _N * _N].reshape((_N, _N))
    for i in range(_N):  # F P = P + E P
        for j in range(_N):
            tmp[i, j] = pm[i, j]
    for i in range(9):
        for k in range(_N):
            e = fm[i, k]
            if e != 0.0:
                for j in range(_N):
                    tmp[i, j] += e * pm[k, j]
    for i in range(_N):  # (F P) F^T = F P + (F P) E^T
        for j in range(_N):
            pm[i, j] = tmp[i, j]
    for j in range(9):
        for k in range(_N):
            e = fm[j, k]
            if e != 0.0:
                for i in range(_N):
                    pm[i, j] += tmp[i, k] * e
    _add_process_noise(pm, p, tt)
    for i in range(_N):
        for j in range(i + 1, _N):
            a = 0.5 * (pm[i, j] + pm[j, i])
            pm[i, j] = a
            pm[j, i] = a
    for i in range(_SC, _T + 1):
        x[i] = 0.0
    _k_refresh(x, p)


@njit
def _k_update(x, p, gn, t, hm, dx, hp, r9):
    flags = 0
    age = t - gn[1]
    lag = age + x[_DTS]
    interval = gn[1] - x[_TLAST]
    x[_TLAST] = gn[1]
    c = x[_C:_C + 9]
    l0, l1, l2 = p[_LEV], p[_LEV + 1], p[_LEV + 2]
    w0, w1, w2 = x[_W], x[_W + 1], x[_W + 2]
    cr0, cr1, cr2 = w1 * l2 - w2 * l1, w2 * l0 - w0 * l2, w0 * l1 - w1 * l0  # w x l
    cl = np.empty(3)
    cwl = np.empty(3)
    for i in range(3):
        cl[i] = c[3 * i] * l0 + c[3 * i + 1] * l1 + c[3 * i + 2] * l2
        cwl[i] = c[3 * i] * cr0 + c[3 * i + 1] * cr1 + c[3 * i + 2] * cr2
    pm = x[_COV:_COV + _N * _N].reshape((_N, _N))
    dx[:] = 0.0
    y = np.empty(3)
    yg = np.empty(3)
    r = np.empty(3)
    s = np.empty((3, 3))
    nz = np.empty((3, _N), np.int64)
    nnz = np.zeros(3, np.int64)
    for kind in range(2):
        o = 2 + 3 * kind
        if not (math.isfinite(gn[o]) and math.isfinite(gn[o + 1]) and math.isfinite(gn[o + 2])):
            continue
        hm[:, :] = 0.0
        if kind == 0:
            for i in range(3):
                y[i] = gn[o + i] - (x[_V + i] + cwl[i] - x[_ACC + i] * lag)
                hm[i, 3 + i] = 1.0
                hm[i, 15] = -x[_ACC + i]
            _k_skew_into(hm, 0, 0, cwl[0], cwl[1], cwl[2], -1.0)
            for i in range(3):  # C [l x]
                hm[i, 9] = c[3 * i + 1] * l2 - c[3 * i + 2] * l1
                hm[i, 10] = -c[3 * i] * l2 + c[3 * i + 2] * l0
                hm[i, 11] = c[3 * i] * l1 - c[3 * i + 1] * l0
            r[0], r[1], r[2] = p[_VH] ** 2, p[_VH] ** 2, p[_VV] ** 2
            blk, last = 3, _RV
        else:
            for i in range(3):
                y[i] = gn[o + i] - (x[_P + i] + cl[i] - x[_V + i] * lag)
                hm[i, 6 + i] = 1.0
                hm[i, 15] = -x[_V + i]
            _k_skew_into(hm, 0, 0, cl[0], cl[1], cl[2], -1.0)
            r[0], r[1], r[2] = p[_PH] ** 2, p[_PH] ** 2, p[_PV] ** 2
            blk, last = 6, _RP
        for i in range(3):  # the non-zero columns of H's rows (H is sparse: 1 to 7 of 15)
            nnz[i] = 0
            for j in range(_N):
                if hm[i, j] != 0.0:
                    nz[i, nnz[i]] = j
                    nnz[i] += 1
        for i in range(3):  # the innovation after this epoch's earlier rows
            acc = 0.0
            for jj in range(nnz[i]):
                acc += hm[i, nz[i, jj]] * dx[nz[i, jj]]
            yg[i] = y[i] - acc
        for i in range(3):  # S = H P H^T + R
            for j in range(_N):
                acc = 0.0
                for kk in range(nnz[i]):
                    acc += hm[i, nz[i, kk]] * pm[nz[i, kk], j]
                hp[i, j] = acc
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for kk in range(nnz[j]):
                    acc += hp[i, nz[j, kk]] * hm[j, nz[j, kk]]
                s[i, j] = acc + (r[i] if i == j else 0.0)
        det = (s[0, 0] * (s[1, 1] * s[2, 2] - s[1, 2] * s[2, 1]) - s[0, 1] * (s[1, 0] * s[2, 2] - s[1, 2] * s[2, 0])
               + s[0, 2] * (s[1, 0] * s[2, 1] - s[1, 1] * s[2, 0]))
        r9[0] = s[1, 1] * s[2, 2] - s[1, 2] * s[2, 1]
        r9[1] = s[0, 2] * s[2, 1] - s[0, 1] * s[2, 2]
        r9[2] = s[0, 1] * s[1, 2] - s[0, 2] * s[1, 1]
        r9[3] = s[1, 2] * s[2, 0] - s[1, 0] * s[2, 2]
        r9[4] = s[0, 0] * s[2, 2] - s[0, 2] * s[2, 0]
        r9[5] = s[0, 2] * s[1, 0] - s[0, 0] * s[1, 2]
        r9[6] = s[1, 0] * s[2, 1] - s[1, 1] * s[2, 0]
        r9[7] = s[0, 1] * s[2, 0] - s[0, 0] * s[2, 1]
        r9[8] = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
        nis = 0.0
        for i in range(3):
            for j in range(3):
                nis += yg[i] * r9[3 * i + j] * yg[j]
        nis /= det
        if nis <= p[_GATE]:
            if kind == 0 and p[_NHM] != 0.0:
                vb = np.empty(3)
                for i in range(3):
                    vb[i] = (c[i] * (gn[o] - cwl[0]) + c[3 + i] * (gn[o + 1] - cwl[1])
                             + c[6 + i] * (gn[o + 2] - cwl[2]))
                _k_nonholonomic_check(x, p, vb, interval)
            for i in range(3):
                hdx = 0.0
                si = r[i]
                for j in range(_N):
                    acc = 0.0
                    for kk in range(nnz[i]):
                        acc += hm[i, nz[i, kk]] * pm[nz[i, kk], j]
                    hp[0, j] = acc
                for kk in range(nnz[i]):
                    si += hp[0, nz[i, kk]] * hm[i, nz[i, kk]]
                    hdx += hm[i, nz[i, kk]] * dx[nz[i, kk]]
                innov = y[i] - hdx
                for j in range(_N):
                    hp[1, j] = hp[0, j] / si  # the gain
                    dx[j] += hp[1, j] * innov
                for j in range(_N):  # symmetric: the upper triangle, mirrored (the same products)
                    kj = hp[1, j]
                    for k in range(j, _N):
                        pm[j, k] -= kj * hp[1, k] * si
                        pm[k, j] = pm[j, k]
            x[last] = t
        elif t - x[last] > p[_GTO]:
            for i in range(3):
                if kind == 0:
                    x[_V + i] += yg[i]
                else:
                    x[_P + i] += yg[i]
                dx[blk + i] = 0.0
                for j in range(_N):
                    pm[blk + i, j] = 0.0
                    pm[j, blk + i] = 0.0
            for i in range(3):
                pm[blk + i, blk + i] = r[i]
            x[last] = t
            flags |= 4096  # GNSS_REJECTED
        else:
            flags |= 4096  # GNSS_REJECTED
    _k_correct(x, dx, r9)
    return flags


@njit
def _k_nonholonomic(x, p, dx, hp, r9):
    """InsGnssFilter._nonholonomic, compiled."""
    c = x[_C:_C + 9]
    pm = x[_COV:_COV + _N * _N].reshape((_N, _N))
    r = p[_NHC] * p[_NHC]
    v0, v1, v2 = x[_V], x[_V + 1], x[_V + 2]
    dx[:] = 0.0
    ay, az = _k_nonholonomic_mount(x)
    hm = np.empty(6)  # the non-zero part of H's row: phi, dv
    for i in range(1, 3):
        a = ay if i == 1 else az
        a0, a1, a2 = c[i] - a * c[0], c[3 + i] - a * c[3], c[6 + i] - a * c[6]  # C u
        hm[0], hm[1], hm[2] = a1 * v2 - a2 * v1, a2 * v0 - a0 * v2, a0 * v1 - a1 * v0
        hm[3], hm[4], hm[5] = a0, a1, a2
        vb = a0 * v0 + a1 * v1 + a2 * v2
        for j in range(_N):
            acc = 0.0
            for kk in range(6):
                acc += hm[kk] * pm[kk, j]
            hp[0, j] = acc
        si = r
        hdx = 0.0
        for kk in range(6):
            si += hp[0, kk] * hm[kk]
            hdx += hm[kk] * dx[kk]
        innov = -vb - hdx
        if innov * innov > _NHGATE * si:
            continue
        for j in range(_N):
            hp[1, j] = hp[0, j] / si
            dx[j] += hp[1, j] * innov
        for j in range(_N):
            kj = hp[1, j]
            for k in range(j, _N):
                pm[j, k] -= kj * hp[1, k] * si
                pm[k, j] = pm[j, k]
    _k_correct(x, dx, r9)


@njit
def _k_correct(x, dx, r9):
    """InsGnssFilter._correct, compiled (the covariance is updated in place in ``x``)."""
    c = x[_C:_C + 9]
    pm = x[_COV:_COV + _N * _N].reshape((_N, _N))
    rodrigues_into(dx[0], dx[1], dx[2], r9)
    t9 = np.empty(9)
    matmul3_into(r9, c, t9)
    for i in range(9):
        c[i] = t9[i]
    for i in range(3):
        x[_V + i] += dx[3 + i]
        x[_P + i] += dx[6 + i]
        x[_BG + i] += dx[9 + i]
        x[_BA + i] += dx[12 + i]
    x[_DTS] += dx[15]
    for i in range(_N):
        for j in range(i + 1, _N):
            a = 0.5 * (pm[i, j] + pm[j, i])
            pm[i, j] = a
            pm[j, i] = a
    for i in range(_N):
        x[_SD + i] = math.sqrt(max(x[_COV + (_N + 1) * i], 0.0))


@njit
def _k_output(x, m, fo, t9, u9, q, r9, c9):
    c = x[_C:_C + 9]
    dts = x[_DTS]
    if dts != 0.0:  # the attitude at the sample's time on the GNSS clock
        rodrigues_into(-x[_W] * dts, -x[_W + 1] * dts, -x[_W + 2] * dts, r9)
        matmul3_into(c, r9, c9)
        c = c9
    for i in range(3):
        for j in range(3):
            u9[3 * i + j] = fo[i, 0] * c[j] + fo[i, 1] * c[3 + j] + fo[i, 2] * c[6 + j]
    for i in range(3):
        for j in range(3):
            t9[3 * i + j] = u9[3 * i] * m[0, j] + u9[3 * i + 1] * m[1, j] + u9[3 * i + 2] * m[2, j]
    dcm_to_quat(t9, q)


@njit
def _k_extras(x, m, fo, e):
    nan = x[_PHASE] != 2.0
    for i in range(3):
        for blk in range(9):
            e[3 * blk + i] = 0.0
        for j in range(3):
            e[i] += fo[i, j] * (x[_V + j] - x[_ACC + j] * x[_DTS])
            e[3 + i] += fo[i, j] * (x[_P + j] - x[_V + j] * x[_DTS])
            e[6 + i] += m[j, i] * x[_BG + j]
            e[9 + i] += m[j, i] * x[_BA + j]
            for blk in range(3):
                d = math.nan if nan else x[_SD + 3 * blk + j]
                e[12 + 3 * blk + i] += abs(fo[i, j]) * d
            for blk in range(3, 5):
                d = math.nan if nan else x[_SD + 3 * blk + j]
                e[12 + 3 * blk + i] += abs(m[j, i]) * d
    e[27] = x[_DTS]
    e[28] = math.nan if nan else x[_SD + 15]


@njit(cache=True)
def _ins_loop(gyr, acc, mag, dt, t, gn, use_mag, m, fo, p, x, ds, dp, al, ap, out_q, out_f, out_e, k_first):
    """The compiled twin of InsGnssFilter.run's reference loop (the same arithmetic), from row
    ``k_first`` (the rows before it: kept samples a re-run may go back to)."""
    q = np.empty(4)
    t9 = np.empty(9)
    u9 = np.empty(9)
    r1 = np.empty(9)
    r2 = np.empty(9)
    c0 = np.empty(9)
    fm = np.empty((_N, _N))
    tmp = np.empty((_N, _N))
    fmt = np.empty((_N, _N))
    hm = np.empty((3, _N))
    hp = np.empty((3, _N))
    dxv = np.empty(_N)
    wie = np.empty(3)
    wen = np.empty(3)
    w = np.empty(3)
    f = np.empty(3)
    zero3 = np.zeros(3)
    n = gyr.shape[0]
    k0 = x[_K] - k_first
    k = k_first
    while k < n:
        g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]
        a0, a1, a2 = acc[k, 0], acc[k, 1], acc[k, 2]
        m0, m1, m2 = mag[k, 0], mag[k, 1], mag[k, 2]
        gyr_ok = math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2)
        acc_ok = (math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)
                  and (a0 != 0.0 or a1 != 0.0 or a2 != 0.0))
        mag_ok = use_mag and (math.isfinite(m0) and math.isfinite(m1) and math.isfinite(m2)
                              and (m0 != 0.0 or m1 != 0.0 or m2 != 0.0))
        flags = 0
        if not gyr_ok:
            flags |= 4
        if not acc_ok:
            flags |= 8
        h = dt[k]
        tk = t[k]
        x[_TIME] = tk
        kk = x[_K]
        x[_K] += 1.0
        done = False
        if x[_PHASE] == 0.0:
            if al[PHASE] == 0.0 and gyr_ok and acc_ok and _motion_step(ds, g0, g1, g2, a0, a1, a2, 0.0, 0.0, 0.0,
                                                                        h, dp) != 0:
                flags |= 2
            status = align_step(al, ap, g0, g1, g2, a0, a1, a2, m0, m1, m2, gyr_ok, acc_ok, mag_ok,
                                (flags & 2) != 0, h, q)
            if status == ALIGNED_NOW or status == ALIGNED_BEFORE:
                quat_to_dcm(q, t9)  # sensor -> NED; C_align = R M^T
                for i in range(3):
                    for j in range(3):
                        u9[3 * i + j] = t9[3 * i] * m[j, 0] + t9[3 * i + 1] * m[j, 1] + t9[3 * i + 2] * m[j, 2]
                if p[_HMAG] != 0.0:
                    ca, sa = math.cos(p[_DECL]), math.sin(p[_DECL])
                    for j in range(3):
                        r1[j], r1[3 + j], r1[6 + j] = ca * u9[j] - sa * u9[3 + j], sa * u9[j] + ca * u9[3 + j], u9[6 + j]
                    for i in range(9):
                        u9[i] = r1[i]
                for i in range(9):
                    x[_CAL + i] = u9[i]
                for i in range(3):
                    x[_GAL + i] = (m[i, 0] * al[BIAS] + m[i, 1] * al[BIAS + 1] + m[i, 2] * al[BIAS + 2]
                                   if al[NGYR] > 0 else 0.0)
                x[_KSTART] = kk + (1.0 if status == ALIGNED_NOW else 0.0)
                if p[_HMAG] != 0.0:
                    _k_start(x, u9, p[_MAGH] ** 2, p, x[_TIME], zero3, 0.0)
                else:
                    for i in range(9):
                        x[_C + i] = u9[i]
                    for i in range(3):
                        x[_BG + i] = x[_GAL + i]
                    x[_PHASE] = 1.0
            if status == ALIGNING or status == ALIGNED_NOW:
                quat_to_dcm(q, u9)
                ca, sa = math.cos(p[_DECL] if p[_HMAG] != 0.0 else 0.0), math.sin(p[_DECL] if p[_HMAG] != 0.0 else 0.0)
                for j in range(3):
                    t9[j], t9[3 + j], t9[6 + j] = ca * u9[j] - sa * u9[3 + j], sa * u9[j] + ca * u9[3 + j], u9[6 + j]
                for i in range(3):
                    for j in range(3):
                        u9[3 * i + j] = fo[i, 0] * t9[j] + fo[i, 1] * t9[3 + j] + fo[i, 2] * t9[6 + j]
                dcm_to_quat(u9, q)
                flags |= 1
                done = True
        if not done:
            c = x[_C:_C + 9]
            fin = False
            for i in range(2, 8):
                if math.isfinite(gn[k, i]):
                    fin = True
            if gn[k, 0] != 0.0 and fin and gn[k, 1] <= tk:
                x[_TGOOD] = max(x[_TGOOD], gn[k, 1])
            if not (tk - x[_TGOOD] <= p[_MAXAGE]):
                flags |= 1024
            if not (gyr_ok and acc_ok):
                if x[_PHASE] == 1.0:
                    flags |= 1
            else:
                for i in range(3):
                    w[i] = m[i, 0] * g0 + m[i, 1] * g1 + m[i, 2] * g2 - x[_BG + i]
                    f[i] = m[i, 0] * a0 + m[i, 1] * a1 + m[i, 2] * a2 - x[_BA + i]
                if x[_PHASE] == 1.0:
                    rodrigues_into(w[0] * h, w[1] * h, w[2] * h, r1)
                    matmul3_into(c, r1, t9)
                    for i in range(9):
                        c[i] = t9[i]
                    age = tk - gn[k, 1]
                    if (gn[k, 0] != 0.0 and math.isfinite(gn[k, 2]) and math.isfinite(gn[k, 3])
                            and math.isfinite(gn[k, 4]) and 0.0 <= age <= p[_MAXAGE]):
                        speed = math.hypot(gn[k, 2], gn[k, 3])
                        if speed >= p[_MINV]:
                            d = math.atan2(gn[k, 3], gn[k, 2]) - math.atan2(c[3], c[0])
                            dpsi = math.atan2(math.sin(d), math.cos(d))
                            ca, sa = math.cos(dpsi), math.sin(dpsi)
                            for j in range(3):
                                c0[j] = ca * x[_CAL + j] - sa * x[_CAL + 3 + j]
                                c0[3 + j] = sa * x[_CAL + j] + ca * x[_CAL + 3 + j]
                                c0[6 + j] = x[_CAL + 6 + j]
                            _k_start(x, c0, (p[_VH] / speed) ** 2 + p[_SLIP] ** 2, p, tk, zero3, 0.0)
                            x[_RESTART] = 1.0
                    flags |= 1
                else:
                    for i in range(3):
                        wie[i] = x[_WIE + i]
                        wen[i] = x[_WEN + i]
                    th0, th1, th2 = w[0] * h, w[1] * h, w[2] * h
                    fc0 = f[0] + 0.5 * (th1 * f[2] - th2 * f[1])
                    fc1 = f[1] + 0.5 * (th2 * f[0] - th0 * f[2])
                    fc2 = f[2] + 0.5 * (th0 * f[1] - th1 * f[0])
                    dv0 = (c[0] * fc0 + c[1] * fc1 + c[2] * fc2) * h
                    dv1 = (c[3] * fc0 + c[4] * fc1 + c[5] * fc2) * h
                    dv2 = (c[6] * fc0 + c[7] * fc1 + c[8] * fc2) * h
                    rodrigues_into(-(wie[0] + wen[0]) * h, -(wie[1] + wen[1]) * h, -(wie[2] + wen[2]) * h, r1)
                    rodrigues_into(th0, th1, th2, r2)
                    matmul3_into(r1, c, t9)
                    matmul3_into(t9, r2, u9)
                    v0, v1, v2 = x[_V], x[_V + 1], x[_V + 2]
                    cx0, cx1, cx2 = 2.0 * wie[0] + wen[0], 2.0 * wie[1] + wen[1], 2.0 * wie[2] + wen[2]
                    grav = x[_GRAV]
                    n0 = v0 + dv0 + (0.0 - (cx1 * v2 - cx2 * v1)) * h
                    n1 = v1 + dv1 + (0.0 - (cx2 * v0 - cx0 * v2)) * h
                    n2 = v2 + dv2 + (grav - (cx0 * v1 - cx1 * v0)) * h
                    x[_P] += x[_S0] * (0.5 * (v0 + n0) * h)
                    x[_P + 1] += x[_S1] * (0.5 * (v1 + n1) * h)
                    x[_P + 2] += 1.0 * (0.5 * (v2 + n2) * h)
                    x[_ACC], x[_ACC + 1], x[_ACC + 2] = (n0 - v0) / h, (n1 - v1) / h, (n2 - v2) / h
                    x[_V], x[_V + 1], x[_V + 2] = n0, n1, n2
                    for i in range(9):
                        c[i] = u9[i]
                        x[_SC + i] += u9[i] * h
                    x[_DV] += dv0
                    x[_DV + 1] += dv1
                    x[_DV + 2] += dv2
                    x[_T] += h
                    for i in range(3):
                        x[_W + i] = w[i]
                    age = tk - gn[k, 1]
                    new = gn[k, 0] != 0.0 and gn[k, 1] > x[_TLAST] and 0.0 <= age <= p[_MAXAGE] and fin
                    if new or x[_T] >= p[_CI] * (1.0 - 1e-9):  # (a sum of dt a rounding short of it counts)
                        _k_propagate(x, p, fm, tmp, fmt)
                        if _k_nonholonomic_on(x, p):
                            _k_nonholonomic(x, p, dxv, hp, r1)
                    if new:
                        flags |= _k_update(x, p, gn[k], tk, hm, dxv, hp, r1)
                        if x[_LEVEL] == 0.0 and max(x[_SD + 12], x[_SD + 13]) < p[_RELEVEL]:
                            _k_relevel(x, p, tk, c0, r1)
            _k_output(x, m, fo, t9, u9, q, r1, r2)
        out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q[0], q[1], q[2], q[3]
        out_f[k] = flags
        _k_extras(x, m, fo, out_e[k])
        if x[_RESTART] != 0.0:
            x[_RESTART] = 0.0
            k = int(x[_KSTART] - k0)
            x[_K] = x[_KSTART]
            continue
        k += 1
