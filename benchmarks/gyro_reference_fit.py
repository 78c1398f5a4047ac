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
                                            [--full] [--bisect [--at 110]]

The fit: the reference's body rate from consecutive quaternions (``2 vec(conj(q[k-1]) q[k+1]) / (2 dt)``),
both it and the gyro low-passed at 5 Hz (zero phase), the gyro one sample earlier (the lag of least
residual on every BROAD trial), over samples that turn faster than 0.3 rad/s and lie more than 1 s from a
reference gap; ``gyro = M w + b`` by least squares, ``E = (M + M^T) / 2 - I``. A clock offset between the
IMU's samples and its timestamps scales every axis alike and cannot be told from a scale factor here (nor
by a filter, which integrates with the same timestamps): the isotropic part of ``E`` is either.

``--full`` fits the whole ``M`` and a g-sensitivity beside it, ``gyro = M w + b + G f`` (``f`` the
accelerometer, low-passed alike): ``M``'s antisymmetric part as the rotation ``phi`` (mrad) of the gyro's
axes against the reference's body frame, and ``G`` (deg/s per g, rows the gyro's axes). ``--bisect``
asks which sensor turns the online estimate: the recorded gyro with an accelerometer made from the
reference (its specific force ``R^T (a + g up)``, ``g`` 9.81, ``a`` the reference position differentiated
twice after a 10 Hz low-pass): gravity alone, with the linear acceleration, with the accelerometer's
body-fixed bias fitted against the reference (``acc = f + K r + b`` low-passed at 2 Hz, ``K r`` the
lever arm's centripetal and tangential terms), the recorded accelerometer, and it with that bias removed; for each the estimate at
``--at`` s and at the end, and the 6D inclination of ``recommended`` and VQF. ``--mag`` also prints
where the reference's north lies: the field's horizontal direction in the reference's frame (deg east
of its north axis) at the rests and over the motion, raw and with the fitted offset removed.
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
from fusionkit.conventions import change_frame, frame_matrix
from fusionkit.rotations import quat_conj, quat_mul, quat_normalize, quat_to_matrix, skew

LOWPASS = 5.0  # Hz: the rates compared below it (the reference's differentiated quaternions are noisy above)
MIN_RATE = 0.3  # rad/s: samples that turn slower say little about a rate-proportional error
WINDOW = 20.0  # s (--windows)
G = 9.81  # m/s^2: gravity of the accelerometer made from the reference (--bisect)


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


def fit_full(rec):
    """``(phi, G)``: ``gyro = M w + b + G f`` over every sample more than 1 s from a reference gap, the rests
    too (``f`` the accelerometer, low-passed as the rates): ``M``'s antisymmetric part as the rotation vector ``phi`` (rad)
    and the g-sensitivity ``G`` (rad/s per m/s^2)."""
    w, valid = _reference_rate(rec)
    b, a = butter(2, LOWPASS / (rec.rate / 2))
    wf, af = filtfilt(b, a, w, axis=0), filtfilt(b, a, rec.acc, axis=0)
    gf = np.roll(filtfilt(b, a, rec.gyr, axis=0), -1, axis=0)
    near_gap = np.convolve((~valid).astype(float), np.ones(2 * int(rec.rate) + 1), "same") > 0
    use = ~near_gap
    use[-1] = False
    x = np.linalg.lstsq(np.hstack([wf[use], np.ones((use.sum(), 1)), af[use]]), gf[use], rcond=None)[0]
    m = x[:3].T
    return np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) / 2, x[4:].T


def _reference_held(rec):
    """The reference's rotation (body -> ENU) and position, each missing sample held from the last finite
    one, and where both are finite."""
    q = change_frame(rec.truth, rec.truth_frame, "ENU")
    p = rec.meta["ref_pos"] @ frame_matrix(rec.truth_frame, "ENU").T
    ok = np.isfinite(q).all(axis=1) & np.isfinite(p).all(axis=1)
    hold = np.maximum.accumulate(np.where(ok, np.arange(len(rec)), 0))
    hold[:np.argmax(ok)] = np.argmax(ok)
    return quat_to_matrix(quat_normalize(q[hold])), p[hold], ok


