"""A minimal third-party fusionkit plugin package."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from fusionkit.config import AlignmentConfig, FilterConfig, PipelineConfig, PluginConfig, PluginSpec, param
from fusionkit.conventions import up_vector
from fusionkit.pipeline import Pipeline
from fusionkit.protocols import Correction, Corrector
from fusionkit.rotations import quat_to_matrix


class TiltConfig(PluginConfig):
    k_p: float = param(1.0, unit="1/s", description="proportional gain of the tilt loop", ge=0)


class TiltCorrector(Corrector):
    """Proportional tilt correction from the accelerometer (Mahony's P term)."""

    name: ClassVar[str] = "example-tilt"
    Config = TiltConfig
    mode: ClassVar[str] = "rate"
    summary: ClassVar[str] = "example: proportional accelerometer tilt loop"

    def initial_state(self, dt, frame):
        return up_vector(frame)  # the earth frame's "up", where specific force points at rest

    def correct(self, estimator, est_state, state, sample, flags):
        if sample.acc is None:  # no usable accelerometer sample: no correction
            return Correction(np.zeros(3))
        up_est = quat_to_matrix(estimator.quat(est_state)).T @ state
        a = sample.acc / np.linalg.norm(sample.acc)
        return Correction(self.config.k_p * np.cross(a, up_est))


class ComplementaryConfig(FilterConfig):
    k_p: float = param(1.0, unit="1/s", description="tilt loop gain", ge=0)


class ComplementaryFilter(Pipeline):
    """poisson-quat + example-tilt after a fixed 1 s alignment."""

    name: ClassVar[str] = "example-complementary"
    Config = ComplementaryConfig
    summary: ClassVar[str] = "example: gyro integration with a proportional tilt loop"

    def pipeline_config(self):
        c = self.config
        return PipelineConfig(
            frame=c.frame, nan_policy=c.nan_policy, gyr_range=c.gyr_range, acc_range=c.acc_range,
            estimator=PluginSpec(name="poisson-quat", params={"step": "exact"}),
            correctors=[PluginSpec(name="example-tilt", params={"k_p": c.k_p})],
            alignment=AlignmentConfig(mode="fixed", duration=1.0),
        )
