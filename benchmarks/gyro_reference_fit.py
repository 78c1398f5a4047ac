"""The gyro's rate error measured against the reference, and what knowing it is worth: per BROAD
trial, the gyro's scale and non-orthogonality ``E`` (the symmetric part, as ``gyro_rate_estimate``
learns it) and its bias, fitted from the optical reference's body rate; the online estimate at the
end of a ``recommended`` 6D run; and the 6D inclination RMSE (deg, over the ``movement`` samples)
with the estimate (``correct``, the default), without it (``off``), and with the gyro corrected by
the reference's ``E`` and the estimate off (``reference E``, an oracle bound: no filter has the
reference). ``--windows`` also prints the fit per 20 s window of motion (is ``E`` a constant of the
sensor?), ``--mag`` the magnetometer's body-fixed offset fitted with the reference's attitude
(``m = R^T m_earth + o`` over the ``movement`` samples: iron carried with the sensor).

    python benchmarks/gyro_reference_fit.py [--data DIR] [--trials 03,24,26] [--windows] [--mag] [--no-runs]

The fit: the reference's body rate from consecutive quaternions (``2 vec(conj(q[k-1]) q[k+1]) / (2 dt)``),
both it and the gyro low-passed at 5 Hz (zero phase), the gyro one sample earlier (the lag of least
residual on every BROAD trial), over samples that turn faster than 0.3 rad/s and lie more than 1 s from a
reference gap; ``gyro = M w + b`` by least squares, ``E = (M + M^T) / 2 - I``. A clock offset between the
IMU's samples and its timestamps scales every axis alike and cannot be told from a scale factor here (nor
by a filter, which integrates with the same timestamps): the isotropic part of ``E`` is either.
"""

from __future__ import annotations

import argparse
import copy

import numpy as np
from _common import data_dir
from scipy.signal import butter, filtfilt

import fusionkit as fk
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.rotations import quat_conj, quat_mul, quat_to_matrix

LOWPASS = 5.0  # Hz: the rates compared below it (the reference's differentiated quaternions are noisy above)
MIN_RATE = 0.3  # rad/s: samples that turn slower say little about a rate-proportional error
WINDOW = 20.0  # s (--windows)


def _reference_rate(rec):
    """The reference's body rate (rad/s) and where it is valid (the reference finite at k-1, k, k+1)."""
    q = rec.truth
    ok = np.isfinite(q).all(axis=1)
    d = quat_mul(quat_conj(q[:-2]), q[2:])
    d *= np.where(d[:, :1] < 0, -1.0, 1.0)
    w = d[:, 1:] * rec.rate  # 2 vec(d) / (2 dt), small angle
    w = np.vstack([w[:1], w, w[-1:]])
    valid = ok.copy()
    valid[1:-1] &= ok[:-2] & ok[2:]
    return np.where(valid[:, None], w, 0.0), valid


def fit(rec, window: float | None = None):
    """``[(t0, E (3 x 3), bias (3,), samples)]``: one row for the whole recording, or (``window``) one
    per ``window`` s with enough motion."""
    w, valid = _reference_rate(rec)
    b, a = butter(2, LOWPASS / (rec.rate / 2))
    wf = filtfilt(b, a, w, axis=0)
    gf = np.roll(filtfilt(b, a, rec.gyr, axis=0), -1, axis=0)  # the gyro a sample earlier
    n = int(rec.rate)
    near_gap = np.convolve((~valid).astype(float), np.ones(2 * n + 1), "same") > 0
    use = ~near_gap & (np.linalg.norm(gf, axis=1) > MIN_RATE)
    use[-1] = False
    t = np.arange(len(rec)) / rec.rate
    spans = [(0.0, np.inf)] if window is None else [(s, s + window) for s in np.arange(0.0, t[-1], window)]
    rows = []
    for t0, t1 in spans:
        m = use & (t >= t0) & (t < t1)
        if m.sum() < 5 * rec.rate:
            continue
        x = np.linalg.lstsq(np.hstack([wf[m], np.ones((m.sum(), 1))]), gf[m], rcond=None)[0]
        M = x[:3].T
        rows.append((t0, (M + M.T) / 2 - np.eye(3), x[3], int(m.sum())))
    return rows


