"""Held-out, physics-randomised comparison of ``recommended`` against VQF on simulated recordings.

Every scenario family of :data:`fusionkit.sim.SCENARIOS` (each isolates one sensor error), several
draws each, with the rest of a consumer MEMS IMU's physics drawn at random on top
(:func:`fusionkit.sim.scenarios.perturbed`) from the ranges in :data:`RANGES`: gyro turn-on bias,
bias random walk, scale factor and misalignment, noise densities, accelerometer bias and scale,
sample rate, the initial rest, residual hard and soft iron, an earth-fixed magnetic disturbance,
inter-sensor delays and a magnetometer read at a lower rate. None of these recordings was used to
tune anything: the point is to find the conditions where ``recommended`` loses.

    python benchmarks/generalisation.py [--quick] [--draws N] [--seed S] [--families A,B]
                                        [--filters recommended,vqf,imufusion] [--diagnose]
                                        [--param KEY=VALUE ...] [--cut S] [--gyr-bias B]
    python benchmarks/generalisation.py --quick --filters recommended+offline,vqf-offline

Scores: 6D inclination RMSE and 9D total RMSE (deg) over the moving samples
(:func:`fusionkit.benchmarking.metrics.rms_errors`). Tables: per family and per condition bucket
(initial rest, turn-on bias, rate, magnetic disturbance, timing), the mean RMSE of each filter,
the win rate of the first filter against the second (``recommended`` against ``vqf``) and the
worst case. Then the conditions where the first loses by more than 10 %; ``--diagnose`` reruns
each of them with one error source switched off at a time and prints the ratio each leaves
(the source whose removal brings the ratio to 1 is the one behind the loss). ``--param KEY=VALUE``
(repeatable, the value JSON) sets a parameter of fusionkit's own filters in the comparison that have
it (``--param mag_distortion_significance=0.99``: an option measured against the default).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import sys
import time
import warnings

import numpy as np
from _common import REPO, param_value

import fusionkit as fk
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.sim import SCENARIOS, FieldPatch, Noise

try:
    from fusionkit.sim.scenarios import perturbed
except ImportError:  # another branch's fusionkit on PYTHONPATH, older than perturbed: this repository's
    # scenarios module on that fusionkit's simulator, so every branch is judged on the same recordings
    _spec = importlib.util.spec_from_file_location("fusionkit.sim._scenarios_here",
                                                   REPO / "fusionkit" / "sim" / "scenarios.py")
    _here = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(_here)
    perturbed = _here.perturbed

_DEG = math.pi / 180.0

#: the physics drawn per condition (consumer MEMS, data-sheet orders of magnitude; uniform unless noted)
RANGES = {
    "rate": "one of 100, 200, 400, 1000 Hz",
    "initial_rest": "0.5-30 s, log-uniform",
    "gyr_bias": "+-0.5 deg/s per axis (turn-on bias; --gyr-bias B: +-B)",
    "gyr_bias_rw": "1e-5 - 2e-4 rad/s/sqrt(s), log-uniform",
    "gyr_noise": "0.004-0.02 deg/s/sqrt(Hz) density",
    "gyr_scale": "+-1.5 % per axis, misalignment +-1 % off-diagonal",
    "acc_noise": "80-300 ug/sqrt(Hz) density",
    "acc_bias": "+-0.15 m/s^2 per axis, scale +-1 %",
    "mag_noise": "0.1-0.5 uT per sample",
    "mag_iron": "residual (after a calibration) hard iron +-2 uT per axis, soft iron I + symmetric +-2 %",
    "disturbance": "half the draws: an earth-fixed 5-30 uT field for 3-15 s during the motion",
    "delays": "gyro 0-2 samples, magnetometer 0-3 samples behind the accelerometer",
    "mag_rate": "half the draws (rate > 100 Hz): the magnetometer read at 50-100 Hz, sampled and held",
}

#: the SensorErrors fields each family sets itself (never drawn for it: the family keeps its own error)
OWN = {"hard-iron-turning": {"mag_offset"}, "carried-magnet": {"mag_offset"}, "magnet-nearby": {"dipoles"},
       "late-gyro": {"gyr_delay"}, "late-mag": {"mag_delay", "mag_lowpass", "mag_rate"},
       "lowpass-gyro": {"gyr_lowpass"}, "scaled-gyro": {"gyr_scale", "gyr_misalignment"},
       "drifting-bias-long": {"gyr_bias_rw", "acc_bias_rw"}, "vibrating": {"vibration"}, "tapped": {"taps"},
       "lossy": {"drop_rate", "gaps"}, "hand-held": {"lever_arm"}}

#: each family's own error switched off (for --diagnose)
OWN_OFF = {"hard-iron-turning": {"offset": (0.0, 0.0, 0.0)}, "carried-magnet": {"moment": 0.0},
           "magnet-nearby": {"moment": 0.0}, "late-gyro": {"delay": 0.0}, "late-mag": {"delay": 0.0},
           "lowpass-gyro": {"cutoff": None}, "scaled-gyro": {"scale": (0.0, 0.0, 0.0), "misalignment": np.zeros((3, 3))},
           "drifting-bias-long": {"gyr_bias_rw": 0.0}, "vibrating": {"amplitude": (0.0, 0.0, 0.0)},
           "tapped": {"times": ()}, "lossy": {"drop_rate": 0.0, "gaps": ()}, "hand-held": {"lever_arm": (0.0, 0.0, 0.0)}}

DIMS = (("6D", "inclination"), ("9D", "total"))


def _skew_free(rng, size: float) -> np.ndarray:
    m = rng.uniform(-size, size, (3, 3))
    np.fill_diagonal(m, 0.0)
    return m


def draw(family: str, seed: int, quick: bool = False, iron: float = 2.0, cut: float | None = None,
         gyr_bias: float = 0.5) -> dict:
    """One condition: the family, its seed and the physics drawn from :data:`RANGES` (a plain
    dict, so a condition can be printed, changed and rebuilt with :func:`build`); ``iron`` (uT)
    bounds the residual hard iron per axis, and in % the soft iron's; ``cut`` (s): the recording
    starts this long after its initial rest ends (in motion), the samples before it cut off; ``gyr_bias``
    (deg/s) bounds the gyro's turn-on bias per axis (the same draws scaled: the rest of the physics is the
    same)."""
    rng = np.random.default_rng([seed, sorted(SCENARIOS).index(family)])
    rate = float(rng.choice([100.0, 200.0, 400.0, 1000.0]))
    rest = float(np.exp(rng.uniform(math.log(0.5), math.log(30.0))))
    noise = {"gyr_noise": rng.uniform(0.004, 0.02) * _DEG * math.sqrt(rate),
             "gyr_bias": tuple(rng.uniform(-gyr_bias, gyr_bias, 3) * _DEG),
             "acc_noise": rng.uniform(80e-6, 300e-6) * 9.81 * math.sqrt(rate),
             "acc_bias": tuple(rng.uniform(-0.15, 0.15, 3)),
             "mag_noise": rng.uniform(0.1, 0.5)}
    soft = rng.uniform(-0.01 * iron, 0.01 * iron, (3, 3))
    soft = np.eye(3) + 0.5 * (soft + soft.T)
    errors = {"gyr_bias_rw": float(np.exp(rng.uniform(math.log(1e-5), math.log(2e-4)))),
              "gyr_scale": tuple(rng.uniform(-0.015, 0.015, 3)), "gyr_misalignment": _skew_free(rng, 0.01),
              "acc_scale": tuple(rng.uniform(-0.01, 0.01, 3)),
              "mag_offset": tuple(rng.uniform(-iron, iron, 3)), "mag_matrix": soft,
              "gyr_delay": rng.uniform(0.0, 2.0) / rate, "mag_delay": rng.uniform(0.0, 3.0) / rate}
    start, length, strength = rng.uniform(0.0, 10.0), rng.uniform(3.0, 15.0), rng.uniform(5.0, 30.0)
    direction = rng.standard_normal(3)
    if rng.random() < 0.5:
        errors["patches"] = (FieldPatch(tuple(strength * direction / np.linalg.norm(direction)), rest + start,
                                        rest + start + length),)
    mag_rate = rng.uniform(50.0, 100.0)
    if rng.random() < 0.5 and rate > 100.0:
        errors["mag_rate"] = mag_rate
    errors = {k: v for k, v in errors.items() if k not in OWN.get(family, ())}
    params = {"duration": 120.0 if quick else 300.0} if family == "drifting-bias-long" else {}
    out = {"family": family, "seed": seed, "rate": rate, "initial_rest": rest, "noise": noise, "errors": errors,
           "params": params}
    if cut is not None:
        out["cut"] = cut
    return out


def build(cond: dict):
    """The recording of a condition (from ``cond["cut"]`` s after its initial rest, where it has one)."""
    rec = perturbed(cond["family"], initial_rest=cond["initial_rest"], errors=cond["errors"],
                    noise=Noise(**cond["noise"]), rate=cond["rate"], seed=cond["seed"], **cond["params"])
    if cond.get("cut") is not None:  # by time: a recording with dropped samples (lossy) has fewer rows per second
        start = int(np.searchsorted(rec.time, cond["initial_rest"] + cond["cut"]))
        if start >= len(rec) - 1:
            raise SystemExit(f"--cut {cond['cut']:g}: past the end of {describe(cond)}")
        rec = rec.slice(start, None)
    return rec


#: ``--param KEY=VALUE``: parameters of fusionkit's own filters (those made with ``use_mag``), each given to
#: the filters whose configuration has it
PARAMS: dict = {}
#: what the script itself gives fusionkit's filters (refused as --param: a keyword given twice)
_SET_HERE = ("use_mag", "offline", "mag_calibration")


def _params(name: str) -> dict:
    """The ``--param`` parameters (:data:`PARAMS`) the fusionkit filter ``name`` has."""
    fields = fk.get(name, "filter").Config.model_fields
    return {k: v for k, v in PARAMS.items() if k in fields}


def make_filter(name: str, dims: str):
    """``name`` as a 6D or 9D filter: ``mode`` for the peers, ``use_mag`` for fusionkit's own.
    ``NAME+offline`` is fusionkit's offline mode of ``NAME`` (``fk.make(NAME, offline=True)``),
    ``NAME+offline-gyro-timing`` the same with the gyroscope re-timed onto the accelerometer's clock
    (``OfflineFilter(..., gyro_timing="recording")``), ``NAME+offline-gyro-lever`` with the delay fitted
    jointly with a lever arm (``gyro_timing="lever"``)."""
    name, _, option = name.partition("+")
    if option not in ("", "offline", "offline-gyro-timing", "offline-gyro-lever"):
        raise SystemExit(f"{name}+{option}: the options are '+offline', '+offline-gyro-timing' and "
                         "'+offline-gyro-lever'")
    fields = fk.get(name, "filter").Config.model_fields
    if "mode" in fields and not option:
        return fk.make(name, mode=dims)
    if "use_mag" in fields and option in ("offline-gyro-timing", "offline-gyro-lever"):
        from fusionkit.offline import OfflineFilter

        timing = "recording" if option == "offline-gyro-timing" else "lever"
        return OfflineFilter(fk.make(name, use_mag=dims == "9D", **_params(name)), gyro_timing=timing)
    if "use_mag" in fields:
        return fk.make(name, offline=option == "offline", use_mag=dims == "9D", **_params(name))
    raise SystemExit(f"{name}: no 'mode' or 'use_mag' parameter to choose 6D or 9D with")


def evaluate(cond: dict, filters, rec=None) -> dict:
    """The RMSE (deg) of each filter on the condition: ``{"6D": {name: incl}, "9D": {name: total}}``."""
    rec = build(cond) if rec is None else rec
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # timestamp gaps (lossy), GNSS epochs outside the IMU's time
        for dims, metric in DIMS:
            out[dims] = {n: rms_errors(make_filter(n, dims).run(rec), rec)[metric] for n in filters}
    return out


def buckets(cond: dict) -> dict:
    """The condition's bucket per axis of the tables."""
    e, rate = cond["errors"], cond["rate"]
    delay = max(abs(e.get("gyr_delay", 0.0)), abs(e.get("mag_delay", 0.0))) * rate
    if cond["family"] in ("late-gyro", "late-mag"):
        delay = max(delay, 0.005 * rate)  # their default delay
    bias = max(abs(b) for b in cond["noise"]["gyr_bias"]) / _DEG
    rest = "none (cut in motion)" if cond.get("cut") is not None else \
        "< 2 s" if cond["initial_rest"] < 2 else "2-10 s" if cond["initial_rest"] < 10 else ">= 10 s"
    return {"initial rest": rest,
            "turn-on gyro bias (max axis)": "< 0.25 deg/s" if bias < 0.25 else ">= 0.25 deg/s",
            "rate": "100-200 Hz" if rate <= 200 else "400-1000 Hz",
            "magnetic disturbance": "yes" if e.get("patches") or cond["family"] == "magnet-nearby" else "no",
            "inter-sensor delay (max)": "< 1 sample" if delay < 1 else ">= 1 sample"}


