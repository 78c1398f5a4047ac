"""What limits ``ins-gnss``'s position at the end of a GNSS outage: an error budget and a
Monte-Carlo over simulated drives.

    python benchmarks/ins_gnss_outage.py [--data DIR] [--seeds 100]

1. Error budget. At the last epoch before the outage the filter's errors (from the truth) are
   split into tilt, heading, velocity, position, gyro and accelerometer bias; the sensor errors
   over the outage are known (``imu - ref`` in the gnss-ins-sim files, the simulator's biases
   and noise in ``fusionkit.sim.flight``). Each part is propagated alone through the filter's
   own linear error model along the true trajectory (``phi' = -C e_g``, ``dv' = -f_n x phi - C
   e_a``, ``dp' = dv``) to the outage's end: its share of the position error (horizontal, m).
   The sum is checked against the filter's actual error. Beside it, each part's predicted 1-sigma
   from the filter's covariance at the outage's start and from the sensor specifications.
2. Monte-Carlo: ``--seeds`` drives of ``fusionkit.sim.flight`` like car_drive (level road, 20 m/s,
   turns, accelerations and braking, the same IMU class and GNSS noise, a 60 s outage from
   170 s): the distribution of the horizontal position error at the outage's end, and the
   fraction within 5 m, of the sensors alone (``nonholonomic='off'``, what the budget's linear
   model describes) and with the default parameters (the constraint, once GNSS confirms it).
"""

import argparse
import math

import numpy as np

import fusionkit as fk
from _common import data_dir, machine
from fusionkit.benchmarking.metrics import gnss_masks
from fusionkit.sim.flight import simulate_flight

ap = argparse.ArgumentParser()
ap.add_argument("--data", default=str(data_dir() / "gnss"))
ap.add_argument("--seeds", type=int, default=100)
args = ap.parse_args()

G = 9.79


def quat_dcm(q):
    from scipy.spatial.transform import Rotation as R

    return R.from_quat(np.roll(q, -1, axis=-1)).as_matrix()


def rotvec(c_true, c_est):
    from scipy.spatial.transform import Rotation as R

    return R.from_matrix(c_true @ c_est.T).as_rotvec()


def propagate(c, fn, dt, phi0=0.0, dv0=0.0, dp0=0.0, eg=0.0, ea=0.0):
    """The filter's error model over the outage (errors true minus estimate, NED): the
    position error at the end. ``eg``, ``ea``: rate and specific-force errors (estimate minus
    truth, body) per sample or constant."""
    n = c.shape[0]
    eg = np.broadcast_to(np.asarray(eg, float), (n, 3))
    ea = np.broadcast_to(np.asarray(ea, float), (n, 3))
    phi = np.asarray(phi0, float) - np.cumsum(np.einsum("nij,nj->ni", c, eg), axis=0) * dt
    dv = np.asarray(dv0, float) + np.cumsum(-np.cross(fn, phi) - np.einsum("nij,nj->ni", c, ea), axis=0) * dt
    return np.asarray(dp0, float) + dv.sum(axis=0) * dt


