"""Run filters over trials side by side: in-process, in a process pool, or on a Dask cluster.

``bench(filters, data)`` returns a :class:`BenchResult` of records, one per (filter, trial)::

    {"filter": label, "name": registered name, "params": {...}, "config": full config,
     "trial": ..., "dataset": ..., "groups": [...], "dimension": "6D" | "9D",
     "reference": None | "ground truth" | "autopilot estimate" | ...,
     "metrics": {...}, "samples": N, "seconds": ..., "samples_per_s": ...,
     "backend": ..., "versions": {...}, "error": None | "Type: message", "cached": bool,
     "skipped": None | reason (e.g. a GNSS-aided filter on a recording without GNSS)}

Results are cached by a hash of (filter, full config, trial file fingerprint, versions, the code
that runs) in ``bench/`` under ``$FUSIONKIT_CACHE``, else ``$FUSIONKIT_CACHE_DIR`` (default
``$XDG_CACHE_HOME/fusionkit`` or ``~/.cache/fusionkit``), so a re-run is instant. The
code is fusionkit's own source files and, for a third-party plugin (the filter, or a plugin a
pipeline composes), its distribution, version and source files (``versions["plugins"]``): fixing
a plugin re-runs it. A record read from the cache has ``cached`` True, and tables mark it ``*``;
it takes the label and params of the filter asked for, not of the run that saved it (specs with
the same full config share an entry: ``vqf`` and ``vqf[tau_acc=3.0]``, 3 being the default).
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

from .._sources import fusionkit_hash, source_hash
from ..config import set_dotted
from ..errors import ConfigError, FusionkitError
from ..offline import OfflineFilter
from .datasets import Trial, discover
from .metrics import trial_metrics
from .report import HIDDEN_BY_DEFAULT, METRIC_LABELS, aiding, dimension, metric_label, not_applicable

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
    if isinstance(v, str) and v[:1] in ("[", "{"):  # (not `in "[{"`: the empty string is in every string)
        return json.loads(v)
    return v


def _code_fingerprint() -> str:
    """A hash of fusionkit's own source files: a code change invalidates cached results even
    when the version number did not change (development installs)."""
    return fusionkit_hash()[:12]


@functools.lru_cache(maxsize=1)
def _distributions() -> dict[str, list[str]]:
    from importlib import metadata

    return metadata.packages_distributions()


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
        digest = source_hash(top)
        if digest is None:
            return None
        dists = _distributions().get(top, [])
        version = ",".join(f"{d} {_version_of(d)}" for d in dists) or "(no distribution)"
        out[top] = f"{version} {digest[:12]}"
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
        rec_out["dimension"] = dimension(f, rec)
        rec_out["aiding"] = aiding(f, rec)  # (before the run: a run that fails keeps it, not "6D" for poisson)
        rec_out["reference"] = None if rec.truth is None else rec.meta.get("truth_kind", "ground truth")
        if warmup:  # compile numba loops outside the timing
            f.run(rec.slice(0, min(len(rec), 200)), progress=False)
        t0 = time.perf_counter()
        res = f.run(rec, progress=False)
        rec_out["seconds"] = time.perf_counter() - t0
        rec_out["samples_per_s"] = len(rec) / rec_out["seconds"]
        rec_out["backend"] = res.diagnostics.get("backend")
        rec_out["metrics"] = trial_metrics(res, rec, rec_out["dimension"])
        na = not_applicable(rec_out["aiding"], gnss_heading=bool(f.requires_gnss), rec=rec)
        rec_out["not_applicable"] = {k: why for k, why in na.items() if k in rec_out["metrics"]}
        for k in rec_out["not_applicable"]:  # a number it cannot have (e.g. a 96 deg "total") is not reported
            rec_out["metrics"][k] = None
    except Exception as exc:  # a filter failing on one trial must not stop the bench
        lines = [line.strip() for line in f"{type(exc).__name__}: {exc}".splitlines() if line.strip()]
        rec_out["error"] = f"{lines[0]} {'; '.join(lines[1:])}".rstrip()  # one line, the whole reason (as the CLI)
        rec_out["traceback"] = traceback.format_exc(limit=4)
    return _jsonable(rec_out)


def _cache_dir(cache_dir) -> Path:
    """``bench/`` under ``cache_dir``, else ``$FUSIONKIT_CACHE``, else fusionkit's cache directory
    (``$FUSIONKIT_CACHE_DIR``, ``$XDG_CACHE_HOME/fusionkit`` or ``~/.cache/fusionkit``, where the
    compiled loops go: README). It ignored ``$FUSIONKIT_CACHE_DIR``, so a user who moved the cache
    there still read and wrote ``~/.cache/fusionkit/bench``."""
    from .._loopgen import cache_base

    d = Path(cache_dir or os.environ.get("FUSIONKIT_CACHE") or cache_base()) / "bench"
    d.mkdir(parents=True, exist_ok=True)
    return d


def _spec_key(spec: FilterSpec) -> str:
    """The part of the cache key that does not depend on the trial; "" for a filter that cannot
    be cached (it does not build, or its source cannot be found)."""
    try:
        f = spec.build()
        cfg = f.config.model_dump(mode="json")
        code = _plugin_code(f)
        # a wrapper keeps the inner filter's config (the offline mode): its own options and class count too
        wrapper = {"class": f"{type(f).__module__}.{type(f).__qualname__}",
                   "options": f.options() if isinstance(f, OfflineFilter) else None}
    except Exception:  # unbuildable: never cached
        return ""
    if code is None:
        return ""
    blob = json.dumps({"name": spec.name, "config": cfg, "v": _versions(), "plugins": code,
                       "peer": _peer_version(spec.name), "filter": wrapper}, sort_keys=True)
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

    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:  # (0, -1 ran serially, unsaid)
        raise ConfigError(f"jobs must be a whole number of worker processes >= 1, got {jobs!r}")
    if isinstance(filters, (str, FilterSpec)):  # one filter: a name was iterated letter by letter ('p' unknown)
        filters = [filters]
    specs = _apply_params([FilterSpec.of(f) for f in filters], params or {})
    if not specs:
        raise ConfigError("no filters to run: name at least one (e.g. filters=['recommended'])")
    for s in specs:
        get(s.name, "filter")  # unknown names fail now, with close matches
        _validate(s)
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
                if hit.is_file():  # another spec with this config may have saved it: its label and
                    # params were kept, and a sweep found no value under its own label
                    records[i] = {**json.loads(hit.read_text()), "filter": s.label, "name": s.name,
                                  "params": _jsonable(s.kwargs), "cached": True}
                    continue
        todo.append(i)
    bar = _bar(len(todo), progress, cached=len(tasks) - len(todo))
    for i, rec in _execute([tasks[i] for i in todo], todo, jobs, scheduler):
        records[i] = rec
        if cdir is not None and keys[i] and rec["error"] is None:
            (cdir / f"{keys[i]}.json").write_text(json.dumps(rec))
        if bar is not None:
            bar.update(f"{rec['filter']} on {rec['trial']}",
                       "error" if rec["error"] else "skipped" if rec.get("skipped") else "done")
    if bar is not None:
        bar.close()
    return BenchResult([r for r in records if r is not None])


def _against_truth(record: dict) -> bool:
    """Whether ``record``'s errors are against a truth: its reference is one ("ground truth", a
    simulator's "ground truth (simulator)") or it has none (then it has no errors either). A PX4 log
    without a simulator's truth carries the autopilot's own estimate: the agreement with another
    filter, not an error, and it was averaged with the real trials' errors."""
    ref = record.get("reference")
    return ref is None or str(ref).startswith("ground truth")


