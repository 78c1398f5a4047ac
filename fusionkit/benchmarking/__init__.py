"""Benchmarking: datasets, metrics (BROAD definitions), the side-by-side runner, sweeps, plots,
sensor timing against a reference.

The entry point is :func:`fusionkit.bench` (this package is ``fusionkit.benchmarking`` so that
the function and the package do not shadow each other).
"""

from .datasets import Trial, discover
from .metrics import broad_errors, rms_errors, trial_metrics
from .runner import BenchResult, FilterSpec, bench, evaluate
from .timing import SensorLags, sensor_lags

__all__ = ["BenchResult", "FilterSpec", "SensorLags", "Trial", "bench", "broad_errors", "discover", "evaluate",
           "rms_errors", "sensor_lags", "trial_metrics"]
