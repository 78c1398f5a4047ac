"""Configuration models (pydantic 2) and their loading from dicts, JSON and TOML.

Every plugin has a ``Config``: a frozen :class:`PluginConfig` with ``extra="forbid"``, ranges
checked, defaults equal to the source document's values, and a description and unit per field
(declared with :func:`param`). Validation failures raise :class:`~fusionkit.errors.ConfigError`
with pydantic's message (which names the field, the value and the rule).
"""

from __future__ import annotations

import json
import os
import reprlib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError, field_validator

from .conventions import FRAMES, check_body
from .errors import ConfigError

__all__ = [
    "PluginConfig",
    "FilterConfig",
    "BodyAxes",
    "PluginSpec",
    "AlignmentConfig",
    "PipelineConfig",
    "param",
    "build_config",
    "load_config",
    "config_file",
    "CONFIG_SUFFIXES",
    "describe_config",
    "set_dotted",
]


def param(default: Any, *, unit: str, description: str, **constraints: Any) -> Any:
    """A config field with its default, unit ("-" for none) and description."""
    return Field(default, description=description, json_schema_extra={"unit": unit}, **constraints)


class PluginConfig(BaseModel):
    """Base of every plugin configuration: frozen, unknown keys rejected, every number finite
    (``inf`` and NaN pass range checks such as ``gt=0`` and would reach the arithmetic)."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_number(cls, value: Any, info) -> Any:
        """A boolean where a number is expected is refused, alone or inside a tuple or list
        (pydantic takes True as 1, so ``tau_acc=True`` ran with 1 s)."""
        if _bool_for_number(cls.model_fields[info.field_name].annotation, value):
            raise ValueError("expected a number, got a boolean" if _is_bool(value)
                             else f"expected numbers, got a boolean in {value!r}")
        return value


def _is_bool(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def _alternatives(annotation: Any) -> tuple:
    """The types a field's annotation takes: unions flattened, ``Annotated[T, ...]`` as ``T``."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return _alternatives(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return tuple(a for arg in typing.get_args(annotation) for a in _alternatives(arg))
    return (annotation,)


def _number_not_bool(annotation: Any) -> bool:
    """Whether a field's type takes a number (float or int, alone or in a union) and no boolean."""
    args = _alternatives(annotation)
    return bool not in args and any(a in (float, int) for a in args)


def _bool_for_number(annotation: Any, value: Any) -> bool:
    """Whether ``value`` is, or (a tuple or list) holds, a boolean where ``annotation`` takes a
    number (``lever_arm=(True, 0, 0)`` ran with 1 m)."""
    if _is_bool(value):
        return _number_not_bool(annotation)
    if not isinstance(value, (tuple, list)):
        return False
    for alt in _alternatives(annotation):
        origin, args = typing.get_origin(alt), typing.get_args(alt)
        if origin not in (tuple, list) or not args:
            continue
        if origin is list or (len(args) == 2 and args[1] is Ellipsis):
            items = [args[0]] * len(value)
        else:
            items = args[:len(value)]
        if any(_bool_for_number(a, v) for a, v in zip(items, value)):
            return True
    return False


def _body(value: str | None) -> str | None:
    return None if value is None else check_body(value, error=ValueError)


