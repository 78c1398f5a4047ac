"""Source 001's levelling and heading laws as pipeline correctors (any estimator, any frame).

The document's platform equation ``dC/dt = C [w_B x] - [w_P x] C`` is integrated exactly over a
sample as ``C <- exp(-[w_P dt x]) C exp([w_B dt x])``: the estimator supplies the right factor
(the gyros), these correctors the left one, the platform rate ``w_P`` found on the previous
sample. They are ``state`` correctors: they turn the estimator's attitude by
``exp(-[w_P dt x])`` in the earth frame, which is the document's platform to rounding (the
``gst`` / ``gst-gnss`` presets are ``poisson-quat`` with these, tests/test_gst.py holds them to
the earlier monolithic filters to 1e-9). With the frame's "up" vector ``u``, the document's
``w_P = [-K d_y, K d_x, 0]`` is ``w_P = u x (K d)`` for the horizontal residual ``d``: no vertical
component, the platform is azimuth-free. ``K = 1 / (g tau)`` with standard gravity.

Per sample (after the estimator's propagation by the bias-corrected gyros):

1. the pending platform rate: ``q <- exp(-w_P dt) (x) q``;
2. the specific force in the frame ``f = R (f_B - b)`` (``b`` the accelerometer bias estimate,
   ``gst-gnss`` only), its horizontal part ``f_h``; the turn rate ``w_up = u . R w_B``;
3. (b) autonomous: ``d_a = LP(f_h)`` (aperiodic link, ``lp``); the gate (``reject``, an
   extension) pauses it while ``| |f| - gravity | > reject_acc``, ``|w_up| > reject_turn`` or
   ``|d_a| > reject_horizontal`` (the last for at most ``reject_timeout`` s in a row);
   (a) ``gst-gnss`` while the sample's GNSS row is usable: ``d_g = LP(f_h - a_kin)`` (``lp_gnss``)
   with the kinematic acceleration ``a_kin = (dV/dt) e + V (dH/dt) r`` on the horizontal forward
   axis ``e`` and the right axis ``r = e x u`` (eqs. 3, 4; V the GNSS ground speed, dH/dt the rate
   of the forward axis' heading H, or ``turn_rate="gyro"``: ``-w_up``), and
   ``K d = w K_g d_g + (1 - w) K_a d_a`` (``gnss_weight`` w; the autonomous part gated);
   in gaps ``K_a d_a``. The accelerometer bias (``tau_acc_bias``, an extension) follows
   ``b <- b + R^T d_g dt / tau_acc_bias`` while GNSS is usable;
4. heading (``gst-gnss``), eq. 5 ``H*_k = H*_{k-1} + (H_k - H_{k-1}) + (H_tr - H*_{k-1}) h / T``:
   the estimator's heading *is* H* (the gyros move it by ``H_k - H_{k-1}``), so the blend is a
   turn of the attitude about ``u`` by ``wrap(H_tr - H) h / T`` while GNSS is usable and the
   ground speed is at least ``min_speed``; ``heading_init="track"`` (an extension) makes the first
   such turn the whole offset. The corrector's horizontal vectors (the low-pass states, the
   pending ``w_P``) are turned with it: they live on the platform, which the document does not
   turn (its H* is an output angle), so the arithmetic stays the document's.

A sample with an invalid gyro is held (nothing changes); one without a usable accelerometer
gets no levelling (``w_P = 0``) while the heading bookkeeping goes on. Flags: ``ACC_REJECTED``
when the gate pauses the only correction, ``GNSS_GAP`` (``gst-gnss``) when GNSS is not usable.
Both have numba kernels (:func:`gst_correct`, :func:`gst_gnss_correct`, held to the readable
:meth:`GstCorrector.correct` on every sample); ``gst-gnss``'s takes the sample's GNSS row.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._kernels import rodrigues_entries, rotvec_quat_entries
from .._numba import njit
from ..config import BodyAxes, PluginConfig, param
from ..conventions import body_axis, east_vector, north_vector, resolve_body, up_vector
from ..protocols import Correction, Corrector, CorrectorKernel
from ..rotations import cross, quat_from_axis_angle, quat_from_rotvec, quat_mul, quat_to_matrix, rodrigues
from ..types import Flag
from ._factor import k_qmul as _qmul

__all__ = ["GstCorrector", "GstGnssCorrector", "GnssLoopConfig", "GateConfig", "gst_correct", "gst_gnss_correct", "G0"]

#: the standard gravity of the loop gain K = 1 / (g tau)
G0 = 9.80665

# state: up (3), north (3), east (3) of the frame, lp autonomous (3), lp GNSS (3), the pending
# platform rate w_P (3), seconds paused by the horizontal test, V_prev, t_prev, dV/dt, V, heading
# initialised, the forward axis' heading after the previous sample, the accelerometer bias (3, body),
# and the kernel's low-pass gains for the last interval (dt, autonomous, GNSS)
_UP, _N, _E, _LPA, _LPG, _WP, _REJT, _VPREV, _TPREV, _ALONG, _V, _HINIT, _HPREV, _BA, _KDT = (
    0, 3, 6, 9, 12, 15, 18, 19, 20, 21, 22, 23, 24, 25, 28)
_SIZE = 31


class GnssLoopConfig(PluginConfig):
    """The GNSS-aided loop's model (see docs/algorithms/gst.md)."""

    tau_gnss: float | None = param(
        None, unit="s", description="levelling loop time constant with GNSS (K = 1/(g tau)); None: from the sensor "
        "model, sqrt(gnss_vel_noise / (g gyro_drift)), the tau that minimises the tilt error the GNSS velocity noise "
        "(~ sigma_v / (g tau)) and the gyro drift (~ drift tau) leave (fusionkit before: 20 s)", gt=0)
    gnss_vel_noise: float = param(
        0.05, unit="m/s", description="GNSS velocity noise per axis (a receiver's specification; sets tau_gnss)", gt=0)
    gyro_drift: float = param(
        4.8e-5, unit="rad/s", description="slow gyro rate error left after the alignment: bias instability (10 deg/h, "
        "a low-cost MEMS gyro's specification; sets tau_gnss)", gt=0)
    tau_acc_bias: float | None = param(
        100.0, unit="s", description="extension: time constant of the accelerometer bias estimate from the GNSS-aided "
        "residual (observable as the vehicle turns); None: the document's loop (no estimate)", gt=0)
    turn_rate: Literal["heading", "gyro"] = param(
        "heading", unit="-", description="dH/dt of the centripetal V dH/dt (eq. 3): 'heading' differentiates the "
        "heading H of the forward axis (the document); 'gyro' takes the vertical component of the body rate, "
        "which differs by (roll rate) sin(pitch) while rolling into or out of a turn at a pitch")

    def gnss_time_constant(self, g: float = G0) -> float:
        """``tau_gnss``, or the one the sensor model gives."""
        return self.tau_gnss if self.tau_gnss is not None else math.sqrt(self.gnss_vel_noise / (g * self.gyro_drift))


