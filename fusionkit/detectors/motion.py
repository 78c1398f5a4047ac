"""Source 000's "motion sensor": detects the moment a still IMU starts to move.

It fires when ANY enabled criterion fires (section 5.2). Statistics are estimated while the IMU
is still "with the current mean": every sample is tested against the mean and standard
deviation of the quiet samples before it, and only quiet samples update them. Criteria are
armed once ``arm_after`` seconds of data have been seen (the document's mandatory 10 s
alignment). After the first firing (the onset) the statistics are frozen; later samples are
still tested against them, so the per-sample output also marks later motion.

Criteria (bit, name):

0. ``acc_norm``: ``| |f| - mean|f| | > 10 sigma|f|``
1. ``gyr_norm``: ``| |w| - mean|w| | > 20 sigma|w|``
2. ``dot``: ``| f.w - mean(f.w) | > 10 sigma(f.w)`` (fires with some delay)
3. ``angle``: ``| integral over the last 0.1 s of (w - bias) | > 0.01 rad``
4. ``velocity``: ``| integral over the last 0.1 s of (L^T f - [0, g, 0]) | > 0.02 m/s``, with L
   from the current alignment attitude (fires with about 0.1 s delay).

With L from the mean specific force ``f_m``, ``L^T f_m = [0, |f_m|, 0]``, so the velocity
integral equals ``|sum(f dt) - g T u|`` with ``u = f_m / |f_m|``; this is what is computed, with
:func:`fusionkit.navigation.strapdown.velocity_increment`. The thresholds come from an allowed
error of 0.01 deg over 10 s at 250 Hz. Motions it cannot see: sliding down a slope with almost
no rotation, a lift accelerating without rotation.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..conventions import GRAVITY
from ..navigation.alignment import alignment_quat
from ..navigation.strapdown import velocity_increment
from ..protocols import Detector, DetectorKernel, Sample
from ..rotations import quat_to_matrix
from ..types import Flag

__all__ = ["MotionDetector", "MotionConfig", "CRITERIA"]

CRITERIA = ("acc_norm", "gyr_norm", "dot", "angle", "velocity")


class MotionConfig(PluginConfig):
    acc_norm: bool = param(True, unit="-", description="enable criterion 1: accelerometer norm")
    acc_norm_sigma: float = param(10.0, unit="sigma", description="criterion 1 threshold", gt=0)
    gyr_norm: bool = param(True, unit="-", description="enable criterion 2: gyroscope norm")
    gyr_norm_sigma: float = param(20.0, unit="sigma", description="criterion 2 threshold", gt=0)
    dot: bool = param(True, unit="-", description="enable criterion 3: dot product f.w")
    dot_sigma: float = param(10.0, unit="sigma", description="criterion 3 threshold", gt=0)
    angle: bool = param(True, unit="-", description="enable criterion 4: angle integral")
    angle_threshold: float = param(0.01, unit="rad", description="criterion 4 threshold", gt=0)
    velocity: bool = param(True, unit="-", description="enable criterion 5: velocity integral")
    velocity_threshold: float = param(0.02, unit="m/s", description="criterion 5 threshold", gt=0)
    window: float = param(0.1, unit="s", description="integration window of criteria 4 and 5", gt=0)
    arm_after: float = param(
        10.0, unit="s", description="statistics gathered before any criterion may fire (mandatory alignment)", ge=0
    )
    gravity: float = param(GRAVITY, unit="m/s^2", description="gravity model of criterion 5 (source 000)", gt=0)
    gravity_source: Literal["model", "measured"] = param(
        "model",
        unit="-",
        description="criterion 5 subtracts 'model' gravity (source 000) or the 'measured' mean |f| "
        "(insensitive to accelerometer scale error)",
    )
    once: bool = param(
        False, unit="-", description="stop at the onset: after its first firing every sample is quiet, untested (a "
        "detector that only ends an alignment: nothing reads it afterwards, and it costs nothing more)")


# state layout
_N, _SF, _SW, _MF, _M2F, _MW, _M2W, _MD, _M2D = 0, 1, 4, 7, 8, 9, 10, 11, 12
_LATCH, _POS, _FILL, _WDT, _DT, _FDT, _SEEN, _NW, _RING = 13, 14, 15, 16, 19, 20, 23, 24, 25
_SLOT = 7  # per ring slot: w dt (3), dt (1), f dt (3)


def armed_for_alignment(motion: MotionConfig, duration: float, early: bool) -> MotionConfig:
    """The detector that ends an alignment of mandatory ``duration`` s: armed after
    :data:`~fusionkit.navigation.alignment.STATISTICS_TIME` (``early``: motion inside the
    mandatory time is seen, and ends the alignment there, reported) or when the mandatory time
    ends (source 000), unless ``arm_after`` was set explicitly."""
    from ..navigation.alignment import STATISTICS_TIME

    if "arm_after" in motion.model_fields_set:
        return motion
    return motion.model_copy(update={"arm_after": min(STATISTICS_TIME, duration) if early else duration})


class MotionDetector(Detector):
    """Source 000's five-criterion motion detector."""

    name: ClassVar[str] = "motion"
    Config = MotionConfig
    flag: ClassVar[Flag] = Flag.MOTION
    criteria_names: ClassVar[tuple[str, ...]] = CRITERIA
    source: ClassVar[str] = "000 (AIST-350 report), section 5"
    summary: ClassVar[str] = "motion onset from five criteria (acc norm, gyro norm, f.w, angle and velocity integrals)"

    def window_samples(self, dt: float) -> int:
        return max(1, int(round(self.config.window / dt)))

    def initial_state(self, dt: float) -> np.ndarray:
        nw = self.window_samples(dt)
        s = np.zeros(_RING + _SLOT * nw)
        s[_NW] = nw
        return s

    # -- readable reference ----------------------------------------------------------------
    def step(self, s: np.ndarray, sample: Sample) -> int:
        cfg = self.config
        if cfg.once and s[_LATCH] != 0.0:
            return 0
        w, f, dt = sample.gyr, sample.acc, sample.dt
        # the sliding window of criteria 4 and 5: a ring of (w dt, dt, f dt) and its running sums
        slots = s[_RING:].reshape(int(s[_NW]), _SLOT)
        pos = int(s[_POS])
        if s[_FILL] == s[_NW]:
            s[_WDT:_WDT + 3] -= slots[pos, 0:3]
            s[_DT] -= slots[pos, 3]
            s[_FDT:_FDT + 3] -= slots[pos, 4:7]
        else:
            s[_FILL] += 1
        slots[pos] = np.concatenate([w * dt, [dt], f * dt])
        s[_WDT:_WDT + 3] += slots[pos, 0:3]
        s[_DT] += slots[pos, 3]
        s[_FDT:_FDT + 3] += slots[pos, 4:7]
        s[_POS] = (pos + 1) % int(s[_NW])

        nf, nw, fw = float(np.linalg.norm(f)), float(np.linalg.norm(w)), float(f @ w)
        bits = 0
        n = s[_N]
        if s[_SEEN] >= cfg.arm_after and n >= 2:
            sd_f = math.sqrt(s[_M2F] / (n - 1))
            sd_w = math.sqrt(s[_M2W] / (n - 1))
            sd_d = math.sqrt(s[_M2D] / (n - 1))
            if cfg.acc_norm and abs(nf - s[_MF]) > cfg.acc_norm_sigma * sd_f:
                bits |= 1
            if cfg.gyr_norm and abs(nw - s[_MW]) > cfg.gyr_norm_sigma * sd_w:
                bits |= 2
            if cfg.dot and abs(fw - s[_MD]) > cfg.dot_sigma * sd_d:
                bits |= 4
            if cfg.angle:
                bias = s[_SW:_SW + 3] / n
                angle = s[_WDT:_WDT + 3] - bias * s[_DT]
                if np.linalg.norm(angle) > cfg.angle_threshold:
                    bits |= 8
            if cfg.velocity:
                f_mean = s[_SF:_SF + 3] / n
                g = cfg.gravity if cfg.gravity_source == "model" else float(np.linalg.norm(f_mean))
                # L from the current alignment attitude: body -> N-Up-E, heading 0
                c_nue_body = quat_to_matrix(alignment_quat(f_mean, frame="NUE"))
                dv = velocity_increment(c_nue_body, s[_FDT:_FDT + 3], [0.0, g, 0.0], s[_DT])
                if np.linalg.norm(dv) > cfg.velocity_threshold:
                    bits |= 16
        if s[_LATCH] == 0.0:
            if bits:
                s[_LATCH] = 1.0
            else:  # a quiet sample: update the statistics (Welford)
                s[_N] = n = n + 1
                s[_SF:_SF + 3] += f
                s[_SW:_SW + 3] += w
                for k, x in ((_MF, nf), (_MW, nw), (_MD, fw)):
                    d = x - s[k]
                    s[k] += d / n
                    s[k + 1] += d * (x - s[k])
        s[_SEEN] += dt
        return bits

    def kernel(self) -> DetectorKernel:
        c = self.config
        p = np.array([
            float(c.acc_norm), c.acc_norm_sigma, float(c.gyr_norm), c.gyr_norm_sigma, float(c.dot), c.dot_sigma,
            float(c.angle), c.angle_threshold, float(c.velocity), c.velocity_threshold, c.arm_after,
            c.gravity, float(c.gravity_source == "measured"), float(c.once),
        ])
        return DetectorKernel(_motion_step, p)


