"""Plugin discovery through entry points, one group per kind.

Groups: ``fusionkit.filters``, ``fusionkit.estimators``, ``fusionkit.correctors``,
``fusionkit.detectors``. fusionkit's own plugins are registered in its ``pyproject.toml``
exactly as a third party registers them::

    [project.entry-points."fusionkit.filters"]
    my-filter = "my_package.module:MyFilter"

Discovery is lazy: importing fusionkit loads no plugin; the entry points are read on the first
look-up, and a plugin module is imported only when that plugin is used. A plugin that fails to
import is reported with its distribution and does not break the others. Two plugins with the
same name in one kind are an error that names both.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from .config import describe_config
from .errors import PluginError
from .protocols import KINDS, Plugin

__all__ = ["Registry", "PluginInfo", "default_registry", "available", "make", "describe", "register", "get"]

GROUPS = {kind: f"fusionkit.{kind}s" for kind in KINDS}


@dataclass
class _Entry:
    name: str
    kind: str
    target: str  # "module:attr" or "<registered>"
    distribution: str
    loader: Any  # EntryPoint, or the class itself when registered in code
    cls: type | None = None
    error: str | None = None


@dataclass
class PluginInfo:
    """What :func:`describe` returns; ``str()`` gives a readable page."""

    name: str
    kind: str
    summary: str
    source: str
    distribution: str
    target: str
    parameters: list[dict[str, Any]] = field(default_factory=list)
    #: a preset's composition with its default config (one line per stage), empty for other plugins
    composition: list[str] = field(default_factory=list)

    def __str__(self) -> str:
        lines = [f"{self.name} ({self.kind}) from {self.distribution} [{self.target}]"]
        if self.summary:
            lines.append(f"  {self.summary}")
        if self.source:
            lines.append(f"  source: {self.source}")
        if self.parameters:
            lines.append("  parameters:")
            for p in self.parameters:
                unit = "" if p["unit"] in ("-", "") else f" [{p['unit']}]"
                cons = f" ({p['constraints']})" if p["constraints"] else ""
                lines.append(f"    {p['name']} = {p['default']!r}{unit}{cons}")
                if p["description"]:
                    lines.append(f"        {p['description']}")
        if self.composition:
            lines.append("  composition (with the defaults):")
            lines += [f"    {c}" for c in self.composition]
        return "\n".join(lines)


class Registry:
    """Name -> plugin class, per kind, discovered from entry points (plus :meth:`register`)."""

    def __init__(self, use_entry_points: bool = True) -> None:
        self._use_entry_points = use_entry_points
        self._entries: dict[str, dict[str, _Entry]] | None = None
        self._extra: list[_Entry] = []

    # -- discovery -------------------------------------------------------------------------
    def refresh(self) -> None:
        """Forget what was discovered (after installing a plugin package at run time)."""
        self._entries = None

    def _discover(self) -> dict[str, dict[str, _Entry]]:
        if self._entries is not None:
            return self._entries
        entries: dict[str, dict[str, _Entry]] = {kind: {} for kind in KINDS}
        found: list[_Entry] = []
        if self._use_entry_points:
            for kind, group in GROUPS.items():
                for ep in metadata.entry_points(group=group):
                    dist = ep.dist.name if ep.dist is not None else "<unknown distribution>"
                    found.append(_Entry(ep.name, kind, ep.value, dist, ep))
        found.extend(self._extra)
        for e in found:
            other = entries[e.kind].get(e.name)
            if other is not None and (other.target, other.distribution) != (e.target, e.distribution):
                raise PluginError(
                    f"duplicate {e.kind} name {e.name!r}: {other.target} from {other.distribution} "
                    f"and {e.target} from {e.distribution}; uninstall one or rename it"
                )
            entries[e.kind][e.name] = e
        self._entries = entries
        return entries

    def register(self, cls: type[Plugin], distribution: str = "<registered in code>") -> type[Plugin]:
        """Register a plugin class without packaging it (also usable as a decorator)."""
        if not (isinstance(cls, type) and issubclass(cls, Plugin)) or cls.kind not in KINDS or not cls.name:
            raise PluginError(f"{cls!r} is not a plugin class with a name and a kind in {KINDS}")
        self._extra.append(_Entry(cls.name, cls.kind, f"{cls.__module__}:{cls.__qualname__}", distribution, None, cls))
        self._entries = None
        return cls

    # -- look-up ---------------------------------------------------------------------------
    def names(self, kind: str | None = None) -> list[str]:
        entries = self._discover()
        kinds = KINDS if kind is None else (self._check_kind(kind),)
        return sorted(n for k in kinds for n in entries[k])

    def available(self) -> dict[str, list[str]]:
        """``{kind: [names]}`` for every kind (plural keys: 'filters', 'detectors', ...)."""
        return {f"{k}s": self.names(k) for k in KINDS}

    def _check_kind(self, kind: str) -> str:
        kind = kind[:-1] if kind.endswith("s") and kind[:-1] in KINDS else kind
        if kind not in KINDS:
            raise PluginError(f"kind must be one of {KINDS}, got {kind!r}")
        return kind

    def _find(self, name: str, kind: str | None) -> _Entry:
        entries = self._discover()
        if kind is not None:
            kind = self._check_kind(kind)
            if name in entries[kind]:
                return entries[kind][name]
            pool = list(entries[kind])
        else:
            if name in entries["filter"]:
                return entries["filter"][name]
            hits = [entries[k][name] for k in KINDS if name in entries[k]]
            if len(hits) == 1:
                return hits[0]
            if len(hits) > 1:
                raise PluginError(
                    f"{name!r} is a plugin of several kinds ({', '.join(h.kind for h in hits)}): pass kind="
                )
            pool = [n for k in KINDS for n in entries[k]]
        close = difflib.get_close_matches(name, pool, n=4, cutoff=0.5)
        hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        where = f"{kind} " if kind else ""
        if not any(entries.values()):
            hint += " (no plugins are registered at all: is fusionkit installed, e.g. `pip install -e .`?)"
        raise PluginError(f"unknown {where}plugin {name!r}{hint} Known: {', '.join(sorted(set(pool))) or 'none'}")

    def _load(self, entry: _Entry) -> type[Plugin]:
        if entry.cls is not None:
            return entry.cls
        if entry.error is not None:
            raise PluginError(entry.error)
        try:
            cls = entry.loader.load()
        except Exception as exc:  # any import-time failure of a third-party module
            entry.error = (
                f"{entry.kind} plugin {entry.name!r} from distribution {entry.distribution!r} "
                f"({entry.target}) failed to load: {type(exc).__name__}: {exc}"
            )
            raise PluginError(entry.error) from exc
        if not (isinstance(cls, type) and issubclass(cls, Plugin)) or cls.kind != entry.kind:
            entry.error = (
                f"{entry.kind} plugin {entry.name!r} from distribution {entry.distribution!r} "
                f"({entry.target}) is not a fusionkit {entry.kind} class"
            )
            raise PluginError(entry.error)
        entry.cls = cls
        return cls

    def get(self, name: str, kind: str | None = None) -> type[Plugin]:
        """The plugin class registered as ``name`` (a filter first, unless ``kind`` is given)."""
        return self._load(self._find(name, kind))

    def make(self, name: str, kind: str | None = None, config: Any = None, **params: Any) -> Plugin:
        """Instantiate the plugin ``name`` with validated parameters."""
        return self.get(name, kind)(config, **params)

    def describe(self, name: str, kind: str | None = None) -> PluginInfo:
        entry = self._find(name, kind)
        cls = self._load(entry)
        return PluginInfo(
            name=entry.name, kind=entry.kind, summary=cls.summary, source=cls.source,
            distribution=entry.distribution, target=entry.target, parameters=describe_config(cls.Config),
            composition=_composition(cls),
        )

    def check_all(self) -> dict[str, str]:
        """Load every plugin; return ``{"kind:name": error}`` for those that fail."""
        errors = {}
        for kind, entries in self._discover().items():
            for e in entries.values():
                try:
                    self._load(e)
                except PluginError as exc:
                    errors[f"{kind}:{e.name}"] = str(exc)
        return errors

    def info(self) -> list[tuple[str, str, str]]:
        """``(kind, name, distribution)`` of every registered plugin, without loading them."""
        return [(k, n, e.distribution) for k, es in self._discover().items() for n, e in sorted(es.items())]


def _composition(cls) -> list[str]:
    """The stages of a preset (a filter that builds a pipeline from its own config) with defaults."""
    from .pipeline import Pipeline

    if not (isinstance(cls, type) and issubclass(cls, Pipeline)) or cls.pipeline_config is Pipeline.pipeline_config:
        return []
    spec = cls().spec
    lines = [f"estimator: {spec.estimator.name} {spec.estimator.params}"]
    lines += [f"corrector: {c.name} {c.params}" for c in spec.correctors]
    lines += [f"detector: {d.name} {d.params}" for d in spec.detectors]
    lines.append(f"alignment: {spec.alignment.model_dump()}")
    return lines


_DEFAULT = Registry()


def default_registry() -> Registry:
    """The process-wide registry used by :func:`make`, :func:`available` and :func:`describe`."""
    return _DEFAULT


def available(kind: str | None = None):
    """Registered plugin names: ``{'filters': [...], ...}``, or a list for one ``kind``."""
    return _DEFAULT.available() if kind is None else _DEFAULT.names(kind)


def make(name: str, kind: str | None = None, config: Any = None, **params: Any) -> Plugin:
    """Build a plugin by name: ``make("poisson", frame="NED")``. A filter name is resolved first;
    pass ``kind="detector"`` (etc.) for the other kinds. Parameters are validated."""
    return _DEFAULT.make(name, kind, config, **params)


def get(name: str, kind: str | None = None) -> type[Plugin]:
    return _DEFAULT.get(name, kind)


def describe(name: str, kind: str | None = None) -> PluginInfo:
    """Parameters (default, unit, description), summary and source document of a plugin."""
    return _DEFAULT.describe(name, kind)


def register(cls: type[Plugin]) -> type[Plugin]:
    """Register a plugin class in the default registry from code (a decorator)."""
    return _DEFAULT.register(cls)