def describe(cond: dict) -> str:
    """A one-line summary of a condition's physics."""
    e, n = cond["errors"], cond["noise"]
    bits = [f"{cond['family']} seed {cond['seed']}", f"{cond['rate']:.0f} Hz", f"rest {cond['initial_rest']:.1f} s",
            "bias " + ",".join(f"{b / _DEG:+.2f}" for b in n["gyr_bias"]) + " deg/s"]
    if "gyr_bias_rw" in e:
        bits.append(f"rw {e['gyr_bias_rw']:.0e}")
    if e.get("patches"):
        p = e["patches"][0]
        bits.append(f"patch {np.linalg.norm(p.field):.0f} uT {p.start:.0f}-{p.stop:.0f} s")
    if "gyr_delay" in e or "mag_delay" in e:
        bits.append(f"delay gyr {e.get('gyr_delay', 0) * cond['rate']:.1f} mag {e.get('mag_delay', 0) * cond['rate']:.1f} smp")
    if "mag_rate" in e:
        bits.append(f"mag {e['mag_rate']:.0f} Hz")
    if cond.get("cut") is not None:
        bits.append(f"from {cond['cut']:g} s into the motion")
    return ", ".join(bits)


def _stats(sel: list[dict], dims: str, a: str, b: str) -> str:
    ea = np.array([r["rmse"][dims][a] for r in sel])
    eb = np.array([r["rmse"][dims][b] for r in sel])
    ratio = ea / eb
    return (f"{ea.mean():.3f} | {eb.mean():.3f} | {100 * np.mean(ea < eb):.0f} % | {ea.max():.2f} / {eb.max():.2f} | "
            f"{ratio.max():.2f}")


