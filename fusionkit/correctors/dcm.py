"""Source 002: the DCM column corrections of a strapdown AHRS, one plugin per idea.

They work on the ``poisson-dcm`` estimator's matrix itself (``state_layout = "dcm"``), in the
paper's terms: ``D = C_{n->b}`` has the earth's axes seen in the body as its columns (``d1``
east, ``d2`` north, ``d3`` up); in the estimator's body->frame matrix these are rows (signed
and permuted for NED, NWU, NUE: exact operations, so every frame runs the same arithmetic).
The accelerometer measures ``d3`` (``a/|a|`` at rest), the magnetometer the field
``T = H d2 + Z d3``. Gains are fractions per second (times ``dt``).

- ``dcm-vertical`` (accelerometer -> ``d3``). ``method="columns"`` (the paper's method 1):
  ``d3 += k_acc dt (a/|a| - d3)``, normalised; ``"vectors"`` (method 2): ``D`` turned by
  ``k_acc dt (d3 x a/|a|)``.
- ``dcm-north`` (magnetometer -> ``d2``, separated). ``m_h`` = the field's part perpendicular to
  ``d3``, normalised. ``"columns"`` (method 1): ``d2 += k_mag dt (m_h - d2)``; ``"vectors"``
  (method 2): ``D`` turned by ``k_mag dt (d2 x m_h)``, an axis parallel to ``d3``: heading only.
- ``dcm-field`` (the paper's unseparated full-field correction, for comparison): the error of
  the whole field ``dT = m/|m| - (H d2 + Z d3)`` corrects ``d2`` and ``d3`` with the same gain,
  ``d2 += k_mag dt H dT``, ``d3 += k_mag dt Z dT`` (``H, Z`` from the first magnetometer
  sample it sees, so any unit works): magnetic disturbances tilt.

Each ends with the orthonormalisation around the vertical column (``d3`` normalised, ``d2``
made perpendicular to it and normalised, ``d1 = d2 x d3``: "the first column follows"), so
nothing a magnetometer corrector does after ``dcm-vertical`` reaches ``d3``. ``dcm-vertical``'s
``orthonormalize=False`` leaves that to a magnetometer corrector that follows it, as the paper
(and the ``channel-dcm`` filter) corrects both columns before restoring orthogonality.
A sample without a valid reading skips its correction (the orthonormalisation still runs).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._kernels import rodrigues_entries
from .._numba import njit
from ..config import PluginConfig, param
from ..conventions import frame_matrix
from ..protocols import Correction, Corrector, CorrectorKernel
from ..rotations import cross, rodrigues

__all__ = ["DcmVertical", "DcmNorth", "DcmField", "frame_rows"]

# corrector state: for the ENU axes east, north, up: the estimator matrix's row and its sign
_ROWS = 0
_LAYOUT = 6
# dcm-field adds: the field's H and Z known, H, Z
_HZ, _H, _Z = 6, 7, 8
_METHODS = {"columns": 0.0, "vectors": 1.0}


def frame_rows(frame: str) -> np.ndarray:
    """``[row_e, sign_e, row_n, sign_n, row_u, sign_u]``: the ENU axis ``j`` seen in the body is
    ``sign_j * C[row_j, :]`` of a body->``frame`` matrix ``C`` (the frames differ from ENU by a
    signed permutation)."""
    m = frame_matrix("ENU", frame)  # v_frame = m v_enu: m[i, j] = +-1 where frame axis i is ENU axis j
    out = np.zeros(_LAYOUT)
    for j in range(3):
        i = int(np.flatnonzero(m[:, j])[0])
        out[2 * j], out[2 * j + 1] = i, m[i, j]
    return out


def _columns(x, s) -> np.ndarray:
    """``D`` (3 x 3, columns east, north, up seen in the body) from the estimator's state."""
    c = x.reshape(3, 3)
    return np.stack([s[2 * j + 1] * c[int(s[2 * j])] for j in range(3)], axis=1)


