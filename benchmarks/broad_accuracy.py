"""Every registered filter (default parameters) on the BROAD trials, with BROAD's metrics.

    python benchmarks/broad_accuracy.py [--data DIR] [--filters poisson,...]

RMS errors (deg) over the `movement` samples, NaN-aware: inclination for every filter, heading
and total too (a filter without a magnetometer has an arbitrary heading, so its total error is
not meaningful). Throughput is the numba run's, compilation excluded.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import fusionkit as fk
from _common import data_dir
from fusionkit.benchmarking.metrics import rms_errors


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--filters", default="")
    args = ap.parse_args()
    files = sorted(Path(args.data).glob("*.hdf5"))
    if not files:
        raise SystemExit(f"no BROAD trials in {args.data}")
    names = args.filters.split(",") if args.filters else [n for n in fk.available("filter") if n != "pipeline"]
    recs = [fk.load(f) for f in files]
    for name in names:
        f = fk.make(name)
        f.run(recs[0].slice(0, 100))
        print(f"\n{name}\n| trial | inclination RMSE [deg] | heading RMSE [deg] | total RMSE [deg] | samples/s |")
        print("|---|---:|---:|---:|---:|")
        incl = []
        for rec in recs:
            t0 = time.perf_counter()
            res = f.run(rec)
            sps = len(rec) / (time.perf_counter() - t0)
            e = rms_errors(res, rec)
            incl.append(e["inclination"])
            print(f"| {rec.name} | {e['inclination']:.2f} | {e['heading']:.2f} | {e['total']:.2f} | {sps:,.0f} |")
        print(f"| **mean of {len(recs)} trials** | {np.mean(incl):.2f} | | | |")


if __name__ == "__main__":
    main()
