"""Shared fixtures. Real data is read in place from ``$FUSIONKIT_DATA`` or ``../shared/data``
(relative to the repository); tests that need it skip cleanly where it is absent."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import fusionkit as fk
from fusionkit import sim

REPO = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    env = os.environ.get("FUSIONKIT_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    d = data_dir() / "broad"
    if not any(d.glob("*.hdf5")):
        pytest.skip(f"BROAD data not found in {d} (set FUSIONKIT_DATA)")
    return d


def broad_mean(broad_dir: Path, name: str, metric: str, six_d: bool = False, **params) -> float:
    """Mean over the BROAD trials of one BROAD metric (``total``, ``inclination``, ``heading``)
    of filter ``name`` with ``params``; ``six_d`` drops the magnetometer."""
    import dataclasses

    from fusionkit.benchmarking.metrics import rms_errors

    vals = []
    for path in sorted(broad_dir.glob("*.hdf5")):
        r = fk.load(path)
        if six_d:
            r = dataclasses.replace(r, mag=None)
        vals.append(rms_errors(fk.make(name, **params).run(r), r)[metric])
    return float(np.mean(vals))


@pytest.fixture(scope="session")
def imu_rec() -> fk.Recording:
    """Seeded noisy recording: 12 s rest, then rotations and a translation."""
    deg = np.pi / 180
    segs = [sim.Rest(12.0), sim.Rotate((0, 0, 1), 90 * deg, 2.0), sim.Rotate((1, 0, 0), 40 * deg, 1.5),
            sim.Translate((1, 0, 0), 0.4, 1.0), sim.Rotate((0, 1, 0), -50 * deg, 1.5), sim.Rest(1.0)]
    return sim.simulate(segs, rate=100.0, noise=sim.Noise.mems(), seed=3)


@pytest.fixture(scope="session")
def clean_rec() -> fk.Recording:
    """The same motions without noise or bias."""
    deg = np.pi / 180
    segs = [sim.Rest(12.0), sim.Rotate((0, 0, 1), 90 * deg, 2.0), sim.Rotate((1, 0, 0), 40 * deg, 1.5),
            sim.Translate((1, 0, 0), 0.4, 1.0), sim.Rotate((0, 1, 0), -50 * deg, 1.5), sim.Rest(1.0)]
    return sim.simulate(segs, rate=100.0, seed=3)
