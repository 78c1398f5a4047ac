"""Run filters over trials side by side: in-process, in a process pool, or on a Dask cluster.

``bench(filters, data)`` returns a :class:`BenchResult` of records, one per (filter, trial)::

    {"filter": label, "name": registered name, "params": {...}, "config": full config,
     "trial": ..., "dataset": ..., "groups": [...], "dimension": "6D" | "9D",
     "reference": None | "ground truth" | "autopilot estimate" | ...,
     "metrics": {...}, "samples": N, "seconds": ..., "samples_per_s": ...,
     "backend": ..., "versions": {...}, "error": None | "Type: message", "cached": bool,
     "skipped": None | reason (e.g. a GNSS-aided filter on a recording without GNSS)}

Results are cached by a hash of (filter, full config, trial file fingerprint, versions, the code
that runs) in ``$FUSIONKIT_CACHE`` (default ``~/.cache/fusionkit``), so a re-run is instant. The
code is fusionkit's own source files and, for a third-party plugin (the filter, or a plugin a
pipeline composes), its distribution, version and source files (``versions["plugins"]``): fixing
a plugin re-runs it. A record read from the cache has ``cached`` True, and tables mark it ``*``.
A filter that raises on one trial gives a record with ``error`` set; the others continue.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import sys
import time
import traceback
from collections.abc import Iterable, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import set_dotted
from ..errors import ConfigError
from .datasets import Trial, discover
from .metrics import trial_metrics

__all__ = ["FilterSpec", "bench", "evaluate", "BenchResult"]


@dataclass(frozen=True)
class FilterSpec:
    """A filter by registered name with parameters, shown as ``label`` in tables."""

    name: str
    params: tuple = ()  # sorted (key, value) pairs, hashable
    label: str = ""

    @classmethod
    def of(cls, item: Any, params: Mapping[str, Any] | None = None) -> "FilterSpec":
        if isinstance(item, FilterSpec):
            return item
        if isinstance(item, (tuple, list)):
            name, p = item[0], dict(item[1])
        else:
            name, p = str(item), {}
        p.update(params or {})
        label = name if not p else f"{name}[{','.join(f'{k}={v}' for k, v in sorted(p.items()))}]"
        return cls(name, tuple(sorted((k, _freeze(v)) for k, v in p.items())), label)

    @property
    def kwargs(self) -> dict[str, Any]:
        return {k: _thaw(v) for k, v in self.params}

    def build(self):
        from ..registry import make

        return make(self.name, kind="filter", **self.kwargs)


def _freeze(v):
    return json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else v


def _thaw(v):
    if isinstance(v, str) and v[:1] in "[{":
        return json.loads(v)
    return v


@functools.lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    """A hash of fusionkit's own source files: a code change invalidates cached results even
    when the version number did not change (development installs)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:12]


@functools.lru_cache(maxsize=1)
def _distributions() -> dict[str, list[str]]:
    from importlib import metadata

    return metadata.packages_distributions()


def _source_files(top: str) -> list[Path]:
    """The ``.py`` files of the top-level module or package ``top`` (empty if it has none)."""
    mod = sys.modules.get(top)
    paths = list(getattr(mod, "__path__", []) or [])
    if paths:
        return sorted(f for d in paths for f in Path(d).rglob("*.py"))
    file = getattr(mod, "__file__", None)
    return [Path(file)] if file else []


def _plugin_code(f) -> dict[str, str] | None:
    """``{top-level module: "distribution version sha"}`` of the code outside fusionkit that the
    built filter ``f`` runs: the modules of its class and of the plugins it holds (a pipeline's
    estimator, correctors and detectors), with their base classes. None when a module's source
    cannot be found (a class typed into a console): such a filter is never cached."""
    from ..protocols import Plugin

    seen: set[int] = set()
    todo, tops = [f], set()
    while todo:
        obj = todo.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        tops.update(c.__module__.partition(".")[0] for c in type(obj).__mro__)
        for v in vars(obj).values():
            todo.extend(x for x in (v if isinstance(v, (list, tuple)) else [v]) if isinstance(x, Plugin))
    out = {}
    for top in sorted(tops - {"fusionkit", "builtins"} - set(sys.stdlib_module_names)):
        files = _source_files(top)
        if not files:
            return None
        h = hashlib.sha256()
        for file in files:
            h.update(str(file).encode())
            h.update(file.read_bytes())
        dists = _distributions().get(top, [])
        version = ",".join(f"{d} {_version_of(d)}" for d in dists) or "(no distribution)"
        out[top] = f"{version} {h.hexdigest()[:12]}"
    return out


