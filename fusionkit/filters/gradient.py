"""The ``gradient-descent`` filter: source 003's iterative gradient descent on the first-order
Poisson propagation (see :mod:`fusionkit.correctors.gradient` for the steps and the stop test).

The patent starts from the first sample (its specific force, and its magnetometer reading for
the heading when there is one), estimates no gyro bias and takes every magnetometer sample:
``initial_rest=0, mag_rejection=False``. Two extensions, on by default, compose plugins the
library already has: source 000's alignment over the initial rest (mean tilt and heading, and the
mean gyro output as the bias; a sample turning faster than ``rest_rate`` ends it early, so a
recording that starts in motion still starts from its first sample), and the ``magnetic``
detector, which withholds disturbed magnetometer samples from the correction. On BROAD they
take the 9D error from 5.34 to 3.9 deg (BENCHMARKS.md).
``madgwick=True`` makes it Madgwick's filter exactly (one correction, rate-scaled fixed beta,
gradient at the previous estimate, started from the first sample, no extensions). The default is one correction per sample: on BROAD's
hand-held motion the patent's iterations (``iterations`` > 1) follow linear accelerations and
magnetic disturbances and cost accuracy (BENCHMARKS.md); they pay off after large orientation
errors (restarts, saturated gyros), which ``tests/test_gradient.py`` shows.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

from ..config import AlignmentConfig, FilterConfig, PipelineConfig, PluginSpec, param
from ..correctors.gradient import GradientConfig
from ..pipeline import Pipeline

__all__ = ["GradientDescentFilter"]


class GradientDescentConfig(FilterConfig, GradientConfig):
    """The filter's fields plus every field of the ``gradient-descent`` corrector."""

    madgwick: bool = param(False, unit="-", description="Madgwick's filter: N=1, fixed rate-scaled beta, gradient at q(t-1)")
    initial: Literal["first-sample", "identity"] = param(
        "first-sample", unit="-", description="start from the first sample's attitude, or from identity (a restart test)")
    initial_rest: float = param(
        3.0, unit="s", description="extension (first-sample start): align over this first stretch at rest (source 000: "
        "mean tilt, heading, gyro bias); 0: the first sample only, no bias (the patent)", ge=0)
    rest_rate: float = param(
        math.radians(5.0), unit="rad/s", description="a gyro sample above this ends the initial rest early (the "
        "recording did not start still)", gt=0)
    mag_rejection: bool = param(
        True, unit="-", description="extension: the magnetic detector withholds disturbed magnetometer samples "
        "(False: the patent)")


class GradientDescentFilter(Pipeline):
    """Source 003: gyro propagation plus iterated gradient-descent corrections."""

    name: ClassVar[str] = "gradient-descent"
    Config = GradientDescentConfig
    source: ClassVar[str] = "003 (patent: iterative gradient-descent orientation)"
    summary: ClassVar[str] = "Madgwick-style gradient descent iterated within each sample until converged (patent)"

    def pipeline_config(self) -> PipelineConfig:
        c = self.config
        corr = {k: getattr(c, k) for k in GradientConfig.model_fields}
        if c.madgwick:
            corr.update(iterations=1, beta_mode="fixed", beta_scale="rate", gradient_at="previous")
        heading = "auto" if c.use_mag else "zero"
        extensions = not c.madgwick  # Madgwick's filter exactly: none of the extensions
        if c.initial == "identity":
            align = AlignmentConfig(mode="none")
        elif c.initial_rest > 0 and extensions:  # source 000's alignment over the initial rest, ended early by motion
            align = AlignmentConfig(mode="fixed", duration=c.initial_rest, heading=heading, estimate_bias=True,
                                    max_rate=c.rest_rate)
        else:  # the first sample's attitude (duration shorter than a sample)
            align = AlignmentConfig(mode="fixed", duration=1e-9, heading=heading, estimate_bias=False)
        return PipelineConfig(
            frame=c.frame, nan_policy=c.nan_policy, gyr_range=c.gyr_range, acc_range=c.acc_range,
            estimator=PluginSpec(name="poisson-quat", params={"step": "first-order", "normalize": not c.madgwick}),
            correctors=[PluginSpec(name="gradient-descent", params=corr)], alignment=align,
            detectors=[PluginSpec(name="magnetic")] if c.mag_rejection and c.use_mag and extensions else [],
        )
