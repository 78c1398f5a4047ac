"""Where VQF still leads `recommended` in 6D on BROAD, and why: the groups, the taps, the segments.

    python benchmarks/broad_groups.py [--data DIR] [--lead S]      # per trial and group, VQF same run
    python benchmarks/broad_groups.py --taps [--data DIR]          # trial 24: each tap's velocity step
    python benchmarks/broad_groups.py --segments [--data DIR]      # 24, 26, 15 in time, fixed tau swept

Default: 6D inclination RMS (deg, over the ``movement`` samples) of ``recommended`` (defaults, with
its impulse clip of 10 since stop 21), ``recommended`` with ``impulse_clip=None`` (the behaviour
before) and VQF, per trial, per BROAD group (``trials.json``) and without the trial the clip helps
most. ``--lead``: every output predicted ahead by ``S`` seconds
(``recommended``'s ``output_lead``; VQF's quaternion turned by ``exp(w S)`` with the measured rate
afterwards, the same prediction), BROAD's reference clock offset being about 0.00245 s.

``--taps``: on the tapping trial, each tap (``| |a| - g | > 30 m/s^2``, 1 s apart) and the velocity
step it gives, integrated from the specific force in the reference's earth frame less gravity
(``R a - g e_z``, over 50 ms before to 100 ms / 1 s after the tap) against the reference's own
(the optical position's derivative over 60 ms at both ends); then the inclination error of each
filter averaged over the taps, from 1 s before to 5 s after them.

``--segments``: the three trials VQF leads (24 tapping, 26 vibration, 15 fast translation), the RMS
over a few segments of each for `recommended`, without the clip, fixed time constants 1-4 s, two
``gyro_rate_error`` values and VQF.
"""

from __future__ import annotations

import argparse
import json
import warnings

import numpy as np
from _common import data_dir, group_and_loo_tables

import fusionkit as fk
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.conventions import change_frame
from fusionkit.rotations import quat_from_rotvec, quat_mul, quat_to_matrix

G = 9.81
NO_CLIP = "impulse_clip=None"  # recommended without its default impulse clip (10): the behaviour before
SEGMENTS = {"24": [(45, 100), (100, 140), (140, 150), (150, 166)],  # the last taps (151, 155 s) are the largest
            "26": [(46, 100), (100, 150), (150, 160), (160, 166)],  # 160-165 s: still, the phone vibrating
            "15": [(40, 60), (60, 100), (100, 146)]}


def _filters(lead: float) -> dict:
    kw = {"output_lead": lead} if lead else {}
    return {"recommended": fk.make("recommended", use_mag=False, **kw),
            NO_CLIP: fk.make("recommended", use_mag=False, impulse_clip=None, **kw),
            "VQF": fk.make("vqf", mode="6D")}


def _errors(f, rec, lead: float = 0.0) -> np.ndarray:
    """Per-sample inclination error (deg); VQF's output predicted by ``lead`` s with the measured rate."""
    res = f.run(rec)
    q = res.quat
    if lead and f.name == "vqf":
        q = quat_mul(q, quat_from_rotvec(rec.gyr * lead))
    return broad_errors(q, change_frame(rec.truth, rec.truth_frame, res.frame))["inclination"]


def _rms(e, mask) -> float:
    v = e[mask]
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v)))


def groups(args) -> None:
    meta = json.loads((args.data / "trials.json").read_text())["trials"]
    filters = _filters(args.lead)
    rows = []
    for t in discover(args.data):
        rec = t.load()
        errs = {k: _rms(_errors(f, rec, args.lead), rec.movement) for k, f in filters.items()}
        rows.append({"trial": t.name[:2], "groups": [g for g in meta[t.name]["groups"] if g != "all_trials"],
                     "errors": errs})
        print(t.name[:2], " ".join(f"{k} {v:.4f}" for k, v in errs.items()), flush=True)
    group_and_loo_tables(rows, list(filters), NO_CLIP)


def _taps(rec) -> list[int]:
    a = np.linalg.norm(rec.acc, axis=1) - G
    taps: list[int] = []
    for i in np.flatnonzero(a > 30.0):
        if not taps or i - taps[-1] > rec.rate:
            taps.append(int(i))
    return taps


