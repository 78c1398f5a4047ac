"""Shared fixtures. Real data is read in place from ``$FUSIONKIT_DATA`` or ``../shared/data``
(relative to the repository); tests that need it skip cleanly where it is absent."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import pytest

# The suite's generated loops call their kernels instead of inlining them (fusionkit/_numba.py,
# LOOP_INLINE): the same numbers at a tenth of the compile time per composition. The inlined
# loops users run are checked against these, preset by preset, in test_inlined_loops*.py.
# Set before fusionkit is imported; the tests' subprocesses inherit it.
os.environ.setdefault("FUSIONKIT_LOOP_INLINE", "0")
# No compile notice on stderr (fusionkit/_numba.py), whatever the developer's environment says: tests
# count the lines a command writes there, and a cold run compiles (test_numba_cache checks the notice).
os.environ["FUSIONKIT_COMPILE_NOTICE"] = "0"

import fusionkit as fk  # noqa: E402
from fusionkit import sim  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


# `-n 2 --dist loadfile` hands whole files to the two workers, and xdist's default order (the
# files with the most tests first) left test_inlined_loops (9 tests, the inlined presets' compiles,
# the suite's longest file cold) to the end, compiling on one worker after the other had finished.
# The files a cold run spends longest in go first instead, longest first (the rest in collection
# order), the second one needing none of the first one's kernels, so the two workers do not start
# by waiting on each other's compile locks (fusionkit/_numba.py). The inlined presets' compiles
# are two files, recommended's (the longest) and the others', so the two workers start on one each.
# The next ones (5-15 s each cold) follow, so that what is left at the end is files of a few
# seconds: the worker that takes the last file ends a few seconds after the other, not the ~17 s
# that test_timing.py (the BROAD data) and test_speed.py, late in collection order, cost.
HEAVY_FIRST = ("test_inlined_loops_recommended.py", "test_inlined_loops.py", "test_ins_gnss.py", "test_contract.py",
               "test_reliability.py", "test_recommended.py", "test_gst.py", "test_time_offset.py", "test_offline.py",
               "test_mag_calibration_gate.py", "test_poisson_filter.py", "test_offline_timing.py", "test_timing.py",
               "test_registry.py", "test_offline_smoothing.py", "test_speed.py", "test_numba_cache.py",
               "test_models.py", "test_loopgen.py", "test_sim_scenarios.py")


def pytest_configure(config):
    if hasattr(config.option, "loadscopereorder"):  # pytest-xdist: keep the order below
        config.option.loadscopereorder = False
    # pytest rewrites the asserts of every module of a package that registers a pytest plugin, and
    # hypothesis (imported by test_fuzz_extremes) is one: ~100 of its modules rewritten in each
    # worker, 0.6 s of CPU, for asserts that are hypothesis's own. The tests' asserts are rewritten
    # as before. pytest's internals: where they differ, everything is rewritten as it was.
    try:
        from _pytest.assertion.rewrite import assertstate_key

        hook = config.stash[assertstate_key].hook
        hook._must_rewrite.discard("hypothesis")
        hook._marked_for_rewrite_cache.clear()
    except (ImportError, KeyError, AttributeError):
        pass


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def data_dir() -> Path:
    env = os.environ.get("FUSIONKIT_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    d = data_dir() / "broad"
    if not any(d.glob("*.hdf5")):
        pytest.skip(f"BROAD data not found in {d} (set FUSIONKIT_DATA)")
    return d


@functools.lru_cache(maxsize=1)
def broad_recordings(broad_dir: Path) -> tuple[fk.Recording, ...]:
    """The BROAD trials, loaded once per process (0.6 s of CPU each time, ~90 MB kept): five
    tests average a filter over all of them. Runs never write into their input."""
    return tuple(fk.load(path) for path in sorted(broad_dir.glob("*.hdf5")))


def broad_mean(broad_dir: Path, name: str, metric: str, six_d: bool = False, **params) -> float:
    """Mean over the BROAD trials of one BROAD metric (``total``, ``inclination``, ``heading``)
    of filter ``name`` with ``params``; ``six_d`` drops the magnetometer."""
    import dataclasses

    from fusionkit.benchmarking.metrics import rms_errors

    vals = []
    for r in broad_recordings(broad_dir):
        if six_d:
            r = dataclasses.replace(r, mag=None)
        vals.append(rms_errors(fk.make(name, **params).run(r), r)[metric])
    return float(np.mean(vals))


def backend_quats(f, rec, split_at: int | None = None) -> dict[str, np.ndarray]:
    """``f``'s output quaternions on ``rec`` from each path, ``{"reference": ..., "numba": ...}``;
    with ``split_at`` as two runs, the second from the first's state (what a split recording gets)."""
    out = {}
    for backend in ("reference", "numba"):
        if split_at is not None:
            first = f.run(rec.slice(0, split_at), backend=backend)
            second = f.run(rec.slice(split_at, len(rec)), backend=backend, state=first.diagnostics["state"])
            out[backend] = np.vstack([first.quat, second.quat])
        else:
            res = f.run(rec, backend=backend)
            assert res.diagnostics["backend"] == backend
            out[backend] = res.quat
    return out


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


def fit_ellipsoid(x):
    """Centre ``c`` and shape ``Q`` of the ellipsoid ``(x - c)^T Q (x - c) = 1`` through the points
    (linear least squares on the general quadric)."""
    d = np.column_stack([x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2, 2 * x[:, 0] * x[:, 1], 2 * x[:, 0] * x[:, 2],
                         2 * x[:, 1] * x[:, 2], 2 * x[:, 0], 2 * x[:, 1], 2 * x[:, 2]])
    p = np.linalg.lstsq(d, np.ones(len(x)), rcond=None)[0]
    q = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    c = -np.linalg.solve(q, p[6:])
    return c, q / (1.0 + c @ q @ c)
