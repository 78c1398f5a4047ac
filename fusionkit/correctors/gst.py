"""Source 001's levelling corrections as pipeline correctors (any estimator, any frame).

The platform equation ``dC/dt = C [w_B x] - [w_P x] C`` equals ``dC/dt = C [(w_B - C^T w_P) x]``,
so the GST's platform rate ``w_P`` is a body-rate correction ``-C^T w_P``: these are ``rate``
correctors. With the earth frame's "up" vector ``u``, the document's ``w_P = [-K d_y, K d_x, 0]``
is ``w_P = K u x d`` for the horizontal residual ``d`` (frame independent).

* ``gst``: ``d`` = the low-passed horizontal specific force (autonomous), gated as in the
  ``gst`` filter (``reject``).
* ``gst-gnss``: while the sample's GNSS row is usable, ``d`` = the low-passed horizontal specific
  force minus the kinematic acceleration (``dV/dt`` along the forward axis, ``V dH/dt`` to the
  right), and the heading is pulled towards the GNSS track angle with time constant ``T``
  (eq. 5 as a rate about the vertical); in gaps it is ``gst``.

The ``gst`` / ``gst-gnss`` filters implement the same laws on the document's azimuth-free
platform with a compiled loop; these correctors let them be composed with other estimators.
Both have kernels (:func:`gst_correct`, :func:`gst_gnss_correct`; rate mode, held to the
reference on every sample); ``gst-gnss``'s takes the sample's GNSS row, which a compiled
pipeline passes to the kernels that declare ``gnss=True``.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._numba import njit
from ..config import BodyAxes, PluginConfig, param
from ..conventions import body_axis, east_vector, north_vector, resolve_body, up_vector
from ..protocols import Correction, Corrector, CorrectorKernel
from ..rotations import quat_to_matrix
from ..types import Flag

__all__ = ["GstCorrector", "GstGnssCorrector", "gst_correct", "gst_gnss_correct"]

# state: up (3), north (3), east (3), lp auto (3), lp gnss (3), |f| at rest, seconds rejected,
# V_prev, t_prev, a_long, V, heading initialised, the forward axis' heading expected at the next
# sample, the accelerometer bias (3, body)
_UP, _N, _E, _LPA, _LPG, _GN, _REJT, _VPREV, _TPREV, _ALONG, _V, _HINIT, _HPREV, _BA = (
    0, 3, 6, 9, 12, 15, 16, 17, 18, 19, 20, 21, 22, 23)
_SIZE = 26


class GstCorrectorConfig(PluginConfig):
    tau: float = param(50.0, unit="s", description="levelling loop time constant (K = 1/(g tau))", gt=0)
    lp: float = param(2.0, unit="s", description="aperiodic-link time constant", gt=0)
    gravity: float = param(9.80665, unit="m/s^2", description="|f| expected at rest (for the gate)", gt=0)
    reject: bool = param(True, unit="-", description="pause under acceleration or turning (extension)")
    reject_acc: float = param(0.3, unit="m/s^2", description="| |f| - g | above this pauses it", gt=0)
    reject_turn: float = param(0.02, unit="rad/s", description="turn rate above this pauses it", gt=0)
    reject_horizontal: float = param(0.5, unit="m/s^2", description="low-passed horizontal force above this pauses it", gt=0)
    reject_timeout: float = param(60.0, unit="s", description="longest pause by the horizontal test alone", gt=0)


class GstCorrector(Corrector):
    """Autonomous GST levelling as a rate correction (source 001, method b)."""

    name: ClassVar[str] = "gst"
    Config = GstCorrectorConfig
    mode: ClassVar[str] = "rate"
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

    def _horizontal(self, r, state, sample):
        f_e = r @ sample.acc
        up = state[_UP:_UP + 3]
        return f_e - (f_e @ up) * up, float((r @ sample.gyr) @ up)

    def _autonomous(self, r, state, sample, f_h, w_up):
        """Update the aperiodic link; the residual to level on (None when the gate pauses it)."""
        c = self.config
        k = 1.0 - math.exp(-sample.dt / c.lp)
        state[_LPA:_LPA + 3] += k * (f_h - state[_LPA:_LPA + 3])
        horizontal = np.linalg.norm(state[_LPA:_LPA + 3]) > c.reject_horizontal
        state[_REJT] = state[_REJT] + sample.dt if horizontal else 0.0
        rejected = c.reject and (abs(np.linalg.norm(sample.acc) - c.gravity) > c.reject_acc
                                 or abs(w_up) > c.reject_turn or (horizontal and state[_REJT] <= c.reject_timeout))
        return None if rejected else state[_LPA:_LPA + 3]

    def _rate(self, r, state, d, tau):
        """Body-rate correction -R^T w_P with w_P = K u x d."""
        w_p = np.cross(state[_UP:_UP + 3], d) / (self.config.gravity * tau)
        return -(r.T @ w_p)

    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        if sample.acc is None:
            return Correction(np.zeros(3))
        r = quat_to_matrix(estimator.quat(est_state))
        f_h, w_up = self._horizontal(r, state, sample)
        d = self._autonomous(r, state, sample, f_h, w_up)
        if d is None:
            return Correction(np.zeros(3), Flag.ACC_REJECTED)
        return Correction(self._rate(r, state, d, self.config.tau))

    def _params(self) -> list[float]:
        c = self.config
        return [c.tau, c.lp, c.gravity, float(c.reject), c.reject_acc, c.reject_turn, c.reject_horizontal,
                c.reject_timeout]

    def kernel(self, estimator) -> CorrectorKernel | None:
        return CorrectorKernel(gst_correct, np.array(self._params()), mode="rate")


_ACC_REJECTED = int(Flag.ACC_REJECTED)
_GNSS_GAP = int(Flag.GNSS_GAP)


@njit(inline="always")
def _inputs(q, s, g0, g1, g2, a0, a1, a2):
    """What both kernels level on: ``R(q)``'s entries, the up vector, the earth-frame specific
    force and the turn rate about up (:meth:`GstCorrector._horizontal`)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r00, r01, r02 = 1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)
    r10, r11, r12 = 2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)
    r20, r21, r22 = 2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)
    u0, u1, u2 = s[_UP], s[_UP + 1], s[_UP + 2]
    f0, f1, f2 = r00 * a0 + r01 * a1 + r02 * a2, r10 * a0 + r11 * a1 + r12 * a2, r20 * a0 + r21 * a1 + r22 * a2
    w_up = ((r00 * g0 + r01 * g1 + r02 * g2) * u0 + (r10 * g0 + r11 * g1 + r12 * g2) * u1
            + (r20 * g0 + r21 * g1 + r22 * g2) * u2)
    return r00, r01, r02, r10, r11, r12, r20, r21, r22, u0, u1, u2, f0, f1, f2, w_up