def taps(args) -> None:
    trial = discover(args.data, ["24"])[0]
    rec = trial.load()
    import h5py

    with h5py.File(trial.path, "r") as f:
        pos = f["opt_pos"][:]
    fs = rec.rate
    ae = np.einsum("nij,nj->ni", quat_to_matrix(rec.truth), rec.acc) - [0.0, 0.0, G]
    k = int(0.03 * fs)

    def vel(i):
        return (pos[i + k] - pos[i - k]) / (2 * k / fs)

    found = _taps(rec)
    print(f"{trial.name}: {len(found)} taps; velocity step (m/s, earth x y z): accelerometer / optical")
    print("| t (s) | peak |a| - g | 100 ms: acc | optical | 1 s: acc | optical | horizontal difference, 1 s |")
    print("|---:|---:|---|---|---|---|---:|")
    diffs = []
    for t in found:
        cells = []
        for w1 in (0.1, 1.0):
            i0, i1 = t - int(0.05 * fs), t + int(w1 * fs)
            dv_acc, dv_opt = np.nansum(ae[i0:i1], axis=0) / fs, vel(i1) - vel(i0)
            cells += [np.array2string(dv_acc, precision=2), np.array2string(dv_opt, precision=2)]
        diffs.append(float(np.hypot(*(dv_acc - dv_opt)[:2])))
        peak = float(np.max(np.linalg.norm(rec.acc[t - 5:t + 20], axis=1)) - G)
        print(f"| {t / fs:.1f} | {peak:.0f} | " + " | ".join(cells) + f" | {diffs[-1]:.2f} |")
    print(f"horizontal difference over 1 s: median {np.median(diffs):.2f}, max {max(diffs):.2f} m/s")
    pre, post = int(fs), int(5 * fs)
    prof = {}
    for name, f in _filters(0.0).items():
        e = np.nan_to_num(_errors(f, rec))
        prof[name] = np.mean([e[t - pre:t + post] for t in found], axis=0)
    print("\nthe inclination error averaged over the taps (deg), from the tap:")
    print("| s | " + " | ".join(prof) + " |")
    print("|---:|" + "---:|" * len(prof))
    for j in range(0, pre + post, int(0.5 * fs)):
        print(f"| {(j - pre) / fs:+.1f} | " + " | ".join(f"{p[j]:.3f}" for p in prof.values()) + " |")


def segments(args) -> None:
    variants = {"recommended": {}, NO_CLIP: {"impulse_clip": None}}
    variants |= {f"tau_acc {t:g} fixed": {"tau_adapt": False, "tau_acc": t} for t in (1.0, 1.5, 2.0, 3.0, 4.0)}
    variants |= {f"gyro_rate_error {k:g}": {"gyro_rate_error": k} for k in (0.005, 0.01)}
    for name, segs in SEGMENTS.items():
        rec = discover(args.data, [name])[0].load()
        t = np.arange(len(rec.acc)) / rec.rate
        masks = [rec.movement & (t >= a) & (t < b) for a, b in segs]
        print(f"\n{rec.name}\n| variant | all | " + " | ".join(f"{a}-{b} s" for a, b in segs) + " |")
        print("|---|---:|" + "---:|" * len(segs))
        runs = {k: fk.make("recommended", use_mag=False, **v) for k, v in variants.items()}
        runs["VQF"] = fk.make("vqf", mode="6D")
        for k, f in runs.items():
            e = _errors(f, rec)
            print(f"| {k} | {_rms(e, rec.movement):.3f} | " + " | ".join(f"{_rms(e, m):.3f}" for m in masks) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--lead", type=float, default=0.0, help="output lead, s (BROAD's clock offset: 0.00245)")
    ap.add_argument("--taps", action="store_true", help="trial 24's taps: velocity steps and the error after them")
    ap.add_argument("--segments", action="store_true", help="24, 26, 15 in segments, fixed tau and kappa swept")
    args = ap.parse_args()
    from pathlib import Path

    args.data = Path(args.data)
    warnings.simplefilter("ignore")
    if args.taps:
        taps(args)
    elif args.segments:
        segments(args)
    else:
        groups(args)


if __name__ == "__main__":
    main()
