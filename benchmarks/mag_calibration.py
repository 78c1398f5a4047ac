"""The ``mag-calibration`` sensor model in front of ``recommended`` on the BROAD trials (9D total):
without it (``mag_calibration=False``), with it (the default: the gate confident, consistent and
reducing the field's scatter; ``mag-heading`` learns its disturbance reference again when the
calibration changes), with the reference kept (``follow_calibration=False``, before issue 14's
second part), with the norm gate (``consistency_test="norm"``, the gate before the earth-frame
test) and with the confidence gate alone (``consistency=False``, the model before issue 14), VQF
in the same run; per trial, per group, and the mean without the trial each variant
helps most (leave-one-out).

    python benchmarks/mag_calibration.py [--data DIR] [--trials A,B] [--params JSON] [--json OUT]
    python benchmarks/mag_calibration.py --scenarios

``--params`` adds a variant with those ``mag-calibration`` parameters. ``--scenarios``: the
simulated scenarios instead (``sim.scenarios``: undisturbed, a magnet carried at 10, 5 and 3 cm,
a magnet on the desk, 2 uT of iron turning through a 20 uT earth-fixed field from 15 to 30 s),
heading RMS over the last 20 s, deg.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _common import data_dir, group_and_loo_tables

import numpy as np

import fusionkit as fk
from fusionkit import sim
from fusionkit.benchmarking.datasets import discover
from fusionkit.benchmarking.metrics import rms_errors
from fusionkit.config import PluginSpec
from fusionkit.pipeline import Pipeline
from fusionkit.rotations import quat_conj, quat_mul


def with_model(params: dict, heading: dict | None = None) -> Pipeline:
    """``recommended`` with ``mag-calibration`` (``params``) in front, and ``heading`` added to
    its ``mag-heading`` parameters."""
    cfg = fk.make("recommended").pipeline_config()
    cors = [c.model_copy(update={"params": {**c.params, **(heading or {})}}) if c.name == "mag-heading" else c
            for c in cfg.correctors]
    return Pipeline(cfg.model_copy(update={"models": [PluginSpec(name="mag-calibration", params=params)],
                                           "correctors": cors}))


def late_heading_deg(rec, res, seconds: float = 20.0) -> float:
    """RMS heading error over the last ``seconds`` of a simulated run (after the calibration had
    time to converge)."""
    q = quat_mul(res.quat, quat_conj(rec.truth))
    z = np.degrees(2.0 * np.arctan(np.abs(q[:, 3] / q[:, 0])))
    return float(np.sqrt(np.mean(z[-int(seconds / rec.nominal_dt):] ** 2)))


def scenarios(variants: dict) -> None:
    """The simulated table: heading RMS over the last 20 s per scenario and variant."""
    recs = {"undisturbed": sim.scenarios.hard_iron_turning(offset=(0.0, 0.0, 0.0)),
            "carried magnet at 10 cm": sim.scenarios.carried_magnet(distance=0.10),
            "carried magnet at 5 cm": sim.scenarios.carried_magnet(distance=0.05),
            "carried magnet at 3 cm": sim.scenarios.carried_magnet(distance=0.03),
            "magnet on the desk (earth-fixed)": sim.scenarios.magnet_nearby(),
            "2 uT iron, 20 uT earth-fixed field 15-30 s": sim.scenarios.perturbed(
                "hard-iron-turning", errors={"patches": (sim.FieldPatch((12.0, -10.0, 12.0), 15.0, 30.0),)},
                offset=(1.5, -1.0, 1.5))}
    print("| scenario | " + " | ".join(variants) + " |")
    print("|---|" + "---:|" * len(variants))
    for name, rec in recs.items():
        print(f"| {name} | " + " | ".join(f"{late_heading_deg(rec, make().run(rec)):.2f}" for make in variants.values())
              + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(data_dir() / "broad"))
    ap.add_argument("--trials", default="")
    ap.add_argument("--params", default="")
    ap.add_argument("--no-vqf", action="store_true")
    ap.add_argument("--json", default="")
    ap.add_argument("--scenarios", action="store_true")
    args = ap.parse_args()
    variants = {"without": lambda: fk.make("recommended", mag_calibration=False),
                "with": lambda: fk.make("recommended", mag_calibration=True),
                "reference kept": lambda: with_model({}, {"follow_calibration": False}),
                "norm gate": lambda: with_model({"consistency_test": "norm"}),
                "confidence only": lambda: with_model({"consistency": False})}
    if args.params:
        variants["params"] = lambda: with_model(json.loads(args.params))
    if args.scenarios:
        scenarios(variants)
        return
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
