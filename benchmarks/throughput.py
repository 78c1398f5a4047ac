"""Throughput (samples/s) of every built-in filter and the peers, side by side, one core.

    python benchmarks/throughput.py [--samples 1000000] [--reference-samples 20000] [--clock cpu]

Compiled (numba) paths run on ``--samples`` samples after a warm-up (compilation excluded), best
of 3; readable reference paths, filters without a kernel and peers written in Python (ahrs) on
``--reference-samples``. C/C++ peers (VQF, imufusion) run on ``--samples`` like the compiled
paths.

Three figures for each compiled filter and C/C++ peer: ``run()`` on a built Recording (the
kernel and the run's own passes), end to end (``fk.Recording(...)`` from the raw arrays, then
``run()``: what a user times; also as ns per sample), and that end-to-end figure over VQF's
``updateBatch`` on the same arrays (6D or 9D as the case), VQF timed right after the case in the
same process (best of ``--repeat`` each), so that both see the same load on a shared machine. The
recording is a BROAD trial tiled to ``--samples`` when the data is present (``--trial``), else
synthetic (12 s still, then smooth rotations; noisy accelerometer and magnetometer around fixed
vectors); the GNSS case is always synthetic. It measures speed only. ``--clock cpu`` times CPU
instead of wall time (a machine shared with other work); the table's legend is printed under it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import fusionkit as fk
from _common import data_dir, machine


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


CLOCK = time.perf_counter


def best_time(fn, repeat) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = CLOCK()
        fn()
        best = min(best, CLOCK() - t0)
    return best


REPEAT = 3


def best_rate(f, rec, backend, repeat) -> float:
    return len(rec) / best_time(lambda: f.run(rec, backend=backend, progress=False), repeat)


def broad_arrays(path, n: int):
    """A BROAD trial's gyr, acc, mag tiled to ``n`` samples (C-contiguous float64) and its rate."""
    import h5py

    with h5py.File(path, "r") as h:
        g, a, m, rate = h["imu_gyr"][:], h["imu_acc"][:], h["imu_mag"][:], float(h.attrs["sampling_rate"])
    reps = -(-n // len(g))
    tile = lambda x: np.ascontiguousarray(np.tile(x, (reps, 1))[:n], dtype=np.float64)  # noqa: E731
    return tile(g), tile(a), tile(m), rate


def end_to_end(f, rec, repeat) -> float:
    """samples/s of ``Recording(...)`` from ``rec``'s arrays plus ``run()``."""
    def go():
        f.run(fk.Recording(gyr=rec.gyr, acc=rec.acc, mag=rec.mag, rate=rec.rate, t=rec.t, gnss=rec.gnss),
              progress=False)
    return len(rec) / best_time(go, repeat)


def vqf_batch(rec, repeat) -> float:
    """samples/s of VQF's updateBatch on ``rec``'s arrays (9D with mag, else 6D); nan without VQF."""
    try:
        import vqf
    except ImportError:
        return float("nan")
    rate = rec.rate if rec.rate is not None else 1.0 / rec.nominal_dt
    return len(rec) / best_time(lambda: vqf.VQF(1.0 / rate).updateBatch(rec.gyr, rec.acc, rec.mag), repeat)


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
    "gst-gnss (source 001, combined; GNSS rows, 10 Hz)": (lambda: fk.make("gst-gnss"), "gnss", "ours"),
    "gradient-descent 6D, N = 1 (source 003)": (lambda: fk.make("gradient-descent"), False, "ours"),
    "gradient-descent 9D, N = 1 (+ magnetic detector)": (lambda: fk.make("gradient-descent"), True, "ours"),
    "gradient-descent madgwick=True, 6D": (lambda: fk.make("gradient-descent", madgwick=True), False, "ours"),
    "channel-dcm 9D (source 002)": (lambda: fk.make("channel-dcm"), True, "ours"),
    "pipeline: poisson-quat + gst corrector (state mode)": (
        pipe({"estimator": "poisson-quat", "detectors": ["motion"], "correctors": ["gst"]}), False, "ours"),
    "pipeline: poisson-quat + gst-gnss corrector + gnss-gap detector (GNSS rows, 10 Hz)": (
        pipe({"estimator": "poisson-quat", "detectors": ["gnss-gap", "motion"], "correctors": ["gst-gnss"]}), "gnss",
        "ours"),
    "pipeline: gradient-descent + rest-bias (state + rate, rest detector)": (
        pipe({"estimator": "poisson-quat", "correctors": ["gradient-descent", "rest-bias"], "detectors": ["rest"],
              "alignment": {"mode": "fixed", "duration": 3.0}}), False, "ours"),
    "recommended 9D": (lambda: fk.make("recommended"), True, "ours"),
    "recommended 6D": (lambda: fk.make("recommended"), False, "ours"),
    "ekf 9D (compiled; reference: filterpy)": (lambda: fk.make("ekf"), True, "ours"),
    "ekf 6D (compiled; reference: filterpy)": (lambda: fk.make("ekf"), False, "ours"),
    "vqf (peer, C++), 6D": (lambda: fk.make("vqf", mode="6D"), False, "peer-fast"),
    "vqf (peer, C++), 9D": (lambda: fk.make("vqf"), True, "peer-fast"),
    "imufusion (peer, C), 9D": (lambda: fk.make("imufusion"), True, "peer-fast"),
    "ahrs-madgwick (peer, Python), 9D": (lambda: fk.make("ahrs-madgwick"), True, "peer-slow"),
    "ahrs-ekf (peer, Python), 9D": (lambda: fk.make("ahrs-ekf"), True, "peer-slow"),
}


