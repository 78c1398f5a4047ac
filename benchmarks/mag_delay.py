"""The magnetometer's timing in ``recommended`` 9D on the BROAD trials: the held samples
(``mag_hold``) and the online magnetometer-vs-gyro delay estimate (``mag_delay_estimate``),
against the old pairing and VQF in the same run; per trial, per group, and the mean without the
trial each variant helps most (leave-one-out).

    python benchmarks/mag_delay.py [--data DIR] [--trials A,B] [--json OUT]

Offsets are in samples: ``d_mag`` is the estimate's remaining offset of the gyro against the
magnetometer beyond the configured pairing (negative: the magnetometer is later), as the
``time-offset`` model reports it; ``lags`` (against the optical reference) gives ``gyr - mag``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _common import data_dir, group_and_loo_tables

import fusionkit as fk
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.correctors.heading import MAG_DELAY
from fusionkit.models.time_offset import CONF, EST, NSEG, OFFSET, STD

VARIANTS = {  # label: recommended's parameters (None: VQF 9D)
    "no hold (old default)": {"mag_hold": False},
    "hold": {},
    "hold + estimate": {"mag_delay_estimate": True},
    "hold + estimate, forced (max_std 1e3)": {"mag_delay_estimate": True, "mag_delay_max_std": 1e3},
    "vqf": None,
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default="")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    rows = []
    for tr in discover(args.data, args.trials.split(",") if args.trials else None):
        rec = tr.load()
        rate = 1.0 / rec.nominal_dt
        row = {"trial": rec.name, "groups": list(tr.groups), "errors": {}}
        for label, params in VARIANTS.items():
            f = fk.make("vqf", mode="9D") if params is None else fk.make("recommended", **params)
            res = f.run(rec)
            row["errors"][label] = rms_errors(res, rec)["total"]
            if label == "hold + estimate":
                s = res.diagnostics["state"]["cor"][[c.name for c in f.correctors].index("mag-heading")]
                row.update(d_mag=s[MAG_DELAY + EST] * rate, d_mag_std=s[MAG_DELAY + STD] * rate,
                           d_mag_applied=s[MAG_DELAY + OFFSET] * rate, conf=bool(s[MAG_DELAY + CONF]),
                           segments=int(s[MAG_DELAY + NSEG]))
        rows.append(row)
        print(f"{rec.name}: d_mag {row['d_mag']:+.2f} (std {row['d_mag_std']:.2f}, applied {row['d_mag_applied']:+.2f}) "
              + "  ".join(f"{k}: {v:.3f}" for k, v in row["errors"].items()), flush=True)
    labels = list(VARIANTS)
    print("\n| trial | d_mag (std) | " + " | ".join(labels) + " |")
    print("|---|---:|" + "---:|" * len(labels))
    for r in rows:
        print(f"| {r['trial']} | {r['d_mag']:+.2f} ({r['d_mag_std']:.2f}) | "
              + " | ".join(f"{r['errors'][k]:.3f}" for k in labels) + " |")
    group_and_loo_tables(rows, labels, "no hold (old default)")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
