"""fusionkit: inertial attitude estimation, filters picked by name, compared side by side.

Public API::

    import fusionkit as fk
    fk.available()                          # registered plugins by kind
    fk.bench(["poisson", "vqf"], data="../shared/data/broad")   # side by side, BROAD metrics
    rec = fk.Recording(gyr=..., acc=..., mag=None, rate=285.7)
    rec = fk.load("trial.hdf5")             # BROAD .hdf5 or CSV
    f = fk.make("poisson", frame="NED")     # any registered plugin, parameters validated
    res = f.run(rec)                        # res.quat (N, 4) w-x-y-z body->frame, res.flags
    print(fk.describe("poisson"))

Conventions: :mod:`fusionkit.conventions`.
"""

from . import conventions, rotations
from .config import AlignmentConfig, PipelineConfig, PluginSpec, load_config
from .errors import ConfigError, FusionkitError, InputError, PluginError
from .io import load
from .protocols import Corrector, Detector, Estimator, Filter
from .registry import available, default_registry, describe, get, make, register
from .types import Channel, Flag, Gnss, Recording, Result

__version__ = "0.1.0"

__all__ = [
    "AlignmentConfig",
    "Channel",
    "ConfigError",
    "Corrector",
    "Detector",
    "Estimator",
    "Filter",
    "Flag",
    "FusionkitError",
    "Gnss",
    "InputError",
    "PipelineConfig",
    "PluginError",
    "PluginSpec",
    "Recording",
    "Result",
    "available",
    "bench",
    "compose",
    "conventions",
    "default_registry",
    "describe",
    "get",
    "load",
    "load_config",
    "make",
    "register",
    "rotations",
    "sim",
    "__version__",
]


def __getattr__(name: str):
    """``fusionkit.sim`` is imported on first use: a make-and-run needs none of it (import time)."""
    if name == "sim":
        import importlib

        return importlib.import_module(".sim", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def bench(filters, data, **kwargs):
    """Run filters side by side on recordings; see :func:`fusionkit.benchmarking.bench`."""
    from .benchmarking import bench as _bench

    return _bench(filters, data, **kwargs)


def compose(config) -> Filter:
    """Build a :class:`~fusionkit.pipeline.Pipeline` from a dict, a JSON/TOML file or string.

    A monolithic filter's config (``{"filter": "ekf", "params": {...}}``, what ``describe("ekf")
    .config()`` gives) is a ConfigError saying to use :func:`make`: pydantic's "estimator: Field
    required ... filter: unknown parameter" did not say what the dict was."""
    from .pipeline import Pipeline

    cfg = load_config(config)
    if "filter" in cfg:
        name = cfg["filter"]
        build = f"fk.make({name!r}, **params)" if isinstance(name, str) else "fk.make(name, **params)"
        raise ConfigError(f"this is a monolithic filter's config ({{'filter': {name!r:.40}, 'params': {{...}}}}, as "
                          "fk.describe(name).config() gives it for a filter that is not a preset): fk.compose builds "
                          "a pipeline from an estimator, correctors and detectors; build this filter with "
                          f"{build}, params being its 'params' (`fusionkit run` takes either layout)")
    return Pipeline(cfg)
