"""Source 002: a strapdown DCM corrected by the accelerometer and the magnetometer in separate
channels, so that a magnetic disturbance cannot reach roll and pitch.

A preset: the composition of registered plugins that :meth:`ChannelDcmFilter.pipeline_config`
builds from the filter's flat config (``fusionkit describe channel-dcm`` prints it):

- estimator ``poisson-dcm`` without its own re-orthonormalisation: ``D <- exp(-[w dt x]) D``
  exactly per sample (the Rodrigues formula of source 004), so each column propagates on its own;
- correctors (:mod:`fusionkit.correctors.dcm`), in this order: ``dcm-vertical`` (the
  accelerometer corrects the vertical column ``d3``), then ``dcm-north`` (the horizontal field
  corrects the north column ``d2``) or, for ``method="unseparated"``, ``dcm-field`` (the whole
  field corrects ``d2`` and ``d3``); the last one restores orthogonality around ``d3``;
- the start (:mod:`fusionkit.navigation.alignment`, ``attitude="first"``): the attitude of the
  first sample with a valid accelerometer (TRIAD: ``d3`` from it, ``d2`` from the field), held
  over the first ``initial_rest`` seconds while the mean gyro output becomes its bias (an
  extension; a sample above ``rest_rate`` ends it early); ``initial_rest=0``: the first sample's
  attitude and no bias (the paper).

``method``: ``"columns"`` (the paper's method 1: each sensor blends its column),
``"vectors"`` (method 2: each turns the DCM, the magnetometer about the vertical) or
``"unseparated"`` (the paper's full-field correction, for comparison). With separation, any
magnetometer input leaves roll and pitch exactly as a magnetometer-free run gives them (tested).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

from ..config import AlignmentConfig, FilterConfig, PipelineConfig, PluginSpec, param
from ..pipeline import Pipeline

__all__ = ["ChannelDcmFilter", "ChannelDcmConfig"]


class ChannelDcmConfig(FilterConfig):
    method: Literal["columns", "vectors", "unseparated"] = param(
        "columns", unit="-", description="'columns' (method 1), 'vectors' (method 2) or 'unseparated' (full field)")
    k_acc: float = param(0.3, unit="1/s", description="accelerometer correction gain (fraction per second)", gt=0)
    k_mag: float = param(0.03, unit="1/s", description="magnetometer correction gain (fraction per second)", gt=0)
    use_mag: bool = param(True, unit="-", description="use the magnetometer when the recording has one (9D)")
    initial_rest: float = param(
        3.0, unit="s", description="extension: hold the first sample's attitude over this first stretch at rest and "
        "take the mean gyro output as the bias; 0: the first sample's attitude, no bias (the paper)", ge=0)
    rest_rate: float = param(
        math.radians(5.0), unit="rad/s", description="a gyro sample above this ends the initial rest early "
        "(the recording did not start at rest)", gt=0)


class ChannelDcmFilter(Pipeline):
    """Source 002: DCM with channel-separated accelerometer and magnetometer corrections."""

    name: ClassVar[str] = "channel-dcm"
    Config = ChannelDcmConfig
    source: ClassVar[str] = "002 (separating the correction channels of a strapdown AHRS)"
    summary: ClassVar[str] = "DCM: accelerometer corrects the vertical column, magnetometer the north column only"

    def pipeline_config(self) -> PipelineConfig:
        c = self.config
        vertical = {"method": "vectors" if c.method == "vectors" else "columns", "k_acc": c.k_acc,
                    "orthonormalize": not c.use_mag}  # with a magnetometer corrector, it restores orthogonality
        correctors = [PluginSpec(name="dcm-vertical", params=vertical)]
        if c.use_mag and c.method == "unseparated":
            correctors.append(PluginSpec(name="dcm-field", params={"k_mag": c.k_mag}))
        elif c.use_mag:
            correctors.append(PluginSpec(name="dcm-north", params={"method": c.method, "k_mag": c.k_mag}))
        heading = "auto" if c.use_mag else "zero"
        if c.initial_rest > 0:
            align = AlignmentConfig(mode="fixed", duration=c.initial_rest, heading=heading, estimate_bias=True,
                                    max_rate=c.rest_rate, attitude="first")
        else:  # the first sample's attitude (a duration shorter than a sample), no bias: the paper
            align = AlignmentConfig(mode="fixed", duration=1e-9, heading=heading, estimate_bias=False)
        return PipelineConfig(
            frame=c.frame, nan_policy=c.nan_policy, gyr_range=c.gyr_range, acc_range=c.acc_range,
            estimator=PluginSpec(name="poisson-dcm", params={"orthonormalize": False}),
            correctors=correctors, alignment=align,
        )
