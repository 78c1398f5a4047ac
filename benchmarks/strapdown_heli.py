"""Source 004's strapdown on heli_cruise: position error after 30 s of free inertial navigation
started from a GNSS fix, per start time.

    python benchmarks/strapdown_heli.py [--data DIR] [--window 30]

From each start time (a GNSS epoch), velocity and position come from that GNSS fix (noisy:
5 m, 0.05 m/s); the attitude is (a) the gst-gnss filter's own estimate, or (b) the reference
attitude (to separate attitude from integration errors). The IMU's constant accelerometer bias
is not removed (it is unknown to a user). Coriolis and transport-rate terms are ignored, as in
the document (at 50 m/s, 2 Omega x v is about 0.007 m/s^2: about 3 m after 30 s).
"""

from __future__ import annotations

import argparse

import numpy as np

import fusionkit as fk
from _common import data_dir
from fusionkit.conventions import change_frame
from fusionkit.navigation.strapdown import strapdown


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "gnss" / "heli_cruise" / "heli_cruise.h5"))
    ap.add_argument("--window", type=float, default=30.0)
    args = ap.parse_args()
    rec = fk.load(args.data)
    g = float(rec.meta["attrs"].get("gravity_at_origin_mps2", 9.80665))
    est = fk.make("gst-gnss", frame="NED").run(rec).quat
    truth_ned = change_frame(rec.truth, rec.truth_frame, "NED")
    ref_pos = rec.meta["ref_pos_ned"]
    rate = 1.0 / rec.nominal_dt
    n_win = int(round(args.window * rate))
    gn = rec.gnss
    print(f"| start [s] | speed [m/s] | error after {args.window:.0f} s, attitude from gst-gnss [m] | "
          f"with the reference attitude [m] |")
    print("|---:|---:|---:|---:|")
    rows = []
    for t0 in range(70, 620, 50):
        e = int(np.argmin(np.abs(gn.t - t0)))
        k0 = int(np.argmin(np.abs(rec.time - gn.t[e])))
        if k0 + n_win >= len(rec) or not gn.valid[e]:
            continue
        sl = slice(k0, k0 + n_win + 1)
        out = []
        for att in (est[sl], truth_ned[sl]):
            r = strapdown(None, rec.acc[sl], rec.dt[sl], attitude=att, vel0=gn.vel[e], pos0=gn.pos[e], gravity=g,
                          frame="NED")
            out.append(float(np.linalg.norm(r.pos[-1] - ref_pos[k0 + n_win])))
        speed = float(np.hypot(*gn.vel[e, :2]))
        rows.append(out)
        print(f"| {gn.t[e]:.0f} | {speed:.1f} | {out[0]:.1f} | {out[1]:.1f} |")
    rows = np.array(rows)
    print(f"\nmedian: {np.median(rows[:, 0]):.1f} m (filter attitude), {np.median(rows[:, 1]):.1f} m (reference attitude)")


if __name__ == "__main__":
    main()
