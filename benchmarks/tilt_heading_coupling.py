"""The adaptive time constant's heading cost on the demo's simulated translation, by the field's dip.

    python benchmarks/tilt_heading_coupling.py [--seeds N]

`fusionkit demo`'s translation (a 12 s rest, six 0.5 m pushes of 1.5 s along the axes, a turn, a
rest; 200 Hz, MEMS noise, no gyro scale error), simulated in a field of the demo's strength with the
dip changed. Per dip: 9D heading and inclination RMS (deg, over the motion) of ``recommended`` with
``tau_adapt`` (the default) and without, mean over the seeds, and the 6D heading drift over the
motion (the gyro chain alone; equal for both). The magnetometer's heading is read in the levelled
frame, so an inclination error about the east axis turns it by up to ``tan(dip)`` times itself: a
cost that grows with the dip and vanishes at 0 is that coupling (docs/algorithms/recommended.md,
"The adaptive time constant"). The last column: the default with ``heading_inclination_noise`` (the
heading's variance counts the inclination's error times ``tan(dip)``, passed through the pipeline's
channel; docs/algorithms/recommended.md, "The heading's variance and the inclination").
"""

from __future__ import annotations

import argparse
import math
import warnings

import numpy as np

import fusionkit as fk
from fusionkit.benchmarking.metrics import broad_errors, rms_errors
from fusionkit.conventions import change_frame
from fusionkit.sim import Noise, simulate
from fusionkit.sim.motion import Rest, Rotate, Translate
from fusionkit.sim.sensors import KYIV_FIELD_ENU

_DEG = math.pi / 180.0


def _segments() -> list:
    axes = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 0, -1))
    return [Rest(12.0)] + [Translate(d, 0.5, 1.5) for d in axes] + [Rotate((0, 0, 1), 30 * _DEG, 2.0), Rest(5.0)]


def _heading_drift_6d(rec, **kw) -> float:
    out = fk.make("recommended", use_mag=False, **kw).run(rec)
    h = broad_errors(out.quat, change_frame(rec.truth, rec.truth_frame, out.frame))["heading"][rec.movement]
    return float(np.sqrt(np.mean((h - h[0]) ** 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=6)
    args = ap.parse_args()
    warnings.filterwarnings("ignore")
    strength = float(np.linalg.norm(KYIV_FIELD_ENU))
    print("| dip [deg] | 9D heading, default | `tau_adapt=False` | 9D inclination, default | `tau_adapt=False` "
          "| 6D heading drift, default | `tau_adapt=False` | 9D heading, `heading_inclination_noise` |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for dip in (68.0, 45.0, 20.0, 0.0):
        field = np.array([0.0, strength * math.cos(dip * _DEG), -strength * math.sin(dip * _DEG)])
        cols = {}
        for key, kw in (("on", {}), ("off", {"tau_adapt": False}), ("noise", {"heading_inclination_noise": True})):
            h, inc, d6 = [], [], []
            for i in range(args.seeds):
                rec = simulate(_segments(), rate=200.0, noise=Noise.mems(), seed=2 + 3 * i, name="translation",
                               mag_field=field)
                e = rms_errors(fk.make("recommended", **kw).run(rec), rec)
                h.append(e["heading"])
                inc.append(e["inclination"])
                if key != "noise":  # (6D: no heading to weigh)
                    d6.append(_heading_drift_6d(rec, **kw))
            cols[key] = (np.mean(h), np.mean(inc), np.mean(d6) if d6 else math.nan)
        on, off = cols["on"], cols["off"]
        print(f"| {dip:.0f} | {on[0]:.3f} | {off[0]:.3f} | {on[1]:.3f} | {off[1]:.3f} | {on[2]:.3f} | {off[2]:.3f} "
              f"| {cols['noise'][0]:.3f} |", flush=True)


if __name__ == "__main__":
    main()
