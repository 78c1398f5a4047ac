"""Real recordings cut to start in motion: ``recommended`` against VQF, 9D, in the same run.

Every BROAD trial starts with a rest, where the magnetic reference, the heading and the inclination
are learned first. A recording cut from a longer one, or started in the middle of a movement, has
none. This cuts each BROAD trial (and each ``gnss/`` flight) to start at fractions of its length and
compares the filters on what is left (9D total RMSE, deg: over BROAD's movement samples, over every
sample of the flights). Nothing was tuned on these runs (docs/generalisation.md, "Stop 30").

    python benchmarks/start_in_motion.py [--data DIR] [--fractions 0.2,0.3,0.4,0.5,0.6]
                                         [--param KEY=VALUE ...] [--json FILE]

``--param`` (repeatable, the value JSON) sets a parameter of ``recommended`` (``--param
'magnetic={"max_rejection": 60}'``: the detector's clock, an option since stop 30; ``--param
'magnetic={"start_evidence": true}'``: a first reference learned in motion provisional, an option since stop 31).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
from _common import data_dir, machine, param_value

import fusionkit as fk
from fusionkit.benchmarking.metrics import rms_errors


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(data_dir()), help="the folder with broad/ and gnss/ (default ../shared/data)")
    ap.add_argument("--fractions", default="0.2,0.3,0.4,0.5,0.6", help="where each recording is cut to start")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--json", default="", help="write each run's RMSEs here")
    args = ap.parse_args()
    params = {k: param_value(v) for k, v in (p.split("=", 1) for p in args.param)}
    fractions = [float(f) for f in args.fractions.split(",")]
    root = Path(args.data)
    files = sorted((root / "broad").glob("*.hdf5")) + sorted((root / "gnss").glob("*/*.h5"))
    if not files:
        raise SystemExit(f"no recordings in {root / 'broad'} or {root / 'gnss'}")
    print(f"machine: {machine()}; recommended params: {params or 'defaults'}")
    rows = []
    warnings.simplefilter("ignore")  # GNSS epochs outside the cut IMU's time
    for path in files:
        rec = fk.load(path)
        n = len(rec)
        for frac in [0.0] + fractions:
            sub = rec.slice(int(frac * n), n)
            mask = sub.movement if sub.movement is not None else np.ones(len(sub), bool)
            if not mask.any():
                print(f"{rec.name} from {frac:.0%}: no movement left, skipped", file=sys.stderr, flush=True)
                continue
            ours = rms_errors(fk.make("recommended", **params).run(sub), sub, mask)["total"]
            vqf = rms_errors(fk.make("vqf").run(sub), sub, mask)["total"]
            rows.append({"recording": rec.name, "from": frac, "recommended": ours, "vqf": vqf})
            print(f"{rec.name} from {frac:.0%}: recommended {ours:.3f} vqf {vqf:.3f}", file=sys.stderr, flush=True)
    print("\n| recordings | from | runs | recommended | vqf | recommended wins | losses > 10 % |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for kind, pick in (("BROAD", lambda r: not r["recording"].startswith(("car", "heli"))),
                       ("gnss flights", lambda r: r["recording"].startswith(("car", "heli")))):
        for label, sel in (("the start", lambda r: r["from"] == 0.0), ("cut", lambda r: r["from"] > 0.0)):
            rs = [r for r in rows if pick(r) and sel(r)]
            if not rs:
                continue
            a, b = np.array([r["recommended"] for r in rs]), np.array([r["vqf"] for r in rs])
            print(f"| {kind} | {label} | {len(rs)} | {a.mean():.3f} | {b.mean():.3f} | {np.mean(a < b):.0%} | "
                  f"{int(np.sum(a > 1.1 * b))} |")
    lost = sorted((r for r in rows if r["recommended"] > 1.1 * r["vqf"]), key=lambda r: -r["recommended"] / r["vqf"])
    print("\nlosses by more than 10 %:\n| recording | from | recommended | vqf |\n|---|---:|---:|---:|")
    for r in lost:
        print(f"| {r['recording']} | {r['from']:.0%} | {r['recommended']:.3f} | {r['vqf']:.3f} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
