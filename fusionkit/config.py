"""Configuration models (pydantic 2) and their loading from dicts, JSON and TOML.

Every plugin has a ``Config``: a frozen :class:`PluginConfig` with ``extra="forbid"``, ranges
checked, defaults equal to the source document's values, and a description and unit per field
(declared with :func:`param`). Validation failures raise :class:`~fusionkit.errors.ConfigError`
with pydantic's message (which names the field, the value and the rule).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from .conventions import FRAMES
from .errors import ConfigError

__all__ = [
    "PluginConfig",
    "FilterConfig",
    "PluginSpec",
    "AlignmentConfig",
    "PipelineConfig",
    "param",
    "build_config",
    "load_config",
    "describe_config",
    "set_dotted",
]


def param(default: Any, *, unit: str, description: str, **constraints: Any) -> Any:
    """A config field with its default, unit ("-" for none) and description."""
    return Field(default, description=description, json_schema_extra={"unit": unit}, **constraints)


class PluginConfig(BaseModel):
    """Base of every plugin configuration: frozen, unknown keys rejected."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class FilterConfig(PluginConfig):
    """Fields every filter has."""

    frame: Literal["ENU", "NED", "NWU", "NUE"] = param(
        "ENU", unit="-", description=f"earth frame of the output quaternions, one of {FRAMES}"
    )
    nan_policy: Literal["raise", "skip"] = param(
        "raise",
        unit="-",
        description="non-finite input: 'raise' an InputError naming the sample, or 'skip' it "
        "(hold the state, flag the sample)",
    )
    gyr_range: float | None = param(
        None, unit="rad/s", description="gyroscope range; samples at or above it are flagged GYR_SATURATED", gt=0
    )
    acc_range: float | None = param(
        None, unit="m/s^2", description="accelerometer range; samples at or above it are flagged ACC_SATURATED", gt=0
    )


class PluginSpec(PluginConfig):
    """A plugin by name with its parameters, as used inside a :class:`PipelineConfig`."""

    name: str = param(..., unit="-", description="registered plugin name")
    params: dict[str, Any] = param({}, unit="-", description="the plugin's config fields")

    @classmethod
    def coerce(cls, value: Any) -> "PluginSpec":
        if isinstance(value, str):
            return cls(name=value)
        return value


class AlignmentConfig(PluginConfig):
    """Initial alignment (source 000, section 3): attitude from the mean specific force, heading 0
    (or from the magnetometer), gyro bias = mean gyro output over the window."""

    mode: Literal["motion", "fixed", "none"] = param(
        "motion",
        unit="-",
        description="'motion': align for at least `duration`, then until a detector flags MOTION "
        "(source 000); 'fixed': exactly `duration`; 'none': start from `initial_quat` with zero bias",
    )
    duration: float = param(10.0, unit="s", description="mandatory alignment time (source 000: 10 s)", gt=0)
    heading: Literal["zero", "magnetometer", "auto"] = param(
        "zero", unit="-",
        description="initial heading: 'zero' = body x to north (source 000's heading 0; ENU yaw 90 deg), from the "
        "mean magnetometer, or 'auto' (magnetometer when given)",
    )
    estimate_bias: bool = param(True, unit="-", description="subtract the mean gyro output of the window")
    max_rate: float | None = param(
        None, unit="rad/s", description="extension: a gyro sample above this ends the alignment before it (the "
        "recording did not start still; that sample is navigated); None: off (source 000)", gt=0)
    initial_quat: tuple[float, float, float, float] = param(
        (1.0, 0.0, 0.0, 0.0), unit="-", description="start attitude for mode 'none' (w, x, y, z), body->frame"
    )

    @field_validator("initial_quat")
    @classmethod
    def _unit(cls, q):
        n = sum(v * v for v in q) ** 0.5
        if not 0.5 < n < 2.0:
            raise ValueError(f"initial_quat must be (close to) a unit quaternion, norm is {n:.3g}")
        return tuple(v / n for v in q)


