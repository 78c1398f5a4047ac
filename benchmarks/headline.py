"""BENCHMARKS.md's headline table: every filter and peer, 6D inclination and 9D total on BROAD,
speed end to end and per kernel, each number with the command that made it.

    fusionkit bench --data ../shared/data/broad --jobs 1 --filters F1,F2,... --format json -o broad-9d.json
    fusionkit bench --data ../shared/data/broad --jobs 1 --filters F1,F2,... --param use_mag=false \\
        --param mode=6D --format json -o broad-6d.json
    python benchmarks/throughput.py > throughput.md
    python benchmarks/headline.py broad-9d.json broad-6d.json throughput.md [--previous ekf=3.46,15728,3289818]

Speed on a shared machine is noisy: each speed is also given as a ratio to VQF measured in the
same run (the end-to-end ratio against VQF 9D in the 9D bench, the kernel ratio against VQF's
row of the same ``throughput.py`` run).
"""

from __future__ import annotations

import argparse
import json
import re

import numpy as np

from fusionkit.benchmarking.plots import library

# filter: (throughput.py case for its 9D or only mode, case for its 6D mode)
KERNELS = {
    "poisson": ("poisson filter (alignment + motion detector + integrator)", None),
    "gst": ("gst (source 001, autonomous)", None),
    "gradient-descent": ("gradient-descent 9D, N = 1 (+ magnetic detector)", "gradient-descent 6D, N = 1 (source 003)"),
    "channel-dcm": ("channel-dcm 9D (source 002)", None),
    "recommended": ("recommended 9D", "recommended 6D"),
    "ekf": ("ekf 9D (compiled; reference: filterpy)", "ekf 6D (compiled; reference: filterpy)"),
    "vqf": ("vqf (peer, C++), 9D", "vqf (peer, C++), 6D"),
    "imufusion": ("imufusion (peer, C), 9D", None),
    "ahrs-madgwick": ("ahrs-madgwick (peer, Python), 9D", None),
    "ahrs-ekf": ("ahrs-ekf (peer, Python), 9D", None),
}
ORDER = ["recommended", "ekf", "gradient-descent", "channel-dcm", "gst", "poisson",
         "vqf", "vqf-offline", "vqf-basic", "imufusion", "ahrs-madgwick", "ahrs-mahony", "ahrs-ekf"]


def load_records(path: str) -> list[dict]:
    return json.loads(open(path).read())


def by_name(records: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in records:
        out.setdefault(r["name"], []).append(r)
    return out


def mean_metric(rs: list[dict], metric: str) -> tuple[float, int]:
    vals = [r["metrics"].get(metric) for r in rs if not r["error"] and r["metrics"].get(metric) is not None]
    return (float(np.mean(vals)) if vals else float("nan")), len(vals)


def median_speed(rs: list[dict]) -> float:
    v = [r["samples_per_s"] for r in rs if r["samples_per_s"]]
    return float(np.median(v)) if v else float("nan")


def read_throughput(path: str) -> dict[str, float]:
    """``{case: samples/s}`` from ``throughput.py``'s table: the compiled column, else the reference one."""
    out = {}
    for line in open(path):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 3 and cells[0] and not cells[0].startswith(("case", "---")):
            nums = [float(c.replace(",", "")) for c in cells[1:3] if re.fullmatch(r"[\d,.]+", c)]
            if nums:
                out[cells[0]] = nums[0]
    return out


def fmt(v: float, digits: int = 2) -> str:
    return "-" if v != v else f"{v:.{digits}f}"


def ratio(v: float) -> str:
    return "-" if v != v else f"{v:.3g}x"


def speed(v: float) -> str:
    if v != v:
        return "-"
    return f"{v / 1e6:.2f} M" if v >= 1e6 else f"{v / 1e3:.1f} k"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("nine", help="the 9D bench's JSON (default parameters)")
    ap.add_argument("six", help="the 6D bench's JSON (use_mag=false, mode=6D)")
    ap.add_argument("throughput", help="throughput.py's output")
    ap.add_argument("--previous", action="append", default=[], metavar="NAME=TOTAL,SPEED,VQF_SPEED",
                    help="a filter not re-measured: 9D total (deg) and end-to-end samples/s from an earlier run, "
                         "with VQF's samples/s in that run (marked in the table)")
    args = ap.parse_args()
    previous = {}
    for item in args.previous:
        name, vals = item.split("=", 1)
        previous[name] = [float(v) for v in vals.split(",")]
    nine, six = by_name(load_records(args.nine)), by_name(load_records(args.six))
    kern = read_throughput(args.throughput)
    vqf_e2e = median_speed(nine.get("vqf", []))
    vqf_k = kern.get(KERNELS["vqf"][0], float("nan"))
    print("| filter | library | 6D inclination RMSE, deg [A] | 9D total RMSE, deg [B] | end to end, samples/s [B] "
          "| vs VQF [B] | kernel, samples/s [C] | vs VQF [C] |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for name in ORDER + sorted(set(nine) - set(ORDER)):
        r9, r6 = nine.get(name, []), six.get(name, [])
        if name in previous and not r9:
            total, e2e, vqf_then = previous[name]
            case = KERNELS.get(name, (None, None))[0]
            k = kern.get(case, float("nan")) if case else float("nan")
            print(f"| {name} | {library('peer:ahrs' if name.startswith('ahrs') else 'reference')} | not measured "
                  f"| {fmt(total)} (earlier run) | {speed(e2e)} (earlier run) | {ratio(e2e / vqf_then)} "
                  f"| {speed(k)} (Python) | {ratio(k / vqf_k)} |")
            continue
        if not r9 and not r6:
            continue
        lib = library(next((r["backend"] for r in r9 + r6 if r["backend"]), None))
        kinds = {r.get("aiding") or r["dimension"] for r in r9 if r["dimension"]}
        only6 = kinds and "9D" not in kinds  # poisson, gst: no magnetometer mode
        incl, n6 = mean_metric(r9 if only6 else r6, "inclination")
        total, n9 = mean_metric(r9, "total") if not only6 else (float("nan"), 0)
        total_cell = (f"n/a ({'gyro-only' if 'gyro-only' in kinds or name == 'poisson' else '6D only'})"
                      if only6 else fmt(total))
        if not r6 and not only6:
            incl_cell = "not measured"
        else:
            incl_cell = fmt(incl, 3) + ("" if n6 in (0, 16) else f" ({n6} trials)")
        e2e = median_speed(r9)
        case = KERNELS.get(name, (None, None))[0]
        k = kern.get(case, float("nan")) if case else float("nan")
        ref = " (Python)" if case and "Python" in case else ""
        print(f"| {name} | {lib} | {incl_cell} | {total_cell} | {speed(e2e)} | {ratio(e2e / vqf_e2e)} "
              f"| {speed(k)}{ref} | {ratio(k / vqf_k)} |")


if __name__ == "__main__":
    main()
