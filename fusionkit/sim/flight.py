"""A simulated vehicle with an IMU and a GNSS receiver, for navigation filters (``ins-gnss``).

:func:`simulate_flight` makes a :class:`~fusionkit.types.Recording` like the gnss-ins-sim files
(``fusionkit.io.gnss``): body axes FRD, a local-level NED frame about the start point on a
rotating WGS-84 earth, GNSS velocity and position (NED, m) at their own rate with white noise and
outages, and the truth (attitude body -> NED, velocity, position, the sensor biases) in
``truth`` and ``meta``.

Motion: still for ``rest`` s, then a random (seeded) sequence of straight legs, coordinated
turns, speed changes and climbs. The nose follows the ground track (no sideslip, unless
``sideslip``); with
``bank=True`` the vehicle rolls into its turns (coordinated, ``tan(roll) = V r / g``) and its
pitch follows the flight path, else roll and pitch stay at their initial trim (a car).

Sensors, sample ``k`` being the interval ``(t[k-1], t[k]]`` as fusionkit reads it: the gyro is
the rotation over the interval divided by ``dt`` plus the rotation of the navigation frame
(earth rate and transport rate), the accelerometer the mean specific force over the interval
``C_mid^T (dv/dt - g + (2 w_ie + w_en) x v)``; both with constant biases, optional first-order
Gauss-Markov bias instability and white noise given as densities (per sample
``density * sqrt(rate)``). ``time_offset`` shifts the IMU (and magnetometer) against the GNSS
and the truth: the sample stamped ``t`` measures the interval that ends at ``t + time_offset``
(an IMU whose time stamps lag the receiver's clock; a multiple of a quarter sample). Positions
are the time integral of the velocity (flat local frame: over a few km the difference to a map
projection is centimetres).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..navigation.earth import EARTH_RATE, normal_gravity, radii
from ..types import Gnss, Recording

__all__ = ["simulate_flight"]

#: the earth's field at the heli_cruise start (NED, uT), declination 2.47 deg
_FIELD_NED = (21.47, 0.93, 42.91)


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    """``x`` convolved with a normalised Hann window of ``n`` samples (edges held)."""
    if n < 3:
        return x
    w = np.hanning(n)
    w /= w.sum()
    pad = np.concatenate([np.full(n, x[0]), x, np.full(n, x[-1])])
    return np.convolve(pad, w, mode="same")[n:-n]


def _commands(t, rest, speed, turn_rate, accel, climb, rng):
    """Piecewise-constant longitudinal acceleration, yaw rate and climb rate after ``rest``."""
    a = np.zeros_like(t)
    r = np.zeros_like(t)
    w = np.zeros_like(t)
    t_acc = speed / accel
    a[(t >= rest) & (t < rest + t_acc)] = accel
    s = rest + t_acc + 5.0
    v = speed
    while s < t[-1]:
        kind = rng.integers(0, 3)
        if kind == 0:  # a turn of 45 to 150 deg either way
            ang = math.radians(rng.uniform(45.0, 150.0)) * rng.choice([-1.0, 1.0])
            d = abs(ang) / turn_rate
            r[(t >= s) & (t < s + d)] = math.copysign(turn_rate, ang)
        elif kind == 1:  # a speed change of up to 40 %
            target = speed * rng.uniform(0.7, 1.4)
            d = abs(target - v) / accel
            a[(t >= s) & (t < s + d)] = math.copysign(accel, target - v)
            v = target
        else:  # a climb or descent, with a half turn
            d = rng.uniform(8.0, 20.0)
            w[(t >= s) & (t < s + d)] = climb * rng.choice([-1.0, 1.0])
            r[(t >= s) & (t < s + d)] = 0.5 * turn_rate * rng.choice([-1.0, 1.0])
        s += d + rng.uniform(5.0, 12.0)
    return a, r, w


def simulate_flight(duration: float = 200.0, *, rest: float = 20.0, rate: float = 100.0, gnss_rate: float = 10.0,
                    speed: float = 20.0, turn_rate: float = 0.1, accel: float = 1.0, climb: float = 2.0,
                    bank: bool = True, trim=(0.5, -0.8), heading0: float = 30.0,
                    origin=(47.4581, 8.5555, 432.0), gyr_bias=(3.5e-3, -2.1e-3, 4.9e-3),
                    acc_bias=(0.04, -0.03, 0.06), gyr_noise: float = 2.18e-4, acc_noise: float = 8.3e-4,
                    gyr_bias_instability: float = 4.85e-5, acc_bias_instability: float = 2e-4,
                    bias_tau: float = 100.0, mag_field=_FIELD_NED, mag_noise: float = 0.1,
                    gnss_pos_std=(5.0, 5.0, 7.0), gnss_vel_std: float = 0.05, outages=(),
                    time_offset: float = 0.0, sideslip: float = 0.0, seed: int = 0,
                    name: str = "flight") -> Recording:
    """Simulate a vehicle with IMU, magnetometer and GNSS (see the module docs).

    Units: s, m, m/s, m/s^2, rad/s, deg (``trim`` = (pitch, roll) at rest, ``heading0``,
    ``origin`` latitude/longitude), ``turn_rate`` rad/s. Noise densities: ``gyr_noise``
    rad/s/sqrt(Hz), ``acc_noise`` m/s^2/sqrt(Hz); bias instabilities are the Gauss-Markov
    processes' standard deviations (correlation time ``bias_tau``). ``outages``: [start, end)
    intervals in s without GNSS. ``time_offset`` (s): the IMU's time stamps lag the GNSS and truth
    clock by this much (a multiple of ``1 / (4 rate)``). ``sideslip`` (deg): the nose swings off
    the ground track by up to this much, a 30 s sine scaled with the speed (a vehicle that crabs:
    a helicopter, a boat in a current; a car does not). The defaults are the low-cost MEMS IMU of
    the gnss-ins-sim files.
    """
    if duration <= rest or rest < 0:
        raise InputError(f"need 0 <= rest < duration, got rest={rest}, duration={duration}")
    if rate <= 0 or gnss_rate <= 0 or gnss_rate > rate:
        raise InputError(f"need 0 < gnss_rate <= rate, got {gnss_rate}, {rate}")
    from scipy.spatial.transform import Rotation

    ovs = 4  # the motion is integrated on a grid 4x finer than the samples
    shift = int(round(time_offset * rate * ovs))  # the IMU's offset in steps of that grid
    if not abs(shift - time_offset * rate * ovs) < 1e-6:
        raise InputError(f"time_offset must be a multiple of 1 / (4 rate) = {0.25 / rate} s, got {time_offset}")
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    n = int(round(duration * rate)) + 1
    nf = (n - 1) * ovs + 1
    tf = np.arange(nf) * (dt / ovs)
    a_cmd, r_cmd, w_cmd = _commands(tf, rest, speed, turn_rate, accel, climb, rng)
    sm = int(1.0 * rate * ovs)  # 1 s Hann smoothing: continuous accelerations and bank angles
    late = max(shift, 0)  # a late IMU needs the motion past the end: the commands held
    a_cmd, r_cmd, w_cmd = (np.concatenate([_smooth(x, sm), np.full(late, x[-1])]) for x in (a_cmd, r_cmd, w_cmd))
    hf = dt / ovs
    tf = np.arange(a_cmd.size) * hf

    def integ(x, x0=0.0):
        return x0 + np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * hf)])

    v_h = np.maximum(integ(a_cmd), 0.0)
    yaw = integ(r_cmd, math.radians(heading0))
    vel = np.stack([v_h * np.cos(yaw), v_h * np.sin(yaw), -w_cmd], axis=1)
    pos = np.stack([integ(vel[:, i]) for i in range(3)], axis=1)
    g0 = normal_gravity(math.radians(origin[0]), origin[2])
    if sideslip:  # the nose off the track (the velocity keeps the track's direction)
        yaw_v = yaw
        yaw = yaw + math.radians(sideslip) * np.sin(2.0 * math.pi * tf / 30.0) * np.clip(v_h / max(speed, 1e-9), 0, 1)
        vel = np.stack([v_h * np.cos(yaw_v), v_h * np.sin(yaw_v), -w_cmd], axis=1)
        pos = np.stack([integ(vel[:, i]) for i in range(3)], axis=1)
    pitch = np.full_like(tf, math.radians(trim[0]))
    roll = np.full_like(tf, math.radians(trim[1]))
    if bank:
        pitch = pitch + np.arctan2(w_cmd, np.maximum(v_h, 1.0))
        roll = roll + np.arctan(v_h * r_cmd / g0)
    s = slice(0, nf, ovs)  # the sample grid: the truth and GNSS
    vel_s, pos_s = vel[s], pos[s]
    truth = Rotation.from_euler("ZYX", np.stack([yaw[s], pitch[s], roll[s]], axis=1))
    quat = np.roll(truth.as_quat(), 1, axis=1)  # (w, x, y, z) body (FRD) -> NED
    si = np.clip(np.arange(n) * ovs + shift, 0, nf - 1 + late)  # the IMU's grid (at rest before 0)
    vel_i, pos_i = vel[si], pos[si]
    rot = Rotation.from_euler("ZYX", np.stack([yaw[si], pitch[si], roll[si]], axis=1))
    rel = (rot[:-1].inv() * rot[1:]).as_rotvec()  # body rotation over each interval
    mid = rot[:-1] * Rotation.from_rotvec(0.5 * rel)
    # navigation-frame rotation at the interval's middle: earth rate and transport rate
    lat0, h0 = math.radians(origin[0]), origin[2]
    rm, rn = radii(lat0)
    pm = 0.5 * (pos_i[1:] + pos_i[:-1])
    vm = 0.5 * (vel_i[1:] + vel_i[:-1])
    lat = lat0 + pm[:, 0] / (rm + h0)
    h = h0 - pm[:, 2]
    w_ie = EARTH_RATE * np.stack([np.cos(lat), np.zeros_like(lat), -np.sin(lat)], axis=1)
    w_en = np.stack([vm[:, 1] / (rn + h), -vm[:, 0] / (rm + h), -vm[:, 1] * np.tan(lat) / (rn + h)], axis=1)
    grav = np.array([normal_gravity(a, b) for a, b in zip(lat, h)])
    f_n = np.diff(vel_i, axis=0) / dt + np.cross(2.0 * w_ie + w_en, vm)
    f_n[:, 2] -= grav
    gyr_true = np.zeros((n, 3))
    acc_true = np.zeros((n, 3))
    gyr_true[1:] = rel / dt + mid.inv().apply(w_ie + w_en)
    acc_true[1:] = mid.inv().apply(f_n)
    gyr_true[0] = rot[0].inv().apply(w_ie[0])
    acc_true[0] = rot[0].inv().apply([0.0, 0.0, -grav[0]])

    def bias(b0, sigma):
        out = np.tile(np.asarray(b0, float), (n, 1))
        if sigma > 0:
            phi = math.exp(-dt / bias_tau)
            e = rng.standard_normal((n, 3)) * sigma * math.sqrt(1.0 - phi * phi)
            gm = np.zeros((n, 3))
            gm[0] = sigma * rng.standard_normal(3)
            for k in range(1, n):
                gm[k] = phi * gm[k - 1] + e[k]
            out += gm
        return out

    bg, ba = bias(gyr_bias, gyr_bias_instability), bias(acc_bias, acc_bias_instability)
    gyr = gyr_true + bg + gyr_noise * math.sqrt(rate) * rng.standard_normal((n, 3))
    acc = acc_true + ba + acc_noise * math.sqrt(rate) * rng.standard_normal((n, 3))
    mag = rot.inv().apply(np.asarray(mag_field, float)) + mag_noise * rng.standard_normal((n, 3))
    step = max(1, int(round(rate / gnss_rate)))
    idx = np.arange(0, n, step)
    tg = idx / rate
    valid = np.ones(idx.size, bool)
    for a, b in outages:
        valid &= ~((tg >= a) & (tg < b))
    gv = vel_s[idx] + gnss_vel_std * rng.standard_normal((idx.size, 3))
    gp = pos_s[idx] + np.asarray(gnss_pos_std, float) * rng.standard_normal((idx.size, 3))
    gv[~valid] = np.nan
    gp[~valid] = np.nan
    m = np.asarray(mag_field, float)
    meta = {
        "simulated": True, "dataset": "fusionkit.sim.flight", "body_frame": "FRD",
        "ref_vel_ned": vel_s, "ref_pos_ned": pos_s, "ref_gyr_bias": bg, "ref_acc_bias": ba,
        "gnss_outages_s": [list(o) for o in outages], "origin_lla": np.asarray(origin, float),
        "mag_declination_deg": math.degrees(math.atan2(m[1], m[0])), "gravity": g0,
    }
    return Recording(gyr=gyr, acc=acc, mag=mag, rate=rate,
                     gnss=Gnss(t=tg, vel=gv, valid=valid, frame="NED", pos=gp),
                     truth=quat, truth_frame="NED", name=name, meta=meta)