@njit
def _motion_step(s, g0, g1, g2, a0, a1, a2, m0, m1, m2, dt, p):
    if s[_LATCH] != 0.0 and p[13] != 0.0:  # once: stopped at the onset
        return 0
    nwin = int(s[_NW])
    pos = int(s[_POS])
    base = _RING + _SLOT * pos
    if int(s[_FILL]) == nwin:
        s[_WDT] -= s[base]
        s[_WDT + 1] -= s[base + 1]
        s[_WDT + 2] -= s[base + 2]
        s[_DT] -= s[base + 3]
        s[_FDT] -= s[base + 4]
        s[_FDT + 1] -= s[base + 5]
        s[_FDT + 2] -= s[base + 6]
    else:
        s[_FILL] += 1.0
    s[base] = g0 * dt
    s[base + 1] = g1 * dt
    s[base + 2] = g2 * dt
    s[base + 3] = dt
    s[base + 4] = a0 * dt
    s[base + 5] = a1 * dt
    s[base + 6] = a2 * dt
    s[_WDT] += s[base]
    s[_WDT + 1] += s[base + 1]
    s[_WDT + 2] += s[base + 2]
    s[_DT] += s[base + 3]
    s[_FDT] += s[base + 4]
    s[_FDT + 1] += s[base + 5]
    s[_FDT + 2] += s[base + 6]
    s[_POS] = (pos + 1) % nwin

    nf = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    nw = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    fw = a0 * g0 + a1 * g1 + a2 * g2
    bits = 0
    n = s[_N]
    if s[_SEEN] >= p[10] and n >= 2:
        if p[0] != 0.0 and abs(nf - s[_MF]) > p[1] * math.sqrt(s[_M2F] / (n - 1)):
            bits |= 1
        if p[2] != 0.0 and abs(nw - s[_MW]) > p[3] * math.sqrt(s[_M2W] / (n - 1)):
            bits |= 2
        if p[4] != 0.0 and abs(fw - s[_MD]) > p[5] * math.sqrt(s[_M2D] / (n - 1)):
            bits |= 4
        if p[6] != 0.0:
            e0 = s[_WDT] - s[_SW] / n * s[_DT]
            e1 = s[_WDT + 1] - s[_SW + 1] / n * s[_DT]
            e2 = s[_WDT + 2] - s[_SW + 2] / n * s[_DT]
            if math.sqrt(e0 * e0 + e1 * e1 + e2 * e2) > p[7]:
                bits |= 8
        if p[8] != 0.0:
            fm0, fm1, fm2 = s[_SF] / n, s[_SF + 1] / n, s[_SF + 2] / n
            fmn = math.sqrt(fm0 * fm0 + fm1 * fm1 + fm2 * fm2)
            g = fmn if p[12] != 0.0 else p[11]
            # |L^T sum(f dt) - [0, g T, 0]| = |sum(f dt) - g T f_m/|f_m||
            v0 = s[_FDT] - g * s[_DT] * fm0 / fmn
            v1 = s[_FDT + 1] - g * s[_DT] * fm1 / fmn
            v2 = s[_FDT + 2] - g * s[_DT] * fm2 / fmn
            if math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) > p[9]:
                bits |= 16
    if s[_LATCH] == 0.0:
        if bits != 0:
            s[_LATCH] = 1.0
        else:
            n = n + 1.0
            s[_N] = n
            s[_SF] += a0
            s[_SF + 1] += a1
            s[_SF + 2] += a2
            s[_SW] += g0
            s[_SW + 1] += g1
            s[_SW + 2] += g2
            d = nf - s[_MF]
            s[_MF] += d / n
            s[_M2F] += d * (nf - s[_MF])
            d = nw - s[_MW]
            s[_MW] += d / n
            s[_M2W] += d * (nw - s[_MW])
            d = fw - s[_MD]
            s[_MD] += d / n
            s[_M2D] += d * (fw - s[_MD])
    s[_SEEN] += dt
    return bits
