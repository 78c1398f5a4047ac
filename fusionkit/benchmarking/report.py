"""What a printed error number means, and which numbers a filter can have.

BROAD's metrics split the rotation error ``q_err = q_est (x) conj(q_ref)`` (earth frame) into a
tilt part and a part about the vertical. A filter without a magnetometer (6D) cannot know its
heading, and a gyro-only filter (an integrator with no accelerometer or magnetometer
correction) keeps whatever heading its start had: their heading and total errors are artefacts
of that start (about 90 deg on BROAD), so tables print ``n/a`` with the reason instead of a
number. Tables keep 6D inclination and 9D total apart: they are different quantities.
"""

from __future__ import annotations

from ..validation import has_finite

__all__ = ["METRIC_LABELS", "HEADING_DEFINITION", "aiding", "not_applicable", "metric_label"]

HEADING_DEFINITION = ("heading error: the error's rotation about the vertical (deg), whatever the "
                      "frame's yaw convention")

#: table section title of each metric, in the order tables print them (others follow by name)
METRIC_LABELS = {
    "inclination": "inclination RMSE (deg, the error's tilt part; every filter, 6D and 9D)",
    "total": "total RMSE (deg, the whole rotation error; 9D filters only)",
    "heading": "heading RMSE (deg, the error's rotation about the vertical; 9D filters only)",
    "tilt_gnss": "tilt RMS with GNSS (deg)",
    "tilt_gap": "tilt RMS in GNSS gaps (deg)",
    "heading_gnss": "heading RMS with GNSS (deg, about the vertical)",
    "heading_gap": "heading RMS in GNSS gaps (deg, about the vertical)",
    "velocity": "velocity RMS error (m/s; filters that output a velocity, on GNSS flights)",
    "position": "position RMS error (m; filters that output a position, on GNSS flights)",
    "position_gap_end": "position error at the end of the last GNSS gap (m)",
    "score": "score (deg; 9D: total RMSE, 6D: inclination RMSE)",
}

#: metrics a table leaves out by default: ``score`` mixes 6D and 9D, ``tilt`` repeats inclination,
#: ``heading`` is in ``total`` (its BROAD definition)
HIDDEN_BY_DEFAULT = ("score", "tilt", "heading")


def metric_unit(name: str) -> str:
    """The unit of a metric's values: m/s for a velocity, m for a position, else deg."""
    return "m/s" if name.startswith("velocity") else "m" if name.startswith("position") else "deg"


def metric_label(name: str) -> str:
    return METRIC_LABELS.get(name, name)


def dimension(f, rec) -> str:
    """``f.dimension(rec)``, the error a benchmark judges ``f`` on (9D: total, 6D: inclination),
    but "6D" when ``rec``'s magnetometer has not one finite sample: with ``nan_policy="skip"`` the
    filter runs without it (the quaternions of a run without ``mag``, its heading the gyro's), and
    its arbitrary heading was scored as a 9D filter's total and heading error."""
    return "6D" if rec.mag is not None and not has_finite(rec.mag) else f.dimension(rec)


def aiding(f, rec) -> str:
    """``"9D"`` (magnetometer used), ``"6D"`` (accelerometer only, or GNSS), or ``"gyro-only"``
    (a pipeline without correctors: integration from the alignment, nothing corrects it):
    :meth:`fusionkit.protocols.Filter.aiding`, what every run records."""
    return f.aiding(rec)


def not_applicable(kind: str, gnss_heading: bool = False, rec=None) -> dict[str, str]:
    """``{metric: reason}`` for the metrics a filter of ``kind`` (:func:`aiding`) cannot have.

    ``gnss_heading``: the filter takes its heading from GNSS (its heading is then measured).
    ``rec``: the recording it ran on, so that a 6D reason says what is true: the filter does not
    read the recording's magnetometer, or the recording has none (or none with a finite sample).
    "6D: no magnetometer" was printed for 6D filters on recordings with one."""
    if kind == "9D" or gnss_heading:
        return {}
    if kind == "gyro-only":
        why = "gyro-only: no correction, heading stays the start's arbitrary one"
    elif rec is None:
        why = "6D: no magnetometer used, heading unobservable"
    elif rec.mag is None:
        why = "6D: no magnetometer in the recording, heading unobservable"
    elif not has_finite(rec.mag):
        why = "6D: the recording's magnetometer has no finite sample, heading unobservable"
    else:
        why = "6D: the filter does not read the magnetometer, heading unobservable"
    return {"total": why, "heading": why}
