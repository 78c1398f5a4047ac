"""GNSS availability per IMU sample: the GNSS-gap detector.

GNSS counts as usable on an IMU sample when the latest epoch at or before it is valid (flag set
and finite velocity) and not older than ``max_age``. The track angle is usable only above
``min_speed`` (below it the direction of a noisy velocity means nothing). The kernel
(:func:`gnss_gap_step`) takes the sample's GNSS row, which a compiled pipeline passes to it.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..errors import InputError
from ..protocols import DetectionResult, Detector, DetectorKernel, Sample
from ..types import Flag, Recording

__all__ = ["GnssGapDetector", "GnssGapConfig", "NO_GNSS", "gnss_gap_step", "gnss_per_sample", "gnss_sample_rows"]


class GnssGapConfig(PluginConfig):
    max_age: float = param(0.5, unit="s", description="an epoch older than this is stale (a gap)", gt=0)
    min_speed: float = param(5.0, unit="m/s", description="below this ground speed the track angle is not used", ge=0)


def gnss_per_sample(rec: Recording) -> dict[str, np.ndarray]:
    """The latest GNSS epoch at each IMU sample: ``vel`` (N, 3, in the stream's frame, NaN
    before the first epoch), ``valid`` (N,), ``age`` (N, s), ``new`` (N,: an epoch arrived
    with this sample), ``index`` (N,, -1 before the first epoch), ``t`` (N,, the epoch's time)."""
    g = rec.gnss
    if g is None:
        raise InputError(f"recording {rec.name!r} has no GNSS stream")
    t = rec.time
    idx = np.searchsorted(g.t, t, side="right") - 1
    has = idx >= 0
    safe = np.clip(idx, 0, None)
    vel = np.where(has[:, None], g.vel[safe], np.nan)
    valid = has & g.valid[safe]
    age = np.where(has, t - g.t[safe], np.inf)
    new = has & np.concatenate([[True], idx[1:] != idx[:-1]])
    t_epoch = np.where(has, g.t[safe], np.nan)
    return {"vel": vel, "valid": valid, "age": age, "new": new, "index": idx, "t": t_epoch}


#: the GNSS row of a sample without GNSS (vn, ve, valid, age, new, t_epoch)
NO_GNSS = np.array([np.nan, np.nan, 0.0, np.inf, 0.0, np.nan])


def gnss_sample_rows(rec: Recording) -> np.ndarray:
    """(N, 6) rows ``vn, ve, valid, age, new, t_epoch`` (velocity north/east in m/s) of the
    latest GNSS epoch at each IMU sample: what GNSS-aided filters take per sample (also through
    ``update(..., gnss=row)``). Without a GNSS stream every row is a gap."""
    from ..conventions import frame_matrix

    out = np.tile(NO_GNSS, (len(rec), 1))
    if rec.gnss is None:
        return out
    per = gnss_per_sample(rec)
    vel = per["vel"] @ frame_matrix(rec.gnss.frame, "NED").T
    out[:, 0], out[:, 1] = vel[:, 0], vel[:, 1]
    out[:, 2], out[:, 3], out[:, 4], out[:, 5] = per["valid"], per["age"], per["new"], per["t"]
    return out


class GnssGapDetector(Detector):
    """Flags the samples without usable GNSS (bit 0 ``gap``) and with a too low ground speed
    for a track angle (bit 1 ``low_speed``)."""

    name: ClassVar[str] = "gnss-gap"
    Config = GnssGapConfig
    flag: ClassVar[Flag] = Flag.GNSS_GAP
    criteria_names: ClassVar[tuple[str, ...]] = ("gap", "low_speed")
    source: ClassVar[str] = "001 (GST with GNSS correction): GNSS gap mode k = 0"
    summary: ClassVar[str] = "GNSS gaps (validity, staleness) and low ground speed, per IMU sample"

    def initial_state(self, dt: float) -> np.ndarray:
        return np.zeros(0)

    def classify(self, valid: bool, age: float, vn: float, ve: float) -> int:
        if not valid or age > self.config.max_age:
            return 1
        return 2 if np.hypot(vn, ve) < self.config.min_speed else 0

    def step(self, state, sample: Sample) -> int:
        g = sample.gnss  # the row vn, ve, valid, age, new, t_epoch, or None without a stream
        if g is None:
            return 1
        return self.classify(bool(g[2]), g[3], g[0], g[1])

    def kernel(self) -> DetectorKernel:
        return DetectorKernel(gnss_gap_step, np.array([self.config.max_age, self.config.min_speed]), gnss=True)

    def run(self, rec, *, nan_policy: str = "raise", backend: str = "auto") -> DetectionResult:
        """Every sample is classified (GNSS does not depend on the IMU sample being valid)."""
        from ..pipeline import run_detector

        if rec.gnss is None:
            raise InputError(f"recording {rec.name!r} has no GNSS stream")
        return run_detector(self, rec, nan_policy=nan_policy, backend=backend, every_sample=True)


@njit
def gnss_gap_step(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p, vn, ve, valid, age, new, t_epoch):
    """The kernel of :meth:`GnssGapDetector.step`: ``p`` = (max_age, min_speed)."""
    if valid == 0.0 or age > p[0]:
        return 1
    return 2 if math.hypot(vn, ve) < p[1] else 0
