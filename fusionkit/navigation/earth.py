"""WGS-84 earth model for navigation in a local-level NED frame: radii of curvature, normal
gravity with its height correction, earth rate and transport rate.

These are the standard expressions (e.g. Groves, *Principles of GNSS, Inertial, and
Multisensor Integrated Navigation Systems*, 2nd ed., ch. 2): they are what a simulator with a
WGS-84 earth (gnss-ins-sim) puts into its sensor values, and what an INS must take out again.
"""

from __future__ import annotations

import math

import numpy as np

from .._numba import njit

__all__ = ["WGS84_A", "WGS84_E2", "EARTH_RATE", "radii", "normal_gravity", "earth_rate_ned", "transport_rate_ned"]

WGS84_A = 6378137.0  #: semi-major axis, m
WGS84_E2 = 6.69437999014e-3  #: first eccentricity squared
EARTH_RATE = 7.292115e-5  #: rad/s


@njit
def radii(lat):
    """``(R_M, R_N)``: meridian and transverse (prime vertical) radii of curvature (m) at
    geodetic latitude ``lat`` (rad)."""
    s2 = math.sin(lat) ** 2
    d = 1.0 - WGS84_E2 * s2
    return WGS84_A * (1.0 - WGS84_E2) / d ** 1.5, WGS84_A / math.sqrt(d)


@njit
def normal_gravity(lat, h):
    """Magnitude of WGS-84 normal gravity (m/s^2, along +down) at latitude ``lat`` (rad) and
    ellipsoidal height ``h`` (m): Somigliana's formula with the second-order height correction."""
    s2 = math.sin(lat) ** 2
    g0 = 9.7803253359 * (1.0 + 0.001931853 * s2) / math.sqrt(1.0 - WGS84_E2 * s2)
    return g0 - (3.087691089e-6 - 4.397731e-9 * s2) * h + 0.721e-12 * h * h


def earth_rate_ned(lat) -> np.ndarray:
    """Earth rotation rate (rad/s) in NED at latitude ``lat`` (rad)."""
    return EARTH_RATE * np.array([math.cos(lat), 0.0, -math.sin(lat)])


def transport_rate_ned(lat, h, v_ned) -> np.ndarray:
    """Rotation rate (rad/s) of the local-level NED frame over the earth for a velocity ``v_ned``."""
    rm, rn = radii(lat)
    vn, ve = float(v_ned[0]), float(v_ned[1])
    return np.array([ve / (rn + h), -vn / (rm + h), -ve * math.tan(lat) / (rn + h)])
