"""The ``time-offset`` sensor model on the BROAD trials: its estimates against ``fusionkit lags``,
and what re-timing does to ``recommended``, ``gradient-descent`` (6D inclination, 9D total),
with VQF in the same run.

    python benchmarks/time_offset.py [--data DIR] [--json OUT] [--trials A,B] [--extra]

The model reads only the IMU, so the re-timed recording (``retime_recording``, the kernel) fed
to a filter is what composing it first in a pipeline's ``models`` does. Offsets are in samples
(the gyro's delay against the accelerometer, ``d_acc``, and against the magnetometer, ``d_mag``);
``lags`` measures each sensor against the optical reference, so its ``gyr - acc`` and
``gyr - mag`` are what the model estimates from the IMU alone.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import fusionkit as fk
from _common import data_dir
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.benchmarking.timing import sensor_lags
from fusionkit.models.time_offset import ACC, CONF, EST, MAG, OFFSET, STD, retime_recording

FILTERS = {  # name: (filter, params, metric)
    "recommended 6D": ("recommended", {"use_mag": False}, "inclination"),
    "recommended 9D": ("recommended", {}, "total"),
    "gradient-descent 6D": ("gradient-descent", {"use_mag": False}, "inclination"),
    "gradient-descent 9D": ("gradient-descent", {}, "total"),
    "vqf 6D": ("vqf", {"mode": "6D"}, "inclination"),
    "vqf 9D": ("vqf", {"mode": "9D"}, "total"),
}
VARIANTS = {"raw": None, "model": {}, "model acc-clock": {"retime": "acc"}}
#: ``--extra``: the estimate applied whatever its confidence, and the magnetometer's alone
EXTRA = {"forced (max_std 1e3)": {"max_std": 1e3}, "mag only, gyro clock (max_std 0.35)": {"retime": "acc", "max_std": 0.35}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--json", default="")
    ap.add_argument("--trials", default="")
    ap.add_argument("--extra", action="store_true", help="also the variants in EXTRA")
    args = ap.parse_args()
    if args.extra:
        VARIANTS.update(EXTRA)
    trials = discover(args.data, args.trials.split(",") if args.trials else None)
    out = []
    for tr in trials:
        rec = tr.load()
        rate = 1.0 / rec.nominal_dt
        lags = sensor_lags(rec)
        row = {"trial": rec.name, "groups": list(tr.groups), "lag_gyr": lags.gyr, "lag_acc": lags.acc,
               "lag_mag": lags.mag, "errors": {}}
        recs = {}
        for var, params in VARIANTS.items():
            if params is None:
                recs[var] = rec
                continue
            r2, st = retime_recording(rec, backend="numba", **params)
            recs[var] = r2
            if var == "model":
                f = st[-1]
                row.update(d_acc=f[ACC + EST] * rate, d_acc_std=f[ACC + STD] * rate,
                           d_acc_applied=f[ACC + OFFSET] * rate, acc_conf=bool(f[ACC + CONF]),
                           acc_conf_at=float(np.argmax(st[:, ACC + CONF] > 0) / rate) if f[ACC + CONF] else None,
                           d_mag=f[MAG + EST] * rate, d_mag_std=f[MAG + STD] * rate,
                           d_mag_applied=f[MAG + OFFSET] * rate, mag_conf=bool(f[MAG + CONF]))
        for label, (name, params, metric) in FILTERS.items():
            for var in VARIANTS:
                if name == "vqf" and var != "raw":
                    continue
                res = fk.make(name, **params).run(recs[var])
                row["errors"][f"{label} | {var}"] = rms_errors(res, rec)[metric]
            if name == "recommended":  # the fixed lead of issue 14's measurement, for comparison
                res = fk.make(name, output_lead=0.00245, **params).run(rec)
                row["errors"][f"{label} | output_lead 0.00245"] = rms_errors(res, rec)[metric]
        out.append(row)
        print(f"{rec.name}: lags gyr-acc {lags.gyr - lags.acc:+.2f} gyr-mag {lags.gyr - lags.mag:+.2f} | model d_acc "
              f"{row['d_acc']:+.2f} (std {row['d_acc_std']:.3f}, applied {row['d_acc_applied']:+.2f}) d_mag "
              f"{row['d_mag']:+.2f} (std {row['d_mag_std']:.3f}, applied {row['d_mag_applied']:+.2f})", flush=True)
        print("   " + "  ".join(f"{k}: {v:.3f}" for k, v in row["errors"].items()), flush=True)
    keys = list(out[0]["errors"])
    print(f"\n| filter | variant | mean of {len(out)} trials [deg] |")
    print("|---|---|---:|")
    for k in keys:
        f, v = k.split(" | ")
        print(f"| {f} | {v} | {np.mean([r['errors'][k] for r in out]):.3f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
