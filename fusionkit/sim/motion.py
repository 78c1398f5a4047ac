"""Trajectories for the simulator: segments run one after the other, each with a smooth
(raised-cosine) profile that starts and ends at rest, and the true motion they make."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rotations import quat_from_axis_angle, quat_mul, quat_to_matrix
from .errors import _direction, _positive, _real

__all__ = ["Rest", "Rotate", "Translate"]

# A segment's duration is rounded to the sample grid by :func:`~fusionkit.sim.simulate`: it lasts
# round(duration * rate) samples, at least one (Rotate(axis, angle, 0.015) at 100 Hz lasts 0.02 s).


@dataclass(frozen=True)
class Rest:
    """No motion for ``duration`` s (finite, > 0; rounded to the sample grid, at least one sample)."""

    duration: float

    def __post_init__(self) -> None:  # (a negative or zero duration was one sample; NaN, inf numpy's error)
        object.__setattr__(self, "duration", _positive("Rest.duration", self.duration, "s"))


@dataclass(frozen=True)
class Rotate:
    """A rotation about the fixed body ``axis`` (3 numbers, not all zero) by ``angle`` rad in
    ``duration`` s (finite, > 0; rounded to the sample grid, at least one sample)."""

    axis: tuple[float, float, float]
    angle: float
    duration: float

    def __post_init__(self) -> None:  # (a zero axis or a NaN angle made a NaN truth)
        object.__setattr__(self, "axis", _direction("Rotate.axis", self.axis))
        object.__setattr__(self, "angle", _real("Rotate.angle", self.angle, "a finite number (rad)"))
        object.__setattr__(self, "duration", _positive("Rotate.duration", self.duration, "s"))


@dataclass(frozen=True)
class Translate:
    """A translation along the ENU ``direction`` (3 numbers, not all zero) by ``distance`` m in
    ``duration`` s (finite, > 0; rounded to the sample grid, at least one sample), no rotation."""

    direction: tuple[float, float, float]
    distance: float
    duration: float

    def __post_init__(self) -> None:  # (a zero direction made a NaN acceleration)
        object.__setattr__(self, "direction", _direction("Translate.direction", self.direction))
        object.__setattr__(self, "distance", _real("Translate.distance", self.distance, "a finite number (m)"))
        object.__setattr__(self, "duration", _positive("Translate.duration", self.duration, "s"))


_QUADRATURE_NODES = 5  # Gauss-Legendre nodes per sample for the interval means (sampling="mean")


def _segment_motion(seg, q0, u, duration):
    """Orientation (body->ENU) and ENU acceleration at progress ``u`` of ``seg`` from ``q0``."""
    acc_e = np.zeros((u.size, 3))
    if isinstance(seg, Rotate):
        quat = quat_mul(q0, quat_from_axis_angle(seg.axis, seg.angle * _progress(u)))
    else:
        quat = np.tile(q0, (u.size, 1))
        if isinstance(seg, Translate):
            d = np.asarray(seg.direction, dtype=float)
            d = d / np.linalg.norm(d)
            acc_e = (2.0 * np.pi * seg.distance / duration**2 * np.sin(2.0 * np.pi * u))[:, None] * d
    return quat, acc_e


def _segment_position(seg, p0, u):
    """Position (m, ENU, from ``p0`` at the segment's start) at progress ``u`` of ``seg``."""
    if not isinstance(seg, Translate):
        return np.tile(p0, (u.size, 1))
    d = np.asarray(seg.direction, dtype=float)
    return p0 + (seg.distance * _progress(u))[:, None] * (d / np.linalg.norm(d))


def _lever_arm_force(seg, u, duration, r):
    """The rotation's tangential and centripetal accelerations ``w_dot x r + w x (w x r)`` (m/s^2,
    body) of a point at ``r`` (m, body) from the rotation centre, at progress ``u`` of ``seg``
    (zero outside a :class:`Rotate`: its axis is fixed in the body, ``w = n angle P'(u) / T``)."""
    out = np.zeros((u.size, 3))
    if isinstance(seg, Rotate):
        n = np.asarray(seg.axis, dtype=float)
        n = n / np.linalg.norm(n)
        rate = seg.angle * (1.0 - np.cos(2.0 * np.pi * u)) / duration
        rate_dot = seg.angle * 2.0 * np.pi * np.sin(2.0 * np.pi * u) / duration**2
        r = np.asarray(r, dtype=float)
        out = rate_dot[:, None] * np.cross(n, r) + (rate**2)[:, None] * np.cross(n, np.cross(n, r))
    return out


def _in_body(quat, v_e):
    """ENU vectors ``v_e`` ((n, 3) or (3,)) seen in the body: ``R^T v``."""
    return np.einsum("nji,nj->ni", quat_to_matrix(quat), np.broadcast_to(v_e, (len(quat), 3)))


def _progress(u):
    """Raised-cosine displacement profile on [0, 1] with zero rate at both ends."""
    return u - np.sin(2.0 * np.pi * u) / (2.0 * np.pi)