def _validate(spec: FilterSpec) -> None:
    """Build ``spec`` once before any trial runs: a configuration it refuses (a value, a
    composition) is one error with its whole reason, as ``fusionkit run`` gives it. It was an error
    record per trial, cut to its first line ("invalid configuration for filter 'x':"). Any other
    exception (a plugin's own bug) is left to each trial's record."""
    try:
        spec.build()
    except FusionkitError:
        raise
    except Exception:
        pass


#: what ``make`` takes beside a filter's config fields, so ``--param offline=true`` (and a sweep's
#: ``--grid offline=true,false``, the offline mode's own options with it) reach it: refused as "no
#: field of the filters" before
MAKE_OPTIONS = {"offline": "run forward and backward in time (fusionkit.offline)",
                **{k: "an option of the offline mode (with offline=True)" for k in OfflineFilter.OPTIONS}}


def _apply_params(specs: list[FilterSpec], params: Mapping[str, Any]) -> list[FilterSpec]:
    from ..registry import get

    names = {s.name for s in specs}
    out = []
    used: set[str] = set()
    for s in specs:
        fields = {**get(s.name, "filter").Config.model_fields, **MAKE_OPTIONS}  # (make's offline=: the build checks it)
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


def _bar(n, progress, cached: int = 0, desc: str = "bench"):
    """Progress on stderr: a tqdm bar on a terminal; with ``progress=True`` and no terminal (a
    log, a pipe), one line per finished run; ``None``: the bar on a terminal, else nothing."""
    if progress is False or n == 0:
        return None
    tty = sys.stderr.isatty()
    if not tty and not progress:
        return None
    return Progress(n, desc, cached=cached, bar=tty)


