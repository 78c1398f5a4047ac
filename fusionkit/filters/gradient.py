"""The ``gradient-descent`` filter: source 003's iterative gradient descent on the first-order
Poisson propagation (see :mod:`fusionkit.correctors.gradient` for the steps and the stop test).

The initial attitude comes from the first sample (its specific force, and its magnetometer
reading for the heading when there is one); the patent estimates no gyro bias.
``madgwick=True`` makes it Madgwick's filter exactly (one correction, rate-scaled fixed beta,
gradient at the previous estimate). The default is one correction per sample: on BROAD's
hand-held motion the patent's iterations (``iterations`` > 1) follow linear accelerations and
magnetic disturbances and cost accuracy (BENCHMARKS.md); they pay off after large orientation
errors (restarts, saturated gyros), which ``tests/test_gradient.py`` shows.
"""

from __future__ import annotations

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
        if c.initial == "first-sample":  # the first sample's attitude (duration shorter than a sample)
            align = AlignmentConfig(mode="fixed", duration=1e-9, heading="auto" if c.use_mag else "zero",
                                    estimate_bias=False)
        else:
            align = AlignmentConfig(mode="none")
        return PipelineConfig(
            frame=c.frame, nan_policy=c.nan_policy, gyr_range=c.gyr_range, acc_range=c.acc_range,
            estimator=PluginSpec(name="poisson-quat", params={"step": "first-order", "normalize": not c.madgwick}),
            correctors=[PluginSpec(name="gradient-descent", params=corr)], alignment=align,
        )
