"""The INS/GNSS filter against source 001's GST loops on the simulated GNSS flights.

    python benchmarks/ins_gnss.py [--data DIR] [--filters ins-gnss gst-gnss gst] [--param key=value]

Per flight and filter, default parameters (``body="FRD"``, the files' axes): tilt RMS while
GNSS is valid and inside the outage, heading RMS after 200 s, velocity RMS and the position
error at the end of the outage (filters that output them), the estimated IMU-to-GNSS time
offset at the end (``ins-gnss``), and throughput (samples/s, numba,
after a warm-up run).
"""

import argparse
import json
import time

import numpy as np

import fusionkit as fk
from _common import data_dir, machine
from fusionkit.benchmarking.metrics import broad_errors, gnss_masks
from fusionkit.conventions import change_frame, frame_matrix

ap = argparse.ArgumentParser()
ap.add_argument("--data", default=str(data_dir() / "gnss"))
ap.add_argument("--flights", nargs="+", default=["heli_cruise", "car_drive"])
ap.add_argument("--filters", nargs="+", default=["ins-gnss", "gst-gnss", "gst"])
ap.add_argument("--heading", default=None, help="ins-gnss heading option (auto, magnetometer, course)")
ap.add_argument("--no-time-offset", action="store_true", help="ins-gnss without the time offset state")
ap.add_argument("--param", action="append", default=[], help="key=value for ins-gnss (JSON value), e.g. "
                "nonholonomic=0.2")
args = ap.parse_args()


def rms(v):
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v ** 2))) if v.size else float("nan")


print(machine())
print("| flight | filter | tilt with GNSS | tilt in outage | heading after 200 s | velocity RMS | position error at outage end "
      "| time offset | samples/s |\n|---|---|---:|---:|---:|---:|---:|---:|---:|")
for name in args.flights:
    rec = fk.load(f"{args.data}/{name}/{name}.h5")
    ok, gap = gnss_masks(rec)
    for nm in args.filters:
        kw = {"body": "FRD"}
        if nm == "ins-gnss" and args.heading:
            kw["heading"] = args.heading
        if nm == "ins-gnss" and args.no_time_offset:
            kw["time_offset_std"] = None
        if nm == "ins-gnss":
            kw.update({k: json.loads(v) for k, v in (a.split("=", 1) for a in args.param)})
        f = fk.make(nm, **kw)
        f.run(rec.slice(0, 300))
        t0 = time.perf_counter()
        r = f.run(rec)
        sps = len(rec) / (time.perf_counter() - t0)
        e = broad_errors(r.quat, change_frame(rec.truth, rec.truth_frame, r.frame))
        late = rec.time > 200
        vel, pos, dts = "-", "-", "-"
        if "time_offset" in r.diagnostics:
            dts = f"{r.diagnostics['time_offset'][-1] * 1e3:.1f} +- {r.diagnostics['time_offset_std'][-1] * 1e3:.1f} ms"
        if "velocity" in r.diagnostics:
            fm = frame_matrix("NED", r.frame)
            ve = r.diagnostics["velocity"] - rec.meta["ref_vel_ned"] @ fm.T
            vel = f"{rms(np.linalg.norm(ve, axis=1)[ok]):.3f} m/s"
            if gap.any():
                k = int(np.flatnonzero(gap)[-1])
                pe = r.diagnostics["position"][k] - fm @ rec.meta["ref_pos_ned"][k]
                pos = f"{np.linalg.norm(pe):.2f} m"
        tg = f"{rms(e['inclination'][gap]):.3f}" if gap.any() else "-"
        print(f"| {name} | {nm} | {rms(e['inclination'][ok]):.3f} | {tg} | {rms(e['heading'][late]):.3f} | {vel} | {pos} "
              f"| {dts} | {sps:,.0f} |", flush=True)