def _store(x, s, d) -> None:
    c = x.reshape(3, 3)  # a view of the state
    for j in range(3):
        c[int(s[2 * j])] = s[2 * j + 1] * d[:, j]


def _orthonormalize(d) -> None:
    """Around the vertical column: ``d3`` normalised, ``d2`` perpendicular to it, ``d1 = d2 x d3``."""
    d[:, 2] /= np.linalg.norm(d[:, 2])
    d[:, 1] -= (d[:, 1] @ d[:, 2]) * d[:, 2]
    d[:, 1] /= np.linalg.norm(d[:, 1])
    d[:, 0] = cross(d[:, 1], d[:, 2])


def _horizontal_field(mag, d):
    """``(m/|m|, m_h)``: the unit field and its part perpendicular to ``d3``, normalised (None for a
    field along the vertical: no heading in it)."""
    m = mag / np.linalg.norm(mag)
    mh = m - (m @ d[:, 2]) * d[:, 2]
    nh = np.linalg.norm(mh)
    return m, (mh / nh if nh > 1e-6 else None)


class _DcmCorrector(Corrector):
    mode: ClassVar[str] = "state"
    state_layout: ClassVar[str] = "dcm"
    source: ClassVar[str] = "002 (separating the correction channels of a strapdown AHRS)"
    _size: ClassVar[int] = _LAYOUT

    def initial_state(self, dt: float, frame: str) -> np.ndarray:
        s = np.zeros(self._size)
        s[_ROWS:_ROWS + _LAYOUT] = frame_rows(frame)
        return s

    def correct(self, estimator, est_state, state, sample, flags) -> Correction:
        d = _columns(est_state, state)
        self._correct(d, state, sample)
        _store(est_state, state, d)
        return Correction(None)


class DcmVerticalConfig(PluginConfig):
    method: Literal["columns", "vectors"] = param(
        "columns", unit="-", description="'columns': blend the vertical column towards a/|a| (method 1); 'vectors': "
        "turn the DCM by k_acc dt (d3 x a/|a|) (method 2)")
    k_acc: float = param(0.3, unit="1/s", description="accelerometer correction gain (fraction per second)", gt=0)
    orthonormalize: bool = param(
        True, unit="-", description="re-orthonormalise around the vertical column after the correction; False only "
        "when a magnetometer DCM corrector (dcm-north, dcm-field) follows and does it")


class DcmVertical(_DcmCorrector):
    """Source 002: the accelerometer corrects the DCM's vertical column (roll and pitch) only."""

    name: ClassVar[str] = "dcm-vertical"
    Config = DcmVerticalConfig
    summary: ClassVar[str] = "DCM: the accelerometer corrects the vertical column d3 (method 1 or 2)"

    def _correct(self, d, state, sample) -> None:
        c = self.config
        if sample.acc is not None:
            a = sample.acc / np.linalg.norm(sample.acc)
            if c.method == "vectors":
                d[:] = rodrigues(c.k_acc * sample.dt * cross(d[:, 2], a)) @ d
            else:
                d[:, 2] += c.k_acc * sample.dt * (a - d[:, 2])
                d[:, 2] /= np.linalg.norm(d[:, 2])
        if c.orthonormalize:
            _orthonormalize(d)

    def kernel(self, estimator) -> CorrectorKernel:
        c = self.config
        return CorrectorKernel(_vertical_kernel, np.array([_METHODS[c.method], c.k_acc, float(c.orthonormalize)]))


class DcmFieldConfig(PluginConfig):
    k_mag: float = param(0.03, unit="1/s", description="magnetometer correction gain (fraction per second)", gt=0)


class DcmNorthConfig(DcmFieldConfig):
    method: Literal["columns", "vectors"] = param(
        "columns", unit="-", description="'columns': blend the north column towards the horizontal field (method 1); "
        "'vectors': turn the DCM about the vertical by k_mag dt (d2 x m_h) (method 2)")