def mag_offset(rec):
    """The magnetometer's body-fixed offset (uT) with the reference's attitude, and the residual's RMS
    (uT) without and with it: ``m = R^T m_earth + o`` over the ``movement`` samples."""
    ok = rec.movement & np.isfinite(rec.truth).all(axis=1) & np.isfinite(rec.mag).all(axis=1)
    Rt = np.transpose(quat_to_matrix(rec.truth[ok]), (0, 2, 1))
    m = rec.mag[ok].reshape(-1)
    A = np.concatenate([Rt, np.broadcast_to(np.eye(3), Rt.shape)], axis=2).reshape(-1, 6)
    x = np.linalg.lstsq(A, m, rcond=None)[0]
    x0 = np.linalg.lstsq(A[:, :3], m, rcond=None)[0]
    res = lambda r: float(np.sqrt(3 * np.mean(r ** 2)))  # noqa: E731 (RMS of the 3-vector)
    return x[3:], res(m - A[:, :3] @ x0), res(m - A @ x)


def _pct(v):
    return "(" + ", ".join(f"{100 * e:+.2f}" for e in v) + ")"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default=None, help="comma-separated name prefixes")
    ap.add_argument("--windows", action="store_true")
    ap.add_argument("--mag", action="store_true")
    ap.add_argument("--no-runs", action="store_true", help="the fits only")
    args = ap.parse_args()
    trials = discover(args.data)
    if args.trials:
        pre = args.trials.split(",")
        trials = [t for t in trials if any(t.name.startswith(p) for p in pre)]
    print("E in %: diagonal (x, y, z) and symmetric off-diagonal (xy, xz, yz); bias deg/s")
    runs = []
    for tr in trials:
        rec = tr.load()
        (_, E, bias, n), = fit(rec)
        line = (f"{tr.name[:34]:34s} reference E diag {_pct(np.diag(E))} off {_pct(E[[0, 0, 1], [1, 2, 2]])} "
                f"bias {np.round(np.degrees(bias), 3)}")
        if not args.no_runs:
            fixed = copy.copy(rec)
            fixed.gyr = np.ascontiguousarray(rec.gyr @ np.linalg.inv(np.eye(3) + E).T)
            res = fk.make("recommended", use_mag=False).run(rec, progress=False)
            r = (rms_errors(res, rec)["inclination"],
                 rms_errors(fk.make("recommended", use_mag=False, gyro_rate_estimate="off").run(rec, progress=False),
                            rec)["inclination"],
                 rms_errors(fk.make("recommended", use_mag=False, gyro_rate_estimate="off").run(fixed, progress=False),
                            rec)["inclination"])
            runs.append(r)
            line += (f" | online E diag {_pct(np.diag(res.diagnostics['gyro_rate_error']))} | 6D correct {r[0]:.3f}"
                     f" off {r[1]:.3f} reference E {r[2]:.3f}")
        print(line, flush=True)
        if args.windows:
            for t0, Ew, bw, _ in fit(rec, WINDOW):
                print(f"    {t0:5.0f}-{t0 + WINDOW:.0f} s E diag {_pct(np.diag(Ew))} bias {np.round(np.degrees(bw), 3)}")
        if args.mag and rec.mag is not None:
            o, before, after = mag_offset(rec)
            print(f"    magnetometer offset {np.round(o, 2)} uT (|o| {np.linalg.norm(o):.2f}); residual RMS {before:.2f} "
                  f"-> {after:.2f} uT")
    if runs:
        m = np.mean(runs, axis=0)
        print(f"mean ({len(runs)} trials): 6D correct {m[0]:.3f} off {m[1]:.3f} reference E {m[2]:.3f}")


if __name__ == "__main__":
    main()
