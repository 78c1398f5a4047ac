"""Strapdown velocity integration pieces (source 004) shared with other modules.

``velocity_increment`` is the one place where specific force becomes an earth-frame velocity
change; source 000's velocity-integral motion criterion uses it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["velocity_increment"]


def velocity_increment(c_earth_body, f_sum_dt, gravity_up, duration):
    """Earth-frame velocity change ``C (sum f dt) - g_up * T`` over a window of length ``T``.

    ``c_earth_body`` (3, 3) body->earth matrix held over the window, ``f_sum_dt`` the body-frame
    specific force integrated over it (m/s), ``gravity_up`` the specific force at rest in earth
    coordinates (e.g. ``[0, g, 0]`` in source 000's N-Up-E frame), ``duration`` T in s.
    """
    return np.asarray(c_earth_body) @ np.asarray(f_sum_dt) - np.asarray(gravity_up) * duration
