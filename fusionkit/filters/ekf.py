"""The ``ekf`` filter: an extended Kalman filter baseline built on filterpy.

An *error-state* (multiplicative) EKF, run by :class:`filterpy.kalman.ExtendedKalmanFilter`:

- nominal state, kept here: the orientation ``q`` (body -> ENU, unit quaternion) and the gyro
  bias ``b`` (rad/s, body);
- filterpy's state ``x``: the 6 error states, the orientation error ``dtheta`` (rad, body frame,
  ``q_true = q (x) exp(dtheta)``) and the bias error ``db`` (``b_true = b + db``), with their
  covariance ``P``. After each update the error is folded into the nominal state and ``x`` is
  zero again. (An additive EKF on the four quaternion components would break the unit norm and
  carry a singular covariance; the error state has neither problem and makes NEES well defined.)

Per sample:

1. **propagation** (gyroscope): ``q <- q (x) exp((w - b) dt)``; ``F = [[exp(-[w dt x]), -I dt],
   [0, I]]``, ``Q = diag(gyr_noise^2 dt I, bias_walk^2 dt I)``: ``kf.predict()``.
2. **accelerometer gravity update**: ``z = a / |a|``, ``h = R(q)^T up``, ``H = [[h x], 0]``. The
   noise is a density (``R = sigma^2 / dt``, so the filter's time constants do not depend on the
   sample rate: the errors that matter, linear accelerations, are correlated, not white):
   ``sigma = (acc_noise + acc_dynamic * D) / g`` with ``D`` the RMS over ``dynamic_tau`` s of
   the dynamic acceleration ``|a - g h|``. Raised under dynamic acceleration, and for every
   sample of a motion alike: weighting each sample by its own deviation would favour the samples
   where a swinging acceleration happens to pass through ``g h``, and those are not zero-mean
   (measured on BROAD's fast-translation trial 15, 6D, otherwise equal settings: 15.6 deg of
   tilt error with each sample's own deviation, 2.1 deg with the RMS).
3. **magnetometer heading update** (9D): the azimuth of the field seen in the earth frame with
   the current tilt, ``psi = atan2(-m_E, m_N)`` of ``R(q) m``, should be zero (the field points
   to north); noise density ``mag_noise`` (rad/sqrt(Hz)); the residual is wrapped to (-pi, pi].
   ``heading_jacobian="full"`` (default) is the azimuth's exact Jacobian, including the tilt
   terms (a tilt error about north moves the tilt-compensated heading by ``tan(dip)`` times
   itself, 2.5x at a 68 deg dip); ``"vertical"`` keeps only the heading row ``e_up^T R`` (the
   magnetometer reaches tilt only through the covariance), which makes the filter
   inconsistent (ANEES 8.5 instead of 6 in the simulated consistency test) and costs 0.5 deg on
   BROAD. Samples the ``magnetic`` detector calls disturbed are skipped (``mag_rejection``,
   flag MAG_DISTURBED).

Both measurements go to one ``kf.update`` (3 or 4 rows). filterpy's arrays are kept as it expects
them, ``x`` a (6, 1) column and ``z`` a column too (a 1-D ``z`` silently broadcasts ``x`` to a
matrix in filterpy), and checked after every predict and update.

Optional (off by default): ``gate``, a chi-square test on each measurement's normalised
innovation squared (NIS); a measurement above it is not used (flags ACC_REJECTED /
MAG_DISTURBED).

The start attitude is the first valid sample's (tilt from the accelerometer, heading from the
magnetometer, zero without one); before it the gyro turns the output from identity. Bad input
(docs/reliability.md): an invalid gyroscope sample holds the state (GYR_INVALID); an invalid
accelerometer or magnetometer sample (non-finite, zero, a glitch beyond 16 g, a reading at
``acc_range``) skips its update (ACC_INVALID / ACC_SATURATED / MAG_INVALID); gyro readings at
``gyr_range`` are flagged GYR_SATURATED. After a timestamp gap (GAP, the state held across it)
or a saturated gyro the attitude covariance is reset to the start's (:meth:`EkfFilter._relevel`).
``Result.diagnostics`` has the final bias and covariance; :meth:`EkfFilter.run` with
``record=True`` adds each sample's NIS for consistency checks.

Two paths: the readable reference on filterpy's ``ExtendedKalmanFilter`` (``self.kf``; what
:meth:`EkfFilter.update`, ``record=True`` and ``backend="reference"`` run), and a compiled loop,
:func:`_ekf_loop`, that spells out filterpy's predict and update products on fixed-size arrays
(``run()``'s default; the tests hold it to the filterpy path to 1e-9 on every sample).
"""