@njit(inline="always")
def _autonomous(s, f0, f1, f2, u0, u1, u2, a0, a1, a2, w_up, dt, p):
    """:meth:`GstCorrector._autonomous` on the earth-frame specific force ``f``: the aperiodic
    link of its horizontal part (``s[_LPA:_LPA + 3]``) and the gate; True when it pauses."""
    fu = f0 * u0 + f1 * u1 + f2 * u2
    k = 1.0 - math.exp(-dt / p[1])
    s[_LPA] += k * ((f0 - fu * u0) - s[_LPA])
    s[_LPA + 1] += k * ((f1 - fu * u1) - s[_LPA + 1])
    s[_LPA + 2] += k * ((f2 - fu * u2) - s[_LPA + 2])
    d0, d1, d2 = s[_LPA], s[_LPA + 1], s[_LPA + 2]
    horizontal = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) > p[6]
    s[_REJT] = s[_REJT] + dt if horizontal else 0.0
    return p[3] != 0.0 and (abs(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2) - p[2]) > p[4] or abs(w_up) > p[5]
                            or (horizontal and s[_REJT] <= p[7]))


@njit(inline="always")
def _turn(r00, r01, r02, r10, r11, r12, r20, r21, r22, w0, w1, w2, rate):
    """``rate -= R^T w``: an earth-frame platform rate ``w`` as a body-rate correction."""
    rate[0] -= r00 * w0 + r10 * w1 + r20 * w2
    rate[1] -= r01 * w0 + r11 * w1 + r21 * w2
    rate[2] -= r02 * w0 + r12 * w1 + r22 * w2