def _version_of(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "?"


def _versions() -> dict[str, str]:
    import numpy

    from .. import __version__

    out = {"fusionkit": __version__, "fusionkit_code": _code_fingerprint(), "numpy": numpy.__version__,
           "python": sys.version.split()[0]}
    try:
        import numba

        out["numba"] = numba.__version__
    except ImportError:  # pragma: no cover
        pass
    return out


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def evaluate(spec: FilterSpec, trial: Trial, warmup: bool = True) -> dict[str, Any]:
    """Run one filter on one trial; never raises (errors go into the record)."""
    rec_out: dict[str, Any] = {
        "filter": spec.label, "name": spec.name, "params": spec.kwargs, "config": None, "trial": trial.name,
        "dataset": trial.dataset, "groups": list(trial.groups), "dimension": None, "metrics": {}, "samples": None,
        "reference": None, "seconds": None, "samples_per_s": None, "skipped": None, "backend": None, "versions": _versions(), "error": None,
        "cached": False,
    }
    try:
        f = spec.build()
        rec_out["config"] = f.config.model_dump(mode="json")
        code = _plugin_code(f)
        if code:  # third-party code: which distribution, version and source produced the numbers
            rec_out["versions"] = {**rec_out["versions"], "plugins": code}
        rec = trial.load()
        rec_out["samples"] = len(rec)
        if f.requires_gnss and rec.gnss is None:
            rec_out["skipped"] = "not applicable: the filter needs a GNSS stream"
            return _jsonable(rec_out)
        rec_out["dimension"] = f.dimension(rec)
        rec_out["reference"] = None if rec.truth is None else rec.meta.get("truth_kind", "ground truth")
        if warmup:  # compile numba loops outside the timing
            f.run(rec.slice(0, min(len(rec), 200)), progress=False)
        t0 = time.perf_counter()
        res = f.run(rec, progress=False)
        rec_out["seconds"] = time.perf_counter() - t0
        rec_out["samples_per_s"] = len(rec) / rec_out["seconds"]
        rec_out["backend"] = res.diagnostics.get("backend")
        rec_out["metrics"] = trial_metrics(res, rec, rec_out["dimension"])
    except Exception as exc:  # a filter failing on one trial must not stop the bench
        rec_out["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0]
        rec_out["traceback"] = traceback.format_exc(limit=4)
    return _jsonable(rec_out)


def _cache_dir(cache_dir) -> Path:
    d = Path(cache_dir or os.environ.get("FUSIONKIT_CACHE") or Path.home() / ".cache" / "fusionkit") / "bench"
    d.mkdir(parents=True, exist_ok=True)
    return d


def _spec_key(spec: FilterSpec) -> str:
    """The part of the cache key that does not depend on the trial; "" for a filter that cannot
    be cached (it does not build, or its source cannot be found)."""
    try:
        f = spec.build()
        cfg = f.config.model_dump(mode="json")
        code = _plugin_code(f)
    except Exception:  # unbuildable: never cached
        return ""
    if code is None:
        return ""
    blob = json.dumps({"name": spec.name, "config": cfg, "v": _versions(), "plugins": code,
                       "peer": _peer_version(spec.name)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _key(spec_key: str, trial: Trial) -> str:
    return hashlib.sha256(f"{spec_key}:{trial.fingerprint}".encode()).hexdigest()[:32] if spec_key else ""


def _peer_version(name: str) -> str:
    """A peer adapter's package version ("" for fusionkit's own filters)."""
    from ..registry import get

    cls = get(name, "filter")
    return cls.version() if getattr(cls, "package", "") else ""


def bench(filters: Iterable[Any], data: Any, *, trials: list[str] | None = None,
          params: Mapping[str, Any] | None = None, jobs: int = 1, cache: bool = True, cache_dir=None,
          scheduler: str | None = None, progress: bool | None = None) -> "BenchResult":
    """Run ``filters`` (names, ``(name, params)`` pairs or :class:`FilterSpec`) on the trials in
    ``data`` (a folder, a file, or a list of :class:`Trial`).

    ``params``: ``{"field": value}`` applied to every filter whose config has the field, or
    ``{"filter.field": value}`` for one filter. ``jobs`` > 1 runs trials in a process pool;
    ``scheduler`` sends the work to a Dask distributed scheduler at that address instead.
    """
    from ..registry import get

    specs = _apply_params([FilterSpec.of(f) for f in filters], params or {})
    for s in specs:
        get(s.name, "filter")  # unknown names fail now, with close matches
    trial_list = list(data) if isinstance(data, (list, tuple)) else discover(data, trials)
    tasks = [(s, t) for s in specs for t in trial_list]
    records: list[dict | None] = [None] * len(tasks)
    cdir = _cache_dir(cache_dir) if cache else None
    keys = [""] * len(tasks)
    spec_keys = {s: _spec_key(s) for s in specs} if cdir is not None else {}
    todo = []
    for i, (s, t) in enumerate(tasks):
        if cdir is not None:
            keys[i] = _key(spec_keys[s], t)
            if keys[i]:
                hit = cdir / f"{keys[i]}.json"
                if hit.is_file():
                    records[i] = {**json.loads(hit.read_text()), "cached": True}
                    continue
        todo.append(i)
    bar = _bar(len(todo), progress)
    for i, rec in _execute([tasks[i] for i in todo], todo, jobs, scheduler):
        records[i] = rec
        if cdir is not None and keys[i] and rec["error"] is None:
            (cdir / f"{keys[i]}.json").write_text(json.dumps(rec))
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return BenchResult([r for r in records if r is not None])


def _apply_params(specs: list[FilterSpec], params: Mapping[str, Any]) -> list[FilterSpec]:
    from ..registry import get

    names = {s.name for s in specs}
    out = []
    used: set[str] = set()
    for s in specs:
        fields = get(s.name, "filter").Config.model_fields
        p = s.kwargs
        for key, value in params.items():
            head, _, rest = key.partition(".")
            if head in names and rest:
                if head == s.name:
                    set_dotted(p, rest, value)
                    used.add(key)
            elif head in fields:
                set_dotted(p, key, value)
                used.add(key)
        out.append(FilterSpec.of((s.name, p)) if p != s.kwargs else s)
    unused = set(params) - used
    if unused:
        raise ConfigError(f"parameters {sorted(unused)} match no field of the filters {sorted(names)}")
    return out


def _execute(tasks, index, jobs, scheduler):
    if scheduler:
        try:
            from distributed import Client, as_completed as dask_completed
        except ImportError as exc:
            raise ConfigError("scheduler= needs dask distributed: pip install 'fusionkit[distributed]'") from exc
        with Client(scheduler) as client:
            futures = {client.submit(evaluate, s, t, pure=False): i for i, (s, t) in zip(index, tasks)}
            for fut in dask_completed(futures):
                yield futures[fut], fut.result()
        return
    if jobs <= 1:
        for i, (s, t) in zip(index, tasks):
            yield i, evaluate(s, t)
        return
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(evaluate, s, t): i for i, (s, t) in zip(index, tasks)}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()


def _bar(n, progress):
    if progress is False or n == 0 or (progress is None and not sys.stderr.isatty()):
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=n, desc="bench", unit="run")


@dataclass
class BenchResult:
    """The records of a :func:`bench` run, with pandas-free tables."""

    records: list[dict[str, Any]] = field(default_factory=list)

    @property
    def filters(self) -> list[str]:
        return list(dict.fromkeys(r["filter"] for r in self.records))

    @property
    def trials(self) -> list[str]:
        return list(dict.fromkeys(r["trial"] for r in self.records))

    def value(self, filter_label: str, trial: str, metric: str = "score") -> float:
        for r in self.records:
            if r["filter"] == filter_label and r["trial"] == trial:
                v = r["metrics"].get(metric)
                return float("nan") if v is None else float(v)
        return float("nan")

    def by_group(self, metric: str = "score") -> dict[str, dict[str, float]]:
        """``{filter: {group: mean of metric over the group's trials}}`` (errors excluded)."""
        out: dict[str, dict[str, list[float]]] = {}
        for r in self.records:
            v = r["metrics"].get(metric)
            if r["error"] or v is None:
                continue
            for g in r["groups"] or ["all"]:
                out.setdefault(r["filter"], {}).setdefault(g, []).append(v)
        return {f: {g: float(np.mean(v)) for g, v in gs.items()} for f, gs in out.items()}

    def summary(self, metric: str = "score") -> list[dict[str, Any]]:
        """Per filter: mean metric over its trials, trials run, failures, median samples/s."""
        rows = []
        for f in self.filters:
            rs = [r for r in self.records if r["filter"] == f]
            vals = [r["metrics"].get(metric) for r in rs if not r["error"] and r["metrics"].get(metric) is not None]
            sps = [r["samples_per_s"] for r in rs if r["samples_per_s"]]
            dims = sorted({r["dimension"] for r in rs if r["dimension"]})
            rows.append({"filter": f, "dimension": "/".join(dims), "mean": float(np.mean(vals)) if vals else float("nan"),
                         "trials": len(vals), "failed": sum(bool(r["error"]) for r in rs),
                         "samples_per_s": float(np.median(sps)) if sps else float("nan")})
        return rows

    def table(self, format: str = "table", metric: str = "score") -> str:
        """``table`` (aligned text), ``markdown``, ``csv`` or ``json`` (all records)."""
        if format == "json":
            return json.dumps(self.records, indent=1)
        if format not in ("table", "markdown", "csv"):
            raise ConfigError(f"format must be table, markdown, csv or json, got {format!r}")
        trials = self.trials
        head = ["trial"] + self.filters
        rows = []
        for t in trials:
            row = [t]
            for f in self.filters:
                r = next((r for r in self.records if r["filter"] == f and r["trial"] == t), None)
                if r is None:
                    row.append("")
                elif r.get("skipped"):
                    row.append("n/a")
                elif r["error"]:
                    row.append("error")
                else:
                    v = r["metrics"].get(metric)
                    mark = "*" if r.get("cached") and format != "csv" else ""
                    row.append("-" if v is None else f"{v:.2f}{mark}")
            rows.append(row)
        summ = {s["filter"]: s for s in self.summary(metric)}
        rows.append(["mean"] + [f"{summ[f]['mean']:.2f}" if summ[f]["trials"] else "n/a" for f in self.filters])
        rows.append(["samples/s"] + [f"{summ[f]['samples_per_s']:,.0f}" if summ[f]["trials"] else "n/a"
                                     for f in self.filters])
        rows.append(["judged as"] + [summ[f]["dimension"] for f in self.filters])
        rows += self._navigation_rows(trials)
        if format == "csv":
            return "\n".join(",".join(c.replace(",", "") if i else c for i, c in enumerate(r)) for r in [head] + rows)
        cached = sum(bool(r.get("cached")) for r in self.records)
        note = (f"*: from the cache ({cached} of {len(self.records)} results): computed earlier with the same code, "
                f"config and file; --no-cache (cache=False) recomputes") if cached else ""
        if format == "markdown":
            lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            lines += ["| " + " | ".join(r) + " |" for r in rows]
            if note:
                lines.append(f"\n{note}")
            errors = [r for r in self.records if r["error"]]
            for r in errors:
                lines.append(f"\nerror: {r['filter']} on {r['trial']}: {r['error']}")
            return "\n".join(lines)
        widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
        fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
        lines = [fmt.format(*head), "-" * (sum(widths) + 2 * len(widths))]
        lines += [fmt.format(*r) for r in rows]
        if note:
            lines.append(note)
        for r in self.records:
            if r["error"]:
                lines.append(f"error: {r['filter']} on {r['trial']}: {r['error']}")
        return "\n".join(lines)

    def _navigation_rows(self, trials) -> list[list[str]]:
        """GNSS trials: tilt and heading with GNSS, velocity (m/s) and position (m) errors
        (filters that output them, e.g. ins-gnss), one row each per trial."""
        rows = []
        for t in trials:
            recs = {r["filter"]: r for r in self.records if r["trial"] == t and not r["error"]}
            if not any("tilt_gnss" in r["metrics"] for r in recs.values()):
                continue
            for key, fmt in (("tilt_gnss", "{:.3f}"), ("heading_gnss", "{:.3f}"), ("velocity", "{:.3f}"),
                             ("position", "{:.2f}"), ("position_gap_end", "{:.2f}")):
                vals = [recs[f]["metrics"].get(key) if f in recs else None for f in self.filters]
                if any(v is not None for v in vals):
                    rows.append([f"{t} {key}"] + ["-" if v is None else fmt.format(v) for v in vals])
        return rows

    def group_table(self, metric: str = "score", format: str = "markdown") -> str:
        """Mean metric per filter (columns) and group (rows)."""
        bg = self.by_group(metric)
        groups = list(dict.fromkeys(g for r in self.records for g in (r["groups"] or ["all"])))
        head = ["group"] + self.filters
        rows = [[g] + [f"{bg.get(f, {}).get(g, float('nan')):.2f}" for f in self.filters] for g in groups]
        if format == "markdown":
            return "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
                             + ["| " + " | ".join(r) + " |" for r in rows])
        return "\n".join(",".join(r) for r in [head] + rows)