class GateConfig(PluginConfig):
    """The autonomous loop's rejection gate (an extension; shared by the corrector and the presets)."""

    gravity: float = param(
        G0, unit="m/s^2", description="|f| expected at rest, for the gate (the monolithic filter before took the "
        "alignment's mean |f|)", gt=0)
    reject: bool = param(True, unit="-", description="extension: pause the autonomous correction under acceleration "
                         "or turning; False: the document's loop")
    reject_acc: float = param(0.3, unit="m/s^2", description="| |f| - gravity | above this pauses it", gt=0)
    reject_turn: float = param(0.02, unit="rad/s", description="turn rate above this pauses it", gt=0)
    reject_horizontal: float = param(
        0.5, unit="m/s^2", description="low-passed horizontal specific force above this pauses it (a levelled "
        "platform sees only a few tenths: more is acceleration)", gt=0)
    reject_timeout: float = param(
        60.0, unit="s", description="after this long paused by the horizontal-force test alone, correct anyway "
        "(recovers a platform tilted beyond that test)", gt=0)


class GstCorrectorConfig(GateConfig):
    tau: float = param(50.0, unit="s", description="autonomous levelling loop time constant (K = 1/(g tau))", gt=0)
    lp: float = param(2.0, unit="s", description="aperiodic-link time constant of the autonomous signal", gt=0)