def tables(rows: list[dict], filters) -> str:
    """The markdown tables: per family, then per bucket of each axis; ``filters[0]`` against
    ``filters[1]`` (mean RMSE, win rate, worst RMSE of each, worst ratio), the others' means."""
    a, b = filters[0], filters[1]
    others = list(filters[2:])
    head = (f"| {{}} | n | {a} | {b} | {a} wins | worst {a} / {b} | worst ratio |"
            + "".join(f" {o} |" for o in others))
    rule = "|---|---:|---:|---:|---:|---:|---:|" + "---:|" * len(others)
    out = []
    axes = [("family", lambda r: r["cond"]["family"])] + [
        (k, (lambda r, k=k: buckets(r["cond"])[k])) for k in buckets(rows[0]["cond"])]
    for dims, metric in DIMS:
        out.append(f"\n### {dims} ({metric} RMSE, deg; {len(rows)} conditions)\n")
        for axis, key in axes:
            out += [head.format(axis), rule]
            groups = sorted({key(r) for r in rows}) + (["all", "all but lossy"] if axis == "family" else [])
            for g in groups:
                sel = [r for r in rows if g == "all" or key(r) == g
                       or (g == "all but lossy" and r["cond"]["family"] != "lossy")]
                if not sel:
                    continue
                extra = "".join(f" {np.mean([r['rmse'][dims][o] for r in sel]):.3f} |" for o in others)
                out.append(f"| {g} | {len(sel)} | {_stats(sel, dims, a, b)} |{extra}")
            out.append("")
    return "\n".join(out)


