"""Read the simulated IMU + GNSS scenarios (gnss-ins-sim HDF5, see ../shared/data/gnss/README.md).

The recording keeps the file's frames: body FRD (``Recording.body``), ``truth`` = ``ref_quat`` body->NED
(``truth_frame="NED"``), GNSS velocity in NED. Attributes and the reference velocity/position
are kept in ``meta``. (Not as ``ref_pos``, the reference position that
:func:`fusionkit.benchmarking.timing.sensor_lags` differentiates: the file's position times like
``p[k] = p[k-1] + v[k-1] dt``, one sample behind its velocity (measured), and would time the
accelerometer a sample early.)

Timing: the file holds each rate forward, over ``[t[k], t[k+1])`` (its README), where fusionkit
reads sample ``k`` as the interval that ends at ``t[k]``; ``fusionkit lags`` measures the gyro
half a sample ahead of the reference (-0.50). The recording is kept as the file has it: moving
every sensor one sample (gyro ``k`` paired with the reference at ``k + 1``) changes the source
001 results by at most 0.016 deg (car heading after 200 s 0.113 -> 0.097), at these vehicles'
rates (at most 41 deg/s, 100 Hz).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..types import Gnss, Recording
from ._guard import file_errors

__all__ = ["load_gnss_scenario", "is_gnss_scenario"]


@file_errors("HDF5")
def is_gnss_scenario(path) -> bool:
    import h5py

    with h5py.File(path, "r") as f:
        return "imu_time" in f and "gnss_time" in f


@file_errors("HDF5")
def load_gnss_scenario(path) -> Recording:
    import h5py

    p = Path(path)
    with h5py.File(p, "r") as f:
        missing = [k for k in ("imu_time", "imu_gyr", "imu_acc", "gnss_time", "gnss_vel_ned", "gnss_valid") if k not in f]
        if missing:
            raise InputError(f"{p.name}: not a GNSS scenario file, missing {missing}")
        attrs = {k: (v.item() if hasattr(v, "item") and np.size(v) == 1 else v) for k, v in f.attrs.items()}
        outages = attrs.get("gnss_outages_s")
        gnss = Gnss(
            t=f["gnss_time"][:], vel=f["gnss_vel_ned"][:], valid=f["gnss_valid"][:].astype(bool), frame="NED",
            pos=f["gnss_pos_ned"][:] if "gnss_pos_ned" in f else None,
        )
        t = f["imu_time"][:]
        meta = {
            "path": str(p), "dataset": "gnss-ins-sim",
            "ref_vel_ned": f["ref_vel_ned"][:] if "ref_vel_ned" in f else None,
            "ref_pos_ned": f["ref_pos_ned"][:] if "ref_pos_ned" in f else None,
            "gnss_outages_s": json.loads(outages) if isinstance(outages, str) else outages,
            "attrs": attrs,
        }
        return Recording(
            gyr=f["imu_gyr"][:], acc=f["imu_acc"][:], mag=f["imu_mag"][:] if "imu_mag" in f else None,
            t=t, gnss=gnss, truth=f["ref_quat"][:] if "ref_quat" in f else None, truth_frame="NED",
            name=p.stem, meta=meta, body="FRD",
        )
