"""Throughput (samples/s) of the Poisson integrators and the `poisson` filter.

    python benchmarks/throughput.py [--samples 1000000] [--reference-samples 20000]

numba runs on ``--samples`` samples after a warm-up (compilation excluded), best of 3; the
readable reference runs on ``--reference-samples`` (it is about 10^4 times slower). One core.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import fusionkit as fk
from _common import machine


def recording(n: int, rate: float = 285.7) -> fk.Recording:
    rng = np.random.default_rng(0)
    rest = int(12 * rate)
    gyr = 0.01 * rng.standard_normal((n, 3))
    gyr[rest:] += np.sin(np.arange(n - rest)[:, None] / rate * [1.0, 1.3, 0.7])  # moving after 12 s
    acc = np.array([0.0, 0.0, 9.81]) + 0.03 * rng.standard_normal((n, 3))
    return fk.Recording(gyr=gyr, acc=acc, rate=rate)


def best_rate(f, rec, backend, repeat) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        f.run(rec, backend=backend, progress=False)
        best = min(best, time.perf_counter() - t0)
    return len(rec) / best


CASES = {
    "poisson-quat first-order (integrator)": lambda: fk.compose({"estimator": "poisson-quat", "alignment": {"mode": "none"}}),
    "poisson-quat exact (integrator)": lambda: fk.compose(
        {"estimator": {"name": "poisson-quat", "params": {"step": "exact"}}, "alignment": {"mode": "none"}}),
    "poisson-dcm (integrator)": lambda: fk.compose({"estimator": "poisson-dcm", "alignment": {"mode": "none"}}),
    "poisson filter (alignment + motion detector + integrator)": lambda: fk.make("poisson"),
    "vqf (peer, C++), 6D": lambda: fk.make("vqf"),
    "motion detector alone": None,
    "gst (source 001, autonomous)": lambda: fk.make("gst"),
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--reference-samples", type=int, default=20_000)
    args = ap.parse_args()
    big, small = recording(args.samples), recording(args.reference_samples)
    print(f"machine: {machine()}")
    print(f"| case | numba samples/s ({args.samples:,} samples) | reference samples/s ({args.reference_samples:,}) |")
    print("|---|---:|---:|")
    for name, build in CASES.items():
        if build is None:
            det = fk.make("motion", kind="detector")
            det.run(small.slice(0, 100), backend="numba")
            rates = []
            for rec, backend, rep in ((big, "numba", 3), (small, "reference", 1)):
                t0 = time.perf_counter()
                det.run(rec, backend=backend)
                rates.append(len(rec) / (time.perf_counter() - t0))
            fast, ref = rates
        else:
            f = build()
            peer = f.name.startswith("vqf")
            backend = "auto" if peer else "numba"  # a peer runs its own code
            f.run(small.slice(0, 100), backend=backend)  # compile
            fast = best_rate(f, big, backend, 3)
            ref = float("nan") if peer else best_rate(f, small, "reference", 1)
        print(f"| {name} | {fast:,.0f} | {'-' if ref != ref else f'{ref:,.0f}'} |")


if __name__ == "__main__":
    main()