def losses(rows: list[dict], filters, margin: float = 1.10) -> list[tuple[float, str, dict]]:
    """(ratio, dims, row) where ``filters[0]``'s RMSE exceeds ``filters[1]``'s by more than ``margin``,
    worst first."""
    a, b = filters[0], filters[1]
    out = [(r["rmse"][d][a] / r["rmse"][d][b], d, r) for r in rows for d, _ in DIMS
           if r["rmse"][d][a] > margin * r["rmse"][d][b]]
    return sorted(out, key=lambda x: -x[0])


def switches(cond: dict) -> dict:
    """Copies of ``cond`` with one error source off each (label -> condition)."""
    def edit(**kw):
        c = {**cond, "noise": dict(cond["noise"]), "errors": dict(cond["errors"]), "params": dict(cond["params"])}
        for k, v in kw.items():
            where, key = k.split("__")
            if where == "top":
                c[key] = v
            elif v is None:
                c[where].pop(key, None)
            else:
                c[where][key] = v
        return c
    return {
        "turn-on bias 0": edit(noise__gyr_bias=(0.0, 0.0, 0.0)),
        "initial rest 30 s": edit(top__initial_rest=30.0, errors__patches=tuple(  # the disturbance stays in the motion
            FieldPatch(p.field, p.start + 30.0 - cond["initial_rest"], p.stop + 30.0 - cond["initial_rest"])
            for p in cond["errors"]["patches"]) if cond["errors"].get("patches") else None),
        "bias random walk 0": edit(errors__gyr_bias_rw=None),
        "gyro scale/misalignment 0": edit(errors__gyr_scale=None, errors__gyr_misalignment=None),
        "acc bias/scale 0": edit(noise__acc_bias=(0.0, 0.0, 0.0), errors__acc_scale=None),
        "delays 0, mag every sample": edit(errors__gyr_delay=None, errors__mag_delay=None, errors__mag_rate=None),
        "iron 0": edit(errors__mag_offset=None, errors__mag_matrix=None),
        "disturbance off": edit(errors__patches=None),
        "rate 200 Hz": edit(top__rate=200.0, noise__gyr_noise=cond["noise"]["gyr_noise"] * math.sqrt(200 / cond["rate"]),
                            noise__acc_noise=cond["noise"]["acc_noise"] * math.sqrt(200 / cond["rate"]),
                            errors__gyr_delay=cond["errors"].get("gyr_delay", 0) * cond["rate"] / 200,
                            errors__mag_delay=cond["errors"].get("mag_delay", 0) * cond["rate"] / 200),
        f"{cond['family']}'s own error off": edit(top__params={**cond["params"], **OWN_OFF[cond["family"]]}),
    }


