"""The ``poisson`` filter: source 000 end to end.

Initial alignment while still (pitch and roll from the mean specific force, heading 0, gyro bias
= mean gyro output), for at least ``alignment_duration`` s and, in mode ``motion``, until the
motion detector fires; then Poisson integration of the bias-corrected rates. No aiding sensor
corrects it afterwards: its error grows with the residual gyro bias and noise.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from ..config import AlignmentConfig, FilterConfig, PipelineConfig, PluginSpec, param
from ..detectors.motion import MotionConfig, armed_for_alignment
from ..pipeline import Pipeline

__all__ = ["PoissonFilter"]


class PoissonConfig(FilterConfig):
    estimator: Literal["poisson-quat", "poisson-dcm"] = param(
        "poisson-quat", unit="-", description="quaternion (source 000) or DCM (source 004) integrator"
    )
    step: Literal["first-order", "exact"] = param(
        "first-order", unit="-", description="poisson-quat step: source 000's first-order one or the exact one"
    )
    alignment: Literal["motion", "fixed"] = param(
        "motion",
        unit="-",
        description="'motion': align until the motion detector fires (at least alignment_duration); "
        "'fixed': align for exactly alignment_duration",
    )
    alignment_duration: float = param(10.0, unit="s", description="mandatory alignment time (source 000)", gt=0)
    heading: Literal["zero", "magnetometer"] = param(
        "zero", unit="-", description="initial heading: 'zero' = body x to north (source 000's heading 0; ENU yaw 90 deg) "
        "or from the mean magnetometer"
    )
    motion: MotionConfig = param(MotionConfig(), unit="-", description="motion detector settings (source 000, section 5)")
    early_motion: bool = param(
        True, unit="-", description="extension: the motion detector is armed after 2 s of statistics, so that motion "
        "inside the mandatory alignment ends it there (never averaged in) with a warning; False: armed when the "
        "mandatory alignment ends (source 000, which assumes the IMU still)")


class PoissonFilter(Pipeline):
    """Source 000: initial alignment, motion detector, Poisson integration."""

    name: ClassVar[str] = "poisson"
    Config = PoissonConfig
    source: ClassVar[str] = "000 (AIST-350 report): alignment, Poisson integration, motion sensor"
    summary: ClassVar[str] = "gyro-only: alignment until motion, then Poisson integration (no aiding)"

    def pipeline_config(self) -> PipelineConfig:
        c = self.config
        est_params = {"step": c.step} if c.estimator == "poisson-quat" else {}
        motion = None
        if c.alignment == "motion":
            motion = armed_for_alignment(c.motion, c.alignment_duration, c.early_motion)
        return PipelineConfig(
            frame=c.frame,
            nan_policy=c.nan_policy,
            gyr_range=c.gyr_range,
            acc_range=c.acc_range,
            estimator=PluginSpec(name=c.estimator, params=est_params),
            detectors=[PluginSpec(name="motion", params=motion.model_dump())] if motion is not None else [],
            alignment=AlignmentConfig(mode=c.alignment, duration=c.alignment_duration, heading=c.heading),
        )
