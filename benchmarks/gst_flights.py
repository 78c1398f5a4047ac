"""Source 001's filters (and peers for reference) on the simulated GNSS flights.

    python benchmarks/gst_flights.py [--data DIR]

Tilt (inclination) RMS overall, with GNSS and in gaps, heading RMS after the first 200 s, and
throughput. Default parameters; the document's autonomous loop is the ``reject=False`` row, the
document's GNSS loop ``tau_acc_bias=None`` (its gain is a parameter), fusionkit's earlier one
``tau_acc_bias=None, tau_gnss=20, turn_rate=gyro``.
"""

import argparse
import time

import numpy as np

import fusionkit as fk
from _common import data_dir
from fusionkit.benchmarking.metrics import broad_errors, trial_metrics
from fusionkit.conventions import change_frame

ap = argparse.ArgumentParser()
ap.add_argument("--data", default=str(data_dir() / "gnss"))
args = ap.parse_args()
print("| flight | filter | tilt RMS | tilt with GNSS | tilt in gap | heading RMS after 200 s | samples/s |\n|---|---|---:|---:|---:|---:|---:|")
for name in ("heli_cruise", "car_drive"):
    rec = fk.load(f'{args.data}/{name}/{name}.h5')
    for flt in ("gst", "gst-gnss", ("gst", {"reject": False}), ("gst-gnss", {"heading_init": "blend"}),
                ("gst-gnss", {"tau_acc_bias": None}), ("gst-gnss", {"tau_acc_bias": None, "tau_gnss": 20.0}),
                ("gst-gnss", {"tau_acc_bias": None, "tau_gnss": 20.0, "turn_rate": "gyro"}), "vqf", "poisson"):
        nm, kw = (flt, {}) if isinstance(flt, str) else flt
        f = fk.make(nm, **kw)  # the loader sets the recording's body axes (FRD)
        f.run(rec.slice(0, 200))
        t0 = time.perf_counter(); r = f.run(rec); sps = len(rec)/(time.perf_counter()-t0)
        m = trial_metrics(r, rec, f.dimension(rec))
        e = broad_errors(r.quat, change_frame(rec.truth, "NED", r.frame))["heading"]
        late = np.sqrt(np.mean(e[rec.time > 200]**2))
        lab = nm + ("" if not kw else f"[{','.join(f'{k}={v}' for k,v in kw.items())}]")
        gap = "-" if np.isnan(m["tilt_gap"]) else f"{m['tilt_gap']:.3f}"
        print(f"| {name} | {lab} | {m['tilt']:.3f} | {m['tilt_gnss']:.3f} | {gap} | {late:.2f} | {sps:,.0f} |")