class DcmNorth(_DcmCorrector):
    """Source 002: the magnetometer corrects the DCM's north column (heading) only: separated."""

    name: ClassVar[str] = "dcm-north"
    Config = DcmNorthConfig
    uses_mag: ClassVar[bool] = True
    summary: ClassVar[str] = "DCM: the horizontal field corrects the north column d2, heading only (method 1 or 2)"

    def _correct(self, d, state, sample) -> None:
        c = self.config
        if sample.mag is not None:
            _, mh = _horizontal_field(sample.mag, d)
            if mh is not None and c.method == "vectors":
                d[:] = rodrigues(c.k_mag * sample.dt * cross(d[:, 1], mh)) @ d
            elif mh is not None:
                d[:, 1] += c.k_mag * sample.dt * (mh - d[:, 1])
        _orthonormalize(d)

    def kernel(self, estimator) -> CorrectorKernel:
        c = self.config
        return CorrectorKernel(_north_kernel, np.array([_METHODS[c.method], c.k_mag]))


class DcmField(_DcmCorrector):
    """Source 002: the full field vector corrects the north AND vertical columns (unseparated)."""

    name: ClassVar[str] = "dcm-field"
    Config = DcmFieldConfig
    uses_mag: ClassVar[bool] = True
    summary: ClassVar[str] = "DCM: the whole field error corrects d2 and d3 (unseparated: disturbances tilt)"
    _size: ClassVar[int] = _Z + 1

    def _correct(self, d, state, sample) -> None:
        if sample.mag is not None:
            m, mh = _horizontal_field(sample.mag, d)
            if not state[_HZ]:  # the field's vertical and north parts, from the first sample
                state[_Z] = m @ d[:, 2]
                state[_H] = math.sqrt(max(0.0, 1.0 - state[_Z] ** 2))
                state[_HZ] = 1.0
            if mh is not None:  # (a field along the vertical: no heading in it, no correction)
                err = m - (state[_H] * d[:, 1] + state[_Z] * d[:, 2])
                d[:, 1] += self.config.k_mag * sample.dt * state[_H] * err
                d[:, 2] += self.config.k_mag * sample.dt * state[_Z] * err
        _orthonormalize(d)

    def kernel(self, estimator) -> CorrectorKernel:
        return CorrectorKernel(_field_kernel, np.array([self.config.k_mag]))


# ---- numba kernels (the references above with scalars; x the estimator's matrix, q unused) ------

@njit(inline="always")
def _col(x, s, j):
    """ENU axis ``j`` seen in the body: ``sign_j * x[row_j]``."""
    r, g = 3 * int(s[2 * j]), s[2 * j + 1]
    return g * x[r], g * x[r + 1], g * x[r + 2]


@njit(inline="always")
def _set_col(x, s, j, v0, v1, v2):
    r, g = 3 * int(s[2 * j]), s[2 * j + 1]
    x[r], x[r + 1], x[r + 2] = g * v0, g * v1, g * v2


