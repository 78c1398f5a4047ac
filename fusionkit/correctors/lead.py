"""Output lead (``output-lead``, a factor corrector): the output predicted ahead by the gyro rate.

``q (x) exp((w - bias) lead)``: compensates a gyroscope that is late against the time base (its
filter's group delay); nothing else reads this factor, so the estimate itself does not change.
``fusionkit lags`` measures such a delay against a reference
(:mod:`fusionkit.benchmarking.timing`); a lead is a property of that hardware, not a default for
every sensor. It composes the output last (after the other factor correctors). A sample without
a valid gyroscope reading is output without the lead.

The readable reference is :meth:`OutputLead.compose`; :func:`output_lead_kernel` its kernel.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .._numba import njit
from ..config import PluginConfig, param
from ..protocols import CorrectorKernel, FactorCorrector
from ..rotations import quat_from_rotvec, quat_mul
from ._factor import k_qmul, k_rotvec

__all__ = ["OutputLeadConfig", "OutputLead", "output_lead_kernel"]


class OutputLeadConfig(PluginConfig):
    lead: float = param(0.0, unit="s", description="predict the output this far ahead (0: the estimate itself)",
                        ge=0)


class OutputLead(FactorCorrector):
    """The output predicted ``lead`` s ahead by the bias-corrected gyro rate (the state unchanged)."""

    name: ClassVar[str] = "output-lead"
    Config = OutputLeadConfig
    source: ClassVar[str] = "fusionkit (a late gyroscope's delay compensated at the output)"
    summary: ClassVar[str] = "output predicted ahead by the gyro rate, q (x) exp((w - bias) lead)"

    def compose(self, state, quat, sample, bias, rate, flags):
        lead = self.config.lead
        if lead > 0.0 and np.isfinite(sample.gyr).all():
            return quat_mul(quat, quat_from_rotvec((sample.gyr - bias) * lead)), 0
        return quat, 0

    def kernel(self, estimator) -> CorrectorKernel:
        return CorrectorKernel(output_lead_kernel, np.array([self.config.lead]), mode="factor")


@njit(inline="always")
def output_lead_kernel(q, s, b, g0, g1, g2, h0, h1, h2, h3, a0, a1, a2, m0, m1, m2, acc_ok, mag_ok, flags, dt, p):
    """The kernel of :meth:`OutputLead.compose`: ``p = (lead,)``."""
    lead = p[0]
    if lead > 0.0 and math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2):
        d0, d1, d2, d3 = k_rotvec((g0 - b[0]) * lead, (g1 - b[1]) * lead, (g2 - b[2]) * lead)
        q[0], q[1], q[2], q[3] = k_qmul(q[0], q[1], q[2], q[3], d0, d1, d2, d3)
    return 0
