"""First compiled run (numba compile included) of a pipeline with N chained correctors, against
the reference path: the measurement behind ``fusionkit.pipeline.MAX_COMPILED_CORRECTORS``.

    python benchmarks/corrector_chain.py 1 4 8 12 16 20 24

Each N runs in a fresh process with empty caches (the generated loop would otherwise load from disk): a ``poisson-quat``
pipeline with the ``motion`` detector and N ``gradient-descent`` correctors, on 300 samples of a
simulated recording. Pass ``--timeout`` to stop a count that compiles too long.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import sys
import time

ONE = """
import sys, time, warnings
import fusionkit as fk
from fusionkit import pipeline, sim
pipeline.MAX_COMPILED_CORRECTORS = 10**6  # measure the compiled chain itself
n = int(sys.argv[1])
rec = sim.demo_recordings()[0].slice(0, 300)
f = fk.compose({"estimator": "poisson-quat", "detectors": ["motion"], "correctors": ["gradient-descent"] * n})
t = time.perf_counter(); f.run(rec, backend="numba"); c = time.perf_counter() - t
t = time.perf_counter(); f.run(rec, backend="reference"); r = time.perf_counter() - t
print(f"| {n} | {c:.1f} | {r:.3f} |")
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("counts", nargs="*", type=int, default=[1, 4, 8, 12, 16, 20, 24])
    ap.add_argument("--timeout", type=float, default=600.0, help="s per count")
    args = ap.parse_args()
    print("| correctors | first compiled run, s | reference run, s |\n|---:|---:|---:|")
    for n in args.counts:
        t0 = time.perf_counter()
        try:
            cache = tempfile.mkdtemp()  # an empty disk cache: the compile is what is measured
            out = subprocess.run([sys.executable, "-c", ONE, str(n)], capture_output=True, text=True,
                                 env={**os.environ, "FUSIONKIT_CACHE_DIR": cache, "NUMBA_CACHE_DIR": cache},
                                 timeout=args.timeout)
        except subprocess.TimeoutExpired:
            print(f"| {n} | > {args.timeout:.0f} (stopped) | |")
            continue
        line = out.stdout.strip().splitlines()[-1:] or [f"| {n} | failed after {time.perf_counter() - t0:.0f} s: "
                                                        f"{(out.stderr.strip().splitlines() or ['?'])[-1][:80]} | |"]
        print(line[0], flush=True)


if __name__ == "__main__":
    main()
