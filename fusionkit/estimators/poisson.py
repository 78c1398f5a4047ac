"""Poisson kinematic integrators (source 000 in quaternions, source 004 in a DCM).

``poisson-quat``: ``dQ/dt = 1/2 Q (x) [0, w]``. Per sample, with ``w`` the body rate (bias
removed) held over ``dt``:

* ``step="first-order"`` (source 000, section 4): ``q = [1, dt/2 w1, dt/2 w2, dt/2 w3]``,
  ``Q <- normalise(Q (x) q)``. Its error per step is O(|w dt|^3) in angle, so a constant-rate
  rotation drifts by about ``|w|^3 dt^2 T / 12`` after ``T`` s.
* ``step="exact"``: ``q = [cos(|w|dt/2), sin(|w|dt/2) w/|w|]``, exact for a rate constant over
  the interval.

``poisson-dcm`` (source 004): ``C <- C (I + sin(s)/s B + (1 - cos s)/s^2 B^2)``,
``B = [w dt x]``, ``s = |w dt|``, then one symmetric orthonormalisation step.

Both hold body->earth orientation; state layouts: quaternion ``[w, x, y, z]``; DCM 9 entries,
row-major.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._kernels import dcm_to_quat, qmul_entries, qnormalize, quat_to_dcm, rodrigues_entries, rotvec_quat_entries
from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import Estimator, EstimatorKernel
from ..rotations import (
    matrix_to_quat,
    orthonormalize,
    quat_from_rotvec,
    quat_mul,
    quat_normalize,
    quat_to_matrix,
    rodrigues,
    small_rotation_quat,
)

__all__ = ["PoissonQuat", "PoissonDcm"]

_STEPS = {"first-order": 0.0, "exact": 1.0}


class PoissonQuatConfig(PluginConfig):
    step: Literal["first-order", "exact"] = param(
        "first-order",
        unit="-",
        description="'first-order': source 000's small-rotation quaternion [1, w dt/2]; "
        "'exact': the rotation-vector quaternion",
    )
    normalize: bool = param(True, unit="-", description="normalise the quaternion every step (source 000)")


class PoissonQuat(Estimator):
    """Quaternion Poisson integrator (source 000, section 4)."""

    name: ClassVar[str] = "poisson-quat"
    state_layout: ClassVar[str] = "quat"
    Config = PoissonQuatConfig
    source: ClassVar[str] = "000 (AIST-350 report), section 4; exact step: extension"
    summary: ClassVar[str] = "quaternion Poisson integration, first-order (source 000) or exact step"

    def initial_state(self, quat) -> np.ndarray:
        return quat_normalize(np.asarray(quat, dtype=float)).copy()

    def propagate(self, state, gyr, dt) -> None:
        rv = np.asarray(gyr, dtype=float) * dt
        q = small_rotation_quat(rv) if self.config.step == "first-order" else quat_from_rotvec(rv)
        state[:] = quat_mul(state, q)
        if self.config.normalize:
            state[:] = quat_normalize(state)

    def quat(self, state) -> np.ndarray:
        return quat_normalize(state[:4])

    def kernel(self) -> EstimatorKernel:
        p = np.array([_STEPS[self.config.step], float(self.config.normalize)])
        return EstimatorKernel(_quat_propagate, _quat_to_quat, _quat_from_quat, p, self.config.normalize)


class PoissonDcmConfig(PluginConfig):
    orthonormalize: bool = param(
        True, unit="-", description="one symmetric re-orthonormalisation step after every update"
    )


class PoissonDcm(Estimator):
    """Rotation-matrix Poisson integrator with source 004's exact (Rodrigues) increment."""

    name: ClassVar[str] = "poisson-dcm"
    #: the body->frame rotation matrix, 9 entries row-major: row i is the frame's axis i seen in the body
    state_layout: ClassVar[str] = "dcm"
    Config = PoissonDcmConfig
    source: ClassVar[str] = "004 (Pitts S-2B strapdown), attitude update"
    summary: ClassVar[str] = "DCM Poisson integration, C <- C exp([w dt x]) (Rodrigues)"

    def initial_state(self, quat) -> np.ndarray:
        return quat_to_matrix(quat_normalize(np.asarray(quat, dtype=float))).reshape(9).copy()

    def propagate(self, state, gyr, dt) -> None:
        c = state.reshape(3, 3) @ rodrigues(np.asarray(gyr, dtype=float) * dt)
        if self.config.orthonormalize:
            c = orthonormalize(c)
        state[:] = c.reshape(9)

    def quat(self, state) -> np.ndarray:
        return matrix_to_quat(state.reshape(3, 3))

    def kernel(self) -> EstimatorKernel:
        p = np.array([float(self.config.orthonormalize)])
        return EstimatorKernel(_dcm_propagate, _dcm_to_quat, _dcm_from_quat, p)


