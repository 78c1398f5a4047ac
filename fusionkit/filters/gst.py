"""Source 001: the azimuth-free horizontal accompanying trihedron (GST) with accelerometer and
GNSS correction. Filters ``gst`` (autonomous) and ``gst-gnss`` (combined).

Frames. Body axes of the document: x right, y forward, z up (``"RFU"``); sensors in other axes
(``Recording.body`` or the ``body=`` argument: "FRD", "FLU", ...) are mapped into them, and the
output is body(sensor axes) -> earth. Without either, the sensors are taken as RFU. The platform trihedron x2 y2 z2 has z up and an
arbitrary, azimuth-free heading.

Per sample (after source 000's alignment has levelled the platform and estimated the gyro bias):

1. Platform Poisson equation ``dC/dt = C [w_B x] - [w_P x] C``, ``C = C_B^P``, integrated
   exactly over the sample: ``C <- exp(-[w_P dt x]) C exp([w_B dt x])`` (Rodrigues, source 004's
   increment), re-orthonormalised. ``w_P = [w_x^C, w_y^C, 0]``: azimuth-free.
2. Specific force on the platform axes ``f_P = C f_B``; gravity has no horizontal component on
   the GST, so the horizontal part of ``f_P`` (minus the vehicle's own horizontal acceleration)
   measures the platform tilt.
3. Correction ``w_x^C = -K d_y``, ``w_y^C = +K d_x`` (the projections "taken with the opposite
   sign", for a z-up platform), ``K = 1 / (g tau)`` for a loop time constant ``tau``:
   (a) GNSS-aided: ``d = LP(f_P,h - a_kin)``, with ``a_kin`` the along-track acceleration
   ``a = dV/dt`` on the forward axis and the centripetal ``V dH/dt`` on the right axis (eqs. 3,
   4), V the GNSS ground speed and dH/dt the rate of the platform heading H (step 4) over the
   sample (``turn_rate="gyro"``: the platform-vertical body rate instead, which differs from
   dH/dt by (roll rate) sin(pitch) while a pitched vehicle rolls into a turn). ``tau`` of this
   loop comes from the sensor model: the GNSS velocity noise leaves a tilt error of about
   ``sigma_v / (g tau)``, a slow gyro rate error ``drift`` one of ``drift tau``; their sum is
   least at ``tau = sqrt(sigma_v / (g drift))`` (``gnss_vel_noise``, ``gyro_drift``; or
   ``tau_gnss``). Extension (``tau_acc_bias``): an accelerometer bias ``b`` tilts any
   accelerometer-levelled platform by ``b_h / g``; it is body-fixed while a tilt is
   platform-fixed, so when the vehicle turns it shows in ``d``: ``b <- b + C^T [d, 0] dt /
   tau_acc_bias`` while GNSS is usable (a decade slower than the tilt loop, so that the two
   separate), and ``f_B - b`` is used throughout. ``tau_acc_bias=None`` is the document's loop;
   (b) autonomous: ``d = LP(f_P,h)``, first-order "aperiodic" low-pass links.
   Combined (``gst-gnss``): (a) while GNSS is usable, (b) in GNSS gaps; one platform, so the
   switch has no jump; ``gnss_weight`` < 1 mixes (b) into (a) as the document's combination.
4. Heading: gyroscopic heading H (platform y2 to the horizontal projection of the forward axis)
   blended with the GNSS track angle (eq. 5): ``H*_k = H*_{k-1} + (H_k - H_{k-1}) +
   (H_tr - H*_{k-1}) h / T``, angles wrapped, paused below ``min_speed`` and in gaps (then H* is
   gyroscopic). Extension: ``heading_init="track"`` sets H* to the first usable track angle
   instead of blending from an arbitrary start.

Extension (``reject=True``, default): the autonomous correction is paused while the specific
force norm differs from gravity by more than ``reject_acc``, the turn rate exceeds
``reject_turn``, or the low-passed horizontal specific force exceeds ``reject_horizontal`` (for
at most ``reject_timeout`` s in a row, so that a platform tilted beyond that test recovers) (coordinated turns put a sustained centripetal acceleration on the horizontal
axes, which the low-pass cannot remove); ``reject=False`` is the document's loop.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import numpy as np

from .._kernels import dcm_to_quat, qmul_into, qnormalize, quat_to_dcm, validity_flags
from .._numba import njit, resolve_backend
from ..config import AlignmentConfig, BodyAxes, FilterConfig, param
from ..conventions import body_matrix, frame_matrix
from ..correctors.gst import GnssLoopConfig
from ..detectors.gnss_gap import NO_GNSS, gnss_sample_rows
from ..detectors.motion import MotionConfig, MotionDetector, _motion_step, armed_for_alignment
from ..errors import InputError
from ..navigation.alignment import (
    ALIGNED_BEFORE, ALIGNED_NOW, ALIGNING, BIAS, DISTURBED, NACC, PHASE, SACC, Aligner, align_step, report_disturbed,
)
from ..protocols import Filter, Sample
from ..rotations import matrix_to_quat, orthonormalize, quat_to_matrix, rodrigues
from ..types import (Flag, Recording, Result, gap_flags, gap_threshold, hold_gaps, mark_gaps, sample_validity,
                    stream_gap)
from ..validation import check_finite_all

__all__ = ["GstFilter", "GstGnssFilter", "BODY_AXES", "MODES"]

#: sensor axes -> the document's body axes (x right, y forward, z up): v_rfu = M v_sensor (any
#: other convention: :func:`fusionkit.conventions.body_matrix`)
BODY_AXES = {b: body_matrix(b, "RFU") for b in ("RFU", "FRD", "FLU")}
#: per-sample mode codes in ``diagnostics["mode"]``
MODES = ("aligning", "autonomous", "gnss", "rejected")

# state layout
_C, _WP, _LPA, _LPG, _VPREV, _TPREV, _ALONG, _V, _HPREV, _HSTAR, _HINIT, _GNORM, _REJT, _BA = (
    0, 9, 12, 14, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25)
_SIZE = 28


class GstConfig(FilterConfig, GnssLoopConfig):
    body: BodyAxes = param(
        None, unit="-", description="sensor axes ('FRD', 'FLU', ...); None: the recording's (Recording.body), else "
        "RFU, the document's (x right, y forward, z up)"
    )
    combined: bool = param(False, unit="-", description="use GNSS when usable (gst-gnss), else autonomous only")
    tau_auto: float = param(50.0, unit="s", description="levelling loop time constant, autonomous", gt=0)
    lp_gnss: float = param(2.0, unit="s", description="low-pass time constant of the GNSS-aided residual", gt=0)
    lp_auto: float = param(2.0, unit="s", description="aperiodic-link time constant of the autonomous signal", gt=0)
    gnss_weight: float = param(1.0, unit="-", description="weight of (a) against (b) while GNSS is usable", ge=0, le=1)
    reject: bool = param(True, unit="-", description="pause the autonomous correction under acceleration or turning")
    reject_acc: float = param(0.3, unit="m/s^2", description="| |f| - g | above this pauses it", gt=0)
    reject_turn: float = param(0.02, unit="rad/s", description="turn rate above this pauses it", gt=0)
    reject_horizontal: float = param(
        0.5, unit="m/s^2", description="low-passed horizontal specific force above this pauses it (a levelled "
        "platform sees only a few tenths: more is acceleration)", gt=0)
    reject_timeout: float = param(
        60.0, unit="s", description="after this long paused by the horizontal-force test alone, correct anyway "
        "(recovers a platform tilted beyond that test)", gt=0)
    heading_T: float = param(50.0, unit="s", description="track-angle blend time constant T (eq. 5)", gt=0)
    heading_init: Literal["track", "blend"] = param(
        "track", unit="-", description="'track': start H* at the first usable track angle; 'blend': eq. 5 from H"
    )
    min_speed: float = param(5.0, unit="m/s", description="no track angle below this ground speed", ge=0)
    gnss_max_age: float = param(0.5, unit="s", description="a GNSS epoch older than this is a gap", gt=0)
    alignment: Literal["motion", "fixed"] = param("motion", unit="-", description="source 000 alignment mode")
    alignment_duration: float = param(10.0, unit="s", description="mandatory alignment time", gt=0)
    early_motion: bool = param(
        True, unit="-", description="extension: the motion detector is armed after 2 s of statistics, so that motion "
        "inside the mandatory alignment ends it there (never averaged in) with a warning; False: armed when the "
        "mandatory alignment ends (source 000, which assumes the IMU still)")
    motion: MotionConfig = param(MotionConfig(), unit="-", description="motion detector ending the alignment")


class GstFilter(Filter):
    """Source 001's GST levelling loops (autonomous; ``combined=True`` adds the GNSS loop)."""

    name: ClassVar[str] = "gst"
    Config = GstConfig
    source: ClassVar[str] = "001 (GST with accelerometer and GNSS correction, Mi-8)"
    summary: ClassVar[str] = "azimuth-free platform levelled by low-passed specific force (autonomous)"

    def __init__(self, config=None, **params: Any) -> None:
        super().__init__(config, **params)
        c = self.config
        self.detector = MotionDetector(armed_for_alignment(c.motion, c.alignment_duration, c.early_motion))
        self.alignment = AlignmentConfig(mode=c.alignment, duration=c.alignment_duration)
        self.M = self.axes(c.body)  # for update(), which has no recording
        self.F = frame_matrix("ENU", c.frame)  # output frame, folded into the output rotation
        self._p = self.params()
        self._aligners: dict[float, Aligner] = {}
        self._stream = None
        self.last_flags = 0

    def dimension(self, rec) -> str:
        return "6D"  # no magnetometer: heading comes from gyros and, in gst-gnss, the GNSS track

    # -- parameters ------------------------------------------------------------------------
    @staticmethod
    def axes(body: str | None) -> np.ndarray:
        """``M`` with ``v_rfu = M v_sensor`` for sensors in ``body`` axes (None: RFU)."""
        return body_matrix(body or "RFU", "RFU")

    def aligner(self, dt: float) -> Aligner:
        if dt not in self._aligners:
            self._aligners[dt] = Aligner(self.alignment, "ENU", dt)
        return self._aligners[dt]

    def params(self, g: float = 9.80665) -> np.ndarray:
        """The kernel's parameter vector (``K = 1/(g tau)`` with standard gravity)."""
        c = self.config
        return np.array([
            1.0 / (g * self.tau_gnss(g)), 1.0 / (g * c.tau_auto), c.lp_gnss, c.lp_auto, c.gnss_weight, float(c.reject),
            c.reject_acc, c.reject_turn, c.heading_T, float(c.heading_init == "track"), c.min_speed,
            c.gnss_max_age, float(c.combined), c.reject_horizontal, c.reject_timeout,
            0.0 if c.tau_acc_bias is None else 1.0 / c.tau_acc_bias, float(c.turn_rate == "heading"),
            c.gyr_range if c.gyr_range is not None else math.inf, c.acc_range if c.acc_range is not None else math.inf,
        ])

    def tau_gnss(self, g: float = 9.80665) -> float:
        """The GNSS loop's time constant: ``tau_gnss``, or from the sensor model."""
        return self.config.gnss_time_constant(g)

    def new_state(self, dt: float) -> dict[str, Any]:
        x = np.zeros(_SIZE)
        x[_C:_C + 9] = np.eye(3).reshape(9)
        x[_TPREV] = np.nan
        return {"dt": dt, "x": x, "det": self.detector.initial_state(dt),
                "align": self.aligner(dt).new_state()}

    # -- the readable reference --------------------------------------------------------------
    def _step(self, st, gyr, acc, gnss, dt, m) -> tuple[np.ndarray, int, int]:
        """One sample; ``gnss`` = (vn, ve, valid, age, new, t_epoch), ``m`` the sensor -> RFU
        matrix (:meth:`axes`). Returns (q body->frame, flags, mode)."""
        c, x, al = self.config, st["x"], st["align"]
        gyr_ok, acc_ok, _, flags = sample_validity(gyr, acc, None, c.gyr_range, c.acc_range)
        # the motion detector only ends the alignment: it does not run afterwards
        if al[PHASE] == 0.0 and gyr_ok and acc_ok and self.detector.step(st["det"], Sample(gyr, acc, None, dt)):
            flags |= Flag.MOTION
        # source 000's alignment: level and gyro bias while still
        status, q = self.aligner(st["dt"]).step(al, gyr, acc, None, gyr_ok, acc_ok, False, bool(flags & Flag.MOTION))
        if status in (ALIGNED_NOW, ALIGNED_BEFORE):
            self._start(x, q, al, m)
        if status in (ALIGNING, ALIGNED_NOW):
            return matrix_to_quat(self.F @ quat_to_matrix(q)), flags | Flag.ALIGNING, 0
        if not gyr_ok:  # hold the state over a bad gyro sample
            return self._output(x, m), flags, 0
        w = m @ (gyr - al[BIAS:BIAS + 3])
        p = self._p
        # 1. platform Poisson equation, exact over the sample
        cm = rodrigues(-x[_WP:_WP + 3] * dt) @ x[_C:_C + 9].reshape(3, 3) @ rodrigues(w * dt)
        cm = orthonormalize(cm)
        x[_C:_C + 9] = cm.reshape(9)
        fwd = cm[:, 1]
        hn = math.hypot(fwd[0], fwd[1])
        fx, fy = fwd[0] / hn, fwd[1] / hn  # horizontal forward direction on the platform
        if acc_ok:
            mode, gnss_ok, flags = self._level(x, cm, w, m @ acc - x[_BA:_BA + 3], gnss, fx, fy, dt, flags)
        else:  # no specific force: the levelling pauses, the gyros go on
            x[_WP:_WP + 3] = 0.0
            mode, gnss_ok = 3, False
        # 4. heading: gyroscopic H, blended with the GNSS track angle (eq. 5)
        h = math.atan2(fx, fy)
        x[_HSTAR] += _wrap(h - x[_HPREV])
        x[_HPREV] = h
        if gnss_ok and x[_V] >= p[10]:
            track = math.atan2(gnss[1], gnss[0])
            if x[_HINIT] == 0.0 and p[9] != 0.0:
                x[_HSTAR] = track
            else:
                x[_HSTAR] += _wrap(track - x[_HSTAR]) * dt / p[8]
            x[_HINIT] = 1.0
        x[_HSTAR] = _wrap(x[_HSTAR])
        return self._output(x, m), flags, mode

    def _level(self, x, cm, w, f, gnss, fx, fy, dt, flags) -> tuple[int, bool, int]:
        """Steps 2-3 on a sample with a valid specific force ``f`` (document axes, the estimated
        accelerometer bias removed): the correction rate for the next sample; returns (mode, GNSS
        usable, flags)."""
        c, p = self.config, self._p
        # 2. specific force on the platform, turn rate
        fp = cm @ f
        w_up = (cm @ w)[2]
        # 3a. GNSS: ground speed and along-track acceleration at each new epoch
        vn, ve, valid, age, new, t_ep = gnss
        gnss_ok = bool(c.combined and valid and age <= c.gnss_max_age)
        if not c.combined:
            pass  # the autonomous filter does not read GNSS
        elif new and valid:
            v = math.hypot(vn, ve)
            if np.isfinite(x[_TPREV]) and t_ep > x[_TPREV]:
                x[_ALONG] = (v - x[_VPREV]) / (t_ep - x[_TPREV])
            x[_VPREV], x[_TPREV], x[_V] = v, t_ep, v
        elif not valid:
            x[_TPREV] = np.nan  # no derivative across a gap
        # centripetal, towards the right for a right (clockwise) turn: V dH/dt (eq. 3), H the
        # platform heading of the forward axis (or the platform-vertical body rate, "gyro")
        turn = _wrap(math.atan2(fx, fy) - x[_HPREV]) / dt if p[16] != 0.0 else -w_up
        a_lat = x[_V] * turn
        ax = x[_ALONG] * fx + a_lat * fy  # right axis = (fy, -fx)
        ay = x[_ALONG] * fy - a_lat * fx
        kg = 1.0 - math.exp(-dt / p[2])
        x[_LPG] += kg * ((fp[0] - ax) - x[_LPG])
        x[_LPG + 1] += kg * ((fp[1] - ay) - x[_LPG + 1])
        # 3b. autonomous: aperiodic links on the platform specific force
        ka = 1.0 - math.exp(-dt / p[3])
        x[_LPA] += ka * (fp[0] - x[_LPA])
        x[_LPA + 1] += ka * (fp[1] - x[_LPA + 1])
        horizontal = math.hypot(x[_LPA], x[_LPA + 1]) > p[13]
        x[_REJT] = x[_REJT] + dt if horizontal else 0.0
        rejected = bool(p[5]) and (abs(np.linalg.norm(f) - x[_GNORM]) > p[6] or abs(w_up) > p[7]
                                   or (horizontal and x[_REJT] <= p[14]))
        # 3c. the correction rate for the next sample
        if gnss_ok:
            wgt = p[4]
            auto_k = 0.0 if rejected else (1.0 - wgt) * p[1]
            dx, dy = wgt * p[0] * x[_LPG] + auto_k * x[_LPA], wgt * p[0] * x[_LPG + 1] + auto_k * x[_LPA + 1]
            mode = 2
        elif rejected:
            dx = dy = 0.0
            mode = 3
            flags |= Flag.ACC_REJECTED
        else:
            dx, dy = p[1] * x[_LPA], p[1] * x[_LPA + 1]
            mode = 1
        if c.combined and not gnss_ok:
            flags |= Flag.GNSS_GAP
        x[_WP], x[_WP + 1], x[_WP + 2] = -dy, dx, 0.0
        if gnss_ok and p[15] > 0.0:  # 3d. the accelerometer bias: the residual seen in the body
            x[_BA:_BA + 3] += (p[15] * dt) * (cm.T @ np.array([x[_LPG], x[_LPG + 1], 0.0]))
        return mode, gnss_ok, flags

    def _start(self, x, q_enu_sensor, al, m) -> None:
        """Level the platform from the alignment attitude; keep |f| at rest as the local gravity."""
        cm = quat_to_matrix(q_enu_sensor) @ m.T
        x[_C:_C + 9] = cm.reshape(9)
        x[_HPREV] = x[_HSTAR] = math.atan2(cm[0, 1], cm[1, 1])
        x[_GNORM] = np.linalg.norm(al[SACC:SACC + 3]) / max(al[NACC], 1.0)
        x[_WP:_WP + 3] = 0.0

    def _output(self, x, m) -> np.ndarray:
        """Body(sensor)->frame: the platform turned by alpha = H* - H about the vertical (ENU),
        then into the output frame."""
        cm = x[_C:_C + 9].reshape(3, 3)
        a = x[_HSTAR] - x[_HPREV]
        ca, sa = math.cos(a), math.sin(a)
        rz = np.array([[ca, sa, 0.0], [-sa, ca, 0.0], [0.0, 0.0, 1.0]])  # Rz(-alpha)
        return matrix_to_quat((self.F @ rz) @ cm @ m)


    # -- public ----------------------------------------------------------------------------
    def _gnss_arrays(self, rec: Recording) -> np.ndarray:
        if not self.config.combined:  # not read: one dummy row per sample only for the reference loop
            return np.broadcast_to(NO_GNSS, (len(rec), 6))
        if rec.gnss is None:
            raise InputError(f"{self.name} needs a GNSS stream (Recording(gnss=...)); use 'gst' without GNSS")
        return gnss_sample_rows(rec)

    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: dict | None = None) -> Result:
        if not isinstance(rec, Recording):
            raise InputError(f"rec must be a fusionkit.Recording, got {type(rec).__name__}")
        check_finite_all({"gyr": rec.gyr, "acc": rec.acc}, self.config.nan_policy)
        used = resolve_backend(backend, True)
        body = self.body_axes(rec)
        m = self.axes(body)
        n = len(rec)
        gn = self._gnss_arrays(rec)
        st = state if state is not None else self.new_state(rec.nominal_dt)
        st = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in st.items()}
        gyr, dt, gaps = hold_gaps(rec.gyr, rec.dt, rec.nominal_dt, self.config.max_gap)
        q = np.empty((n, 4))
        flags = np.zeros(n, np.uint32)
        mode = np.zeros(n, np.uint8)
        if used == "numba":
            _gst_loop(gyr, rec.acc, dt, gn, matrix_to_quat(m), matrix_to_quat(self.F), self._p, st["x"], st["det"],
                      self.detector.kernel().params, st["align"], self.aligner(st["dt"]).params(),
                      q, flags, mode)
        else:
            for k in range(n):
                q[k], flags[k], mode[k] = self._step(st, gyr[k], rec.acc[k], gn[k], dt[k], m)
        al = st["align"]
        diag = {"backend": used, "filter": self.name, "config": self.config.model_dump(), "mode": mode,
                "mode_names": MODES, "bias": al[BIAS:BIAS + 3].copy(), "body": body or "RFU",
                "alignment_end_index": None if al[17] < 0 else int(al[17]), "state": st}
        mark_gaps(flags, gaps, rec.gyr, diag, gap_threshold(rec.nominal_dt, self.config.max_gap))
        diag["alignment_disturbed"] = bool(al[DISTURBED])
        report_disturbed(al, st["dt"], self.config.alignment_duration)
        return Result(q, flags, self.config.frame, diag)

    def reset(self) -> None:
        self._stream = None

    def update(self, gyr, acc, mag=None, dt: float | None = None, gnss=None) -> np.ndarray:
        """One sample; ``gnss`` = (vn, ve, valid, age, new, t_epoch) of the latest epoch, or None.
        Without a recording, the sensors' axes are the config's ``body`` (None: RFU)."""
        from ..validation import as_vector, check_positive

        if dt is None:
            raise InputError("update() needs dt, the sample interval in s")
        dt = check_positive("dt", dt)
        g, a = as_vector("gyr", gyr), as_vector("acc", acc)
        if self.config.nan_policy == "raise" and not (np.isfinite(g).all() and np.isfinite(a).all()):
            raise InputError("non-finite gyr/acc sample; pass nan_policy='skip' to hold and flag")
        self.check_stream_units(g, a)
        if self._stream is None:
            self._stream = self.new_state(dt)
        g, dt, gap = stream_gap(g, dt, self._stream["dt"], self.config.max_gap)
        gn = NO_GNSS if gnss is None else np.asarray(gnss, float)
        q, f, _ = self._step(self._stream, g, a, gn, dt, self.M)
        self.last_flags = gap_flags(f, gap)
        return q


