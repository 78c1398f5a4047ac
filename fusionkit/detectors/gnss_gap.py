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
from ..gnss_rows import NO_GNSS, gnss_per_sample, gnss_sample_rows
from ..protocols import DetectionResult, Detector, DetectorKernel, Sample
from ..types import Flag

__all__ = ["GnssGapDetector", "GnssGapConfig", "NO_GNSS", "gnss_gap_step", "gnss_per_sample", "gnss_sample_rows"]


class GnssGapConfig(PluginConfig):
    max_age: float = param(0.5, unit="s", description="an epoch older than this is stale (a gap)", gt=0)
    min_speed: float = param(5.0, unit="m/s", description="below this ground speed the track angle is not used", ge=0)


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
        from ._run import run_detector

        if rec.gnss is None:
            raise InputError(f"recording {rec.name!r} has no GNSS stream")
        return run_detector(self, rec, nan_policy=nan_policy, backend=backend, every_sample=True)


@njit
def gnss_gap_step(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p, vn, ve, valid, age, new, t_epoch):
    """The kernel of :meth:`GnssGapDetector.step`: ``p`` = (max_age, min_speed)."""
    if valid == 0.0 or age > p[0]:
        return 1
    return 2 if math.hypot(vn, ve) < p[1] else 0