from __future__ import annotations

import functools
import math
from typing import Any, ClassVar, Literal

import numpy as np

from .._kernels import alignment_quat as _k_alignment_quat
from .._kernels import qmul_into, quat_to_dcm, rodrigues_into, rotvec_quat, validity_flags
from .._numba import njit
from ..config import FilterConfig, param
from ..conventions import change_frame
from ..detectors.magnetic import (MAG_DISTURBED, MAG_SIZE, MAG_SOFT, MagneticConfig, MagneticDetector,
                                  field_norm_dip, magnetic_step)
from ..errors import ConfigError, PluginError
from ..navigation.alignment import alignment_quat
from ..rotations import quat_to_matrix, wrap_angle as _wrap
from ..types import Flag, sample_validity
from ._step_filter import StepFilter

__all__ = ["EkfFilter", "EkfConfig"]

# state: q (4), bias (3), P (36, row-major), started, low-passed squared dynamic acceleration, the magnetic
# detector's state
_Q, _B, _P, _START, _DYN, _MAG = 0, 4, 7, 43, 44, 45
_SIZE = _MAG + MAG_SIZE
_UP = np.array([0.0, 0.0, 1.0])
_kwrap = njit(_wrap)


class EkfConfig(FilterConfig):
    gyr_noise: float = param(
        0.01, unit="rad/s/sqrt(Hz)", description="gyroscope white noise density (also covers scale errors)", gt=0)
    bias_walk: float = param(1e-4, unit="rad/s/sqrt(s)", description="gyro bias random walk", gt=0)
    acc_noise: float = param(
        0.1, unit="m/s^2/sqrt(Hz)", description="accelerometer noise density, including unmodelled linear acceleration",
        gt=0)
    acc_dynamic: float = param(
        0.2, unit="sqrt(s)", description="adds this x the dynamic acceleration (RMS, see dynamic) to the accelerometer "
        "noise density (about the square root of the accelerations' correlation time)", ge=0)
    dynamic: Literal["deviation", "norm"] = param(
        "deviation", unit="-", description="dynamic acceleration measured as |a - g v| (the deviation of the specific "
        "force from the predicted gravity: sees horizontal accelerations) or | |a| - g | (the norm only)")
    dynamic_tau: float = param(
        1.0, unit="s", description="the dynamic acceleration is the RMS over about this long (a low-pass of its square); "
        "0: the sample's own value", ge=0)
    mag_noise: float = param(
        0.15, unit="rad/sqrt(Hz)", description="noise density of the magnetometer heading (disturbances included)", gt=0)
    use_mag: bool = param(True, unit="-", description="use the magnetometer when the recording has one (9D)")
    heading_jacobian: Literal["full", "vertical"] = param(
        "full", unit="-", description="'full': the azimuth's exact Jacobian (tilt errors move the tilt-compensated "
        "heading by up to tan(dip) x tilt); 'vertical': heading only (the magnetometer reaches tilt only through the "
        "covariance, but the filter is inconsistent by the tilt terms it leaves out)")
    mag_rejection: bool = param(
        True, unit="-", description="skip the heading update on magnetically disturbed samples (the magnetic detector)")
    magnetic: MagneticConfig = param(MagneticConfig(), unit="-", description="the magnetic disturbance detector")
    gate: float | None = param(
        None, unit="-", description="reject a measurement whose NIS exceeds this (chi-square); None: off", gt=0)
    gravity: float = param(9.81, unit="m/s^2", description="g", gt=0)
    initial_tilt_std: float = param(0.05, unit="rad", description="initial roll/pitch std", gt=0)
    initial_heading_std: float = param(0.3, unit="rad", description="initial heading std", gt=0)
    initial_bias_std: float = param(0.01, unit="rad/s", description="initial gyro bias std", gt=0)


