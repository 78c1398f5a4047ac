"""Error metrics with the BROAD benchmark's definitions.

With ``q_err = q_est (x) conj(q_ref)`` (the error expressed in the earth frame, whose z axis is
vertical; both quaternions body->ENU or both body->NED, ...):

* total error: ``2 acos(|w|)``
* heading error: ``2 atan(|z / w|)``
* inclination error: ``2 acos(sqrt(w^2 + z^2))``

RMS over the ``movement`` samples, ignoring samples where the reference is NaN. All in degrees.
A 6D (magnetometer-free) filter is judged on inclination, a 9D filter on total error.
"""

from __future__ import annotations

import numpy as np

from ..conventions import change_frame
from ..errors import InputError
from ..rotations import quat_conj, quat_mul

__all__ = ["broad_errors", "rms_errors"]


def broad_errors(q_est, q_ref) -> dict[str, np.ndarray]:
    """Per-sample total, heading and inclination errors in degrees (NaN where ``q_ref`` is)."""
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    if q_est.shape != q_ref.shape or q_est.shape[-1] != 4:
        raise InputError(f"q_est {q_est.shape} and q_ref {q_ref.shape} must both have shape (N, 4)")
    e = quat_mul(q_est, quat_conj(q_ref))
    w, z = np.abs(e[..., 0]), e[..., 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
        heading = 2.0 * np.arctan(np.abs(z / w))
        incl = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return {"total": np.degrees(total), "heading": np.degrees(heading), "inclination": np.degrees(incl)}


def rms_errors(result, rec, mask=None) -> dict[str, float]:
    """RMS total/heading/inclination errors (deg) of a :class:`Result` against ``rec.truth``,
    over ``mask`` (default ``rec.movement``, else all samples)."""
    if rec.truth is None:
        raise InputError(f"recording {rec.name!r} has no ground truth")
    q_ref = change_frame(rec.truth, rec.truth_frame, result.frame)
    errs = broad_errors(result.quat, q_ref)
    if mask is None:
        mask = rec.movement if rec.movement is not None else np.ones(len(rec), bool)
    out = {}
    for k, v in errs.items():
        v = v[mask]
        v = v[np.isfinite(v)]
        out[k] = float(np.sqrt(np.mean(v**2))) if v.size else float("nan")
    return out