@njit(inline="always")
def _level(r00, r01, r02, r10, r11, r12, r20, r21, r22, u0, u1, u2, s, i, kg, rate):
    """Level on the residual ``d = s[i:i + 3]``: the platform rate ``w_P = K u x d`` (``K = kg``)
    as the body-rate correction ``-R^T w_P``."""
    d0, d1, d2 = s[i], s[i + 1], s[i + 2]
    _turn(r00, r01, r02, r10, r11, r12, r20, r21, r22,
          (u1 * d2 - u2 * d1) * kg, (u2 * d0 - u0 * d2) * kg, (u0 * d1 - u1 * d0) * kg, rate)


@njit
def gst_correct(q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate):
    """The kernel of :meth:`GstCorrector.correct`: ``p`` = (tau, lp, gravity, reject, reject_acc,
    reject_turn, reject_horizontal, reject_timeout)."""
    if not acc_ok:
        return 0
    r00, r01, r02, r10, r11, r12, r20, r21, r22, u0, u1, u2, f0, f1, f2, w_up = _inputs(q, s, g0, g1, g2, a0, a1, a2)
    if _autonomous(s, f0, f1, f2, u0, u1, u2, a0, a1, a2, w_up, dt, p):
        return _ACC_REJECTED
    _level(r00, r01, r02, r10, r11, r12, r20, r21, r22, u0, u1, u2, s, _LPA, 1.0 / (p[2] * p[0]), rate)
    return 0