class PipelineConfig(FilterConfig):
    """A filter composed from plugins: one estimator, correctors and detectors, plus alignment.

    Per sample the pipeline runs, in this order: detectors -> alignment or propagation ->
    correctors (see :mod:`fusionkit.pipeline`).
    """

    estimator: PluginSpec = param(..., unit="-", description="the estimator (owns the orientation state)")
    correctors: list[PluginSpec] = param([], unit="-", description="correctors, applied in this order")
    detectors: list[PluginSpec] = param([], unit="-", description="detectors, run first on every sample")
    alignment: AlignmentConfig = param(AlignmentConfig(), unit="-", description="initial alignment")

    @field_validator("estimator", mode="before")
    @classmethod
    def _est(cls, v):
        return PluginSpec.coerce(v)

    @field_validator("correctors", "detectors", mode="before")
    @classmethod
    def _lst(cls, v):
        return [PluginSpec.coerce(x) for x in v] if isinstance(v, (list, tuple)) else v


def set_dotted(d: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    """``set_dotted(d, "motion.window", 0.2)`` sets ``d["motion"]["window"]`` (creating levels)."""
    parts = key.split(".")
    node = d
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    node[parts[-1]] = value
    return d


def _format_validation(where: str, exc: ValidationError) -> str:
    lines = [f"invalid configuration for {where}:"]
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"]) or "(root)"
        if err["type"] == "extra_forbidden":
            lines.append(f"  {loc}: unknown parameter")
        else:
            lines.append(f"  {loc}: {err['msg']} (got {err.get('input')!r})")
    return "\n".join(lines)


def build_config(cls: type[PluginConfig], config: Any = None, params: Mapping[str, Any] | None = None,
                 where: str = "") -> PluginConfig:
    """Validate ``config`` (a model, a mapping or None) updated with ``params`` into ``cls``."""
    data: dict[str, Any] = {}
    if isinstance(config, BaseModel):
        if not isinstance(config, cls):
            raise ConfigError(f"{where}: expected a {cls.__name__}, got {type(config).__name__}")
        if not params:
            return config
        data = config.model_dump()
    elif isinstance(config, Mapping):
        data = dict(config)
    elif config is not None:
        raise ConfigError(f"{where}: config must be a {cls.__name__} or a mapping, got {type(config).__name__}")
    data.update(params or {})
    try:
        return cls(**data)
    except ValidationError as exc:
        raise ConfigError(_format_validation(where or cls.__name__, exc)) from None


def load_config(source: Any) -> dict[str, Any]:
    """Read a config from a dict, a JSON or TOML file path, or a JSON/TOML string."""
    if isinstance(source, Mapping):
        return dict(source)
    text: str
    suffix = ""
    if isinstance(source, Path) or (isinstance(source, str) and "\n" not in source and Path(source).suffix in (".json", ".toml")):
        path = Path(source)
        if not path.is_file():
            raise ConfigError(f"config file {str(path)!r} does not exist")
        text, suffix = path.read_text(), path.suffix
    elif isinstance(source, str):
        text = source
    else:
        raise ConfigError(f"config must be a mapping, a path or a string, got {type(source).__name__}")
    if suffix == ".json" or (not suffix and text.lstrip().startswith("{")):
        try:
            return json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"config is not valid JSON: {exc}") from None
    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config is not valid TOML: {exc}") from None


_OPS = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}


def _constraint_text(m: Any) -> str:
    for attr, op in _OPS.items():
        if getattr(m, attr, None) is not None:
            return f"{op} {getattr(m, attr)}"
    return str(m)


def describe_config(cls: type[PluginConfig]) -> list[dict[str, Any]]:
    """One dict per field: name, default, unit, description, constraints."""
    rows = []
    for name, f in cls.model_fields.items():
        extra = f.json_schema_extra if isinstance(f.json_schema_extra, dict) else {}
        constraints = [_constraint_text(m) for m in f.metadata]
        default = f.default
        if isinstance(default, BaseModel):
            default = default.model_dump()
        rows.append(
            {
                "name": name,
                "default": "(required)" if f.is_required() else default,
                "unit": extra.get("unit", "-"),
                "description": f.description or "",
                "constraints": ", ".join(constraints),
                "type": getattr(f.annotation, "__name__", str(f.annotation)).replace("typing.", ""),
            }
        )
    return rows