#: a config field holding a body axis convention (``"FLU"``, ``"FRD"``, ...) or None
BodyAxes = Annotated[str | None, AfterValidator(_body)]


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
        None, unit="m/s^2", description="accelerometer range; samples at or above it are flagged ACC_SATURATED and "
        "not used for corrections (None: samples beyond 16 g are glitches, ACC_INVALID)", gt=0
    )
    max_gap: float | None = param(
        0.1, unit="s", description="a sample interval longer than this and than 5 nominal intervals is a timestamp "
        "gap: flagged GAP, the state held across it instead of integrating one gyro sample over it (None: integrate every "
        "interval as one step)", gt=0
    )
    body: BodyAxes = param(
        None, unit="-", description="the sensors' body axes ('FLU', 'FRD', 'RFU', ...); None: the recording's "
        "(Recording.body); one that contradicts the recording's is an error"
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
    attitude: Literal["mean", "first"] = param(
        "mean", unit="-", description="'mean': the attitude from the window's mean specific force (and field) (source "
        "000); 'first': from the first sample with a valid accelerometer (and its field), held while the window "
        "estimates the bias (source 002's start)")
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

    Per sample the pipeline runs, in this order: sensor models -> detectors -> alignment or
    propagation -> correctors (see :mod:`fusionkit.pipeline`).
    """

    estimator: PluginSpec = param(..., unit="-", description="the estimator (owns the orientation state)")
    correctors: list[PluginSpec] = param([], unit="-", description="correctors, applied in this order")
    detectors: list[PluginSpec] = param([], unit="-", description="detectors, run on every sample after the models")
    models: list[PluginSpec] = param(
        [], unit="-", description="sensor models (calibration, time offsets), applied first to every sample, in order")
    alignment: AlignmentConfig = param(AlignmentConfig(), unit="-", description="initial alignment")

    @field_validator("estimator", mode="before")
    @classmethod
    def _est(cls, v):
        return PluginSpec.coerce(v)

    @field_validator("correctors", "detectors", "models", mode="before")
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
            lines.append(f"  {loc}: {err['msg']} (got {reprlib.repr(err.get('input'))})")
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
    _check_depth(data, where or cls.__name__)
    try:
        return cls(**data)
    except ValidationError as exc:
        raise ConfigError(_format_validation(where or cls.__name__, exc)) from None


#: deeper nesting is not a configuration (a pipeline's deepest field is about 5 levels down): refused
#: before it can exhaust Python's recursion limit in a parser or validator
MAX_CONFIG_DEPTH = 32


#: the suffixes of the config files :func:`load_config` reads, in any case (``GD.TOML``)
CONFIG_SUFFIXES = (".toml", ".json")


def _looks_like_path(text: str) -> bool:
    """Whether a string given as a config names a file rather than holding config text: one line
    that names an existing file (``run=3/gd.toml`` too), or else is not JSON (``{``, ``[``), a TOML
    table or comment, nor a ``key = value`` line, and has a path separator or a suffix. Such a string
    can never be a valid config text, so reading it as one only gave "not valid TOML" for a file name."""
    t = text.strip()
    if not t or "\n" in text:
        return False
    p = Path(t)
    try:
        if p.expanduser().is_file():
            return True
    except (OSError, ValueError):  # a name too long, a NUL byte: not a file
        return False
    if t[0] in "{[#" or "=" in t:
        return False
    return bool(p.suffix) or any(sep and sep in t for sep in (os.sep, os.altsep, "/"))


def config_file(source: Any) -> Path | None:
    """The config file ``source`` names (a path, or a string that looks like one), checked: it
    exists and has a suffix of :data:`CONFIG_SUFFIXES` (any case); None for config text or a
    mapping. A ConfigError names the file and the suffixes read: ``GD.TOML`` and ``nosuch.yaml``
    were read as TOML text ("Expected '=' after a key")."""
    if isinstance(source, os.PathLike):
        path = Path(source)
    elif isinstance(source, str) and _looks_like_path(source):
        path = Path(source.strip())
    else:
        return None
    where = f"config file {str(path)!r}"
    supported = path.suffix.lower() in CONFIG_SUFFIXES
    formats = "fusionkit reads TOML (.toml) and JSON (.json) config files, the suffix in any case"
    try:
        exists = path.expanduser().exists()
    except (OSError, ValueError) as exc:  # a name too long, a NUL byte
        raise ConfigError(f"{where} cannot be read: {exc}") from None
    if not exists:
        raise ConfigError(f"{where} does not exist" + ("" if supported else f"; {formats}"))
    if path.expanduser().is_dir():
        raise ConfigError(f"{where} is a folder, not a config file")
    if not supported:
        what = f"has the suffix {path.suffix!r}" if path.suffix else "has no suffix"
        raise ConfigError(f"{where} {what}: {formats}")
    return path.expanduser()


def load_config(source: Any) -> dict[str, Any]:
    """Read a config from a dict, a JSON or TOML file path, or a JSON/TOML string.

    A path's suffix says its format (.toml or .json, any case: :func:`config_file`). Anything that
    is not a mapping of settings (a missing or unreadable file, another suffix, non-UTF-8, a syntax
    error, a JSON list, nesting deeper than :data:`MAX_CONFIG_DEPTH`) is a :class:`ConfigError`
    naming the file."""
    if isinstance(source, Mapping):
        return _check_depth(dict(source), "config")
    text: str
    suffix = ""
    path = config_file(source)
    if path is not None:
        where = f"config file {str(path)!r}"
        try:
            text, suffix = path.read_bytes().decode("utf-8-sig"), path.suffix.lower()
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{where} is not UTF-8 text ({exc})") from None
        except OSError as exc:
            raise ConfigError(f"{where} cannot be read: {exc.strerror or exc}") from None
    elif isinstance(source, str):
        text, where = source, "config"
    else:
        raise ConfigError(f"config must be a mapping, a path or a string, got {type(source).__name__}")
    head = text.lstrip()[:1]
    data: Any = None
    try:
        if suffix == ".json" or (not suffix and head in ("{", "[")):
            try:
                data = json.loads(text)
            except json.JSONDecodeError as exc:
                if suffix or head == "{":  # a string starting with "[" may be TOML ("[estimator]")
                    raise ConfigError(f"{where} is not valid JSON: {exc}") from None
        if data is None:
            try:
                import tomllib
            except ImportError:  # Python 3.10
                import tomli as tomllib  # type: ignore[no-redef]
            try:
                data = tomllib.loads(text)
            except tomllib.TOMLDecodeError as exc:
                raise ConfigError(f"{where} is not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{where} nests deeper than a configuration can (at most {MAX_CONFIG_DEPTH} levels)") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be an object of settings ({{\"estimator\": ...}} or name = value lines), "
                          f"got a JSON {type(data).__name__}")
    return _check_depth(data, where)


def _check_depth(data: dict[str, Any], where: str) -> dict[str, Any]:
    """``data`` unchanged, or a ConfigError naming the first path deeper than MAX_CONFIG_DEPTH."""
    todo: list[tuple[Any, str, int]] = [(data, "", 1)]
    while todo:
        node, at, depth = todo.pop()
        if depth > MAX_CONFIG_DEPTH:
            raise ConfigError(f"{where} nests deeper than a configuration can (at most {MAX_CONFIG_DEPTH} levels): "
                              f"{at[:80]}{'...' if len(at) > 80 else ''}")
        items = node.items() if isinstance(node, Mapping) else enumerate(node) if isinstance(node, (list, tuple)) else ()
        todo.extend((v, f"{at}.{k}" if at else str(k), depth + 1) for k, v in items)
    return data


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v == float("inf") else "-inf" if v == float("-inf") else repr(v))
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise ConfigError(f"cannot write {type(v).__name__} {v!r} as TOML")


def _toml_key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def to_toml(config: Mapping[str, Any]) -> str:
    """A config dict (:func:`load_config`'s layout) as TOML text that reads back to the same dict.

    TOML has no null: a ``None`` value is written as a comment (the key is left out, so the
    field takes its default; where that default is not None, use JSON instead, which has null).
    """
    lines: list[str] = []

    def table(prefix: str, d: Mapping[str, Any]) -> None:
        subs, arrays = [], []
        for k, v in d.items():
            if isinstance(v, Mapping):
                subs.append((k, v))
            elif isinstance(v, (list, tuple)) and v and all(isinstance(x, Mapping) for x in v):
                arrays.append((k, v))
            elif v is None:
                lines.append(f"# {_toml_key(k)} = None (TOML has no null: left out, the default applies)")
            else:
                lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
        for k, v in subs:
            name = f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k)
            lines.extend(["", f"[{name}]"])
            table(name, v)
        for k, v in arrays:
            name = f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k)
            for item in v:
                lines.extend(["", f"[[{name}]]"])
                table(name, item)

    table("", config)
    return "\n".join(lines).lstrip("\n") + "\n"


_OPS = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}


def _constraint_text(m: Any) -> str:
    """A bound as ``> 0``; "" for a validator function (``BodyAxes``' check: its repr, a function's
    address, was printed as the constraint; its description says what it takes)."""
    for attr, op in _OPS.items():
        if getattr(m, attr, None) is not None:
            return f"{op} {getattr(m, attr)}"
    return "" if callable(getattr(m, "func", None)) else str(m)


def describe_config(cls: type[PluginConfig]) -> list[dict[str, Any]]:
    """One dict per field: name, default, unit, description, constraints."""
    rows = []
    for name, f in cls.model_fields.items():
        extra = f.json_schema_extra if isinstance(f.json_schema_extra, dict) else {}
        constraints = [c for c in map(_constraint_text, f.metadata) if c]
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