class EkfFilter(StepFilter):
    """Error-state EKF (orientation and gyro bias) on filterpy's ExtendedKalmanFilter."""

    name: ClassVar[str] = "ekf"
    Config = EkfConfig
    source: ClassVar[str] = "baseline (filterpy ExtendedKalmanFilter)"
    summary: ClassVar[str] = "error-state EKF: gyro propagation, accelerometer gravity and magnetometer heading updates"
    state_size: ClassVar[int] = _SIZE

    def __init__(self, config=None, **params: Any) -> None:
        super().__init__(config, **params)
        self.magnetic = MagneticDetector(self.config.magnetic)
        self._t4, self._u4, self._r9 = np.empty(4), np.empty(4), np.empty(9)  # per-sample buffers
        self.nis: list[tuple[float, float]] | None = None  # (acc NIS, heading NIS) per sample when recording

    @functools.cached_property
    def kf(self):
        """filterpy's ``ExtendedKalmanFilter`` of the reference path, made on its first use:
        importing filterpy imports scipy.stats, seconds that the compiled path does not need."""
        from filterpy.kalman import ExtendedKalmanFilter

        return ExtendedKalmanFilter(dim_x=6, dim_z=3)

    def new_state(self) -> np.ndarray:
        x = np.zeros(_SIZE)
        x[_Q] = 1.0
        return x

    def _diagnostics(self, x) -> dict:
        out = {"bias": x[_B:_B + 3].copy(), "P": x[_P:_P + 36].reshape(6, 6).copy()}
        if self.nis is not None:
            out["nis"] = np.array(self.nis)
            out["states"] = np.array(self._states).reshape(-1, _SIZE)
        return out

    def _kernel(self):
        return _ekf_loop

    def params(self) -> np.ndarray:
        """The compiled loop's parameter vector."""
        c = self.config
        return np.array([
            c.gyr_noise, c.bias_walk, c.acc_noise, c.acc_dynamic, float(c.dynamic == "deviation"), c.dynamic_tau,
            c.mag_noise, float(c.heading_jacobian == "full"), float(c.mag_rejection),
            c.gate if c.gate is not None else math.inf, c.gravity, c.initial_tilt_std, c.initial_heading_std,
            c.initial_bias_std, c.gyr_range if c.gyr_range is not None else math.inf,
            c.acc_range if c.acc_range is not None else math.inf, *self.magnetic.params(),
            *change_frame(np.array([1.0, 0.0, 0.0, 0.0]), "NUE", "ENU"), c.magnetic.max_rejection or 0.0,
            float(c.magnetic.start_evidence), float(c.magnetic.max_rejection_mode == "soft"),
        ])

    def run(self, rec, *, backend: str = "auto", progress: bool | None = None, state=None, record: bool = False):
        """As :meth:`StepFilter.run`; ``record=True`` adds ``diagnostics["nis"]``, an (N, 2) array
        of each sample's accelerometer and heading NIS (NaN where that update did not run), and
        ``diagnostics["states"]``, the state array after each sample (quaternion, bias, P: for
        NEES): the filterpy path records them, so it runs then."""
        if record:
            if backend == "numba":
                raise ConfigError("ekf: record=True runs the filterpy path; use backend='auto' or 'reference'")
            backend = "reference"
        self.nis = [] if record else None
        self._states: list[np.ndarray] = []
        try:
            return super().run(rec, backend=backend, progress=progress, state=state)
        finally:
            self.nis = None

    def _check(self, where: str) -> None:
        kf = self.kf
        if kf.x.shape != (6, 1) or kf.P.shape != (6, 6):
            raise PluginError(f"filterpy's arrays lost their shapes after {where}: x {kf.x.shape} (expected (6, 1)), "
                             f"P {kf.P.shape} (expected (6, 6))")

    def _start(self, x, acc, mag) -> None:
        c = self.config
        x[_Q:_Q + 4] = alignment_quat(acc, mag, frame="ENU")
        x[_B:_B + 3] = 0.0
        x[_P:_P + 36] = np.diag([0.0] * 3 + [c.initial_bias_std ** 2] * 3).reshape(36)
        self._relevel(x)
        x[_START] = 1.0

    def _relevel(self, x) -> None:
        """The attitude covariance of the start (after a timestamp gap or a saturated gyro, too:
        the attitude error is as unknown as at the start, and the next measurements re-level at
        the start's speed). The tilt/heading stds are given about the earth axes; P is in the
        body frame."""
        c = self.config
        p = x[_P:_P + 36].reshape(6, 6)
        r = quat_to_matrix(x[_Q:_Q + 4])
        p[:3, :] = p[:, :3] = 0.0
        p[:3, :3] = r.T @ np.diag([c.initial_tilt_std ** 2] * 2 + [c.initial_heading_std ** 2]) @ r

    def _turn(self, q, r0, r1, r2) -> None:
        """``q <- normalise(q (x) exp(r))`` in place (scalar kernels: this runs per sample)."""
        t, u = self._t4, self._u4
        rotvec_quat(r0, r1, r2, t)
        qmul_into(q[0], q[1], q[2], q[3], t[0], t[1], t[2], t[3], u)
        q[:] = u / math.sqrt(u @ u)

    def _step(self, x, gyr, acc, mag, dt):
        c = self.config
        gyr_ok, acc_ok, mag_ok, flags = sample_validity(gyr, acc, mag, c.gyr_range, c.acc_range)
        nis = [math.nan, math.nan]
        if not x[_START]:
            if acc_ok:
                self._start(x, acc, mag if mag_ok else None)
            elif gyr_ok:  # no accelerometer yet: the gyro still turns the output (from identity)
                self._turn(x[_Q:_Q + 4], gyr[0] * dt, gyr[1] * dt, gyr[2] * dt)
            if self.nis is not None:
                self.nis.append(tuple(nis))
                self._states.append(x.copy())
            return self._output(x), flags
        kf = self.kf
        kf.x = np.zeros((6, 1))
        kf.P = x[_P:_P + 36].reshape(6, 6).copy()
        q, b = x[_Q:_Q + 4], x[_B:_B + 3]

        # 1. propagation: F = [[exp(-[w dt x]), -I dt], [0, I]], Q from the noise densities
        if gyr_ok:
            r0, r1, r2 = (gyr[0] - b[0]) * dt, (gyr[1] - b[1]) * dt, (gyr[2] - b[2]) * dt
            f = np.eye(6)
            rodrigues_into(-r0, -r1, -r2, self._r9)
            f[:3, :3] = self._r9.reshape(3, 3)
            f[0, 3] = f[1, 4] = f[2, 5] = -dt
            kf.F = f
            qd = np.zeros((6, 6))
            qd[0, 0] = qd[1, 1] = qd[2, 2] = c.gyr_noise ** 2 * dt
            qd[3, 3] = qd[4, 4] = qd[5, 5] = c.bias_walk ** 2 * dt
            kf.Q = qd
            kf.predict()
            self._check("predict")
            self._turn(q, r0, r1, r2)

        # 2. and 3. measurements, stacked into one update
        quat_to_dcm(q, self._r9)
        r = self._r9.reshape(3, 3)
        zs, hs, hjs, rs = [], [], [], []
        if acc_ok:
            na = math.sqrt(acc @ acc)
            v = r[2].copy()  # R^T up: the earth's vertical in the body
            if c.dynamic == "deviation":
                dyn = math.sqrt((acc[0] - c.gravity * v[0]) ** 2 + (acc[1] - c.gravity * v[1]) ** 2
                                + (acc[2] - c.gravity * v[2]) ** 2)
            else:
                dyn = abs(na - c.gravity)
            if c.dynamic_tau > 0:  # RMS over the last dynamic_tau s: every sample of a motion weighs the same
                x[_DYN] += (1.0 - math.exp(-dt / c.dynamic_tau)) * (dyn * dyn - x[_DYN])
                dyn = math.sqrt(x[_DYN])
            sigma = (c.acc_noise + c.acc_dynamic * dyn) / (c.gravity * math.sqrt(dt))  # per sample, unit-free
            hj = np.zeros((3, 6))  # [v x]
            hj[0, 1], hj[0, 2], hj[1, 0], hj[1, 2], hj[2, 0], hj[2, 1] = -v[2], v[1], v[2], -v[0], -v[1], v[0]
            if self._accept(acc / na - v, hj, sigma ** 2, 0, nis):
                zs.append(acc / na)
                hs.append(v)
                hjs.append(hj)
                rs += [sigma ** 2] * 3
            else:
                flags |= Flag.ACC_REJECTED
        if mag_ok:
            m_e = r @ mag
            norm, dip = field_norm_dip(m_e, _UP)
            rate = math.sqrt(gyr @ gyr) if gyr_ok else 0.0
            mag_ok = not (self.magnetic.reference_step(x[_MAG:_MAG + MAG_SIZE], norm, dip, rate, dt) in (
                MAG_DISTURBED, MAG_SOFT) and c.mag_rejection)  # (soft: kept out here too)
            if not mag_ok:
                flags |= Flag.MAG_DISTURBED
            elif m_e[0] ** 2 + m_e[1] ** 2 < 1e-12 * norm ** 2:  # a vertical field: no heading in it
                mag_ok = False
        if mag_ok:
            psi = math.atan2(-m_e[0], m_e[1])
            hj = np.zeros((1, 6))
            if c.heading_jacobian == "full":
                # psi(m_e), m_e = R exp([dtheta x]) m = m_e - R [m x] dtheta
                dpsi = np.array([-m_e[1], m_e[0], 0.0]) / (m_e[0] ** 2 + m_e[1] ** 2)
                hj[0, :3] = -(dpsi @ r) @ np.array([[0.0, -mag[2], mag[1]], [mag[2], 0.0, -mag[0]],
                                                     [-mag[1], mag[0], 0.0]])
            else:
                hj[0, :3] = r[2]  # d psi / d dtheta: the vertical component of the earth-frame rotation
            r_mag = c.mag_noise ** 2 / dt
            if self._accept(np.array([_wrap(-psi)]), hj, r_mag, 1, nis):
                zs.append(np.zeros(1))
                hs.append(np.array([psi]))
                hjs.append(hj)
                rs.append(r_mag)
            else:
                flags |= Flag.MAG_DISTURBED
        if zs:
            z = np.concatenate(zs).reshape(-1, 1)
            hx = np.concatenate(hs).reshape(-1, 1)
            hj = np.vstack(hjs)
            wrap_last = mag_ok and not (flags & Flag.MAG_DISTURBED)  # the heading row is last

            def residual(a, bb):
                y = a - bb
                if wrap_last:
                    y[-1, 0] = _wrap(y[-1, 0])
                return y

            kf.update(z, lambda _x: hj, lambda _x: hx, R=np.diag(rs), residual=residual)
            self._check("update")
            dx = kf.x[:, 0]
            self._turn(q, dx[0], dx[1], dx[2])
            b += dx[3:]
        p = kf.P
        x[_P:_P + 36] = (0.5 * (p + p.T)).reshape(36)
        if self.nis is not None:
            self.nis.append(tuple(nis))
            self._states.append(x.copy())
        return self._output(x), flags

    def _accept(self, y, hj, r_var, slot, nis) -> bool:
        """NIS of one measurement (recorded in ``nis[slot]``); False when ``gate`` rejects it."""
        if self.config.gate is None and self.nis is None:
            return True
        p = self.kf.P
        s = hj @ p @ hj.T + r_var * np.eye(len(y))
        val = float(y @ np.linalg.solve(s, y))
        nis[slot] = val
        return self.config.gate is None or val <= self.config.gate

    def _output(self, x) -> np.ndarray:
        out, f, q = np.empty(4), self.qf, x[_Q:_Q + 4]
        qmul_into(f[0], f[1], f[2], f[3], q[0], q[1], q[2], q[3], out)
        return out


