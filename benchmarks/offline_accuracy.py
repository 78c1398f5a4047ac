"""The offline mode on the BROAD trials: ``recommended`` online, ``recommended`` offline and
``vqf-offline``, in one run (9D total RMSE and 6D inclination RMSE, deg, per trial and mean),
the mean without the trial the offline mode helps most (leave-one-out), and end-to-end
throughput (samples/s, compilation excluded).

    python benchmarks/offline_accuracy.py [--data DIR] [--trials 01,06] [--param key=value ...]
    python benchmarks/offline_accuracy.py --targets     # issue 14's tables: means, groups, leave-one-out

``--targets`` adds VQF online to both modes and prints issue 14's tables from the one run: each
mean (online and offline, 6D and 9D) against its target and its peer (``vqf``, ``vqf-offline``), the
mean per BROAD group of each pair with the groups where the peer's is lower named, and each pair's
means without the trial where fusionkit's lead over its peer is largest;

``--param`` sets a parameter of the recommended filter in both of its runs (an ablation);
``--equal-weights`` adds a column with the two passes fused half and half (the information
weights switched off); ``--no-mask`` a column without the disturbance mask decided by both passes
(``disturbance_gap=None``: each pass's own rejection only); ``--gap S`` sets ``disturbance_gap``
of the offline mode (default: ``OfflineFilter.DISTURBANCE_GAP``); ``--per-pass`` a column with each
pass running its own magnetometer calibration model (``calibration="per-pass"``, the mode before the
calibration was decided with the whole recording) and one without the model (``mag_calibration=False``);
``--as-is-timing`` a column with the magnetometer as it is recorded (``mag_timing="as-is"``, the mode
before its timing was decided with the whole recording); ``--average-inclination`` a column with the
passes' inclinations fused as they are (``inclination="average"``, the mode before the smoothing in
the other direction of time); ``--gyro-timing`` a column with the gyroscope moved onto the
accelerometer's clock by its delay estimated over the recording (``gyro_timing="recording"``, an
option; each trial's estimate is printed); ``--groups`` adds, per mode, the mean
of each BROAD group (``trials.json`` in the data folder: rotation, translation, slow, fast,
magnets ...) for every column: which kinds of motion the offline mode wins or loses against
``vqf-offline``; ``--bands`` adds, per column, where in frequency its inclination error is (the
mean square of the tilt error in the body frame per band, deg^2, and the part of its 0.5-3 Hz band
that follows the linear acceleration: deg per g and R^2); ``--lever-blocks`` prints, per trial, how
far ``gyro_delay_lever``'s model explains the accelerometer: the delay's signature against the
residual, and the fit's bound per stretch of one period of the band's lowest frequency (samples),
in ``--lever-band LO,HI`` (Hz; default the option's ``LEVER_BAND``); ``--rest-offset`` adds, per
column, the inclination RMSE with the accelerometer's tilt against the reference at the rests taken
out of the reference (read at the rest before and the rest after the movement, linear in time
between them, as a body-fixed misalignment of the reference) and prints those tilts: the part of the
error that is the rig's, which no filter can see from the IMU (the rests lie at one orientation);
``--oracle-fusion`` prints the offline mode's two smoothed passes fused with weights the reference
chooses (per sample, and per 2 s block): a bound on any weighting of the passes.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import fusionkit as fk
from _common import data_dir, machine, param_value
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.conventions import change_frame
from fusionkit.offline import LEVER_BAND, OfflineFilter, _lever_fit, gyro_delay_lever
from fusionkit.rotations import quat_to_matrix

#: the frequency bands (Hz) of ``--bands``: the offsets and drift, the time constants' range
#: (0.5-4 s), a hand's movements, and above
BANDS = ((0.0, 0.05), (0.05, 0.2), (0.2, 0.5), (0.5, 1.0), (1.0, 3.0), (3.0, None))


class _EqualWeights(OfflineFilter):
    """The offline mode with both passes weighted 1/2 on every sample."""

    def run(self, rec, **kw):
        import fusionkit.offline as off

        saved = off._weights
        off._weights = lambda a, b: np.full(a.shape, 0.5)
        try:
            return super().run(rec, **kw)
        finally:
            off._weights = saved


def _membership(path: Path, recs, always: tuple[str, ...] = ()) -> tuple[list[set], list[str]]:
    """Each trial's BROAD groups (``trials.json``'s ``groups``; none where the file or the trial is not
    there), each with the groups of ``always`` added, and every group met, ``all_trials`` first."""
    trials = json.loads(path.read_text())["trials"] if path.exists() else {}
    member = [set(trials.get(r.name, {}).get("groups", list(always))) for r in recs]
    if always:
        member = [m | set(always) for m in member]
    return member, sorted(dict.fromkeys(g for m in member for g in m), key=lambda g: g != "all_trials")


def _groups(path: Path, recs, err: dict, key: str) -> None:
    """The mean of every column per BROAD group (``trials.json``'s ``groups`` of each trial)."""
    if not path.exists():
        print(f"(no {path}: no groups)")
        return
    member, groups = _membership(path, recs)
    names = list(err)
    print(f"\nper group: mean {key} RMSE [deg]\n| group (trials) | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for g in groups:
        idx = [i for i, m in enumerate(member) if g in m]
        print(f"| {g} ({len(idx)}) | " + " | ".join(f"{np.mean([err[n][i] for i in idx]):.3f}" for n in names) + " |")


def _tilt_bands(res, rec) -> tuple[list[float], float, float]:
    """The tilt error of ``res`` against ``rec.truth`` in the body frame (``z_est x z_ref``, deg: no
    heading in it, which 6D does not know) split into :data:`BANDS` (the mean square over the
    movement, deg^2, each band by a second-order Butterworth forward and backward; the error is
    interpolated over the reference's gaps first), and its 0.5-3 Hz part regressed on the apparent
    tilt the linear acceleration makes (``z_ref x a / g``, ``a`` the specific force less gravity
    along the reference's vertical, same band): the coefficient (deg of error per g) and R^2."""
    from scipy.signal import butter, sosfiltfilt

    fs = 1.0 / rec.nominal_dt
    q_ref = change_frame(rec.truth, rec.truth_frame, res.frame)
    ok = np.isfinite(q_ref).all(axis=1) & np.isfinite(res.quat).all(axis=1)
    q_ref = np.where(ok[:, None], q_ref, [1.0, 0.0, 0.0, 0.0])
    z_ref, z_est = quat_to_matrix(q_ref)[:, 2, :], quat_to_matrix(np.where(ok[:, None], res.quat, 1.0))[:, 2, :]
    err = np.degrees(np.cross(z_est, z_ref))
    tilt = np.cross(z_ref, rec.acc - 9.81 * z_ref) / 9.81  # the apparent tilt of the linear acceleration (rad)
    k = np.arange(len(rec))
    for v in (err, tilt):
        good = ok & np.isfinite(v).all(axis=1)
        for i in range(3):
            v[:, i] = np.interp(k, k[good], v[good, i])
    move = (rec.movement if rec.movement is not None else np.ones(len(rec), bool)) & ok

    def band(v, lo, hi):
        if lo == 0.0:
            sos = butter(2, hi, fs=fs, output="sos")
        elif hi is None or hi >= 0.45 * fs:
            sos = butter(2, lo, btype="high", fs=fs, output="sos")
        else:
            sos = butter(2, [lo, hi], btype="band", fs=fs, output="sos")
        return sosfiltfilt(sos, v, axis=0)

    ms = [float(np.mean(np.sum(band(err, lo, hi)[move] ** 2, axis=1))) for lo, hi in BANDS]
    e, x = band(err, 0.5, 3.0)[move], np.degrees(band(tilt, 0.5, 3.0)[move])
    xx = float(np.sum(x * x))
    c = float(np.sum(e * x) / xx) if xx > 0.0 else float("nan")
    r2 = 1.0 - float(np.sum((e - c * x) ** 2) / np.sum(e * e)) if xx > 0.0 else float("nan")
    return ms, c * 57.29577951308232, r2  # deg of error per rad of apparent tilt -> per g (1 rad of a / g)


def _rest_tilt(rec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The accelerometer's tilt against the reference at the rest before and after the movement (rad,
    body frame, ``z_acc x z_ref`` averaged over each rest), the reference's vertical (body) and the
    movement's first and last sample as a weight ``s`` (0 before, 1 after, linear between)."""
    q_ref = change_frame(rec.truth, rec.truth_frame, "ENU")
    ok = np.isfinite(q_ref).all(axis=1)
    z_ref = quat_to_matrix(np.where(ok[:, None], q_ref, [1.0, 0.0, 0.0, 0.0]))[:, 2, :]
    e = np.cross(rec.acc / np.linalg.norm(rec.acc, axis=1)[:, None], z_ref)
    move = np.flatnonzero(rec.movement)
    k = np.arange(len(rec))
    pre, post = ok & (k < move[0]), ok & (k > move[-1])
    s = np.clip((k - move[0]) / max(move[-1] - move[0], 1), 0.0, 1.0)[:, None]
    return e[pre].mean(axis=0), e[post].mean(axis=0), z_ref, s


def _rest_offset(res, rec) -> float:
    """``res``'s inclination RMSE over the movement (deg) with :func:`_rest_tilt`'s tilts taken out of
    the reference as a body-fixed misalignment ``m`` (its horizontal part at the rests: a misaligned
    reference tilts by ``-(I - z z^T) m`` at any orientation), linear in time between the two rests."""
    e_pre, e_post, z_ref, s = _rest_tilt(rec)
    m = -((1.0 - s) * e_pre + s * e_post)
    m[:, 2] = 0.0  # the rests are level: only the horizontal part is seen
    q = change_frame(res.quat, res.frame, "ENU")
    ok = np.isfinite(q).all(axis=1) & np.isfinite(rec.truth).all(axis=1) & rec.movement
    z = quat_to_matrix(np.where(np.isfinite(q).all(axis=1)[:, None], q, [1.0, 0.0, 0.0, 0.0]))[:, 2, :]
    err = np.cross(z, z_ref) + m - np.sum(m * z_ref, axis=1)[:, None] * z_ref
    return float(np.degrees(np.sqrt(np.mean(np.sum(err[ok] ** 2, axis=1)))))


class _Passes(OfflineFilter):
    """The offline mode that keeps its two smoothed passes (ENU, the recording's order) in ``last``."""

    def _smoothed(self, *args):
        self.last = super()._smoothed(*args)
        return self.last


def _oracle_fusion(filt: _Passes, rec, block: float = 2.0) -> tuple[float, float]:
    """The tilt RMSE over the movement (deg) of ``filt``'s last two smoothed passes fused with the
    weight the reference chooses, per sample and per ``block`` s (the tilt errors ``e_f``, ``e_b`` as
    vectors: the point of the segment between them nearest to zero)."""
    q_ref = change_frame(rec.truth, rec.truth_frame, "ENU")
    ok = np.isfinite(q_ref).all(axis=1)
    z_ref = quat_to_matrix(np.where(ok[:, None], q_ref, [1.0, 0.0, 0.0, 0.0]))[:, 2, :]
    e_f, e_b = (np.cross(quat_to_matrix(q)[:, 2, :], z_ref) for q in filt.last)
    d = e_b - e_f
    w = np.clip(-np.sum(e_f * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-30), 0.0, 1.0)
    m = int(round(block / rec.nominal_dt))
    wb = np.empty_like(w)
    for i in range(0, len(w), m):
        dd = d[i:i + m]
        den = float(np.sum(dd * dd))
        wb[i:i + m] = np.clip(-np.sum(e_f[i:i + m] * dd) / den, 0.0, 1.0) if den > 0.0 else 0.5
    move = ok & rec.movement
    return tuple(float(np.degrees(np.sqrt(np.mean(np.sum((e_f + v[:, None] * d)[move] ** 2, axis=1)))))
                 for v in (w, wb))


def _lever_blocks(rec, band: tuple[float, float] = LEVER_BAND) -> str:
    """One line on how far ``gyro_delay_lever``'s model explains ``rec``'s accelerometer (in ``band``,
    Hz): its delay and jackknife standard deviation (samples), the RMS of the delay's signature for one sample of delay and of the fit's residual
    (mm/s^2, in the band), and its bound (samples: the residual's RMS over the delay column's, the
    lever arm's columns projected out) over the recording and per block of ``1 / band[0]`` s (one
    period of the band's lowest frequency): 10th percentile, median, least, and the blocks under 4."""
    fit = _lever_fit(rec, None, band, "auto", 6)
    if fit is None:
        return f"| {rec.name} | nothing to fit (under ten periods of {band[0]} Hz) |"
    a, y, sol = fit
    dt = rec.nominal_dt
    std = gyro_delay_lever(rec, band=band)[1]
    res = y - a @ sol
    c = a[:, 0] - a[:, 1:] @ np.linalg.lstsq(a[:, 1:], a[:, 0], rcond=None)[0]
    m = int(round(1.0 / band[0] / dt))
    bounds = np.array([np.sqrt(np.mean(res[3 * i:3 * (i + m)] ** 2) / np.mean(c[3 * i:3 * (i + m)] ** 2)) / dt
                       for i in range(0, len(y) // 3 - m + 1, m) if np.mean(c[3 * i:3 * (i + m)] ** 2) > 0.0])
    return (f"| {rec.name} | {sol[0] / dt:+.2f} +- {std / dt:.2f} | {np.sqrt(np.mean(c ** 2)) * dt * 1e3:.1f} | "
            f"{np.sqrt(np.mean(res ** 2)) * 1e3:.0f} | {np.sqrt(np.mean(res ** 2) / np.mean(c ** 2)) / dt:.1f} | "
            f"{np.percentile(bounds, 10):.1f} / {np.median(bounds):.1f} / {bounds.min():.1f} | "
            f"{int(np.sum(bounds < 4.0))} of {bounds.size} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default="", help="comma-separated trial prefixes (default: all)")
    ap.add_argument("--param", action="append", default=[], help="key=value for recommended (JSON value)")
    ap.add_argument("--modes", default="9D,6D")
    ap.add_argument("--equal-weights", action="store_true")
    ap.add_argument("--no-mask", action="store_true", help="add the offline mode without the disturbance mask")
    ap.add_argument("--gap", type=float, default=OfflineFilter.DISTURBANCE_GAP, help="disturbance_gap [s]")
    ap.add_argument("--per-pass", action="store_true", help="add the per-pass calibration and no calibration")
    ap.add_argument("--as-is-timing", action="store_true", help="add the magnetometer's timing as recorded")
    ap.add_argument("--average-inclination", action="store_true",
                    help="add the passes' inclinations fused as they are (the mode before the smoothing)")
    ap.add_argument("--gyro-timing", action="store_true",
                    help="add the gyroscope re-timed onto the accelerometer's clock (gyro_timing='recording')")
    ap.add_argument("--groups", action="store_true", help="add the mean per BROAD group (trials.json)")
    ap.add_argument("--targets", action="store_true",
                    help="add VQF online and print issue 14's targets: the means, per group and without each "
                         "comparison's best trial, against VQF in the same run")
    ap.add_argument("--bands", action="store_true", help="add where in frequency each column's tilt error is")
    ap.add_argument("--lever-blocks", action="store_true", help="print how far the lever fit explains each trial")
    ap.add_argument("--lever-band", default=",".join(map(str, LEVER_BAND)),
                    help="LO,HI (Hz): the band of --lever-blocks (default: the option's LEVER_BAND)")
    ap.add_argument("--rest-offset", action="store_true",
                    help="add each column with the accelerometer's tilt against the reference at the rests taken out")
    ap.add_argument("--oracle-fusion", action="store_true",
                    help="print the offline mode's smoothed passes fused with weights the reference chooses")
    args = ap.parse_args()
    files = sorted(Path(args.data).glob("*.hdf5"))
    if args.trials:
        keep = tuple(args.trials.split(","))
        files = [f for f in files if f.name.startswith(keep)]
    if not files:
        raise SystemExit(f"no BROAD trials in {args.data}")
    params = dict(p.split("=", 1) for p in args.param)
    params = {k: param_value(v) for k, v in params.items()}
    recs = [fk.load(f) for f in files]
    print(f"machine: {machine()}; recommended params: {params or 'defaults'}")
    if args.lever_blocks:
        lo, hi = (float(v) for v in args.lever_band.split(","))
        print(f"\ngyro_delay_lever, {lo:g}-{hi:g} Hz: delay, RMS of one sample's signature and of "
              f"the residual, bound over the recording and per {1.0 / lo:g} s block\n| trial | delay +- std "
              "[samples] | signature [mm/s^2 per sample] | residual [mm/s^2] | bound [samples] | block bound p10 / "
              "median / least | blocks under 4 |\n|---|---:|---:|---:|---:|---:|---:|")
        for rec in recs:
            print(_lever_blocks(rec, (lo, hi)))
    targets: dict = {}
    for mode in args.modes.split(","):
        six = mode == "6D"
        kw = dict(params, use_mag=False) if six else params
        runs = {"recommended": fk.make("recommended", **kw),
                "recommended offline": (_Passes if args.oracle_fusion else OfflineFilter)(
                    fk.make("recommended", **kw), disturbance_gap=args.gap),
                "vqf-offline": fk.make("vqf-offline", mode="6D" if six else "auto")}
        if args.targets:
            runs["vqf"] = fk.make("vqf", mode="6D" if six else "auto")
        if args.equal_weights:
            runs["offline, equal weights"] = _EqualWeights(fk.make("recommended", **kw), disturbance_gap=args.gap)
        if args.no_mask and not six:
            runs["offline, no mask"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=None)
        if args.per_pass and not six:
            runs["offline, per-pass calibration"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=args.gap,
                                                                  calibration="per-pass")
            runs["offline, no calibration"] = OfflineFilter(fk.make("recommended", **dict(kw, mag_calibration=False)),
                                                            disturbance_gap=args.gap)
        if args.as_is_timing and not six:
            runs["offline, timing as-is"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=args.gap,
                                                          mag_timing="as-is")
        if args.average_inclination:
            runs["offline, inclination averaged"] = OfflineFilter(fk.make("recommended", **kw),
                                                                  disturbance_gap=args.gap, inclination="average")
        if args.gyro_timing:
            runs["offline, gyro timing"] = OfflineFilter(fk.make("recommended", **kw), disturbance_gap=args.gap,
                                                         gyro_timing="recording")
        key = "inclination" if six else "total"
        err = {n: [] for n in runs}
        bands = {n: [] for n in runs}
        rest_err = {n: [] for n in runs}
        oracle = []
        secs = {n: 0.0 for n in runs}
        for f in runs.values():
            f.run(recs[0].slice(0, 500))  # compile
        for rec in recs:
            for n, f in runs.items():
                t0 = time.perf_counter()
                res = f.run(rec)
                secs[n] += time.perf_counter() - t0
                err[n].append(rms_errors(res, rec)[key])
                if args.bands:
                    bands[n].append(_tilt_bands(res, rec))
                if args.rest_offset:
                    rest_err[n].append(_rest_offset(res, rec))
                if args.oracle_fusion and n == "recommended offline":
                    oracle.append((rms_errors(res, rec)["inclination"],) + _oracle_fusion(f, rec))
                if n == "offline, gyro timing":
                    g = res.diagnostics["gyro_timing"]
                    print(f"{rec.name}: gyro delay {g['delay'] / rec.nominal_dt:+.2f} +- "
                          f"{g['std'] / rec.nominal_dt:.2f} samples, applied {g['applied']}")
        names = list(runs)
        print(f"\n{mode}: {key} RMSE [deg]\n| trial | " + " | ".join(names) + " |")
        print("|---|" + "---:|" * len(names))
        for i, rec in enumerate(recs):
            print(f"| {rec.name} | " + " | ".join(f"{err[n][i]:.2f}" for n in names) + " |")
        print("| **mean** | " + " | ".join(f"**{np.mean(err[n]):.3f}**" for n in names) + " |")
        pairs = [("recommended", "recommended offline", "offline's")]
        if args.equal_weights:
            pairs.append(("offline, equal weights", "recommended offline", "the information weights'"))
        if "offline, no mask" in runs:
            pairs.append(("offline, no mask", "recommended offline", "the disturbance mask's"))
        if "offline, per-pass calibration" in runs:
            pairs.append(("offline, per-pass calibration", "recommended offline", "the recording's calibration's"))
        if "offline, gyro timing" in runs:
            pairs.append(("recommended offline", "offline, gyro timing", "the gyro timing's"))
        if "offline, timing as-is" in runs:
            pairs.append(("offline, timing as-is", "recommended offline", "the recording's timing's"))
        for base, new, what in pairs:
            gain = np.array(err[base]) - np.array(err[new])
            best = int(np.argmax(gain))
            rest = [i for i in range(len(recs)) if i != best]
            print(f"| mean without {recs[best].name} ({what} largest gain, {gain[best]:.2f}) | "
                  + " | ".join(f"{np.mean([err[n][i] for i in rest]):.3f}" for n in names) + " |")
        total = sum(len(r) for r in recs)
        print("| samples/s (end to end) | " + " | ".join(f"{total / secs[n]:,.0f}" for n in names) + " |")
        if args.groups:
            _groups(Path(args.data) / "trials.json", recs, err, key)
        if args.targets:
            targets[mode] = err
        if args.rest_offset:
            print(f"\n{mode}: inclination RMSE [deg] with the accelerometer's tilt against the reference at the rests "
                  "taken out of the reference; those tilts (deg, body x, y) before / after the movement\n| trial | "
                  + " | ".join(names) + " | rest before | rest after |\n|---|" + "---:|" * (len(names) + 2))
            for i, rec in enumerate(recs):
                a, b = (np.degrees(v) for v in _rest_tilt(rec)[:2])
                print(f"| {rec.name} | " + " | ".join(f"{rest_err[n][i]:.3f}" for n in names)
                      + f" | {a[0]:+.2f}, {a[1]:+.2f} | {b[0]:+.2f}, {b[1]:+.2f} |")
            print("| **mean** | " + " | ".join(f"**{np.mean(rest_err[n]):.3f}**" for n in names) + " | | |")
            if args.groups:
                _groups(Path(args.data) / "trials.json", recs, rest_err, key + ", rest tilts out,")
        if args.oracle_fusion:
            o = np.array(oracle)
            print(f"\n{mode}: the offline mode's smoothed passes fused by weights the reference chooses, inclination "
                  "RMSE [deg]\n| trial | offline | per sample | per 2 s |\n|---|---:|---:|---:|")
            for i, rec in enumerate(recs):
                print(f"| {rec.name} | " + " | ".join(f"{v:.3f}" for v in o[i]) + " |")
            print("| **mean** | " + " | ".join(f"**{v:.4f}**" for v in o.mean(axis=0)) + " |")
        if args.bands:
            heads = " | ".join(f"{lo:g}-{hi:g}" if hi else f">{lo:g}" for lo, hi in BANDS)
            print(f"\n{mode}: tilt error (body frame) by band [deg^2] and its 0.5-3 Hz part that follows the "
                  f"linear acceleration [deg/g, R^2]\n| trial | column | {heads} | deg/g | R^2 |")
            print("|---|---|" + "---:|" * (len(BANDS) + 2))
            for i, rec in enumerate(recs):
                for n in names:
                    ms, c, r2 = bands[n][i]
                    print(f"| {rec.name[:2]} | {n} | " + " | ".join(f"{v:.4f}" for v in ms) + f" | {c:+.2f} | {r2:.2f} |")
            for n in names:
                print(f"| mean | {n} | " + " | ".join(f"{np.mean([b[0][j] for b in bands[n]]):.4f}"
                                                for j in range(len(BANDS))) + " | | |")
    if args.targets:
        _targets(Path(args.data) / "trials.json", recs, targets)


#: issue 14's targets on BROAD's 16 development trials (mode, column: the most its mean may be, deg)
TARGETS = {("6D", "recommended"): 0.62, ("9D", "recommended"): 2.0, ("6D", "recommended offline"): 0.50,
           ("9D", "recommended offline"): 1.8}
#: each of fusionkit's columns against its peer
PEERS = (("recommended", "vqf"), ("recommended offline", "vqf-offline"))


def _targets(path: Path, recs, targets: dict) -> None:
    """Issue 14's tables from the errors of one run (``targets[mode][column]``, per trial): each mean
    against its target and its peer, the mean per BROAD group with the lower of each pair in bold
    (and the groups where the peer's is lower named), and each pair's means without the trial where
    fusionkit's lead over the peer is largest (does the lead hold without it?)."""
    member, groups = _membership(path, recs, ("all_trials",))
    cols = [(mode, ours, peer) for mode in targets for ours, peer in PEERS]
    print("\nissue 14's targets: the mean over the trials against the target and the peer in the same run (deg; "
          "6D inclination, 9D total)\n| mode | filter | mean | target | peer | peer's mean | met |")
    print("|---|---|---:|---:|---|---:|---|")
    for mode, ours, peer in cols:
        m, target = float(np.mean(targets[mode][ours])), TARGETS.get((mode, ours))
        met = "-" if target is None else "yes" if m <= target else "no"
        print(f"| {mode} | {ours} | {m:.3f} | {target if target is not None else '-'} | {peer} | "
              f"{np.mean(targets[mode][peer]):.3f} | {met} |")
    head = " | ".join(f"{mode} {ours} | {peer}" for mode, ours, peer in cols)
    print(f"\nper group (mean of its trials; the lower of each pair in bold)\n| group (trials) | {head} | "
          "the peer's mean is lower in |\n|---|" + "---:|" * (2 * len(cols)) + "---|")
    for g in groups:
        idx = [i for i, m in enumerate(member) if g in m]
        cells, lost = [], []
        for mode, ours, peer in cols:
            a, b = (float(np.mean([targets[mode][c][i] for i in idx])) for c in (ours, peer))
            cells += [f"**{a:.3f}**" if a <= b else f"{a:.3f}", f"**{b:.3f}**" if b < a else f"{b:.3f}"]
            if b < a:
                lost.append(f"{mode} {ours}")
        print(f"| {g} ({len(idx)}) | " + " | ".join(cells) + f" | {', '.join(lost) or '-'} |")
    print("\nleave-one-out: each pair's means without the trial where fusionkit's lead over the peer is largest\n"
          "| mode | pair | trial left out | its lead | mean | peer's mean |\n|---|---|---|---:|---:|---:|")
    for mode, ours, peer in cols:
        lead = np.array(targets[mode][peer]) - np.array(targets[mode][ours])
        best = int(np.argmax(lead))
        rest = [i for i in range(len(recs)) if i != best]
        print(f"| {mode} | {ours} / {peer} | {recs[best].name} | {lead[best]:.2f} | "
              f"{np.mean([targets[mode][ours][i] for i in rest]):.3f} | "
              f"{np.mean([targets[mode][peer][i] for i in rest]):.3f} |")


if __name__ == "__main__":
    main()
