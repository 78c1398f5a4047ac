"""The ``mag-calibration`` sensor model in front of ``recommended`` on the BROAD trials (9D total):
without it, with it (the default gate: confident, consistent and reducing the field's scatter),
and with the confidence gate alone (``consistency=False``, the model before issue 14), VQF in the
same run; per trial, per group, and the mean without the trial the model helps most
(leave-one-out).

    python benchmarks/mag_calibration.py [--data DIR] [--trials A,B] [--params JSON] [--json OUT]

``--params`` adds a variant with those ``mag-calibration`` parameters.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _common import data_dir, group_and_loo_tables

import fusionkit as fk
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.config import PluginSpec
from fusionkit.pipeline import Pipeline


def with_model(params: dict) -> Pipeline:
    """``recommended`` with ``mag-calibration`` (``params``) in front."""
    cfg = fk.make("recommended").pipeline_config()
    return Pipeline(cfg.model_copy(update={"models": [PluginSpec(name="mag-calibration", params=params)]}))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default="")
    ap.add_argument("--params", default="")
    ap.add_argument("--no-vqf", action="store_true")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    variants = {"without": lambda: fk.make("recommended"), "with": lambda: fk.make("recommended", mag_calibration=True),
                "confidence only": lambda: with_model({"consistency": False})}
    if args.params:
        variants["params"] = lambda: with_model(json.loads(args.params))
    if not args.no_vqf:
        variants["vqf"] = lambda: fk.make("vqf", mode="9D")
    rows = []
    for tr in discover(args.data, args.trials.split(",") if args.trials else None):
        rec = tr.load()
        row = {"trial": rec.name, "groups": list(tr.groups), "errors": {}}
        for label, make in variants.items():
            row["errors"][label] = rms_errors(make().run(rec), rec)["total"]
        rows.append(row)
        print(f"{rec.name}: " + "  ".join(f"{k}: {v:.3f}" for k, v in row["errors"].items()), flush=True)
    labels = list(variants)
    print("\n| trial | " + " | ".join(labels) + " |")
    print("|---|" + "---:|" * len(labels))
    for r in rows:
        print(f"| {r['trial']} | " + " | ".join(f"{r['errors'][k]:.3f}" for k in labels) + " |")
    group_and_loo_tables(rows, labels, "without")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