def budget(rec, res, b_g, b_a, noise_g, noise_a):
    """Shares (horizontal m at the outage's end) of the error sources, their predicted 1-sigma
    (filter covariance / sensor specs) and the filter's actual error. ``b_g``, ``b_a``: the
    true biases per sample (None: unknown, then the whole sensor error is ``noise_*``)."""
    ok, gap = gnss_masks(rec)
    k1 = int(np.flatnonzero(gap)[-1])
    k0 = int(np.flatnonzero(gap)[0]) - 1  # the last sample with GNSS (its epoch applied)
    sl = slice(k0 + 1, k1 + 1)
    dt = float(rec.nominal_dt)
    d = res.diagnostics
    c_true = quat_dcm(rec.truth)
    c0_est = quat_dcm(res.quat[k0])
    phi0 = rotvec(c_true[k0], c0_est)
    dv0 = rec.meta["ref_vel_ned"][k0] - d["velocity"][k0]
    dp0 = rec.meta["ref_pos_ned"][k0] - d["position"][k0]
    c = c_true[sl]
    fn = np.einsum("nij,nj->ni", c, rec.meta["f_body"][sl])
    bg0, ba0 = d["gyr_bias"][k0], d["acc_bias"][k0]
    parts = {
        "tilt at the start": propagate(c, fn, dt, phi0=[phi0[0], phi0[1], 0.0]),
        "heading at the start": propagate(c, fn, dt, phi0=[0.0, 0.0, phi0[2]]),
        "velocity at the start": propagate(c, fn, dt, dv0=dv0),
        "position at the start": dp0,
    }
    if b_g is not None:
        parts["gyro bias: estimate's error at the start"] = propagate(c, fn, dt, eg=b_g[k0] - bg0)
        parts["gyro bias: drift in the outage"] = propagate(c, fn, dt, eg=b_g[sl] - b_g[k0])
        parts["gyro white noise"] = propagate(c, fn, dt, eg=noise_g[sl])
        parts["accel bias: estimate's error at the start"] = propagate(c, fn, dt, ea=b_a[k0] - ba0)
        parts["accel bias: drift in the outage"] = propagate(c, fn, dt, ea=b_a[sl] - b_a[k0])
        parts["accel white noise"] = propagate(c, fn, dt, ea=noise_a[sl])
    else:
        parts["gyro: turn-on bias minus estimate"] = propagate(c, fn, dt, eg=rec.meta["gyr_bias0"] - bg0)
        parts["gyro: white noise + instability"] = propagate(c, fn, dt, eg=noise_g[sl])
        parts["accel: turn-on bias minus estimate"] = propagate(c, fn, dt, ea=rec.meta["acc_bias0"] - ba0)
        parts["accel: white noise + instability"] = propagate(c, fn, dt, ea=noise_a[sl])
    total = sum(parts.values())
    actual = d["position"][k1] - rec.meta["ref_pos_ned"][k1]
    return parts, -total, actual


def predicted(rec, k0, k1, p0):
    """1-sigma (horizontal, m) at the outage's end from each block of the filter's covariance at
    its start, and from the sensor specifications over the outage (white noise densities, bias
    instability as the filter models it)."""
    dt = float(rec.nominal_dt)
    sl = slice(k0 + 1, k1 + 1)
    c = quat_dcm(rec.truth)[sl]
    fn = np.einsum("nij,nj->ni", c, rec.meta["f_body"][sl])
    cfg = fk.make("ins-gnss").config
    out = {}
    # the position error's map from each block of the error state (true minus estimate): a
    # gyro bias error db_g is a rate error of the same sign (phi' = -C db_g), likewise db_a
    for blk, key, idx in (("tilt", "phi0", (0, 1)), ("heading", "phi0", (2,)), ("velocity", "dv0", (3, 4, 5)),
                          ("gyro bias", "eg", (9, 10, 11)), ("accel bias", "ea", (12, 13, 14))):
        a = np.stack([propagate(c, fn, dt, **{key: np.eye(3)[i % 3]}) for i in idx], axis=1)
        cov = a @ p0[np.ix_(idx, idx)] @ a.T
        out[f"{blk} (filter's P at the start)"] = math.sqrt(cov[0, 0] + cov[1, 1])
    tt = c.shape[0] * dt  # the outage's length
    # white gyro noise: tilt random walk through gravity; horizontal, two axes
    out["gyro white noise (spec, g ARW T^2.5 / sqrt(20))"] = (
        math.sqrt(2.0) * G * cfg.gyr_noise * tt ** 2.5 / math.sqrt(20.0))
    out["accel white noise (spec, VRW T^1.5 / sqrt(3))"] = math.sqrt(2.0) * cfg.acc_noise * tt ** 1.5 / math.sqrt(3.0)
    q = cfg.gyr_bias_instability * math.sqrt(2.0 / cfg.bias_tau)  # the filter's random walk density
    out["gyro bias instability (random walk of the filter, g q T^3.5 / sqrt(252))"] = (
        math.sqrt(2.0) * G * q * tt ** 3.5 / math.sqrt(252.0))
    return out


