"""Time to the first result in a new process, cold and warm, where it goes, and per-sample
``update()`` against VQF's own per-sample ``update()`` in the same run.

    python benchmarks/first_result.py [--filters gradient-descent,recommended,...] [--repeat 3] [--no-streaming]

First result: a fresh ``python`` process imports fusionkit, makes the filter, builds a
1,000-sample recording and runs the filter. *Cold*: empty numba and fusionkit caches
(``NUMBA_CACHE_DIR`` and ``FUSIONKIT_CACHE_DIR`` point at a new folder: every kernel and
generated pipeline loop compiles). *Warm*: the same folders again (everything loads from disk).
Python's bytecode cache is part of the warm state as on a user's machine: the children write it
under the same folder (``PYTHONPYCACHEPREFIX``), also where the calling environment sets
``PYTHONDONTWRITEBYTECODE``.

The warm runs are alternated between the filters (one process each per round, ``--repeat``
rounds) so that all see the same machine load; the best (least CPU) one per filter is reported
with its breakdown: *import* (``import numpy, fusionkit``: numba and pydantic with it), *make*
(``fk.make``: the plugin modules and their configs), *recording*, *load* (the first ``run()``
less a second one on the same recording: the generated loop's module and numba's load of its
machine code) and *run* (the second ``run()``). Wall and CPU time of the child up to its result
(not its interpreter start or exit).

Streaming: ``f.update(gyr, acc, mag, dt)`` per sample of a 20,000-sample recording (after one
warm-up sample), against ``vqf.VQF.update`` + ``getQuat9D`` on the same samples, alternated in
chunks so that both see the same machine load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from _common import machine

CHILD = r"""
import json, sys, time
T = [(time.perf_counter(), time.process_time())]
import numpy as np, fusionkit as fk
T.append((time.perf_counter(), time.process_time()))
f = fk.make(sys.argv[1])
T.append((time.perf_counter(), time.process_time()))
rng = np.random.default_rng(0)
n = 1000
rec = fk.Recording(gyr=0.1 * rng.standard_normal((n, 3)), acc=[0, 0, 9.81] + 0.05 * rng.standard_normal((n, 3)),
                   mag=[0, 19, -47] + 0.3 * rng.standard_normal((n, 3)), rate=100.0)
T.append((time.perf_counter(), time.process_time()))
res = f.run(rec)
T.append((time.perf_counter(), time.process_time()))
f.run(rec)
T.append((time.perf_counter(), time.process_time()))
wall = [b[0] - a[0] for a, b in zip(T, T[1:])]
cpu = [b[1] - a[1] for a, b in zip(T, T[1:])]
print(json.dumps({"wall": wall, "cpu": cpu, "backend": res.diagnostics.get("backend", "?")}))
"""

PHASES = ("import", "make", "recording", "load", "run")


class FirstResult:
    """One child's times: ``total`` / ``cpu`` up to the first result, ``phases`` (wall) as in
    :data:`PHASES`."""

    def __init__(self, out: dict) -> None:
        w, c = out["wall"], out["cpu"]
        self.total, self.cpu = sum(w[:4]), sum(c[:4])
        self.phases = dict(zip(PHASES, [w[0], w[1], w[2], w[3] - w[4], w[4]]))
        self.backend = out["backend"]


def first_result(name: str, cache: str) -> FirstResult:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache, "FUSIONKIT_CACHE_DIR": cache,
           "PYTHONPYCACHEPREFIX": os.path.join(cache, "pyc")}
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = subprocess.run([sys.executable, "-W", "ignore", "-c", CHILD, name], env=env, capture_output=True,
                         text=True, check=True)
    return FirstResult(json.loads(out.stdout.strip().splitlines()[-1]))


def streaming(name: str, n: int = 20000) -> tuple[float, float]:
    import vqf

    import fusionkit as fk

    rng = np.random.default_rng(1)
    gyr = 0.3 * rng.standard_normal((n, 3))
    acc = np.array([0, 0, 9.81]) + 0.05 * rng.standard_normal((n, 3))
    mag = np.array([0, 19, -47]) + 0.3 * rng.standard_normal((n, 3))
    f, v = fk.make(name), vqf.VQF(0.01)
    f.update(gyr[0], acc[0], mag[0], dt=0.01)
    ours = peer = 0.0
    for lo in range(1, n, 1000):
        t = time.perf_counter()
        for k in range(lo, min(n, lo + 1000)):
            f.update(gyr[k], acc[k], mag[k], dt=0.01)
        ours += time.perf_counter() - t
        t = time.perf_counter()
        for k in range(lo, min(n, lo + 1000)):
            v.update(gyr[k], acc[k], mag[k])
            v.getQuat9D()
        peer += time.perf_counter() - t
    return ours / (n - 1) * 1e6, peer / (n - 1) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--filters", default="gradient-descent,poisson,recommended,channel-dcm,gst")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-streaming", action="store_true", help="only the first result")
    args = ap.parse_args()
    names = args.filters.split(",")
    print(f"machine: {machine()}; load average before: {os.getloadavg()[0]:.2f}\n")
    with tempfile.TemporaryDirectory() as root:
        caches = {n: os.path.join(root, n) for n in names}
        cold = {n: first_result(n, caches[n]) for n in names}
        warm = {n: [] for n in names}
        for _ in range(args.repeat):  # alternated: every filter sees the same load
            for n in names:
                warm[n].append(first_result(n, caches[n]))
    print("| filter | first result, cold (s) | warm (s) | warm CPU (s) | " + " | ".join(PHASES) + " | backend |")
    print("|---|---:|---:|---:|" + "---:|" * len(PHASES) + "---|")
    for n in names:
        best = min(warm[n], key=lambda r: r.cpu)
        print(f"| {n} | {cold[n].total:.2f} | {best.total:.2f} | {best.cpu:.2f} | "
              + " | ".join(f"{best.phases[p]:.3f}" for p in PHASES) + f" | {best.backend} |", flush=True)
    print(f"\nwarm: the run with the least CPU of {args.repeat}; phases in wall seconds of that run; "
          f"load average after: {os.getloadavg()[0]:.2f}")
    if args.no_streaming:
        return
    print("\n| filter | update() us/sample | VQF update()+getQuat9D us/sample | ratio |")
    print("|---|---|---|---|")
    for name in names:
        ours, peer = streaming(name)
        print(f"| {name} | {ours:.2f} | {peer:.2f} | {ours / peer:.2f}x |", flush=True)


if __name__ == "__main__":
    main()