@njit
def gst_gnss_correct(q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p, rate,
                     vn, ve, valid, age, new, t_epoch):
    """The kernel of :meth:`GstGnssCorrector.correct` (it takes the sample's GNSS row): ``p`` =
    (gst's 8 parameters, tau_gnss, lp_gnss, heading_T, heading_init == "track", min_speed,
    gnss_max_age, the body's forward axis (3), turn_rate == "heading", 1 / tau_acc_bias or 0)."""
    if not acc_ok:
        return 0
    a0, a1, a2 = a0 - s[_BA], a1 - s[_BA + 1], a2 - s[_BA + 2]
    r00, r01, r02, r10, r11, r12, r20, r21, r22, u0, u1, u2, f0, f1, f2, w_up = _inputs(q, s, g0, g1, g2, a0, a1, a2)
    rejected = _autonomous(s, f0, f1, f2, u0, u1, u2, a0, a1, a2, w_up, dt, p)
    usable = valid != 0.0 and age <= p[13]
    if new != 0.0 and valid != 0.0:  # a new valid epoch: ground speed and its derivative
        v = math.hypot(vn, ve)
        if math.isfinite(s[_TPREV]) and t_epoch > s[_TPREV]:
            s[_ALONG] = (v - s[_VPREV]) / (t_epoch - s[_TPREV])
        s[_VPREV], s[_TPREV], s[_V] = v, t_epoch, v
    elif valid == 0.0:
        s[_TPREV] = math.nan
    b0, b1, b2 = p[14], p[15], p[16]  # the forward axis, levelled, and its heading
    e0, e1, e2 = r00 * b0 + r01 * b1 + r02 * b2, r10 * b0 + r11 * b1 + r12 * b2, r20 * b0 + r21 * b1 + r22 * b2
    eu = e0 * u0 + e1 * u1 + e2 * u2
    e0, e1, e2 = e0 - eu * u0, e1 - eu * u1, e2 - eu * u2
    en = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / en, e1 / en, e2 / en
    heading = math.atan2(e0 * s[_E] + e1 * s[_E + 1] + e2 * s[_E + 2], e0 * s[_N] + e1 * s[_N + 1] + e2 * s[_N + 2])
    turn_rate = -w_up
    if p[17] != 0.0 and math.isfinite(s[_HPREV]) and math.isfinite(heading):
        turn_rate = ((heading - s[_HPREV] + math.pi) % (2.0 * math.pi) - math.pi) / dt
    s[_HPREV] = heading
    if not usable:  # the autonomous loop
        if rejected:
            return _ACC_REJECTED | _GNSS_GAP
        _level(r00, r01, r02, r10, r11, r12, r20, r21, r22, u0, u1, u2, s, _LPA, 1.0 / (p[2] * p[0]), rate)
        return _GNSS_GAP
    h0, h1, h2 = e1 * u2 - e2 * u1, e2 * u0 - e0 * u2, e0 * u1 - e1 * u0  # right = fwd x up
    along, lateral = s[_ALONG], s[_V] * turn_rate
    fu = f0 * u0 + f1 * u1 + f2 * u2
    k = 1.0 - math.exp(-dt / p[9])
    s[_LPG] += k * (((f0 - fu * u0) - (along * e0 + lateral * h0)) - s[_LPG])
    s[_LPG + 1] += k * (((f1 - fu * u1) - (along * e1 + lateral * h1)) - s[_LPG + 1])
    s[_LPG + 2] += k * (((f2 - fu * u2) - (along * e2 + lateral * h2)) - s[_LPG + 2])
    _level(r00, r01, r02, r10, r11, r12, r20, r21, r22, u0, u1, u2, s, _LPG, 1.0 / (p[2] * p[8]), rate)
    if p[18] > 0.0:  # the accelerometer bias: R^T d
        kb, d0, d1, d2 = p[18] * dt, s[_LPG], s[_LPG + 1], s[_LPG + 2]
        s[_BA] += kb * (r00 * d0 + r10 * d1 + r20 * d2)
        s[_BA + 1] += kb * (r01 * d0 + r11 * d1 + r21 * d2)
        s[_BA + 2] += kb * (r02 * d0 + r12 * d1 + r22 * d2)
    if s[_V] >= p[12]:  # eq. 5: pull the heading towards the track angle
        err = (math.atan2(ve, vn) - heading + math.pi) % (2.0 * math.pi) - math.pi
        if s[_HINIT] == 0.0 and p[11] != 0.0:
            turn = err / dt  # the whole offset in one sample
        else:
            turn = err / p[10]
        s[_HINIT] = 1.0
        s[_HPREV] = heading + turn * dt  # the pull is no turn of the vehicle
        _turn(r00, r01, r02, r10, r11, r12, r20, r21, r22, turn * u0, turn * u1, turn * u2, rate)
    return 0


class GnssLoopConfig(PluginConfig):
    """The GNSS-aided loop's model (shared by the ``gst-gnss`` filter and corrector; see
    docs/algorithms/gst.md)."""

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

    def gnss_time_constant(self, g: float = 9.80665) -> float:
        """``tau_gnss``, or the one the sensor model gives."""
        return self.tau_gnss if self.tau_gnss is not None else math.sqrt(self.gnss_vel_noise / (g * self.gyro_drift))


class GstGnssCorrectorConfig(GstCorrectorConfig, GnssLoopConfig):
    lp_gnss: float = param(2.0, unit="s", description="low-pass of the GNSS-aided residual", gt=0)
    heading_T: float = param(50.0, unit="s", description="track-angle blend time constant T (eq. 5)", gt=0)
    heading_init: Literal["track", "blend"] = param("track", unit="-", description="jump to the first track angle or blend")
    min_speed: float = param(5.0, unit="m/s", description="no track angle below this ground speed", ge=0)
    gnss_max_age: float = param(0.5, unit="s", description="a GNSS epoch older than this is a gap", gt=0)
    body: BodyAxes = param(None, unit="-", description="sensor axes (which one is forward); None: the pipeline's "
                           "or the recording's, else the document's RFU")


