"""What each filter does with bad input, measured on simulated data (docs/reliability.md).

One recording (100 Hz, MEMS noise): 11 s still, four rotations of 40-90 deg over 8 s, 6 s still.
Per filter (defaults; peers where installed), the largest inclination error (deg) after:

- ``gap motion``: 2 s of samples missing while turning (a timestamp gap);
- ``gap rest``: 5 s missing while still;
- ``glitch``: one accelerometer sample of 1e4 m/s^2 (deviation from the clean run);
- ``dead acc`` / ``dead mag``: 5 s of NaN while turning (``nan_policy="skip"``);
- ``saturated``: a 35 rad/s turn read by a gyro clipped at 30 rad/s (``gyr_range=30``): the
  error right after, and 10 s later.

    python benchmarks/reliability.py
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.metrics import broad_errors
from fusionkit.rotations import quat_angle

DEG = np.pi / 180
NAMES = ["recommended", "gradient-descent", "channel-dcm", "ekf", "gst", "poisson", "vqf", "imufusion",
         "ahrs-madgwick", "ahrs-mahony", "ahrs-ekf"]


def incl(res, rec):
    return broad_errors(res.to_frame("ENU"), rec.truth)["inclination"]


def drop(rec, a, b):
    keep = np.r_[0:a, b:len(rec)]
    return fk.Recording(gyr=rec.gyr[keep], acc=rec.acc[keep], mag=rec.mag[keep], t=rec.time[keep],
                        truth=rec.truth[keep])


def main() -> None:
    warnings.simplefilter("ignore")
    segs = [sim.Rest(11), sim.Rotate((1, 0.3, 0), 60 * DEG, 2), sim.Rotate((0, 1, 0), -50 * DEG, 2),
            sim.Rotate((0, 0, 1), 90 * DEG, 2), sim.Rotate((1, 0, 0), -40 * DEG, 2), sim.Rest(6)]
    rec = sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=2, gnss_rate=None)
    spin = sim.simulate([sim.Rest(6), sim.Rotate((1, 0, 0), 17.5, 1.0), sim.Rest(10)], rate=200.0,
                        noise=sim.Noise.mems(), seed=1, gnss_rate=None)
    spin = dataclasses.replace(spin, gyr=np.clip(spin.gyr, -30.0, 30.0))
    gap_m, gap_r = drop(rec, 1300, 1500), drop(rec, 300, 800)
    glitch = dataclasses.replace(rec, acc=rec.acc.copy())
    glitch.acc[1500] = [1e4, 0.0, 0.0]
    print("| filter | gap motion | gap rest | glitch | dead acc | dead mag | saturated: after, +10 s |")
    print("|---|---|---|---|---|---|---|")
    for name in NAMES:
        cls = fk.get(name)
        if hasattr(cls, "package") and cls.version() == "missing":
            continue
        cells = [incl(fk.make(name).run(gap_m), gap_m)[1300:].max(), incl(fk.make(name).run(gap_r), gap_r)[300:].max()]
        good = fk.make(name).run(rec)
        cells.append(np.degrees(quat_angle(fk.make(name).run(glitch).quat, good.quat)).max())
        for sensor in ("acc", "mag"):
            bad = dataclasses.replace(rec, acc=rec.acc.copy(), mag=rec.mag.copy())
            getattr(bad, sensor)[1300:1800] = np.nan
            cells.append(incl(fk.make(name, nan_policy="skip").run(bad), bad)[1300:1800].max())
        res = fk.make(name, gyr_range=30.0).run(spin)
        last = np.flatnonzero(res.flags & fk.Flag.GYR_SATURATED)[-1]
        e = incl(res, spin)
        print(f"| {name} | " + " | ".join(f"{c:.1f}" for c in cells) + f" | {e[last + 1]:.1f}, {e[-1]:.1f} |")


if __name__ == "__main__":
    main()
