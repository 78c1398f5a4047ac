"""Helpers shared by the benchmark scripts (not part of the package)."""

from __future__ import annotations

import os
import platform
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    """``$FUSIONKIT_DATA`` or ``../shared/data`` beside the repository."""
    env = os.environ.get("FUSIONKIT_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def param_value(text: str):
    """A ``--param KEY=VALUE``'s value: JSON where it parses (numbers, booleans, null, objects), else the text."""
    import json

    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def machine() -> str:
    import numba
    import numpy

    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, numba {numba.__version__}")


def group_and_loo_tables(rows: list[dict], labels: list[str], base: str) -> None:
    """Print the per-group means of ``rows[i]["errors"][label]`` and the leave-one-out means (each
    variant's mean without the trial it helps most against ``base``)."""
    import numpy as np

    groups = sorted({g for r in rows for g in r["groups"]})
    print("\n| group (trials) | " + " | ".join(labels) + " |")
    print("|---|" + "---:|" * len(labels))
    for g in ["all"] + groups:
        sel = [r for r in rows if g == "all" or g in r["groups"]]
        print(f"| {g} ({len(sel)}) | " + " | ".join(f"{np.mean([r['errors'][k] for r in sel]):.3f}" for k in labels)
              + " |")
    print(f"\nleave-one-out (the mean without the trial each variant helps most against '{base}'):")
    for k in labels:
        gain = [r["errors"][base] - r["errors"][k] for r in rows]
        best = int(np.argmax(gain))
        rest = [r for i, r in enumerate(rows) if i != best]
        print(f"  {k}: {np.mean([r['errors'][k] for r in rest]):.3f} against {np.mean([r['errors'][base] for r in rest]):.3f}"
              f" without {rows[best]['trial']}")
