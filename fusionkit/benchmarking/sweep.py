"""Parameter sweeps: a grid over any filter's config fields.

Reports, as in the BROAD paper, the *trial-agnostic good parameters* (TAGP: the one parameter
set with the lowest mean error over all trials) and the per-trial minimum (the best parameter
set for each trial separately, an optimistic bound no single setting reaches).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import build_config, set_dotted
from ..errors import ConfigError
from .report import HIDDEN_BY_DEFAULT, METRIC_LABELS, metric_label, metric_unit
from .runner import MAKE_OPTIONS, BenchResult, FilterSpec, bench

__all__ = ["sweep", "SweepResult"]


@dataclass
class SweepResult:
    filter: str
    grid: dict[str, list[Any]]
    metric: str
    result: BenchResult
    combos: list[dict[str, Any]]

    def _label(self, combo) -> str:
        return FilterSpec.of((self.filter, combo)).label

    def _show(self, combo) -> dict[str, Any]:
        """Only the swept fields of a parameter set."""
        flat = {}
        for k in self.grid:
            v = combo
            for part in k.split("."):
                v = v[part]
            flat[k] = v
        return flat

    def mean_by_combo(self) -> list[tuple[dict[str, Any], float]]:
        """Each parameter set's mean over the trials scored against a truth (a PX4 log's autopilot
        estimate is left out: the agreement with another filter would choose the parameters)."""
        trials = self.result.scored_trials
        out = []
        for c in self.combos:
            vals = [self.result.value(self._label(c), t, self.metric) for t in trials]
            out.append((c, float(np.mean(vals)) if np.all(np.isfinite(vals)) else float("nan")))
        return out

    @property
    def tagp(self) -> tuple[dict[str, Any], float]:
        """(parameters, mean error) of the best common parameter set."""
        ok = [(c, v) for c, v in self.mean_by_combo() if np.isfinite(v)]
        if not ok:
            raise ConfigError("no parameter set ran on every trial")
        return min(ok, key=lambda cv: cv[1])

    def per_trial_minimum(self) -> dict[str, tuple[dict[str, Any], float]]:
        out = {}
        for t in self.result.scored_trials:
            vals = [(c, self.result.value(self._label(c), t, self.metric)) for c in self.combos]
            vals = [(c, v) for c, v in vals if np.isfinite(v)]
            if vals:
                out[t] = min(vals, key=lambda cv: cv[1])
        return out

    def report(self) -> str:
        """The sweep as text, every number with its unit (the metric's: deg, or m and m/s for the
        navigation metrics, which were labelled deg)."""
        u = metric_unit(self.metric)
        lines = [f"sweep of {self.filter} over {self.grid} ({len(self.combos)} sets, metric {self.metric}: "
                 f"{metric_label(self.metric)})", "",
                 f"| parameters | mean over trials ({u}) |", "|---|---:|"]
        for c, v in sorted(self.mean_by_combo(), key=lambda cv: (np.isnan(cv[1]), cv[1])):
            lines.append(f"| {self._show(c)} | {v:.3f} |")
        p, v = self.tagp
        ptm = self.per_trial_minimum()
        lines += ["", f"TAGP (best common parameters): {self._show(p)} -> {v:.3f} {u}",
                  f"per-trial minimum (mean of each trial's best): {np.mean([v for _, v in ptm.values()]):.3f} {u}", "",
                  f"| trial | best parameters | error ({u}) |", "|---|---|---:|"]
        lines += [f"| {t} | {self._show(c)} | {v:.3f} |" for t, (c, v) in ptm.items()]
        other = self.result._other_references()
        if other:
            lines += ["", "not in the means: " + ", ".join(f"{t} (vs {ref}, not a truth)" for t, ref in other.items())]
        return "\n".join(lines)


def sweep(filter_name: str, grid: dict[str, list[Any]], data, *, metric: str = "score", base: dict | None = None,
          **bench_kwargs) -> SweepResult:
    """Run ``filter_name`` for every combination of ``grid`` values (plus fixed ``base``)."""
    from ..registry import get

    if not grid:
        raise ConfigError("the grid is empty: give at least one field with values")
    cls = get(filter_name, "filter")
    fields = {**cls.Config.model_fields, **MAKE_OPTIONS}  # (make's offline=, checked by the build)
    for k in grid:
        if k.split(".")[0] not in fields:
            raise ConfigError(f"{filter_name} has no parameter {k!r}; it has {sorted(fields)}")
    if metric not in (*METRIC_LABELS, *HIDDEN_BY_DEFAULT):
        raise ConfigError(f"metric must be one of {sorted({*METRIC_LABELS, *HIDDEN_BY_DEFAULT})}, got {metric!r}")
    keys = list(grid)
    fixed = _flatten(base or {})
    for k in keys:  # (the grid's value replaced the fixed one, or a table of it dropped the others)
        same = [b for b in fixed if b == k or b.startswith(k + ".") or k.startswith(b + ".")]
        if same:
            raise ConfigError(f"{k!r} is both in the grid and a fixed parameter ({same[0]!r}): give it in one place")
    combos = [dict(zip(keys, vals)) for vals in itertools.product(*(grid[k] for k in keys))]
    specs = [FilterSpec.of((filter_name, _nest({**fixed, **c}))) for c in combos]
    for s in specs:  # a value the filter refuses is an error now, not a set that "ran on no trial"
        build_config(cls.Config, None, {k: v for k, v in s.kwargs.items() if k not in MAKE_OPTIONS},
                     f"filter {filter_name!r} ({s.label})")
    res = bench(specs, data, **bench_kwargs)
    return SweepResult(filter_name, grid, metric, res, [dict(s.kwargs) for s in specs])


def _flatten(nested: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"motion": {"window": 0.2}}`` -> ``{"motion.window": 0.2}``: fixed parameters and grid
    values meet leaf by leaf (a grid on ``motion.window`` with a fixed ``motion.arm_after``: both;
    the grid's ``motion`` table replaced the fixed one whole, dropping ``arm_after``)."""
    out: dict[str, Any] = {}
    for k, v in nested.items():
        if isinstance(v, dict) and v:
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _nest(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in flat.items():
        set_dotted(out, k, v)
    return out
