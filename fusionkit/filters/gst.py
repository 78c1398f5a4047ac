"""Source 001: the azimuth-free horizontal accompanying trihedron (GST) with accelerometer and
GNSS correction. Filters ``gst`` (autonomous) and ``gst-gnss`` (combined).

Presets: the composition of registered plugins that :meth:`GstFilter.pipeline_config` builds
from the filter's flat config (``fusionkit describe gst-gnss`` prints it):

- estimator ``poisson-quat`` with the exact step: the right factor ``exp([w_B dt x])`` of the
  platform equation ``C <- exp(-[w_P dt x]) C exp([w_B dt x])``;
- corrector ``gst`` (autonomous, method b) or ``gst-gnss`` (combined: GNSS-aided method a while
  GNSS is usable, b in gaps, the heading blended with the GNSS track angle, eq. 5), which apply
  the left factor, the azimuth-free platform rate (the laws: :mod:`fusionkit.correctors.gst`);
- source 000's alignment (levels the platform, estimates the gyro bias), ended by the ``motion``
  detector (``once``: it stops at the onset, which is all the alignment reads).

Frames. The document's body axes are x right, y forward, z up (``"RFU"``); only the forward axis
matters to the laws (the heading H, the kinematic acceleration), so sensors in other axes
(``Recording.body`` or ``body=``: "FRD", "FLU", ...) are used as they are and the output is
body(sensor axes) -> ``frame``. Without either, the sensors are taken as RFU.

Extensions, each an option with the document's behaviour available (docs/algorithms/gst.md):
the rejection gate (``reject=False``: the document's autonomous loop), the accelerometer bias
estimate (``tau_acc_bias=None``: the document's GNSS loop), ``heading_init="track"``
(``"blend"``: eq. 5 alone), the GNSS loop gain from the sensor model (``tau_gnss=`` sets it).
``gnss_weight`` < 1 mixes (b) into (a) as the document's combination of the two solutions.
"""

from __future__ import annotations

import warnings
from typing import ClassVar, Literal

import numpy as np

from ..config import AlignmentConfig, BodyAxes, FilterConfig, PipelineConfig, PluginSpec, param
from ..conventions import body_matrix
from ..correctors.gst import G0, GateConfig, GnssLoopConfig
from ..detectors.motion import MotionConfig, armed_for_alignment
from ..errors import InputError
from ..pipeline import Pipeline
from ..types import Flag, Recording

__all__ = ["GstFilter", "GstGnssFilter", "GstConfig", "BODY_AXES", "MODES", "modes"]

#: sensor axes -> the document's body axes (x right, y forward, z up): v_rfu = M v_sensor (any
#: other convention: :func:`fusionkit.conventions.body_matrix`)
BODY_AXES = {b: body_matrix(b, "RFU") for b in ("RFU", "FRD", "FLU")}
#: per-sample mode codes in ``diagnostics["mode"]``
MODES = ("aligning", "autonomous", "gnss", "rejected")


class GstConfig(FilterConfig, GnssLoopConfig, GateConfig):
    body: BodyAxes = param(
        None, unit="-", description="sensor axes ('FRD', 'FLU', ...); None: the recording's (Recording.body), else "
        "RFU, the document's (x right, y forward, z up)"
    )
    combined: bool = param(False, unit="-", description="use GNSS when usable (gst-gnss), else autonomous only")
    tau_auto: float = param(50.0, unit="s", description="levelling loop time constant, autonomous", gt=0)
    lp_gnss: float = param(2.0, unit="s", description="low-pass time constant of the GNSS-aided residual", gt=0)
    lp_auto: float = param(2.0, unit="s", description="aperiodic-link time constant of the autonomous signal", gt=0)
    gnss_weight: float = param(1.0, unit="-", description="weight of (a) against (b) while GNSS is usable", ge=0, le=1)
    heading_T: float = param(50.0, unit="s", description="track-angle blend time constant T (eq. 5)", gt=0)
    heading_init: Literal["track", "blend"] = param(
        "track", unit="-", description="'track': start H* at the first usable track angle; 'blend': eq. 5 from H"
    )
    min_speed: float = param(5.0, unit="m/s", description="no track angle below this ground speed", ge=0)
    gnss_max_age: float = param(0.5, unit="s", description="a GNSS epoch older than this is a gap", gt=0)
    alignment: Literal["motion", "fixed"] = param("motion", unit="-", description="source 000 alignment mode")
    alignment_duration: float = param(10.0, unit="s", description="mandatory alignment time", gt=0)
    early_motion: bool = param(
        True, unit="-", description="extension: the motion detector is armed after 2 s of statistics, so that motion "
        "inside the mandatory alignment ends it there (never averaged in) with a warning; False: armed when the "
        "mandatory alignment ends (source 000, which assumes the IMU still)")
    motion: MotionConfig = param(MotionConfig(), unit="-", description="motion detector ending the alignment")