def reference_accelerometers(rec):
    """``({name: (N, 3) accelerometer}, bias)``: the accelerometers of ``--bisect`` made from the reference
    (module doc), the recorded one and it less the bias, and the body-fixed bias (m/s^2) fitted against the reference."""
    rot, pos, ok = _reference_held(rec)
    b, a = butter(2, 10.0 / (rec.rate / 2))
    lin = np.gradient(np.gradient(filtfilt(b, a, pos, axis=0), axis=0), axis=0) * rec.rate ** 2
    grav = np.einsum("nji,j->ni", rot, [0.0, 0.0, G])
    force = np.einsum("nji,nj->ni", rot, lin + [0.0, 0.0, G])
    # the bias: acc = f + K r + b below 2 Hz, K = [w]x^2 + [dw/dt]x (the IMU's lever arm r from the position)
    b2, a2 = butter(2, 2.0 / (rec.rate / 2))
    w = filtfilt(b2, a2, rec.gyr, axis=0)
    k = np.einsum("nij,njk->nik", skew(w), skew(w)) + skew(np.gradient(w, axis=0) * rec.rate)
    use = ~(np.convolve((~ok).astype(float), np.ones(4 * int(rec.rate) + 1), "same") > 0)
    use[:int(3 * rec.rate)] = False
    y = (filtfilt(b2, a2, rec.acc, axis=0) - filtfilt(b2, a2, force, axis=0))[use]
    x = np.concatenate([k[use], np.broadcast_to(np.eye(3), (use.sum(), 3, 3))], axis=2).reshape(-1, 6)
    bias = np.linalg.lstsq(x, y.reshape(-1), rcond=None)[0][3:]
    return {"gravity": grav, "gravity + linear": force, "gravity + linear + bias": force + bias,
            "recorded": rec.acc, "recorded - bias": rec.acc - bias}, bias


def rate_error_at(rec, t_at: float):
    """The online estimate's ``E`` (recommended 6D) after ``t_at`` s and at the end, and the inclination RMSE."""
    f = fk.make("recommended", use_mag=False)
    part = f.run(rec.slice(0, int(t_at * rec.rate)), progress=False)
    res = f.run(rec, progress=False)
    return (part.diagnostics["gyro_rate_error"], res.diagnostics["gyro_rate_error"],
            rms_errors(res, rec)["inclination"])


def _sym(e):
    """E's six entries (00, 11, 22, 01, 02, 12) in %."""
    return "(" + ", ".join(f"{100 * v:+.2f}" for v in e[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]) + ")"


def north(rec, offset):
    """Where the reference's north lies: the field's horizontal direction (deg east of the reference frame's
    north axis), ``{(rest|motion, raw|offset removed): deg}``."""
    q = change_frame(rec.truth, rec.truth_frame, "ENU")
    ok = np.isfinite(q).all(axis=1) & np.isfinite(rec.mag).all(axis=1)
    rot = quat_to_matrix(np.where(ok[:, None], q, [1.0, 0.0, 0.0, 0.0]))
    t = np.arange(len(rec)) / rec.rate
    out = {}
    for name, m in (("raw", rec.mag), ("offset removed", rec.mag - offset)):
        e = np.einsum("nij,nj->ni", rot, m)
        for part, sel in (("rest", ok & ~rec.movement & (t > 2)), ("motion", ok & rec.movement)):
            v = e[sel].mean(axis=0)
            out[part, name] = float(np.degrees(np.arctan2(v[0], v[1])))
    return out


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
    ap.add_argument("--full", action="store_true", help="M's antisymmetric part and the g-sensitivity")
    ap.add_argument("--bisect", action="store_true", help="the estimate with accelerometers made from the reference")
    ap.add_argument("--at", type=float, default=110.0, help="--bisect: the estimate after this many seconds")
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
            d = north(rec, o)
            print("    field's direction from the reference's north (deg): " + ", ".join(
                f"{part} {name} {v:+.2f}" for (part, name), v in d.items()))
        if args.full:
            phi, g_sens = fit_full(rec)
            print(f"    M's antisymmetric part phi {np.round(1000 * phi, 2)} mrad; G (deg/s per g) "
                  f"{np.round(np.degrees(g_sens) * 9.81, 2).tolist()}")
        if args.bisect:
            accs, bias = reference_accelerometers(rec)
            print(f"    accelerometer bias fitted against the reference {np.round(bias, 3)} m/s^2; "
                  f"E in %: 00, 11, 22, 01, 02, 12")
            for name, acc in accs.items():
                r2 = copy.copy(rec)
                r2.acc = np.ascontiguousarray(acc)
                e_at, e_end, incl = rate_error_at(r2, args.at)
                vqf = rms_errors(fk.make("vqf", mode="6D").run(r2, progress=False), rec)["inclination"]
                print(f"    {name:24s} E at {args.at:.0f} s {_sym(e_at)} end {_sym(e_end)} | 6D {incl:.3f} VQF {vqf:.3f}",
                      flush=True)
    if runs:
        m = np.mean(runs, axis=0)
        print(f"mean ({len(runs)} trials): 6D correct {m[0]:.3f} off {m[1]:.3f} reference E {m[2]:.3f}")


if __name__ == "__main__":
    main()