class GstCorrector(Corrector):
    """Autonomous GST levelling (source 001, method b): the platform rate from the low-passed
    horizontal specific force, applied as the platform equation's left factor."""

    name: ClassVar[str] = "gst"
    Config = GstCorrectorConfig
    mode: ClassVar[str] = "state"
    combined: ClassVar[bool] = False  #: reads GNSS (``gst-gnss``)
    source: ClassVar[str] = "001 (GST), autonomous correction"
    summary: ClassVar[str] = "level by the low-passed horizontal specific force (autonomous GST loop)"

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        s = np.zeros(_SIZE)
        s[_UP:_UP + 3] = up_vector(frame)
        s[_N:_N + 3] = north_vector(frame)
        s[_E:_E + 3] = east_vector(frame)
        s[_TPREV] = np.nan
        s[_HPREV] = np.nan
        return s

    def params(self) -> np.ndarray:
        """The kernel's parameter vector (``gst_gnss_correct`` documents it)."""
        c = self.config
        p = [c.tau, c.lp, c.gravity, float(c.reject), c.reject_acc, c.reject_turn, c.reject_horizontal,
             c.reject_timeout]
        if not self.combined:
            p += [1.0, 1.0, 1.0, 0.0, 0.0, 1.0] + self._forward().tolist() + [0.0, 0.0, 1.0, 0.0]
        else:
            p += [c.gnss_time_constant(), c.lp_gnss, c.heading_T, float(c.heading_init == "track"), c.min_speed,
                  c.gnss_max_age] + self._forward().tolist() + [
                float(c.turn_rate == "heading"), 0.0 if c.tau_acc_bias is None else 1.0 / c.tau_acc_bias,
                c.gnss_weight, 1.0]
        return np.array(p + [1.0 / (G0 * p[0]), p[19] / (G0 * p[8])])  # the gains K_a, w K_g

    def _forward(self) -> np.ndarray:
        """The forward axis in the sensor's axes (RFU, the document's, when not known)."""
        return body_axis(getattr(self.config, "body", None) or "RFU", "F")

    # -- the readable reference ----------------------------------------------------------------
    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        if not np.all(np.isfinite(sample.gyr)):  # an invalid gyro sample: the state is held
            return Correction(None)
        p, s, dt = self.params(), state, sample.dt
        up, north, east = s[_UP:_UP + 3], s[_N:_N + 3], s[_E:_E + 3]
        # 1. the platform rate found on the previous sample (the platform equation's left factor)
        q = quat_mul(quat_from_rotvec(-s[_WP:_WP + 3] * dt), estimator.quat(est_state))
        r = quat_to_matrix(q)
        if dt != s[_KDT]:  # the low-pass gains (kept for the kernel, which computes them once per interval)
            s[_KDT:_KDT + 3] = dt, 1.0 - math.exp(-dt / p[1]), 1.0 - math.exp(-dt / p[9])
        fwd = self._forward()
        heading = _heading(r @ fwd, up, north, east) if self.combined else 0.0  # of the forward axis
        if self.combined and np.isnan(s[_HPREV]):  # the first sample: the heading before its rotation
            s[_HPREV] = _heading(r @ rodrigues(-sample.gyr * dt) @ fwd, up, north, east)
        out = 0
        usable = False
        if sample.acc is not None:
            a = sample.acc - s[_BA:_BA + 3]
            f = r @ a
            f_h = f - (f @ up) * up
            w_up = float((r @ sample.gyr) @ up)
            if self.combined:
                usable = self._gnss(s, sample.gnss, p)
                e = r @ fwd
                e = e - (e @ up) * up
                e /= np.linalg.norm(e)
                turn = _kwrap(heading - s[_HPREV]) / dt if p[17] != 0.0 else -w_up
                a_kin = s[_ALONG] * e + s[_V] * turn * cross(e, up)
                s[_LPG:_LPG + 3] += s[_KDT + 2] * ((f_h - a_kin) - s[_LPG:_LPG + 3])
            s[_LPA:_LPA + 3] += s[_KDT + 1] * (f_h - s[_LPA:_LPA + 3])
            horizontal = np.linalg.norm(s[_LPA:_LPA + 3]) > p[6]
            s[_REJT] = s[_REJT] + dt if horizontal else 0.0
            rejected = p[3] != 0.0 and (abs(np.linalg.norm(a) - p[2]) > p[4] or abs(w_up) > p[5]
                                        or (horizontal and s[_REJT] <= p[7]))
            k_auto = p[21]  # 1 / (g tau)
            if usable:  # (a), with the document's combination weight
                auto = 0.0 if rejected else (1.0 - p[19]) * k_auto
                d = p[22] * s[_LPG:_LPG + 3] + auto * s[_LPA:_LPA + 3]
            elif rejected:
                d = np.zeros(3)
                out |= Flag.ACC_REJECTED
            else:  # (b)
                d = k_auto * s[_LPA:_LPA + 3]
            if self.combined and not usable:
                out |= Flag.GNSS_GAP
            s[_WP:_WP + 3] = cross(up, d)
            if usable and p[18] > 0.0:  # the accelerometer bias: the residual seen in the body
                s[_BA:_BA + 3] += (p[18] * dt) * (r.T @ s[_LPG:_LPG + 3])
        else:  # no specific force: the levelling pauses, the gyros go on
            s[_WP:_WP + 3] = 0.0
        if self.combined:
            s[_HPREV] = heading
        if usable and s[_V] >= p[12]:  # eq. 5: turn the heading towards the track angle
            delta = _kwrap(math.atan2(sample.gnss[1], sample.gnss[0]) - heading)
            if not (s[_HINIT] == 0.0 and p[11] != 0.0):  # heading_init="track": the whole offset at first
                delta = delta * dt / p[10]
            s[_HINIT] = 1.0
            turn = quat_from_axis_angle(up, -delta)  # heading (clockwise from north) up by delta
            q = quat_mul(turn, q)
            m = quat_to_matrix(turn)
            for i in (_LPA, _LPG, _WP):  # the platform's vectors keep their place on it
                s[i:i + 3] = m @ s[i:i + 3]
            s[_HPREV] = heading + delta  # the blend is no turn of the vehicle
        estimator.set_quat(est_state, q)
        return Correction(None, out)

    def _gnss(self, s, g, p) -> bool:
        """The GNSS row's bookkeeping (ground speed and its derivative at each new valid epoch);
        whether it is usable on this sample."""
        if g is None:
            return False
        if g[4] and g[2]:
            v = math.hypot(g[0], g[1])
            if np.isfinite(s[_TPREV]) and g[5] > s[_TPREV]:
                s[_ALONG] = (v - s[_VPREV]) / (g[5] - s[_TPREV])
            s[_VPREV], s[_TPREV], s[_V] = v, g[5], v
        elif not g[2]:
            s[_TPREV] = np.nan  # no derivative across a gap
        return bool(g[2]) and g[3] <= p[13]

    def kernel(self, estimator) -> CorrectorKernel | None:
        return CorrectorKernel(gst_correct, self.params(), mode="state")


