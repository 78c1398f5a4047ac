"""Source 002: a strapdown DCM corrected by the accelerometer and the magnetometer in separate
channels, so that a magnetic disturbance cannot reach roll and pitch.

The state is ``D = C_{n->b}``: its columns are the earth's axes seen in the body (ENU: ``d1``
east, ``d2`` north, ``d3`` up). Poisson: ``dD/dt = -[w x] D``, integrated exactly per sample
(``D <- exp(-[w dt x]) D``, the Rodrigues formula of source 004); each column propagates on its
own. The accelerometer measures ``d3`` (``a / |a|`` at rest), the magnetometer the field
``T = H d2 + Z d3`` (north and vertical components, ``H, Z`` learned from the first sample).

``method``:

- ``"columns"`` (the paper's method 1, DCM only): the accelerometer corrects the third column
  only, ``d3 += k_acc dt (a/|a| - d3)``; the magnetometer the second only, towards the field's
  part perpendicular to ``d3``, ``d2 += k_mag dt (m_h - d2)``; then ``d3`` is normalised, ``d2``
  made perpendicular to it and normalised, and ``d1 = d2 x d3`` (orthogonality).
- ``"vectors"`` (method 2, also for quaternions): mutually perpendicular references, the
  vertical (gravity) and the horizontal part of the field. The accelerometer turns ``D`` by
  ``k_acc dt (d3 x a/|a|)``; then the magnetometer by ``k_mag dt (d2 x m_h)``, which is
  parallel to ``d3``: a turn about the vertical, heading only.
- ``"unseparated"`` (the document's full-vector correction, for comparison): the error of the
  whole field ``dT = m/|m| - (H d2 + Z d3)`` corrects the second AND third columns with the
  same gain, ``d2 += k_mag dt H dT``, ``d3 += k_mag dt Z dT``: magnetic disturbances tilt.

With separation, any magnetometer input leaves ``d3`` (roll and pitch) exactly as a
magnetometer-free run (tested to 1e-12 on a constant offset, a rotating field and spikes).
The paper estimates no gyro bias; ``initial_rest`` (an extension; 0 = off, the paper) averages
the gyro over the first seconds of a recording that starts at rest and removes it (a sample
above ``rest_rate`` ends that early; the attitude is held meanwhile, flag ALIGNING). On BROAD
it is what brings the 9D error from 7.2 to 4.3 deg (BENCHMARKS.md).
The start attitude comes from the first valid sample (TRIAD: ``d3`` from the accelerometer,
``d2`` from the field; without a field, or with one along the vertical, heading zero: body y
north, or body x when y is near vertical).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._kernels import dcm_to_quat, matmul3_into, qmul_into, rodrigues_into, validity_flags
from .._numba import njit
from ..config import FilterConfig, param
from ..rotations import matrix_to_quat, quat_mul, rodrigues
from ..types import Flag, sample_validity
from ._step_filter import StepFilter

__all__ = ["ChannelDcmFilter", "ChannelDcmConfig"]

METHODS = ("columns", "vectors", "unseparated")
# state: D (9, row-major), started, field H and Z known, H, Z, bias (3), rest samples, rest seconds
_D, _START, _HZ, _H, _Z, _BIAS, _NB, _TB, _SIZE = 0, 9, 10, 11, 12, 13, 16, 17, 18


class ChannelDcmConfig(FilterConfig):
    method: Literal["columns", "vectors", "unseparated"] = param(
        "columns", unit="-", description="'columns' (method 1), 'vectors' (method 2) or 'unseparated' (full field)")
    k_acc: float = param(0.3, unit="1/s", description="accelerometer correction gain (fraction per second)", gt=0)
    k_mag: float = param(0.03, unit="1/s", description="magnetometer correction gain (fraction per second)", gt=0)
    use_mag: bool = param(True, unit="-", description="use the magnetometer when the recording has one (9D)")
    initial_rest: float = param(
        3.0, unit="s", description="extension: average the gyro over this first stretch (at rest) as its bias; "
        "0: off (the paper)", ge=0)
    rest_rate: float = param(
        math.radians(5.0), unit="rad/s", description="a gyro sample above this ends the initial rest early "
        "(the recording did not start at rest)", gt=0)


class ChannelDcmFilter(StepFilter):
    """Source 002: DCM with channel-separated accelerometer and magnetometer corrections."""

    name: ClassVar[str] = "channel-dcm"
    Config = ChannelDcmConfig
    source: ClassVar[str] = "002 (separating the correction channels of a strapdown AHRS)"
    summary: ClassVar[str] = "DCM: accelerometer corrects the vertical column, magnetometer the north column only"
    state_size: ClassVar[int] = _SIZE

    def new_state(self) -> np.ndarray:
        x = np.zeros(_SIZE)
        x[_D:_D + 9] = np.eye(3).reshape(9)
        return x

    def _kernel(self):
        return _dcm_loop

    def _diagnostics(self, x) -> dict:
        return {"bias": x[_BIAS:_BIAS + 3].copy()}

    def params(self) -> np.ndarray:
        c = self.config
        return np.array([float(METHODS.index(c.method)), c.k_acc, c.k_mag, c.initial_rest, c.rest_rate,
                         c.gyr_range if c.gyr_range is not None else math.inf,
                         c.acc_range if c.acc_range is not None else math.inf])

    # -- the readable reference --------------------------------------------------------------
    def _step(self, x, gyr, acc, mag, dt) -> tuple[np.ndarray, int]:
        c = self.config
        gyr_ok, acc_ok, mag_ok, flags = sample_validity(gyr, acc, mag if c.use_mag else None, c.gyr_range,
                                                        c.acc_range)
        d = x[_D:_D + 9].reshape(3, 3)  # a view: columns are the earth axes in the body
        if not x[_START]:
            if acc_ok:  # TRIAD from the first valid sample
                d3 = acc / np.linalg.norm(acc)
                ref = mag / np.linalg.norm(mag) if mag_ok else np.zeros(3)
                d2 = ref - (ref @ d3) * d3
                if np.linalg.norm(d2) < 1e-6:  # no field, or one along the vertical: heading zero,
                    ref = np.array([0.0, 1.0, 0.0] if abs(d3[1]) < 0.9 else [1.0, 0.0, 0.0])  # body y (x) north
                    d2 = ref - (ref @ d3) * d3
                d[:, 2], d[:, 1] = d3, d2 / np.linalg.norm(d2)
                d[:, 0] = np.cross(d[:, 1], d[:, 2])
                x[_START] = 1.0
            elif gyr_ok:  # no accelerometer yet: the gyro still turns the output (from identity)
                d[:] = rodrigues(-gyr * dt) @ d
            return self._output(d), flags
        # extension: bias from the initial rest (half a sample of margin: the sample count must not
        # hinge on the last bit of a sum of dt's)
        if c.initial_rest > 0 and gyr_ok and x[_TB] + 0.5 * dt < c.initial_rest:
            if np.linalg.norm(gyr) > c.rest_rate:
                x[_TB] = c.initial_rest  # moving: the rest is over
                return self._step(x, gyr, acc, mag, dt)
            x[_NB] += 1.0
            x[_TB] += dt
            x[_BIAS:_BIAS + 3] += (gyr - x[_BIAS:_BIAS + 3]) / x[_NB]
            return self._output(d), flags | Flag.ALIGNING
        if gyr_ok:  # Poisson, exactly: D <- exp(-[w dt x]) D
            d[:] = rodrigues(-(gyr - x[_BIAS:_BIAS + 3]) * dt) @ d
        method = c.method
        if acc_ok:
            a = acc / np.linalg.norm(acc)
            if method == "vectors":
                d[:] = rodrigues(c.k_acc * dt * np.cross(d[:, 2], a)) @ d
            else:
                d[:, 2] += c.k_acc * dt * (a - d[:, 2])
                d[:, 2] /= np.linalg.norm(d[:, 2])
        if mag_ok:
            m = mag / np.linalg.norm(mag)
            if not x[_HZ]:  # the field's vertical and north parts, from the first sample
                x[_Z] = m @ d[:, 2]
                x[_H] = math.sqrt(max(0.0, 1.0 - x[_Z] ** 2))
                x[_HZ] = 1.0
            mh = m - (m @ d[:, 2]) * d[:, 2]
            nh = np.linalg.norm(mh)
            mh = mh / nh if nh > 1e-6 else None  # a field along the vertical: no heading in it
            if mh is None:
                pass
            elif method == "vectors":
                d[:] = rodrigues(c.k_mag * dt * np.cross(d[:, 1], mh)) @ d
            elif method == "columns":
                d[:, 1] += c.k_mag * dt * (mh - d[:, 1])
            else:
                dt_field = m - (x[_H] * d[:, 1] + x[_Z] * d[:, 2])
                d[:, 1] += c.k_mag * dt * x[_H] * dt_field
                d[:, 2] += c.k_mag * dt * x[_Z] * dt_field
        # orthonormalise around the vertical column
        d[:, 2] /= np.linalg.norm(d[:, 2])
        d[:, 1] -= (d[:, 1] @ d[:, 2]) * d[:, 2]
        d[:, 1] /= np.linalg.norm(d[:, 1])
        d[:, 0] = np.cross(d[:, 1], d[:, 2])
        return self._output(d), flags

    def _output(self, d) -> np.ndarray:
        return quat_mul(self.qf, matrix_to_quat(d.T))  # D^T: body -> ENU


# ---- the compiled loop (ChannelDcmFilter._step with scalars) ----------------------------------

@njit
def _col_normalize(d, j):
    n = math.sqrt(d[j] ** 2 + d[3 + j] ** 2 + d[6 + j] ** 2)
    d[j] /= n
    d[3 + j] /= n
    d[6 + j] /= n


@njit
def _rotate(d, r0, r1, r2, rm, tmp):
    """``D <- exp([r x]) D``."""
    rodrigues_into(r0, r1, r2, rm)
    matmul3_into(rm, d, tmp)
    for i in range(9):
        d[i] = tmp[i]


@njit
def _dcm_loop(gyr, acc, mag, dt, has_mag, x, p, qf, out_q, out_f):
    method, k_acc, k_mag, initial_rest, rest_rate = int(p[0]), p[1], p[2], p[3], p[4]
    gyr_range, acc_range = p[5], p[6]
    d = x[_D:_D + 9]
    rm = np.empty(9)
    tmp = np.empty(9)
    ct = np.empty(9)
    q = np.empty(4)
    for k in range(gyr.shape[0]):
        h = dt[k]
        g0, g1, g2 = gyr[k, 0], gyr[k, 1], gyr[k, 2]
        a0, a1, a2 = acc[k, 0], acc[k, 1], acc[k, 2]
        m0, m1, m2 = mag[k, 0], mag[k, 1], mag[k, 2]
        gyr_ok, acc_ok, mag_ok, flags = validity_flags(g0, g1, g2, a0, a1, a2, m0, m1, m2, has_mag, gyr_range,
                                                                acc_range)
        run = True
        if x[_START] == 0.0:
            run = False
            if acc_ok:
                na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
                u0, u1, u2 = a0 / na, a1 / na, a2 / na
                r0 = r1 = r2 = 0.0
                if mag_ok:
                    nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
                    r0, r1, r2 = m0 / nm, m1 / nm, m2 / nm
                dp = r0 * u0 + r1 * u1 + r2 * u2
                v0, v1, v2 = r0 - dp * u0, r1 - dp * u1, r2 - dp * u2
                nv = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                if nv < 1e-6:  # no field, or one along the vertical: body y north (body x if y is vertical)
                    r0, r1, r2 = (0.0, 1.0, 0.0) if abs(u1) < 0.9 else (1.0, 0.0, 0.0)
                    dp = r0 * u0 + r1 * u1 + r2 * u2
                    v0, v1, v2 = r0 - dp * u0, r1 - dp * u1, r2 - dp * u2
                    nv = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
                v0, v1, v2 = v0 / nv, v1 / nv, v2 / nv
                d[2], d[5], d[8] = u0, u1, u2
                d[1], d[4], d[7] = v0, v1, v2
                d[0], d[3], d[6] = v1 * u2 - v2 * u1, v2 * u0 - v0 * u2, v0 * u1 - v1 * u0
                x[_START] = 1.0
            elif gyr_ok:  # no accelerometer yet: the gyro still turns the output (from identity)
                _rotate(d, -g0 * h, -g1 * h, -g2 * h, rm, tmp)
        elif initial_rest > 0.0 and gyr_ok and x[_TB] + 0.5 * h < initial_rest and \
                math.sqrt(g0 * g0 + g1 * g1 + g2 * g2) > rest_rate:
            x[_TB] = initial_rest  # moving: the rest is over (and this sample is navigated)
        elif initial_rest > 0.0 and gyr_ok and x[_TB] + 0.5 * h < initial_rest:
            run = False
            x[_NB] += 1.0
            x[_TB] += h
            x[_BIAS] += (g0 - x[_BIAS]) / x[_NB]
            x[_BIAS + 1] += (g1 - x[_BIAS + 1]) / x[_NB]
            x[_BIAS + 2] += (g2 - x[_BIAS + 2]) / x[_NB]
            flags |= 1
        if run:
            if gyr_ok:
                _rotate(d, -(g0 - x[_BIAS]) * h, -(g1 - x[_BIAS + 1]) * h, -(g2 - x[_BIAS + 2]) * h, rm, tmp)
            if acc_ok:
                na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
                u0, u1, u2 = a0 / na, a1 / na, a2 / na
                if method == 1:
                    kk = k_acc * h
                    _rotate(d, kk * (d[5] * u2 - d[8] * u1), kk * (d[8] * u0 - d[2] * u2),
                            kk * (d[2] * u1 - d[5] * u0), rm, tmp)
                else:
                    d[2] += k_acc * h * (u0 - d[2])
                    d[5] += k_acc * h * (u1 - d[5])
                    d[8] += k_acc * h * (u2 - d[8])
                    _col_normalize(d, 2)
            if mag_ok:
                nm = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
                u0, u1, u2 = m0 / nm, m1 / nm, m2 / nm
                dz = u0 * d[2] + u1 * d[5] + u2 * d[8]
                if x[_HZ] == 0.0:
                    x[_Z] = dz
                    x[_H] = math.sqrt(max(0.0, 1.0 - dz * dz))
                    x[_HZ] = 1.0
                h0, h1, h2 = u0 - dz * d[2], u1 - dz * d[5], u2 - dz * d[8]
                nh = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
                if nh > 1e-6:
                    h0, h1, h2 = h0 / nh, h1 / nh, h2 / nh
                if nh <= 1e-6:  # a field along the vertical: no heading in it
                    pass
                elif method == 1:
                    kk = k_mag * h
                    _rotate(d, kk * (d[4] * h2 - d[7] * h1), kk * (d[7] * h0 - d[1] * h2),
                            kk * (d[1] * h1 - d[4] * h0), rm, tmp)
                elif method == 0:
                    d[1] += k_mag * h * (h0 - d[1])
                    d[4] += k_mag * h * (h1 - d[4])
                    d[7] += k_mag * h * (h2 - d[7])
                else:
                    e0 = u0 - (x[_H] * d[1] + x[_Z] * d[2])
                    e1 = u1 - (x[_H] * d[4] + x[_Z] * d[5])
                    e2 = u2 - (x[_H] * d[7] + x[_Z] * d[8])
                    kh, kz = k_mag * h * x[_H], k_mag * h * x[_Z]
                    d[1] += kh * e0
                    d[4] += kh * e1
                    d[7] += kh * e2
                    d[2] += kz * e0
                    d[5] += kz * e1
                    d[8] += kz * e2
            _col_normalize(d, 2)
            dp = d[1] * d[2] + d[4] * d[5] + d[7] * d[8]
            d[1] -= dp * d[2]
            d[4] -= dp * d[5]
            d[7] -= dp * d[8]
            _col_normalize(d, 1)
            d[0] = d[4] * d[8] - d[7] * d[5]
            d[3] = d[7] * d[2] - d[1] * d[8]
            d[6] = d[1] * d[5] - d[4] * d[2]
        for i in range(3):  # D^T, body -> ENU
            for j in range(3):
                ct[3 * i + j] = d[3 * j + i]
        dcm_to_quat(ct, q)
        qmul_into(qf[0], qf[1], qf[2], qf[3], q[0], q[1], q[2], q[3], tmp)
        out_q[k, 0], out_q[k, 1], out_q[k, 2], out_q[k, 3] = tmp[0], tmp[1], tmp[2], tmp[3]
        out_f[k] = flags
