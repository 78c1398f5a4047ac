"""The offline mode on the BROAD trials: ``recommended`` online, ``recommended`` offline and
``vqf-offline``, in one run (9D total RMSE and 6D inclination RMSE, deg, per trial and mean),
the mean without the trial the offline mode helps most (leave-one-out), and end-to-end
throughput (samples/s, compilation excluded).

    python benchmarks/offline_accuracy.py [--data DIR] [--trials 01,06] [--param key=value ...]

``--param`` sets a parameter of the recommended filter in both of its runs (an ablation);
``--equal-weights`` adds a column with the two passes fused half and half (the information
weights switched off); ``--no-mask`` a column without the disturbance mask decided by both passes
(``disturbance_gap=None``: each pass's own rejection only); ``--gap S`` sets ``disturbance_gap``
of the offline mode (default: ``OfflineFilter.DISTURBANCE_GAP``); ``--per-pass`` a column with each
pass running its own magnetometer calibration model (``calibration="per-pass"``, the mode before the
calibration was decided with the whole recording) and one without the model (``mag_calibration=False``);
``--as-is-timing`` a column with the magnetometer as it is recorded (``mag_timing="as-is"``, the mode
before its timing was decided with the whole recording); ``--average-inclination`` a column with the
passes' inclinations fused as they are (``inclination="average"``, the mode before the smoothing in
the other direction of time); ``--gyro-timing`` a column with the gyroscope moved onto the
accelerometer's clock by its delay estimated over the recording (``gyro_timing="recording"``, an
option; each trial's estimate is printed); ``--groups`` adds, per mode, the mean
of each BROAD group (``trials.json`` in the data folder: rotation, translation, slow, fast,
magnets ...) for every column: which kinds of motion the offline mode wins or loses against
``vqf-offline``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import fusionkit as fk
from _common import data_dir, machine
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.offline import OfflineFilter


def _value(text: str):
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


class _EqualWeights(OfflineFilter):
    """The offline mode with both passes weighted 1/2 on every sample."""

    def run(self, rec, **kw):
        import fusionkit.offline as off

        saved = off._weights
        off._weights = lambda a, b: np.full(a.shape, 0.5)
        try:
            return super().run(rec, **kw)
        finally:
            off._weights = saved


def _groups(path: Path, recs, err: dict, key: str) -> None:
    """The mean of every column per BROAD group (``trials.json``'s ``groups`` of each trial)."""
    if not path.exists():
        print(f"(no {path}: no groups)")
        return
    trials = json.loads(path.read_text())["trials"]
    member = [set(trials.get(r.name, {}).get("groups", [])) for r in recs]
    groups = sorted(dict.fromkeys(g for m in member for g in m), key=lambda g: g != "all_trials")  # all first
    names = list(err)
    print(f"\nper group: mean {key} RMSE [deg]\n| group (trials) | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for g in groups:
        idx = [i for i, m in enumerate(member) if g in m]
        print(f"| {g} ({len(idx)}) | " + " | ".join(f"{np.mean([err[n][i] for i in idx]):.3f}" for n in names) + " |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default="", help="comma-separated trial prefixes (default: all)")
    ap.add_argument("--param", action="append", default=[], help="key=value for recommended (JSON value)")
    ap.add_argument("--modes", default="9D,6D")
    ap.add_argument("--equal-weights", action="store_true")
    ap.add_argument("--no-mask", action="store_true", help="add the offline mode without the disturbance mask")
    ap.add_argument("--gap", type=float, default=OfflineFilter.DISTURBANCE_GAP, help="disturbance_gap [s]")
    ap.add_argument("--per-pass", action="store_true", help="add the per-pass calibration and no calibration")
    ap.add_argument("--as-is-timing", action="store_true", help="add the magnetometer's timing as recorded")
    ap.add_argument("--average-inclination", action="store_true",
                    help="add the passes' inclinations fused as they are (the mode before the smoothing)")
    ap.add_argument("--gyro-timing", action="store_true",
                    help="add the gyroscope re-timed onto the accelerometer's clock (gyro_timing='recording')")
    ap.add_argument("--groups", action="store_true", help="add the mean per BROAD group (trials.json)")
    args = ap.parse_args()
    files = sorted(Path(args.data).glob("*.hdf5"))
    if args.trials:
        keep = tuple(args.trials.split(","))
        files = [f for f in files if f.name.startswith(keep)]
    if not files:
        raise SystemExit(f"no BROAD trials in {args.data}")
    params = dict(p.split("=", 1) for p in args.param)
    params = {k: _value(v) for k, v in params.items()}
    recs = [fk.load(f) for f in files]
    print(f"machine: {machine()}; recommended params: {params or 'defaults'}")
    for mode in args.modes.split(","):
        six = mode == "6D"
        kw = dict(params, use_mag=False) if six else params
        runs = {"recommended": fk.make("recommended", **kw),
                "recommended offline": OfflineFilter(fk.make("recommended", **kw), disturbance_gap=args.gap),
                "vqf-offline": fk.make("vqf-offline", mode="6D" if six else "auto")}
        if args.equal_weights:
            runs["offline, equal weights"] = _EqualWeights(fk.make("recommended", **kw), disturbance_gap=args.gap)
        if args.no_mask and not six:
            runs["offline, no mask"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=None)
        if args.per_pass and not six:
            runs["offline, per-pass calibration"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=args.gap,
                                                                  calibration="per-pass")
            runs["offline, no calibration"] = OfflineFilter(fk.make("recommended", **dict(kw, mag_calibration=False)),
                                                            disturbance_gap=args.gap)
        if args.as_is_timing and not six:
            runs["offline, timing as-is"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=args.gap,
                                                          mag_timing="as-is")
        if args.average_inclination:
            runs["offline, inclination averaged"] = OfflineFilter(fk.make("recommended", **kw),
                                                                  disturbance_gap=args.gap, inclination="average")
        if args.gyro_timing:
            runs["offline, gyro timing"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=args.gap,
                                                         gyro_timing="recording")
        key = "inclination" if six else "total"
        err = {n: [] for n in runs}
        secs = {n: 0.0 for n in runs}
        for f in runs.values():
            f.run(recs[0].slice(0, 500))  # compile
        for rec in recs:
            for n, f in runs.items():
                t0 = time.perf_counter()
                res = f.run(rec)
                secs[n] += time.perf_counter() - t0
                err[n].append(rms_errors(res, rec)[key])
                if n == "offline, gyro timing":
                    g = res.diagnostics["gyro_timing"]
                    print(f"{rec.name}: gyro delay {g['delay'] / rec.nominal_dt:+.2f} +- "
                          f"{g['std'] / rec.nominal_dt:.2f} samples, applied {g['applied']}")
        names = list(runs)
        print(f"\n{mode}: {key} RMSE [deg]\n| trial | " + " | ".join(names) + " |")
        print("|---|" + "---:|" * len(names))
        for i, rec in enumerate(recs):
            print(f"| {rec.name} | " + " | ".join(f"{err[n][i]:.2f}" for n in names) + " |")
        print("| **mean** | " + " | ".join(f"**{np.mean(err[n]):.3f}**" for n in names) + " |")
        pairs = [("recommended", "recommended offline", "offline's")]
        if args.equal_weights:
            pairs.append(("offline, equal weights", "recommended offline", "the information weights'"))
        if "offline, no mask" in runs:
            pairs.append(("offline, no mask", "recommended offline", "the disturbance mask's"))
        if "offline, per-pass calibration" in runs:
            pairs.append(("offline, per-pass calibration", "recommended offline", "the recording's calibration's"))
        if "offline, gyro timing" in runs:
            pairs.append(("recommended offline", "offline, gyro timing", "the gyro timing's"))
        if "offline, timing as-is" in runs:
            pairs.append(("offline, timing as-is", "recommended offline", "the recording's timing's"))
        for base, new, what in pairs:
            gain = np.array(err[base]) - np.array(err[new])
            best = int(np.argmax(gain))
            rest = [i for i in range(len(recs)) if i != best]
            print(f"| mean without {recs[best].name} ({what} largest gain, {gain[best]:.2f}) | "
                  + " | ".join(f"{np.mean([err[n][i] for i in rest]):.3f}" for n in names) + " |")
        total = sum(len(r) for r in recs)
        print("| samples/s (end to end) | " + " | ".join(f"{total / secs[n]:,.0f}" for n in names) + " |")
        if args.groups:
            _groups(Path(args.data) / "trials.json", recs, err, key)


if __name__ == "__main__":
    main()