def p_at(rec, k):
    """The filter's covariance after sample ``k`` (a run up to it)."""
    r = fk.make("ins-gnss", frame="NED", nonholonomic="off").run(rec.slice(0, k + 1))
    return r.diagnostics["P"]


def show(title, parts, total, actual, pred):
    print(f"\n### {title}\n\n| source | share at the outage's end (N, E m) | horizontal m |\n|---|---|---:|")
    for k, v in parts.items():
        e = -np.asarray(v)  # estimate minus truth
        print(f"| {k} | {e[0]:+.2f}, {e[1]:+.2f} | {math.hypot(e[0], e[1]):.2f} |")
    print(f"| **sum (linear model)** | {total[0]:+.2f}, {total[1]:+.2f} | {math.hypot(total[0], total[1]):.2f} |")
    print(f"| **filter's actual error** | {actual[0]:+.2f}, {actual[1]:+.2f} | {math.hypot(actual[0], actual[1]):.2f} |")
    print("\n| predicted 1-sigma (horizontal) | m |\n|---|---:|")
    for k, v in pred.items():
        print(f"| {k} | {v:.1f} |")


def car_like(seed, **kw):
    """A drive like car_drive: its biases, site and IMU class (the simulator's defaults)."""
    args = dict(rest=40.0, speed=20.0, turn_rate=0.35, accel=1.0, climb=0.0, bank=False, trim=(0.0, 0.0),
                heading0=-177.0, origin=(31.508183, 120.401989, 0.0), gyr_bias=np.radians([0.10, 0.30, -0.22]),
                acc_bias=(0.03, 0.05, -0.05), mag_field=(32.94, -3.41, 36.55), outages=[(170.0, 230.0)], seed=seed)
    return simulate_flight(480.0, **{**args, **kw})


def sim_f_body(rec):
    """The true specific force (body) of a simulated drive: the measurement minus its biases
    and noise is not stored, so rebuild it from the truth's velocity and attitude."""
    from fusionkit.navigation.earth import normal_gravity

    dt = float(rec.nominal_dt)
    v = rec.meta["ref_vel_ned"]
    a = np.zeros_like(v)
    a[1:] = np.diff(v, axis=0) / dt
    g = normal_gravity(math.radians(rec.meta["origin_lla"][0]), rec.meta["origin_lla"][2])
    fn = a - np.array([0.0, 0.0, g])
    return np.einsum("nji,nj->ni", quat_dcm(rec.truth), fn)


print(machine())
# -- 1a. the data flight
import h5py  # noqa: E402

path = f"{args.data}/car_drive/car_drive.h5"
rec = fk.load(path)
with h5py.File(path, "r") as h:
    import json

    em = json.loads(h.attrs["imu_error_model_json"])
    rec.meta["f_body"] = h["ref_acc"][:]
    eg_all = h["imu_gyr"][:] - h["ref_gyr"][:]
    ea_all = h["imu_acc"][:] - h["ref_acc"][:]
rec.meta["gyr_bias0"] = np.radians(np.asarray(em["gyro_b"], float) / 3600.0)
rec.meta["acc_bias0"] = np.asarray(em["accel_b"], float)
res = fk.make("ins-gnss", frame="NED", nonholonomic="off").run(rec)
ok, gap = gnss_masks(rec)
k0, k1 = int(np.flatnonzero(gap)[0]) - 1, int(np.flatnonzero(gap)[-1])
parts, total, actual = budget(rec, res, None, None, eg_all - rec.meta["gyr_bias0"], ea_all - rec.meta["acc_bias0"])
show("car_drive (gnss-ins-sim file), the sensors alone (nonholonomic='off')", parts, total, actual,
     predicted(rec, k0, k1, p_at(rec, k0)))

