"""The simulator proper: a trajectory sampled as an IMU reports it (see :mod:`fusionkit.sim`)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..rotations import quat_normalize, quat_to_matrix
from ..types import Gnss, Recording
from . import errors as _err
from .errors import SensorErrors
from .motion import (
    _QUADRATURE_NODES,
    Rest,
    Rotate,
    Translate,
    _in_body,
    _lever_arm_force,
    _progress,
    _segment_motion,
    _segment_position,
)
from .noise import Noise

__all__ = ["simulate", "KYIV_FIELD_ENU"]

#: source 002's field at Kyiv, ENU, uT: horizontal 18.964 north, 46.962 down
KYIV_FIELD_ENU = (0.0, 18.964, -46.962)


def simulate(segments, rate: float = 100.0, noise: Noise = Noise(), initial=(1.0, 0.0, 0.0, 0.0),
             mag_field=KYIV_FIELD_ENU, gravity: float = 9.81, seed: int | None = 0, name: str = "sim",
             gnss_rate: float | None = 10.0, gnss_vel_noise: float = 0.0, initial_velocity=(0.0, 0.0, 0.0),
             sampling: str = "mean", errors: SensorErrors | None = None) -> Recording:
    """Simulate ``segments`` at ``rate`` Hz (see module doc); ``seed`` makes the noise repeatable.

    Each segment lasts ``round(duration * rate)`` samples, at least one: durations are rounded to
    the sample grid (``Rotate(axis, angle, 0.015)`` at 100 Hz lasts 0.02 s, its angle in full), so
    the recording lasts the rounded durations' sum.

    ``sampling``: ``"mean"`` (the specific force and the field averaged over each sample's
    interval, like the gyro's rate) or ``"point"`` (their values at the sample's time).

    With ``gnss_rate`` (Hz; None: no GNSS) the recording carries a GNSS velocity stream (ENU,
    white noise of ``gnss_vel_noise`` m/s per axis) sampled from the true velocity, which starts at
    ``initial_velocity`` (m/s, ENU): an epoch every ``round(rate / gnss_rate)`` samples (every
    sample at a rate above the IMU's).

    ``errors``: a :class:`~fusionkit.sim.SensorErrors` (hard and soft iron, earth-fixed magnetic
    disturbances, delays and low-passes, scale factors and misalignments, bias random walks,
    vibration, taps, dropped samples, timestamp gaps; :mod:`fusionkit.sim.errors`); None or an
    empty one simulates exactly what it did without. With errors, ``meta`` also holds
    ``errors``, ``ref_pos`` (the true position, m, ENU, from the start: the segments'
    displacements plus ``initial_velocity`` times the time), ``gyr_bias`` and
    ``acc_bias`` (the true biases per sample) and ``kept`` (the indices of the rows kept out of
    the uniform grid).
    """
    rate = _err._positive("rate", rate, "Hz")  # (NaN, "100": numpy's or Python's error)
    if sampling not in ("mean", "point"):
        raise InputError(f"sampling must be 'mean' or 'point', got {sampling!r}")
    if errors is not None and not isinstance(errors, SensorErrors):
        raise InputError(f"errors must be a fusionkit.sim.SensorErrors or None, got {type(errors).__name__}")
    if not isinstance(noise, Noise):
        raise InputError(f"noise must be a fusionkit.sim.Noise, got {noise!r:.80}")
    if gnss_rate is None or gnss_rate is False or (isinstance(gnss_rate, (int, float, np.integer, np.floating))
                                                   and gnss_rate == 0):
        gnss_rate = None  # (None, 0 and False: no GNSS, as always)
    else:  # (-5 gave an epoch every sample; anything else not a number is named by _positive)
        gnss_rate = _err._positive("gnss_rate", gnss_rate, "Hz; None or 0: no GNSS")
    gnss_vel_noise = _err._nonneg("gnss_vel_noise", gnss_vel_noise)
    mag_field = _err._vec("mag_field", mag_field)
    initial_velocity = _err._vec("initial_velocity", initial_velocity)
    if errors is not None and errors.mag_rate is not None and errors.mag_rate > rate:
        raise InputError(f"SensorErrors.mag_rate ({errors.mag_rate} Hz) is above the IMU's rate ({rate} Hz): a "
                         "magnetometer read faster than the IMU is sampled cannot be simulated (use mag_rate <= rate, "
                         "or None)")
    if isinstance(segments, (Rest, Rotate, Translate)) or not hasattr(segments, "__iter__"):
        raise InputError(f"segments must be a list of Rest, Rotate and Translate, got {segments!r:.80}")
    segments = list(segments)
    if not segments:
        raise InputError("segments is empty")
    for seg in segments:
        if not isinstance(seg, (Rest, Rotate, Translate)):
            raise InputError(f"unknown segment {seg!r}: use Rest, Rotate or Translate")
    dt = 1.0 / rate
    counts = [max(1, int(round(s.duration * rate))) for s in segments]
    n = sum(counts) + 1
    quat = np.empty((n, 4))
    acc_e = np.zeros((n, 3))
    moving = np.zeros(n, bool)
    gyr = np.zeros((n, 3))
    initial = _err._vec("initial", initial, 4)
    if not any(initial):
        raise InputError("initial must be a quaternion (w, x, y, z), not all zero")
    q = quat_normalize(np.asarray(initial))
    quat[0] = q
    g_e = np.array([0.0, 0.0, gravity])
    m_e = np.asarray(mag_field, dtype=float)
    acc, mag = np.empty((n, 3)), np.empty((n, 3))
    acc[0], mag[0] = quat_to_matrix(q).T @ g_e, quat_to_matrix(q).T @ m_e
    nodes, weights = np.polynomial.legendre.leggauss(_QUADRATURE_NODES)
    nodes = 0.5 * (nodes + 1.0)  # on (0, 1)
    weights = 0.5 * weights
    disturbed = errors is not None and bool(errors.dipoles or errors.patches)
    lever = None if errors is None or not any(errors.lever_arm) else errors.lever_arm
    pos = np.zeros((n, 3))  # the segments' displacement (m, ENU) from the start; + v0 t: the true position
    p = np.zeros(3)
    v0 = np.asarray(initial_velocity)
    k = 1
    for seg, m in zip(segments, counts):
        u = np.arange(1, m + 1) / m  # progress at the segment's samples
        quat[k:k + m], acc_e[k:k + m] = _segment_motion(seg, q, u, m * dt)
        if isinstance(seg, Rotate):
            axis = np.asarray(seg.axis, dtype=float)
            ang = seg.angle * _progress(u)
            gyr[k:k + m] = np.diff(np.concatenate([[0.0], ang]))[:, None] / dt * (axis / np.linalg.norm(axis))
        moving[k:k + m] = not isinstance(seg, Rest)
        pos[k:k + m] = _segment_position(seg, p, u)
        if disturbed:
            def field(v, seg=seg, p=p, k=k, m=m):  # the earth's field plus its disturbances at progress v
                t = (k - 1 + v * m) * dt
                return m_e + _err.earth_disturbance(errors, _segment_position(seg, p, v) + t[:, None] * v0, t)
        else:
            def field(v):
                return m_e
        if sampling == "point":
            acc[k:k + m] = _in_body(quat[k:k + m], acc_e[k:k + m] + g_e)
            if lever is not None:
                acc[k:k + m] += _lever_arm_force(seg, u, m * dt, lever)
            mag[k:k + m] = _in_body(quat[k:k + m], field(u))
        else:  # the means over each sample's interval ((j - 1) / m, j / m]
            acc[k:k + m] = mag[k:k + m] = 0.0
            for c, w in zip(nodes, weights):
                qn, an = _segment_motion(seg, q, (np.arange(m) + c) / m, m * dt)
                acc[k:k + m] += w * _in_body(qn, an + g_e)
                if lever is not None:
                    acc[k:k + m] += w * _lever_arm_force(seg, (np.arange(m) + c) / m, m * dt, lever)
                mag[k:k + m] += w * _in_body(qn, field((np.arange(m) + c) / m))
        q = quat[k + m - 1].copy()
        p = pos[k + m - 1].copy()
        k += m
    if disturbed:
        mag[0] = quat_to_matrix(quat[0]).T @ (m_e + _err.earth_disturbance(errors, pos[:1], np.zeros(1))[0])
    extra = {}
    if errors is not None:
        gyr, acc, mag, extra = _apply_errors(errors, gyr, acc, mag, rate, sampling, seed)
    rng = np.random.default_rng(seed)
    gyr = gyr + np.asarray(noise.gyr_bias) + noise.gyr_noise * rng.standard_normal((n, 3))
    acc = acc + np.asarray(noise.acc_bias) + noise.acc_noise * rng.standard_normal((n, 3))
    mag = mag + noise.mag_noise * rng.standard_normal((n, 3))
    if errors is not None and errors.mag_rate is not None:  # sample and hold: the reading, noise and all
        mag = mag[_err.held_source(n, errors.mag_rate, rate)]
    epochs = None  # the GNSS epochs: (sample indices, velocities)
    if gnss_rate:
        vel = v0 + np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (acc_e[1:] + acc_e[:-1]) * dt, axis=0)])
        step = max(1, int(round(rate / gnss_rate)))
        idx = np.arange(0, n, step)
        epochs = idx, vel[idx] + gnss_vel_noise * rng.standard_normal((idx.size, 3))
    meta = {"simulated": True, "noise": noise, "gravity": gravity}
    if errors is None:
        return Recording(gyr=gyr, acc=acc, mag=mag, rate=rate, truth=quat, truth_frame="ENU", movement=moving,
                         gnss=_gnss(epochs, np.arange(n) / rate), name=name, meta=meta)
    pos += np.arange(n)[:, None] * dt * v0  # (the GNSS velocity had the initial velocity, ref_pos did not)
    meta.update(errors=errors, ref_pos=pos, gyr_bias=extra["gyr_bias"] + np.asarray(noise.gyr_bias),
                acc_bias=extra["acc_bias"] + np.asarray(noise.acc_bias))
    kept = _err.kept_rows(errors, np.arange(n) * dt, extra["rng"])
    if len(kept) == n:
        meta["kept"] = kept
        return Recording(gyr=gyr, acc=acc, mag=mag, rate=rate, truth=quat, truth_frame="ENU", movement=moving,
                         gnss=_gnss(epochs, np.arange(n) / rate), name=name, meta=meta)
    for key in ("ref_pos", "gyr_bias", "acc_bias"):
        meta[key] = meta[key][kept]
    meta["kept"] = kept
    return Recording(gyr=gyr[kept], acc=acc[kept], mag=mag[kept], t=kept * dt, truth=quat[kept], truth_frame="ENU",
                     movement=moving[kept], gnss=_gnss(epochs, np.arange(n) * dt), name=name, meta=meta)


def _gnss(epochs, clock: np.ndarray) -> Gnss | None:
    """The GNSS stream of ``epochs`` (sample indices, ENU velocities; None: none) on the IMU's
    clock: ``clock`` holds its sample times as the recording computes them (``k / rate``, or the
    timestamps ``k * dt`` of a recording with lost rows). Epoch times ``idx * dt`` rounded past
    ``(n - 1) / rate``, the last sample's, and its epoch was dropped with a false warning."""
    return None if epochs is None else Gnss(t=clock[epochs[0]], vel=epochs[1], frame="ENU")


def _apply_errors(errors: SensorErrors, gyr, acc, mag, rate, sampling, seed):
    """The sensor's own errors on the ideal samples, in a real sensor's order (the world's
    vibration and taps, delays, low-passes, scale and misalignment or iron, bias random walks);
    their random draws come from a stream of their own."""
    n, dt = len(gyr), 1.0 / rate
    rng = np.random.default_rng(None if seed is None else [int(seed), 14])
    acc = acc + _err.specific_force_extra(errors, np.arange(n) * dt, dt, sampling, rng)
    e = errors
    gyr = _err.lowpassed(_err.delayed(gyr, e.gyr_delay * rate), e.gyr_lowpass, rate, e.lowpass_order)
    acc = _err.lowpassed(_err.delayed(acc, e.acc_delay * rate), e.acc_lowpass, rate, e.lowpass_order)
    mag = _err.lowpassed(_err.delayed(mag, e.mag_delay * rate), e.mag_lowpass, rate, e.lowpass_order)
    gyr = _err.scaled(gyr, e.gyr_scale, e.gyr_misalignment)
    acc = _err.scaled(acc, e.acc_scale, e.acc_misalignment)
    if e.mag_matrix is not None:
        mag = mag @ e.mag_matrix.T
    mag = mag + np.asarray(e.mag_offset)
    gyr_bias = _err.random_walk(n, e.gyr_bias_rw, dt, rng) if e.gyr_bias_rw else np.zeros((n, 3))
    acc_bias = _err.random_walk(n, e.acc_bias_rw, dt, rng) if e.acc_bias_rw else np.zeros((n, 3))
    return gyr + gyr_bias, acc + acc_bias, mag, {"gyr_bias": gyr_bias, "acc_bias": acc_bias, "rng": rng}