def _heading(v, up, north, east) -> float:
    """The heading of ``v`` (clockwise from north) in the frame."""
    return math.atan2(v @ east, v @ north)


class GstGnssCorrectorConfig(GstCorrectorConfig, GnssLoopConfig):
    lp_gnss: float = param(2.0, unit="s", description="low-pass time constant of the GNSS-aided residual", gt=0)
    gnss_weight: float = param(
        1.0, unit="-", description="weight w of (a) against (b) while GNSS is usable: K d = w K_g d_g + (1 - w) K_a d_a "
        "(the document's combination of the two solutions; 1: (a) alone)", ge=0, le=1)
    heading_T: float = param(50.0, unit="s", description="track-angle blend time constant T (eq. 5)", gt=0)
    heading_init: Literal["track", "blend"] = param(
        "track", unit="-", description="extension 'track': start H* at the first usable track angle; 'blend': eq. 5 "
        "from the gyroscopic heading (the document)")
    min_speed: float = param(5.0, unit="m/s", description="no track angle below this ground speed", ge=0)
    gnss_max_age: float = param(0.5, unit="s", description="a GNSS epoch older than this is a gap", gt=0)
    body: BodyAxes = param(None, unit="-", description="sensor axes (which one is forward); None: the pipeline's "
                           "or the recording's, else the document's RFU")


