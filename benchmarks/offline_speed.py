"""End-to-end speed of the offline mode against ``vqf-offline`` on the BROAD trials.

    python benchmarks/offline_speed.py [--data DIR] [--repeat 3]

``f.run(recording)`` for ``recommended`` with ``offline=True`` (9D and 6D) and ``vqf-offline``
(9D and 6D), each trial's best of ``--repeat`` runs (wall clock; compilation excluded by a first
run), the median over the trials in samples/s. Both see the same machine load: compare the ratio.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from _common import data_dir

import fusionkit as fk
from fusionkit.benchmarking.datasets import discover


def best_time(f, rec, repeat: int) -> float:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f.run(rec)
        out.append(time.perf_counter() - t0)
    return min(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    warnings.simplefilter("ignore")  # the trials' own warnings (gaps) are not what is measured here
    recs = [t.load() for t in discover(args.data)]
    filters = {"recommended offline 9D": fk.make("recommended", offline=True),
               "recommended offline 6D": fk.make("recommended", use_mag=False, offline=True),
               "vqf-offline 9D": fk.make("vqf-offline"), "vqf-offline 6D": fk.make("vqf-offline", mode="6D")}
    for f in filters.values():
        f.run(recs[0])  # compile
    rate = {k: np.median([len(r) / best_time(f, r, args.repeat) for r in recs]) for k, f in filters.items()}
    print(f"| filter | samples/s, median of {len(recs)} trials | vs vqf-offline (same dims) |\n|---|---:|---:|")
    for k, v in rate.items():
        peer = rate["vqf-offline " + k[-2:]]
        print(f"| {k} | {v:,.0f} | {v / peer:.2f}x |")


if __name__ == "__main__":
    main()