class Progress:
    """Progress of ``n`` steps on stderr: a tqdm bar (``bar=True``), or one line per step,
    ``[3/16] poisson on 01_undisturbed_slow_rotation_A: done in 1.2 s`` (a log or a pipe)."""

    def __init__(self, n: int, desc: str, cached: int = 0, bar: bool | None = None):
        self.n, self.k, self.t, self.desc = n, 0, time.perf_counter(), desc
        self.bar = None
        if sys.stderr.isatty() if bar is None else bar:
            try:
                from tqdm import tqdm

                self.bar = tqdm(total=n, desc=desc, unit="run", file=sys.stderr)
            except ImportError:  # pragma: no cover
                pass
        if self.bar is None and cached:
            print(f"{desc}: {cached} runs served from the cache, {n} to run", file=sys.stderr, flush=True)

    def update(self, label: str, status: str = "done") -> None:
        self.k += 1
        if self.bar is not None:
            self.bar.set_postfix_str(label, refresh=False)
            self.bar.update(1)
            return
        now = time.perf_counter()
        print(f"[{self.k}/{self.n}] {label}: {status} in {now - self.t:.1f} s", file=sys.stderr, flush=True)
        self.t = now

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


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
        """``{filter: {group: mean of metric over the group's trials}}`` (errors excluded, and the
        trials whose reference is not a truth: :func:`_against_truth`)."""
        out: dict[str, dict[str, list[float]]] = {}
        for r in self.records:
            v = r["metrics"].get(metric)
            if r["error"] or v is None or not _against_truth(r):
                continue
            for g in r["groups"] or ["all"]:
                out.setdefault(r["filter"], {}).setdefault(g, []).append(v)
        return {f: {g: float(np.mean(v)) for g, v in gs.items()} for f, gs in out.items()}

    def summary(self, metric: str = "score") -> list[dict[str, Any]]:
        """Per filter: mean metric over its trials, trials run, failures, median samples/s, and how
        it was judged (``dimension``: 6D/9D; ``aiding``: 9D, 6D or gyro-only). The mean leaves out the
        trials whose reference is not a truth (:func:`_against_truth`: a PX4 log's autopilot estimate);
        their rows in the tables say what they were compared with."""
        rows = []
        for f in self.filters:
            rs = [r for r in self.records if r["filter"] == f]
            vals = [r["metrics"].get(metric) for r in rs
                    if not r["error"] and r["metrics"].get(metric) is not None and _against_truth(r)]
            sps = [r["samples_per_s"] for r in rs if r["samples_per_s"]]
            dims = sorted({r["dimension"] for r in rs if r["dimension"]})
            aid = sorted({r.get("aiding") or r["dimension"] for r in rs if r["dimension"]})
            rows.append({"filter": f, "dimension": "/".join(dims), "aiding": "/".join(aid),
                         "mean": float(np.mean(vals)) if vals else float("nan"),
                         "trials": len(vals), "failed": sum(bool(r["error"]) for r in rs),
                         "samples_per_s": float(np.median(sps)) if sps else float("nan")})
        return rows

    def _other_references(self) -> dict[str, str]:
        """``{trial: its reference}`` for the trials whose reference is not a truth."""
        return {r["trial"]: r["reference"] for r in self.records if not _against_truth(r)}

    @property
    def scored_trials(self) -> list[str]:
        """The trials whose errors are against a truth (:func:`_against_truth`): what means and sweeps
        average over."""
        other = self._other_references()
        return [t for t in self.trials if t not in other]

    def metrics(self) -> list[str]:
        """The metrics the records have, in the tables' order (``report.METRIC_LABELS`` first,
        then any other by name; ``score``, ``tilt`` and ``heading`` are left to explicit requests, and
        a metric no filter can have is left out)."""
        seen = dict.fromkeys(k for r in self.records for k in list(r["metrics"] or {}) + list(r.get("not_applicable") or {}))
        order = [m for m in METRIC_LABELS if m in seen] + [m for m in seen if m not in METRIC_LABELS]
        return [m for m in order if m not in HIDDEN_BY_DEFAULT and len(self.not_applicable(m)) < len(self.filters)]

    def _record(self, f: str, t: str) -> dict | None:
        return next((r for r in self.records if r["filter"] == f and r["trial"] == t), None)

    def not_applicable(self, metric: str) -> dict[str, str]:
        """``{filter: reason}`` for the filters that cannot have ``metric`` on any of their trials."""
        out = {}
        for f in self.filters:
            rs = [r for r in self.records if r["filter"] == f and r["metrics"]]  # run, with a reference
            why = [(r.get("not_applicable") or {}).get(metric) for r in rs]
            if rs and all(why):  # (trials with and without a magnetometer: each reason once)
                out[f] = "; ".join(dict.fromkeys(why))
        return out

    def _cell(self, r: dict | None, metric: str) -> str:
        if r is None:
            return ""
        if r.get("skipped"):
            return "n/a"
        if r["error"]:
            return "error"
        if (r.get("not_applicable") or {}).get(metric):
            return "n/a"
        v = r["metrics"].get(metric)
        return "-" if v is None else f"{v:.2f}" + ("*" if r.get("cached") else "")

    def _number(self, r: dict, metric: str) -> str:
        """``metric`` of record ``r`` for CSV: the number at full precision, or "" where the table
        says n/a, - or error."""
        if r.get("skipped") or r["error"] or (r.get("not_applicable") or {}).get(metric):
            return ""
        v = r["metrics"].get(metric)
        return "" if v is None else repr(float(v))

    def sections(self, metrics: list[str] | None = None) -> list[tuple[str, list[str], list[list[str]], str]]:
        """``(title, header, rows, note)`` per metric (6D inclination and 9D total apart), then one
        for speed (none when every run failed: the errors are all there is). A filter that cannot
        have a metric is left out of its section; ``note`` says why."""
        out = []
        other = self._other_references()  # (the trials', the same for every metric)
        for m in self.metrics() if metrics is None else metrics:
            na = self.not_applicable(m)
            filters = [f for f in self.filters if f not in na]
            if not filters:
                continue
            rows = [[t + (f" (vs {other[t]})" if t in other else "")] + [self._cell(self._record(f, t), m)
                                                                          for f in filters] for t in self.trials]
            summ = {s["filter"]: s for s in self.summary(m)}
            rows.append(["mean over trials"] + [f"{summ[f]['mean']:.2f} ({summ[f]['trials']})" if summ[f]["trials"]
                                                 else "n/a" for f in filters])
            note = "; ".join([f"{f}: n/a ({why})" for f, why in na.items()] + (
                [f"not in the mean: {', '.join(other)} (a reference that is not a truth)"] if other else []))
            out.append((metric_label(m), ["trial"] + filters, rows, note))
        summ = self.summary()
        if self.records and all(r["error"] for r in self.records):  # every run failed: no speed to show
            return out
        rows = [["samples/s"] + [f"{s['samples_per_s']:,.0f}" if np.isfinite(s["samples_per_s"]) else "n/a"
                                 for s in summ],
                ["aiding"] + [s["aiding"] or "-" for s in summ]]
        out.append(("speed (samples/s, median over trials, one core, compile excluded) and aiding "
                    "(9D: magnetometer, 6D: accelerometer only, gyro-only: no correction)",
                    ["filter"] + self.filters, rows, ""))
        return out

    def table(self, format: str = "table", metric: str | None = None) -> str:
        """``table`` (aligned text), ``markdown``, ``csv`` (one row per record, numbers at full
        precision, a ``cached`` column true/false) or ``json`` (all records). One section per
        metric (``metric``: only that one), then speed; the mean row says over how many trials."""
        if format == "json":
            return json.dumps(self.records, indent=1)
        if format not in ("table", "markdown", "csv"):
            raise ConfigError(f"format must be table, markdown, csv or json, got {format!r}")
        metrics = self.metrics() if metric is None else [metric]
        if format == "csv":  # for programs: full precision, plain numbers ("0.60*" was rounded and marked)
            head = ["filter", "trial", "aiding"] + metrics + ["samples_per_s", "cached", "error"]
            lines = [",".join(head)]
            for r in self.records:
                cells = [r["filter"], r["trial"], r.get("aiding") or r["dimension"] or ""]
                cells += [self._number(r, m) for m in metrics]
                cells += ["" if not r["samples_per_s"] else repr(float(r["samples_per_s"])),
                          "true" if r.get("cached") else "false", r["error"] or r.get("skipped") or ""]
                lines.append(",".join(c.replace(",", ";") for c in cells))
            return "\n".join(lines)
        blocks = [_render(title, head, rows, note, format) for title, head, rows, note in self.sections(metrics)]
        errors = [f"error: {r['filter']} on {r['trial']}: {r['error']}" for r in self.records if r["error"]]
        cached = sum(bool(r.get("cached")) for r in self.records)
        if cached:
            blocks.append(f"*: from the cache ({cached} of {len(self.records)} results): computed earlier with the same "
                          "code, config and file; --no-cache (cache=False) recomputes")
        return "\n\n".join(blocks + (["\n".join(errors)] if errors else []))

    def group_table(self, metric: str | None = None, format: str = "table") -> str:
        """Mean per filter (columns) and group (rows), one table per metric (or only ``metric``), in
        ``format`` as :meth:`table` (``table``, ``markdown`` or ``csv``). Anything but markdown
        came out as csv, and ``fusionkit bench --format table`` printed them in markdown."""
        if format not in ("table", "markdown", "csv"):
            raise ConfigError(f"format must be table, markdown or csv, got {format!r}")
        groups = list(dict.fromkeys(g for r in self.records for g in (r["groups"] or ["all"])))
        blocks = []
        for m in self.metrics() if metric is None else [metric]:
            bg, na = self.by_group(m), self.not_applicable(m)
            filters = [f for f in self.filters if f not in na]
            rows = [[g] + [f"{bg.get(f, {}).get(g, float('nan')):.2f}" for f in filters] for g in groups]
            if filters:
                blocks.append(_render(metric_label(m) + ", mean per group", ["group"] + filters, rows,
                                      "; ".join(f"{f}: n/a" for f in na), format))
        return "\n\n".join(blocks)


def _render(title: str, head: list[str], rows: list[list[str]], note: str, format: str) -> str:
    """One titled table: aligned text, markdown or csv."""
    if format == "markdown":
        lines = [f"**{title}**", "", "| " + " | ".join(head) + " |", "|" + "---|" + "---:|" * (len(head) - 1)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
    elif format == "csv":
        lines = [f"# {title}"] + [",".join(c.replace(",", "") for c in r) for r in [head] + rows]
    else:
        widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
        fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
        lines = [title, fmt.format(*head), "-" * (sum(widths) + 2 * len(widths))] + [fmt.format(*r) for r in rows]
    if note:
        lines.append(("" if format != "markdown" else "\n") + note)
    return "\n".join(lines)
