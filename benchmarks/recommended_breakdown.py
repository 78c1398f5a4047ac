"""Where ``recommended`` 9D's end-to-end time goes, against VQF's ``updateBatch`` in the same process.

    python benchmarks/recommended_breakdown.py [--samples 1000000] [--repeat 5] [--trial PATH]

Two tables, CPU time per sample, median over ``--repeat`` rounds (each round times VQF first, then
every case, so all see the same machine load):

1. end to end: ``fk.Recording(...)`` from the raw arrays, then ``run()`` split into the input's
   finiteness scan (a pipeline with a sensor model checks its input before the loop), the
   compiled loop (``Pipeline._run_compiled``) and the rest of ``run()`` (the run's own arrays, the
   diagnostics, the Result);
2. the loop per plugin: the composition with one plugin removed at a time (and mag-calibration
   with its segments never closing), so each part's cost is the difference to the default.

The recording is a BROAD trial tiled to ``--samples`` (``benchmarks/throughput.py``'s
``broad_arrays``); the script needs the data and VQF. A loaded machine moves the absolute numbers:
read the differences and the ratios to VQF.
"""

from __future__ import annotations

import argparse
import copy
import os
import time

import numpy as np

import fusionkit as fk
from fusionkit import pipeline as pl
from _common import data_dir, machine
from throughput import broad_arrays

CLOCK = time.process_time


def variants() -> dict[str, fk.Filter]:
    """The default composition and the variants without one part each."""
    base = fk.make("recommended").pipeline_config().model_dump()

    def make(change):
        d = copy.deepcopy(base)
        change(d)
        return pl.Pipeline(d)

    def without(name):
        return lambda d: d.update(correctors=[c for c in d["correctors"] if c["name"] != name])

    return {
        "recommended 9D (default)": make(lambda d: None),
        "mag-calibration without segments": make(
            lambda d: d["models"][0]["params"].update(segment_angle=1e3, segment_time=1e3)),
        "without mag-calibration": make(lambda d: d.update(models=[])),
        "without mag-heading": make(without("mag-heading")),
        "without inertial-tilt": make(without("inertial-tilt")),
        "inertial-tilt without the bias in motion": make(
            lambda d: [c["params"].update(motion_bias_tau=None, rate_error_estimate=False, rate_error_correct=False)
                       for c in d["correctors"] if c["name"] == "inertial-tilt"]),
        "without rest-bias-lowpass": make(without("rest-bias-lowpass")),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--trial", default=str(data_dir() / "broad" / "21_undisturbed_fast_combined.hdf5"))
    args = ap.parse_args()
    import vqf

    g, a, m, rate = broad_arrays(args.trial, args.samples)
    n = len(g)
    cases = variants()
    rec = fk.Recording(gyr=g, acc=a, mag=m, rate=rate)
    for f in cases.values():
        f.run(rec.slice(0, 300))  # compile or load
    spent = {"loop": 0.0, "scan": 0.0}
    run_compiled, scan = pl.Pipeline._run_compiled, pl.check_finite_all

    def timed(key, fn):
        def wrapper(*args, **kw):
            t = CLOCK()
            fn(*args, **kw)
            spent[key] += CLOCK() - t
        return wrapper

    parts, loops = [], {k: [] for k in cases}
    default = cases["recommended 9D (default)"]
    for _ in range(args.repeat):
        t = CLOCK()
        vqf.VQF(1.0 / rate).updateBatch(g, a, m)
        t_vqf = CLOCK() - t
        spent["loop"] = spent["scan"] = 0.0
        pl.Pipeline._run_compiled, pl.check_finite_all = timed("loop", run_compiled), timed("scan", scan)
        try:
            t0 = CLOCK()
            r = fk.Recording(gyr=g, acc=a, mag=m, rate=rate)
            t1 = CLOCK()
            default.run(r, progress=False)
            t2 = CLOCK()
        finally:
            pl.Pipeline._run_compiled, pl.check_finite_all = run_compiled, scan
        parts.append((t_vqf, t1 - t0, t2 - t1, spent["scan"], spent["loop"], t2 - t1 - spent["scan"] - spent["loop"]))
        for k, f in cases.items():
            t = CLOCK()
            f.run(rec, progress=False)
            loops[k].append(CLOCK() - t)
    ns = np.median(np.array(parts), axis=0) / n * 1e9
    e2e = np.median([(p[1] + p[2]) / p[0] for p in parts])
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.1f}; {n:,} samples of {os.path.basename(args.trial)}")
    print("\n| end to end | ns/sample |\n|---|---:|")
    for name, v in zip(["VQF updateBatch", "Recording build", "run()", "  input finiteness scan", "  compiled loop",
                        "  rest of run()"], ns):
        print(f"| {name} | {v:.0f} |")
    print(f"\nend to end / VQF updateBatch: {1.0 / e2e:.2f}x (median of the rounds' ratios)")
    base = np.median(loops["recommended 9D (default)"]) / n * 1e9
    print("\n| loop variant | run() ns/sample | difference to the default |\n|---|---:|---:|")
    for k, v in loops.items():
        t = np.median(v) / n * 1e9
        print(f"| {k} | {t:.0f} | {base - t:+.0f} |")


if __name__ == "__main__":
    main()
