"""Throughput (samples/s) of every built-in filter and the peers, side by side, one core.

    python benchmarks/throughput.py [--samples 1000000] [--reference-samples 20000]

Compiled (numba) paths run on ``--samples`` samples after a warm-up (compilation excluded), best
of 3; readable reference paths, filters without a kernel (the filterpy EKF) and peers written in
Python (ahrs) on ``--reference-samples``. C/C++ peers (VQF, imufusion) run on ``--samples`` like
the compiled paths. The recording is synthetic (12 s still, then smooth rotations; accelerometer
and magnetometer noisy around fixed vectors): it measures speed only.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import fusionkit as fk
from _common import machine


def recording(n: int, rate: float = 285.7, mag: bool = True, gnss: bool = False) -> fk.Recording:
    rng = np.random.default_rng(0)
    rest = int(12 * rate)
    gyr = 0.01 * rng.standard_normal((n, 3))
    gyr[rest:] += np.sin(np.arange(n - rest)[:, None] / rate * [1.0, 1.3, 0.7])  # moving after 12 s
    acc = np.array([0.0, 0.0, 9.81]) + 0.03 * rng.standard_normal((n, 3))
    m = np.array([0.0, 19.0, -47.0]) + 0.3 * rng.standard_normal((n, 3)) if mag else None
    g = None
    if gnss:  # 10 Hz, 20 m/s north, a 20 s gap every 100 s
        t = np.arange(0.0, (n - 1) / rate, 0.1)
        vel = np.tile([0.0, 20.0, 0.0], (t.size, 1)) + 0.05 * rng.standard_normal((t.size, 3))
        g = fk.Gnss(t=t, vel=vel, valid=(t % 100.0) < 80.0, frame="ENU")
    return fk.Recording(gyr=gyr, acc=acc, mag=m, rate=rate, gnss=g)


def best_rate(f, rec, backend, repeat) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        f.run(rec, backend=backend, progress=False)
        best = min(best, time.perf_counter() - t0)
    return len(rec) / best


def pipe(spec):
    return lambda: fk.compose(spec)


# name: (factory, 9D? ("gnss": 6D with a GNSS stream), kind) with kind "ours" (numba and reference), "ref-only" (no kernel),
# "peer-fast" (compiled peer, big recording), "peer-slow" (Python peer, small recording)
CASES = {
    "poisson-quat first-order (integrator)": (pipe({"estimator": "poisson-quat", "alignment": {"mode": "none"}}),
                                              False, "ours"),
    "poisson-quat exact (integrator)": (pipe({"estimator": {"name": "poisson-quat", "params": {"step": "exact"}},
                                              "alignment": {"mode": "none"}}), False, "ours"),
    "poisson-dcm (integrator)": (pipe({"estimator": "poisson-dcm", "alignment": {"mode": "none"}}), False, "ours"),
    "poisson filter (alignment + motion detector + integrator)": (lambda: fk.make("poisson"), False, "ours"),
    "motion detector alone": (None, False, "detector"),
    "gst (source 001, autonomous)": (lambda: fk.make("gst"), False, "ours"),
    "gradient-descent 6D, N = 1 (source 003)": (lambda: fk.make("gradient-descent"), False, "ours"),
    "gradient-descent 9D, N = 1 (+ magnetic detector)": (lambda: fk.make("gradient-descent"), True, "ours"),
    "gradient-descent madgwick=True, 6D": (lambda: fk.make("gradient-descent", madgwick=True), False, "ours"),
    "channel-dcm 9D (source 002)": (lambda: fk.make("channel-dcm"), True, "ours"),
    "pipeline: poisson-quat + gst corrector (rate mode)": (
        pipe({"estimator": "poisson-quat", "detectors": ["motion"], "correctors": ["gst"]}), False, "ours"),
    "pipeline: poisson-quat + gst-gnss corrector + gnss-gap detector (GNSS rows, 10 Hz)": (
        pipe({"estimator": "poisson-quat", "detectors": ["gnss-gap", "motion"], "correctors": ["gst-gnss"]}), "gnss",
        "ours"),
    "pipeline: gradient-descent + rest-bias (state + rate, rest detector)": (
        pipe({"estimator": "poisson-quat", "correctors": ["gradient-descent", "rest-bias"], "detectors": ["rest"],
              "alignment": {"mode": "fixed", "duration": 3.0}}), False, "ours"),
    "recommended 9D": (lambda: fk.make("recommended"), True, "ours"),
    "recommended 6D": (lambda: fk.make("recommended"), False, "ours"),
    "ekf 9D (filterpy)": (lambda: fk.make("ekf"), True, "ref-only"),
    "ekf 6D (filterpy)": (lambda: fk.make("ekf"), False, "ref-only"),
    "vqf (peer, C++), 6D": (lambda: fk.make("vqf", mode="6D"), False, "peer-fast"),
    "vqf (peer, C++), 9D": (lambda: fk.make("vqf"), True, "peer-fast"),
    "imufusion (peer, C), 9D": (lambda: fk.make("imufusion"), True, "peer-fast"),
    "ahrs-madgwick (peer, Python), 9D": (lambda: fk.make("ahrs-madgwick"), True, "peer-slow"),
    "ahrs-ekf (peer, Python), 9D": (lambda: fk.make("ahrs-ekf"), True, "peer-slow"),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--reference-samples", type=int, default=20_000)
    ap.add_argument("--only", default="", help="comma-separated substrings of case names")
    args = ap.parse_args()
    recs = {(size, kind): recording(n, mag=kind is True, gnss=kind == "gnss")
            for size, n in (("big", args.samples), ("small", args.reference_samples)) for kind in (False, True, "gnss")}
    print(f"machine: {machine()}")
    print(f"| case | compiled samples/s ({args.samples:,} samples) | reference samples/s "
          f"({args.reference_samples:,}) |")
    print("|---|---:|---:|")
    for name, (build, nine, kind) in CASES.items():
        if args.only and not any(s in name for s in args.only.split(",")):
            continue
        big, small = recs[("big", nine)], recs[("small", nine)]
        fast = ref = float("nan")
        try:
            if kind == "detector":
                det = fk.make("motion", kind="detector")
                det.run(small.slice(0, 100), backend="numba")
                t0 = time.perf_counter()
                det.run(big, backend="numba")
                fast = len(big) / (time.perf_counter() - t0)
                t0 = time.perf_counter()
                det.run(small, backend="reference")
                ref = len(small) / (time.perf_counter() - t0)
            else:
                f = build()
                if kind == "ours":
                    f.run(small.slice(0, 100), backend="numba")  # compile
                    fast = best_rate(f, big, "numba", 3)
                    ref = best_rate(f, small, "reference", 1)
                elif kind == "ref-only":
                    ref = best_rate(f, small, "reference", 1)
                elif kind == "peer-fast":
                    f.run(small.slice(0, 100))
                    fast = best_rate(f, big, "auto", 3)
                else:
                    ref = best_rate(f, small, "auto", 1)
        except ImportError as exc:  # a peer that is not installed
            print(f"| {name} | not installed ({exc.name}) | |")
            continue
        cell = lambda v: "-" if v != v else f"{v:,.0f}"  # noqa: E731
        print(f"| {name} | {cell(fast)} | {cell(ref)} |", flush=True)


if __name__ == "__main__":
    main()
