"""A small IMU simulator for tests, the demo and users without data.

A trajectory is a list of segments run one after the other, each with a smooth (raised-cosine)
profile that starts and ends at rest:

* :class:`Rest` ``(duration)``;
* :class:`Rotate` ``(axis, angle, duration)``: about a fixed *body* axis by ``angle`` rad;
* :class:`Translate` ``(direction, distance, duration)``: along an ENU direction, no rotation.

:func:`simulate` returns a :class:`~fusionkit.types.Recording` with the true orientation
(body->ENU) as ``truth`` and ``movement`` marking the non-rest segments. Gyro sample ``k`` is
the mean rate over ``(t[k-1], t[k]]`` (so integrating it with the exact step reproduces the
truth). Accelerometer and magnetometer sample ``k`` are, by default (``sampling="mean"``), the
means of the specific force ``R^T (a + [0, 0, g])`` and of the field ``R^T m`` over the same
interval, as an IMU that samples all its sensors alike reports them (Gauss-Legendre quadrature,
exact to far below the noise); ``sampling="point"`` gives their values at ``t[k]`` instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..rotations import quat_from_axis_angle, quat_mul, quat_normalize, quat_to_matrix
from ..types import Gnss, Recording

__all__ = ["Rest", "Rotate", "Translate", "Noise", "simulate", "demo_recordings", "KYIV_FIELD_ENU"]

#: source 002's field at Kyiv, ENU, uT: horizontal 18.964 north, 46.962 down
KYIV_FIELD_ENU = (0.0, 18.964, -46.962)


@dataclass(frozen=True)
class Rest:
    duration: float


@dataclass(frozen=True)
class Rotate:
    axis: tuple[float, float, float]
    angle: float
    duration: float


@dataclass(frozen=True)
class Translate:
    direction: tuple[float, float, float]
    distance: float
    duration: float


@dataclass(frozen=True)
class Noise:
    """Sensor errors: white noise std per sample and constant biases (SI units)."""

    gyr_noise: float = 0.0
    gyr_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    acc_noise: float = 0.0
    acc_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_noise: float = 0.0

    @classmethod
    def mems(cls) -> "Noise":
        """A consumer MEMS IMU: 0.005 rad/s and 0.03 m/s^2 noise, gyro bias about 0.3 deg/s."""
        return cls(gyr_noise=0.005, gyr_bias=(0.004, -0.006, 0.003), acc_noise=0.03, acc_bias=(0.0, 0.0, 0.0),
                   mag_noise=0.3)


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


def _in_body(quat, v_e):
    """ENU vectors ``v_e`` ((n, 3) or (3,)) seen in the body: ``R^T v``."""
    return np.einsum("nji,nj->ni", quat_to_matrix(quat), np.broadcast_to(v_e, (len(quat), 3)))


def _progress(u):
    """Raised-cosine displacement profile on [0, 1] with zero rate at both ends."""
    return u - np.sin(2.0 * np.pi * u) / (2.0 * np.pi)


def simulate(segments, rate: float = 100.0, noise: Noise = Noise(), initial=(1.0, 0.0, 0.0, 0.0),
             mag_field=KYIV_FIELD_ENU, gravity: float = 9.81, seed: int | None = 0, name: str = "sim",
             gnss_rate: float | None = 10.0, gnss_vel_noise: float = 0.0, initial_velocity=(0.0, 0.0, 0.0),
             sampling: str = "mean") -> Recording:
    """Simulate ``segments`` at ``rate`` Hz (see module doc); ``seed`` makes the noise repeatable.

    ``sampling``: ``"mean"`` (the specific force and the field averaged over each sample's
    interval, like the gyro's rate) or ``"point"`` (their values at the sample's time).

    With ``gnss_rate`` (Hz) the recording carries a GNSS velocity stream (ENU, white noise of
    ``gnss_vel_noise`` m/s per axis) sampled from the true velocity.
    """
    if rate <= 0:
        raise InputError(f"rate must be > 0, got {rate}")
    if sampling not in ("mean", "point"):
        raise InputError(f"sampling must be 'mean' or 'point', got {sampling!r}")
    segments = list(segments)
    if not segments:
        raise InputError("segments is empty")
    dt = 1.0 / rate
    counts = [max(1, int(round(s.duration * rate))) for s in segments]
    n = sum(counts) + 1
    quat = np.empty((n, 4))
    acc_e = np.zeros((n, 3))
    moving = np.zeros(n, bool)
    gyr = np.zeros((n, 3))
    q = quat_normalize(np.asarray(initial, dtype=float))
    quat[0] = q
    g_e = np.array([0.0, 0.0, gravity])
    m_e = np.asarray(mag_field, dtype=float)
    acc, mag = np.empty((n, 3)), np.empty((n, 3))
    acc[0], mag[0] = quat_to_matrix(q).T @ g_e, quat_to_matrix(q).T @ m_e
    nodes, weights = np.polynomial.legendre.leggauss(_QUADRATURE_NODES)
    nodes = 0.5 * (nodes + 1.0)  # on (0, 1)
    weights = 0.5 * weights
    k = 1
    for seg, m in zip(segments, counts):
        if not isinstance(seg, (Rest, Rotate, Translate)):
            raise InputError(f"unknown segment {seg!r}: use Rest, Rotate or Translate")
        u = np.arange(1, m + 1) / m  # progress at the segment's samples
        quat[k:k + m], acc_e[k:k + m] = _segment_motion(seg, q, u, m * dt)
        if isinstance(seg, Rotate):
            axis = np.asarray(seg.axis, dtype=float)
            ang = seg.angle * _progress(u)
            gyr[k:k + m] = np.diff(np.concatenate([[0.0], ang]))[:, None] / dt * (axis / np.linalg.norm(axis))
        moving[k:k + m] = not isinstance(seg, Rest)
        if sampling == "point":
            acc[k:k + m] = _in_body(quat[k:k + m], acc_e[k:k + m] + g_e)
            mag[k:k + m] = _in_body(quat[k:k + m], m_e)
        else:  # the means over each sample's interval ((j - 1) / m, j / m]
            acc[k:k + m] = mag[k:k + m] = 0.0
            for c, w in zip(nodes, weights):
                qn, an = _segment_motion(seg, q, (np.arange(m) + c) / m, m * dt)
                acc[k:k + m] += w * _in_body(qn, an + g_e)
                mag[k:k + m] += w * _in_body(qn, m_e)
        q = quat[k + m - 1].copy()
        k += m
    rng = np.random.default_rng(seed)
    gyr = gyr + np.asarray(noise.gyr_bias) + noise.gyr_noise * rng.standard_normal((n, 3))
    acc = acc + np.asarray(noise.acc_bias) + noise.acc_noise * rng.standard_normal((n, 3))
    mag = mag + noise.mag_noise * rng.standard_normal((n, 3))
    gnss = None
    if gnss_rate:
        vel = np.asarray(initial_velocity, dtype=float) + np.concatenate(
            [np.zeros((1, 3)), np.cumsum(0.5 * (acc_e[1:] + acc_e[:-1]) * dt, axis=0)])
        step = max(1, int(round(rate / gnss_rate)))
        idx = np.arange(0, n, step)
        gnss = Gnss(t=idx * dt, vel=vel[idx] + gnss_vel_noise * rng.standard_normal((idx.size, 3)), frame="ENU")
    return Recording(gyr=gyr, acc=acc, mag=mag, rate=rate, truth=quat, truth_frame="ENU", movement=moving,
                     gnss=gnss, name=name, meta={"simulated": True, "noise": noise, "gravity": gravity})


def demo_recordings(rate: float = 200.0, seed: int = 0) -> list[Recording]:
    """Three short noisy recordings for the demo: slow rotations, fast rotations, translations."""
    deg = np.pi / 180.0
    noise = Noise.mems()
    slow = [Rest(12.0), Rotate((0, 0, 1), 90 * deg, 4.0), Rotate((1, 0, 0), 45 * deg, 3.0), Rest(2.0),
            Rotate((0, 1, 0), -60 * deg, 4.0), Rotate((0, 0, 1), -90 * deg, 4.0), Rest(5.0)]
    fast = [Rest(12.0)] + [Rotate(ax, 120 * deg * s, 1.0) for s in (1, -1) for ax in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0))] + [Rest(5.0)]
    trans = [Rest(12.0)] + [Translate(d, 0.5, 1.5) for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1))] + [Rotate((0, 0, 1), 30 * deg, 2.0), Rest(5.0)]
    return [simulate(s, rate=rate, noise=noise, seed=seed + i, name=nm)
            for i, (nm, s) in enumerate((("slow-rotation", slow), ("fast-rotation", fast), ("translation", trans)))]
