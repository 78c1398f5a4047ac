"""Error metrics with the BROAD benchmark's definitions.

With ``q_err = q_est (x) conj(q_ref)`` (the error expressed in the earth frame, whose z axis is
vertical; both quaternions body->ENU or both body->NED, ...):

* total error: ``2 acos(|w|)``
* heading error: ``2 atan(|z / w|)``
* inclination error: ``2 acos(sqrt(w^2 + z^2))``

RMS over the ``movement`` samples, ignoring samples where the reference is NaN. All in degrees.
A 6D (magnetometer-free) filter is judged on inclination, a 9D filter on total error. A result in
source 000's NUE frame (whose vertical is its second axis) is compared in ENU
(:func:`truth_errors`).
"""

from __future__ import annotations

import numpy as np

from ..conventions import _unit, change_frame, up_vector
from ..errors import InputError
from ..rotations import quat_conj, quat_mul

__all__ = ["broad_errors", "rms_errors", "trial_metrics", "truth_errors", "gnss_masks", "navigation_errors"]


def broad_errors(q_est, q_ref) -> dict[str, np.ndarray]:
    """Per-sample total, heading and inclination errors in degrees (NaN where ``q_ref`` is).

    Both sides are read as the rotations they stand for, normalised where a row is off unit
    length (the angles come off the error's w, clipped at 1: an estimate scaled by 3 scored 0), as
    a :class:`~fusionkit.Recording` normalises its truth. A zero row of either, or a non-finite
    row of the estimate (a reference row that is NaN is a sample without one), is an
    :class:`InputError` naming it."""
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    if q_est.shape != q_ref.shape or q_est.shape[-1] != 4:
        raise InputError(f"q_est {q_est.shape} and q_ref {q_ref.shape} must both have shape (N, 4)")
    finite = np.isfinite(q_est).all(axis=-1)
    if not finite.all():
        i = np.unravel_index(int(np.argmin(finite)), finite.shape) if finite.ndim else ()
        raise InputError(f"q_est{list(map(int, i)) if i else ''} is {q_est[i].tolist()}: an estimate must be a "
                         "finite quaternion")
    q_est, q_ref = _unit(q_est, "q_est"), _unit(q_ref, "q_ref")
    e = quat_mul(q_est, quat_conj(q_ref))
    w, z = np.abs(e[..., 0]), e[..., 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
        heading = 2.0 * np.arctan(np.abs(z / w))
        incl = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return {"total": np.degrees(total), "heading": np.degrees(heading), "inclination": np.degrees(incl)}


def truth_errors(quat, frame: str, rec) -> dict[str, np.ndarray]:
    """:func:`broad_errors` of body->``frame`` quaternions against ``rec.truth``, both expressed
    in a frame whose z axis is vertical, as the heading/inclination split needs: ``frame`` itself
    (ENU, NED, NWU), or ENU for NUE (its z axis is East: split about it, a heading error counted
    as inclination and the reverse)."""
    if abs(up_vector(frame)[2]) != 1.0:
        quat, frame = change_frame(quat, frame, "ENU"), "ENU"
    return broad_errors(quat, change_frame(rec.truth, rec.truth_frame, frame))


def rms_errors(result, rec, mask=None) -> dict[str, float]:
    """RMS total/heading/inclination errors (deg) of a :class:`Result` against ``rec.truth``,
    over ``mask`` (default ``rec.movement``, else all samples)."""
    if rec.truth is None:
        raise InputError(f"recording {rec.name!r} has no ground truth")
    errs = truth_errors(result.quat, result.frame, rec)
    if mask is None:
        mask = rec.movement if rec.movement is not None else np.ones(len(rec), bool)
    out = {}
    for k, v in errs.items():
        v = v[mask]
        v = v[np.isfinite(v)]
        out[k] = float(np.sqrt(np.mean(v**2))) if v.size else float("nan")
    return out


def _rms(v: np.ndarray) -> float:
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def gnss_masks(rec) -> tuple[np.ndarray, np.ndarray]:
    """Per IMU sample: GNSS available (the latest epoch at or before it is valid) and in a gap."""
    g = rec.gnss
    if g.t.size == 0:  # (no epoch: no sample has GNSS; the index below was out of bounds)
        none = np.zeros(len(rec), bool)
        return none, ~none
    idx = np.searchsorted(g.t, rec.time, side="right") - 1
    ok = (idx >= 0) & g.valid[np.clip(idx, 0, None)]
    return ok, ~ok


def navigation_errors(result, rec, ok, gap) -> dict[str, float]:
    """Velocity and position errors of a result that outputs them (``diagnostics["velocity"]``,
    ``["position"]`` in its frame, as ``ins-gnss`` does) against a reference that has them
    (``meta["ref_vel_ned"]``, ``["ref_pos_ned"]``, the GNSS scenarios and ``fusionkit.sim.flight``):
    RMS of the error's norm while GNSS is usable (``velocity``, m/s; ``position``, m) and the
    position error at the end of the last gap (``position_gap_end``, m). Empty otherwise."""
    from ..conventions import frame_matrix

    out: dict[str, float] = {}
    m = frame_matrix("NED", result.frame)
    for key, ref in (("velocity", "ref_vel_ned"), ("position", "ref_pos_ned")):
        est, truth = result.diagnostics.get(key), rec.meta.get(ref)
        if est is None or truth is None or np.shape(est) != np.shape(truth):
            continue
        err = np.linalg.norm(np.asarray(est) - np.asarray(truth) @ m.T, axis=1)
        out[key] = _rms(err[ok])
        if key == "position" and gap.any():
            out["position_gap_end"] = float(err[np.flatnonzero(gap)[-1]])
    return out


def trial_metrics(result, rec, dimension: str) -> dict[str, float]:
    """The metrics of a run, by the kind of recording.

    BROAD-like (``movement`` mask): total, heading, inclination RMSE over the movement samples;
    ``score`` is total for a 9D run and inclination for a 6D one. GNSS flights: tilt
    (inclination) and heading RMS overall, with GNSS and in gaps, and for filters that output
    them the velocity and position errors (:func:`navigation_errors`). Other recordings with a
    reference: RMS over all samples where the reference is finite. No reference: ``{}``.
    """
    if rec.truth is None:
        return {}
    errs = truth_errors(result.quat, result.frame, rec)
    if rec.movement is not None:
        m = rec.movement
        out = {k: _rms(v[m]) for k, v in errs.items()}
    else:
        out = {k: _rms(v) for k, v in errs.items()}
        if rec.gnss is not None:
            ok, gap = gnss_masks(rec)
            out["tilt"] = out["inclination"]
            for name, mask in (("gnss", ok), ("gap", gap)):
                out[f"tilt_{name}"] = _rms(errs["inclination"][mask])
                out[f"heading_{name}"] = _rms(errs["heading"][mask])
            out.update(navigation_errors(result, rec, ok, gap))
    out["score"] = out["total"] if dimension == "9D" else out["inclination"]
    return out