class GstGnssCorrector(GstCorrector):
    """GNSS-aided GST levelling and track-angle heading (source 001, method a and eq. 5),
    autonomous in GNSS gaps (the combined algorithm)."""

    name: ClassVar[str] = "gst-gnss"
    Config = GstGnssCorrectorConfig
    combined: ClassVar[bool] = True
    uses_gnss: ClassVar[bool] = True
    source: ClassVar[str] = "001 (GST), GNSS correction and combined algorithm"
    summary: ClassVar[str] = "level by GNSS-compensated specific force, heading towards the track angle, autonomous in gaps"

    def for_body(self, body):
        b = resolve_body(body, self.config.body, f"corrector {self.name!r}")
        return self if b == self.config.body else type(self)(self.config.model_copy(update={"body": b}))

    def kernel(self, estimator) -> CorrectorKernel | None:
        return CorrectorKernel(gst_gnss_correct, self.params(), mode="state", gnss=True)


# ---- numba kernels: the same steps as GstCorrector.correct -------------------------------------

_ACC_REJECTED = int(Flag.ACC_REJECTED)
_GNSS_GAP = int(Flag.GNSS_GAP)


@njit(inline="always")
def _kwrap(a):
    """``a`` in [-pi, pi) for ``|a| < 3 pi`` (differences of wrapped angles); the reference calls it too."""
    if a >= math.pi:
        return a - 2.0 * math.pi
    if a < -math.pi:
        return a + 2.0 * math.pi
    return a


@njit(inline="always")
def _turn_about(s, i, c, sn, u0, u1, u2):
    """Turn the horizontal vector ``s[i:i + 3]`` about ``u`` (cos ``c``, sin ``sn``)."""
    v0, v1, v2 = s[i], s[i + 1], s[i + 2]
    s[i] = c * v0 + sn * (u1 * v2 - u2 * v1)
    s[i + 1] = c * v1 + sn * (u2 * v0 - u0 * v2)
    s[i + 2] = c * v2 + sn * (u0 * v1 - u1 * v0)


