"""Time to build a ``Recording`` of 1M samples (C-contiguous float64 arrays), with a breakdown.

    python benchmarks/recording_build.py [--samples 1000000] [--rounds 5] [--builds 9] [--old PATH]

Cases: gyr + acc + mag with ``rate=``, the same with ``t=`` (timestamps), and gyr + acc with
``rate=``. Each round is a fresh child process that builds each recording ``--builds`` times
after one warm-up build (compilation and cache loads excluded) and keeps its best; the figure
is the best over ``--rounds``. With ``--old PATH`` (a directory holding another version's
``fusionkit`` package, e.g. ``git archive HEAD~3 fusionkit | tar -x -C /tmp/old``) the rounds
alternate between that version and this one, so that both see the same machine load.

Breakdown of the best build: the time spent in the checks' functions (``as_vectors``,
``check_time``, the unit scan, the turning windows and fits, the ``dt`` array), and the rest.
The arrays are a BROAD trial tiled to ``--samples`` when the data is present, else synthetic
(still, then smooth rotations). The machine's other load shows as spread between rounds: read
best-of figures, and compare versions only within one alternated run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[3])
from throughput import broad_arrays, recording
import fusionkit as fk
from fusionkit import types, validation
print(fk.__file__, file=sys.stderr)

n, trial, builds = int(sys.argv[1]), sys.argv[2], int(sys.argv[4])
try:
    gyr, acc, mag, rate = broad_arrays(trial, n)
except Exception:
    r = recording(n)
    gyr, acc, mag, rate = r.gyr, r.acc, r.mag, r.rate
t = np.arange(n) / rate

spent = {}
def timed(mod, name, label):
    f = getattr(mod, name, None)
    if f is None:
        return
    def wrap(*a, **k):
        t0 = time.perf_counter()
        try:
            return f(*a, **k)
        finally:
            spent[label] = spent.get(label, 0.0) + time.perf_counter() - t0
    setattr(mod, name, wrap)

timed(types, "as_vectors", "as_vectors")
timed(types, "check_time", "check_time")
timed(validation, "unit_scan", "unit scan")
timed(validation, "window_turns", "turning windows")
timed(validation, "turning_scale", "turning fits")
dt_prop = types.Recording.dt
def dt_timed(self):
    t0 = time.perf_counter()
    try:
        return dt_prop.fget(self)
    finally:
        spent["dt array"] = spent.get("dt array", 0.0) + time.perf_counter() - t0
types.Recording.dt = property(dt_timed)

cases = {"9D rate": dict(gyr=gyr, acc=acc, mag=mag, rate=rate), "9D t": dict(gyr=gyr, acc=acc, mag=mag, t=t),
         "6D rate": dict(gyr=gyr, acc=acc, rate=rate)}
out = {}
for name, kw in cases.items():
    rec = fk.Recording(**kw)  # warm-up: compilation or cache load
    shared = bool(np.shares_memory(rec.gyr, gyr) and np.shares_memory(rec.acc, acc))
    best = (float("inf"), {})
    for _ in range(builds):
        spent.clear()
        t0 = time.perf_counter()
        fk.Recording(**kw)
        total = time.perf_counter() - t0
        if total < best[0]:
            best = (total, dict(spent))
    out[name] = {"total": best[0], "parts": best[1], "shared": shared}
print(json.dumps(out))
"""


def child(tree: str | None, n: int, trial: str, builds: int) -> dict:
    env = dict(os.environ)
    if tree:
        env["PYTHONPATH"] = tree + os.pathsep + env.get("PYTHONPATH", "")
    here = str(Path(__file__).resolve().parent)
    out = subprocess.run([sys.executable, "-W", "ignore", "-c", CHILD, str(n), trial, here, str(builds)], env=env,
                         cwd=here, capture_output=True, text=True, check=True)  # cwd: not the repository's package
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import data_dir, machine

    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--builds", type=int, default=9)
    ap.add_argument("--old", default="", help="a directory holding another version's fusionkit package")
    ap.add_argument("--trial", default=str(data_dir() / "broad" / "21_undisturbed_fast_combined.hdf5"))
    args = ap.parse_args()
    versions = {"old": args.old, "new": None} if args.old else {"this": None}
    best: dict[str, dict] = {v: {} for v in versions}
    for _ in range(args.rounds):
        for v, tree in versions.items():
            for case, r in child(tree, args.samples, args.trial, args.builds).items():
                if case not in best[v] or r["total"] < best[v][case]["total"]:
                    best[v][case] = r
    print(f"machine: {machine()}; {args.samples:,} samples; best of {args.rounds} rounds x {args.builds} builds")
    print("| version | case | build (ms) | input shared | breakdown (ms) |")
    print("|---|---|---:|---|---|")
    for v, cases in best.items():
        for case, r in cases.items():
            parts = ", ".join(f"{k} {1e3 * s:.2f}" for k, s in sorted(r["parts"].items(), key=lambda kv: -kv[1]))
            rest = 1e3 * (r["total"] - sum(r["parts"].values()))
            print(f"| {v} | {case} | {1e3 * r['total']:.2f} | {'yes' if r['shared'] else 'no'} | {parts}, "
                  f"rest {rest:.2f} |")


if __name__ == "__main__":
    main()