def diagnose(cond: dict, dims: str, filters) -> list[tuple[str, float, float, float]]:
    """(switch, RMSE of ``filters[0]``, of ``filters[1]``, ratio) for each of :func:`switches`; in 9D
    with ``recommended`` first, also its run without its magnetometer calibration model (a part
    of the filter switched off, to tell its share; not a proposed setting)."""
    a, b = filters[0], filters[1]
    out = []
    for label, c in switches(cond).items():
        e = evaluate(c, (a, b))[dims]
        out.append((label, e[a], e[b], e[a] / e[b]))
    if dims == "9D" and a == "recommended":
        rec = build(cond)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ea = rms_errors(fk.make(a, mag_calibration=False, **_params(a)).run(rec), rec)["total"]
        eb = evaluate(cond, (b,), rec)[dims][b]
        out.append(("(recommended mag_calibration=False)", ea, eb, ea / eb))
    return out


def run(families, draws: int, seed: int, filters, quick: bool = False, progress: bool = True,
        iron: float = 2.0, cut: float | None = None, gyr_bias: float = 0.5) -> list[dict]:
    """Draw and evaluate ``draws`` conditions per family: rows of ``{"cond", "rmse"}``."""
    rows = []
    t0 = time.time()
    for i in range(draws):
        for fam in families:
            cond = draw(fam, seed * 1000 + i, quick, iron, cut, gyr_bias)
            rows.append({"cond": cond, "rmse": evaluate(cond, filters)})
            if progress:
                r = rows[-1]["rmse"]
                print(f"[{time.time() - t0:5.0f} s] {describe(cond)}: "
                      + "; ".join(f"{d} " + " ".join(f"{n} {v:.3f}" for n, v in r[d].items()) for d, _ in DIMS),
                      file=sys.stderr, flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 draws per family, 120 s drifting-bias-long")
    ap.add_argument("--draws", type=int, default=None, help="conditions per family (default 2 quick, 20 full)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", default="", help="comma-separated SCENARIOS names (default all)")
    ap.add_argument("--filters", default="recommended,vqf",
                    help="the first is compared with the second; the others' means are listed")
    ap.add_argument("--diagnose", action="store_true", help="rerun each loss with one error source off at a time")
    ap.add_argument("--max-diagnose", type=int, default=12,
                    help="diagnose the worst loss of each family, at most N of each of 6D and 9D")
    ap.add_argument("--json", default="", help="write each condition's description and RMSEs here")
    ap.add_argument("--iron", type=float, default=2.0,
                    help="residual hard iron bound, uT per axis (and soft iron, %%; default 2: after a calibration)")
    ap.add_argument("--gyr-bias", type=float, default=0.5, metavar="B",
                    help="the gyro's turn-on bias bound per axis, deg/s (default 0.5: a calibrated consumer gyro)")
    ap.add_argument("--cut", type=float, default=None, metavar="S",
                    help="start each recording S s after its initial rest ends (in motion: no rest to learn from)")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                    help="a parameter (JSON value) of the fusionkit filters that have it, e.g. "
                    "mag_distortion_significance=0.99; repeatable")
    args = ap.parse_args()
    families = args.families.split(",") if args.families else list(SCENARIOS)
    filters = args.filters.split(",")
    if len(filters) < 2:
        ap.error("--filters needs at least two filters")
    for item in args.param:
        key, eq, raw = item.partition("=")
        if not eq:
            ap.error(f"--param takes KEY=VALUE, got {item!r}")
        PARAMS[key] = param_value(raw)
    fields = [fk.get(f.partition("+")[0], "filter").Config.model_fields for f in filters]
    for key in PARAMS:
        if key in _SET_HERE:
            ap.error(f"--param {key}: the script sets it itself (6D / 9D, offline, the diagnosis's calibration off)")
        if not any(key in f and "use_mag" in f for f in fields):
            ap.error(f"--param {key}: no fusionkit filter among {filters} has it")
    if not (math.isfinite(args.gyr_bias) and args.gyr_bias >= 0.0):
        ap.error(f"--gyr-bias must be a finite number >= 0 deg/s, got {args.gyr_bias}")
    if args.cut is not None and not args.cut >= 0.0:
        ap.error(f"--cut must be >= 0 s, got {args.cut}")
    draws = args.draws or (2 if args.quick else 20)
    rows = run(families, draws, args.seed, filters, args.quick, iron=args.iron, cut=args.cut, gyr_bias=args.gyr_bias)
    print(f"# generalisation: {filters[0]} vs {filters[1]}, {len(rows)} conditions "
          f"(seed {args.seed}, {draws} draws per family, iron {args.iron:g}{', quick' if args.quick else ''}"
          f"{'' if args.cut is None else f', from {args.cut:g} s into the motion'}"
          f"{'' if args.gyr_bias == 0.5 else f', gyro bias +-{args.gyr_bias:g} deg/s'})"
          + "".join(f", {k}={json.dumps(v)}" for k, v in PARAMS.items()))
    print(tables(rows, filters))
    lost = losses(rows, filters)
    print(f"\n### conditions where {filters[0]} loses by > 10 % ({len(lost)} of {2 * len(rows)} runs)\n")
    print(f"| ratio | dims | {filters[0]} | {filters[1]} | condition |\n|---:|---|---:|---:|---|")
    for ratio, d, r in lost:
        print(f"| {ratio:.2f} | {d} | {r['rmse'][d][filters[0]]:.3f} | {r['rmse'][d][filters[1]]:.3f} | "
              f"{describe(r['cond'])} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump([{"condition": describe(r["cond"]), "rmse": r["rmse"]} for r in rows], fh, indent=1)
    if args.diagnose:
        worst, seen = [], set()
        for x in lost:  # the worst loss of each family, 6D and 9D, at most --max-diagnose of each
            key = (x[1], x[2]["cond"]["family"])
            if key not in seen and sum(y[1] == x[1] for y in worst) < args.max_diagnose:
                seen.add(key)
                worst.append(x)
        for ratio, d, r in worst:
            print(f"\n{d} {describe(r['cond'])}: ratio {ratio:.2f}; with one source off:")
            for label, ea, eb, q in diagnose(r["cond"], d, filters):
                print(f"  {label:32s} {ea:7.3f} {eb:7.3f}  ratio {q:.2f}", flush=True)


if __name__ == "__main__":
    main()
