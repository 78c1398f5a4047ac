"""The bias in motion in ``recommended`` (``bias_filter``, ``bias_sigma_rest``) on the BROAD trials:
6D inclination and 9D total, per trial, per group and the mean without the trial each variant
helps most (leave-one-out), VQF in the same run.

    python benchmarks/bias_in_motion.py [--data DIR] [--trials A,B] [--windows] [--sims]

``--windows`` prints, per 15 s window, the gyroscope minus the reference's rate (median, deg/s:
the error the gyro has there, bias and rate-proportional parts together) beside the bias each
variant holds at the window's end: a rest's bias against the error in motion.

``--sims`` runs the simulator's short-rest scenarios instead (2 s of rest, of which 0.5 s of REST
samples, and a MEMS turn-on bias of 0.45 deg/s: what BROAD's 30 s rests at the start hide): 6D
inclination and 9D total RMS per scenario.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from _common import data_dir, group_and_loo_tables

import fusionkit as fk
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.rotations import quat_conj, quat_mul

VARIANTS = {  # label: recommended's parameters (None: VQF)
    "lowpass (before)": {"bias_filter": "lowpass"},
    "kalman (default)": {},
    "kalman, VQF's rest 0.03 deg/s": {"bias_sigma_rest": math.radians(0.03)},
    "rest gain fixed (before stop 18)": {"rest_bias_gain": "fixed"},
    "no bias in motion": {"motion_bias_tau": None},
    "vqf": None,
}


def _windows(rec, window: float = 15.0) -> None:
    q = np.asarray(rec.truth)
    dq = quat_mul(quat_conj(q[:-1]), q[1:])
    dq = dq * np.where(dq[:, :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(dq[:, 1:], axis=1)
    w_ref = dq[:, 1:] * (2.0 * np.arctan2(s, dq[:, 0]) / np.where(s > 0, s, 1.0) / rec.dt[1:])[:, None]
    err = rec.gyr[1:] - w_ref
    n, step = len(err), int(window / rec.nominal_dt)
    held = {}
    for label, params in VARIANTS.items():
        if params is None:
            continue
        f, st, held[label] = fk.make("recommended", use_mag=False, **params), None, []
        for k in range(0, n, step):
            res = f.run(rec.slice(k, min(k + step, n + 1)), state=st)
            st = res.diagnostics["state"]
            held[label].append(np.degrees(res.diagnostics["bias"]))
    print(f"\n{rec.name}: window start (s), moving fraction, gyro - reference (deg/s), bias held: "
          + ", ".join(held))
    for i, k in enumerate(range(0, n, step)):
        seg = err[k:k + step]
        seg = seg[np.isfinite(seg).all(axis=1)]
        ref = np.degrees(np.median(seg, axis=0)) if len(seg) else np.full(3, np.nan)
        print(f"  {k * rec.nominal_dt:5.0f} {rec.movement[k + 1:k + 1 + step].mean():.2f} {np.round(ref, 3)} "
              + " ".join(str(np.round(b[i], 3)) for b in held.values()))


SIMS = ("hand-held", "tapped", "vibrating", "late-mag")


def _sims() -> None:
    print("| variant | " + " | ".join(f"{n} 6D" for n in SIMS) + " | " + " | ".join(f"{n} 9D" for n in SIMS) + " |")
    print("|---|" + "---:|" * (2 * len(SIMS)))
    recs = [fk.sim.scenario(n) for n in SIMS]
    for label, params in VARIANTS.items():
        cells = []
        for dims, use_mag, metric in (("6D", False, "inclination"), ("9D", True, "total")):
            for rec in recs:
                f = (fk.make("vqf", mode=dims) if params is None
                     else fk.make("recommended", use_mag=use_mag, **params))
                cells.append(rms_errors(f.run(rec), rec)[metric])
        print(f"| {label} | " + " | ".join(f"{x:.3f}" for x in cells) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default="")
    ap.add_argument("--windows", action="store_true")
    ap.add_argument("--sims", action="store_true")
    args = ap.parse_args()
    if args.sims:
        _sims()
        return
    rows = {"6D": [], "9D": []}
    for tr in discover(args.data, args.trials.split(",") if args.trials else None):
        rec = tr.load()
        for dims, use_mag, metric in (("6D", False, "inclination"), ("9D", True, "total")):
            row = {"trial": rec.name, "groups": list(tr.groups), "errors": {}}
            for label, params in VARIANTS.items():
                f = (fk.make("vqf", mode=dims) if params is None
                     else fk.make("recommended", use_mag=use_mag, **params))
                row["errors"][label] = rms_errors(f.run(rec), rec)[metric]
            rows[dims].append(row)
        print(rec.name, " ".join(f"{d} " + " ".join(f"{v:.3f}" for v in rows[d][-1]["errors"].values())
                                 for d in rows), flush=True)
        if args.windows:
            _windows(rec)
    labels = list(VARIANTS)
    for dims, metric in (("6D", "inclination"), ("9D", "total")):
        print(f"\n{dims} {metric} (deg)\n| trial | " + " | ".join(labels) + " |")
        print("|---|" + "---:|" * len(labels))
        for r in rows[dims]:
            print(f"| {r['trial']} | " + " | ".join(f"{r['errors'][k]:.3f}" for k in labels) + " |")
        group_and_loo_tables(rows[dims], labels, "lowpass (before)")


if __name__ == "__main__":
    main()