# -- 1b./2. simulated drives: the budget and the Monte-Carlo
errs, stds, shares, floor, errs_nhc = [], [], {}, [], []
FLOOR = ("gyro bias: drift in the outage", "gyro white noise", "accel bias: drift in the outage", "accel white noise")
for seed in range(args.seeds):
    sim = car_like(seed)
    sim.meta["f_body"] = sim_f_body(sim)
    r = fk.make("ins-gnss", frame="NED", nonholonomic="off").run(sim)
    okk, gp = gnss_masks(sim)
    j1 = int(np.flatnonzero(gp)[-1])
    e = fk.make("ins-gnss", frame="NED").run(sim).diagnostics["position"][j1] - sim.meta["ref_pos_ned"][j1]
    errs_nhc.append(math.hypot(e[0], e[1]))
    e = r.diagnostics["position"][j1] - sim.meta["ref_pos_ned"][j1]
    errs.append(math.hypot(e[0], e[1]))
    s = r.diagnostics["position_std"][j1]
    stds.append(math.hypot(s[0], s[1]))
    # the budget of every drive: the RMS share of each source
    bg, ba = sim.meta["ref_gyr_bias"], sim.meta["ref_acc_bias"]
    # the sensors' noise is the measurement minus the error-free value; rebuild the latter
    sim0 = car_like(seed, gyr_noise=0.0, acc_noise=0.0, gyr_bias_instability=0.0, acc_bias_instability=0.0,
                    gyr_bias=(0.0, 0.0, 0.0), acc_bias=(0.0, 0.0, 0.0))
    p, tot, act = budget(sim, r, bg, ba, sim.gyr - sim0.gyr - bg, sim.acc - sim0.acc - ba)
    for k, v in list(p.items()) + [("sum (linear model)", -tot), ("filter's actual error", -act)]:
        shares.setdefault(k, []).append(math.hypot(v[0], v[1]))
    fl = sum(p[k] for k in FLOOR)  # what a filter with the exact state at the outage's start would have
    floor.append(math.hypot(fl[0], fl[1]))
errs, stds = np.array(errs), np.array(stds)
print(f"\n### Simulated drives like car_drive ({args.seeds} seeds), the sensors alone (nonholonomic='off')\n")
print("| source | RMS share, horizontal m |\n|---|---:|")
for k, v in shares.items():
    print(f"| {k} | {math.sqrt(np.mean(np.square(v))):.2f} |")
q = np.percentile(errs, [5, 25, 50, 75, 95])
print(f"\nhorizontal error at the outage's end: median {q[2]:.1f} m, 5/25/75/95 % {q[0]:.1f} / {q[1]:.1f} / {q[3]:.1f} / "
      f"{q[4]:.1f} m, RMS {math.sqrt(np.mean(errs ** 2)):.1f} m; within 5 m: {np.mean(errs <= 5.0) * 100:.0f} %; "
      f"the filter's 1-sigma (horizontal norm) median {np.median(stds):.1f} m; "
      f"error / sigma RMS {math.sqrt(np.mean((errs / stds) ** 2)):.2f}")
floor = np.array(floor)
q = np.percentile(floor, [5, 25, 50, 75, 95])
print(f"\nthe sensor's floor (the exact state at the outage's start; the IMU's white noise and bias drift over it): "
      f"median {q[2]:.1f} m, 5/25/75/95 % {q[0]:.1f} / {q[1]:.1f} / {q[3]:.1f} / {q[4]:.1f} m, RMS "
      f"{math.sqrt(np.mean(floor ** 2)):.1f} m; within 5 m: {np.mean(floor <= 5.0) * 100:.0f} %")
errs_nhc = np.array(errs_nhc)
q = np.percentile(errs_nhc, [5, 25, 50, 75, 95])
print(f"\ndefault parameters (nonholonomic='auto': the constraint once GNSS confirms it): median {q[2]:.1f} m, "
      f"5/25/75/95 % {q[0]:.1f} / {q[1]:.1f} / {q[3]:.1f} / {q[4]:.1f} m, RMS {math.sqrt(np.mean(errs_nhc ** 2)):.1f} m; "
      f"within 5 m: {np.mean(errs_nhc <= 5.0) * 100:.0f} %")