@njit(inline="always")
def _gst_step(q, s, g0, g1, g2, a0, a1, a2, acc_ok, dt, p, vn, ve, valid, age, new, t_epoch):
    """:meth:`GstCorrector.correct` on the quaternion ``q`` (changed in place); ``p[20]``: GNSS
    is read (``gst-gnss``)."""
    if not (math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2)):
        return -1
    combined = p[20] != 0.0
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    wp0, wp1, wp2 = s[_WP], s[_WP + 1], s[_WP + 2]
    if wp0 != 0.0 or wp1 != 0.0 or wp2 != 0.0:  # 1. q <- exp(-w_P dt) (x) q
        d0, d1, d2, d3 = rotvec_quat_entries(-wp0 * dt, -wp1 * dt, -wp2 * dt)
        qw, qx, qy, qz = _qmul(d0, d1, d2, d3, qw, qx, qy, qz)
    r00, r01, r02 = 1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qw * qz), 2.0 * (qx * qz + qw * qy)
    r10, r11, r12 = 2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qw * qx)
    r20, r21, r22 = 2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy)
    u0, u1, u2 = s[_UP], s[_UP + 1], s[_UP + 2]
    if dt != s[_KDT]:  # the low-pass gains, recomputed only when the interval changes
        s[_KDT], s[_KDT + 1], s[_KDT + 2] = dt, 1.0 - math.exp(-dt / p[1]), 1.0 - math.exp(-dt / p[9])
    b0, b1, b2 = p[14], p[15], p[16]  # the forward axis, its heading (gst-gnss)
    e0 = e1 = e2 = heading = 0.0
    if combined:
        e0, e1, e2 = r00 * b0 + r01 * b1 + r02 * b2, r10 * b0 + r11 * b1 + r12 * b2, r20 * b0 + r21 * b1 + r22 * b2
        heading = math.atan2(e0 * s[_E] + e1 * s[_E + 1] + e2 * s[_E + 2],
                             e0 * s[_N] + e1 * s[_N + 1] + e2 * s[_N + 2])
    if combined and math.isnan(s[_HPREV]):  # the first sample: the heading before this sample's rotation
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = rodrigues_entries(-g0 * dt, -g1 * dt, -g2 * dt)
        c0, c1, c2 = m00 * b0 + m01 * b1 + m02 * b2, m10 * b0 + m11 * b1 + m12 * b2, m20 * b0 + m21 * b1 + m22 * b2
        o0, o1, o2 = r00 * c0 + r01 * c1 + r02 * c2, r10 * c0 + r11 * c1 + r12 * c2, r20 * c0 + r21 * c1 + r22 * c2
        s[_HPREV] = math.atan2(o0 * s[_E] + o1 * s[_E + 1] + o2 * s[_E + 2],
                               o0 * s[_N] + o1 * s[_N + 1] + o2 * s[_N + 2])
    flags = 0
    usable = False
    if acc_ok:
        a0, a1, a2 = a0 - s[_BA], a1 - s[_BA + 1], a2 - s[_BA + 2]
        f0, f1, f2 = r00 * a0 + r01 * a1 + r02 * a2, r10 * a0 + r11 * a1 + r12 * a2, r20 * a0 + r21 * a1 + r22 * a2
        fu = f0 * u0 + f1 * u1 + f2 * u2
        h0, h1, h2 = f0 - fu * u0, f1 - fu * u1, f2 - fu * u2
        w_up = ((r00 * g0 + r01 * g1 + r02 * g2) * u0 + (r10 * g0 + r11 * g1 + r12 * g2) * u1
                + (r20 * g0 + r21 * g1 + r22 * g2) * u2)
        if combined:
            if new != 0.0 and valid != 0.0:  # a new valid epoch: ground speed and its derivative
                v = math.hypot(vn, ve)
                if math.isfinite(s[_TPREV]) and t_epoch > s[_TPREV]:
                    s[_ALONG] = (v - s[_VPREV]) / (t_epoch - s[_TPREV])
                s[_VPREV], s[_TPREV], s[_V] = v, t_epoch, v
            elif valid == 0.0:
                s[_TPREV] = math.nan
            usable = valid != 0.0 and age <= p[13]
            eu = e0 * u0 + e1 * u1 + e2 * u2
            x0, x1, x2 = e0 - eu * u0, e1 - eu * u1, e2 - eu * u2
            en = 1.0 / math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            x0, x1, x2 = x0 * en, x1 * en, x2 * en
            turn = _kwrap(heading - s[_HPREV]) / dt if p[17] != 0.0 else -w_up
            along, lateral = s[_ALONG], s[_V] * turn
            k = s[_KDT + 2]  # right = e x u
            s[_LPG] += k * ((h0 - (along * x0 + lateral * (x1 * u2 - x2 * u1))) - s[_LPG])
            s[_LPG + 1] += k * ((h1 - (along * x1 + lateral * (x2 * u0 - x0 * u2))) - s[_LPG + 1])
            s[_LPG + 2] += k * ((h2 - (along * x2 + lateral * (x0 * u1 - x1 * u0))) - s[_LPG + 2])
        k = s[_KDT + 1]
        s[_LPA] += k * (h0 - s[_LPA])
        s[_LPA + 1] += k * (h1 - s[_LPA + 1])
        s[_LPA + 2] += k * (h2 - s[_LPA + 2])
        l0, l1, l2 = s[_LPA], s[_LPA + 1], s[_LPA + 2]
        horizontal = math.sqrt(l0 * l0 + l1 * l1 + l2 * l2) > p[6]
        s[_REJT] = s[_REJT] + dt if horizontal else 0.0
        rejected = p[3] != 0.0 and (abs(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) - p[2]) > p[4] or abs(w_up) > p[5]
                                    or (horizontal and s[_REJT] <= p[7]))
        k_auto = p[21]
        if usable:
            auto = 0.0 if rejected else (1.0 - p[19]) * k_auto
            kg = p[22]
            d0, d1, d2 = kg * s[_LPG] + auto * l0, kg * s[_LPG + 1] + auto * l1, kg * s[_LPG + 2] + auto * l2
        elif rejected:
            d0 = d1 = d2 = 0.0
            flags |= _ACC_REJECTED
        else:
            d0, d1, d2 = k_auto * l0, k_auto * l1, k_auto * l2
        if combined and not usable:
            flags |= _GNSS_GAP
        s[_WP], s[_WP + 1], s[_WP + 2] = u1 * d2 - u2 * d1, u2 * d0 - u0 * d2, u0 * d1 - u1 * d0
        if usable and p[18] > 0.0:  # the accelerometer bias: R^T d_g
            kb, l0, l1, l2 = p[18] * dt, s[_LPG], s[_LPG + 1], s[_LPG + 2]
            s[_BA] += kb * (r00 * l0 + r10 * l1 + r20 * l2)
            s[_BA + 1] += kb * (r01 * l0 + r11 * l1 + r21 * l2)
            s[_BA + 2] += kb * (r02 * l0 + r12 * l1 + r22 * l2)
    else:
        s[_WP] = s[_WP + 1] = s[_WP + 2] = 0.0
    if combined:
        s[_HPREV] = heading
    if usable and s[_V] >= p[12]:  # eq. 5
        delta = _kwrap(math.atan2(ve, vn) - heading)
        if not (s[_HINIT] == 0.0 and p[11] != 0.0):
            delta = delta * dt / p[10]
        s[_HINIT] = 1.0
        d0, d1, d2, d3 = rotvec_quat_entries(-delta * u0, -delta * u1, -delta * u2)  # about u by -delta
        qw, qx, qy, qz = _qmul(d0, d1, d2, d3, qw, qx, qy, qz)
        sh = d1 * u0 + d2 * u1 + d3 * u2  # sin(-delta / 2): the full angle's cos and sin from the half's
        c, sn = d0 * d0 - sh * sh, 2.0 * d0 * sh
        _turn_about(s, _LPA, c, sn, u0, u1, u2)
        _turn_about(s, _LPG, c, sn, u0, u1, u2)
        _turn_about(s, _WP, c, sn, u0, u1, u2)
        s[_HPREV] = heading + delta
    q[0], q[1], q[2], q[3] = qw, qx, qy, qz
    return flags


@njit
def gst_correct(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, p):
    """The kernel of :meth:`GstCorrector.correct` (``p``: :func:`gst_gnss_correct`'s, not
    reading GNSS)."""
    return _gst_step(q, s, g0, g1, g2, a0, a1, a2, acc_ok, dt, p, 0.0, 0.0, 0.0, math.inf, 0.0, math.nan)


@njit
def gst_gnss_correct(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, p,
                     vn, ve, valid, age, new, t_epoch):
    """The kernel of :meth:`GstGnssCorrector.correct` (it takes the sample's GNSS row): ``p`` =
    (tau, lp, gravity, reject, reject_acc, reject_turn, reject_horizontal, reject_timeout,
    tau_gnss, lp_gnss, heading_T, heading_init == "track", min_speed, gnss_max_age, the body's
    forward axis (3), turn_rate == "heading", 1 / tau_acc_bias or 0, gnss_weight, reads GNSS,
    1 / (g tau), gnss_weight / (g tau_gnss))."""
    return _gst_step(q, s, g0, g1, g2, a0, a1, a2, acc_ok, dt, p, vn, ve, valid, age, new, t_epoch)
