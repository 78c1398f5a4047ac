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
import warnings
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from .config import describe_config
from .errors import ConfigError, PluginError, PluginWarning
from .protocols import KINDS, Plugin, plugin_class_problem

__all__ = ["Registry", "PluginInfo", "default_registry", "available", "make", "describe", "register", "get"]

GROUPS = {kind: f"fusionkit.{kind}s" for kind in KINDS}
BUILTIN = "fusionkit"  # the distribution whose plugins win a name clash


@dataclass
class _Entry:
    name: str
    kind: str
    target: str  # "module:attr" or "<registered>"
    distribution: str
    loader: Any  # EntryPoint, or the class itself when registered in code
    cls: type | None = None
    error: str | None = None


def _same_class(a: _Entry, b: _Entry) -> bool:
    """Whether two entries of one name, one of them a class registered in code, are the same class:
    the other names the same ``module:class``, or is an entry point that loads to it. Registering a
    class that an installed entry point also finds made its name a "duplicate" and unusable; a
    different class under the name stays an error. Entry points alone are not loaded here."""
    coded = [e for e in (a, b) if e.cls is not None and e.loader is None and e.error is None]
    if not coded:
        return False
    other = b if coded[0] is a else a
    if other.error is not None:
        return False
    if other.cls is not None:
        return other.cls is coded[0].cls
    if other.target == coded[0].target:
        return True
    try:
        return other.loader.load() is coded[0].cls
    except KeyboardInterrupt:
        raise
    except BaseException:  # a module that fails to import is not this class (its error shows when it is used)
        return False


def _where(e: _Entry) -> str:
    """``module:attr from distribution`` (a name clash's entry already names all of its plugins)."""
    return e.target if e.error else f"{e.target} from {e.distribution}"


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
    #: for a filter that is a preset (a pipeline over plugins): its composition with the default
    #: parameters, as a :class:`~fusionkit.config.PipelineConfig` dict; None for other plugins
    composition: dict[str, Any] | None = None
    #: for a filter: "" when ``make(name, offline=True)`` runs it forward and backward in time
    #: (:mod:`fusionkit.offline`), else why it cannot; None for other kinds
    offline: str | None = None

    def config(self) -> dict[str, Any] | None:
        """For a filter, a config ``fusionkit run`` and :func:`fusionkit.compose` / ``make`` take:
        a preset's composition (change a plugin in it and run it), or ``{"filter": name,
        "params": defaults}`` for a monolithic filter; None for other kinds."""
        if self.kind != "filter":
            return None
        if self.composition is not None:
            return self.composition
        return {"filter": self.name, "params": {p["name"]: p["default"] for p in self.parameters}}

    def __str__(self) -> str:
        lines = [f"{self.name} ({self.kind}) from {self.distribution} [{self.target}]"]
        if self.summary:
            lines.append(f"  {self.summary}")
        if self.source:
            lines.append(f"  source: {self.source}")
        if self.composition is not None:
            c = self.composition
            lines.append("  composition (a preset: `fusionkit describe NAME --toml` prints it as a config to edit):")
            lines.append(f"    estimator: {_spec_text(c['estimator'])}")
            for key in ("models", "detectors", "correctors"):
                if c.get(key):
                    lines.append(f"    {key}: " + ", ".join(_spec_text(x) for x in c[key]))
            al = c.get("alignment", {})  # mode 'none' starts at once, from initial_quat: no duration, no heading
            timing = "" if al.get("mode") == "none" else f" ({al.get('duration')} s, heading {al.get('heading')})"
            lines.append(f"    alignment: {al.get('mode')}{timing}")
        if self.offline is not None:
            lines.append(f"  offline: make({self.name!r}, offline=True) runs it forward and backward in time "
                         "(fusionkit.offline)" if not self.offline else f"  offline: not supported: {self.offline}")
        if self.parameters:
            lines.append("  parameters:")
            for p in self.parameters:
                unit = "" if p["unit"] in ("-", "") else f" [{p['unit']}]"
                cons = f" ({p['constraints']})" if p["constraints"] else ""
                lines.append(f"    {p['name']} = {p['default']!r}{unit}{cons}")
                if p["description"]:
                    lines.append(f"        {p['description']}")
        return "\n".join(lines)


#: where a plugin of each kind goes: "unknown corrector plugin 'rest'" did not say that 'rest' is a detector
_PLACE = {
    "filter": "{name!r} is a filter, not a part of a composition: build it with make({name!r})",
    "estimator": "{name!r} is an estimator: give it as a composition's estimator",
    "corrector": "{name!r} is a corrector: in a composition list it under correctors",
    "detector": "{name!r} is a detector: in a composition list it under detectors",
    "model": "{name!r} is a sensor model: in a composition list it under models",
}


def _spec_text(spec: dict[str, Any]) -> str:
    params = ", ".join(f"{k}={v!r}" for k, v in spec.get("params", {}).items())
    return f"{spec['name']}({params})" if params else spec["name"]


