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


def machine() -> str:
    import numba
    import numpy

    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, numba {numba.__version__}")
