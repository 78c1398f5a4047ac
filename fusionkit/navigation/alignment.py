"""Initial alignment of a still IMU (source 000, section 3).

At rest the accelerometers measure ``f_r = -L g_e``; with matrix (1) and heading 0::

    f = [g sin(theta), g cos(theta) cos(gamma), -g cos(theta) sin(gamma)]

so ``theta = atan(f1 / sqrt(f2^2 + f3^2))`` and ``gamma = atan2(-f3, f2)``. The document prints
``gamma = atan(f3 / f2)``, which contradicts its own matrix in the sign of ``f3``; the form here
is derived from (1) and proven by round trips in all four roll quadrants
(``tests/test_alignment.py``). Heading is 0 (source 000 has no magnetometer), or, as an
extension, the heading that points the horizontal magnetic field to north.
"""

from __future__ import annotations

import numpy as np

from ..conventions import change_frame, source000_quat
from ..rotations import quat_from_axis_angle, quat_mul, quat_rotate

__all__ = ["alignment_angles", "alignment_quat"]


def alignment_angles(acc_mean) -> tuple[float, float]:
    """``(theta, gamma)``: source 000's pitch and roll (rad) from the mean specific force."""
    f1, f2, f3 = np.asarray(acc_mean, dtype=float)
    theta = np.arctan2(f1, np.hypot(f2, f3))  # = atan(f1 / sqrt(f2^2 + f3^2)), cos(theta) >= 0
    gamma = np.arctan2(-f3, f2)  # from matrix (1): f2 = g cos(theta) cos(gamma), f3 = -g cos(theta) sin(gamma)
    return float(theta), float(gamma)


def alignment_quat(acc_mean, mag_mean=None, frame: str = "ENU") -> np.ndarray:
    """Body->``frame`` quaternion of a still IMU from its mean specific force.

    With ``mag_mean`` the heading is turned about the vertical so that the horizontal part of
    the magnetic field points to (magnetic) north; without it the heading is source 000's 0.
    """
    theta, gamma = alignment_angles(acc_mean)
    q = source000_quat(0.0, theta, gamma)  # body -> NUE
    if mag_mean is not None:
        m_nue = quat_rotate(q, mag_mean)
        beta = np.arctan2(m_nue[2], m_nue[0])  # angle of the field from North towards East
        q = quat_mul(quat_from_axis_angle([0.0, 1.0, 0.0], beta), q)  # rotate about Up (axis 2)
    q = change_frame(q, "NUE", frame)
    return q / np.linalg.norm(q)