# ---- the compiled loop: EkfFilter._step's arithmetic, filterpy's predict and update spelt out ----
#
# filterpy's ExtendedKalmanFilter computes predict as P = F P F^T + Q and update as
# S = H P H^T + R, K = P H^T S^-1, x = K y, P = (I - K H) P (I - K H)^T + K R K^T (x is zero before
# each update: the error state). The loop below does exactly these products on fixed-size arrays;
# the tests hold it to the filterpy path to 1e-9 on every sample.

@njit
def _mm(a, b, out, n, m, l, b_t):
    """``out[:n, :l] = a[:n, :m] @ b[:m, :l]`` (``b_t``: ``@ b[:l, :m].T``)."""
    for i in range(n):
        for j in range(l):
            s = 0.0
            for k in range(m):
                s += a[i, k] * (b[j, k] if b_t else b[k, j])
            out[i, j] = s


@njit
def _inv(a, n, out):
    """``out[:n, :n] = a[:n, :n]^-1`` by Gauss-Jordan elimination with partial pivoting (``a`` is
    not changed). The innovation covariances here are at most 4 x 4; numba's ``np.linalg`` (its
    LAPACK wrappers and their error paths) took longer to compile than the rest of the filter."""
    w = np.empty((n, 2 * n))
    for i in range(n):
        for j in range(n):
            w[i, j] = a[i, j]
            w[i, n + j] = 1.0 if i == j else 0.0
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(w[r, c]) > abs(w[piv, c]):
                piv = r
        if piv != c:
            for j in range(2 * n):
                w[c, j], w[piv, j] = w[piv, j], w[c, j]
        d = w[c, c]
        for j in range(2 * n):
            w[c, j] /= d
        for r in range(n):
            if r != c:
                f = w[r, c]
                for j in range(2 * n):
                    w[r, j] -= f * w[c, j]
    for i in range(n):
        for j in range(n):
            out[i, j] = w[i, n + j]