def _wrap(a: float) -> float:
    """``a`` in [-pi, pi) for ``|a| < 3 pi`` (differences of wrapped angles)."""
    if a >= math.pi:
        return a - 2.0 * math.pi
    if a < -math.pi:
        return a + 2.0 * math.pi
    return a


class GstGnssFilter(GstFilter):
    """Source 001's combined algorithm: GNSS-aided levelling and track-angle heading while GNSS
    is usable, the autonomous loop and gyroscopic heading in GNSS gaps."""

    name: ClassVar[str] = "gst-gnss"
    requires_gnss: ClassVar[bool] = True
    summary: ClassVar[str] = "GST levelled with GNSS-compensated specific force, track-angle heading, autonomous in gaps"

    class Config(GstConfig):
        combined: bool = param(True, unit="-", description="use GNSS when usable (gst-gnss), else autonomous only")


# ---- numba kernel: the same steps as GstFilter._step -------------------------------------------


@njit
def _kwrap(a):
    if a >= math.pi:
        return a - 2.0 * math.pi
    if a < -math.pi:
        return a + 2.0 * math.pi
    return a


@njit
def _exp_quat(r0, r1, r2, out):
    """Exact quaternion of the rotation vector r (rotations.quat_from_rotvec); a polynomial
    below 0.05 rad (error under 1e-22), sin/cos above."""
    s2 = r0 * r0 + r1 * r1 + r2 * r2
    if s2 < 0.0025:
        x = 0.25 * s2  # (s/2)^2
        c = 1.0 - x / 2.0 + x * x / 24.0 - x * x * x / 720.0 + x * x * x * x / 40320.0
        k = 0.5 * (1.0 - x / 6.0 + x * x / 120.0 - x * x * x / 5040.0 + x * x * x * x / 362880.0)
    else:
        s = math.sqrt(s2)
        c = math.cos(0.5 * s)
        k = math.sin(0.5 * s) / s
    out[0], out[1], out[2], out[3] = c, k * r0, k * r1, k * r2