# ---- numba kernels --------------------------------------------------------------------------


@njit
def _quat_propagate(x, w0, w1, w2, dt, p):
    r0, r1, r2 = w0 * dt, w1 * dt, w2 * dt
    if p[0] == 0.0:
        d0, d1, d2, d3 = 1.0, 0.5 * r0, 0.5 * r1, 0.5 * r2
    else:
        d0, d1, d2, d3 = rotvec_quat_entries(r0, r1, r2)
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    y0, y1, y2, y3 = qmul_entries(x0, x1, x2, x3, d0, d1, d2, d3)
    if p[1] != 0.0:
        # |q (x) d| = |q| |d|: |d| comes from the gyro alone and 1/|q| (|q| = 1 to rounding: the
        # state is normalised every step) is one Newton step, (3 - |q|^2) / 2, exact to O((|q|^2 - 1)^2).
        # The same value as normalising the product, without a square root and a division on the
        # sample-to-sample dependency chain (the kernel's speed is that chain's latency): 1/|d| is
        # off it, so the chain sees a multiplication, and the product stays in registers until
        # its one store.
        rd = 1.0 / math.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3)
        r = (1.5 - 0.5 * (x0 * x0 + x1 * x1 + x2 * x2 + x3 * x3)) * rd
        y0, y1, y2, y3 = y0 * r, y1 * r, y2 * r, y3 * r
    x[0], x[1], x[2], x[3] = y0, y1, y2, y3


@njit
def _quat_to_quat(x, out):
    out[0], out[1], out[2], out[3] = x[0], x[1], x[2], x[3]
    qnormalize(out)


@njit
def _quat_from_quat(q, x):
    x[0], x[1], x[2], x[3] = q[0], q[1], q[2], q[3]
    qnormalize(x)


@njit
def _dcm_propagate(x, w0, w1, w2, dt, p):
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = rodrigues_entries(w0 * dt, w1 * dt, w2 * dt)
    for i in range(3):  # C <- C R, row by row
        c0, c1, c2 = x[3 * i], x[3 * i + 1], x[3 * i + 2]
        x[3 * i] = c0 * m00 + c1 * m10 + c2 * m20
        x[3 * i + 1] = c0 * m01 + c1 * m11 + c2 * m21
        x[3 * i + 2] = c0 * m02 + c1 * m12 + c2 * m22
    if p[0] != 0.0:
        _bjorck(x)


@njit
def _bjorck(x):
    # C <- C - 0.5 C (C^T C - I)
    e00 = x[0] * x[0] + x[3] * x[3] + x[6] * x[6] - 1.0
    e11 = x[1] * x[1] + x[4] * x[4] + x[7] * x[7] - 1.0
    e22 = x[2] * x[2] + x[5] * x[5] + x[8] * x[8] - 1.0
    e01 = x[0] * x[1] + x[3] * x[4] + x[6] * x[7]
    e02 = x[0] * x[2] + x[3] * x[5] + x[6] * x[8]
    e12 = x[1] * x[2] + x[4] * x[5] + x[7] * x[8]
    for i in range(3):
        c0, c1, c2 = x[3 * i], x[3 * i + 1], x[3 * i + 2]
        x[3 * i] = c0 - 0.5 * (c0 * e00 + c1 * e01 + c2 * e02)
        x[3 * i + 1] = c1 - 0.5 * (c0 * e01 + c1 * e11 + c2 * e12)
        x[3 * i + 2] = c2 - 0.5 * (c0 * e02 + c1 * e12 + c2 * e22)


@njit
def _dcm_to_quat(x, out):
    dcm_to_quat(x, out)


@njit
def _dcm_from_quat(q, x):
    quat_to_dcm(q, x)
