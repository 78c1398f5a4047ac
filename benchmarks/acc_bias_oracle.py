"""Is the BROAD accelerometer's departure from the reference's gravity at rest an accelerometer
bias that ``recommended`` could learn? An oracle bound: per trial, fit the error from the reference,
remove it from the recording, run ``recommended`` 6D and compare its inclination RMS (over the
``movement`` samples, as the benchmark) with the recording as recorded.

    python benchmarks/acc_bias_oracle.py [--data DIR] [--trials A,B] [--lead S]

``--lead``: ``recommended``'s ``output_lead`` (s; BROAD's reference clock offset is about 0.00245).

The fits (``u`` = the reference's "up" in the body frame, ``g`` = 9.81 m/s^2):

- ``rest bias``: ``b = mean(a - g u)`` over the rests (``movement`` false), ``a - b`` run;
  ``rest bias xy``: its components across the body's z only (``b_z = 0``); ``... 1st half``: fitted
  on the first half of the rest samples only (not the evaluation's own samples);
- ``lowpass bias``: over every sample, in the earth frame ``R a - g e_z = R b + (linear
  acceleration)``, both sides averaged over 4 s windows (the linear acceleration averages out):
  the motion's orientations make all three components observable; ``... 1st half``: the first
  half of the trial; ``+ scale`` / ``+ 3x3``: with the accelerometer's scale factors (diagonal)
  or its whole scale/misalignment matrix (a full accelerometer calibration against the reference);
- ``fixed 3x3 from other rotation trials``: the bias and the whole scale/misalignment matrix
  fitted (as ``lowpass bias + 3x3``) on the rotation trials other than the one run, pooled: what a
  laboratory calibration of this accelerometer would be, if the errors were the sensor's;
- ``rest mounting``: a body-frame rotation (gyro and accelerometer together: the reference's body
  mounting) fitted at the rests, minimum norm (the rotation about the vertical is not observable);
- ``earth tilt``: the reference's earth z axis off the vertical: the rests' mean specific force in
  the reference's earth frame, the filter's output rotated by it (a reference error: no filter can
  learn it, it only says how much of the error is the reference's).

It also counts each trial's rests longer than 1 s and their spread of orientations: the
information an online sphere fit (the rests' mean specific forces on a sphere of radius g about
the bias) would have.
"""

from __future__ import annotations

import argparse
import copy

import numpy as np
from _common import data_dir, group_and_loo_tables

import fusionkit as fk
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.rotations import quat_from_rotvec, quat_mul, quat_to_matrix, rodrigues, skew

G = 9.81
WINDOW = 4.0  # s, the low-pass fit's averaging window