class GstFilter(Pipeline):
    """Source 001's GST levelling loops (autonomous; ``combined=True`` adds the GNSS loop)."""

    name: ClassVar[str] = "gst"
    Config = GstConfig
    source: ClassVar[str] = "001 (GST with accelerometer and GNSS correction, Mi-8)"
    summary: ClassVar[str] = "azimuth-free platform levelled by low-passed specific force (autonomous)"

    def pipeline_config(self) -> PipelineConfig:
        c = self.config
        cor = {"tau": c.tau_auto, "lp": c.lp_auto, **c.model_dump(include=set(GateConfig.model_fields))}
        if c.combined:
            cor.update(c.model_dump(include=set(GnssLoopConfig.model_fields)), lp_gnss=c.lp_gnss,
                       gnss_weight=c.gnss_weight, heading_T=c.heading_T, heading_init=c.heading_init,
                       min_speed=c.min_speed, gnss_max_age=c.gnss_max_age, body=c.body)
        detectors = []
        if c.alignment == "motion":  # only the onset ends the alignment: the detector stops there
            motion = armed_for_alignment(c.motion, c.alignment_duration, c.early_motion)
            if "once" not in motion.model_fields_set:
                motion = motion.model_copy(update={"once": True})
            detectors.append(PluginSpec(name="motion", params=motion.model_dump()))
        return PipelineConfig(
            frame=c.frame, nan_policy=c.nan_policy, gyr_range=c.gyr_range, acc_range=c.acc_range, max_gap=c.max_gap,
            body=c.body, estimator=PluginSpec(name="poisson-quat", params={"step": "exact"}),
            correctors=[PluginSpec(name="gst-gnss" if c.combined else "gst", params=cor)], detectors=detectors,
            alignment=AlignmentConfig(mode=c.alignment, duration=c.alignment_duration),
        )

    def dimension(self, rec) -> str:
        return "6D"  # no magnetometer: heading comes from gyros and, in gst-gnss, the GNSS track

    def tau_gnss(self, g: float = G0) -> float:
        """The GNSS loop's time constant: ``tau_gnss``, or from the sensor model."""
        return self.config.gnss_time_constant(g)

    def run(self, rec: Recording, *, backend: str = "auto", progress: bool | None = None,
            state: dict | None = None):
        if self.config.combined and isinstance(rec, Recording) and rec.gnss is None:
            raise InputError(f"{self.name} needs a GNSS stream (Recording(gnss=...)); use 'gst' without GNSS")
        with warnings.catch_warnings(record=True) as caught:  # re-issued below at the caller's line
            warnings.simplefilter("always")
            res = super().run(rec, backend=backend, progress=progress, state=state)
        for w in caught:
            warnings.warn(w.message, w.category, stacklevel=2)
        res.diagnostics.update(mode=modes(res.flags, self.config.combined), mode_names=MODES,
                               body=self.body_axes(rec) or "RFU")
        return res


def modes(flags: np.ndarray, combined: bool) -> np.ndarray:
    """The per-sample mode (:data:`MODES`) from a run's flags: aligning (or a held sample),
    autonomous, GNSS-aided, or no levelling (rejected by the gate, or no usable accelerometer)."""
    m = np.full(flags.shape, 2 if combined else 1, np.uint8)
    m[(flags & Flag.GNSS_GAP) != 0] = 1
    m[(flags & (Flag.ACC_REJECTED | Flag.ACC_INVALID | Flag.ACC_SATURATED)) != 0] = 3
    m[(flags & (Flag.ALIGNING | Flag.GYR_INVALID)) != 0] = 0
    return m


class GstGnssFilter(GstFilter):
    """Source 001's combined algorithm: GNSS-aided levelling and track-angle heading while GNSS
    is usable, the autonomous loop and gyroscopic heading in GNSS gaps."""

    name: ClassVar[str] = "gst-gnss"
    requires_gnss: ClassVar[bool] = True
    summary: ClassVar[str] = "GST levelled with GNSS-compensated specific force, track-angle heading, autonomous in gaps"

    class Config(GstConfig):
        combined: bool = param(True, unit="-", description="use GNSS when usable (gst-gnss), else autonomous only")