class Registry:
    """Name -> plugin class, per kind, discovered from entry points (plus :meth:`register`)."""

    def __init__(self, use_entry_points: bool = True) -> None:
        self._use_entry_points = use_entry_points
        self._entries: dict[str, dict[str, _Entry]] | None = None
        self._extra: list[_Entry] = []
        self.duplicates: list[str] = []  #: third-party plugins shadowed by a built-in of the same name

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
            # one scan of the installed distributions for every group (each scan reads every
            # distribution's entry points), and each distribution's name read once (it parses
            # the distribution's metadata file)
            eps, names = metadata.entry_points(), {}
            for kind, group in GROUPS.items():
                for ep in eps.select(group=group):
                    if ep.dist is None:
                        dist = "<unknown distribution>"
                    elif id(ep.dist) in names:
                        dist = names[id(ep.dist)]
                    else:
                        dist = names[id(ep.dist)] = ep.dist.name
                    found.append(_Entry(ep.name, kind, ep.value, dist, ep))
        found.extend(self._extra)
        duplicates = []
        for e in found:
            other = entries[e.kind].get(e.name)
            if other is None or (other.target, other.distribution) == (e.target, e.distribution):
                entries[e.kind][e.name] = e
                continue
            if _same_class(other, e):  # a class registered in code that an entry point names too: one plugin
                keep = e if other.loader is None else other  # the entry point's: it names the distribution
                keep.cls = keep.cls or other.cls or e.cls
                entries[e.kind][e.name] = keep
                continue
            if BUILTIN in (other.distribution, e.distribution) and other.distribution != e.distribution:
                builtin, shadowed = (other, e) if other.distribution == BUILTIN else (e, other)
                entries[e.kind][e.name] = builtin
                duplicates.append(
                    f"{e.kind} {e.name!r}: {_where(shadowed)} is ignored, the built-in "
                    f"{builtin.target} from {BUILTIN} is used; rename the third-party plugin"
                )
                continue
            # two third-party plugins: an entry that fails to load, naming all of them
            both = f"{_where(other)} and {_where(e)}"
            entries[e.kind][e.name] = _Entry(
                e.name, e.kind, both, f"{other.distribution}, {e.distribution}", None,
                error=f"duplicate {e.kind} name {e.name!r}: {both}; uninstall one or rename it")
        for msg in duplicates:
            if msg not in self.duplicates:
                warnings.warn(f"duplicate plugin name: {msg}", PluginWarning, stacklevel=3)
        self.duplicates = duplicates
        self._entries = entries
        return entries

    def register(self, cls: type[Plugin], distribution: str = "<registered in code>") -> type[Plugin]:
        """Register a plugin class without packaging it (also usable as a decorator)."""
        problem = plugin_class_problem(cls)  # (one that only said kind="filter" had no run(): taken, failed on use)
        if problem is not None:
            raise PluginError(f"cannot register {cls!r}: {problem}")
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
        if not isinstance(kind, str):  # (make("x", {...}): the parameters passed where the kind goes)
            raise PluginError(f"kind must be one of {KINDS}, got {kind!r:.80}; a plugin's parameters are keywords "
                              "(make(name, tau=1.0)) or config=")
        kind = kind[:-1] if kind.endswith("s") and kind[:-1] in KINDS else kind
        if kind not in KINDS:
            raise PluginError(f"kind must be one of {KINDS}, got {kind!r}")
        return kind

    def _find(self, name: str, kind: str | None) -> _Entry:
        if not isinstance(name, str):
            raise PluginError(f"a plugin name is a string such as 'recommended', got {name!r:.80}")
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
        if kind is not None:  # a plugin of another kind in the wrong list: say what it is and where it goes
            other = [_PLACE[k].format(name=name) for k in KINDS if k != kind and name in entries[k]]
            if other:
                hint = f" ({'; '.join(other)}){hint}"
        if not any(entries.values()):
            hint += " (no plugins are registered at all: is fusionkit installed, e.g. `pip install -e .`?)"
        end = "" if close else "."  # (without a suggestion it read "unknown plugin 'nosuch' Known: ...")
        raise PluginError(f"unknown {where}plugin {name!r}{hint}{end} Known: {', '.join(sorted(set(pool))) or 'none'}")

    def _load(self, entry: _Entry) -> type[Plugin]:
        if entry.cls is not None:
            return entry.cls
        if entry.error is not None:
            raise PluginError(entry.error)
        try:
            cls = entry.loader.load()
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # any import-time failure of a third-party module, sys.exit() too
            entry.error = (
                f"{entry.kind} plugin {entry.name!r} from distribution {entry.distribution!r} "
                f"({entry.target}) failed to load: {type(exc).__name__}: {exc}"
            )
            raise PluginError(entry.error) from exc
        problem = plugin_class_problem(cls)
        if problem is not None or cls.kind != entry.kind:
            entry.error = (
                f"{entry.kind} plugin {entry.name!r} from distribution {entry.distribution!r} "
                f"({entry.target}) is not a fusionkit {entry.kind} class" + (f": {problem}" if problem else "")
            )
            raise PluginError(entry.error)
        entry.cls = cls
        return cls

    def get(self, name: str, kind: str | None = None) -> type[Plugin]:
        """The plugin class registered as ``name`` (a filter first, unless ``kind`` is given)."""
        return self._load(self._find(name, kind))

    def make(self, name: str, /, kind: str | None = None, config: Any = None, *, offline: bool = False,
             **params: Any) -> Plugin:
        """Instantiate the plugin ``name`` with validated parameters (a parameter called ``name``
        is a parameter, refused by the config as unknown, not a second plugin name). ``offline``:
        the filter run forward and backward in time (:class:`fusionkit.offline.OfflineFilter`);
        a PluginError for a plugin that is not a filter or a filter that does not support it, a
        ConfigError for anything but True or False (``offline="no"`` is a non-empty string: true).
        With ``offline=True`` the offline mode's own options (``OfflineFilter.OPTIONS``:
        ``disturbance_gap``, ``inclination``, ...) go to it and the other parameters to the filter
        (they could be set only as ``OfflineFilter(make(name), option=...)``); a filter parameter
        of the same name would be ambiguous and is a ConfigError."""
        if type(offline).__name__ not in ("bool", "bool_"):  # Python's or numpy's, without importing numpy
            raise ConfigError(f"offline must be True or False, got {offline!r:.80}")
        cls = self.get(name, kind)
        fields = getattr(getattr(cls, "Config", None), "model_fields", {})
        if not offline:
            try:
                return cls(config, **params)
            except ConfigError as exc:  # an offline option without offline=True: said where it belongs
                from .offline import OfflineFilter

                stray = [k for k in params if k in OfflineFilter.OPTIONS and k not in fields]
                if cls.kind != "filter" or not stray:
                    raise
                raise ConfigError(f"{exc}\n  ({stray[0]!r} is an option of the offline mode: "
                                  f"make({name!r}, offline=True, {stray[0]}=...))") from None
        from .offline import OfflineFilter

        options = {k: params.pop(k) for k in OfflineFilter.OPTIONS if k in params}
        if cls.kind != "filter":
            raise PluginError(f"offline=True is for filters; {name!r} is a {cls.kind}")
        both = [k for k in options if k in fields]
        if both:
            raise ConfigError(f"{', '.join(map(repr, both))} is both a parameter of {name!r} and an option of the "
                              f"offline mode: set the offline one as OfflineFilter(make({name!r}, ...), "
                              f"{both[0]}=...)")
        return OfflineFilter(cls(config, **params), **options)

    def describe(self, name: str, kind: str | None = None) -> PluginInfo:
        entry = self._find(name, kind)
        cls = self._load(entry)
        composition = None
        if entry.kind == "filter" and hasattr(cls, "pipeline_config") and entry.name != "pipeline":
            composition = cls(registry=self).pipeline_config().model_dump()
        offline = None
        if entry.kind == "filter" and entry.name != "pipeline":
            from .offline import supports_offline

            try:
                offline = supports_offline(cls()) or ""
            except Exception:  # noqa: BLE001 (a filter that does not build with its defaults: not said)
                offline = None
        return PluginInfo(
            name=entry.name, kind=entry.kind, summary=cls.summary, source=cls.source,
            distribution=entry.distribution, target=entry.target, parameters=describe_config(cls.Config),
            composition=composition, offline=offline,
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


_DEFAULT = Registry()


def default_registry() -> Registry:
    """The process-wide registry used by :func:`make`, :func:`available` and :func:`describe`."""
    return _DEFAULT


def available(kind: str | None = None):
    """Registered plugin names: ``{'filters': [...], ...}``, or a list for one ``kind``."""
    return _DEFAULT.available() if kind is None else _DEFAULT.names(kind)


def make(name: str, /, kind: str | None = None, config: Any = None, *, offline: bool = False,
         **params: Any) -> Plugin:
    """Build a plugin by name: ``make("poisson", frame="NED")``. A filter name is resolved first;
    pass ``kind="detector"`` (etc.) for the other kinds. Parameters are validated.
    ``offline=True``: the filter run forward and backward in time, for recordings processed after
    the fact (:mod:`fusionkit.offline`; filters that support it, e.g. ``recommended``); the offline
    mode's own options go with it: ``make("recommended", offline=True, disturbance_gap=None)``."""
    return _DEFAULT.make(name, kind, config, offline=offline, **params)


def get(name: str, kind: str | None = None) -> type[Plugin]:
    return _DEFAULT.get(name, kind)


def describe(name: str, kind: str | None = None) -> PluginInfo:
    """Parameters (default, unit, description), summary and source document of a plugin."""
    return _DEFAULT.describe(name, kind)


def register(cls: type[Plugin]) -> type[Plugin]:
    """Register a plugin class in the default registry from code (a decorator)."""
    return _DEFAULT.register(cls)