@njit(inline="always")
def _turn(x, r0, r1, r2):
    """``D <- exp([r x]) D``: every axis seen in the body turned (rows of ``x``; signs commute)."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = rodrigues_entries(r0, r1, r2)
    for i in range(3):
        c0, c1, c2 = x[3 * i], x[3 * i + 1], x[3 * i + 2]
        x[3 * i] = m00 * c0 + m01 * c1 + m02 * c2
        x[3 * i + 1] = m10 * c0 + m11 * c1 + m12 * c2
        x[3 * i + 2] = m20 * c0 + m21 * c1 + m22 * c2


@njit(inline="always")
def _normalized(v0, v1, v2):
    n = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    return v0 / n, v1 / n, v2 / n


@njit(inline="always")
def _k_orthonormalize(x, s):
    u0, u1, u2 = _col(x, s, 2)
    u0, u1, u2 = _normalized(u0, u1, u2)
    n0, n1, n2 = _col(x, s, 1)
    dp = n0 * u0 + n1 * u1 + n2 * u2
    n0, n1, n2 = _normalized(n0 - dp * u0, n1 - dp * u1, n2 - dp * u2)
    _set_col(x, s, 2, u0, u1, u2)
    _set_col(x, s, 1, n0, n1, n2)
    _set_col(x, s, 0, n1 * u2 - n2 * u1, n2 * u0 - n0 * u2, n0 * u1 - n1 * u0)


@njit(inline="always")
def _k_horizontal(x, s, m0, m1, m2):
    """``(u, h, ok)``: the unit field, its horizontal part normalised, and whether it has one."""
    u0, u1, u2 = _normalized(m0, m1, m2)
    d0, d1, d2 = _col(x, s, 2)
    dz = u0 * d0 + u1 * d1 + u2 * d2
    h0, h1, h2 = u0 - dz * d0, u1 - dz * d1, u2 - dz * d2
    nh = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2)
    if nh > 1e-6:
        return u0, u1, u2, dz, h0 / nh, h1 / nh, h2 / nh, True
    return u0, u1, u2, dz, h0, h1, h2, False


@njit(inline="always")  # no call and no reference counting of the arrays per sample
def _vertical_kernel(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, p):
    if acc_ok:
        u0, u1, u2 = _normalized(a0, a1, a2)
        d0, d1, d2 = _col(x, s, 2)
        kk = p[1] * dt
        if p[0] == 1.0:
            _turn(x, kk * (d1 * u2 - d2 * u1), kk * (d2 * u0 - d0 * u2), kk * (d0 * u1 - d1 * u0))
        else:
            v0, v1, v2 = _normalized(d0 + kk * (u0 - d0), d1 + kk * (u1 - d1), d2 + kk * (u2 - d2))
            _set_col(x, s, 2, v0, v1, v2)
    if p[2] != 0.0:
        _k_orthonormalize(x, s)
    return 0


@njit(inline="always")  # no call and no reference counting of the arrays per sample
def _north_kernel(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, p):
    if mag_ok:
        u0, u1, u2, dz, h0, h1, h2, ok = _k_horizontal(x, s, m0, m1, m2)
        if ok:
            n0, n1, n2 = _col(x, s, 1)
            kk = p[1] * dt
            if p[0] == 1.0:
                _turn(x, kk * (n1 * h2 - n2 * h1), kk * (n2 * h0 - n0 * h2), kk * (n0 * h1 - n1 * h0))
            else:
                _set_col(x, s, 1, n0 + kk * (h0 - n0), n1 + kk * (h1 - n1), n2 + kk * (h2 - n2))
    _k_orthonormalize(x, s)
    return 0


@njit(inline="always")  # no call and no reference counting of the arrays per sample
def _field_kernel(x, q, s, g0, g1, g2, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, dt, p):
    if mag_ok:
        u0, u1, u2, dz, h0, h1, h2, ok = _k_horizontal(x, s, m0, m1, m2)
        if s[_HZ] == 0.0:
            s[_Z] = dz
            s[_H] = math.sqrt(max(0.0, 1.0 - dz * dz))
            s[_HZ] = 1.0
        if ok:
            hh, zz = s[_H], s[_Z]
            n0, n1, n2 = _col(x, s, 1)
            d0, d1, d2 = _col(x, s, 2)
            e0, e1, e2 = u0 - (hh * n0 + zz * d0), u1 - (hh * n1 + zz * d1), u2 - (hh * n2 + zz * d2)
            kh, kz = p[0] * dt * hh, p[0] * dt * zz
            _set_col(x, s, 1, n0 + kh * e0, n1 + kh * e1, n2 + kh * e2)
            _set_col(x, s, 2, d0 + kz * e0, d1 + kz * e1, d2 + kz * e2)
    _k_orthonormalize(x, s)
    return 0