@njit(cache=True)
def _gst_loop(gyr, acc, dt, gn, qm, qf, p, x, ds, dp, al, ap, out_q, out_f, out_m):
    """The compiled twin of GstFilter._step. The platform attitude is kept as a quaternion here
    (the same exact exponentials as the reference's Rodrigues matrices, about half the
    arithmetic); ``x`` holds it as C again when the loop returns."""
    q = np.empty(4)
    qc = np.empty(4)  # body (RFU) -> platform
    dq = np.empty(4)
    tq = np.empty(4)
    qfz = np.empty(4)  # the output frame turned by -alpha about the vertical
    t1 = np.empty(9)
    if al[PHASE] != 0.0:
        dcm_to_quat(x[_C:_C + 9], qc)
    m = np.empty(9)
    quat_to_dcm(qm, m)  # body -> RFU as a matrix, for the sensor vectors
    last_h, kg, ka = -1.0, 0.0, 0.0
    last_alpha = np.nan
    for k in range(gyr.shape[0]):
        g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]
        a0, a1, a2 = acc[k, 0], acc[k, 1], acc[k, 2]
        gyr_ok, acc_ok, _, flags = validity_flags(g0, g1, g2, a0, a1, a2, 0.0, 0.0, 0.0, False, p[17], p[18])
        h = dt[k]
        if al[PHASE] == 0.0:
            if gyr_ok and acc_ok and _motion_step(ds, g0, g1, g2, a0, a1, a2, 0.0, 0.0, 0.0, h, dp) != 0:
                flags |= 2
            status = align_step(al, ap, g0, g1, g2, a0, a1, a2, 0.0, 0.0, 0.0, gyr_ok, acc_ok, False,
                                (flags & 2) != 0, q)
            if status == ALIGNED_NOW or status == ALIGNED_BEFORE:
                # level the platform: q_C = q_align (x) q_M^-1; |f| at rest
                qmul_into(q[0], q[1], q[2], q[3], qm[0], -qm[1], -qm[2], -qm[3], qc)
                quat_to_dcm(qc, t1)
                x[_HPREV] = math.atan2(t1[1], t1[4])
                x[_HSTAR] = x[_HPREV]
                nacc = max(al[NACC], 1.0)
                x[_GNORM] = math.sqrt(al[SACC] ** 2 + al[SACC + 1] ** 2 + al[SACC + 2] ** 2) / nacc
                x[_WP], x[_WP + 1], x[_WP + 2] = 0.0, 0.0, 0.0
            if status == ALIGNING or status == ALIGNED_NOW:
                qmul_into(qf[0], qf[1], qf[2], qf[3], q[0], q[1], q[2], q[3], tq)  # into the output frame
                _positive(tq)
                out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = tq[0], tq[1], tq[2], tq[3]
                out_f[k] = flags | 1
                out_m[k] = 0
                continue
        if gyr_ok:
            b0, b1, b2 = g0 - al[BIAS], g1 - al[BIAS + 1], g2 - al[BIAS + 2]
            w0 = m[0] * b0 + m[1] * b1 + m[2] * b2
            w1 = m[3] * b0 + m[4] * b1 + m[5] * b2
            w2 = m[6] * b0 + m[7] * b1 + m[8] * b2
            f0 = m[0] * a0 + m[1] * a1 + m[2] * a2 - x[_BA]
            f1 = m[3] * a0 + m[4] * a1 + m[5] * a2 - x[_BA + 1]
            f2 = m[6] * a0 + m[7] * a1 + m[8] * a2 - x[_BA + 2]
            # 1. platform Poisson equation: q_C <- exp(-w_P dt) (x) q_C (x) exp(w_B dt)
            _exp_quat(-x[_WP] * h, -x[_WP + 1] * h, -x[_WP + 2] * h, dq)
            qmul_into(dq[0], dq[1], dq[2], dq[3], qc[0], qc[1], qc[2], qc[3], tq)
            _exp_quat(w0 * h, w1 * h, w2 * h, dq)
            qmul_into(tq[0], tq[1], tq[2], tq[3], dq[0], dq[1], dq[2], dq[3], qc)
            qnormalize(qc)
            cw, cx, cy, cz = qc[0], qc[1], qc[2], qc[3]
            c00 = 1 - 2 * (cy * cy + cz * cz)
            c01 = 2 * (cx * cy - cw * cz)
            c02 = 2 * (cx * cz + cw * cy)
            c10 = 2 * (cx * cy + cw * cz)
            c11 = 1 - 2 * (cx * cx + cz * cz)
            c12 = 2 * (cy * cz - cw * cx)
            c20 = 2 * (cx * cz - cw * cy)
            c21 = 2 * (cy * cz + cw * cx)
            c22 = 1 - 2 * (cx * cx + cy * cy)
            hn = math.hypot(c01, c11)
            fx, fy = c01 / hn, c11 / hn
            if acc_ok:
                # 2. platform specific force, turn rate, forward direction
                fp0 = c00 * f0 + c01 * f1 + c02 * f2
                fp1 = c10 * f0 + c11 * f1 + c12 * f2
                w_up = c20 * w0 + c21 * w1 + c22 * w2
                # 3a. GNSS
                if p[12] != 0.0:  # the autonomous filter does not read GNSS (gn may be a dummy row)
                    vn, ve, valid, age, new, t_ep = gn[k, 0], gn[k, 1], gn[k, 2] != 0.0, gn[k, 3], gn[k, 4] != 0.0, gn[k, 5]
                else:
                    vn, ve, valid, age, new, t_ep = 0.0, 0.0, False, np.inf, False, np.nan
                gnss_ok = p[12] != 0.0 and valid and age <= p[11]
                if p[12] == 0.0:
                    pass
                elif new and valid:
                    v = math.hypot(vn, ve)
                    if math.isfinite(x[_TPREV]) and t_ep > x[_TPREV]:
                        x[_ALONG] = (v - x[_VPREV]) / (t_ep - x[_TPREV])
                    x[_VPREV], x[_TPREV], x[_V] = v, t_ep, v
                elif not valid:
                    x[_TPREV] = np.nan
                if p[16] != 0.0:
                    a_lat = x[_V] * _kwrap(math.atan2(fx, fy) - x[_HPREV]) / h
                else:
                    a_lat = x[_V] * (-w_up)
                ax = x[_ALONG] * fx + a_lat * fy
                ay = x[_ALONG] * fy - a_lat * fx
                if h != last_h:  # the low-pass coefficients, recomputed only when dt changes
                    kg = 1.0 - math.exp(-h / p[2])
                    ka = 1.0 - math.exp(-h / p[3])
                    last_h = h
                x[_LPG] += kg * ((fp0 - ax) - x[_LPG])
                x[_LPG + 1] += kg * ((fp1 - ay) - x[_LPG + 1])
                # 3b. autonomous
                x[_LPA] += ka * (fp0 - x[_LPA])
                x[_LPA + 1] += ka * (fp1 - x[_LPA + 1])
                fn = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
                horizontal = math.hypot(x[_LPA], x[_LPA + 1]) > p[13]
                x[_REJT] = x[_REJT] + h if horizontal else 0.0
                rejected = p[5] != 0.0 and (abs(fn - x[_GNORM]) > p[6] or abs(w_up) > p[7]
                                            or (horizontal and x[_REJT] <= p[14]))
                # 3c. correction
                if gnss_ok:
                    wgt = p[4]
                    auto_k = 0.0 if rejected else (1.0 - wgt) * p[1]
                    dx = wgt * p[0] * x[_LPG] + auto_k * x[_LPA]
                    dy = wgt * p[0] * x[_LPG + 1] + auto_k * x[_LPA + 1]
                    mode = 2
                elif rejected:
                    dx = 0.0
                    dy = 0.0
                    mode = 3
                    flags |= 512
                else:
                    dx = p[1] * x[_LPA]
                    dy = p[1] * x[_LPA + 1]
                    mode = 1
                if p[12] != 0.0 and not gnss_ok:
                    flags |= 1024
                x[_WP], x[_WP + 1], x[_WP + 2] = -dy, dx, 0.0
                if gnss_ok and p[15] > 0.0:  # 3d. accelerometer bias: C^T [d, 0]
                    kb, l0, l1 = p[15] * h, x[_LPG], x[_LPG + 1]
                    x[_BA] += kb * (c00 * l0 + c10 * l1)
                    x[_BA + 1] += kb * (c01 * l0 + c11 * l1)
                    x[_BA + 2] += kb * (c02 * l0 + c12 * l1)
            else:  # no specific force: the levelling pauses, the gyros go on
                x[_WP], x[_WP + 1], x[_WP + 2] = 0.0, 0.0, 0.0
                mode = 3
                gnss_ok = False
                vn = ve = 0.0
            # 4. heading
            hh = math.atan2(fx, fy)
            x[_HSTAR] += _kwrap(hh - x[_HPREV])
            x[_HPREV] = hh
            if gnss_ok and x[_V] >= p[10]:
                track = math.atan2(ve, vn)
                if x[_HINIT] == 0.0 and p[9] != 0.0:
                    x[_HSTAR] = track
                else:
                    x[_HSTAR] += _kwrap(track - x[_HSTAR]) * h / p[8]
                x[_HINIT] = 1.0
            x[_HSTAR] = _kwrap(x[_HSTAR])
        else:
            mode = 0  # a bad sample: the state is held
        # output: q_F (x) Rz(-alpha) (x) q_C (x) q_M, with the first two combined while alpha holds
        alpha = x[_HSTAR] - x[_HPREV]
        if not abs(alpha - last_alpha) < 1e-12:  # constant without GNSS, but for rounding (NaN at first)
            ca, sa = math.cos(0.5 * alpha), -math.sin(0.5 * alpha)
            qmul_into(qf[0], qf[1], qf[2], qf[3], ca, 0.0, 0.0, sa, qfz)
            last_alpha = alpha
        qmul_into(qfz[0], qfz[1], qfz[2], qfz[3], qc[0], qc[1], qc[2], qc[3], tq)
        qmul_into(tq[0], tq[1], tq[2], tq[3], qm[0], qm[1], qm[2], qm[3], q)
        _positive(q)
        out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = q[0], q[1], q[2], q[3]
        out_f[k] = flags
        out_m[k] = mode
    if al[PHASE] != 0.0:
        quat_to_dcm(qc, t1)
        for i in range(9):
            x[_C + i] = t1[i]


@njit
def _positive(q):
    """The w >= 0 representative (as rotations.matrix_to_quat returns), normalised."""
    if q[0] < 0.0:
        q[0], q[1], q[2], q[3] = -q[0], -q[1], -q[2], -q[3]
    qnormalize(q)