@njit
def _nis(P, hj, rows, y, r_var, pht, s, si):
    """``y^T (H P H^T + r_var I)^-1 y`` of ``rows`` measurement rows (EkfFilter._accept)."""
    _mm(P, hj, pht, 6, 6, rows, True)
    _mm(hj, pht, s, rows, 6, rows, False)
    for i in range(rows):
        s[i, i] += r_var
    _inv(s, rows, si)
    v = 0.0
    for i in range(rows):
        for j in range(rows):
            v += y[i] * si[i, j] * y[j]
    return v


@njit
def _ekf_loop(gyr, acc, mag, dt, has_mag, x, p, qf, out_q, out_f):
    gyr_noise, bias_walk, acc_noise, acc_dynamic, deviation, dyn_tau = p[0], p[1], p[2], p[3], p[4] != 0.0, p[5]
    mag_noise, full_jac, mag_rej, gate, grav = p[6], p[7] != 0.0, p[8] != 0.0, p[9], p[10]
    tilt_std, heading_std, bias_std, gyr_range, acc_range = p[11], p[12], p[13], p[14], p[15]
    m_init, m_nth, m_dth, m_new_t, m_new_rate, m_ref_tau = p[16], p[17], p[18], p[19], p[20], p[21]
    q_nue = p[22:26]
    q = x[_Q:_Q + 4]
    ms = x[_MAG:_MAG + MAG_SIZE]
    P = np.empty((6, 6))
    F = np.empty((6, 6))
    T = np.empty((6, 6))
    H = np.zeros((4, 6))
    K = np.empty((6, 4))
    pht = np.empty((6, 4))
    S = np.empty((4, 4))
    si = np.empty((4, 4))
    y = np.empty(4)
    rr = np.empty(4)
    hj1 = np.zeros((3, 6))  # the accelerometer's rows, [v x] 0
    hm = np.zeros((1, 6))  # the heading's row
    r9 = np.empty(9)
    t4 = np.empty(4)
    u4 = np.empty(4)
    for k in range(gyr.shape[0]):
        h = dt[k]
        g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]
        a0, a1, a2 = acc[k, 0], acc[k, 1], acc[k, 2]
        m0, m1, m2 = mag[k, 0], mag[k, 1], mag[k, 2]
        gyr_ok, acc_ok, mag_ok, flags = validity_flags(g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, gyr_range,
                                                        acc_range)
        if x[_START] == 0.0:
            if acc_ok:  # EkfFilter._start
                _k_alignment_quat(a0, a1, a2, m0, m1, m2, mag_ok, q_nue, q)
                x[_B] = x[_B + 1] = x[_B + 2] = 0.0
                for i in range(36):
                    x[_P + i] = 0.0
                d = (tilt_std ** 2, tilt_std ** 2, heading_std ** 2)
                quat_to_dcm(q, r9)
                for i in range(3):  # r^T diag(d) r
                    for j in range(3):
                        x[_P + 6 * i + j] = (r9[i] * d[0] * r9[j] + r9[3 + i] * d[1] * r9[3 + j]
                                             + r9[6 + i] * d[2] * r9[6 + j])
                    x[_P + 7 * (3 + i)] = bias_std ** 2
                x[_START] = 1.0
            qmul_into(qf[0], qf[1], qf[2], qf[3], q[0], q[1], q[2], q[3], u4)
            out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = u4[0], u4[1], u4[2], u4[3]
            out_f[k] = flags
            continue
        for i in range(6):
            for j in range(6):
                P[i, j] = x[_P + 6 * i + j]
        # 1. propagation: P = F P F^T + Q
        if gyr_ok:
            r0, r1, r2 = (g0 - x[_B]) * h, (g1 - x[_B + 1]) * h, (g2 - x[_B + 2]) * h
            rodrigues_into(-r0, -r1, -r2, r9)
            for i in range(6):
                for j in range(6):
                    F[i, j] = 1.0 if i == j else 0.0
            for i in range(3):
                for j in range(3):
                    F[i, j] = r9[3 * i + j]
                F[i, 3 + i] = -h
            _mm(F, P, T, 6, 6, 6, False)
            _mm(T, F, P, 6, 6, 6, True)
            for i in range(3):
                P[i, i] += gyr_noise ** 2 * h
                P[3 + i, 3 + i] += bias_walk ** 2 * h
            rotvec_quat(r0, r1, r2, t4)  # EkfFilter._turn
            qmul_into(q[0], q[1], q[2], q[3], t4[0], t4[1], t4[2], t4[3], u4)
            n = math.sqrt(u4[0] * u4[0] + u4[1] * u4[1] + u4[2] * u4[2] + u4[3] * u4[3])
            for i in range(4):
                q[i] = u4[i] / n
        # 2. and 3. the measurements, stacked
        quat_to_dcm(q, r9)
        rows = 0
        heading_row = False
        na = v0 = v1 = v2 = psi = 0.0
        if acc_ok:
            na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            v0, v1, v2 = r9[6], r9[7], r9[8]
            if deviation:
                dyn = math.sqrt((a0 - grav * v0) ** 2 + (a1 - grav * v1) ** 2 + (a2 - grav * v2) ** 2)
            else:
                dyn = abs(na - grav)
            if dyn_tau > 0:
                x[_DYN] += (1.0 - math.exp(-h / dyn_tau)) * (dyn * dyn - x[_DYN])
                dyn = math.sqrt(x[_DYN])
            sigma = (acc_noise + acc_dynamic * dyn) / (grav * math.sqrt(h))
            hj1[0, 1], hj1[0, 2], hj1[1, 0], hj1[1, 2], hj1[2, 0], hj1[2, 1] = -v2, v1, v2, -v0, -v1, v0
            y[0], y[1], y[2] = a0 / na - v0, a1 / na - v1, a2 / na - v2
            # the row count as a run-time number (a literal 3 or 1 would compile _nis and _mm once each)
            if gate == math.inf or _nis(P, hj1, hj1.shape[0], y, sigma ** 2, pht, S, si) <= gate:
                for i in range(3):
                    for j in range(6):
                        H[i, j] = hj1[i, j]
                    rr[i] = sigma ** 2
                rows = 3
            else:
                flags |= 512  # ACC_REJECTED
        if mag_ok:
            e0 = r9[0] * m0 + r9[1] * m1 + r9[2] * m2
            e1 = r9[3] * m0 + r9[4] * m1 + r9[5] * m2
            e2 = r9[6] * m0 + r9[7] * m1 + r9[8] * m2
            norm = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            dip = math.asin(max(-1.0, min(1.0, e2 / norm)))
            rate = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2) if gyr_ok else 0.0
            code = magnetic_step(ms, norm, dip, rate, h, m_init, m_nth, m_dth, m_new_t, m_new_rate, m_ref_tau,
                                 p[26], p[27], p[28])
            if (code == MAG_DISTURBED or code == MAG_SOFT) and mag_rej:
                flags |= 256
                mag_ok = False
            elif e0 * e0 + e1 * e1 < 1e-12 * norm * norm:
                mag_ok = False
        if mag_ok:
            psi = math.atan2(-e0, e1)
            if full_jac:
                hh = e0 * e0 + e1 * e1
                d0, d1 = -e1 / hh, e0 / hh
                c0 = d0 * r9[0] + d1 * r9[3]  # dpsi @ r
                c1 = d0 * r9[1] + d1 * r9[4]
                c2 = d0 * r9[2] + d1 * r9[5]
                # -(c @ [m x]), [m x] = [[0, -m2, m1], [m2, 0, -m0], [-m1, m0, 0]]
                hm[0, 0], hm[0, 1], hm[0, 2] = -(c1 * m2 - c2 * m1), -(-c0 * m2 + c2 * m0), -(c0 * m1 - c1 * m0)
            else:
                hm[0, 0], hm[0, 1], hm[0, 2] = r9[6], r9[7], r9[8]
            r_mag = mag_noise ** 2 / h
            y[0] = _kwrap(-psi)
            if gate == math.inf or _nis(P, hm, hm.shape[0], y, r_mag, pht, S, si) <= gate:
                for j in range(6):
                    H[rows, j] = hm[0, j]
                rr[rows] = r_mag
                rows += 1
                heading_row = True
            else:
                flags |= 256
        if acc_ok and rows >= 3:  # the residuals (y was overwritten by the gate tests)
            y[0], y[1], y[2] = a0 / na - v0, a1 / na - v1, a2 / na - v2
        if heading_row:
            y[rows - 1] = _kwrap(0.0 - psi)
        if rows > 0:  # filterpy's update, x = 0 before it
            _mm(P, H, pht, 6, 6, rows, True)
            _mm(H, pht, S, rows, 6, rows, False)
            for i in range(rows):
                S[i, i] += rr[i]
            _inv(S, rows, si)
            _mm(pht, si, K, 6, rows, rows, False)
            dx = np.zeros(6)
            for i in range(6):
                for j in range(rows):
                    dx[i] += K[i, j] * y[j]
            _mm(K, H, T, 6, rows, 6, False)
            for i in range(6):
                for j in range(6):
                    F[i, j] = (1.0 if i == j else 0.0) - T[i, j]  # I - K H
            _mm(F, P, T, 6, 6, 6, False)
            _mm(T, F, P, 6, 6, 6, True)
            for i in range(6):  # + K R K^T
                for j in range(6):
                    s = 0.0
                    for l in range(rows):
                        s += K[i, l] * rr[l] * K[j, l]
                    P[i, j] += s
            rotvec_quat(dx[0], dx[1], dx[2], t4)
            qmul_into(q[0], q[1], q[2], q[3], t4[0], t4[1], t4[2], t4[3], u4)
            n = math.sqrt(u4[0] * u4[0] + u4[1] * u4[1] + u4[2] * u4[2] + u4[3] * u4[3])
            for i in range(4):
                q[i] = u4[i] / n
            for i in range(3):
                x[_B + i] += dx[3 + i]
        for i in range(6):
            for j in range(6):
                x[_P + 6 * i + j] = 0.5 * (P[i, j] + P[j, i])
        qmul_into(qf[0], qf[1], qf[2], qf[3], q[0], q[1], q[2], q[3], u4)
        out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = u4[0], u4[1], u4[2], u4[3]
        out_f[k] = flags
