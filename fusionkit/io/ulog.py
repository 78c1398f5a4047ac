"""Read PX4 ULog flight logs with pyulog (``pip install "fusionkit[ulog]"``).

IMU from ``sensor_combined`` (gyro rad/s, accelerometer m/s^2, body FRD, ``Recording.body``; the accelerometer is
specific force), the magnetometer from ``vehicle_magnetometer`` (gauss, held to the IMU times),
GPS velocity from ``vehicle_gps_position`` as a NED :class:`~fusionkit.types.Gnss` stream (valid
where ``vel_ned_valid`` and a 3D fix), and as ``truth`` (body->NED) the simulator's ``vehicle_attitude_groundtruth`` where the log has
it, else the autopilot's own ``vehicle_attitude`` estimate: ``meta["truth_kind"]`` says which
(an estimate is a reference to agree with, not the truth).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Gnss, Recording
from ._guard import file_errors

__all__ = ["load_ulog"]


def _topic(ulog, name):
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0:
            return d.data
    return None


def _vec(data, prefix, n=3):
    return np.column_stack([data[f"{prefix}[{i}]"] for i in range(n)]).astype(float)


@file_errors("ULog")
def load_ulog(path) -> Recording:
    try:
        from pyulog import ULog
    except ImportError as exc:
        raise InputError("reading .ulg needs pyulog: pip install 'fusionkit[ulog]'") from exc
    from scipy.spatial.transform import Rotation, Slerp

    p = Path(path)
    ulog = ULog(str(p))
    sc = _topic(ulog, "sensor_combined")
    if sc is None:
        raise InputError(f"{p.name}: no sensor_combined topic")
    t_us = sc["timestamp"].astype(np.int64)
    keep = np.concatenate([[True], np.diff(t_us) > 0])  # drop repeated timestamps
    t = t_us[keep] / 1e6
    gyr, acc = _vec(sc, "gyro_rad")[keep], _vec(sc, "accelerometer_m_s2")[keep]
    mag = None
    vm = _topic(ulog, "vehicle_magnetometer")
    if vm is not None and len(vm["timestamp"]) > 1:
        tm = vm["timestamp"] / 1e6
        m = _vec(vm, "magnetometer_ga")
        idx = np.clip(np.searchsorted(tm, t, side="right") - 1, 0, len(tm) - 1)  # sample and hold
        mag = m[idx]
        mag[t < tm[0]] = m[0]
    gnss = None
    gps = _topic(ulog, "vehicle_gps_position")
    if gps is not None and len(gps["timestamp"]) > 1 and "vel_n_m_s" in gps:
        tg = gps["timestamp"] / 1e6 - t[0]
        _, first = np.unique(tg, return_index=True)
        vel = np.column_stack([gps["vel_n_m_s"], gps["vel_e_m_s"], gps["vel_d_m_s"]])[first]
        valid = (gps["vel_ned_valid"].astype(bool) & (gps["fix_type"] >= 3))[first]
        inside = (tg[first] >= 0) & (tg[first] <= t[-1] - t[0])
        if inside.sum() > 1:
            gnss = Gnss(t=tg[first][inside], vel=vel[inside], valid=valid[inside], frame="NED")
    truth, kind = None, "none"
    for topic, label in (("vehicle_attitude_groundtruth", "ground truth (simulator)"),
                         ("vehicle_attitude", "autopilot estimate")):
        att = _topic(ulog, topic)
        if att is not None and len(att["timestamp"]) > 1:
            ta = att["timestamp"] / 1e6
            q = _vec(att, "q", 4)
            _, first = np.unique(ta, return_index=True)
            ta, q = ta[first], q[first]
            slerp = Slerp(ta, Rotation.from_quat(q[:, [1, 2, 3, 0]]))
            inside = (t >= ta[0]) & (t <= ta[-1])
            truth = np.full((len(t), 4), np.nan)
            truth[inside] = slerp(t[inside]).as_quat()[:, [3, 0, 1, 2]]
            kind = label
            break
    return Recording(gyr=gyr, acc=acc, mag=mag, t=t - t[0], gnss=gnss, truth=truth, truth_frame="NED", name=p.stem,
                     body="FRD", meta={"path": str(p), "dataset": "ulog", "truth_kind": kind,
                           "t0_s": float(t[0])})
