"""Every registered filter and peer on the BROAD trials, side by side; updates BENCHMARKS.md.

    python benchmarks/side_by_side.py [--data DIR] [--jobs 2] [--no-write]

Every registered filter that can run without GNSS, with its default parameters, plus reference
rows: ahrs' Madgwick with the BROAD-tuned beta 0.12, VQF and ``recommended`` in 6D
(magnetometer-free), and the documents' own modes of ``gradient-descent`` (the patent: no
initial-rest alignment, no magnetic rejection) and ``channel-dcm`` (the paper: no bias). 9D filters are judged on total RMSE,
6D ones on inclination RMSE (BROAD's rule). The tables replace the section between the
``side-by-side`` markers in BENCHMARKS.md; the plots go to docs/img/.
"""

from __future__ import annotations

import argparse
import re

import fusionkit as fk
from _common import REPO, data_dir, machine
from fusionkit.benchmarking import bench, discover
from fusionkit.benchmarking.plots import plot_by_group, plot_error_over_time, plot_throughput


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-write", action="store_true", help="print, do not touch BENCHMARKS.md")
    args = ap.parse_args()
    # every filter that can run on BROAD (a GNSS-aided one cannot: BROAD has no GNSS)
    names = [n for n in fk.available("filter") if n != "pipeline" and not fk.get(n, "filter").requires_gnss]
    filters = names + [("ahrs-madgwick", {"gain": 0.12}), ("vqf", {"mode": "6D"}), ("recommended", {"use_mag": False}),
                       ("gradient-descent", {"initial_rest": 0.0, "mag_rejection": False}),  # the patent
                       ("channel-dcm", {"initial_rest": 0.0})]  # the paper
    res = bench(filters, args.data, jobs=args.jobs, progress=True)
    out = [f"Measured with `python benchmarks/side_by_side.py` on {machine()}; "
           f"{len(res.trials)} trials; throughput is one core per trial (median over trials).", "",
           "Per trial (deg; 9D: total RMSE, 6D: inclination RMSE, as the last rows say):", "",
           res.table("markdown"), "", "By BROAD group (mean over the group's trials, deg):", "",
           res.group_table(format="markdown"), "",
           "![error by group](docs/img/broad_by_group.png)", "",
           "![throughput](docs/img/broad_throughput.png)", "",
           "![error over time, trial 04](docs/img/broad_error_04.png)"]
    text = "\n".join(out)
    print(text)
    img = REPO / "docs" / "img"
    img.mkdir(parents=True, exist_ok=True)
    plot_by_group(res, img / "broad_by_group.png")
    plot_throughput(res, img / "broad_throughput.png")
    trial = discover(args.data, ["04"])[0]
    plot_error_over_time(["recommended", "vqf", "ekf", "gradient-descent", "channel-dcm", ("ahrs-madgwick", {"gain": 0.12})],
                         trial,
                         img / "broad_error_04.png")
    if not args.no_write:
        path = REPO / "BENCHMARKS.md"
        doc = path.read_text()
        block = f"<!-- side-by-side:start -->\n{text}\n<!-- side-by-side:end -->"
        if "<!-- side-by-side:start -->" in doc:
            doc = re.sub(r"<!-- side-by-side:start -->.*<!-- side-by-side:end -->", lambda m: block, doc, flags=re.S)
        else:
            doc += "\n## Side by side on BROAD (every filter and peer)\n\n" + block + "\n"
        path.write_text(doc)
        print(f"updated {path}")


if __name__ == "__main__":
    main()