class GstGnssCorrector(GstCorrector):
    """GNSS-aided GST levelling and track-angle heading (source 001, method a and eq. 5),
    autonomous in GNSS gaps."""

    name: ClassVar[str] = "gst-gnss"
    Config = GstGnssCorrectorConfig
    source: ClassVar[str] = "001 (GST), GNSS correction and combined algorithm"
    summary: ClassVar[str] = "level by GNSS-compensated specific force, heading towards the track angle, autonomous in gaps"

    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        c = self.config
        if sample.acc is None:
            return Correction(np.zeros(3))
        sample = sample._replace(acc=sample.acc - state[_BA:_BA + 3])
        r = quat_to_matrix(estimator.quat(est_state))
        f_h, w_up = self._horizontal(r, state, sample)
        d_auto = self._autonomous(r, state, sample, f_h, w_up)
        g = sample.gnss
        usable = g is not None and bool(g[2]) and g[3] <= c.gnss_max_age
        if g is not None and g[4] and g[2]:  # a new valid epoch: ground speed and its derivative
            v = math.hypot(g[0], g[1])
            if np.isfinite(state[_TPREV]) and g[5] > state[_TPREV]:
                state[_ALONG] = (v - state[_VPREV]) / (g[5] - state[_TPREV])
            state[_VPREV], state[_TPREV], state[_V] = v, g[5], v
        elif g is not None and not g[2]:
            state[_TPREV] = np.nan
        up, north, east = state[_UP:_UP + 3], state[_N:_N + 3], state[_E:_E + 3]
        fwd = r @ self._forward()
        fwd = fwd - (fwd @ up) * up
        fwd /= np.linalg.norm(fwd)
        heading = math.atan2(fwd @ east, fwd @ north)  # of the forward axis, clockwise from north
        turn_rate = -w_up
        if c.turn_rate == "heading" and np.isfinite(state[_HPREV]) and np.isfinite(heading):
            turn_rate = ((heading - state[_HPREV] + math.pi) % (2.0 * math.pi) - math.pi) / sample.dt
        state[_HPREV] = heading
        if not usable:
            if d_auto is None:
                return Correction(np.zeros(3), Flag.ACC_REJECTED | Flag.GNSS_GAP)
            return Correction(self._rate(r, state, d_auto, c.tau), Flag.GNSS_GAP)
        right = np.cross(fwd, up)
        a_kin = state[_ALONG] * fwd + state[_V] * turn_rate * right
        k = 1.0 - math.exp(-sample.dt / c.lp_gnss)
        state[_LPG:_LPG + 3] += k * ((f_h - a_kin) - state[_LPG:_LPG + 3])
        rate = self._rate(r, state, state[_LPG:_LPG + 3], c.gnss_time_constant())
        if c.tau_acc_bias is not None:  # the accelerometer bias: the residual seen in the body
            state[_BA:_BA + 3] += (sample.dt / c.tau_acc_bias) * (r.T @ state[_LPG:_LPG + 3])
        if state[_V] >= c.min_speed:  # eq. 5: pull the heading towards the track angle
            err = (math.atan2(g[1], g[0]) - heading + math.pi) % (2 * math.pi) - math.pi
            if state[_HINIT] == 0.0 and c.heading_init == "track":
                turn = err / sample.dt  # the whole offset in one sample
            else:
                turn = err / c.heading_T
            state[_HINIT] = 1.0
            state[_HPREV] = heading + turn * sample.dt  # the pull is no turn of the vehicle
            rate = rate - r.T @ (turn * up)  # clockwise (heading up) is negative about "up"
        return Correction(rate)

    def _forward(self) -> np.ndarray:
        """The forward axis in the sensor's axes (RFU, the document's, when not known)."""
        return body_axis(self.config.body or "RFU", "F")

    def for_body(self, body):
        b = resolve_body(body, self.config.body, f"corrector {self.name!r}")
        return self if b == self.config.body else type(self)(self.config.model_copy(update={"body": b}))

    def kernel(self, estimator) -> CorrectorKernel | None:
        c = self.config
        p = self._params() + [c.gnss_time_constant(), c.lp_gnss, c.heading_T, float(c.heading_init == "track"),
                              c.min_speed, c.gnss_max_age] + self._forward().tolist() + [
            float(c.turn_rate == "heading"), 0.0 if c.tau_acc_bias is None else 1.0 / c.tau_acc_bias]
        return CorrectorKernel(gst_gnss_correct, np.array(p), mode="rate", gnss=True)