def main() -> None:
    global CLOCK
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--reference-samples", type=int, default=20_000)
    ap.add_argument("--only", default="", help="comma-separated substrings of case names")
    ap.add_argument("--trial", default=str(data_dir() / "broad" / "21_undisturbed_fast_combined.hdf5"),
                    help="BROAD trial tiled into the recordings (synthetic data when it is absent)")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                    help="wall: elapsed time; cpu: this process's CPU time (a machine shared with other work)")
    ap.add_argument("--repeat", type=int, default=REPEAT, help="timed runs per figure on --samples (the best counts)")
    args = ap.parse_args()
    CLOCK = time.process_time if args.clock == "cpu" else time.perf_counter
    rep = max(1, args.repeat)
    recs = {(size, kind): recording(n, mag=kind is True, gnss=kind == "gnss")
            for size, n in (("big", args.samples), ("small", args.reference_samples)) for kind in (False, True, "gnss")}
    source = "synthetic"
    if Path(args.trial).exists():
        g, a, m, rate = broad_arrays(args.trial, args.samples)
        recs[("big", False)] = fk.Recording(gyr=g, acc=a, rate=rate)
        recs[("big", True)] = fk.Recording(gyr=g, acc=a, mag=m, rate=rate)
        source = f"BROAD {Path(args.trial).stem} tiled"
    vqf_rates = {nine: vqf_batch(recs[("big", nine)], rep) for nine in (False, True)}
    print(f"machine: {machine()}; clock: {args.clock}; data: {source}; best of {rep}")
    print(f"VQF updateBatch on the same arrays at the start: 6D {vqf_rates[False]:,.0f}, 9D {vqf_rates[True]:,.0f} "
          "samples/s (each case's ratio uses VQF timed again right after it)")
    print(f"| case | run() samples/s ({args.samples:,}) | Recording + run() samples/s (ns/sample) "
          f"| end to end / VQF updateBatch | reference samples/s ({args.reference_samples:,}) |")
    print("|---|---:|---:|---:|---:|")
    for name, (build, nine, kind) in CASES.items():
        if args.only and not any(s in name for s in args.only.split(",")):
            continue
        big, small = recs[("big", nine)], recs[("small", nine)]
        fast = ref = e2e = vs = float("nan")
        try:
            if kind == "detector":
                det = fk.make("motion", kind="detector")
                det.run(small.slice(0, 100), backend="numba")
                fast = len(big) / best_time(lambda: det.run(big, backend="numba"), 1)
                ref = len(small) / best_time(lambda: det.run(small, backend="reference"), 1)
            else:
                f = build()
                if kind == "ours":
                    f.run(small.slice(0, 100), backend="numba")  # compile
                    fast = best_rate(f, big, "numba", rep)
                    e2e, vs = end_to_end(f, big, rep), vqf_batch(big, rep) if nine != "gnss" else float("nan")
                    ref = best_rate(f, small, "reference", 1)
                elif kind == "ref-only":
                    ref = best_rate(f, small, "reference", 1)
                elif kind == "peer-fast":
                    f.run(small.slice(0, 100))
                    fast = best_rate(f, big, "auto", rep)
                    e2e, vs = end_to_end(f, big, rep), vqf_batch(big, rep)
                else:
                    ref = best_rate(f, small, "auto", 1)
        except ImportError as exc:  # a peer that is not installed
            print(f"| {name} | not installed ({exc.name}) | | | |")
            continue
        cell = lambda v: "-" if v != v else f"{v:,.0f}"  # noqa: E731
        ratio = "-" if e2e != e2e or vs != vs else f"{e2e / vs:.2f}x"
        e2e_cell = "-" if e2e != e2e else f"{e2e:,.0f} ({1e9 / e2e:.0f})"
        print(f"| {name} | {cell(fast)} | {e2e_cell} | {ratio} | {cell(ref)} |", flush=True)
    print(f"""
run(): the compiled loop and the run's own passes on a Recording built beforehand (--samples samples).
Recording + run(): fk.Recording(...) from the raw arrays, then run(): what a user times; ns/sample in brackets.
end to end / VQF updateBatch: that figure over VQF's C++ updateBatch on the same arrays (6D or 9D as the case;
  '-' for the GNSS cases: VQF has no GNSS), VQF timed right after the case, so both see the same machine load;
  above 1x is faster than VQF.
reference: the readable Python path on --reference-samples samples (the numbers the compiled path equals to 1e-9).
Samples/s are the best of {rep} runs ({args.clock} clock); on a shared machine compare ratios within one run.""")


if __name__ == "__main__":
    main()