def _first_half(mask: np.ndarray) -> np.ndarray:
    idx = np.flatnonzero(mask)
    out = np.zeros_like(mask)
    out[idx[: len(idx) // 2]] = True
    return out


def _rest_bias(rec, sel, xy=False):
    R = quat_to_matrix(rec.truth[sel])
    u = R[:, 2, :]  # the earth's z axis in body coordinates: R^T e_z
    ok = np.isfinite(u).all(axis=1)
    b = (rec.acc[sel][ok] - G * u[ok]).mean(axis=0)
    if xy:
        b[2] = 0.0
    return b, np.zeros(3)


def _boxcar(x, n):
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    return ((c[n:] - c[:-n]) / n)[:: max(n // 4, 1)]


def _equations(rec, sel, bias=True, mounting=False, scale=None):
    """The window means of ``R a - g e_z = R b + R [a]x d + R E a`` (``d``: the small rotation of
    the mounting; ``E``: the accelerometer's scale errors, ``scale="diag"`` or ``"full"``): the
    stacked matrix, right-hand side and the ``(k, j)`` of ``E``'s unknowns."""
    R = quat_to_matrix(rec.truth)
    ok = np.isfinite(R.reshape(len(R), -1)).all(axis=1) & np.isfinite(rec.acc).all(axis=1) & sel
    y = np.einsum("nij,nj->ni", R, rec.acc) - [0.0, 0.0, G]
    cols = ([R] if bias else []) + ([np.einsum("nij,njk->nik", R, skew(rec.acc))] if mounting else [])
    pairs = [] if scale is None else [(k, j) for k in range(3) for j in range(3) if scale == "full" or k == j]
    cols += [R[:, :, k:k + 1] * rec.acc[:, None, j:j + 1] for k, j in pairs]
    A = np.concatenate(cols, axis=-1)
    y[~ok], A[~ok] = 0.0, 0.0
    n = int(WINDOW * rec.rate)
    cnt = _boxcar(ok.astype(float), n)
    keep = cnt > 0.9
    y = _boxcar(y, n)[keep] / cnt[keep, None]
    A = _boxcar(A, n)[keep] / cnt[keep, None, None]
    return A.reshape(-1, A.shape[-1]), y.ravel(), pairs


def _solve(A, y, pairs, bias=True, mounting=False, scale=None):
    """Least squares, minimum norm (``rcond``) where a direction is not observed: ``(b, d)`` or,
    with ``scale``, ``(b, E)``."""
    x = np.linalg.lstsq(A, y, rcond=1e-2)[0]
    if scale is not None:
        E = np.zeros((3, 3))
        for (k, j), e in zip(pairs, x[3:]):
            E[k, j] = e
        return x[:3], E
    return (x[:3] if bias else np.zeros(3)), (x[-3:] if mounting else np.zeros(3))


def _lowpass_fit(rec, sel, bias=True, mounting=False, scale=None):
    return _solve(*_equations(rec, sel, bias, mounting, scale), bias, mounting, scale)


def _rest_mounting(rec, sel):
    return _lowpass_fit(rec, sel, bias=False, mounting=True)


def _corrected(rec, b, d):
    """The recording less the bias ``b``, rotated by ``d`` (a rotation vector: accelerometer and
    gyroscope) or, where ``d`` is a matrix ``E``, the accelerometer less ``E a`` too."""
    out = copy.copy(rec)
    if np.ndim(d) == 2:
        out.acc = np.ascontiguousarray(rec.acc - b - rec.acc @ d.T)
        return out
    C = rodrigues(d)
    out.acc = np.ascontiguousarray((rec.acc - b) @ C.T)
    out.gyr = np.ascontiguousarray(rec.gyr @ C.T)
    return out


def _earth_tilt(rec, sel):
    R = quat_to_matrix(rec.truth[sel])
    ok = np.isfinite(R.reshape(len(R), -1)).all(axis=1)
    up = np.einsum("nij,nj->ni", R[ok], rec.acc[sel][ok]).mean(axis=0)
    up /= np.linalg.norm(up)
    axis = np.cross([0.0, 0.0, 1.0], up)
    s = np.linalg.norm(axis)
    return quat_from_rotvec(axis / s * np.arcsin(s)), np.degrees(np.arcsin(s))


def _rests(rec):
    """Rests longer than 1 s, the largest angle of their mean specific force from the rests' mean
    (deg) and the sphere fit's information ``sum [u 1][u 1]^T / n``'s smallest eigenvalue."""
    d = np.diff(np.concatenate([[0], (~rec.movement).astype(int), [0]]))
    segs = [(s, e) for s, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)) if e - s > rec.rate]
    u = np.array([rec.acc[s:e].mean(axis=0) for s, e in segs])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    m = u.mean(axis=0) / np.linalg.norm(u.mean(axis=0))
    J = np.c_[u, np.ones(len(u))]
    return len(segs), float(np.degrees(np.arccos(np.clip(u @ m, -1, 1))).max()), float(np.linalg.eigvalsh(J.T @ J / len(u))[0])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default="")
    ap.add_argument("--lead", type=float, default=0.0)
    args = ap.parse_args()
    f = fk.make("recommended", use_mag=False, **({"output_lead": args.lead} if args.lead else {}))
    fits = {
        "rest bias": lambda r, rest, all_: _rest_bias(r, rest),
        "rest bias, 1st half": lambda r, rest, all_: _rest_bias(r, _first_half(rest)),
        "rest bias xy": lambda r, rest, all_: _rest_bias(r, rest, xy=True),
        "rest bias xy, 1st half": lambda r, rest, all_: _rest_bias(r, _first_half(rest), xy=True),
        "lowpass bias": lambda r, rest, all_: _lowpass_fit(r, all_),
        "lowpass bias, 1st half": lambda r, rest, all_: _lowpass_fit(r, _first_half(all_)),
        "lowpass bias + mounting": lambda r, rest, all_: _lowpass_fit(r, all_, mounting=True),
        "lowpass bias + scale": lambda r, rest, all_: _lowpass_fit(r, all_, scale="diag"),
        "lowpass bias + 3x3": lambda r, rest, all_: _lowpass_fit(r, all_, scale="full"),
        "rest mounting": lambda r, rest, all_: _rest_mounting(r, rest),
    }
    labels = ["recorded", *fits, "earth tilt", "earth tilt, 1st half"]
    trials = discover(args.data, args.trials.split(",") if args.trials else None)
    recs = [tr.load() for tr in trials]
    eqs = {r.name: _equations(r, np.ones(len(r), bool), scale="full") for r in recs if "rotation" in r.name}
    labels.insert(-2, "fixed 3x3 from other rotation trials")
    rows = []
    for tr, rec in zip(trials, recs):
        rest, all_ = ~rec.movement, np.ones(len(rec), bool)
        row = {"trial": rec.name, "groups": list(tr.groups), "errors": {}}
        base = f.run(rec)
        row["errors"]["recorded"] = rms_errors(base, rec)["inclination"]
        for label, fit in fits.items():
            b, d = fit(rec, rest, all_)
            row["errors"][label] = rms_errors(f.run(_corrected(rec, b, d)), rec)["inclination"]
        others = [v for k, v in eqs.items() if k != rec.name]
        if others:
            A, y = np.concatenate([o[0] for o in others]), np.concatenate([o[1] for o in others])
            b, E = _solve(A, y, others[0][2], scale="full")
            row["errors"][labels[-3]] = rms_errors(f.run(_corrected(rec, b, E)), rec)["inclination"]
        else:
            row["errors"][labels[-3]] = float("nan")
        tilts = []
        for label, sel in (("earth tilt", rest), ("earth tilt, 1st half", _first_half(rest))):
            q, t = _earth_tilt(rec, sel)
            tilts.append(t)
            res = copy.copy(base)
            res.quat = quat_mul(np.broadcast_to(q, base.quat.shape), base.quat)
            row["errors"][label] = rms_errors(res, rec)["inclination"]
        n, spread, eig = _rests(rec)
        b = _rest_bias(rec, rest)[0]
        print(f"{rec.name}: rest bias {np.round(b, 3)} m/s^2, earth tilt {tilts[0]:.3f} deg, {n} rests > 1 s within "
              f"{spread:.2f} deg, sphere information min eig {eig:.1e}", flush=True)
        rows.append(row)
    print("\n6D inclination (deg)\n| trial | " + " | ".join(labels) + " |")
    print("|---|" + "---:|" * len(labels))
    for r in rows:
        print(f"| {r['trial']} | " + " | ".join(f"{r['errors'][k]:.3f}" for k in labels) + " |")
    group_and_loo_tables(rows, labels, "recorded")


if __name__ == "__main__":
    main()
