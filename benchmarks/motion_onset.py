"""Source 000's motion detector against the BROAD `movement` flags.

    python benchmarks/motion_onset.py [--data DIR] [--gravity-source model|measured]

Per trial: the detector's onset relative to the first flagged movement sample (negative =
before the flag), how many samples fire before the flag, and the evidence at the onset: the
gyro norm there against its mean over the rest before it, and the largest rotation of the
optical reference within 0.5 s after the onset against its attitude 2 s before (the optical
reference has noise of a few tenths of a degree). Also the `poisson` filter's inclination error
at the end of its alignment (how good source 000's alignment is on real data).
"""

from __future__ import annotations

import argparse

import numpy as np

import fusionkit as fk
from _common import data_dir
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.rotations import quat_angle


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--gravity-source", default="model", choices=["model", "measured"])
    args = ap.parse_args()
    from pathlib import Path

    files = sorted(Path(args.data).glob("*.hdf5"))
    if not files:
        raise SystemExit(f"no BROAD trials in {args.data}")
    det = fk.make("motion", kind="detector", gravity_source=args.gravity_source)
    flt = fk.make("poisson", motion={"gravity_source": args.gravity_source})
    print("| trial | onset - flag [s] | samples firing before the flag | first criteria | gyro norm at onset / rest mean "
          "| reference rotation 0.5 s after onset [deg] | alignment inclination error [deg] |")
    print("|---|---:|---:|---|---:|---:|---:|")
    delays, early = [], 0
    for f in files:
        rec = fk.load(f)
        fs = rec.rate
        start = int(np.argmax(rec.movement))
        r = det.run(rec)
        on = r.onset_index
        if on is None:
            print(f"| {rec.name} | never | - | - | - | - | - |")
            continue
        ok = np.isfinite(rec.truth).all(axis=1)
        i0 = max(0, on - int(2 * fs))
        ref_idx = [k for k in range(i0, on) if ok[k]]
        after = [k for k in range(on, min(on + int(0.5 * fs), len(rec))) if ok[k]]
        moved = np.degrees(quat_angle(rec.truth[after], rec.truth[ref_idx[0]])).max() if after and ref_idx else np.nan
        w_rest = np.linalg.norm(rec.gyr[:on], axis=1).mean()
        w_on = np.linalg.norm(rec.gyr[on], axis=0)
        res = flt.run(rec)
        k = res.diagnostics["alignment_end_index"] - 1
        incl = broad_errors(res.quat[k:k + 1], rec.truth[k:k + 1])["inclination"][0] if ok[k] else np.nan
        delays.append((on - start) / fs)
        early += on < start
        print(f"| {rec.name} | {(on - start) / fs:+.2f} | {int(r.fired[:start].sum())} | {', '.join(r.which(on))} "
              f"| {w_on / w_rest:.1f} | {moved:.2f} | {incl:.2f} |")
    d = np.array(delays)
    print(f"\nonset before the flag in {early}/{len(d)} trials; median onset - flag {np.median(d):+.2f} s, "
          f"range {d.min():+.2f} .. {d.max():+.2f} s")


if __name__ == "__main__":
    main()
